"""Per-note value and SE on simulated changing notes (issue 38): 2-SE coverage and RMS z.

Run: ``.venv/bin/python benchmarks/bench_note_coverage.py`` (pure numpy, seed 38, a few
seconds): per row, 1000 notes of 20-60 windows, slopes of 2-10 window SEs over the note,
AR(1) window errors of the row's rho, no shared term; the truth is the line at the note's
centre. docs/uncertainty.md, "A note's value and its uncertainty", holds the table.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
from headline import record  # noqa: E402

from mpipe.inversion.trust.notes import note_budget  # noqa: E402

TRUTH = 10.0
NOTES = 1000


def ar1(rng, n: int, rho: float, sigma: float) -> np.ndarray:
    """An AR(1) series of marginal standard deviation ``sigma``."""
    e = rng.normal(0.0, sigma * math.sqrt(1 - rho**2), n)
    x = np.empty(n)
    x[0] = rng.normal(0.0, sigma)
    for i in range(1, n):
        x[i] = rho * x[i - 1] + e[i]
    return x


def coverage(rhos, seed: int = 38) -> tuple[float, float]:
    """2-SE coverage and RMS z of the note's value over :data:`NOTES` simulated notes."""
    rng = np.random.default_rng(seed)
    hits, z = [], []
    for _ in range(NOTES):
        n = int(rng.integers(20, 61))
        rho = float(rng.choice(rhos))
        slope = float(rng.uniform(2, 10) * rng.choice([-1, 1]))
        t = 0.02 * np.arange(n)
        line = TRUTH + slope * (t - t.mean()) / np.ptp(t)
        w = pd.DataFrame({"t_start_s": t, "q": line + ar1(rng, n, rho, 1.0),
                          "q_se_noise": np.ones(n)})  # fmt: skip
        b = note_budget(w, "q")
        hits.append(abs(b["q_median"] - TRUTH) <= 2 * b["q_se"])
        z.append((b["q_median"] - TRUTH) / b["q_se"])
    return float(np.mean(hits)), float(np.sqrt(np.mean(np.square(z))))


def main() -> None:
    for rhos in ([0.3, 0.6], [0.0], [0.3], [0.6], [0.8]):
        cov, rms = coverage(rhos)
        print(f"rho {rhos}: 2-SE coverage {cov:.3f}, RMS z {rms:.3f}")
        if rhos == [0.3, 0.6]:
            record("trending notes: per-note 2-SE coverage", cov, target=">= 0.90")
            record("trending notes: per-note RMS z", rms, target="<= 1.25")


if __name__ == "__main__":
    main()
