"""The passes of one run of the take's fit: kernels rebuilt at T, slopes set between them.

A run (:func:`mpipe.inversion.whole_take.take_fit._run_from`) is a few passes of the damped
Gauss-Newton (:func:`~mpipe.inversion.whole_take.gauss_newton.joint_pass`). Between two
passes the shards' objectives are remade: on the bore's kernels at the new temperature when
T moved by more than :data:`~mpipe.inversion.whole_take.estimator.T_SETTLED_C`, and with each
window's mouth-pressure slope set again from the new p_m
(:mod:`mpipe.inversion.whole_take.mouth_slopes`) when the slopes moved.
"""

from __future__ import annotations

import logging

from mpipe.inversion.whole_take.estimator import MAX_PASSES, T_SETTLED_C
from mpipe.inversion.whole_take.gauss_newton import (
    LOOSE_SE,
    SE_TOLERANCE,
    FitState,
    TakeProblem,
    joint_pass,
)
from mpipe.inversion.whole_take.mouth_slopes import mouth_slopes, slopes_moved
from mpipe.inversion.whole_take.take_shards import Blocks

log = logging.getLogger(__name__)


def run_passes(take: TakeProblem, state: FitState, kernels, ends=None, final=SE_TOLERANCE):
    """The passes of the joint fit, kernels rebuilt at T between them (``kernels(T)``).

    A pass first runs to :data:`LOOSE_SE` (where T is headed); when T has moved by more
    than :data:`T_SETTLED_C` the kernels are rebuilt there, and when the windows'
    mouth-pressure slopes at the pass's p_m moved
    (:func:`~mpipe.inversion.whole_take.mouth_slopes.slopes_moved`) the objectives are
    remade with them, the pass's terms in T and Jacobians kept when T has not moved
    (:func:`reslope`); either way a new pass starts. Else the same pass goes on to
    ``final`` SEs (:data:`SE_TOLERANCE`; nothing more when ``final`` is :data:`LOOSE_SE`).
    ``ends = (stop, near)``, for a second run:
    ``stop(take, state, blocks, weight)`` is asked after each pass whether the run may end
    there (its reason, or ""), ``near(slow)`` at every accepted step whether it has reached
    the first run's minimum (:func:`~mpipe.inversion.whole_take.cold_starts.agree`).
    Returns ``(state, (blocks, weight, exact), steps, passes, converged, message, left)``,
    ``left``: it ended so.
    """
    stop, near = ends if ends is not None else (None, None)
    total, converged, t_built, start = 0, True, state.t, None
    for passes in range(1, MAX_PASSES + 1):
        last = passes == MAX_PASSES
        tolerance = final if last else max(final, LOOSE_SE)
        state, ended, steps, ok, message = joint_pass(take, state, tolerance, start, near=near)
        total += steps
        log.debug("take fit pass %d: T %.3f degC, %d steps (%s)", passes, state.t, steps, message)
        why = stop(take, state, ended[0], ended[1]) if stop is not None else ""
        if why:
            return state, ended, total, passes, ok, why, True
        slopes = slopes_at(take, state)
        # a run that only finds the basin (``final`` LOOSE_SE: the thinned take's) takes no
        # pass for the slopes alone; they are set again whenever T moves
        moved = final < LOOSE_SE and slopes is not None and slopes_moved(
            take.slopes, slopes, state.fast[:, take.ramp[2]], take.ramp[1])  # fmt: skip
        if (abs(state.t - t_built) < T_SETTLED_C and not moved) or last:
            if not last and final < tolerance:  # on to the tolerance, on the same kernels
                state, ended, steps, ok, message = joint_pass(take, state, final, ended)
                total += steps
            converged = ok
            break
        start = None
        if abs(state.t - t_built) < T_SETTLED_C:  # only the slopes moved: the terms kept
            start = reslope(take, slopes, state, ended[1])
        if start is None:
            if abs(state.t - t_built) >= T_SETTLED_C:
                t_built = state.t
            set_slopes(take, slopes, t_built, kernels(t_built))
    if abs(state.t - t_built) >= T_SETTLED_C or moved:
        # the last pass ended far from its kernels or slopes: its blocks measured anew
        if moved:
            set_slopes(take, slopes, t_built, kernels(t_built))
        ended = (take.blocks(state, "measure"), ended[1], True)
    return state, ended, total, passes, converged, message, False


def slopes_at(take: TakeProblem, state: FitState):
    """Each window's mouth-pressure slope at ``state``, Pa/s (None: p_m is not fitted)."""
    if take.ramp is None:
        return None
    fs, reach, i_pm = take.ramp
    n = take.problems[0].target.p.size
    times = [(q.start + 0.5 * n) / fs for q in take.problems]
    return mouth_slopes(times, [q.note for q in take.problems], state.fast[:, i_pm], reach,
                        [q.informs for q in take.problems])  # fmt: skip


def reslope(take: TakeProblem, slopes, state: FitState, weight: float):
    """The next pass's start when only the slopes moved: ``(blocks, weight, exact)``.

    The shards keep the pass's Taylor terms in T and their Jacobians
    (:meth:`~mpipe.inversion.whole_take.take_shards.Shard.reslope`) and play each window's
    residual again under its new slope; the pass goes on from there on a secant Jacobian
    instead of measuring the terms anew (three model runs and a Jacobian a window). None
    when a window cannot be played so: the objectives are then made anew
    (:func:`set_slopes`).
    """
    parts = take.shards.split(slopes)
    out = take.shards.call("reslope", [(part, state.t) for part in parts])
    take.slopes = slopes
    if any(b is None for b in out):
        return None
    return Blocks.join(out), weight, False


def set_slopes(take: TakeProblem, slopes, t: float, made: dict) -> None:
    """The shards' objectives remade at ``t`` degC, with each window's slope (Pa/s).

    ``slopes`` None: the slopes as they are.
    """
    if slopes is not None:
        take.slopes = slopes
    parts = take.shards.split(slopes) if slopes is not None else [None] * len(take.shards.ranges)
    take.shards.call("rebuild", [(t, made, part) for part in parts])


__all__ = ["reslope", "run_passes", "set_slopes", "slopes_at"]
