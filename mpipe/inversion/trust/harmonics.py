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
from scipy.linalg import solve_triangular

from mpipe.core.harmonic_fit import (
    amplitudes,
    bin_columns,
    centred_gram,
    centred_projection,
    harmonic_synthesis,
)
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


def column_spectra(j: np.ndarray) -> np.ndarray:
    """The DFT of every column of ``j`` (n, p), shape (n // 2 + 1, p): ``rfft(j, axis=0)``.

    Transformed as contiguous rows of ``j.T`` (the same transforms, a quarter of the time
    of the strided ones on a window's Jacobian).
    """
    return np.fft.rfft(np.ascontiguousarray(np.asarray(j, dtype=float).T), axis=1).T


def band_top(j: np.ndarray, fs: float, energy: float = BAND_ENERGY, jf=None) -> float:
    """Frequency below which ``energy`` of the Jacobian's column-normalised energy lies, Hz.

    ``jf``: :func:`column_spectra` of ``j`` when already computed.
    """
    n = j.shape[0]
    jf = np.abs(column_spectra(j) if jf is None else jf) ** 2
    tot = jf.sum(axis=0)
    share = (jf / np.where(tot > 0, tot, 1.0)).sum(axis=1) * one_sided_weights(n)
    cum = np.cumsum(share) / max(share.sum(), 1e-300)
    return float(np.searchsorted(cum, energy) + 1) * fs / n


def _dirichlet(w: np.ndarray, n: int) -> np.ndarray:
    """``sum_{t<n} exp(i w t)`` in closed form (the Dirichlet kernel), exact near w = 0."""
    half = 0.5 * np.asarray(w, dtype=float)
    s = np.sin(half)
    tiny = np.abs(s) < 1e-12
    ratio = np.where(tiny, float(n), np.sin(n * half) / np.where(tiny, 1.0, s))
    return np.exp(1j * (n - 1) * half) * ratio


class HarmonicBasis:
    """The constant-plus-harmonics design of an n-sample window, through its Gram matrix.

    Columns ``[1, cos(w_k t), sin(w_k t)]``, ``w_k = 2 pi k f0 / fs``, k = 1..K. The Gram
    matrix ``H^T H`` has a closed form (sums of Dirichlet kernels at ``w_k +- w_l``) and
    ``H^T x`` is the DFT of x at the harmonics (powers of one complex exponential), so the
    fit's power costs O(n K + K^3) instead of the O(n K^2) of a least-squares solve on H.
    The values are those of ``numpy.linalg.lstsq`` on the explicit design to rounding (the
    design is far from rank deficient while every harmonic stays below Nyquist).

    One f0 at a time, on the window's own time: the plain reference of the batched fits
    (:func:`_fit_powers`, :func:`_harmonic_parts`, on the centred design of
    :mod:`mpipe.core.harmonic_fit`) and their fallback on a degenerate design.

    Raises ``numpy.linalg.LinAlgError`` when the Gram matrix is not positive definite.
    """

    def __init__(self, n: int, fs: float, f0: float, harmonics: int):
        self.n, self.k = n, harmonics
        self.w = 2 * np.pi * f0 / fs  # rad per sample
        # w_k +- w_l = (k +- l) w: the Dirichlet kernel at the multiples -K..2K of w
        d = _dirichlet(self.w * np.arange(-harmonics, 2 * harmonics + 1), n)
        k = np.arange(1, harmonics + 1)
        plus = d[harmonics + k[:, None] + k[None, :]]
        minus = d[harmonics + k[:, None] - k[None, :]]
        ones = d[harmonics + k]
        m = 2 * harmonics + 1
        c, s = slice(1, harmonics + 1), slice(harmonics + 1, m)
        g = np.empty((m, m))
        g[0, 0] = n
        g[0, c] = g[c, 0] = ones.real
        g[0, s] = g[s, 0] = ones.imag
        g[c, c] = 0.5 * (minus.real + plus.real)
        g[s, s] = 0.5 * (minus.real - plus.real)
        # sum cos(w_k t) sin(w_l t) = Im(D(w_l + w_k) + D(w_l - w_k)) / 2
        g[c, s] = 0.5 * (plus.imag - minus.imag)
        g[s, c] = g[c, s].T
        self.gram = g
        self.chol = np.linalg.cholesky(g)

    def _exponentials(self):
        """``exp(i w_1 t)`` and its k-th powers one at a time (phase error ~k eps)."""
        z = np.exp(1j * self.w * np.arange(self.n))
        zk = z.copy()
        for _ in range(self.k):
            yield zk
            zk = zk * z

    def project(self, x: np.ndarray) -> np.ndarray:
        """``H^T x`` for x of shape (n,): the DFT of x at the harmonics."""
        dft = np.array([zk @ x for zk in self._exponentials()], dtype=complex)
        return np.concatenate([[np.sum(x)], dft.real, dft.imag])

    def power(self, x: np.ndarray) -> float:
        """``||H c||^2`` of the least-squares fit ``H c ~ x`` (x's unit^2)."""
        y = solve_triangular(self.chol, self.project(x), lower=True)  # L y = H^T x
        return float(y @ y)

    def design(self) -> np.ndarray:
        """The explicit design H, shape (n, 2K + 1)."""
        powers = np.array(list(self._exponentials())).reshape(self.k, self.n)
        return np.column_stack([np.ones(self.n), powers.real.T, powers.imag.T])

    def orthonormal(self) -> np.ndarray:
        """An orthonormal basis of H's columns, shape (n, 2K + 1): ``H L^-T``."""
        return solve_triangular(self.chol, self.design().T, lower=True).T


