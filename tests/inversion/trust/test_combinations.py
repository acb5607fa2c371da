"""Identifiable combinations: values against direct formulas, exponents, invariance."""

import math

import numpy as np
import pytest

from mpipe.inversion.trust.combinations import COMBINATIONS, combination_values
from mpipe.inversion.trust.uncertainty import scale_direction
from mpipe.reed.parameters import ReedParameters

TABLE1 = ReedParameters(
    k=8.66e6, S=7.62e-5, y_m=4e-4, p_m=1800.0, lam=0.013, m=0.05, g=3000.0, k_c=8.23e10
)


def test_combinations_against_direct_formulas_and_delta_method():
    values = {n: getattr(TABLE1, n) for n in ("k", "S", "y_m", "p_m", "m", "g", "lam", "k_c")}
    values["y_c"] = TABLE1.y_c
    z_c, rho = 5.0e6, 1.2
    c = combination_values(values, z_c, rho)
    assert c["p_M"] == pytest.approx(8.66e6 * 4e-4)
    assert c["gamma"] == pytest.approx(1800 / 3464)
    assert c["zeta"] == pytest.approx(z_c * 0.013 * 4e-4 * math.sqrt(2 / (rho * 3464)))
    assert c["f_r"] == pytest.approx(TABLE1.resonance_hz)
    assert c["Q_r"] == pytest.approx(2 * math.pi * TABLE1.resonance_hz / 3000)
    # every combination's exponents reproduce its value's log-derivative (finite difference)
    for comb in COMBINATIONS:
        for name, e in comb.exponents.items():
            bumped = dict(values, **{name: values[name] * math.exp(1e-6)})
            slope = math.log(combination_values(bumped, z_c, rho)[comb.name] / c[comb.name]) / 1e-6
            assert slope == pytest.approx(e, abs=1e-5)
        # and every combination is invariant under the scale symmetry
        e = np.array([comb.exponents.get(n, 0.0) for n in ("k", "S", "y_m", "m", "lam", "k_c")])
        assert e @ scale_direction(("k", "S", "y_m", "m", "lam", "k_c")) == 0
