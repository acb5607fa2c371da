"""An independent-simulator suite (issue 34): OpenWInD plays three geometries, mpipe reads them.

Usage: ``.venv/bin/python benchmarks/bench_foreign.py [--quick] [--geometries a,b]
[--playings a,b] [--snrs clean,60,45] [--rates own,default] [--jobs N] [--workers N]
[--cache DIR] [--keep DIR] [--json FILE]``

OpenWInD (pip ``openwind``, GPL-3, benchmark-only; ``make bench`` installs it into .venv)
plays, with its one-degree-of-freedom reed mapped from the paper's Table 1 reed as
``bench_openwind.py`` maps it (scaled a little per geometry), three bores that mpipe has
never been shown (``foreign_sim.py`` describes them and writes the matching calibration
files): a cylinder of another length and radius with another mouthpiece section, a bore whose
lower half is a cone widening to 20 mm, and a holed tube played with two of its three holes
open. Each plays a crescendo, a 5 Hz vibrato, two tongued notes and a diminuendo to near the
oscillation threshold (about 1.2-1.3 s each). The simulation is cached (``--cache``, default
``benchmarks/.cache/foreign/``); each is recorded at 48 kHz (resampled from the simulation
rate), clean and with white noise at 60 and 45 dB SNR per channel, written as mpipe's
virtual takes are (``mpipe.reed.take_files``) and run through ``mpipe run`` in a subprocess
with the shipped pipeline, at the take's own rate (``inversion.sample_rate`` = 48 kHz:
``own``) and at mpipe's default rate (``default``).

Per take it prints: the sounding windows (of the pipeline's grid, inside a note after its
first 50 ms and before its last 30 ms, notes trimmed to where the oscillation is at least a
tenth of its loud level), the ok ones; of the ok windows in notes, the fraction with p_m and
p_M within 2 reported SE (``p_m_se``, ``p_M_se``; over the windows whose SE is finite), the
median relative p_m SE, the count without a finite p_m SE, the median and worst |error| of
p_m and p_M; per note (the per-note table, :func:`note_columns`), p_m and p_M within 2 of
their per-note SE; the take's verdict (``report.html``) and the exit status; the wall time of
``mpipe run`` and of its inversion stage. Then the issue's targets, met or missed, the
model-form figures (relative residual of ok windows; errors of p_m, p_M, k, y_m, S, lambda of
ok windows on clean takes against the truth), and the inversion time of the foreign crescendo
against an own virtual take of the same length (``mpipe synth-take``, shipped calibration).
``--json FILE`` saves all of it. Timings on a loaded 2-core machine are upper bounds.
"""

from __future__ import annotations

import argparse
import html
import json
import re
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor, as_completed
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
import foreign_sim as fsim  # noqa: E402
from bench_playing import grid, inside, truth_over  # noqa: E402
from headline import record  # noqa: E402

from mpipe.inversion.table.records import read_windows  # noqa: E402

CAL = ROOT / "calibration" / "simplified_clarinet.yaml"
REED = ROOT / "calibration" / "reed_table1.yaml"
PIPELINE = ROOT / "pipelines" / "simplified_clarinet.yaml"
CACHE = HERE / ".cache" / "foreign"
RECORD_FS = 48_000.0
SNRS = {"clean": None, "60": 60.0, "45": 45.0}
#: Files that may hold the per-note table, first found wins (inversion/ of a take).
NOTE_FILES = ("note_budget.csv", "notes.csv", "segments.csv")
#: Parameters whose clean-take errors measure the model-form floor (truth key in the reed).
FORM = (("p_m", None), ("p_M", None), ("k", "k"), ("y_m", "y_m"), ("S", "S"), ("lam", "lam"))


def note_columns(table: pd.DataFrame, name: str) -> tuple[str | None, str | None]:
    """(value column, SE column) of ``name`` in the per-note table; None where absent.

    Accepts today's ``<p>_median`` / ``<p>_median_se`` and the names a note budget may use.
    """
    values = (f"{name}_note", f"{name}_median", f"{name}_value", name)
    ses = (f"{name}_note_se", f"{name}_combined_se", f"{name}_median_se", f"{name}_se")
    value = next((c for c in values if c in table), None)
    se = next((c for c in ses if c in table), None)
    return value, se


