"""A batch of takes side by side: each take's table is the one it gets run alone."""

import shutil
from pathlib import Path

import pandas as pd
import pytest
import yaml

from mpipe.cli.main import main
from mpipe.cli.virtual_takes import SynthOptions, make_take
from mpipe.pipeline.batch import batch_workers, summary_lines
from mpipe.pipeline.orchestration import run_take
from mpipe.pipeline.settings import load_pipeline
from mpipe.pipeline.take_calibration import take_calibrations

ROOT = Path(__file__).resolve().parents[2]


#: Mouth pressure (Pa) of each take: three players of different loudness. Each file is
#: scaled to its own peak, so each take has its own sensitivities (Pa per full-scale unit,
#: 20-90 % apart): read with another take's calibration its p_m would be off as much.
PLAYERS = (1600.0, 2300.0, 1900.0)


@pytest.fixture(scope="module")
def takes(tmp_path_factory):
    """Three short takes of different players (mouth pressures) and noise."""
    folder = tmp_path_factory.mktemp("takes")
    reed = yaml.safe_load((ROOT / "calibration" / "reed_table1.yaml").read_text())
    made = []
    for i, p_m in enumerate(PLAYERS):
        path = folder / f"reed{i}.yaml"
        path.write_text(yaml.safe_dump({**reed, "p_m": p_m}))
        options = SynthOptions(duration_s=0.62, snr_db=60.0, seed=11 + i)
        made.append(
            make_take(ROOT / "calibration" / "simplified_clarinet.yaml", path,
                      folder / f"take{i}.flac", options)
        )  # fmt: skip
    return made


def _pipeline(folder: Path, take, workers: int, scheduler: str | None = None) -> Path:
    data = yaml.safe_load((ROOT / "pipelines" / "simplified_clarinet.yaml").read_text())
    data["calibration"] = str(take.calibration)
    data["executor"] = {"kind": "local", "workers": workers}
    if scheduler is not None:
        data["executor"] = {"kind": "dask", "scheduler": scheduler}
    data["conditioning"] = {"edge_s": 0.25}
    data["inversion"]["hop_s"] = 0.04  # three windows between 0.25 s and 0.37 s
    # light inversion: the executors are tested here, the estimator elsewhere (32 design
    # points: with 16, the soft player's cold start missed its basin on the DC-corrected kernel)
    data["inversion"].update(design_points=32, local_starts=2)
    path = folder / f"pipeline{workers}{'dask' if scheduler else ''}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _windows(folder: Path) -> pd.DataFrame:
    table = pd.read_csv(folder / "inversion" / "windows.csv", keep_default_na=False)
    return table.drop(columns="wall_time_s")


@pytest.fixture(scope="module")
def alone(takes, tmp_path_factory):
    """Each take run alone, in this process: ``OUT/<take>`` of every take."""
    folder = tmp_path_factory.mktemp("alone")
    cfg = load_pipeline(_pipeline(folder, takes[0], 1))
    for t in takes:  # each with its own calibration copy
        run_take(cfg, t.calibration, [t.audio], folder, say=lambda s: None)
    return folder


def _light_search_checks(line: str) -> bool:
    """A CHECK line of what the light search can cause: a narrow cold start, and its note."""
    reason = line.split("CHECK: ", 1)[1]
    return reason.startswith(("the cold start's minimum", "the model cannot play note"))


def test_a_batch_side_by_side_gives_each_take_its_own_table(takes, alone, tmp_path, capsys):
    pipe = _pipeline(tmp_path, takes[0], 2)
    assert batch_workers(load_pipeline(pipe), len(takes)) == 2
    bad = tmp_path / "empty.flac"
    bad.write_bytes(b"not audio")
    good = [str(t.audio) for t in takes]
    argv = ["run", str(pipe), str(bad), *good, "-o", str(tmp_path / "batch")]
    assert main(argv) == 1  # the bad take fails, the others go on
    out = capsys.readouterr().out
    assert "4 takes:" in out and "  empty: failed" in out
    # the light search of these tests (2 short searches) may leave a cold start agreed by
    # one, in a wrong minimum: a take-level CHECK naming it (and the note whose windows it
    # left not ok); nothing else may be
    checks = [line for line in out.splitlines() if "]     CHECK: " in line]
    assert all(_light_search_checks(line) for line in checks), "\n".join(checks)
    for t, p_m in zip(takes, PLAYERS, strict=True):
        name = t.audio.stem
        batch = _windows(tmp_path / "batch" / name)
        pd.testing.assert_frame_equal(_windows(alone / name), batch)
        assert f"[{name}] 5/6 inversion: done" in out and f"  {name}: ok;" in out
        # each take read with its own calibration (found beside it): its p_m is right in the
        # windows called ok (a wrong minimum of the light search is flagged, not ok)
        ok = batch[batch["status"] == "ok"]
        assert len(ok) and abs(ok["p_m"].median() / p_m - 1) < 0.05, (name, ok["p_m"].median())
    # resumable as a single run: everything skipped the second time
    code = main(["run", str(pipe), *good, "-o", str(tmp_path / "batch")])
    assert code == (1 if checks else 0)  # a CHECK is exit status 1
    assert capsys.readouterr().out.count("already done") == 18


