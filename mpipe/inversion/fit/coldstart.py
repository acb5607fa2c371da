"""Global cold start of step 2: a space-filling design, short local searches, one polish.

Step 2's objective has several local minima over the bounded parameter box: on measured
(zero-mean) flow a start from step 1 alone can settle in one with the reed mass, damping and
contact stiffness on their lower bounds and the rest opening pinned at the contact point.
The cold start therefore does not trust any single start point:

1. **Design.** F2 is evaluated at the points of a scrambled Sobol sequence over the whole
   box of the free parameters in log coordinates (``design_points`` points, a fixed seed, so
   the design is the same on every run), and at the seeds the caller gives (step 1's
   estimate).
2. **Short local searches.** From the seeds and the best distinct design points
   (``local_starts`` in all), a short trust-region least-squares search
   (``local_evaluations`` model runs each).
3. **Polish.** The best end point is polished by the configured step-2 search to its full
   tolerance.

The number of local searches that end within about 5 % (every parameter) of the polished
minimum is kept as a diagnostic:
when only one of them finds the best minimum, the basin is narrow and the result deserves a
second look.

References
----------
I. M. Sobol', "On the distribution of points in a cube and the approximate evaluation of
integrals", USSR Comput. Math. Math. Phys. 7(4):86-112, 1967; A. B. Owen, "Scrambling Sobol'
and Niederreiter-Xing points", J. Complexity 14(4):466-489, 1998.
"""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.stats import qmc

from mpipe.inversion.fit.least_squares import trust_region
from mpipe.inversion.fit.rosenbrock import SearchResult

#: A local search that ends within this log distance (every parameter within about 5 %) of
#: the polished minimum found the same minimum.
AGREEMENT = 0.05


#: How independent tasks of the cold start and the temperature fit are run: None (one by
#: one, here) or ``mapper(fn, items) -> [fn(shared, item) ...]`` in the order of ``items``
#: (a worker pool: :func:`mpipe.inversion.fit.execution.stage_workers`).
_MAPPER: contextvars.ContextVar = contextvars.ContextVar("mpipe_stage_mapper", default=None)


@contextlib.contextmanager
def spread_over(mapper: Callable | None) -> Iterator[None]:
    """Run the independent tasks of cold starts and temperature fits with ``mapper`` here."""
    token = _MAPPER.set(mapper)
    try:
        yield
    finally:
        _MAPPER.reset(token)


def spreading() -> bool:
    """Whether :func:`map_tasks` spreads its tasks over workers here (a pool is open)."""
    return _MAPPER.get() is not None


def run_tasks_here() -> None:
    """From now on in this context, :func:`map_tasks` runs its tasks here, one by one."""
    _MAPPER.set(None)


def map_tasks(fn: Callable, items: Sequence, shared=None) -> list:
    """``[fn(shared, item) for item in items]``, on the workers of :func:`spread_over`.

    Each task depends only on its item (and ``shared``, which the workers hold as given
    when the pool was made), and results come in the order of ``items``: the answer does
    not depend on the number of workers.
    """
    mapper = _MAPPER.get()
    if mapper is None or len(items) < 2:
        return [fn(shared, item) for item in items]
    return mapper(fn, list(items))


def _design_task(_shared, item) -> list[float]:
    objective, points = item
    return [float(objective(x)) for x in points]


def _local_task(_shared, item) -> SearchResult:
    residuals, jacobian, x0, lower, upper, budget, infeasible_at = item
    return trust_region(
        residuals,
        x0,
        lower=lower,
        upper=upper,
        x_tolerance=1e-3,
        max_evaluations=budget,
        infeasible_norm=infeasible_at,
        jacobian=jacobian,
    )


@dataclass(frozen=True)
class ColdStart:
    """Result of :func:`global_search`.

    Attributes
    ----------
    search : SearchResult
        The polish, with ``n_evaluations`` and ``history`` covering the whole cold start.
    local_f : ndarray
        F2 at the end of each short local search, Pa, in the order they were run (seeds
        first).
    agreeing : int
        Local searches that ended within :data:`AGREEMENT` (log distance, every parameter)
        of the polished minimum.
    design_evaluations : int
        Model runs of the design stage.
    """

    search: SearchResult
    local_f: np.ndarray
    agreeing: int
    design_evaluations: int


@dataclass(frozen=True)
class ColdStartOptions:
    """Sizes of the cold start's stages (``inversion`` settings of the same names).

    Attributes
    ----------
    design_points : int
        Size of the Sobol design (rounded up to a power of two).
    local_starts : int
        Short local searches in all, seeds included.
    local_evaluations : int
        Model runs per short local search.
    seed : int
        Scrambling seed of the design (fixed: one answer per input).
    """

    design_points: int = 256
    local_starts: int = 8
    local_evaluations: int = 300
    seed: int = 0

    @classmethod
    def of(cls, config) -> ColdStartOptions:
        """The options of an :class:`~mpipe.inversion.settings.InversionConfig`."""
        return cls(
            config.design_points, config.local_starts, config.local_evaluations,
            config.design_seed,
        )  # fmt: skip