def note_table(take: Path) -> pd.DataFrame | None:
    for name in NOTE_FILES:
        path = take / "inversion" / name
        if path.exists():
            return pd.read_csv(path)
    return None


def verdict(take: Path) -> str:
    """The take's verdict line from its report (PASS / CHECK / FAIL), or "?"."""
    path = take / "report.html"
    if not path.exists():
        return "?"
    m = re.search(r"\b(PASS|CHECK|FAIL)(:[^<]{0,160})?", path.read_text(errors="replace"))
    return html.unescape(m.group(0).strip()) if m else "?"


def stage_wall(take: Path, stage: str) -> float:
    path = take / stage / "manifest.json"
    if not path.exists():
        return float("nan")
    return float(json.loads(path.read_text()).get("wall_s", float("nan")))


def pipeline_file(folder: Path, cal: Path, rate: float | None, workers: int, tag: str) -> Path:
    """The shipped pipeline on ``cal`` with ``workers`` and the inversion's rate (None: default)."""
    data = yaml.safe_load(PIPELINE.read_text())
    data["calibration"] = str(cal)
    data.setdefault("executor", {})["workers"] = workers
    if rate is not None:
        data.setdefault("inversion", {})["sample_rate"] = float(rate)
    path = folder / f"pipeline_{tag}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def run_mpipe(pipe: Path, files, out: Path, reuse: bool = False) -> dict:
    """``mpipe run`` on one take (or, with ``reuse``, the run already in ``out``)."""
    take = out / files.audio.stem
    saved = take / "bench_run.json"
    if reuse and saved.exists():
        return {**json.loads(saved.read_text()), "take": take, "reused": True}
    cmd = [sys.executable, "-m", "mpipe.cli.main", "run", str(pipe), str(files.audio),
           "--calibration", str(files.calibration), "-o", str(out), "--force",
           "--accept-failed-validation"]  # fmt: skip
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    tail = "\n".join((proc.stdout + proc.stderr).strip().splitlines()[-4:])
    run = {"exit": proc.returncode, "wall_s": time.perf_counter() - t0, "tail": tail,
           "inversion_s": stage_wall(take, "inversion")}  # fmt: skip
    if take.exists():
        saved.write_text(json.dumps(run))
    return {**run, "take": take}


def _frac(mask) -> float:
    mask = np.asarray(mask, dtype=bool)
    return float(mask.mean()) if mask.size else float("nan")


