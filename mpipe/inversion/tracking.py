"""Per-window inversion over a take: one shared cold start, warm windows, parallel execution.

A take's mouthpiece signals are cut into windows (20 ms by default, hop configurable).
The first window is cold-started: step 1 on both branches, then the global search of
:mod:`mpipe.inversion.coldstart` (or the paper's single start from step 1). Every other
window starts from that one result and runs the local search to its tolerance, so a
window's answer depends only on its own data and on the take's cold start, whatever the
number of workers or the executor (local processes or a Dask cluster). A window that is not
``ok`` after its warm start gets a cold start of its own. Each window then gets a status
(:mod:`mpipe.inversion.status`); a failed window is recorded with its error and the run
goes on.

References
----------
Chatziioannou & van Walstijn 2012, sections 3 and 4.2; physics.md H, I, J.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from mpipe.core.filters import design_lowpass
from mpipe.core.io import write_atomic, write_csv, write_text_atomic
from mpipe.core.progress import ProgressBar  # the bar drawn by the commands (tqdm)
from mpipe.inversion.coldstart import global_search
from mpipe.inversion.conditioning import is_zero_mean
from mpipe.inversion.least_squares import trust_region
from mpipe.inversion.objective import F2Objective, ObjectiveSettings, TargetWindow
from mpipe.inversion.rosenbrock import SearchResult, minimise
from mpipe.inversion.settings import PARAMETER_NAMES, ExecutorConfig, InversionConfig
from mpipe.inversion.status import classify, on_bounds, search_bounds, window_status
from mpipe.inversion.step1 import Step1Result, step1
from mpipe.inversion.uncertainty import (
    CORRELATION_COLUMNS,
    SE_PARAMETERS,
    correlation_records,
    covariance,
    log_jacobian,
    uncertainty_columns,
    window_uncertainty,
)
from mpipe.reed.bore_kernel import BoreKernel
from mpipe.reed.parameters import ReedParameters

log = logging.getLogger(__name__)

#: Columns of the per-window table, in order.
COLUMNS = (
    "window", "t_start_s", "t_end_s", *PARAMETER_NAMES, "y_c", "alpha",
    "status", "status_reason", "converged", *uncertainty_columns(),
    "step1_p_m", "k_closing", "S_closing", "y_m_closing", "f1_closing",
    "k_opening", "S_opening", "y_m_opening", "f1_opening",
    "f2", "relative_residual", "n_iterations", "n_evaluations", "optimiser",
    "optimiser_converged", "optimiser_message", "at_bound", "warm", "cold_starts_agreeing",
    "retried_cold", "wall_time_s", "error",
)  # fmt: skip


@dataclass(frozen=True)
class WindowOutcome:
    """Full result of one window.

    Attributes
    ----------
    row : dict
        One row of the table (keys of :data:`COLUMNS`).
    step1 : Step1Result or None
        Step-1 fits (None when step 1 was not run or failed).
    search : SearchResult or None
        Step-2 search (None when it failed).
    reed : ReedParameters or None
        Step-2 estimate.
    """

    row: dict
    step1: Step1Result | None
    search: SearchResult | None
    reed: ReedParameters | None


def detect_zero_mean(u: np.ndarray, kind: str, ratio: float = 0.2) -> bool:
    """Whether a take's flow is zero-mean (measured) from the configured ``signal`` kind.

    Parameters
    ----------
    u : ndarray
        Flow, m^3/s.
    kind : {"measured", "model", "auto"}
        Configured signal kind; "auto" decides from mean(u)/rms(u).
    ratio : float
        "auto": zero-mean when |mean(u)| / rms(u) is below this (``zero_mean_ratio``).

    Returns
    -------
    bool
    """
    if kind == "measured":
        return True
    if kind == "model":
        return False
    return is_zero_mean(u, ratio)


def plan_windows(
    n_samples: int,
    fs: float,
    window_s: float,
    hop_s: float,
    start_s: float = 0.0,
    end_s: float | None = None,
) -> list[int]:
    """First sample of every window that fits in ``[start_s, end_s]``.

    Parameters
    ----------
    n_samples : int
        Length of the take, samples.
    fs : float
        Sample rate, Hz.
    window_s, hop_s : float
        Window length and hop, s.
    start_s : float
        Start of the analysed span, s.
    end_s : float, optional
        End of the analysed span, s (default: end of the take).

    Returns
    -------
    list of int
    """
    n = int(round(window_s * fs))
    hop = max(int(round(hop_s * fs)), 1)
    first = max(int(round(start_s * fs)), 0)
    last = n_samples if end_s is None else min(n_samples, int(round(end_s * fs)))
    return list(range(first, last - n + 1, hop))


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
    if config.contact == "closure":
        return ReedParameters(**values, y_c=values["y_m"], alpha=config.alpha)
    values["y_m"] = max(values["y_m"], 1.1 * config.y_c)
    return ReedParameters(**values, y_c=config.y_c, alpha=config.alpha)


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
    """
    budget = config.max_evaluations if cold else config.warm_max_evaluations
    if config.optimiser == "trust-region":
        return trust_region(
            objective.residuals,
            x0,
            lower=bounds[:, 0],
            upper=bounds[:, 1],
            x_tolerance=config.step_tolerance,
            f_tolerance=(
                config.warm_f_tolerance if not cold and config.warm_secant else config.f_tolerance
            )
            or None,
            max_evaluations=budget,
            infeasible_norm=objective.penalty,
            secant=not cold and config.warm_secant,
        )
    return minimise(
        objective,
        x0,
        method=config.optimiser,
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
) -> WindowOutcome:
    """Invert one window of a take.

    A cold window (no ``warm`` start) runs step 1 on both branches and then the cold start
    of ``config.cold_start``: the global search of :mod:`mpipe.inversion.coldstart` (step 1's
    estimate among its starts) or the paper's single start from step 1. A warm window runs
    the local search from ``warm`` only (step 1 too when ``config.step1_every_window``).

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

    Returns
    -------
    WindowOutcome
        Never raises for a failing window: the error is recorded in ``row["error"]``. The
        row's status is provisional (see :func:`mpipe.inversion.status.classify`, which
        compares windows across the take).
    """
    t0 = time.perf_counter()
    n = int(round(config.window_s * fs))
    cold = warm is None
    row = {c: np.nan for c in COLUMNS}
    row.update(
        window=-1,
        t_start_s=start / fs,
        t_end_s=(start + n) / fs,
        error="",
        status="failed",
        status_reason="",
        converged=False,
        optimiser=config.optimiser,
        optimiser_converged=False,
        optimiser_message="",
        at_bound="",
        warm=not cold,
        retried_cold=False,
        uncertainty_note="no estimate",
    )
    row.update({c: False for c in COLUMNS if c.startswith("determined_")})
    s1 = search = reed = None
    try:
        pw, uw = p[start : start + n], u[start : start + n]
        if pw.size < n:
            raise ValueError(f"window at {start / fs:.4f} s runs past the end of the take")
        if cold or config.step1_every_window:
            estimate = config.step1_p_m == "estimate"
            s1 = step1(
                pw,
                uw,
                fs,
                rho=rho,
                lam=config.lam,
                p_m=config.step1_p_m,
                solver=config.step1_solver,
                zero_mean=zero_mean,
                # with contact from closure, step 1's shut-reed test already covers it
                y_c=config.y_c if estimate and config.contact != "closure" else None,
            )
            row.update(step1_p_m=s1.p_m)
            for b in ("closing", "opening"):
                fit = s1.branch(b)
                row.update(
                    {f"k_{b}": fit.k, f"S_{b}": fit.S, f"y_m_{b}": fit.y_m, f"f1_{b}": fit.f1}
                )
        base = warm if warm is not None else start_point(s1, config)
        target = TargetWindow(pw, uw, p[:start], u[:start], fs, zero_mean)
        settings = ObjectiveSettings(
            start=config.start,
            lead_s=config.lead_s,
            settle_s=config.settle_s,
            lowpass=design_lowpass(fs, config.lowpass_hz) if zero_mean else None,
        )
        names = config.search_parameters
        objective = F2Objective(
            kernel,
            target,
            settings,
            base,
            names,
            fast=config.fast_objective,
            contact_at_closure=config.contact == "closure",
        )
        bounds = search_bounds(config, float(np.max(pw)))
        x0 = np.clip([getattr(base, name) for name in names], bounds[:, 0], bounds[:, 1])
        if cold and config.cold_start == "global":
            found = global_search(
                objective,
                objective.residuals,
                bounds[:, 0],
                bounds[:, 1],
                [x0],
                lambda x: local_search(objective, x, bounds, config, cold=True),
                design_points=config.design_points,
                local_starts=config.local_starts,
                local_evaluations=config.local_evaluations,
                infeasible_at=objective.penalty,
                seed=config.design_seed,
            )
            search = found.search
            row["cold_starts_agreeing"] = found.agreeing
        else:
            search = local_search(objective, x0, bounds, config, cold=cold)
        if not search.f < objective.penalty:
            raise RuntimeError("no feasible parameter set found (model silent or unstable)")
        reed = objective.reed(search.x)
        row.update({name: getattr(reed, name) for name in (*PARAMETER_NAMES, "y_c", "alpha")})
        row.update(
            f2=search.f,
            relative_residual=search.f / (float(np.linalg.norm(pw)) + 1e-300),
            n_iterations=search.n_iterations,
            n_evaluations=search.n_evaluations,
            optimiser_converged=search.converged,
            optimiser_message=search.message,
            at_bound=";".join(on_bounds(dict(zip(names, search.x, strict=True)), bounds, config)),
        )
        try:
            row.update(
                _uncertainty(objective, search, bounds, reed, kernel, config, row["at_bound"])
            )
        except (ValueError, np.linalg.LinAlgError) as exc:
            # the estimate stands; only its error bars are missing
            log.warning("window at %.4f s: no standard errors: %s", start / fs, exc)
            row["uncertainty_note"] = f"no standard errors: {exc}"
    except Exception as exc:  # noqa: BLE001 - a failed window is recorded, the take goes on
        log.warning("window at %.4f s failed: %s", start / fs, exc)
        row["error"] = f"{type(exc).__name__}: {exc}"
    row["wall_time_s"] = time.perf_counter() - t0
    row.update(zip(("status", "status_reason"), window_status(row), strict=True))
    row["converged"] = row["status"] == "ok"
    return WindowOutcome(row=row, step1=s1, search=search, reed=reed)


