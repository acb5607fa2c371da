"""The Jacobian of F2's residuals from the model's sensitivities, against differences."""

import dataclasses

import numpy as np
import pytest

from mpipe.core.filters import design_lowpass
from mpipe.inversion.fit.objective import F2Objective, ObjectiveSettings, TargetWindow
from mpipe.inversion.settings import PARAMETER_NAMES
from tests.inversion.fit.table1 import FS, TABLE1, W0, N


def _objective(kernel, sim, zero_mean, closure, resistance=0.0, slope=0.0):
    kernel = dataclasses.replace(kernel, reference_resistance=resistance)
    p, u = sim.p.copy(), sim.u.copy()
    if zero_mean:
        u = u - u.mean()  # the measured path: the flow's mean is lost
    target = TargetWindow(p[W0 : W0 + N], u[W0 : W0 + N], p[:W0], u[:W0], FS, zero_mean, slope)
    settings = ObjectiveSettings(lowpass=design_lowpass(FS) if zero_mean else None)
    return F2Objective(kernel, target, settings, TABLE1, PARAMETER_NAMES, closure)


@pytest.mark.parametrize(
    ("zero_mean", "resistance", "slope"),
    [(False, 0.0, 0.0), (True, 0.0, 0.0), (True, 5e3, 0.0), (True, 5e3, 4e3)],
)
@pytest.mark.parametrize("closure", [False, True])
def test_jacobian_matches_central_differences(table1_note, zero_mean, closure, resistance,
                                              slope):  # fmt: skip
    # 3 candidates within +-5 % of Table 1 per case: every column of the Jacobian agrees
    # with central differences of the residuals to 1e-4 relative (observed 2e-9..2e-6; the
    # differences' own error is ~1e-7), and its residuals are the residuals' bit for bit;
    # slope: the mouth pressure ramping 4000 Pa/s about the window (held in the Jacobian)
    kernel, sim = table1_note
    obj = _objective(kernel, sim, zero_mean, closure, resistance, slope)
    assert obj.has_jacobian
    x0 = np.array([getattr(TABLE1, n) for n in PARAMETER_NAMES])
    rng = np.random.default_rng(11)
    for _ in range(3):
        x = x0 * np.exp(0.05 * rng.uniform(-1, 1, x0.size))
        r, jac = obj.jacobian(x)
        assert np.array_equal(r, obj.residuals(x))
        for j in range(x.size):
            h = 1e-6 * x[j]
            hi, lo = x.copy(), x.copy()
            hi[j] += h
            lo[j] -= h
            fd = (obj.residuals(hi) - obj.residuals(lo)) / (2 * h)
            err = np.linalg.norm(jac[:, j] - fd) / np.linalg.norm(fd)
            assert err < 1e-4, (PARAMETER_NAMES[j], err)


def test_no_jacobian_for_an_infeasible_candidate(table1_note):
    # an unstable reed (T above 2 sqrt(m/k)) has no Jacobian; the search then falls back
    kernel, sim = table1_note
    obj = _objective(kernel, sim, True, False)
    x = np.array([getattr(TABLE1, n) for n in PARAMETER_NAMES])
    x[PARAMETER_NAMES.index("m")] = 1e-6
    assert obj.jacobian(x) is None
