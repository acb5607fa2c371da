"""Each note's own kernel temperature, whether the notes agree, and which to leave out.

The kernel temperature fitted to a take (:mod:`mpipe.inversion.whole_take.temperature`) is one
number for every note. A note the model cannot play (a reed outside the search bounds, a
wrong bore for that note) has a residual whose minimum in T lies elsewhere, and R(T) summed
over the take follows it: one such note pulled a phrase's temperature 2 degC off and every
other note's parameters 10-20 % with it. So the fit's windows are also read one by one:

- each window's own minimum of F2^2 in T and its standard error, from the parabola through
  the fit's last triple (``se_w^2 = s_w^2 / a_w``, ``s_w^2 = F2^2 / (n_eff - p)``: the
  take's rule for one window);
- each note's temperature, the inverse-variance mean of its windows' minima, with the SE
  ``se_g^2 = max(1 / sum 1/se_w^2, s_within^2 / n_g)``: the windows' scatter within the
  notes (pooled over the notes with two windows or more) bounds it from below, as the
  take's SE is bounded by the scatter of all its windows;
- the notes agree when ``chi^2 = sum_g (T_g - T_bar)^2 / se_g^2`` (``T_bar`` their
  weighted mean) is below the chi-square quantile of ``G - 1`` degrees of freedom at
  :data:`DISAGREE_P`. When they do not, and three notes or more are left, the note
  farthest from the weighted mean of the others (in its combined SE) is left out, and the
  test repeated, while more than half of the notes stay. A note whose every fitted window
  ended on a search bound is left out first (the model does not play it).

The take's temperature is then fitted again on the notes kept; the notes left out are
named in the console and the manifest, and a disagreement makes the take CHECK
(:mod:`mpipe.inversion.trust.diagnostics`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

#: The notes' temperatures disagree when their chi-square exceeds its quantile at this
#: tail probability (a good take flags about one time in a thousand, when the SEs are right).
DISAGREE_P = 1e-3
#: A window's own minimum is kept within this distance of the triple's centre, degC (the
#: triple is 0.5 degC wide: farther, the parabola's extrapolation says only "far").
REACH_C = 4.0


@dataclass(frozen=True)
class NoteTemperatures:
    """Each note's own kernel temperature and the test of their agreement.

    Attributes
    ----------
    temperature_c : dict
        Segment -> its temperature, degC.
    se_c : dict
        Segment -> its standard error, degC.
    excluded : dict
        Segment -> why it was left out of the take's temperature (empty: none).
    chi2 : float
        The chi-square of the notes kept about their weighted mean (NaN: fewer than two).
    dof : int
        Its degrees of freedom (notes kept - 1).
    p_value : float
        Its tail probability (NaN: fewer than two notes).
    first_chi2, first_dof, first_p : float, int, float
        The same over every note with a temperature, before any was left out.
    """

    temperature_c: Mapping[int, float] = field(default_factory=dict)
    se_c: Mapping[int, float] = field(default_factory=dict)
    excluded: Mapping[int, str] = field(default_factory=dict)
    chi2: float = math.nan
    dof: int = 0
    p_value: float = math.nan
    first_chi2: float = math.nan
    first_dof: int = 0
    first_p: float = math.nan

    @property
    def disagree(self) -> bool:
        """Whether the notes' temperatures disagree (before any was left out)."""
        return bool(self.excluded) or (math.isfinite(self.first_p) and self.first_p < DISAGREE_P)

    def words(self) -> str:
        """Each note's own temperature for the console line ("" for one note)."""
        if len(self.temperature_c) < 2:
            return ""
        out = "; each note's own: " + ", ".join(
            f"{t:.2f}" + (" (left out)" if g in self.excluded else "")
            for g, t in self.temperature_c.items()
        )
        return out + (f", chi^2 p = {self.first_p:.2g}" if math.isfinite(self.first_p) else "")

    def reason(self, numbers: dict | None = None) -> str:
        """One line for the take's checks ("" when the notes agree).

        ``numbers`` maps a segment id to its note's number in the take (the name the line
        gives a left-out note; without one it names the segment).
        """
        if not self.disagree:
            return ""
        each = ", ".join(
            f"{self.temperature_c[g]:.2f} +- {self.se_c[g]:.2f}" for g in self.temperature_c
        )
        parts = []
        if math.isfinite(self.first_p) and self.first_p < DISAGREE_P:
            parts.append(
                f"the notes' kernel temperatures disagree ({each} degC; chi^2 "
                f"{self.first_chi2:.1f} on {self.first_dof} degrees of freedom, p = "
                f"{self.first_p:.2g} < {DISAGREE_P:g})"
            )
        if self.excluded:
            parts.append(
                "left out of the take's kernel temperature: "
                + "; ".join(
                    (f"note {numbers[g]}" if numbers and g in numbers else f"segment {g}")
                    + f" ({why})"
                    for g, why in self.excluded.items()
                )
                + (f" (each note's: {each} degC)" if len(parts) == 0 else "")
            )
        return "; ".join(parts)

    def summary(self) -> dict:
        """JSON-ready record."""

        def num(x: float):
            return None if not math.isfinite(x) else float(x)

        return {
            "temperature_c": {str(g): t for g, t in self.temperature_c.items()},
            "se_c": {str(g): num(s) for g, s in self.se_c.items()},
            "excluded": {str(g): why for g, why in self.excluded.items()},
            "chi2": num(self.first_chi2),
            "dof": self.first_dof,
            "p_value": num(self.first_p),
            "chi2_kept": num(self.chi2),
            "p_value_kept": num(self.p_value),
        }


