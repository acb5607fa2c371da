"""Time-domain clarinet model: lumped reed coupled to the bore's reflection function.

The explicit scheme of the paper's Appendix A with its signs restored (physics.md G.2-G.4).
Per sample n -> n+1:

1. reed displacement by centred differences, ``y(n+1) = a1 y(n) + a2 y(n-1) + b1 dp(n)
   + a3 [y(n) - y_c]_+^alpha``;
2. opening ``h = max(y_m - y(n+1), 0)`` and reed flow ``u_r = S (y(n+1) - y(n)) / T``;
3. the bore's history term ``q = sum_{j>=1} h_j p+(n+1-j)``;
4. Bernoulli flow ``u_f`` in closed form from the quadratic of physics.md G.3, with the
   lag-0 tap ``h_0`` folded in exactly (physics.md D.2 step 6):
   ``q' = q / (1 - h_0)`` and ``Z0' = Z0 (1 + h_0) / (1 - h_0)`` replace p- and Z0;
5. ``u = u_f + u_r``, ``p+(n+1) = (q + Z0 u) / (1 - h_0)``, ``p- = p+ - Z0 u``,
   ``p = p+ + p-`` and ``dp(n+1) = p_m(n+1) - p``.

Three interchangeable kernels compute step 3:

``"fast"``
    Exact partitioned convolution: lags 1..B-1 run as a direct dot product every sample;
    lags >= B run blockwise in the frequency domain (uniformly partitioned overlap-save
    with a frequency-domain delay line). That works because a block of B outputs only
    needs p+ at least B samples old, which is all known when the block starts
    (physics.md D.4). The FFT is a small radix-2 implementation compiled with numba.
``"direct"``
    The same compiled loop with every lag in the direct dot product.
``"numpy"``
    A plain Python/NumPy loop written from the equations, kept as a slow reference.

Time axis: output sample ``i`` is the state at ``t[i] = (i + 1) / fs``; ``t = 0`` is the
initial state (rest, or the end of a given history), which is not part of the output.

References
----------
Chatziioannou & van Walstijn 2012, Appendix A, eqs. (A.1)-(A.17); physics.md D.2, D.4, G.
"""

from __future__ import annotations

import functools
import logging
import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from mpipe.acoustics.air import Air
from mpipe.acoustics.reflection import ReflectionFunction
from mpipe.reed.parameters import ReedParameters, check_stability

log = logging.getLogger(__name__)

METHODS = ("fast", "direct", "numpy")

# Block size of the partitioned convolution (= number of direct taps + 1). On the shipped
# instrument (6822 taps at 100 kHz) 128 and 256 were fastest of 32..1024, within the noise
# of each other; 64 and 512 were about 35 % slower (benchmarks/bench_model.py --head-taps).
DEFAULT_HEAD_TAPS = 128

# Samples used to refine a playing-frequency estimate (see playing_frequency).
_REFINE_SAMPLES = 2**14


@dataclass(frozen=True)
class BoreKernel:
    """The bore's reflection function prepared for repeated simulation.

    Built once per (bore, air, fs) by :func:`prepare_bore` and reused for every run. All
    arrays are read-only.

    Attributes
    ----------
    h : ndarray
        Reflection function, ``h[j]`` the tap at a lag of j samples (dimensionless).
    fs : float
        Sample rate, Hz.
    z0 : float
        Real characteristic impedance of the entry, Pa s/m^3 (the Z0 of the reflectance).
    rho : float
        Air density, kg/m^3.
    head_taps : int
        Block size B of the partitioned convolution: lags 1..B-1 run direct, lags >= B by FFT.
    tail_re, tail_im : ndarray
        Shape ``(P, B + 1)``: real and imaginary parts of the spectra (``rfft`` of length
        2B) of the tail partitions ``[h[B + p B : B + (p + 1) B], 0 * B]``.
    fft_bitrev : ndarray
        Bit-reversal permutation for the complex FFT of length B (int64).
    fft_tw_re, fft_tw_im : ndarray
        Twiddles of every FFT stage: ``exp(-i pi k / half)``, k < half, at offset
        ``half - 1``, for half = 1, 2, 4, ..., B/2.
    rfft_w_re, rfft_w_im : ndarray
        Twiddles ``exp(-2 pi i k / (2B))``, k = 0..B, for the real-FFT split.
    """

    h: np.ndarray
    fs: float
    z0: float
    rho: float
    head_taps: int
    tail_re: np.ndarray
    tail_im: np.ndarray
    fft_bitrev: np.ndarray
    fft_tw_re: np.ndarray
    fft_tw_im: np.ndarray
    rfft_w_re: np.ndarray
    rfft_w_im: np.ndarray

    @property
    def n_taps(self) -> int:
        """Number of taps of h, including lag 0."""
        return int(self.h.size)

    @property
    def n_partitions(self) -> int:
        """Number P of FFT partitions of the tail."""
        return int(self.tail_re.shape[0])

    @functools.cached_property
    def lean(self) -> LeanKernel:
        """The two-level partition of the lean kernel (:func:`prepare_lean`), made once."""
        return prepare_lean(self)