def window_figures(take: Path, truth) -> tuple[dict, pd.DataFrame]:
    """Sounding / ok windows, 2-SE coverage, SEs and errors of the ok windows in notes."""
    path = take / "inversion" / "windows.csv"
    if not path.exists():
        return {"sounding": 0, "ok_sounding": 0, "frac_ok": float("nan")}, pd.DataFrame()
    win = read_windows(path)
    notes = list(zip(truth["note_start_s"], truth["note_end_s"], strict=True))
    spans = list(zip(truth["planned_note_start_s"], truth["planned_note_end_s"], strict=True))
    spans += list(zip(truth["tongue_start_s"], truth["tongue_end_s"], strict=True))
    cells = grid(take, win)
    sounding = sum(int(inside(cells, a, b).sum()) for a, b in notes)
    ok = win["status"].astype(str) == "ok"
    in_sounding = np.zeros(len(win), dtype=bool)
    for a, b in notes:
        in_sounding |= inside(win, a, b).to_numpy()
    centre = 0.5 * (win["t_start_s"] + win["t_end_s"])
    in_note = np.zeros(len(win), dtype=bool)
    for a, b in spans:
        in_note |= ((centre >= a) & (centre <= b)).to_numpy()
    okw = win[ok.to_numpy() & in_note].copy()
    span = list(zip(okw["t_start_s"], okw["t_end_s"], strict=True))
    okw["p_m_true"] = [truth_over(truth, "control_p_m", a, b) for a, b in span]
    okw["p_M_true"] = [truth_over(truth, "control_p_M", a, b) for a, b in span]
    for name, key in FORM[2:]:
        okw[f"{name}_true"] = float(truth[f"reed_{'lambda' if key == 'lam' else key}"])
    res = {"sounding": sounding, "ok_sounding": int((ok.to_numpy() & in_sounding).sum()),
           "n_ok": len(okw), "statuses": win["status"].value_counts().to_dict()}  # fmt: skip
    res["frac_ok"] = res["ok_sounding"] / sounding if sounding else float("nan")
    snd = win[ok.to_numpy() & in_sounding]
    snd_true = [truth_over(truth, "control_p_M", a, b)
                for a, b in zip(snd["t_start_s"], snd["t_end_s"], strict=True)]  # fmt: skip
    near = np.abs(snd["p_M"].to_numpy(float) / np.asarray(snd_true, dtype=float) - 1) <= 0.05
    res["p_M_5pc"] = int(near.sum()) / sounding if sounding else float("nan")
    for name in ("p_m", "p_M"):
        err = (okw[name] - okw[f"{name}_true"]).to_numpy(float)
        se = okw[f"{name}_se"].to_numpy(float) if f"{name}_se" in okw else np.full(len(okw), np.nan)
        finite = np.isfinite(se)
        res[f"{name}_cover"] = _frac(np.abs(err[finite]) <= 2 * se[finite])
        res[f"{name}_no_se"] = int((~finite).sum())
        rel = np.abs(err / okw[f"{name}_true"].to_numpy(float))
        res[f"{name}_err_med"] = float(np.median(rel)) if rel.size else float("nan")
        res[f"{name}_err_max"] = float(np.max(rel)) if rel.size else float("nan")
    rse = (okw["p_m_se"] / okw["p_m"]).to_numpy(float) if len(okw) else np.zeros(0)
    rse = rse[np.isfinite(rse)]
    res["p_m_rel_se_med"] = float(np.median(rse)) if rse.size else float("nan")
    rr = okw["relative_residual"].to_numpy(float) if len(okw) else np.zeros(0)
    res["resid_med"] = float(np.median(rr)) if rr.size else float("nan")
    res["resid_p90"] = float(np.percentile(rr, 90)) if rr.size else float("nan")
    noise_cols = [c for c in okw.columns if "noise" in c and okw[c].dtype.kind == "f"]
    res["noise_columns"] = {c: float(okw[c].median()) for c in noise_cols}
    return res, okw


def note_figures(take: Path, okw: pd.DataFrame) -> dict:
    """Per note: p_m and p_M of the per-note table within 2 of its SE of the truth.

    The truth of a note is the median, over the note's ok windows, of the truth averaged
    over each window (the note's value is a median over the same windows).
    """
    table = note_table(take)
    out = {"pairs": 0, "within": 0, "no_se": 0, "columns": {}}
    if table is None or okw.empty or "segment" not in okw or "segment" not in table:
        return out
    for name in ("p_m", "p_M"):
        vcol, scol = note_columns(table, name)
        out["columns"][name] = [vcol, scol]
        if vcol is None or scol is None:
            continue
        for _, row in table.iterrows():
            mine = okw[okw["segment"] == row["segment"]]
            if mine.empty:
                continue
            value, se = float(row[vcol]), float(row[scol])
            true = float(np.median(mine[f"{name}_true"]))
            out["pairs"] += 1
            if not np.isfinite(se):
                out["no_se"] += 1
            elif abs(value - true) <= 2 * se:
                out["within"] += 1
    out["frac"] = out["within"] / out["pairs"] if out["pairs"] else float("nan")
    return out


