"""Dask on a real cluster (issue 25): repeated runs, a worker killed mid-run, a batch of takes.

Usage: ``.venv/bin/python benchmarks/bench_dask.py [--runs 20] [--batch 8] [--duration 1.5]``

A scheduler and two worker processes are started as a user starts them (``dask scheduler``,
``dask worker ADDRESS --nthreads 1``, on 127.0.0.1 only) and the pipeline runs with
``executor: {kind: dask, scheduler: ...}``, through ``mpipe run`` (in this process):

1. ``--runs`` consecutive runs of one take: failures counted, every table compared with the
   local run's (one worker, in this process). The first four stages are copied from the
   local run (their manifests match, so ``mpipe run`` skips them): each run redoes the
   inversion and the resynthesis, the stages that use the cluster.
2. The same with one worker killed (SIGKILL) while it has windows in flight; a new worker
   joins for part 3.
3. A batch of ``--batch`` short takes (different mouth pressures and noise) on the two
   workers against the same takes one after the other in one process; each take's table
   compared with its run alone. Beside the speed-up, the machine's own two-process
   efficiency measured in the same run (a CPU burner, as bench_realtime does): on a shared,
   loaded machine two processes of anything get less than two cores.

Timings on a loaded machine are upper bounds.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import pandas as pd
import yaml

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT))
from bench_realtime import machine_parallelism  # noqa: E402
from headline import record  # noqa: E402

from mpipe.cli.virtual_takes import SynthOptions, make_take  # noqa: E402
from mpipe.inversion.table.records import read_windows  # noqa: E402
from tests.inversion.cluster_helpers import real_cluster, start_worker  # noqa: E402

CAL = ROOT / "calibration" / "simplified_clarinet.yaml"
REED = ROOT / "calibration" / "reed_table1.yaml"
EARLY = ("separation", "translation", "validation", "conditioning")


def pipeline(folder: Path, calibration: Path, executor: dict, name: str, **inv) -> Path:
    data = yaml.safe_load((ROOT / "pipelines" / "simplified_clarinet.yaml").read_text())
    data["calibration"] = str(calibration)
    data["executor"] = executor
    data["inversion"].update(inv)
    path = folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def windows(folder: Path) -> pd.DataFrame:
    table = read_windows(folder / "inversion" / "windows.csv")
    return table.drop(columns="wall_time_s")


def identical(a: Path, b: Path) -> bool:
    try:
        pd.testing.assert_frame_equal(windows(a), windows(b))
    except (AssertionError, FileNotFoundError):
        return False
    return True


def run(argv: list[str]) -> tuple[int, float]:
    """``mpipe run`` as a user runs it (its own process, output silenced): exit, wall s."""
    cmd = [sys.executable, "-m", "mpipe.cli.main", "run", *map(str, argv)]
    t0 = time.perf_counter()
    done = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if done.returncode != 0:
        print(f"    exit {done.returncode}: {done.stderr.strip().splitlines()[-1:]}", flush=True)
    return done.returncode, time.perf_counter() - t0


def prepared(ref: Path, out: Path) -> Path:
    """``out`` with the first four stages of the reference run (skipped by mpipe run)."""
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    for stage in EARLY:
        shutil.copytree(ref / stage, out / stage)
    return out.parent


class Killer(threading.Thread):
    """Kills (SIGKILL) one worker once it has had windows in flight for ``after_s``.

    The windows of a short take spend well under a second on the cluster (the cold start
    and temperature fit run in the ``mpipe run`` process): by default the first worker
    seen with windows in flight is killed.
    """

    def __init__(self, client, after_s: float = 0.0):
        super().__init__(daemon=True)
        self.client, self.after_s = client, after_s
        self.pids = client.run(os.getpid)
        self.killed = None
        self.stop = threading.Event()

    def run(self) -> None:
        """Watch the workers' tasks every 50 ms until one worker is killed or stopped."""
        since = {}
        while not self.stop.wait(0.05) and self.killed is None:
            for worker, keys in self.client.processing().items():
                if any("_dask_windows" in str(k) for k in keys):  # windows, not a take
                    since.setdefault(worker, time.perf_counter())
                    if time.perf_counter() - since[worker] > self.after_s:
                        os.kill(self.pids[worker], signal.SIGKILL)
                        self.killed = worker
                        return