@dataclass(frozen=True)
class ModelState:
    """State of the model at one instant, to start a run from a known history.

    Attributes
    ----------
    p_plus : ndarray
        Past samples of the forward wave p+ at the entry, oldest first, ending at the
        current instant n; length at least ``len(h)`` (Pa).
    y : float
        Reed displacement at n, m.
    y_prev : float
        Reed displacement at n - 1, m.
    dp : float
        Pressure difference p_m - p at n, Pa.
    """

    p_plus: np.ndarray
    y: float
    y_prev: float
    dp: float


@dataclass(frozen=True)
class Simulation:
    """Output of :func:`simulate`, all signals at the mouthpiece entry.

    Attributes
    ----------
    fs : float
        Sample rate, Hz.
    t : ndarray
        Time of each sample, s; ``t[i] = (i + 1) / fs`` after the initial state.
    p : ndarray
        Mouthpiece pressure, Pa.
    u : ndarray
        Volume flow into the bore, m^3/s.
    u_f : ndarray
        Bernoulli flow through the reed channel, m^3/s.
    u_r : ndarray
        Reed-induced flow S dy/dt, m^3/s.
    y : ndarray
        Reed-tip displacement, positive towards closing, m.
    h : ndarray
        Reed opening max(y_m - y, 0), m.
    p_plus, p_minus : ndarray
        Forward and backward pressure waves, Pa.
    reed : ReedParameters
        Parameters used.
    mouth_pressure : ndarray
        Mouth pressure used at each sample (onset and noise included), Pa.
    final_state : ModelState
        State after the last sample, to continue the run.
    method : str
        Kernel used.
    """

    fs: float
    t: np.ndarray
    p: np.ndarray
    u: np.ndarray
    u_f: np.ndarray
    u_r: np.ndarray
    y: np.ndarray
    h: np.ndarray
    p_plus: np.ndarray
    p_minus: np.ndarray
    reed: ReedParameters
    mouth_pressure: np.ndarray
    final_state: ModelState
    method: str


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.flags.writeable = False
    return a


