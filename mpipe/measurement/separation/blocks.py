"""Analysis blocks of the separation and the spectra of one block (physics.md E.5).

The take is cut into blocks overlapping by half (:func:`block_layout`, :func:`padded_block`);
:func:`cross_spectra` prepares one block for the estimation of theta as a
:class:`BlockSpectra` (windowed microphone powers in Pa^2/Hz at the estimation bins, and the
spectra of the block with context on which the null filter acts); :func:`window_correlation`
gives the correlation of white noise between the bins of a windowed block.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import fft as sfft

# Bin offsets over which the residuals of a Hann-windowed block on the twice zero-padded
# grid are correlated; beyond them the correlation is below 1e-3.
_CORR_BINS = 8


# Context taken on each side of a block before the null filter is applied, s: longer than
# the filter's impulse response (the delays between microphones, ~0.1 ms, and the tails of
# the visco-thermal terms), so that the residual inside the block is an exact filtering.
FILTER_MARGIN_S = 0.005


@dataclass(frozen=True)
class BlockSpectra:
    """One block prepared for the estimation: its spectra and the residual filter grid.

    Attributes
    ----------
    freqs : ndarray
        Frequencies in Hz of the estimation bins (``fmin_hz..fmax_hz`` on the grid of the
        windowed residual, an FFT of ``nfft_out`` = twice the block).
    bins : ndarray
        Integer index of each estimation bin on that grid.
    mic_power : ndarray
        ``|X_m(f)|^2`` of the Hann-windowed microphone signals at the estimation bins,
        scaled as :func:`noise_levels` (Pa^2/Hz), shape ``(n, N)``.
    model_freqs : ndarray
        Frequencies (Hz) where the null filter is evaluated, on the grid of ``nfft_in``.
    model_taper : ndarray
        Raised-cosine taper of the null filter over ``model_freqs`` (1 inside the band).
    spectra : ndarray
        Spectra of the unwindowed block with its context on each side, zero-padded, at
        ``model_freqs`` (unnormalised FFT, Pa), shape ``(n_model, N)``.
    window : ndarray
        Periodic Hann window of the block at the reduced rate ``fs / dec``.
    margin : int
        Samples of context on each side at the reduced rate.
    nfft_in, nfft_out : int
        Lengths of the inverse FFT of the residual and of the windowed FFT, at the
        reduced rate.
    fs : float
        Sample rate, Hz.
    scale : float
        Normalisation of the windowed residual to unit noise variance.
    """

    freqs: np.ndarray
    bins: np.ndarray
    mic_power: np.ndarray
    model_freqs: np.ndarray
    model_taper: np.ndarray
    model_index: np.ndarray
    spectra: np.ndarray
    window: np.ndarray
    margin: int
    nfft_in: int
    nfft_out: int
    fs: float
    scale: float = 1.0

    @property
    def hop(self) -> int:
        """Hop between segments (one segment per block), samples."""
        return self.window.size

    @property
    def nfft(self) -> int:
        """FFT length of the windowed residual."""
        return self.nfft_out

    def use(self, noise: np.ndarray, min_snr_db: float) -> np.ndarray:
        """Bins whose coherent power exceeds the noise power by ``min_snr_db`` (bool)."""
        total = float(np.sum(noise))
        trace = np.sum(self.mic_power, axis=1)
        return trace - total >= 10 ** (min_snr_db / 10) * total

    def residual(self, w: np.ndarray, use: np.ndarray) -> np.ndarray:
        """Windowed spectra of the residual signals ``sum_m w_mk * p_m`` at the used bins.

        ``w`` (shape ``(n_model, N, K)``) holds the K = N - 2 noise-whitened null filters
        at ``model_freqs`` (:func:`mpipe.measurement.separation.residual.null_weights`); the
        result is the K residual spectra, one after the other (component-major), shape
        ``(K * sum(use),)``. The
        filter is applied to the unwindowed block with context, and the window only
        afterwards, so that a harmonic between two bins is cancelled exactly at the true
        parameters (filtering the windowed segments instead evaluates the model at the
        bin frequency, not at the harmonic's, a bias of the order of the bin width over
        the harmonic's frequency). The residual signal is band-limited by the filter's
        taper, so it is formed at ``fs / decimation`` (exactly, not an approximation).
        Scaled to unit variance for white noise.
        """
        e = np.sum(w * self.spectra[:, :, None], axis=1) * self.model_taper[:, None]
        full = np.zeros((self.nfft_in // 2 + 1, e.shape[1]), dtype=complex)
        full[self.model_index] = e
        sig = sfft.irfft(full, self.nfft_in, axis=0)[self.margin : self.margin + self.window.size]
        out = sfft.rfft(sig * self.window[:, None], self.nfft_out, axis=0)[self.bins[use]]
        return (out * self.scale).T.reshape(-1)


def _taper(f: np.ndarray, lo0: float, lo1: float, hi0: float, hi1: float) -> np.ndarray:
    up = np.clip((f - lo0) / max(lo1 - lo0, 1e-9), 0.0, 1.0)
    down = np.clip((hi1 - f) / max(hi1 - hi0, 1e-9), 0.0, 1.0)
    return 0.25 * (1 - np.cos(np.pi * up)) * (1 - np.cos(np.pi * down))


def cross_spectra(
    block: np.ndarray,
    fs: float,
    fmin_hz: float,
    fmax_hz: float,
    margin: int = 0,
    f_singular_hz: float | None = None,
) -> BlockSpectra:
    """Prepare a block for the estimation (see :class:`BlockSpectra`).

    Parameters
    ----------
    block : ndarray
        Microphone pressures in Pa, shape ``(length + 2 margin, N)``: the block with
        ``margin`` samples of context on each side.
    fs : float
        Sample rate in Hz.
    fmin_hz, fmax_hz : float
        Estimation band, Hz.
    margin : int
        Context samples on each side.
    f_singular_hz : float, optional
        First singular frequency of the microphone spacing, Hz: the null filter's taper
        ends below 0.9 of it.

    Returns
    -------
    BlockSpectra
    """
    lo0, lo1 = 0.5 * fmin_hz, 0.8 * fmin_hz
    hi1 = 1.2 * fmax_hz + 200.0
    cap = 0.45 * fs if f_singular_hz is None else min(0.9 * f_singular_hz, 0.45 * fs)
    hi1 = min(hi1, cap)
    hi0 = min(fmax_hz + 100.0, 0.5 * (fmax_hz + hi1))
    # The residual signal holds nothing above hi1: it is formed at fs / dec, with a
    # Nyquist frequency at least 1.25 hi1 (the window widens its spectrum a little).
    dec = max(int(fs // (2.5 * hi1)), 1)
    skip = margin % dec
    block = block[skip:]
    margin -= skip
    total = block.shape[0]
    length = (total - 2 * margin) // dec * dec
    win_full = np.hanning(length + 1)[:-1]
    nfft_out = 2 * length
    f_out = np.fft.rfftfreq(nfft_out, 1 / fs)
    keep = (f_out >= fmin_hz) & (f_out <= fmax_hz)
    xw = sfft.rfft(block[margin : margin + length] * win_full[:, None], nfft_out, axis=0)[keep]
    power = np.abs(xw) ** 2 / (fs * np.sum(win_full**2))
    n_small = sfft.next_fast_len(-(-2 * total // dec), real=True)
    nfft_in = n_small * dec
    f_in = np.fft.rfftfreq(nfft_in, 1 / fs)
    model = (f_in > lo0) & (f_in < hi1)
    spec_ = sfft.rfft(block, nfft_in, axis=0)[model]
    win = np.hanning(length // dec + 1)[:-1]
    return BlockSpectra(
        freqs=f_out[keep],
        bins=np.flatnonzero(keep),
        mic_power=power,
        model_freqs=f_in[model],
        model_taper=_taper(f_in[model], lo0, lo1, hi0, hi1),
        model_index=np.flatnonzero(model),
        spectra=spec_,
        window=win,
        margin=margin // dec,
        nfft_in=n_small,
        nfft_out=nfft_out // dec,
        fs=float(fs),
        scale=float(1.0 / np.sqrt(fs * dec * np.sum(win**2))),
    )


def window_correlation(spectra: BlockSpectra) -> dict[int, np.ndarray]:
    """Correlation of white noise between the bins of a windowed block spectrum.

    Returns
    -------
    dict
        Bin offset ``df`` to ``E[X(f) conj(X(f + df))] / E|X|^2`` for white noise: for a
        window ``w`` on a grid of ``N`` bins, ``sum_n w[n]^2 exp(2 pi j df n / N) /
        sum_n w[n]^2`` (the same for every bin).
    """
    w = spectra.window
    n = np.arange(w.size)
    norm = float(np.sum(w**2))
    return {
        df: complex(np.sum(w**2 * np.exp(2j * np.pi * df * n / spectra.nfft_out)) / norm)
        for df in range(-_CORR_BINS, _CORR_BINS + 1)
    }


def block_layout(n: int, fs: float, block_s: float) -> tuple[int, int, np.ndarray]:
    """(hop, length, starts), in samples, of half-overlapping blocks covering the signal.

    Blocks of ``block_s`` s at ``fs`` Hz over ``n`` samples; the first starts half a block
    before the signal, so that the windows sum to one over every sample of it.
    """
    hop = max(int(round(block_s * fs / 2)), 8)
    length = 2 * hop
    # Blocks start half a block before the signal so that the windows sum to one over
    # every sample of it.
    n_blocks = int(np.ceil(n / hop)) + 1
    starts = -hop + hop * np.arange(n_blocks)
    return hop, length, starts


def padded_block(x: np.ndarray, start: int, length: int) -> np.ndarray:
    """Rows ``start`` to ``start + length`` of ``x`` (time along axis 0), zero outside it."""
    out = np.zeros((length, x.shape[1]))
    lo, hi = max(start, 0), min(start + length, x.shape[0])
    if hi > lo:
        out[lo - start : hi - start] = x[lo:hi]
    return out
