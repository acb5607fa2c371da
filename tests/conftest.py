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


@pytest.fixture(scope="session")
def dask_cluster():
    """A scheduler and two worker processes of their own: ``(client, address, workers)``."""
    pytest.importorskip("distributed")
    from tests.inversion.cluster_helpers import real_cluster

    with real_cluster(2) as cluster:
        yield cluster
