"""Rosenbrock's rotating-coordinate search, and scipy searches for comparison.

All three searches work on log-scaled parameters ``z_i = ln(theta_i / theta0_i)`` inside
bounds, as step 2 does (physics.md I). A trial point that is out of bounds or whose value
is not finite, or not below ``infeasible_at``, counts as a failure (Rosenbrock) or as a very
poor value (scipy).

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
from scipy import optimize

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
        ``"rosenbrock"``, ``"powell"``, ``"nelder-mead"`` or ``"trust-region"``.
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
    f_target: float = 0.0,
    max_evaluations: int = 1500,
    infeasible_at: float = math.inf,
    reset_steps: bool = False,
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
    f_target : float
        Stop when the objective reaches this value or less.
    max_evaluations : int
        Evaluation budget.
    infeasible_at : float
        Values at or above this count as infeasible (failures).
    reset_steps : bool
        After each rotation, reset the steps to ``initial_step`` instead of keeping their
        magnitudes.

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
    it stops when a restart gains nothing.

    References
    ----------
    Rosenbrock 1960, Computer Journal 3(3):175-184; Palmer 1969; physics.md I.
    """
    to_x, z_lo, z_hi, x0 = _scaling(x0, lower, upper, log_scale)
    n = x0.size
    steps0 = np.broadcast_to(np.asarray(initial_step, dtype=float), (n,)).copy()
    if np.any(steps0 <= 0):
        raise ValueError("initial_step must be positive")
    history: list[float] = []
    n_eval = 0
    best = math.inf

    def evaluate(z: np.ndarray) -> float:
        nonlocal n_eval, best
        n_eval += 1
        try:
            value = float(fun(to_x(z)))
        except (FloatingPointError, ValueError, ZeroDivisionError, OverflowError):
            value = math.nan
        if not (math.isfinite(value) and value < infeasible_at):
            value = math.inf
        best = min(best, value)
        history.append(best)
        return value

    z = np.zeros(n)
    f = evaluate(z)
    if not math.isfinite(f):
        # Every comparison with an infeasible start would count as a success (inf <= inf)
        # and the steps would grow without bound: report the start as infeasible instead.
        return SearchResult(
            x=to_x(z), f=f, n_iterations=0, n_evaluations=n_eval, n_stages=0,
            converged=False, message="infeasible start point", history=np.asarray(history),
            method="rosenbrock",
        )  # fmt: skip
    directions = np.eye(n)
    steps = steps0.copy()
    n_trials = 0
    n_stages = 0
    restart_f = math.nan
    converged = False
    message = "evaluation budget spent"
    while n_eval < max_evaluations:
        advances = np.zeros(n)
        succeeded = np.zeros(n, dtype=bool)
        done = np.zeros(n, dtype=bool)
        f_stage = f
        stopped = False
        while not done.all():
            for i in range(n):
                if n_eval >= max_evaluations:
                    stopped = True
                    break
                trial = z + steps[i] * directions[i]
                n_trials += 1
                inside = bool(np.all(trial >= z_lo) and np.all(trial <= z_hi))
                f_trial = evaluate(trial) if inside else math.inf
                if math.isfinite(f_trial) and f_trial <= f:
                    z, f = trial, f_trial
                    advances[i] += steps[i]
                    succeeded[i] = True
                    steps[i] *= EXPAND
                else:
                    if succeeded[i]:
                        done[i] = True
                    steps[i] *= CONTRACT
            if stopped:
                break
            if f <= f_target:
                converged, message = True, "objective reached its target"
                break
            if np.all(np.abs(steps) < step_tolerance):
                # Rotated directions can all point into an active bound and shrink to
                # nothing away from the constrained minimum. Restart once along the
                # coordinate axes; converge only if that restart gains nothing.
                if f < restart_f or math.isnan(restart_f):
                    restart_f = f
                    directions = np.eye(n)
                    steps = steps0.copy()
                    advances[:] = 0.0
                    succeeded[:] = False
                    done[:] = False
                    f_stage = f
                    continue
                converged, message = True, "all steps below the step tolerance"
                break
        if stopped or converged:
            break
        n_stages += 1
        drop = (f_stage - f) / f_stage if math.isfinite(f_stage) and f_stage > 0 else math.inf
        if drop < f_tolerance:
            converged, message = True, "relative fall of the objective over a stage below tolerance"
            break
        directions = palmer_directions(directions, advances)
        steps = steps0.copy() if reset_steps else np.abs(steps)
    log.debug("rosenbrock: %s after %d evaluations, f=%.6g", message, n_eval, f)
    return SearchResult(
        x=to_x(z),
        f=f,
        n_iterations=n_trials,
        n_evaluations=n_eval,
        n_stages=n_stages,
        converged=converged,
        message=message,
        history=np.array(history),
        method="rosenbrock",
    )


