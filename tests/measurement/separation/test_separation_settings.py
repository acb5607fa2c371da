"""Tests of the separation settings: the cross-field checks of SeparationConfig."""

from __future__ import annotations

import pytest

from mpipe.measurement.separation.settings import SeparationConfig


def test_config_cross_field_checks():
    with pytest.raises(ValueError, match="fmax_hz"):
        SeparationConfig(fmin_hz=5000.0, fmax_hz=100.0).validate()
    with pytest.raises(ValueError, match="temperature_bounds_c"):
        SeparationConfig(temperature_bounds_c=(30.0, 10.0)).validate()