def sobol_design(lower: np.ndarray, upper: np.ndarray, n_points: int, seed: int) -> np.ndarray:
    """Scrambled Sobol points spread evenly over a box in log coordinates.

    Parameters
    ----------
    lower, upper : ndarray
        Bounds of each parameter (positive, SI units).
    n_points : int
        Number of points; rounded up to a power of two (Sobol's balance holds for those).
    seed : int
        Scrambling seed.

    Returns
    -------
    ndarray, shape (n, d)
        Points in the parameters' own units.
    """
    lo, hi = np.log(np.asarray(lower, float)), np.log(np.asarray(upper, float))
    m = max(int(math.ceil(math.log2(max(n_points, 1)))), 0)
    unit = qmc.Sobol(lo.size, scramble=True, seed=seed).random_base2(m)
    return np.exp(lo + unit * (hi - lo))


def global_search(
    objective: Callable[[np.ndarray], float],
    residuals: Callable[[np.ndarray], np.ndarray],
    lower: np.ndarray,
    upper: np.ndarray,
    seeds: Sequence[np.ndarray],
    polish: Callable[[np.ndarray], SearchResult],
    *,
    options: ColdStartOptions = ColdStartOptions(),
    infeasible_at: float = math.inf,
    jacobian: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray] | None] | None = None,
) -> ColdStart:
    """Find the global basin of F2 inside bounds and polish its minimum.

    Parameters
    ----------
    objective : callable
        ``objective(x) -> F2`` in Pa; infeasible candidates give ``infeasible_at`` or more.
    residuals : callable
        ``residuals(x) -> ndarray``, whose norm is F2.
    lower, upper : ndarray
        Bounds of the free parameters, SI units.
    seeds : sequence of ndarray
        Start points that always get a local search (step 1's estimate).
    polish : callable
        ``polish(x0) -> SearchResult``: the full step-2 search from the best point found.
    options : ColdStartOptions
        Design size, number of short local searches, their budget, the design's seed.
    infeasible_at : float
        F2 at or above this marks an infeasible candidate.
    jacobian : callable, optional
        ``jacobian(x) -> (r, J)`` for the short local searches (see
        :func:`mpipe.inversion.fit.least_squares.trust_region`).

    The design's points and the short local searches are independent tasks: they run on
    the workers of :func:`spread_over` when there are some (the same answer either way).

    Returns
    -------
    ColdStart
    """
    lower = np.asarray(lower, float)
    upper = np.asarray(upper, float)
    seeds = [np.clip(np.asarray(s, float), lower, upper) for s in seeds]
    design = sobol_design(lower, upper, options.design_points, options.seed)
    chunks = [c for c in np.array_split(design, 8) if len(c)] if len(design) else []
    parts = map_tasks(_design_task, [(objective, c) for c in chunks])
    values = np.array([v for part in parts for v in part])
    trace = list(np.minimum.accumulate(values)) if values.size else []
    feasible = np.flatnonzero(values < infeasible_at)
    starts = list(seeds)
    for i in feasible[np.argsort(values[feasible], kind="stable")]:
        if len(starts) >= options.local_starts:
            break
        # distinct from the starts already chosen: more than 5 % apart in some parameter
        if all(np.max(np.abs(np.log(design[i] / s))) > 0.05 for s in starts):
            starts.append(design[i])
    local = map_tasks(
        _local_task,
        [
            (residuals, jacobian, x0, lower, upper, options.local_evaluations, infeasible_at)
            for x0 in starts
        ],
    )
    local_f = np.array([r.f for r in local])
    for r in local:
        trace.extend(np.minimum(r.history, trace[-1] if trace else math.inf))
    best = local[int(np.argmin(local_f))] if local else None
    x_best = best.x if best is not None else design[int(np.argmin(values))]
    final = polish(x_best)
    if best is not None and best.f < final.f:
        # The polish never moves away from a better point it started from; guard anyway.
        final = dataclasses.replace(final, x=best.x, f=best.f)
    prior = trace[-1] if trace else math.inf
    trace.extend(np.minimum(final.history, prior))
    agreeing = sum(bool(np.max(np.abs(np.log(r.x / final.x))) < AGREEMENT) for r in local)
    total = int(values.size + sum(r.n_evaluations for r in local) + final.n_evaluations)
    search = dataclasses.replace(final, n_evaluations=total, history=np.asarray(trace))
    return ColdStart(search, local_f, agreeing, int(values.size))


__all__ = [
    "AGREEMENT",
    "ColdStart",
    "ColdStartOptions",
    "global_search",
    "map_tasks",
    "run_tasks_here",
    "sobol_design",
    "spread_over",
    "spreading",
]
