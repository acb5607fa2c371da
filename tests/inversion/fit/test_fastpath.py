"""The compiled F2 evaluator against the plain reference, and the lean model kernel."""

import dataclasses
import os
import subprocess
import sys

import numpy as np
import pytest

from mpipe.core.filters import design_lowpass
from mpipe.inversion.fit.fastpath import WindowEvaluator
from mpipe.inversion.fit.objective import F2Objective, ObjectiveSettings, TargetWindow
from mpipe.inversion.settings import PARAMETER_NAMES
from mpipe.reed.model import ModelState, simulate, simulate_pressure
from tests.inversion.fit.table1 import FS, ROOT, TABLE1, W0, N


def _objectives(kernel, sim, zero_mean, resistance=0.0, slope=0.0):
    # resistance: the bore's steady-flow resistance to the pressure's reference plane (Pa
    # s/m^3; the shipped instrument's is 5197): the measured pressure lacks it times c
    kernel = dataclasses.replace(kernel, reference_resistance=resistance)
    p, u = sim.p.copy(), sim.u.copy()
    if zero_mean:
        u = u - u.mean()  # what the separation delivers: the flow's mean is lost
    target = TargetWindow(p[W0 : W0 + N], u[W0 : W0 + N], p[:W0], u[:W0], FS, zero_mean, slope)
    settings = ObjectiveSettings(lowpass=design_lowpass(FS) if zero_mean else None)
    fast = F2Objective(kernel, target, settings, TABLE1, PARAMETER_NAMES)
    return fast, dataclasses.replace(fast, fast=False)


@pytest.mark.parametrize(
    ("zero_mean", "resistance", "slope"),
    [(False, 0.0, 0.0), (True, 0.0, 0.0), (True, 5e3, 0.0), (False, 0.0, 4e3), (True, 5e3, -4e3)],
)
def test_fast_residuals_match_the_reference(table1_note, zero_mean, resistance, slope):
    # 12 random candidates within +-10 % of Table 1 (several seeds' worth of spread): every
    # residual vector agrees with the plain reference to rounding; slope: a mouth pressure
    # ramping by 4000 Pa/s about the window (+-40 Pa over its 20 ms), both ways
    kernel, sim = table1_note
    fast, ref = _objectives(kernel, sim, zero_mean, resistance, slope)
    x0 = np.array([getattr(TABLE1, n) for n in PARAMETER_NAMES])
    rng = np.random.default_rng(7)
    for _ in range(12):
        x = x0 * np.exp(0.1 * rng.uniform(-1, 1, x0.size))
        a, b = fast.residuals(x), ref.residuals(x)
        assert np.max(np.abs(a - b)) <= 1e-11 * np.max(np.abs(b)), x
        assert fast(x) == pytest.approx(ref(x), rel=1e-12)


def test_fast_path_flags_infeasible_candidates_like_the_reference(table1_note):
    kernel, sim = table1_note
    fast, ref = _objectives(kernel, sim, True)
    x = np.array([getattr(TABLE1, n) for n in PARAMETER_NAMES])
    unstable = x.copy()
    unstable[PARAMETER_NAMES.index("m")] = 5e-4  # with k = 5e7 Pa/m, T > 2 sqrt(m/k)
    unstable[PARAMETER_NAMES.index("k")] = 5e7
    # a target 1000x louder than any model run: every candidate is "silent" against it
    loud = dataclasses.replace(fast.target, p=1000 * fast.target.p)
    quiet_fast = dataclasses.replace(fast, target=loud)
    quiet_ref = dataclasses.replace(ref, target=loud)
    assert quiet_ref.evaluate(x).reason == "silent"
    assert ref.evaluate(unstable).reason.startswith("unstable")
    np.testing.assert_array_equal(quiet_fast.residuals(x), quiet_ref.residuals(x))
    np.testing.assert_array_equal(fast.residuals(unstable), ref.residuals(unstable))
    out = np.empty(N)
    ev = WindowEvaluator(kernel, loud, fast.settings)
    assert ev.residuals_into(TABLE1, out) == "silent"
    assert ev.residuals_into(fast.reed(unstable), out).startswith("unstable")


