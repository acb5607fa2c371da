"""One window's inversion: step 1, the cold or warm start, the step-2 search, its errors.

A cold window (the first of a take, or a retry) runs step 1 on both branches and the
global cold start of :mod:`mpipe.inversion.fit.coldstart` (step 1's estimate among its starts).
A warm window starts the local search from the take's cold-start result. The estimate
gets its standard errors (:mod:`mpipe.inversion.trust.window_errors`) and a provisional status
(:mod:`mpipe.inversion.trust.status`); a failing window is recorded with its error, never raised.

References
----------
Chatziioannou & van Walstijn 2012, sections 3 and 4.2; physics.md H, I, J.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

import numpy as np

from mpipe.inversion.fit.coldstart import ColdStartOptions, global_search
from mpipe.inversion.fit.history_start import lead_in
from mpipe.inversion.fit.least_squares import trust_region
from mpipe.inversion.fit.objective import F2Objective, ObjectiveSettings, TargetWindow
from mpipe.inversion.fit.rosenbrock import SearchResult, rosenbrock
from mpipe.inversion.fit.step1 import Step1Result, step1
from mpipe.inversion.settings import PARAMETER_NAMES, InversionConfig
from mpipe.inversion.table.records import Correlation, WindowRecord
from mpipe.inversion.table.tables import blank_row
from mpipe.inversion.trust.diagnostics import playing_difference
from mpipe.inversion.trust.status import (
    on_bounds,
    required_quantities,
    search_bounds,
    window_status,
)
from mpipe.inversion.trust.uncertainty import SE_PARAMETERS, covariance, log_jacobian
from mpipe.inversion.trust.window_errors import window_uncertainty
from mpipe.reed.bore_kernel import BoreKernel
from mpipe.reed.parameters import ReedParameters

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class WindowOutcome:
    """Full result of one window.

    Attributes
    ----------
    row : WindowRecord
        The window's record (columns of :data:`mpipe.inversion.table.tables.COLUMNS`).
    step1 : Step1Result or None
        Step-1 fits (None when step 1 was not run or failed).
    search : SearchResult or None
        Step-2 search (None when it failed).
    reed : ReedParameters or None
        Step-2 estimate.
    """

    row: WindowRecord
    step1: Step1Result | None
    search: SearchResult | None
    reed: ReedParameters | None


def start_point(
    s1: Step1Result, config: InversionConfig, branch: str | None = None
) -> ReedParameters:
    """Step-2 start from step 1 (k, S, y_m of the seed branch, p_m) and the configuration.

    Values are clipped into the search bounds, and y_m is kept above y_c (with
    ``contact: closure`` y_c is y_m).

    Parameters
    ----------
    s1 : Step1Result
        Step-1 fits of the window.
    config : InversionConfig
        Fixed values (lam, y_c, alpha), literature values (m, g, k_c) and bounds.
    branch : str, optional
        Seed branch; default ``config.seed_branch``.

    Returns
    -------
    ReedParameters
    """
    fit = s1.branch(branch or config.seed_branch)
    values = dict(
        k=fit.k,
        S=fit.S,
        y_m=fit.y_m,
        p_m=s1.p_m,
        lam=config.lam,
        m=config.m,
        g=config.g,
        k_c=config.k_c,
    )
    for name, v in values.items():
        lo, hi = config.bounds.absolute(name, s1.max_p)
        if not math.isfinite(v):
            v = math.sqrt(lo * hi)
        values[name] = float(np.clip(v, lo, hi))
    if config.law == "closure":
        return ReedParameters(**values, y_c=values["y_m"], alpha=config.alpha)
    values["y_m"] = max(values["y_m"], 1.1 * config.y_c)
    return ReedParameters(**values, y_c=config.y_c, alpha=config.alpha)


def _jacobian(objective: F2Objective):
    """The objective's sensitivity Jacobian when it has one (compiled path), else None."""
    return objective.jacobian if objective.has_jacobian else None


