"""Constant or drifting: the model of theta over a take, chosen by the data (physics.md E.5).

Each trusted block gives a Gaussian measurement of theta (its estimate with the prior
removed, weighted by its data information). Three models of theta(t) are fitted to them,
each with the prior counted once: a constant, a straight line in time, and the local
linear smoother (:func:`mpipe.measurement.separation.tracking.smooth_blocks`). The simpler
constant is kept unless the line or the smoother lowers chi^2 by more than noise would at
the level ``drift_level`` (likelihood-ratio tests, the level shared between the two; the
smoother's degrees of freedom are the trace of its hat matrix), and the line is preferred
to the smoother unless the smoother beats it at that level. A steady take thus gets one
value with the pooled standard error, and a drift the data show is followed.

Adjacent blocks overlap by half, so their estimates correlate (``rho``, 3/70 for the Hann
window, :func:`overlap_correlation`): the covariances are sandwich estimates with that
correlation, and the test statistics are divided by ``1 + 2 rho``. The take-level fits
leave the temperature's prior out when the data know T four times better than it
(:func:`_level_prior`), so that a prior mean a few degC off does not pull the take's value.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy import stats

from mpipe.measurement.separation.propagation import BlockEstimate, Prior

#: The models, simplest first.
MODELS = ("constant", "linear", "smooth")


#: A prior this improbable given the microphones' data (two-sided) is contradicted by them:
#: the validation's false-alarm rate (``validation.false_alarm``'s default).
CONFLICT_P = 1e-3


@dataclass(frozen=True)
class PriorConflict:
    """The temperature prior against the microphones' own take-level temperature.

    The constant model is fitted to the blocks with every prior but the temperature's
    (``data_c`` +- ``data_se_c``, degC, the blocks' overlap in its sandwich); under the
    model that estimate and the prior's mean differ by a normal deviate of variance
    ``data_se_c^2 + prior_se_c^2``, so ``z`` is standard normal when both hold (Evans &
    Moshonov 2006, "Checking for prior-data conflict", Bayesian Analysis 1(4)). A
    significant ``z`` says the prior holds the separation at a temperature the
    microphones contradict: the waves are separated and translated at the wrong speed of
    sound, so every result after it is suspect. A temperature prior only matters when it
    is narrow (the default 5 degC never decides a take), so the check fires on a prior a
    user set narrow and wrong.
    """

    prior_c: float
    prior_se_c: float
    data_c: float
    data_se_c: float

    @property
    def z(self) -> float:
        """(data - prior) / sqrt(data_se^2 + prior_se^2)."""
        return (self.data_c - self.prior_c) / float(np.hypot(self.data_se_c, self.prior_se_c))

    def reasons(self) -> list[str]:
        """The check's reason when the conflict is significant at :data:`CONFLICT_P`."""
        limit = float(stats.norm.isf(CONFLICT_P / 2.0))
        if not abs(self.z) > limit:
            return []
        return [f"the separation's temperature prior, {self.prior_c:.2f} +- "
                f"{self.prior_se_c:.2g} degC, is contradicted by the microphones, which put the "
                f"air at {self.data_c:.2f} +- {self.data_se_c:.2g} degC (z = {self.z:.3g}, |z| > "
                f"{limit:.2f}): the waves were separated and translated at a temperature the "
                "data reject; widen separation.temperature_prior_c or correct the calibration's "
                "air temperature",]  # fmt: skip

    def summary(self) -> dict:
        """JSON-safe figures and, when significant, the reason (``front_end_checks``)."""
        return {"temperature_prior_c": [self.prior_c, self.prior_se_c],
                "temperature_data_c": self.data_c, "temperature_data_se_c": self.data_se_c,
                "temperature_prior_z": self.z, "front_end_checks": self.reasons()}  # fmt: skip


@dataclass(frozen=True)
class TrackChoice:
    """theta over the take as the data support it.

    Attributes
    ----------
    model : str
        ``'constant'``, ``'linear'`` or ``'smooth'`` (or ``'held'``: not estimated).
    values, se : ndarray
        Shape ``(n_blocks, 4)``: theta per block under the chosen model (degC, -, -, m)
        and its standard errors (0 for held parameters).
    level, level_se : ndarray
        Shape ``(4,)``: the take-level value, theta averaged over the trusted blocks
        (the constant, or the line at their mean time), and its standard error.
    change, change_se : ndarray
        Shape ``(4,)``: the change of theta from the first to the last trusted block by
        the straight line, and its standard error.
    p_drift : float
        p-value of the constant model against the line or the smoother, whichever is
        smaller, doubled (Bonferroni; small: the data show a change).
    p_curve : float
        p-value of the line against the smoother (small: the change is not linear).
    span_s : float
        Time between the first and the last trusted block, s.
    drift_level : float
        The test level the choice was made at (``separation.drift_level``; NaN: unknown).
    level_cov : ndarray or None
        Shape ``(4, 4)``: the covariance of ``level`` (its diagonal ``level_se**2``, zero
        rows for held parameters; None: not known). The parameters' errors correlate: the
        temperature and the losses both set the waves' propagation between microphones, and
        on the 45 dB crescendos of ``benchmarks/bench_estimator.py`` their take-level errors
        correlate by +0.6.
    """

    model: str
    values: np.ndarray
    se: np.ndarray
    level: np.ndarray
    level_se: np.ndarray
    change: np.ndarray
    change_se: np.ndarray
    p_drift: float
    p_curve: float
    span_s: float
    drift_level: float = float("nan")
    level_cov: np.ndarray | None = None
    prior_conflict: PriorConflict | None = None

    def sentence(self, deg: str = "degC", pm: str = "+-") -> str:
        """Whether the data show a drift of the temperature, in words (``deg``: its unit)."""
        t, se = self.level[0], self.level_se[0]
        dt, dse = self.change[0], self.change_se[0]
        if self.model == "held":
            return f"Effective temperature held at {t:.2f} {deg} (not estimated)."
        head = f"Effective temperature {t:.2f} {pm} {se:.2f} {deg} over the take"
        if self.model == "constant":
            return f"{head}, one value; {self._no_drift_words(deg, pm)}"
        shape = "linear" if self.model == "linear" else "not linear (smoothed track)"
        return (
            f"{head}; the data show a drift of {dt:+.2f} {pm} {dse:.2f} {deg} over "
            f"{self.span_s:.1f} s (joint test of temperature, losses and Mach p = "
            f"{self.p_drift:.2g}), {shape}."
        )

    def _no_drift_words(self, deg: str, pm: str) -> str:
        """Why one value: the joint test's result first, then the line's change and its weight.

        The change of the straight line is given with how many standard errors it is from
        none and its p-value alone, so that a change of 2 SE is not read as a drift the
        sentence then denies: both numbers are judged at the same level.
        """
        dt, dse = self.change[0], self.change_se[0]
        level = self.drift_level
        where = f"separation.drift_level = {level:g}" if np.isfinite(level) else "the level"
        words = (
            f"no drift at the test level (joint test of temperature, losses and Mach over "
            f"{self.span_s:.1f} s: p = {self.p_drift:.2g}, a drift needs p below {where})."
        )
        if not (np.isfinite(dse) and dse > 0):
            return words
        z = abs(dt) / dse
        p_alone = float(2.0 * stats.norm.sf(z))
        words += (
            f" A straight line through the blocks changes by {dt:+.2f} {pm} {dse:.2f} {deg}, "
            f"{z:.1f} standard errors from none (p = {p_alone:.2g} for the temperature alone"
        )
        if np.isfinite(level) and p_alone < level:
            return words + (
                ", below the level: the temperature alone suggests a change of that size, "
                "which the joint test does not confirm; read the take's value with it in mind)."
            )
        return words + ", not below the level either)."

    def summary(self) -> dict:
        """JSON-safe take-level figures (degC): model, value, SE, drift, its SE, in words.

        With a temperature prior, also the microphones' own take-level temperature, the
        prior-data conflict and, when it is significant, ``front_end_checks``: the reason
        the take should not pass (:class:`PriorConflict`).
        """
        conflict = {} if self.prior_conflict is None else self.prior_conflict.summary()
        return conflict | {
            "track_model": self.model,
            "temperature_c_take": float(self.level[0]),
            "temperature_se_c_take": float(self.level_se[0]),
            "temperature_drift_c": float(self.change[0]),
            "temperature_drift_se_c": float(self.change_se[0]),
            "drift_p_value": float(self.p_drift),
            "drift_sentence": self.sentence("°C", "±"),
        }


def overlap_correlation(length: int, hop: int) -> float:
    """Correlation of the estimates of two blocks ``hop`` samples apart (white noise).

    A block's estimate error is, to first order, ``sum_t w(t)^2 s(t) e(t)`` for its
    window ``w``, a steady sensitivity signal ``s`` and white noise ``e``, so two blocks
    correlate by ``sum w_1^2 w_2^2 / sum w^4`` (3/70 for Hann windows overlapping by half).
    """
    w = np.hanning(length + 1)[:-1]
    if hop >= length:
        return 0.0
    return float(np.sum(w[hop:] ** 2 * w[: length - hop] ** 2) / np.sum(w**4))


def _measurements(estimates: list[BlockEstimate | None], prior: Prior):
    """Per trusted block: index, data information and information vector (prior removed)."""
    idx = np.flatnonzero(prior.free)
    info_p = prior.information
    mu0 = prior.mean[idx]
    out = []
    for j, e in enumerate(estimates):
        if e is None:
            continue
        post = np.linalg.pinv(e.cov)
        out.append((j, e.data_information, post @ e.values[idx] - info_p @ mu0))
    return out


def _line_fit(times, meas, prior: Prior, degree: int, t_ref: float, rho: float):
    """Constant (degree 0) or line (1) by weighted least squares: coefficients, cov, chi^2."""
    idx = np.flatnonzero(prior.free)
    p = idx.size
    info_p = prior.information
    mu0 = prior.mean[idx]
    q = (degree + 1) * p
    m = np.zeros((q, q))
    rhs = np.zeros(q)
    meat = np.zeros((q, q))
    xs = {}
    for j, i_j, h_j in meas:
        tau = times[j] - t_ref
        x = np.hstack([np.eye(p)] + ([tau * np.eye(p)] if degree else []))
        xs[j] = (x, i_j)
        m += x.T @ i_j @ x
        rhs += x.T @ h_j
    meat[:] = m
    for j, (x, i_j) in xs.items():
        if j + 1 in xs:
            x2, i_2 = xs[j + 1]
            cross = rho * x.T @ (0.5 * (i_j + i_2)) @ x2
            meat += cross + cross.T
    m[:p, :p] += info_p
    rhs[:p] += info_p @ mu0
    meat[:p, :p] += info_p
    minv = np.linalg.pinv(m)
    beta = minv @ rhs
    cov = minv @ meat @ minv
    chi2 = 0.0
    for j, i_j, h_j in meas:
        y = np.linalg.pinv(i_j) @ h_j
        r = y - xs[j][0] @ beta
        chi2 += float(r @ i_j @ r)
    return beta, cov, chi2


# The take-level fits leave the temperature's prior out when the take's data alone know
# the temperature this many times better (in information) than the prior does.
_PRIOR_DROP = 4.0


def _level_prior(meas, prior: Prior) -> Prior:
    """The prior of the take-level fits: without the temperature's when the data suffice.

    The temperature's prior mean is a guess (the configured or calibration temperature,
    often a few degC from the air in the bore); counted once in the pooled fit it pulls
    the take's value towards it by ``SE^2 / width^2`` of the offset (0.2 SE for a 1 s take
    at 45 dB 3 degC off). When the data hold at least ``_PRIOR_DROP`` times the prior's
    information on T (with the other parameters' priors), the take-level value is the data's
    alone; the blocks' own fits keep the prior (it keeps the nonlinear fits in range).
    """
    idx = np.flatnonzero(prior.free)
    if not (prior.free[0] and np.isfinite(prior.width[0])):
        return prior
    total = sum(i_j for _, i_j, _ in meas) + prior.information
    total[0, 0] -= 1.0 / prior.width[0] ** 2
    var_t = float(np.linalg.pinv(total)[0, 0]) if idx[0] == 0 else np.inf
    if var_t > 0 and 1.0 / var_t >= _PRIOR_DROP / prior.width[0] ** 2:
        width = prior.width.copy()
        width[0] = np.inf
        return replace(prior, width=width)
    return prior


def choose_track(
    times: np.ndarray,
    estimates: list[BlockEstimate | None],
    prior: Prior,
    smooth: tuple[np.ndarray, np.ndarray, float],
    rho: float,
    level: float,
) -> TrackChoice:
    """Fit the constant, the line and the smoother, and keep the simplest the data allow.

    Parameters
    ----------
    times : ndarray
        Block centres, s.
    estimates : list
        Per block its :class:`BlockEstimate`, or None (not fitted or not trusted).
    prior : Prior
        Prior on (T, eta, M, dx), counted once in each model.
    smooth : tuple
        The smoother's values and standard errors (each shape ``(n_blocks, 4)``) and its
        degrees of freedom (:func:`smooth_blocks` with ``dof=True``).
    rho : float
        Correlation of adjacent blocks' estimates (:func:`overlap_correlation`).
    level : float
        Test level: a more complex model is taken when its p-value is below it.

    Returns
    -------
    TrackChoice
    """
    s_values, s_se, s_dof = smooth
    idx = np.flatnonzero(prior.free)
    p = idx.size
    meas = _measurements(estimates, prior)
    zeros = np.zeros(prior.mean.size)
    if p == 0 or not meas:
        lev = s_values[0] if len(s_values) else prior.mean
        return TrackChoice("held", s_values, s_se, lev, zeros, zeros, zeros, 1.0, 1.0, 0.0)
    level_prior = _level_prior(meas, prior)
    t_used = np.array([times[j] for j, _, _ in meas])
    t_ref = float(np.mean(t_used))
    span = float(t_used.max() - t_used.min())
    b0, c0, chi0 = _line_fit(times, meas, level_prior, 0, t_ref, rho)
    b1, c1, chi1 = _line_fit(times, meas, level_prior, 1, t_ref, rho)
    chi_s = 0.0
    for j, i_j, h_j in meas:
        r = np.linalg.pinv(i_j) @ h_j - s_values[j, idx]
        chi_s += float(r @ i_j @ r)
    inflate = 1.0 + 2.0 * rho

    def p_value(chi_simple: float, chi_complex: float, dof: float) -> float:
        if dof < 0.5 or len(meas) < 2:
            return 1.0
        return float(stats.chi2.sf(max(chi_simple - chi_complex, 0.0) / inflate, dof))

    # Any change against the constant: a line, or a smooth curve (a rise and fall has no
    # linear trend); the two tests share the level (Bonferroni).
    p_line = p_value(chi0, chi1, p)
    p_any = p_value(chi0, chi_s, s_dof - p)
    p_drift = min(1.0, 2.0 * min(p_line, p_any))
    p_curve = p_value(chi1, chi_s, s_dof - 2 * p)
    values, se = s_values.copy(), s_se.copy()
    if p_drift >= level:
        model = "constant"
        values[:, idx] = b0
        se[:, idx] = np.sqrt(np.maximum(np.diag(c0), 0.0))
    elif p_curve >= level:
        model = "linear"
        for b, t in enumerate(times):
            x = np.hstack([np.eye(p), (t - t_ref) * np.eye(p)])
            values[b, idx] = x @ b1
            se[b, idx] = np.sqrt(np.maximum(np.diag(x @ c1 @ x.T), 0.0))
    else:
        model = "smooth"
    values = np.clip(values, prior.lower, prior.upper)
    lev, lev_se, change, change_se = (zeros.copy() for _ in range(4))
    lev[:] = values[0]
    use_b, use_c = (b0, c0) if model == "constant" else (b1, c1)
    lev[idx] = use_b[:p]
    lev_se[idx] = np.sqrt(np.maximum(np.diag(use_c)[:p], 0.0))
    lev_cov = np.zeros((zeros.size, zeros.size))
    lev_cov[np.ix_(idx, idx)] = 0.5 * (use_c[:p, :p] + use_c[:p, :p].T)
    change[idx] = b1[p:] * span
    change_se[idx] = np.sqrt(np.maximum(np.diag(c1)[p:], 0.0)) * span
    return TrackChoice(
        model,
        values,
        se,
        lev,
        lev_se,
        change,
        change_se,
        p_drift,
        p_curve,
        span,
        level,
        lev_cov,
        _conflict(times, meas, prior, t_ref, rho),
    )


def _conflict(times, meas, prior: Prior, t_ref: float, rho: float) -> PriorConflict | None:
    """The temperature prior against the blocks' constant fit without it (None: no prior)."""
    idx = np.flatnonzero(prior.free)
    if not (idx.size and idx[0] == 0 and np.isfinite(prior.width[0]) and prior.width[0] > 0):
        return None
    width = prior.width.copy()
    width[0] = np.inf
    beta, cov, _ = _line_fit(times, meas, replace(prior, width=width), 0, t_ref, rho)
    var = float(cov[0, 0])
    if not (np.isfinite(var) and var > 0):
        return None
    return PriorConflict(float(prior.mean[0]), float(prior.width[0]), float(beta[0]),
                         float(np.sqrt(var)))  # fmt: skip