def _scaling(x0, lower, upper, log_scale):
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


def scipy_search(
    fun: Callable[[np.ndarray], float],
    x0: np.ndarray,
    *,
    method: str,
    lower: np.ndarray | None = None,
    upper: np.ndarray | None = None,
    log_scale: bool = True,
    initial_step: float = 0.05,
    step_tolerance: float = 1e-4,
    f_tolerance: float = 1e-4,
    max_evaluations: int = 1500,
    infeasible_at: float = math.inf,
) -> SearchResult:
    """Minimise ``fun`` with scipy's Powell or Nelder-Mead on the same scaled, bounded problem.

    Parameters
    ----------
    fun : callable
        ``fun(x) -> float`` as for :func:`rosenbrock`.
    x0 : ndarray
        Start point inside the bounds.
    method : {"powell", "nelder-mead"}
        The scipy method.
    lower, upper : ndarray, optional
        Bounds in the caller's coordinates.
    log_scale : bool
        Search over ``ln(x / x0)``.
    initial_step : float
        Size of the initial simplex (Nelder-Mead) or direction vectors (Powell) in z.
    step_tolerance : float
        ``xatol`` (Nelder-Mead) or ``xtol`` (Powell), z units.
    f_tolerance : float
        ``fatol`` relative to the start value (Nelder-Mead) or ``ftol`` (Powell).
    max_evaluations : int
        Evaluation budget (``maxfev``).
    infeasible_at : float
        Values at or above this, NaN or infinite are replaced by a large finite penalty.

    Returns
    -------
    SearchResult
    """
    key = method.lower()
    if key not in ("powell", "nelder-mead"):
        raise ValueError(f"method must be 'powell' or 'nelder-mead', got {method!r}")
    to_x, z_lo, z_hi, x0 = _scaling(x0, lower, upper, log_scale)
    n = x0.size
    history: list[float] = []
    best = [math.inf, np.zeros(n)]
    penalty = [1e300]

    def wrapped(z: np.ndarray) -> float:
        if np.any(z < z_lo) or np.any(z > z_hi):
            return penalty[0]
        try:
            value = float(fun(to_x(z)))
        except (FloatingPointError, ValueError, ZeroDivisionError, OverflowError):
            value = math.nan
        if not (math.isfinite(value) and value < infeasible_at):
            value = penalty[0]
        elif value < best[0]:
            best[0], best[1] = value, z.copy()
        history.append(best[0])
        return value

    f0 = wrapped(np.zeros(n))
    if math.isfinite(f0) and f0 < 1e300:
        penalty[0] = max(1e3 * abs(f0), 1e3)
    bounds = list(zip(np.maximum(z_lo, -1e3), np.minimum(z_hi, 1e3), strict=True))
    if key == "nelder-mead":
        simplex = np.vstack([np.zeros(n), initial_step * np.eye(n)])
        simplex = np.clip(simplex, [b[0] for b in bounds], [b[1] for b in bounds])
        options = {
            "initial_simplex": simplex,
            "xatol": step_tolerance,
            "fatol": f_tolerance * max(abs(f0), 1e-300),
            "maxfev": max_evaluations - 1,
        }
        res = optimize.minimize(
            wrapped, np.zeros(n), method="Nelder-Mead", bounds=bounds, options=options
        )
    else:
        options = {
            "direc": initial_step * np.eye(n),
            "xtol": step_tolerance,
            "ftol": f_tolerance,
            "maxfev": max_evaluations - 1,
        }
        res = optimize.minimize(
            wrapped, np.zeros(n), method="Powell", bounds=bounds, options=options
        )
    z_best = best[1] if best[0] <= float(res.fun) else np.asarray(res.x)
    return SearchResult(
        x=to_x(z_best),
        f=float(min(best[0], res.fun)),
        n_iterations=int(getattr(res, "nit", 0)),
        n_evaluations=len(history),
        n_stages=0,
        converged=bool(res.success),
        message=str(res.message),
        history=np.array(history),
        method=key,
    )


def minimise(
    fun: Callable[[np.ndarray], float], x0: np.ndarray, *, method: str = "rosenbrock", **kwargs
) -> SearchResult:
    """Dispatch to :func:`rosenbrock` or :func:`scipy_search` by ``method`` name.

    Parameters
    ----------
    fun : callable
        Objective, ``fun(x) -> float``.
    x0 : ndarray
        Start point.
    method : {"rosenbrock", "powell", "nelder-mead"}
        Search method.
    **kwargs
        Keyword arguments of the chosen function (bounds, tolerances, budget).

    Returns
    -------
    SearchResult
    """
    if method == "rosenbrock":
        return rosenbrock(fun, x0, **kwargs)
    kwargs.pop("reset_steps", None)
    kwargs.pop("f_target", None)
    return scipy_search(fun, x0, method=method, **kwargs)
