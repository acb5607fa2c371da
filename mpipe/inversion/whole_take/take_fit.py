"""The take's joint fit from its windows: cold starts, warm chains, passes in T.

The driver of :mod:`mpipe.inversion.whole_take.estimator` (which holds the fit's records,
its pass and its stopping rule): the windows of a plan in time order and their notes, the
take's cold starts (its first, loudest and middle steady window,
:mod:`mpipe.inversion.whole_take.cold_starts`), from each start that lies in a basin of
its own a run on the thinned take (:func:`thinned`), the whole take from the lowest
(:func:`rival_costs`) at its note constants, temperature and controls: each window's
controls warm along its chain, the passes with the kernels rebuilt at the temperature
between them (the shards that hold the windows:
:mod:`mpipe.inversion.whole_take.take_shards`), and its windows' figures at the solution.
The runs minimise one objective from different starts; which one ends lowest is the
estimate (a multi-start search, not two estimates reconciled).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import logging
import time
from dataclasses import dataclass

import numpy as np

from mpipe.inversion.fit.coldstart import map_tasks
from mpipe.inversion.fit.execution import stage_workers
from mpipe.inversion.pooling.take_system import TierSizes
from mpipe.inversion.preparation.kernel import KernelSource, bore_kernel, fingered
from mpipe.inversion.settings import ExecutorConfig
from mpipe.inversion.trust.status import MIN_NOTE, robust_level
from mpipe.inversion.whole_take.cold_starts import (
    agree,
    cold_fits,
    cold_start,
    cold_windows,
    same_basin,
)
from mpipe.inversion.whole_take.estimator import (
    TakeData,
    TakeFit,
    informing,
    layout_of,
    problems_of,
    search_boxes,
)
from mpipe.inversion.whole_take.frontend_joint import frontend_shares
from mpipe.inversion.whole_take.gauss_newton import (
    LOOSE_SE,
    SE_TOLERANCE,
    FitState,
    TakeProblem,
    joint_pass,
)
from mpipe.inversion.whole_take.note_starts import swapped_origin
from mpipe.inversion.whole_take.passes import run_passes, set_slopes, slopes_at
from mpipe.inversion.whole_take.rivals import RIVAL_MARGIN, apart, best_run, rival_costs
from mpipe.inversion.whole_take.shard_workers import Shards, shard_ranges
from mpipe.inversion.whole_take.take_shards import DELTA_T_C, ShardSpec
from mpipe.inversion.whole_take.warm_starts import Origin, chains, renumber, run_start
from mpipe.reed.parameters import ReedParameters

log = logging.getLogger(__name__)


def fit_take(
    data: TakeData, *, prior: tuple[float, float], t_range: tuple[float, float],
    executor: ExecutorConfig | None = None, workers: int = 1,
) -> tuple[TakeFit, ReedParameters, dict]:  # fmt: skip
    """The take's joint fit (see :mod:`mpipe.inversion.whole_take.estimator`).

    Parameters
    ----------
    data : TakeData
        The take's signals, its windows and the settings.
    prior : (float, float)
        The temperature's prior, mean and standard error, degC.
    t_range : (float, float)
        Bounds of the temperature, degC.
    executor : ExecutorConfig, optional
        Where the cold start's searches run (local processes by default).
    workers : int
        Worker processes the windows are spread over (1: all here).

    Returns
    -------
    (TakeFit, ReedParameters, dict)
        The fit, the cold start's reed (the fixed parameters' values) and the cold start
        window's record (its step-1 columns and the cold start's agreement).

    Raises
    ------
    ValueError
        When no window of the take can be cold-started or played.
    """
    p, u, fs, calibration, windows = data.p, data.u, data.fs, data.calibration, data.windows
    config, zero_mean = data.config, data.zero_mean
    source = KernelSource(calibration, fs, windows.fingering_map())
    problems, steady = _problems(p, u, fs, source, windows, config, zero_mean, prior[0])
    # a window of a note's onset or release (or not steady, without phases): fitted given
    problems = informing(problems, _informs(windows))
    colds = []
    with stage_workers((p, u), executor or ExecutorConfig(), workers):
        windows_ = cold_windows(problems, steady)
        todo = [problems[i] for i in windows_ if problems[i].start not in data.cold]
        jobs = [(q.start, q.fingering, prior[0], config) for q in todo]
        made = dict(zip([q.start for q in todo], cold_fits(p, u, fs, source, jobs, zero_mean),
                        strict=True))  # fmt: skip
        for window in windows_:
            cold = cold_start(data, source, problems, steady, prior[0], window, made)
            if not any(same_basin(cold[0], c[0], config) for c in colds):
                colds.append(cold)
    origins = [Origin(reed, peak) for reed, _, peak in colds]
    fit_ = functools.partial(_runs, data=data, prior=prior, t_range=t_range, workers=workers,
                             source=source)  # fmt: skip
    with contextlib.ExitStack() as stack:
        thin = thinned(problems)
        if len(thin) < len(problems):  # the basins found on the thinned take, then the whole
            with contextlib.ExitStack() as searched:
                sub = [problems[i] for i in thin]
                found = fit_(searched, sub, origins, tolerance=LOOSE_SE)
                found, origins, colds = _note_start(fit_, searched, sub, (found, origins, colds),
                                                    tolerance=LOOSE_SE)  # fmt: skip
                costs = rival_costs(found)
                order = [int(k) for k in np.argsort(costs)]
                near = [k for k in order[1:] if not found[k].left
                        and costs[k] - costs[order[0]] < LEAVE_MARGIN]  # fmt: skip
                if len(found) > 1:
                    log.info("take fit: %d cold starts on %d of %d windows, costs %s (%s)",
                             len(found), len(thin), len(problems),
                             ", ".join(f"{c:.6g}" for c in costs),
                             "; ".join(r.message for r in found[1:]))  # fmt: skip
                chosen = [order[0], *near]  # a rival the thinned take cannot tell apart
                origins_full = [found[k].origin_here(origins[k]) for k in chosen]
                colds = [colds[k] for k in chosen]
        else:
            origins_full = origins
        runs = fit_(stack, problems, origins_full)
        if len(thin) == len(problems):
            runs, _, colds = _note_start(fit_, stack, problems, (runs, origins_full, colds))
        costs = rival_costs(runs)
        best = best_run(costs, [r.left for r in runs])
        rivals = [k for k, r in enumerate(runs) if k != best and not r.left
                  and apart(runs[best], r) > RIVAL_MARGIN]  # fmt: skip
        if len(runs) > 1:
            log.info("take fit: %d starts on the whole take, costs %s (%s); kept run %d, the "
                     "lowest that ended at its own minimum", len(runs),
                     ", ".join(f"{c:.6g}" for c in costs),
                     "; ".join(r.message for r in runs[1:]), best + 1)  # fmt: skip
        kept = tuple(costs[[best, *rivals]]) if rivals else ()
        fit = _finish(runs[best], data, kept)
    return fit, colds[best][0], colds[best][1]


#: The take's cold starts are followed on every ``THIN``-th window of each note (at least
#: :data:`THIN_MIN` of a note's windows, all of a shorter note's): the basin each ends in
#: and its cost on that thinned take (a quarter of the data: the crescendos' second
#: minimum lies 280-300 chi-square units above the first on the whole take, 70-75 on a
#: quarter), then the whole take from the lowest, its note constants and temperature
#: already near the minimum (a few steps of the whole take instead of a pass from the
#: cold start's constants).
THIN = 4
THIN_MIN = 4


def thinned(problems) -> list[int]:
    """The windows (take indices) of the thinned take: every ``THIN``-th of each note."""
    notes = np.array([q.note for q in problems])
    out: list[int] = []
    for note in dict.fromkeys(notes.tolist()):
        idx = np.flatnonzero(notes == note)
        if idx.size <= THIN_MIN:
            out += idx.tolist()
            continue
        every = idx[::THIN]
        if every.size < THIN_MIN:  # spread evenly instead
            every = idx[np.round(np.linspace(0, idx.size - 1, THIN_MIN)).astype(int)]
        out += sorted(set(every.tolist()))
    return sorted(out)


def _note_start(fit_, stack, problems, starts, **kw):
    """One more start where notes of the lowest run lie in a worse basin than another's.

    ``starts = (runs, origins, colds)``, one of each per run; returns them with the run from
    :func:`~mpipe.inversion.whole_take.note_starts.swapped_origin` added (its origin, and the
    cold start of the run it moved), or as given when no note of the lowest run moved.
    """
    runs, origins, colds = starts
    k = int(np.argmin(rival_costs(runs)))
    swapped = swapped_origin(runs[k], origins[k])
    if swapped is None:
        return runs, origins, colds
    run = fit_(stack, problems, [swapped[0]], **kw)[0]
    return [*runs, run], [*origins, swapped[0]], [*colds, colds[k]]


def _runs(stack, problems, origins, *, data, prior, t_range, workers, source,
          tolerance: float = SE_TOLERANCE) -> list:  # fmt: skip
    """The fit from each origin over ``problems``; a later one may end early (:func:`_leave`).

    ``source``: the take's kernels, built here once per temperature for every run
    (:func:`pass_kernels`); ``tolerance``: where each run stops, in SEs (the thinned take's
    runs, which only find the basins and a start for the whole take, stop at
    :data:`LOOSE_SE`: on the 4 s tone of the speed benchmark their steps on to
    :data:`SE_TOLERANCE` (3 of 11) changed the whole take's estimates by at most 0.005 of
    their SEs).
    """
    fit = functools.partial(_run_from, stack, data, problems, prior=prior, t_range=t_range,
                            workers=workers, source=source, tolerance=tolerance)  # fmt: skip
    runs = [fit(origins[0])]
    for origin in origins[1:]:
        ends = (functools.partial(_leave, first=runs[0]),
                functools.partial(agree, b=runs[0].state.slow))  # fmt: skip
        runs.append(fit(origin, ends=ends))
    return runs


def pass_kernels(source: KernelSource, t: float, names) -> dict:
    """The kernels of a pass at ``t`` degC: fingerings ``names`` at T and T -+ DELTA_T_C.

    Built here once (those missing, spread over the stage's workers: the same kernels) and
    kept in ``source``, so that the shards of every run and pass build none: the passes of
    the thinned take's runs and the whole take's first one start at temperatures met
    before (the prior's, the thinned run's last), and each shard built all three itself.
    Returns ``(T, fingering) -> (kernel, air)``, keyed as :meth:`KernelSource.named` keys.
    """
    keys = [(round(float(x), 6), name) for x in (t - DELTA_T_C, t, t + DELTA_T_C)
            for name in names]  # fmt: skip
    missing = [k for k in keys if k not in source.built]
    if source.build is None:
        made = map_tasks(_kernel_task, [(source.calibration, source.fs, *k) for k in missing])
        source.built.update(zip(missing, made, strict=True))
    return {k: source.named(*k) for k in keys}


def _kernel_task(_shared, item):
    calibration, fs, t, name = item
    return bore_kernel(fingered(calibration, name), fs, t)


#: A second run whose cost after a pass lies this far above the first run's final cost
#: (chi-square units) is in a worse basin and ends there: a pass to 1 SE leaves a few
#: units at most to fall (the second minimum of the crescendos lies 280-300 above).
LEAVE_MARGIN = 40.0


def _leave(take: TakeProblem, state: FitState, blocks, weight: float, *, first: _Run) -> str:
    """Why a second run may end after a pass ("": it goes on).

    It rejoined the first run's minimum (every note constant within :data:`AGREEMENT`), or
    its cost lies :data:`LEAVE_MARGIN` above the first run's final one (a worse basin).
    """
    del weight  # compared on the first run's weight
    if agree(state.slow, first.state.slow):
        return "left: in the first cold start's basin"
    probe = _Run(take, state, blocks, first.weight, 0, 0, True, "", {}, False)
    theirs, mine = rival_costs([first, probe])
    if mine > theirs + LEAVE_MARGIN:
        return f"left: its cost {mine:.6g} above the first start's {theirs:.6g}"
    return ""


@dataclass
class _Run:
    """The take's fit from one cold start, its shards still open (for :func:`_finish`)."""

    take: TakeProblem
    state: FitState
    blocks: object
    weight: float
    steps: int
    passes: int
    converged: bool
    message: str
    excluded: dict
    left: bool = False  # ended early in the first run's basin or above it (not a rival)
    notes: tuple = ()  # the take's index of each note of ``state.slow``
    exact: bool = True  # ``blocks`` hold the exact Jacobian (not a secant update)

    def origin_here(self, origin: Origin) -> Origin:
        """``origin`` moved to where this run ended (its notes' constants, its T)."""
        slow = {n: self.state.slow[k] for k, n in enumerate(self.notes)}
        fast = {q.start: self.state.fast[i] for i, q in enumerate(self.take.problems)}
        return dataclasses.replace(origin, slow=slow, t=float(self.state.t), fast=fast)


def _run_from(stack: contextlib.ExitStack, data: TakeData, problems, origin: Origin, *, prior,
              t_range, workers, source, ends=None, tolerance=SE_TOLERANCE) -> _Run:  # fmt: skip
    """The take's fit from ``origin``: its warm chains and passes (shards in ``stack``).

    ``source``: the take's kernels (:func:`pass_kernels`); ``ends``: ``(stop, near)`` of a
    second run, which may end early; ``tolerance``: the last pass's, SEs
    (:func:`~mpipe.inversion.whole_take.passes.run_passes`).
    """
    fs, config = data.fs, data.config
    # a note of this run without an informing window: every one of its windows informs
    problems = informing(problems, [q.informs for q in problems])
    layout = layout_of(config)
    sizes = TierSizes(layout.n_fast, len(layout.names) - layout.n_fast, 1)
    fingerings = data.windows.fingering_map()
    t0 = float(prior[0]) if origin.t is None else float(origin.t)
    names = sorted({q.fingering for q in problems})
    noise = None if data.front is None else data.front.noise
    spec = ShardSpec(tuple(problems), data.calibration, fs, fingerings, origin.reed, config,
                     layout, t0, pass_kernels(source, t0, names), noise)  # fmt: skip
    clock = time.perf_counter()
    own = stack.enter_context(contextlib.ExitStack())
    ranges = shard_ranges(chains(problems), workers)
    shards = own.enter_context(Shards(spec, ranges, processes=workers > 1))
    slow0, fast, excluded = run_start(shards, problems, layout, origin)
    log.debug("take fit: warm chains after %.2f s", time.perf_counter() - clock)
    if excluded:  # the windows left out, the shards made again without them
        keep = [i for i, q in enumerate(problems) if q.start not in excluded]
        slow0 = slow0[list(dict.fromkeys(problems[i].note for i in keep))]
        problems, fast = [problems[i] for i in keep], fast[keep]
        problems = informing(problems, [q.informs for q in problems])
        spec = dataclasses.replace(spec, problems=tuple(renumber(problems)))  # same kernels
        ranges = shard_ranges(chains(problems), workers)
        own.close()
        shards = own.enter_context(Shards(spec, ranges, processes=workers > 1))
    notes = tuple(dict.fromkeys(q.note for q in problems))  # the take's, before renumbering
    problems = renumber(problems)
    state = FitState(fast, slow0, t0)
    boxes = search_boxes(problems, layout.n_fast, len(notes), t_range)
    take = TakeProblem(shards, problems, layout, sizes, prior, boxes)
    kernels = functools.partial(pass_kernels, source, names=names)
    fast_names = list(layout.names[: layout.n_fast])
    if "p_m" in fast_names:  # the windows' slopes from the warm chains' p_m
        take.ramp = (fs, config.lead_s + 0.5 * config.window_s, fast_names.index("p_m"))
        set_slopes(take, slopes_at(take, state), t0, kernels(t0))
    state, ended, total, passes, converged, message, left = run_passes(take, state, kernels, ends,
                                                                    tolerance)  # fmt: skip
    far = misfit_windows(take.problems, ended[0].rr, config.residual_factor)
    if far and not left:  # windows the model does not play: fitted given their notes
        may = [q.informs and i not in far for i, q in enumerate(take.problems)]
        take.problems = informing(take.problems, may)
        log.info("take fit: %d windows far above their notes' sum of squares fitted given "
                 "their notes (at %s s)", len(far),
                 ", ".join(f"{take.problems[i].start / fs:.3f}" for i in far[:5]))  # fmt: skip
        state, ended, more, extra, converged, message, left = run_passes(take, state, kernels,
                                                                      ends, tolerance)  # fmt: skip
        total, passes = total + more, passes + extra
    log.debug("take fit: passes after %.2f s", time.perf_counter() - clock)
    return _Run(take, state, ended[0], ended[1], total, passes, converged, message, excluded,
                left, notes, ended[2])  # fmt: skip


def misfit_windows(problems, rr, factor: float) -> list[int]:
    """Informing windows whose F2 lies far above their note's: the model does not play them.

    Over each note's informing windows (at least :data:`~mpipe.inversion.trust.status.MIN_NOTE`)
    the level is the status's (:func:`~mpipe.inversion.trust.status.robust_level`) of their
    F2 (Pa, ``sqrt(rr)``). A window above it carries what the model cannot play
    (a fingering changing within it, a click) and would pull its note's constants: on a
    noise-free slur of the four-hole clarinet the window before the change (F2 48 times its
    note's median) moved the first note's m by +84 %, g +110 %, k_c x15 and left its other
    windows at 1.5 % relative residual against 0.02 % in the other notes. Such a window is
    then fitted given its note, as a release's is (:func:`_informs`). F2 in Pa, not relative:
    a quiet window's noise is no larger than a loud one's.
    """
    f2 = np.sqrt(np.maximum(np.asarray(rr, float), 0.0))
    notes = np.array([q.note for q in problems])
    may = np.array([q.informs for q in problems], dtype=bool)
    out: list[int] = []
    for note in np.unique(notes):
        idx = np.flatnonzero((notes == note) & may)
        if idx.size < MIN_NOTE:
            continue
        out += idx[f2[idx] > robust_level(f2[idx], factor)].tolist()
    return sorted(out)


def _finish(run: _Run, data: TakeData, rivals: tuple) -> TakeFit:
    """The run's windows' figures at its solution (residuals, noise grams, entries)."""
    if not all(q.informs for q in run.take.problems):
        run = _settle(run)
    take, state, layout = run.take, run.state, run.take.layout
    shards, problems = take.shards, take.problems
    records = sum(shards.call("final", [(v, state.t, data.config.model_form_floor) for v in
                  shards.split(state.values(layout, problems))]), [])  # fmt: skip
    entries = shards.call("entries", [()] * len(shards.ranges))
    z0 = np.concatenate([e[0] for e in entries])
    rho = np.concatenate([e[1] for e in entries])
    front = None
    if data.front is not None:  # its share, on the Jacobians the fit ended with
        front = frontend_shares(take, state, run.blocks, run.weight, data.front,
                                data.calibration)  # fmt: skip
    return TakeFit(layout.names, take.sizes, tuple(problems), state.fast, state.slow, state.t,
                   run.blocks, records, run.weight, take.prior, run.steps, run.passes,
                   run.converged, run.message, run.excluded, z0, rho, np.array(take.history),
                   rivals, front)  # fmt: skip


def _settle(run: _Run) -> _Run:
    """The fit's second stage: every window's controls at the shared unknowns found.

    The first stage fitted the notes' constants, T and the informing windows' controls
    and held the other windows' controls (not in its cost); here the shared unknowns are
    held and every window's controls fitted at them, all windows counted, on the same
    kernels and weight.
    """
    take = run.take
    take.settling = True
    state, ended, steps, ok, message = joint_pass(take, run.state, SE_TOLERANCE,
                                                  (run.blocks, run.weight, run.exact))  # fmt: skip
    log.debug("take fit, the windows given the shared unknowns: %d steps (%s)", steps, message)
    note = message if not ok else run.message
    return dataclasses.replace(run, state=state, blocks=ended[0], exact=ended[2],
                               steps=run.steps + steps, converged=run.converged and ok,
                               message=note)  # fmt: skip


def _informs(windows) -> list[bool]:
    """Which windows (in time order) may inform their note: all but its build-up's and release's.

    The conditioning's phase (onset, sustain, release, from the note's segment) marks where
    the player's p_m falls within a window, which the model holds: the release. The note's
    build-up, its windows from its first up to its first steady one (the paper's steadiness
    test: the level changes by more than 2 % a window), reads a history the front end cannot
    give: the mean flow rises there from nothing to the note's within a few windows, and the
    separation's u0 carries no flow below ``separation.u_highpass_hz`` (physics.md E.4), so
    the measured flow over such a window and its history differs from the truth by far more
    than the constant the window model restores (:mod:`mpipe.inversion.fit.lead_in`).
    Measured on the diminuendos of ``benchmarks/bench_estimator.py`` (seed 0, 100 dB): over
    each window and the 70 ms before it, that difference varied by 3-9e-5 m^3/s in the
    build-up (the flow's RMS is 4.8e-5) and by 3e-6 after it; the build-up's five windows
    were then the ones the noise-free fit found it could not play (:func:`misfit_windows`),
    and informing, they moved k -0.092 %, lambda -0.110 % (-0.024 %, -0.029 % with the
    truth's flow). At 60 dB their sum of squares is hidden in the noise, yet they moved k by
    -0.09 % in every seed tried (the part even in the noise: half the sum of the fits with
    the noise and with it negated), three quarters of its standard error. Other transient
    windows (a crescendo's, a vibrato's, the sound building after a tongued attack past the
    first steady window) inform: their p_m is held, the model is exact there, and they are
    what tells a note's constants apart. Without phases every window informs; without the
    steadiness flags, every window but the release's.
    """
    n = len(windows.starts)
    if windows.phases is None:
        return [True] * n
    order = np.argsort(np.asarray(windows.starts), kind="stable")
    steady = windows.steady if windows.steady is not None else (True,) * n
    notes = windows.segments if windows.segments is not None else (0,) * n
    building: dict = {}  # note -> still in its build-up (no steady window yet)
    out = []
    for i in order:
        building[notes[i]] = building.get(notes[i], True) and not steady[i]
        out.append(windows.phases[i] != "release" and not building[notes[i]])
    return out


def _problems(p, u, fs, source, windows, config, zero_mean, t):
    """The windows in time order, notes numbered 0.. by first appearance; their steadiness."""
    order = np.argsort(np.asarray(windows.starts), kind="stable")
    starts = [windows.starts[i] for i in order]
    segments = [windows.segment_ids[i] for i in order]
    names = [(windows.fingerings or ("",) * len(order))[i] for i in order]
    steady = [(windows.steady or (True,) * len(order))[i] for i in order]
    note_of = {g: k for k, g in enumerate(dict.fromkeys(segments))}
    n_taps = max(source.named(t, name)[0].n_taps for name in set(names))
    notes = [note_of[g] for g in segments]
    return problems_of(p, u, fs, starts, notes, names, config, zero_mean, n_taps), steady


__all__ = ["fit_take", "misfit_windows", "thinned"]
