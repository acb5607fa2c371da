"""Forward sensitivities of the model's pressure against central finite differences."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from mpipe.acoustics.reflection import reflection_function
from mpipe.measurement.calibration import load_calibration
from mpipe.reed.bore_kernel import prepare_bore
from mpipe.reed.model import simulate, simulate_pressure
from mpipe.reed.parameters import ReedParameters
from mpipe.reed.scheme import reed_coefficients
from mpipe.reed.sensitivity import DIFFERENTIABLE, coefficient_derivatives, pressure_sensitivities

ROOT = Path(__file__).resolve().parents[2]
TABLE1 = ReedParameters(
    k=8.66e6, S=7.62e-5, y_m=4e-4, p_m=1800.0, lam=0.013, m=0.05, g=3000.0, k_c=8.23e10
)


@pytest.fixture(scope="module")
def kernel():
    cal = load_calibration(ROOT / "calibration" / "simplified_clarinet.yaml")
    air = cal.air_properties()
    return prepare_bore(reflection_function(cal.bore, air, fs=100_000.0), air)


def _central(reed, kernel, n, name, state, rel=1e-6, closure=False):
    v = getattr(reed, name)
    out = []
    for s in (1, -1):
        values = {name: v * (1 + s * rel)}
        if closure and name == "y_m":
            values["y_c"] = values["y_m"]
        out.append(simulate_pressure(dataclasses.replace(reed, **values), kernel, n, state=state))
    return (out[0] - out[1]) / (2 * rel * v)


def test_coefficient_derivatives_match_differences_of_the_coefficients():
    # the seed matrix's rows a1, a2, a3, b1 against central differences of reed_coefficients
    fs = 100_000.0
    d = coefficient_derivatives(TABLE1, fs, ("k", "m", "g", "k_c"))
    for j, name in enumerate(("k", "m", "g", "k_c")):
        v = getattr(TABLE1, name)
        hi = reed_coefficients(dataclasses.replace(TABLE1, **{name: v * (1 + 1e-6)}), fs)
        lo = reed_coefficients(dataclasses.replace(TABLE1, **{name: v * (1 - 1e-6)}), fs)
        fd = (np.array(hi) - np.array(lo)) / (2e-6 * v)
        np.testing.assert_allclose(d[:4, j], fd, rtol=1e-6, atol=1e-9 * np.abs(fd).max())
    with pytest.raises(ValueError, match="alpha"):
        coefficient_derivatives(TABLE1, fs, ("alpha",))


@pytest.mark.parametrize("closure", [False, True])
def test_sensitivities_match_central_differences(kernel, closure):
    # three playing states (after 0.15, 0.2 and 0.25 s of a Table 1 note, so with beating
    # and contact) and every parameter: each derivative agrees with central differences
    # to 1e-5 relative (observed ~1e-7; the differences' own error is ~1e-8), and the
    # pressure is bit-identical to simulate_pressure's
    reed = dataclasses.replace(TABLE1, y_c=TABLE1.y_m) if closure else TABLE1
    sim = simulate(reed, kernel, 25_000)
    n = 1500
    for start in (15_000, 20_000, 25_000):
        state = dataclasses.replace(
            sim.final_state, p_plus=sim.p_plus[:start][-kernel.n_taps :],
            y=sim.y[start - 1], y_prev=sim.y[start - 2], dp=reed.p_m - sim.p[start - 1],
        )  # fmt: skip
        p, dp = pressure_sensitivities(
            reed, kernel, n, DIFFERENTIABLE, state=state, contact_at_closure=closure
        )
        assert np.array_equal(p, simulate_pressure(reed, kernel, n, state=state))
        for j, name in enumerate(DIFFERENTIABLE):
            if closure and name == "y_c":
                continue
            fd = _central(reed, kernel, n, name, state, closure=closure)
            err = np.linalg.norm(dp[j] - fd) / np.linalg.norm(fd)
            assert err < 1e-5, (start, name, err)
