"""Filters shared by the measurement chain and the model comparison.

The same filters must be applied to the measured signals and to the model output before
they are compared (physics.md F.2 and J), so both stages take them from here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal


@dataclass(frozen=True)
class LowPass:
    """A linear-phase FIR low-pass filter.

    Attributes
    ----------
    taps : ndarray
        Symmetric impulse response, odd length.
    fs : float
        Sample rate in Hz.
    cutoff_hz : float
        Frequency of the -6 dB point in Hz.
    """

    taps: np.ndarray
    fs: float
    cutoff_hz: float

    @property
    def delay(self) -> int:
        """Group delay in samples, (N - 1) / 2."""
        return (self.taps.size - 1) // 2


def design_lowpass(
    fs: float,
    cutoff_hz: float = 7250.0,
    transition_hz: float = 1500.0,
    stopband_db: float = 60.0,
) -> LowPass:
    """Design the linear-phase Kaiser-window FIR low-pass of physics.md F.2.

    Parameters
    ----------
    fs : float
        Sample rate in Hz.
    cutoff_hz : float
        -6 dB frequency in Hz (the paper: 7.25 kHz).
    transition_hz : float
        Width of the transition band in Hz, centred on the cut-off.
    stopband_db : float
        Stop-band attenuation in dB.

    Returns
    -------
    LowPass
        Odd-length symmetric filter (type I), so its delay is an integer number of samples.

    Raises
    ------
    ValueError
        If the band does not fit below the Nyquist frequency.
    """
    nyq = fs / 2
    if not (0 < cutoff_hz - transition_hz / 2 and cutoff_hz + transition_hz / 2 < nyq):
        raise ValueError(
            f"low-pass cut-off {cutoff_hz:g} Hz with a {transition_hz:g} Hz transition does not "
            f"fit below the Nyquist frequency {nyq:g} Hz (sample rate {fs:g} Hz)"
        )
    numtaps, beta = signal.kaiserord(stopband_db, transition_hz / nyq)
    numtaps |= 1
    taps = signal.firwin(numtaps, cutoff_hz, window=("kaiser", beta), fs=fs)
    return LowPass(taps=taps, fs=float(fs), cutoff_hz=float(cutoff_hz))


#: Samples per block of :func:`apply_lowpass`.
LOWPASS_BLOCK = 2**18


def apply_lowpass(x: np.ndarray, lp: LowPass, axis: int = -1) -> np.ndarray:
    """Filter with ``lp`` and remove its delay, so the output is aligned with the input.

    The signal is extended at both ends by its edge value over the filter length, so the
    first and last ``lp.delay`` samples are not pulled towards zero.

    Parameters
    ----------
    x : ndarray
        Signal(s), any units.
    lp : LowPass
        Filter from :func:`design_lowpass`.
    axis : int
        Time axis.

    Returns
    -------
    ndarray
        Same shape as ``x``.
    """
    x = np.moveaxis(np.asarray(x, dtype=float), axis, -1)
    n = x.shape[-1]
    y = np.empty_like(x)
    # in blocks of LOWPASS_BLOCK samples (memory bounded by the block, not the signal),
    # each convolved with d samples of context on either side
    for a in range(0, n, LOWPASS_BLOCK):
        b = min(a + LOWPASS_BLOCK, n)
        y[..., a:b] = lowpass_block(x, lp, a, b)
    return np.moveaxis(y, -1, axis)


def lowpass_block(x, lp: LowPass, a: int, b: int) -> np.ndarray:
    """Samples ``a..b`` of :func:`apply_lowpass`'s output, reading only ``a - d..b + d`` of x.

    The same arithmetic as :func:`apply_lowpass` (identical numbers) when ``a`` and ``b``
    lie on its grid of ``LOWPASS_BLOCK`` samples (``b`` may be the signal's end), so a
    signal on disk (:class:`mpipe.core.signals.DiskArray`) is low-passed block by block.

    Parameters
    ----------
    x : array-like
        Signal(s), any units, time on the last axis; only sliced (``x[..., i:j]``).
    lp : LowPass
        Filter from :func:`design_lowpass` (``d`` is its delay, samples).
    a, b : int
        First and one-past-last output sample.

    Returns
    -------
    ndarray
        Shape ``x.shape[:-1] + (b - a,)``.
    """
    d, n = lp.delay, x.shape[-1]
    seg = np.asarray(x[..., max(a - d, 0) : min(b + d, n)], dtype=float)
    taps = lp.taps.reshape((1,) * (seg.ndim - 1) + (-1,))
    before, after = max(d - a, 0), max(b + d - n, 0)
    if before or after:
        seg = np.pad(seg, [(0, 0)] * (seg.ndim - 1) + [(before, after)], mode="edge")
    return signal.oaconvolve(seg, taps, mode="valid", axes=-1)


def highpass_zero_phase(
    x: np.ndarray, fs: float, cutoff_hz: float = 20.0, order: int = 2, axis: int = -1
) -> np.ndarray:
    """Zero-phase Butterworth high-pass (forward-backward), physics.md J.

    The measured flow has no DC (the three-microphone system is singular at DC): tests and
    benchmarks make a model flow look measured with it. The inversion does not filter the
    model's output with it (it estimates the flow's missing mean instead,
    :mod:`mpipe.inversion.fit.objective`).

    Parameters
    ----------
    x : ndarray
        Signal(s), any units.
    fs : float
        Sample rate in Hz.
    cutoff_hz : float
        Cut-off frequency in Hz.
    order : int
        Butterworth order of each pass (the forward-backward magnitude is squared).
    axis : int
        Time axis.

    Returns
    -------
    ndarray
        Same shape as ``x``.
    """
    sos = signal.butter(order, cutoff_hz, btype="highpass", fs=fs, output="sos")
    return signal.sosfiltfilt(sos, np.asarray(x, dtype=float), axis=axis)