def _harmonic_fit(x: np.ndarray, fs: float, f0: float, harmonics: int) -> np.ndarray:
    """The constant-plus-harmonics least-squares fit of x (same unit)."""
    h = _design(x.size, fs, f0, harmonics)
    coef, *_ = np.linalg.lstsq(h, x, rcond=None)
    return h @ coef


def _fit_power(x: np.ndarray, fs: float, f0: float, harmonics: int) -> float:
    """Power of :func:`_harmonic_fit` (x's unit^2), through the Gram matrix when it can."""
    try:
        return HarmonicBasis(x.size, fs, f0, harmonics).power(x)
    except np.linalg.LinAlgError:  # a degenerate design: the rank-revealing solve
        return float(np.sum(_harmonic_fit(x, fs, f0, harmonics) ** 2))


def _orthonormal(n: int, fs: float, f0: float, harmonics: int) -> np.ndarray:
    """An orthonormal basis of the harmonic design, shape (n, 2K + 1)."""
    try:
        return HarmonicBasis(n, fs, f0, harmonics).orthonormal()
    except np.linalg.LinAlgError:  # a degenerate design: Householder QR of it
        return np.linalg.qr(_design(n, fs, f0, harmonics))[0]


def _design(n: int, fs: float, f0: float, harmonics: int) -> np.ndarray:
    t = np.arange(n) / fs
    arg = 2 * np.pi * f0 * np.outer(t, np.arange(1, harmonics + 1))
    return np.column_stack([np.ones(n), np.cos(arg), np.sin(arg)])


def refine_f0(p: np.ndarray, fs: float, f0: float, harmonics: int) -> float:
    """f0 (Hz) maximising the power of ``p``'s harmonic fit, near the given one.

    Three passes, each a 5-point scan and a parabola through the best three, from
    +-:data:`F0_SEARCH` down to a sixteenth of it (the 30th harmonic needs f0 to 1e-4).
    Each pass's five fits at once (:func:`_fit_powers`).
    """
    return _search(p, fs, f0, harmonics, _fit_powers)


def _refine_f0_reference(p: np.ndarray, fs: float, f0: float, harmonics: int) -> float:
    """:func:`refine_f0` one fit at a time (the plain reference), Hz."""
    return _search(p, fs, f0, harmonics, _scan_reference)