def test_lean_kernel_matches_simulate(table1_note):
    # from rest and from a history, the pressure-only kernel reproduces simulate's pressure
    kernel, sim = table1_note
    rest = simulate_pressure(TABLE1, kernel, 5000)
    np.testing.assert_allclose(rest, simulate(TABLE1, kernel, 5000).p, rtol=0, atol=1e-10)
    state = ModelState(sim.p_plus[:W0], sim.y[W0 - 1], sim.y[W0 - 2], TABLE1.p_m - sim.p[W0 - 1])
    cont = simulate_pressure(TABLE1, kernel, N, state=state)
    np.testing.assert_allclose(cont, sim.p[W0 : W0 + N], rtol=0, atol=1e-9 * np.abs(sim.p).max())


# Run in a fresh interpreter with its own numba cache directory: the first run compiles
# every kernel and fills the cache, the second loads them from it.
_CACHE_RUN = """
import sys
import numpy as np
from mpipe.acoustics.reflection import reflection_function
from mpipe.core.filters import design_lowpass
from mpipe.inversion.fit.objective import F2Objective, ObjectiveSettings, TargetWindow
from mpipe.inversion.settings import PARAMETER_NAMES
from mpipe.measurement.calibration import load_calibration
from mpipe.reed.bore_kernel import prepare_bore
from mpipe.reed.model import simulate_pressure
from mpipe.reed.parameters import ReedParameters

reed = ReedParameters(
    k=8.66e6, S=7.62e-5, y_m=4e-4, p_m=1800.0, lam=0.013, m=0.05, g=3000.0, k_c=8.23e10
)
cal = load_calibration(sys.argv[1])
air = cal.air_properties()
kernel = prepare_bore(reflection_function(cal.bore, air, fs=1e5), air)
p = simulate_pressure(reed, kernel, 7000)
u = (p - p.mean()) / kernel.z0  # any measured-like flow will do: only equality is checked
target = TargetWindow(p[5000:], u[5000:], p[:5000], u[:5000], 1e5, True)
settings = ObjectiveSettings(lowpass=design_lowpass(1e5))
objective = F2Objective(kernel, target, settings, reed, PARAMETER_NAMES)
x = np.array([getattr(reed, n) for n in PARAMETER_NAMES]) * 1.01
np.savez(sys.argv[2], lean=p, r=objective.residuals(x), f2=objective(x))
"""


def test_numbers_do_not_depend_on_the_numba_cache(tmp_path):
    # the lean model and F2 are bit-identical whether numba compiled the kernels fresh or
    # loaded them from its on-disk cache (fastmath once made the two differ by ~1e-14).
    # simulate's kernel is left out to keep this test short: it shares the same helpers
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba")}
    cal = str(ROOT / "calibration" / "simplified_clarinet.yaml")
    runs = []
    for name in ("fresh", "cached"):
        out = tmp_path / f"{name}.npz"
        cmd = [sys.executable, "-c", _CACHE_RUN, cal, str(out)]
        subprocess.run(cmd, env=env, check=True, timeout=300)
        runs.append(np.load(out))
    assert any((tmp_path / "numba").rglob("*.nbc"))  # the second run had a cache to load
    fresh, cached = runs
    assert [k for k in fresh.files if not np.array_equal(fresh[k], cached[k])] == []


def test_the_history_term_is_the_sum_that_defines_it(table1_note):
    # q(i) = sum_{j > i} h_j x(i - j): the circular convolution of history_term against
    # the sum written out, for a run shorter and one longer than the kernel
    from mpipe.inversion.fit.fastpath import history_term

    kernel, _ = table1_note
    h = np.asarray(kernel.h, float)
    x = np.random.default_rng(3).standard_normal(kernel.n_taps - 1)  # x(-len) .. x(-1)
    for n in (700, kernel.n_taps + 50):
        q = history_term(kernel, x, n)
        want = np.zeros(n)
        for i in range(min(n, h.size - 1)):
            j = np.arange(i + 1, min(h.size, i + 1 + x.size))
            want[i] = np.sum(h[j] * x[x.size + i - j])
        np.testing.assert_allclose(q, want, rtol=0, atol=1e-12 * np.sum(np.abs(h)) * 4)
