"""Fixtures of the fit's tests."""

import pytest

from mpipe.acoustics.reflection import reflection_function
from mpipe.measurement.calibration import load_calibration
from mpipe.reed.bore_kernel import prepare_bore
from mpipe.reed.model import simulate
from tests.inversion.fit.table1 import FS, ROOT, TABLE1, W0, N


@pytest.fixture(scope="module")
def table1_note():
    """(kernel, simulation): the Table 1 reed's note on the shipped bore, W0 + N + 500 samples."""
    cal = load_calibration(ROOT / "calibration" / "simplified_clarinet.yaml")
    air = cal.air_properties()
    kernel = prepare_bore(reflection_function(cal.bore, air, fs=FS), air)
    return kernel, simulate(TABLE1, kernel, W0 + N + 500)