def _search(p: np.ndarray, fs: float, f0: float, harmonics: int, scan) -> float:
    """:func:`refine_f0` with the powers of a scan ``scan(p, fs, grid_hz, harmonics)``, Hz."""
    width = F0_SEARCH
    for _ in range(3):
        grid = f0 * (1 + np.linspace(-width, width, 5))
        power = scan(p, fs, grid, harmonics)
        i = int(np.clip(np.argmax(power), 1, grid.size - 2))
        y0, y1, y2 = power[i - 1 : i + 2]
        den = y0 - 2 * y1 + y2
        step = 0.5 * (y0 - y2) / den if den < 0 else 0.0
        f0 = float(grid[i] + np.clip(step, -1, 1) * (grid[1] - grid[0]))
        width /= 4
    return f0


def _fit_powers(x: np.ndarray, fs: float, f0s: np.ndarray, harmonics: int) -> np.ndarray:
    """:func:`_fit_power` at every candidate f0 (Hz, shape (G,)) at once, x's unit^2.

    On the centred design (:mod:`mpipe.core.harmonic_fit`), block by block: the power is
    ``||L^-1 b||^2`` (L the block's Cholesky factor, b its projection), read from the
    factor of the Gram matrix bordered by b (:func:`_bordered_power`). A degenerate design
    sends the scan to :func:`_scan_reference`.
    """
    w = 2 * np.pi * np.asarray(f0s, dtype=float) / fs
    grams = centred_gram(x.size, w, harmonics)
    projections = centred_projection(x, w, harmonics)
    corner = 2.0 * float(x @ x) + 1.0  # above any fit's power: the bordered matrix stays PD
    try:
        return sum(_bordered_power(g, b, corner) for g, b in zip(grams, projections, strict=True))
    except np.linalg.LinAlgError:
        return _scan_reference(x, fs, f0s, harmonics)


def _bordered_power(gram: np.ndarray, b: np.ndarray, corner: float) -> np.ndarray:
    """``||L^-1 b||^2`` for each of a stack of Gram matrices ``G = L L^T`` (b's unit^2).

    The Cholesky factor of ``[[G, b], [b^T, c]]`` is ``[[L, 0], [(L^-1 b)^T, d]]``: one
    factorisation gives both (``c`` above ``b^T G^-1 b`` keeps it positive definite).
    Raises ``numpy.linalg.LinAlgError`` when G is not positive definite.
    """
    m = gram.shape[-1]
    bordered = np.empty((*gram.shape[:-2], m + 1, m + 1))
    bordered[..., :m, :m] = gram
    bordered[..., :m, m] = bordered[..., m, :m] = b
    bordered[..., m, m] = corner
    last = np.linalg.cholesky(bordered)[..., m, :m]
    return np.sum(last**2, axis=-1)


def _scan_reference(x: np.ndarray, fs: float, f0s: np.ndarray, harmonics: int) -> np.ndarray:
    """:func:`_fit_powers` one candidate at a time (the plain reference), x's unit^2."""
    return np.array([_fit_power(x, fs, f, harmonics) for f in f0s])


