"""Estimate of the propagation parameters of one block (physics.md E.5).

theta = (T in degC, eta, M, and the position correction dx of the middle microphone in m)
maximises the posterior of one block: the concentrated likelihood of
:mod:`mpipe.measurement.separation.residual` and the Gaussian :class:`Prior` about the
configured values, by bounded Gauss-Newton (:func:`estimate_block`). ``kappa`` inflates the
variances for the correlation of adjacent bins (a sandwich estimate), so that the standard
errors of :class:`BlockEstimate` are honest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import optimize

from mpipe.measurement.separation.blocks import BlockSpectra, window_correlation
from mpipe.measurement.separation.residual import null_weights
from mpipe.measurement.separation.settings import SeparationConfig
from mpipe.measurement.separation.waves import Geometry, Theta, zk_excess


def fixed_mach(config: SeparationConfig, geometry: Geometry, c: float) -> float | None:
    """The Mach number the settings hold fixed, or None when it is estimated.

    ``mach`` when set, else ``mean_flow_m3_s`` (m^3/s) over the bore's cross-section at the
    sound speed ``c`` (m/s).
    """
    if config.mach is not None:
        return config.mach
    if config.mean_flow_m3_s is not None:
        return config.mean_flow_m3_s / (np.pi * geometry.radius**2 * c)
    return None


@dataclass(frozen=True)
class Prior:
    """Gaussian prior on (T, eta, M) and which of them are free.

    Attributes
    ----------
    mean : ndarray
        Prior means: temperature (degC), eta, Mach number, position correction of the
        middle microphone (m).
    width : ndarray
        Standard deviations (inf: no prior).
    lower, upper : ndarray
        Bounds.
    free : ndarray
        Boolean, which parameters are estimated.
    """

    mean: np.ndarray
    width: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    free: np.ndarray

    @property
    def information(self) -> np.ndarray:
        """Prior information matrix of the free parameters."""
        w = self.width[self.free]
        return np.diag(np.where(np.isfinite(w), 1.0 / w**2, 0.0))

    @classmethod
    def from_config(
        cls, config: SeparationConfig, t0: float, free_mach: bool, n_mics: int = 3
    ) -> Prior:
        """Build the prior of a configuration around the start temperature ``t0`` degC.

        The position correction of the middle microphone is free only with ``n_mics`` = 3
        (and a ``mic_position_prior_m``); with more microphones the positions are held.
        """

        def wid(v: float | None) -> float:
            return np.inf if v is None else float(v)

        bounds = (
            config.temperature_bounds_c,
            config.loss_bounds,
            config.mach_bounds,
            config.mic_position_bounds_m,
        )
        return cls(
            mean=np.array([t0, config.loss_scale, 0.0, 0.0]),
            width=np.array(
                [
                    wid(config.temperature_prior_c),
                    wid(config.loss_prior),
                    wid(config.mach_prior),
                    wid(config.mic_position_prior_m),
                ]
            ),
            lower=np.array([b[0] for b in bounds]),
            upper=np.array([b[1] for b in bounds]),
            free=np.array(
                [
                    True,
                    config.estimate_loss,
                    free_mach,
                    config.mic_position_prior_m is not None and n_mics == 3,
                ]
            ),
        )


@dataclass(frozen=True)
class BlockEstimate:
    """The estimate of one block.

    Attributes
    ----------
    values : ndarray
        Temperature (degC), eta, Mach number, position correction of the middle microphone
        (m); fixed ones at their held values.
    cov : ndarray
        Posterior covariance of the free parameters (data and prior).
    data_information : ndarray
        Information matrix of the data alone (without the prior), free parameters.
    residual : float
        chi^2 per degree of freedom at the estimate: the sum of the squared unit-variance
        residuals over the terms less those the fitted parameters take (about 1 when the
        sensor noise explains the misfit).
    kappa : float
        Variance inflation from correlated residual terms.
    at_bound : tuple of str
        Names of the parameters on a bound.
    evaluations : int
        Residual evaluations.
    """

    values: np.ndarray
    cov: np.ndarray
    data_information: np.ndarray
    residual: float
    kappa: float
    at_bound: tuple[str, ...]
    evaluations: int


PROPAGATION_NAMES = ("temperature", "eta", "mach", "position")


# Solver scales: 1 degC, 0.1 of eta, 1e-3 of Mach, 0.1 mm.
_SCALES = np.array([1.0, 0.1, 1e-3, 1e-4])


def fixed_mach_at(config: SeparationConfig, geometry: Geometry, t: float) -> float | None:
    """:func:`fixed_mach` at the sound speed of temperature ``t`` (degC)."""
    return fixed_mach(config, geometry, geometry.sound_speed(t))


def estimate_block(
    spectra: BlockSpectra,
    use: np.ndarray,
    noise: np.ndarray,
    geometry: Geometry,
    start: np.ndarray,
    prior: Prior,
    config: SeparationConfig,
    corr: dict | None = None,
    kappa_start: float = 1.0,
) -> BlockEstimate:
    """Maximum a posteriori (T, eta, M) of one block (bounded Gauss-Newton, trust region).

    Parameters
    ----------
    spectra : BlockSpectra
        Segment spectra of the block.
    use : ndarray
        Bins entering the estimate (bool over ``spectra.freqs``).
    noise : ndarray
        Noise levels of the N >= 3 channels (:func:`noise_levels`), floored.
    geometry : Geometry
        Microphone offsets and bore.
    start : ndarray
        Start values (degC, -, -).
    prior : Prior
        Prior means, widths, bounds and the free parameters.
    config : SeparationConfig
        ``max_evaluations``, the held Mach number.
    corr : dict, optional
        :func:`window_correlation` of the block (computed when omitted).
    kappa_start : float
        First guess of ``kappa`` (the previous block's: it depends mostly on the window,
        so the fit is rarely repeated).

    Returns
    -------
    BlockEstimate

    Notes
    -----
    The real residual vector is ``[sqrt(2 / kappa) Re r, sqrt(2 / kappa) Im r,
    (theta - mean) / width]``, so that half its squared norm is the negative log posterior
    and the inverse Gauss-Newton matrix its covariance. ``kappa`` is found from the
    sandwich ``(2 Re G^H C G)`` against ``(2 Re G^H G)`` at the estimate, ``C`` the
    correlation of the residual terms (:func:`window_correlation`), and the fit is
    repeated once with it. The visco-thermal excess is evaluated at the start
    temperature and again when the estimate moved by more than 0.25 degC: it changes by
    about 0.4 % per degC, which the free ``eta`` would otherwise absorb.
    """
    omega = 2 * np.pi * spectra.model_freqs
    free = prior.free
    idx = np.flatnonzero(free)
    scales = _SCALES[idx]
    lo = prior.lower[idx] / scales
    hi = prior.upper[idx] / scales
    info_prior = prior.information
    has_prior = np.isfinite(prior.width[idx])
    if corr is None:
        corr = window_correlation(spectra)

    def values(z: np.ndarray) -> np.ndarray:
        v = np.array(start, dtype=float)
        v[idx] = z * scales
        held = fixed_mach_at(config, geometry, v[0])
        if not free[2]:
            v[2] = held if held is not None else start[2]
        return v

    def theta_of(v: np.ndarray) -> Theta:
        return Theta(geometry.sound_speed(float(v[0])), float(v[1]), float(v[2]))

    def geometry_of(v: np.ndarray) -> Geometry:
        return geometry.corrected(float(v[3]))

    current = values(np.clip(np.asarray(start)[idx] / scales, lo, hi))
    kappa = float(kappa_start)
    evals = 0
    res = None
    # N - 2 residual components per used bin
    m = int(np.sum(use)) * max(geometry.offsets.size - 2, 1)
    excess = zk_excess(omega, geometry, geometry.sound_speed(current[0]))[0]
    for _ in range(4):
        z0 = np.clip(current[idx] / scales, lo + 1e-9, hi - 1e-9)
        kappa_fit = kappa

        def fun(z, excess=excess, kappa=kappa_fit):
            v = values(z)
            g = geometry_of(v)
            w = null_weights(theta_of(v), spectra.model_freqs, g, excess, noise)
            r = np.sqrt(2.0 / kappa) * spectra.residual(w, use)
            pr = ((v[idx] - prior.mean[idx]) / prior.width[idx])[has_prior]
            return np.concatenate([r.real, r.imag, pr])

        res = _least_squares(fun, z0, lo, hi, config.max_evaluations)
        evals += int(res.nfev) * (1 + z0.size)
        new = values(res.x)
        moved = abs(new[0] - current[0])
        current = new
        # kappa from the sandwich at this estimate (Jacobian per natural unit)
        jac = np.asarray(res.jac)[: 2 * m] / scales[None, :]
        g = (jac[:m] + 1j * jac[m:]) * np.sqrt(kappa_fit / 2.0)
        kappa = _kappa(g, use, corr, prior, idx)
        if moved >= 0.25:
            excess = zk_excess(omega, geometry, geometry.sound_speed(current[0]))[0]
        elif abs(kappa - kappa_fit) <= 0.1 * kappa_fit:
            break
    jac = np.asarray(res.jac)[: 2 * m] / scales[None, :]
    # data information with the final kappa (the Jacobian carries 1 / kappa_fit)
    info_data = (jac.T @ jac) * (kappa_fit / kappa)
    cov = np.linalg.pinv(info_data + info_prior)
    # chi^2 per degree of freedom: the fitted parameters take kappa tr(I_data cov) terms'
    # worth of the residual (the sandwich trace; a parameter held by its prior takes none)
    lost = kappa * float(np.trace(info_data @ cov))
    dof = max(m - lost, 0.5 * m, 1.0)
    chi2 = float(np.sum(res.fun[: 2 * m] ** 2) / 2.0 * kappa_fit / dof)
    return BlockEstimate(current, cov, info_data, chi2, kappa, _on_bounds(current, prior), evals)


def _least_squares(
    fun, z0: np.ndarray, lo: np.ndarray, hi: np.ndarray, max_evaluations: int
) -> optimize.OptimizeResult:
    """Bounded trust-region least squares of ``fun`` from ``z0`` (scaled parameters)."""
    return optimize.least_squares(
        fun,
        z0,
        bounds=(lo, hi),
        method="trf",
        x_scale=1.0,
        diff_step=1e-7,
        # half the cost is the negative log-likelihood: a change of 1e-8 of it, or a
        # step of 1e-6 of a scale unit, is far below one standard error
        xtol=1e-6,
        ftol=1e-8,
        gtol=1e-8,
        max_nfev=max_evaluations,
    )


def _on_bounds(values: np.ndarray, prior: Prior) -> tuple[str, ...]:
    """Names of the free parameters within 1e-6 of their range from a bound."""
    return tuple(
        PROPAGATION_NAMES[i]
        for i in np.flatnonzero(prior.free)
        if min(values[i] - prior.lower[i], prior.upper[i] - values[i])
        <= 1e-6 * max(prior.upper[i] - prior.lower[i], 1e-12)
    )


def _kappa(g: np.ndarray, use: np.ndarray, corr: dict, prior: Prior, idx: np.ndarray) -> float:
    """Variance inflation of correlated residual terms (sandwich over naive), >= 1.

    ``g[f, p]`` is the derivative of the unit-variance residual at the used bins (the
    K components one after the other, as :meth:`BlockSpectra.residual`; the components
    are uncorrelated, the bins of one component correlated by the window).
    """
    p = g.shape[1]
    m = int(np.sum(use))
    naive = np.zeros((p, p))
    sand = np.zeros((p, p))
    n_f = use.size
    for comp in range(g.shape[0] // max(m, 1)):
        full = np.zeros((use.size, p), dtype=complex)
        full[use] = g[comp * m : (comp + 1) * m]
        naive += 2 * np.real(np.conj(full).T @ full)
        for df, c in corr.items():
            f0, f1 = max(0, -df), min(n_f, n_f - df)
            if f1 <= f0:
                continue
            # E[r_i conj(r_j)] = c for j = i + df: G^H C G sums conj(G_i) C_ij G_j
            sand += 2 * np.real(c * (np.conj(full[f0:f1]).T @ full[f0 + df : f1 + df]))
    # Summarise the matrix ratio by a trace weighted with the prior variances (unit-free).
    w = np.where(np.isfinite(prior.width[idx]), prior.width[idx] ** 2, _SCALES[idx] ** 2)
    num = float(np.sum(np.diag(sand) * w))
    den = float(np.sum(np.diag(naive) * w))
    if not den > 0:
        return 1.0
    return float(max(num / den, 1.0))
