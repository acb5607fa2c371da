"""The residual's response to changes of its measured signals, against moved targets."""

import dataclasses

import numpy as np
import pytest

from mpipe.core.filters import design_lowpass
from mpipe.inversion.fit.input_tangents import InputTangents
from mpipe.inversion.fit.objective import F2Objective, ObjectiveSettings, TargetWindow
from mpipe.inversion.settings import PARAMETER_NAMES
from tests.inversion.fit.table1 import FS, TABLE1, W0, N


def _objective(kernel, target, zero_mean):
    settings = ObjectiveSettings(lowpass=design_lowpass(FS) if zero_mean else None)
    return F2Objective(kernel, target, settings, TABLE1, PARAMETER_NAMES, False)


def _moved(target, dp, du, eps):
    """``target`` with ``eps (dp, du)`` added over the last h history samples and the window."""
    n = target.p.size
    h = dp.size - n
    ph, uh = target.p_history.copy(), target.u_history.copy()
    ph[ph.size - h :] += eps * dp[:h]
    uh[uh.size - h :] += eps * du[:h]
    return dataclasses.replace(target, p=target.p + eps * dp[h:], u=target.u + eps * du[h:],
                               p_history=ph, u_history=uh)  # fmt: skip


@pytest.mark.parametrize(
    ("zero_mean", "resistance", "slope"), [(False, 0.0, 0.0), (True, 0.0, 0.0), (True, 5e3, 0.0),
                                           (True, 5e3, 4e3)],
)  # fmt: skip
def test_responses_match_the_model_run_on_moved_targets(table1_note, zero_mean, resistance,
                                                        slope):  # fmt: skip
    # Three changes over the window and the 6000 samples before it (the lead-in, the
    # low-pass's context and most of the bore's reach): white, low-passed and one in the
    # history only. Each dr agrees with central differences of the residuals of the
    # target moved by -+ the change to 1e-5 relative (observed 4e-10..5e-10), and the
    # run's residual is the evaluator's bit for bit.
    kernel, sim = table1_note
    kernel = dataclasses.replace(kernel, reference_resistance=resistance)
    p, u = sim.p.copy(), sim.u.copy()
    if zero_mean:
        u = u - u.mean()
    target = TargetWindow(p[W0 : W0 + N], u[W0 : W0 + N], p[:W0], u[:W0], FS, zero_mean, slope)
    obj = _objective(kernel, target, zero_mean)
    x = np.array([getattr(TABLE1, n) for n in PARAMETER_NAMES])
    rng = np.random.default_rng(5)
    h = 6000
    white = rng.standard_normal((2, h + N))
    smooth = np.cumsum(rng.standard_normal((2, h + N)), axis=1) / 30.0
    history_only = rng.standard_normal((2, h + N)) * (np.arange(h + N) < h)
    changes = np.array([white, smooth, history_only])  # (K, 2, h + N)
    dp, du = changes[:, 0] * 5.0, changes[:, 1] * 2e-6  # Pa, m^3/s
    r, dr = InputTangents(obj.evaluator, len(changes)).responses(obj.reed(x), dp, du)
    assert np.array_equal(r, obj.residuals(x))
    eps = 1e-3
    for k in range(len(changes)):
        hi = _objective(kernel, _moved(target, dp[k], du[k], eps), zero_mean).residuals(x)
        lo = _objective(kernel, _moved(target, dp[k], du[k], -eps), zero_mean).residuals(x)
        fd = (hi - lo) / (2 * eps)
        err = np.linalg.norm(dr[k] - fd) / np.linalg.norm(fd)
        assert err < 1e-5, (k, err)


def test_an_unplayable_candidate_says_why(table1_note):
    kernel, sim = table1_note
    target = TargetWindow(sim.p[W0 : W0 + N], sim.u[W0 : W0 + N], sim.p[:W0], sim.u[:W0],
                          FS, False)  # fmt: skip
    obj = _objective(kernel, target, False)
    reed = dataclasses.replace(TABLE1, m=5e-4, k=1e8)  # unstable at this rate
    out = InputTangents(obj.evaluator, 1).responses(reed, np.zeros((1, N)), np.zeros((1, N)))
    assert isinstance(out, str) and out.startswith("unstable")
