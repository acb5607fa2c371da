"""The kernel temperature's profile R(T) and its minimum by successive parabolas.

:class:`Profile` memoises ``R(T) = sum over the fitted windows of F2^2`` with each window's
reed re-fitted at T (warm started from the nearest temperature tried); :func:`settle`
finds its minimum (:mod:`mpipe.inversion.whole_take.temperature` uses both). The profile's
starts: one cold start per take, later notes warm from the note before (:func:`cold_starts`),
and whether a cold start made again would change anything (:func:`same_basin`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from mpipe.inversion.fit.window import invert_window
from mpipe.inversion.settings import PARAMETER_NAMES, InversionConfig
from mpipe.inversion.trust.note_temperature import parabola_vertex
from mpipe.reed.parameters import ReedParameters

#: Two reeds are in one basin of step 2 when every parameter agrees to this log distance
#: (5 %): the basins a cold start far from the fitted temperature falls into differ by
#: factors (m and g collapsed), the warm and cold searches of one basin by far less.
BASIN_TOLERANCE = 0.05
#: Spacing of the coarse and the fine triples of :func:`settle`, degC.
COARSE_C = 1.0
FINE_C = 0.25


@dataclass
class Profile:
    """Memo of ``R(T)``: the windows' solutions at every temperature tried."""

    solve: Callable[[float, Sequence[ReedParameters]], tuple[float, list, list]]
    anchor: list[ReedParameters]
    tried: dict = dataclasses.field(default_factory=dict)  # T -> (R, reeds, rows)

    def __call__(self, t: float) -> float:
        """``R(t)``, Pa^2 (``t`` degC), solved once per temperature (to 1e-4 degC)."""
        t = round(float(t), 4)
        if t not in self.tried:
            near = min(self.tried, key=lambda s: abs(s - t)) if self.tried else None
            warm = self.anchor if near is None else self.tried[near][1]
            self.tried[t] = self.solve(t, warm)
        return self.tried[t][0]

    def subset(self, keep: Sequence[bool], solve) -> Profile:
        """The profile of the windows kept, its memo taken from this one's."""
        idx = [i for i, k in enumerate(keep) if k]
        tried = {}
        for t, (total, reeds, rows) in self.tried.items():
            whole = math.isfinite(total) and len(rows) == len(keep)
            tried[t] = (
                sum(float(rows[i]["f2"]) ** 2 for i in idx) if whole else math.inf,
                [reeds[i] for i in idx],
                [rows[i] for i in idx] if whole else [],
            )
        return Profile(solve, [self.anchor[i] for i in idx], tried)


def settle(
    profile: Profile, t0: float, lo: float, hi: float, max_evaluations: int, coarse: bool = True
):
    """Minimum of ``profile`` by parabolas through three points.

    R(T) is close to a parabola near its minimum (a sum of squares of residuals nearly
    linear in T there). A coarse triple ``t0 + (-1, 0, 1) degC`` is walked downhill until it
    brackets the minimum; a fine triple of half-spacing ``FINE_C`` around the coarse
    parabola's vertex then gives the vertex, the curvature and the sensitivities, and is
    re-centred while the vertex moves by more than ``FINE_C / 2``. With ``coarse`` False
    the fine triples start at once from ``t0``.

    Returns
    -------
    (vertex degC, curvature Pa^2/degC^2, centre of the fine triple degC) or None
    """
    mid = t0
    while coarse:  # coarse: bracket the minimum
        triple = (max(mid - COARSE_C, lo), mid, min(mid + COARSE_C, hi))
        values = [profile(t) for t in triple]
        best = triple[int(np.argmin(values))]
        if best == mid or best in (lo, hi) or len(profile.tried) >= max_evaluations:
            break
        mid = best
    centre = mid
    if coarse:
        vertex, _ = parabola_vertex(triple, values)
        centre = mid if not math.isfinite(vertex) else min(max(vertex, triple[0]), triple[2])
    for step in range(3):  # fine: settle the vertex
        triple = (centre - FINE_C, centre, centre + FINE_C)
        values = [profile(t) for t in triple]
        vertex, curvature = parabola_vertex(triple, values)
        if not all(math.isfinite(v) for v in values) or not math.isfinite(vertex):
            return None
        # never further than the triple's reach from its (evaluated) centre
        vertex = min(max(vertex, centre - 2 * FINE_C), centre + 2 * FINE_C)
        if abs(vertex - centre) <= FINE_C / 2 or len(profile.tried) >= max_evaluations:
            break
        if step < 2:
            centre = vertex  # the last triple's centre stays the evaluated one
    return vertex, curvature, centre


