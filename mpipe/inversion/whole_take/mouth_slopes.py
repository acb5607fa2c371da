"""The player's mouth pressure about each window: its slope from the neighbouring windows.

The paper's window holds the mouth pressure p_m over the window (eq. 15), and the history
start drives the reed over the lead-in before it with the same p_m (physics.md H). In a
crescendo p_m rises throughout, so the lead-in plays a mouth pressure higher than the
player's there, and the mean flow it finds missing (``c``,
:mod:`mpipe.inversion.fit.lead_in`) is biased in one direction; within the window the
departure is symmetric about the centre and p_m takes the window's mean. Measured
(``benchmarks/true_signals.py``, the noise-free crescendo of ``bench_estimator.py``, seed
0, +540 Pa/s): y_m +0.158 %, k -0.204 %, lambda -0.201 % with p_m held; with the truth's
slope over the lead-in only +0.051, -0.093, -0.157 %; over the lead-in and the window
+0.037, -0.016, +0.015 %. The error grew with the lead-in (+0.131 % at 3 ms, +0.318 % at 40
ms) and was absent on a steady tone (0.012 %).

So the take's fit plays each window at ``p_m + s (t - t_c)``
(:attr:`mpipe.inversion.fit.objective.TargetWindow.p_m_slope`), with ``s`` the slope of a
least-squares line of the fitted p_m against time through its note's windows: of three
lines over 0.4 s (:data:`SPAN_S` either side of the window, before it, after it), the one
about which the p_m scatter least, so that a bend of the player's curve (a crescendo's
end) is followed, not smoothed (the choice of essentially non-oscillatory schemes). ``s``
is held within a pass of the fit and set again from the new p_m between passes
(:func:`mpipe.inversion.whole_take.passes.run_passes`); the fit's Jacobian does not carry
its dependence on the neighbours' p_m (a window's p_m is still its mean, and the slope's
noise moves the mouth pressure at a lead-in's start by a thirtieth of a window's p_m
noise). p_m itself stays one value per window: the take's ``p_m`` track is unchanged in
meaning.

Measured, same takes, noise-free (the crescendo, then a diminuendo 2610 -> 1800 Pa):
with the truth's slopes y_m +0.037 / -0.015 %, k -0.016 / -0.003 %, lambda +0.015 /
-0.024 %; with these, the same to 0.002 %; with one centred line, the diminuendo's k
-0.091 %, lambda -0.096 % (its bend at 1.9 s smoothed over the 0.2 s after it); held p_m,
its p_m +0.126 %, k +0.126 %, lambda +0.217 %.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: Half the span of a window's lines, s (each through at least :data:`MIN_WINDOWS`). Over a
#: steady note the slope is only the p_m's noise: through 21 windows 20 ms apart it moves
#: the mouth pressure at a lead-in's start by a thirtieth of one window's p_m noise.
#: Shorter lines (five windows, a third of it; seven, 0.06 s) moved the 0.6 s steady tone's
#: refit along its flat valley of p_m, y_m, m, g by about a standard error from the
#: linear shift (tests/inversion/whole_take/test_frontend_joint.py: 0.89-1.13 chi-square
#: units against 0.10 with p_m held and 0.16 with these).
SPAN_S = 0.2
#: The fewest windows a slope is drawn through; a note of fewer holds p_m (slope 0).
MIN_WINDOWS = 5
#: The slopes are settled when they move the mouth pressure at the lead-ins' starts by less
#: than this fraction of p_m, root-mean-square over the windows (the crescendo's ramp is
#: 5e-3 there; on a steady 45 dB tone the first pass moves them by 4-9e-4 from the warm
#: chains', the second by 1e-4).
SLOPE_SETTLED = 2e-4
#: A slope is limited to move the mouth pressure at its lead-in's start by this fraction of
#: p_m (a note's onset, where the fitted p_m of the first windows rise steeply).
MAX_RAMP = 0.5


def mouth_slopes(times_s: Sequence[float], notes: Sequence[int], p_m: np.ndarray,
                 reach_s: float, drawn: Sequence[bool] | None = None) -> np.ndarray:  # fmt: skip
    """Each window's mouth-pressure slope from its note's neighbouring windows, Pa/s.

    Parameters
    ----------
    times_s : sequence of float
        Each window's centre, s (the windows in time order).
    notes : sequence of int
        Each window's note.
    p_m : ndarray
        Each window's fitted mouth pressure, Pa.
    reach_s : float
        From a window's centre to its lead-in's start, s (the slope is limited there to
        :data:`MAX_RAMP` of p_m).
    drawn : sequence of bool, optional
        The windows whose p_m the lines are drawn through (default all): those that inform
        their note. A release's p_m falls within its window (the player stops blowing):
        its windows are played at the line through the windows before them (drawn through
        the release, a single centred line tilted the steady window before it, which on a
        noise-free 0.6 s tone then fitted far above its note and was left out).

    Returns
    -------
    ndarray
        The slope of the best of three least-squares lines of p_m against time through
        its note's windows (:func:`_line_slope`); 0 in a note of fewer than
        :data:`MIN_WINDOWS` windows.
    """
    t = np.asarray(times_s, float)
    notes_ = np.asarray(notes)
    p = np.asarray(p_m, float)
    use = np.ones(t.size, bool) if drawn is None else np.asarray(drawn, bool)
    out = np.zeros(t.size)
    for note in np.unique(notes_):
        idx = np.flatnonzero((notes_ == note) & use)
        if idx.size < MIN_WINDOWS:
            continue
        for i in np.flatnonzero(notes_ == note):
            out[i] = _line_slope(t[idx], p[idx], t[i])
    limit = MAX_RAMP * np.abs(p) / max(reach_s, 1e-12)
    return np.clip(out, -limit, limit)


def _line_slope(t: np.ndarray, p: np.ndarray, at: float) -> float:
    """The slope at ``at`` of the best-fitting of the lines about, before and after it.

    Each line is drawn through the windows within a span of ``2 SPAN_S`` (at least
    :data:`MIN_WINDOWS`; else the nearest): centred on ``at``, ending at it, starting at it; the
    one whose p_m scatter least about it gives the slope (essentially non-oscillatory
    choice, as in ENO schemes): after a crescendo's end the line before it, not one across
    the bend.
    """
    best, slope = np.inf, 0.0
    for lo, hi in ((at - SPAN_S, at + SPAN_S), (at - 2 * SPAN_S, at), (at, at + 2 * SPAN_S)):
        near = (t >= lo - 1e-9) & (t <= hi + 1e-9)
        if near.sum() >= MIN_WINDOWS:
            b, scatter = _line(t[near], p[near])
            if scatter < best:
                best, slope = scatter, b
    if not np.isfinite(best):  # no span holds MIN_WINDOWS: the nearest ones
        slope = _line(*(x[np.argsort(np.abs(t - at), kind="stable")[:MIN_WINDOWS]]
                        for x in (t, p)))[0]  # fmt: skip
    return slope


def _line(t: np.ndarray, p: np.ndarray) -> tuple[float, float]:
    """The least-squares line's slope (Pa/s) and the mean square of p about it (Pa^2)."""
    dt, dp = t - t.mean(), p - p.mean()
    b = float(dt @ dp / (dt @ dt))
    return b, float(np.mean((dp - b * dt) ** 2))


def slopes_moved(old: np.ndarray, new: np.ndarray, p_m: np.ndarray, reach_s: float) -> bool:
    """Whether the slopes moved the lead-ins' mouth pressure by over :data:`SLOPE_SETTLED`.

    The move at each lead-in's start as a fraction of the window's p_m, root-mean-square
    over the windows (``reach_s`` as :func:`mouth_slopes`').
    """
    move = (np.asarray(new, float) - np.asarray(old, float)) * reach_s / np.asarray(p_m, float)
    return bool(np.sqrt(np.mean(move**2)) > SLOPE_SETTLED)


__all__ = ["MAX_RAMP", "MIN_WINDOWS", "SLOPE_SETTLED", "SPAN_S", "mouth_slopes", "slopes_moved"]
