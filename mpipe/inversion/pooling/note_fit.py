"""One note's joint fit: shared slow parameters, per-window fast ones, one Levenberg-Marquardt.

**Which parameters are slow.** The reed's stiffness k, effective area S, width lam, mass m,
damping g and contact stiffness k_c (and the contact point y_c when it is searched) are
properties of the reed and of how it sits on the lay: they change over a note only as the
reed warms and wets, over seconds. The mouth pressure p_m and the rest opening y_m are the
player's controls (blowing, lip force): a crescendo, a vibrato or an embouchure change moves
them within 20 ms. So p_m and y_m are fitted per window and the others per note.

**The fit.** Each window keeps its own objective
(:class:`mpipe.inversion.fit.objective.F2Objective`,
started from its measured history) and its Jacobian from the model's forward sensitivities
(:mod:`mpipe.inversion.fit.sensitivities`); the note's sum of squares is minimised by a damped
Gauss-Newton (Levenberg-Marquardt) step on the block-arrow system of
:mod:`mpipe.inversion.pooling.arrow`, in log parameters, every window's fast block eliminated
by the Schur complement. A step costs one sensitivity run per window. Started from the
per-window answers (the note's median for the slow parameters), it is a refinement of a few
steps.

**Its covariance.** Each window's noise gram is measured at the note's harmonics as in the
per-window fit (:func:`mpipe.inversion.trust.uncertainty.residual_grams`), and the joint sandwich
(:meth:`mpipe.inversion.pooling.arrow.ArrowSystem.covariance`) gives the slow parameters' SE
per note and the fast ones' per window from one covariance.

References
----------
K. Levenberg 1944; D. W. Marquardt 1963. Chatziioannou & van Walstijn 2012, eq. (15).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from mpipe.core.statistics import integrated_autocorrelation
from mpipe.inversion.fit.objective import F2Objective
from mpipe.inversion.pooling.arrow import ArrowCovariance, ArrowSystem
from mpipe.inversion.trust.uncertainty import residual_grams

#: The player's controls, fitted per window.
FAST_PARAMETERS = ("p_m", "y_m")
#: The reed's own properties, shared by a note's windows.
SLOW_PARAMETERS = ("k", "S", "lam", "m", "g", "k_c", "y_c")


@dataclass(frozen=True)
class NoteFit:
    """The joint fit of one note.

    Attributes
    ----------
    names : tuple of str
        Every window's free parameters, in the order of ``x``'s columns: fast then slow.
    n_fast : int
        How many of ``names`` are per window.
    x : ndarray
        Each window's parameters, shape (W, len(names)), SI units (slow columns equal).
    residuals : list of ndarray
        Each window's residual at ``x``, Pa.
    jacobians : list of ndarray
        Each window's ``d residual / d ln x`` at ``x`` (columns ``names``), Pa.
    cost : float
        Sum of squares over the note, Pa^2.
    start_cost : float
        Its value at the start, Pa^2.
    n_iterations : int
        Steps tried.
    converged : bool
        A tolerance, not the iteration limit, ended the fit.
    message : str
        Why it stopped.
    """

    names: tuple[str, ...]
    n_fast: int
    x: np.ndarray
    residuals: list
    jacobians: list
    cost: float
    start_cost: float
    n_iterations: int
    converged: bool
    message: str

    def system(self) -> ArrowSystem:
        """The block-arrow normal equations at the solution."""
        return ArrowSystem.of(self.jacobians, self.residuals, self.n_fast)


def split_names(free: Sequence[str]) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The searched parameters ``free`` split into (fast, slow), each in ``free``'s order."""
    fast = tuple(n for n in free if n in FAST_PARAMETERS)
    slow = tuple(n for n in free if n not in FAST_PARAMETERS)
    return fast, slow


def _evaluate(objectives, names, order, z):
    """Residuals and log Jacobians (columns ``names``) of every window at ``z`` (W, p), or None."""
    res, jacs = [], []
    for obj, zi in zip(objectives, z, strict=True):
        x = np.exp(zi)
        out = obj.jacobian(x[order])  # the objective's own column order
        if out is None:
            return None
        r, jx = out
        jz = (np.asarray(jx, float) * x[order])[:, np.argsort(order)]
        if not (np.all(np.isfinite(jz)) and np.all(np.isfinite(r))):
            return None
        res.append(np.asarray(r, float))
        jacs.append(jz)
    return res, jacs


