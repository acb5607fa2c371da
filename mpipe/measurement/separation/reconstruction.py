"""Reconstruction of p0 and u0 from the blocks (physics.md E.4).

Every block is multiplied by a periodic Hann window (hop = half a block, so the windows sum
to one), zero-padded, separated in the frequency domain with its smoothed theta and
overlap-added (:func:`overlap_add`): no block seams, and with a fixed theta one linear
filtering of the whole take. The separation filters fall to zero above the band edge (Hz)
before the first singular frequency, and the u0 filter rises from zero at low frequency
(u0 is unmeasurable at DC). :func:`reference_noise` carries the sensor noise (Pa^2/Hz)
through the same filters.
"""

from __future__ import annotations

import numpy as np
from scipy import fft as sfft

from mpipe.measurement.separation.blocks import padded_block
from mpipe.measurement.separation.settings import SeparationConfig
from mpipe.measurement.separation.waves import Geometry, Theta, separation_filters


def _band_taper(
    freqs: np.ndarray, config: SeparationConfig, geometry: Geometry, theta: Theta
) -> np.ndarray:
    # The taper must reach zero before the first singular frequency of this block's theta
    # (physics.md E.4), which moves with temperature and flow.
    f1 = theta.c * (1 - theta.mach**2) / (2 * geometry.spacing)
    hi = min(config.band_edge_hz + config.band_taper_hz, 0.97 * f1)
    lo = min(config.band_edge_hz, hi - 0.5 * config.band_taper_hz)
    x = np.clip((freqs - lo) / (hi - lo), 0.0, 1.0)
    return 0.5 * (1 + np.cos(np.pi * x))


def _u_ramp(freqs: np.ndarray, config: SeparationConfig) -> np.ndarray:
    hi = config.u_highpass_hz
    lo = hi / 2
    x = np.clip((freqs - lo) / (hi - lo), 0.0, 1.0)
    return 0.5 * (1 - np.cos(np.pi * x))


