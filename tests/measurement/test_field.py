"""The sound field at the microphones (physics.md E.1, F.1), against independent references.

Plane waves written out here, and power conservation: a lossless duct carries the mouthpiece's
acoustic power to every microphone unchanged, a lossy one only loses power downstream.
"""

import dataclasses

import numpy as np

from mpipe.acoustics.ducts import propagation
from mpipe.measurement.field import microphone_field, microphone_spectra, mouthpiece_to_reference


def test_microphone_spectra_flow_changes_only_the_wavenumbers(shipped_calibration, shipped_air):
    cal, air = shipped_calibration, shipped_air
    f = np.array([500.0, 2000.0, 7000.0])
    gamma, zc = propagation(2 * np.pi * f, cal.main_radius, air, cal.bore.losses)
    mach = 0.02
    # a pure forward wave (B = 0) decays from mic to mic as exp(-Gamma d / (1 + M))
    pm = microphone_spectra(1.0, 1.0 / zc, f, cal, air, mach)
    d = np.array([m.position for m in cal.microphones]) - cal.reference_plane
    np.testing.assert_allclose(pm, np.exp(-np.outer(gamma, d) / (1 + mach)), rtol=1e-12)
    # a pure backward wave (A = 0) grows downstream as exp(+Gamma d / (1 - M))
    pm = microphone_spectra(1.0, -1.0 / zc, f, cal, air, mach)
    np.testing.assert_allclose(pm, np.exp(np.outer(gamma, d) / (1 - mach)), rtol=1e-12)


def test_power_flow_conserved_lossless_and_dissipated_with_losses(shipped_calibration):
    cal = shipped_calibration
    air = cal.air_properties()
    f = np.linspace(50.0, 7000.0, 40)
    w = 2 * np.pi * f
    rng = np.random.default_rng(0)
    P = 1000 * (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size))
    U = 1e-4 * (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size))
    positions = [m.position for m in cal.microphones]

    def power(p, u):
        return 0.5 * np.real(p * np.conj(u))

    lossless = cal.with_bore(dataclasses.replace(cal.bore, losses="lossless"))
    p0, u0 = mouthpiece_to_reference(P, U, w, lossless, air)
    np.testing.assert_allclose(power(p0, u0), power(P, U), rtol=1e-9, atol=1e-12)
    pm, um = microphone_field(p0, u0, f, lossless, air, 0.0, positions)
    for i in range(3):
        np.testing.assert_allclose(power(pm[:, i], um[:, i]), power(P, U), rtol=1e-9, atol=1e-12)

    # passive lossy ducts: the power carried downstream can only decrease
    p0, u0 = mouthpiece_to_reference(P, U, w, cal, air)
    pm, um = microphone_field(p0, u0, f, cal, air, 0.0, positions)
    flows = [power(P, U), power(p0, u0)] + [power(pm[:, i], um[:, i]) for i in range(3)]
    for up, down in zip(flows, flows[1:], strict=False):
        assert np.all(down <= up + 1e-12)
    assert np.all(flows[-1] < flows[0])
