"""One window's sum of squares profiled over p_m, from a run's output folder.

Usage: ``.venv/bin/python benchmarks/window_profile.py RUN_FOLDER PIPELINE.yaml
CALIBRATION.yaml T_START_S [T_START_S ...] [--truth TAKE.truth.npz] [--span 0.6,1.4]
[--points 17]``

For a window of a take that ``mpipe run`` inverted (``RUN_FOLDER`` is the take's output
folder, with ``translation/mouthpiece.npz`` and ``inversion/windows.parquet``), the window's
F2 (Pa) at p_m on a grid around the estimate (or around the truth's p_m with ``--truth``, a
virtual or OpenWInD take's ``*.truth.npz``), y_m at its best for each p_m, every other
parameter and the bore's temperature as the table gives them (the note's constants and the
take's temperature of the joint fit). The contact law is the table's (closure when y_c is
y_m in every window). One minimum far from the truth says the window's data, given the
model and its note's constants, put p_m there (model form, not a search); a minimum below
the fit's F2 says the fit stopped in another basin (benchmarks.md, "The independent-simulator
suite", 2026-12-07).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.optimize import minimize_scalar

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from bench_playing import truth_over  # noqa: E402

from mpipe.inversion.fit.history_start import lead_in  # noqa: E402
from mpipe.inversion.fit.objective import TargetWindow  # noqa: E402
from mpipe.inversion.fit.window import window_objective  # noqa: E402
from mpipe.inversion.preparation.kernel import bore_kernel  # noqa: E402
from mpipe.measurement.calibration import load_calibration  # noqa: E402
from mpipe.pipeline.settings import load_pipeline  # noqa: E402
from mpipe.reed.parameters import ReedParameters  # noqa: E402

REED = ("k", "S", "y_m", "p_m", "m", "g", "lam", "k_c", "y_c", "alpha")


def profile(objective, x0: np.ndarray, names, closure: bool, grid: np.ndarray) -> list:
    """``(p_m, best y_m, F2)`` at each p_m of ``grid`` (Pa), y_m searched on (0.1, 1) mm."""
    ip, iy = names.index("p_m"), names.index("y_m")
    out = []
    for pm in grid:

        def f2(log_y, pm=pm):
            x = x0.copy()
            x[ip], x[iy] = pm, np.exp(log_y)
            if closure and "y_c" in names:
                x[names.index("y_c")] = np.exp(log_y)
            return objective(x)

        res = minimize_scalar(f2, bounds=(np.log(1e-4), np.log(1e-3)), method="bounded",
                              options={"xatol": 1e-4})  # fmt: skip
        out.append((float(pm), float(np.exp(res.x)), float(res.fun)))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("pipeline", type=Path)
    ap.add_argument("calibration", type=Path)
    ap.add_argument("t_start", type=float, nargs="+", help="window starts, s")
    ap.add_argument("--truth", type=Path)
    ap.add_argument("--span", default="0.6,1.4", help="grid of p_m, factors of its centre")
    ap.add_argument("--points", type=int, default=17)
    args = ap.parse_args(argv)
    windows = pd.read_parquet(args.folder / "inversion" / "windows.parquet")
    closure = bool(np.allclose(windows["y_c"], windows["y_m"]))
    config = dataclasses.replace(load_pipeline(args.pipeline).inversion,
                                 contact="closure" if closure else "fixed")  # fmt: skip
    signals = np.load(args.folder / "translation" / "mouthpiece.npz")
    p, u, fs = signals["p"], signals["u"], float(signals["fs"])
    kernel, _ = bore_kernel(load_calibration(args.calibration), fs,
                            float(windows["kernel_temperature_c"].iloc[0]))  # fmt: skip
    n = int(round(config.window_s * fs))
    names = list(config.search_parameters)
    truth = None if args.truth is None else np.load(args.truth)
    lo, hi = (float(v) for v in args.span.split(","))
    for t0 in args.t_start:
        row = windows.iloc[int(np.argmin(np.abs(windows["t_start_s"] - t0)))]
        s = int(round(float(row["t_start_s"]) * fs))
        history = lead_in(p, u, s, n, kernel.n_taps, config.lead_s, fs)
        target = TargetWindow(p[s : s + n], u[s : s + n], *history, fs, True)
        base = ReedParameters(**{k: float(row[k]) for k in REED})
        objective = window_objective(kernel, target, base, config)
        x0 = np.array([float(row[k]) for k in names])
        true = None
        if truth is not None and "control_p_m" in truth:
            true = truth_over(truth, "control_p_m", float(row["t_start_s"]), float(row["t_end_s"]))
        centre = true if true is not None else float(row["p_m"])
        print(f"window at {row['t_start_s']:.3f} s: fit p_m {row['p_m']:.1f} Pa, y_m "
              f"{row['y_m']:.4g} m, F2 {objective(x0):.3f} Pa"
              + ("" if true is None else f"; true p_m {true:.1f} Pa"))  # fmt: skip
        for pm, y, f2 in profile(objective, x0, names, closure,
                                 np.linspace(lo, hi, args.points) * centre):  # fmt: skip
            print(f"  p_m {pm:8.1f} Pa  best y_m {y:.4g} m  F2 {f2:.3f} Pa")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
