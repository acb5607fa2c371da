"""Which of the chain's mouthpiece signals carries a take's systematic error: p, u or neither.

Usage: ``.venv/bin/python benchmarks/true_signals.py [--score crescendo] [--snr 100]
[--seed 0] [--folder DIR] [--workers 1] [--lead-s 0.003,0.01,0.04] [--true-slopes]``

Inverts one of ``bench_estimator.py``'s virtual takes (made or read from ``--folder``) four
ways, each with the take's estimator: the chain's p and u (what ``mpipe run`` inverts);
the truth's p, low-passed as the translation does, in place of the chain's; the truth's u
(low-passed, its mean over the take removed, as the chain's has none) in place of the
chain's; and both. Prints each quantity's median error over the ok windows and over the
take's last 0.25 s. An error the truth's p removes is the pressure's (the mean flow's
Poiseuille drop of the twelfth session was found so), one the truth's u removes the
flow's; one neither removes is the inversion's own. With ``--lead-s``, the chain's signals
again at each reed lead-in length given (``inversion.lead_s``, s); with ``--true-slopes``,
again with each window's mouth-pressure slope the truth's (one worker), which tells an error
of the slopes fitted from the neighbouring windows from one of the model's.
"""

from __future__ import annotations

import argparse
import contextlib
from pathlib import Path

import numpy as np
from bench_estimator import ROOT, front_end, invert, score_path, scores

from mpipe.core.filters import apply_lowpass, design_lowpass
from mpipe.inversion.whole_take import passes
from mpipe.pipeline.settings import load_pipeline

PIPELINE = ROOT / "pipelines" / "simplified_clarinet.yaml"

QUANTITIES = ("p_m", "p_M", "k", "y_m", "S", "lam")
MODES = ("chain", "true p", "true u", "both")


def signals_for(mode: str, signals: dict, truth: dict) -> dict:
    """The take's signals with the truth's p and/or u (low-passed as the chain's) in place."""
    tr = load_pipeline(PIPELINE).translation
    fs = float(signals["fs"])
    lp = design_lowpass(fs, tr.lowpass_hz, tr.transition_hz, tr.stopband_db)
    out = dict(signals)
    if mode in ("true p", "both"):
        out["p"] = apply_lowpass(truth["p"], lp)
    if mode in ("true u", "both"):
        u = apply_lowpass(truth["u"], lp)
        out["u"] = u - u.mean()
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--score", default="crescendo")
    ap.add_argument("--snr", type=float, default=100.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--folder", type=Path, default=ROOT / "benchmarks" / ".cache" / "estimator")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--lead-s", default="", help="lead-in lengths, s, comma-separated")
    ap.add_argument("--true-slopes", action="store_true",
                    help="the chain's signals again, each window's mouth-pressure slope the "
                    "truth's instead of the one fitted from its neighbours")  # fmt: skip
    args = ap.parse_args(argv)
    args.folder.mkdir(parents=True, exist_ok=True)
    signals, truth, cal = front_end(args.seed, args.snr, score_path(args.score), args.folder)
    print(f"{args.score}, {args.snr:g} dB, seed {args.seed}: median error over the ok windows "
          "(over the last 0.25 s)")  # fmt: skip
    for mode in MODES:
        done, _, duration = invert(signals_for(mode, signals, truth), cal, "take", args.workers)
        _line(mode, done, truth, duration)
    for lead in [float(x) for x in args.lead_s.split(",")] if args.lead_s else []:
        done, _, duration = invert(signals, cal, "take", args.workers, lead_s=lead)
        _line(f"lead {1e3 * lead:g} ms", done, truth, duration)
    if args.true_slopes:
        with _truth_slopes(truth):
            done, _, duration = invert(signals, cal, "take", args.workers)
        _line("true ṗ_m", done, truth, duration)
    return 0


@contextlib.contextmanager
def _truth_slopes(truth: dict):
    """The take fit's slopes (``passes.mouth_slopes``) replaced by the truth's dp_m/dt.

    Benchmark-only: the windows' centres are where the truth's control curve is read; one
    worker sees the replacement (the shards of more run in processes of their own, which
    take the fit's own slopes).
    """
    curve = np.asarray(truth["control_p_m"], float)
    t = np.arange(curve.size) / float(truth["control_fs"])
    rate = np.gradient(curve, t)
    kept = passes.mouth_slopes
    passes.mouth_slopes = lambda times, *_a, **_k: np.interp(np.asarray(times), t, rate)
    try:
        yield
    finally:
        passes.mouth_slopes = kept


def _line(label: str, done, truth: dict, duration: float) -> None:
    table = done.tracking.table
    s = scores(table, truth)
    ok = table["status"].eq("ok").to_numpy()
    late = ok & (table["t_start_s"].to_numpy() > duration - 0.25)
    cells = [f"{q} {100 * np.median(s[q]['err'][ok]):+.3f}% "
             f"({100 * np.median(s[q]['err'][late]):+.3f}%)" for q in QUANTITIES]  # fmt: skip
    print(f"{label:9s} T {done.temperature.temperature_c:.3f}  " + "  ".join(cells), flush=True)


if __name__ == "__main__":
    raise SystemExit(main())
