"""Tone holes: side branches of the bore, open or closed (physics.md D.3).

A tone hole at axial position ``x_h`` (the centre of the hole) is a symmetric T-network
between the two halves of the main bore (Keefe 1982; Dalmont et al. 2002; Lefebvre &
Scavone 2012, eq. 2)::

    T_h = [[1, Za/2], [0, 1]] @ [[1, 0], [1/Zs, 1]] @ [[1, Za/2], [0, 1]]

with the *series* impedance ``Za = j omega rho t_a / (pi a^2)``, a (negative) inertance
referred to the main bore of radius ``a`` at the hole, and the *shunt* impedance::

    Zs = j omega rho (t_i + t_m) / (pi b^2) + Z_chimney

where ``Z_chimney`` is the input impedance of the chimney (a lossy cylinder of radius
``b`` and height ``t``, the wall thickness at the hole) loaded by the radiation impedance
of the hole's outer end when the hole is open, or by a rigid end when it is closed. A
closed hole is thus, at low frequency, the compliance of its chimney volume
``pi b^2 t``. The length corrections (delta = b / a) are those of the modal theory of
Dubos et al. (1999) as given by Chaigne & Kergomard (2016, sec. 7.7), which OpenWInD
also uses::

    t_i = b (0.82 - 0.193 delta - 1.09 delta^2 + 1.27 delta^3 - 0.71 delta^4)
    t_a = b delta^2 (-0.37 + 0.087 delta)
    t_m = b delta / 8 (1 + 0.207 delta^3)        (matching volume, Nederveen et al. 1998)

``det T_h = 1`` exactly (reciprocity), and ``Re Zs >= 0`` when the radiation and the
chimney losses are passive.

References
----------
D. H. Keefe, "Theory of the single woodwind tone hole", JASA 72(3):676-687, 1982.
V. Dubos, J. Kergomard, A. Khettabi, J.-P. Dalmont, D. H. Keefe, C. J. Nederveen, "Theory
of sound propagation in a duct with a branched tube using modal decomposition", Acta
Acustica united with Acustica 85(2):153-169, 1999.
C. J. Nederveen, J. K. M. Jansen, R. R. van Hassel, "Corrections for woodwind tone-hole
calculations", Acta Acustica united with Acustica 84(5):957-966, 1998.
J.-P. Dalmont, C. J. Nederveen, V. Dubos, S. Ollivier, V. Meserette, E. te Sligte,
"Experimental determination of the equivalent circuit of an open side hole: linear and
non linear behaviour", Acta Acustica united with Acustica 88(4):567-575, 2002.
A. Lefebvre, G. P. Scavone, "Characterization of woodwind instrument toneholes with the
finite element method", JASA 131(4):3153-3163, 2012.
A. Chaigne, J. Kergomard, *Acoustics of Musical Instruments*, Springer, 2016, sec. 7.7.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from mpipe.acoustics import ducts
from mpipe.acoustics.air import Air
from mpipe.acoustics.radiation import radiation_impedance
from mpipe.core.config import Where, between, spec

# Radiation models that describe the outer end of a hole (no flange radius to give).
HOLE_RADIATION_MODELS = ("unflanged", "flanged", "flanged-norris", "ideal-open")

# Plausible tone-hole radii and chimney heights, m: a slip of units is caught early.
HOLE_RADIUS_RANGE = (1e-7, 0.05)
CHIMNEY_RANGE = (1e-5, 0.2)


@dataclass(frozen=True)
class ToneHole:
    """A side hole in the bore wall: its geometry (open or closed is the fingering's)."""

    name: str = spec("", "label, used by the fingerings")
    position: float = spec(
        "m", "axial position of the hole's centre from the mouthpiece entry", between(0.0, 5.0)
    )
    radius: float = spec(
        "m", "radius of the hole (1.5 mm is 0.0015)", between(*HOLE_RADIUS_RANGE, "metres")
    )
    chimney: float = spec(
        "m", "chimney height: the wall thickness at the hole", between(*CHIMNEY_RANGE, "metres")
    )


def length_corrections(hole_radius: float, main_radius: float) -> tuple[float, float, float]:
    """Length corrections of a T-junction: inner ``t_i``, matching volume ``t_m``, series ``t_a``.

    Parameters
    ----------
    hole_radius : float
        Radius b of the hole, m.
    main_radius : float
        Radius a of the main bore at the hole, m (b <= a).

    Returns
    -------
    t_i, t_m, t_a : float
        Lengths in m; ``t_a`` is negative. ``t_i`` and ``t_m`` are referred to the hole's
        cross-section, ``t_a`` to the main bore's.

    References
    ----------
    Dubos et al. 1999; Chaigne & Kergomard 2016, sec. 7.7; Nederveen et al. 1998 (t_m).
    """
    b = float(hole_radius)
    d = b / float(main_radius)
    t_i = b * (0.82 - 0.193 * d - 1.09 * d**2 + 1.27 * d**3 - 0.71 * d**4)
    t_m = b * d / 8.0 * (1.0 + 0.207 * d**3)
    t_a = b * d**2 * (-0.37 + 0.087 * d)
    return t_i, t_m, t_a


def shunt_impedance(
    omega: np.ndarray,
    hole: ToneHole,
    main_radius: float,
    air: Air,
    is_open: bool,
    losses: str = "bessel",
    radiation_model: str = "unflanged",
) -> np.ndarray:
    """Shunt impedance Zs of a tone hole, Pa s/m^3 (physics.md D.3).

    Parameters
    ----------
    omega : ndarray
        Angular frequency, rad/s.
    hole : ToneHole
        Geometry.
    main_radius : float
        Radius of the main bore at the hole, m.
    air : Air
        Air properties.
    is_open : bool
        Open (chimney radiating) or closed (chimney ending on a rigid pad).
    losses : str
        Visco-thermal loss model of the chimney, see :func:`mpipe.acoustics.ducts.series_shunt`.
    radiation_model : str
        Radiation of the open hole's outer end, one of :data:`HOLE_RADIATION_MODELS`.

    Returns
    -------
    ndarray
        Complex Zs, same shape as ``omega``.
    """
    omega = np.asarray(omega, dtype=float)
    b = hole.radius
    t_i, t_m, _ = length_corrections(b, main_radius)
    inertance = 1j * np.maximum(omega, ducts.OMEGA_FLOOR) * air.rho * (t_i + t_m) / (np.pi * b**2)
    chimney = ducts.cylinder_matrix(omega, b, hole.chimney, air, losses)
    if is_open:
        z_rad = radiation_impedance(omega, b, air, radiation_model)
        z_chimney = ducts.load_impedance(chimney, z_rad)
    else:
        # rigid end: Z = A / C, the limit of (A Z + B) / (C Z + D) for Z -> infinity
        z_chimney = chimney[:, 0, 0] / chimney[:, 1, 0]
    return inertance + z_chimney


def series_impedance(omega: np.ndarray, hole: ToneHole, main_radius: float, air: Air) -> np.ndarray:
    """Series impedance Za = j omega rho t_a / (pi a^2) of a tone hole, Pa s/m^3 (t_a < 0)."""
    _, _, t_a = length_corrections(hole.radius, main_radius)
    omega = np.asarray(omega, dtype=float)
    return 1j * omega * air.rho * t_a / (np.pi * main_radius**2) + 0j


def hole_matrix(
    omega: np.ndarray,
    hole: ToneHole,
    main_radius: float,
    air: Air,
    is_open: bool,
    losses: str = "bessel",
    radiation_model: str = "unflanged",
) -> np.ndarray:
    """Transfer matrix of a tone hole, shape ``(n, 2, 2)``, det = 1 (physics.md D.3).

    ``[P_up, U_up] = T_h @ [P_down, U_down]`` across the hole's centre plane; see the
    module docstring for the T-network. Arguments as :func:`shunt_impedance`.

    References
    ----------
    Keefe 1982; Lefebvre & Scavone 2012, eq. (2).
    """
    omega = np.atleast_1d(np.asarray(omega, dtype=float))
    zs = shunt_impedance(omega, hole, main_radius, air, is_open, losses, radiation_model)
    za = series_impedance(omega, hole, main_radius, air)
    half = za / (2.0 * zs)
    # the product of the three matrices, written out: det = (1 + half)^2 - za (1 + half/2)/zs = 1
    return ducts.abcd(1.0 + half, za * (1.0 + 0.5 * half), 1.0 / zs, 1.0 + half)


def check_holes(
    holes: Sequence[ToneHole],
    length: float,
    radius_at: Callable[[float], float],
    where: Where,
    key: str = "holes",
) -> None:
    """Validate tone holes against the bore: one-line ConfigErrors.

    Parameters
    ----------
    holes : sequence of ToneHole
        The holes, in any order.
    length : float
        Length of the bore, m.
    radius_at : callable
        Radius of the bore (m) at an axial position (m).
    where : Where
        Position of the bore in its file, for the messages.
    key : str
        Key of the hole list below ``where``.

    Raises
    ------
    ConfigError
        A duplicate name, a hole (with its radius) not inside the bore, a hole wider than
        the bore at its position, or two holes that overlap.
    """
    names = [h.name for h in holes]
    for i, h in enumerate(holes):
        here = where.child(key).child(i)
        if not h.name:
            raise here.error("name", "every hole needs a name (the fingerings refer to it)")
        if names.count(h.name) > 1:
            raise here.error("name", f"two holes are named {h.name!r}")
        if not (h.radius < h.position < length - h.radius):
            raise here.error(
                "position",
                f"hole {h.name!r} at {h.position:g} m with radius {h.radius:g} m is not inside "
                f"the bore (0 to {length:g} m)",
            )
        a = min(radius_at(h.position - h.radius), radius_at(h.position + h.radius))
        if h.radius > a:
            raise here.error(
                "radius",
                f"hole {h.name!r} has radius {h.radius:g} m, larger than the bore's radius "
                f"{a:g} m at {h.position:g} m (expected hole radius <= bore radius)",
            )
    ordered = sorted(holes, key=lambda h: h.position)
    for h0, h1 in zip(ordered, ordered[1:], strict=False):
        if h1.position - h0.position < h0.radius + h1.radius:
            raise where.error(
                key,
                f"holes {h0.name!r} ({h0.position:g} m) and {h1.name!r} ({h1.position:g} m) "
                f"overlap: their centres are {h1.position - h0.position:g} m apart, less than "
                f"the sum of their radii {h0.radius + h1.radius:g} m",
            )