def print_row(row: dict) -> None:
    w, n = row["windows"], row["notes"]
    pct = 100 * np.nan_to_num(w.get("frac_ok", np.nan), nan=0.0)
    print(f"{row['geometry']:<8} {row['playing']:<10} {row['snr']:>5} {row['rate']:<7} "
          f"{w['sounding']:>4} {w['ok_sounding']:>4} {pct:6.1f} "
          f"{100 * w.get('p_m_cover', np.nan):6.1f} {100 * w.get('p_M_cover', np.nan):6.1f} "
          f"{100 * w.get('p_m_rel_se_med', np.nan):7.3f} "
          f"{n['within']:>3}/{n['pairs']:<3} {w.get('p_m_no_se', 0):>3}/{w.get('p_M_no_se', 0):<3} "
          f"{100 * w.get('p_m_err_med', np.nan):6.2f} {100 * w.get('p_m_err_max', np.nan):6.2f} "
          f"{100 * w.get('p_M_err_med', np.nan):6.2f} {100 * w.get('p_M_err_max', np.nan):6.2f} "
          f"{100 * w.get('resid_med', np.nan):6.3f} {100 * w.get('resid_p90', np.nan):6.3f} "
          f"{row['exit']:>2} {row['wall_s']:5.0f} {row['inversion_s']:5.1f}  {row['verdict'][:60]}",
          flush=True)  # fmt: skip
    statuses = ", ".join(f"{k} {v}" for k, v in w.get("statuses", {}).items())
    print(f"{'':<33}statuses: {statuses}")


HEADER = (
    "geometry playing     snr rate    snd   ok  ok%   pm2SE  pM2SE pmSE%  note2SE noSE "
    "pm|e|% pmmax% pM|e|% pMmax% rres% rr90%  ex  wall  inv  verdict"
)
LEGEND = """columns: snd sounding windows; ok of them ok; ok% (target >= 85); pm2SE, pM2SE: % of ok
windows (finite SE) with p_m, p_M within 2 SE of the truth (target 90-99); pmSE%: median p_m SE
of ok windows, % of p_m (target <= 1 on clean and 60 dB); note2SE: (note, p_m/p_M) pairs within
2 per-note SE (target >= 90 %); noSE: ok windows without a finite p_m SE (target 0), p_M SE; pm|e|%,
pmmax%, pM|e|%, pMmax%: median and worst |error| of ok windows, %; rres%, rr90%: median and
90th percentile of the ok windows' relative residual, %; ex: exit status of mpipe run; wall:
its wall time, s; inv: its inversion stage, s; verdict: the report's."""


def targets(rows: list[dict]) -> list[tuple[str, str, bool]]:
    """The issue's targets over the takes: (target, measured, met)."""
    done = [r for r in rows if r["windows"]["sounding"]]
    if not done:
        return []
    W = [r["windows"] for r in done]  # noqa: N806
    worst_ok = min(np.nan_to_num(w["frac_ok"], nan=0.0) for w in W)
    out = [(">= 85 % of sounding windows ok in every take", f"worst {100 * worst_ok:.1f} %",
            worst_ok >= 0.85)]  # fmt: skip
    for name in ("p_m", "p_M"):
        cov = [w.get(f"{name}_cover", np.nan) for w in W]
        lo, hi = np.nanmin(cov) if np.any(np.isfinite(cov)) else np.nan, np.nanmax(cov)
        n_in = sum(0.90 <= c <= 0.99 for c in cov if np.isfinite(c))
        out.append((f"{name} within 2 SE in 90-99 % of ok windows, every take",
                    f"{100 * lo:.1f}-{100 * hi:.1f} %, {n_in}/{len(cov)} takes in range",
                    n_in == len(cov)))  # fmt: skip
    quiet = [w.get("p_m_rel_se_med", np.nan) for r, w in zip(done, W, strict=True)
             if r["snr"] in ("clean", "60")]  # fmt: skip
    if quiet:
        worst = np.nanmax(quiet) if np.any(np.isfinite(quiet)) else np.nan
        out.append(("median p_m SE of ok windows <= 1 % (clean, 60 dB)",
                    f"worst {100 * worst:.3f} %", bool(worst <= 0.01)))  # fmt: skip
    pairs = sum(r["notes"]["pairs"] for r in done)
    within = sum(r["notes"]["within"] for r in done)
    frac = within / pairs if pairs else float("nan")
    out.append(("per-note p_m, p_M within 2 SE >= 90 %", f"{within}/{pairs} = {100 * frac:.1f} %",
                bool(frac >= 0.90)))  # fmt: skip
    no_se = sum(w.get("p_m_no_se", 0) for w in W)
    out.append(("0 ok windows without a finite p_m SE", f"{no_se}", no_se == 0))
    near = [np.nan_to_num(w.get("p_M_5pc", np.nan), nan=0.0) for w in W]
    out.append(("issue 45: >= 80 % of sounding windows ok with p_M within 5 %, every take",
                f"worst {100 * min(near):.1f} %", min(near) >= 0.80))  # fmt: skip
    passed = sum(r["verdict"].startswith("PASS") for r in done)
    out.append(("issue 45: every take PASS (no false CHECK or FAIL)",
                f"{passed}/{len(done)} PASS", passed == len(done)))  # fmt: skip
    return out


