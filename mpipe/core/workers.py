"""Worker processes that never outlive the process that started them.

A worker left running after its parent died keeps writing into an output folder that a new
run may be using: results of two runs get mixed. Every process mpipe starts for parallel
work therefore runs :func:`worker_init` first, which

- asks the Linux kernel to kill it when its parent dies (``prctl(PR_SET_PDEATHSIG)``), which
  covers SIGKILL of the parent, where no Python code of the parent can run;
- starts a watchdog thread that ends it when its parent process id changes (the portable
  fallback, checked every ``PARENT_POLL_S``);
- restores the default SIGTERM action and ignores SIGINT, so that a Ctrl-C is handled once,
  by the parent, which then ends its workers (:func:`process_pool`).
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import faulthandler
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from multiprocessing.managers import SyncManager

log = logging.getLogger(__name__)

#: Interval of the parent watchdog, s.
PARENT_POLL_S = 0.5
#: Time a terminated main process is given for its cleanup before it exits regardless, s.
SIGTERM_GRACE_S = 5.0
#: ``PR_SET_PDEATHSIG`` of ``<linux/prctl.h>``.
_PR_SET_PDEATHSIG = 1


def set_parent_death_signal(sig: int = signal.SIGKILL) -> bool:
    """Ask the kernel to send ``sig`` to this process when its parent ends (Linux only).

    Returns
    -------
    bool
        Whether the request was accepted (False on other systems).
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        return libc.prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def _watch_parent(parent_pid: int, interval_s: float) -> None:
    while True:
        if os.getppid() != parent_pid:
            # The parent is gone (we were re-parented): stop at once, without cleanup that
            # could still write results.
            os._exit(1)
        time.sleep(interval_s)


def worker_init(parent_pid: int, interval_s: float = PARENT_POLL_S) -> None:
    """Initializer of every worker process: end with the parent, whatever ends the parent.

    Parameters
    ----------
    parent_pid : int
        Process id of the process that starts the workers (``os.getpid()`` there).
    interval_s : float
        Watchdog polling interval, s.
    """
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    set_parent_death_signal(signal.SIGKILL)
    plain_log_handlers()
    # The parent may have died before prctl took effect: the watchdog's first check
    # runs immediately and catches that case.
    threading.Thread(
        target=_watch_parent, args=(parent_pid, interval_s), name="mpipe-parent-watchdog",
        daemon=True,
    ).start()  # fmt: skip


def plain_log_handlers() -> None:
    """Replace a progress-bar-aware log handler by a plain one on stderr (in a worker).

    A forked worker inherits the parent's progress-bar-aware log handler, and with it the
    bar's lock as it was at the fork (possibly held by the parent's timer thread) and
    copies of the parent's bars: it logs plainly to stderr instead.
    """
    root = logging.getLogger()
    for handler in list(root.handlers):
        if "tqdm" in type(handler).__name__.lower():
            plain = logging.StreamHandler(sys.stderr)
            plain.setFormatter(handler.formatter)
            plain.setLevel(handler.level)
            root.removeHandler(handler)
            root.addHandler(plain)


@contextlib.contextmanager
def process_pool(
    max_workers: int, initializer: Callable | None = None, initargs: tuple = ()
) -> Iterator[ProcessPoolExecutor]:
    """A process pool whose workers end with this process.

    On leaving the block by an exception (including ``KeyboardInterrupt`` and the
    ``SystemExit`` that :func:`exit_on_sigterm` raises), pending tasks are cancelled and
    the workers are terminated instead of being waited for.

    Parameters
    ----------
    max_workers : int
        Number of worker processes.
    initializer : callable, optional
        Run in each worker after :func:`worker_init`, with ``initargs`` (e.g. to receive
        data shared by every task once per worker instead of once per task).
    initargs : tuple
        Arguments of ``initializer``.
    """
    pool = ProcessPoolExecutor(
        max_workers=max_workers,
        initializer=_init_then,
        initargs=(os.getpid(), initializer, initargs),
    )
    try:
        yield pool
    except BaseException:
        terminate_pool(pool)
        raise
    else:
        pool.shutdown(wait=True)


def _init_then(parent_pid: int, initializer, initargs: tuple) -> None:
    worker_init(parent_pid)
    if initializer is not None:
        initializer(*initargs)


def terminate_pool(pool: ProcessPoolExecutor) -> None:
    """Cancel pending tasks and terminate the pool's worker processes now."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in processes:
        with contextlib.suppress(Exception):
            proc.terminate()
    for proc in processes:
        with contextlib.suppress(Exception):
            proc.join(timeout=2.0)


def manager():
    """A started ``multiprocessing`` SyncManager whose server process ends with this one.

    Use it as a context manager: ``with manager() as m: queue = m.Queue()``.
    """
    m = SyncManager()
    m.start(worker_init, (os.getpid(),))
    return m


def exit_on_sigterm(grace_s: float = SIGTERM_GRACE_S) -> None:
    """Turn SIGTERM into ``SystemExit(143)`` in this (main) process.

    ``finally`` blocks then run: worker pools are terminated, temporary files of atomic
    writes are removed and the output-folder lock is released. Should that cleanup hang
    (the standard library's pool shutdown can wait on a worker that is already gone), the
    process dumps its threads' stacks to stderr and exits anyway after ``grace_s``: a
    terminated run always ends.

    Parameters
    ----------
    grace_s : float
        Time allowed for the cleanup, s.
    """

    def handler(signum, frame):
        timer = threading.Timer(grace_s, _exit_now, args=(128 + signum,))
        timer.daemon = True
        timer.start()
        raise SystemExit(128 + signum)

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, handler)


def _exit_now(code: int) -> None:
    sys.stderr.write(f"mpipe: cleanup after termination did not finish; exiting (code {code})\n")
    with contextlib.suppress(Exception):
        faulthandler.dump_traceback(all_threads=True)
    os._exit(code)


__all__ = [
    "PARENT_POLL_S",
    "SIGTERM_GRACE_S",
    "exit_on_sigterm",
    "manager",
    "process_pool",
    "set_parent_death_signal",
    "terminate_pool",
    "worker_init",
]