def repeated_runs(work: Path, take, address: str, n: int, client, workers) -> None:
    local_pipe = pipeline(work, take.calibration, {"kind": "local", "workers": 1}, "local")
    dask_pipe = pipeline(work, take.calibration, {"kind": "dask", "scheduler": address}, "dask")
    code, wall = run([local_pipe, take.audio, "-o", work / "local"])
    ref = work / "local" / take.audio.stem
    print(f"  local run (1 worker, in its process): exit {code}, {wall:.1f} s", flush=True)
    failures, same, walls = 0, 0, []
    for i in range(n):
        out = prepared(ref, work / f"dask{i}" / take.audio.stem)
        code, wall = run([dask_pipe, take.audio, "-o", out])
        walls.append(wall)
        failures += code != 0
        same += code == 0 and identical(ref, out / take.audio.stem)
        print(f"    run {i + 1}: exit {code}, {wall:.1f} s, {same} identical so far", flush=True)
    print(
        f"1. {n} consecutive runs on a scheduler + 2 worker processes: {failures} failed, "
        f"{same} of {n} tables identical to the local run (inversion + resynthesis "
        f"{statistics.median(walls):.1f} s each, median)"
    )
    record("consecutive Dask runs failed", failures, "", target="<= 0")
    record("consecutive Dask runs with the local table", same / n, "", target=">= 1")

    out = prepared(ref, work / "killed" / take.audio.stem)
    killer = Killer(client)
    killer.start()
    code, wall = run([dask_pipe, take.audio, "-o", out])
    killer.stop.set()
    ok = code == 0 and identical(ref, out / take.audio.stem)
    print(
        f"2. one worker killed mid-run ({killer.killed or 'none killed'}): exit {code}, table "
        f"{'identical to' if ok else 'DIFFERENT from'} the local run ({wall:.1f} s)"
    )
    record("table identical after a worker was killed", float(ok and bool(killer.killed)), "",
           target=">= 1")  # fmt: skip
    workers.append(start_worker(address))
    client.wait_for_workers(2, timeout=120)


def batch(work: Path, n: int, address: str) -> None:
    takes = []
    for i in range(n):
        reed = yaml.safe_load(REED.read_text())
        reed["p_m"] = 1650.0 + 50.0 * i
        path = work / f"reed{i}.yaml"
        path.write_text(yaml.safe_dump(reed))
        options = SynthOptions(duration_s=0.62, snr_db=50.0, seed=100 + i)
        takes.append(make_take(CAL, path, work / f"short{i}.flac", options))
    cal = takes[0].calibration  # one rig: the takes share its calibration
    short = dict(conditioning={"edge_s": 0.25})
    one = pipeline(work, cal, {"kind": "local", "workers": 1}, "one", hop_s=0.04)
    two = pipeline(work, cal, {"kind": "dask", "scheduler": address}, "two", hop_s=0.04)
    for path in (one, two):
        data = yaml.safe_load(path.read_text())
        path.write_text(yaml.safe_dump({**data, **short}))
    audio = [t.audio for t in takes]
    code1, serial = run([one, *audio, "-o", work / "serial"])
    code2, side = run([two, *audio, "-o", work / "batch"])
    same = sum(identical(work / "serial" / a.stem, work / "batch" / a.stem) for a in audio)
    offered = machine_parallelism(3)
    print(
        f"3. {n} takes of 0.62 s: one after the other in one process {serial:.1f} s (exit "
        f"{code1}); side by side on 2 Dask workers {side:.1f} s (exit {code2}): "
        f"x{serial / side:.2f}; {same} of {n} tables identical to the take run alone"
    )
    print(
        f"   the machine right now: 2 processes of a CPU burner run x{offered:.2f} faster "
        f"than 1 (2.00 on two free cores); the batch got {serial / side / offered:.0%} of it"
    )
    record(f"batch of {n} takes on 2 workers", side, "s", baseline=serial, target="")
    record("batch speed-up over one after the other", serial / side, "", target=">= 1.7")
    record("two-process speed-up the machine offered", offered, "")
    record("batch tables identical to the takes alone", same / n, "", target=">= 1")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20, help="consecutive runs (part 1)")
    parser.add_argument("--batch", type=int, default=8, help="takes in the batch (part 3)")
    parser.add_argument("--duration", type=float, default=1.5, help="take of parts 1-2, s")
    parser.add_argument("--keep", type=Path, default=None, help="work here and keep it")
    args = parser.parse_args()
    sys.stdout.reconfigure(line_buffering=True)  # each figure as soon as it is known
    work = args.keep or Path(tempfile.mkdtemp(prefix="bench_dask_"))
    work.mkdir(parents=True, exist_ok=True)
    try:
        options = SynthOptions(duration_s=args.duration, snr_db=45.0, seed=1)
        take = make_take(CAL, REED, work / "take.flac", options, force=True)
        with real_cluster(2) as (client, address, workers):
            print(f"cluster: {address}, 2 worker processes, 1 thread each", flush=True)
            if args.runs:
                repeated_runs(work, take, address, args.runs, client, workers)
            if args.batch:
                batch(work, args.batch, address)
    finally:
        if args.keep is None:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