def _uncertainty(objective, search, bounds, reed, kernel, config, at_bound: str) -> dict:
    """Standard errors, combinations and correlations of one window.

    See :mod:`mpipe.inversion.uncertainty`.
    The trust-region search's own Jacobian at the solution is used; other searches (and
    the rare trust-region end that is not scipy's point) get a forward-difference one.
    The correlation matrix rides in the row under ``_correlation`` (not a table column).
    """
    names = objective.free
    if search.jacobian is not None and search.residuals is not None:
        jac, res = search.jacobian, search.residuals
    else:
        res = objective.residuals(search.x)
        jac = log_jacobian(objective.residuals, search.x, r0=res, upper=bounds[:, 1])
    cov = covariance(jac, res, names)
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
        scale_gauge=None if config.contact == "fixed" else "lam",
        invalid=invalid,
    )
    if not search.converged:
        out["uncertainty_note"] = "; ".join(
            x for x in ("search not converged: SEs at its last point", out["uncertainty_note"]) if x
        )
    out["_correlation"] = {"names": list(names), "matrix": cov.correlation().tolist()}
    return out


def _checkpoint_path(checkpoint: Path, start: int) -> Path:
    return checkpoint / f"w{start:010d}.json"


def _save_window(checkpoint: Path, start: int, row: dict, history) -> None:
    record = {
        "row": {k: (v.item() if isinstance(v, np.generic) else v) for k, v in row.items()},
        "history": None if history is None else np.asarray(history, dtype=float).tolist(),
    }
    write_text_atomic(_checkpoint_path(checkpoint, start), json.dumps(record))


