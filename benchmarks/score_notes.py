"""Each note's error against the truth in a kept verdict corpus: RMS z and median error.

Usage: ``.venv/bin/python benchmarks/score_notes.py DIR`` with ``DIR`` the ``--keep`` folder
of ``bench_verdicts.py`` (its ``runs/*/*/inversion/windows.csv`` and ``takes/*.truth.npz``).
Over each note's ok windows, for p_m, p_M, k, y_m, lambda and g: the RMS of
``(estimate - truth) / SE`` and the median relative error, the truth read at each window's
centre from the take's control tracks (``control_*``, the mouth pressure for p_m), or its
constant reed (``reed_*``) where the take has no track of that parameter.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd

#: Table column -> the truth's name (a control track ``control_<name>`` or ``reed_<name>``).
QUANTITIES = {"p_m": "p_m", "p_M": "p_M", "k": "k", "y_m": "y_m", "lam": "lambda", "g": "g"}


def truth_at(truth, name: str, centres_s: np.ndarray) -> np.ndarray:
    """The truth of ``name`` at each time (s): its control track, else its constant."""
    track = f"control_{name}"
    if track in truth.files:
        i = np.clip((centres_s * float(truth["control_fs"])).astype(int), 0, truth[track].size - 1)
        return np.asarray(truth[track], float)[i]
    return np.full(centres_s.size, float(truth[f"reed_{name}"]))


def score(windows: Path, truth_path: Path) -> dict:
    """Per quantity, per note: (RMS z, median relative error)."""
    truth = np.load(truth_path)
    d = pd.read_csv(windows)
    d = d[d["status"] == "ok"]
    centres = ((d["t_start_s"] + d["t_end_s"]) / 2).to_numpy(float)
    out = {}
    for col, name in QUANTITIES.items():
        true = truth_at(truth, name, centres)
        frame = pd.DataFrame({"note": d["note_number"].to_numpy(),
                              "z": (d[col].to_numpy(float) - true) / d[f"{col}_se"].to_numpy(float),
                              "e": d[col].to_numpy(float) / true - 1.0})  # fmt: skip
        by = frame.groupby("note")
        out[col] = [(float(np.sqrt(np.nanmean(g.z**2))), float(g.e.median())) for _, g in by]
    return out


def main(argv: list[str]) -> int:
    root = Path(argv[0])
    for windows in sorted(root.glob("runs/*/*/inversion/windows.csv")):
        name = windows.parent.parent.name
        truth = root / "takes" / f"{name}.truth.npz"
        if not truth.exists():
            continue
        parts = [f"{q}: " + " ".join(f"{z:.1f}/{100 * e:+.1f}%" for z, e in notes)
                 for q, notes in score(windows, truth).items()]  # fmt: skip
        print(f"{name:30s} " + " | ".join(parts))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
