"""Where windows run: contiguous chunks of windows; nothing to run, nothing dispatched."""

import os
import signal
import sys
from pathlib import Path

import pandas as pd
import pytest

from mpipe.acoustics.reflection import reflection_function
from mpipe.inversion.fit.execution import Job, dispatch, split_chains
from mpipe.inversion.output.resynthesis import reed_from_row
from mpipe.inversion.settings import ExecutorConfig, InversionConfig
from mpipe.inversion.table.tables import COLUMNS
from mpipe.inversion.whole_take.tracking import RunOptions, WindowPlan, track
from mpipe.measurement.calibration import load_calibration
from mpipe.reed.bore_kernel import prepare_bore
from mpipe.reed.model import simulate
from mpipe.reed.parameters import ReedParameters
from tests.inversion.cluster_helpers import free_port, start_worker

ROOT = Path(__file__).resolve().parents[3]


def test_split_chains_contiguous():
    chains = split_chains(list(range(10)), 3)
    assert [c[0] for c in chains] == [0, 4, 7]
    assert sum(chains, []) == list(range(10))
    assert split_chains([1, 2], 5) == [[1], [2]]


def test_dispatch_of_no_windows_starts_no_worker():
    assert dispatch(None, [], None, ExecutorConfig(workers=2), 2, None, None) == []


# --- a real cluster: a scheduler and two worker processes of their own (issue 25) ---------

FS = 100_000.0
TABLE1 = ReedParameters(
    k=8.66e6, S=7.62e-5, y_m=4e-4, p_m=1800.0, lam=0.013, m=0.05, g=3000.0, k_c=8.23e10
)
# cheap windows: only p_m searched, small budgets (the executors, not the estimator, are
# tested here; the estimator is tested with one worker in test_tracking and test_take); the
# warm windows stop before converging, so they are dispatched again for their cold retries
CHEAP = InversionConfig(
    free=("p_m",), max_evaluations=60, warm_max_evaluations=3, design_points=16, local_starts=2
)
#: Columns that must not depend on the executor (all but the timing).
SAME = [c for c in COLUMNS if c != "wall_time_s"]


@pytest.fixture(scope="module")
def take():
    cal = load_calibration(ROOT / "calibration" / "simplified_clarinet.yaml")
    air = cal.air_properties()
    kernel = prepare_bore(reflection_function(cal.bore, air, fs=FS), air)
    sim = simulate(TABLE1, kernel, 50000)
    return kernel, air.rho, sim


@pytest.fixture
def cluster(dask_cluster):
    return dask_cluster


def _track(take, executor, end_s=None, **kw):
    kernel, rho, sim = take
    windows = WindowPlan.span(sim.p.size, FS, CHEAP, start_s=0.26, end_s=end_s)
    return track(sim.p, sim.u, FS, kernel, rho, CHEAP, executor, windows=windows,
                 options=RunOptions(**kw))  # fmt: skip


def test_repeated_runs_on_a_real_cluster_equal_the_local_run(take, cluster):
    # Issue 25: two of six runs lost their scattered data ("lost dependencies") when a take
    # was dispatched twice (then: warm windows, then cold retries) under the same content key.
    client, address, _ = cluster
    local = _track(take, ExecutorConfig(workers=1))
    assert len(local.table) == 12
    dask_cfg = ExecutorConfig(kind="dask", scheduler=address, chunks=4)
    result = _track(take, dask_cfg, client=client)
    pd.testing.assert_frame_equal(local.table[SAME], result.table[SAME])
    # the same take's data dispatched back to back, as the tracking does between its calls
    kernel, rho, sim = take
    job = Job(sim.p, sim.u, FS, kernel, rho, CHEAP, False, None)
    items = [int(round(s * FS)) for s in local.table["t_start_s"].to_numpy()[1:]]
    warm = reed_from_row(local.table.iloc[0].to_dict())
    first = _rows(dispatch(job, items, warm, dask_cfg, 2, client, None))
    for _ in range(5):
        again = _rows(dispatch(job, items, warm, dask_cfg, 2, client, None))
        pd.testing.assert_frame_equal(again, first)
    assert first["t_start_s"].is_monotonic_increasing  # in the order of the items


def _rows(results):
    return pd.DataFrame([row for row, _ in results]).drop(columns="wall_time_s")


class _KillOnFirstResult:
    """A progress bar that kills a worker with windows in flight when a first group ends.

    (The take's cold-started window runs in this process: when it ends, nothing is in
    flight yet.)
    """

    def __init__(self, client):
        self.client = client
        self.pids = client.run(os.getpid)
        self.killed = None

    def update(self, n=1):
        if self.killed is None:
            busy = [w for w, keys in self.client.processing().items() if keys]
            if not busy:
                return
            self.killed = busy[0]
            os.kill(self.pids[busy[0]], signal.SIGKILL)


