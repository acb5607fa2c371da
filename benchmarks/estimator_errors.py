"""Where a group of takes' error-bar excess lies: shared by a take's windows, or scattered.

Usage: ``.venv/bin/python benchmarks/estimator_errors.py TABLES FOLDER GROUP [GROUP ...]
[--seeds 20]``

``TABLES`` and ``FOLDER`` are ``bench_estimator.py``'s ``--tables`` and ``--folder`` (the
windows tables and the takes with their ``*.truth.npz``); a ``GROUP`` is a score, SNR pair
as the tables name it (``steady_60dB``). For each group, over its seeds: the RMS z without
the rate component of p_m, p_M and y_m over the ok windows (as ``bench_estimator.py``
counts it), split into each take's mean z (an error every window of the take shares: the
note's constants, the temperature, a systematic of the chain) and z about that mean (the
windows' own); k, S and lambda once per take (its one note) with their mean z; the
temperature's RMS z; and the correlations over the takes of the take means of T, p_m, y_m,
k, S and lambda (which direction the shared error takes).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pandas as pd
from bench_estimator import scores

SHARED = ("p_m", "p_M", "y_m")
MEANS = ("p_m", "y_m", "k", "S", "lam")
NOTES = ("k", "S", "lam")


def take_z(tables: Path, folder: Path, name: str) -> tuple[dict, float]:
    """One take's z per quantity (ok windows, rate left out) and its temperature's z."""
    table = pd.read_parquet(tables / f"{name}_take.parquet")
    with np.load(folder / f"{name}.truth.npz") as d:
        truth = {k: d[k] for k in d.files}
    s = scores(table, truth)
    figures = json.loads((tables / f"{name}_take.json").read_text())
    t_z = (figures["t"] - figures["t_true"]) / figures["t_se"]
    z = {q: s[q]["z_norate"][np.isfinite(s[q]["z_norate"])] for q in (*SHARED, *MEANS)}
    return z, float(t_z)


def rms(x) -> float:
    """Root mean square."""
    return float(np.sqrt(np.mean(np.square(x))))


def report(tables: Path, folder: Path, group: str, seeds: int) -> None:
    """Print one group's split of RMS z and the take means' correlations."""
    takes = [take_z(tables, folder, f"{group}_seed{k}") for k in range(seeds)]
    print(f"{group}: {seeds} takes, temperature RMS z {rms([t for _, t in takes]):.2f}")
    for q in SHARED:
        parts = [z[q] for z, _ in takes]
        every = np.concatenate(parts)
        means = [p.mean() for p in parts]
        about = np.concatenate([p - p.mean() for p in parts])
        print(
            f"  {q}: RMS z {rms(every):.2f}; take means {rms(means):.2f}, about them "
            f"{rms(about):.2f}; |z| > 4 in {int(np.sum(np.abs(every) > 4))} of {every.size}"
        )
    for q in NOTES:  # each note's constant once (its windows share it): RMS and mean of z
        z = np.array([np.median(z[q]) for z, _ in takes if z[q].size])
        print(f"  {q} (once per take's note): RMS z {rms(z):.2f}, mean z {z.mean():+.2f}")
    frame = pd.DataFrame([{"T": t, **{q: z[q].mean() for q in MEANS}} for z, t in takes])
    print("  correlations of the take means:")
    print(frame.corr().round(2).to_string())


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tables", type=Path)
    parser.add_argument("folder", type=Path)
    parser.add_argument("groups", nargs="+")
    parser.add_argument("--seeds", type=int, default=20)
    args = parser.parse_args(argv)
    for group in args.groups:
        report(args.tables, args.folder, group, args.seeds)


if __name__ == "__main__":
    main()
