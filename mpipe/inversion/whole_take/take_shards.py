"""The take's windows spread over workers: each shard holds its windows' objectives.

The joint fit of :mod:`mpipe.inversion.whole_take.estimator` needs, per step, only each
window's small blocks of the normal equations (:class:`Blocks`: ``J^T J``, ``J^T r`` and
``r^T r`` over its own columns), never its residual or Jacobian themselves. A
:class:`Shard` holds a contiguous run of windows with their compiled objectives on the
bore at the current temperature and computes those blocks;
:class:`~mpipe.inversion.whole_take.shard_workers.Shards` spreads the take's windows over
``workers`` shards, each in a process of its own that keeps its objectives from one step
to the next (only the parameter values travel), or runs one shard here. Every window's
numbers depend only on its own data and the values it is
given, and the parent sums them in window order: 1 or N workers give the same fit.

**The temperature's terms.** A shard's objectives are built on the kernel at ``T_k``;
each window's residual slope ``dr/dT`` and curvature ``d2r/dT2`` are measured once per pass
(:meth:`Shard.measure`, on the kernels at ``T_k -+ DELTA_T_C``), and within the pass the
residual is their quadratic in T. The curvature matters: T is so well determined (a few
hundredths of a degree on the shipped instrument) that a linear model's error over the
1 degC from the front end's estimate stopped each pass at 60-70 % of the way.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from mpipe.core.statistics import integrated_autocorrelation
from mpipe.inversion.fit.objective import F2Objective
from mpipe.inversion.fit.window import window_objective
from mpipe.inversion.preparation.kernel import KernelSource
from mpipe.inversion.trust.diagnostics import playing_difference
from mpipe.inversion.trust.uncertainty import residual_grams
from mpipe.inversion.whole_take.frontend_joint import shard_changes
from mpipe.inversion.whole_take.history_noise import drawn_gram

log = logging.getLogger(__name__)

#: Step of the temperature derivatives' central differences, degC.
DELTA_T_C = 0.5
#: Windows of a note warm-started one from the other in one chain (a chain's first window
#: starts from the take's cold start): fixed, so that chains, and the answer, do not depend
#: on the number of workers.
CHAIN = 16


@dataclass(frozen=True)
class Blocks:
    """Each window's blocks of the normal equations over its own columns (L = f + s + 1).

    Attributes
    ----------
    grams : ndarray
        ``J^T J``, (w, L, L), Pa^2 per (unit ln x or degC) squared.
    grads : ndarray
        ``J^T r``, (w, L).
    rr : ndarray
        ``r^T r``, (w,), Pa^2.
    n : ndarray
        Samples of each residual, (w,).
    n_eff : ndarray
        Effective samples ``n / tau`` of each residual (measured with the Taylor terms; NaN
        otherwise), (w,).
    """

    grams: np.ndarray
    grads: np.ndarray
    rr: np.ndarray
    n: np.ndarray
    n_eff: np.ndarray

    @staticmethod
    def join(parts: Sequence[Blocks]) -> Blocks:
        """The blocks of several shards, in order."""
        return Blocks(*(np.concatenate([getattr(b, f) for b in parts]) for f in
                        ("grams", "grads", "rr", "n", "n_eff")))  # fmt: skip


@dataclass(frozen=True)
class Layout:
    """The fit's parameter names and their places in the objectives' ``free`` order.

    Attributes
    ----------
    names : tuple of str
        The fit's reed parameters, fast then slow.
    n_fast : int
        How many are per window.
    order : ndarray
        For each of the objectives' free parameters, its index in ``names``.
    """

    names: tuple[str, ...]
    n_fast: int
    order: np.ndarray

    def free_values(self, fast: np.ndarray, slow: np.ndarray) -> np.ndarray:
        """Free-order values of one window from its fast and its note's slow values."""
        return np.concatenate([fast, slow])[self.order]

    def to_names(self, jac_free: np.ndarray, x_free: np.ndarray) -> np.ndarray:
        """A Jacobian over the free parameters (per SI unit) as one over ln x, names order."""
        jz = jac_free * x_free
        out = np.empty_like(jz)
        out[:, self.order] = jz
        return out


