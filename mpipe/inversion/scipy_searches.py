"""scipy's Powell and Nelder-Mead on step 2's scaled, bounded problem, and the dispatch.

They search the same log-scaled parameters ``z_i = ln(theta_i / theta0_i)`` inside bounds
as :func:`mpipe.inversion.rosenbrock.rosenbrock` (physics.md I); a trial point out of
bounds, not finite or not below ``infeasible_at`` gets a very poor finite value.
:func:`minimise` picks the search by name.

References
----------
Chatziioannou & van Walstijn 2012, section 3.2.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from scipy import optimize

from mpipe.inversion.rosenbrock import SearchResult, rosenbrock, scaling


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
        ``fun(x) -> float`` as for :func:`mpipe.inversion.rosenbrock.rosenbrock`.
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
    to_x, z_lo, z_hi, x0 = scaling(x0, lower, upper, log_scale)
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
    """Run the search named ``method``: Rosenbrock's or :func:`scipy_search`.

    Rosenbrock's search is :func:`mpipe.inversion.rosenbrock.rosenbrock`.

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


__all__ = ["minimise", "scipy_search"]
