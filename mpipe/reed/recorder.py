"""The recorder of a virtual take: microphone errors, resampling, noise and quantisation.

What happens to the true microphone pressures of :func:`mpipe.reed.recording.virtual_recording`
after the acoustics (its steps 3 and 4): each microphone's complex gain error (constant over
frequency), resampling to the output rate (``scipy.signal.resample_poly``), additive white
noise at a given SNR per channel (seeded), and quantisation to ``bits`` with the peak at
``-headroom_db`` dBFS.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.fft
from scipy import signal

from mpipe.core.resampling import rate_ratio

SUPPORTED_BITS = (16, 24, 32)
# Anti-aliasing window of resample_poly. scipy's default (Kaiser beta 5) ripples by ~1e-3 in
# the pass band; beta 10 keeps the gain within 1e-5 up to 12 kHz at 100 -> 48 kHz.
_RESAMPLE_WINDOW = ("kaiser", 10.0)


@dataclass(frozen=True)
class RecorderOptions:
    """What the microphones and the recorder add to the true pressures of a virtual take.

    Attributes
    ----------
    gain_error_db : sequence of N float, optional
        Sensitivity error of each microphone, dB (recorded = true x 10^(dB/20)); default 0.
    phase_error_deg : sequence of N float, optional
        Phase error of each microphone, degrees, constant over frequency; default 0.
    snr_db : float, optional
        Add white Gaussian noise with an RMS ``snr_db`` below each channel's RMS, dB.
    bits : {16, 24, 32}, optional
        Quantise to this word length with the peak at ``-headroom_db`` dBFS.
    fs_out : float, optional
        Output sample rate in Hz, a rational multiple of the model's; default the model's.
    seed : int
        Seed of the noise generator (``numpy.random.default_rng``).
    headroom_db : float
        Peak level below digital full scale, dB.
    """

    gain_error_db: Sequence[float] | None = None
    phase_error_deg: Sequence[float] | None = None
    snr_db: float | None = None
    bits: int | None = None
    fs_out: float | None = None
    seed: int = 0
    headroom_db: float = 6.0


def quantise(x: np.ndarray, full_scale: float, bits: int) -> np.ndarray:
    """Round to the grid of a ``bits``-bit two's-complement converter.

    Parameters
    ----------
    x : ndarray
        Signal in any unit.
    full_scale : float
        Value (same unit) at digital full scale.
    bits : int
        Word length.

    Returns
    -------
    ndarray
        ``x`` rounded to multiples of ``full_scale / 2^(bits - 1)`` and clipped to the
        converter's range; the error is at most half a step inside the range.
    """
    steps = 2.0 ** (bits - 1)
    q = np.clip(np.round(x / full_scale * steps), -steps, steps - 1)
    return q / steps * full_scale


def per_microphone(values: Sequence[float] | None, n_mics: int, name: str) -> tuple[float, ...]:
    """One finite value per microphone (0 for each when ``values`` is None); else ValueError."""
    if values is None:
        return (0.0,) * n_mics
    vals = tuple(float(v) for v in values)
    if len(vals) != n_mics or not all(math.isfinite(v) for v in vals):
        raise ValueError(
            f"{name} needs {n_mics} finite numbers, one per microphone of the calibration, "
            f"got {values!r}"
        )
    return vals


def output_rate_ratio(fs: float, fs_out: float) -> tuple[int, int]:
    """(up, down) with fs_out = fs up / down exactly; ValueError when no such integers exist."""
    if not fs_out > 0:
        raise ValueError(f"output sample rate must be positive, got {fs_out} Hz")
    up, down, error = rate_ratio(fs, fs_out)
    if error != 0.0:
        raise ValueError(
            f"output rate {fs_out:g} Hz is not an exact rational multiple of {fs:g} Hz "
            "(a file stores an integer rate in Hz)"
        )
    return up, down


def resample_by(x: np.ndarray, up: int, down: int) -> np.ndarray:
    """``x`` (time along axis 0) resampled by up / down; ``x`` itself when they are equal."""
    if up == down:
        return x
    return signal.resample_poly(x, up, down, axis=0, window=_RESAMPLE_WINDOW)


def add_noise(
    recorded: np.ndarray, snr_db: float | None, seed: int
) -> tuple[np.ndarray, tuple[float, ...]]:
    """White Gaussian noise ``snr_db`` below each channel's RMS; returns (signals, noise RMS)."""
    if snr_db is None:
        return recorded, (0.0,) * recorded.shape[1]
    rms = np.sqrt(np.mean(recorded**2, axis=0))
    std = rms * 10.0 ** (-snr_db / 20.0)
    noise = np.random.default_rng(seed).standard_normal(recorded.shape) * std
    return recorded + noise, tuple(float(s) for s in std)


def apply_gains(x: np.ndarray, g: np.ndarray, pad: int) -> np.ndarray:
    """Apply complex gains ``g`` (one per column) in the frequency domain.

    DC and Nyquist bins must stay real for a real signal; they get ``|g|``.
    """
    if np.allclose(g, 1.0, rtol=0, atol=0):
        return x.copy()
    n = x.shape[0]
    n_fft = scipy.fft.next_fast_len(n + 2 * pad, real=True)
    spec = scipy.fft.rfft(x, n_fft, axis=0)
    gains = np.broadcast_to(g, spec.shape).copy()
    gains[0] = np.abs(g)
    if n_fft % 2 == 0:
        gains[-1] = np.abs(g)
    return scipy.fft.irfft(spec * gains, n_fft, axis=0)[:n]
