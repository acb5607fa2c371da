"""Radiation impedance of the open end of a cylindrical pipe.

All models are written as a reflection coefficient ``R_L = -|R| exp(-2 j k l)`` with an
end correction ``l`` (m), turned into an acoustic impedance
``Z_L = Z0 (1 + R_L) / (1 - R_L)`` with ``Z0 = rho c / (pi a^2)`` real (physics.md C).

Models
------
``"unflanged"``
    Silva et al. (2009) non-causal fit to Levine & Schwinger (1948).
``"flanged"``
    Silva et al. (2009) non-causal fit to the infinite-flange solution (Zorumski). Default.
``"flanged-norris"``
    Norris & Sheng (1989) infinite-flange fit.
``"finite-flange"``
    Dalmont, Nederveen & Joly (2001) interpolation for a flange of outer radius ``b``,
    with the interpolated modulus of Scavone's implementation (physics.md C.5).
``"closed"`` / ``"ideal-open"``
    Limit cases for tests: rigid end (infinite impedance, expressed as a huge value) and
    pressure release (Z_L = 0).

References
----------
F. Silva, Ph. Guillemain, J. Kergomard, B. Mallaroni, A. N. Norris, "Approximation
formulae for the acoustic radiation impedance of a cylindrical pipe", J. Sound Vib.
322(1-2):255-263, 2009.

A. N. Norris, I. C. Sheng, "Acoustic radiation from a circular pipe with an infinite
flange", J. Sound Vib. 135(1):85-93, 1989.

J.-P. Dalmont, C. J. Nederveen, N. Joly, "Radiation impedance of tubes with different
flanges: numerical and experimental investigations", J. Sound Vib. 244(3):505-534, 2001.
"""

from __future__ import annotations

import numpy as np

from mpipe.acoustics.air import Air

RADIATION_MODELS = (
    "flanged",
    "unflanged",
    "flanged-norris",
    "finite-flange",
    "ideal-open",
    "closed",
)

# (a1, a2, a3, b1, b2, b3, b4, beta_s, eta) of Silva et al. 2009
_SILVA = {
    "unflanged": (0.800, 0.266, 0.0263, 0.0599, 0.238, -0.0153, 0.0015, 0.5, 0.6133),
    "flanged": (0.730, 0.372, 0.0231, 0.244, 0.723, -0.0198, 0.00366, 1.0, 0.8216),
}

# Impedance standing in for a rigid termination, in units of Z0. Large enough that
# Z_in of a closed pipe matches -j Z0 cot(kL) to ~1e-12 relative.
_CLOSED_Z = 1e15


def silva_reflection(ka: np.ndarray, kind: str) -> tuple[np.ndarray, np.ndarray]:
    """Modulus of the reflection coefficient and normalised end correction, Silva et al. 2009.

    Parameters
    ----------
    ka : array_like
        Helmholtz number (wavenumber times radius, dimensionless).
    kind : {"unflanged", "flanged"}
        Which fit.

    Returns
    -------
    modulus : ndarray
        |R| (dimensionless).
    l_over_a : ndarray
        End correction divided by the radius.
    """
    a1, a2, a3, b1, b2, b3, b4, beta_s, eta = _SILVA[kind]
    x2 = np.asarray(ka, dtype=float) ** 2
    modulus = (1 + a1 * x2) / (1 + (beta_s + a1) * x2 + a2 * x2**2 + a3 * x2**3)
    l_over_a = eta * (1 + b1 * x2) / (1 + b2 * x2 + b3 * x2**2 + b4 * x2**3)
    return modulus, l_over_a