def load_checkpoint(checkpoint: str | Path, start: int) -> tuple[dict, np.ndarray | None] | None:
    """The saved result of the window starting at sample ``start``, or None."""
    path = _checkpoint_path(Path(checkpoint), start)
    if not path.exists():
        return None
    record = json.loads(path.read_text())
    hist = record["history"]
    return record["row"], None if hist is None else np.asarray(hist)


@dataclass(frozen=True)
class _Job:
    """What every window of a take shares (shipped once per task to the workers)."""

    p: np.ndarray
    u: np.ndarray
    fs: float
    kernel: BoreKernel
    rho: float
    config: InversionConfig
    zero_mean: bool
    checkpoint: Path | None


def _run_windows(
    job: _Job,
    items: Sequence[tuple[int, dict | None]],
    warm: ReedParameters | None,
    report: Callable[[int], None] | None = None,
) -> list[tuple[dict, np.ndarray | None]]:
    """Invert windows, each from the same start ``warm`` (cold when None).

    ``items`` are ``(start sample, previous row)`` pairs. Every window depends only on its
    own data and on ``warm``, never on which windows ran before it in the same task, so the
    table does not depend on how windows are spread over workers. With a checkpoint folder
    each finished window is saved as it completes, and windows already saved are read back
    instead of recomputed.

    A window given with a previous row is a retry: it gets a cold start of its own, and its
    row is replaced when the cold start reaches a lower F2 (``retried_cold`` either way).
    """
    with _one_blas_thread():
        return _run_windows_inner(job, items, warm, report)


