import numpy as np
import pytest

from mpipe.core.statistics import integrated_autocorrelation


def test_integrated_autocorrelation_of_white_and_ar1_noise():
    # AR(1) with coefficient phi: tau = (1 + phi) / (1 - phi) exactly.
    rng = np.random.default_rng(3)
    n = 40_000
    for phi in (0.0, 0.5, 0.8):
        e = rng.standard_normal(n)
        x = np.empty(n)
        x[0] = e[0]
        for i in range(1, n):
            x[i] = phi * x[i - 1] + e[i]
        expected = (1 + phi) / (1 - phi)
        assert integrated_autocorrelation(x) == pytest.approx(expected, rel=0.15)
