"""One estimator for the take: every window, note and the bore's air in one least-squares fit.

``inversion.estimator: take``. The take's model is fitted to its mouthpiece pressure once,
with its parameters in three tiers (:mod:`mpipe.inversion.pooling.take_system`):

- each window's fast controls, the player's (p_m, y_m), which move within 20 ms;
- each note's slow reed constants (k, S, lam, m, g, k_c; y_c when searched), which change
  over seconds as the reed warms and wets;
- the take's air temperature T (degC), which sets the bore's reflection function, with
  the front end's estimate and its standard error as a Gaussian prior.

**How it runs.** Two cold starts per take, on its first and its loudest steady window
(:mod:`mpipe.inversion.whole_take.cold_starts`: the global search of
:mod:`mpipe.inversion.fit.coldstart`), at the prior's temperature, each followed on the
thinned take (every 4th window of a note) and the whole take fitted from the lower one's
minimum (:mod:`mpipe.inversion.whole_take.take_fit`). Every window starts warm from the
window before it in its chain (:data:`mpipe.inversion.whole_take.take_shards.CHAIN`
windows of one note): its fast controls fitted with the reed's constants held, so a
crescendo or a new note is followed without a search. The joint fit is a damped
Gauss-Newton (Levenberg-Marquardt) on the whole take's normal equations, each window's
block eliminated; the windows' residual blocks come from the one compiled recursion with
forward sensitivities, computed where the windows are
(:mod:`mpipe.inversion.whole_take.take_shards`).

**Passes.** The bore's kernel is built at the current temperature ``T_k`` and the
residual taken as a quadratic in T about it (its Taylor terms measured once per pass). A
pass is a damped Gauss-Newton to :data:`SE_TOLERANCE`; when T moved by more than
:data:`T_SETTLED_C` the kernels are rebuilt there and a new pass starts from the current
values: a few kernels per take, not one per temperature tried.

**The stopping rule** is the undamped Gauss-Newton step's length in the fit's own standard
errors (the Newton decrement): the estimate is within :data:`SE_TOLERANCE` SE of the local
quadratic's minimum. A damped step's length is no test: in the narrow valley of T against
the reed's constants it is small long before the minimum.

**Weights.** One weight for every window, ``1 / (tau s^2)`` from the take's pooled misfit
per sample ``s^2`` and its residuals' integrated autocorrelation ``tau``, so the sum of
squares counts each effective sample once and the prior weighs against it in the same
units. Weights from each window's own misfit move with the fit (a window the start fits
badly counts less): every pass re-weighted and moved the solution again (the demo take's
temperature crept 0.7, 0.17, 0.06, 0.03 degC over four passes).

References
----------
Chatziioannou & van Walstijn 2012, eq. (15) and section 3.2; Triggs et al. 2000
(bundle adjustment); K. Levenberg 1944, D. W. Marquardt 1963.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from mpipe.inversion.fit.history_start import lead_in
from mpipe.inversion.fit.objective import TargetWindow
from mpipe.inversion.fit.window import window_bounds
from mpipe.inversion.pooling.take_system import TakeSystem, TierSizes, split_names
from mpipe.inversion.settings import InversionConfig
from mpipe.inversion.whole_take.shard_workers import Shards
from mpipe.inversion.whole_take.take_shards import Blocks, Layout
from mpipe.reed.parameters import ReedParameters

log = logging.getLogger(__name__)

#: A pass ends within this many standard errors of its minimum (0.1 SE moves no estimate
#: by anything its error bar can show).
SE_TOLERANCE = 0.1
#: A pass after which the kernels may be rebuilt stops within this many SEs of its
#: minimum: only the last pass needs :data:`SE_TOLERANCE`.
LOOSE_SE = 1.0
#: An estimate this close to a bound (in ln x; degC for T) is on it (the per-window fit's
#: ``inversion.bound_tolerance`` default).
BOUND_TOLERANCE = 1e-3
#: Secant (Broyden) updates of the Jacobian before it is made exact again; a step rejected on
#: a secant Jacobian makes it exact at once (it has mispredicted the fall). A step rejected
#: on the exact one only raises the damping: making it exact again at the same point gives
#: the same Jacobian, for about five model runs per window.
SECANT_STEPS = 6
#: A pass whose sum of squares fell by less than its tolerance (in SE^2) over this many
#: steps has converged (see :func:`joint_pass`).
STALL_STEPS = 5
#: Most damped Gauss-Newton steps tried in one pass.
MAX_STEPS = 40
#: Most passes (kernels rebuilt at the new temperature).
MAX_PASSES = 4
#: A pass whose temperature moved less than this is the last, degC.
T_SETTLED_C = 0.25


@dataclass(frozen=True)
class TakeData:
    """A take's mouthpiece signals and what of them is inverted, and how.

    Attributes
    ----------
    p, u : array-like
        Mouthpiece pressure (Pa) and flow (m^3/s) of the take (only sliced).
    fs : float
        Sample rate, Hz.
    calibration : Calibration
        The instrument (its bore and fingerings).
    windows : WindowPlan
        The windows, their notes, steadiness and fingerings
        (:class:`mpipe.inversion.whole_take.tracking.WindowPlan`).
    config : InversionConfig
        Inversion settings.
    zero_mean : bool
        The flow is zero-mean (measured).
    cold : dict
        First sample -> a cold start already made there on these settings and at the
        prior's temperature (its ``WindowOutcome``: the contact law's choice), reused.
    front : FrontEnd, optional
        The front end's estimate with its SEs
        (:class:`mpipe.inversion.whole_take.shared_errors.FrontEnd`): its share of every
        estimate is propagated through the fit
        (:mod:`mpipe.inversion.whole_take.frontend_joint`); None: not measured.
    """

    p: object
    u: object
    fs: float
    calibration: object
    windows: object
    config: InversionConfig
    zero_mean: bool
    cold: dict = dataclasses.field(default_factory=dict)
    front: object = None


@dataclass(frozen=True)
class WindowProblem:
    """One window of the take's fit: where it is and what it compares.

    Attributes
    ----------
    start : int
        First sample.
    note : int
        Its note's index in the fit, 0..N-1 (time order).
    fingering : str
        Its note's fingering ("" the calibration's bore).
    target : TargetWindow
        The measured window and the history the model reads.
    bounds : ndarray
        Search bounds of the free parameters in the fit's order (fast then slow), (p, 2).
    """

    start: int
    note: int
    fingering: str
    target: TargetWindow
    bounds: np.ndarray


@dataclass(frozen=True)
class TakeFit:
    """The take's joint fit at its solution.

    Attributes
    ----------
    names : tuple of str
        The fit's reed parameters, fast then slow.
    sizes : TierSizes
        f, s and t (= 1: the temperature).
    problems : tuple of WindowProblem
        The windows fitted (in time order).
    fast : ndarray
        Each window's fast parameters, SI units, (W, f).
    slow : ndarray
        Each note's slow parameters, SI units, (N, s).
    temperature_c : float
        The take's air temperature, degC.
    blocks : Blocks
        Each window's blocks of the normal equations at the solution (unweighted), over
        (ln fast, ln slow, T degC).
    records : list of dict
        Each window's residual figures and noise grams at the solution
        (:meth:`mpipe.inversion.whole_take.take_shards.Shard.final`).
    weight : float
        The windows' weight, 1/Pa^2.
    prior : tuple of float
        The temperature's prior: mean and standard error, degC.
    n_steps, n_passes : int
        Steps tried over all passes, and the passes.
    converged : bool
        Every pass ended by its tolerance, not by its step limit.
    message : str
        Why the last pass stopped.
    excluded : dict
        First sample -> why that window is not in the fit.
    z0, rho : ndarray
        Each window's entry impedance (Pa s/m^3) and air density (kg/m^3) at the fit's
        temperature, on its fingering's bore.
    history : ndarray
        Each window's F2 (Pa) at every point the fit took, (points, W).
    rivals : tuple of float
        The cost of the fit from each of the take's cold starts that began in a basin of
        its own, this one's among them (``take_fit.rival_costs``; empty: one start).
    frontend : FrontendShares, optional
        The solution moved by one SE of each front-end parameter
        (:mod:`mpipe.inversion.whole_take.frontend_joint`); None: not measured.
    """

    names: tuple[str, ...]
    sizes: TierSizes
    problems: tuple[WindowProblem, ...]
    fast: np.ndarray
    slow: np.ndarray
    temperature_c: float
    blocks: Blocks
    records: list
    weight: float
    prior: tuple[float, float]
    n_steps: int
    n_passes: int
    converged: bool
    message: str
    excluded: dict
    z0: np.ndarray
    rho: np.ndarray
    history: np.ndarray
    rivals: tuple = ()
    frontend: object = None

    def system(self) -> TakeSystem:
        """The weighted normal equations at the solution, the prior included."""
        return _system(self.blocks, self.weight, self.problems, self.sizes, self.temperature_c,
                       self.prior)  # fmt: skip

    def reed(self, i: int, base: ReedParameters, contact_at_closure: bool) -> ReedParameters:
        """Window i's reed: its fast controls, its note's constants, ``base`` for the rest."""
        q = self.problems[i]
        values = dict(zip(self.names, [*self.fast[i], *self.slow[q.note]], strict=True))
        if contact_at_closure:
            values["y_c"] = values.get("y_m", base.y_m)
        return dataclasses.replace(base, **{k: float(v) for k, v in values.items()})


def layout_of(config: InversionConfig) -> Layout:
    """The fit's names (fast then slow) and their places among the searched parameters."""
    fast, slow = split_names(config.search_parameters)
    names = (*fast, *slow)
    order = np.array([names.index(n) for n in config.search_parameters])
    return Layout(names, len(fast), order)


