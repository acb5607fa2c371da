"""Where a take's windows run: in this process, a local process pool, or a Dask cluster.

Every window depends only on its own data and on the start it is given (the take's cold
start, or none for a retry), never on which windows ran before it in the same task, so the
table does not depend on how windows are spread over workers. Windows are grouped into
contiguous chunks, several per worker, handed out as workers free up. With a checkpoint
folder each finished window is saved as it completes and windows already saved are read
back instead of recomputed.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mpipe.inversion.coldstart import spread_over
from mpipe.inversion.settings import ExecutorConfig, InversionConfig
from mpipe.inversion.tables import load_checkpoint, save_checkpoint
from mpipe.inversion.window import invert_window
from mpipe.reed.bore_kernel import BoreKernel
from mpipe.reed.parameters import ReedParameters


@dataclass(frozen=True)
class Job:
    """What every window of a take shares (shipped once per task to the workers)."""

    p: np.ndarray
    u: np.ndarray
    fs: float
    kernel: BoreKernel
    rho: float
    config: InversionConfig
    zero_mean: bool
    checkpoint: Path | None


def run_windows(
    job: Job,
    items: Sequence[tuple[int, dict | None]],
    warm: ReedParameters | Mapping[int, ReedParameters] | None,
    report: Callable[[int], None] | None = None,
) -> list[tuple[dict, np.ndarray | None]]:
    """Invert windows, each from the same start ``warm`` (cold when None).

    ``warm`` may also map a window's start sample to its start (its segment's cold start);
    a window missing from the mapping is cold-started.

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
        out.append(_one_window(job, s, previous, warm))
        if report is not None:
            report(1)
    return out


def _one_window(job: Job, s: int, previous: dict | None, warm) -> tuple[dict, np.ndarray | None]:
    """Row and step-2 history of the window at sample ``s``: read back, retried or inverted."""
    saved = None if job.checkpoint is None else load_checkpoint(job.checkpoint, s)
    if previous is not None and saved is not None and saved[0].get("retried_cold"):
        row, hist = saved
    elif previous is not None:
        row, hist = _retry_cold(job, s, previous)
    elif saved is not None:
        row, hist = saved
    else:
        start = warm.get(s) if isinstance(warm, Mapping) else warm  # per segment, or one
        o = invert_window(
            job.p, job.u, job.fs, s, job.kernel, job.rho, job.config,
            zero_mean=job.zero_mean, warm=start,
        )  # fmt: skip
        row, hist = o.row, None if o.search is None else o.search.history
    if job.checkpoint is not None and (saved is None or previous is not None):
        save_checkpoint(job.checkpoint, s, row, hist)
    return row, hist


def _retry_cold(job: Job, s: int, previous: dict) -> tuple[dict, np.ndarray | None]:
    """A cold start of the window's own; kept when it reaches a lower F2 than ``previous``."""
    o = invert_window(
        job.p, job.u, job.fs, s, job.kernel, job.rho, job.config,
        zero_mean=job.zero_mean, warm=None,
    )  # fmt: skip
    row, hist = previous, None
    if not o.row["error"] and o.row["f2"] < previous["f2"]:
        row, hist = o.row, None if o.search is None else o.search.history
    return {**row, "retried_cold": True}, hist


# The take's shared data in a worker process of the local pool: set once per worker by the
# pool initializer, so a task ships only its window starts and the warm start (the signals
# and the bore kernel are several MB; pickling them per task cost more than the windows).
_WORKER_JOB: list = []


def _init_worker(job: Job) -> None:
    _WORKER_JOB[:] = [job]


def _windows_task(args) -> list[tuple[dict, np.ndarray | None]]:
    # Top-level function: picklable for process pools.
    items, warm, queue = args
    return run_windows(_WORKER_JOB[0], items, warm, None if queue is None else queue.put)


def split_chains(starts: Sequence[int], n_chains: int) -> list[list[int]]:
    """Split window starts into at most ``n_chains`` contiguous groups of similar length."""
    n_chains = max(1, min(n_chains, len(starts)))
    return [list(c) for c in np.array_split(np.asarray(starts, dtype=int), n_chains) if c.size]


def dispatch(
    job: Job,
    items: Sequence[tuple[int, dict | None]],
    warm: ReedParameters | Mapping[int, ReedParameters] | None,
    executor: ExecutorConfig,
    workers: int,
    client,
    update: Callable[[int], None] | None,
) -> list[tuple[dict, np.ndarray | None]]:
    """Run windows on the configured executor; the grouping does not change any result.

    ``items`` and ``warm`` as in :func:`run_windows`; ``client`` is a Dask client or None.
    Results come in the order of ``items`` for the local executors and in completion order
    for Dask: the caller sorts them.
    """
    if not items:
        return []
    if executor.kind == "local" and workers == 1 and client is None:
        return run_windows(job, items, warm, update)
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
    from mpipe.inversion.sensitivities import load_compiled

    load_compiled()  # once here: the forked workers inherit the loaded compiled code

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
    return run_windows(job, items, warm)


# The signals of the take in a worker of :func:`stage_workers` (set once per worker).
_STAGE_SHARED: list = []


def _init_stage(shared) -> None:
    _STAGE_SHARED[:] = [shared]


def _stage_task(args):
    # Top-level function: picklable for process pools.
    fn, item = args
    with _one_blas_thread():
        return fn(_STAGE_SHARED[0], item)


@contextlib.contextmanager
def stage_workers(shared, executor: ExecutorConfig, workers: int, client=None) -> Iterator[None]:
    """Spread the independent tasks of cold starts and temperature fits over workers.

    Inside the block, :func:`mpipe.inversion.coldstart.map_tasks` runs its tasks (the cold
    start's design points and short local searches, the temperature fit's windows) on a
    pool of ``workers`` local processes that hold ``shared`` (the take's p and u, shipped
    once per worker). Results come in the order of the tasks, each task depends only on
    its own inputs: the same answer as one worker. With one worker, or a Dask executor
    (whose windows already spread over the cluster), the tasks run here, one by one.
    """
    if executor.kind != "local" or client is not None or workers < 2:
        with spread_over(None):
            yield
        return
    from mpipe.core.workers import process_pool
    from mpipe.inversion.sensitivities import load_compiled

    load_compiled()  # once here: the forked workers inherit it
    with process_pool(workers, initializer=_init_stage, initargs=(shared,)) as pool:

        def mapper(fn, items):
            return list(pool.map(_stage_task, [(fn, item) for item in items]))

        with spread_over(mapper):
            yield


__all__ = ["Job", "dispatch", "run_windows", "split_chains", "stage_workers"]
