"""Real playing (issue 18): virtual takes played like people, through the whole pipeline.

Usage: ``.venv/bin/python benchmarks/bench_playing.py [--seeds N] [--cases a,b] [--skip-long]``

Makes the four takes of issue 18's "Done when" from the shipped scores in
``examples/scores/`` (a crescendo of +45 % in 1.5 s; a 5 Hz vibrato of ±8 % on p_m; an
embouchure change y_m -15 % in 1 s; three tongued notes with 0.25 s silences), with
microphone noise at 45 dB SNR, for several noise seeds, and a 20 s take with a 10 % swell;
runs each through ``mpipe run`` as a user would (a subprocess, the shipped pipeline with
``--accept-failed-validation``, so a validation that fails is reported and the inversion is
still measured), and prints the issue's table per take:

- **sounding windows ok**: of the windows of the pipeline's grid (``plan.csv``) that lie in a
  note after its first 50 ms and before its last 30 ms (notes from ``TAKE.truth.npz``: from
  the release of the tongue, or the start of the attack, to the end of the release), the
  fraction whose status is ``ok`` (target >= 90 %);
- **within tolerance**: of the ok windows inside notes, the fraction with p_m within 3 %
  and p_M = k y_m within 5 % of the truth averaged over the window (target >= 90 %);
- **ok in silence**: ok windows whose centre lies outside every note (from its start, tongue
  hold included, to the end of its release) (target 0);
- **per note**: windows, ok, median p_m and p_M against the truth's median over the same
  windows;
- **20 s swell**: median S and lambda of the ok windows against the truth (target within 3 %).

Optional columns of ``windows.csv`` are used when present: ``segment`` (the segment id; the
notes' segments are listed) and ``phase`` (onset / sustain / release; the ok fraction per
phase). Timings on a loaded 2-core machine are upper bounds.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
from headline import record  # noqa: E402

from mpipe.inversion.table.records import read_windows as read_window_table  # noqa: E402

CAL = ROOT / "calibration" / "simplified_clarinet.yaml"
REED = ROOT / "calibration" / "reed_table1.yaml"
PIPELINE = ROOT / "pipelines" / "simplified_clarinet.yaml"
SCORES = ROOT / "examples" / "scores"
CASES = ("crescendo", "vibrato", "embouchure", "phrase")
#: A note's first and last stretch that the criterion leaves out, s.
HEAD_S, TAIL_S = 0.05, 0.03
#: Tolerances of the criterion: p_m within 3 %, p_M within 5 %.
TOL_PM, TOL_PCLOSE = 0.03, 0.05


def pipeline_copy(folder: Path, workers: int) -> Path:
    """The shipped pipeline with an absolute calibration path and ``workers`` processes."""
    data = yaml.safe_load(PIPELINE.read_text())
    data["calibration"] = str(CAL)
    data.setdefault("executor", {})["workers"] = workers
    path = folder / "pipeline.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def make(name: str, folder: Path, seed: int, snr: float, duration: float | None = None):
    """Write one take (a shipped score, or the long swell when ``duration`` is given)."""
    from mpipe.cli.virtual_takes import SynthOptions, make_take

    if duration is None:
        opts = SynthOptions(
            duration_s=None, snr_db=snr, seed=seed, score=str(SCORES / f"{name}.yaml")
        )
    else:
        opts = SynthOptions(duration_s=duration, snr_db=snr, seed=seed, swell=0.10)
    return make_take(CAL, REED, folder / f"{name}_s{seed}.flac", opts, force=True)


def run_pipeline(files, pipe: Path, out: Path) -> tuple[int, float, str]:
    """``mpipe run`` on a take as a user runs it; (exit status, wall time s, last lines)."""
    cmd = [sys.executable, "-m", "mpipe.cli.main", "run", str(pipe), str(files.audio),
           "--calibration", str(files.calibration), "-o", str(out), "--force",
           "--accept-failed-validation"]  # fmt: skip
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    tail = "\n".join((proc.stdout + proc.stderr).strip().splitlines()[-3:])
    return proc.returncode, time.perf_counter() - t0, tail


def truth_over(truth, key: str, t0: float, t1: float) -> float:
    """The truth curve ``key`` averaged over [t0, t1) s (cells of the control grid)."""
    fs = float(truth["control_fs"])
    values = truth[key].astype(float)
    a = int(np.floor(t0 * fs))
    b = max(int(np.ceil(t1 * fs)), a + 1)
    return float(np.mean(values[a : min(b, values.size)]))


def grid(folder: Path, windows: pd.DataFrame) -> pd.DataFrame:
    """Every window of the pipeline's grid (``plan.csv``; else the windows table), in s."""
    plan_path = folder / "conditioning" / "plan.csv"
    if plan_path.exists():
        plan = pd.read_csv(plan_path)
        if {"t_start_s", "t_end_s"} <= set(plan.columns):
            return plan[["t_start_s", "t_end_s"]]
    return windows[["t_start_s", "t_end_s"]]


