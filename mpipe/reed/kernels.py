"""Compiled per-sample scheme of the time-domain clarinet model (numba).

Two kernels run the explicit scheme of :mod:`mpipe.reed.model` (the paper's Appendix A,
physics.md G.2-G.4) sample by sample; both take one step n -> n+1 with :func:`_step`, which
numba inlines into each loop, and differ only in how they form the bore's history term
``q = sum_{j>=1} h_j p+(n+1-j)`` and what they keep:

:func:`_run`
    Every output (p, u, u_f, u_r, y, h, p-) for any mouth-pressure series; lags 1..B-1 by a
    direct dot product, lags >= B by a uniformly partitioned frequency-domain delay line of
    block B (or every lag direct). The ``"fast"`` and ``"direct"`` methods of
    :func:`mpipe.reed.model.simulate`.
:func:`_run_pressure`
    Pressure only, constant mouth pressure, no allocation: the lean kernel of the inversion
    (:mod:`mpipe.inversion.fastpath`), with a two-level partition of the reflection
    function (:class:`mpipe.reed.bore_kernel.LeanKernel`).

Both are exact convolutions: a block of B outputs only needs p+ at least B samples old,
which is all known when the block starts (physics.md D.4).

References
----------
Chatziioannou & van Walstijn 2012, Appendix A, eqs. (A.1)-(A.17); physics.md D.2 step 6,
D.4, G.2-G.4.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from mpipe.reed.block_fft import _irfft_last_half, _rfft, _rfft_lean


@njit(cache=True, fastmath={"reassoc", "contract"})
def _dot(a, xs):
    """Sum of a[k] xs[k] over k < len(a); xs is a contiguous slice.

    Reassociation lets LLVM split the sum over SIMD lanes; the result differs from a
    sequential sum only by rounding. Indexing a slice by a ``range`` index (not
    ``start + k``) spares numba's negative-index wraparound, which blocks vectorisation.
    """
    s = 0.0
    for k in range(a.size):
        s += a[k] * xs[k]
    return s


@njit(inline="always")
def _step(q, p_m, y, y_prev, dp, reed, bore):
    """One step n -> n+1 of the scheme, given the history term ``q`` of the backward wave.

    ``reed`` is (a1, a2, a3, b1, y_m, y_c, alpha, square, lam, s_fs) with ``square`` =
    (alpha == 2) and ``s_fs`` = S fs (m^2/s); ``bore`` is (z0, rho, inv, z0p, two_over_rho)
    with inv = 1 / (1 - h0) and z0p = Z0 (1 + h0) / (1 - h0). ``p_m`` is the mouth pressure
    at n+1, Pa. Returns (y, h, u_r, u_f, u, p+, p) at n+1. Inlined into both kernels (numba
    IR inlining), so that they share one scheme at no cost per sample.
    """
    a1, a2, a3, b1, y_m, y_c, alpha, square, lam, s_fs = reed
    z0, rho, inv, z0p, two_over_rho = bore
    # 1. reed displacement, centred differences with explicit contact force (A.1)
    y_new = a1 * y + a2 * y_prev + b1 * dp
    e = y - y_c
    if e > 0.0:
        y_new += a3 * (e * e if square else e**alpha)
    # 2. opening, clipped: the Bernoulli flow stops when the reed shuts the channel
    hh = y_m - y_new
    if hh < 0.0:
        hh = 0.0
    # 3. reed-induced flow by backward difference (A.3)
    ur = s_fs * (y_new - y)
    # 4. (q, the history part of the backward wave (A.4), comes from the caller)
    # 5. Bernoulli flow from the quadratic, cancellation-free (A.10)-(A.17)
    uf = 0.0
    if hh > 0.0:
        lh2 = (lam * hh) ** 2
        big_l = lh2 * z0p / rho
        big_g = lh2 * two_over_rho * (2.0 * q * inv + z0p * ur - p_m)
        uf = -big_g / (big_l + math.sqrt(big_l * big_l + abs(big_g)))
    u = uf + ur
    # 6. forward wave, with the lag-0 reflection folded in
    pp = (q + z0 * u) * inv
    p = 2.0 * pp - z0 * u
    return y_new, hh, ur, uf, u, pp, p


@njit(cache=True)
def history_spectra(x, n0, block, n_part, bitrev, tw_re, tw_im, w_re, w_im):
    """Spectra of the P history blocks -1..-P of ``x`` for the frequency-domain delay line.

    Returns ``(f_re, f_im)`` of shape ``(max(P, 1), B + 1)``, slot ``c mod P`` holding the
    ``rfft`` of ``x[n0 + (c - 1) B : n0 + (c + 1) B]``: what :func:`_run` computes before
    its first sample. Built once per window (the history does not depend on the candidate)
    and handed to :func:`_run_pressure`.
    """
    nb = block + 1
    f_re = np.zeros((max(n_part, 1), nb))
    f_im = np.zeros((max(n_part, 1), nb))
    zr = np.zeros(block)
    zi = np.zeros(block)
    for c in range(-n_part, 0):
        slot = c % n_part
        _rfft(
            x, n0 + (c - 1) * block, f_re[slot], f_im[slot], zr, zi, bitrev, tw_re, tw_im,
            w_re, w_im,
        )  # fmt: skip
    return f_re, f_im


@njit(cache=True)
def _uniform_tail(x, n0, b, g_re, g_im, f_re, f_im, acc_re, acc_im, zr, zi, tail, tables):
    """Tail (lags >= B) of :func:`_run`'s uniform delay line for output block ``b``.

    Block ``b - 1`` of p+ has just been completed: its spectrum enters slot ``(b - 1) mod
    P``, then ``acc = sum_k G_k F_{b-1-k}`` and the second half of its inverse go to
    ``tail``. ``tables`` is (bitrev, tw_re, tw_im, w_re, w_im) of block B.
    """
    bitrev, tw_re, tw_im, w_re, w_im = tables
    block = zr.size
    n_part = g_re.shape[0]
    nb = block + 1
    if b > 0:
        c = b - 1
        slot = c % n_part
        _rfft(
            x, n0 + (c - 1) * block, f_re[slot], f_im[slot], zr, zi, bitrev, tw_re, tw_im,
            w_re, w_im,
        )  # fmt: skip
    # the products are summed here, not by _accumulate: without its fastmath, so that the
    # fast kernel keeps its exact rounding (the lean kernel's differs by contraction)
    acc_re[:] = 0.0
    acc_im[:] = 0.0
    for k in range(n_part):
        slot = (b - 1 - k) % n_part
        gr = g_re[k]
        gi = g_im[k]
        fr = f_re[slot]
        fi = f_im[slot]
        for j in range(nb):
            acc_re[j] += gr[j] * fr[j] - gi[j] * fi[j]
            acc_im[j] += gr[j] * fi[j] + gi[j] * fr[j]
    _irfft_last_half(acc_re, acc_im, tail, zr, zi, bitrev, tw_re, tw_im, w_re, w_im)


@njit(cache=True)
def _run(
    x, n0, n, head_rev, h0, z0, rho, a1, a2, a3, b1, y_m, y_c, alpha, lam, s_fs, pm, y,
    y_prev, dp, block, g_re, g_im, bitrev, tw_re, tw_im, w_re, w_im, out_p, out_u, out_uf,
    out_ur, out_y, out_h, out_pminus,
):  # fmt: skip
    """Run the scheme for n samples; x holds p+ with n0 samples of history before it.

    ``head_rev`` is h[H-1], ..., h[1] (lags H-1 down to 1, run direct). With P = len(g_re)
    > 0, lags block..(P+1)*block-1 run by partitioned FFT (then H must equal ``block``).
    Returns the final (y, y_prev, dp).
    """
    n_head = head_rev.size
    n_part = g_re.shape[0]
    inv = 1.0 / (1.0 - h0)
    bore = (z0, rho, inv, z0 * (1.0 + h0) * inv, 2.0 / rho)
    reed = (a1, a2, a3, b1, y_m, y_c, alpha, alpha == 2.0, lam, s_fs)
    tables = (bitrev, tw_re, tw_im, w_re, w_im)
    # work arrays, allocated once before the loop; the frequency-domain delay line holds
    # the spectrum of input block c (x[n0 + c B : n0 + (c + 1) B]) in slot c mod P,
    # starting with the history blocks -1..-P
    f_re, f_im = history_spectra(x, n0, block, n_part, *tables)
    acc_re = np.zeros(block + 1)
    acc_im = np.zeros(block + 1)
    zr = np.zeros(block)
    zi = np.zeros(block)
    tail = np.zeros(block)
    for i in range(n):
        m = n0 + i
        r = i % block
        if n_part > 0 and r == 0:
            _uniform_tail(
                x, n0, i // block, g_re, g_im, f_re, f_im, acc_re, acc_im, zr, zi, tail, tables
            )
        q = _dot(head_rev, x[m - n_head : m])
        if n_part > 0:
            q += tail[r]
        p_m = pm[i]
        y_new, hh, ur, uf, u, pp, p = _step(q, p_m, y, y_prev, dp, reed, bore)
        x[m] = pp
        out_p[i] = p
        out_u[i] = u
        out_uf[i] = uf
        out_ur[i] = ur
        out_y[i] = y_new
        out_h[i] = hh
        out_pminus[i] = pp - z0 * u
        y_prev = y
        y = y_new
        dp = p_m - p
    return y, y_prev, dp


@njit(cache=True, fastmath={"reassoc", "contract"})
def _accumulate(acc_re, acc_im, g_re, g_im, f_re, f_im, newest):
    """Acc = sum_k G_k F_{newest - k}: the spectral products of the delay line.

    Reassociation lets the inner loop over bins run on SIMD lanes; the sum over partitions
    keeps its order, so the result differs from :func:`_run`'s only by contraction (fma).
    """
    n_part = g_re.shape[0]
    nb = acc_re.size
    for j in range(nb):
        acc_re[j] = 0.0
        acc_im[j] = 0.0
    for k in range(n_part):
        slot = newest - k
        if slot < 0:
            slot += n_part
        gr = g_re[k]
        gi = g_im[k]
        fr = f_re[slot]
        fi = f_im[slot]
        for j in range(nb):
            acc_re[j] += gr[j] * fr[j] - gi[j] * fi[j]
            acc_im[j] += gr[j] * fi[j] + gi[j] * fr[j]


@njit(cache=True)
def _fdl_tail(x, n0, blk, level, f_re, f_im, work):
    """Tail of one delay-line level for output block ``blk`` into ``work[4, :B]``.

    ``level`` is (G_re, G_im, bitrev, tw_re, tw_im, w_re, w_im) of block size B; block
    ``blk - 1`` of p+ has just been completed, so its spectrum enters the delay line first.
    """
    g_re, g_im, bitrev, tw_re, tw_im, w_re, w_im = level
    b = bitrev.size
    n_part = g_re.shape[0]
    acc_re = work[0, : b + 1]
    acc_im = work[1, : b + 1]
    zr = work[2, :b]
    zi = work[3, :b]
    tail = work[4, :b]
    if blk > 0:
        c = blk - 1
        _rfft_lean(
            x, n0 + (c - 1) * b, f_re[c % n_part], f_im[c % n_part], zr, zi, bitrev, tw_re,
            tw_im, w_re, w_im,
        )  # fmt: skip
    _accumulate(acc_re, acc_im, g_re, g_im, f_re, f_im, (blk - 1) % n_part)
    _irfft_last_half(acc_re, acc_im, tail, zr, zi, bitrev, tw_re, tw_im, w_re, w_im)


@njit(cache=True)
def _run_pressure(
    x, n0, n, head_rev, h0, z0, rho, a1, a2, a3, b1, y_m, y_c, alpha, lam, s_fs, p_m, y,
    y_prev, dp, level1, f1_re, f1_im, work1, level2, f2_re, f2_im, work2, out_p,
):  # fmt: skip
    """The scheme of :func:`_run` for a constant mouth pressure, pressure output only.

    The lean kernel of the inversion, with a two-level (non-uniform) partition of the
    reflection function: lags 1..B1-1 direct, lags B1..B2-1 by a frequency-domain delay
    line of block B1 (``level1``), lags >= B2 by one of block B2 (``level2``); see
    :class:`mpipe.reed.bore_kernel.LeanKernel`. Each level's history spectra ``f*_re,
    f*_im`` come precomputed (:func:`history_spectra`; overwritten here) and the scratch
    ``work*`` (shape ``(5, B + 1)``) is the caller's, so a run allocates nothing. Returns
    the final (y, y_prev, dp).
    """
    n_head = head_rev.size
    blk1 = level1[2].size
    blk2 = level2[2].size
    on1 = level1[0].shape[0] > 0
    on2 = level2[0].shape[0] > 0
    tail1 = work1[4, :blk1]
    tail2 = work2[4, :blk2]
    inv = 1.0 / (1.0 - h0)
    bore = (z0, rho, inv, z0 * (1.0 + h0) * inv, 2.0 / rho)
    reed = (a1, a2, a3, b1, y_m, y_c, alpha, alpha == 2.0, lam, s_fs)
    r1 = 0
    r2 = 0
    c1 = 0
    c2 = 0
    for i in range(n):
        m = n0 + i
        if on2 and r2 == 0:
            _fdl_tail(x, n0, c2, level2, f2_re, f2_im, work2)
        if on1 and r1 == 0:
            _fdl_tail(x, n0, c1, level1, f1_re, f1_im, work1)
        q = _dot(head_rev, x[m - n_head : m])
        if on1:
            q += tail1[r1]
        if on2:
            q += tail2[r2]
        y_new, _, _, _, _, pp, p = _step(q, p_m, y, y_prev, dp, reed, bore)
        x[m] = pp
        out_p[i] = p
        y_prev = y
        y = y_new
        dp = p_m - p
        r1 += 1
        if r1 == blk1:
            r1 = 0
            c1 += 1
        r2 += 1
        if r2 == blk2:
            r2 = 0
            c2 += 1
    return y, y_prev, dp
