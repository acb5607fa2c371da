"""Bore geometry, its transfer matrices, input impedance and reflectance.

The bore is a chain of cylinders and truncated cones along +x, from the mouthpiece
entry (x = 0) to the open end. Steps between radii at segment junctions are allowed and
have the identity matrix (physics.md B.7). Tone holes in the wall, open or closed, are
T-networks inserted at their positions (:mod:`mpipe.acoustics.tone_holes`, physics.md D.3).

References
----------
Chatziioannou & van Walstijn 2012, section 2 and Fig. 3 (bore of the simplified
clarinet); physics.md sections B-D.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mpipe.acoustics import ducts
from mpipe.acoustics.air import Air
from mpipe.acoustics.measured_bore import MeasuredInput
from mpipe.acoustics.radiation import RADIATION_MODELS, radiation_impedance
from mpipe.acoustics.tone_holes import HOLE_RADIATION_MODELS, ToneHole, check_holes, hole_matrix
from mpipe.core.config import Where, between, spec

# Plausible radii of a woodwind bore, m: below 0.5 mm or above 5 cm is a unit slip.
RADIUS_RANGE = (5e-4, 0.05)
# Plausible positions along a woodwind, m.
LENGTH_RANGE = (0.0, 5.0)
# Tolerance on gaps or overlaps between consecutive segments, m.
JOIN_TOLERANCE = 1e-9

_RADIUS_HINT = "radii are in metres; 7.5 mm is 0.0075"
_POSITION_HINT = "positions are in metres from the mouthpiece entry"


@dataclass(frozen=True)
class Segment:
    """One duct segment: a cylinder when both radii are equal, otherwise a truncated cone.

    In YAML give ``radius`` for a cylinder or ``radius_start`` and ``radius_end`` for a cone.
    """

    x_start: float = spec(
        "m", "position of the upstream end", between(*LENGTH_RANGE, _POSITION_HINT)
    )
    x_end: float = spec(
        "m", "position of the downstream end", between(*LENGTH_RANGE, _POSITION_HINT)
    )
    radius: float | None = spec(
        "m", "radius of a cylinder", between(*RADIUS_RANGE, _RADIUS_HINT), default=None
    )
    radius_start: float | None = spec(
        "m", "upstream radius of a cone", between(*RADIUS_RANGE, _RADIUS_HINT), default=None
    )
    radius_end: float | None = spec(
        "m", "downstream radius of a cone", between(*RADIUS_RANGE, _RADIUS_HINT), default=None
    )
    name: str = spec("", "label used in plots and messages", default="")

    def _check(self, where: Where) -> None:
        if self.x_end <= self.x_start:
            raise where.error(
                "x_end", f"expected x_end > x_start = {self.x_start:g} m, got {self.x_end:g} m"
            )
        cylinder = self.radius is not None
        cone = self.radius_start is not None or self.radius_end is not None
        if cylinder == cone or (cone and (self.radius_start is None or self.radius_end is None)):
            raise where.error(
                None,
                "give either 'radius' (cylinder) or both 'radius_start' and 'radius_end' (cone)",
            )

    @property
    def length(self) -> float:
        """Axial length in m."""
        return self.x_end - self.x_start

    @property
    def r_in(self) -> float:
        """Upstream radius in m."""
        return self.radius if self.radius is not None else self.radius_start

    @property
    def r_out(self) -> float:
        """Downstream radius in m."""
        return self.radius if self.radius is not None else self.radius_end

    @property
    def is_cylinder(self) -> bool:
        """True when the segment has a constant radius."""
        return self.r_in == self.r_out

    def radius_at(self, x: float) -> float:
        """Radius in m at axial position ``x`` (m) inside the segment."""
        frac = (x - self.x_start) / self.length
        return self.r_in + frac * (self.r_out - self.r_in)

    def cut(self, x0: float, x1: float) -> Segment:
        """The part of this segment between ``x0`` and ``x1`` (m)."""
        r0, r1 = self.radius_at(x0), self.radius_at(x1)
        if self.is_cylinder:
            return Segment(x0, x1, radius=self.radius, name=self.name)
        return Segment(x0, x1, radius_start=r0, radius_end=r1, name=self.name)

    def matrix(self, omega: np.ndarray, air: Air, losses: str = "bessel") -> np.ndarray:
        """Transfer matrix, shape ``(n, 2, 2)``, of this segment (physics.md B.4, B.6)."""
        return ducts.cone_matrix(omega, self.r_in, self.r_out, self.length, air, losses)


@dataclass(frozen=True)
class Radiation:
    """Termination of the open end."""

    model: str = spec(
        "",
        f"radiation model, one of {', '.join(RADIATION_MODELS)}",
        lambda v: (
            None if v in RADIATION_MODELS else f"expected one of {RADIATION_MODELS}, got {v!r}"
        ),
        default="flanged",
    )
    flange_radius: float | None = spec(
        "m", "outer radius of a finite flange", between(*RADIUS_RANGE, _RADIUS_HINT), default=None
    )
    hole_model: str = spec(
        "",
        f"radiation model of the open tone holes' outer ends, one of "
        f"{', '.join(HOLE_RADIATION_MODELS)}",
        lambda v: (
            None
            if v in HOLE_RADIATION_MODELS
            else f"expected one of {HOLE_RADIATION_MODELS}, got {v!r}"
        ),
        default="unflanged",
    )

    def _check(self, where: Where) -> None:
        if self.model == "finite-flange" and self.flange_radius is None:
            raise where.error("flange_radius", "required when model is 'finite-flange'")


@dataclass(frozen=True)
class Bore:
    """The air column: contiguous segments from the mouthpiece entry to the open end."""

    segments: tuple[Segment, ...] = spec("", "segments from the mouthpiece entry outwards")
    radiation: Radiation = spec("", "open-end termination", default=Radiation())
    losses: str = spec(
        "",
        "visco-thermal loss model: bessel (exact), keefe (large radius) or lossless",
        lambda v: None if v in ducts.LOSS_MODELS else f"expected one of {ducts.LOSS_MODELS}",
        default="bessel",
    )
    holes: tuple[ToneHole, ...] = spec(
        "", "tone holes in the wall (physics.md D.3); the fingerings open them", default=()
    )
    open_holes: tuple[str, ...] = spec(
        "",
        "names of the open holes; set by the loader from the calibration's fingering "
        "(write fingerings in a calibration file, not this key)",
        default=(),
    )

    measured: str | None = spec(
        "",
        "a measured input impedance file that stands in for the theory (physics.md D.5), "
        "path relative to the calibration file; its layout declared as for "
        "`mpipe impedance --measured` (YAML header or sidecar FILE.yaml); the segments still "
        "give the duct to the microphones and the equivalent bore outside the measured band",
        default=None,
    )
    measured_input: MeasuredInput | None = spec(
        "",
        "the measured impedance and its fitted equivalent bore (set by the loader)",
        default=None,
    )

    def _check(self, where: Where) -> None:
        if not self.segments:
            raise where.error("segments", "expected at least one segment")
        if abs(self.segments[0].x_start) > JOIN_TOLERANCE:
            raise where.error(
                "segments[0].x_start",
                "the bore must start at the mouthpiece entry x = 0, "
                f"got {self.segments[0].x_start:g} m",
            )
        for i in range(1, len(self.segments)):
            prev, seg = self.segments[i - 1], self.segments[i]
            gap = seg.x_start - prev.x_end
            if abs(gap) > JOIN_TOLERANCE:
                kind = "gap" if gap > 0 else "overlap"
                raise where.error(
                    f"segments[{i}].x_start",
                    f"{kind} of {abs(gap):.6g} m after segment {i - 1} "
                    f"(which ends at {prev.x_end:g} m); expected x_start = {prev.x_end:g} m",
                )
        check_holes(self.holes, self.length, self.radius_at, where)
        known = {h.name for h in self.holes}
        for name in self.open_holes:
            if name not in known:
                raise where.error(
                    "open_holes", f"no hole named {name!r}; the holes are {sorted(known)}"
                )

    @property
    def length(self) -> float:
        """Total length in m."""
        return self.segments[-1].x_end

    @property
    def entry_radius(self) -> float:
        """Radius at the mouthpiece entry in m."""
        return self.segments[0].r_in

    @property
    def exit_radius(self) -> float:
        """Radius of the open end in m."""
        return self.segments[-1].r_out

    def entry_impedance(self, air: Air) -> float:
        """Real characteristic impedance Z0 = rho c / S at the entry, Pa s/m^3."""
        return air.impedance(np.pi * self.entry_radius**2)

    def radius_at(self, x: float) -> float:
        """Radius in m at axial position ``x`` (m); the upstream segment's at a junction."""
        return self.segment_at(min(max(x, 0.0), self.length)).radius_at(x)

    def is_open(self, hole: ToneHole) -> bool:
        """True when ``hole`` is open in this bore's fingering."""
        return hole.name in self.open_holes

    def holes_between(self, x0: float, x1: float) -> tuple[ToneHole, ...]:
        """Tone holes with centres in ``[x0, x1)`` (m), upstream first."""
        return tuple(
            sorted((h for h in self.holes if x0 <= h.position < x1), key=lambda h: h.position)
        )

    def segment_at(self, x: float) -> Segment:
        """The segment containing position ``x`` (m); raises ValueError outside the bore."""
        for seg in self.segments:
            if seg.x_start <= x <= seg.x_end:
                return seg
        raise ValueError(f"position {x:g} m is outside the bore (0 to {self.length:g} m)")

    def between(self, x0: float, x1: float) -> tuple[Segment, ...]:
        """The pieces of the bore between positions ``x0 < x1`` (m), upstream first."""
        if not 0.0 <= x0 <= x1 <= self.length + JOIN_TOLERANCE:
            raise ValueError(f"cannot cut the bore between {x0:g} m and {x1:g} m")
        pieces = []
        for seg in self.segments:
            lo, hi = max(seg.x_start, x0), min(seg.x_end, x1)
            if hi - lo > JOIN_TOLERANCE:
                pieces.append(seg.cut(lo, hi))
        return tuple(pieces)


