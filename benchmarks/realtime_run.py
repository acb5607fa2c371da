"""Parts of ``bench_realtime.py``: the whole ``mpipe run`` and the start-up, in fresh processes.

Not a benchmark of its own (``run_all.py`` runs ``bench_*.py`` only).
"""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

from headline import record

from mpipe.cli.virtual_takes import SynthOptions, make_take

ROOT = Path(__file__).resolve().parents[1]
CAL = ROOT / "calibration" / "simplified_clarinet.yaml"
REED = ROOT / "calibration" / "reed_table1.yaml"
PIPE = ROOT / "pipelines" / "simplified_clarinet.yaml"


def startup(repeats: int) -> tuple[float, float]:
    """Import time of the command line and first-call time of the compiled kernels, s.

    Each in a fresh interpreter (medians of ``repeats``, after one run that fills numba's
    cache if it is cold); the first call's time less the second's is what loading the
    compiled kernels from the cache cost.
    """
    code = """
import time
t0 = time.perf_counter()
import mpipe.cli.main  # what the mpipe command imports first
t1 = time.perf_counter()
from mpipe.acoustics.reflection import reflection_function
from mpipe.measurement.calibration import load_calibration
from mpipe.reed.bore_kernel import prepare_bore
from mpipe.reed.model import simulate_pressure
from mpipe.reed.parameters import load_reed
from mpipe.reed.sensitivity import pressure_sensitivities
from mpipe.inversion.fit.fastpath import WindowEvaluator
from mpipe.inversion.fit.sensitivities import SensitivityEvaluator
cal = load_calibration(r"CAL")
air = cal.air_properties()
kernel = prepare_bore(reflection_function(cal.bore, air, fs=100_000.0), air)
reed = load_reed(r"REED")
calls = []
for _ in range(2):
    t2 = time.perf_counter()
    simulate_pressure(reed, kernel, 1000)
    pressure_sensitivities(reed, kernel, 1000, ("k",))
    calls.append(time.perf_counter() - t2)
print(t1 - t0, calls[0] - calls[1])
""".replace("CAL", str(CAL)).replace("REED", str(REED))
    imports, loads = [], []
    # a first run (not counted) fills numba's on-disk cache if it is cold
    subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    for _ in range(repeats):
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
        a, b = out.stdout.split()
        imports.append(float(a))
        loads.append(float(b))
    return statistics.median(imports), statistics.median(loads)


def whole_run(duration: float, snr: float, workers: tuple[int, ...], tmp: Path) -> dict:
    """Wall time of ``mpipe run`` and of each stage per worker count, on one virtual take."""
    files = make_take(CAL, REED, tmp / "take.flac", SynthOptions(duration_s=duration, snr_db=snr))
    mpipe = Path(sys.executable).parent / "mpipe"
    out = {}
    for w in workers:
        text = PIPE.read_text().replace("  workers: 0\n", f"  workers: {w}\n")
        text = text.replace("calibration: ../calibration/", f"calibration: {ROOT}/calibration/")
        pipe = tmp / f"pipeline_{w}.yaml"
        pipe.write_text(text)
        folder = tmp / f"run_{w}"
        cmd = [str(mpipe), "run", str(pipe), str(files.audio), "--calibration",
               str(files.calibration), "-o", str(folder)]  # fmt: skip
        t0 = time.perf_counter()
        done = subprocess.run(cmd, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        if done.returncode != 0:
            raise RuntimeError(f"mpipe run failed ({done.returncode}): {done.stderr[-2000:]}")
        stages = {}
        for manifest in sorted(folder.rglob("manifest.json")):
            rec = json.loads(manifest.read_text())
            stages[rec["stage"]] = float(rec["wall_s"])
        out[w] = (wall, stages)
    return out


def report_whole_run(runs: dict, duration: float, offered: float) -> None:
    """Print and record the whole run's figures (``runs`` from :func:`whole_run`)."""
    for w, (wall, stages) in runs.items():
        rest = wall - sum(stages.values())
        parts = ", ".join(f"{k} {v:.2f}" for k, v in stages.items())
        print(
            f"  {w} worker(s): whole command {wall:.2f} s, real-time factor "
            f"{duration / wall:.2f}; stages (s): {parts}; start-up and writing outside the "
            f"stages {rest:.2f} s"
        )
    if 1 in runs and 2 in runs:
        (w1, s1), (w2, s2) = runs[1], runs[2]
        inv1, inv2 = s1.get("inversion", float("nan")), s2.get("inversion", float("nan"))
        print(
            f"  2 workers / 1 worker: whole command x{w1 / w2:.2f}, inversion stage "
            f"x{inv1 / inv2:.2f} (the machine offered x{offered:.2f} to 2 processes)"
        )
        record("mpipe run real-time factor, 2 workers", duration / w2, "", duration / w1, ">= 2")
        record("inversion stage real-time factor (mpipe run), 2 workers", duration / inv2, "",
               duration / inv1, ">= 4")  # fmt: skip