def _one_blas_thread():
    """Limit BLAS to one thread while windows run (a context manager).

    The searches use BLAS only on tiny matrices (a (2000, 8) Jacobian at most), where a
    threaded BLAS gains nothing and, on a machine whose cores are busy (other workers,
    other users), its spinning threads stall each call by tens of ms: the cold start took
    5-7x longer wall time with the default threads on a loaded 2-core machine.
    """
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=1, user_api="blas")


def _run_windows_inner(job, items, warm, report):
    out = []
    for s, previous in items:
        saved = None if job.checkpoint is None else load_checkpoint(job.checkpoint, s)
        if previous is not None and saved is not None and saved[0].get("retried_cold"):
            row, hist = saved
        elif previous is not None:
            o = invert_window(
                job.p, job.u, job.fs, s, job.kernel, job.rho, job.config,
                zero_mean=job.zero_mean, warm=None,
            )  # fmt: skip
            row, hist = previous, None
            if not o.row["error"] and o.row["f2"] < previous["f2"]:
                row, hist = o.row, None if o.search is None else o.search.history
            row = {**row, "retried_cold": True}
        elif saved is not None:
            row, hist = saved
        else:
            o = invert_window(
                job.p, job.u, job.fs, s, job.kernel, job.rho, job.config,
                zero_mean=job.zero_mean, warm=warm,
            )  # fmt: skip
            row, hist = o.row, None if o.search is None else o.search.history
        if job.checkpoint is not None and (saved is None or previous is not None):
            _save_window(job.checkpoint, s, row, hist)
        out.append((row, hist))
        if report is not None:
            report(1)
    return out


# The take's shared data in a worker process of the local pool: set once per worker by the
# pool initializer, so a task ships only its window starts and the warm start (the signals
# and the bore kernel are several MB; pickling them per task cost more than the windows).
_WORKER_JOB: list = []


def _init_worker(job: _Job) -> None:
    _WORKER_JOB[:] = [job]


def _windows_task(args) -> list[tuple[dict, np.ndarray | None]]:
    # Top-level function: picklable for process pools.
    items, warm, queue = args
    return _run_windows(_WORKER_JOB[0], items, warm, None if queue is None else queue.put)


def split_chains(starts: Sequence[int], n_chains: int) -> list[list[int]]:
    """Split window starts into at most ``n_chains`` contiguous groups of similar length."""
    n_chains = max(1, min(n_chains, len(starts)))
    return [list(c) for c in np.array_split(np.asarray(starts, dtype=int), n_chains) if c.size]


@dataclass(frozen=True)
class Tracking:
    """Result of :func:`track`.

    Attributes
    ----------
    table : pandas.DataFrame
        One row per window (columns :data:`COLUMNS`).
    histories : dict
        Window index -> step-2 objective history (best F2 after each evaluation, Pa).
    zero_mean : bool
        Whether the flow was treated as zero-mean (measured).
    correlations : pandas.DataFrame
        Correlation of the log parameters per window, long format: ``window,
        t_start_s, parameter_a, parameter_b, correlation`` (one row per pair a < b).
    """

    table: pd.DataFrame
    histories: dict
    zero_mean: bool
    correlations: pd.DataFrame = dataclasses.field(
        default_factory=lambda: pd.DataFrame(columns=list(CORRELATION_COLUMNS))
    )


