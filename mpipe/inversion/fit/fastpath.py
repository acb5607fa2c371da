"""Compiled evaluation of F2's residual vector for one window (the inversion's inner loop).

:func:`mpipe.inversion.fit.objective.run_model` is the plain reference: it builds the model
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
* runs the model's one compiled kernel (:func:`mpipe.reed.kernels.run`) for the pressure
  only, on the two-level partition of r_f, without allocation;
* low-passes the pressure only (the flow does not enter F2) with the measurement's
  linear-phase FIR, by overlap-save FFT convolution over exactly the samples the
  reference's edge-padded filter reads for the window (the padding never reaches them);
* forms the residual ``p_target - p_model`` in place.

It agrees with the reference to rounding (tests/inversion/fit/test_fastpath.py: ~1e-12
relative); the reference still computes the model flow, for plots.
Given a ``jac`` record the same compiled evaluation (:func:`_evaluate`) also differentiates
every step forward and writes the Jacobian (:mod:`mpipe.inversion.fit.sensitivities`). Its
arguments are records (tuples numba types), documented in :func:`_evaluate`.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numba import njit
from scipy import fft as sfft

from mpipe.core.filters import apply_lowpass
from mpipe.inversion.fit.history_start import pad_history
from mpipe.inversion.fit.lead_in import lead_in, lead_in_tangent, missing_flow, missing_tangent
from mpipe.inversion.fit.objective import ObjectiveSettings, TargetWindow, mouth_pressure_ramp
from mpipe.reed.block_fft import fft_tables, irfft_last_half, rfft_block
from mpipe.reed.bore_kernel import BoreKernel, prepare_lean
from mpipe.reed.kernels import run
from mpipe.reed.parameters import ReedParameters, check_stability
from mpipe.reed.scheme import scheme_records

#: Status codes of :func:`_evaluate`.
OK, DIVERGED, SILENT = 0, 1, 2
REASONS = {DIVERGED: "diverged", SILENT: "silent"}


@njit(cache=True)
def _history_share(q_ext, win, shift, lines):
    """``q_ext = q_base + shift q_ones`` (the history's share, Pa); zero the lines' spectra.

    ``lines`` holds (level, f_re, f_im, work) records, of the pressure or of its tangents.
    """
    q_base, q_ones = win[6], win[7]
    for i in range(q_ext.size):
        q_ext[i] = q_base[i] + shift * q_ones[i]
    for line in lines:
        line[1].fill(0.0)
        line[2].fill(0.0)


def history_term(kernel: BoreKernel, history: np.ndarray, n: int) -> np.ndarray:
    """The history's share of the bore's history term over the next ``n`` samples, Pa.

    ``q(i) = sum_{j > i} h_j x(i - j)`` for i = 0..n-1, with ``x(-1)`` the last sample of
    ``history`` (p+, Pa) and ``h`` the kernel's taps: the part of ``q = sum_{j>=1} h_j
    p+(i - j)`` that a run started at sample 0 does not compute itself (float64).

    One circular convolution of length ``L >= max(len(history) + n, len(h))``: the linear
    convolution's samples ``len(history) .. len(history) + n - 1`` are then free of wrap
    (nothing wraps below ``len(history) + n``, and what wraps from above ``L`` lands
    below ``len(h) - 1 - (L - len(history)) <= len(history)``). The taps' spectrum at ``L``
    is kept on the kernel (the same for every window on it), so a window costs one FFT of
    its history and one inverse. A 2-D ``history`` holds one history per row (of equal
    length) and gives one row each.
    """
    x = np.asarray(history, dtype=float)
    m = x.shape[-1]
    size = sfft.next_fast_len(max(m + n, kernel.n_taps), real=True)
    cache = kernel.__dict__.setdefault("_taps_spectra", {})
    if size not in cache:
        cache[size] = sfft.rfft(np.asarray(kernel.h, dtype=float), size)
    full = sfft.irfft(sfft.rfft(x, size, axis=-1) * cache[size], size, axis=-1)
    out = np.zeros((*x.shape[:-1], n))
    tail = full[..., m : m + min(n, max(kernel.n_taps - 1, 0))]
    out[..., : tail.shape[-1]] = tail
    return out


def _ones_term(kernel: BoreKernel, n_history: int, n_run: int) -> np.ndarray:
    """:func:`history_term` of a history of ones (the missing mean flow's share), Pa per Pa.

    The same for every window on one kernel: made once per (history, run length) and kept
    on the kernel, as :func:`run_kernel` keeps its lean kernels; the evaluators only read
    it (a read-only flag would give the compiled kernels another type to compile for).
    """
    cache = kernel.__dict__.setdefault("_ones_terms", {})
    key = (int(n_history), int(n_run))
    if key not in cache:
        cache[key] = history_term(kernel, np.ones(n_history), n_run)
    return cache[key]


def _filter_edge(lp, n: int, n_ctx: int) -> np.ndarray:
    """``1 - LP([1] * n_ctx + [0] * (n + n_ctx))`` over the n window samples (dimensionless).

    What of a constant added to the pressure before and in the window reaches the window
    through the measurement's low-pass when only the window's part is the model's: the
    measured pressure's missing ``R c`` enters the residual as ``R c`` times this. The
    same for every window of a length: made once per (n, n_ctx) and kept on the low-pass,
    as :func:`_ones_term` keeps its terms on the kernel (a filtering cost 0.36 ms, a third
    of an evaluator's build, and a take builds thousands); the evaluators only read it.
    """
    cache = lp.__dict__.setdefault("_filter_edges", {})
    key = (int(n), int(n_ctx))
    if key not in cache:
        x = np.concatenate([np.ones(n_ctx), np.zeros(n + n_ctx)])
        cache[key] = np.ascontiguousarray(1.0 - apply_lowpass(x, lp)[n_ctx : n_ctx + n])
    return cache[key]


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
def measured_lowpass(out, n, p_mod, p_ctx, lp):
    """The first n samples of the measurement's low-pass of [p_ctx, p_mod] past p_ctx.

    Overlap-save FFT convolution: ``lp`` is (fir, fir_work, buf, n_taps_fir) with the
    filter's spectrum ``fir`` = (H_re, H_im, tables) for segments of 2M. The input is
    stored at offset M in ``buf`` (whose other samples stay zero); output i is sum_j
    taps[j] seq[i + 1 + j] (symmetric taps), the linear convolution at i + 1 + 2d, which a
    segment starting at buf[i0 + 1 + 2d] (i0 = first output of the block) gives as the
    second half of its circular convolution.
    """
    (h_re, h_im, tables), fir_work, buf, n_taps_fir = lp
    m = tables[0].size
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
        rfft_block(buf, i0 + n_taps_fir, acc_re, acc_im, zr, zi, tables)
        for j in range(m + 1):
            ar = acc_re[j]
            ai = acc_im[j]
            acc_re[j] = ar * h_re[j] - ai * h_im[j]
            acc_im[j] = ar * h_im[j] + ai * h_re[j]
        irfft_last_half(acc_re, acc_im, half, zr, zi, tables)
        for j in range(min(m, n - i0)):
            out[i0 + j] = half[j]
        i0 += m


@njit(cache=True)
def model_residual(out_r, p_mod, win, lp, drop):
    """``target - measured model pressure`` into ``out_r``; returns a status code.

    ``drop``: the mean flow's drop the measured pressure lacks (``R c``, Pa); the
    measurement's model pressure is short of it but for the filter's edge
    (``win[10]``, :class:`WindowEvaluator`).
    """
    target_p, target_std, filt, p_ctx, edge = win[0], win[1], win[4], win[5], win[10]
    n_run = p_mod.size
    for i in range(n_run):
        if not math.isfinite(p_mod[i]):
            return DIVERGED
    n = target_p.size
    if filt:
        measured_lowpass(out_r, n, p_mod, p_ctx, lp)
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
        out_r[i] = target_p[i] - out_r[i] + drop * edge[i]
        if not math.isfinite(out_r[i]):
            return DIVERGED
    return OK


@njit(cache=True)
def tangent_start(tan, ylead, win, cand):
    """The kernel's ``tangent`` record after the lead-in: the lead-in's and c's tangents.

    ``tan`` = (d, tw, xt, dp_mod, conv_t, dpl, dul, q_t): the seed matrix (one column per
    parameter or change), the lead-in's tangents' scratch, p+'s, the output's, the
    tangents' delay lines, each column's change of the measured lead-in pressure and flow
    (zeros for a parameter) and its history term's tangent from the measured history
    (zeros for a parameter), to which the missing flow's shift ``((Z0 + R) dc / 2)
    q_ones`` is added here (R the reference resistance, ``win[9]``: the measured pressure
    lacks ``R c``). Returns the kernel's record and each column's ``dc`` (m^3/s per unit).
    """
    d, tw, xt, dp_mod, conv_t, dpl, dul, q_t = tan
    n_lead = win[2].size
    n_par = d.shape[1]
    dyl = tw[:, :n_lead]
    lead_in_tangent(dyl, ylead, win[2], d, dpl, cand)
    dmiss = np.zeros(n_par)
    if win[4]:
        missing_tangent(dmiss, dyl, ylead, d, dpl, dul, win, cand)
    fut_t, line1_t, line2_t = conv_t
    for line in (line1_t, line2_t):
        line[0].fill(0.0)
        line[1].fill(0.0)
    dy = dyl[:, n_lead - 1].copy()
    dy_prev = dyl[:, n_lead - 2].copy()
    ddp = d[7] - dpl[:, n_lead - 1]
    z0 = cand[0][1][0]
    q_ones = win[7]
    for j in range(n_par):
        c_t = 0.5 * (z0 + win[9]) * dmiss[j]
        for i in range(q_ones.size):
            q_t[j, i] += c_t * q_ones[i]
    return (d, dy, dy_prev, ddp, xt, fut_t, line1_t, line2_t, dp_mod, q_t), dmiss


@njit(cache=True)
def start_run(win, buffers, cand):
    """Before a candidate's run: the reed's lead-in, the missing flow, the history's share.

    Writes the lead-in into ``buffers``' work row 0, the history's share into its
    ``q_ext`` and the mouth pressure into its ``pm`` (records: :func:`_evaluate`); returns
    the run's start state (y, y_prev, dp) in m, m, Pa, and the missing mean flow c, m^3/s
    (the history's p+ moves by ``(Z0 + R) c / 2``, R the reference resistance ``win[9]``).
    """
    _, _, conv, q_ext, _, pm, work = buffers
    p_lead = win[2]
    n_lead = p_lead.size
    p_m = cand[3]
    ylead = work[0, :n_lead]
    lead_in(ylead, p_lead, cand)
    missing = 0.0
    if win[4]:
        missing = missing_flow(ylead, win, cand)
    _history_share(q_ext, win, 0.5 * (cand[0][1][0] + win[9]) * missing, conv[2:])
    # the mouth pressure's ramp about the window's centre (win[11], Pa/s; the lead-in's
    # is in p_lead, win[2]: objective.mouth_pressure_ramp)
    slope, half = win[11], 0.5 * win[0].size
    for i in range(pm.size):
        pm[i] = p_m + slope * (i - half) / win[8]
    return (ylead[n_lead - 1], ylead[n_lead - 2], p_m - p_lead[n_lead - 1]), missing


# numba's on-disk cache of a function is keyed on its own file only: after editing the
# kernels it calls (mpipe/reed/kernels.py, block_fft.py, fit/lead_in.py, or the helpers
# above from another module), delete the stale caches (mpipe/**/__pycache__/*.nb*),
# which keep the old code.
@njit(cache=True)
def _evaluate(out_r, win, lp, buffers, cand, jac):
    """Residual of one candidate into ``out_r``; returns a status code (OK, DIVERGED, SILENT).

    Mirrors :func:`mpipe.inversion.fit.objective.run_model`. The
    history's share of the history term is ``q_base + ((Z0 + R) c / 2) q_ones`` (c the
    missing mean flow, R the reference resistance ``win[9]``: the measured pressure lacks
    ``R c``; :func:`history_term`); the run starts on a zero history. Records:

    * ``win`` = (target_p, target_std, p_lead, u_lead, filt, p_ctx, q_base, q_ones, fs,
      r_dc, edge, slope): r_dc the reference resistance (Pa s/m^3, 0 for a flow with its
      mean), edge ``1 - LP([1 over p_ctx, 0 over the run])`` over the window, slope the
      mouth pressure's ramp (Pa/s, ``TargetWindow.p_m_slope``); p_lead is the measured
      lead-in less the ramp's share there (the reed reads only ``p_m(t) - p``);
    * ``lp`` = :func:`measured_lowpass`'s;
    * ``buffers`` = (x, n0, conv, q_ext, p_mod, pm, work): the kernel's p+ buffer and
      ``conv`` (:func:`mpipe.reed.kernels.run`), the history share, the model pressure,
      the mouth-pressure series and the lead-in's scratch;
    * ``cand`` = (model, k, S, p_m): the kernel's ``model`` record of the candidate and
      the parameters the lead-in reads (SI units);
    * ``jac``: None, or (d, out_j, tw, xt, dp_mod, ctx0, col, conv_t, still, q_t) to also
      write the Jacobian ``out_j`` (n, P) from the forward sensitivities (seed matrix
      ``d``, :mod:`mpipe.inversion.fit.sensitivities`; ``still`` zeros for the measured
      lead-in, ``q_t`` the history term's tangent, zeroed here); written only when the
      status is OK.
    """
    x, n0, conv, q_ext, p_mod, pm, work = buffers
    state, missing = start_run(win, buffers, cand)
    ylead = work[0, : win[2].size]
    r_dc, edge = win[9], win[10]
    if jac is None:
        run(x, n0, cand[0], conv, state, pm, q_ext, p_mod, None, None)
        return model_residual(out_r, p_mod, win, lp, r_dc * missing)
    still, q_t = jac[8], jac[9]  # the measured signals do not move with theta
    q_t.fill(0.0)
    tangent, dmiss = tangent_start((jac[0], jac[2], jac[3], jac[4], jac[7], still, still, q_t),
                                   ylead, win, cand)  # fmt: skip
    run(x, n0, cand[0], conv, state, pm, q_ext, p_mod, None, tangent)
    code = model_residual(out_r, p_mod, win, lp, r_dc * missing)
    if code != OK:
        return code
    d, out_j, dp_mod, ctx0, col = jac[0], jac[1], jac[4], jac[5], jac[6]
    n = out_r.size
    for j in range(d.shape[1]):
        if win[4]:
            measured_lowpass(col, n, dp_mod[j], ctx0, lp)
        else:
            col[:n] = dp_mod[j, :n]
        for i in range(n):
            out_j[i, j] = -col[i] + r_dc * dmiss[j] * edge[i]
    return OK


class WindowEvaluator:
    """Residual vector of F2 for one window's candidates, computed fast.

    Holds work buffers, so one evaluator must not be used by two threads at once; each
    window (and each worker process) builds its own.

    Parameters
    ----------
    kernel : BoreKernel
        Prepared bore.
    target : TargetWindow
        Target window and history.
    settings : ObjectiveSettings
        The lead-in, and the ``lowpass`` zero-mean targets need.

    Raises
    ------
    ValueError
        For a zero-mean target without a low-pass, or a lead-in under 3 samples.
    """

    def __init__(self, kernel: BoreKernel, target: TargetWindow, settings: ObjectiveSettings):
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
        filt = bool(target.zero_mean)
        lp = settings.lowpass if filt else None
        if filt and lp is None:
            raise ValueError("a zero-mean target needs settings.lowpass")
        self.target_p = np.ascontiguousarray(target.p, dtype=float)
        n_pad = lp.delay + 1 if filt else 0
        n_run = n + n_pad
        # The history's share of the bore's history term is the same for every candidate
        # but for the missing mean flow c, in which it is affine: convolved here once.
        # The kernel then runs on a zero history with r_f cut to the run's length.
        ph = p_hist[-(n_taps - 1) :]
        uh = u_hist[-(n_taps - 1) :]
        p_ctx = np.ascontiguousarray(p_hist[-(lp.delay + 1) :]) if filt else np.zeros(0)
        ramp_lead, _ = mouth_pressure_ramp(target.p_m_slope, n, n_lead, fs)
        self.win = (
            self.target_p,
            float(np.std(self.target_p)),
            np.ascontiguousarray(p_hist[-n_lead:] - ramp_lead),
            np.ascontiguousarray(u_hist[-n_lead:]),
            filt,
            p_ctx,
            history_term(kernel, 0.5 * (ph + kernel.z0 * uh), n_run),
            _ones_term(kernel, ph.size, n_run),
            self.fs,
            float(kernel.reference_resistance) if filt else 0.0,
            _filter_edge(lp, n, n_pad) if filt else np.zeros(n),
            float(target.p_m_slope),
        )
        self.lean = run_kernel(kernel, n_run)
        x = np.zeros(self.lean.n0 + n_run)
        width = max(n_lead, n + 2 * n_pad + 2)
        self.buffers = (
            x, self.lean.n0, self.lean.quiet_conv(n_run), np.empty(n_run), np.empty(n_run),
            np.empty(n_run), np.zeros((2, width)),
        )  # fmt: skip
        self.lp = _lowpass_record(lp, n, n_pad)

    def candidate(self, reed: ReedParameters) -> tuple:
        """The compiled evaluation's ``cand`` record of a candidate (:func:`_evaluate`)."""
        k = self.kernel
        model = scheme_records(reed, self.fs, self.lean.h0, k.z0, k.rho)
        return model, reed.k, reed.S, reed.p_m

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
        return self.evaluate_into(reed, out, None)

    def evaluate_into(self, reed: ReedParameters, out: np.ndarray, jac: tuple | None) -> str:
        """:meth:`residuals_into`, and with a ``jac`` record (:func:`_evaluate`) the Jacobian."""
        try:
            check_stability(reed, self.fs)
        except ValueError as exc:
            return f"unstable: {exc}"
        k = self.kernel
        cand = (scheme_records(reed, self.fs, self.lean.h0, k.z0, k.rho), reed.k, reed.S, reed.p_m)
        with np.errstate(all="ignore"):
            code = _evaluate(out, self.win, self.lp, self.buffers, cand, jac)
        return REASONS.get(int(code), "")


def _lowpass_record(lp, n: int, n_pad: int) -> tuple:
    """:func:`measured_lowpass`'s record for the measurement's FIR ``lp`` (None: a dummy)."""
    if lp is None:
        return (
            (np.zeros(1), np.zeros(1), fft_tables(4, real_nyquist=True)),
            np.zeros((5, 5)),
            np.zeros(1),
            0,
        )
    taps = np.asarray(lp.taps, dtype=float)
    # segments of 2M samples give M outputs each once the L taps fit: L - 1 <= M
    m = max(256, 1 << int(math.ceil(math.log2(max(taps.size - 1, 1)))))
    # the taps' spectrum and the FFT tables are the same for every window the filter
    # serves (0.2 ms of tables each): made once and kept on the filter, only read
    cache = lp.__dict__.setdefault("_segment_spectra", {})
    if m not in cache:
        spec = np.fft.rfft(taps, 2 * m)
        cache[m] = (spec.real.copy(), spec.imag.copy(), fft_tables(m, real_nyquist=True))
    fir = cache[m]
    # zero prefix of M, the input, and enough zeros for the last segment
    n_blocks = -(-n // m)
    buf = np.zeros(max((n_blocks - 1) * m + taps.size + 2 * m, m + n + 2 * n_pad))
    return fir, np.zeros((5, m + 1)), buf, taps.size


__all__ = [
    "WindowEvaluator",
    "history_term",
    "measured_lowpass",
    "model_residual",
    "start_run",
    "tangent_start",
]
