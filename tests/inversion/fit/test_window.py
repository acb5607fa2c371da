"""One window's inversion: its start from step 1, and a failing window recorded, not raised."""

import numpy as np
import pytest

from mpipe.acoustics.reflection import reflection_function
from mpipe.inversion.fit.step1 import step1
from mpipe.inversion.fit.window import invert_window, start_point
from mpipe.inversion.settings import InversionConfig
from mpipe.reed.bore_kernel import prepare_bore
from mpipe.reed.model import simulate
from mpipe.reed.parameters import ReedParameters

FS = 100_000.0
TABLE1 = ReedParameters(
    k=8.66e6, S=7.62e-5, y_m=4e-4, p_m=1800.0, lam=0.013, m=0.05, g=3000.0, k_c=8.23e10
)
LIGHT = InversionConfig(free=("p_m",), max_evaluations=60, warm_max_evaluations=30)


@pytest.fixture(scope="module")
def take(shipped_calibration, shipped_air):
    reflection = reflection_function(shipped_calibration.bore, shipped_air, fs=FS)
    kernel = prepare_bore(reflection, shipped_air)
    return kernel, shipped_air.rho, simulate(TABLE1, kernel, 34000)


def test_start_point_is_inside_the_bounds_and_above_the_contact(take):
    _, rho, sim = take
    s1 = step1(sim.p[30000:32000], sim.u[30000:32000], FS, rho=rho, lam=0.013)
    x = start_point(s1, LIGHT)
    for name in ("k", "S", "y_m", "p_m"):
        lo, hi = LIGHT.bounds.absolute(name, s1.max_p)
        assert lo <= getattr(x, name) <= hi
    assert x.y_m >= 1.1 * LIGHT.y_c and x.lam == LIGHT.lam


def test_window_past_the_end_is_recorded_as_failed(take):
    kernel, rho, sim = take
    out = invert_window(sim.p, sim.u, FS, 33000, kernel, rho, LIGHT, zero_mean=False)
    assert out.row["status"] == "failed" and "past the end" in out.row["error"]
    assert out.search is None and out.reed is None and not out.row["warm"]


def test_warm_window_skips_step1(take):
    kernel, rho, sim = take
    out = invert_window(sim.p, sim.u, FS, 30000, kernel, rho, LIGHT, zero_mean=False, warm=TABLE1)
    assert out.step1 is None and out.row["warm"] and np.isnan(out.row["step1_p_m"])
    assert out.row["error"] == "" and out.row["n_evaluations"] <= LIGHT.warm_max_evaluations
