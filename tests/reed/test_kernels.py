"""The one compiled kernel, every variant, against the plain NumPy reference loop.

Short runs on the shipped instrument (calibration/simplified_clarinet.yaml) with the
paper's Table 1 reed, and a synthetic reflection function with a large lag-0 tap.
"""

import numpy as np

from mpipe.acoustics.reflection import ReflectionFunction
from mpipe.reed.bore_kernel import prepare_bore
from mpipe.reed.model import simulate, simulate_pressure
from mpipe.reed.sensitivity import pressure_sensitivities


def rel_diff(a, b):
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


def test_kernels_agree(setup):
    _, air, reed, rf, kernel = setup
    n = 20_000  # 0.2 s: through the attack into large-amplitude oscillation
    runs = {m: simulate(reed, kernel, n, method=m, onset_s=0.005) for m in ("fast", "direct")}
    runs["numpy"] = simulate(reed, kernel, n, method="numpy", onset_s=0.005)
    assert np.ptp(runs["numpy"].p[-2000:]) > 2000  # it does play
    for m in ("fast", "direct"):
        for name in ("p", "u", "u_f", "u_r", "y", "p_plus", "p_minus"):
            assert rel_diff(getattr(runs[m], name), getattr(runs["numpy"], name)) < 1e-9, (m, name)
    # other block sizes, including one spanning the whole response (no FFT partitions)
    for head in (16, 512, 8192):
        other = simulate(reed, prepare_bore(rf, air, head_taps=head), n, onset_s=0.005)
        assert rel_diff(other.p, runs["direct"].p) < 1e-9, head


def test_short_reflection_function_and_lag0_tap(setup):
    # A synthetic response with a large lag-0 tap checks the exact h[0] handling
    # (physics.md D.2 step 6) independently of the shipped bore.
    _, air, reed, rf, _ = setup
    h = np.zeros(300)
    h[0] = 0.05
    h[100] = -0.6
    h[200] = -0.2
    short = ReflectionFunction(h, rf.fs, rf.z0, 0.0, 0.0, -0.75, 0.0, 0.0, (20.0, 7250.0))
    kernel = prepare_bore(short, air, head_taps=32)
    ref = simulate(reed, kernel, 3000, method="numpy")
    for m in ("fast", "direct"):
        assert rel_diff(simulate(reed, kernel, 3000, method=m).p, ref.p) < 1e-9
    s = ref
    np.testing.assert_allclose(s.p, s.p_plus + s.p_minus, rtol=0, atol=1e-9)
    np.testing.assert_allclose(kernel.z0 * s.u, s.p_plus - s.p_minus, rtol=0, atol=1e-9)
    # p-(n) = sum_j h[j] p+(n - j), with p+ = 0 before the start
    conv = np.convolve(s.p_plus, h)[: s.p_plus.size]
    np.testing.assert_allclose(s.p_minus, conv, rtol=0, atol=1e-9 * np.abs(s.p).max())


def test_pressure_only_and_tangent_variants_against_the_reference(setup):
    # the one compiled kernel's other variants (pressure only on the two-level partition,
    # and with the forward sensitivities) against the plain reference loop, from rest and
    # from a history, at constant mouth pressure
    _, _, reed, _, kernel = setup
    ref = simulate(reed, kernel, 6000, method="numpy")
    assert np.ptp(ref.p[-1000:]) > 1000  # it plays
    cont = simulate(reed, kernel, 2000, method="numpy", state=ref.final_state)
    for state, want in ((None, ref.p), (ref.final_state, cont.p)):
        n = want.size
        p = simulate_pressure(reed, kernel, n, state=state)
        assert rel_diff(p, want) < 1e-9
        p_t, _ = pressure_sensitivities(reed, kernel, n, ("k", "y_m"), state=state)
        assert np.array_equal(p_t, p)
