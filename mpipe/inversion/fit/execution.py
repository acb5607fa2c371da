"""Where a take's windows run: in this process, a local process pool, or a Dask cluster.

Every window depends only on its own data and on the start it is given (its note's cold
start, or none: a cold start of its own), never on which windows ran before it in the same
task, so the table does not depend on how windows are spread over workers. Windows are grouped into
contiguous chunks, several per worker, handed out as workers free up. With a checkpoint
folder each finished window is saved as it completes and windows already saved are read
back instead of recomputed.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, CancelledError, wait
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from mpipe import __version__
from mpipe.core.cluster import check_scheduler, require_dask
from mpipe.core.errors import UserError
from mpipe.core.workers import manager as worker_manager
from mpipe.core.workers import process_pool
from mpipe.inversion.fit.coldstart import run_tasks_here, spread_over, spreading
from mpipe.inversion.fit.sensitivities import load_compiled
from mpipe.inversion.fit.window import invert_window
from mpipe.inversion.settings import ExecutorConfig, InversionConfig
from mpipe.inversion.table.tables import load_checkpoint, save_checkpoint
from mpipe.reed.bore_kernel import BoreKernel
from mpipe.reed.parameters import ReedParameters

log = logging.getLogger(__name__)

#: Time allowed to reach a Dask scheduler and to hear its greeting, s.
CONNECT_TIMEOUT_S = 5.0
#: Reruns of a Dask task whose window search raised (a worker killed mid-task is rerun by
#: the scheduler, up to its ``distributed.scheduler.allowed-failures``).
TASK_RETRIES = 2
#: Times the take's data are scattered again when every worker holding them died.
LOST_DATA_ATTEMPTS = 3


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
    starts: Sequence[int],
    warm: ReedParameters | Mapping[int, ReedParameters] | None,
    report: Callable[[int], None] | None = None,
) -> list[tuple[dict, np.ndarray | None]]:
    """Invert the windows at first samples ``starts``, each from ``warm`` (cold when None).

    ``warm`` may also map a window's start sample to its start (its segment's cold start);
    a window missing from the mapping is cold-started. Every window depends only on its
    own data and on ``warm``, never on which windows ran before it in the same task, so the
    table does not depend on how windows are spread over workers. With a checkpoint folder
    each finished window is saved as it completes, and windows already saved are read back
    instead of recomputed.
    """
    with _one_blas_thread():
        return _run_windows_inner(job, starts, warm, report)


def _one_blas_thread():
    """Limit BLAS to one thread while windows run (a context manager).

    The searches use BLAS only on tiny matrices (a (2000, 8) Jacobian at most), where a
    threaded BLAS gains nothing and, on a machine whose cores are busy (other workers,
    other users), its spinning threads stall each call by tens of ms: the cold start took
    5-7x longer wall time with the default threads on a loaded 2-core machine.
    """
    return threadpool_limits(limits=1, user_api="blas")


def _run_windows_inner(job, starts, warm, report):
    out = []
    for s in starts:
        out.append(_one_window(job, int(s), warm))
        if report is not None:
            report(1)
    return out


def _one_window(job: Job, s: int, warm) -> tuple[dict, np.ndarray | None]:
    """Row and step-2 history of the window at sample ``s``: read back, or inverted."""
    saved = None if job.checkpoint is None else load_checkpoint(job.checkpoint, s)
    if saved is not None:
        return saved
    start = warm.get(s) if isinstance(warm, Mapping) else warm  # per segment, or one
    o = invert_window(job.p, job.u, job.fs, s, job.kernel, job.rho, job.config,
                      zero_mean=job.zero_mean, warm=start)  # fmt: skip
    row, hist = o.row, None if o.search is None else o.search.history
    if job.checkpoint is not None:
        save_checkpoint(job.checkpoint, s, row, hist)
    return row, hist


# The take's shared data in a worker process of the local pool: set once per worker by the
# pool initializer, so a task ships only its window starts and the warm start (the signals
# and the bore kernel are several MB; pickling them per task cost more than the windows).
_WORKER_JOB: list = []


def _init_worker(job: Job) -> None:
    _WORKER_JOB[:] = [job]


def _windows_task(args) -> list[tuple[dict, np.ndarray | None]]:
    # Top-level function: picklable for process pools.
    starts, warm, queue = args
    return run_windows(_WORKER_JOB[0], starts, warm, None if queue is None else queue.put)


def split_chains(starts: Sequence[int], n_chains: int) -> list[list[int]]:
    """Split window starts into at most ``n_chains`` contiguous groups of similar length."""
    n_chains = max(1, min(n_chains, len(starts)))
    return [c.tolist() for c in np.array_split(np.asarray(starts, dtype=int), n_chains) if c.size]


def dispatch(
    job: Job,
    starts: Sequence[int],
    warm: ReedParameters | Mapping[int, ReedParameters] | None,
    executor: ExecutorConfig,
    workers: int,
    client,
    update: Callable[[int], None] | None,
) -> list[tuple[dict, np.ndarray | None]]:
    """Run windows on the configured executor; the grouping does not change any result.

    ``starts`` and ``warm`` as in :func:`run_windows`; ``client`` is a Dask client or None.
    Results come in the order of ``starts`` whatever the executor.
    """
    if not starts:
        return []
    if executor.kind == "local" and workers == 1 and client is None:
        return run_windows(job, starts, warm, update)
    # Several chunks per worker, handed out as workers free up: windows differ in cost
    # (a few need more steps), and one chunk per worker left one idle at the end.
    groups = split_chains(list(starts), executor.chunks or 4 * workers)
    if executor.kind == "dask" or client is not None:
        return _track_dask(job, groups, warm, executor, client, update)
    return _track_processes(job, groups, warm, workers, update)


def _track_processes(job, groups, warm, workers, update):

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
    own = client is None
    if own:
        client = connect(executor.scheduler, executor.connect_timeout_s)
    try:
        if job.checkpoint is None:
            parts = gather_in_order(client, job, groups, warm, update)
            return [r for part in parts for r in part]
        return _dask_checkpointed(client, job, groups, warm, update)
    finally:
        if own:
            client.close()


def _dask_checkpointed(client, job: Job, groups, warm, update) -> list:
    """:func:`gather_in_order` with the checkpoint folder kept by this process.

    Windows saved there are read back here; the others run on the cluster without a
    checkpoint folder and are saved here as their group arrives: the workers need not see
    this process's file system.
    """
    items = [s for g in groups for s in g]
    results: list = [None] * len(items)
    todo = []
    for i, s in enumerate(items):
        saved = load_checkpoint(job.checkpoint, s)
        if saved is not None:
            results[i] = saved
        else:
            todo.append(i)
    if update is not None and len(todo) < len(items):
        update(len(items) - len(todo))
    chunks = split_chains(todo, len(groups)) if todo else []

    def keep(k: int, part: list) -> None:
        for i, (row, hist) in zip(chunks[k], part, strict=True):
            save_checkpoint(job.checkpoint, items[i], row, hist)
            results[i] = (row, hist)

    if chunks:
        remote = dataclasses.replace(job, checkpoint=None)
        groups = [[items[i] for i in c] for c in chunks]
        gather_in_order(client, remote, groups, warm, update, keep)
    return results


def connect(scheduler: str, timeout_s: float | None = None, option: str = "executor.scheduler"):
    """A Dask client of ``scheduler``, or one clear line when it cannot be used.

    Checked before any work: the scheduler answers within ``timeout_s``, and every worker
    runs the same mpipe version as this process (a worker with another version could give
    other numbers, one without mpipe cannot run a window).

    Parameters
    ----------
    scheduler : str
        Address of the scheduler, e.g. ``tcp://10.0.0.5:8786``.
    timeout_s : float, optional
        Time allowed to connect and to hear the scheduler's greeting, s (default
        ``CONNECT_TIMEOUT_S``).
    option : str
        The option or key that gave the address, named in the errors.

    Returns
    -------
    distributed.Client

    Raises
    ------
    UserError
        When Dask is not installed, the address is malformed, the scheduler cannot be
        reached or is not a Dask scheduler (:func:`mpipe.core.cluster.check_scheduler`),
        or a worker runs another mpipe version.
    """
    timeout_s = CONNECT_TIMEOUT_S if timeout_s is None else timeout_s
    require_dask()
    # the address, the port and the scheduler's greeting checked first: Dask's client
    # waits minutes on a silent port and misreads an HTTP reply (issue 32)
    address = check_scheduler(scheduler, timeout_s, option)
    from distributed import Client

    try:
        client = Client(address, timeout=f"{timeout_s:g}s", set_as_default=False)
    except (OSError, TimeoutError) as exc:
        raise UserError(
            f"{option}: cannot reach the Dask scheduler at {scheduler} within "
            f"{timeout_s:g} s ({type(exc).__name__}); start it (dask scheduler) or fix the address"
        ) from None
    except Exception as exc:  # it greets as Dask does, but does not serve a client
        raise UserError(
            f"{option}: {address} greets as Dask does but is not a scheduler a client can use "
            f"({type(exc).__name__}: {exc}); a worker's address?"
        ) from None
    try:
        versions = client.run(_mpipe_version)
    except Exception as exc:  # a worker that cannot even import this function
        client.close()
        raise UserError(
            f"{scheduler}: a Dask worker cannot run this mpipe ({type(exc).__name__}: {exc}); "
            f"install mpipe {__version__} on every worker and restart the workers"
        ) from None
    other = {w: v for w, v in versions.items() if v != __version__}
    if other:
        client.close()
        worker, version = next(iter(other.items()))
        raise UserError(
            f"{scheduler}: {len(other)} Dask worker(s) run mpipe {version} ({worker}), this is "
            f"{__version__}; install the same version on every worker"
        )
    return client


def _mpipe_version() -> str:

    return __version__


def gather_in_order(client, job: Job, groups, warm, update=None, done=None) -> list:
    """Run each group of windows as one Dask task; the groups' results in their order.

    The take's shared data are scattered to every worker under a key of their own
    (``hash=False``) and held until every group has finished. (A content-hashed key, the
    default, is the same for the same take in two consecutive calls, such as the notes'
    cold starts and then their warm windows: the release of the first call's copy could reach
    the scheduler after the second scatter and delete it, and the tasks waiting on it were
    cancelled with "lost dependencies".) A task that raised is retried (``TASK_RETRIES``);
    a task whose worker died is rerun on another worker by the scheduler; when the data
    themselves were lost (every worker holding them died), they are scattered again and the
    groups not yet finished are resubmitted, up to ``LOST_DATA_ATTEMPTS`` times.

    Parameters
    ----------
    client : distributed.Client
    job : Job
    groups : sequence of sequence of int
        Windows per task (their first samples), as ``starts`` of :func:`run_windows`.
    warm : ReedParameters or None
        The start of every window.
    update : callable, optional
        Called with the number of windows of each finished group.
    done : callable, optional
        Called with the index of each finished group and its results, as they arrive.

    Returns
    -------
    list
        One list of ``(row, history)`` per group, in the order of ``groups``.
    """
    from distributed import as_completed

    parts: list = [None] * len(groups)
    todo = list(range(len(groups)))
    for attempt in range(1, LOST_DATA_ATTEMPTS + 1):
        job_f = client.scatter(job, broadcast=True, hash=False)
        futures = {
            client.submit(
                _dask_windows, job_f, groups[i], warm, pure=False, retries=TASK_RETRIES
            ): i
            for i in todo
        }
        lost = []
        for f in as_completed(list(futures), loop=client.loop):
            try:
                parts[futures[f]] = f.result()
            except CancelledError as exc:  # its data were lost with their workers
                lost.append(futures[f])
                reason = exc
                continue
            if done is not None:
                done(futures[f], parts[futures[f]])
            if update is not None:
                update(len(groups[futures[f]]))
        del job_f, futures  # released only now: every task that needs the data has finished
        if not lost:
            return parts
        log.warning(
            "%d of %d window groups lost their data on the cluster (%s); scattering again "
            "(attempt %d of %d)", len(lost), len(groups), reason, attempt, LOST_DATA_ATTEMPTS,
        )  # fmt: skip
        todo = sorted(lost)
    raise RuntimeError(
        f"{len(todo)} window groups lost their data on the Dask cluster "
        f"{LOST_DATA_ATTEMPTS} times (workers dying?): {reason}"
    )


def _dask_windows(job, starts, warm):
    return run_windows(job, starts, warm)


# The signals of the take in a worker of :func:`stage_workers` (set once per worker).
_STAGE_SHARED: list = []


def _init_stage(shared) -> None:

    _STAGE_SHARED[:] = [shared]
    # a forked worker inherits the parent's mapper, whose pool no thread serves here: a
    # nested map_tasks inside a task would wait for ever; in a worker tasks run in place
    run_tasks_here()


def _stage_task(args):
    # Top-level function: picklable for process pools.
    fn, item = args
    with _one_blas_thread():
        return fn(_STAGE_SHARED[0], item)


@contextlib.contextmanager
def stage_workers(shared, executor: ExecutorConfig, workers: int, client=None) -> Iterator[None]:
    """Spread the independent tasks of cold starts and temperature fits over workers.

    Inside the block, :func:`mpipe.inversion.fit.coldstart.map_tasks` runs its tasks (the cold
    start's design points and short local searches, the temperature fit's windows) on a
    pool of ``workers`` local processes that hold ``shared`` (the take's p and u, shipped
    once per worker). Results come in the order of the tasks, each task depends only on
    its own inputs: the same answer as one worker. With one worker, or a Dask executor
    (whose windows already spread over the cluster), the tasks run here, one by one.
    Inside an open pool (an outer ``stage_workers`` of the same take) that pool is used.
    """
    if spreading():
        yield
        return
    if executor.kind != "local" or client is not None or workers < 2:
        with spread_over(None):
            yield
        return

    load_compiled()  # once here: the forked workers inherit it
    with process_pool(workers, initializer=_init_stage, initargs=(shared,)) as pool:

        def mapper(fn, items):
            return list(pool.map(_stage_task, [(fn, item) for item in items]))

        with spread_over(mapper):
            yield


__all__ = [
    "Job",
    "connect",
    "dispatch",
    "gather_in_order",
    "run_windows",
    "split_chains",
    "stage_workers",
]
