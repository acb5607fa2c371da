"""Sensor noise of the microphones, measured once per take (physics.md E.5).

:func:`noise_levels` gives the white-noise power spectral density of each channel (Pa^2/Hz,
the scaling of :attr:`BlockSpectra.mic_power`) from the incoherent part of the take's cross
spectra; ``NOISE_FLOOR`` bounds it from below relative to the strongest bin of a block.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from mpipe.core.resampling import resample
from mpipe.measurement.separation.settings import SeparationConfig

# Floor of the noise levels relative to the strongest bin of a block's microphone spectra:
# a virtual take without noise would otherwise weigh the weakest harmonics by numerical
# noise. It must stay below the noise of any real recording: at 1e-10 (the former value)
# it lay 4x above the white noise of a 70 dB take at 100 kHz (the fundamental's bin holds
# ~1e3 times the take's power per bin), so chi^2 per term came out 0.35 and the standard
# errors 1.7x too wide. 1e-14 is ~100 dB below the strongest bin's share of a take at
# 80 dB SNR; 24-bit quantisation lies near 1e-17.
NOISE_FLOOR = 1e-14

# The noise level is measured where the resampler's power response (when the take was
# resampled from a lower rate) is at least this, after dividing by it.
_RESPONSE_MIN = 0.9

# and below this fraction of the recording's Nyquist frequency (a converter's own
# anti-aliasing filter starts to fall above it).
_NYQUIST_FRACTION = 0.9


# Quantile of the per-bin power spectrum taken as the noise floor when there is no band
# above the separation band (bins between the harmonics of a note).
_NOISE_QUANTILE = 0.2


def noise_levels(
    x: np.ndarray, fs: float, config: SeparationConfig, band_limit_hz: float | None = None
) -> np.ndarray:
    """White noise power spectral density of each channel over the whole take.

    Parameters
    ----------
    x : ndarray
        Calibrated microphone pressures in Pa, shape ``(n, N)``, N >= 2.
    fs : float
        Sample rate in Hz.
    config : SeparationConfig
        ``noise_fmin_hz``, the separation and estimation bands, ``welch_segment_s``.
    band_limit_hz : float, optional
        Highest frequency the recording holds, Hz: the Nyquist frequency of the file when
        the take was resampled to a higher rate (default ``fs / 2``).

    Returns
    -------
    ndarray
        Shape ``(N,)``, Pa^2/Hz in the scaling of the diagonal of
        :attr:`BlockSpectra.mic_power` (two-sided: the one-sided PSD is twice this): the
        median incoherent power spectral density between ``noise_fmin_hz`` and 0.9 of
        ``band_limit_hz``, where a played note has little energy left; without such a band,
        the ``_NOISE_QUANTILE`` quantile of the spectrum in the estimation band, i.e. the
        floor between the harmonics.

    Notes
    -----
    Sensor noise is stationary, so one level per channel for the whole take is far more
    precise than a per-block estimate. It is assumed white: where it is not, the weights
    of the estimate are off by the ratio of the noise in the estimation band to the noise
    measured, which moves the standard errors, not the minimum.
    """
    segment = min(max(int(round(config.welch_segment_s * fs)), 16), x.shape[0])
    hop = max(segment // 2, 1)
    win = np.hanning(segment + 1)[:-1]
    freqs = np.fft.rfftfreq(segment, 1 / fs)
    n_mics = x.shape[1]
    cross = np.zeros((freqs.size, n_mics, n_mics), dtype=complex)
    n_seg = 0
    # Running sum rather than one stacked array: a long take at 100 kHz stays small.
    for s0 in range(0, x.shape[0] - segment + 1, hop):
        spec_ = np.fft.rfft(x[s0 : s0 + segment] * win[:, None], axis=0)
        cross += spec_[:, :, None] * np.conj(spec_[:, None, :])
        n_seg += 1
    cross *= 1.0 / (fs * np.sum(win**2) * max(n_seg, 1))
    # Incoherent part of each channel (three-channel method, with the two nearest other
    # channels j, k): the coherent power of channel i is |S_ij| |S_ik| / |S_jk|, so
    # harmonics of the note in the band (a clean take) do not count as noise. With two
    # channels it is |S_12| sqrt(S_ii / S_jj), exact when both channels have the same
    # signal-to-noise ratio (the microphones are a few cm apart in one field).
    diag = np.real(np.einsum("fii->fi", cross))
    psd = np.empty_like(diag)
    # Only bins where all pairs are clearly coherent carry signal: for independent
    # noise, |S_ij|^2 / (S_ii S_jj) of n averages is about 1 / n, and subtracting that
    # random coherent part everywhere would bias the noise level low by ~20 %.
    pairs = [(i, j) for i in range(n_mics) for j in range(i + 1, n_mics)]
    gamma2 = [
        np.abs(cross[:, i, j]) ** 2 / np.maximum(diag[:, i] * diag[:, j], 1e-300) for i, j in pairs
    ]
    signal = np.min(gamma2, axis=0) > 5.0 / max(n_seg, 1)
    for i in range(n_mics):
        others = sorted((j for j in range(n_mics) if j != i), key=lambda j: (abs(j - i), j))
        if n_mics == 2:
            j = others[0]
            coh = np.abs(cross[:, i, j]) * np.sqrt(diag[:, i] / np.maximum(diag[:, j], 1e-300))
        else:
            j, k = others[:2]
            coh = np.abs(cross[:, i, j]) * np.abs(cross[:, i, k])
            coh = coh / np.maximum(np.abs(cross[:, j, k]), 1e-300)
        psd[:, i] = np.maximum(diag[:, i] - np.where(signal, coh, 0.0), 0.0)
    lo = config.noise_fmin_hz
    if lo is None:
        lo = 1.1 * (config.band_edge_hz + config.band_taper_hz)
    top = fs / 2 if band_limit_hz is None else min(band_limit_hz, fs / 2)
    high = (freqs >= lo) & (freqs <= _NYQUIST_FRACTION * top)
    if top < fs / 2:
        # The resampler's filter falls off below the file's Nyquist frequency (to 0.96 at
        # 0.8 of it for 44.1 -> 100 kHz): measured there, the noise came out 6 % low.
        response = resampler_response(freqs, fs, 2 * top)
        high &= response >= _RESPONSE_MIN
        psd = psd / np.maximum(response, 1e-300)[:, None]
    if np.any(high) and np.ptp(freqs[high]) >= 1000.0:
        # The median of Welch estimates (chi^2 of nu degrees of freedom over nu) lies
        # below their mean by the chi^2 distribution's median over nu.
        nu = 2.0 * n_seg / (1.0 + 2.0 * _overlap_correlation(win, hop) ** 2)
        return np.median(psd[high], axis=0) / (stats.chi2.median(nu) / nu)
    band = (freqs >= config.fmin_hz) & (freqs <= config.fmax_hz)
    if not np.any(band):
        return np.ones(n_mics)
    return np.quantile(psd[band], _NOISE_QUANTILE, axis=0)


def resampler_response(freqs: np.ndarray, fs: float, fs_file: float) -> np.ndarray:
    """Power response of the resampling from ``fs_file`` to ``fs`` at ``freqs`` (Hz).

    The upsampled unit impulse of :func:`mpipe.core.resampling.resample` (the one place
    that changes rates), its squared spectrum normalised to the average in the lowest
    half of the file's band (1 where the resampler passes white noise unchanged).

    Parameters
    ----------
    freqs : ndarray
        Frequencies, Hz.
    fs, fs_file : float
        Sample rates of the resampled signal and of the file, Hz.

    Returns
    -------
    ndarray
        Dimensionless, shape of ``freqs``.
    """
    n_file = 4096
    impulse = np.zeros((n_file, 1))
    impulse[n_file // 2] = 1.0
    h = resample(impulse, fs_file, fs)[:, 0]
    f_h = np.fft.rfftfreq(h.size, 1 / fs)
    power = np.abs(np.fft.rfft(h)) ** 2
    power /= np.mean(power[(f_h > 0.05 * fs_file) & (f_h < 0.25 * fs_file)])
    return np.interp(freqs, f_h, power, right=0.0)


def _overlap_correlation(win: np.ndarray, hop: int) -> float:
    """Correlation of the spectra of white noise in Welch segments ``hop`` apart.

    ``sum w[n] w[n + hop] / sum w^2`` (1/3 for a Hann window overlapping by half); the
    periodograms correlate by its square.
    """
    if hop >= win.size:
        return 0.0
    return float(np.sum(win[hop:] * win[: win.size - hop]) / np.sum(win**2))
