"""The take fit's sandwich covariance on takes with no front end: its RMS z.

Usage: ``.venv/bin/python benchmarks/bench_sandwich.py [--seeds 8] [--noise 5.6e-3]``

The model's own output (the Table 1 reed on the shipped bore at 20 degC, 0.38 s), with
white noise of ``--noise`` times each signal's standard deviation added to p and u
(5.6e-3: 45 dB), inverted by the take's estimator on 14 windows with a calibration 1.5 degC
off and no front end (the take's temperature prior is the calibration's +- 5 degC), as
``tests/inversion/whole_take/test_estimator.py`` makes its takes. No separation, no
translation: what is left is the fit and its sandwich covariance. Printed: the RMS z
(error over the SE without the rate component) of k, S, lambda (once per take: one note),
p_m and y_m (every ok window) and the temperature. An honest covariance gives about 1.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests" / "inversion" / "whole_take"))
sys.path.insert(0, str(ROOT / "benchmarks"))

from headline import record  # noqa: E402
from test_estimator import CONFIG, FS, PLAYED_C, TABLE1, _take  # noqa: E402

from mpipe.inversion.settings import ExecutorConfig  # noqa: E402
from mpipe.inversion.whole_take.take import invert_take  # noqa: E402
from mpipe.measurement.calibration import load_calibration  # noqa: E402

NOTE = ("k", "S", "lam")
WINDOW = ("p_m", "y_m")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=8)
    parser.add_argument("--noise", type=float, default=5.6e-3)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args(argv)
    cal = load_calibration(ROOT / "calibration" / "simplified_clarinet.yaml")
    starts = list(range(8000, 36000, 2000))
    zs: dict[str, list] = {q: [] for q in (*NOTE, *WINDOW, "T")}
    for seed in range(args.seeds):
        p, u, c = _take(cal, [TABLE1], seed=seed, noise=args.noise)
        done = invert_take(p, u, FS, c, CONFIG, ExecutorConfig(workers=args.workers),
                           windows=starts)  # fmt: skip
        t = done.tracking.table
        ok = t["status"].eq("ok").to_numpy()
        for q in (*NOTE, *WINDOW):
            rate = t[f"{q}_se_rate"].to_numpy(float) if f"{q}_se_rate" in t else 0.0
            se = np.sqrt(np.maximum(t[f"{q}_se"].to_numpy(float) ** 2 - np.nan_to_num(rate) ** 2,
                                    0.0))  # fmt: skip
            z = ((t[q].to_numpy(float) - getattr(TABLE1, q)) / se)[ok]
            zs[q].append(np.median(z) if q in NOTE else z)
        fit = done.temperature
        zs["T"].append((fit.temperature_c - PLAYED_C) / fit.se_c)
        print(f"seed {seed}: T {fit.temperature_c:.3f} +- {fit.se_c:.3f} degC, "
              f"{int(ok.sum())}/{len(t)} windows ok", flush=True)  # fmt: skip
    print(f"\n{args.seeds} takes, noise {args.noise:g} of each signal's std; RMS z (-rate):")
    for q, values in zs.items():
        z = np.concatenate([np.atleast_1d(v) for v in values])
        z = z[np.isfinite(z)]
        value = float(np.sqrt(np.mean(z**2)))
        print(f"  {q:4s} {value:5.2f}  (n {z.size})")
        record(f"RMS z of {q} (-rate), take fit without a front end", value, "",
               target="[0.8, 1.25]")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
