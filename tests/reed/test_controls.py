"""Control curves: one run when nothing varies, pieces that add up to it, tongue holds."""

import numpy as np
import pytest

from mpipe.acoustics.bore import find_resonances, input_impedance
from mpipe.reed.controls import control_curves, hold_shut, make_controls, play, vibrato
from mpipe.reed.model import ModelState, simulate

FS = 100_000.0


def test_constant_controls_are_the_plain_simulation_bit_for_bit(setup):
    *_, reed, _, kernel = setup
    n = 8000
    pm = reed.p_m * (1 + 0.1 * np.arange(1, n + 1) / n)
    old = simulate(reed, kernel, n, mouth_pressure=pm, onset_s=0.01, noise_std_pa=20, seed=4)
    run = play(reed, kernel, make_controls(FS, n, pm, k=reed.k), onset_s=0.01,
               noise_std_pa=20, seed=4)  # fmt: skip
    assert len(run.pieces) == 1
    for name in ("p", "u", "y", "mouth_pressure"):
        assert np.array_equal(getattr(run, name), getattr(old, name)), name


@pytest.mark.parametrize(("method", "rtol"), [("direct", 0.0), ("fast", 1e-12)])
def test_pieces_with_the_state_carried_give_one_run(setup, method, rtol):
    # a y_m curve that moves only in its last sample: every 1 ms cell before it is cut into
    # its own piece with the same value, so the pieces must reproduce one run
    *_, reed, _, kernel = setup
    n = 6000
    ym = np.full(n, reed.y_m)
    ym[-1] *= 0.999
    run = play(reed, kernel, make_controls(FS, n, reed.p_m, y_m=ym), onset_s=0.005,
               method=method)  # fmt: skip
    assert len(run.pieces) == 2 and run.pieces[0].stop == n - 100
    one = simulate(reed, kernel, n, onset_s=0.005, method=method)
    head = slice(0, n - 100)
    # every piece boundary of the first 5900 samples was a fresh call to the kernel
    pieces = play(reed, kernel, make_controls(FS, n, reed.p_m, y_m=ym), onset_s=0.005,
                  method=method, chunk_s=3.7e-4)  # fmt: skip
    assert len(pieces.pieces) == 2
    for r in (run, pieces):
        scale = np.max(np.abs(one.p))
        np.testing.assert_allclose(r.p[head], one.p[head], rtol=0, atol=rtol * scale)


def test_varying_reed_converges_as_the_pieces_shrink(setup):
    *_, reed, _, kernel = setup
    n = 15_000

    def ramp(t):
        return np.clip((t - 0.03) / 0.1, 0, 1)

    ctl = make_controls(FS, n, reed.p_m, y_m=lambda t: reed.y_m * (1 - 0.15 * ramp(t)),
                        k=lambda t: reed.k * (1 + 0.1 * ramp(t)))  # fmt: skip
    ref = play(reed, kernel, ctl, onset_s=0.01, chunk_s=5e-5).p
    errors = []
    for chunk in (4e-3, 1e-3, 2.5e-4):
        run = play(reed, kernel, ctl, onset_s=0.01, chunk_s=chunk)
        errors.append(np.sqrt(np.mean((run.p - ref) ** 2) / np.mean(ref**2)))
    assert errors[0] > errors[1] > errors[2], errors
    assert errors[1] < 2e-3, errors  # the default 1 ms piece
    # the model did play the ramp: the closing pressure k y_m fell by 1 - 0.85 * 1.1
    p_close = run.parameter("k") * run.parameter("y_m")
    assert p_close[-1] / p_close[0] == pytest.approx(0.85 * 1.1, rel=1e-3)


def test_a_tongue_hold_shuts_the_reed_and_the_bore_rings_down(setup):
    *_, reed, _, kernel = setup
    n = 40_000
    ctl = make_controls(FS, n, reed.p_m, tongue=[(0.15, 0.35)])
    run = play(reed, kernel, ctl, onset_s=0.01)
    held = run.tongued
    assert held.sum() == 20_000 and held[14_999] and not held[14_998]
    assert np.all(run.u[held] == 0) and np.all(run.h[held] == 0)
    assert np.all(run.y[held] == reed.y_m)
    # the entry shut (u = 0), the bore rings at the peaks of its input impedance and decays
    # as its first resonance does: amplitude ~ exp(-pi f1 t / Q1), f1 and Q1 from Z_in
    blocks = run.p[15_000:33_000].reshape(-1, 2000)
    rms = np.sqrt(np.mean(blocks**2, axis=1))
    assert np.all(np.diff(rms) < 0), rms
    cal, air = setup[0], setup[1]
    f = np.arange(50.0, 400.0, 0.05)
    first = find_resonances(f, input_impedance(cal.bore, 2 * np.pi * f, air), 1.0, 1)[0]
    rate = -np.polyfit(0.02 * np.arange(rms.size), np.log(rms), 1)[0]
    assert rate == pytest.approx(np.pi * first.frequency_hz / first.q, rel=0.1)
    # and the reed plays again after the release
    after = run.p[-5000:]
    assert np.std(after) > 0.3 * np.std(run.p[5000:14_000])


def test_hold_shut_from_rest_stays_silent(setup):
    *_, reed, _, kernel = setup
    state = ModelState(np.zeros(kernel.n_taps), 0.0, 0.0, 0.0)
    signals, end = hold_shut(kernel, state, np.full(500, 1000.0), reed.y_m)
    assert np.all(signals["p"] == 0) and end.dp == 1000.0 and end.y == reed.y_m


def test_control_curves_hold_what_was_played(setup):
    *_, reed, _, kernel = setup
    n = 5000
    t = np.arange(1, n + 1) / FS
    ym = reed.y_m * (1 - 0.1 * t / t[-1])
    pm = reed.p_m * vibrato(t, 5.0, 0.08)
    run = play(reed, kernel, make_controls(FS, n, pm, y_m=ym, tongue=[(0.02, 0.03)]))
    curves = control_curves(run, 1e-3)
    assert curves["control_fs"] == 1000.0 and curves["control_y_m"].dtype == np.float32
    cells = ym.reshape(-1, 100).mean(axis=1)
    np.testing.assert_allclose(curves["control_y_m"], cells, rtol=1e-6)
    np.testing.assert_allclose(curves["control_p_m"], pm.reshape(-1, 100).mean(1), rtol=1e-6)
    np.testing.assert_allclose(curves["control_p_M"], reed.k * cells, rtol=1e-6)
    # held for 0.02 <= t < 0.03 s: samples 1999..2998 (t = (i + 1) / fs), in cells 19..29
    cells_held = np.flatnonzero(curves["control_tongued"] > 0)
    assert cells_held.tolist() == list(range(19, 30))
    assert np.sum(curves["control_tongued"]) == pytest.approx(10.0)
    assert curves["control_k"][0] == np.float32(reed.k)


def test_controls_refuse_bad_curves():
    with pytest.raises(ValueError, match="y_m: expected 10 finite values"):
        make_controls(FS, 10, 1800.0, y_m=np.ones(9))
    with pytest.raises(ValueError, match="p_c: not a reed curve"):
        make_controls(FS, 10, 1800.0, p_c=1.0)
