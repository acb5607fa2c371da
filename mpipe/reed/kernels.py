"""Compiled per-sample scheme of the time-domain clarinet model (numba).

Two kernels run the explicit scheme of :mod:`mpipe.reed.model` (the paper's Appendix A,
physics.md G.2-G.4) sample by sample; both take one step n -> n+1 with :func:`_step`, which
numba inlines into each loop, and differ only in how they form the bore's history term
``q = sum_{j>=1} h_j p+(n+1-j)`` and what they keep:

:func:`_run`
    Every output (p, u, u_f, u_r, y, h, p-) for any mouth-pressure series; lags 1..B-1 by a
    direct sum (:func:`_spread`), lags >= B by a uniformly partitioned frequency-domain
    delay line of block B (or every lag direct). The ``"fast"`` and ``"direct"`` methods of
    :func:`mpipe.reed.model.simulate`.
:func:`_run_pressure`
    Pressure only, constant mouth pressure, no allocation: the lean kernel of the inversion
    (:mod:`mpipe.inversion.fastpath`), with a two-level partition of the reflection
    function (:class:`mpipe.reed.bore_kernel.LeanKernel`).

Both are exact convolutions: a block of B outputs only needs p+ at least B samples old,
which is all known when the block starts (physics.md D.4).

No kernel uses fastmath: with reassociation or contraction (fma) LLVM orders the sums
itself, and numba keeps several differently optimised copies of a kernel (each caller
links its own; which copy runs depends on what was compiled fresh and what was loaded
from the on-disk cache), so the numbers depended on the cache's state. Every sum here has
its order written in the source; the loops that need SIMD are elementwise.

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


@njit(cache=True)
def _spread(fut, i, v, head):
    """Add ``v h[j]`` to ``fut[i + j]`` for lags j = 1..H-1 with ``i + j >= 0``.

    The direct part of the history term, ``q(n) = sum_{j=1}^{H-1} h_j p+(n-j)``, in
    transposed form: each new sample ``v = p+(i)`` is spread at once over the H-1 later
    outputs it reaches (``head`` = h[1..H-1]), so ``fut[n]`` holds q(n) when sample n
    starts. Each q(n) then sums its terms oldest first, an order fixed in the source, and
    the loop over j is elementwise, which LLVM runs on SIMD lanes without fastmath. (A dot
    product needs fastmath's reassociation for SIMD, and LLVM then picks the order per
    compiled copy of a kernel: a fresh compile and numba's cache gave different numbers.)
    """
    lo = -1 - i if i < -1 else 0
    dst = fut[i + 1 + lo : i + 1 + head.size]
    src = head[lo:]
    for j in range(src.size):
        dst[j] += v * src[j]


@njit(cache=True)
def _seed(fut, n, x, n0, head):
    """Zero ``fut[: n + K]`` and spread the history ``x[n0 - K : n0]`` into it, K = len(head).

    Leaves in ``fut[i]`` the history's share of q(i) for the run's first K outputs.
    """
    n_head = head.size
    for j in range(n + n_head):
        fut[j] = 0.0
    for i in range(-n_head, 0):
        _spread(fut, i, x[n0 + i], head)


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
    if b > 0:
        c = b - 1
        slot = c % n_part
        _rfft(
            x, n0 + (c - 1) * block, f_re[slot], f_im[slot], zr, zi, bitrev, tw_re, tw_im,
            w_re, w_im,
        )  # fmt: skip
    _accumulate(acc_re, acc_im, g_re, g_im, f_re, f_im, (b - 1) % n_part)
    _irfft_last_half(acc_re, acc_im, tail, zr, zi, bitrev, tw_re, tw_im, w_re, w_im)


@njit(cache=True)
def _run(
    x, n0, n, head, h0, z0, rho, a1, a2, a3, b1, y_m, y_c, alpha, lam, s_fs, pm, y,
    y_prev, dp, block, g_re, g_im, bitrev, tw_re, tw_im, w_re, w_im, out_p, out_u, out_uf,
    out_ur, out_y, out_h, out_pminus,
):  # fmt: skip
    """Run the scheme for n samples; x holds p+ with n0 samples of history before it.

    ``head`` is h[1], ..., h[H-1] (lags 1 to H-1, run direct). With P = len(g_re)
    > 0, lags block..(P+1)*block-1 run by partitioned FFT (then H must equal ``block``).
    Returns the final (y, y_prev, dp).
    """
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
    fut = np.empty(n + head.size)
    _seed(fut, n, x, n0, head)
    for i in range(n):
        m = n0 + i
        r = i % block
        if n_part > 0 and r == 0:
            _uniform_tail(
                x, n0, i // block, g_re, g_im, f_re, f_im, acc_re, acc_im, zr, zi, tail, tables
            )
        q = fut[i]
        if n_part > 0:
            q += tail[r]
        p_m = pm[i]
        y_new, hh, ur, uf, u, pp, p = _step(q, p_m, y, y_prev, dp, reed, bore)
        x[m] = pp
        _spread(fut, i, pp, head)
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


@njit(cache=True)
def _accumulate(acc_re, acc_im, g_re, g_im, f_re, f_im, newest):
    """Acc = sum_k G_k F_{newest - k}: the spectral products of the delay line.

    The loop over bins is elementwise (SIMD lanes without fastmath) and the sum over
    partitions runs in order: no fastmath here, whose contraction (fma) LLVM applied
    differently in each compiled copy of the kernels (a fresh compile against numba's
    cache) and so changed the numbers.
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
    x, n0, n, head, h0, z0, rho, a1, a2, a3, b1, y_m, y_c, alpha, lam, s_fs, p_m, y,
    y_prev, dp, level1, f1_re, f1_im, work1, level2, f2_re, f2_im, work2, fut, out_p, q_ext,
):  # fmt: skip
    """The scheme of :func:`_run` for a constant mouth pressure, pressure output only.

    The lean kernel of the inversion, with a two-level (non-uniform) partition of the
    reflection function: lags 1..B1-1 direct, lags B1..B2-1 by a frequency-domain delay
    line of block B1 (``level1``), lags >= B2 by one of block B2 (``level2``); see
    :class:`mpipe.reed.bore_kernel.LeanKernel`. Each level's history spectra ``f*_re,
    f*_im`` come precomputed (:func:`history_spectra`; overwritten here) and the scratch
    ``work*`` (shape ``(5, B + 1)``) and ``fut`` (the direct part's pending sums, at least
    ``n + B1`` samples) are the caller's, so a run allocates nothing. ``q_ext`` (n
    samples, Pa) is added to the history term: the share of p+ history that the caller
    convolved itself (the inversion's, :mod:`mpipe.inversion.fastpath`), zeros otherwise.
    Returns the final (y, y_prev, dp).
    """
    _seed(fut, n, x, n0, head)
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
        q = fut[i]
        if on1:
            q += tail1[r1]
        if on2:
            q += tail2[r2]
        q += q_ext[i]
        y_new, _, _, _, _, pp, p = _step(q, p_m, y, y_prev, dp, reed, bore)
        x[m] = pp
        _spread(fut, i, pp, head)
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
