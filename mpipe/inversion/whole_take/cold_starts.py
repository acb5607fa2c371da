"""The take's cold starts: which windows, each one's own global search, one basin or more.

The take's fit (:mod:`mpipe.inversion.whole_take.take_fit`) starts from the global search
of the per-window fit (:func:`mpipe.inversion.fit.window.invert_window`, cold) on its first
and its loudest steady window (:func:`cold_windows`); two starts whose note constants
agree within :data:`~mpipe.inversion.fit.coldstart.AGREEMENT` are one (:func:`same_basin`).
The contact law's choice (:mod:`mpipe.inversion.whole_take.contact_law`) fits the loudest
window the same way, and the take reuses that fit.
"""

from __future__ import annotations

import logging

import numpy as np

from mpipe.inversion.fit.coldstart import AGREEMENT, map_tasks
from mpipe.inversion.fit.window import invert_window
from mpipe.inversion.preparation.kernel import KernelSource
from mpipe.inversion.whole_take.estimator import TakeData, layout_of
from mpipe.reed.parameters import ReedParameters

log = logging.getLogger(__name__)


def agree(a: np.ndarray, b: np.ndarray) -> bool:
    """Every note constant of ``a`` within :data:`AGREEMENT` (ln x) of ``b``'s, (N, s) each."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return a.shape == b.shape and bool(np.all(np.abs(np.log(a / b)) < AGREEMENT))


def cold_windows(problems, steady) -> list[int]:
    """The windows the take's cold starts are made on: its first, loudest and middle steady.

    One window's own minimum need not be the take's: on a 45 dB crescendo (seed 3 of
    ``benchmarks/bench_estimator.py``) the first steady window's global search ends in a
    second minimum of the model (lambda 13 % low, k_c 30 % low), which 10 of the take's
    107 windows prefer and the take as a whole does not (its sum of squares 12 % above the
    other's); the loudest window, where the reed beats hardest on the lay, ends in the
    take's. On seeds 0 and 2 it is the other way round. On seed 8 both ended outside the
    take's basin (thinned costs 924 and 1211) once the window model carried the mean
    flow's drop, and the steady window in the middle of the take's time found it (198):
    all three are started and the lower sum of squares of the whole take is kept
    (:func:`rival_costs`); a start that meets another's basin ends there.
    """
    ok = np.array(steady, bool) if any(steady) else np.ones(len(problems), bool)
    idx = np.flatnonzero(ok)
    first, middle = int(idx[0]), int(idx[idx.size // 2])
    return list(dict.fromkeys([first, loudest([q.target.p for q in problems], steady), middle]))


def loudest(windows, steady) -> int:
    """The index of the loudest (RMS pressure) steady window; every window when none is.

    ``windows``: each window's pressure (Pa), in time order; ``steady``: a flag per window
    or None. The take's second cold start and the contact law's choice are made on it
    (:mod:`mpipe.inversion.whole_take.contact_law`), so that the one fit serves both.
    """
    flags = [True] * len(windows) if steady is None else list(steady)
    idx = [i for i, ok in enumerate(flags) if ok] or list(range(len(windows)))
    rms = [float(np.sqrt(np.mean(np.square(np.asarray(windows[i], float))))) for i in idx]
    return int(idx[int(np.argmax(rms))])


def same_basin(a: ReedParameters, b: ReedParameters, config) -> bool:
    """Two cold starts' reeds agree within :data:`AGREEMENT` in every note constant."""
    layout = layout_of(config)
    names = layout.names[layout.n_fast :]
    return agree([getattr(a, n) for n in names], [getattr(b, n) for n in names])


def cold_fit(p, u, fs: float, source: KernelSource, start: int, fingering: str, t: float,
             config, zero_mean: bool):  # fmt: skip
    """One window's own fit: the per-window fit's global search of every parameter.

    On fingering ``fingering``'s bore at ``t`` degC, without standard errors. The take's
    cold starts and the contact law's choice (:mod:`mpipe.inversion.whole_take.contact_law`)
    are made by it. Returns the window's ``WindowOutcome``.
    """
    return cold_fits(p, u, fs, source, [(start, fingering, t, config)], zero_mean)[0]


def cold_fits(p, u, fs: float, source: KernelSource, jobs, zero_mean: bool) -> list:
    """Several windows' own fits (:func:`cold_fit`) at once, spread over the stage's workers.

    ``jobs``: ``(start, fingering, t, config)`` per fit. Each fit is one task (its global
    search run in the worker, one by one): the searches' own tasks are too few to keep two
    workers busy, and a search's step 1 and polish run alone. The kernels are built here
    first (once, kept in ``source``). Returns the ``WindowOutcome`` of each job, in order:
    the same as :func:`cold_fit` on each, with any number of workers. Inside a pool of
    :func:`~mpipe.inversion.fit.execution.stage_workers` the workers read the take's p and u
    the pool was made with, which must be ``p`` and ``u``.
    """
    items = []
    for start, fingering, t, config in jobs:
        kernel, air = source.named(t, fingering)
        items.append((fs, int(start), kernel, air.rho, config, zero_mean))
    return map_tasks(_cold_task, items, shared=(p, u))


def _cold_task(shared, item):
    p, u = shared
    fs, start, kernel, rho, config, zero_mean = item
    return invert_window(p, u, fs, start, kernel, rho, config, zero_mean=zero_mean,
                         errors=False)  # fmt: skip


def cold_start(data: TakeData, source, problems, steady, t, window: int, made=None):
    """A cold start on ``window``, else on the next steady windows that give an estimate.

    ``made``: first sample -> a fit already made there at ``t`` (:func:`cold_fits`), as
    ``data.cold``.
    """
    made = {**(made or {}), **data.cold}
    picks = [window] + [i for i, ok in enumerate(steady) if ok and i != window]
    picks += [i for i, ok in enumerate(steady) if not ok and i != window]
    for i in picks[:4]:
        q = problems[i]
        out = made.get(q.start) or cold_fit(
            data.p, data.u, data.fs, source, q.start, q.fingering, t, data.config, data.zero_mean
        )
        if out.reed is not None:
            log.info("take cold start on the window at %.3f s", q.start / data.fs)
            return out.reed, dict(out.row), float(np.max(q.target.p))
    raise ValueError("no window of the take could be cold-started (the model does not play it)")


__all__ = ["agree", "cold_fit", "cold_fits", "cold_start", "cold_windows", "loudest", "same_basin"]
