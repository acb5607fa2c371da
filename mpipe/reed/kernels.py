"""The compiled time-domain clarinet model (numba): one kernel, :func:`run`.

:func:`run` takes the explicit scheme of :mod:`mpipe.reed.model` (the paper's Appendix A,
physics.md G.2-G.4) through n samples, one step n -> n+1 at a time by :func:`_step`. The
bore's history term ``q = sum_{j>=1} h_j p+(n+1-j)`` comes from a partition of the
reflection function (:class:`mpipe.reed.bore_kernel.Partition`): lags 1..B1-1 by a direct
sum (:func:`_spread`), then up to two frequency-domain delay lines of blocks B1 and B2
(:func:`_fdl_tail`). Every variant is this one source; numba compiles one specialisation
per combination of optional arguments, pruning the branches of those that are ``None``:

* every output (p, u, u_f, u_r, y, h, p-) with ``full`` given: :func:`~mpipe.reed.model.simulate`
  ("fast": the uniform partition of block B; "direct": every lag direct);
* the pressure only (``full=None``): the inversion's model runs
  (:func:`~mpipe.reed.model.simulate_pressure`, :mod:`mpipe.inversion.fit.fastpath`), with the
  two-level partition;
* with ``tangent`` given, also the forward sensitivities of the pressure to the reed
  parameters (:mod:`mpipe.reed.sensitivity`): each step's derivative
  (:func:`_step_tangent`) and the tangent of p+ through the same partition;
* ``q_ext`` adds a history share the caller convolved itself (the inversion's).

The plain reference the tests compare it with is :func:`mpipe.reed.scheme.run_reference`.
Both are exact convolutions: a block of B outputs only needs p+ at least B samples old,
which is all known when the block starts (physics.md D.4).

Records (tuples, so that numba types them and calls stay short):

``model``
    ``(reed, bore)`` of :func:`mpipe.reed.scheme.scheme_records`.
``conv``
    ``(head, fut, line1, line2)``: h[1..B1-1], the direct part's pending sums (at least
    ``n + len(head)`` samples) and each level's ``(level, f_re, f_im, work)``: the level
    ``(G_re, G_im, tables)`` (:class:`~mpipe.reed.bore_kernel.Partition`), the spectra of
    its delay line (the history's, :func:`history_spectra`; overwritten) and its scratch
    of shape ``(5, B + 1)``.

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

from mpipe.reed.block_fft import irfft_last_half, rfft_block


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
    at n+1, Pa. Returns (y, h, u_r, u_f, u, p+, p) at n+1.
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


@njit(inline="always")
def _step_tangent(d, j, dq, tstate, step, reed, bore):
    """Tangent of one :func:`_step` for column ``j`` of the seed matrix ``d``.

    ``d`` is :func:`mpipe.reed.sensitivity.coefficient_derivatives`' matrix, ``dq`` the
    tangent of the history term, ``tstate`` the tangent state (dy, dy_prev, ddp) at n,
    ``step`` the step's inputs and results (q, p_m, y, y_prev, dp, y_new, h, u_r, u_f).
    Returns the tangents (dy, dp+, dp) at n+1 (the formulas:
    :mod:`mpipe.reed.sensitivity`).
    """
    a1, a2, a3, b1, y_m, y_c, alpha, square, lam, s_fs = reed
    z0, rho, inv, z0p, two_over_rho = bore
    dy, dy_prev, ddp = tstate
    q, p_m, y, y_prev, dp, y_new, hh, ur, uf = step
    dy_new = d[0, j] * y + a1 * dy + d[1, j] * y_prev + a2 * dy_prev + d[3, j] * dp + b1 * ddp
    e = y - y_c
    if e > 0.0:
        de = dy - d[6, j]
        if square:
            dy_new += d[2, j] * (e * e) + a3 * (2.0 * e * de)
        else:
            dy_new += d[2, j] * e**alpha + a3 * (alpha * e ** (alpha - 1.0) * de)
    dur = d[4, j] * (y_new - y) + s_fs * (dy_new - dy)
    duf = 0.0
    if hh > 0.0:
        dhh = d[5, j] - dy_new
        lh = lam * hh
        lh2 = lh * lh
        dlh2 = 2.0 * lh * (d[8, j] * hh + lam * dhh)
        big_l = lh2 * z0p / rho
        dbig_l = dlh2 * z0p / rho
        w = 2.0 * q * inv + z0p * ur - p_m
        dw = 2.0 * dq * inv + z0p * dur - d[7, j]
        dbig_g = two_over_rho * (dlh2 * w + lh2 * dw)
        duf = -(2.0 * uf * dbig_l + dbig_g) / (2.0 * (abs(uf) + big_l))
    du = duf + dur
    dpp = (dq + z0 * du) * inv
    return dy_new, dpp, 2.0 * dpp - z0 * du


@njit(cache=True)
def history_spectra(x, n0, level):
    """Spectra of the P history blocks -1..-P of ``x`` for a level's delay line.

    ``level`` is (G_re, G_im, tables) of block B. Returns ``(f_re, f_im)`` of shape
    ``(max(P, 1), B + 1)``, slot ``c mod P`` holding the ``rfft`` of
    ``x[n0 + (c - 1) B : n0 + (c + 1) B]``: the delay line before the first sample.
    """
    g_re, _, tables = level
    block = tables[0].size
    n_part = g_re.shape[0]
    nb = block + 1
    f_re = np.zeros((max(n_part, 1), nb))
    f_im = np.zeros((max(n_part, 1), nb))
    zr = np.zeros(block)
    zi = np.zeros(block)
    for c in range(-n_part, 0):
        slot = c % n_part
        rfft_block(x, n0 + (c - 1) * block, f_re[slot], f_im[slot], zr, zi, tables)
    return f_re, f_im


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
def _fdl_tail(x, n0, blk, line):
    """Tail of one delay-line level for output block ``blk`` into ``work[4, :B]``.

    ``line`` is (level, f_re, f_im, work) with ``level`` = (G_re, G_im, tables) of block
    size B; block ``blk - 1`` of p+ has just been completed, so its spectrum enters the
    delay line (slot ``(blk - 1) mod P``) first.
    """
    level, f_re, f_im, work = line
    g_re, g_im, tables = level
    b = tables[0].size
    n_part = g_re.shape[0]
    acc_re = work[0, : b + 1]
    acc_im = work[1, : b + 1]
    zr = work[2, :b]
    zi = work[3, :b]
    if blk > 0:
        c = blk - 1
        rfft_block(x, n0 + (c - 1) * b, f_re[c % n_part], f_im[c % n_part], zr, zi, tables)
    _accumulate(acc_re, acc_im, g_re, g_im, f_re, f_im, (blk - 1) % n_part)
    irfft_last_half(acc_re, acc_im, work[4, :b], zr, zi, tables)


@njit(cache=True)
def _tangent_tails(xt, n0, blk, line, line_t):
    """:func:`_fdl_tail` of every tangent column j (``xt[j]``, spectra and work ``[j]``).

    ``line`` is the pressure's delay line (its level is shared), ``line_t`` the tangents'
    (ft_re, ft_im, work), one row per column.
    """
    level = line[0]
    ft_re, ft_im, wt = line_t
    for j in range(xt.shape[0]):
        _fdl_tail(xt[j], n0, blk, (level, ft_re[j], ft_im[j], wt[j]))


@njit(inline="always")
def _level_shape(line):
    """(B, on, tail) of a delay line: its block, whether it has partitions, its output."""
    blk = line[0][2][0].size
    return blk, line[0][0].shape[0] > 0, line[3][4, :blk]


@njit(inline="always")
def _advance(r, c, blk):
    """The next sample's position ``r`` in its block of ``blk`` and the block count ``c``."""
    r += 1
    if r == blk:
        return 0, c + 1
    return r, c