def _tapered_filters(
    freqs: np.ndarray, theta: Theta, geometry: Geometry, config: SeparationConfig, ramp: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The separation filters to P0 and U0 with the band taper, and the u0 ramp on U0's."""
    g_p, g_u = separation_filters(freqs, theta, geometry)
    taper = _band_taper(freqs, config, geometry, theta)
    return g_p * taper[:, None], g_u * (taper * ramp)[:, None]


def reference_noise(
    freqs: np.ndarray,
    theta: Theta,
    geometry: Geometry,
    noise_psd: np.ndarray,
    config: SeparationConfig,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Power spectral densities of the sensor noise carried into p0 and u0.

    Parameters
    ----------
    freqs : ndarray
        Frequencies, Hz.
    theta : Theta
        Propagation parameters of the separation filters.
    geometry : Geometry
        Microphones and bore.
    noise_psd : ndarray
        One-sided white-noise PSD of each microphone, Pa^2/Hz, shape ``(N,)``.
    config : SeparationConfig
        Band taper and u0 ramp.

    Returns
    -------
    s_pp : ndarray
        One-sided PSD of the noise in p0, Pa^2/Hz.
    s_uu : ndarray
        One-sided PSD of the noise in u0, (m^3/s)^2/Hz.
    s_pu : ndarray
        Their cross-spectral density ``E[N_p conj(N_u)]``, Pa m^3/s/Hz (complex).

    Notes
    -----
    ``N_U0 = sum_m g_u,m N_m`` with independent channel noises, so ``S_uu = sum_m |g_u,m|^2
    D_m``. Below the first resonance of the microphone spacing, ``|g_u| ~ 1 / (Z_c k s)``:
    the noise of u0 rises as 1 / f towards low frequency (physics.md E.4).
    """
    freqs = np.asarray(freqs, dtype=float)
    g_p, g_u = _tapered_filters(freqs, theta, geometry, config, _u_ramp(freqs, config))
    d = np.asarray(noise_psd, dtype=float)[None, :]
    s_pp = np.sum(np.abs(g_p) ** 2 * d, axis=1)
    s_uu = np.sum(np.abs(g_u) ** 2 * d, axis=1)
    s_pu = np.sum(g_p * np.conj(g_u) * d, axis=1)
    return s_pp, s_uu, s_pu


def overlap_add(
    x: np.ndarray,
    fs: float,
    starts: np.ndarray,
    length: int,
    smooth: np.ndarray,
    c_track: np.ndarray,
    geometry: Geometry,
    config: SeparationConfig,
) -> tuple[np.ndarray, np.ndarray]:
    """Separate every windowed block with its smoothed theta and overlap-add.

    Parameters
    ----------
    x : ndarray
        Microphone pressures, Pa, shape ``(n, N)``.
    fs : float
        Sample rate, Hz.
    starts : ndarray
        First sample of every block (half a block apart).
    length : int
        Block length, samples.
    smooth : ndarray
        Shape ``(n_blocks, 4)``: theta of every block (degC, eta, M, position correction
        of the middle microphone in m).
    c_track : ndarray
        Sound speed of every block, m/s.
    geometry : Geometry
        Microphones and bore (before the position correction).
    config : SeparationConfig
        ``pad_s``, the band taper and the u0 ramp.

    Returns
    -------
    p0 : ndarray
        Pressure at the reference plane, Pa, shape ``(n,)``.
    u0 : ndarray
        Volume flow at the reference plane, m^3/s, shape ``(n,)``.
    """
    n = x.shape[0]
    p0, u0 = np.zeros(n), np.zeros(n)
    for a, b, chunk in overlap_add_blocks(x, fs, starts, length, smooth, c_track, geometry,
                                          config):  # fmt: skip
        p0[a:b], u0[a:b] = chunk[:, 0], chunk[:, 1]
    return p0, u0


# Eight parameters: those of overlap_add, whose blocks these are.
def overlap_add_blocks(x, fs, starts, length, smooth, c_track, geometry, config):
    """:func:`overlap_add`'s p0 and u0 in stretches, each yielded once it is complete.

    Yields ``(a, b, chunk)``: samples ``a..b`` of ``[p0, u0]`` (shape ``(b - a, 2)``), in
    order, covering the take. Each block's inverse FFT is added where it falls, in block
    order, into a buffer that holds only the samples later blocks still reach; the samples
    before the next block's first one are final and leave the buffer. The same additions
    in the same order as one buffer of the whole take: the same numbers, with memory
    bounded by a block. ``x`` is only sliced (a take on disk is read block by block).
    """
    n, n_mics = x.shape
    pad = int(round(config.pad_s * fs))
    nfft = sfft.next_fast_len(length + 2 * pad, real=True)
    freqs = np.fft.rfftfreq(nfft, 1 / fs)
    band = freqs <= config.band_edge_hz + config.band_taper_hz
    fb = freqs[band]
    ramp = _u_ramp(fb, config)
    win = np.hanning(length + 1)[:-1]  # periodic Hann: shifted copies at hop sum to one
    base, acc = 0, np.zeros((0, 2))  # acc holds samples base.. (sample 0 is the take's)
    done = 0  # samples of the take already yielded
    for k, s in enumerate(starts):
        lo = int(s) - pad  # the block's padded inverse FFT covers lo..lo + nfft
        if k == 0:
            base = min(lo, 0)
        if lo > base:  # samples before lo are final: no later block reaches them
            done = yield from _emit(acc[: lo - base], base, done, n)
            acc, base = acc[lo - base :], lo
        if lo + nfft > base + acc.shape[0]:
            acc = np.concatenate([acc, np.zeros((lo + nfft - base - acc.shape[0], 2))])
        th = Theta(c_track[k], smooth[k, 1], smooth[k, 2])
        geo_b = geometry.corrected(float(smooth[k, 3]))
        g_p, g_u = _tapered_filters(fb, th, geo_b, config, ramp)
        seg = np.zeros((nfft, n_mics))
        seg[pad : pad + length] = padded_block(x, int(s), length) * win[:, None]
        spec_ = np.fft.rfft(seg, axis=0)[band]
        y = np.zeros((freqs.size, 2), dtype=complex)
        y[band, 0] = np.sum(g_p * spec_, axis=1)
        y[band, 1] = np.sum(g_u * spec_, axis=1)
        acc[lo - base : lo - base + nfft] += np.fft.irfft(y, nfft, axis=0)
    done = yield from _emit(acc, base, done, n)
    if done < n:  # samples no block reached stay zero
        yield done, n, np.zeros((n - done, 2))


def _emit(acc: np.ndarray, base: int, done: int, n: int):
    """Yield the part of ``acc`` (samples ``base..``) inside the take; return the new end."""
    a, b = max(base, done, 0), min(base + acc.shape[0], n)
    if b > a:
        if a > done:  # samples before the first block: no block reached them
            yield done, a, np.zeros((a - done, 2))
        yield a, b, acc[a - base : b - base]
        return b
    return done
