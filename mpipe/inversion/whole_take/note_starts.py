"""Each note of a run started again from the other notes' constants: a start per note.

A run of the take's fit (:mod:`mpipe.inversion.whole_take.take_fit`) starts every note
from one cold start's constants, found on one window of one note. A note played after a
slur into another fingering may then end in a basin of its own sum of squares that the
other notes are not in: on the four-hole clarinet's slurs at 45 dB (a reed that does not
change) the last note, fingered as the first, ended with lambda -25 %, g -59 %, p_m -13 %
while the four before it were right, its F2 a third above theirs and the take PASS.

Given the temperature, the notes are independent (the windows of one note share only its
constants), so each note's sum of squares can be compared at every other note's
constants with its windows' controls fitted along their chains and the constants held
(:func:`~mpipe.inversion.whole_take.warm_starts.run_start`'s warm chains, one call of the
shards for every note at once). A note whose sum there lies below its own fitted minimum
is in a worse basin; :func:`swapped_origin` starts it from those constants, and the run
from that origin is one more start of the multi-start search: its cost on the take decides
(:func:`~mpipe.inversion.whole_take.rivals.rival_costs`), not a rule.
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from mpipe.inversion.whole_take.cold_starts import agree
from mpipe.inversion.whole_take.warm_starts import Origin, warm_controls

log = logging.getLogger(__name__)


def alternatives(slow: np.ndarray) -> list[list[int]]:
    """For each note, the other notes whose constants it might take (indices into ``slow``).

    ``slow``: the notes' constants (N, s), SI units. A note's alternatives are the other
    notes whose constants do not :func:`~mpipe.inversion.whole_take.cold_starts.agree` with
    its own, one of each group that agree among themselves (the first in take order).
    """
    slow = np.asarray(slow, float)
    out: list[list[int]] = []
    for n in range(slow.shape[0]):
        mine: list[int] = []
        for m in range(slow.shape[0]):
            if m == n or agree(slow[m], slow[n]) or any(agree(slow[m], slow[k]) for k in mine):
                continue
            mine.append(m)
        out.append(mine)
    return out


def note_sums(problems, rr) -> np.ndarray:
    """Each note's sum of squares over its informing windows, Pa^2 (inf where one is None).

    ``problems``: the run's windows (notes numbered 0..); ``rr``: each window's r^T r, or
    None where the model did not play the window.
    """
    notes = np.array([q.note for q in problems])
    out = np.zeros(int(notes.max()) + 1 if notes.size else 0)
    for q, r in zip(problems, rr, strict=True):
        if q.informs:
            out[q.note] += np.inf if r is None else float(r)
    return out


def swapped_origin(run, origin: Origin) -> tuple[Origin, list[int]] | None:
    """``origin`` moved to where ``run`` ended, with notes in a worse basin started elsewhere.

    ``run``: a run of the take's fit with its shards open (its ``take``, ``state``,
    ``blocks`` and ``notes``, the take's index of each note of ``state.slow``). Each note's
    sum of squares at each alternative's constants (:func:`alternatives`) is measured with
    the run's shards; a note takes the constants where it is lowest, when that lies below
    its sum at the run's own constants. Returns the moved origin and the take's indices of
    the notes that moved, or None when no note did (or the run has one note).
    """
    slow = np.asarray(run.state.slow, float)
    if slow.shape[0] < 2:
        return None
    problems, layout = run.take.problems, run.take.layout
    own = note_sums(problems, run.blocks.rr)
    best = own.copy()
    moved: dict[int, int] = {}
    fast_of: dict[int, dict] = {}
    known = Origin(origin.reed, origin.peak,
                   fast={q.start: run.state.fast[i] for i, q in enumerate(problems)})  # fmt: skip
    options = alternatives(slow)
    for j in range(max((len(o) for o in options), default=0)):
        pick = np.array([o[j] if j < len(o) else n for n, o in enumerate(options)])
        found = warm_controls(run.take.shards, problems, layout, known,
                              slow[pick[[q.note for q in problems]]])  # fmt: skip
        sums = note_sums(problems, [None if x is None else x[1] for x in found])
        for n in np.flatnonzero((pick != np.arange(pick.size)) & (sums < best)):
            best[n], moved[int(n)] = sums[n], int(pick[n])
            fast_of[int(n)] = {q.start: x[0] for q, x in zip(problems, found, strict=True)
                               if q.note == n and x is not None}  # fmt: skip
    if not moved:
        return None
    here = run.origin_here(origin)
    slow_map, fast_map = dict(here.slow), dict(here.fast)
    for n, m in moved.items():
        slow_map[run.notes[n]] = slow[m]
        fast_map.update(fast_of[n])
    log.info("take fit: %s started again from %s (their sums of squares %s, from %s)",
             ", ".join(f"note {run.notes[n] + 1}" for n in moved),
             ", ".join(f"note {run.notes[m] + 1}'s constants" for m in moved.values()),
             ", ".join(f"{best[n]:.4g}" for n in moved),
             ", ".join(f"{own[n]:.4g}" for n in moved))  # fmt: skip
    return dataclasses.replace(here, slow=slow_map, fast=fast_map), [run.notes[n] for n in moved]


__all__ = ["alternatives", "note_sums", "swapped_origin"]