def local_search(
    objective: F2Objective,
    x0: np.ndarray,
    bounds: np.ndarray,
    config: InversionConfig,
    *,
    cold: bool,
) -> SearchResult:
    """The configured step-2 local search from ``x0`` inside ``bounds`` (shape (n, 2)).

    A cold search gets ``max_evaluations`` model runs, a warm one ``warm_max_evaluations``.
    The trust region runs scipy's reflective method when cold and the Broyden-updated
    secant method when warm; ``optimiser: rosenbrock`` is the paper's search (reference).
    """
    budget = config.max_evaluations if cold else config.warm_max_evaluations
    if config.optimiser == "trust-region":
        return trust_region(
            objective.residuals,
            x0,
            lower=bounds[:, 0],
            upper=bounds[:, 1],
            x_tolerance=config.step_tolerance,
            f_tolerance=(config.f_tolerance if cold else config.warm_f_tolerance) or None,
            max_evaluations=budget,
            infeasible_norm=objective.penalty,
            secant=not cold,
            jacobian=_jacobian(objective),
        )
    return rosenbrock(
        objective,
        x0,
        lower=bounds[:, 0],
        upper=bounds[:, 1],
        initial_step=config.initial_step if cold else config.warm_initial_step,
        step_tolerance=config.step_tolerance,
        f_tolerance=config.f_tolerance,
        max_evaluations=budget,
        infeasible_at=objective.penalty,
    )


def invert_window(
    p: np.ndarray,
    u: np.ndarray,
    fs: float,
    start: int,
    kernel: BoreKernel,
    rho: float,
    config: InversionConfig,
    *,
    zero_mean: bool,
    warm: ReedParameters | None = None,
    errors: bool = True,
) -> WindowOutcome:
    """Invert one window of a take.

    A cold window (no ``warm`` start) runs step 1 on both branches and then the global
    cold start of :mod:`mpipe.inversion.fit.coldstart` (step 1's estimate among its starts). A
    warm window runs the local search from ``warm`` only.

    Parameters
    ----------
    p : ndarray
        Mouthpiece pressure of the whole take, Pa.
    u : ndarray
        Mouthpiece flow of the whole take, m^3/s.
    fs : float
        Sample rate, Hz.
    start : int
        First sample of the window.
    kernel : BoreKernel
        Prepared bore at ``fs``.
    rho : float
        Air density, kg/m^3.
    config : InversionConfig
        Inversion settings.
    zero_mean : bool
        The flow is zero-mean (measured).
    warm : ReedParameters, optional
        Start step 2 here (the take's cold-start result) instead of cold.
    errors : bool
        Compute the standard errors (False: the estimate and F2 only, for the re-fits of
        a budget component that use nothing else; the status then lacks them).

    Returns
    -------
    WindowOutcome
        Never raises for a failing window: the error is recorded in ``row["error"]``. The
        row's status is provisional (see :func:`mpipe.inversion.trust.status.classify`, which
        compares windows across the take).
    """
    t0 = time.perf_counter()
    n = int(round(config.window_s * fs))
    cold = warm is None
    row = blank_row(start, n, fs, config, cold=cold)
    s1 = search = reed = None
    try:
        pw, uw = p[start : start + n], u[start : start + n]
        if pw.size < n:
            raise ValueError(f"window at {start / fs:.4f} s runs past the end of the take")
        if cold:
            s1 = _step1(pw, uw, fs, rho, config, zero_mean,
                        f"window at {start / fs:.3f}-{(start + n) / fs:.3f} s")  # fmt: skip
            row.update(_step1_columns(s1))
        base = warm if warm is not None else start_point(s1, config)
        history = lead_in(p, u, start, n, kernel.n_taps, config.lead_s, fs)
        target = TargetWindow(pw, uw, *history, fs, zero_mean)
        objective = window_objective(kernel, target, base, config)
        bounds = window_bounds(config, p, start, n, fs)
        search, agreeing = _search(objective, base, bounds, config, cold=cold)
        if agreeing is not None:
            row["cold_starts_agreeing"] = agreeing
        if not search.f < objective.penalty:
            raise RuntimeError("no feasible parameter set found (model silent or unstable)")
        reed = objective.reed(search.x)
        row.update(_estimate_columns(reed, search, pw, bounds, config))
        if errors:
            found, row.correlation = _errors_or_note(
                objective, search, bounds, reed, kernel, config, row, start / fs
            )
            row.update(found)
        res = search.residuals if search.residuals is not None else objective.residuals(search.x)
        row.update(playing_difference(pw, pw - np.asarray(res, dtype=float), fs))
    except Exception as exc:  # noqa: BLE001 - a failed window is recorded, the take goes on
        log.warning("window at %.4f s failed: %s", start / fs, exc)
        row["error"] = f"{type(exc).__name__}: {exc}"
    row["wall_time_s"] = time.perf_counter() - t0
    status = window_status(row, required_quantities(config))
    row.update(zip(("status", "status_reason"), status, strict=True))
    return WindowOutcome(row=row, step1=s1, search=search, reed=reed)