def test_a_worker_killed_mid_run_changes_nothing(take, cluster):
    client, address, workers = cluster
    local = _track(take, ExecutorConfig(workers=1))
    bar = _KillOnFirstResult(client)
    try:
        result = _track(take, ExecutorConfig(kind="dask", scheduler=address, chunks=8),
                        client=client, progress=bar)  # fmt: skip
        assert bar.killed is not None
        pd.testing.assert_frame_equal(local.table[SAME], result.table[SAME])
    finally:  # the cluster gets its second worker back for the tests after this one
        workers.append(start_worker(address))
        client.wait_for_workers(2, timeout=120)


def test_an_unreachable_scheduler_is_one_line_before_any_work(tmp_path, monkeypatch, capsys):
    from mpipe.cli.main import main
    from mpipe.inversion.fit import execution

    monkeypatch.setattr(execution, "CONNECT_TIMEOUT_S", 1.0)
    pipe = tmp_path / "pipe.yaml"
    cal = ROOT / "calibration" / "simplified_clarinet.yaml"
    address = f"tcp://127.0.0.1:{free_port()}"  # nothing listens there
    pipe.write_text(f"calibration: {cal}\nexecutor: {{kind: dask, scheduler: '{address}'}}\n")
    take_file = tmp_path / "take.wav"
    take_file.write_bytes(b"")  # never read: the scheduler is checked first
    assert main(["run", str(pipe), str(take_file), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and address in err[0] and "cannot reach" in err[0], err
    assert not list((tmp_path / "out").rglob("*.*"))  # no work done, not even a lock


def _run_on(tmp_path, executor: str) -> tuple[int, float]:
    """``mpipe run`` with ``executor`` (a YAML flow mapping): exit status, start time."""
    import time

    from mpipe.cli.main import main

    pipe = tmp_path / "pipe.yaml"
    cal = ROOT / "calibration" / "simplified_clarinet.yaml"
    pipe.write_text(f"calibration: {cal}\nexecutor: {executor}\n")
    take_file = tmp_path / "take.wav"
    take_file.write_bytes(b"")  # never read: the scheduler is checked first
    t0 = time.perf_counter()
    status = main(["run", str(pipe), str(take_file), "-o", str(tmp_path / "out")])
    return status, t0


@pytest.mark.parametrize(
    ("case", "expected"),
    [
        ("http", "not a Dask scheduler: it sent nothing within 0.5 s"),
        ("malformed", "executor.scheduler: malformed scheduler address 'tcp://10.0.0.5'"),
        ("missing", "executor.kind: dask needs Dask's distributed package"),
    ],
)
def test_a_scheduler_that_cannot_serve_is_one_line_and_exit_2(
    case, expected, tmp_path, monkeypatch, capsys
):
    import time

    from tests.core.test_cluster import http_server

    with http_server() as address:
        if case == "malformed":
            address = "tcp://10.0.0.5"
        if case == "missing":
            monkeypatch.setitem(sys.modules, "distributed", None)  # as if not installed
        status, t0 = _run_on(
            tmp_path, f"{{kind: dask, scheduler: '{address}', connect_timeout_s: 0.5}}"
        )
        wall = time.perf_counter() - t0
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and expected in err[0], err
    assert case in ("malformed", "missing") or address in err[0]
    assert wall < 5.0  # not Dask's minutes
    assert not list((tmp_path / "out").rglob("*.*"))  # no work done, not even a lock


def test_on_dask_this_process_keeps_the_checkpoints(take, cluster, tmp_path):
    # the workers get no checkpoint folder (they need not see this file system): the
    # windows are saved here as they arrive, and read back here when the run resumes
    import json

    client, address, _ = cluster
    dask_cfg = ExecutorConfig(kind="dask", scheduler=address, chunks=4)
    ckpt = tmp_path / "windows.d"
    first = _track(take, dask_cfg, client=client, checkpoint=ckpt, end_s=0.40)
    files = sorted(ckpt.glob("w*.json"))
    assert len(files) == len(first.table) == 7
    # a saved window is read back, not recomputed: a mark put in its file comes back
    record = json.loads(files[3].read_text())
    record["row"]["n_evaluations"] = 12345
    files[3].write_text(json.dumps(record))
    files[5].unlink()  # lost with an interruption: recomputed
    again = _track(take, dask_cfg, client=client, checkpoint=ckpt, end_s=0.40)
    assert again.table["n_evaluations"].iloc[3] == 12345
    same = [c for c in SAME if c != "n_evaluations"]
    pd.testing.assert_frame_equal(first.table[same], again.table[same])
    assert len(list(ckpt.glob("w*.json"))) == 7


def test_a_stage_worker_runs_nested_tasks_in_place():
    # a forked worker must not inherit the parent's pool mapper (no thread serves it there:
    # a nested map_tasks would wait for ever); after the worker's initializer it is unset
    from mpipe.inversion.fit import coldstart
    from mpipe.inversion.fit.execution import _init_stage

    with coldstart.spread_over(lambda fn, items: 1 / 0):  # a mapper that must not be used
        _init_stage((None, None))
        assert coldstart.map_tasks(lambda shared, item: item + 1, [1, 2]) == [2, 3]
