"""``mpipe run`` end to end on a short virtual take: accuracy, resuming, errors."""

import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from mpipe.cli.main import main
from mpipe.cli.virtual_takes import SynthOptions, make_take
from mpipe.core.errors import OutputExistsError
from mpipe.pipeline.orchestration import STAGES, run_take
from mpipe.pipeline.settings import load_pipeline

ROOT = Path(__file__).resolve().parents[2]
# true value and tolerance of the median over the windows: the front end's errors (the
# flow within a few per cent, the DC of u lost) reach the parameters; the contact stiffness
# is the least sensitive of them (F2 changes little with it), so its bound is wider
TRUTH = {
    "k": (8.66e6, 0.05),
    "S": (7.62e-5, 0.05),
    "y_m": (4e-4, 0.05),
    "p_m": (1800.0, 0.05),
    "lam": (0.013, 0.05),
    "k_c": (8.23e10, 0.2),
}


@pytest.fixture(scope="module")
def take(tmp_path_factory):
    folder = tmp_path_factory.mktemp("take")
    options = SynthOptions(duration_s=0.62, snr_db=70.0, seed=7)
    return make_take(
        ROOT / "calibration" / "simplified_clarinet.yaml",
        ROOT / "calibration" / "reed_table1.yaml",
        folder / "short.flac",
        options,
    )


@pytest.fixture(scope="module")
def pipeline(tmp_path_factory, take):
    data = yaml.safe_load((ROOT / "pipelines" / "simplified_clarinet.yaml").read_text())
    data["calibration"] = str(take.calibration)
    data["executor"] = {"kind": "local", "workers": 1}
    data["inversion"]["hop_s"] = 0.04  # three windows between 0.25 s and 0.37 s
    data["conditioning"] = {"edge_s": 0.25}
    path = tmp_path_factory.mktemp("pipe") / "pipeline.yaml"
    path.write_text(yaml.safe_dump(data))
    return load_pipeline(path)


@pytest.fixture(scope="module")
def finished(tmp_path_factory, take, pipeline):
    out = tmp_path_factory.mktemp("run")
    lines = []
    run = run_take(pipeline, take.calibration, [take.audio], out, say=lines.append)
    return out, run, lines


def test_full_pipeline_recovers_the_truth(finished):
    out, run, lines = finished
    assert [r.status for r in run.records.values()] == ["done"] * len(STAGES)
    assert len(lines) > len(STAGES)  # a line per stage, plus verdicts
    assert run.records["validation"].summary["passed"]
    windows = pd.read_csv(run.folder / "inversion" / "windows.csv", keep_default_na=False)
    assert len(windows) >= 2 and (windows["error"] == "").all()
    # measured (zero-mean) path through the front end: within a few per cent
    for name, (true, tolerance) in TRUTH.items():
        got = windows[name].median()
        assert abs(got / true - 1) < tolerance, (name, got, true)
    assert windows["relative_residual"].max() < 0.02
    # every searched parameter carries a standard error, the correlations a side file
    ok = windows[windows["status"] == "ok"]
    for name in ("k", "y_m", "p_m", "p_M", "gamma", "zeta"):
        assert (pd.to_numeric(ok[f"{name}_se"]) > 0).all(), name
    corr = pd.read_csv(run.folder / "inversion" / "correlations.csv")
    assert corr["correlation"].abs().max() <= 1 + 1e-9 and len(corr) >= len(windows)
    report = (run.folder / "report.html").read_text()
    assert "PASS" in report and "Reed parameters per window" in report and "overlay 1" in report
    # self-contained: every figure embedded, none linked
    assert report.count('src="data:image/png;base64,') >= 6 and 'src="' not in report.replace(
        'src="data:', ""
    )
    assert "uncertainty" in report.lower()
    # the report says which temperature the bore model used, and what the verdict compared
    fitted = windows["kernel_temperature_c"].iloc[0]
    assert "fitted to the playing" in report and f"{fitted:.4g}" in report
    assert "Harmonics of the note" in report or "Resonances: theory" in report
    for stage in STAGES:
        assert (run.folder / stage / "manifest.json").exists()


