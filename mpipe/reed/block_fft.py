"""The small radix-2 FFT of the model's partitioned convolution, compiled with numba.

The model's kernel (:mod:`mpipe.reed.kernels`) transforms one block of the forward wave p+
per B samples and inverts one accumulated spectrum per delay-line level; these routines
do that in place, without allocation, on blocks of a power-of-two length.
:func:`fft_tables` builds the bit reversal and twiddle tables (``tables``) they read.

References
----------
physics.md D.4 (uniformly partitioned overlap-save convolution).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


def fft_tables(b: int, real_nyquist: bool = False) -> tuple[np.ndarray, ...]:
    """Bit reversal, FFT twiddles and real-FFT twiddles for blocks of B samples.

    Returns ``(bitrev, tw_re, tw_im, w_re, w_im)``, the ``tables`` of :func:`rfft_block` and
    :func:`irfft_last_half`. With ``real_nyquist`` the last real-FFT twiddle's imaginary
    part, sin(-pi) ~ -1.2e-16 in floating point, is set to 0: :func:`rfft_block` then gives
    bin M the exactly real value of a real sequence's Nyquist bin (the lean levels' and
    the low-pass's convention; the uniform kernel keeps the plain tables).
    """
    bits = int(round(math.log2(b)))
    idx = np.arange(b)
    bitrev = np.zeros(b, dtype=np.int64)
    for k in range(bits):
        bitrev |= ((idx >> k) & 1) << (bits - 1 - k)
    tw = np.concatenate(
        [np.exp(-1j * np.pi * np.arange(half) / half) for half in 2 ** np.arange(bits)]
    )
    rw = np.exp(-2j * np.pi * np.arange(b + 1) / (2 * b))
    if real_nyquist:
        rw[b] = rw[b].real
    return bitrev, tw.real.copy(), tw.imag.copy(), rw.real.copy(), rw.imag.copy()


@njit(cache=True)
def _fft(re, im, bitrev, tw_re, tw_im):
    """In-place radix-2 complex FFT (forward, exp(-i...)) of length n = len(re) >= 4.

    ``tw_re, tw_im`` hold the twiddles of every stage: the stage combining halves of length
    ``half`` reads exp(-i pi k / half), k < half, at offset ``half - 1``. The first two
    stages, whose twiddles are 1 and -i, are fused into one radix-4 pass.
    """
    n = re.size
    for i in range(n):
        j = bitrev[i]
        if j > i:
            t = re[i]
            re[i] = re[j]
            re[j] = t
            t = im[i]
            im[i] = im[j]
            im[j] = t
    for g in range(n // 4):
        xr = re[4 * g : 4 * g + 4]
        xi = im[4 * g : 4 * g + 4]
        a0r = xr[0] + xr[1]
        a0i = xi[0] + xi[1]
        a1r = xr[0] - xr[1]
        a1i = xi[0] - xi[1]
        a2r = xr[2] + xr[3]
        a2i = xi[2] + xi[3]
        a3r = xr[2] - xr[3]
        a3i = xi[2] - xi[3]
        xr[0] = a0r + a2r
        xi[0] = a0i + a2i
        xr[2] = a0r - a2r
        xi[2] = a0i - a2i
        # -i * a3 = a3i - i a3r
        xr[1] = a1r + a3i
        xi[1] = a1i - a3r
        xr[3] = a1r - a3i
        xi[3] = a1i + a3r
    half = 4
    while half < n:
        wr = tw_re[half - 1 : 2 * half - 1]
        wi = tw_im[half - 1 : 2 * half - 1]
        for g in range(n // (2 * half)):
            lo = 2 * half * g
            ar = re[lo : lo + half]
            ai = im[lo : lo + half]
            br = re[lo + half : lo + 2 * half]
            bi = im[lo + half : lo + 2 * half]
            for k in range(half):
                xr2 = br[k] * wr[k] - bi[k] * wi[k]
                xi2 = br[k] * wi[k] + bi[k] * wr[k]
                br[k] = ar[k] - xr2
                bi[k] = ai[k] - xi2
                ar[k] += xr2
                ai[k] += xi2
        half *= 2


@njit(cache=True)
def rfft_block(x, start, out_re, out_im, zr, zi, tables):
    """Spectrum (bins 0..M) of the real segment x[start : start + 2M], M = len(zr).

    Packs even and odd samples into one complex sequence z of length M, transforms it and
    splits the result: X[k] = E[k] + w^k O[k] with w = exp(-i pi / M). ``tables`` is
    :func:`fft_tables` of M. Bins 0 and M are set apart; bins 1..M-1 pair z[k] with
    z[M - k] through slices (no modulo indexing: this loop cost as much as the FFT). Bin
    M's imaginary part is ``w_im[M] z_im[0]``: sin(-pi) z_im[0] ~ 1e-16 z_im[0] with the
    plain tables, exactly 0 with ``real_nyquist`` tables.
    """
    bitrev, tw_re, tw_im, w_re, w_im = tables
    m = zr.size
    xs = x[start : start + 2 * m]
    for n in range(m):
        zr[n] = xs[2 * n]
        zi[n] = xs[2 * n + 1]
    _fft(zr, zi, bitrev, tw_re, tw_im)
    out_re[0] = zr[0] + zi[0]
    out_im[0] = 0.0
    out_re[m] = zr[0] - zi[0]
    out_im[m] = 0.0 + w_im[m] * zi[0]
    za_r = zr[1:m]
    za_i = zi[1:m]
    wr = w_re[1:m]
    wi = w_im[1:m]
    ore = out_re[1:m]
    oim = out_im[1:m]
    for k in range(m - 1):
        kb = m - 2 - k
        ar = za_r[k]
        ai = za_i[k]
        br = za_r[kb]
        bi = za_i[kb]
        er = 0.5 * (ar + br)
        ei = 0.5 * (ai - bi)
        orr = 0.5 * (ai + bi)
        oi = -0.5 * (ar - br)
        ore[k] = er + wr[k] * orr - wi[k] * oi
        oim[k] = ei + wr[k] * oi + wi[k] * orr


@njit(cache=True)
def irfft_last_half(x_re, x_im, out, zr, zi, tables):
    """Second half (samples M..2M-1) of the real inverse FFT of bins 0..M, M = len(zr)."""
    bitrev, tw_re, tw_im, w_re, w_im = tables
    m = zr.size
    for k in range(m):
        ar = x_re[k]
        ai = x_im[k]
        br = x_re[m - k]
        bi = -x_im[m - k]
        er = 0.5 * (ar + br)
        ei = 0.5 * (ai + bi)
        dr = 0.5 * (ar - br)
        di = 0.5 * (ai - bi)
        # odd part: the difference times the conjugate twiddle
        orr = dr * w_re[k] + di * w_im[k]
        oi = di * w_re[k] - dr * w_im[k]
        # Z = E + i O, conjugated so that a forward FFT computes the inverse
        zr[k] = er - oi
        zi[k] = -(ei + orr)
    _fft(zr, zi, bitrev, tw_re, tw_im)
    scale = 1.0 / m
    half = m // 2
    for n in range(half, m):
        out[2 * (n - half)] = zr[n] * scale
        out[2 * (n - half) + 1] = -zi[n] * scale