def _harmonic_parts(r: np.ndarray, p: np.ndarray, fs: float, f0: float, harmonics: int):
    """The harmonic fits of r and p (Pa) and the share of each DFT bin the fit takes.

    The share is ``sum_j |DFT_f(q_j)|^2 / n`` over an orthonormal basis q of the span
    (what a white noise's power at bin f leaves in the fit, dimensionless): with ``q = H
    L^-T`` per block of the centred design, ``||L^-1 c_f||^2 / n``, ``c_f`` the design's
    DFT at the bin (real up to a phase the blocks share, :func:`bin_columns`). No basis
    is formed: :func:`_harmonic_parts_reference` forms it, and is the fallback of a
    degenerate design.
    """
    n, w = r.size, 2 * np.pi * f0 / fs
    try:
        chols = [np.linalg.cholesky(g) for g in centred_gram(n, w, harmonics)]
    except np.linalg.LinAlgError:
        return _harmonic_parts_reference(r, p, fs, f0, harmonics)
    # L^-1 of each block (a product with it is faster than a triangular solve of many)
    inverse = [solve_triangular(c, np.eye(c.shape[0]), lower=True) for c in chols]
    blocks = centred_projection(np.stack([r, p]), w, harmonics)  # (2, K + 1), (2, K)
    coef = [(li.T @ (li @ b.T)).T for li, b in zip(inverse, blocks, strict=True)]  # G^-1 b
    constant, lines = amplitudes(coef[0], coef[1], w, n)
    fits = constant[:, None] + harmonic_synthesis(lines, w, np.arange(1, harmonics + 1), n)
    columns = bin_columns(n, w, harmonics)
    held = sum(np.sum((li @ c) ** 2, axis=0) for li, c in zip(inverse, columns, strict=True))
    return fits[0], fits[1], held / n


def _harmonic_parts_reference(r: np.ndarray, p: np.ndarray, fs: float, f0: float, harmonics: int):
    """:func:`_harmonic_parts` through an orthonormal basis and its FFT (the plain reference)."""
    basis = _orthonormal(r.size, fs, f0, harmonics)
    held = periodogram(basis).sum(axis=1)
    return basis @ (basis.T @ r), basis @ (basis.T @ p), held


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
    r: np.ndarray, p: np.ndarray, j: np.ndarray, fs: float, *, floor: float = 0.0, jf=None
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
    jf : ndarray, optional
        :func:`column_spectra` of ``j`` when already computed.

    Returns
    -------
    ResidualSplit or None
        None when ``p`` has no period in 60-2000 Hz or the band holds no harmonic.
    """
    return _split(r, p, j, fs, floor, refine_f0, _harmonic_parts, jf)


def _split(r, p, j, fs, floor, refine, parts, jf=None) -> ResidualSplit | None:
    """:func:`split_residual` with its f0 search ``refine`` and harmonic fit ``parts``.

    ``(refine_f0, _harmonic_parts)`` batched, or ``(_refine_f0_reference,
    _harmonic_parts_reference)``: the plain reference, one fit at a time.
    """
    n = r.size
    period = estimate_period(p, fs)
    if not period > 0:
        return None
    # the harmonics of the Jacobian's band and of the pressure's (a misfit sits where the
    # note has power, and one left out of h would be counted as noise next to the band)
    top = min(max(band_top(j, fs, jf=jf), band_top((p - p.mean())[:, None], fs)), 0.5 * fs)
    f0 = fs / period
    k = _count(top, f0, fs)
    if k < 1:
        return None
    f0 = refine(p - p.mean(), fs, f0, k)
    k = max(1, _count(top, f0, fs))
    # h: the residual's harmonic fit; held: the share of a white noise's power at each bin
    # that the fit takes into h (exactly: sum over an orthonormal basis of |DFT|^2 / n), so
    # e = r - h keeps 1 - held of it; ph: p's fit, the same projection
    h, ph, held = parts(r, p, fs, f0, k)
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


def spectral_gram(j: np.ndarray, spectrum: np.ndarray, jf=None) -> np.ndarray:
    """``J^T Sigma J`` for a stationary noise of one-sided spectrum ``spectrum`` (Pa^2).

    ``(1/n) sum_f w_f Re(J_f^H J_f) S_f``: ``s^2 J^T J`` for white noise of variance s^2.
    ``jf``: :func:`column_spectra` of ``j`` when already computed.
    """
    n = j.shape[0]
    jf = column_spectra(j) if jf is None else jf
    return np.real((jf.conj().T * (one_sided_weights(n) * spectrum)) @ jf) / n


__all__ = [
    "BAND_ENERGY",
    "column_spectra",
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
