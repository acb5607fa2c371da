"""Headline figures of the benchmarks, gathered by ``run_all.py`` into one table.

A benchmark prints its full report as it likes and, for the few figures that matter, also
calls :func:`record`. When ``run_all.py`` runs it, the environment variable
``MPIPE_BENCH_TABLE`` names a file where each call appends one JSON line; run alone, a
benchmark records nothing.
"""

from __future__ import annotations

import json
import math
import os
import sys
from pathlib import Path

#: Environment variable naming the JSON-lines file that collects the figures.
TABLE_ENV = "MPIPE_BENCH_TABLE"


def record(
    figure: str,
    value: float,
    unit: str = "",
    baseline: float | None = None,
    target: str = "",
) -> None:
    """Record one headline figure of the running benchmark.

    Parameters
    ----------
    figure : str
        What was measured, e.g. ``"input impedance, 5000 frequencies"``.
    value : float
        The figure, in ``unit``.
    unit : str
        Its unit (``"ms"``, ``"M samples/s"``, ``"%"``, ...).
    baseline : float, optional
        The same figure for the baseline measured in the same run (same unit); the table
        shows ``baseline / value`` for times and ``value / baseline`` otherwise.
    target : str
        The figure an issue asks for, as text (``"< 20 ms"``), or "" for none.
    """
    path = os.environ.get(TABLE_ENV)
    if not path:
        return
    row = {
        "benchmark": Path(sys.argv[0]).stem,
        "figure": figure,
        "value": float(value),
        "unit": unit,
        "baseline": None if baseline is None or not math.isfinite(baseline) else float(baseline),
        "target": target,
    }
    with open(path, "a", encoding="utf-8") as f:
        f.write(json.dumps(row) + "\n")
