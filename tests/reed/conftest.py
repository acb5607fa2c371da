"""Fixtures of the reed-model tests: the shipped instrument with the paper's Table 1 reed."""

from pathlib import Path

import pytest

from mpipe.acoustics.reflection import reflection_function
from mpipe.measurement.calibration import load_calibration
from mpipe.reed.bore_kernel import prepare_bore
from mpipe.reed.parameters import load_reed

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def setup():
    """(calibration, air, Table 1 reed, reflection function at 100 kHz, prepared bore)."""
    cal = load_calibration(ROOT / "calibration" / "simplified_clarinet.yaml")
    air = cal.air_properties()
    reed = load_reed(ROOT / "calibration" / "reed_table1.yaml")
    rf = reflection_function(cal.bore, air, fs=100_000.0)
    return cal, air, reed, rf, prepare_bore(rf, air)
