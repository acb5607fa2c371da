"""Frozen copy of the harmonic split (mpipe.inversion.trust.harmonics) before issue 31.

Its f0 search solved 15 least-squares problems on the explicit harmonic design per window
and its split took a Householder QR of it; mpipe.inversion.trust.harmonics now goes through the
design's closed-form Gram matrix. Not a benchmark of its own (run_all.py runs bench_*.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mpipe.inversion.preparation.conditioning import estimate_period

#: Periodogram bins averaged into a spectrum (50 Hz apart on a 20 ms window: 250 Hz).
SPECTRUM_BINS = 5

#: The Jacobian's band ends where this fraction of its (column-normalised) energy lies below.
BAND_ENERGY = 0.999

#: Relative half-width of the search that refines f0 (the autocorrelation's estimate is
#: within a fraction of a percent; the 30th harmonic needs f0 to 1e-4 to stay in phase).
F0_SEARCH = 0.004


def band_average(
    values: np.ndarray, bins: int = SPECTRUM_BINS, use: np.ndarray | None = None
) -> np.ndarray:
    """Average of per-bin ``values`` over ``bins`` neighbouring one-sided DFT bins.

    Mirrored at 0 and Nyquist. ``use`` (bool per bin): only those bins enter the average
    (a bin whose neighbourhood holds none of them keeps its own value).
    """
    half = bins // 2
    if half == 0 or values.size <= half + 1:
        return values
    mask = np.ones(values.size) if use is None else np.asarray(use, dtype=float)

    def total(v: np.ndarray) -> np.ndarray:
        padded = np.concatenate([v[1 : half + 1][::-1], v, v[-half - 1 : -1][::-1]])
        return np.convolve(padded, np.ones(bins), mode="valid")[: v.size]

    count = total(mask)
    return np.where(count > 0, total(values * mask) / np.where(count > 0, count, 1), values)


def periodogram(x: np.ndarray) -> np.ndarray:
    """``|X_f|^2 / n`` on the one-sided DFT grid (``sum_f w_f P_f = ||x||^2``; x's unit^2)."""
    return np.abs(np.fft.rfft(x, axis=0)) ** 2 / x.shape[0]


def smoothed_periodogram(x: np.ndarray, bins: int = SPECTRUM_BINS) -> np.ndarray:
    """:func:`periodogram` averaged over ``bins`` neighbouring bins (:func:`band_average`)."""
    return band_average(periodogram(x), bins)


def one_sided_weights(n: int) -> np.ndarray:
    """Weights of the one-sided DFT bins of an n-sample signal (1 at DC and Nyquist, else 2)."""
    w = np.full(n // 2 + 1, 2.0)
    w[0] = 1.0
    if n % 2 == 0:
        w[-1] = 1.0
    return w


def band_top(j: np.ndarray, fs: float, energy: float = BAND_ENERGY) -> float:
    """Frequency below which ``energy`` of the Jacobian's column-normalised energy lies, Hz."""
    n = j.shape[0]
    jf = np.abs(np.fft.rfft(j, axis=0)) ** 2
    tot = jf.sum(axis=0)
    share = (jf / np.where(tot > 0, tot, 1.0)).sum(axis=1) * one_sided_weights(n)
    cum = np.cumsum(share) / max(share.sum(), 1e-300)
    return float(np.searchsorted(cum, energy) + 1) * fs / n


def _design(n: int, fs: float, f0: float, harmonics: int) -> np.ndarray:
    t = np.arange(n) / fs
    arg = 2 * np.pi * f0 * np.outer(t, np.arange(1, harmonics + 1))
    return np.column_stack([np.ones(n), np.cos(arg), np.sin(arg)])


def _harmonic_fit(x: np.ndarray, fs: float, f0: float, harmonics: int) -> np.ndarray:
    """The constant-plus-harmonics least-squares fit of x (same unit)."""
    h = _design(x.size, fs, f0, harmonics)
    coef, *_ = np.linalg.lstsq(h, x, rcond=None)
    return h @ coef


def refine_f0(p: np.ndarray, fs: float, f0: float, harmonics: int) -> float:
    """f0 (Hz) maximising the power of ``p``'s harmonic fit, near the given one.

    Three passes, each a 5-point scan and a parabola through the best three, from
    +-:data:`F0_SEARCH` down to a sixteenth of it (the 30th harmonic needs f0 to 1e-4).
    """
    width = F0_SEARCH
    for _ in range(3):
        grid = f0 * (1 + np.linspace(-width, width, 5))
        power = [float(np.sum(_harmonic_fit(p, fs, f, harmonics) ** 2)) for f in grid]
        i = int(np.clip(np.argmax(power), 1, grid.size - 2))
        y0, y1, y2 = power[i - 1 : i + 2]
        den = y0 - 2 * y1 + y2
        step = 0.5 * (y0 - y2) / den if den < 0 else 0.0
        f0 = float(grid[i] + np.clip(step, -1, 1) * (grid[1] - grid[0]))
        width /= 4
    return f0


def _count(top: float, f0: float, fs: float) -> int:
    """Harmonics up to the band's top (the nearest), their half-spacing below Nyquist."""
    return min(int(math.floor(top / f0 + 0.5)), int(math.floor(0.5 * fs / f0 - 0.5)))


@dataclass(frozen=True)
class ResidualSplit:
    """A window's residual split at the harmonics (see the module docstring).

    Attributes
    ----------
    f0 : float
        Playing frequency of the window, Hz.
    harmonics : int
        K, harmonics fitted (all inside the Jacobian's band).
    band_dof : float
        N_b, real degrees of freedom of the band (2 x its DFT bins).
    noise_dof : float
        N_b - 2K - 1: those left to measure the noise.
    noise : ndarray
        Noise spectrum S_f on the one-sided DFT grid, Pa^2 (``sum w_f S_f`` is the noise's
        expected ``||r||^2``).
    excess : ndarray
        Model-form spectrum X_f (absorbed share included), Pa^2.
    noise_residual : float
        Relative residual the noise alone leaves: ``sqrt(sum w_f S_f) / ||p||``.
    model_residual : float
        Relative residual at the harmonics beyond the noise (visible):
        ``sqrt(sum w_f X_f) / ||p||`` before the absorbed share.
    """

    f0: float
    harmonics: int
    band_dof: float
    noise_dof: float
    noise: np.ndarray
    excess: np.ndarray
    noise_residual: float
    model_residual: float


def split_residual(
    r: np.ndarray, p: np.ndarray, j: np.ndarray, fs: float, *, floor: float = 0.0
) -> ResidualSplit | None:
    """Noise and model-form spectra of a window's residual, or None without a period.

    Parameters
    ----------
    r : ndarray
        Residual ``p - p_model`` at the solution, Pa.
    p : ndarray
        Measured pressure over the window, Pa (its period gives f0).
    j : ndarray
        Jacobian ``dr / d ln x``, shape ``(n, p)``, Pa (its band bounds the harmonics).
    fs : float
        Sample rate, Hz.
    floor : float
        Model-form floor: the misfit assumed at least at every harmonic k >= 1, as a fraction
        of the measured pressure's amplitude there (``inversion.model_form_floor``).

    Returns
    -------
    ResidualSplit or None
        None when ``p`` has no period in 60-2000 Hz or the band holds no harmonic.
    """
    n = r.size
    period = estimate_period(p, fs)
    if not period > 0:
        return None
    # the harmonics of the Jacobian's band and of the pressure's (a misfit sits where the
    # note has power, and one left out of h would be counted as noise next to the band)
    top = min(max(band_top(j, fs), band_top((p - p.mean())[:, None], fs)), 0.5 * fs)
    f0 = fs / period
    k = _count(top, f0, fs)
    if k < 1:
        return None
    f0 = refine_f0(p - p.mean(), fs, f0, k)
    k = max(1, _count(top, f0, fs))
    basis, _ = np.linalg.qr(_design(n, fs, f0, k))
    h = basis @ (basis.T @ r)
    # share of a white noise's power at each bin that the harmonic fit takes into h
    # (exactly: sum over the basis of |DFT|^2 / n), so e = r - h keeps 1 - held of it
    held = periodogram(basis).sum(axis=1)
    freqs = np.fft.rfftfreq(n, 1 / fs)
    inband = (freqs >= 0.5 * f0) & (freqs <= (k + 0.5) * f0)
    band_dof = 2.0 * float(np.count_nonzero(inband))
    noise_dof = 2.0 * float(np.sum(1.0 - held[inband]))
    if noise_dof < 1:
        return None
    w = one_sided_weights(n)

    # in the band the noise at a harmonic is averaged over the band's bins only: the noise
    # below f0/2 (a slow drift) is where the Jacobian does not look
    def average(values: np.ndarray) -> np.ndarray:
        return np.where(inband, band_average(values, use=inband),
                        band_average(values, use=~inband))  # fmt: skip

    noise = average(periodogram(r - h)) / np.clip(average(1.0 - held), 1e-3, None)
    expected = average(held) * noise  # the noise's share of h
    visible = np.clip(average(periodogram(h)) - expected, 0.0, None)
    absorbed = (2 * k + 1) / max(2 * k + 1 - j.shape[1], 1)
    excess = visible * absorbed
    if floor > 0:
        ph = _harmonic_fit(p, fs, f0, k)
        excess = np.maximum(excess, floor**2 * smoothed_periodogram(ph - ph.mean()))
    norm_p2 = float(np.sum(p**2)) + 1e-300
    return ResidualSplit(
        f0=f0,
        harmonics=k,
        band_dof=band_dof,
        noise_dof=noise_dof,
        noise=noise,
        excess=excess,
        noise_residual=math.sqrt(float(np.sum(w * noise)) / norm_p2),
        model_residual=math.sqrt(float(np.sum(w * visible)) / norm_p2),
    )


def spectral_gram(j: np.ndarray, spectrum: np.ndarray) -> np.ndarray:
    """``J^T Sigma J`` for a stationary noise of one-sided spectrum ``spectrum`` (Pa^2).

    ``(1/n) sum_f w_f Re(J_f^H J_f) S_f``: ``s^2 J^T J`` for white noise of variance s^2.
    """
    n = j.shape[0]
    jf = np.fft.rfft(j, axis=0)
    return np.real((jf.conj().T * (one_sided_weights(n) * spectrum)) @ jf) / n


__all__ = [
    "BAND_ENERGY",
    "F0_SEARCH",
    "ResidualSplit",
    "SPECTRUM_BINS",
    "band_average",
    "band_top",
    "one_sided_weights",
    "periodogram",
    "refine_f0",
    "smoothed_periodogram",
    "spectral_gram",
    "split_residual",
]
