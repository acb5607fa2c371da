"""Playing frequency of a simulated or measured mouthpiece signal.

:func:`playing_frequency` finds the fundamental of a steady, periodic segment by a
normalised autocorrelation and refines it on the Blackman-Harris-windowed spectrum; the
``simulate`` command and the tests use it to check where the model plays against the
bore's impedance peaks.
"""

from __future__ import annotations

import math

import numpy as np

# Samples used to refine a playing-frequency estimate (see playing_frequency).
_REFINE_SAMPLES = 2**14


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