def mean_flow_resistance(bore: Bore, air: Air, x0: float = 0.0, x1: float | None = None) -> float:
    """The bore's resistance to a steady flow between ``x0`` and ``x1`` (m), Pa s/m^3.

    Poiseuille's law along the main bore, ``R = int 8 mu / (pi a(x)^4) dx``: for a cylinder
    ``8 mu L / (pi a^4)``, for a cone from radius a0 to a1 ``8 mu L (a0^2 + a0 a1 + a1^2) /
    (3 pi a0^3 a1^3)`` (``int dx / a^4`` of a linear a(x)). The limit at zero frequency of
    the transfer matrix's series term (:func:`transfer_matrix`, viscous losses). Side holes
    are left out (closed, they carry no steady flow). ``air.mu`` is the dynamic viscosity,
    Pa s.
    """
    x1 = bore.length if x1 is None else x1
    total = 0.0
    for seg in bore.between(x0, x1):
        a0, a1 = seg.r_in, seg.r_out
        total += seg.length * (a0 * a0 + a0 * a1 + a1 * a1) / (3.0 * a0**3 * a1**3)
    return 8.0 * air.mu / math.pi * total


def transfer_matrix(
    bore: Bore, omega: np.ndarray, air: Air, x0: float = 0.0, x1: float | None = None
) -> np.ndarray:
    """Transfer matrix of the bore between positions ``x0`` and ``x1`` (m).

    Parameters
    ----------
    bore : Bore
        Geometry.
    omega : array_like
        Angular frequency in rad/s, shape ``(n,)``.
    air : Air
        Air properties.
    x0, x1 : float
        Upstream and downstream positions in m; defaults to the whole bore.

    Returns
    -------
    ndarray
        Shape ``(n, 2, 2)``: ``[P(x0), U(x0)] = T @ [P(x1), U(x1)]``. The identity when
        ``x0 == x1``. The tone holes whose centres lie in [x0, x1) are
        included (a hole at a cut belongs downstream), open or closed as ``bore.open_holes`` says.
    """
    omega = np.atleast_1d(np.asarray(omega, dtype=float))
    x1 = bore.length if x1 is None else x1
    matrices = []
    start = x0
    # the tone holes cut the duct into pieces; each hole's T-network sits at its centre
    for hole in bore.holes_between(x0, x1):
        matrices += [p.matrix(omega, air, bore.losses) for p in bore.between(start, hole.position)]
        matrices.append(
            hole_matrix(
                omega,
                hole,
                bore.radius_at(hole.position),
                air,
                bore.is_open(hole),
                bore.losses,
                bore.radiation.hole_model,
            )
        )
        start = hole.position
    matrices += [p.matrix(omega, air, bore.losses) for p in bore.between(start, x1)]
    if not matrices:
        return ducts.identity_matrix(omega.size)
    return ducts.chain(matrices)