def memo_start(profile: Profile) -> float:
    """Where the minimum of ``profile`` lies by its memo alone, degC (no new evaluation).

    The vertex of the parabola through the lowest temperature tried and its nearest
    neighbours on either side (the lowest itself without both); snapped to a tried
    temperature whose fine triple is tried too when within ``FINE_C / 2`` of one, so that
    settling from there costs nothing more when the minimum has not moved.
    """
    ts = sorted(t for t, v in profile.tried.items() if math.isfinite(v[0]))
    if not ts:
        return math.nan
    i = min(range(len(ts)), key=lambda j: profile.tried[ts[j]][0])
    start = ts[i]
    if 0 < i < len(ts) - 1:
        triple = (ts[i - 1], ts[i], ts[i + 1])
        vertex, _ = parabola_vertex(triple, [profile.tried[t][0] for t in triple])
        if math.isfinite(vertex):
            start = min(max(vertex, triple[0]), triple[2])
    whole = [
        t for t in ts
        if round(t - FINE_C, 4) in profile.tried and round(t + FINE_C, 4) in profile.tried
    ]  # fmt: skip
    near = min(whole, key=lambda t: abs(t - start), default=None)
    return near if near is not None and abs(near - start) <= FINE_C / 2 else start


def cold_starts(p, u, fs, firsts, zero_mean, source, t, config, only=None) -> dict:
    """Segment -> the start of its first fitted window at ``t`` degC (stops at a failure).

    One cold start per take: the first note is cold-started, each later note starts warm
    from the note before it and is cold-started only when that start does not hold
    (:func:`holds`): a note's reed is near its neighbour's, and the global search costs
    about 0.7 s of CPU per note. ``only``: the cold start of that segment alone.
    """
    out, before, first = {}, None, None
    for g, start in firsts.items():
        if only is not None and g != only:
            continue
        kernel, air = source.at(t, start)
        fit = None
        if before is not None:
            fit = invert_window(p, u, fs, start, kernel, air.rho, config,
                                zero_mean=zero_mean, warm=before.reed)  # fmt: skip
            fit = fit if holds(fit, first, config) else None
        if fit is None:
            fit = invert_window(p, u, fs, start, kernel, air.rho, config, zero_mean=zero_mean)
        out[g] = fit
        if fit.reed is None:
            break
        before, first = fit, first or fit
    return out


def holds(fit, first, config: InversionConfig) -> bool:
    """Whether a note's warm start is as good as a cold start would be.

    Converged, and its relative residual within ``residual_factor`` of the take's cold
    start's (the rule that makes a window ``high-residual``,
    :func:`mpipe.inversion.trust.status.classify`): a start in a wrong basin plays the
    note markedly worse than the cold-started note played its own.
    """
    if fit.reed is None or not fit.row.get("optimiser_converged"):
        return False
    ours, theirs = fit.row.get("relative_residual"), first.row.get("relative_residual")
    if ours is None or theirs is None or not (math.isfinite(ours) and math.isfinite(theirs)):
        return False
    return ours <= config.residual_factor * theirs


def same_basin(profile: Profile, centre: float, cold, config, group) -> bool:
    """Whether a cold start at ``centre`` (degC) lands in the profile's own basin.

    One cold start, of the first note's first fitted window at the temperature the profile
    settled at, beside that window's warm-tracked reed there: when every parameter agrees
    within :data:`BASIN_TOLERANCE`, making every note's cold start again and settling a
    second profile would reproduce the first (the repeat cost 2-3 s of CPU on a 2 s take).
    Otherwise the repeat is made. (The reeds are compared, not their F2: at a temperature
    far from its own minimum the right basin may fit worse than a wrong one.)
    """
    tried = profile.tried.get(round(centre, 4))
    first = cold(centre, config, only=group).get(group)
    if tried is None or not tried[1] or first is None or first.reed is None:
        return False
    warm = tried[1][0]
    return all(
        abs(math.log(getattr(first.reed, name) / getattr(warm, name))) <= BASIN_TOLERANCE
        for name in PARAMETER_NAMES
        if getattr(first.reed, name) > 0 and getattr(warm, name) > 0
    )


__all__ = [
    "COARSE_C",
    "FINE_C",
    "Profile",
    "cold_starts",
    "holds",
    "memo_start",
    "same_basin",
    "settle",
]