@njit(cache=True)
def run(x, n0, model, conv, state, pm, q_ext, out_p, full, tangent):
    """Run the scheme for n = len(out_p) samples; x holds p+ with n0 samples of history.

    Parameters (records: module docstring)
    --------------------------------------
    x : p+ buffer, Pa, ``n0 + n`` samples; the run writes ``x[n0:]``.
    model, conv : the scheme's and the partition's records.
    state : (y, y_prev, dp) at the start (m, m, Pa).
    pm : mouth pressure per sample, Pa.
    q_ext : None, or n samples (Pa) added to the history term.
    out_p : the pressure, Pa (written).
    full : None, or the arrays (u, u_f, u_r, y, h, p-) to fill as well.
    tangent : None, or (d, dy, dy_prev, ddp, xt, fut_t, line1, line2, out_dp, q_t):
        the seed matrix d (rows :data:`mpipe.reed.sensitivity.SEED_ROWS`, one column per
        parameter or input perturbation), the tangent state per column (updated in
        place), the tangent of p+ (``xt[j]``, history given), its pending direct sums, its
        delay lines ((f_re, f_im, work) with one row per column, on ``conv``'s levels), the
        output d p / d theta_j, and ``q_t[j]`` (n samples, Pa per unit) added to column j's
        tangent of the history term (the tangent of ``q_ext``).

    Returns the final (y, y_prev, dp).
    """
    reed, bore = model
    head, fut, line1, line2 = conv
    y, y_prev, dp = state
    n = out_p.size
    _seed(fut, n, x, n0, head)
    blk1, on1, tail1 = _level_shape(line1)
    blk2, on2, tail2 = _level_shape(line2)
    # records unpacked once, outside the loop: an array taken from a tuple is a new
    # reference, counted up and down (atomically) wherever it is taken
    if full is not None:
        out_u, out_uf, out_ur, out_y, out_h, out_pminus = full
    if tangent is not None:
        d, dy, dy_prev, ddp, xt, fut_t, lt1, lt2, out_dp, q_t = tangent
        wt1 = lt1[2]
        wt2 = lt2[2]
        for j in range(d.shape[1]):
            _seed(fut_t[j], n, xt[j], n0, head)
    r1 = r2 = c1 = c2 = 0  # position in, and number of, each level's current block
    for i in range(n):
        if on2 and r2 == 0:
            _fdl_tail(x, n0, c2, line2)
            if tangent is not None:
                _tangent_tails(xt, n0, c2, line2, lt2)
        if on1 and r1 == 0:
            _fdl_tail(x, n0, c1, line1)
            if tangent is not None:
                _tangent_tails(xt, n0, c1, line1, lt1)
        q = fut[i]
        if on1:
            q += tail1[r1]
        if on2:
            q += tail2[r2]
        if q_ext is not None:
            q += q_ext[i]
        p_m = pm[i]
        y_new, hh, ur, uf, u, pp, p = _step(q, p_m, y, y_prev, dp, reed, bore)
        x[n0 + i] = pp
        _spread(fut, i, pp, head)
        out_p[i] = p
        if full is not None:
            out_u[i] = u
            out_uf[i] = uf
            out_ur[i] = ur
            out_y[i] = y_new
            out_h[i] = hh
            out_pminus[i] = pp - bore[0] * u
        if tangent is not None:
            step = (q, p_m, y, y_prev, dp, y_new, hh, ur, uf)
            for j in range(d.shape[1]):
                # the tangent of the history term, summed in the pressure's order
                dq = fut_t[j, i]
                if on1:
                    dq += wt1[j, 4, r1]
                if on2:
                    dq += wt2[j, 4, r2]
                dq += q_t[j, i]
                tstate = (dy[j], dy_prev[j], ddp[j])
                dy_new, dpp, dpo = _step_tangent(d, j, dq, tstate, step, reed, bore)
                xt[j, n0 + i] = dpp
                _spread(fut_t[j], i, dpp, head)
                out_dp[j, i] = dpo
                dy_prev[j] = dy[j]
                dy[j] = dy_new
                ddp[j] = d[7, j] - dpo
        y_prev = y
        y = y_new
        dp = p_m - p
        r1, c1 = _advance(r1, c1, blk1)
        r2, c2 = _advance(r2, c2, blk2)
    return y, y_prev, dp