def inside(table: pd.DataFrame, a: float, b: float) -> pd.Series:
    """Windows of ``table`` after a note's first 50 ms and before its last 30 ms."""
    return (table["t_start_s"] >= a + HEAD_S - 1e-9) & (table["t_end_s"] <= b - TAIL_S + 1e-9)


def read_windows(folder: Path, notes, spans) -> pd.DataFrame:
    """``windows.csv`` with ``ok``, ``note`` (index, -1 outside) and ``in_note`` columns."""
    path = folder / "inversion" / "windows.csv"
    if not path.exists():
        return pd.DataFrame(columns=["t_start_s", "t_end_s", "status", "ok", "note", "in_note"])
    win = read_window_table(path)
    win["ok"] = win["status"].astype(str) == "ok"
    centre = 0.5 * (win["t_start_s"] + win["t_end_s"])
    win["note"] = -1
    for i, (a, b) in enumerate(notes):
        win.loc[inside(win, a, b), "note"] = i
    win["in_note"] = False
    for a, b in spans:
        win["in_note"] |= (centre >= a) & (centre <= b)
    return win


def evaluate(folder: Path, truth) -> dict:
    """The issue's figures for one take folder ``OUT/<take>`` against its truth."""
    notes = list(zip(truth["note_start_s"], truth["note_end_s"], strict=True))
    win = read_windows(folder, notes, notes_with_holds(truth, notes))
    cells = grid(folder, win)
    sounding = [int(inside(cells, a, b).sum()) for a, b in notes]
    ok = win[win["ok"] & win["in_note"]].copy()
    span = list(zip(ok["t_start_s"], ok["t_end_s"], strict=True))
    ok["pm_true"] = [truth_over(truth, "control_p_m", a, b) for a, b in span]
    ok["pM_true"] = [truth_over(truth, "control_p_M", a, b) for a, b in span]
    ok["p_M"] = ok["k"] * ok["y_m"]
    good = ((ok["p_m"] / ok["pm_true"] - 1).abs() <= TOL_PM) & (
        (ok["p_M"] / ok["pM_true"] - 1).abs() <= TOL_PCLOSE
    )
    per_note = []
    for i, count in enumerate(sounding):
        mine = ok[ok["note"] == i]
        segs = sorted(set(mine["segment"].dropna().astype(int))) if "segment" in mine else None
        per_note.append(
            {
                "note": i + 1,
                "sounding": count,
                "ok": len(mine),
                **{c: mine[c].median() for c in ("p_m", "pm_true", "p_M", "pM_true")},
                "segments": segs,
            }
        )
    phases = None
    if "phase" in win:
        by_phase = win[win["note"] >= 0].groupby("phase")["ok"]
        phases = by_phase.agg(["sum", "count"]).to_dict("index")
    ok_sounding = int((win["ok"] & (win["note"] >= 0)).sum())
    return {
        "sounding": sum(sounding),
        "ok_sounding": ok_sounding,
        "frac_ok": ok_sounding / sum(sounding) if sum(sounding) else float("nan"),
        "n_ok": len(ok),
        "frac_good": float(good.mean()) if len(ok) else float("nan"),
        "ok_in_silence": int((win["ok"] & ~win["in_note"]).sum()),
        "per_note": per_note,
        "phases": phases,
        "statuses": win["status"].value_counts().to_dict(),
    }


def notes_with_holds(truth, notes):
    """Each note from its start (tongue hold included) to the end of its release, s."""
    holds = list(zip(truth["tongue_start_s"], truth["tongue_end_s"], strict=True))
    out = []
    for a, b in notes:
        starts = [h0 for h0, h1 in holds if abs(h1 - a) < 1e-3]
        out.append((min(starts) if starts else a, b))
    return out


def verdict(folder: Path) -> str:
    """The validation's verdict from its manifest, or "?"."""
    path = folder / "validation" / "manifest.json"
    if not path.exists():
        return "?"
    return str(json.loads(path.read_text()).get("summary", {}).get("verdict", "?"))


def report(name: str, seed: int, res: dict, run: tuple, folder: Path) -> None:
    """Print one take's figures."""
    code, wall, _ = run
    print(f"\n{name}, seed {seed}: mpipe run exit {code}, {wall:.0f} s, validation "
          f"{verdict(folder)}; statuses {res['statuses']}")  # fmt: skip
    print(f"  sounding windows ok: {res['ok_sounding']}/{res['sounding']} = "
          f"{100 * res['frac_ok']:.1f} % (target >= 90 %)")  # fmt: skip
    print(f"  ok windows with p_m within 3 % and p_M within 5 %: "
          f"{100 * res['frac_good']:.1f} % of {res['n_ok']} (target >= 90 %)")  # fmt: skip
    print(f"  ok windows in silences: {res['ok_in_silence']} (target 0)")
    if res["phases"]:
        parts = [f"{k} {v['sum']}/{v['count']}" for k, v in res["phases"].items()]
        print("  ok by phase (sounding windows): " + ", ".join(parts))
    print("  note  sounding   ok  p_m med   truth   err %  p_M med   truth   err %  segments")
    for n in res["per_note"]:
        e1 = 100 * (n["p_m"] / n["pm_true"] - 1) if n["ok"] else float("nan")
        e2 = 100 * (n["p_M"] / n["pM_true"] - 1) if n["ok"] else float("nan")
        segs = "-" if n["segments"] is None else n["segments"]
        print(f"  {n['note']:>4}  {n['sounding']:>8}  {n['ok']:>3}  {n['p_m']:7.1f}  "
              f"{n['pm_true']:6.1f}  {e1:+6.2f}  {n['p_M']:7.1f}  {n['pM_true']:6.1f}  "
              f"{e2:+6.2f}  {segs}")  # fmt: skip


