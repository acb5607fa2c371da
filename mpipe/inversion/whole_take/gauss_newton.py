"""The take's fit as a damped Gauss-Newton on its block-arrow normal equations.

The solver of :mod:`mpipe.inversion.whole_take.estimator`: where the fit is
(:class:`FitState`), its windows and their shards (:class:`TakeProblem`), and one pass on
a pass's kernels (:func:`joint_pass`), a Levenberg-Marquardt on the system of
:class:`mpipe.inversion.pooling.take_system.TakeSystem` with secant (Broyden) updates of
the windows' Jacobians between exact ones.

**Stages.** The first stage's cost is the sum over the windows that inform the shared
unknowns (``WindowProblem.informs``); the other windows' controls are held in it and
fitted in the second stage (``TakeProblem.settling``), with the note constants and T held
at the first stage's solution and every window counted.

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
K. Levenberg 1944, D. W. Marquardt 1963; J. Nocedal, S. J. Wright, *Numerical
Optimization*, Springer 2006, section 10.3 (Gauss-Newton, Levenberg-Marquardt).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from mpipe.inversion.pooling.take_system import TakeSystem
from mpipe.inversion.whole_take.estimator import given_mask, normal_system
from mpipe.inversion.whole_take.shard_workers import Shards
from mpipe.inversion.whole_take.take_shards import Blocks, Layout

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
#: Most damped Gauss-Newton steps tried in one pass: a budget for the stopping rules to
#: decide within, not a rule of its own. An OpenWInD diminuendo to the threshold (holed
#: bore, 45 dB) crawls: its last pass lowers the cost by about 0.04 a step and stops by the
#: stall rule at step 52; at 40 it ended "step limit", every window not-converged, the
#: take FAIL with right estimates (``docs/benchmarks.md``, the independent simulator).
MAX_STEPS = 100


def _cost(blocks: Blocks, weight: float, t: float, prior, counted=None) -> float:
    """The weighted sum of squares of the ``counted`` windows (all) and the prior's term."""
    mean, se = prior
    rr = blocks.rr if counted is None else blocks.rr[counted]
    return weight * float(np.sum(rr)) + ((t - mean) / se) ** 2


def pooled_weight(blocks: Blocks, counted=None) -> float:
    """The windows' one weight ``1 / (tau s^2)``, 1/Pa^2 (see the module docstring).

    Measured on the ``counted`` windows (all): those the fit's cost is the sum over.
    """
    keep = np.ones(blocks.rr.size, bool) if counted is None else np.asarray(counted, bool)
    ss, n = float(np.sum(blocks.rr[keep])), float(np.sum(blocks.n[keep]))
    n_eff = float(np.sum(blocks.n_eff[keep]))
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
        self.n_eff = np.full(len(problems), math.nan)  # each window's, at the last measurement
        # the second stage: the windows' controls alone, the shared unknowns held
        self.settling = False
        # the mouth pressure's slope each window plays (Pa/s; None: p_m held over it) and
        # what sets them (passes.slopes_at: fs in Hz, a lead-in's reach in s, p_m's column)
        self.slopes: np.ndarray | None = None
        self.ramp: tuple | None = None

    def given(self) -> np.ndarray | None:
        """The windows fitted given the shared unknowns (:func:`given_mask`)."""
        return given_mask(self.problems)

    def counted(self) -> np.ndarray:
        """The windows the cost sums over: those that inform (every one when settling)."""
        if self.settling:
            return np.ones(len(self.problems), bool)
        return np.array([q.informs for q in self.problems], dtype=bool)

    def held(self, n_notes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The unknowns a stage holds, masks (W, f), (N, s), (t,).

        The fit's first stage holds the controls of the windows fitted given the shared
        unknowns (they are not in its cost); the second (``settling``) holds the shared
        ones and fits every window's controls at them.
        """
        f, s = self.layout.n_fast, len(self.layout.names) - self.layout.n_fast
        fast = np.broadcast_to(~self.counted()[:, None], (len(self.problems), f)).copy()
        slow = np.full((n_notes, s), self.settling)
        return fast, slow, np.array([self.settling])

    def blocks(self, state: FitState, method: str = "trial", accept: bool = False):
        """Every window's blocks at ``state`` (None when a window cannot be played).

        ``method``: a secant ``trial``, the ``exact`` Jacobian, or with the Taylor terms in
        T measured first (``measure``); ``accept``: the last trial was accepted.
        """
        parts = self.shards.split(state.values(self.layout, self.problems))
        args = [(v, state.t) if method == "measure" else (v, state.t, accept) for v in parts]
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
        stage = self.held(len(state.slow))
        base, held = system.frozen(*stage), stage
        system = base
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
        weight, exact = pooled_weight(blocks, take.counted()), True
        take.n_eff = blocks.n_eff  # effective samples, measured with T's terms
    else:
        blocks, weight, exact = start
    counted = take.counted()
    cost = _cost(blocks, weight, state.t, take.prior, counted)
    take.history.append(np.sqrt(blocks.rr))
    n_data = float(np.sum(take.n_eff[counted]))
    n_par = state.fast[counted].size + (0 if take.settling else state.slow.size + 1)
    mu, nu, message, converged, steps = 1e-3, 2.0, "step limit", False, 0
    # the last trial was taken; trials since the Jacobian was exact; the accepted point's
    # Jacobian is the exact one (no secant update accepted since)
    accepted, secant = False, 0
    recent: list[float] = []  # the cost at every step
    for steps in range(1, max_steps + 1):  # noqa: B007 - the count is reported
        system = normal_system(blocks, weight, take.problems, take.sizes, state.t, take.prior,
                         given=not take.settling)  # fmt: skip
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
        new_cost = _cost(trial, weight, new_state.t, take.prior, counted) if trial else math.inf
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


__all__ = [
    "BOUND_TOLERANCE",
    "LOOSE_SE",
    "MAX_STEPS",
    "SE_TOLERANCE",
    "FitState",
    "TakeProblem",
    "joint_pass",
    "pooled_weight",
]
