"""Identifiable combinations of the reed parameters: p_M, gamma, zeta, f_r, Q_r.

Every combination reported is a monomial ``c = C prod x_i^{e_i}``, so
``ln c = const + e . z`` (``z = ln x``) and ``var(ln c) = e^T cov(z) e`` exactly to first
order: its standard error follows from the covariance of the log parameters
(:mod:`mpipe.inversion.trust.uncertainty`) whether or not the parameters themselves are
determined. See :data:`COMBINATIONS` and docs/uncertainty.md.

References
----------
J.-P. Dalmont, J. Gilbert, S. Ollivier, "Nonlinear characteristics of single-reed
instruments: quasistatic volume flow and reed opening measurements", J. Acoust. Soc. Am.
114(4):2253-2262, 2003 (p_M). A. Chaigne, J. Kergomard, *Acoustics of Musical
Instruments*, Springer 2016, chapter 9 (gamma, zeta).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Combination:
    """An identifiable combination of reed parameters, ``C prod x_i^{e_i}``.

    Attributes
    ----------
    name : str
        Column name.
    unit : str
        SI unit.
    exponents : dict
        Parameter name -> exponent e_i.
    description : str
        What it is.
    """

    name: str
    unit: str
    exponents: Mapping[str, float]
    description: str


#: The combinations clarinet acousticians use (definitions in docs/uncertainty.md). zeta and Q_r
#: also need constants: Z_c sqrt(2/rho) for zeta and 1/(2 pi) for f_r (see
#: :func:`combination_values`).
COMBINATIONS = (
    Combination("p_M", "Pa", {"k": 1.0, "y_m": 1.0}, "closing pressure k y_m"),
    Combination("gamma", "", {"p_m": 1.0, "k": -1.0, "y_m": -1.0}, "p_m / p_M"),
    Combination(
        "zeta",
        "",
        {"lam": 1.0, "y_m": 0.5, "k": -0.5},
        "Z_c lam y_m sqrt(2 / (rho p_M))",
    ),  # fmt: skip
    Combination("f_r", "Hz", {"k": 0.5, "m": -0.5}, "reed resonance sqrt(k/m) / (2 pi)"),
    Combination("Q_r", "", {"k": 0.5, "m": -0.5, "g": -1.0}, "reed quality factor omega_r / g"),
)
COMBINATION_NAMES = tuple(c.name for c in COMBINATIONS)


def combination_values(values: Mapping[str, float], z_c: float, rho: float) -> dict[str, float]:
    """Values of :data:`COMBINATIONS` from reed parameters.

    Parameters
    ----------
    values : mapping
        ``k`` (Pa/m), ``y_m`` (m), ``p_m`` (Pa), ``lam`` (m), ``m`` (kg/m^2), ``g`` (1/s).
    z_c : float
        Real characteristic impedance of the mouthpiece entry, rho c / S_entry, Pa s/m^3.
    rho : float
        Air density, kg/m^3.

    Returns
    -------
    dict
        ``p_M`` (Pa), ``gamma``, ``zeta``, ``f_r`` (Hz), ``Q_r``.
    """
    k, y_m, p_m = values["k"], values["y_m"], values["p_m"]
    p_close = k * y_m
    omega = math.sqrt(k / values["m"])
    return {
        "p_M": p_close,
        "gamma": p_m / p_close,
        "zeta": z_c * values["lam"] * y_m * math.sqrt(2.0 / (rho * p_close)),
        "f_r": omega / (2 * math.pi),
        "Q_r": omega / values["g"],
    }


def exponent_vector(exponents: Mapping[str, float], names: Sequence[str]) -> np.ndarray:
    """Exponents of a monomial over the free parameters ``names`` (fixed ones drop out)."""
    return np.array([exponents.get(n, 0.0) for n in names])


def combination_errors(
    cov,
    comb: Mapping[str, float],
    free: Sequence[str],
    invalid: Mapping[str, str],
    limit: float,
) -> dict:
    """``<name>_se`` and ``determined_<name>`` of every combination.

    Parameters
    ----------
    cov : mpipe.inversion.trust.uncertainty.Covariance or None
        Covariance of the log free parameters (None: every SE is NaN).
    comb : mapping
        Values of the combinations (:func:`combination_values`).
    free : sequence of str
        Free parameters, in the covariance's order.
    invalid : mapping
        Free parameter -> reason its SE is not valid: a combination involving it gets NaN.
    limit : float
        A combination is determined when its relative SE is below this.

    Returns
    -------
    dict
        SE in the combination's unit (delta method on ``ln c = const + e . ln x``).
    """
    row = {}
    for c in COMBINATIONS:
        if cov is None or any(n in invalid for n in c.exponents):
            se = math.nan
        else:
            se = comb[c.name] * cov.log_se(exponent_vector(c.exponents, free))
        row[f"{c.name}_se"] = se
        row[f"determined_{c.name}"] = bool(math.isfinite(se) and se / comb[c.name] < limit)
    return row


__all__ = [
    "COMBINATIONS",
    "COMBINATION_NAMES",
    "Combination",
    "combination_errors",
    "combination_values",
    "exponent_vector",
]
