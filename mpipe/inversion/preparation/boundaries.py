"""Where notes start and end in the mouthpiece pressure: level, valleys, periodicity, pitch steps.

:func:`note_spans` places a take's notes from two tracks of the pressure (settings in
``conditioning``, docs/playing.md):

1. the level: a centred moving RMS over ``level_frame_s`` every millisecond
   (:func:`level_envelope`). A stretch can sound where the level is above a threshold: the
   take's loud level (99th percentile) less ``silence_db``, its noise floor (the level of
   its aperiodic frames, lower quartile) plus ``noise_margin_db``, and ``min_rms_pa``
   (:func:`level_threshold`);
2. valleys: inside such a stretch, a dip of more than ``edge_db`` below the sounds on both
   sides of it and at least ``min_silence_s`` long is a gap between two notes (a tongued
   gap, or breath noise between notes that keeps the level above the threshold);
3. periodicity: a stretch holding no periodic YIN frame is not a note (breath noise, a
   noise burst). A note starts at the foot of the attack that brings its level within
   ``edge_db`` of its own level, and ends where its level is last within ``edge_db`` of
   its own level near that end (its first and last periodic frames), so a quiet note keeps its
   own edges and breath noise around a note is left out; and it ends where its level
   falls for good ``edge_db`` below its level over the 50 ms before (a room's
   reverberation after a note is periodic too, but decays from well below it; a sound at
   the note's pitch, ``edge_db`` below it, starting within 0.15 s of its end, is its
   echo, not a note);
4. pitch steps (:func:`pitch_cuts`): inside a note, the median pitch over ``25 ms`` before
   and after each frame, taken ``glide_s / 2`` plus half an f0 frame away from it, differ
   by more than ``pitch_jump_cents``: a legato change of note (instantaneous, or glided
   over up to ``glide_s``), a register change, a squeak. The cut is the centre of the
   frames where the difference is near its peak, so a glide is cut at its middle.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import maximum_filter1d, median_filter

from mpipe.core.signals import blocks, pairwise_sum

#: Length of the span whose median pitch is compared on each side of a frame, s.
SIDE_S = 0.025
#: Fraction of the peak pitch difference that marks a step's extent (its centre is the cut).
PEAK_FRACTION = 0.8
#: Span over which a note's level is remembered when looking for its final decay, s.
DROP_S = 0.05
#: Span past a note's first periodic frame (before its last) that gives its own level, s.
REF_S = 0.2
#: Span over which the level after a note's decay is smoothed before looking for a rise, s.
RIPPLE_S = 0.02
#: Longest walk below the silence threshold to the foot of a note's attack, s.
FOOT_S = 0.1
#: Longest delay after a note within which a softer sound at its pitch is its echo, s.
ECHO_S = 0.15
#: Slowest decay of an echo, dB/s (a room of RT60 3 s); a softer sound that holds its
#: level is a note (a subito piano, a soft slurred note), not an echo.
ECHO_DECAY_DB_S = 20.0
#: Shortest soft part after a note's fall (a subito piano) or between two louder notes (a
#: soft slurred note) that is a note of its own, s: over a shorter span a room's decay
#: (60 dB/s at RT60 1 s) is not told from a held level.
HELD_S = 0.2


def level_envelope(p: np.ndarray, fs: float, frame_s: float, step_s: float = 1e-3):
    """Centred moving RMS of ``p`` (mean removed) every ``step_s``: times (s), RMS (Pa)."""
    n = len(p)
    half = max(int(round(frame_s * fs / 2)), 1)
    centres = np.arange(0, n, max(int(round(step_s * fs)), 1))
    lo = np.clip(centres - half, 0, n)
    hi = np.clip(centres + half, 0, n)
    e_hi, e_lo = _energy_at(p, (hi, lo))
    rms = np.sqrt(np.maximum(e_hi - e_lo, 0.0) / np.maximum(hi - lo, 1))
    return centres / fs, rms


def _energy_at(p, indices: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
    """``e[i]`` at the given indices, ``e = [0, cumsum((p - mean p)^2)]``, read in blocks.

    The running sum is carried from block to block as the first term of the next block's
    cumulative sum: the same additions in the same order as one cumulative sum (numpy's
    accumulate is sequential), and the mean is numpy's to the last bit
    (:func:`mpipe.core.signals.pairwise_sum`).
    """
    n = len(p)
    mean = pairwise_sum(p) / n if n else 0.0
    out = [np.zeros(i.size) for i in indices]
    carry = 0.0
    for a, b in blocks(n):
        x = np.asarray(p[a:b], dtype=float) - mean
        e = np.cumsum(np.concatenate([[carry], x * x]))  # e[a..b]
        for o, i in zip(out, indices, strict=True):
            inside = (i >= a) & (i <= b)
            o[inside] = e[i[inside] - a]
        carry = float(e[-1])
    return tuple(out)


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``(first, last + 1)`` of every run of True."""
    edges = np.diff(np.concatenate([[0], np.asarray(mask).astype(int), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True))


def level_threshold(t, level, centres, f0, conditioning) -> float:
    """The level (Pa) below which a take is silent (see the module docstring, item 1).

    Parameters
    ----------
    t, level : ndarray
        The level envelope: times (s), RMS (Pa).
    centres, f0 : ndarray
        The f0 track: frame centres (s), f0 (Hz, NaN where aperiodic).
    conditioning : mpipe.inversion.settings.ConditioningConfig
        ``silence_db``, ``noise_margin_db``, ``min_rms_pa``.
    """
    c = conditioning
    if not level.size:
        return float(c.min_rms_pa)
    loud = float(np.percentile(level, 99))
    floor = 0.0
    quiet = ~np.isfinite(f0)
    if quiet.sum() >= 5:  # the noise floor: where the take is not periodic
        idx = np.clip(np.searchsorted(t, centres[quiet]), 0, level.size - 1)
        floor = float(np.percentile(level[idx], 25))
    return max(
        float(c.min_rms_pa),
        loud * 10 ** (-c.silence_db / 20),
        floor * 10 ** (c.noise_margin_db / 20),
    )


def _valleys(level: np.ndarray, depth: float, shortest: int) -> list[tuple[int, int]]:
    """Dips of a stretch's level below ``depth`` times the sounds on both sides of them."""
    left = np.maximum.accumulate(level)
    right = np.maximum.accumulate(level[::-1])[::-1]
    dip = level < depth * np.minimum(left, right)
    return [(a, b) for a, b in runs(dip) if b - a >= shortest]


def _trim(a: int, b: int, level, t, periodic_t, frame_s: float, depth: float):
    """A stretch ``[a, b)`` narrowed to its first note: (foot, end, sounding index) or None.

    The foot is where the blowing lifts the level off the floor; the sounding index, where
    the attack brings the level within ``depth`` of the note's own level.

    The note lies within half an f0 frame of its periodic frames (a blowing pressure's rise
    before the oscillation grows is not yet the note), where its level is within ``depth``
    of its own level near each end, and ends where its level falls for good.
    """
    inside = periodic_t[(periodic_t >= t[a]) & (periodic_t < t[b - 1])]
    if inside.size < 2:
        return None
    first = max(a, int(np.searchsorted(t, inside[0] - frame_s / 2)))
    last = min(b, int(np.searchsorted(t, inside[-1] + frame_s / 2)))
    ends = []
    for centre, side in ((inside[0], 1), (inside[-1], -1)):
        # the note's own level past its attack (before its release): its first (last) REF_S
        lo, hi = sorted((centre, centre + side * REF_S))
        near = (t >= max(lo, inside[0])) & (t <= min(hi, inside[-1]))
        ref = float(np.percentile(level[near], 90)) if near.any() else 0.0
        loud = np.flatnonzero(level[first:last] >= depth * ref)
        ends.append(first + (loud[0] if side > 0 else loud[-1] + 1) if loud.size else None)
    if ends[0] is None or ends[1] is None or ends[1] <= ends[0]:
        return None
    below = max(a - int(round(FOOT_S / (t[1] - t[0]))) if t.size > 1 else a, 0)
    foot = _foot(level, below, ends[0], t)
    return foot, _decay_start(level, ends[0], ends[1], t, depth), ends[0]


def _foot(level, a: int, start: int, t) -> int:
    """The foot of the attack that reaches ``start``: back while the level keeps falling.

    Smoothed over :data:`RIPPLE_S`; never before ``a``, which may lie below the silence
    threshold (at most :data:`FOOT_S` before the stretch). A note starts where its level
    leaves the floor (silence, breath noise, a tongued gap's bottom), as a score's note
    does when the blowing starts, not where it nears its own level.
    """
    step = float(t[1] - t[0]) if t.size > 1 else 1e-3
    width = max(int(RIPPLE_S / step), 1)
    smooth = median_filter(level[a : start + width], width)  # past start: no edge plateau
    i = start - a
    while i > 0 and smooth[i - 1] < smooth[i]:
        i -= 1
    return a + i


def _decay_start(level, a: int, b: int, t, depth: float) -> int:
    """The end of ``[a, b)`` where the level falls for good ``depth`` below its recent maximum.

    Recent: over the :data:`DROP_S` before.
    A room's (or a sensor's) decay after a note is periodic too: only its level tells it
    from the note.
    """
    step = float(t[1] - t[0]) if t.size > 1 else 1e-3
    span = max(int(round(DROP_S / step)), 1)
    x = level[a:b]
    before = maximum_filter1d(x, span, origin=(span - 1) // 2)  # max over the span ending here
    after = np.maximum.accumulate(x[::-1])[::-1]
    gone = np.flatnonzero(after < depth * before)
    return a + int(gone[0]) if gone.size else b


def note_spans(t, level, threshold, centres, f0, frame_s, conditioning, duration=None):
    """Notes ``(start s, end s)`` of a take (the module docstring, items 1-3), pitch aside.

    Parameters
    ----------
    t, level : ndarray
        The level envelope (:func:`level_envelope`): times (s), RMS (Pa).
    threshold : float
        Silence level, Pa (:func:`level_threshold`).
    centres, f0 : ndarray
        The f0 track: frame centres (s), f0 (Hz, NaN where aperiodic).
    frame_s : float
        The f0 frame's length, s.
    conditioning : mpipe.inversion.settings.ConditioningConfig
        ``edge_db``, ``min_silence_s``, ``min_note_s``.
    duration : float, optional
        The take's length, s: a note still sounding at the last envelope sample ends there
        (default the last envelope time plus one step).

    Returns
    -------
    list of (float, float, float)
        Each note's start (the blowing onset: the foot of its attack), end, and sounding
        onset (where its level first comes within ``edge_db`` of its own level), s, in time
        order.
    """
    c = conditioning
    step = float(t[1] - t[0]) if t.size > 1 else 1e-3
    mask = level >= threshold
    for a, b in runs(~mask):  # short silences inside a note do not split it
        if a > 0 and b < mask.size and (b - a) * step < c.min_silence_s:
            mask[a:b] = True
    depth = 10 ** (-c.edge_db / 20)
    shortest = max(int(round(c.min_silence_s / step)), 1)
    periodic_t = centres[np.isfinite(f0)]
    hop = float(np.median(np.diff(centres))) if centres.size > 1 else step

    def periodic(i0: int, i1: int) -> bool:
        """Periodic frames over min_note_s in ``[t[i0], t[i1 - 1]]``, a level that holds.

        A room's reverberation is periodic too, but decays (:func:`_decays`).
        """
        inside = (periodic_t >= t[i0]) & (periodic_t <= t[min(i1, t.size) - 1])
        enough = inside.sum() * hop >= c.min_note_s
        return bool(enough and not _decays(t[i0:i1], level[i0:i1]))

    spans = []
    for a, b in runs(mask):
        valleys = [(a + v0, a + v1) for v0, v1 in _valleys(level[a:b], depth, shortest)]
        cuts = [a, *[x for v in valleys for x in v], b]
        pieces = [(x, y, False) for x, y in zip(cuts[::2], cuts[1::2], strict=True)]
        # a valley that is periodic is a soft note (slurred between two louder), not a gap
        held = [(*v, True) for v in valleys if (v[1] - v[0]) * step >= HELD_S and periodic(*v)]
        pieces = sorted(pieces + held)
        while pieces:
            a1, b1, held = pieces.pop(0)
            kept = _trim(a1, b1, level, t, periodic_t, frame_s, depth) if b1 - a1 > 1 else None
            if kept is None:
                continue
            if kept[1] < b1:  # after the note's decay, from its lowest point, another may
                # sound: where the level rises again by edge_db / 2 (a decay's ripple does
                # not; smoothed over RIPPLE_S, as two decays interfering make deep notches)
                tail = median_filter(level[kept[1] : b1], max(int(RIPPLE_S / step), 1))
                low = int(np.argmin(tail))
                if tail[low:].max() * np.sqrt(depth) >= tail[low]:
                    pieces.insert(0, (kept[1] + low, b1, False))
                elif (b1 - kept[1]) * step >= HELD_S and periodic(kept[1], b1):
                    # a soft part that sounds on (a subito piano): a note if it does not
                    # decay as a room's echo does (:func:`_without_echoes` asks)
                    pieces.insert(0, (kept[1], b1, True))
            if (kept[1] - kept[0]) * step >= c.min_note_s:
                end = t[-1] + step if duration is None else duration
                last = end if kept[1] == level.size else float(t[kept[1] - 1] + step)
                start = max(float(t[kept[0]]), spans[-1][1] if spans else 0.0)  # no overlap
                sounding = max(float(t[max(kept[2], kept[0])]), start)
                if last > start:
                    spans.append((start, last, sounding, held))
    return _without_echoes(spans, t, level, centres, f0, depth, c.pitch_jump_cents)


def _median_f0(centres, f0, a: float, b: float) -> float:
    """Median f0 (Hz) of the periodic frames centred in ``[a, b]`` (NaN without one)."""
    sel = f0[(centres >= a) & (centres <= b) & np.isfinite(f0)]
    return float(np.median(sel)) if sel.size else np.nan


def _without_echoes(spans, t, level, centres, f0, depth: float, jump: float):
    """The spans less those that are the reverberation of the note before them.

    An echo: it starts within :data:`ECHO_S` of that note's end, stays ``depth`` below that
    note's level (90th percentile) and plays its pitch (within ``jump`` cents). A span
    found as a soft note whose level holds (``held``: a subito piano, a periodic valley)
    is no echo.
    """

    def loudness(a, b):
        sel = level[(t >= a) & (t < b)]
        return (float(np.max(sel)), float(np.percentile(sel, 90))) if sel.size else (0.0, 0.0)

    out = []
    for a, b, sounding, held in spans:
        if out:
            a0, b0, _ = out[-1]
            close = a - b0 < ECHO_S and loudness(a, b)[0] < depth * loudness(a0, b0)[1]
            pitch, pitch0 = _median_f0(centres, f0, a, b), _median_f0(centres, f0, a0, b0)
            if close and abs(1200 * np.log2(pitch / pitch0)) < jump and not held:
                continue
        out.append((a, b, sounding))
    return out


def _decays(times: np.ndarray, level: np.ndarray) -> bool:
    """The level (Pa) falls faster than :data:`ECHO_DECAY_DB_S` over ``times`` (s): a room's.

    The slope of a straight line fitted to the level in dB; fewer than 4 samples decay.
    """
    sel = level > 0
    if sel.sum() < 4:
        return True
    slope = np.polyfit(times[sel], 20 * np.log10(level[sel]), 1)[0]
    return bool(slope < -ECHO_DECAY_DB_S)


def _side_medians(times, cents, gap: float, side: float):
    """Median pitch over ``[t - gap - side, t - gap]`` and ``[t + gap, t + gap + side]``.

    Each side is a window of frames whose both ends only move forward with ``t``: every
    frame enters and leaves it once, and a Fenwick tree over the pitches' ranks gives the
    window's order statistics, so the whole track costs O(n log n) (a median per frame by
    sorting each window cost O(n w log w), O(n^2) on a long note).
    """
    times = np.asarray(times, dtype=float)
    cents = np.asarray(cents, dtype=float)
    lo = _window_medians(times, cents, times - gap - side, times - gap)
    hi = _window_medians(times, cents, times + gap, times + gap + side)
    both = np.isfinite(lo) & np.isfinite(hi)
    return np.where(both, lo, np.nan), np.where(both, hi, np.nan)


def _window_medians(times, values, starts, stops) -> np.ndarray:
    """Median of the finite ``values`` with ``starts[i] <= times <= stops[i]`` (NaN if < 2).

    ``times``, ``starts`` and ``stops`` are non-decreasing.
    """
    n = times.size
    first = np.searchsorted(times, starts, side="left")
    last = np.searchsorted(times, stops, side="right")  # window: [first, last)
    finite = np.isfinite(values)
    order = np.argsort(np.where(finite, values, np.inf), kind="stable")
    rank = np.empty(n, dtype=int)
    rank[order] = np.arange(n)
    tree = np.zeros(n + 1, dtype=int)
    sorted_values = values[order]
    out = np.full(n, np.nan)
    head = tail = count = 0  # frames [head, tail) are in the tree
    for i in range(n):
        while tail < last[i]:
            if finite[tail]:
                _add(tree, rank[tail] + 1, 1)
                count += 1
            tail += 1
        while head < first[i]:
            if head < tail and finite[head]:
                _add(tree, rank[head] + 1, -1)
                count -= 1
            head += 1
        tail = max(tail, head)
        if count >= 2:
            k1, k2 = (count + 1) // 2, count // 2 + 1
            out[i] = 0.5 * (sorted_values[_kth(tree, k1)] + sorted_values[_kth(tree, k2)])
    return out


def _add(tree: np.ndarray, i: int, delta: int) -> None:
    while i < tree.size:
        tree[i] += delta
        i += i & -i


def _kth(tree: np.ndarray, k: int) -> int:
    """The 0-based rank of the k-th smallest (1-based k) element counted in the tree."""
    pos, step = 0, 1 << (tree.size - 1).bit_length()
    while step:
        nxt = pos + step
        if nxt < tree.size and tree[nxt] < k:
            pos = nxt
            k -= tree[nxt]
        step >>= 1
    return pos


def pitch_cuts(start, end, centres, cents, frame_s, conditioning) -> list[float]:
    """Times inside ``[start, end]`` (s) where the pitch steps (the module docstring, item 4).

    Parameters
    ----------
    start, end : float
        The note, s.
    centres, cents : ndarray
        The f0 track's frame centres (s) and pitch (cent, NaN where aperiodic).
    frame_s : float
        The f0 frame's length, s.
    conditioning : mpipe.inversion.settings.ConditioningConfig
        ``pitch_jump_cents``, ``glide_s``, ``min_note_s``.
    """
    c = conditioning
    inside = (centres >= start) & (centres <= end)
    if inside.sum() < 5:
        return []
    times, track = centres[inside], cents[inside]
    before, after = _side_medians(times, track, c.glide_s / 2 + frame_s / 2, SIDE_S)
    step = np.abs(after - before)
    cuts = []
    for a, b in runs(np.nan_to_num(step, nan=0.0) > c.pitch_jump_cents):
        peak = float(np.max(step[a:b]))
        near = a + np.flatnonzero(step[a:b] >= PEAK_FRACTION * peak)
        cut = float(np.mean(times[near]))
        last = cuts[-1] if cuts else start
        if cut - last >= c.min_note_s and end - cut >= c.min_note_s:
            cuts.append(cut)
    return _distinct(start, end, cuts, times, track, c.pitch_jump_cents)


def _distinct(start, end, cuts, times, track, jump: float) -> list[float]:
    """The cuts whose two segments differ in median pitch by more than ``jump`` (cent).

    A noisy f0 track (a soft note in breath noise) can step for a moment; the notes on
    either side of a real step differ as wholes.
    """
    cuts = list(cuts)
    changed = True
    while changed and cuts:
        changed = False
        edges = [start, *cuts, end]
        medians = [np.nanmedian(track[(times >= a) & (times < b)]) if np.isfinite(
            track[(times >= a) & (times < b)]).any() else np.nan
            for a, b in zip(edges[:-1], edges[1:], strict=True)]  # fmt: skip
        for i, cut in enumerate(cuts):
            if not abs(medians[i + 1] - medians[i]) > jump:
                cuts.remove(cut)
                changed = True
                break
    return cuts


__all__ = ["level_envelope", "level_threshold", "note_spans", "pitch_cuts", "runs"]
