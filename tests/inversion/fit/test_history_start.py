"""The model started from the target's past: the reed's lead-in, the missing mean flow."""

import numpy as np
import pytest

from mpipe.acoustics.reflection import reflection_function
from mpipe.inversion.fit.history_start import lead_in, missing_mean_flow, pad_history
from mpipe.reed.bore_kernel import prepare_bore
from mpipe.reed.model import simulate
from mpipe.reed.opening import reed_trajectory
from mpipe.reed.parameters import ReedParameters

FS = 100_000.0
TABLE1 = ReedParameters(
    k=8.66e6, S=7.62e-5, y_m=4e-4, p_m=1800.0, lam=0.013, m=0.05, g=3000.0, k_c=8.23e10
)
W0 = 30000


@pytest.fixture(scope="module")
def take(shipped_calibration, shipped_air):
    reflection = reflection_function(shipped_calibration.bore, shipped_air, fs=FS)
    return simulate(TABLE1, prepare_bore(reflection, shipped_air), W0 + 10), shipped_air.rho


def test_reed_lead_in_converges_to_the_model_reed(take):
    sim, _ = take
    y, y_prev = reed_trajectory(TABLE1, sim.p[W0 - 1000 : W0], FS)[-2:][::-1]
    assert y == pytest.approx(sim.y[W0 - 1], rel=1e-4)
    assert y_prev == pytest.approx(sim.y[W0 - 2], rel=1e-4)


def test_pad_history_keeps_the_last_samples_and_pads_in_front():
    np.testing.assert_array_equal(pad_history([1.0, 2.0, 3.0], 2), [2.0, 3.0])
    np.testing.assert_array_equal(pad_history([1.0], 3), [0.0, 0.0, 1.0])


def test_missing_mean_flow_restores_the_mean_of_a_zero_mean_flow(take):
    sim, rho = take
    dp = TABLE1.p_m - sim.p[W0 - 2000 : W0]
    y = reed_trajectory(TABLE1, sim.p[W0 - 2000 : W0], FS)
    u = sim.u[W0 - 2000 : W0]
    lost = missing_mean_flow(TABLE1, dp, y, u - u.mean(), FS, rho)
    # with the true reed the candidate's flow is the model's own: the mean lost is exact
    assert lost == pytest.approx(u.mean(), rel=1e-6)


@pytest.mark.parametrize("start", [0, 1, 150, 999, 5000])
@pytest.mark.parametrize("taps", [1, 300, 2500])
def test_the_lead_in_holds_every_sample_the_model_reads(start, taps):
    # what the objective reads of a history: pad_history of max(taps, lead-in) samples
    # and the last window's worth for the period; the lead-in must give the same
    p = np.random.default_rng(start).standard_normal(6000)
    n, lead_s = 400, 0.01
    hp, hu = lead_in(p, -p, start, n, taps, lead_s, FS)
    np.testing.assert_array_equal(hu, -hp)
    for length in (taps, int(round(lead_s * FS)), n, 2):
        np.testing.assert_array_equal(pad_history(hp, length), pad_history(p[:start], length))
    np.testing.assert_array_equal(hp[-n:], p[:start][-n:])