def model_form(rows: list[dict], frames: dict) -> dict:
    """Relative errors of the clean takes' ok windows against the truth, per rate."""
    out = {}
    for rate in sorted({r["rate"] for r in rows}):
        keys = [k for k in frames if k[2] == "clean" and k[3] == rate]
        if not keys:
            continue
        pooled = pd.concat([frames[k] for k in keys], ignore_index=True)
        per = {}
        for name, _ in FORM:
            if pooled.empty or name not in pooled:
                continue
            rel = np.abs(pooled[name] / pooled[f"{name}_true"] - 1).to_numpy(float)
            rel = rel[np.isfinite(rel)]
            if rel.size:
                per[name] = {"median": float(np.median(rel)), "p90": float(np.percentile(rel, 90))}
        rr = pooled["relative_residual"].to_numpy(float) if not pooled.empty else np.zeros(0)
        out[rate] = {"windows": len(pooled), "errors": per, "residual_median":
                     float(np.median(rr)) if rr.size else float("nan"), "residual_p90":
                     float(np.percentile(rr, 90)) if rr.size else float("nan")}  # fmt: skip
    return out


def own_take(folder: Path, duration: float, snr: float, rates, workers: int, reuse: bool) -> dict:
    """The inversion time of an own virtual crescendo of ``duration`` s (shipped bore)."""
    stem = folder / "own_crescendo.flac"
    from mpipe.reed.take_files import take_file_paths

    files = take_file_paths(stem)
    if reuse:
        return {
            lb: run_mpipe(None, files, folder / f"out_own_{lb}", True)
            for lb, _ in rates
            if (folder / f"out_own_{lb}" / stem.stem / "bench_run.json").exists()
        }
    cmd = [sys.executable, "-m", "mpipe.cli.main", "synth-take", str(CAL), "--reed", str(REED),
           "--duration", str(duration), "--swell", "0.45", "--snr", str(snr), "--fs-out",
           str(int(RECORD_FS)), "-o", str(stem), "--force"]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        print(f"own take: synth-take failed: {proc.stderr[-500:]}")
        return {}
    out = {}
    for label, rate in rates:
        pipe = pipeline_file(folder, files.calibration, rate, workers, f"own_{label}")
        out[label] = run_mpipe(pipe, files, folder / f"out_own_{label}", reuse)
    return out


