"""The take fit's noise error bars where the noise is the only error, against its effect.

Usage: ``.venv/bin/python benchmarks/bench_noise_scores.py [--seeds 0,1,2,3,4]
[--score crescendo] [--snr 45]``

Each seed's take (``bench_estimator.py``'s virtual takes, cached there) is separated with
theta held at the truth (the take's air, eta 1, no Mach number, no position error), so the
front end adds no error of its own and the estimates move by the microphones' noise alone
(and the model's own bias). The take is fitted twice by ``estimator: take``: with the noise
gram drawn from the front end's mouthpiece noise (``history_noise``, what ``mpipe run``
does) and with the gram of each window's between-harmonics residual (the baseline, what the
signals without noise spectra get). Printed per meat: the temperature's error, scatter and
SE; for k, S and lambda their errors against the noise and temperature components (RMS z),
and for p_m and y_m per window the same with the model-form component. RMS z near 1: the
noise error bars are honest.
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
from bench_estimator import PIPELINE, TRUTH, front_end, score_path
from bench_estimator import ROOT as BENCH_ROOT
from headline import record

from mpipe.inversion.preparation.conditioning import plan_inversion
from mpipe.inversion.settings import ExecutorConfig
from mpipe.inversion.whole_take.front_end import FrontEnd, MouthpieceNoise
from mpipe.inversion.whole_take.take import invert_take
from mpipe.measurement.calibration import load_calibration
from mpipe.measurement.separation.stage import separate
from mpipe.measurement.takes import read_take
from mpipe.measurement.translation import mouthpiece_noise, translate
from mpipe.pipeline.settings import load_pipeline

CACHE = BENCH_ROOT / "benchmarks" / ".cache" / "estimator"


def held_signals(stem, pipe):
    """The take separated with theta at the truth: signals, truth, calibration, noise."""
    cal = load_calibration(stem.with_suffix(".calibration.yaml"))
    truth = dict(np.load(stem.with_suffix(".truth.npz")))
    take = read_take(stem.with_suffix(".flac"), cal, fs=pipe.inversion.sample_rate)
    t_true = float(np.mean(truth["temperature_c"]))
    cfg = dataclasses.replace(pipe.separation, adaptive=False, temperature_c=t_true,
                              mach=float(truth["mach"]), loss_scale=1.0)  # fmt: skip
    sep = separate(take.pressures, take.fs, cal, cfg, take.band_limit_hz)
    tr = translate(sep.p0, sep.u0, take.fs, cal, pipe.translation, sep.temperature_track())
    noise = mouthpiece_noise(take.fs, cal, sep.noise_psd, sep.median_theta(), t_true, cfg,
                             pipe.translation)  # fmt: skip
    return tr, take.fs, truth, cal, MouthpieceNoise.of(noise)


def fit(tr, fs, cal, pipe, noise):
    """The take fit (``estimator: take``) with ``noise`` (None: the residual's gram)."""
    level = np.array([float(np.median(tr.temperature_c)), 1.0, 0.0, 0.0])
    front = FrontEnd(tr.p0, tr.u0, tr.temperature_c, level, np.zeros(4), 5e3, pipe.translation,
                     None, noise)  # fmt: skip
    plan = plan_inversion(tr.p, fs, pipe.conditioning, pipe.inversion.window_s,
                          pipe.inversion.hop_s)  # fmt: skip
    config = dataclasses.replace(pipe.inversion, estimator="take")
    return invert_take(tr.p, tr.u, fs, cal, config, ExecutorConfig(workers=1), windows=plan,
                       temperature_c=tr.temperature_c, front_end=front)  # fmt: skip


def figures(done, truth) -> dict:
    """Errors and noise SEs of one fit: T, the note constants, p_m and y_m per window."""
    t = done.tracking.table
    ok = t[t["status"] == "ok"]
    out = {"T": done.temperature.temperature_c - float(np.mean(truth["temperature_c"])),
           "T_se": done.temperature.se_c}  # fmt: skip
    times = ok["t_start_s"].to_numpy() + 0.5 * (ok["t_end_s"] - ok["t_start_s"]).to_numpy()
    for q in ("k", "S", "lam", "p_m", "y_m"):
        curve = truth[f"control_{TRUTH.get(q, q)}"]
        true = np.interp(times, np.arange(curve.size) / float(truth["control_fs"]), curve)
        parts = ("noise", "temperature") + (("model",) if q in ("p_m", "y_m") else ())
        se = np.sqrt(sum(ok[f"{q}_se_{c}"].to_numpy() ** 2 for c in parts))
        z = (ok[q].to_numpy() - true) / se
        out[q] = z if q in ("p_m", "y_m") else z[len(z) // 2 : len(z) // 2 + 1]
        out[q + "_err"] = float(np.median(ok[q].to_numpy() / true - 1))
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0,1,2,3,4")
    parser.add_argument("--score", default="crescendo")
    parser.add_argument("--snr", type=float, default=45.0)
    args = parser.parse_args(argv)
    pipe = load_pipeline(PIPELINE)
    CACHE.mkdir(parents=True, exist_ok=True)
    runs = {"drawn": [], "residual": []}
    for seed in (int(s) for s in args.seeds.split(",")):
        stem = CACHE / f"{score_path(args.score).stem}_{args.snr:g}dB_seed{seed}"
        if not stem.with_suffix(".flac").exists():  # bench_estimator's take, made once
            front_end(seed, args.snr, score_path(args.score), CACHE)
        tr, fs, truth, cal, noise = held_signals(stem, pipe)
        for meat, given in (("drawn", noise), ("residual", None)):
            f = figures(fit(tr, fs, cal, pipe, given), truth)
            runs[meat].append(f)
            print(
                f"seed {seed} {meat:8s}: T err {f['T']:+.3f} SE {f['T_se']:.3f} degC; "
                f"k {100 * f['k_err']:+.2f} %, S {100 * f['S_err']:+.2f} %",
                flush=True,
            )
    print(f"\n{len(runs['drawn'])} takes ({args.score}, {args.snr:g} dB), theta held at the truth")
    for meat, rows in runs.items():
        t = np.array([r["T"] for r in rows])
        se = np.median([r["T_se"] for r in rows])
        cells = []
        for q in ("k", "S", "lam", "p_m", "y_m"):
            z = np.concatenate([r[q] for r in rows])
            value = float(np.sqrt(np.mean(z**2)))
            cells.append(f"{q} {value:.2f}")
            if meat == "drawn":
                record(f"RMS z of {q}, noise alone (theta at the truth)", value, "",
                       target="[0.8, 1.25]")  # fmt: skip
        print(f"{meat:8s}: T err mean {t.mean():+.3f} sd {t.std(ddof=1) if t.size > 1 else 0:.3f} "
              f"SE {se:.3f} degC (RMS z {float(np.sqrt(np.mean((t / se) ** 2))):.2f}); "
              f"RMS z {', '.join(cells)}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
