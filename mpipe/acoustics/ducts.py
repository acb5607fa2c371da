"""Plane-wave propagation with visco-thermal losses, and transfer matrices of duct segments.

Conventions (see ``docs/conventions.md``): time dependence exp(+j omega t); a transfer
matrix maps the downstream port (2) to the upstream port (1),
``[P1, U1] = T @ [P2, U2]``. Transfer matrices are arrays of shape ``(n_freq, 2, 2)``:
frequency first, so that numpy's ``@`` chains whole spectra at once.

References
----------
C. Zwikker, C. W. Kosten, *Sound Absorbing Materials*, Elsevier, 1949.
A. Chaigne, J. Kergomard, *Acoustics of Musical Instruments*, Springer, 2016,
eqs. 5.132-5.144 and 7.83.
A. Ernoult, J. Kergomard, "Transfer matrix of a truncated cone with viscothermal losses:
application of the WKB method", Acta Acustica 4(2):7, 2020.
"""

from __future__ import annotations

import numpy as np
from scipy import special

from mpipe.acoustics.air import Air

LOSS_MODELS = ("bessel", "keefe", "lossless")

# Below this angular frequency (rad/s) the loss formulas are evaluated at OMEGA_FLOOR
# instead: both are singular at DC (physics.md D.2).
OMEGA_FLOOR = 2 * np.pi * 1e-3


def _hankel_coefficients(nu: int, n_terms: int) -> np.ndarray:
    """Coefficients a_k(nu) of Hankel's asymptotic expansion (Abramowitz & Stegun 9.2.5)."""
    mu = 4.0 * nu * nu
    a = np.ones(n_terms)
    for k in range(1, n_terms):
        a[k] = a[k - 1] * (mu - (2 * k - 1) ** 2) / (8.0 * k)
    return a


_ASYMPTOTIC_MIN_ABS = 25.0
_A0 = _hankel_coefficients(0, 16)
_A1 = _hankel_coefficients(1, 16)


def bessel_ratio(z: np.ndarray) -> np.ndarray:
    """Return F(z) = 2 J1(z) / (z J0(z)) for z on the ray arg z = -pi/4 (physics.md B.2).

    For |z| >= 25 the ratio J1/J0 comes from Hankel's expansion of H^(1), which dominates
    J there (the neglected H^(2) part is smaller by exp(-sqrt(2)|z|) < 1e-15); 16 terms are
    accurate to ~1e-15 and five times faster than ``jve``. Below, the exponentially scaled
    ``jve`` is used (its scale factors cancel; unscaled ``jv`` overflows above a few kHz).
    """
    z = np.asarray(z, dtype=complex)
    out = np.empty_like(z)
    big = np.abs(z) >= _ASYMPTOTIC_MIN_ABS
    zb = z[big]
    w = 1j / zb
    s0 = np.zeros_like(zb)
    s1 = np.zeros_like(zb)
    for a0, a1 in zip(_A0[::-1], _A1[::-1], strict=True):
        s0 = s0 * w + a0
        s1 = s1 * w + a1
    out[big] = -2j * s1 / (s0 * zb)
    zs = z[~big]
    out[~big] = 2.0 * special.jve(1, zs) / (zs * special.jve(0, zs))
    return out


def series_shunt(
    omega: np.ndarray, radius: float, air: Air, losses: str = "bessel"
) -> tuple[np.ndarray, np.ndarray]:
    """Series impedance and shunt admittance per unit length of a cylindrical duct.

    Telegraph form ``dP/dx = -Zv U``, ``dU/dx = -Yt P`` (physics.md B.1).

    Parameters
    ----------
    omega : array_like
        Angular frequency in rad/s (non-negative).
    radius : float
        Duct radius in m.
    air : Air
        Air properties.
    losses : {"bessel", "keefe", "lossless"}
        Exact Zwikker-Kosten form, Keefe's large-radius approximation, or no losses.

    Returns
    -------
    zv : ndarray
        Series impedance per unit length, Pa s/m^4.
    yt : ndarray
        Shunt admittance per unit length, m^4/(Pa s) per m.
    """
    w = np.maximum(np.asarray(omega, dtype=float), OMEGA_FLOOR)
    area = np.pi * radius**2
    zv0 = 1j * w * air.rho / area
    yt0 = 1j * w * area / (air.rho * air.c**2)
    if losses == "lossless":
        return zv0, yt0
    sqrt_pr = air.nu_sqrt_pr
    if losses == "bessel":
        kv = np.sqrt(-1j * w * air.rho / air.mu)
        kt = sqrt_pr * kv
        zv = zv0 / (1.0 - bessel_ratio(kv * radius))
        yt = yt0 * (1.0 + (air.gamma - 1.0) * bessel_ratio(kt * radius))
        return zv, yt
    if losses == "keefe":
        rv = radius * np.sqrt(w * air.rho / air.mu)
        rt = sqrt_pr * rv
        sqrt_mj = (1 - 1j) / np.sqrt(2.0)
        zv = zv0 * (1 + 2 * sqrt_mj / rv - 3j / rv**2)
        yt = yt0 * (1 + (air.gamma - 1.0) * (2 * sqrt_mj / rt + 1j / rt**2))
        return zv, yt
    raise ValueError(f"unknown loss model {losses!r}; expected one of {LOSS_MODELS}")