def parse(argv):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--geometries", default=",".join(fsim.GEOMETRIES))
    ap.add_argument("--playings", default=",".join(fsim.PLAYINGS))
    ap.add_argument("--snrs", default="clean,60,45", help="of clean, 60, 45 (clean,60,45)")
    ap.add_argument(
        "--rates",
        default="own,default",
        help="own: the take's 48 kHz; default: mpipe's default (own,default)",
    )
    ap.add_argument(
        "--quick", action="store_true", help="cylinder, crescendo and tongued, 45 dB, own rate"
    )
    ap.add_argument("--jobs", type=int, default=1, help="takes run at once (1)")
    ap.add_argument("--workers", type=int, default=2, help="workers of each mpipe run (2)")
    ap.add_argument("--cache", default=str(CACHE), help="OpenWInD simulations (%(default)s)")
    ap.add_argument("--keep", metavar="DIR", help="keep takes and runs in DIR")
    ap.add_argument("--json", metavar="FILE", help="save every figure as JSON")
    ap.add_argument("--no-own", action="store_true", help="skip the own take's timing")
    ap.add_argument(
        "--reuse",
        action="store_true",
        help="with --keep: score the runs already in DIR instead of running them",
    )
    args = ap.parse_args(argv)
    if args.reuse and not args.keep:
        ap.error("--reuse needs --keep DIR (the folder of the earlier runs)")
    if args.quick:
        args.geometries, args.playings, args.snrs, args.rates = (
            "cylinder", "crescendo,tongued", "45", "own")  # fmt: skip
    pick = {"geometries": fsim.GEOMETRIES, "playings": fsim.PLAYINGS, "snrs": SNRS,
            "rates": {"own": 0, "default": 0}}  # fmt: skip
    for key, known in pick.items():
        values = [v for v in getattr(args, key).split(",") if v]
        bad = [v for v in values if v not in known]
        if bad or not values:
            ap.error(
                f"--{key}: unknown {', '.join(bad) or '(none)'}; expected of {', '.join(known)}"
            )
        setattr(args, key, values)
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse(argv)
    sys.stdout.reconfigure(line_buffering=True)
    try:
        import openwind  # noqa: F401
    except ImportError:
        print("bench_foreign: skipped: OpenWInD is not installed (`make bench` installs it; "
              "GPL-3, used by the benchmarks only)")  # fmt: skip
        return 0
    t_start = time.perf_counter()
    cache = Path(args.cache)
    geos = [fsim.GEOMETRIES[g] for g in args.geometries]
    plays = [fsim.PLAYINGS[p] for p in args.playings]
    reeds = {g.name: fsim.reed_for(g, REED) for g in geos}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(args.keep) if args.keep else Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        cals = {g.name: fsim.write_calibration(g, folder) for g in geos}
        for g in geos:  # the calibration must hold OpenWInD's bore before mpipe is judged
            df, dl = fsim.impedance_check(g, cals[g.name])
            print(f"{g.name}: {g.label}; reed {reeds[g.name].k:.4g} Pa/m, y_m "
                  f"{reeds[g.name].y_m:.4g} m; calibration against OpenWInD's impedance: "
                  f"worst resonance {df:.3f} %, peak level {dl:.2f} dB")  # fmt: skip
        sims = simulate_all(geos, plays, reeds, cache, args.jobs, args.reuse)
        rates = [(r, RECORD_FS if r == "own" else None) for r in args.rates]
        specs = []
        for g in geos:
            for p in plays:
                if (g.name, p.name) not in sims:  # --reuse: not simulated
                    continue
                for snr in args.snrs:
                    stem = f"{g.name}_{p.name}_{snr}"
                    seed = int(sims[g.name, p.name].stem[-6:], 16) + len(snr)
                    files = fsim.write_take(sims[g.name, p.name], folder, stem, g, p,
                                            reeds[g.name], SNRS[snr], RECORD_FS, seed,
                                            cals[g.name])  # fmt: skip
                    specs += [(g.name, p.name, snr, label, rate, files) for label, rate in rates]
        print(f"\n{len(specs)} runs of mpipe run ({args.jobs} at once, {args.workers} workers "
              f"each); takes recorded at {RECORD_FS:g} Hz\n{HEADER}")  # fmt: skip
        rows, frames = run_all_takes(specs, folder, args)
        print(LEGEND)
        summary = targets(rows)
        print("\nissue 34's targets (independent-simulator suite):")
        for name, value, ok in summary:
            print(f"  {'met   ' if ok else 'MISSED'}  {name}: {value}")
        form = model_form(rows, frames)
        print_form(rows, form)
        timing = {}
        if not args.no_own and "crescendo" in args.playings:
            timing = own_timing(rows, folder, rates, args.workers, args.reuse)
        elapsed = time.perf_counter() - t_start
        print(f"\nelapsed {elapsed:.0f} s")
        headline(rows, summary, timing)
        if args.json:
            save_json(args, rows, summary, form, timing, elapsed)
    return 0