# More than ten parameters would not help here: the tolerances are keyword-only.
def fit_note(
    objectives: Sequence[F2Objective],
    start: np.ndarray,
    bounds: np.ndarray,
    n_fast: int,
    *,
    max_iterations: int = 200,
    x_tolerance: float = 1e-6,
    se_tolerance: float = 0.01,
    f_tolerance: float | None = None,
) -> NoteFit:
    """Minimise the note's sum of squares over shared slow and per-window fast parameters.

    Parameters
    ----------
    objectives : sequence of F2Objective
        One per window, all with the same ``free`` parameters.
    start : ndarray
        Start, shape (W, p), SI units, columns: the fast parameters then the slow ones (the
        slow columns are taken from the first row: they are shared).
    bounds : ndarray
        Shape (W, p, 2): each window's search bounds, same columns (the slow ones are
        intersected over the windows).
    n_fast : int
        How many leading columns are per window.
    max_iterations : int
        Steps tried at most (a safeguard: the fit stops by ``se_tolerance``).
    x_tolerance : float
        Stop when the step in log parameters is below ``x_tolerance (1 + ||z||)``.
    se_tolerance : float
        Stop when an accepted step is below this many standard errors in every parameter:
        its length in the fit's own metric, ``sqrt(dz' J'J dz) / sigma`` with
        ``sigma^2 = cost / (N - P)``, bounds ``|dz_j| / se_j`` for every parameter j
        (Cauchy-Schwarz), so the rule is measured in SEs, not in a relative fall of the
        cost (which stopped a crescendo's stretch at 30 steps far from its minimum).
    f_tolerance : float, optional
        Or when an accepted step lowers the sum of squares by less than this fraction
        (None: not used).

    Returns
    -------
    NoteFit

    Raises
    ------
    ValueError
        When a window is infeasible at the start (its model is silent or unstable).
    """
    free = objectives[0].free
    fast, slow = split_names(free)
    names = (*fast, *slow)
    order = np.array([names.index(n) for n in free])  # names-order -> objective order
    lo = np.log(bounds[..., 0])
    hi = np.log(bounds[..., 1])
    lo[:, n_fast:] = lo[:, n_fast:].max(axis=0)
    hi[:, n_fast:] = hi[:, n_fast:].min(axis=0)
    z = np.log(np.asarray(start, float))
    z[:, n_fast:] = z[0, n_fast:]
    z = np.clip(z, lo, hi)
    state = _evaluate(objectives, names, order, z)
    if state is None:
        raise ValueError("a window of the note is infeasible at the pooled start")
    res, jacs = state
    cost = start_cost = float(sum(r @ r for r in res))
    mu, nu = 1e-3, 2.0
    message, converged, steps = "iteration limit", False, 0
    for it in range(1, max_iterations + 1):
        steps = it
        system = ArrowSystem.of(jacs, res, n_fast)
        d_fast, d_slow = system.step(mu)
        z_new = z.copy()
        z_new[:, :n_fast] += d_fast
        z_new[:, n_fast:] += d_slow
        z_new = np.clip(z_new, lo, hi)
        dz = z_new - z
        step = math.sqrt(float(np.sum(dz[:, :n_fast] ** 2) + np.sum(dz[0, n_fast:] ** 2)))
        size = math.sqrt(float(np.sum(z[:, :n_fast] ** 2) + np.sum(z[0, n_fast:] ** 2)))
        if step <= x_tolerance * (1.0 + size):
            message, converged = "step below tolerance", True
            break
        predicted = system.predicted_fall(dz[:, :n_fast], dz[0, n_fast:])
        trial = _evaluate(objectives, names, order, z_new)
        new_cost = float(sum(r @ r for r in trial[0])) if trial is not None else math.inf
        gain = (cost - new_cost) / predicted if predicted > 0 else -1.0
        if gain > 0:
            fall = cost - new_cost
            in_se = _step_in_se(jacs, dz, n_fast, new_cost)
            z, (res, jacs), cost = z_new, trial, new_cost
            mu *= max(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3)
            nu = 2.0
            if in_se <= se_tolerance:
                message, converged = f"step below {se_tolerance:g} SE in every parameter", True
                break
            if f_tolerance is not None and fall <= f_tolerance * cost:
                message, converged = "fall of the sum of squares below tolerance", True
                break
        else:
            mu *= nu
            nu *= 2.0
            if mu > 1e12:
                message, converged = "no step lowers the sum of squares", True
                break
    return NoteFit(names, n_fast, np.exp(z), res, jacs, cost, start_cost, steps, converged, message)


def _step_in_se(jacs, dz: np.ndarray, n_fast: int, cost: float) -> float:
    """A step's length in standard errors: ``sqrt(sum_w |J_w dz_w|^2 / sigma^2)``.

    ``sigma^2 = cost / (N - P)`` (N residual samples, P parameters); an upper bound on the
    step of every parameter in units of its SE (the Gauss-Newton covariance).
    """
    n = sum(j.shape[0] for j in jacs)
    p = n_fast * len(jacs) + dz.shape[1] - n_fast
    sigma2 = cost / max(n - p, 1)
    if not sigma2 > 0:
        return math.inf
    moved = sum(
        float(np.sum((j @ np.concatenate([d[:n_fast], dz[0, n_fast:]])) ** 2))
        for j, d in zip(jacs, dz, strict=True)
    )
    return math.sqrt(moved / sigma2)


def note_covariance(
    fit: NoteFit, pressures: Sequence[np.ndarray], fs: float, floor: float = 0.0
) -> tuple[ArrowCovariance, list[dict]]:
    """The joint covariance of a note's fit, and each window's noise figures.

    Parameters
    ----------
    fit : NoteFit
        The note's fit.
    pressures : sequence of ndarray
        Each window's measured pressure, Pa (its harmonics carry the noise measurement).
    fs : float
        Sample rate, Hz.
    floor : float
        Model-form floor (``inversion.model_form_floor``).

    Returns
    -------
    (ArrowCovariance, list of dict)
        The covariance of the log parameters (columns ``fit.names``) and per window its
        ``n_eff``, ``dof``, ``noise_residual``, ``model_residual`` and ``sigma`` (Pa).
    """
    grams, figures = [], []
    p = len(fit.names)
    for j, r, pw in zip(fit.jacobians, fit.residuals, pressures, strict=True):
        n = r.size
        n_eff = n / integrated_autocorrelation(r)
        gram, _, n_eff, dof, extra = residual_grams(j, r, pw, fs, floor, n_eff, n_eff - p)
        grams.append(gram)
        sigma = float(np.linalg.norm(r)) / math.sqrt(max(dof, 1.0))
        figures.append(dict(n_eff=n_eff, dof=dof, sigma=sigma, **extra))
    return fit.system().covariance(np.asarray(grams)), figures


__all__ = [
    "FAST_PARAMETERS",
    "NoteFit",
    "SLOW_PARAMETERS",
    "fit_note",
    "note_covariance",
    "split_names",
]