def norris_sheng_reflection(ka: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """|R| and l/a for an infinite flange, Norris & Sheng 1989 (stated for ka < 3.5)."""
    ka = np.asarray(ka, dtype=float)
    modulus = (1 + 0.323 * ka - 0.077 * ka**2) / (1 + 0.323 * ka + (1 - 0.077) * ka**2)
    l_over_a = 0.8216 / (1 + (0.77 * ka) ** 2 / (1 + 0.77 * ka))
    return modulus, l_over_a


def dalmont_unflanged_reflection(ka: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """|R| and l/a for an unflanged pipe, the fit quoted by Dalmont et al. 2001."""
    ka = np.asarray(ka, dtype=float)
    modulus = (1 + 0.2 * ka - 0.084 * ka**2) / (1 + 0.2 * ka + (0.5 - 0.084) * ka**2)
    l_over_a = 0.6133 * ((1 + 0.044 * ka**2) / (1 + 0.19 * ka**2) - 0.02 * np.sin(2 * ka) ** 2)
    return modulus, l_over_a


def reflection_coefficient(
    omega: np.ndarray,
    radius: float,
    air: Air,
    model: str = "flanged",
    flange_radius: float | None = None,
) -> np.ndarray:
    """Pressure reflection coefficient R_L of the open end, referred to the end plane.

    Parameters
    ----------
    omega : array_like
        Angular frequency in rad/s.
    radius : float
        Radius of the open end in m.
    air : Air
        Air properties.
    model : str
        One of :data:`RADIATION_MODELS` except ``"closed"``.
    flange_radius : float, optional
        Outer radius of a finite flange in m (``"finite-flange"`` only); must exceed ``radius``.

    Returns
    -------
    ndarray
        Complex R_L (dimensionless).
    """
    k = np.asarray(omega, dtype=float) / air.c
    ka = k * radius
    if model in _SILVA:
        modulus, l_over_a = silva_reflection(ka, model)
    elif model == "flanged-norris":
        modulus, l_over_a = norris_sheng_reflection(ka)
    elif model == "finite-flange":
        return _finite_flange(k, radius, flange_radius)
    elif model == "ideal-open":
        return -np.ones_like(k, dtype=complex)
    else:
        raise ValueError(f"unknown radiation model {model!r}; expected one of {RADIATION_MODELS}")
    return -modulus * np.exp(-2j * k * l_over_a * radius)


def _finite_flange(k: np.ndarray, a: float, b: float | None) -> np.ndarray:
    if b is None or not b > a:
        raise ValueError(
            f"finite-flange radiation needs flange_radius > pipe radius {a} m, got {b!r}"
        )
    ka = k * a
    r_inf, l_inf = norris_sheng_reflection(ka)
    r_0, l_0 = dalmont_unflanged_reflection(ka)
    q = a / b
    l_c = (l_inf + q * (l_0 - l_inf) + 0.057 * q * (1 - q**5)) * a
    modulus = r_inf ** ((b - a) / b) * r_0**q
    edge = (
        -0.43
        * (b - a)
        * a
        / b**2
        * np.sin(k * b / (1.85 - q)) ** 2
        * np.exp(-1j * k * b * (1 + q * (2.3 - q - 0.3 * ka**2)))
    )
    return -modulus * np.exp(-2j * k * l_c) + edge


def radiation_impedance(
    omega: np.ndarray,
    radius: float,
    air: Air,
    model: str = "flanged",
    flange_radius: float | None = None,
) -> np.ndarray:
    """Radiation impedance Z_L of the open end in Pa s/m^3.

    Parameters
    ----------
    omega : array_like
        Angular frequency in rad/s.
    radius : float
        Radius of the open end in m.
    air : Air
        Air properties.
    model : str
        One of :data:`RADIATION_MODELS`.
    flange_radius : float, optional
        Outer flange radius in m, for ``"finite-flange"``.

    Returns
    -------
    ndarray
        Complex Z_L. ``"closed"`` returns a very large real impedance.
    """
    z0 = air.impedance(np.pi * radius**2)
    omega = np.asarray(omega, dtype=float)
    if model == "closed":
        return np.full(omega.shape, _CLOSED_Z * z0, dtype=complex)
    r_l = reflection_coefficient(omega, radius, air, model, flange_radius)
    return z0 * (1 + r_l) / (1 - r_l)