def simulate_all(geos, plays, reeds, cache: Path, jobs: int, only_cached: bool = False) -> dict:
    """The cached simulation of each geometry and playing, run where missing (or left out)."""
    todo = [(g, p) for g in geos for p in plays]
    out = {}
    t0 = time.perf_counter()
    if only_cached:
        todo = [(g, p) for g, p in todo if fsim.cached(g, p, reeds[g.name], RECORD_FS, cache)]
    with ProcessPoolExecutor(max(1, jobs)) as pool:
        futs = {pool.submit(fsim.simulate, g, p, reeds[g.name], RECORD_FS, cache): (g, p)
                for g, p in todo}  # fmt: skip
        for fut in as_completed(futs):
            g, p = futs[fut]
            path = fut.result()
            sim = np.load(path)
            out[g.name, p.name] = path
            print(f"OpenWInD {g.name}/{p.name}: {path.name} ({float(sim['fs_sim']):g} Hz, "
                  f"{float(sim['sim_seconds']):.0f} s when simulated)")  # fmt: skip
    print(f"simulations ready in {time.perf_counter() - t0:.0f} s (cache {cache})")
    return out


def run_one(spec, folder: Path, workers: int, reuse: bool):
    g, p, snr, label, rate, files = spec
    if reuse and not (folder / f"out_{label}" / files.audio.stem / "bench_run.json").exists():
        return None, None
    pipe = pipeline_file(folder, files.calibration, rate, workers, f"{files.audio.stem}_{label}")
    run = run_mpipe(pipe, files, folder / f"out_{label}", reuse)
    truth = np.load(files.truth)
    win, okw = window_figures(run["take"], truth)
    notes = note_figures(run["take"], okw)
    row = {"geometry": g, "playing": p, "snr": snr, "rate": label, "windows": win,
           "notes": notes, "exit": run["exit"], "wall_s": run["wall_s"],
           "inversion_s": run["inversion_s"], "verdict": verdict(run["take"])}  # fmt: skip
    if run["exit"] not in (0, 1):
        row["tail"] = run["tail"]
    return row, okw


def run_all_takes(specs, folder: Path, args):
    rows, frames = [], {}
    with ThreadPoolExecutor(max(1, args.jobs)) as pool:
        futs = {pool.submit(run_one, s, folder, args.workers, args.reuse): s for s in specs}
        for fut in as_completed(futs):
            row, okw = fut.result()
            if row is None:  # --reuse: not run in the kept folder
                continue
            rows.append(row)
            frames[row["geometry"], row["playing"], row["snr"], row["rate"]] = okw
            print_row(row)
            if "tail" in row:
                print(f"    mpipe run failed: {row['tail']}")
    order = {k: i for i, k in enumerate((s[0], s[1], s[2], s[3]) for s in specs)}
    rows.sort(key=lambda r: order[r["geometry"], r["playing"], r["snr"], r["rate"]])
    return rows, frames


def print_form(rows, form: dict) -> None:
    print("\nmodel form: relative residual of ok windows (median / 90th percentile, %), per take")
    for r in rows:
        w = r["windows"]
        extra = ", ".join(f"{k} {v:.4g}" for k, v in w.get("noise_columns", {}).items())
        print(f"  {r['geometry']:<8} {r['playing']:<10} {r['snr']:>5} {r['rate']:<7} "
              f"{100 * w.get('resid_med', np.nan):7.3f} {100 * w.get('resid_p90', np.nan):7.3f}"
              f"{'  noise: ' + extra if extra else ''}")  # fmt: skip
    print(
        "model form: clean takes, ok windows pooled, |relative error| against the truth "
        "(median / 90th percentile, %)"
    )
    for rate, f in form.items():
        parts = [
            f"{n} {100 * v['median']:.2f}/{100 * v['p90']:.2f}" for n, v in f["errors"].items()
        ]
        print(f"  rate {rate} ({f['windows']} windows; residual {100 * f['residual_median']:.3f}/"
              f"{100 * f['residual_p90']:.3f} %): " + ", ".join(parts))  # fmt: skip


