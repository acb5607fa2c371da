"""Sample-rate conversion of any rate to any other: one polyphase filter, one stated error.

:func:`rate_ratio` turns two rates (Hz) into the integer factors ``up / down`` of a
polyphase resampler: the exact ratio for every pair of integer rates up to
:data:`MAX_FACTOR` (8 kHz ... 384 kHz, 93 034 Hz and 51 200 Hz included), otherwise the
closest fraction whose factors stay below it, whose relative rate error is returned (every
frequency is scaled by ``1 + error``; below 1e-9 for rates given to 0.01 Hz).
:func:`resample` applies it with ``scipy.signal.resample_poly`` and a Kaiser window
(beta 10): the gain is within 1e-3 of one up to 0.8 of the lower Nyquist frequency (or
9 kHz, the analysis band, when that is lower). :func:`resample_blocks` gives the same
samples a block at a time, reading only a block and the filter's reach around it.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from fractions import Fraction

import numpy as np
from scipy import signal

log = logging.getLogger(__name__)

#: Largest up or down factor, and so (as 20 x MAX_FACTOR taps) the filter's size: 8e6 taps,
#: 64 MB, designed in a few seconds; every integer rate up to 400 kHz converts exactly.
MAX_FACTOR = 400_000

# Anti-aliasing filter: scipy's default window (Kaiser beta 5) ripples by ~1e-3 in the pass
# band, beta 10 by ~1e-5 (stop band ~100 dB). Its transition spans about +-3.2 / K of the
# lower Nyquist frequency for 2 K max(up, down) + 1 taps: K = 10 (scipy's default) is flat
# within 1e-3 up to 0.6 of it, which covers the 9 kHz analysis band from 30 kHz up; below,
# K = 32 keeps the gain within 1e-3 up to 0.8 of the Nyquist frequency.
_BETA = 10.0
_ANALYSIS_BAND_HZ = 9000.0


def _taps(up: int, down: int, fs_low: float) -> np.ndarray:
    """The anti-aliasing FIR of resample_poly (cut-off at the lower Nyquist frequency)."""
    k = 10 if 0.6 * fs_low / 2 >= _ANALYSIS_BAND_HZ else 32
    m = max(up, down)
    return signal.firwin(2 * k * m + 1, 1.0 / m, window=("kaiser", _BETA))


def rate_ratio(fs_from: float, fs_to: float) -> tuple[int, int, float]:
    """Integer factors ``up, down`` with ``up / down`` the ratio ``fs_to / fs_from``.

    Parameters
    ----------
    fs_from, fs_to : float
        Sample rates, Hz (positive, finite).

    Returns
    -------
    up, down : int
        Coprime factors, both at most :data:`MAX_FACTOR`.
    error : float
        Relative error of ``up / down`` against the exact ratio (0 when exact): the output
        rate is ``fs_to (1 + error)`` in truth, every frequency scaled by ``1 + error``.

    Raises
    ------
    ValueError
        For a rate that is not positive and finite.
    """
    for name, fs in (("input", fs_from), ("output", fs_to)):
        if not (np.isfinite(fs) and fs > 0):
            raise ValueError(f"{name} sample rate must be positive and finite, got {fs} Hz")
    exact = Fraction(float(fs_to)) / Fraction(float(fs_from))
    ratio = exact
    if max(ratio.numerator, ratio.denominator) > MAX_FACTOR:
        # best approximation whose numerator and denominator both stay below MAX_FACTOR
        ratio = exact.limit_denominator(max(int(MAX_FACTOR / max(float(exact), 1.0)), 1))
    return ratio.numerator, ratio.denominator, float(ratio / exact) - 1.0


def resample(x: np.ndarray, fs_from: float, fs_to: float) -> np.ndarray:
    """Resample signals along axis 0 with a polyphase filter (``scipy.signal.resample_poly``).

    The one place where mpipe changes a sample rate, shared by every command: takes at
    the pipeline's rate, mouthpiece signals at the inversion's rate.

    Parameters
    ----------
    x : ndarray
        Signals, time along axis 0.
    fs_from, fs_to : float
        Sample rates in Hz, any (see :func:`rate_ratio` for the rate error of pairs that
        are not integer rates up to :data:`MAX_FACTOR`, which is logged).

    Returns
    -------
    ndarray
        ``ceil(n up / down)`` samples (float64).
    """
    up, down, error = rate_ratio(fs_from, fs_to)
    if up == down:
        return np.array(x, dtype=float)
    if error != 0.0:
        log.info(
            "resampling %g Hz -> %g Hz as %d/%d: rate error %.2g (frequencies scaled by 1 %+.2g)",
            fs_from,
            fs_to,
            up,
            down,
            abs(error),
            error,
        )
    taps = _taps(up, down, min(fs_from, fs_to))
    return signal.resample_poly(np.asarray(x, dtype=float), up, down, axis=0, window=taps)


#: Input samples per block of :func:`resample_blocks` (rounded up to a multiple of ``down``).
RESAMPLE_BLOCK = 1 << 18


def resample_blocks(
    x, fs_from: float, fs_to: float, block: int = RESAMPLE_BLOCK
) -> Iterator[tuple[int, np.ndarray]]:
    """:func:`resample` a block at a time: ``(first output sample, samples)`` in order.

    Each block of input samples starts at a multiple of ``down``, so its outputs fall on
    the whole signal's output grid, and is read with the filter's reach on either side
    (zeros beyond the signal's ends, as :func:`resample` has them): each output sample is
    the same sum of the same products as the whole array's (equal to within 1e-12 of its
    peak, ``tests/core/test_resampling.py``). Memory is bounded by the block.

    Parameters
    ----------
    x : array-like
        Signals, time along axis 0 (sliced only: a :class:`mpipe.core.signals.DiskArray`
        is read a block at a time).
    fs_from, fs_to : float
        Sample rates, Hz.
    block : int
        Input samples per block.
    """
    n = len(x)
    up, down, _ = rate_ratio(fs_from, fs_to)
    if up == down:
        for a in range(0, n, block):
            yield a, np.array(x[a : a + block], dtype=float)
        return
    taps = _taps(up, down, min(fs_from, fs_to))
    half = (taps.size - 1) // 2
    # input samples the filter reaches from an output sample, rounded up to whole ``down``s
    reach = -(-(half // up + 2) // down) * down
    step = -(-max(block, 1) // down) * down
    n_out = -(-n * up // down)
    for a in range(0, n, step):
        b = min(a + step, n)
        lo, hi = max(a - reach, 0), min(b + reach, n)
        y = signal.resample_poly(np.asarray(x[lo:hi], dtype=float), up, down, axis=0,
                                 window=taps)  # fmt: skip
        j0, j1 = a * up // down, (b * up // down if b < n else n_out)
        yield j0, y[j0 - lo * up // down : j1 - lo * up // down]
