"""The reed update's coefficients: the centred-difference damped oscillator."""

import math
from pathlib import Path

import numpy as np
import pytest

from mpipe.reed.parameters import load_reed
from mpipe.reed.scheme import reed_coefficients

ROOT = Path(__file__).resolve().parents[2]


def test_reed_update_is_the_damped_oscillator():
    # The linear part of the centred-difference update has poles r exp(+-j w T) with
    # r = sqrt((2 - gT)/(2 + gT)) ~ exp(-gT/2) and w close to sqrt(k/m - g^2/4).
    reed = load_reed(ROOT / "calibration" / "reed_table1.yaml")
    fs = 100_000.0
    a1, a2, a3, b1 = reed_coefficients(reed, fs)
    poles = np.roots([1.0, -a1, -a2])
    t = 1 / fs
    assert abs(poles[0]) ** 2 == pytest.approx((2 - reed.g * t) / (2 + reed.g * t), rel=1e-12)
    assert abs(poles[0]) == pytest.approx(math.exp(-reed.g * t / 2), rel=1e-5)
    w = abs(np.angle(poles[0])) * fs
    assert w == pytest.approx(math.sqrt(reed.k / reed.m - reed.g**2 / 4), rel=1e-3)
    # static gain: y = dp / k
    assert b1 / (1 - a1 - a2) == pytest.approx(1 / reed.k, rel=1e-12)
    assert a3 == pytest.approx(-reed.k_c * b1)
