"""Shared fixtures: the shipped instrument and its air."""

from pathlib import Path

import pytest
from hypothesis import settings

from mpipe.measurement.calibration import load_calibration

# Property tests draw the same examples on every run (a test passes every time);
# `pytest --hypothesis-profile=explore` draws new ones to look for failures.
settings.register_profile("default", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile("default")

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "calibration" / "simplified_clarinet.yaml"


@pytest.fixture(scope="session")
def shipped_calibration():
    return load_calibration(SHIPPED)


@pytest.fixture(scope="session")
def shipped_air(shipped_calibration):
    return shipped_calibration.air_properties()


@pytest.fixture(scope="session")
def dask_cluster():
    """A scheduler and two worker processes of their own: ``(client, address, workers)``."""
    pytest.importorskip("distributed")
    from tests.inversion.cluster_helpers import real_cluster

    with real_cluster(2) as cluster:
        yield cluster