def prepare_bore(rf: ReflectionFunction, air: Air, head_taps: int | None = None) -> BoreKernel:
    """Precompute what every simulation on this bore needs.

    Parameters
    ----------
    rf : ReflectionFunction
        Reflection function of the bore at the model's sample rate.
    air : Air
        Air properties (only the density is used here), consistent with ``rf``.
    head_taps : int, optional
        Block size B of the fast kernel, a power of two in [8, 8192]; lags 1..B-1 run as a
        direct dot product, the rest by FFT. Default :data:`DEFAULT_HEAD_TAPS`.

    Returns
    -------
    BoreKernel

    Raises
    ------
    ValueError
        When ``head_taps`` is not a power of two in range, or h is empty or not finite.

    References
    ----------
    physics.md D.2 step 6 (index convention) and D.4 (partitioned convolution).
    """
    b = DEFAULT_HEAD_TAPS if head_taps is None else int(head_taps)
    if b < 8 or b > 8192 or b & (b - 1):
        raise ValueError(f"head_taps: expected a power of two in [8, 8192], got {head_taps!r}")
    h = np.asarray(rf.h, dtype=float)
    if h.ndim != 1 or h.size < 2 or not np.all(np.isfinite(h)):
        raise ValueError("reflection function: expected a finite 1-D array of >= 2 taps")
    if abs(h[0]) >= 0.5:
        # (1 - h0) divides p+; a lag-0 reflection this large means a wrong index shift
        raise ValueError(f"reflection function: lag-0 tap h[0] = {h[0]:g} is implausibly large")
    n = h.size
    n_part = max(0, -(-(n - b) // b))
    tail = np.zeros(n_part * b)
    if n_part:
        tail[: n - b] = h[b:]
    # Each partition is zero-padded to 2B, so overlap-save keeps the last B outputs exact.
    padded = np.zeros((n_part, 2 * b))
    padded[:, :b] = tail.reshape(n_part, b)
    spectra = np.fft.rfft(padded, axis=1) if n_part else np.zeros((0, b + 1), complex)
    bits = int(round(math.log2(b)))
    idx = np.arange(b)
    bitrev = np.zeros(b, dtype=np.int64)
    for k in range(bits):
        bitrev |= ((idx >> k) & 1) << (bits - 1 - k)
    tw = np.concatenate(
        [np.exp(-1j * np.pi * np.arange(half) / half) for half in 2 ** np.arange(bits)]
    )
    rw = np.exp(-2j * np.pi * np.arange(b + 1) / (2 * b))
    return BoreKernel(
        h=_readonly(h.copy()),
        fs=float(rf.fs),
        z0=float(rf.z0),
        rho=float(air.rho),
        head_taps=b,
        tail_re=_readonly(spectra.real.copy()),
        tail_im=_readonly(spectra.imag.copy()),
        fft_bitrev=_readonly(bitrev),
        fft_tw_re=_readonly(tw.real.copy()),
        fft_tw_im=_readonly(tw.imag.copy()),
        rfft_w_re=_readonly(rw.real.copy()),
        rfft_w_im=_readonly(rw.imag.copy()),
    )


def state_from_signals(
    p: np.ndarray, u: np.ndarray, z0: float, n_taps: int, y: float, y_prev: float, dp: float
) -> ModelState:
    """Model state from a measured or target history of pressure and flow.

    Parameters
    ----------
    p : ndarray
        Mouthpiece pressure history, Pa, oldest first, ending at the current instant.
    u : ndarray
        Volume flow into the bore at the same instants, m^3/s.
    z0 : float
        Real characteristic impedance of the entry, Pa s/m^3.
    n_taps : int
        Length of the reflection function; at least this many samples are needed.
    y, y_prev : float
        Reed displacement at the current and the previous instant, m.
    dp : float
        Pressure difference p_m - p at the current instant, Pa.

    Returns
    -------
    ModelState
        With ``p_plus = (p + Z0 u) / 2`` over the last ``n_taps`` samples.

    Raises
    ------
    ValueError
        When the histories differ in length or are shorter than ``n_taps``.

    References
    ----------
    physics.md 0 (p = p+ + p-, Z0 u = p+ - p-).
    """
    p = np.asarray(p, dtype=float)
    u = np.asarray(u, dtype=float)
    if p.shape != u.shape or p.ndim != 1:
        raise ValueError(f"p and u: expected 1-D arrays of one length, got {p.shape}, {u.shape}")
    if p.size < n_taps:
        raise ValueError(f"p, u: need at least n_taps = {n_taps} samples of history, got {p.size}")
    p_plus = 0.5 * (p[-n_taps:] + z0 * u[-n_taps:])
    return ModelState(p_plus=p_plus, y=float(y), y_prev=float(y_prev), dp=float(dp))


def reed_coefficients(reed: ReedParameters, fs: float) -> tuple[float, float, float, float]:
    """Coefficients of the centred-difference reed update.

    Parameters
    ----------
    reed : ReedParameters
        Reed parameters.
    fs : float
        Sample rate, Hz.

    Returns
    -------
    a1, a2, a3, b1 : float
        a1 and a2 dimensionless; a3 in m^(1-alpha), so that a3 [y - y_c]^alpha is in m;
        b1 in m/Pa.

    References
    ----------
    Chatziioannou & van Walstijn 2012, eqs. (A.1)-(A.2); physics.md G.2.
    """
    t = 1.0 / fs
    d = reed.m / t**2 + reed.m * reed.g / (2 * t)
    a1 = (2 * reed.m / t**2 - reed.k) / d
    a2 = -(reed.m / t**2 - reed.m * reed.g / (2 * t)) / d
    a3 = -reed.k_c / d
    b1 = 1.0 / d
    return a1, a2, a3, b1


# ---------------------------------------------------------------------------------------
# Compiled kernels


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
def _rfft(x, start, out_re, out_im, zr, zi, bitrev, tw_re, tw_im, w_re, w_im):
    """Spectrum (bins 0..M) of the real segment x[start : start + 2M], M = len(zr).

    Packs even and odd samples into one complex sequence of length M, transforms it and
    splits the result: X[k] = E[k] + w^k O[k] with w = exp(-i pi / M).
    """
    m = zr.size
    xs = x[start : start + 2 * m]
    for n in range(m):
        zr[n] = xs[2 * n]
        zi[n] = xs[2 * n + 1]
    _fft(zr, zi, bitrev, tw_re, tw_im)
    for k in range(m + 1):
        ka = k % m
        kb = (m - k) % m
        er = 0.5 * (zr[ka] + zr[kb])
        ei = 0.5 * (zi[ka] - zi[kb])
        orr = 0.5 * (zi[ka] + zi[kb])
        oi = -0.5 * (zr[ka] - zr[kb])
        out_re[k] = er + w_re[k] * orr - w_im[k] * oi
        out_im[k] = ei + w_re[k] * oi + w_im[k] * orr


@njit(cache=True)
def _irfft_last_half(x_re, x_im, out, zr, zi, bitrev, tw_re, tw_im, w_re, w_im):
    """Second half (samples M..2M-1) of the real inverse FFT of bins 0..M, M = len(zr)."""
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


@njit(cache=True)
def _run(
    x,
    n0,
    n,
    head_rev,
    h0,
    z0,
    rho,
    a1,
    a2,
    a3,
    b1,
    y_m,
    y_c,
    alpha,
    lam,
    s_fs,
    pm,
    y,
    y_prev,
    dp,
    block,
    g_re,
    g_im,
    bitrev,
    tw_re,
    tw_im,
    w_re,
    w_im,
    out_p,
    out_u,
    out_uf,
    out_ur,
    out_y,
    out_h,
    out_pminus,
):
    """Run the scheme for n samples; x holds p+ with n0 samples of history before it.

    ``head_rev`` is h[H-1], ..., h[1] (lags H-1 down to 1, run direct). With P = len(g_re)
    > 0, lags block..(P+1)*block-1 run by partitioned FFT (then H must equal ``block``).
    Returns the final (y, y_prev, dp).
    """
    n_head = head_rev.size
    n_part = g_re.shape[0]
    inv = 1.0 / (1.0 - h0)
    z0p = z0 * (1.0 + h0) * inv
    two_over_rho = 2.0 / rho
    square = alpha == 2.0
    # work arrays, allocated once before the loop
    nb = block + 1
    f_re = np.zeros((max(n_part, 1), nb))
    f_im = np.zeros((max(n_part, 1), nb))
    acc_re = np.zeros(nb)
    acc_im = np.zeros(nb)
    zr = np.zeros(block)
    zi = np.zeros(block)
    tail = np.zeros(block)
    if n_part > 0:
        # frequency-domain delay line: spectrum of input block c in slot c mod P, where
        # block c is x[n0 + c B : n0 + (c + 1) B]; fill it with the history blocks -1..-P
        for c in range(-n_part, 0):
            slot = c % n_part
            _rfft(
                x, n0 + (c - 1) * block, f_re[slot], f_im[slot], zr, zi, bitrev, tw_re, tw_im,
                w_re, w_im,
            )  # fmt: skip
    for i in range(n):
        m = n0 + i
        r = i % block
        if n_part > 0 and r == 0:
            b = i // block
            if b > 0:
                c = b - 1
                slot = c % n_part
                _rfft(
                    x, n0 + (c - 1) * block, f_re[slot], f_im[slot], zr, zi, bitrev, tw_re,
                    tw_im, w_re, w_im,
                )  # fmt: skip
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
        # 4. history part of the backward wave (A.4), lags >= 1
        q = _dot(head_rev, x[m - n_head : m])
        if n_part > 0:
            q += tail[r]
        # 5. Bernoulli flow from the quadratic, cancellation-free (A.10)-(A.17)
        p_m = pm[i]
        uf = 0.0
        if hh > 0.0:
            lh2 = (lam * hh) ** 2
            big_l = lh2 * z0p / rho
            big_g = lh2 * two_over_rho * (2.0 * q * inv + z0p * ur - p_m)
            uf = -big_g / (big_l + math.sqrt(big_l * big_l + abs(big_g)))
        u = uf + ur
        # 6. forward wave, with the lag-0 reflection folded in
        pp = (q + z0 * u) * inv
        x[m] = pp
        p = 2.0 * pp - z0 * u
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
def _rfft_lean(x, start, out_re, out_im, zr, zi, bitrev, tw_re, tw_im, w_re, w_im):
    """:func:`_rfft` with the split loop free of modulo indexing (the lean kernel's).

    Bins 0 and M are set apart; bins 1..M-1 pair z[k] with z[M - k] through slices, which
    spares two integer divisions per bin (this loop cost as much as the FFT itself).
    """
    m = zr.size
    xs = x[start : start + 2 * m]
    for n in range(m):
        zr[n] = xs[2 * n]
        zi[n] = xs[2 * n + 1]
    _fft(zr, zi, bitrev, tw_re, tw_im)
    out_re[0] = zr[0] + zi[0]
    out_im[0] = 0.0
    out_re[m] = zr[0] - zi[0]
    out_im[m] = 0.0
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
    :class:`LeanKernel`. Each level's history spectra ``f*_re, f*_im`` come precomputed
    (:func:`history_spectra`; overwritten here) and the scratch ``work*`` (shape
    ``(5, B + 1)``) is the caller's, so a run allocates nothing. Returns the final
    (y, y_prev, dp).
    """
    n_head = head_rev.size
    blk1 = level1[2].size
    blk2 = level2[2].size
    on1 = level1[0].shape[0] > 0
    on2 = level2[0].shape[0] > 0
    tail1 = work1[4, :blk1]
    tail2 = work2[4, :blk2]
    inv = 1.0 / (1.0 - h0)
    z0p = z0 * (1.0 + h0) * inv
    two_over_rho = 2.0 / rho
    square = alpha == 2.0
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
        y_new = a1 * y + a2 * y_prev + b1 * dp
        e = y - y_c
        if e > 0.0:
            y_new += a3 * (e * e if square else e**alpha)
        hh = y_m - y_new
        if hh < 0.0:
            hh = 0.0
        ur = s_fs * (y_new - y)
        q = _dot(head_rev, x[m - n_head : m])
        if on1:
            q += tail1[r1]
        if on2:
            q += tail2[r2]
        uf = 0.0
        if hh > 0.0:
            lh2 = (lam * hh) ** 2
            big_l = lh2 * z0p / rho
            big_g = lh2 * two_over_rho * (2.0 * q * inv + z0p * ur - p_m)
            uf = -big_g / (big_l + math.sqrt(big_l * big_l + abs(big_g)))
        u = uf + ur
        pp = (q + z0 * u) * inv
        x[m] = pp
        p = 2.0 * pp - z0 * u
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


# ---------------------------------------------------------------------------------------
# Plain reference


def _run_numpy(x, n0, n, h, z0, rho, reed, fs, pm, y, y_prev, dp):
    """Reference loop written directly from physics.md G.2-G.4 and D.2 step 6 (slow)."""
    a1, a2, a3, b1 = reed_coefficients(reed, fs)
    h0 = h[0]
    taps = h[1:][::-1].copy()  # lags N-1 .. 1
    nt = taps.size
    z0p = z0 * (1 + h0) / (1 - h0)
    out = {k: np.empty(n) for k in ("p", "u", "u_f", "u_r", "y", "h", "p_minus")}
    for i in range(n):
        m = n0 + i
        y_new = a1 * y + a2 * y_prev + b1 * dp + a3 * max(y - reed.y_c, 0.0) ** reed.alpha
        opening = max(reed.y_m - y_new, 0.0)
        ur = reed.S * (y_new - y) * fs
        q = float(np.dot(taps, x[m - nt : m]))
        qp = q / (1 - h0)
        lam_big = (reed.lam * opening) ** 2 * z0p / rho
        gam = 2 * (reed.lam * opening) ** 2 / rho * (2 * qp + z0p * ur - pm[i])
        # the two sign cases of the quadratic, as derived (physics.md G.3)
        if opening == 0.0:
            uf = 0.0
        elif gam <= 0.0:
            uf = -lam_big + math.sqrt(lam_big**2 - gam)
        else:
            uf = lam_big - math.sqrt(lam_big**2 + gam)
        u = uf + ur
        p = 2 * qp + z0p * u
        x[m] = (q + z0 * u) / (1 - h0)
        out["p"][i] = p
        out["u"][i] = u
        out["u_f"][i] = uf
        out["u_r"][i] = ur
        out["y"][i] = y_new
        out["h"][i] = opening
        out["p_minus"][i] = p - x[m]
        y_prev, y, dp = y, y_new, pm[i] - p
    return out, (y, y_prev, dp)


# ---------------------------------------------------------------------------------------
# Public entry point


def mouth_pressure_series(
    reed: ReedParameters,
    n_samples: int,
    fs: float,
    mouth_pressure: np.ndarray | float | None = None,
    onset_s: float = 0.0,
    noise_std_pa: float = 0.0,
    seed: int = 0,
) -> np.ndarray:
    """Mouth pressure at each output sample, Pa.

    Parameters
    ----------
    reed : ReedParameters
        Supplies the constant p_m when ``mouth_pressure`` is None.
    n_samples : int
        Number of samples.
    fs : float
        Sample rate, Hz.
    mouth_pressure : float or ndarray, optional
        Constant mouth pressure (Pa), or one value per output sample (Pa).
    onset_s : float
        Duration of a raised-cosine rise from 0, s (0: a step).
    noise_std_pa : float
        Standard deviation of white Gaussian breath noise added to the mouth pressure, Pa;
        shaped by the onset like the pressure itself.
    seed : int
        Seed of the noise generator.

    Returns
    -------
    ndarray
        Length ``n_samples``; sample i at t = (i + 1) / fs.
    """
    if mouth_pressure is None:
        pm = np.full(n_samples, reed.p_m)
    elif np.ndim(mouth_pressure) == 0:
        pm = np.full(n_samples, float(mouth_pressure))
    else:
        pm = np.array(mouth_pressure, dtype=float)
        if pm.shape != (n_samples,):
            raise ValueError(
                f"mouth_pressure: expected {n_samples} samples (one per output sample), "
                f"got shape {pm.shape}"
            )
    if not np.all(np.isfinite(pm)):
        raise ValueError("mouth_pressure: contains non-finite values")
    if onset_s < 0 or noise_std_pa < 0:
        raise ValueError(f"onset_s and noise_std_pa must be >= 0, got {onset_s}, {noise_std_pa}")
    env = np.ones(n_samples)
    if onset_s > 0:
        t = np.arange(1, n_samples + 1) / fs
        rising = t < onset_s
        env[rising] = 0.5 * (1 - np.cos(np.pi * t[rising] / onset_s))
    if noise_std_pa > 0:
        rng = np.random.default_rng(seed)
        pm = pm + noise_std_pa * rng.standard_normal(n_samples)
    return pm * env


def simulate(
    reed: ReedParameters,
    kernel: BoreKernel,
    n_samples: int,
    *,
    mouth_pressure: np.ndarray | float | None = None,
    onset_s: float = 0.0,
    noise_std_pa: float = 0.0,
    seed: int = 0,
    method: str = "fast",
    state: ModelState | None = None,
) -> Simulation:
    """Simulate the clarinet: reed model coupled to the bore through its reflection function.

    Parameters
    ----------
    reed : ReedParameters
        Reed parameters (SI units).
    kernel : BoreKernel
        Prepared bore, from :func:`prepare_bore`; fixes the sample rate.
    n_samples : int
        Number of samples to compute.
    mouth_pressure : float or ndarray, optional
        Constant mouth pressure in Pa or one value per output sample (Pa); default
        ``reed.p_m``.
    onset_s : float
        Raised-cosine rise time of the mouth pressure, s.
    noise_std_pa : float
        Standard deviation of white breath noise added to the mouth pressure, Pa.
    seed : int
        Seed of the breath noise.
    method : {"fast", "direct", "numpy"}
        Convolution kernel: partitioned FFT (default), direct (compiled), or the plain
        NumPy reference (slow; for tests on short runs).
    state : ModelState, optional
        Start from this history instead of from rest. From rest means y = y_prev = 0,
        p+ = 0 and dp = the mouth pressure at t = 0 (0 with an onset).

    Returns
    -------
    Simulation

    Raises
    ------
    ValueError
        For an unknown method, a too-short state history, bad mouth pressure, or a time
        step that violates the stability bound of the reed update.

    Notes
    -----
    The run is not stopped when it diverges; a diverging run (possible with contact
    stiffness too high for the time step, see :func:`mpipe.reed.parameters.check_stability`) gives
    non-finite samples and a warning in the log.

    References
    ----------
    Chatziioannou & van Walstijn 2012, Appendix A, eqs. (A.1)-(A.17); physics.md G.2-G.4,
    D.2 step 6.
    """
    if method not in METHODS:
        raise ValueError(f"method: expected one of {METHODS}, got {method!r}")
    n_samples = int(n_samples)
    if n_samples < 1:
        raise ValueError(f"n_samples: expected at least 1, got {n_samples}")
    fs = kernel.fs
    check_stability(reed, fs)
    pm = mouth_pressure_series(reed, n_samples, fs, mouth_pressure, onset_s, noise_std_pa, seed)
    h = kernel.h
    n_taps = h.size
    b = kernel.head_taps
    n_part = kernel.n_partitions
    if method == "fast" and n_part > 0:
        n_head = b - 1
    else:
        n_head = n_taps - 1
        n_part = 0
    # history long enough for the direct taps and for the FFT of the P oldest blocks
    n0 = max(n_taps - 1, (n_part + 1) * b if n_part else 0)
    x = np.zeros(n0 + n_samples)
    if state is None:
        # from rest; dp(0) is the mouth pressure at t = 0, which an onset makes 0
        y, y_prev = 0.0, 0.0
        dp = 0.0 if onset_s > 0 else float(pm[0])
    else:
        hist = np.asarray(state.p_plus, dtype=float)
        if hist.ndim != 1 or hist.size < n_taps:
            raise ValueError(
                f"state.p_plus: expected at least len(h) = {n_taps} past samples, got {hist.size}"
            )
        x[n0 - (n_taps - 1) : n0] = hist[-(n_taps - 1) :]
        y, y_prev, dp = float(state.y), float(state.y_prev), float(state.dp)

    if method == "numpy":
        out, (y, y_prev, dp) = _run_numpy(
            x, n0, n_samples, h, kernel.z0, kernel.rho, reed, fs, pm, y, y_prev, dp
        )
    else:
        a1, a2, a3, b1 = reed_coefficients(reed, fs)
        head_rev = np.ascontiguousarray(h[1 : n_head + 1][::-1])
        g_re = kernel.tail_re if n_part else np.zeros((0, b + 1))
        g_im = kernel.tail_im if n_part else np.zeros((0, b + 1))
        if not n_part:
            g_re.flags.writeable = False
            g_im.flags.writeable = False
        head_rev.flags.writeable = False
        out = {k: np.empty(n_samples) for k in ("p", "u", "u_f", "u_r", "y", "h", "p_minus")}
        y, y_prev, dp = _run(
            x, n0, n_samples, head_rev, float(h[0]), kernel.z0, kernel.rho, a1, a2, a3, b1,
            reed.y_m, reed.y_c, reed.alpha, reed.lam, reed.S * fs, pm, y, y_prev, dp, b,
            g_re, g_im, kernel.fft_bitrev, kernel.fft_tw_re, kernel.fft_tw_im,
            kernel.rfft_w_re, kernel.rfft_w_im, out["p"], out["u"], out["u_f"], out["u_r"],
            out["y"], out["h"], out["p_minus"],
        )  # fmt: skip
    if not np.isfinite(out["p"][-1]):
        # debug, not warning: an optimiser meets diverging candidates routinely
        log.debug("simulation diverged (non-finite pressure); check the reed parameters")
    p_plus = x[n0:]
    final = ModelState(p_plus=x[-n_taps:].copy(), y=y, y_prev=y_prev, dp=dp)
    return Simulation(
        fs=fs,
        t=np.arange(1, n_samples + 1) / fs,
        p=out["p"],
        u=out["u"],
        u_f=out["u_f"],
        u_r=out["u_r"],
        y=out["y"],
        h=out["h"],
        p_plus=p_plus,
        p_minus=out["p_minus"],
        reed=reed,
        mouth_pressure=pm,
        final_state=final,
        method=method,
    )


def playing_frequency(x: np.ndarray, fs: float, fmin: float = 50.0, fmax: float = 2000.0) -> float:
    """Fundamental frequency of a periodic signal by autocorrelation, Hz.

    Parameters
    ----------
    x : ndarray
        Signal (any unit), ideally a steady-state segment of several periods.
    fs : float
        Sample rate, Hz.
    fmin, fmax : float
        Search range, Hz.

    Returns
    -------
    float
        The frequency, Hz, or NaN when the signal is not periodic in the range.

    Notes
    -----
    Takes the first autocorrelation peak within 90 % of the highest in the lag range, so
    that a peak at two periods is not mistaken for the period, then refines the estimate
    at the peak of the Blackman-Harris-windowed spectrum near it. Needs a few periods of signal.
    """
    x = np.asarray(x, dtype=float) - np.mean(x)
    n = x.size
    lo = max(int(fs / fmax), 1)
    hi = min(int(math.ceil(fs / fmin)), n - 2)
    if hi <= lo + 2 or not np.any(x):
        return float("nan")
    nfft = 1 << int(math.ceil(math.log2(2 * n)))
    spec = np.fft.rfft(x, nfft)
    ac = np.fft.irfft(spec * np.conj(spec), nfft)[: hi + 2]
    # normalised cross-correlation of x[:n-L] and x[L:]: dividing by the energies of the
    # two overlapping parts removes the bias of a window holding a fractional period
    e = np.concatenate([[0.0], np.cumsum(x**2)])
    lags = np.arange(ac.size)
    energy = np.sqrt((e[n - lags] - e[0]) * (e[n] - e[lags]))
    if energy[0] <= 0:
        return float("nan")
    ac = ac / np.maximum(energy, 1e-300)
    seg = ac[lo : hi + 1]
    peaks = np.flatnonzero((seg[1:-1] > seg[:-2]) & (seg[1:-1] >= seg[2:])) + 1 + lo
    if peaks.size == 0:
        return float("nan")
    best = ac[peaks].max()
    if best < 0.3 * ac[0]:
        return float("nan")
    k = int(peaks[np.argmax(ac[peaks] >= 0.9 * best)])
    a, b, c = ac[k - 1], ac[k], ac[k + 1]
    denom = a - 2 * b + c
    delta = 0.5 * (a - c) / denom if denom != 0 else 0.0
    rough = fs / (k + delta)
    # The peak of a square-ish waveform's autocorrelation is a triangle, on which the
    # parabola is biased by ~1e-4; refine on the windowed spectrum's fundamental peak
    # instead (Blackman-Harris: its -92 dB sidelobes keep the harmonics from pulling it).
    # the refinement costs O(n) per step: the last 2^14 samples hold enough periods
    x = x[-_REFINE_SAMPLES:]
    n = x.size
    # 4-term Blackman-Harris window (Harris 1978, Proc. IEEE 66(1), -92 dB sidelobes)
    phase = 2 * np.pi * np.arange(n) / (n - 1)
    window = 0.35875 - 0.48829 * np.cos(phase) + 0.14128 * np.cos(2 * phase)
    window -= 0.01168 * np.cos(3 * phase)
    weighted = x * window
    idx = np.arange(n)

    def magnitude(f: float) -> float:
        return abs(np.dot(weighted, np.exp(-2j * np.pi * f / fs * idx)))

    # golden-section search for the peak within +-half a bin of the rough estimate, where
    # the main lobe is unimodal; 32 steps shrink the bracket (one bin) by 0.618^32 ~ 2e-7
    lo, hi = rough - 0.5 * fs / n, rough + 0.5 * fs / n
    ratio = (math.sqrt(5) - 1) / 2
    c, d = hi - ratio * (hi - lo), lo + ratio * (hi - lo)
    fc, fd = magnitude(c), magnitude(d)
    for _ in range(32):
        if fc > fd:
            hi, d, fd = d, c, fc
            c = hi - ratio * (hi - lo)
            fc = magnitude(c)
        else:
            lo, c, fc = c, d, fd
            d = lo + ratio * (hi - lo)
            fd = magnitude(d)
    return float(0.5 * (lo + hi))


def _fft_tables(b: int) -> tuple[np.ndarray, ...]:
    """Bit reversal, FFT twiddles and real-FFT twiddles for blocks of B samples."""
    bits = int(round(math.log2(b)))
    idx = np.arange(b)
    bitrev = np.zeros(b, dtype=np.int64)
    for k in range(bits):
        bitrev |= ((idx >> k) & 1) << (bits - 1 - k)
    tw = np.concatenate(
        [np.exp(-1j * np.pi * np.arange(half) / half) for half in 2 ** np.arange(bits)]
    )
    rw = np.exp(-2j * np.pi * np.arange(b + 1) / (2 * b))
    return bitrev, tw.real.copy(), tw.imag.copy(), rw.real.copy(), rw.imag.copy()


def _partition_spectra(segment: np.ndarray, b: int) -> tuple[np.ndarray, np.ndarray]:
    """Spectra (rfft of length 2B) of ``segment`` cut into zero-padded blocks of B taps."""
    n_part = -(-segment.size // b)
    padded = np.zeros((n_part, 2 * b))
    padded[:, :b].flat[: segment.size] = segment
    spectra = np.fft.rfft(padded, axis=1) if n_part else np.zeros((0, b + 1), complex)
    return spectra.real.copy(), spectra.imag.copy()


@dataclass(frozen=True)
class LeanKernel:
    """The reflection function partitioned for the lean (pressure-only) kernel.

    Two delay-line levels (non-uniform partitioned convolution): lags ``1..B1-1`` run as a
    direct dot product every sample, lags ``B1..B2-1`` by a frequency-domain delay line of
    block B1 (a few short partitions, recomputed every B1 samples), and the long tail,
    lags ``>= B2``, by one of block B2 (few long partitions, every B2 samples). A uniform
    partition must trade the direct part's cost (B per sample) against the delay line's
    (about 8 N / B flops per sample for N taps); two levels make both small. Each level is
    exact by the same argument as the uniform one: a block of B outputs only needs p+ at
    least B samples old.

    Attributes
    ----------
    block1, block2 : int
        B1 and B2, powers of two with B1 < B2.
    n0 : int
        Samples of p+ history a run buffer holds before its first output sample.
    head_rev : ndarray
        h[B1 - 1], ..., h[1] (the direct part).
    h0 : float
        Lag-0 tap.
    level1, level2 : tuple of ndarray
        (G_re, G_im, bitrev, tw_re, tw_im, w_re, w_im) of each level; G has shape
        ``(P, B + 1)``.
    """

    block1: int
    block2: int
    n0: int
    head_rev: np.ndarray
    h0: float
    level1: tuple
    level2: tuple

    def history_spectra(self, x: np.ndarray) -> tuple[np.ndarray, ...]:
        """Delay-line spectra of the history in ``x[:n0]``: (f1_re, f1_im, f2_re, f2_im)."""
        out = []
        for level in (self.level1, self.level2):
            g_re = level[0]
            b = level[2].size
            out.extend(history_spectra(x, self.n0, b, g_re.shape[0], *level[2:]))
        return tuple(out)


#: Block sizes of the lean kernel's two levels, chosen by measurement on the shipped
#: instrument (7200 taps at 100 kHz), interleaved runs against today's kernel, thread CPU
#: time (medians of 7): (16, 256) 1.25x, (32, 256) 1.39x, (32, 512) 1.49x, (64, 256) 1.52x,
#: (64, 512) 1.60x (benchmarks/bench_realtime.py prints the rate beside today's kernel).
LEAN_BLOCKS = (64, 512)


def prepare_lean(kernel: BoreKernel, block1: int | None = None, block2: int | None = None):
    """Partition a prepared bore's reflection function for the lean kernel.

    Parameters
    ----------
    kernel : BoreKernel
        Prepared bore.
    block1, block2 : int, optional
        Block sizes B1 < B2 (powers of two, >= 4); default :data:`LEAN_BLOCKS`.

    Returns
    -------
    LeanKernel
    """
    b1 = LEAN_BLOCKS[0] if block1 is None else int(block1)
    b2 = LEAN_BLOCKS[1] if block2 is None else int(block2)
    for b in (b1, b2):
        if b < 4 or b > 8192 or b & (b - 1):
            raise ValueError(f"lean kernel blocks: expected powers of two in [4, 8192], got {b}")
    if not b1 < b2:
        raise ValueError(f"lean kernel blocks: expected block1 < block2, got {b1}, {b2}")
    h = kernel.h
    n = h.size
    level1 = (*_partition_spectra(h[b1 : min(b2, n)], b1), *_fft_tables(b1))
    level2 = (*_partition_spectra(h[b2:], b2), *_fft_tables(b2))
    p1, p2 = level1[0].shape[0], level2[0].shape[0]
    n0 = max(n - 1, (p1 + 1) * b1, (p2 + 1) * b2)
    head_rev = np.ascontiguousarray(h[1 : min(b1, n)][::-1])
    for a in (head_rev, *level1, *level2):
        a.flags.writeable = False
    return LeanKernel(b1, b2, n0, head_rev, float(h[0]), level1, level2)


def simulate_pressure(
    reed: ReedParameters,
    kernel: BoreKernel,
    n_samples: int,
    *,
    state: ModelState | None = None,
    lean: LeanKernel | None = None,
) -> np.ndarray:
    """Mouthpiece pressure of :func:`simulate` at constant mouth pressure, by the lean kernel.

    The same scheme as ``simulate(..., method="fast")`` with ``mouth_pressure = reed.p_m``
    and no onset, but only the pressure is computed and kept, and the reflection function
    is split over two delay-line levels (:class:`LeanKernel`); this is the kernel the
    inversion runs (:mod:`mpipe.inversion.fastpath`). Agrees with :func:`simulate` to
    rounding.

    Parameters
    ----------
    reed : ReedParameters
        Reed parameters (SI units).
    kernel : BoreKernel
        Prepared bore.
    n_samples : int
        Number of samples.
    state : ModelState, optional
        Start from this history instead of from rest.
    lean : LeanKernel, optional
        The partition to use (default: :func:`prepare_lean` of ``kernel``).

    Returns
    -------
    ndarray
        Pressure, Pa; sample i at t = (i + 1) / fs, as :attr:`Simulation.p`.

    Raises
    ------
    ValueError
        As :func:`simulate`.
    """
    n_samples = int(n_samples)
    if n_samples < 1:
        raise ValueError(f"n_samples: expected at least 1, got {n_samples}")
    check_stability(reed, kernel.fs)
    lean = prepare_lean(kernel) if lean is None else lean
    n_taps = kernel.n_taps
    n0 = lean.n0
    x = np.zeros(n0 + n_samples)
    if state is None:
        y, y_prev, dp = 0.0, 0.0, float(reed.p_m)
    else:
        hist = np.asarray(state.p_plus, dtype=float)
        if hist.ndim != 1 or hist.size < n_taps:
            raise ValueError(
                f"state.p_plus: expected at least len(h) = {n_taps} past samples, got {hist.size}"
            )
        x[n0 - (n_taps - 1) : n0] = hist[-(n_taps - 1) :]
        y, y_prev, dp = float(state.y), float(state.y_prev), float(state.dp)
    out = np.empty(n_samples)
    f1_re, f1_im, f2_re, f2_im = lean.history_spectra(x)
    a1, a2, a3, b1 = reed_coefficients(reed, kernel.fs)
    _run_pressure(
        x, n0, n_samples, lean.head_rev, lean.h0, kernel.z0, kernel.rho, a1, a2, a3, b1,
        reed.y_m, reed.y_c, reed.alpha, reed.lam, reed.S * kernel.fs, reed.p_m, y, y_prev,
        dp, lean.level1, f1_re, f1_im, np.zeros((5, lean.block1 + 1)), lean.level2, f2_re,
        f2_im, np.zeros((5, lean.block2 + 1)), out,
    )  # fmt: skip
    return out
