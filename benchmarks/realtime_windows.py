"""Part of ``bench_realtime.py``: where a warm window's CPU goes, and the harmonic split's cost.

Not a benchmark of its own (``run_all.py`` runs ``bench_*.py`` only). Thread CPU time, so
that the figures hold on a shared machine; every comparison is interleaved window by window.
"""

from __future__ import annotations

import contextlib
import statistics
import time

import numpy as np
from harmonics_lstsq import split_residual as split_before
from headline import record
from threadpoolctl import threadpool_limits

from mpipe.inversion.fit import objective as objective_module
from mpipe.inversion.fit.window import invert_window
from mpipe.inversion.output.resynthesis import reed_from_row
from mpipe.inversion.trust.harmonics import split_residual


@contextlib.contextmanager
def counted_model_runs(counts: dict):
    """Count plain model runs (``res``) and sensitivity runs (``jac``) and their thread CPU."""
    cls = objective_module.F2Objective
    plain, sens = cls.residuals, cls.jacobian

    def wrap(fn, key):
        def inner(self, x):
            t0 = time.thread_time()
            try:
                return fn(self, x)
            finally:
                counts[key] += 1
                counts[f"{key}_s"] += time.thread_time() - t0

        return inner

    cls.residuals, cls.jacobian = wrap(plain, "res"), wrap(sens, "jac")
    try:
        yield counts
    finally:
        cls.residuals, cls.jacobian = plain, sens


def _relative(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b)) / (np.max(np.abs(a)) + 1e-300))


def window_costs(data: dict, kernel, rho: float, config, n_windows: int) -> None:
    """Warm windows from a cold start in the take's middle: model runs, CPU split, the split.

    Prints, per warm window (medians): plain and sensitivity model runs and their CPU, the
    whole window's CPU with and without its standard errors (``errors=False``, the
    front-end re-fits), and the harmonic split of its residual now and before issue 31
    (the frozen copy ``harmonics_lstsq``), with their largest relative difference.
    """
    p, u, fs = data["p"], data["u"], float(data["fs"])
    starts = [int(s) for s in data["starts"]]
    n = int(round(config.window_s * fs))
    with threadpool_limits(limits=1, user_api="blas"):  # as the workers run windows
        cold = invert_window(p, u, fs, starts[len(starts) // 2], kernel, rho, config,
                             zero_mean=True)  # fmt: skip
        anchor = reed_from_row(cold.row)
        rows = []
        picked = starts[1 : 1 + n_windows]
        for s in picked:
            counts = dict.fromkeys(("res", "res_s", "jac", "jac_s"), 0)
            with counted_model_runs(counts):
                t0 = time.thread_time()
                out = invert_window(p, u, fs, s, kernel, rho, config, zero_mean=True, warm=anchor)
                full = time.thread_time() - t0
            t0 = time.thread_time()
            invert_window(p, u, fs, s, kernel, rho, config, zero_mean=True, warm=anchor,
                          errors=False)  # fmt: skip
            bare = time.thread_time() - t0
            if out.search is None or out.search.jacobian is None:
                continue
            args = (out.search.residuals, p[s : s + n], out.search.jacobian, fs)
            t0 = time.thread_time()
            now = split_residual(*args, floor=config.model_form_floor)
            t_now = time.thread_time() - t0
            t0 = time.thread_time()
            before = split_before(*args, floor=config.model_form_floor)
            t_before = time.thread_time() - t0
            diff = np.nan
            if now is not None and before is not None:
                diff = max(_relative(before.noise, now.noise), _relative(before.excess, now.excess))
            rows.append((counts["res"], counts["jac"], counts["res_s"], counts["jac_s"], full,
                         bare, t_now, t_before, diff, out.row["status"] == "ok"))  # fmt: skip
    a = np.array(rows, dtype=float)
    med = [statistics.median(a[:, i]) for i in range(8)]
    print(
        f"  {len(rows)} warm windows (from a cold start at the take's middle), medians: "
        f"{med[0]:.0f} plain model runs ({1e3 * med[2]:.1f} ms CPU) + {med[1]:.0f} "
        f"sensitivity runs ({1e3 * med[3]:.1f} ms); the whole window {1e3 * med[4]:.1f} ms CPU, "
        f"{1e3 * med[5]:.1f} ms without its standard errors; status ok {int(a[:, 9].sum())}"
        f"/{len(rows)}"
    )
    print(
        f"  harmonic split of the residual: {1e3 * med[6]:.1f} ms CPU now, {1e3 * med[7]:.1f} ms "
        f"before (least squares per f0; x{med[7] / med[6]:.1f}, same run); largest relative "
        f"difference of the noise and model-form spectra {np.nanmax(a[:, 8]):.1e}"
    )
    record("warm window CPU (baseline: its harmonic split before)", 1e3 * med[4], "ms",
           1e3 * (med[4] - med[6] + med[7]))  # fmt: skip
