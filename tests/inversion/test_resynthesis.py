"""Resynthesis, plots, WAV output and the ``mpipe invert`` command."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import soundfile

from mpipe.acoustics.reflection import reflection_function
from mpipe.cli.main import main
from mpipe.inversion import resynthesis as rs
from mpipe.inversion.records import window_frame
from mpipe.inversion.settings import InversionConfig
from mpipe.inversion.step1 import step1
from mpipe.inversion.tables import blank_row
from mpipe.measurement.calibration import load_calibration
from mpipe.reed.bore_kernel import prepare_bore
from mpipe.reed.model import simulate
from mpipe.reed.parameters import ReedParameters

FS = 100_000.0
ROOT = Path(__file__).resolve().parents[2]
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
        rs.plot_tracks(table_of(TABLE1, [30000, 32000]), tmp_path / "t.png"),
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
        "0.3",
        "--end",
        "0.34",
    ]
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


def test_track_bands_stay_positive_and_lines_break_between_notes():

    from mpipe.inversion.resynthesis import _band, _breaks, _split

    x = np.array([1.0, 2.0, 4.0])
    se = np.array([0.001, 2.0, 40.0])  # relative SE 0.1 %, 100 %, 1000 %
    lo, hi = _band(x, se)
    assert np.all(lo > 0)  # a linear band would reach -2, -76
    np.testing.assert_allclose([lo[0], hi[0]], [1 - 0.002, 1 + 0.002], rtol=1e-5)  # linear
    np.testing.assert_allclose(lo * hi, x**2)  # symmetric in log space
    neg_lo, _ = _band(np.array([-1.0]), np.array([0.1]))
    assert neg_lo[0] == pytest.approx(-1.2)  # not positive: the linear band
    table = pd.DataFrame({"segment": [1, 1, 1, 3, 3, 3]})
    t = np.array([0.1, 0.12, 0.14, 0.5, 0.52, 0.58])
    np.testing.assert_array_equal(_breaks(table, t), [3, 5])  # a new note; a 60 ms gap
    assert np.isnan(_split(t, _breaks(table, t))[[3, 6]]).all()
