"""Throughput of the time-domain model's convolution kernels on the shipped instrument.

Runs the Table 1 reed on ``calibration/simplified_clarinet.yaml`` at 100 kHz (about 6800
taps of r_f) with the fast (partitioned FFT) and the direct kernel, after a warm-up run
that loads or compiles the numba code, and prints the median samples/second of several
runs of each and their ratio, all measured in this one process.

Usage: ``python benchmarks/bench_model.py [--seconds S] [--repeats N] [--head-taps B]``
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
from headline import record

from mpipe.acoustics.reflection import reflection_function
from mpipe.measurement.calibration import load_calibration
from mpipe.reed.bore_kernel import prepare_bore
from mpipe.reed.model import simulate
from mpipe.reed.parameters import load_reed

ROOT = Path(__file__).resolve().parents[1]


def rate(reed, kernel, n: int, method: str, repeats: int) -> tuple[float, np.ndarray]:
    """Median samples/s over ``repeats`` runs of ``n`` samples, and the last pressure."""
    simulate(reed, kernel, 2000, method=method)  # warm-up: compile or load the cache
    rates = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        sim = simulate(reed, kernel, n, method=method)
        rates.append(n / (time.perf_counter() - t0))
    return statistics.median(rates), sim.p


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=2.0, help="simulated seconds per run")
    parser.add_argument("--repeats", type=int, default=5, help="runs per kernel (median)")
    parser.add_argument("--head-taps", type=int, default=None, help="block size of the fast kernel")
    args = parser.parse_args()

    cal = load_calibration(ROOT / "calibration" / "simplified_clarinet.yaml")
    air = cal.air_properties()
    reed = load_reed(ROOT / "calibration" / "reed_table1.yaml")
    kernel = prepare_bore(reflection_function(cal.bore, air, fs=100_000.0), air, args.head_taps)
    n = int(args.seconds * kernel.fs)
    print(
        f"r_f: {kernel.n_taps} taps at {kernel.fs:g} Hz; fast kernel: {kernel.head_taps - 1} "
        f"direct taps + {kernel.n_partitions} FFT partitions of {kernel.head_taps}"
    )
    fast, p_fast = rate(reed, kernel, n, "fast", args.repeats)
    direct, p_direct = rate(reed, kernel, n, "direct", max(1, args.repeats // 2))
    diff = np.max(np.abs(p_fast - p_direct)) / np.max(np.abs(p_direct))
    record("model, fast kernel (baseline: direct)", fast / 1e6, "M samples/s", direct / 1e6)
    print(f"fast:   {fast / 1e6:7.2f} M samples/s (median of {args.repeats} runs of {n})")
    print(f"direct: {direct / 1e6:7.2f} M samples/s (median of {max(1, args.repeats // 2)} runs)")
    print(f"ratio fast/direct: {fast / direct:.1f}; max |p_fast - p_direct| / max |p|: {diff:.1e}")


if __name__ == "__main__":
    main()
