"""Tests of the plane-wave model (physics.md E.1-E.4).

The separation filters, the model matrix and the singular frequencies, on analytic fields
of any number of microphones.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mpipe.measurement.separation.waves import (
    Geometry,
    Theta,
    model_matrix,
    null_vector,
    projection_residual,
    separation_filters,
    singular_frequencies,
    wavenumbers,
    zk_excess,
)
from tests.measurement.separation.separation_fields import CAL, analytic_field, mic_spectra


def test_single_frequency_fields_separate_exactly():
    geo = Geometry.from_calibration(CAL)
    freqs = np.array([100.0, 440.0, 1234.5, 3000.0, 6999.0])
    P0 = np.array([1.0, 2.0 - 1j, 0.5j, 3.0, -1.0])
    U0 = np.array([1e-5, -2e-6j, 4e-6, 1e-6 + 1e-6j, 3e-7])
    for mach in (0.0, 0.01):
        th = Theta(CAL.air_properties(20.0).c, 1.0, mach)
        g_p, g_u = separation_filters(freqs, th, geo)
        mics = mic_spectra(P0, U0, freqs, 20.0, mach)
        np.testing.assert_allclose(np.sum(g_p * mics, axis=1), P0, rtol=1e-7, atol=1e-12)
        np.testing.assert_allclose(np.sum(g_u * mics, axis=1), U0, rtol=1e-7, atol=1e-16)


def test_flow_is_unmeasurable_at_dc():
    geo = Geometry.from_calibration(CAL)
    g_p, g_u = separation_filters(np.array([0.0, 50.0]), Theta(343.0), geo)
    assert np.all(g_u[0] == 0)
    # a uniform static pressure is reproduced
    np.testing.assert_allclose(np.sum(g_p[0]), 1.0, atol=1e-6)


@pytest.mark.parametrize("offsets", [(0.0, 0.02), (0.0, 0.02, 0.04), (0.0, 0.013, 0.031, 0.05)])
def test_any_number_of_microphones_separates_the_analytic_field(offsets):
    # Held propagation parameters (the configured ones): 2 microphones give the exact
    # solution, 3 and 4 the least-squares one; all reproduce P0 and U0 of the analytic field
    # away from the singular frequencies, and leave no projection residual.
    geo = dataclasses.replace(Geometry.from_calibration(CAL), offsets=np.array(offsets))
    th = Theta(CAL.air_properties(20.0).c, 1.0, 0.0)
    rng = np.random.default_rng(len(offsets))
    freqs = np.sort(rng.uniform(30.0, 7000.0, 40))
    sing = singular_frequencies(geo, th, 20_000.0)
    freqs = freqs[np.all(np.abs(freqs[:, None] - sing[None, :]) > 200.0, axis=1)]
    P0 = rng.normal(size=freqs.size) + 1j * rng.normal(size=freqs.size)
    U0 = (rng.normal(size=freqs.size) + 1j * rng.normal(size=freqs.size)) * 1e-5
    mics = analytic_field(offsets, P0, U0, freqs)
    g_p, g_u = separation_filters(freqs, th, geo)
    np.testing.assert_allclose(np.sum(g_p * mics, axis=1), P0, rtol=1e-7, atol=1e-10)
    np.testing.assert_allclose(np.sum(g_u * mics, axis=1), U0, rtol=1e-7, atol=1e-15)
    omega = 2 * np.pi * freqs
    ex = zk_excess(omega, geo, th.c)[0]
    h = model_matrix(*wavenumbers(omega, th, ex), geo.offsets)
    res = projection_residual(mics, h)
    assert np.max(np.abs(res)) < 1e-9 * np.max(np.abs(mics))
    # random data: zero residual for 2 microphones (exact), the null-vector form for 3
    noise = rng.normal(size=mics.shape) + 1j * rng.normal(size=mics.shape)
    r = projection_residual(noise, h)
    if len(offsets) == 2:
        assert np.max(np.abs(r)) < 1e-9
        # singular every c / (2 s): 8.6, 17.2 kHz for 2 cm at 20 degC
        np.testing.assert_allclose(sing, [th.c / 0.04, th.c / 0.02], rtol=1e-12)
    elif len(offsets) == 3:
        n = null_vector(h)
        want = np.abs(np.sum(n * noise, axis=1)) ** 2
        np.testing.assert_allclose(np.sum(np.abs(r) ** 2, axis=1), want, rtol=1e-9)
        np.testing.assert_allclose(sing, [th.c / 0.04, th.c / 0.02], rtol=1e-12)  # equal
    else:
        assert sing.size == 0  # incommensurate spacings: never singular below 20 kHz
        assert np.all(np.sum(np.abs(r) ** 2, axis=1) > 0)
