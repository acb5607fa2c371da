"""The front end's share of the take fit propagated through the whole take's own system.

Usage: ``.venv/bin/python benchmarks/bench_frontend_joint.py [--seed 0] [--snr 45]``

A question for issue 45, not yet the pipeline's method: mpipe gives the front end's share
of each estimate (``<q>_se_frontend``) by propagating each front-end parameter's SE window
by window (``shared_errors.frontend_linear``: six windows, each its own Hessian, the median
shift). Here the same SEs go through the take's joint normal equations instead: the whole
take re-separated and translated with each parameter moved by one SE (about 0.06 s each on a
2.25 s take), every window's residual change at the fit's solution, and one solve of the
take's Gauss-Newton system over every window's p_m, y_m, the note's constants and T. Printed
beside the table's per-window figures and the estimates' actual errors, on one crescendo of
``bench_estimator.py`` (cached in its folder). Also: the front end's own theta against the
truth over every take in that folder (RMS z of its temperature, losses, Mach number and
microphone position).
"""

import argparse
import dataclasses
import glob
import logging
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_estimator as be  # noqa: E402
from headline import record  # noqa: E402

from mpipe.inversion.fit.window import window_objective  # noqa: E402
from mpipe.inversion.preparation.kernel import KernelSource  # noqa: E402
from mpipe.inversion.whole_take.estimator import layout_of, problems_of  # noqa: E402
from mpipe.measurement.separation.perturbation import reseparate  # noqa: E402
from mpipe.measurement.translation import translate  # noqa: E402
from mpipe.pipeline.settings import load_pipeline  # noqa: E402
from mpipe.reed.parameters import ReedParameters  # noqa: E402

FOLDER = be.ROOT / "benchmarks" / ".cache" / "estimator"
NAMES = ("temperature", "eta", "mach", "position")


def _moved_problems(signals, cal, pipe, fs, starts, config, n_taps) -> dict:
    """Every window's problem on the take re-separated with each theta moved by one SE."""
    level = np.asarray(signals["theta_level"], float)
    se = np.asarray(signals["theta_level_se"], float)
    band = pipe.separation.band_edge_hz + pipe.separation.band_taper_hz
    out = {}
    for j, name in enumerate(NAMES):
        moved = level.copy()
        moved[j] += se[j]
        p0, u0 = reseparate(signals["p0"], signals["u0"], fs, cal, level, moved, band)
        temps = np.asarray(signals["temperature_c"], float) + (se[0] if j == 0 else 0.0)
        tr = translate(p0, u0, fs, cal, pipe.translation, temps, quiet=True)
        out[name] = _problems(tr.p, tr.u, fs, starts, config, n_taps)
    return out


def _problems(p, u, fs, starts, config, n_taps):
    blank = [0] * len(starts)
    return problems_of(p, u, fs, starts, blank, [""] * len(starts), config, True, n_taps)


def _reed(row) -> ReedParameters:
    return ReedParameters(**{n: float(row[n]) for n in ("k", "S", "y_m", "p_m", "lam", "m",
                                                        "g", "k_c")})  # fmt: skip


def _system(rows, probs, moved, kernels, config, lay):
    """The take's Gauss-Newton matrix and each theta's gradient change (dense)."""
    w, f = len(probs), lay.n_fast
    s = len(lay.names) - f
    size = w * f + s + 1
    a = np.zeros((size, size))
    grads = {name: np.zeros(size) for name in moved}
    k0, kp, km = kernels
    for i, q in enumerate(probs):
        reed = _reed(rows.iloc[i])
        x = np.array([getattr(reed, n) for n in config.search_parameters])
        r0, jac = window_objective(k0, q.target, reed, config).jacobian(x)
        rp = window_objective(kp, q.target, reed, config).residuals(x)
        rm = window_objective(km, q.target, reed, config).residuals(x)
        j = np.concatenate([lay.to_names(jac, x), ((rp - rm) / 0.5)[:, None]], axis=1)
        idx = [*range(i * f, i * f + f), *range(w * f, w * f + s), size - 1]
        a[np.ix_(idx, idx)] += j.T @ j
        for name, problems in moved.items():
            dr = window_objective(k0, problems[i].target, reed, config).residuals(x) - r0
            grads[name][idx] += j.T @ dr
    return a, grads


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--snr", type=float, default=45.0)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    FOLDER.mkdir(parents=True, exist_ok=True)
    signals, truth, cal = be.front_end(args.seed, args.snr, be.score_path("crescendo"), FOLDER)
    pipe = load_pipeline(be.PIPELINE)
    fs = float(signals["fs"])
    done, _, _ = be.invert(signals, cal, "take", 2)
    table = done.tracking.table
    rows = table[table["error"].astype(str).eq("")].reset_index(drop=True)
    t_c = done.temperature.temperature_c
    config = dataclasses.replace(pipe.inversion, sample_rate=fs, contact="fixed")
    lay = layout_of(config)
    starts = [int(round(s * fs)) for s in rows["t_start_s"]]
    source = KernelSource(cal, fs, {})
    kernels = tuple(source.named(t_c + dt, "")[0] for dt in (0.0, 0.25, -0.25))
    probs = _problems(signals["p"], signals["u"], fs, starts, config, kernels[0].n_taps)
    moved = _moved_problems(signals, cal, pipe, fs, starts, config, kernels[0].n_taps)
    a, grads = _system(rows, probs, moved, kernels, config, lay)
    w, f = len(probs), lay.n_fast
    total = dict.fromkeys(lay.names, 0.0)
    t_share = 0.0
    for name, g in grads.items():
        d = -np.linalg.solve(a, g)
        each = {n: float(np.median(d[j : w * f : f])) for j, n in enumerate(lay.names[:f])}
        each.update({n: float(d[w * f + j]) for j, n in enumerate(lay.names[f:])})
        print(f"{name:12s} d ln q per SE, %: "
              + ", ".join(f"{n} {100 * v:+.3f}" for n, v in each.items())
              + f"; dT {d[-1]:+.4f} degC")  # fmt: skip
        for n, v in each.items():
            total[n] += v * v
        t_share += float(d[-1]) ** 2
    times = (rows["t_start_s"] + 0.01).to_numpy()
    print("\nfront end's share, % of the value: joint / per window (the table) / actual error")
    for n in lay.names:
        table_pc = 100 * float(np.median(rows[f"{n}_se_frontend"] / rows[n]))
        err = 100 * float(np.median(rows[n] / be.truth_at(truth, times, n) - 1))
        print(f"  {n:4s} {100 * np.sqrt(total[n]):6.3f} {table_pc:6.3f} {err:+7.3f}")
    print(f"  T share {np.sqrt(t_share):.3f} degC (T {t_c:.3f} +- {done.temperature.se_c:.3f})")
    record("front end's share of k, joint propagation", 100 * float(np.sqrt(total["k"])), "%",
           baseline=100 * float(np.median(rows["k_se_frontend"] / rows["k"])))  # fmt: skip
    truth_theta = np.array([20.0, 1.0, 0.0, 0.0])
    fronts = [np.load(f) for f in sorted(glob.glob(str(FOLDER / "*.front.npz")))]
    z = np.array([(d["theta_level"] - truth_theta) / d["theta_level_se"] for d in fronts])
    rms = np.sqrt(np.mean(z**2, axis=0))
    print(f"\nthe front end's theta over {len(z)} cached takes, RMS z (T, eta, Mach, "
          f"position): {np.round(rms, 2)}")  # fmt: skip
    record("RMS z of the front end's temperature", float(rms[0]), "", target="[0.8, 1.25]")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
