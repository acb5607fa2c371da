"""Compiled evaluation of F2's residual vector for one window (the inversion's inner loop).

:func:`mpipe.inversion.objective.run_model` is the plain reference: it builds the model
state, runs :func:`mpipe.reed.model.simulate` with every output, filters pressure and flow and
compares. The search only needs the pressure residual, and most of what the reference
recomputes for every candidate is the same for every candidate of a window. A
:class:`WindowEvaluator` is built once per window and then, per candidate:

* runs the reed lead-in and the missing-mean-flow estimate in compiled code;
* builds the forward-wave history ``p+ = (p + Z0 (u + c)) / 2`` into a reused buffer. The
  spectra of its blocks, which the partitioned convolution needs before its first sample,
  are affine in the one candidate-dependent number ``c`` (the mean flow the measurement
  lost), so they are computed once per window as ``F0 + c F1`` instead of 50-odd FFTs per
  run (FFT linearity);
* runs the lean kernel :func:`mpipe.reed.kernels._run_pressure` (pressure only, no allocation);
* low-passes the pressure only (the flow does not enter F2) with the measurement's
  linear-phase FIR, by overlap-save FFT convolution over exactly the samples the
  reference's edge-padded filter reads for the window (the padding never reaches them);
* forms the residual ``p_target - p_model`` in place.

It agrees with the reference to rounding (tests/inversion/test_fastpath.py: ~1e-12
relative); the reference still computes the model flow for plots and the ``rest`` start.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from mpipe.inversion.history_start import pad_history
from mpipe.inversion.objective import ObjectiveSettings, TargetWindow
from mpipe.reed.block_fft import _fft_tables, _irfft_last_half, _rfft_lean
from mpipe.reed.bore_kernel import BoreKernel
from mpipe.reed.kernels import _run_pressure
from mpipe.reed.parameters import ReedParameters, check_stability
from mpipe.reed.scheme import reed_coefficients

#: Status codes of :func:`_evaluate`.
OK, DIVERGED, SILENT = 0, 1, 2
REASONS = {DIVERGED: "diverged", SILENT: "silent"}


@njit(cache=True)
def _lead_in(ylead, p_lead, k, p_m, y_c, alpha, a1, a2, a3, b1):
    """Reed lead-in driven by the measured pressure (history_start.reed_trajectory)."""
    n_lead = p_lead.size
    y0 = (p_m - p_lead[0]) / k
    ylead[0] = y0
    ylead[1] = y0
    for i in range(1, n_lead - 1):
        c = ylead[i] - y_c
        contact = c**alpha if c > 0.0 else 0.0
        ylead[i + 1] = a1 * ylead[i] + a2 * ylead[i - 1] + b1 * (p_m - p_lead[i]) + a3 * contact


@njit(cache=True)
def _missing_flow(ylead, p_lead, u_lead, rho, fs, s_area, y_m, p_m, lam):
    """history_start.missing_mean_flow: candidate minus measured flow over the lead-in."""
    n_lead = p_lead.size
    half = n_lead // 2
    acc = 0.0
    for i in range(half, n_lead):
        dp = p_m - p_lead[i]
        h = y_m - ylead[i]
        if h < 0.0:
            h = 0.0
        sgn = 1.0 if dp > 0.0 else (-1.0 if dp < 0.0 else 0.0)
        uf = sgn * lam * h * math.sqrt(2.0 * abs(dp) / rho)
        prev = ylead[i - 1] if i > 0 else ylead[0]
        ur = s_area * (ylead[i] - prev) * fs
        acc += uf + ur - u_lead[i]
    return acc / (n_lead - half)


@njit(cache=True)
def _load_history(x, n0, ph, uh, z0, missing, base, ones, f):
    """Forward-wave history into ``x[:n0]`` and its block spectra ``f = base + c ones``.

    The spectra are affine in the missing mean flow (c = Z0 missing / 2).
    """
    n_hist = ph.size
    start = n0 - n_hist
    for j in range(start):
        x[j] = 0.0
    for j in range(n_hist):
        x[start + j] = 0.5 * (ph[j] + z0 * (uh[j] + missing))
    cshift = 0.5 * z0 * missing
    for lvl in range(4):
        fl = f[lvl]
        bl = base[lvl]
        ol = ones[lvl]
        for s in range(fl.shape[0]):
            for j in range(fl.shape[1]):
                fl[s, j] = bl[s, j] + cshift * ol[s, j]


@njit(cache=True)
def _lowpass(out, n, p_mod, p_ctx, fir, fir_work, buf, n_taps_fir):
    """The first n samples of the measurement's low-pass of [p_ctx, p_mod] past p_ctx.

    Overlap-save FFT convolution: the filter's spectrum ``fir`` = (H_re, H_im, bitrev,
    tw_re, tw_im, w_re, w_im) for segments of 2M. The input is stored at offset M in
    ``buf`` (whose other samples stay zero); output i is sum_j taps[j] seq[i + 1 + j]
    (symmetric taps), the linear convolution at i + 1 + 2d, which a segment starting at
    buf[i0 + 1 + 2d] (i0 = first output of the block) gives as the second half of its
    circular convolution.
    """
    h_re, h_im, bitrev, tw_re, tw_im, w_re, w_im = fir
    m = bitrev.size
    n_ctx = p_ctx.size
    n_run = p_mod.size
    for j in range(n_ctx):
        buf[m + j] = p_ctx[j]
    for j in range(n_run):
        buf[m + n_ctx + j] = p_mod[j]
    acc_re = fir_work[0, : m + 1]
    acc_im = fir_work[1, : m + 1]
    zr = fir_work[2, :m]
    zi = fir_work[3, :m]
    half = fir_work[4, :m]
    i0 = 0
    while i0 < n:
        _rfft_lean(buf, i0 + n_taps_fir, acc_re, acc_im, zr, zi, bitrev, tw_re, tw_im, w_re, w_im)
        for j in range(m + 1):
            ar = acc_re[j]
            ai = acc_im[j]
            acc_re[j] = ar * h_re[j] - ai * h_im[j]
            acc_im[j] = ar * h_im[j] + ai * h_re[j]
        _irfft_last_half(acc_re, acc_im, half, zr, zi, bitrev, tw_re, tw_im, w_re, w_im)
        for j in range(min(m, n - i0)):
            out[i0 + j] = half[j]
        i0 += m


@njit(cache=True)
def _residual(out_r, target_p, target_std, p_mod, filt, p_ctx, fir, fir_work, buf, n_taps_fir):
    """``target - measured model pressure`` into ``out_r``; returns a status code."""
    n_run = p_mod.size
    for i in range(n_run):
        if not math.isfinite(p_mod[i]):
            return DIVERGED
    n = target_p.size
    if filt:
        _lowpass(out_r, n, p_mod, p_ctx, fir, fir_work, buf, n_taps_fir)
    else:
        for i in range(n):
            out_r[i] = p_mod[i]
    mean = 0.0
    for i in range(n):
        mean += out_r[i]
    mean /= n
    var = 0.0
    for i in range(n):
        var += (out_r[i] - mean) ** 2
    if math.sqrt(var / n) < 0.01 * target_std:
        return SILENT
    for i in range(n):
        out_r[i] = target_p[i] - out_r[i]
        if not math.isfinite(out_r[i]):
            return DIVERGED
    return OK


# numba's on-disk cache of a function is keyed on its own file only: after editing the
# kernels it calls (mpipe/reed/kernels.py, block_fft.py, or the helpers above from another
# module), delete the stale caches (mpipe/**/__pycache__/*.nb*), which keep the old code.
@njit(cache=True)
def _evaluate(
    out_r, target_p, target_std, p_lead, u_lead, filt, rho, fs, ph, uh, x, n0, z0,
    base, ones, f, head, h0, level1, level2, work1, work2, fut, work, p_mod, p_ctx, fir,
    fir_work, buf, n_taps_fir, k, s_area, y_m, p_m, lam, y_c, alpha, a1, a2, a3, b1,
):  # fmt: skip
    """Residual of one candidate into ``out_r``; returns a status code (OK, DIVERGED, SILENT).

    Mirrors :func:`mpipe.inversion.objective.run_model` with the history start. ``base``,
    ``ones`` and ``f`` are 4-tuples (level-1 re, im, level-2 re, im) of the history
    spectra with no mean-flow shift, of the shift's indicator, and the ones to fill.
    """
    n_lead = p_lead.size
    ylead = work[0, :n_lead]
    _lead_in(ylead, p_lead, k, p_m, y_c, alpha, a1, a2, a3, b1)
    missing = 0.0
    if filt:
        missing = _missing_flow(ylead, p_lead, u_lead, rho, fs, s_area, y_m, p_m, lam)
    _load_history(x, n0, ph, uh, z0, missing, base, ones, f)
    y = ylead[n_lead - 1]
    y_prev = ylead[n_lead - 2]
    dp0 = p_m - p_lead[n_lead - 1]
    _run_pressure(
        x, n0, p_mod.size, head, h0, z0, rho, a1, a2, a3, b1, y_m, y_c, alpha, lam,
        s_area * fs, p_m, y, y_prev, dp0, level1, f[0], f[1], work1, level2, f[2], f[3],
        work2, fut, p_mod,
    )  # fmt: skip
    return _residual(
        out_r, target_p, target_std, p_mod, filt, p_ctx, fir, fir_work, buf, n_taps_fir
    )


class WindowEvaluator:
    """Residual vector of F2 for one window's candidates, computed fast (history start).

    Holds work buffers, so one evaluator must not be used by two threads at once; each
    window (and each worker process) builds its own.

    Parameters
    ----------
    kernel : BoreKernel
        Prepared bore.
    target : TargetWindow
        Target window and history.
    settings : ObjectiveSettings
        Must use ``start="history"``; ``lowpass`` for zero-mean targets.

    Raises
    ------
    ValueError
        For a ``rest`` start (use the reference :func:`~mpipe.inversion.objective.run_model`).
    """

    def __init__(self, kernel: BoreKernel, target: TargetWindow, settings: ObjectiveSettings):
        if settings.start != "history":
            raise ValueError("the compiled evaluator supports the history start only")
        fs = target.fs
        n = target.p.size
        n_taps = kernel.n_taps
        n_lead = max(int(round(settings.lead_s * fs)), 2)
        if n_lead < 3:
            raise ValueError("lead_s: the compiled evaluator needs a lead-in of >= 3 samples")
        length = max(n_taps, n_lead)
        p_hist = pad_history(target.p_history, length)
        u_hist = pad_history(target.u_history, length)
        self.kernel = kernel
        self.fs = float(fs)
        self.filt = bool(target.zero_mean)
        lp = settings.lowpass if self.filt else None
        if self.filt and lp is None:
            raise ValueError("a zero-mean target needs settings.lowpass")
        self.target_p = np.ascontiguousarray(target.p, dtype=float)
        self.target_std = float(np.std(self.target_p))
        self.p_lead = np.ascontiguousarray(p_hist[-n_lead:])
        self.u_lead = np.ascontiguousarray(u_hist[-n_lead:])
        lean = kernel.lean
        self.lean = lean
        self.n0 = lean.n0
        self.ph = np.ascontiguousarray(p_hist[-(n_taps - 1) :])
        self.uh = np.ascontiguousarray(u_hist[-(n_taps - 1) :])
        n_pad = lp.delay + 1 if self.filt else 0
        self.x = np.zeros(self.n0 + n + n_pad)
        # spectra of the history with c = 0 and of its indicator (the part c multiplies)
        base = np.zeros(self.n0)
        base[self.n0 - self.ph.size :] = 0.5 * (self.ph + kernel.z0 * self.uh)
        ones = np.zeros(self.n0)
        ones[self.n0 - self.ph.size :] = 1.0
        self.base = lean.history_spectra(base)
        self.ones = lean.history_spectra(ones)
        self.f = tuple(np.empty_like(a) for a in self.base)
        self.work1 = np.zeros((5, lean.block1 + 1))
        self.work2 = np.zeros((5, lean.block2 + 1))
        width = max(n_lead, n + 2 * n_pad + 2)
        self.work = np.zeros((2, width))
        self.p_mod = np.empty(n + n_pad)
        self.fut = np.empty(n + n_pad + lean.head.size)
        if self.filt:
            taps = np.asarray(lp.taps, dtype=float)
            # segments of 2M samples give M outputs each once the L taps fit: L - 1 <= M
            m = max(256, 1 << int(math.ceil(math.log2(max(taps.size - 1, 1)))))
            spec = np.fft.rfft(taps, 2 * m)
            self.fir = (spec.real.copy(), spec.imag.copy(), *_fft_tables(m))
            self.fir_work = np.zeros((5, m + 1))
            self.p_ctx = np.ascontiguousarray(p_hist[-(lp.delay + 1) :])
            # zero prefix of M, the input, and enough zeros for the last segment
            n_blocks = -(-n // m)
            self.buf = np.zeros(max((n_blocks - 1) * m + taps.size + 2 * m, m + n + 2 * n_pad))
            self.n_taps_fir = taps.size
        else:
            self.fir = (np.zeros(1), np.zeros(1), *_fft_tables(4))
            self.fir_work = np.zeros((5, 5))
            self.p_ctx = np.zeros(0)
            self.buf = np.zeros(1)
            self.n_taps_fir = 0
        self.rho = float(kernel.rho)

    def residuals_into(self, reed: ReedParameters, out: np.ndarray) -> str:
        """Write ``p_target - p_model`` (Pa) into ``out``; return "" or why it is infeasible.

        Parameters
        ----------
        reed : ReedParameters
            Candidate.
        out : ndarray
            Length of the window; undefined when infeasible.

        Returns
        -------
        str
            "" for a feasible candidate, else the reason ("unstable: ...", "diverged",
            "silent").
        """
        try:
            check_stability(reed, self.fs)
        except ValueError as exc:
            return f"unstable: {exc}"
        a1, a2, a3, b1 = reed_coefficients(reed, self.fs)
        k = self.kernel
        with np.errstate(all="ignore"):
            code = _evaluate(
                out, self.target_p, self.target_std, self.p_lead, self.u_lead, self.filt,
                self.rho, self.fs, self.ph, self.uh, self.x, self.n0, k.z0, self.base,
                self.ones, self.f, self.lean.head, self.lean.h0, self.lean.level1,
                self.lean.level2, self.work1, self.work2, self.fut, self.work, self.p_mod,
                self.p_ctx, self.fir, self.fir_work, self.buf, self.n_taps_fir, reed.k, reed.S,
                reed.y_m, reed.p_m, reed.lam, reed.y_c, reed.alpha, a1, a2, a3, b1,
            )  # fmt: skip
        return REASONS.get(int(code), "")


__all__ = ["WindowEvaluator"]
