"""Parameters of the lumped single-reed model, their validation and YAML loading.

The reed is a damped mass-spring oscillator per unit area with a one-sided contact force
against the lay (physics.md G.1):

    m y'' + m g y' + k y + k_c [y - y_c]_+^alpha = p_m - p,

with the reed-tip displacement y positive towards closing, the opening h = y_m - y, the
Bernoulli flow through the slit of effective width lambda and the reed-induced flow S y'.

YAML file format (one flat mapping, SI units; the key ``lambda`` maps to the field ``lam``)::

    k: 8.66e6        # Pa/m
    S: 7.62e-5       # m^2
    y_m: 4.0e-4      # m
    p_m: 1800.0      # Pa
    lambda: 0.013    # m
    m: 0.05          # kg/m^2
    g: 3000.0        # 1/s
    k_c: 8.23e10     # Pa/m^alpha
    y_c: 2.4e-4      # m (optional, default 2.4e-4)
    alpha: 2.0       # (optional, default 2)

References
----------
Chatziioannou & van Walstijn 2012, eqs. (1)-(4) and Table 1; physics.md G and I.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mpipe.core.config import ConfigError, Where, build, load_yaml, spec

# Contact onset displacement held fixed in the paper's step 2 (physics.md I, K), m.
Y_C_DEFAULT = 2.4e-4
# Exponent of the contact force (physics.md G.1).
ALPHA_DEFAULT = 2.0

# Order of the parameters in the optimiser's vector (physics.md I).
VECTOR_FIELDS = ("k", "S", "y_m", "p_m", "m", "g", "lam", "k_c")

# A decimal number with an exponent, as YAML 1.2 (but not PyYAML's YAML 1.1) reads it.
_NUMBER = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+")

# Field name -> YAML key, where they differ (``lambda`` is a Python keyword).
_YAML_KEYS = {"lam": "lambda"}

# Plausibility limits: the search bounds of physics.md I widened about tenfold on each side.
# A value outside them is almost certainly a unit slip (mm for m, kPa for Pa), not a reed.
PLAUSIBLE = {
    "k": (1e5, 1e9),
    "S": (1e-6, 5e-3),
    "y_m": (1e-5, 1e-2),
    "p_m": (1.0, 1e5),
    "lam": (5e-4, 0.2),
    "m": (5e-4, 5.0),
    "g": (10.0, 2e5),
    "k_c": (1e8, 1e14),
    "y_c": (1e-6, 1e-2),
    "alpha": (1.0, 5.0),
}

_HINTS = {
    "k": "stiffness per unit area in Pa/m",
    "S": "effective reed area in m^2; 76 mm^2 is 7.6e-5",
    "y_m": "rest opening in metres; 0.4 mm is 4e-4",
    "p_m": "mouth pressure in Pa; 1.8 kPa is 1800",
    "lam": "effective slit width in metres; 13 mm is 0.013",
    "m": "mass per unit area in kg/m^2",
    "g": "damping rate in 1/s",
    "k_c": "contact stiffness in Pa/m^alpha",
    "y_c": "contact onset displacement in metres",
    "alpha": "contact exponent (dimensionless)",
}


def _plausible(name: str):
    """Check for field ``name``: positive, and within the plausibility limits."""
    lo, hi = PLAUSIBLE[name]

    def check(value: float) -> str | None:
        if name == "k_c" and value == 0.0:
            return None  # contact switched off on purpose
        if not value > 0:
            return f"expected a positive value, got {value:g}"
        if not lo <= value <= hi:
            return (
                f"implausible value {value:g}; expected a value in [{lo:g}, {hi:g}] "
                f"({_HINTS[name]})"
            )
        return None

    return check


class InvalidReedError(ValueError):
    """A reed parameter set is invalid; ``key`` names the offending parameter."""

    def __init__(self, key: str, message: str):
        super().__init__(f"{_YAML_KEYS.get(key, key)}: {message}")
        self.key = key
        self.message = message


@dataclass(frozen=True)
class ReedParameters:
    """Parameters of the lumped reed model, SI units.

    Attributes
    ----------
    k : float
        Stiffness per unit area, Pa/m.
    S : float
        Effective reed area (reed-induced flow u_r = S dy/dt), m^2.
    y_m : float
        Rest opening of the reed channel, m.
    p_m : float
        Mouth (blowing) pressure, gauge, Pa.
    lam : float
        Effective width of the reed channel, m (YAML key ``lambda``).
    m : float
        Mass per unit area, kg/m^2.
    g : float
        Damping rate, 1/s.
    k_c : float
        Contact stiffness, Pa/m^alpha (0 switches contact off).
    y_c : float
        Displacement at which the reed starts to touch the lay, m; at most y_m (y_c = y_m:
        contact starts at closure, the convention of several time-domain simulators).
    alpha : float
        Exponent of the contact force (dimensionless).

    Raises
    ------
    InvalidReedError
        On construction, when a value is non-positive, implausible or y_c > y_m.

    References
    ----------
    Chatziioannou & van Walstijn 2012, eqs. (1)-(4), Table 1; physics.md G.1.
    """

    k: float = spec("Pa/m", "reed stiffness per unit area", _plausible("k"))
    S: float = spec("m^2", "effective reed area for the reed-induced flow", _plausible("S"))
    y_m: float = spec("m", "rest opening of the reed channel", _plausible("y_m"))
    p_m: float = spec("Pa", "mouth pressure (gauge)", _plausible("p_m"))
    lam: float = spec(
        "m", "effective width of the reed channel (YAML key lambda)", _plausible("lam")
    )
    m: float = spec("kg/m^2", "reed mass per unit area", _plausible("m"))
    g: float = spec("1/s", "reed damping rate", _plausible("g"))
    k_c: float = spec("Pa/m^alpha", "contact stiffness (0: no contact)", _plausible("k_c"))
    y_c: float = spec(
        "m",
        "displacement where contact with the lay begins",
        _plausible("y_c"),
        default=Y_C_DEFAULT,
    )
    alpha: float = spec("", "contact force exponent", _plausible("alpha"), default=ALPHA_DEFAULT)

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise InvalidReedError(f.name, f"expected a number, got {value!r}")
            if not math.isfinite(value):
                raise InvalidReedError(f.name, f"expected a finite number, got {value!r}")
            message = f.metadata["check"](value)
            if message:
                raise InvalidReedError(f.name, message)
            # normalise ints from YAML or callers to float, so numba sees one signature
            object.__setattr__(self, f.name, float(value))
        if self.y_c > self.y_m:
            raise InvalidReedError(
                "y_c",
                f"contact must begin at or before closure: expected y_c <= y_m = "
                f"{self.y_m:g} m, got {self.y_c:g} m",
            )

    @property
    def resonance_hz(self) -> float:
        """Natural frequency sqrt(k/m) / (2 pi) of the free reed, Hz."""
        return math.sqrt(self.k / self.m) / (2 * math.pi)

    def as_vector(self) -> np.ndarray:
        """The optimised parameters as a vector, in the order of :data:`VECTOR_FIELDS`.

        Returns
        -------
        ndarray
            ``[k, S, y_m, p_m, m, g, lam, k_c]`` in Pa/m, m^2, m, Pa, kg/m^2, 1/s, m,
            Pa/m^alpha (physics.md I; y_c and alpha are held fixed).
        """
        return np.array([getattr(self, name) for name in VECTOR_FIELDS], dtype=float)

    @classmethod
    def from_vector(
        cls, x: Sequence[float] | np.ndarray, y_c: float = Y_C_DEFAULT, alpha: float = ALPHA_DEFAULT
    ) -> ReedParameters:
        """Build parameters from an optimiser vector (inverse of :meth:`as_vector`).

        Parameters
        ----------
        x : sequence of 8 floats
            ``[k, S, y_m, p_m, m, g, lam, k_c]`` in SI units (see :meth:`as_vector`).
        y_c : float
            Contact onset displacement, m.
        alpha : float
            Contact exponent.

        Returns
        -------
        ReedParameters

        Raises
        ------
        InvalidReedError
            When the vector has the wrong length or describes an invalid reed.
        """
        x = np.asarray(x, dtype=float).ravel()
        if x.size != len(VECTOR_FIELDS):
            raise InvalidReedError(
                "vector", f"expected {len(VECTOR_FIELDS)} values {VECTOR_FIELDS}, got {x.size}"
            )
        values = dict(zip(VECTOR_FIELDS, (float(v) for v in x), strict=True))
        return cls(**values, y_c=y_c, alpha=alpha)

    def to_mapping(self) -> dict[str, float]:
        """The parameters keyed as in the YAML file (``lambda`` for ``lam``), SI units."""
        return {
            _YAML_KEYS.get(f.name, f.name): getattr(self, f.name) for f in dataclasses.fields(self)
        }


def load_reed(path: str | Path) -> ReedParameters:
    """Read and validate a reed parameter file.

    Parameters
    ----------
    path : str or Path
        YAML file holding one flat mapping (see the module docstring).

    Returns
    -------
    ReedParameters

    Raises
    ------
    ConfigError
        Naming the file and the key: unknown or missing keys, non-numbers, non-positive
        or implausible values, y_c > y_m.
    """
    data = dict(load_yaml(path))
    return reed_from_mapping(data, Where(str(path)))


def reed_from_mapping(data: dict, where: Where) -> ReedParameters:
    """Build reed parameters from a parsed YAML mapping keyed as in the file.

    Parameters
    ----------
    data : dict
        Mapping with YAML keys (``lambda``, not ``lam``).
    where : Where
        Position of the mapping, for error messages.

    Returns
    -------
    ReedParameters

    Raises
    ------
    ConfigError
        Naming the file and the key.
    """
    to_field = {v: k for k, v in _YAML_KEYS.items()}
    allowed = [_YAML_KEYS.get(f.name, f.name) for f in dataclasses.fields(ReedParameters)]
    for key in data:
        if key not in allowed:
            raise where.error(str(key), f"unknown key; expected one of: {', '.join(allowed)}")
    values = {to_field.get(k, k): _yaml11_number(v) for k, v in data.items()}
    try:
        return build(ReedParameters, values, where)
    except InvalidReedError as exc:  # checks across fields, raised on construction
        raise where.error(_YAML_KEYS.get(exc.key, exc.key), exc.message) from None
    except ConfigError as exc:
        # build() names fields; report the YAML spelling of renamed keys
        text = str(exc)
        for field, key in _YAML_KEYS.items():
            text = text.replace(f"{where.child(field).path}:", f"{where.child(key).path}:", 1)
        raise ConfigError(text) from None


def _yaml11_number(value):
    """Read ``8.66e6`` as a number.

    PyYAML follows YAML 1.1, where a float needs a dot and a signed exponent (``8.66e+6``),
    so the common spelling ``8.66e6`` arrives as a string. Only strings that are plain
    decimal numbers are converted; anything else is left for :func:`build` to reject.
    """
    if isinstance(value, str) and _NUMBER.fullmatch(value.strip()):
        return float(value)
    return value


def stability_limit(reed: ReedParameters, contact: bool = False) -> float:
    """Largest stable time step of the explicit reed update, s.

    Parameters
    ----------
    reed : ReedParameters
        Reed parameters.
    contact : bool
        Also account for the contact stiffness at closure: replace k by
        k_eff = k + alpha k_c (y_m - y_c)^(alpha - 1), the local stiffness when the reed
        reaches y = y_m (physics.md G.5).

    Returns
    -------
    float
        2 sqrt(m / k) (or with k_eff), s.

    References
    ----------
    physics.md G.5 (Jury conditions on the centred-difference update, eq. (A.1)-(A.2)
    of Chatziioannou & van Walstijn 2012).
    """
    k = reed.k
    if contact and reed.k_c > 0:
        k += reed.alpha * reed.k_c * (reed.y_m - reed.y_c) ** (reed.alpha - 1)
    return 2.0 * math.sqrt(reed.m / k)


def check_stability(reed: ReedParameters, fs: float, contact: bool = False) -> None:
    """Raise if the time step 1/fs violates the stability bound T < 2 sqrt(m/k).

    Parameters
    ----------
    reed : ReedParameters
        Reed parameters.
    fs : float
        Sample rate, Hz.
    contact : bool
        Use the stiffness in contact at closure as well (stricter; see
        :func:`stability_limit`).

    Raises
    ------
    ValueError
        Naming the parameters and the bound.

    References
    ----------
    physics.md G.5.
    """
    if not fs > 0:
        raise ValueError(f"fs: expected a positive sample rate in Hz, got {fs!r}")
    limit = stability_limit(reed, contact)
    step = 1.0 / fs
    if not step < limit:
        which = "k_eff (k with contact at closure)" if contact else "k"
        raise ValueError(
            f"unstable reed update: time step T = 1/fs = {step:.3g} s is not below "
            f"2 sqrt(m/{which}) = {limit:.3g} s (m = {reed.m:g} kg/m^2, k = {reed.k:g} Pa/m); "
            f"raise fs above {2.0 / limit:.4g} Hz or check m and k"
        )
