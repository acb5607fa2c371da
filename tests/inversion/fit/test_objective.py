"""The step-2 objective F2: the history start, the measured chain, infeasible candidates."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from mpipe.acoustics.reflection import reflection_function
from mpipe.core.filters import design_lowpass
from mpipe.inversion.fit.objective import (
    F2Objective,
    ObjectiveSettings,
    TargetWindow,
)
from mpipe.inversion.fit.rosenbrock import rosenbrock
from mpipe.inversion.settings import PARAMETER_NAMES
from mpipe.measurement.calibration import load_calibration
from mpipe.reed.bore_kernel import prepare_bore
from mpipe.reed.model import simulate
from mpipe.reed.parameters import ReedParameters

FS = 100_000.0
ROOT = Path(__file__).resolve().parents[3]
TABLE1 = ReedParameters(
    k=8.66e6, S=7.62e-5, y_m=4e-4, p_m=1800.0, lam=0.013, m=0.05, g=3000.0, k_c=8.23e10
)
W0, N = 30000, 2000


@pytest.fixture(scope="module")
def setup():
    cal = load_calibration(ROOT / "calibration" / "simplified_clarinet.yaml")
    air = cal.air_properties()
    kernel = prepare_bore(reflection_function(cal.bore, air, fs=FS), air)
    sim = simulate(TABLE1, kernel, W0 + N + 5000)
    target = TargetWindow(sim.p[W0 : W0 + N], sim.u[W0 : W0 + N], sim.p[:W0], sim.u[:W0], FS, False)
    return kernel, sim, target


def test_history_start_is_exact_at_truth(setup):
    kernel, _, target = setup
    obj = F2Objective(kernel, target, ObjectiveSettings(), TABLE1, PARAMETER_NAMES)
    x = TABLE1.as_vector()
    detail = obj.evaluate(x)
    assert detail.feasible and detail.relative_residual < 1e-6
    for i in range(x.size):
        y = x.copy()
        y[i] *= 1.01
        assert obj(y) > 100 * detail.f2


def test_a_ramping_mouth_pressure_is_exact_with_its_slope(setup):
    # a crescendo's window: the model played at p_m rising 4000 Pa/s throughout; the
    # window's target with that slope is matched by the reed at p_m = the mouth pressure at
    # the window's centre, to the lead-in's transient; held (slope 0, the paper's window)
    # the same reed misses by far more, and the window's best held p_m is off
    kernel, _, _ = setup
    slope, n_run = 4000.0, W0 + N + 500
    centre = W0 + N / 2
    mouth = TABLE1.p_m + slope * (np.arange(n_run) - centre) / FS
    sim = simulate(TABLE1, kernel, n_run, mouth_pressure=mouth)
    ramped = TargetWindow(sim.p[W0 : W0 + N], sim.u[W0 : W0 + N], sim.p[:W0], sim.u[:W0], FS,
                          False, slope)  # fmt: skip
    held = dataclasses.replace(ramped, p_m_slope=0.0)
    x = TABLE1.as_vector()
    exact = F2Objective(kernel, ramped, ObjectiveSettings(), TABLE1, PARAMETER_NAMES)
    plain = F2Objective(kernel, held, ObjectiveSettings(), TABLE1, PARAMETER_NAMES)
    assert exact.evaluate(x).relative_residual < 1e-6
    assert plain.evaluate(x).relative_residual > 100 * exact.evaluate(x).relative_residual
    # the fast path plays the same ramp (the reference's residual to rounding)
    ref = dataclasses.replace(exact, fast=False)
    scale = float(np.linalg.norm(ramped.p))
    assert np.linalg.norm(exact.residuals(x) - ref.residuals(x)) < 1e-9 * scale


def test_zero_mean_target_has_its_minimum_at_the_truth(setup):
    # The measurement chain as the separation delivers it: p keeps its DC, the flow loses
    # it (high-pass over the whole take), both are low-passed at 7.25 kHz.
    kernel, sim, _ = setup
    from mpipe.core.filters import apply_lowpass, highpass_zero_phase

    lp = design_lowpass(FS)
    p = apply_lowpass(sim.p, lp)
    u = apply_lowpass(highpass_zero_phase(sim.u, FS, 20.0), lp)
    target = TargetWindow(p[W0 : W0 + N], u[W0 : W0 + N], p[:W0], u[:W0], FS, True)
    obj = F2Objective(kernel, target, ObjectiveSettings(lowpass=lp), TABLE1, PARAMETER_NAMES)
    detail = obj.evaluate(TABLE1.as_vector())
    # left: the mean flow lost from the history is estimated from the candidate
    assert detail.feasible and detail.relative_residual < 0.01
    assert abs(np.mean(detail.u) - np.mean(target.u)) < 1e-12  # window mean as measured
    f_true = obj(TABLE1.as_vector())
    for i in range(len(PARAMETER_NAMES)):
        for factor in (0.99, 1.01):
            x = TABLE1.as_vector()
            x[i] *= factor
            assert obj(x) > f_true, (PARAMETER_NAMES[i], factor)


def test_a_pressure_short_of_the_mean_flows_drop_fits_with_the_reference_resistance(setup):
    # A translation of a zero-mean flow cannot add the mean flow's Poiseuille drop between
    # the mouthpiece and where the pressure's mean was measured: the measured pressure lacks
    # R u_mean (R the shipped instrument's 5197 Pa s/m^3 to its reference plane, about 0.6 Pa
    # here). With the kernel's reference_resistance the truth is F2's minimum again and its
    # F2 there near the unshifted target's; without it F2 at the truth is 9 times as large
    # (observed 3.1 and 27 Pa against 2.6).
    import dataclasses

    from mpipe.acoustics.bore import mean_flow_resistance
    from mpipe.core.filters import apply_lowpass, highpass_zero_phase

    kernel, sim, _ = setup
    cal = load_calibration(ROOT / "calibration" / "simplified_clarinet.yaml")
    resistance = mean_flow_resistance(cal.bore, cal.air_properties(), 0.0, cal.reference_plane)
    lp = design_lowpass(FS)
    u = apply_lowpass(highpass_zero_phase(sim.u, FS, 20.0), lp)
    mean_flow = float(np.mean(sim.u[W0 - 5000 : W0 + N]))
    true_p = apply_lowpass(sim.p, lp)

    def objective(p, r):
        target = TargetWindow(p[W0 : W0 + N], u[W0 : W0 + N], p[:W0], u[:W0], FS, True)
        k = dataclasses.replace(kernel, reference_resistance=r)
        return F2Objective(k, target, ObjectiveSettings(lowpass=lp), TABLE1, PARAMETER_NAMES)

    x = TABLE1.as_vector()
    short = true_p - resistance * mean_flow
    plain, fixed = objective(true_p, 0.0), objective(short, resistance)
    unfixed = objective(short, 0.0)
    assert fixed(x) < 1.5 * plain(x) and unfixed(x) > 5 * fixed(x)
    for i in range(len(PARAMETER_NAMES)):
        for factor in (0.99, 1.01):
            y = x.copy()
            y[i] *= factor
            assert fixed(y) > fixed(x), (PARAMETER_NAMES[i], factor)


@pytest.mark.parametrize(
    ("change", "reason"),
    [
        ({"m": 1e-4}, "invalid"),
        ({"y_m": 2e-4}, "invalid"),
        ({"k": 1e9, "m": 5e-4}, "unstable"),
    ],
)
def test_infeasible_candidates_give_penalty(setup, change, reason):
    kernel, _, target = setup
    names = tuple(change)
    obj = F2Objective(kernel, target, ObjectiveSettings(), TABLE1, names)
    x = np.array(list(change.values()))
    detail = obj.evaluate(x)
    assert not detail.feasible and reason in detail.reason
    assert obj(x) == pytest.approx(obj.penalty, rel=1e-12) and np.isfinite(obj.penalty)


def test_round_trip_three_parameters_near_truth(setup):
    """Light Table-1 round trip: k, y_m, p_m started 3 % off, the rest fixed."""
    kernel, _, target = setup
    names = ("k", "y_m", "p_m")
    truth = np.array([TABLE1.k, TABLE1.y_m, TABLE1.p_m])
    obj = F2Objective(kernel, target, ObjectiveSettings(), TABLE1, names)
    x0 = truth * np.array([1.03, 0.97, 1.03])
    r = rosenbrock(
        obj, x0, lower=truth * 0.5, upper=truth * 2, max_evaluations=600, infeasible_at=obj.penalty
    )
    np.testing.assert_allclose(r.x, truth, rtol=1e-3)
    assert r.history[-1] < 1e-3 * r.history[0]
