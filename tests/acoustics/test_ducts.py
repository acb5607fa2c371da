import numpy as np
import pytest

from mpipe.acoustics import ducts
from mpipe.acoustics.air import air_properties

AIR = air_properties(20.0)
OMEGA = 2 * np.pi * np.linspace(20.0, 7000.0, 400)


def det(t):
    return t[:, 0, 0] * t[:, 1, 1] - t[:, 0, 1] * t[:, 1, 0]


@pytest.mark.parametrize("losses", ducts.LOSS_MODELS)
def test_cylinder_and_cone_are_reciprocal(losses):
    for t in (
        ducts.cylinder_matrix(OMEGA, 0.0075, 0.5, AIR, losses),
        ducts.cone_matrix(OMEGA, 0.006, 0.0075, 0.051, AIR, losses),
        ducts.cone_matrix(OMEGA, 0.0075, 0.004, 0.2, AIR, losses),
    ):
        np.testing.assert_allclose(det(t), 1.0, atol=1e-10)


def test_zero_length_is_identity():
    np.testing.assert_allclose(
        ducts.cylinder_matrix(OMEGA, 0.0075, 0.0, AIR), ducts.identity_matrix(OMEGA.size)
    )


def test_inverse_undoes_matrix():
    t = ducts.cone_matrix(OMEGA, 0.006, 0.0075, 0.051, AIR)
    np.testing.assert_allclose(t @ ducts.invert(t), ducts.identity_matrix(OMEGA.size), atol=1e-9)


def test_cascading_is_associative_and_splits_a_cylinder():
    a = ducts.cylinder_matrix(OMEGA, 0.0075, 0.1, AIR)
    b = ducts.cone_matrix(OMEGA, 0.0075, 0.009, 0.05, AIR)
    c = ducts.cylinder_matrix(OMEGA, 0.009, 0.3, AIR)
    np.testing.assert_allclose((a @ b) @ c, a @ (b @ c), rtol=1e-12)
    whole = ducts.cylinder_matrix(OMEGA, 0.0075, 0.4, AIR)
    halves = ducts.chain([ducts.cylinder_matrix(OMEGA, 0.0075, 0.2, AIR)] * 2)
    np.testing.assert_allclose(halves, whole, rtol=1e-10, atol=1e-10 * np.abs(whole).max())


def test_lossless_cylinder_matches_analytic():
    k = OMEGA / AIR.c
    length, radius = 0.5, 0.0075
    z0 = AIR.impedance(np.pi * radius**2)
    t = ducts.cylinder_matrix(OMEGA, radius, length, AIR, "lossless")
    # ideal open end: Z = j Z0 tan kL ; rigid end: Z = -j Z0 cot kL
    np.testing.assert_allclose(t[:, 0, 1] / t[:, 1, 1], 1j * z0 * np.tan(k * length), rtol=1e-9)
    np.testing.assert_allclose(t[:, 0, 0] / t[:, 1, 0], -1j * z0 / np.tan(k * length), rtol=1e-9)


def _staircase(r1, r2, length, n, losses):
    edges = np.linspace(0, length, n + 1)
    mids = r1 + (r2 - r1) * (edges[:-1] + edges[1:]) / (2 * length)
    return ducts.chain([ducts.cylinder_matrix(OMEGA, r, length / n, AIR, losses) for r in mids])


def test_lossless_cone_converges_to_staircase_of_cylinders():
    r1, r2, length = 0.006, 0.0075, 0.051
    cone = ducts.cone_matrix(OMEGA, r1, r2, length, AIR, "lossless")
    scale = np.abs(cone).max(axis=(1, 2))[:, None, None]
    errors = [
        np.max(np.abs(_staircase(r1, r2, length, n, "lossless") - cone) / scale) for n in (50, 200)
    ]
    assert errors[1] < errors[0] / 8  # second order: 4x finer steps give ~16x smaller error
    assert errors[1] < 1e-5


def test_lossy_cone_close_to_staircase_of_lossy_cylinders():
    # The WKB cone puts the losses of the log-mean radius along the whole cone; a fine
    # staircase puts local losses on each step. They differ by the approximation error only.
    r1, r2, length = 0.006, 0.0075, 0.051
    cone = ducts.cone_matrix(OMEGA, r1, r2, length, AIR, "bessel")
    stairs = _staircase(r1, r2, length, 400, "bessel")
    scale = np.abs(cone).max(axis=(1, 2))[:, None, None]
    assert np.max(np.abs(stairs - cone) / scale) < 5e-3


def test_cone_lossless_matches_spherical_wave_solution():
    # physics.md B.5: lossless truncated cone, spherical-wave form
    r1, r2, length = 0.006, 0.0075, 0.051
    k = OMEGA / AIR.c
    x1 = r1 * length / (r2 - r1)
    x2 = x1 + length
    rc = AIR.rho * AIR.c
    s, c = np.sin(k * length), np.cos(k * length)
    a = r2 / r1 * c - s / (k * x1)
    b = 1j * rc / (np.pi * r1 * r2) * s
    cc = (
        np.pi
        * r1
        * r2
        / rc
        * (1j * (1 + 1 / (k**2 * x1 * x2)) * s - 1j * length / (k * x1 * x2) * c)
    )
    d = r1 / r2 * c + s / (k * x2)
    t = ducts.cone_matrix(OMEGA, r1, r2, length, AIR, "lossless")
    for got, want in ((t[:, 0, 0], a), (t[:, 0, 1], b), (t[:, 1, 0], cc), (t[:, 1, 1], d)):
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12 * np.abs(want).max())


def test_large_radius_approximation_within_stated_error():
    # physics.md B.3: ~1e-4 relative for a = 7.5 mm above 100 Hz; worse at small r_v
    omega = 2 * np.pi * np.linspace(100.0, 7000.0, 200)
    g_b, z_b = ducts.propagation(omega, 0.0075, AIR, "bessel")
    g_k, z_k = ducts.propagation(omega, 0.0075, AIR, "keefe")
    assert np.max(np.abs(g_k / g_b - 1)) < 2e-4
    assert np.max(np.abs(z_k / z_b - 1)) < 2e-4
    # r_v ~ 4.5 (a = 0.5 mm near 100 Hz): about 2 %
    w = np.array([2 * np.pi * 100.0])
    rv = 0.0005 * np.sqrt(w * AIR.rho / AIR.mu)
    assert 3 < rv[0] < 6
    g_b, _ = ducts.propagation(w, 0.0005, AIR, "bessel")
    g_k, _ = ducts.propagation(w, 0.0005, AIR, "keefe")
    assert 1e-3 < abs(g_k[0] / g_b[0] - 1) < 5e-2


def test_bessel_ratio_matches_scipy_across_regimes():
    from scipy import special

    z = np.sqrt(-1j * np.logspace(-2, 8, 2000))
    exact = 2 * special.jve(1, z) / (z * special.jve(0, z))
    np.testing.assert_allclose(ducts.bessel_ratio(z), exact, rtol=1e-13)


def test_losses_attenuate_forward_wave():
    gamma, _ = ducts.propagation(OMEGA, 0.0075, AIR)
    assert np.all(gamma.real > 0)
    # phase speed slightly below c because of the boundary layer
    assert np.all(OMEGA / gamma.imag < AIR.c)


def test_unknown_loss_model():
    with pytest.raises(ValueError, match="unknown loss model"):
        ducts.propagation(OMEGA, 0.0075, AIR, "magic")