def test_report_says_whether_the_temperature_drifts(finished):
    # The virtual take's air is at a constant 20 degC: the separation's summary holds the
    # take-level value with its pooled SE (within 3 SE of the truth), the drift in words,
    # and the report carries that sentence beside the figure with its error bands.
    _, run, _ = finished
    sep = run.records["separation"].summary
    assert sep["track_model"] in ("constant", "linear", "smooth")
    assert sep["temperature_se_c_take"] > 0
    assert abs(sep["temperature_c_take"] - 20.0) < 3 * sep["temperature_se_c_take"]
    report = (run.folder / "report.html").read_text()
    assert sep["drift_sentence"].split(";")[0] in report
    assert "standard error bands" in report


def test_interrupted_run_resumes_and_redoes_nothing_done(finished, take, pipeline, monkeypatch):
    # the take's one fit (inversion.estimator: take) is one computation: a Ctrl-C during it
    # leaves no inversion manifest, and the rerun redoes the inversion only, to the same
    # table (the per-window estimator's checkpoints: tests/inversion/whole_take/test_tracking.py)
    import mpipe.inversion.whole_take.take_estimate as joint  # where the take's fit is called

    out, run, _ = finished
    before = pd.read_csv(run.folder / "inversion" / "windows.csv", keep_default_na=False)
    partial = run.folder / "inversion" / "partial"
    assert not partial.exists()  # a finished stage keeps no resumable state (issue 19)
    (run.folder / "inversion" / "manifest.json").unlink()
    real = joint.fit_take
    calls = []

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(joint, "fit_take", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run_take(pipeline, take.calibration, [take.audio], out, say=lambda s: None)
    assert not (run.folder / "inversion" / "manifest.json").exists()
    monkeypatch.setattr(joint, "fit_take", lambda *a, **k: calls.append(1) or real(*a, **k))
    again = run_take(pipeline, take.calibration, [take.audio], out, say=lambda s: None)
    status = {k: r.status for k, r in again.records.items()}
    assert status["separation"] == status["translation"] == status["validation"] == "skipped"
    assert status["inversion"] == "done" and len(calls) == 1
    assert not partial.exists()
    after = pd.read_csv(run.folder / "inversion" / "windows.csv", keep_default_na=False)
    np.testing.assert_allclose(after["k"], before["k"], rtol=1e-9)
    # a finished run is skipped whole, and other settings never overwrite it silently
    third = run_take(pipeline, take.calibration, [take.audio], out, say=lambda s: None)
    assert {r.status for r in third.records.values()} == {"skipped"}
    from dataclasses import replace

    changed = replace(pipeline, inversion=replace(pipeline.inversion, warm_max_evaluations=99))
    with pytest.raises(OutputExistsError, match="--force"):
        run_take(changed, take.calibration, [take.audio], out, say=lambda s: None)


def test_malformed_pipeline_and_take_give_clear_errors(tmp_path, take, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("calibration: nowhere.yaml\ninversion:\n  window: 0.02\n")
    assert main(["run", str(bad), str(take.audio), "-o", str(tmp_path / "o")]) == 2
    assert "inversion.window: unknown key" in capsys.readouterr().err
    good = tmp_path / "good.yaml"
    good.write_text(f"calibration: {take.calibration}\n")
    stereo = tmp_path / "stereo.wav"
    import soundfile as sf

    sf.write(stereo, np.zeros((20000, 2)), 100000)
    assert main(["run", str(good), str(stereo), "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "stereo.wav: has 2 channels" in err
    # with several takes, a bad one is reported and the others go on
    other = tmp_path / "stereo2.wav"
    sf.write(other, np.zeros((20000, 2)), 100000)
    assert main(["run", str(good), str(stereo), str(other), "-o", str(tmp_path / "o")]) == 1
    assert "2 of 2 takes failed" in capsys.readouterr().out
    assert main(["run", str(good), str(tmp_path / "missing.flac"), "-o", str(tmp_path)]) == 2
    assert "no such take file" in capsys.readouterr().err


def test_every_door_gives_the_same_table(finished, take, pipeline, tmp_path):
    # `mpipe run`, `mpipe separate` + `mpipe invert` and the Python API fit the same kernel
    # temperature and invert the same windows: the same numbers to 0.1 %.
    import mpipe
    from mpipe.inversion.preparation.conditioning import plan_inversion
    from mpipe.inversion.settings import PARAMETER_NAMES
    from mpipe.inversion.whole_take.front_end import FrontEnd
    from mpipe.measurement.calibration import load_calibration
    from mpipe.measurement.separation.stage import separate
    from mpipe.measurement.takes import read_take
    from mpipe.measurement.translation import translate

    _, run, _ = finished
    via_run = pd.read_csv(run.folder / "inversion" / "windows.csv", keep_default_na=False)
    sep_dir, inv_dir = tmp_path / "sep", tmp_path / "inv"
    argv = ["separate", str(take.audio), str(take.calibration), "--pipeline", pipeline.source]
    assert main([*argv, "-o", str(sep_dir)]) == 0
    argv = ["invert", str(sep_dir / "mouthpiece.npz"), "--pipeline", pipeline.source]
    assert main([*argv, "-o", str(inv_dir)]) == 0
    via_cli = pd.read_csv(inv_dir / "windows.csv", keep_default_na=False)

    cal = load_calibration(take.calibration)
    t = read_take(take.audio, cal)
    sep = separate(t.pressures, t.fs, cal, pipeline.separation)
    tr = translate(sep.p0, sep.u0, t.fs, cal, pipeline.translation, sep.temperature_track())
    inv = pipeline.inversion
    plan = plan_inversion(tr.p, t.fs, pipeline.conditioning, inv.window_s, inv.hop_s)
    starts = plan.loc[plan["invert"], "start"].tolist()
    # the front end's estimate with its SEs, as mpipe run passes it: its temperature's SE is
    # the prior of the take's temperature (without it the prior is the weak default)
    front = FrontEnd(tr.p0, tr.u0, tr.temperature_c, sep.track.level, sep.track.level_se,
                     pipeline.separation.band_edge_hz + pipeline.separation.band_taper_hz,
                     pipeline.translation)  # fmt: skip
    via_api = mpipe.invert_take(
        tr.p,
        tr.u,
        t.fs,
        cal,
        inv,
        pipeline.executor,
        windows=starts,
        temperature_c=tr.temperature_c,
        front_end=front,
    ).tracking.table

    # issue 33: load_run reads the folders of mpipe invert and mpipe separate too, and no
    # finished command leaves its lock file behind (it is held while the command runs:
    # tests/core/test_io.py)
    from_invert, from_separate = mpipe.load_run(inv_dir), mpipe.load_run(sep_dir)
    np.testing.assert_array_equal(from_invert.tables["windows"]["t_start_s"], via_cli["t_start_s"])
    assert {"windows", "plan", "segments"} <= set(from_invert.tables)
    assert from_invert.manifests["invert"]["mouthpiece"] == str(
        (sep_dir / "mouthpiece.npz").resolve()
    )
    assert from_invert.unit("windows.k") == "Pa/m"
    assert from_separate.fs == 100_000.0 and from_separate.unit("mouthpiece.p") == "Pa"
    assert from_separate.signals["mouthpiece.p"].size == from_separate.signals["mouthpiece.u"].size
    assert {"blocks", "impedance", "resonances"} <= set(from_separate.tables)
    for folder in (sep_dir, inv_dir, run.folder):
        assert not (folder / ".mpipe.lock").exists(), folder

    assert np.isfinite(via_run["kernel_temperature_se_c"]).all()  # fitted, with its SE
    for other in (via_cli, via_api):
        np.testing.assert_array_equal(other["t_start_s"], via_run["t_start_s"])
        np.testing.assert_allclose(other["kernel_temperature_c"], via_run["kernel_temperature_c"])
        assert list(other["status"]) == list(via_run["status"])
        for name in PARAMETER_NAMES:
            np.testing.assert_allclose(other[name], via_run[name], rtol=1e-3, err_msg=name)


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def test_load_run_gives_tables_and_signals_with_units(finished):
    import mpipe

    out, run, _ = finished
    data = mpipe.load_run(out)
    assert data.folder == run.folder and data.fs == 100_000.0
    assert data.verdict == "pass"
    assert set(data.tables) == {"blocks", "impedance", "resonances", "harmonics", "plan",
                                "windows", "segments"}  # fmt: skip
    # what was played: one note (the virtual take), its windows carry their phase, pitch,
    # level and the fitted reed's opening; the reed's opening signal is in the outputs
    notes = data.tables["segments"][data.tables["segments"]["label"] == "note"]
    assert len(notes) == 1 and notes["ok_windows"].iloc[0] >= 1
    w = data.tables["windows"]
    assert set(w["phase"]) <= {"onset", "sustain", "release"}
    assert (w["segment"] == notes["segment"].iloc[0]).all()
    assert w["spl_db"].between(130, 175).all() and np.isfinite(w["pitch_cents"]).all()
    ok = w[w["status"] == "ok"]
    assert (ok["h_mean"] > 0).all() and (ok["h_mean"] < ok["y_m"]).all()
    assert ok["closed_fraction"].between(0, 1).all()
    assert data.unit("windows.h_mean") == "m" and data.unit("segments.p_m_median") == "Pa"
    assert data.unit("windows.spl_db") == "dB" and data.unit("windows.pitch_cents") == "cent"
    h = data.signals["resynthesis.h"]
    assert h.size == data.signals["mouthpiece.p"].size and np.nanmax(h) < ok["y_m"].max()
    assert data.unit("resynthesis.h") == "m"
    assert data.unit("windows.k") == "Pa/m" and data.unit("windows.t_start_s") == "s"
    assert data.unit("mouthpiece.p") == "Pa" and data.unit("mouthpiece.u") == "m³/s"
    assert data.unit("blocks.temperature_c") == "°C" and data.unit("plan.f0_hz") == "Hz"
    p = data.signals["mouthpiece.p"]
    assert p.ndim == 1 and p.size == data.signals["mouthpiece.u"].size
    # the table is read from Parquet at full precision; the CSV carries 10 digits
    csv = pd.read_csv(run.folder / "inversion" / "windows.csv", keep_default_na=False)
    np.testing.assert_allclose(csv["k"], data.tables["windows"]["k"], rtol=1e-9)
    import csv as csv_module

    with open(run.folder / "inversion" / "windows.csv", newline="") as f:
        rows = list(csv_module.reader(f))[1:]
    numeric = [tok for row in rows for tok in row if _is_number(tok)]
    assert numeric and not any(len(tok) > 17 for tok in numeric)
    with pytest.raises(TypeError):
        data.tables["windows"] = None


def test_a_run_prints_short(finished):
    # issue 33: printing a RunData dumped every table and signal
    import mpipe

    data = mpipe.load_run(finished[0])
    text = repr(data)
    assert text.startswith("RunData(") and len(text.splitlines()) < 30 and len(text) < 2500
    n = len(data.tables["windows"])
    assert f"tables['windows']: {n} rows x " in text
    line = next(x for x in text.splitlines() if "mouthpiece.p [Pa]" in x)
    assert line.startswith(f"  signals ({data.signals['mouthpiece.p'].size} samples): ")
    assert "validation: pass" in text and "fs: 100000 Hz" in text
    statuses = data.tables["windows"]["status"].value_counts()
    assert all(f"{count} {status}" in text for status, count in statuses.items())
    html = data._repr_html_()
    assert html.startswith("<table>") and "tables[&#x27;windows&#x27;]" in html
    assert len(html) < 5000


def test_load_run_finds_the_run_in_the_folder_above(finished, tmp_path):
    # Issue 19: docs/python_api.md's mpipe.load_run("demo_output") (the run is in demo_output/run)
    import mpipe

    out, run, _ = finished
    (tmp_path / "run").symlink_to(out, target_is_directory=True)
    assert mpipe.load_run(tmp_path).folder.resolve() == run.folder.resolve()


@pytest.fixture(scope="module")
def wrong_bore(tmp_path_factory, take):
    """The take's calibration with a main bore 3 % longer: the validation must FAIL."""
    data = yaml.safe_load(Path(take.calibration).read_text())
    data["bore"]["segments"][-1]["x_end"] *= 1.03
    for mic in data["microphones"]:
        if mic.get("calibration"):
            mic["calibration"] = str(Path(take.calibration).parent / mic["calibration"])
    path = tmp_path_factory.mktemp("wrong") / "long.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_failed_validation_stops_the_run_and_separate_exits_non_zero(
    tmp_path, take, pipeline, wrong_bore, capsys, monkeypatch
):
    import mpipe.pipeline.orchestration as orch

    assert main(["separate", str(take.audio), str(wrong_bore), "-o", str(tmp_path / "s")]) == 1
    out = capsys.readouterr().out
    assert "impedance validation: FAIL" in out and "validation FAILED" in out
    # the inputs that can do this are named, the bore's first (harmonics 100 deg off)
    assert "suspect inputs: the bore's length" in out and "microphones'" in out, out
    assert (tmp_path / "s" / "mouthpiece.npz").exists()
    with np.load(tmp_path / "s" / "mouthpiece.npz") as mp:
        assert {"u_noise_freq_hz", "u_noise_psd", "p_noise_psd"} <= set(mp.files)
        assert mp["u_noise_psd"].shape == mp["u_noise_freq_hz"].shape
    # mpipe run stops before the inversion, and says how to go on (the take alone, without
    # its own calibration beside it: it would be read with that one)
    pipe = tmp_path / "pipe.yaml"
    pipe.write_text(f"calibration: {wrong_bore}\nexecutor: {{kind: local, workers: 1}}\n")
    (tmp_path / "bare").mkdir()
    audio = tmp_path / "bare" / take.audio.name
    shutil.copy(take.audio, audio)
    code = main(["run", str(pipe), str(audio), "-o", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert code == 1 and "stopped before the inversion" in err  # a result, not a usage error
    assert "--accept-failed-validation" in err
    assert not (tmp_path / "r" / take.audio.stem / "inversion").exists()
    # with --accept-failed-validation it goes on to the inversion (stopped here by a probe)
    reached = []

    def probe(*args, **kwargs):
        reached.append(True)
        raise ValueError("probe: inversion reached")

    monkeypatch.setattr(orch, "stage_inversion", probe)
    code = main(["run", str(pipe), str(audio), "-o", str(tmp_path / "r"),
                 "--accept-failed-validation"])  # fmt: skip
    assert reached and "inverting despite the FAILED validation" in capsys.readouterr().out


@pytest.mark.parametrize("scale", [1000.0, 0.001])
def test_a_flow_in_the_wrong_unit_is_refused_in_one_line(
    finished, pipeline, tmp_path, capsys, scale
):
    # the user's path: the mouthpiece file of `mpipe run` with its flow in L/s (x1000) or
    # scaled by 0.001, given to `mpipe invert`: no window inverted, one line saying why
    out, run, _ = finished
    assert run.records["inversion"].summary["take_checks"] == []  # the right unit passes
    with np.load(run.folder / "translation" / "mouthpiece.npz") as mp:
        data = {k: mp[k] for k in mp.files}
    data["u"] = data["u"] * scale
    bad = tmp_path / "mouthpiece.npz"
    np.savez(bad, **data)
    code = main(["invert", str(bad), "--pipeline", pipeline.source, "-o", str(tmp_path / "i")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and not (tmp_path / "i" / "windows.csv").exists()
    assert "implausible" in err and "m^3/s expected" in err and len(err.splitlines()) == 1, err


def test_run_says_at_once_that_the_bore_is_measured_and_how_its_extension_fits(tmp_path):
    from mpipe.core.errors import UserError

    cal = ROOT / "calibration" / "simplified_clarinet.yaml"
    assert main(["impedance", str(cal), "--fmin", "40", "--fmax", "3000", "--df", "1",
                 "--csv", str(tmp_path / "z.csv")]) == 0  # fmt: skip
    data = yaml.safe_load(cal.read_text())
    data["bore"]["measured"] = "z.csv"
    for mic in data.get("microphones", []):
        mic.pop("calibration", None)
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(data))
    said: list[str] = []
    cfg = load_pipeline(ROOT / "pipelines" / "simplified_clarinet.yaml")
    with pytest.raises((UserError, FileNotFoundError)):  # no take: stops at the first stage
        run_take(cfg, tmp_path / "m.yaml", [tmp_path / "none.flac"], tmp_path / "out",
                 say=said.append)  # fmt: skip
    line = next(s for s in said if "the bore is measured" in s)
    assert "misfit is" in line and "dB rms" in line and "cents" in line
