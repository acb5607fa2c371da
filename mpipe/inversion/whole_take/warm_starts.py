"""Where a run of the take's fit starts: its origin, the windows' chains, warm controls.

A run of :mod:`mpipe.inversion.whole_take.take_fit` starts from an :class:`Origin` (a
cold start's reed, or where a fit of the thinned take ended); every note from its
constants, every window's controls fitted along its chain (:func:`chains`: consecutive
windows of one note) with them held (:func:`run_start`), so a crescendo or a new note is
followed without a search.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from mpipe.inversion.whole_take.shard_workers import Shards
from mpipe.inversion.whole_take.take_shards import CHAIN, Layout
from mpipe.reed.parameters import ReedParameters


@dataclass(frozen=True)
class Origin:
    """Where a run of the take's fit starts.

    Attributes
    ----------
    reed : ReedParameters
        A cold start's reed (every note's constants and every chain's first controls).
    peak : float
        The cold start window's peak pressure, Pa (a chain's first p_m scales with its own).
    slow : dict, optional
        Note (its index in the take) -> its constants (s,), SI units, where a fit of the
        thinned take found them (the others from ``reed``).
    t : float, optional
        The temperature to start from, degC (None: the prior's mean).
    fast : dict, optional
        First sample -> a window's controls (f,), SI units, fitted with ``slow``: a chain's
        first window starts from the nearest of them (before the cold start's).
    """

    reed: ReedParameters
    peak: float
    slow: dict = dataclasses.field(default_factory=dict)
    t: float | None = None
    fast: dict = dataclasses.field(default_factory=dict)


def chains(problems) -> list[list[int]]:
    """Runs of at most ``CHAIN`` consecutive windows of one note (take indices)."""
    chains: list[list[int]] = []
    for i, q in enumerate(problems):
        if chains and problems[chains[-1][-1]].note == q.note and len(chains[-1]) < CHAIN:
            chains[-1].append(i)
        else:
            chains.append([i])
    return chains


def run_start(shards: Shards, problems, layout: Layout, origin: Origin):
    """The fit's start: each note's constants and each window's controls, and those left out.

    Every note starts from the constants a fit of the thinned take found for it
    (``origin.slow``), else the cold start's; each window's controls are fitted along its
    chain with them held. Whether the fit then ends in the take's minimum depends on the
    cold start's window
    (:func:`mpipe.inversion.whole_take.cold_starts.cold_windows`); tried and not kept
    (benchmarks/bench_estimator.py): every note from the median of its chains' first
    windows' own fits; choosing between starts by the warm chains' sum of squares, which
    picked the worse basin on one take of five where the passes' final one did not.
    """
    f, cold = layout.n_fast, origin.reed
    notes = list(dict.fromkeys(q.note for q in problems))
    base = np.array([getattr(cold, n) for n in layout.names[f:]])
    slow = np.array([origin.slow.get(n, base) for n in notes], float)
    row = {n: k for k, n in enumerate(notes)}
    found = warm_controls(shards, problems, layout, origin, slow[[row[q.note] for q in problems]])
    cold_fast = np.array([getattr(cold, n) for n in layout.names[:f]])
    excluded = {q.start: "the model does not play this window from the take's cold start"
                for q, x in zip(problems, found, strict=True) if x is None}  # fmt: skip
    if len(excluded) == len(problems):
        raise ValueError("the model plays none of the take's windows from its cold start")
    fast = np.array([x[0] if x is not None else cold_fast for x in found])
    return slow, fast, excluded


def warm_controls(shards: Shards, problems, layout: Layout, origin: Origin, slow):
    """Every window's fast controls warm along its chain: ``(fast, r^T r)`` or None.

    ``slow`` are each window's note's constants (W, s), held. A chain's first window
    starts from the nearest window's controls in ``origin.fast`` (fitted with those
    constants on the thinned take), else from the cold start's (p_m scaled by the window's
    peak pressure against the cold start window's, ``origin.peak``). None: none of the
    window's starts plays.
    """
    f = layout.n_fast
    cold_fast = np.array([getattr(origin.reed, n) for n in layout.names[:f]])
    peaks = np.array([float(np.max(q.target.p)) for q in problems])
    known = np.array(sorted(origin.fast), dtype=float)
    runs = chains(problems)
    per_shard = []
    for a, b in shards.ranges:
        mine = [k for k, c in enumerate(runs) if a <= c[0] < b]
        firsts = []
        for k in mine:
            first = problems[runs[k][0]]
            scaled = cold_fast.copy()
            if "p_m" in layout.names[:f]:  # p_m follows the window's loudness
                scaled[layout.names.index("p_m")] *= peaks[runs[k][0]] / origin.peak
            tries = [scaled, cold_fast]
            if known.size:  # the nearest window of the thinned take's fit
                near = int(known[np.argmin(np.abs(known - first.start))])
                tries.insert(0, np.asarray(origin.fast[near], float))
            firsts.append(tries)
        slows = [slow[runs[k][0]] for k in mine]
        per_shard.append(([[i - a for i in runs[k]] for k in mine], firsts, slows))
    return sum(shards.call("warm", per_shard), [])


def renumber(problems):
    """``problems`` with their notes numbered 0.. by first appearance."""
    index = {n: k for k, n in enumerate(dict.fromkeys(q.note for q in problems))}
    return [dataclasses.replace(q, note=index[q.note]) for q in problems]


__all__ = ["Origin", "chains", "renumber", "run_start", "warm_controls"]