def _sensitivity(path: Path) -> float:
    return yaml.safe_load(path.read_text())["microphones"][0]["sensitivity"]


def test_a_calibration_given_that_differs_from_a_takes_own_is_refused(takes, tmp_path, capsys):
    # the takes' sensitivities differ by 20 % or more: one calibration for all would scale p_m
    ratios = [_sensitivity(t.calibration) / _sensitivity(takes[0].calibration) for t in takes]
    assert min(abs(r - 1) for r in ratios[1:]) > 0.2, ratios
    pipe = _pipeline(tmp_path, takes[0], 1)
    argv = ["run", str(pipe), *[str(t.audio) for t in takes], "-o", str(tmp_path / "o"),
            "--calibration", str(takes[0].calibration)]  # fmt: skip
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "take1.flac: has its own calibration" in err, err
    assert not (tmp_path / "o").exists()  # refused before any work
    # the same calibration given explicitly, or a copy of it elsewhere, is no conflict
    copy = tmp_path / "copy.yaml"
    copy.write_text(takes[0].calibration.read_text())
    assert take_calibrations([[takes[0].audio]], copy, Path("x")) == [takes[0].calibration]


def test_a_take_read_with_another_takes_calibration_ends_check(takes, tmp_path, capsys):
    # take 1 without its calibration copy (its sidecar kept), run with take 0's
    for path in (takes[1].audio, takes[1].sidecar):
        shutil.copy(path, tmp_path / path.name)
    pipe = _pipeline(tmp_path, takes[0], 1)
    argv = ["run", str(pipe), str(tmp_path / takes[1].audio.name), "-o", str(tmp_path / "o"),
            "--calibration", str(takes[0].calibration)]  # fmt: skip
    assert main(argv) == 1
    out = capsys.readouterr().out
    assert "CHECK: the take is read with microphone sensitivities" in out, out
    assert "another take's calibration" in out and "1 of 1 takes CHECK" in out
    windows = pd.read_csv(tmp_path / "o" / "take1" / "inversion" / "windows.csv")
    assert windows["take_checks"].str.contains("sidecar take1.yaml").all()


def test_one_take_or_one_worker_is_not_a_batch(takes, tmp_path):
    pipe = load_pipeline(_pipeline(tmp_path, takes[0], 2))
    assert batch_workers(pipe, 1) == 1
    one = load_pipeline(_pipeline(tmp_path, takes[0], 1))
    assert batch_workers(one, 5) == 1
    lines = summary_lines([([tmp_path / "x.flac"], ValueError("broken\nmore"), 1.0)])
    assert lines == ["  x: failed (1.0 s): broken"]


def test_a_batch_on_a_real_cluster_gives_each_take_its_own_table(
    takes, alone, tmp_path, capsys, dask_cluster
):
    pipe = _pipeline(tmp_path, takes[0], 0, scheduler=dask_cluster[1])
    argv = ["run", str(pipe), *[str(t.audio) for t in takes], "-o", str(tmp_path / "b")]
    code = main(argv)
    out = capsys.readouterr().out
    # only the light search's cold-start CHECK may end it with exit status 1
    checks = [line for line in out.splitlines() if "]     CHECK: " in line]
    assert all(_light_search_checks(line) for line in checks), "\n".join(checks)
    assert code == (1 if checks else 0)
    for t in takes:
        name = t.audio.stem
        pd.testing.assert_frame_equal(_windows(alone / name), _windows(tmp_path / "b" / name))
        assert f"  {name}: ok;" in out


def test_each_take_of_a_batch_names_itself_in_library_log_lines(monkeypatch, caplog, tmp_path):
    # issue 33: the library's log lines (not only the stage lines) carry the take's name
    import logging
    from types import SimpleNamespace

    import mpipe.pipeline.batch as batch

    def fake_run_take(cfg, cal, take, out, *args):
        logging.getLogger("mpipe.inversion.whole_take.tracking").info("inverting %d windows", 3)
        return "done"

    monkeypatch.setattr(batch, "run_take", fake_run_take)
    cfg = SimpleNamespace(executor=SimpleNamespace(workers=1))
    takes = [[tmp_path / "one.flac"], [tmp_path / "two.flac"]]
    with caplog.at_level(logging.INFO):
        results = list(batch.run_takes(cfg, tmp_path / "cal.yaml", takes, tmp_path / "out"))
        list(batch.run_takes(cfg, tmp_path / "cal.yaml", takes[:1], tmp_path / "out"))
    assert [r for _, r, _ in results] == ["done", "done"]
    assert caplog.messages == [
        "[one] inverting 3 windows",
        "[two] inverting 3 windows",
        "inverting 3 windows",  # one take alone: its lines as before
    ]
