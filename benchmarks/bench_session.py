"""A recording session (issue 32): many takes in one command, killed, resumed, and on Dask.

Usage: ``.venv/bin/python benchmarks/bench_session.py [--takes 12] [--workers 2]``

``--takes`` short virtual takes (0.62 s, the light pipeline of the batch tests) with three
calibrations (the simplified clarinet; the four-hole clarinet; the four-hole clarinet at
another air temperature) and, on the four-hole instruments, two fingerings (xxxx, xxxo),
listed in one session file. ``mpipe session`` runs as a user runs it (its own process):

1. through, on ``--workers`` local workers: the reference tables and the wall time;
2. again into another folder, killed (SIGKILL of the command, whose workers end with it)
   when half the takes have said their report line (read from its output as it comes: an
   event, not a delay), then resumed: wall time of the resume, whether the takes finished
   before the kill were skipped, and whether the tables equal the reference;
3. on a Dask cluster of a scheduler and two worker processes (127.0.0.1): wall time and
   whether the tables equal the reference.

"Identical" means ``session.csv`` and ``session_takes.csv`` equal byte for byte. Timings on
a loaded machine are upper bounds.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT))
from headline import record  # noqa: E402

from mpipe.cli.virtual_takes import SynthOptions, make_take  # noqa: E402
from tests.inversion.cluster_helpers import real_cluster  # noqa: E402

PLAIN = ROOT / "calibration" / "simplified_clarinet.yaml"
HOLES = ROOT / "calibration" / "four_hole_clarinet.yaml"
REED = ROOT / "calibration" / "reed_table1.yaml"
TABLES = ("session.csv", "session_takes.csv")


def calibrations(folder: Path) -> list[Path]:
    """Three calibrations: two instruments, one of them also at 24 degC."""
    warm = folder / "four_hole_24c.yaml"
    text = HOLES.read_text().replace("temperature_c: 20.0", "temperature_c: 24.0", 1)
    assert text != HOLES.read_text(), "four_hole_clarinet.yaml: no temperature_c: 20.0 to change"
    warm.write_text(text)  # the file names no other file
    return [PLAIN, HOLES, warm]


def make_session(folder: Path, n: int, duration_s: float) -> Path:
    """``n`` takes in a session file; each take's own calibration copy lies beside it."""
    cals = calibrations(folder)
    reed = yaml.safe_load(REED.read_text())
    entries = []
    for i in range(n):
        cal = cals[i % 3]
        fingering = None if cal == PLAIN else ("xxxx", "xxxo")[(i // 3) % 2]
        reed_file = folder / f"reed{i}.yaml"
        reed_file.write_text(yaml.safe_dump({**reed, "p_m": 1700.0 + 40.0 * i}))
        options = SynthOptions(
            duration_s=duration_s, snr_db=60.0, seed=100 + i, fingering=fingering
        )
        take = make_take(cal, reed_file, folder / f"take{i:02d}.flac", options)
        entries.append({"take": take.audio.name, "fingering": fingering,
                        "notes": f"{cal.stem}, {fingering or 'no holes'}"})  # fmt: skip
    data = yaml.safe_load((ROOT / "pipelines" / "simplified_clarinet.yaml").read_text())
    data["calibration"] = str(PLAIN)
    data["conditioning"] = {"edge_s": 0.25}
    data["inversion"]["hop_s"] = 0.04
    data["inversion"].update(design_points=16, local_starts=2)
    (folder / "pipeline.yaml").write_text(yaml.safe_dump(data))
    path = folder / "session.yaml"
    path.write_text(yaml.safe_dump({"pipeline": "pipeline.yaml", "takes": entries}))
    return path


def command(session: Path, out: Path, *options: str) -> list[str]:
    return [sys.executable, "-m", "mpipe.cli.main", "session", str(session), "-o", str(out),
            *options]  # fmt: skip


def run(cmd: list[str]) -> tuple[int, float, list[str]]:
    """A command's exit status, wall time (s) and output lines."""
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode not in (0, 1):
        print(f"    exit {done.returncode}: {done.stderr.strip().splitlines()[-1:]}", flush=True)
    return done.returncode, time.perf_counter() - t0, done.stdout.splitlines()


def killed_midway(cmd: list[str], after: int) -> tuple[float, int]:
    """Run ``cmd`` and SIGKILL it once ``after`` takes said their report line: (wall s, done)."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                            env=env)  # fmt: skip
    reports = 0
    for line in proc.stdout:  # blocks until the next line: no polling
        reports += "    report: " in line
        if reports >= after:
            proc.send_signal(signal.SIGKILL)
            break
    proc.wait()
    proc.stdout.close()
    return time.perf_counter() - t0, reports


def same_tables(a: Path, b: Path) -> bool:
    try:
        return all((a / t).read_bytes() == (b / t).read_bytes() for t in TABLES)
    except FileNotFoundError:
        return False


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--takes", type=int, default=12, help="takes in the session")
    parser.add_argument("--workers", type=int, default=2, help="local workers")
    parser.add_argument("--duration", type=float, default=0.62, help="each take, s")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_session_") as tmp:
        work = Path(tmp)
        t0 = time.perf_counter()
        session = make_session(work, args.takes, args.duration)
        print(f"{args.takes} takes of {args.duration:g} s made in "
              f"{time.perf_counter() - t0:.1f} s", flush=True)  # fmt: skip
        local = ["--workers", str(args.workers)]
        code, wall, _ = run(command(session, work / "through", *local))
        print(f"1. through on {args.workers} local workers: exit {code}, {wall:.1f} s",
              flush=True)  # fmt: skip
        record(f"session of {args.takes} takes, {args.workers} local workers", wall, "s")

        half = max(1, args.takes // 2)
        wall_kill, seen = killed_midway(command(session, work / "killed", *local), half)
        code, wall_resume, lines = run(command(session, work / "killed", *local))
        skipped = sum("5/6 inversion: already done, skipped" in s for s in lines)
        same = same_tables(work / "through", work / "killed")
        print(f"2. killed after {seen} takes ({wall_kill:.1f} s), resumed: exit {code}, "
              f"{wall_resume:.1f} s; {skipped} inversions skipped; tables identical: {same}",
              flush=True)  # fmt: skip
        record("session killed midway and resumed: tables identical", float(same), "",
               target=">= 1")  # fmt: skip

        with real_cluster(2) as (_, address, _):
            code, wall_dask, _ = run(command(session, work / "dask", "--scheduler", address))
        same_dask = same_tables(work / "through", work / "dask")
        print(f"3. on Dask (2 workers): exit {code}, {wall_dask:.1f} s; tables identical: "
              f"{same_dask}", flush=True)  # fmt: skip
        record("session on Dask, 2 workers: tables identical", float(same_dask), "",
               target=">= 1")  # fmt: skip
        record(f"session of {args.takes} takes on Dask, 2 workers", wall_dask, "s")


if __name__ == "__main__":
    main()