def parabola_vertex(x: Sequence[float], y: Sequence[float]) -> tuple[float, float]:
    """Vertex abscissa and curvature ``a`` of the parabola ``a (x - x0)^2 + c`` through 3 points.

    The vertex is NaN when the parabola has no minimum (``a <= 0``).
    """
    a, b, _ = np.polyfit(np.asarray(x) - x[1], y, 2)
    if a <= 0:
        return math.nan, a
    return x[1] - b / (2 * a), a


def window_minima(
    triple: Sequence[Sequence[Mapping]], centre: float, h: float
) -> tuple[list[float], list[float]]:
    """Each window's own minimum of F2^2 in T and its standard error, degC.

    Parameters
    ----------
    triple : three sequences of rows
        The windows' rows (``f2`` Pa, ``dof``) at ``centre - h``, ``centre``, ``centre + h``.
    centre, h : float
        The triple's centre and half-spacing, degC.

    Returns
    -------
    (minima, ses)
        NaN minimum and infinite SE where a window's F2^2 has no minimum.
    """
    ts = (centre - h, centre, centre + h)
    minima, ses = [], []
    for rows in zip(*triple, strict=True):
        f2 = [float(r["f2"]) ** 2 for r in rows]
        vertex, a = parabola_vertex(ts, f2)
        dof = float(rows[1].get("dof", math.nan) or math.nan)
        s2 = f2[1] / max(dof if math.isfinite(dof) else 1.0, 1.0)
        if not math.isfinite(vertex):
            minima.append(math.nan)
            ses.append(math.inf)
            continue
        minima.append(min(max(vertex, centre - REACH_C), centre + REACH_C))
        ses.append(math.sqrt(s2 / a))
    return minima, ses


def scatter_se(minima: Sequence[float]) -> float:
    """Standard error of the mean of the windows' minima, degC (0 for fewer than 3)."""
    finite = [m for m in minima if math.isfinite(m)]
    if len(finite) < 3:
        return 0.0
    return float(np.std(finite, ddof=1) / math.sqrt(len(finite)))


def _chi2(t: np.ndarray, se: np.ndarray) -> tuple[float, int, float]:
    if t.size < 2:
        return math.nan, 0, math.nan
    w = 1.0 / se**2
    mean = float(np.sum(w * t) / np.sum(w))
    chi2 = float(np.sum(w * (t - mean) ** 2))
    return chi2, t.size - 1, float(stats.chi2.sf(chi2, t.size - 1))


