"""Rosenbrock's rotating-coordinate search, the paper's step-2 search (the reference).

It works on log-scaled parameters ``z_i = ln(theta_i / theta0_i)`` inside bounds, as step
2 does (physics.md I). A trial point that is out of bounds or whose value
is not finite, or not below ``infeasible_at``, counts as a failure.

References
----------
H. H. Rosenbrock, "An automatic method for finding the greatest or least value of a
function", Computer Journal 3(3):175-184, 1960.

J. R. Palmer, "An improved procedure for orthogonalising the search vectors in
Rosenbrock's and Swann's direct search optimisation methods", Computer Journal 12(1):69-71,
1969.

Chatziioannou & van Walstijn 2012, section 3.2.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

log = logging.getLogger(__name__)

# Rosenbrock's expansion and contraction factors (physics.md I, step 2).
EXPAND = 3.0
CONTRACT = -0.5


@dataclass(frozen=True)
class SearchResult:
    """Outcome of a bounded search.

    Attributes
    ----------
    x : ndarray
        Best point, in the caller's (unscaled) coordinates.
    f : float
        Objective at ``x``.
    n_iterations : int
        Trial points tried (Rosenbrock), or the scipy method's iteration count.
    n_evaluations : int
        Calls of the objective (out-of-bounds trials are not evaluated).
    n_stages : int
        Completed Rosenbrock stages (rotations of the directions); 0 for scipy methods.
    converged : bool
        True when a tolerance was met before the evaluation budget ran out.
    message : str
        Why the search stopped.
    history : ndarray
        Best objective value after each evaluation (paper Fig. 7).
    method : str
        ``"rosenbrock"`` or ``"trust-region"``.
    jacobian : ndarray or None
        d residual / d ln x at ``x``, shape ``(n_residuals, n_parameters)``, where the
        method computes it (``"trust-region"``); None otherwise.
    residuals : ndarray or None
        Residual vector at ``x`` where the method works on one; None otherwise.
    """

    x: np.ndarray
    f: float
    n_iterations: int
    n_evaluations: int
    n_stages: int
    converged: bool
    message: str
    history: np.ndarray
    method: str
    jacobian: np.ndarray | None = None
    residuals: np.ndarray | None = None


def palmer_directions(directions: np.ndarray, advances: np.ndarray) -> np.ndarray:
    """New orthonormal search directions after a stage (Palmer's procedure).

    Parameters
    ----------
    directions : ndarray, shape (n, n)
        Current orthonormal directions, one per row.
    advances : ndarray, shape (n,)
        Total advance made along each direction during the stage.

    Returns
    -------
    ndarray, shape (n, n)
        Orthonormal directions, the first along the total progress of the stage. Where
        Palmer's formula is undefined (an advance of zero in the middle of the list), the
        set is completed by Gram-Schmidt on the old directions, so zero advances are
        tolerated.

    References
    ----------
    Palmer 1969; Rosenbrock 1960 (the vectors A_i = sum_{j>=i} advance_j d_j).
    """
    d = np.asarray(directions, dtype=float)
    a = np.asarray(advances, dtype=float)
    n = a.size
    # A_i = sum_{j >= i} a_j d_j and |A_i|^2 = sum_{j >= i} a_j^2 (the d_j are orthonormal).
    big_a = np.cumsum((a[:, None] * d)[::-1], axis=0)[::-1]
    norm2 = np.cumsum((a**2)[::-1])[::-1]
    candidates = []
    scale2 = norm2[0] if norm2[0] > 0 else 1.0
    if norm2[0] > 0:
        candidates.append(big_a[0] / math.sqrt(norm2[0]))
    for i in range(1, n):
        gap = norm2[i - 1] - norm2[i]
        if norm2[i] <= 1e-24 * scale2 or gap <= 1e-24 * scale2:
            continue
        num = norm2[i - 1] * big_a[i] - norm2[i] * big_a[i - 1]
        den = math.sqrt(norm2[i - 1]) * math.sqrt(norm2[i]) * math.sqrt(gap)
        candidates.append(num / den)
    # Complete (and, against round-off, re-orthogonalise) with the old directions.
    basis: list[np.ndarray] = []
    for v in [*candidates, *d]:
        w = v.copy()
        for b in basis:
            w -= (w @ b) * b
        nw = float(np.linalg.norm(w))
        if nw > 1e-8:
            basis.append(w / nw)
        if len(basis) == n:
            break
    return np.array(basis)


def rosenbrock(
    fun: Callable[[np.ndarray], float],
    x0: np.ndarray,
    *,
    lower: np.ndarray | None = None,
    upper: np.ndarray | None = None,
    log_scale: bool = True,
    initial_step: float | np.ndarray = 0.05,
    step_tolerance: float = 1e-4,
    f_tolerance: float = 1e-4,
    max_evaluations: int = 1500,
    infeasible_at: float = math.inf,
) -> SearchResult:
    """Minimise ``fun`` inside bounds by Rosenbrock's rotating-coordinate method.

    Parameters
    ----------
    fun : callable
        ``fun(x) -> float``; x in the caller's coordinates (SI units for step 2). NaN,
        infinite and values ``>= infeasible_at`` mark an infeasible point.
    x0 : ndarray
        Start point; must lie inside the bounds (and be positive when ``log_scale``).
    lower, upper : ndarray, optional
        Bounds in the caller's coordinates (positive when ``log_scale``).
    log_scale : bool
        Search over ``z = ln(x / x0)`` (True, for parameters spanning orders of magnitude)
        or over ``z = x - x0``.
    initial_step : float or ndarray
        Initial step per coordinate in z (0.05 = 5 % with log scaling).
    step_tolerance : float
        Stop when every |step| is below this (z units).
    f_tolerance : float
        Stop when the relative fall of the objective over a stage is below this.
    max_evaluations : int
        Evaluation budget.
    infeasible_at : float
        Values at or above this count as infeasible (failures).

    Returns
    -------
    SearchResult

    Raises
    ------
    ValueError
        If ``x0`` is outside the bounds, or not positive with ``log_scale``.

    Notes
    -----
    A success (f(trial) <= f) moves the point and multiplies the step by 3; a failure
    multiplies it by -0.5. A stage ends once every direction has had a success followed by a
    failure (Rosenbrock's rule); the directions are then rotated by Palmer's procedure.
    When every step has fallen below ``step_tolerance`` the search restarts once along the
    coordinate axes with the initial steps (rotated directions can jam against a bound);
    it stops when a restart gains nothing, or when the objective (a norm) reaches zero.

    References
    ----------
    Rosenbrock 1960, Computer Journal 3(3):175-184; Palmer 1969; physics.md I.
    """
    to_x, z_lo, z_hi, x0 = scaling(x0, lower, upper, log_scale)
    n = x0.size
    steps0 = np.broadcast_to(np.asarray(initial_step, dtype=float), (n,)).copy()
    if np.any(steps0 <= 0):
        raise ValueError("initial_step must be positive")
    evaluate = _Evaluations(fun, to_x, infeasible_at)
    z = np.zeros(n)
    f = evaluate(z)
    if not math.isfinite(f):
        # Every comparison with an infeasible start would count as a success (inf <= inf)
        # and the steps would grow without bound: report the start as infeasible instead.
        return SearchResult(
            x=to_x(z), f=f, n_iterations=0, n_evaluations=evaluate.n, n_stages=0,
            converged=False, message="infeasible start point",
            history=np.asarray(evaluate.history), method="rosenbrock",
        )  # fmt: skip
    state = _State(z=z, f=f, directions=np.eye(n), steps=steps0.copy())
    limits = _Limits(z_lo, z_hi, steps0, step_tolerance, max_evaluations)
    n_stages = 0
    converged = False
    message = "evaluation budget spent"
    while evaluate.n < max_evaluations:
        advances, f_stage, outcome = _stage(state, evaluate, limits)
        if outcome == _BUDGET_SPENT:
            break
        if outcome is not None:
            converged, message = True, outcome
            break
        n_stages += 1
        f = state.f
        drop = (f_stage - f) / f_stage if math.isfinite(f_stage) and f_stage > 0 else math.inf
        if drop < f_tolerance:
            converged, message = True, "relative fall of the objective over a stage below tolerance"
            break
        state.directions = palmer_directions(state.directions, advances)
        state.steps = np.abs(state.steps)
    log.debug("rosenbrock: %s after %d evaluations, f=%.6g", message, evaluate.n, state.f)
    return SearchResult(
        x=to_x(state.z),
        f=state.f,
        n_iterations=state.n_trials,
        n_evaluations=evaluate.n,
        n_stages=n_stages,
        converged=converged,
        message=message,
        history=np.array(evaluate.history),
        method="rosenbrock",
    )


class _Evaluations:
    """``fun`` at a point z, counted, with the best value after each call (the history).

    NaN, infinite, failing (a floating-point error) and infeasible (``>= infeasible_at``)
    values all become +inf.
    """

    def __init__(self, fun: Callable[[np.ndarray], float], to_x, infeasible_at: float):
        self.fun, self.to_x, self.infeasible_at = fun, to_x, infeasible_at
        self.n = 0
        self.best = math.inf
        self.history: list[float] = []

    def __call__(self, z: np.ndarray) -> float:
        self.n += 1
        try:
            value = float(self.fun(self.to_x(z)))
        except (FloatingPointError, ValueError, ZeroDivisionError, OverflowError):
            value = math.nan
        if not (math.isfinite(value) and value < self.infeasible_at):
            value = math.inf
        self.best = min(self.best, value)
        self.history.append(self.best)
        return value


@dataclass
class _State:
    """Where the search stands: point z, its value, the directions and their steps."""

    z: np.ndarray
    f: float
    directions: np.ndarray
    steps: np.ndarray
    n_trials: int = 0
    restart_f: float = math.nan  # f at the last restart along the axes (NaN: none yet)


@dataclass(frozen=True)
class _Limits:
    """Bounds in z, initial steps and the stopping rules of a search."""

    z_lo: np.ndarray
    z_hi: np.ndarray
    steps0: np.ndarray
    step_tolerance: float
    max_evaluations: int


#: Outcome of a stage cut short by the evaluation budget.
_BUDGET_SPENT = "budget"


def _stage(
    state: _State, evaluate: _Evaluations, limits: _Limits
) -> tuple[np.ndarray, float, str | None]:
    """One stage: sweep the directions until each has had a success then a failure.

    Returns the advance along each direction, f at the start of the stage (or of its
    restart), and None when the stage ended normally, :data:`_BUDGET_SPENT`, or the
    message of convergence.
    """
    n = state.z.size
    advances = np.zeros(n)
    succeeded = np.zeros(n, dtype=bool)
    done = np.zeros(n, dtype=bool)
    f_stage = state.f
    while not done.all():
        if _sweep(state, evaluate, limits, advances, succeeded, done):
            return advances, f_stage, _BUDGET_SPENT
        if state.f <= 0.0:  # a norm cannot fall further
            return advances, f_stage, "objective reached its target"
        if np.all(np.abs(state.steps) < limits.step_tolerance):
            # Rotated directions can all point into an active bound and shrink to
            # nothing away from the constrained minimum. Restart once along the
            # coordinate axes; converge only if that restart gains nothing.
            if state.f < state.restart_f or math.isnan(state.restart_f):
                state.restart_f = state.f
                state.directions = np.eye(n)
                state.steps = limits.steps0.copy()
                advances[:] = 0.0
                succeeded[:] = False
                done[:] = False
                f_stage = state.f
                continue
            return advances, f_stage, "all steps below the step tolerance"
    return advances, f_stage, None


def _sweep(state, evaluate, limits, advances, succeeded, done) -> bool:
    """One trial step along every direction (arrays updated in place); True: budget spent.

    A success (f(trial) <= f) moves the point and expands the step; a failure contracts
    and reverses it, and ends the direction's part of the stage once it has succeeded.
    """
    for i in range(state.z.size):
        if evaluate.n >= limits.max_evaluations:
            return True
        trial = state.z + state.steps[i] * state.directions[i]
        state.n_trials += 1
        inside = bool(np.all(trial >= limits.z_lo) and np.all(trial <= limits.z_hi))
        f_trial = evaluate(trial) if inside else math.inf
        if math.isfinite(f_trial) and f_trial <= state.f:
            state.z, state.f = trial, f_trial
            advances[i] += state.steps[i]
            succeeded[i] = True
            state.steps[i] *= EXPAND
        else:
            if succeeded[i]:
                done[i] = True
            state.steps[i] *= CONTRACT
    return False


def scaling(x0, lower, upper, log_scale):
    """Map from search coordinates z to x, the bounds in z, and x0 as a float array.

    ``z = ln(x / x0)`` with ``log_scale`` (x0 positive, bounds non-negative), else
    ``z = x - x0``; raises ValueError when x0 lies outside the bounds.
    """
    x0 = np.asarray(x0, dtype=float).copy()
    n = x0.size
    lower = np.full(n, -np.inf) if lower is None else np.asarray(lower, dtype=float)
    upper = np.full(n, np.inf) if upper is None else np.asarray(upper, dtype=float)
    if np.any(x0 < lower) or np.any(x0 > upper):
        raise ValueError(f"start point {x0} lies outside the bounds [{lower}, {upper}]")
    if log_scale:
        if np.any(x0 <= 0) or np.any(lower < 0):
            raise ValueError("log scaling needs a positive start point and non-negative bounds")
        with np.errstate(divide="ignore"):
            z_lo = np.log(lower / x0)
        z_hi = np.log(upper / x0)

        def to_x(z: np.ndarray) -> np.ndarray:
            return x0 * np.exp(z)

    else:
        z_lo, z_hi = lower - x0, upper - x0

        def to_x(z: np.ndarray) -> np.ndarray:
            return x0 + z

    return to_x, z_lo, z_hi, x0
