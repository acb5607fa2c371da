"""Resynthesis, plots, WAV output and the ``mpipe invert`` command."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import soundfile

from mpipe.acoustics.reflection import reflection_function
from mpipe.cli.main import main
from mpipe.inversion.fit.step1 import step1
from mpipe.inversion.output import resynthesis as rs
from mpipe.inversion.output.tracks_plot import plot_tracks
from mpipe.inversion.settings import InversionConfig
from mpipe.inversion.table.records import window_frame
from mpipe.inversion.table.tables import blank_row
from mpipe.measurement.calibration import load_calibration
from mpipe.reed.bore_kernel import prepare_bore
from mpipe.reed.model import simulate
from mpipe.reed.parameters import ReedParameters

FS = 100_000.0
ROOT = Path(__file__).resolve().parents[3]
TABLE1 = ReedParameters(
    k=8.66e6, S=7.62e-5, y_m=4e-4, p_m=1800.0, lam=0.013, m=0.05, g=3000.0, k_c=8.23e10
)


@pytest.fixture(scope="module")
def setup():
    cal = load_calibration(ROOT / "calibration" / "simplified_clarinet.yaml")
    air = cal.air_properties()
    kernel = prepare_bore(reflection_function(cal.bore, air, fs=FS), air)
    return kernel, air.rho, simulate(TABLE1, kernel, 34000)


def table_of(reed, starts):
    rows = []
    for i, s in enumerate(starts):
        row = blank_row(s, 2000, FS, InversionConfig(), cold=True)
        row.update(
            {
                f: getattr(reed, f)
                for f in ("k", "S", "y_m", "p_m", "m", "g", "lam", "k_c", "y_c", "alpha")
            }
        )
        row.update(window=i, status="ok", error="")
        rows.append(row)
    return window_frame(rows)


def test_resynthesis_with_true_parameters_matches(setup):
    kernel, _, sim = setup
    res = rs.resynthesise(
        table_of(TABLE1, [30000, 32000]),
        sim.p,
        sim.u,
        FS,
        kernel,
        InversionConfig(),
        zero_mean=False,
    )
    sl = slice(30000, 34000)
    np.testing.assert_allclose(res.p[sl], sim.p[sl], atol=1e-3)
    np.testing.assert_allclose(res.u[sl], sim.u[sl], rtol=1e-6, atol=1e-12)
    assert np.all(np.isnan(res.p[:30000]))


def test_plots_and_wav(setup, tmp_path):
    _, rho, sim = setup
    sl = slice(30000, 32000)
    t = np.arange(sim.p.size) / FS
    s1 = step1(sim.p[sl], sim.u[sl], FS, rho=rho, lam=0.013)
    paths = [
        rs.plot_signals(t[sl], sim.p[sl], sim.u[sl], sim.p[sl], sim.u[sl], tmp_path / "s.png"),
        rs.plot_flow_pressure(sim.p[sl], sim.u[sl], FS, s1, tmp_path / "f.png"),
        rs.plot_history(np.geomspace(100, 1, 50), tmp_path / "h.png"),
        plot_tracks(table_of(TABLE1, [30000, 32000]), tmp_path / "t.png"),
    ]
    for p in paths:
        assert p.read_bytes()[:4] == b"\x89PNG"
    wav = rs.write_wav(tmp_path / "p.wav", sim.p[sl], FS)
    data, rate = soundfile.read(wav)
    assert rate == 100000 and np.max(np.abs(data)) == pytest.approx(1.0)
    assert soundfile.info(wav).subtype == "FLOAT"


def test_invert_command(setup, tmp_path, capsys):
    _, _, sim = setup
    npz = tmp_path / "sim.npz"
    np.savez(npz, t=sim.t, p=sim.p, u=sim.u, fs=FS)
    pipe = tmp_path / "pipe.yaml"
    pipe.write_text(
        f"calibration: {ROOT / 'calibration' / 'simplified_clarinet.yaml'}\n"
        "inversion: {free: [p_m], max_evaluations: 40, warm_max_evaluations: 20}\n"
        "executor: {workers: 1}\n"
    )
    out = tmp_path / "out"
    args = [
        "invert",
        str(npz),
        "--pipeline",
        str(pipe),
        "-o",
        str(out),
        "--start",
        "0.28",
        "--end",
        "0.33",
    ]  # the note starts at the take's first ms: two of its windows lie in the span
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "2 windows: 2 ok" in printed
    # issue 33: a summary, not the whole windows table (windows.csv holds it)
    assert "t_start_s" not in printed and "n_evaluations" not in printed
    assert "medians over the 2 ok windows: k " in printed and " Pa/m" in printed
    for name in (
        "windows.csv",
        "signals.png",
        "flow_pressure.png",
        "history.png",
        "tracks.png",
        "resynthesis.wav",
        "run.json",
    ):
        assert (out / name).is_file()
    assert main(args) == 2  # outputs exist, no --force
    assert "--force" in capsys.readouterr().err
    assert main([*args, "--force"]) == 0
    # issue 33: exactly one window (0.30 - 0.28 < 0.02 in floating point) is one window
    one = [*args[:-4], "--start", "0.28", "--end", "0.30", "--force"]
    capsys.readouterr()
    assert main(one) == 0
    assert "1 windows: 1 ok" in capsys.readouterr().out


def test_invert_command_bad_npz(tmp_path, capsys):
    npz = tmp_path / "bad.npz"
    np.savez(npz, p=np.zeros(10), fs=FS)
    pipe = ROOT / "pipelines" / "simplified_clarinet.yaml"
    assert main(["invert", str(npz), "--pipeline", str(pipe), "-o", str(tmp_path / "o")]) == 2
    assert "missing key 'u'" in capsys.readouterr().err


def test_two_periods_end_the_window_from_an_upward_crossing():
    # 250 Hz sine over a 20 ms window: two periods are 800 samples, the last ones that
    # start where the pressure crosses its mean upwards
    n = np.arange(2000)
    p = 300.0 * np.sin(2 * np.pi * 250.0 * (n + 37) / FS)
    show = rs.two_periods(p, FS, 250.0)
    assert show.stop - show.start == 800 and show.stop <= 2000
    assert p[show.start - 1] < 0 <= p[show.start]
    assert show.start + 400 + 800 > 2000  # no later crossing leaves two periods
    assert rs.two_periods(p, FS, np.nan) == slice(0, 2000)  # no pitch: the whole window
    assert rs.two_periods(p, FS, 80.0) == slice(0, 2000)  # fewer than two periods


def test_the_note_is_shown_by_an_ok_sustain_window_and_every_label_says_its_status():
    rows = pd.DataFrame({
        "window": [0, 1, 2, 3], "t_start_s": [0.1, 0.12, 0.14, 0.16],
        "t_end_s": [0.12, 0.14, 0.16, 0.18], "error": ["", "", "", ""],
        "phase": ["onset", "sustain", "sustain", "release"],
        "status": ["ok", "ok", "ok", "not-converged"], "relative_residual": [0.1, 0.2, 0.3, 0.01],
        "status_reason": ["", "", "", "the search stopped at its budget"],
    })  # fmt: skip
    assert rs.pick_window(rows)["window"] == 2  # nearest the middle (0.14 s) of the sustain
    bad = rows.assign(status="high-residual")
    assert rs.pick_window(bad)["window"] == 3  # none ok: the smallest residual, not ok
    assert rs.pick_window(rows.assign(error="x")) is None
    words = rs.window_words(rows.iloc[3])
    assert words.startswith("window 3 at 0.160 s (release): status not-converged")
    assert "budget" in words
    assert rs.window_words(rows.iloc[1]).endswith("status ok")