def window_bounds(
    config: InversionConfig, p: np.ndarray, start: int, n: int, fs: float
) -> np.ndarray:
    """Search bounds of the window at ``start`` (``n`` samples).

    p_m's lower bound scales with the window's own peak pressure, its upper one with the
    peak within ``p_m_context_s`` of the window.
    """
    bounds = search_bounds(config, float(np.max(p[start : start + n])))
    if "p_m" in config.search_parameters and config.p_m_context_s > 0:
        reach = int(round(config.p_m_context_s * fs))
        peak = float(np.max(p[max(start - reach, 0) : start + n + reach]))
        i = config.search_parameters.index("p_m")
        bounds[i, 1] = max(bounds[i, 1], config.bounds.p_m[1] * peak)
    return bounds


def _step1(
    pw: np.ndarray,
    uw: np.ndarray,
    fs: float,
    rho: float,
    config: InversionConfig,
    zero_mean: bool,
    where: str = "",
) -> Step1Result:
    """Step 1 on the window's pressure ``pw`` (Pa) and flow ``uw`` (m^3/s), as configured.

    ``where`` names the window (its span in the take) for the console.
    """
    estimate = config.step1_p_m == "estimate"
    return step1(
        pw,
        uw,
        fs,
        rho=rho,
        lam=config.lam,
        p_m=config.step1_p_m,
        zero_mean=zero_mean,
        # with contact from closure, step 1's shut-reed test already covers it
        y_c=config.y_c if estimate and config.law != "closure" else None,
        where=where,
    )


def _step1_columns(s1: Step1Result) -> dict:
    """The row's step-1 columns: p_m and each branch's k, S, y_m and F1."""
    row = {"step1_p_m": s1.p_m}
    for b in ("closing", "opening"):
        fit = s1.branch(b)
        row.update({f"k_{b}": fit.k, f"S_{b}": fit.S, f"y_m_{b}": fit.y_m, f"f1_{b}": fit.f1})
    return row


def window_objective(
    kernel: BoreKernel, target: TargetWindow, base: ReedParameters, config: InversionConfig,
    lowpass=None,
) -> F2Objective:  # fmt: skip
    """F2 of the window over the configured search parameters, the others held at ``base``.

    ``lowpass``: ``config.lowpass.design(target.fs)`` when the caller already has it (one
    design for the many windows of a take; made here otherwise).
    """
    if target.zero_mean and lowpass is None:
        lowpass = config.lowpass.design(target.fs)
    settings = ObjectiveSettings(lead_s=config.lead_s,
                                 lowpass=lowpass if target.zero_mean else None)  # fmt: skip
    return F2Objective(
        kernel,
        target,
        settings,
        base,
        config.search_parameters,
        contact_at_closure=config.law == "closure",
    )


