"""Per-window inversion over a take: step 1, step 2, warm starts, parallel execution.

A take's mouthpiece signals are cut into windows (20 ms by default, hop configurable).
Each window runs step 1 (both branches) and step 2; a window is warm-started from its
predecessor's step-2 result (smaller initial steps, smaller budget). Windows are grouped
into contiguous chains, one warm-start chain per task, and the chains run in parallel on
local processes or on a Dask distributed cluster. A window that fails is recorded with its
error and the run goes on; the next window then starts cold.

References
----------
Chatziioannou & van Walstijn 2012, sections 3 and 4.2; physics.md H, I, J.
"""

from __future__ import annotations

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

from mpipe.conditioning import is_zero_mean
from mpipe.filters import design_lowpass
from mpipe.inversion.objective import F2Objective, ObjectiveSettings, TargetWindow
from mpipe.inversion.rosenbrock import SearchResult, minimise
from mpipe.inversion.step1 import Step1Result, step1
from mpipe.io import write_atomic, write_csv, write_text_atomic
from mpipe.model import BoreKernel
from mpipe.pipeline import PARAMETER_NAMES, ExecutorConfig, InversionConfig
from mpipe.progress import ProgressBar  # the bar drawn by the commands (tqdm)
from mpipe.reed import ReedParameters

log = logging.getLogger(__name__)

#: Columns of the per-window table, in order.
COLUMNS = (
    "window", "t_start_s", "t_end_s", *PARAMETER_NAMES, "y_c", "alpha",
    "step1_p_m", "k_closing", "S_closing", "y_m_closing", "f1_closing",
    "k_opening", "S_opening", "y_m_opening", "f1_opening",
    "f2", "relative_residual", "n_iterations", "n_evaluations", "converged", "warm",
    "wall_time_s", "error",
)  # fmt: skip