def track(
    p: np.ndarray,
    u: np.ndarray,
    fs: float,
    kernel: BoreKernel,
    rho: float,
    config: InversionConfig,
    executor: ExecutorConfig | None = None,
    *,
    start_s: float = 0.0,
    end_s: float | None = None,
    progress: ProgressBar | None = None,
    client=None,
    starts: Sequence[int] | None = None,
    checkpoint: str | Path | None = None,
) -> Tracking:
    """Invert every window of a take.

    The first window is cold-started (see :func:`invert_window`); every other window is
    started from its result, so each window's answer depends only on its own data and on
    that one shared start: 1 or N workers, local processes or Dask give the same table.
    Windows whose status is not ``ok`` after their warm start are then given a cold start
    of their own (``config.retry_cold``), and every window gets its final status from
    :func:`mpipe.inversion.status.classify`.

    Parameters
    ----------
    p : ndarray
        Mouthpiece pressure of the take, Pa.
    u : ndarray
        Mouthpiece flow of the take, m^3/s.
    fs : float
        Sample rate, Hz; must equal the kernel's.
    kernel : BoreKernel
        Prepared bore.
    rho : float
        Air density, kg/m^3.
    config : InversionConfig
        Inversion and window settings.
    executor : ExecutorConfig, optional
        Local processes (default) or Dask.
    start_s, end_s : float, optional
        Span of the take to analyse, s.
    progress : ProgressBar, optional
        Updated as windows finish.
    client : distributed.Client, optional
        An existing Dask client (overrides the scheduler address).
    starts : sequence of int, optional
        Window start samples to invert (default: every window of the span); the
        conditioning stage passes the steady windows only.
    checkpoint : str or Path, optional
        Folder where each finished window is saved; windows found there are not redone.

    Returns
    -------
    Tracking

    Raises
    ------
    ValueError
        When the sample rates differ or no window fits in the span.
    """
    from mpipe.inversion.resynthesis import reed_from_row

    executor = executor or ExecutorConfig()
    p = np.asarray(p, dtype=float)
    u = np.asarray(u, dtype=float)
    if abs(kernel.fs - fs) > 1e-6 * fs:
        raise ValueError(f"signals at {fs:g} Hz but the bore kernel is at {kernel.fs:g} Hz")
    zero_mean = detect_zero_mean(u, config.signal, config.zero_mean_ratio)
    if starts is None:
        starts = plan_windows(p.size, fs, config.window_s, config.hop_s, start_s, end_s)
    starts = [int(s) for s in starts]
    if checkpoint is not None:
        checkpoint = Path(checkpoint)
        checkpoint.mkdir(parents=True, exist_ok=True)
    if not starts:
        raise ValueError(
            f"no {config.window_s:g} s window fits between {start_s:g} s and "
            f"{end_s if end_s is not None else p.size / fs:g} s"
        )
    job = _Job(p, u, fs, kernel, rho, config, zero_mean, checkpoint)
    workers = executor.workers or os.cpu_count() or 1
    update = progress.update if progress is not None else None
    log.info(
        "%d windows (%s executor, %d workers), %s flow",
        len(starts),
        executor.kind,
        workers,
        "zero-mean" if zero_mean else "full",
    )
    # One cold start per take, shared by every other window.
    results = _run_windows(job, [(starts[0], None)], None, update)
    anchor = None if results[0][0].get("error") else reed_from_row(results[0][0])
    items = [(s, None) for s in starts[1:]]
    results += _dispatch(job, items, anchor, executor, workers, client, update)
    results.sort(key=lambda r: r[0]["t_start_s"])
    table = classify(pd.DataFrame([r for r, _ in results], columns=list(COLUMNS)), config)
    if config.retry_cold:
        redo = [
            i
            for i, (row, _) in enumerate(results)
            if table.loc[i, "status"] not in ("ok", "failed") and row["warm"]
            and not row["retried_cold"]
        ]  # fmt: skip
        if redo:
            log.info("%d windows not ok after their warm start: cold-starting them", len(redo))
            items = [(int(round(results[i][0]["t_start_s"] * fs)), results[i][0]) for i in redo]
            again = _dispatch(job, items, None, executor, workers, client, None)
            for i, new in zip(redo, sorted(again, key=lambda r: r[0]["t_start_s"]), strict=True):
                results[i] = new
            table = classify(pd.DataFrame([r for r, _ in results], columns=list(COLUMNS)), config)
    histories = {}
    records = []
    for i, (row, hist) in enumerate(results):
        if hist is not None:
            histories[i] = hist
        corr = row.get("_correlation")
        if corr:
            records += correlation_records(i, row["t_start_s"], corr["names"], corr["matrix"])
    table["window"] = np.arange(len(table))
    correlations = pd.DataFrame(records, columns=list(CORRELATION_COLUMNS))
    return Tracking(
        table=table, histories=histories, zero_mean=zero_mean, correlations=correlations
    )


