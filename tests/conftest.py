"""Shared fixtures: the shipped instrument and its air."""

from pathlib import Path

import pytest

from mpipe.measurement.calibration import load_calibration

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "calibration" / "simplified_clarinet.yaml"


@pytest.fixture(scope="session")
def shipped_calibration():
    return load_calibration(SHIPPED)


@pytest.fixture(scope="session")
def shipped_air(shipped_calibration):
    return shipped_calibration.air_properties()