@dataclass(frozen=True)
class WindowOutcome:
    """Full result of one window.

    Attributes
    ----------
    row : dict
        One row of the table (keys of :data:`COLUMNS`).
    step1 : Step1Result or None
        Step-1 fits (None when step 1 failed).
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

    Values are clipped into the search bounds, and y_m is kept above y_c.

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
    values["y_m"] = max(values["y_m"], 1.1 * config.y_c)
    return ReedParameters(**values, y_c=config.y_c, alpha=config.alpha)


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
    """Invert one window of a take: step 1 on both branches, then step 2.

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
        Start step 2 here (the previous window's estimate) instead of from step 1.

    Returns
    -------
    WindowOutcome
        Never raises for a failing window: the error is recorded in ``row["error"]``.
    """
    t0 = time.perf_counter()
    n = int(round(config.window_s * fs))
    row = {c: np.nan for c in COLUMNS}
    row.update(
        window=-1,
        t_start_s=start / fs,
        t_end_s=(start + n) / fs,
        error="",
        converged=False,
        warm=warm is not None,
    )
    s1 = search = reed = None
    try:
        pw, uw = p[start : start + n], u[start : start + n]
        if pw.size < n:
            raise ValueError(f"window at {start / fs:.4f} s runs past the end of the take")
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
            y_c=config.y_c if estimate else None,
        )
        row.update(step1_p_m=s1.p_m)
        for b in ("closing", "opening"):
            fit = s1.branch(b)
            row.update({f"k_{b}": fit.k, f"S_{b}": fit.S, f"y_m_{b}": fit.y_m, f"f1_{b}": fit.f1})
        base = warm if warm is not None else start_point(s1, config)
        target = TargetWindow(pw, uw, p[:start], u[:start], fs, zero_mean)
        settings = ObjectiveSettings(
            start=config.start,
            lead_s=config.lead_s,
            settle_s=config.settle_s,
            lowpass=design_lowpass(fs, config.lowpass_hz) if zero_mean else None,
        )
        objective = F2Objective(kernel, target, settings, base, config.free)
        x0 = np.array([getattr(base, name) for name in config.free])
        max_p = float(np.max(pw))
        bounds = np.array([config.bounds.absolute(name, max_p) for name in config.free])
        x0 = np.clip(x0, bounds[:, 0], bounds[:, 1])
        search = minimise(
            objective,
            x0,
            method=config.optimiser,
            lower=bounds[:, 0],
            upper=bounds[:, 1],
            initial_step=config.warm_initial_step if warm is not None else config.initial_step,
            step_tolerance=config.step_tolerance,
            f_tolerance=config.f_tolerance,
            max_evaluations=(
                config.warm_max_evaluations if warm is not None else config.max_evaluations
            ),
            infeasible_at=objective.penalty,
        )
        if not search.f < objective.penalty:
            raise RuntimeError("no feasible parameter set found (model silent or unstable)")
        reed = objective.reed(search.x)
        row.update({name: getattr(reed, name) for name in (*PARAMETER_NAMES, "y_c", "alpha")})
        row.update(
            f2=search.f,
            relative_residual=search.f / (float(np.linalg.norm(pw)) + 1e-300),
            n_iterations=search.n_iterations,
            n_evaluations=search.n_evaluations,
            converged=search.converged,
        )
    except Exception as exc:  # noqa: BLE001 - a failed window is recorded, the take goes on
        log.warning("window at %.4f s failed: %s", start / fs, exc)
        row["error"] = f"{type(exc).__name__}: {exc}"
    row["wall_time_s"] = time.perf_counter() - t0
    return WindowOutcome(row=row, step1=s1, search=search, reed=reed)


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


def _run_chain(
    p: np.ndarray,
    u: np.ndarray,
    fs: float,
    starts: Sequence[int],
    kernel: BoreKernel,
    rho: float,
    config: InversionConfig,
    zero_mean: bool,
    report: Callable[[int], None] | None = None,
    checkpoint: Path | None = None,
    warm: ReedParameters | None = None,
) -> list[tuple[dict, np.ndarray | None]]:
    """Invert a contiguous chain of windows, each warm-started from its predecessor.

    With ``checkpoint`` (a folder), each finished window is saved there as it completes and
    windows already saved are read back instead of recomputed, so an interrupted run
    resumes where it stopped, with the same warm starts.
    """
    from mpipe.resynthesis import reed_from_row

    out = []
    for s in starts:
        saved = None if checkpoint is None else load_checkpoint(checkpoint, s)
        if saved is not None:
            row, hist = saved
            warm = reed_from_row(row) if not row.get("error") else None
        else:
            o = invert_window(p, u, fs, s, kernel, rho, config, zero_mean=zero_mean, warm=warm)
            warm = o.reed
            row, hist = o.row, None if o.search is None else o.search.history
            if checkpoint is not None:
                _save_window(checkpoint, s, row, hist)
        out.append((row, hist))
        if report is not None:
            report(1)
    return out


def _chain_task(args) -> list[tuple[dict, np.ndarray | None]]:
    # Top-level function: picklable for process pools and Dask.
    p, u, fs, starts, kernel, rho, config, zero_mean, queue, checkpoint, warm = args
    report = None if queue is None else queue.put
    return _run_chain(p, u, fs, starts, kernel, rho, config, zero_mean, report, checkpoint, warm)


def split_chains(starts: Sequence[int], n_chains: int) -> list[list[int]]:
    """Split window starts into at most ``n_chains`` contiguous chains of similar length."""
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
    """

    table: pd.DataFrame
    histories: dict
    zero_mean: bool


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
    workers = executor.workers or os.cpu_count() or 1
    n_chains = executor.chunks or (1 if executor.kind == "local" and workers == 1 else workers)
    # One cold start, shared: the first window is inverted from step 1 and every chain
    # is warm-started from its result. Independent cold starts per chain can settle in
    # different local minima, and each costs tens of warm windows.
    results: list[tuple[dict, np.ndarray | None]] = []
    update = progress.update if progress is not None else None
    warm0 = None
    if n_chains > 1 and len(starts) > 1:
        from mpipe.resynthesis import reed_from_row

        results = _run_chain(
            p, u, fs, starts[:1], kernel, rho, config, zero_mean, update, checkpoint
        )
        if not results[0][0].get("error"):
            warm0 = reed_from_row(results[0][0])
        starts = starts[1:]
    chains = split_chains(starts, n_chains)
    log.info(
        "%d windows in %d chains (%s executor), %s flow",
        len(starts),
        len(chains),
        executor.kind,
        "zero-mean" if zero_mean else "full",
    )
    if executor.kind == "dask" or client is not None:
        results += _track_dask(
            p, u, fs, chains, kernel, rho, config, zero_mean, executor, client, update,
            checkpoint, warm0,
        )  # fmt: skip
    elif workers == 1:
        for chain in chains:
            results.extend(
                _run_chain(
                    p, u, fs, chain, kernel, rho, config, zero_mean, update, checkpoint, warm0
                )
            )
    else:
        results += _track_processes(
            p, u, fs, chains, kernel, rho, config, zero_mean, workers, update, checkpoint,
            warm0,
        )  # fmt: skip
    results.sort(key=lambda r: r[0]["t_start_s"])
    histories = {}
    for i, (row, hist) in enumerate(results):
        row["window"] = i
        if hist is not None:
            histories[i] = hist
    table = pd.DataFrame([r for r, _ in results], columns=list(COLUMNS))
    return Tracking(table=table, histories=histories, zero_mean=zero_mean)


def _track_processes(
    p, u, fs, chains, kernel, rho, config, zero_mean, workers, update, checkpoint, warm0=None
):
    from mpipe.workers import manager as worker_manager
    from mpipe.workers import process_pool

    results = []
    # workers (and the queue's server) end with this process, whatever ends it
    with worker_manager() as manager:
        queue = manager.Queue() if update is not None else None
        with process_pool(min(workers, len(chains))) as pool:
            futures = [
                pool.submit(
                    _chain_task,
                    (p, u, fs, c, kernel, rho, config, zero_mean, queue, checkpoint, warm0),
                )
                for c in chains
            ]
            pending = set(futures)
            while pending:
                finished = {f for f in pending if f.done()}
                pending -= finished
                if queue is not None:
                    while not queue.empty():
                        update(queue.get())
                if pending:
                    time.sleep(0.05)
            for f in futures:
                results.extend(f.result())
            if queue is not None:
                while not queue.empty():
                    update(queue.get())
    return results


def _track_dask(
    p, u, fs, chains, kernel, rho, config, zero_mean, executor, client, update, checkpoint,
    warm0=None,
):  # fmt: skip
    from distributed import Client
    from distributed import as_completed as dask_completed

    own = client is None
    if own:
        client = Client(executor.scheduler)
    try:
        # Scatter the large arrays once instead of shipping them with every task.
        p_f, u_f, k_f = client.scatter([p, u, kernel], broadcast=True)
        futures = [
            client.submit(
                _dask_chain,
                p_f,
                u_f,
                fs,
                c,
                k_f,
                rho,
                config,
                zero_mean,
                checkpoint,
                warm0,
                pure=False,
            )
            for c in chains
        ]
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


def _dask_chain(p, u, fs, starts, kernel, rho, config, zero_mean, checkpoint=None, warm=None):
    # The checkpoint folder must be reachable from the workers (a shared file system).
    return _run_chain(p, u, fs, starts, kernel, rho, config, zero_mean, None, checkpoint, warm)


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


__all__ = [
    "COLUMNS",
    "ProgressBar",
    "Tracking",
    "WindowOutcome",
    "detect_zero_mean",
    "invert_window",
    "plan_windows",
    "split_chains",
    "start_point",
    "track",
    "write_table",
]
