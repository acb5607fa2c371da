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

import dataclasses
import math

import numpy as np
from numba import njit

from mpipe.inversion.history_start import pad_history
from mpipe.inversion.objective import ObjectiveSettings, TargetWindow
from mpipe.reed.block_fft import _fft_tables, _irfft_last_half, _rfft_lean
from mpipe.reed.bore_kernel import BoreKernel, prepare_lean
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
def _history_share(q_ext, q_base, q_ones, shift, f):
    """``q_ext = q_base + shift q_ones`` (the history's share, Pa) and zero spectra ``f``."""
    for i in range(q_ext.size):
        q_ext[i] = q_base[i] + shift * q_ones[i]
    for lvl in range(len(f)):
        fl = f[lvl]
        for s in range(fl.shape[0]):
            for j in range(fl.shape[1]):
                fl[s, j] = 0.0


def history_term(h: np.ndarray, history: np.ndarray, n: int) -> np.ndarray:
    """The history's share of the bore's history term over the next ``n`` samples, Pa.

    ``q(i) = sum_{j > i} h_j x(i - j)`` for i = 0..n-1, with ``x(-1)`` the last sample of
    ``history`` (p+, Pa): the part of ``q = sum_{j>=1} h_j p+(i - j)`` that a run started
    at sample 0 does not compute itself (FFT convolution, float64).
    """
    from scipy.signal import fftconvolve

    full = fftconvolve(np.asarray(history, dtype=float), np.asarray(h, dtype=float))
    out = np.zeros(n)
    tail = full[history.size : history.size + n]
    out[: tail.size] = tail
    return out


def run_kernel(kernel: BoreKernel, n_run: int):
    """The lean kernel of a run of ``n_run`` samples from a zero history (r_f cut to it).

    Lags of ``n_run`` samples or more reach only the history, which :func:`history_term`
    convolves; made once per (kernel, length) and kept on the kernel.
    """
    cache = kernel.__dict__.setdefault("_run_kernels", {})
    length = max(min(kernel.n_taps, n_run), 2)
    if length not in cache:
        cut = dataclasses.replace(kernel, h=kernel.h[:length])
        cache[length] = prepare_lean(cut)
    return cache[length]


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
    out_r, target_p, target_std, p_lead, u_lead, filt, rho, fs, q_base, q_ones, q_ext, x,
    n0, z0, f, head, h0, level1, level2, work1, work2, fut, work, p_mod, p_ctx, fir,
    fir_work, buf, n_taps_fir, k, s_area, y_m, p_m, lam, y_c, alpha, a1, a2, a3, b1,
):  # fmt: skip
    """Residual of one candidate into ``out_r``; returns a status code (OK, DIVERGED, SILENT).

    Mirrors :func:`mpipe.inversion.objective.run_model` with the history start. The
    history's share of the history term is ``q_base + (Z0 c / 2) q_ones`` (c the missing
    mean flow; :func:`history_term`); ``x`` holds a zero history and ``f`` the 4-tuple
    (level-1 re, im, level-2 re, im) of its delay-line spectra (zeroed before each run).
    """
    n_lead = p_lead.size
    ylead = work[0, :n_lead]
    _lead_in(ylead, p_lead, k, p_m, y_c, alpha, a1, a2, a3, b1)
    missing = 0.0
    if filt:
        missing = _missing_flow(ylead, p_lead, u_lead, rho, fs, s_area, y_m, p_m, lam)
    _history_share(q_ext, q_base, q_ones, 0.5 * z0 * missing, f)
    y = ylead[n_lead - 1]
    y_prev = ylead[n_lead - 2]
    dp0 = p_m - p_lead[n_lead - 1]
    _run_pressure(
        x, n0, p_mod.size, head, h0, z0, rho, a1, a2, a3, b1, y_m, y_c, alpha, lam,
        s_area * fs, p_m, y, y_prev, dp0, level1, f[0], f[1], work1, level2, f[2], f[3],
        work2, fut, p_mod, q_ext,
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
        n_pad = lp.delay + 1 if self.filt else 0
        n_run = n + n_pad
        # The history's share of the bore's history term is the same for every candidate
        # but for the missing mean flow c, in which it is affine: convolved here once.
        # The kernel then runs on a zero history with r_f cut to the run's length.
        ph = p_hist[-(n_taps - 1) :]
        uh = u_hist[-(n_taps - 1) :]
        self.q_base = history_term(kernel.h, 0.5 * (ph + kernel.z0 * uh), n_run)
        self.q_ones = history_term(kernel.h, np.ones(ph.size), n_run)
        self.q_ext = np.empty(n_run)
        lean = run_kernel(kernel, n_run)
        self.lean = lean
        self.n0 = lean.n0
        self.x = np.zeros(self.n0 + n_run)
        self.f = lean.history_spectra(self.x)
        self.work1 = np.zeros((5, lean.block1 + 1))
        self.work2 = np.zeros((5, lean.block2 + 1))
        width = max(n_lead, n + 2 * n_pad + 2)
        self.work = np.zeros((2, width))
        self.p_mod = np.empty(n_run)
        self.fut = np.empty(n_run + lean.head.size)
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
                self.rho, self.fs, self.q_base, self.q_ones, self.q_ext, self.x, self.n0, k.z0,
                self.f, self.lean.head, self.lean.h0, self.lean.level1,
                self.lean.level2, self.work1, self.work2, self.fut, self.work, self.p_mod,
                self.p_ctx, self.fir, self.fir_work, self.buf, self.n_taps_fir, reed.k, reed.S,
                reed.y_m, reed.p_m, reed.lam, reed.y_c, reed.alpha, a1, a2, a3, b1,
            )  # fmt: skip
        return REASONS.get(int(code), "")


__all__ = ["WindowEvaluator"]