@dataclass(frozen=True)
class ShardSpec:
    """What a shard is built from (pickled once to its worker)."""

    problems: tuple
    calibration: object
    fs: float
    fingerings: dict
    base: object
    config: object
    layout: Layout
    t: float
    kernels: dict = dataclasses.field(default_factory=dict)  # (T, fingering) -> kernel, air
    noise: object = None  # MouthpieceNoise: the noise gram by realisations (history_noise)


class Shard:
    """A run of windows with their objectives on the bore at one temperature.

    Each window keeps its accepted point (free values ``x``, residual ``r0`` on the kernel
    at ``t``) and a Jacobian ``J0`` over the reed's ln parameters there: exact after
    :meth:`measure` and :meth:`exact` (the model's forward sensitivities, ~9 model runs),
    then updated by Broyden's secant rule at every trial (:meth:`trial`, one run). The
    temperature's column is the pass's Taylor terms, exact in T.
    """

    def __init__(self, spec: ShardSpec):
        self.spec = spec
        self.source = KernelSource(spec.calibration, spec.fs, spec.fingerings)
        self.problems = list(spec.problems)
        self.runs = [0] * len(self.problems)  # model runs of each window (one per candidate)
        self.lowpass = spec.config.lowpass.design(spec.fs)  # one design for every window
        self.rebuild(spec.t, spec.kernels)

    def rebuild(self, t: float, kernels: dict | None = None, slopes=None) -> None:
        """Objectives on the kernels at ``t`` degC (the Taylor terms and points forgotten).

        ``kernels``: ``(T, fingering) -> (kernel, air)`` made by the caller for this pass (at
        ``t`` and ``t -+ DELTA_T_C``); the others are built here when asked for.
        ``slopes``: each window's mouth-pressure slope, Pa/s
        (:attr:`~mpipe.inversion.fit.objective.TargetWindow.p_m_slope`; None: as they are).
        """
        if slopes is not None:
            self.problems = [
                dataclasses.replace(q, target=dataclasses.replace(q.target, p_m_slope=float(s)))
                for q, s in zip(self.problems, slopes, strict=True)
            ]
        self.t = float(t)
        self.source.built.clear()  # the kernels of other temperatures are not used again
        self.source.built.update(kernels or {})
        self.objectives = [self._objective(q, self.t) for q in self.problems]
        self.taylor: list | None = None
        self.accepted: list | None = None  # per window (x, r0, J0)
        self.pending: list | None = None
        self.exact_accepted = False  # the accepted points' J0 are exact (no secant since)

    def reslope(self, slopes: np.ndarray, t: float) -> Blocks | None:
        """The windows' mouth-pressure slopes set anew, the pass's terms kept (Pa/s each).

        Only the objectives change: the Taylor terms in T and the accepted points'
        Jacobians are kept (a slope moves the mouth pressure at a lead-in's start by a few
        10^-4 of p_m, its Jacobian and T terms to that order), and each accepted point's
        residual is played again under its new slope (one model run a window). Returns the
        blocks there at ``t`` degC with the Jacobian a secant one (made exact before the pass
        may stop), or None when a window cannot be played.
        """
        self.commit(False)
        taylor, accepted = self.taylor, self.accepted
        self.rebuild(self.t, dict(self.source.built), slopes)
        self.taylor, self.accepted = taylor, accepted
        # a trial at the accepted points themselves: their residuals under the new slopes,
        # the secant update of a zero step leaving each Jacobian as it was
        out = self.trial(np.array([x for x, _, _ in accepted]), t)
        self.commit(True)
        return out

    def _objective(self, q, t: float) -> F2Objective:
        kernel, _ = self.source.named(t, q.fingering)
        return window_objective(kernel, q.target, self.spec.base, self.spec.config,
                                self.lowpass)  # fmt: skip

    def entries(self) -> tuple[np.ndarray, np.ndarray]:
        """Each window's entry impedance (Pa s/m^3) and air density (kg/m^3) at ``t``."""
        return (np.array([o.kernel.z0 for o in self.objectives]),
                np.array([o.kernel.rho for o in self.objectives]))  # fmt: skip

    def in_t(self, i: int, r0: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The residual at ``t`` and its T column, from the pass's Taylor terms."""
        if self.taylor is None:
            return r0, np.zeros_like(r0)
        slope, curvature = self.taylor[i]
        dt = t - self.t
        return r0 + dt * slope + 0.5 * dt**2 * curvature, slope + dt * curvature

    def _block(self, i: int, r0: np.ndarray, j0: np.ndarray, t: float) -> tuple:
        r, d_t = self.in_t(i, r0, t)
        j = np.concatenate([j0, d_t[:, None]], axis=1)
        return j.T @ j, j.T @ r, float(r @ r), r.size

    @staticmethod
    def _blocks(parts: list, n_eff=None) -> Blocks:
        grams, grads, rr, n = (np.array(v) for v in zip(*parts, strict=True))
        n_eff = np.full(len(n), np.nan) if n_eff is None else np.asarray(n_eff, float)
        return Blocks(grams, grads, rr, n.astype(float), n_eff)

    def commit(self, accept: bool) -> None:
        """Make the last trial the accepted point (``accept``), or forget it."""
        if accept and self.pending is not None:
            self.accepted, self.exact_accepted = self.pending, False
        self.pending = None

    def _exact(self, i: int, x: np.ndarray):
        self.runs[i] += 1
        out = self.objectives[i].jacobian(x)
        if out is None:
            return None
        r0, jac = out
        j0 = self.spec.layout.to_names(jac, x)
        if not (np.isfinite(j0).all() and np.isfinite(r0).all()):
            return None
        return r0, j0

    def at(self, i: int, x: np.ndarray):
        """Window i's residual and exact Jacobian at ``x``, the accepted ones if they are."""
        if self.exact_accepted and self.accepted is not None:
            x0, r0, j0 = self.accepted[i]
            if np.array_equal(x0, x):
                return r0, j0
        return self._exact(i, x)

    def exact(self, values: np.ndarray, t: float, accept: bool = False) -> Blocks | None:
        """Every window's blocks at ``values`` (w, p) and ``t``, its Jacobian exact.

        The point becomes each window's accepted one; None if one window cannot be played.
        """
        self.commit(accept)
        points, parts = [], []
        for i, x in enumerate(values):
            out = self._exact(i, x)
            if out is None:
                return None
            points.append((np.array(x, float), *out))
            parts.append(self._block(i, out[0], out[1], t))
        self.accepted, self.exact_accepted = points, True
        return self._blocks(parts)

    def trial(self, values: np.ndarray, t: float, accept: bool = False) -> Blocks | None:
        """Every window's blocks at a trial point, its Jacobian a secant one.

        The Jacobian is updated by Broyden's rule from the accepted point (one model run
        per window); ``accept``: the previous trial was accepted (it becomes the point
        updated from). None if one window cannot be played.
        """
        self.commit(accept)
        pending, parts = [], []
        for i, x in enumerate(values):
            x0, r_acc, j_acc = self.accepted[i]
            self.runs[i] += 1
            r0 = self.objectives[i].residuals(x)
            if self.objectives[i].infeasible(r0):
                return None
            dz = np.log(x) - np.log(x0)
            j0 = j_acc.copy()
            names_dz = np.empty_like(dz)
            names_dz[self.spec.layout.order] = dz
            dd = float(names_dz @ names_dz)
            if dd > 0:
                j0 += np.outer((r0 - r_acc) - j_acc @ names_dz, names_dz / dd)
            pending.append((np.array(x, float), r0, j0))
            parts.append(self._block(i, r0, j0, t))
        self.pending = pending
        return self._blocks(parts)

    def measure(self, values: np.ndarray, t: float | None = None) -> Blocks | None:
        """The Taylor terms in T at ``values`` (w, p), then the exact blocks there at ``t``.

        The terms are measured about the kernels' temperature (:attr:`t`); the blocks and
        the effective samples are taken at ``t`` degC (default the kernels'): the fit's
        point, which after a pass that moved only the slopes lies off the kernels' T. Taken
        at the kernels' T instead, the 4 s tone of ``mpipe run`` (fit at 19.899 degC on
        kernels at 19.997) began its slopes' pass on a sum of squares 17 % above the point's
        and spent four rejected steps walking back.
        """
        t = self.t if t is None else float(t)
        self.taylor = None
        terms, n_eff = [], []
        for i, x in enumerate(values):
            self.runs[i] += 3  # this run and the two at T -+ DELTA_T_C
            r = self.objectives[i].residuals(x)
            if self.objectives[i].infeasible(r):
                return None
            sides = []
            for sign in (-1.0, 1.0):
                side = self._objective(self.problems[i], self.t + sign * DELTA_T_C)
                r_side = side.residuals(x)
                if side.infeasible(r_side):
                    return None
                sides.append(r_side)
            terms.append(((sides[1] - sides[0]) / (2 * DELTA_T_C),
                          (sides[1] - 2.0 * r + sides[0]) / DELTA_T_C**2))  # fmt: skip
            slope, curvature = terms[-1]
            dt = t - self.t
            r_t = r + dt * slope + 0.5 * dt**2 * curvature
            n_eff.append(r_t.size / integrated_autocorrelation(r_t))
        self.taylor = terms
        out = self.exact(values, t)
        if out is None:
            return None
        return Blocks(out.grams, out.grads, out.rr, out.n, np.array(n_eff))

    def fast_fit(self, i: int, fast0: np.ndarray, slow: np.ndarray, steps: int = 12):
        """Window i's fast controls with its note's constants held: ``(fast, r^T r)``.

        A small damped Gauss-Newton from ``fast0`` on forward differences; None when the
        model cannot play the start.
        """
        lay = self.spec.layout
        f = lay.n_fast
        obj = self.objectives[i]
        bounds = self.problems[i].bounds
        lo, hi = np.log(bounds[:f, 0]), np.log(bounds[:f, 1])

        def residual(z):
            self.runs[i] += 1
            r = obj.residuals(lay.free_values(np.exp(z), slow))
            return None if obj.infeasible(r) else r

        z = np.clip(np.log(np.asarray(fast0, float)), lo, hi)
        r = residual(z)
        if r is None:
            return None
        cost, mu = float(r @ r), 1e-3
        for _ in range(steps):
            jf = _difference(residual, z, r, hi)
            if jf is None:
                break
            a, g = jf.T @ jf, jf.T @ r
            d0 = np.linalg.lstsq(a, -g, rcond=None)[0]
            if float(d0 @ a @ d0) <= 0.05**2 * cost / max(r.size - f, 1):  # within 0.05 SE
                break
            d = np.linalg.solve(a + mu * np.diag(np.maximum(np.diag(a), 1e-300)), -g)
            z_new = np.clip(z + d, lo, hi)
            trial = residual(z_new)
            new = float(trial @ trial) if trial is not None else math.inf
            if new < cost:
                z, r, cost = z_new, trial, new
                mu = max(mu / 3.0, 1e-9)
            else:
                mu *= 4.0
                if mu > 1e8:
                    break
        return np.exp(z), cost

    def warm(self, chains: Sequence[Sequence[int]], starts: Sequence[Sequence[np.ndarray]],
             slows: Sequence[np.ndarray]) -> list:  # fmt: skip
        """Each chain of windows (shard indices), warm one from the other.

        Returns every window's ``(fast values, r^T r)``, or None when none of its starts
        plays.
        ``starts[c]`` are the chain's first window's starts, tried in order; a later window
        tries the one before it first; ``slows[c]`` the reed's constants the chain holds.
        Then the chain's first window, which has no window before it, is fitted again
        from the controls of the one after it and keeps the lower of its two minima: its
        start may lie in another basin of its own sum of squares. On the crescendos of
        ``benchmarks/bench_estimator.py`` the onset window of 10 takes of 40 (45 and 60
        dB) ended 25-49 % from that minimum (p_m 33 % low with 9 times its sum of
        squares, a noise SE of 0.9 %: status ok). Every window walked back so changed no
        other window's p_m by 2 % on 53 takes, and cost about 7 % of the fit (one
        cProfile run of a 2.25 s crescendo, 1 worker, the machine busy).
        """
        out = [None] * len(self.problems)
        for chain, first, slow in zip(chains, starts, slows, strict=True):
            previous = None
            for i in chain:
                tries = ([previous] if previous is not None else []) + list(first)
                for x0 in tries:
                    found = self.fast_fit(i, x0, slow)
                    if found is not None:
                        out[i] = found
                        previous = found[0]
                        break
            if len(chain) > 1 and out[chain[1]] is not None:  # the first from its successor
                i = chain[0]
                found = self.fast_fit(i, out[chain[1]][0], slow)
                if found is not None and (out[i] is None or found[1] < out[i][1]):
                    out[i] = found
        return out

    def frontend(self, values: np.ndarray, t: float, span, sliced, spans) -> dict:
        """Each window's gradient change for each moved front end (:func:`shard_changes`)."""
        return shard_changes(self, values, t, span, sliced, spans)

    def final(self, values: np.ndarray, t: float, floor: float) -> list[dict]:
        """Each window's residual figures and noise grams at its solution (exact Jacobian).

        The accepted point's exact Jacobian is used where ``values`` are that point (the
        pass ended on it), else it is computed; either way it becomes the accepted one, for
        the front end's share after it (:meth:`frontend`).
        """
        out, points = [], []
        p_loc = len(self.spec.layout.names) + 1
        for i, x in enumerate(values):
            x = np.asarray(x, float)
            r0, j0 = self.at(i, x)
            points.append((x, r0, j0))
            r, d_t = self.in_t(i, r0, t)
            j = np.concatenate([j0, d_t[:, None]], axis=1)
            pw = self.problems[i].target.p
            n_eff = r.size / integrated_autocorrelation(r)
            gram, excess, n_eff, dof, extra = residual_grams(j, r, pw, self.spec.fs, floor,
                                                             n_eff, n_eff - p_loc)  # fmt: skip
            drawn = None if self.spec.noise is None else drawn_gram(self, i, x, j,
                                                                     self.spec.noise)  # fmt: skip
            norm_p = float(np.linalg.norm(pw)) + 1e-300
            if drawn is not None:
                gram, extra["drawn_noise_residual"] = drawn[0], math.sqrt(drawn[1]) / norm_p
            f2 = float(np.linalg.norm(r))
            rel = f2 / norm_p
            played = playing_difference(pw, pw - r, self.spec.fs)
            out.append(dict(gram=gram, excess=excess, n_eff=n_eff, dof=dof, tau=r.size / n_eff,
                            runs=self.runs[i],
                            sigma=f2 / math.sqrt(max(dof, 1.0)), f2=f2, relative_residual=rel,
                            playing=played, **extra))  # fmt: skip
        self.accepted, self.exact_accepted, self.pending = points, True, None
        return out


#: Step of the fast controls' forward differences, in ln x (0.01 %, as the window fit's).
DIFF_STEP = 1e-4


def _difference(residual, z: np.ndarray, r: np.ndarray, hi: np.ndarray):
    """Forward-difference Jacobian of ``residual`` in ``z`` (backwards at an upper bound)."""
    cols = []
    for k in range(z.size):
        h = DIFF_STEP if z[k] + DIFF_STEP <= hi[k] else -DIFF_STEP
        zk = z.copy()
        zk[k] += h
        rk = residual(zk)
        if rk is None:
            return None
        cols.append((rk - r) / h)
    return np.column_stack(cols)


__all__ = ["CHAIN", "DELTA_T_C", "Blocks", "Layout", "Shard", "ShardSpec"]
