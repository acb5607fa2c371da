"""Covariance of the step-2 estimates (coloured residual), and what the data cannot determine.

Step 2 is a nonlinear least-squares fit of the residual vector ``r = p - p_model`` (Pa,
one entry per sample of the window) in log parameters ``z = ln x``. Near the solution
the model is linear in ``z`` with Jacobian ``J = dr/dz`` (shape ``(n, p)``), and the
covariance of the estimate is the sandwich

    cov(z) = A^-1 B A^-1,     A = J^T J,     B = J^T Sigma J,

with ``Sigma`` the covariance of the noise in ``r``.

**Coloured residual: the sandwich in the frequency domain.** The residual is far from
white: the mouthpiece pressure's noise comes through the wave separation and the 7.25 kHz
low-pass, and on a measured take most of its power lies below a few hundred hertz (its
integrated autocorrelation time ``tau`` is about 100 samples at 100 kHz), while the
Jacobian's columns live at the note's harmonics. For a stationary noise over the window
``Sigma`` is nearly circulant, so ``B = (1/n) sum_f w_f Re(J_f^H J_f) S_f`` with ``J_f``
the DFT of the columns, ``w_f`` the one-sided weights and ``S_f`` the residual's
periodogram ``|R_f|^2 / n`` averaged over :data:`SPECTRUM_BINS` neighbouring bins: each
frequency's noise is weighted by how much the parameters' signature holds there. For white
noise of variance s^2 this is ``s^2 J^T J`` (Parseval), the Gauss-Newton covariance.

**Where the noise is measured.** Given the window's pressure, the noise spectrum is measured
at the note's harmonics and the residual's misfit there is a component of its own (the
model form): :mod:`mpipe.inversion.trust.harmonics`, ``Covariance.cov_model``; the degrees of
freedom are those of the harmonics' band. Without a period (or without the pressure) the
noise is the residual's whole smoothed periodogram and ``B`` is scaled by
``n_eff / (n_eff - p)``, ``n_eff = n / tau`` (``tau = 1 + 2 sum rho_k``, the integrated
autocorrelation time, summed by Geyer's initial positive sequence): the coloured analogue of
``n / (n - p)``, which a drift below the first harmonic inflates (mpipe <= 0.4 used it
always).

Why not ``s^2 (J^T J)^-1`` with ``s^2 = ||r||^2 / (n_eff - p)`` (mpipe <= 0.3): that
inflates the noise uniformly by ``tau``, which is right only when the noise spectrum is
flat over the Jacobian's band. On measured takes it made the SEs about twice too wide
(RMS z 0.5 over six 1 s takes at 45 dB); the sandwich gives RMS z 1.0-1.2 on the same
windows (``benchmarks/bench_uncertainty.py --coverage``). Whitening with an
autoregressive model was not chosen either: the residual has no power above the low-pass
cut-off, so a whitening filter has an enormous gain there and the whitened Jacobian is
dominated by round-off.

**Undetermined directions.** ``J`` is decomposed by SVD. A direction ``v`` in log-parameter
space with a singular value below ``rcond`` times the largest is a null direction: the data
do not constrain the parameters along it (for instance the exact scale invariance of a reed
whose contact starts at closure, see :func:`scale_direction`). The covariance is the
pseudo-inverse over the other directions; every parameter or combination with a component
along a null direction gets an infinite standard error.

**Degrees of freedom.** ``n_eff - p`` is kept (:attr:`Covariance.dof`): below 1 the
residual cannot measure the noise, the SEs are computed with one degree of freedom and the
window's status says so (``low-dof``, :mod:`mpipe.inversion.trust.status`). A Jacobian or
residual that is not finite, or an SVD that does not converge, raises: the window then has
no standard errors and its status is ``no-errors``.

**Standard errors in the parameters' own units** by the delta method:
``se_x = x se_z``. The relative standard error is ``se_z``; a parameter is *determined*
when it is below a limit (default 0.10); the columns of a window's row are made by
:mod:`mpipe.inversion.trust.window_errors`.

References
----------
C. J. Geyer, "Practical Markov chain Monte Carlo", Statistical Science 7(4):473-483, 1992
(initial positive sequence). G. A. F. Seber, C. J. Wild, *Nonlinear Regression*, Wiley
1989, sections 2.1 and 6.2 (Gauss-Newton covariance, correlated errors).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from mpipe.core.statistics import integrated_autocorrelation
from mpipe.inversion.trust.harmonics import (
    SPECTRUM_BINS,
    column_spectra,
    spectral_gram,
    split_residual,
)

#: Step of the forward-difference Jacobian in log parameters (0.01 % of each parameter):
#: the covariance's and the search's (:mod:`mpipe.inversion.fit.least_squares`).
DIFF_STEP = 1e-4
#: Singular values below this fraction of the largest mark a null direction. A forward
#: difference of step 1e-4 in log parameters leaves the Jacobian of an exactly invariant
#: direction at about 1e-4 of the largest singular value; an identifiable direction of
#: step 2 sits well above 1e-3 (measured on the Table 1 reed).
RCOND = 1e-3
#: Singular values below this fraction of the largest mark an *exact* invariance: a forward
#: difference of step 1e-4 leaves one near 1e-4 of the largest, exact sensitivities far
#: below. Between this and :data:`RCOND` a direction is weakly determined, not invisible: a
#: quantity with a component along it gets the sandwich's (large, finite) SE from that
#: direction's own singular value instead of inf. mpipe <= 0.5 gave inf for any component
#: above 1e-3 of the quantity's exponents, so p_M = k y_m of a reed that barely touches y_c
#: (a near scale invariance whose direction does not cancel in k y_m to 1e-3) was inf while
#: p_M was within 0.4 % (issue 38).
EXACT_NULL = 3e-4

#: Parameters that may carry a standard error, in the table's order.
SE_PARAMETERS = ("k", "S", "y_m", "p_m", "m", "g", "lam", "k_c", "y_c")


def log_jacobian(
    residuals: Callable[[np.ndarray], np.ndarray],
    x: np.ndarray,
    *,
    r0: np.ndarray | None = None,
    upper: np.ndarray | None = None,
    step: float = DIFF_STEP,
    mapper: Callable[[Callable, Iterable], Iterable] = map,
) -> np.ndarray:
    """Forward-difference Jacobian ``d residuals / d ln x`` at ``x``.

    Parameters
    ----------
    residuals : callable
        ``residuals(x) -> ndarray`` (Pa for F2).
    x : ndarray
        Point, positive, in the caller's units.
    r0 : ndarray, optional
        ``residuals(x)`` if already known (saves one model run).
    upper : ndarray, optional
        Upper bounds: a parameter within one step of its upper bound is differenced
        backwards, so no model run leaves the box.
    step : float
        Step in ln x.
    mapper : callable
        ``map``-like function used to evaluate the perturbed points (pass a pool's ``map``
        to run the columns in parallel).

    Returns
    -------
    ndarray
        Shape ``(n_residuals, n_parameters)``.
    """
    x = np.asarray(x, dtype=float)
    if r0 is None:
        r0 = np.asarray(residuals(x), dtype=float)
    steps = np.full(x.size, float(step))
    if upper is not None:
        steps[np.log(np.asarray(upper, dtype=float) / x) < step] = -step
    points = []
    for i, h in enumerate(steps):
        xi = x.copy()
        xi[i] = x[i] * math.exp(h)
        points.append(xi)
    columns = [np.asarray(c, dtype=float) for c in mapper(residuals, points)]
    return np.column_stack([(c - r0) / h for c, h in zip(columns, steps, strict=True)])


@dataclass(frozen=True)
class Covariance:
    """Sandwich covariance of log parameters with the residual's spectrum accounted for.

    Attributes
    ----------
    names : tuple of str
        Free parameters, in the order of the Jacobian's columns.
    cov : ndarray
        Covariance of ``ln x`` over the determined directions (pseudo-inverse of ``J^T J``
        in the sandwich), shape ``(p, p)``.
    null : ndarray
        Unit null directions in ln-x space, shape ``(n_null, p)``.
    singular_values : ndarray
        Singular values of ``J`` (Pa per unit ln x), largest first.
    sigma : float
        ``s = ||r|| / sqrt(n_eff - p)``, Pa: the residual's level per effective degree of
        freedom (reported; the covariance uses the residual's spectrum).
    n : int
        Samples in the residual.
    tau : float
        Integrated autocorrelation time of the residual, samples.
    n_eff : float
        ``n / tau``.
    dof : float
        Degrees of freedom of the noise estimate (below 1: the SEs are rough): with the
        harmonic split, the band's ``N_b - 2K - 1``; without it (no period), ``n_eff - p``.
    cov_model : ndarray or None
        Model-form covariance of ``ln x`` (the sandwich with the residual's excess spectrum
        at the harmonics and the floor, :mod:`mpipe.inversion.trust.harmonics`); None without a
        period (the component does not apply).
    noise_residual, model_residual : float
        Relative residual the noise alone leaves, and the misfit beyond it at the
        harmonics (NaN without a period).
    """

    names: tuple[str, ...]
    cov: np.ndarray
    null: np.ndarray
    singular_values: np.ndarray
    sigma: float
    n: int
    tau: float
    n_eff: float
    dof: float
    cov_model: np.ndarray | None = None
    noise_residual: float = math.nan
    model_residual: float = math.nan
    exact_null: np.ndarray | None = None
    cov_full: np.ndarray | None = None
    cov_model_full: np.ndarray | None = None

    def log_se(self, exponents: np.ndarray, tol: float = 1e-3) -> float:
        """Standard error of ``e . ln x`` (the noise component).

        Infinite when ``e`` has a component larger than ``tol`` times its norm along an
        exactly invariant direction (``exact_null``; all of ``null`` when it is not given).
        Along a weakly determined null direction (singular value between
        :data:`EXACT_NULL` and :data:`RCOND` times the largest) the SE is the sandwich's
        over every measurable direction (``cov_full``): large for a quantity that lies
        along it, barely changed for one that only grazes it.
        """
        e = np.asarray(exponents, dtype=float)
        norm = float(np.linalg.norm(e))
        if norm == 0:
            return 0.0
        exact = self.null if self.exact_null is None else self.exact_null
        if exact.size and np.max(np.abs(exact @ e)) > tol * norm:
            return math.inf
        cov = self.cov
        if self.null.size and np.max(np.abs(self.null @ e)) > tol * norm:
            if self.cov_full is None:
                return math.inf
            cov = self.cov_full
        return math.sqrt(max(float(e @ cov @ e), 0.0))

    def model_form(self) -> Covariance | None:
        """The model-form component as a covariance of its own (None when it does not apply)."""
        if self.cov_model is None:
            return None
        return dataclasses.replace(self, cov=self.cov_model, cov_full=self.cov_model_full,
                                   cov_model=None, cov_model_full=None)  # fmt: skip

    def correlation(self) -> np.ndarray:
        """Correlation matrix of ``ln x`` over the determined directions.

        NaN where a variance is zero.
        """
        d = np.sqrt(np.clip(np.diag(self.cov), 0.0, None))
        with np.errstate(divide="ignore", invalid="ignore"):
            c = self.cov / np.outer(d, d)
        return np.where(np.outer(d, d) > 0, c, np.nan)


def noise_weighted_gram(j: np.ndarray, r: np.ndarray, bins: int = SPECTRUM_BINS) -> np.ndarray:
    """``J^T Sigma J`` with ``Sigma`` the circulant covariance of the residual's spectrum.

    Parameters
    ----------
    j : ndarray
        Jacobian, shape ``(n, p)``.
    r : ndarray
        Residual, length n; its periodogram, averaged over ``bins`` neighbouring bins
        (mirrored at 0 and Nyquist), is the noise spectrum.
    bins : int
        Width of the average, bins.

    Returns
    -------
    ndarray
        Shape ``(p, p)``; ``s^2 J^T J`` for white noise of variance ``s^2``.
    """
    n = r.size
    jf = np.fft.rfft(j, axis=0)
    power = np.abs(np.fft.rfft(r)) ** 2 / n
    half = bins // 2
    padded = np.concatenate([power[1 : half + 1][::-1], power, power[-half - 1 : -1][::-1]])
    smooth = np.convolve(padded, np.ones(bins) / bins, mode="valid")[: power.size]
    weights = np.full(power.size, 2.0)
    weights[0] = 1.0
    if n % 2 == 0:
        weights[-1] = 1.0
    return np.real((jf.conj().T * (weights * smooth)) @ jf) / n


def covariance(
    jacobian: np.ndarray,
    residual: np.ndarray,
    names: Sequence[str],
    *,
    rcond: float = RCOND,
    pressure: np.ndarray | None = None,
    fs: float | None = None,
    floor: float = 0.0,
) -> Covariance:
    """Covariance of the log parameters from the Jacobian and residual at the solution.

    Parameters
    ----------
    jacobian : ndarray
        ``d residual / d ln x``, shape ``(n, p)``, Pa.
    residual : ndarray
        Residual at the solution, Pa.
    names : sequence of str
        Parameter names of the columns.
    rcond : float
        Relative singular-value threshold of a null direction.
    pressure : ndarray, optional
        Measured pressure over the window, Pa, and ``fs`` its sample rate, Hz: with both,
        the noise is measured at the harmonics and the model-form component is computed
        (:func:`mpipe.inversion.trust.harmonics.split_residual`); without them, or when the
        window has no period, the noise is the residual's whole spectrum inflated by
        ``n_eff / (n_eff - p)`` and there is no model-form component.
    floor : float
        Model-form floor, relative to the pressure's amplitude at each harmonic.

    Returns
    -------
    Covariance

    Raises
    ------
    numpy.linalg.LinAlgError
        When the Jacobian or the residual is not finite, or the SVD does not converge.
    """
    j = np.asarray(jacobian, dtype=float)
    r = np.asarray(residual, dtype=float)
    if not (np.all(np.isfinite(j)) and np.all(np.isfinite(r))):
        raise np.linalg.LinAlgError("the Jacobian or the residual is not finite")
    n, p = j.shape
    tau = integrated_autocorrelation(r)
    n_eff = n / tau
    dof = n_eff - p
    sigma = float(np.linalg.norm(r)) / math.sqrt(max(dof, 1.0))
    _, sv, vt = np.linalg.svd(j, full_matrices=False)
    top = sv[0] if sv.size and sv[0] > 0 else 1.0
    keep = sv > rcond * top
    measurable = sv > EXACT_NULL * top
    a_inv = (vt[keep].T / sv[keep] ** 2) @ vt[keep]
    a_full = (vt[measurable].T / sv[measurable] ** 2) @ vt[measurable]
    gram, excess, n_eff, dof, extra = residual_grams(j, r, pressure, fs, floor, n_eff, dof)
    if excess is not None:
        extra["cov_model"] = _sandwich(a_inv, excess)
        extra["cov_model_full"] = _sandwich(a_full, excess)
    cov = a_inv @ gram @ a_inv
    return Covariance(
        names=tuple(names),
        cov=0.5 * (cov + cov.T),
        null=vt[~keep],
        singular_values=sv,
        sigma=sigma,
        n=n,
        tau=tau,
        n_eff=n_eff,
        dof=dof,
        exact_null=vt[~measurable],
        cov_full=_sandwich(a_full, gram),
        **extra,
    )


def _sandwich(a_inv: np.ndarray, gram: np.ndarray) -> np.ndarray:
    out = a_inv @ gram @ a_inv
    return 0.5 * (out + out.T)


def residual_grams(
    j: np.ndarray,
    r: np.ndarray,
    pressure: np.ndarray | None,
    fs: float | None,
    floor: float,
    n_eff: float,
    dof: float,
) -> tuple[np.ndarray, np.ndarray | None, float, float, dict]:
    """A window's noise gram ``B = J^T Sigma J`` and model-form gram (see :func:`covariance`).

    Parameters are those of :func:`covariance`, with the residual's ``n_eff`` and ``n_eff -
    p`` (used without a harmonic split). Returns the noise gram (Pa^2 per unit ln x
    squared), the model-form gram (None without a period), the effective samples and degrees
    of freedom (the band's with the split), and the split's residual levels
    (``noise_residual``, ``model_residual``; empty without it).
    """
    split, jf = None, None
    if pressure is not None and fs is not None and np.size(pressure) == r.size:
        jf = column_spectra(j)  # one transform for the band's top and both grams
        split = split_residual(r, np.asarray(pressure, dtype=float), j, fs, floor=floor, jf=jf)
    if split is None:
        # Below one degree of freedom the noise is not measured: one is used so the result
        # stays finite (and large), and the status says the SEs are rough.
        return noise_weighted_gram(j, r) * (n_eff / max(dof, 1.0)), None, n_eff, dof, {}
    extra = dict(noise_residual=split.noise_residual, model_residual=split.model_residual)
    return (
        spectral_gram(j, split.noise, jf),
        spectral_gram(j, split.excess, jf),
        split.band_dof,
        split.noise_dof,
        extra,
    )


def scale_direction(names: Sequence[str], alpha: float = 2.0) -> np.ndarray:
    """The scale invariance of a reed whose contact point moves with the rest opening.

    The reed equation per unit area (physics.md) is
    ``m y'' + m g y' + k y + k_c [y - y_c]_+^alpha = dp``, the reed's flow ``S dy/dt`` and
    the flow through the opening ``lam (y_m - y) sqrt(2 dp / rho)``. Scaling every
    displacement by a (y, y_m, y_c) leaves dp, and so p and u, unchanged when m, k and S
    and lam scale by 1/a, g not at all, and the contact term ``k_c a^alpha [y - y_c]^alpha``
    stays the same: k_c scales by ``a^-alpha``. This holds when y_c moves with y_m (contact
    from closure) or is free. In ln space the direction over
    ``(k, S, y_m, p_m, m, g, lam, k_c, y_c)`` is ``(-1, -1, +1, 0, -1, 0, -1, -alpha, +1)``.

    Parameters
    ----------
    names : sequence of str
        Free parameter names.
    alpha : float
        Exponent of the contact force (``inversion.alpha``).

    Returns
    -------
    ndarray
        Unnormalised direction over ``names``.
    """
    weights = {"k": -1.0, "S": -1.0, "y_m": 1.0, "m": -1.0, "lam": -1.0, "k_c": -alpha,
               "y_c": 1.0}  # fmt: skip
    return np.array([weights.get(n, 0.0) for n in names])


__all__ = [
    "Covariance",
    "DIFF_STEP",
    "EXACT_NULL",
    "RCOND",
    "SE_PARAMETERS",
    "SPECTRUM_BINS",
    "covariance",
    "log_jacobian",
    "noise_weighted_gram",
    "residual_grams",
    "scale_direction",
]
