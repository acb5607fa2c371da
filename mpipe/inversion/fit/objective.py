"""The step-2 objective F2 = ||p - p_model||_2 over one window (paper eq. 15).

Every model run starts at the window's first sample from the target's own past: the
forward wave ``p+ = (p + Z0 u) / 2`` over the reflection function's length, and a reed
state made by driving the reed equation with the target's pressure difference over a short
lead-in, started from the quasi-static estimate ``y = dp/k``. The model then runs over the
window only and is compared sample by sample: no synchronisation is needed. (The paper
runs the model from rest into steady state and synchronises it with the target by a lag
search over one period, physics.md J. That start was a setting until issue 23 and left the
package with issue 45: it cost a 250 ms run per evaluation instead of 20 ms on the shipped
instrument, and its F2 jumps wherever the chosen lag changes, while the history start's F2
is smooth near the optimum and vanishes with exact parameters to the lead-in transient,
~e^{-g t/2}.)

For a zero-mean (measured) target the model output passes through the measurement's
7.25 kHz FIR before the comparison. The pressure gets no high-pass: the separation keeps
its DC, and a zero-phase high-pass on a short model record distorts the window's ends.
With a history start the mean flow missing from the measured history is estimated from
the candidate's flow over the lead-in.

References
----------
Chatziioannou & van Walstijn 2012, eq. (15), sections 3.2 and 4.2; physics.md I, J.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass

import numpy as np

from mpipe.core.filters import LowPass, apply_lowpass
from mpipe.inversion.fit.history_start import missing_mean_flow, pad_history
from mpipe.inversion.preparation.conditioning import relative_residual
from mpipe.reed.bore_kernel import BoreKernel
from mpipe.reed.model import ModelState, simulate
from mpipe.reed.opening import reed_trajectory
from mpipe.reed.parameters import ReedParameters, check_stability


@dataclass(frozen=True)
class TargetWindow:
    """Target signals of one window and what precedes it.

    Attributes
    ----------
    p : ndarray
        Mouthpiece pressure over the window, Pa.
    u : ndarray
        Mouthpiece volume flow over the window, m^3/s.
    p_history : ndarray
        Pressure before the window (oldest first, ending at the sample before it), Pa.
    u_history : ndarray
        Flow before the window, m^3/s.
    fs : float
        Sample rate, Hz.
    zero_mean : bool
        The flow is zero-mean (a measurement); the model output is filtered to match.
    p_m_slope : float
        The mouth pressure's rate of change about the window, Pa/s: the lead-in and the
        window are played at ``p_m + p_m_slope (t - t_c)``, ``t_c`` the window's centre,
        so that ``p_m`` stays the window's mean (:func:`mouth_pressure_ramp`). 0 (the
        paper's window, p_m held) unless the take's fit sets it from the neighbouring
        windows (:mod:`mpipe.inversion.whole_take.mouth_slopes`).
    """

    p: np.ndarray
    u: np.ndarray
    p_history: np.ndarray
    u_history: np.ndarray
    fs: float
    zero_mean: bool
    p_m_slope: float = 0.0


def mouth_pressure_ramp(slope: float, n: int, n_lead: int, fs: float):
    """The mouth pressure's departure from p_m over a lead-in and a window's run, Pa.

    ``(lead, run)``: at the lead-in's ``n_lead`` samples before the window and at its
    samples ``0..n-1`` (and on, for a run longer than the window), ``slope (t - t_c)`` with
    ``t_c`` the window's centre, ``n / 2`` samples in; ``slope`` in Pa/s. The compiled
    evaluator plays the same (:func:`mpipe.inversion.fit.fastpath.start_run`).
    """
    half = 0.5 * n
    lead = slope * (np.arange(-n_lead, 0) - half) / fs
    return lead, lambda m: slope * (np.arange(m) - half) / fs


@dataclass(frozen=True)
class ObjectiveSettings:
    """How F2 is computed.

    Attributes
    ----------
    lead_s : float
        Reed lead-in driven by the target pressure before the window, s.
    lowpass : LowPass or None
        The measurement's FIR, applied to model output of zero-mean targets.
    """

    lead_s: float = 0.01
    lowpass: LowPass | None = None


@dataclass(frozen=True)
class ModelWindow:
    """Model output over a window, conditioned and aligned with the target.

    Attributes
    ----------
    p, u : ndarray
        Model pressure (Pa) and flow (m^3/s) over the window, filtered like the target.
    f2 : float
        ||p_target - p|| in Pa (the penalty when infeasible).
    relative_residual : float
        ||p_target - p|| / ||p_target||.
    feasible : bool
        The candidate gave a stable, oscillating run.
    reason : str
        Why it is infeasible ("" otherwise).
    """

    p: np.ndarray
    u: np.ndarray
    f2: float
    relative_residual: float
    feasible: bool
    reason: str


def _measured_pressure(p: np.ndarray, lp, ctx: int, n: int) -> np.ndarray:
    """Model pressure as the measurement chain delivers it: the FIR low-pass only.

    The separation keeps the pressure's DC (the three-microphone system is singular only
    for the flow), so no high-pass is applied to p. A zero-phase IIR high-pass on a short
    record would distort the window's ends by several per cent and bias F2.
    """
    return apply_lowpass(p, lp)[ctx : ctx + n]


def _measured_flow(u: np.ndarray, lp, ctx: int, n: int, target: TargetWindow) -> np.ndarray:
    """Model flow as measured: low-passed, with the window mean of the measured flow.

    The measured flow has no DC over the take; over a 20 ms window its mean is what the
    take's high-pass left. The model's mean flow is replaced by that mean (u does not enter
    F2; this only puts the two flows on one footing in plots and residuals).
    """
    y = apply_lowpass(u, lp)[ctx : ctx + n]
    return y - y.mean() + float(np.mean(target.u))


def run_model(
    reed: ReedParameters,
    kernel: BoreKernel,
    target: TargetWindow,
    settings: ObjectiveSettings,
    penalty: float,
) -> ModelWindow:
    """Run the model for one candidate and condition its output like the target.

    Never raises for a bad candidate: an unstable, diverging or silent run gives
    ``feasible=False`` and ``f2=penalty``.

    Parameters
    ----------
    reed : ReedParameters
        Candidate.
    kernel : BoreKernel
        Prepared bore (its sample rate must equal ``target.fs``).
    target : TargetWindow
        Target window and history.
    settings : ObjectiveSettings
        Start method and filters.
    penalty : float
        Value of F2 for an infeasible candidate, Pa.

    Returns
    -------
    ModelWindow

    References
    ----------
    Chatziioannou & van Walstijn 2012, eq. (15); physics.md J.
    """
    n = target.p.size
    fs = target.fs
    empty = np.full(n, np.nan)

    def infeasible(reason: str) -> ModelWindow:
        return ModelWindow(empty, empty, penalty, math.inf, False, reason)

    try:
        check_stability(reed, fs)
    except ValueError as exc:
        return infeasible(f"unstable: {exc}")
    try:
        with np.errstate(all="ignore"):
            p_mod, u_mod = _run_from_history(reed, kernel, target, settings)
    except _Infeasible as exc:
        return infeasible(str(exc))
    if np.std(p_mod) < 0.01 * np.std(target.p):
        return infeasible("silent")
    f2 = float(np.linalg.norm(target.p - p_mod))
    if not math.isfinite(f2):
        return infeasible("diverged")
    return ModelWindow(p_mod, u_mod, f2, relative_residual(target.p, p_mod), True, "")


class _Infeasible(Exception):
    """The model cannot run the candidate, or its output is unusable (the reason)."""


def _simulate(reed: ReedParameters, kernel: BoreKernel, n: int, state=None, mouth=None):
    """Model pressure and flow over ``n`` samples; raises :class:`_Infeasible` on failure.

    ``mouth``: the mouth pressure per sample, Pa (None: ``reed.p_m`` held).
    """
    try:
        sim = simulate(reed, kernel, n, state=state, mouth_pressure=mouth)
    except ValueError as exc:
        raise _Infeasible(f"model: {exc}") from exc
    if not np.all(np.isfinite(sim.p)):
        raise _Infeasible("diverged")
    return sim.p, sim.u


def _run_from_history(
    reed: ReedParameters, kernel: BoreKernel, target: TargetWindow, settings: ObjectiveSettings
) -> tuple[np.ndarray, np.ndarray]:
    """The model started from the target's history, over the window (conditioned).

    A zero-mean target's flow lacks its mean c (estimated from the candidate over the
    lead-in), and its pressure the mean flow's drop over the bore between the mouthpiece
    and where the pressure's mean was measured, ``R c`` (``kernel.reference_resistance``):
    both are added to the history, and the model pressure is returned as the measurement
    gives it (low-passed, less ``R c``).
    """
    n, fs = target.p.size, target.fs
    filt = target.zero_mean
    lp = settings.lowpass if filt else None
    n_taps = kernel.h.size
    n_lead = max(int(round(settings.lead_s * fs)), 2)
    p_hist = pad_history(target.p_history, max(n_taps, n_lead))
    u_hist = pad_history(target.u_history, max(n_taps, n_lead))
    ramp_lead, ramp = mouth_pressure_ramp(target.p_m_slope, n, n_lead, fs)
    # the reed reads only p_m(t) - p: a ramp of the mouth pressure is the measured
    # pressure less the ramp under a held p_m
    dp_lead = reed.p_m + ramp_lead - p_hist[-n_lead:]
    y_lead = reed_trajectory(reed, p_hist[-n_lead:] - ramp_lead, fs)
    y, y_prev = float(y_lead[-1]), float(y_lead[-2])
    drop = 0.0  # Pa: the mean flow's drop the measured pressure lacks
    if filt:
        c = missing_mean_flow(reed, dp_lead, y_lead, u_hist[-n_lead:], fs, kernel.rho)
        drop = kernel.reference_resistance * c
        u_hist, p_hist = u_hist + c, p_hist + drop
    state = ModelState(
        p_plus=0.5 * (p_hist[-n_taps:] + kernel.z0 * u_hist[-n_taps:]),
        y=y,
        y_prev=y_prev,
        dp=float(dp_lead[-1]),
    )
    # Run on past the window when filtering: the linear-phase FIR needs its
    # half-length of signal on both sides of the window.
    n_pad = lp.delay + 1 if filt else 0
    mouth = reed.p_m + ramp(n + n_pad) if target.p_m_slope else None
    p_mod, u_mod = _simulate(reed, kernel, n + n_pad, state=state, mouth=mouth)
    if filt:
        ctx = lp.delay + 1
        p_mod = _measured_pressure(np.concatenate([p_hist[-ctx:], p_mod]), lp, ctx, n) - drop
        u_mod = _measured_flow(np.concatenate([u_hist[-ctx:], u_mod]), lp, ctx, n, target)
    return p_mod, u_mod


@dataclass(frozen=True)
class F2Objective:
    """F2 as a function of the free parameters, for the optimisers.

    Calling the object with a vector of free-parameter values (SI units, in the order of
    ``free``) returns F2 in Pa; an infeasible candidate (invalid reed, unstable step,
    divergence, silence) returns ``penalty``, a large finite value. It never raises.

    Attributes
    ----------
    kernel : BoreKernel
        Prepared bore.
    target : TargetWindow
        Target window and history.
    settings : ObjectiveSettings
        Start method and filters.
    base : ReedParameters
        Values of the fixed parameters (and the start of the free ones).
    free : tuple of str
        Names of the free parameters (fields of ReedParameters).
    contact_at_closure : bool
        Tie the contact point to the rest opening (y_c = y_m) in every candidate.
    fast : bool
        Compute F2 and the residuals by the compiled evaluator of
        :mod:`mpipe.inversion.fit.fastpath` (the same numbers to rounding).
        False: by :func:`run_model`, the plain reference. :meth:`evaluate` (model pressure
        and flow, for plots) always uses the reference.
    """

    kernel: BoreKernel
    target: TargetWindow
    settings: ObjectiveSettings
    base: ReedParameters
    free: tuple[str, ...]
    contact_at_closure: bool = False
    fast: bool = True

    @functools.cached_property
    def _evaluator(self):
        # built on first use, once per window: the history spectra and buffers it holds
        # are shared by every candidate of the window
        from mpipe.inversion.fit.fastpath import WindowEvaluator

        if not self.fast:
            return None
        return WindowEvaluator(self.kernel, self.target, self.settings)

    @property
    def evaluator(self):
        """The window's compiled evaluator (None without one: ``fast`` false)."""
        return self._evaluator

    @functools.cached_property
    def _sensitivities(self):
        # the Jacobian's work buffers, built on first use once per window
        from mpipe.inversion.fit.sensitivities import SensitivityEvaluator

        ev = self._evaluator
        if ev is None:
            return None
        return SensitivityEvaluator(ev, self.free, self.contact_at_closure)

    @property
    def has_jacobian(self) -> bool:
        """True when :meth:`jacobian` gives the model's own derivatives (compiled path)."""
        return self._evaluator is not None

    def jacobian(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """Residuals (Pa) and their Jacobian from the model's forward sensitivities.

        Parameters
        ----------
        x : ndarray
            Free-parameter values, SI units, in the order of ``free``.

        Returns
        -------
        (r, J) or None
            ``r`` as :meth:`residuals`, ``J[i, j] = d r_i / d x_j`` (Pa per the SI unit of
            parameter j), computed in one model run
            (:mod:`mpipe.inversion.fit.sensitivities`); None for an infeasible candidate or
            without the compiled evaluator (``fast`` false).
        """
        sens = self._sensitivities
        if sens is None:
            return None
        try:
            reed = self.reed(x)
        except ValueError:
            return None
        n = self.target.p.size
        r = np.empty(n)
        jac = np.empty((n, len(self.free)))
        if sens.jacobian_into(reed, r, jac):
            return None
        return r, jac

    @property
    def penalty(self) -> float:
        """F2 of an infeasible candidate, Pa: far above any feasible mismatch."""
        return 1e3 * (float(np.linalg.norm(self.target.p)) + 1.0)

    def infeasible(self, r: np.ndarray) -> bool:
        """``r`` (from :meth:`residuals`) is the penalty vector of an infeasible candidate."""
        return bool(np.all(r == r[0])) and abs(r[0]) * math.sqrt(r.size) >= 0.999 * self.penalty

    def reed(self, x: np.ndarray) -> ReedParameters:
        """Reed parameters for free-parameter values ``x`` (may raise InvalidReedError)."""
        values = {name: float(v) for name, v in zip(self.free, np.ravel(x), strict=True)}
        if self.contact_at_closure:
            values["y_c"] = values.get("y_m", self.base.y_m)
        return dataclasses.replace(self.base, **values)

    def evaluate(self, x: np.ndarray) -> ModelWindow:
        """Model output and F2 for free-parameter values ``x``."""
        try:
            reed = self.reed(x)
        except ValueError as exc:
            n = self.target.p.size
            nan = np.full(n, np.nan)
            return ModelWindow(nan, nan, self.penalty, math.inf, False, f"invalid: {exc}")
        return run_model(reed, self.kernel, self.target, self.settings, self.penalty)

    def __call__(self, x: np.ndarray) -> float:
        """F2 in Pa for free-parameter values ``x``."""
        if self._evaluator is None:
            return self.evaluate(x).f2
        r = self.residuals(x)
        return float(np.linalg.norm(r))

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """Target minus model pressure over the window, Pa (F2 is its norm).

        An infeasible candidate gives a constant vector whose norm is ``penalty``, so the
        residual vector always has the window's length.
        """
        n = self.target.p.size
        ev = self._evaluator
        if ev is None:
            w = self.evaluate(x)
            if not w.feasible:
                return np.full(n, self.penalty / math.sqrt(n))
            return self.target.p - w.p
        try:
            reed = self.reed(x)
        except ValueError:
            return np.full(n, self.penalty / math.sqrt(n))
        out = np.empty(n)
        if ev.residuals_into(reed, out):
            return np.full(n, self.penalty / math.sqrt(n))
        return out
