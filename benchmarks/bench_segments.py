"""A phrase of three notes: segments, every sounding window inverted, each note its own start.

Run: ``.venv/bin/python benchmarks/bench_segments.py [--seeds 0,1,2] [--workers 2]
[--baseline]`` (about 4 minutes per seed on a loaded 2-core machine).

The take is mpipe's own model (Table 1 reed, shipped bore) played with a mouth pressure of
three notes (1800, 2000, 1700 Pa; 0.4 s each; 20 ms raised-cosine tongued attacks and
releases; 0.25 s silences), with white noise at 45 dB SNR on p and on the zero-mean
(20 Hz high-passed) flow: the mouthpiece path, not the microphones' (the front end is
measured elsewhere; issue 18's bench_playing covers the whole path). For each seed it
prints, against the truth at each window's centre:

- the segments found (start, end) against the notes played;
- the sounding windows (a note's windows after its first 50 ms and before its last 30 ms,
  issue 18) that are ok, and the ok windows where p_m is within 3 % and p_M = k y_m within
  5 %; the ok windows in a silence (must be 0); each note's median p_m;
- with ``--baseline``, the same take with one cold start for the whole take (the windows
  of every note warm from the first note's start), as before segments.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from headline import record  # noqa: E402

NOTES = ((0.4, 1800.0), (0.4, 2000.0), (0.4, 1700.0))
GAP_S, LEAD_S, TONGUE_S = 0.25, 0.1, 0.02


def phrase(fs: float) -> tuple[np.ndarray, list[tuple[float, float]]]:
    """Mouth pressure (Pa) per sample and the (start, end) of each note, s."""
    parts, spans, t = [np.zeros(int(LEAD_S * fs))], [], LEAD_S
    r = int(TONGUE_S * fs)
    ramp = 0.5 * (1 - np.cos(np.pi * np.arange(r) / r))
    for dur, pm in NOTES:
        env = np.ones(int(dur * fs))
        env[:r], env[-r:] = ramp, ramp[::-1]
        parts += [pm * env, np.zeros(int(GAP_S * fs))]
        spans.append((t, t + dur))
        t += dur + GAP_S
    return np.concatenate(parts), spans


def run(seed: int, workers: int, baseline: bool) -> dict:
    from mpipe.core.filters import highpass_zero_phase
    from mpipe.inversion.preparation.conditioning import bore_resonances, plan_take
    from mpipe.inversion.preparation.kernel import bore_kernel
    from mpipe.inversion.settings import ExecutorConfig
    from mpipe.inversion.whole_take.take import WindowPlan, invert_take
    from mpipe.measurement.calibration import load_calibration
    from mpipe.pipeline.settings import load_pipeline
    from mpipe.reed.model import simulate
    from mpipe.reed.parameters import load_reed

    cal = load_calibration(ROOT / "calibration" / "simplified_clarinet.yaml")
    reed = load_reed(ROOT / "calibration" / "reed_table1.yaml")
    pipe = load_pipeline(ROOT / "pipelines" / "simplified_clarinet.yaml")
    fs = pipe.inversion.sample_rate
    kernel, _ = bore_kernel(cal, fs, cal.air.temperature_c)
    mouth, spans = phrase(fs)
    sim = simulate(reed, kernel, mouth.size, mouth_pressure=mouth)
    rng = np.random.default_rng(seed)
    sounding = mouth > 0
    p = sim.p + rng.standard_normal(mouth.size) * np.std(sim.p[sounding]) * 10 ** (-45 / 20)
    u = highpass_zero_phase(sim.u, fs, 20.0)
    u = u + rng.standard_normal(u.size) * np.std(u[sounding]) * 10 ** (-45 / 20)
    plan, segments = plan_take(p, fs, pipe.conditioning, 0.02, 0.02,
                               resonances_hz=bore_resonances(cal))  # fmt: skip
    chosen = plan[plan["invert"]]
    t0 = time.perf_counter()
    done = invert_take(
        p, u, fs, cal, pipe.inversion, ExecutorConfig(workers=workers),
        windows=chosen["start"].tolist() if baseline else WindowPlan.of(chosen),
        temperature_c=None,
    )  # fmt: skip
    wall = time.perf_counter() - t0
    table = done.tracking.table
    mid = ((table["t_start_s"] + table["t_end_s"]) / 2).to_numpy()
    i_mid = np.clip((mid * fs).astype(int), 0, mouth.size - 1)
    pm_true = mouth[i_mid]
    pM_true = reed.k * reed.y_m
    ok = (table["status"] == "ok").to_numpy()
    t0s, t1s = table["t_start_s"].to_numpy(), table["t_end_s"].to_numpy()
    # sounding windows of every note: after its first 50 ms, before its last 30 ms
    n_sound = 0
    sound = np.zeros(len(table), bool)
    for a, b in spans:
        n_sound += len(plan[(plan["t_start_s"] >= a + 0.05) & (plan["t_end_s"] <= b - 0.03)])
        sound |= (t0s >= a + 0.05) & (t1s <= b - 0.03)
    in_silence = ok & (pm_true == 0)
    pm_err = np.abs(table["p_m"].to_numpy() / np.where(pm_true > 0, pm_true, np.nan) - 1)
    pM_err = np.abs(table["k"].to_numpy() * table["y_m"].to_numpy() / pM_true - 1)
    good = ok & (pm_err < 0.03) & (pM_err < 0.05)
    notes = segments[segments["label"] == "note"]
    per_note = [float(table.loc[ok & (t0s >= a) & (t1s <= b), "p_m"].median()) for a, b in spans]
    return {
        "seed": seed, "wall_s": wall, "notes_found": len(notes),
        "boundaries": list(zip(notes["start_s"].round(3), notes["end_s"].round(3), strict=True)),
        "sounding": n_sound, "sounding_ok": int((ok & sound).sum()),
        "ok": int(ok.sum()), "ok_good": int(good.sum()), "ok_in_silence": int(in_silence.sum()),
        "per_note_p_m": per_note, "temperature": done.temperature.line(),
    }  # fmt: skip


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0", help="noise seeds, comma-separated")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--baseline", action="store_true", help="also one cold start per take")
    args = ap.parse_args(argv)
    seeds = [int(s) for s in args.seeds.split(",")]
    print(f"notes played (s): {phrase(100_000.0)[1]}; p_m {[pm for _, pm in NOTES]} Pa")
    print("(times are upper bounds: a loaded 2-core machine)")
    rows = {}
    for way in ("segments", "one start per take") if args.baseline else ("segments",):
        rows[way] = [run(s, args.workers, way != "segments") for s in seeds]
        for r in rows[way]:
            print(f"[{way}] seed {r['seed']}: {r['notes_found']} notes found {r['boundaries']}; "
                  f"sounding windows ok {r['sounding_ok']}/{r['sounding']}; ok windows with "
                  f"p_m within 3 % and p_M within 5 %: {r['ok_good']}/{r['ok']}; ok windows in "
                  f"a silence: {r['ok_in_silence']}; note medians p_m "
                  f"{[round(x) for x in r['per_note_p_m']]} Pa; {r['wall_s']:.0f} s; "
                  f"{r['temperature']}")  # fmt: skip
    seg = rows["segments"]
    frac_ok = sum(r["sounding_ok"] for r in seg) / max(sum(r["sounding"] for r in seg), 1)
    frac_good = sum(r["ok_good"] for r in seg) / max(sum(r["ok"] for r in seg), 1)
    base = rows.get("one start per take")
    base_ok = (
        sum(r["sounding_ok"] for r in base) / max(sum(r["sounding"] for r in base), 1)
        if base
        else None
    )
    print(f"sounding windows ok: {100 * frac_ok:.1f} %" +
          (f" (one start per take: {100 * base_ok:.1f} %)" if base else "")
          + f"; ok windows within 3 % / 5 %: {100 * frac_good:.1f} %; ok windows in silences: "
          f"{sum(r['ok_in_silence'] for r in seg)}")  # fmt: skip
    record("phrase of 3 notes: sounding windows ok", 100 * frac_ok, "%",
           None if base_ok is None else 100 * base_ok, target=">= 90")  # fmt: skip
    record("phrase: ok windows with p_m within 3 %, p_M within 5 %", 100 * frac_good, "%",
           target=">= 90")  # fmt: skip
    record("phrase: ok windows in a silence", sum(r["ok_in_silence"] for r in seg), "",
           target="< 1")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
