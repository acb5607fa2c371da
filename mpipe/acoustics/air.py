"""Thermodynamic and transport properties of air.

Two models are offered:

``"keefe"`` (default)
    Linear fits about 300 K from Benade (1968) as tabulated by Keefe (1984),
    stated valid within +-10 K of 26.85 degC.
``"ernoult"``
    Humidity- and CO2-dependent fits of Ernoult (2023, Inria RR-9500), as used by
    OpenWInD's ``"RR"`` option.

References
----------
D. H. Keefe, "Acoustical wave propagation in cylindrical ducts: transmission line
parameter approximations for isothermal and nonisothermal boundary conditions",
J. Acoust. Soc. Am. 75(1):58-62, 1984.

A. Ernoult, "Effect of air humidity and carbon dioxide in the sound propagation for
the modeling of wind musical instruments", Inria research report RR-9500, 2023.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

_KEEFE_REFERENCE_C = 26.85
_KEEFE_C0 = 347.23
_KEEFE_C_SLOPE = 0.00166

AIR_MODELS = ("keefe", "ernoult")


@dataclass(frozen=True)
class Air:
    """Properties of air at one temperature.

    Attributes
    ----------
    temperature_c : float
        Temperature in degrees Celsius.
    rho : float
        Density in kg/m^3.
    c : float
        Speed of sound in m/s.
    mu : float
        Shear viscosity in kg/(m s).
    gamma : float
        Ratio of specific heats (dimensionless).
    prandtl : float
        Prandtl number (dimensionless).
    model : str
        Name of the formula set that produced the values.
    """

    temperature_c: float
    rho: float
    c: float
    mu: float
    gamma: float
    prandtl: float
    model: str = "keefe"

    @property
    def nu_sqrt_pr(self) -> float:
        """Square root of the Prandtl number (dimensionless)."""
        return math.sqrt(self.prandtl)

    def impedance(self, area: float) -> float:
        """Real characteristic impedance rho c / S of a duct, in Pa s/m^3.

        Parameters
        ----------
        area : float
            Cross-sectional area in m^2.
        """
        return self.rho * self.c / area


def air_properties(
    temperature_c: float,
    model: str = "keefe",
    humidity: float = 0.0,
    co2_fraction: float = 4.2e-4,
) -> Air:
    """Compute air properties at a temperature.

    Parameters
    ----------
    temperature_c : float
        Temperature in degrees Celsius.
    model : {"keefe", "ernoult"}
        Formula set (see module docstring).
    humidity : float
        Relative humidity in [0, 1]; used by ``"ernoult"`` only.
    co2_fraction : float
        Molar fraction of CO2; used by ``"ernoult"`` only.

    Returns
    -------
    Air
        The properties, SI units.

    Raises
    ------
    ValueError
        For an unknown model or a temperature outside -20..60 degC (a likely unit error).
    """
    if not -20.0 <= temperature_c <= 60.0:
        raise ValueError(
            f"temperature {temperature_c} degC is outside the plausible range -20..60 degC "
            "(temperatures are in degrees Celsius)"
        )
    if model == "keefe":
        if humidity != 0.0:
            raise ValueError(
                "the 'keefe' air model is for dry air; use model 'ernoult' for humidity"
            )
        dt = temperature_c - _KEEFE_REFERENCE_C
        return Air(
            temperature_c=float(temperature_c),
            rho=1.1769 * (1.0 - 0.00335 * dt),
            c=_KEEFE_C0 * (1.0 + _KEEFE_C_SLOPE * dt),
            mu=1.846e-5 * (1.0 + 0.0025 * dt),
            gamma=1.4017 * (1.0 - 0.00002 * dt),
            prandtl=(0.8410 * (1.0 - 0.0002 * dt)) ** 2,
            model=model,
        )
    if model == "ernoult":
        if not 0.0 <= humidity <= 1.0:
            raise ValueError(f"relative humidity {humidity} is outside [0, 1]")
        return _ernoult(temperature_c, humidity, co2_fraction)
    raise ValueError(f"unknown air model {model!r}; expected one of {AIR_MODELS}")


def _ernoult(temperature_c: float, humidity: float, co2_fraction: float) -> Air:
    t_k = temperature_c + 273.15
    t20 = 293.15
    d_t = t_k / t20 - 1.0
    h = humidity * 10.0 ** (5.21899 - 5.8294 * (t20 / t_k) - 1.0252 * (t20 / t_k) ** 2)
    d_h = h - 0.011571
    d_c = co2_fraction - 4.2e-4
    c = 343.986 * math.sqrt(
        (t_k / t20) * (1 + 0.314 * d_h - 0.520 * d_c + 0.25 * d_c**2 - 0.16 * d_c * d_t)
    )
    rho = 1.19930 * (t20 / t_k) * (1 - 0.3767 * d_h + 0.4162 * d_c - 0.00291 * d_t)
    cp = 1012.25 * (
        1
        + 0.5438 * d_h
        + 0.638 * d_h**2
        - 0.1594 * d_c
        + 0.075 * d_c**2
        + 9.52e-3 * d_t
        + 4.06e-2 * d_t**2
        + 0.3976 * d_c * d_t
    )
    gamma = 1.40108 * (1 - 0.060 * d_h - 0.104 * d_c - 0.0087 * d_t - 0.154 * d_c * d_t)
    mu = 1.8206e-5 * (1 + 0.77013 * d_t)
    kappa = 2.5562e-2 * (1 + 0.8490 * d_t)
    return Air(
        temperature_c=float(temperature_c),
        rho=rho,
        c=c,
        mu=mu,
        gamma=gamma,
        prandtl=mu * cp / kappa,
        model="ernoult",
    )


def temperature_from_sound_speed(
    c: float,
    model: str = "keefe",
    humidity: float = 0.0,
    co2_fraction: float = 4.2e-4,
) -> float:
    """The temperature (degC) at which air of the given model has sound speed ``c`` (m/s).

    Used to turn the effective sound speed estimated by the wave separation into an
    effective temperature for all other air properties (physics.md A.2). The inverse must
    be that of the model the calibration uses: the Keefe and Ernoult fits differ by about
    0.35 m/s at 20 degC, i.e. 0.6 degC.

    Parameters
    ----------
    c : float
        Sound speed in m/s.
    model : {"keefe", "ernoult"}
        Air model of :func:`air_properties`.
    humidity, co2_fraction : float
        Relative humidity in [0, 1] and CO2 molar fraction (``"ernoult"`` only).

    Returns
    -------
    float
        Temperature in degC. For ``"keefe"`` the linear fit is inverted exactly (also
        outside -20..60 degC); for ``"ernoult"`` the monotonic c(T) is inverted by bracketing
        in -20..60 degC, and values outside that range are clipped to its ends.
    """
    if model == "keefe":
        return _KEEFE_REFERENCE_C + (c / _KEEFE_C0 - 1.0) / _KEEFE_C_SLOPE
    if model != "ernoult":
        raise ValueError(f"unknown air model {model!r}; expected one of {AIR_MODELS}")
    lo, hi = -20.0, 60.0

    def f(t: float) -> float:
        return _ernoult(t, humidity, co2_fraction).c - c

    f_lo, f_hi = f(lo), f(hi)
    if f_lo >= 0:
        return lo
    if f_hi <= 0:
        return hi
    # Bisection on a smooth monotonic function: 60 halvings reach 1e-16 degC.
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if f(mid) < 0:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)