def input_impedance(bore: Bore, omega: np.ndarray, air: Air) -> np.ndarray:
    """Input impedance at the mouthpiece entry, Pa s/m^3 (physics.md D.1).

    A bore with a ``measured_input`` gives the measured impedance in its band and its
    fitted equivalent bore's outside (physics.md D.5).

    Parameters
    ----------
    bore : Bore
        Geometry and termination.
    omega : array_like
        Angular frequency in rad/s.
    air : Air
        Air properties.

    Returns
    -------
    ndarray
        Complex Z_in, same shape as ``omega``.
    """
    omega = np.atleast_1d(np.asarray(omega, dtype=float))
    measured = bore.measured_input
    if measured is not None:
        # the measurement in its band, the fitted equivalent bore outside (physics.md D.5)
        return measured.blend(omega, air, input_impedance(measured.equivalent, omega, air))
    z_l = radiation_impedance(
        omega, bore.exit_radius, air, bore.radiation.model, bore.radiation.flange_radius
    )
    return ducts.load_impedance(transfer_matrix(bore, omega, air), z_l)


def reflectance(bore: Bore, omega: np.ndarray, air: Air) -> np.ndarray:
    """Pressure reflectance at the entry, R = (Z_in - Z0) / (Z_in + Z0), Z0 real.

    Z0 is the real characteristic impedance of the entry, the same one that appears in the
    time-domain model (paper eq. A.7).
    """
    z_in = input_impedance(bore, omega, air)
    z0 = bore.entry_impedance(air)
    return (z_in - z0) / (z_in + z0)


