"""A Dask cluster as a user starts one: a scheduler and worker processes of their own.

Not ``LocalCluster``: its in-process scheduler hid the lost-data failure of issue 25. Every
process is started by the command-line entry points, on 127.0.0.1 only, ends with the test
process (``PR_SET_PDEATHSIG``) and is waited for by events (the scheduler's
``wait_for_workers``), never by sleeping.
"""

from __future__ import annotations

import contextlib
import signal
import socket
import subprocess
import sys

from mpipe.core.workers import set_parent_death_signal


def free_port() -> int:
    """A TCP port free on 127.0.0.1 now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _child() -> None:
    set_parent_death_signal(signal.SIGKILL)


def start_worker(address: str) -> subprocess.Popen:
    """One worker process (no nanny: killing it kills the worker) with one thread."""
    cmd = [sys.executable, "-m", "distributed.cli.dask_worker", address, "--nthreads", "1",
           "--no-nanny", "--host", "127.0.0.1", "--no-dashboard"]  # fmt: skip
    return subprocess.Popen(
        cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, preexec_fn=_child
    )


@contextlib.contextmanager
def real_cluster(n_workers: int = 2, timeout_s: float = 120.0):
    """Yield ``(client, address, workers)``: a connected client and the worker processes."""
    from distributed import Client

    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    cmd = [sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
           "--port", str(port), "--no-dashboard"]  # fmt: skip
    procs = [subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                              preexec_fn=_child)]  # fmt: skip
    client = None
    try:
        workers = [start_worker(address) for _ in range(n_workers)]
        procs += workers
        client = Client(address, timeout=f"{timeout_s:g}s", set_as_default=False)
        client.wait_for_workers(n_workers, timeout=timeout_s)
        yield client, address, workers
    finally:
        if client is not None:
            client.close()
        for p in procs[::-1]:
            p.kill()
            p.wait()
