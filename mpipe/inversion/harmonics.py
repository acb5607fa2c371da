"""A window's residual split at the note's harmonics: the noise there, and the model's misfit.

Step 2's Jacobian lives at the note's harmonics (the model's answer to a change of a reed
parameter is periodic at the playing frequency f0). The residual ``r = p - p_model`` holds,
at those frequencies, the noise that scatters the estimate and whatever the model cannot
play (its form); between them, noise only. So the residual is fitted, by least squares over
the window, with a constant and the harmonics ``k f0`` (k = 1..K, every one inside the band
where the Jacobian has its energy):

    r = h + e,     h = a_0 + sum_k (a_k cos 2 pi k f0 t + b_k sin 2 pi k f0 t).

``e`` holds no harmonic: its periodogram, averaged over :data:`SPECTRUM_BINS` bins, measures
the noise's spectrum everywhere, the harmonics included (a stationary noise's spectrum is
smooth there). The sinusoids took 2K + 1 of the ``N_b`` real degrees of freedom of the band
(``N_b`` = 2 x the DFT bins between f0/2 and (K + 1/2) f0), so inside the band ``e`` keeps
``(N_b - 2K - 1) / N_b`` of the noise's power: its spectrum is divided by that. This is the
degrees-of-freedom factor of the noise component: it comes from the effective number of
samples in the Jacobian's band, not from the residual's autocorrelation time (driven by
noise below the first harmonic, where the fit does not look).

The noise expected in ``h`` is the rest: ``(2K + 1) / N_b`` of the noise spectrum. What ``h``
holds beyond that is the model's misfit, the **excess spectrum**
``X_f = max(0, H_f - (1 - 1 / c) S_f)`` (``H_f`` the averaged periodogram of ``h``,
``S_f`` the noise spectrum, ``c = N_b / (N_b - 2K - 1)``). The fit has already absorbed the
misfit's projection on its p directions, which the residual cannot show; with no reason for
the misfit to avoid them, the visible excess is ``(2K + 1 - p) / (2K + 1)`` of the whole and
is scaled back by the inverse.

References
----------
ISO/IEC Guide 98-3 (GUM, JCGM 100:2008), sections 4.3 (Type B) and 5.1 (combination).
G. A. F. Seber, C. J. Wild, *Nonlinear Regression*, Wiley 1989, section 2.1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mpipe.inversion.conditioning import estimate_period

#: Periodogram bins averaged into a spectrum (50 Hz apart on a 20 ms window: 250 Hz).
SPECTRUM_BINS = 5

#: The Jacobian's band ends where this fraction of its (column-normalised) energy lies below.
BAND_ENERGY = 0.999

#: Relative half-width of the search that refines f0 (the autocorrelation's estimate is
#: within a fraction of a percent; the 30th harmonic needs f0 to 1e-4 to stay in phase).
F0_SEARCH = 0.004


def smoothed_periodogram(x: np.ndarray, bins: int = SPECTRUM_BINS) -> np.ndarray:
    """``|X_f|^2 / n`` on the one-sided DFT grid, averaged over ``bins`` neighbouring bins.

    Mirrored at 0 and Nyquist. ``sum_f w_f P_f = ||x||^2`` before the average (w_f the
    one-sided weights, :func:`one_sided_weights`). Unit: that of x squared.
    """
    n = x.size
    power = np.abs(np.fft.rfft(x)) ** 2 / n
    half = bins // 2
    if half == 0 or power.size <= half + 1:
        return power
    padded = np.concatenate([power[1 : half + 1][::-1], power, power[-half - 1 : -1][::-1]])
    return np.convolve(padded, np.ones(bins) / bins, mode="valid")[: power.size]


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

    A coarse scan over +-:data:`F0_SEARCH` and a parabola through the best three.
    """
    grid = f0 * (1 + np.linspace(-F0_SEARCH, F0_SEARCH, 9))
    power = [float(np.sum(_harmonic_fit(p, fs, f, harmonics) ** 2)) for f in grid]
    i = int(np.clip(np.argmax(power), 1, grid.size - 2))
    y0, y1, y2 = power[i - 1 : i + 2]
    den = y0 - 2 * y1 + y2
    step = 0.5 * (y0 - y2) / den if den < 0 else 0.0
    return float(grid[i] + np.clip(step, -1, 1) * (grid[1] - grid[0]))


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
    top = min(band_top(j, fs), 0.5 * fs)
    f0 = fs / period
    k = int(math.floor(top / f0 - 0.5))
    if k < 1:
        return None
    f0 = refine_f0(p - p.mean(), fs, f0, min(k, 10))
    k = max(1, int(math.floor(min(top, 0.5 * fs) / f0 - 0.5)))
    h = _harmonic_fit(r, fs, f0, k)
    freqs = np.fft.rfftfreq(n, 1 / fs)
    inband = (freqs >= 0.5 * f0) & (freqs <= (k + 0.5) * f0)
    band_dof = 2.0 * float(np.count_nonzero(inband))
    noise_dof = band_dof - 2 * k - 1
    if noise_dof < 1:
        return None
    c = band_dof / noise_dof
    w = one_sided_weights(n)
    noise = smoothed_periodogram(r - h) * np.where(inband, c, 1.0)
    held = np.where(inband, 1.0 - 1.0 / c, 0.0) * noise
    visible = np.clip(smoothed_periodogram(h) - held, 0.0, None)
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
    "band_top",
    "one_sided_weights",
    "refine_f0",
    "smoothed_periodogram",
    "spectral_gram",
    "split_residual",
]