def _dispatch(job, items, warm, executor, workers, client, update):
    """Run windows on the configured executor; the grouping does not change any result."""
    if not items:
        return []
    if executor.kind == "local" and workers == 1 and client is None:
        return _run_windows(job, items, warm, update)
    # Several chunks per worker, handed out as workers free up: windows differ in cost
    # (a few need more steps), and one chunk per worker left one idle at the end.
    groups = [
        [items[i] for i in g]
        for g in split_chains(list(range(len(items))), executor.chunks or 4 * workers)
    ]
    if executor.kind == "dask" or client is not None:
        return _track_dask(job, groups, warm, executor, client, update)
    return _track_processes(job, groups, warm, workers, update)


def _track_processes(job, groups, warm, workers, update):
    import contextlib
    from concurrent.futures import FIRST_COMPLETED, wait

    from mpipe.core.workers import manager as worker_manager
    from mpipe.core.workers import process_pool

    # workers (and the queue's server) end with this process, whatever ends it
    with contextlib.ExitStack() as stack:
        queue = None
        if update is not None:
            queue = stack.enter_context(worker_manager()).Queue()

        def drain() -> None:
            while queue is not None and not queue.empty():
                update(queue.get())

        pool = stack.enter_context(
            process_pool(min(workers, len(groups)), initializer=_init_worker, initargs=(job,))
        )
        futures = [pool.submit(_windows_task, (g, warm, queue)) for g in groups]
        pending = set(futures)
        while pending:
            _, pending = wait(pending, timeout=0.1, return_when=FIRST_COMPLETED)
            drain()
        results = [r for f in futures for r in f.result()]
        drain()
    return results


def _track_dask(job, groups, warm, executor, client, update):
    from distributed import Client
    from distributed import as_completed as dask_completed

    own = client is None
    if own:
        client = Client(executor.scheduler)
    try:
        # Scatter the shared data once instead of shipping it with every task. The
        # checkpoint folder must be reachable from the workers (a shared file system).
        job_f = client.scatter(job, broadcast=True)
        futures = [client.submit(_dask_windows, job_f, g, warm, pure=False) for g in groups]
        results = []
        for f in dask_completed(futures):
            part = f.result()
            results.extend(part)
            if update is not None:
                update(len(part))
        return results
    finally:
        if own:
            client.close()


def _dask_windows(job, items, warm):
    return _run_windows(job, items, warm)


def write_table(table: pd.DataFrame, directory: str | Path, stem: str = "windows") -> list[Path]:
    """Write the per-window table as CSV (10 significant digits) and as Parquet (full precision).

    Parameters
    ----------
    table : pandas.DataFrame
        The table of :func:`track`.
    directory : str or Path
        Output directory.
    stem : str
        File name without suffix.

    Returns
    -------
    list of Path
        Files written (atomically).
    """
    directory = Path(directory)
    written = [write_csv(directory / f"{stem}.csv", table)]
    try:
        import pyarrow  # noqa: F401
    except ImportError:  # a dependency; only a broken installation lacks it
        log.warning("pyarrow cannot be imported: no Parquet output")
    else:
        written.append(
            write_atomic(
                directory / f"{stem}.parquet", lambda tmp: table.to_parquet(tmp, index=False)
            )
        )
    return written


def write_correlations(
    correlations: pd.DataFrame, directory: str | Path, stem: str = "correlations"
) -> Path:
    """Write the per-window correlation matrices (long format CSV, atomically).

    Parameters
    ----------
    correlations : pandas.DataFrame
        :attr:`Tracking.correlations`.
    directory : str or Path
        Output directory.
    stem : str
        File name without suffix.

    Returns
    -------
    Path
    """
    return write_atomic(
        Path(directory) / f"{stem}.csv",
        lambda tmp: correlations.to_csv(tmp, index=False, float_format="%.6g"),
    )


__all__ = [
    "COLUMNS",
    "ProgressBar",
    "Tracking",
    "WindowOutcome",
    "detect_zero_mean",
    "invert_window",
    "local_search",
    "plan_windows",
    "split_chains",
    "start_point",
    "track",
    "write_correlations",
    "write_table",
]