def propagation(
    omega: np.ndarray, radius: float, air: Air, losses: str = "bessel"
) -> tuple[np.ndarray, np.ndarray]:
    """Propagation constant and characteristic impedance of a cylindrical duct.

    Parameters
    ----------
    omega : array_like
        Angular frequency in rad/s.
    radius : float
        Duct radius in m.
    air : Air
        Air properties.
    losses : {"bessel", "keefe", "lossless"}
        Loss model, see :func:`series_shunt`.

    Returns
    -------
    gamma : ndarray
        Complex propagation constant Gamma = sqrt(Zv Yt) in 1/m, Re >= 0; a forward wave
        varies as exp(-Gamma x). The lossy wavenumber is k = -j Gamma.
    zc : ndarray
        Complex characteristic impedance sqrt(Zv / Yt) in Pa s/m^3.
    """
    zv, yt = series_shunt(omega, radius, air, losses)
    gamma = np.sqrt(zv * yt)
    # principal root has Re >= 0 already; keep the branch explicit for safety at DC
    gamma = np.where(gamma.real < 0, -gamma, gamma)
    zc = np.sqrt(zv / yt)
    return gamma, zc


def cylinder_matrix(
    omega: np.ndarray, radius: float, length: float, air: Air, losses: str = "bessel"
) -> np.ndarray:
    """Transfer matrix of a lossy cylinder (physics.md B.4).

    Parameters
    ----------
    omega : array_like
        Angular frequency in rad/s, shape ``(n,)``.
    radius, length : float
        Radius and length in m.
    air : Air
        Air properties.
    losses : str
        Loss model, see :func:`series_shunt`.

    Returns
    -------
    ndarray
        Shape ``(n, 2, 2)``, complex; ``[P_in, U_in] = T @ [P_out, U_out]``.
    """
    gamma, zc = propagation(omega, radius, air, losses)
    gl = gamma * length
    ch, sh = np.cosh(gl), np.sinh(gl)
    return abcd(ch, zc * sh, sh / zc, ch)


def cone_matrix(
    omega: np.ndarray,
    radius_in: float,
    radius_out: float,
    length: float,
    air: Air,
    losses: str = "bessel",
) -> np.ndarray:
    """Transfer matrix of a truncated cone with visco-thermal losses (physics.md B.6).

    Losses are those of a cylinder of the log-mean radius (Ernoult & Kergomard 2020). Falls
    back to :func:`cylinder_matrix` when the radii are equal.

    Parameters
    ----------
    omega : array_like
        Angular frequency in rad/s.
    radius_in, radius_out : float
        Radii at the upstream and downstream ends in m.
    length : float
        Axial length in m.
    air : Air
        Air properties.
    losses : str
        Loss model, see :func:`series_shunt`.

    Returns
    -------
    ndarray
        Shape ``(n, 2, 2)``.

    References
    ----------
    Chaigne & Kergomard 2016, eq. 7.83; Ernoult & Kergomard 2020, Acta Acustica 4(2):7.
    """
    r1, r2 = float(radius_in), float(radius_out)
    if abs(r2 - r1) <= 1e-12 * max(r1, r2):
        return cylinder_matrix(omega, r1, length, air, losses)
    rmin, rmax = min(r1, r2), max(r1, r2)
    r_eq = (rmax - rmin) / np.log(1.0 + (rmax - rmin) / rmin)
    gamma, zc = propagation(omega, r_eq, air, losses)
    zc1 = zc * (r_eq / r1) ** 2
    beta = (r2 - r1) / (r1 * length)
    gl = gamma * length
    ch, sh = np.cosh(gl), np.sinh(gl)
    a = (r2 / r1) * ch - (beta / gamma) * sh
    b = (r1 / r2) * zc1 * sh
    c = ((r2 / r1 - beta**2 / gamma**2) * sh + (length * beta**2 / gamma) * ch) / zc1
    d = (r1 / r2) * (ch + (beta / gamma) * sh)
    return abcd(a, b, c, d)


def identity_matrix(n: int) -> np.ndarray:
    """Identity transfer matrices of shape ``(n, 2, 2)``.

    This is also the plane-wave matrix of a step between radii: P and U are continuous
    across the step (physics.md B.7; the discontinuity inertance is neglected).
    """
    out = np.zeros((n, 2, 2), dtype=complex)
    out[:, 0, 0] = 1.0
    out[:, 1, 1] = 1.0
    return out


def chain(matrices: list[np.ndarray]) -> np.ndarray:
    """Cascade transfer matrices, upstream first: ``T = T1 @ T2 @ ... @ Tn``."""
    if not matrices:
        raise ValueError("chain() needs at least one transfer matrix")
    out = matrices[0]
    for m in matrices[1:]:
        out = out @ m
    return out


def invert(t: np.ndarray) -> np.ndarray:
    """Invert reciprocal transfer matrices (det = 1): ``[[D, -B], [-C, A]]``.

    Maps upstream quantities to downstream ones.
    """
    return abcd(t[..., 1, 1], -t[..., 0, 1], -t[..., 1, 0], t[..., 0, 0])


def load_impedance(t: np.ndarray, z_load: np.ndarray) -> np.ndarray:
    """Impedance at the upstream port of ``t`` when the downstream port sees ``z_load``.

    ``Z_in = (A Z_L + B) / (C Z_L + D)`` (physics.md D.1), in Pa s/m^3.
    """
    a, b, c, d = t[..., 0, 0], t[..., 0, 1], t[..., 1, 0], t[..., 1, 1]
    return (a * z_load + b) / (c * z_load + d)


def abcd(a, b, c, d) -> np.ndarray:
    """Stack the elements A, B, C, D (broadcast together) into matrices of shape ``(..., 2, 2)``."""
    a = np.asarray(a, dtype=complex)
    shape = np.broadcast(a, b, c, d).shape
    out = np.empty(shape + (2, 2), dtype=complex)
    out[..., 0, 0] = a
    out[..., 0, 1] = b
    out[..., 1, 0] = c
    out[..., 1, 1] = d
    return out
