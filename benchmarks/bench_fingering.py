"""A phrase of several fingerings through ``mpipe run --fingering auto``: every note checked.

Run: ``.venv/bin/python benchmarks/bench_fingering.py [--seed 0] [--workers 2] [--out DIR]``
(a 2.9 s take: some 10-30 minutes on a loaded 2-core machine).

Issue 30's target: a virtual phrase of 5 notes on the four-hole instrument
(``calibration/four_hole_clarinet.yaml``) with 3 fingerings, slurred and tongued, one note
softer, at 45 dB SNR, run with ``fingering: auto``: every note found within 30 ms, every
fingering named right, every note's validation PASS, >= 90 % of the sounding windows ok,
p_m within 3 % in >= 90 % of the ok windows.

The take is ``mpipe synth-take``'s (a score with a fingering per note: the fingerings change
over 5 ms, :mod:`mpipe.reed.fingered_bore`; Table 1 reed), read back with its calibration
copy whose default fingering is removed (so ``auto`` is the default, as for a user's file
that names none), and run by :func:`mpipe.pipeline.orchestration.run_take` as ``mpipe run``
does. Per note it prints: the found note's onset and offset errors against the truth's
sounding span (ms), the fingering named (and its probability) against the one played, the
note's validation verdict, the share of its inverted windows that are ok, and the share of
its ok windows whose p_m is within 3 % of the truth's mean mouth pressure over the window.

The soft note: the Table 1 reed plays no steady note 30 dB below its normal level (below
about p_m = 1300 Pa the oscillation dies away; a rest opening of 0.26 mm and p_m = 900 Pa
give a steady note about 15 dB down, the softest found). The benchmark plays that note and
prints the level difference it measured.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import yaml
from headline import record

from mpipe.cli.virtual_takes import SynthOptions, make_take
from mpipe.pipeline.orchestration import ValidationFailed, run_take
from mpipe.pipeline.settings import load_pipeline

ROOT = Path(__file__).resolve().parents[1]
CAL = ROOT / "calibration" / "four_hole_clarinet.yaml"
REED = ROOT / "calibration" / "reed_table1.yaml"
SCORE = {
    "description": "five notes, three fingerings, slurred and tongued, the fourth soft",
    "end": 0.05,
    "notes": [
        {"duration": 0.55, "fingering": "xxxx", "p_m": 1800.0, "attack": 0.02, "release": 0.005},
        {"duration": 0.55, "fingering": "xxoo", "p_m": 1800.0, "attack": 0.005},
        {"gap": 0.06, "duration": 0.55, "fingering": "xooo", "p_m": 1800.0, "tongued": True},
        {"gap": 0.06, "duration": 0.6, "fingering": "xxoo", "p_m": 900.0, "y_m": 2.6e-4,
         "tongued": True, "release": 0.005},
        {"duration": 0.55, "fingering": "xxxx", "p_m": 1800.0, "y_m": 4.0e-4, "attack": 0.005},
    ],
}  # fmt: skip


def make(folder: Path, seed: int) -> tuple[Path, Path]:
    """Write the score, synthesise the take; return the take and its calibration copy."""
    score = folder / "phrase_score.yaml"
    score.write_text(yaml.safe_dump(SCORE))
    take = folder / "phrase.flac"
    opts = SynthOptions(duration_s=None, score=str(score), snr_db=45.0, seed=seed)
    make_take(CAL, REED, take, opts, force=True)
    cal = folder / "phrase.calibration.yaml"
    data = yaml.safe_load(cal.read_text())
    data.pop("fingering", None)  # no default: auto
    cal.write_text(yaml.safe_dump(data))
    return take, cal


def per_note(root: Path, truth: dict) -> pd.DataFrame:
    """One row per true note: its found note, fingering, verdict and windows' figures."""
    notes = pd.read_csv(root / "validation" / "notes.csv", keep_default_na=False)
    windows = pd.read_csv(root / "inversion" / "windows.csv", keep_default_na=False)
    fs_c = float(truth["control_fs"])
    pm = np.asarray(truth["control_p_m"], float)
    rows = []
    for i, (a, b) in enumerate(zip(truth["note_start_s"], truth["note_end_s"], strict=True)):
        overlap = np.minimum(notes["end_s"], b) - np.maximum(notes["start_s"], a)
        j = int(np.argmax(overlap))
        found = notes.iloc[j] if overlap.iloc[j] > 0 else None
        row = {"note": i + 1, "played": SCORE["notes"][i]["fingering"]}
        if found is None:
            rows.append({**row, "found": False})
            continue
        mine = windows[windows["segment"] == int(found.segment)]
        ok = mine[mine["status"] == "ok"]
        truth_pm = np.array([
            pm[int(s * fs_c):max(int(e * fs_c), int(s * fs_c) + 1)].mean()
            for s, e in zip(ok["t_start_s"], ok["t_end_s"], strict=True)
        ])  # fmt: skip
        within = np.abs(ok["p_m"].to_numpy(float) / truth_pm - 1) <= 0.03 if len(ok) else []
        rows.append({
            **row, "found": True,
            "onset_ms": 1e3 * (found.start_s - a), "offset_ms": 1e3 * (found.end_s - b),
            "named": found.fingering, "p": float(found.fingering_probability),
            "verdict": found.verdict, "windows": len(mine),
            "ok_pct": 100 * len(ok) / len(mine) if len(mine) else float("nan"),
            "pm_within_3_pct": 100 * float(np.mean(within)) if len(ok) else float("nan"),
        })  # fmt: skip
    return pd.DataFrame(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0, help="noise seed (0)")
    parser.add_argument("--workers", type=int, default=2, help="local workers (2)")
    parser.add_argument("--out", default=None, help="keep the run here (default: temporary)")
    parser.add_argument(
        "--resume", action="store_true", help="resume the run kept in --out (its take as is)"
    )
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(args.out or tmp)
        folder.mkdir(parents=True, exist_ok=True)
        if args.resume and (folder / "phrase.flac").exists():
            take, cal = folder / "phrase.flac", folder / "phrase.calibration.yaml"
        else:
            take, cal = make(folder, args.seed)
        cfg = load_pipeline(ROOT / "pipelines" / "simplified_clarinet.yaml")
        cfg = dataclasses.replace(
            cfg, fingering="auto",
            executor=dataclasses.replace(cfg.executor, workers=args.workers),
        )  # fmt: skip
        try:
            run = run_take(cfg, cal, [take], folder / "run", force=not args.resume)
        except ValidationFailed as exc:
            print(f"validation FAILED: {exc}")
            return
        truth = dict(np.load(folder / "phrase.truth.npz"))
        table = per_note(run.folder, truth)
    with pd.option_context("display.width", 160, "display.max_columns", 20):
        print(table.to_string(index=False, float_format=lambda x: f"{x:.1f}"))
    found = table[table["found"]]
    levels = _levels(truth)
    print(f"soft note's level re the loudest: {levels:.1f} dB")
    worst = float(np.max(np.abs(found[["onset_ms", "offset_ms"]].to_numpy()))) if len(found) else 0
    right = int((found["named"] == found["played"]).sum())
    passed = int((found["verdict"] == "pass").sum())
    print(f"notes found {len(found)}/5; worst onset/offset error {worst:.0f} ms (target 30); "
          f"fingerings right {right}/5; validation PASS {passed}/5")  # fmt: skip
    record("phrase of 5 notes, worst onset/offset error", worst, "ms", target="<= 30 ms")
    record("phrase of 5 notes, fingerings named right", right, "of 5", target="5")
    record("phrase of 5 notes, notes whose validation PASSes", passed, "of 5", target="5")
    record("phrase: lowest share of a note's windows ok", float(found["ok_pct"].min()), "%",
           target=">= 90 %")  # fmt: skip
    record("phrase: lowest share of ok windows with p_m within 3 %",
           float(found["pm_within_3_pct"].min()), "%", target=">= 90 %")  # fmt: skip


def _levels(truth: dict) -> float:
    """The soft (fourth) note's steady level re the loudest note's, dB (the truth's p)."""
    p, fs = np.asarray(truth["p"], float), float(truth["fs"])
    level = []
    for a, b in zip(truth["note_start_s"], truth["note_end_s"], strict=True):
        mid = slice(int((a + 0.6 * (b - a)) * fs), int((a + 0.9 * (b - a)) * fs))
        level.append(float(np.std(p[mid])))
    return 20 * np.log10(level[3] / max(level))


if __name__ == "__main__":
    main()