def problems_of(
    p, u, fs: float, starts: Sequence[int], notes: Sequence[int], fingerings: Sequence[str],
    config: InversionConfig, zero_mean: bool, n_taps: int,
) -> list[WindowProblem]:  # fmt: skip
    """Every window's target and bounds (the fit's order of parameters: fast then slow)."""
    n = int(round(config.window_s * fs))
    order = layout_of(config).names
    index = [config.search_parameters.index(name) for name in order]
    out = []
    for s, g, name in zip(starts, notes, fingerings, strict=True):
        history = lead_in(p, u, s, n, n_taps, config.lead_s, fs)
        target = TargetWindow(np.asarray(p[s : s + n], float), np.asarray(u[s : s + n], float),
                              *history, fs, zero_mean)  # fmt: skip
        bounds = window_bounds(config, p, s, n, fs)[index]
        out.append(WindowProblem(int(s), int(g), name, target, bounds))
    return out


def _prior(t: float, prior: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """The temperature prior's information (1x1) and gradient at ``t``."""
    mean, se = prior
    info = 1.0 / se**2
    return np.array([[info]]), np.array([info * (t - mean)])


def _system(blocks: Blocks, weight: float, problems, sizes, t, prior) -> TakeSystem:
    info, grad = _prior(t, prior)
    notes = np.array([q.note for q in problems], dtype=int)
    return TakeSystem(sizes, notes, weight * blocks.grams, weight * blocks.grads, info, grad)


def _cost(blocks: Blocks, weight: float, t: float, prior) -> float:
    mean, se = prior
    return weight * float(np.sum(blocks.rr)) + ((t - mean) / se) ** 2


def pooled_weight(blocks: Blocks) -> float:
    """The windows' one weight ``1 / (tau s^2)``, 1/Pa^2 (see the module docstring)."""
    ss, n, n_eff = float(np.sum(blocks.rr)), float(np.sum(blocks.n)), float(np.sum(blocks.n_eff))
    return (n_eff / n) / (ss / n) if ss > 0 else 1.0


@dataclass(frozen=True)
class FitState:
    """Where the joint fit is: fast (W, f) and slow (N, s) values (SI), T (degC)."""

    fast: np.ndarray
    slow: np.ndarray
    t: float

    def values(self, layout: Layout, problems) -> np.ndarray:
        """Every window's free-order values, (W, p)."""
        return np.array([layout.free_values(self.fast[i], self.slow[q.note])
                         for i, q in enumerate(problems)])  # fmt: skip


class TakeProblem:
    """The fit's windows, their shards and bounds (one object per take's fit)."""

    def __init__(self, shards: Shards, problems, layout: Layout, sizes, prior, boxes):
        self.shards, self.problems, self.layout = shards, problems, layout
        self.sizes, self.prior, self.boxes = sizes, prior, boxes
        self.history: list[np.ndarray] = []  # every window's F2 (Pa) at each point taken
        self.n_data = math.nan  # the windows' effective samples at the last measurement

    def blocks(self, state: FitState, method: str = "trial", accept: bool = False):
        """Every window's blocks at ``state`` (None when a window cannot be played).

        ``method``: a secant ``trial``, the ``exact`` Jacobian, or with the Taylor terms in
        T measured first (``measure``); ``accept``: the last trial was accepted.
        """
        parts = self.shards.split(state.values(self.layout, self.problems))
        args = [(v,) if method == "measure" else (v, state.t, accept) for v in parts]
        out = self.shards.call(method, args)
        return None if any(b is None for b in out) else Blocks.join(out)

    def free_system(self, system: TakeSystem, state: FitState):
        """The system without the estimates on a bound that its step pushes out of it.

        Returns the system (those unknowns held, :meth:`TakeSystem.frozen`) and its undamped
        Gauss-Newton step. An estimate on a bound is then judged by the other unknowns'
        step alone: the step out of the box would never shrink, and a note the model cannot
        play within its bounds would hold the whole take's fit at its step limit.
        """
        (flo, fhi), (slo, shi), (tlo, thi) = self.boxes
        zf, zs = np.log(state.fast), np.log(state.slow)
        tol = BOUND_TOLERANCE
        base, held = system, None
        for _ in range(4):
            d_fast, d_slow, d_t = system.step(0.0)
            masks = (
                ((zf <= flo + tol) & (d_fast < 0)) | ((zf >= fhi - tol) & (d_fast > 0)),
                ((zs <= slo + tol) & (d_slow < 0)) | ((zs >= shi - tol) & (d_slow > 0)),
                np.array([(state.t <= tlo + tol and d_t[0] < 0) or
                          (state.t >= thi - tol and d_t[0] > 0)]),
            )  # fmt: skip
            if held is not None:
                masks = tuple(m | h for m, h in zip(masks, held, strict=True))
            if held is not None and all((m == h).all() for m, h in zip(masks, held, strict=True)):
                break
            if not any(m.any() for m in masks):
                break
            held = masks
            system = base.frozen(*held)
        return system, (d_fast, d_slow, d_t)

    def moved(self, state: FitState, d_fast, d_slow, d_t) -> FitState:
        """``state`` moved by a step (ln fast, ln slow, T), clipped into the bounds."""
        (flo, fhi), (slo, shi), (tlo, thi) = self.boxes
        fast = np.exp(np.clip(np.log(state.fast) + d_fast, flo, fhi))
        slow = np.exp(np.clip(np.log(state.slow) + d_slow, slo, shi))
        return FitState(fast, slow, float(np.clip(state.t + d_t[0], tlo, thi)))


def joint_pass(take: TakeProblem, state: FitState, tolerance: float = SE_TOLERANCE, start=None,
               max_steps: int = MAX_STEPS, near=None):  # fmt: skip
    """One pass of the joint fit on the shards' kernels (see the module docstring).

    ``tolerance`` is the stopping rule's, in SEs; ``start`` the ``(blocks, weight, exact)`` a
    pass on the same kernels ended with (None: the Taylor terms are measured at ``state``;
    ``exact``: its blocks' Jacobian is the exact one, not a secant update). ``near(slow)``,
    when given, is asked at every accepted step whether the pass may end there (the note
    constants, (N, s)). Returns
    ``(state, (blocks, weight, exact), steps, converged, message)``; raises ValueError when
    a window cannot be played at the pass's start.
    """
    if start is None:
        blocks = take.blocks(state, "measure")
        if blocks is None:
            raise ValueError("a window's model cannot play at the start of a pass of the "
                             "take's fit")  # fmt: skip
        weight, exact = pooled_weight(blocks), True
        take.n_data = float(np.sum(blocks.n_eff))  # effective samples, measured with T's terms
    else:
        blocks, weight, exact = start
    cost = _cost(blocks, weight, state.t, take.prior)
    take.history.append(np.sqrt(blocks.rr))
    n_data = take.n_data
    n_par = state.fast.size + state.slow.size + 1
    mu, nu, message, converged, steps = 1e-3, 2.0, "step limit", False, 0
    # the last trial was taken; trials since the Jacobian was exact; the accepted point's
    # Jacobian is the exact one (no secant update accepted since)
    accepted, secant = False, 0
    recent: list[float] = []  # the cost at every step
    for steps in range(1, max_steps + 1):  # noqa: B007 - the count is reported
        system = _system(blocks, weight, take.problems, take.sizes, state.t, take.prior)
        system, newton = take.free_system(system, state)
        sigma2 = cost / max(n_data - n_par, 1.0)
        decrement = system.predicted_fall(*newton)
        done = decrement <= tolerance**2 * sigma2
        log.debug("step %d: cost %.6g, decrement %.3g SE^2, mu %.3g, secant %d", steps, cost,
                  decrement / sigma2, mu, secant)  # fmt: skip
        if done and exact:
            message, converged = f"within {tolerance:g} SE of the minimum", True
            break
        recent.append(cost)
        if len(recent) > STALL_STEPS and recent[-STALL_STEPS - 1] - cost <= tolerance**2 * sigma2:
            # Gauss-Newton converges only linearly where the residual is far from zero (a
            # measured take's misfit): its decrement is then no exact test, and the cost's
            # fall over the last steps is the measure of what is left
            message = (f"the sum of squares fell by less than {tolerance:g}^2 SE^2 over "
                       f"{STALL_STEPS} steps")  # fmt: skip
            converged = True
            break
        if not exact and (done or secant >= SECANT_STEPS or (secant and not accepted)):
            # converged on a secant Jacobian, or it has served long or badly: made exact
            blocks = take.blocks(state, "exact", accepted)
            accepted, secant, exact = False, 0, True
            continue
        new_state = take.moved(state, *system.step(mu))
        d = (
            np.log(new_state.fast) - np.log(state.fast),
            np.log(new_state.slow) - np.log(state.slow),
            np.array([new_state.t - state.t]),
        )
        predicted = system.predicted_fall(*d)
        trial = take.blocks(new_state, "trial", accepted)
        secant += 1
        new_cost = _cost(trial, weight, new_state.t, take.prior) if trial else math.inf
        gain = (cost - new_cost) / predicted if predicted > 0 else -1.0
        accepted = gain > 0
        if accepted:
            state, blocks, cost, exact = new_state, trial, new_cost, False
            take.history.append(np.sqrt(blocks.rr))
            mu *= max(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3)
            nu = 2.0
            if near is not None and near(state.slow):
                message, converged = "left: in the first cold start's basin", True
                break
        else:
            mu *= nu
            nu *= 2.0
            if mu > 1e10:
                message, converged = "no step lowers the sum of squares", True
                break
    if accepted:  # the shards' last trial is where the pass ends
        take.shards.call("commit", [(True,)] * len(take.shards.ranges))
    return state, (blocks, weight, exact), steps, converged, message


def search_boxes(problems, n_fast: int, n_notes: int, t_range):
    """Log bounds of the fast values (W, f), the slow ones (N, s), and T's (degC)."""
    lo = np.array([np.log(q.bounds[:, 0]) for q in problems])
    hi = np.array([np.log(q.bounds[:, 1]) for q in problems])
    notes = np.array([q.note for q in problems])
    slow_lo = np.array([lo[notes == n, n_fast:].max(axis=0) for n in range(n_notes)])
    slow_hi = np.array([hi[notes == n, n_fast:].min(axis=0) for n in range(n_notes)])
    return (lo[:, :n_fast], hi[:, :n_fast]), (slow_lo, slow_hi), t_range


__all__ = [
    "MAX_PASSES",
    "MAX_STEPS",
    "SE_TOLERANCE",
    "T_SETTLED_C",
    "TakeData",
    "TakeFit",
    "WindowProblem",
    "FitState",
    "Layout",
    "TakeProblem",
    "joint_pass",
    "search_boxes",
    "layout_of",
    "pooled_weight",
    "problems_of",
]