def note_temperatures(
    groups: Sequence[int],
    minima: Sequence[float],
    ses: Sequence[float],
    unplayable: Sequence[int] = (),
) -> NoteTemperatures:
    """Each note's temperature, their agreement, and the notes to leave out (module doc).

    Parameters
    ----------
    groups : sequence of int
        The segment of each fitted window.
    minima, ses : sequence of float
        Each window's own minimum and its SE, degC (:func:`window_minima`).
    unplayable : sequence of int
        Segments whose every fitted window ended on a search bound.

    Returns
    -------
    NoteTemperatures
    """
    by_note: dict[int, list[tuple[float, float]]] = {}
    for g, m, s in zip(groups, minima, ses, strict=True):
        if math.isfinite(m) and math.isfinite(s) and s > 0:
            by_note.setdefault(int(g), []).append((m, s))
    if not by_note:
        return NoteTemperatures()
    within = [m - np.mean([x for x, _ in v]) for v in by_note.values() if len(v) > 1 for m, _ in v]
    n_within = sum(len(v) - 1 for v in by_note.values() if len(v) > 1)
    s2_within = float(np.sum(np.square(within)) / n_within) if n_within else 0.0
    temps, se = {}, {}
    for g, v in by_note.items():
        x, s = np.array([m for m, _ in v]), np.array([s for _, s in v])
        w = 1.0 / s**2
        temps[g] = float(np.sum(w * x) / np.sum(w))
        se[g] = math.sqrt(max(1.0 / float(np.sum(w)), s2_within / len(v)))
    notes = list(temps)
    first = _chi2(np.array([temps[g] for g in notes]), np.array([se[g] for g in notes]))
    excluded: dict[int, str] = {}
    for g in unplayable:
        if g in temps and len(notes) > 1:
            notes.remove(g)
            excluded[g] = "its fitted windows ended on a search bound"
    result = _chi2(np.array([temps[g] for g in notes]), np.array([se[g] for g in notes]))
    while len(notes) >= 3 and result[2] < DISAGREE_P and 2 * (len(notes) - 1) > len(temps):
        worst = max(notes, key=lambda g: _distance(g, notes, temps, se))
        notes.remove(worst)
        excluded[worst] = (
            f"{temps[worst]:.2f} +- {se[worst]:.2f} degC, "
            f"{_distance(worst, [*notes, worst], temps, se):.1f} SE from the others"
        )
        result = _chi2(np.array([temps[g] for g in notes]), np.array([se[g] for g in notes]))
    return NoteTemperatures(temps, se, excluded, *result, *first)


def notes_from_triple(
    triple: Sequence[Sequence[Mapping]], centre: float, h: float, groups: Sequence[int]
) -> NoteTemperatures:
    """:func:`note_temperatures` from the fit's last triple of rows (see :func:`window_minima`).

    A note is unplayable when each of its windows' rows at ``centre`` names a bound
    (``at_bound``).
    """
    minima, ses = window_minima(triple, centre, h)
    bounded: dict[int, bool] = {}
    for g, row in zip(groups, triple[1], strict=True):
        bounded[int(g)] = bounded.get(int(g), True) and bool(row.get("at_bound"))
    return note_temperatures(groups, minima, ses, [g for g, b in bounded.items() if b])


def _distance(g: int, notes: Sequence[int], temps: Mapping, se: Mapping) -> float:
    """``|T_g - mean of the others| / sqrt(se_g^2 + se_mean^2)``."""
    others = [o for o in notes if o != g]
    w = np.array([1.0 / se[o] ** 2 for o in others])
    mean = float(np.sum(w * np.array([temps[o] for o in others])) / np.sum(w))
    return abs(temps[g] - mean) / math.sqrt(se[g] ** 2 + 1.0 / float(np.sum(w)))


__all__ = [
    "DISAGREE_P",
    "NoteTemperatures",
    "note_temperatures",
    "notes_from_triple",
    "parabola_vertex",
    "scatter_se",
    "window_minima",
]
