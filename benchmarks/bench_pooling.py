"""Pooling a note's windows (issue 29): ``inversion.pooling: window`` beside ``note``.

Usage: ``.venv/bin/python benchmarks/bench_pooling.py [--quick] [--seeds N] [--cases a,b]
[--snr DB] [--keep DIR]``

Makes issue 18's four virtual takes from the shipped scores (crescendo +45 %, vibrato 5 Hz
+-8 %, embouchure y_m -15 %, three tongued notes; :mod:`bench_playing`) at 45 dB SNR for
each seed, runs each through ``mpipe run`` twice (the shipped pipeline with
``inversion.pooling: window``, then ``note``), and prints per take and mode:

- **within tol.**: of the ok windows inside notes, % with p_m within 3 % and p_M within 5 %
  of the truth (target >= 90 %);
- **sounding ok**: % of the sounding windows ok (target >= 90 %);
- **g det., k_c det.**: % of notes whose g (k_c) is determined (the note's combined SE below
  ``inversion.determined_limit`` of its value: ``inversion/segments.csv``; target >= 80 %);
- **g in 2 SE, k_c in 2 SE**: % of those notes whose value lies within 2 combined SE of the
  truth (target >= 90 %);
- **inversion s**: the inversion stage's wall time (``inversion/manifest.json``).

``--snr 60 --cases vibrato`` gives the issue's 60 dB vibrato figure (sounding ok). ``--quick``:
one seed per take. Timings on a loaded machine are upper bounds; compare the two modes on
the same run only.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from bench_playing import CASES, evaluate, make, pipeline_copy, run_pipeline  # noqa: E402
from headline import record  # noqa: E402

MODES = ("window", "note")


def pipeline_for(folder: Path, mode: str, workers: int) -> Path:
    """The shipped pipeline with ``inversion.pooling: mode``."""
    sub = folder / mode
    sub.mkdir(parents=True, exist_ok=True)
    path = pipeline_copy(sub, workers)
    data = yaml.safe_load(path.read_text())
    data.setdefault("inversion", {})["pooling"] = mode
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def wall_s(folder: Path) -> float:
    """The inversion stage's wall time from its manifest, s (NaN when absent)."""
    path = folder / "inversion" / "manifest.json"
    if not path.exists():
        return float("nan")
    data = json.loads(path.read_text())
    return float(data.get("wall_s", float("nan")))  # run_stage's record


def note_flags(folder: Path, truth, name: str, limit: float = 0.10) -> tuple[int, int, int]:
    """Notes (with ok windows), notes where ``name`` is determined, and of those within 2 SE."""
    path = folder / "inversion" / "segments.csv"
    if not path.exists():
        return 0, 0, 0
    seg = pd.read_csv(path)
    true = float(truth[f"reed_{name}"]) if f"reed_{name}" in truth else float("nan")
    notes = seg[(seg.get("ok_windows", 0) > 0) & seg[f"{name}_median"].notna()]
    value, se = notes[f"{name}_median"].to_numpy(float), notes[f"{name}_se"].to_numpy(float)
    det = np.isfinite(se) & (se < limit * np.abs(value))
    within = det & (np.abs(value - true) <= 2 * se)
    return len(notes), int(det.sum()), int(within.sum())


def one(name: str, seed: int, snr: float, folder: Path, pipes: dict) -> dict:
    """Both modes on one take: the figures of the module docstring per mode."""
    files = make(name, folder, seed, snr)
    truth = np.load(files.truth)
    out = {}
    for mode, pipe in pipes.items():
        run = run_pipeline(files, pipe, folder / mode / "out")
        take = folder / mode / "out" / files.audio.stem
        res = evaluate(take, truth)
        g, kc = note_flags(take, truth, "g"), note_flags(take, truth, "k_c")
        out[mode] = dict(res, exit=run[0], wall=wall_s(take), g=g, k_c=kc)
        if run[0] not in (0, 1):
            print(f"  {name} s{seed} {mode}: mpipe run failed: {run[2]}")
    return out


def _pct(a: int, b: int) -> float:
    return 100.0 * a / b if b else float("nan")


def line(name: str, seed: int, mode: str, r: dict) -> str:
    """One row of the table."""
    g, kc = r["g"], r["k_c"]
    return (
        f"  {name:<10} {seed:>4}  {mode:<6} {100 * r['frac_good']:>9.1f} "
        f"{100 * r['frac_ok']:>11.1f} {_pct(g[1], g[0]):>7.0f} {_pct(g[2], g[1]):>9.0f} "
        f"{_pct(kc[1], kc[0]):>9.0f} {_pct(kc[2], kc[1]):>11.0f} {r['wall']:>11.1f}"
    )


HEADER = (
    "  take       seed  mode   within %  sounding ok %  g det %  g in 2SE %  k_c det %  "
    "k_c in 2SE %  inversion s"
)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one seed per take")
    ap.add_argument("--seeds", type=int, default=5, help="noise seeds per take (5)")
    ap.add_argument("--snr", type=float, default=45.0, help="microphone SNR, dB (45)")
    ap.add_argument("--cases", default=",".join(CASES), help=f"some of {', '.join(CASES)}")
    ap.add_argument("--workers", type=int, default=1, help="worker processes (1)")
    ap.add_argument("--keep", metavar="DIR", help="keep the takes and runs in DIR")
    args = ap.parse_args(argv)
    sys.stdout.reconfigure(line_buffering=True)
    cases = [c for c in args.cases.split(",") if c]
    if set(cases) - set(CASES):
        ap.error(f"--cases: expected some of {', '.join(CASES)}")
    seeds = 1 if args.quick else args.seeds
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(args.keep) if args.keep else Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        pipes = {m: pipeline_for(folder, m, args.workers) for m in MODES}
        print(f"pooling at {args.snr:g} dB SNR")
        print(HEADER)
        for name in cases:
            for seed in range(seeds):
                res = one(name, seed, args.snr, folder, pipes)
                for mode in MODES:
                    print(line(name, seed, mode, res[mode]))
                    rows.append((name, seed, mode, res[mode]))
    for mode in MODES:
        mine = [r for _, _, m, r in rows if m == mode]
        worst_good = min(100 * np.nan_to_num(r["frac_good"]) for r in mine)
        worst_ok = min(100 * r["frac_ok"] for r in mine)
        record(f"pooling {mode}: ok windows within tol. (worst take)", worst_good, "%",
               target=">= 90")  # fmt: skip
        record(f"pooling {mode}: sounding windows ok (worst take)", worst_ok, "%", target=">= 90")
        g = np.sum([r["g"] for r in mine], axis=0)
        kc = np.sum([r["k_c"] for r in mine], axis=0)
        print(f"{mode}: g determined in {g[1]}/{g[0]} notes, {g[2]} within 2 SE; k_c "
              f"determined in {kc[1]}/{kc[0]}, {kc[2]} within 2 SE; inversion "
              f"{sum(r['wall'] for r in mine):.0f} s in all")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
