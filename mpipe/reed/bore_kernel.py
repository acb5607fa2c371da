"""The bore's reflection function prepared for the model's compiled kernels.

:func:`prepare_bore` builds a :class:`BoreKernel` once per (bore, air, fs): the reflection
function with the spectra of its uniformly partitioned tail and the FFT tables of the fast
kernel. A :class:`Partition` splits it between the compiled kernel's direct sum and delay
lines: uniform (``BoreKernel.partition("fast")``), all direct, or the two levels of the
inversion's lean runs (:func:`prepare_lean`).

References
----------
physics.md D.2 step 6 (index convention) and D.4 (partitioned convolution).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from mpipe.acoustics.air import Air
from mpipe.acoustics.reflection import ReflectionFunction
from mpipe.reed.block_fft import fft_tables
from mpipe.reed.kernels import history_spectra

# Block size of the partitioned convolution (= number of direct taps + 1). On the shipped
# instrument (6822 taps at 100 kHz) 128 and 256 were fastest of 32..1024, within the noise
# of each other; 64 and 512 were about 35 % slower (benchmarks/bench_model.py --head-taps).
DEFAULT_HEAD_TAPS = 128


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
    reference_resistance : float
        Resistance to a steady flow of the bore between its entry and the plane where a
        measurement took the pressure's mean, Pa s/m^3 (0: none). A mouthpiece pressure
        translated from there with a zero-mean flow lacks it times the mean flow: the
        inversion's window model adds it back (:mod:`mpipe.inversion.fit.objective`). Not
        used by the model's run.
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
    reference_resistance: float = 0.0

    @property
    def n_taps(self) -> int:
        """Number of taps of h, including lag 0."""
        return int(self.h.size)

    @property
    def n_partitions(self) -> int:
        """Number P of FFT partitions of the tail."""
        return int(self.tail_re.shape[0])

    @functools.cached_property
    def lean(self) -> Partition:
        """The two-level partition of the lean kernel (:func:`prepare_lean`), made once."""
        return prepare_lean(self)

    def partition(self, method: str) -> Partition:
        """The partition of :func:`mpipe.reed.model.simulate`'s ``method``, made once.

        "fast": lags 1..B-1 direct, the rest by the uniform delay line of block B (the
        tail spectra above, plain FFT tables); "direct": every lag direct.
        """
        cache = self.__dict__.setdefault("_partitions", {})
        if method not in cache:
            b = self.head_taps
            tables = (
                self.fft_bitrev,
                self.fft_tw_re,
                self.fft_tw_im,
                self.rfft_w_re,
                self.rfft_w_im,
            )
            off = (np.zeros((0, 5)), np.zeros((0, 5)), fft_tables(4))
            if method == "fast":
                cache[method] = _partition(self.h, b, (self.tail_re, self.tail_im, tables), off)
            else:
                cache[method] = _partition(self.h, self.n_taps, (*off[:2], tables), off)
        return cache[method]


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
    # Each partition is zero-padded to 2B, so overlap-save keeps the last B outputs exact.
    tail_re, tail_im = _partition_spectra(h[b:], b)
    bitrev, tw_re, tw_im, rw_re, rw_im = fft_tables(b)
    return BoreKernel(
        h=_readonly(h.copy()),
        fs=float(rf.fs),
        z0=float(rf.z0),
        rho=float(air.rho),
        head_taps=b,
        tail_re=_readonly(tail_re),
        tail_im=_readonly(tail_im),
        fft_bitrev=_readonly(bitrev),
        fft_tw_re=_readonly(tw_re),
        fft_tw_im=_readonly(tw_im),
        rfft_w_re=_readonly(rw_re),
        rfft_w_im=_readonly(rw_im),
    )


def _partition_spectra(segment: np.ndarray, b: int) -> tuple[np.ndarray, np.ndarray]:
    """Spectra (rfft of length 2B) of ``segment`` cut into zero-padded blocks of B taps."""
    n_part = -(-segment.size // b)
    padded = np.zeros((n_part, 2 * b))
    padded[:, :b].flat[: segment.size] = segment
    spectra = np.fft.rfft(padded, axis=1) if n_part else np.zeros((0, b + 1), complex)
    return spectra.real.copy(), spectra.imag.copy()


@dataclass(frozen=True)
class Partition:
    """The reflection function partitioned for the compiled kernel (:mod:`mpipe.reed.kernels`).

    Lags ``1..B1-1`` run as a direct sum every sample (``head``), lags ``B1..B2-1`` by a
    frequency-domain delay line of block B1 (``level1``), lags ``>= B2`` by one of block
    B2 (``level2``); a level with no partitions is off. Three partitions are made:

    * the lean one, two levels (non-uniform partitioned convolution; :func:`prepare_lean`):
      a few short partitions recomputed every B1 samples and few long ones every B2. A
      uniform partition must trade the direct part's cost (B per sample) against the delay
      line's (about 8 N / B flops per sample for N taps); two levels make both small;
    * the uniform one of block B (level 2 off; :meth:`BoreKernel.partition` "fast");
    * every lag direct (both levels off; "direct").

    Each level is exact by the same argument: a block of B outputs only needs p+ at least
    B samples old.

    Attributes
    ----------
    block1, block2 : int
        B1 and B2, powers of two.
    n0 : int
        Samples of p+ history a run buffer holds before its first output sample.
    head : ndarray
        h[1], ..., h[B1 - 1] (the direct part).
    h0 : float
        Lag-0 tap.
    level1, level2 : tuple
        (G_re, G_im, tables) of each level: G of shape ``(P, B + 1)``, the spectra of the
        zero-padded partitions, and the FFT tables of block B
        (:func:`mpipe.reed.block_fft.fft_tables`).
    """

    block1: int
    block2: int
    n0: int
    head: np.ndarray
    h0: float
    level1: tuple
    level2: tuple

    def history_spectra(self, x: np.ndarray) -> tuple[np.ndarray, ...]:
        """Delay-line spectra of the history in ``x[:n0]``: (f1_re, f1_im, f2_re, f2_im)."""
        return (
            *history_spectra(x, self.n0, self.level1),
            *history_spectra(x, self.n0, self.level2),
        )

    def conv(self, x: np.ndarray, n: int) -> tuple:
        """The kernel's ``conv`` record for a run of ``n`` samples on the history in ``x``.

        (head, fut, line1, line2) with each line (level, f_re, f_im, work): the history's
        spectra and fresh work buffers (:mod:`mpipe.reed.kernels`).
        """
        f1_re, f1_im, f2_re, f2_im = self.history_spectra(x)
        line1 = (self.level1, f1_re, f1_im, np.zeros((5, self.block1 + 1)))
        line2 = (self.level2, f2_re, f2_im, np.zeros((5, self.block2 + 1)))
        return self.head, np.empty(n + self.head.size), line1, line2

    def quiet_conv(self, n: int) -> tuple:
        """:meth:`conv` on a zero history: its spectra are zero, no FFT is taken.

        The same record as ``conv(np.zeros(...), n)`` (the spectra of zeros are zeros),
        for a run that starts from rest, or whose evaluator zeroes the spectra itself.
        """
        lines = []
        for level, block in ((self.level1, self.block1), (self.level2, self.block2)):
            rows = max(level[0].shape[0], 1)
            lines.append((level, np.zeros((rows, block + 1)), np.zeros((rows, block + 1)),
                          np.zeros((5, block + 1))))  # fmt: skip
        return self.head, np.empty(n + self.head.size), lines[0], lines[1]


#: Block sizes of the lean kernel's two levels, chosen by measurement on the shipped
#: instrument (7200 taps at 100 kHz), interleaved runs against today's kernel, thread CPU
#: time (medians of 7): (16, 256) 1.25x, (32, 256) 1.39x, (32, 512) 1.49x, (64, 256) 1.52x,
#: (64, 512) 1.60x (benchmarks/bench_realtime.py prints the rate beside today's kernel).
LEAN_BLOCKS = (64, 512)


def prepare_lean(kernel: BoreKernel, block1: int | None = None, block2: int | None = None):
    """Partition a prepared bore's reflection function in two delay-line levels.

    Parameters
    ----------
    kernel : BoreKernel
        Prepared bore.
    block1, block2 : int, optional
        Block sizes B1 < B2 (powers of two, >= 4); default :data:`LEAN_BLOCKS`.

    Returns
    -------
    Partition
        With the FFT tables' ``real_nyquist`` convention.
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
    level1 = (*_partition_spectra(h[b1 : min(b2, n)], b1), fft_tables(b1, real_nyquist=True))
    level2 = (*_partition_spectra(h[b2:], b2), fft_tables(b2, real_nyquist=True))
    return _partition(h, b1, level1, level2)


def _partition(h: np.ndarray, b1: int, level1: tuple, level2: tuple) -> Partition:
    """A read-only :class:`Partition` of ``h`` with direct lags 1..b1-1 and two levels."""
    b2 = level2[2][0].size
    p1, p2 = level1[0].shape[0], level2[0].shape[0]
    n0 = max(h.size - 1, (p1 + 1) * b1, (p2 + 1) * b2)
    head = np.ascontiguousarray(h[1 : min(b1, h.size)])
    for a in (head, *level1[:2], *level1[2], *level2[:2], *level2[2]):
        a.flags.writeable = False
    return Partition(b1, b2, n0, head, float(h[0]), level1, level2)
