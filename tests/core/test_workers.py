"""Process hygiene: workers end with their parent; output folders are locked and checked."""

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from mpipe.core.io import folder_lock

# A parent that runs a pool of two workers and a manager (as the inversion does), prints
# their process ids and waits to be killed. It waits in 0.1 s slices, as the inversion's
# dispatch loop does: a signal sent to a process may be delivered to any of its threads,
# and Python runs the handler only when the main thread wakes; a single long sleep would
# then outlast the test (CI saw that once).
PARENT = textwrap.dedent(
    """
    import os, sys, time
    from mpipe.core.workers import exit_on_sigterm, manager, process_pool

    def nap(_):
        time.sleep(60)

    def pid(_):
        return os.getpid()

    exit_on_sigterm()
    with manager() as m:
        q = m.Queue()
        with process_pool(2) as pool:
            pids = set()
            while len(pids) < 2:
                pids |= set(pool.map(pid, range(8)))
            futures = [pool.submit(nap, i) for i in range(2)]
            print(" ".join(map(str, [*pids, m._process.pid])), flush=True)
            for _ in range(600):
                time.sleep(0.1)
    """
)


def _alive(pid: int) -> bool:
    # a zombie (not reaped by a container's init) counts as ended
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state not in ("Z", "X")


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc (Linux)")
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_no_worker_outlives_a_killed_parent(sig):
    parent = subprocess.Popen(
        [sys.executable, "-c", PARENT], stdout=subprocess.PIPE, text=True, start_new_session=True
    )
    children = []
    try:
        children = [int(x) for x in parent.stdout.readline().split()]
        assert len(children) == 3 and all(_alive(c) for c in children)
        os.kill(parent.pid, sig)
        parent.wait(timeout=10)
        deadline = time.monotonic() + 5.0
        while any(_alive(c) for c in children) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not [c for c in children if _alive(c)]
    finally:
        if parent.poll() is None:
            parent.kill()
        for c in children:  # never leave a survivor behind, even when the test fails
            if _alive(c):
                os.kill(c, signal.SIGKILL)


PIPELINE = Path(__file__).resolve().parents[2] / "pipelines" / "simplified_clarinet.yaml"


def test_run_refuses_a_file_as_output_in_one_line(tmp_path, capsys):
    from mpipe.cli.main import main

    take = tmp_path / "take.flac"
    take.write_bytes(b"not audio: never read, the output check comes first")
    out = tmp_path / "out"
    out.write_text("a file")
    assert main(["run", str(PIPELINE), str(take), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"mpipe run: error: {out}: exists and is not a folder; choose another output path"


def test_run_refuses_a_folder_another_run_holds(tmp_path, capsys):
    from mpipe.cli.main import main

    take = tmp_path / "take.flac"
    take.write_bytes(b"not audio: never read, the lock comes first")
    out = tmp_path / "out"
    with folder_lock(out / "take"):
        assert main(["run", str(PIPELINE), str(take), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "in use by another mpipe run" in err[0]


def test_output_files_under_a_file_are_refused_before_any_work(tmp_path, capsys):
    from mpipe.cli.main import main

    blocker = tmp_path / "file"
    blocker.write_text("x")
    cal = Path(__file__).resolve().parents[2] / "calibration" / "simplified_clarinet.yaml"
    assert main(["impedance", str(cal), "--csv", str(blocker / "z.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"mpipe impedance: error: {blocker}: exists and is not a folder; choose " \
        "another output path"  # fmt: skip
    assert main(["config", "-o", str(tmp_path)]) == 2
    assert "is a folder; expected an output file name" in capsys.readouterr().err


def test_workers_log_plainly_not_through_the_parents_progress_bars():
    import logging

    from mpipe.core.progress import logging_redirect
    from mpipe.core.workers import plain_log_handlers

    root = logging.getLogger()
    with logging_redirect():
        assert any("tqdm" in type(h).__name__.lower() for h in root.handlers)
        plain_log_handlers()  # what a forked worker does first
        assert not any("tqdm" in type(h).__name__.lower() for h in root.handlers)


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc (Linux)")
def test_a_terminated_run_ends_even_when_its_cleanup_hangs():
    # the cleanup (a finally block) never returns: the grace timer must end the process
    code = textwrap.dedent(
        """
        import time
        from mpipe.core.workers import exit_on_sigterm
        exit_on_sigterm(grace_s=0.5)
        try:
            print("ready", flush=True)
            time.sleep(60)
        finally:
            time.sleep(60)
        """
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout.readline().strip() == "ready"
        os.kill(proc.pid, signal.SIGTERM)
        assert proc.wait(timeout=10) == 128 + signal.SIGTERM
        assert "did not finish" in proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