def own_timing(rows, folder: Path, rates, workers: int, reuse: bool) -> dict:
    """Inversion time of every foreign crescendo against an own 45 dB one, per rate."""
    mine = [r for r in rows if r["playing"] == "crescendo"]
    if not mine:
        return {}
    duration = fsim.PLAYINGS["crescendo"].duration
    own = own_take(folder, duration, 45.0, rates, workers, reuse)
    out = {}
    print(f"\ninversion stage time of each foreign crescendo against an own virtual crescendo "
          f"of {duration:g} s (shipped bore, +45 %, 45 dB), s (runs made at different times "
          "on a shared machine compare their loads too):")  # fmt: skip
    for label, _ in rates:
        foreign = {f"{r['geometry']} {r['snr']}": r["inversion_s"] for r in mine
                   if r["rate"] == label}  # fmt: skip
        if label not in own or not foreign:
            continue
        ratio = float(np.median(list(foreign.values()))) / own[label]["inversion_s"]
        out[label] = {"foreign_s": foreign, "own_s": own[label]["inversion_s"], "ratio": ratio}
        print(f"  rate {label}: foreign " + ", ".join(f"{k} {v:.1f}" for k, v in foreign.items())
              + f"; own {own[label]['inversion_s']:.1f}; median ratio {ratio:.2f} "
              "(target <= 1)")  # fmt: skip
    return out


def headline(rows, summary, timing) -> None:
    W = [r["windows"] for r in rows if r["windows"]["sounding"]]  # noqa: N806
    if not W:
        return
    record("foreign: sounding windows ok (worst take)",
           100 * min(np.nan_to_num(w["frac_ok"]) for w in W), "%", target=">= 85")  # fmt: skip
    for name in ("p_m", "p_M"):
        cov = [w.get(f"{name}_cover", np.nan) for w in W]
        record(f"foreign: {name} within 2 SE (worst take)", 100 * np.nan_to_num(np.nanmin(cov)),
               "%", target=">= 90")  # fmt: skip
    pairs = sum(r["notes"]["pairs"] for r in rows)
    if pairs:
        record(
            "foreign: per-note p_m, p_M within 2 SE",
            100 * sum(r["notes"]["within"] for r in rows) / pairs,
            "%",
            target=">= 90",
        )
    record("foreign: ok windows without finite p_m SE", sum(w.get("p_m_no_se", 0) for w in W), "",
           target="<= 0")  # fmt: skip
    for label, t in timing.items():
        record(f"foreign: crescendo inversion / own take ({label} rate)", t["ratio"], "",
               target="<= 1")  # fmt: skip


def save_json(args, rows, summary, form, timing, elapsed) -> None:
    def clean(x):
        if isinstance(x, dict):
            return {str(k): clean(v) for k, v in x.items()}
        if isinstance(x, list | tuple):
            return [clean(v) for v in x]
        if isinstance(x, np.generic):
            x = x.item()
        if isinstance(x, float) and not np.isfinite(x):
            return None
        return x

    data = {"command": " ".join(sys.argv), "elapsed_s": elapsed, "record_fs": RECORD_FS,
            "geometries": {g: fsim.GEOMETRIES[g].label for g in args.geometries},
            "playings": {p: fsim.PLAYINGS[p].label for p in args.playings},
            "takes": rows, "targets": [{"target": a, "measured": b, "met": c}
                                       for a, b, c in summary],
            "model_form": form, "timing": timing}  # fmt: skip
    Path(args.json).write_text(json.dumps(clean(data), indent=1))
    print(f"figures saved to {args.json}")


if __name__ == "__main__":
    raise SystemExit(main())