def _search(
    objective: F2Objective,
    base: ReedParameters,
    bounds: np.ndarray,
    config: InversionConfig,
    *,
    cold: bool,
) -> tuple[SearchResult, int | None]:
    """Step 2 from ``base``: the global cold start, or one local search.

    Returns the search and, for the global cold start, how many of its starts agreed.
    """
    names = config.search_parameters
    x0 = np.clip([getattr(base, name) for name in names], bounds[:, 0], bounds[:, 1])
    if not cold:
        return local_search(objective, x0, bounds, config, cold=cold), None
    found = global_search(
        objective,
        objective.residuals,
        bounds[:, 0],
        bounds[:, 1],
        [x0],
        lambda x: local_search(objective, x, bounds, config, cold=True),
        options=ColdStartOptions.of(config),
        infeasible_at=objective.penalty,
        jacobian=_jacobian(objective),
    )
    return found.search, found.agreeing


def _estimate_columns(
    reed: ReedParameters,
    search: SearchResult,
    pw: np.ndarray,
    bounds: np.ndarray,
    config: InversionConfig,
) -> dict:
    """The row's estimate and search columns (``pw``: the window's pressure, Pa)."""
    names = config.search_parameters
    row = {name: getattr(reed, name) for name in (*PARAMETER_NAMES, "y_c", "alpha")}
    row.update(
        f2=search.f,
        relative_residual=search.f / (float(np.linalg.norm(pw)) + 1e-300),
        n_iterations=search.n_iterations,
        n_evaluations=search.n_evaluations,
        optimiser_converged=search.converged,
        optimiser_message=search.message,
        at_bound=";".join(on_bounds(dict(zip(names, search.x, strict=True)), bounds, config)),
    )
    return row


def _errors_or_note(
    objective, search, bounds, reed, kernel, config, row, t_start
) -> tuple[dict, Correlation | None]:
    """Uncertainty columns and correlation, or a note saying why there are none (``t_start``, s)."""
    try:
        return _uncertainty(objective, search, bounds, reed, kernel, config, row["at_bound"])
    except (ValueError, np.linalg.LinAlgError) as exc:
        # the estimate stands; only its error bars are missing
        log.warning("window at %.4f s: no standard errors: %s", t_start, exc)
        return {"uncertainty_note": f"no standard errors: {exc}", "dof": math.nan}, None


def _uncertainty(
    objective, search, bounds, reed, kernel, config, at_bound: str
) -> tuple[dict, Correlation]:
    """Standard errors, combinations and correlations of one window.

    See :mod:`mpipe.inversion.trust.uncertainty`.
    The trust-region search's own Jacobian at the solution is used; other searches (and
    the rare trust-region end that is not scipy's point) get a forward-difference one.
    Returns the uncertainty columns and the correlation of the free parameters.
    """
    names = objective.free
    if search.jacobian is not None and search.residuals is not None:
        jac, res = search.jacobian, search.residuals
    else:
        res = objective.residuals(search.x)
        jac = log_jacobian(objective.residuals, search.x, r0=res, upper=bounds[:, 1])
    cov = covariance(
        jac, res, names, pressure=objective.target.p, fs=objective.target.fs,
        floor=config.model_form_floor,
    )  # fmt: skip
    invalid = {
        hit.split("=")[0]: f"estimate on its {hit.split('=')[1]} bound: the Gauss-Newton "
        "covariance assumes an interior minimum"
        for hit in at_bound.split(";")
        if hit
    }
    out = window_uncertainty(
        cov,
        {n: getattr(reed, n) for n in SE_PARAMETERS},
        z_c=kernel.z0,
        rho=kernel.rho,
        limit=config.determined_limit,
        scale_gauge=None if config.law == "fixed" else "lam",
        invalid=invalid,
        alpha=config.alpha,
    )
    if not search.converged:
        out["uncertainty_note"] = "; ".join(
            x for x in ("search not converged: SEs at its last point", out["uncertainty_note"]) if x
        )
    return out, Correlation(tuple(names), cov.correlation())


__all__ = [
    "WindowOutcome",
    "invert_window",
    "local_search",
    "start_point",
    "window_bounds",
    "window_objective",
]