def long_take(folder: Path, pipe: Path, snr: float, duration: float) -> None:
    """The 20 s take with a 10 % swell: median S and lambda of the ok windows."""
    files = make("swell", folder, 0, snr, duration)
    code, wall, tail = run_pipeline(files, pipe, folder / "out")
    take = folder / "out" / files.audio.stem
    truth = np.load(files.truth)
    path = take / "inversion" / "windows.csv"
    if not path.exists():
        print(f"\n{duration:g} s swell: no windows table (exit {code}): {tail}")
        return
    win = read_window_table(path)
    ok = win[win["status"] == "ok"]
    s_err = 100 * (ok["S"].median() / float(truth["reed_S"]) - 1)
    lam_err = 100 * (ok["lam"].median() / float(truth["reed_lambda"]) - 1)
    temps = ", ".join(f"{t:.2f}" for t in win["kernel_temperature_c"].dropna().unique()[:5])
    print(f"\n{duration:g} s take, 10 % swell: mpipe run exit {code}, {wall:.0f} s; "
          f"{len(ok)} of {len(win)} windows ok; median S {s_err:+.2f} %, lambda "
          f"{lam_err:+.2f} % (target within 3 %); kernel temperature(s) {temps} degC "
          f"(truth {float(truth['temperature_c'][0]):.2f})")  # fmt: skip
    record(f"{duration:g} s swell: median S error", abs(s_err), "%", target="<= 3")
    record(f"{duration:g} s swell: median lambda error", abs(lam_err), "%", target="<= 3")


def summarise(summary: list, cases: list[str], snr: float) -> None:
    """The table over takes and seeds, and the headline figures (worst seed per take)."""
    print(f"\nsummary (issue 18, 'Done when'; every take at {snr:g} dB SNR)")
    print("  take        seed  sounding ok %  within tol %  ok in silence")
    for name, seed, res in summary:
        print(f"  {name:<10}  {seed:>4}  {100 * res['frac_ok']:>13.1f}  "
              f"{100 * res['frac_good']:>12.1f}  {res['ok_in_silence']:>13}")  # fmt: skip
    for name in cases:
        rows = [r for n, _, r in summary if n == name]
        worst_ok = 100 * min(r["frac_ok"] for r in rows)
        worst_good = 100 * min(np.nan_to_num(r["frac_good"]) for r in rows)
        record(f"{name}: sounding windows ok (worst seed)", worst_ok, "%", target=">= 90")
        record(f"{name}: ok windows within tol. (worst seed)", worst_good, "%", target=">= 90")
        silent = max(r["ok_in_silence"] for r in rows)
        record(f"{name}: ok windows in silence (most)", silent, "", target="<= 0")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=2, help="noise seeds per take (2)")
    ap.add_argument("--first-seed", type=int, default=0, help="first noise seed (0)")
    ap.add_argument("--snr", type=float, default=45.0, help="microphone SNR, dB (45)")
    ap.add_argument(
        "--cases", default=",".join(CASES), help=f"comma-separated, of {', '.join(CASES)}"
    )
    ap.add_argument("--skip-long", action="store_true", help="skip the 20 s swell take")
    ap.add_argument(
        "--long-duration", type=float, default=20.0, help="length of the swell take, s (20)"
    )
    ap.add_argument("--workers", type=int, default=1, help="worker processes of mpipe run (1)")
    ap.add_argument("--keep", metavar="DIR", help="keep the takes and runs in DIR")
    args = ap.parse_args(argv)
    sys.stdout.reconfigure(line_buffering=True)  # each take's table as soon as it is done
    cases = [c for c in args.cases.split(",") if c]
    unknown = set(cases) - set(CASES)
    if unknown:
        ap.error(
            f"--cases: unknown {', '.join(sorted(unknown))}; expected some of {', '.join(CASES)}"
        )
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(args.keep) if args.keep else Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        pipe = pipeline_copy(folder, args.workers)
        summary = []
        for name in cases:
            for seed in range(args.first_seed, args.first_seed + args.seeds):
                files = make(name, folder, seed, args.snr)
                run = run_pipeline(files, pipe, folder / "out")
                take = folder / "out" / files.audio.stem
                res = evaluate(take, np.load(files.truth))
                report(name, seed, res, run, take)
                if run[0] not in (0, 1):
                    print(f"  mpipe run failed: {run[2]}")
                summary.append((name, seed, res))
        summarise(summary, cases, args.snr)
        if not args.skip_long:
            long_take(folder, pipe, args.snr, args.long_duration)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
