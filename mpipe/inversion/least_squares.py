"""Trust-region least squares on the residual vector of F2, in log parameters.

F2 is the norm of a residual vector (target minus model pressure, one entry per sample of
the window), so a Gauss-Newton-type method that sees every residual, not only their norm,
converges in far fewer model runs than a direct search: on the measured path a cold window
takes a few hundred model runs instead of several thousand, and a warm one a few dozen.
The Jacobian is taken by forward differences in ``z = ln(x / x_ref)``; its value at the
solution is kept, for the parameter uncertainties.

The search works in ``z = ln(x / x_ref)`` with ``x_ref`` the geometric mean of each
parameter's bounds, so the result does not depend on where the search started beyond the
basin it lands in, and relative tolerances mean the same for every parameter.

References
----------
M. A. Branch, T. F. Coleman, Y. Li, "A subspace, interior, and conjugate gradient method
for large-scale bound-constrained minimization problems", SIAM J. Sci. Comput. 21(1):1-23,
1999 (the trust-region reflective method of ``scipy.optimize.least_squares``).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from scipy import optimize

from mpipe.inversion.rosenbrock import SearchResult

#: Step of the forward-difference Jacobian in log parameters (0.01 % of each parameter).
DIFF_STEP = 1e-4


def trust_region(
    residuals: Callable[[np.ndarray], np.ndarray],
    x0: np.ndarray,
    *,
    lower: np.ndarray,
    upper: np.ndarray,
    x_tolerance: float = 1e-6,
    f_tolerance: float | None = 1e-10,
    max_evaluations: int = 400,
    infeasible_norm: float = math.inf,
) -> SearchResult:
    """Minimise ``||residuals(x)||`` inside bounds by the trust-region reflective method.

    Parameters
    ----------
    residuals : callable
        ``residuals(x) -> ndarray`` of fixed length, in the caller's units (Pa for F2). An
        infeasible candidate must return a vector of norm at least ``infeasible_norm``.
    x0 : ndarray
        Start point (clipped into the bounds).
    lower, upper : ndarray
        Bounds in the caller's coordinates, all positive.
    x_tolerance : float
        Stop when the step in log parameters falls below this (relative to 1 + ||z||).
    f_tolerance : float or None
        Stop when the sum of squares falls by less than this fraction in a step (None: off).
    max_evaluations : int
        Budget of model runs, Jacobian columns included.
    infeasible_norm : float
        Residual norms at or above this mark an infeasible candidate.

    Returns
    -------
    SearchResult
        ``f`` is the residual norm at ``x``; ``converged`` is True when a tolerance (not
        the budget) ended the search; ``jacobian`` is d residual / d ln x at ``x``
        (shape ``(n_residuals, n_parameters)``) and ``residuals`` the residual vector (both
        None in the rare case where the best point is not scipy's end point).
    """
    lower = np.asarray(lower, dtype=float)
    upper = np.asarray(upper, dtype=float)
    x_ref = np.sqrt(lower * upper)
    z_lo, z_hi = np.log(lower / x_ref), np.log(upper / x_ref)
    span = z_hi - z_lo
    # scipy's reflective method needs a strictly interior start
    z0 = np.clip(
        np.log(np.asarray(x0, dtype=float) / x_ref), z_lo + 1e-9 * span, z_hi - 1e-9 * span
    )
    n = z0.size
    history: list[float] = []
    best = [math.inf, z0.copy()]

    def fun(z: np.ndarray) -> np.ndarray:
        r = np.asarray(residuals(x_ref * np.exp(np.clip(z, z_lo, z_hi))), dtype=float)
        norm = float(np.linalg.norm(r))
        if not math.isfinite(norm):
            r = np.full(r.size, infeasible_norm / math.sqrt(max(r.size, 1)))
            norm = infeasible_norm
        if norm < best[0] and norm < infeasible_norm:
            best[0], best[1] = norm, z.copy()
        history.append(min(best[0], norm))
        return r

    # scipy counts only the evaluations of the residuals themselves, not the n more that
    # each forward-difference Jacobian costs: translate the model-run budget.
    max_nfev = max(int(max_evaluations // (n + 1)), 2)
    res = optimize.least_squares(
        fun,
        z0,
        bounds=(z_lo, z_hi),
        method="trf",
        jac="2-point",
        diff_step=DIFF_STEP,
        x_scale=1.0,
        xtol=x_tolerance,
        ftol=f_tolerance,
        gtol=1e-12,
        max_nfev=max_nfev,
    )
    z = np.asarray(res.x)
    f = float(np.linalg.norm(res.fun))
    jac, fun = np.asarray(res.jac), np.asarray(res.fun)
    if best[0] < f:
        # The reflective steps keep the accepted point, but a Jacobian column can land lower.
        # scipy's Jacobian belongs to its own end point: none is returned for this one.
        z, f = best[1], best[0]
        jac = fun = None
    converged = bool(res.status > 0) and f < infeasible_norm
    messages = {
        0: "evaluation budget spent",
        1: "gradient below tolerance",
        2: "relative fall of the sum of squares below tolerance",
        3: "step below tolerance",
        4: "sum of squares and step below tolerance",
    }
    return SearchResult(
        x=x_ref * np.exp(z),
        f=f,
        n_iterations=int(res.nfev),
        n_evaluations=len(history),
        n_stages=0,
        converged=converged,
        message=messages.get(int(res.status), str(res.message)),
        history=np.asarray(history),
        method="trust-region",
        jacobian=jac,
        residuals=fun,
    )


__all__ = ["DIFF_STEP", "trust_region"]
