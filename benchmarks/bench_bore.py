"""Benchmark: input impedance at 5000 frequencies and the reflection function at 100 kHz.

Run: ``.venv/bin/python benchmarks/bench_bore.py``. Prints median wall times over several
runs and, as a baseline measured in the same run, the same impedance with scipy's ``jve``
Bessel ratio everywhere (the code path before the asymptotic expansion was added).
Target: impedance at 5000 frequencies in under 20 ms.
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path
from unittest import mock

import numpy as np
from headline import record
from scipy import special

from mpipe.acoustics import ducts
from mpipe.acoustics.bore import input_impedance
from mpipe.acoustics.reflection import reflection_function
from mpipe.measurement.calibration import load_calibration

CAL = Path(__file__).resolve().parents[1] / "calibration" / "simplified_clarinet.yaml"


def median_time(fn, repeats: int) -> float:
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def jve_ratio(z):
    return 2.0 * special.jve(1, z) / (z * special.jve(0, z))


def main() -> None:
    cal = load_calibration(CAL)
    air = cal.air_properties()
    omega = 2 * np.pi * np.linspace(10.0, 5000.0, 5000)
    t_z = median_time(lambda: input_impedance(cal.bore, omega, air), 30)
    with mock.patch.object(ducts, "bessel_ratio", jve_ratio):
        t_base = median_time(lambda: input_impedance(cal.bore, omega, air), 30)
    t_rf = median_time(lambda: reflection_function(cal.bore, air, 100_000.0), 5)
    rf = reflection_function(cal.bore, air, 100_000.0)
    record("input impedance, 5000 frequencies", t_z * 1e3, "ms", t_base * 1e3, "< 20 ms")
    record("reflection function at 100 kHz", t_rf * 1e3, "ms")
    print(f"input impedance, 5000 frequencies : {t_z * 1e3:7.2f} ms (target < 20 ms)")
    print(f"  baseline (jve everywhere)       : {t_base * 1e3:7.2f} ms  ratio {t_base / t_z:.2f}x")
    print(
        f"reflection function at 100 kHz    : {t_rf * 1e3:7.1f} ms "
        f"({rf.n_taps} taps, {rf.n_taps / rf.fs * 1e3:.1f} ms; tail energy {rf.tail_energy:.1e}; "
        f"|Z| error {rf.max_error_db:.3f} dB)"
    )


if __name__ == "__main__":
    main()