@dataclass(frozen=True)
class Resonance:
    """One resonance (peak of |Z_in|).

    Attributes
    ----------
    frequency_hz : float
        Peak frequency in Hz (parabolic interpolation on the grid).
    level_db : float
        20 log10 |Z_in / Z0| at the peak, dB.
    q : float
        Quality factor f / Δf, Δf the half-power (-3 dB) bandwidth of |Z_in|
        (:func:`half_power_bandwidth`); a single-degree-of-freedom resonance
        Z = R / (1 + jQ(f/f_r - f_r/f)) gives its Q.
    """

    frequency_hz: float
    level_db: float
    q: float


def find_resonances(freqs: np.ndarray, z: np.ndarray, z0: float, count: int = 5) -> list[Resonance]:
    """Locate the first peaks of |Z| on a frequency grid.

    Parameters
    ----------
    freqs : ndarray
        Uniform frequency grid in Hz.
    z : ndarray
        Impedance on that grid, Pa s/m^3.
    z0 : float
        Normalising impedance, Pa s/m^3.
    count : int
        How many peaks to return at most.

    Returns
    -------
    list of Resonance
    """
    level = 20 * np.log10(np.abs(z) / z0)
    peaks = np.flatnonzero((level[1:-1] > level[:-2]) & (level[1:-1] >= level[2:])) + 1
    out = []
    for i in peaks[:count]:
        # parabolic interpolation of the dB curve around the grid maximum
        a, b, c = level[i - 1], level[i], level[i + 1]
        denom = a - 2 * b + c
        delta = 0.5 * (a - c) / denom if denom != 0 else 0.0
        df = freqs[1] - freqs[0]
        f_peak = freqs[i] + delta * df
        l_peak = b - 0.25 * (a - c) * delta
        bandwidth = half_power_bandwidth(freqs, level, i, l_peak)
        q = f_peak / bandwidth if bandwidth > 0 else float("nan")
        out.append(Resonance(float(f_peak), float(l_peak), float(q)))
    return out


def half_power_bandwidth(freqs: np.ndarray, level_db: np.ndarray, i: int, peak_db: float) -> float:
    """Half-power (-3.01 dB) bandwidth of the peak of a level curve at grid index ``i``, Hz.

    Near a single-degree-of-freedom resonance ``1/|Z|^2`` is a parabola in frequency, its
    minimum at the peak and twice that at the half-power points. The parabola is fitted
    (least squares) to the grid points from the last below half power on one side to the
    first on the other, and the bandwidth is the distance between its two crossings of
    twice its minimum: exact to a small fraction of a step, where the grid points inside
    the band alone made the Q of a Q = 25 peak read 27 to 37 on a 0.5-2 Hz grid.

    Parameters
    ----------
    freqs : ndarray
        Frequencies, Hz (any increasing grid).
    level_db : ndarray
        20 log10 |Z / Z0| on that grid, dB.
    i : int
        Index of the grid maximum of the peak.
    peak_db : float
        Level of the peak, dB: where the walk to either side stops (``peak_db`` - 3.01 dB).

    Returns
    -------
    float
        The bandwidth, Hz; NaN when a half-power point lies outside the grid.
    """
    target = peak_db - 10 * np.log10(2.0)
    lo = i
    while lo > 0 and level_db[lo] > target:
        lo -= 1
    hi = i
    while hi < len(level_db) - 1 and level_db[hi] > target:
        hi += 1
    if level_db[lo] > target or level_db[hi] > target:
        return float("nan")
    f = freqs[lo : hi + 1] - freqs[i]  # centred: a well-conditioned fit
    with np.errstate(over="ignore"):
        inverse = 10 ** (-(level_db[lo : hi + 1] - peak_db) / 10)  # |Z_peak|^2 / |Z|^2
    if hi - lo < 2 or not np.all(np.isfinite(inverse)):
        # a peak one bin wide, or a measured curve with empty bins (hundreds of dB down)
        return float("nan")
    c2, c1, c0 = np.polyfit(f, inverse, 2)
    minimum = c0 - c1**2 / (4 * c2)
    if not (c2 > 0 and minimum > 0):
        return float("nan")
    return float(2 * np.sqrt(minimum / c2))
