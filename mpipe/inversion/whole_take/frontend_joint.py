"""The front end's share of the take's fit, through the fit's own normal equations.

The separation's take-level theta (temperature, losses, Mach number, position of the middle
microphone; :class:`mpipe.inversion.whole_take.shared_errors.FrontEnd`) has standard
errors. Moving one of them by its SE changes the mouthpiece p and u the take's fit reads
(re-separated and translated over each shard's span,
:func:`mpipe.inversion.whole_take.frontend_propagation.span_changes`), and so every
window's residual at the solution by ``dr_i``. The take's minimum then moves, to first
order (the implicit function theorem on the Gauss-Newton system the fit solved and its
sandwich covariance uses), by

    dx = -A^-1 w sum_i J_i^T dr_i,

``A`` the take's weighted normal matrix (every window's p_m, y_m, each note's constants, T;
the prior's information), one block-arrow solve per parameter
(:class:`mpipe.inversion.pooling.take_system.TakeSystem`). The temperature's prior is the
front end's own temperature, so moving that parameter moves the prior's mean too (its
gradient by ``-se / se_prior^2``), and its variance then belongs here, not in the noise
sandwich (:func:`mpipe.inversion.whole_take.take_rows.take_covariances` leaves it out).

Each window's front-end covariance over (its reed parameters, T) is ``D^T R D``, D its
shifts per SE (one row per parameter) and R the correlation of the front end's errors (from
the separation's covariance of its take-level theta, :meth:`FrontEnd.correlation`): its
quantities' ``<q>_se_frontend`` and the temperature's share follow from it as every other
component's do. The correlation matters: the temperature's and the losses' errors
correlate by about +0.6 and move the take's temperature in opposite directions (on seed 0's
45 dB crescendo by +0.12 and -0.09 degC per SE), so counted as independent the front end's
share of T was 0.15 degC where the takes' temperatures scatter by 0.07 about their mean. No
window is re-fitted: one residual per window per parameter, on the Jacobians the fit ended
with.

Replaces, for ``estimator: take``, the six sampled windows' own propagation
(:func:`mpipe.inversion.whole_take.shared_errors.frontend_linear`, kept for ``estimator:
window``), whose median shift moved the take's p_m SE by a factor of 2.4 between two
solutions of one take 0.01 SE apart (its windows' local fits each start from the table).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from mpipe.inversion.fit.input_tangents import InputTangents
from mpipe.inversion.pooling.take_system import TakeSystem
from mpipe.inversion.whole_take import frontend_propagation as fp


@dataclass(frozen=True)
class FrontendShares:
    """The take's minimum moved by one SE of each front-end parameter.

    Attributes
    ----------
    names : tuple of str
        The parameters propagated (those with a positive, finite SE), in
        :data:`~mpipe.inversion.whole_take.frontend_propagation.FRONTEND_NAMES` order.
    se : ndarray
        Their standard errors (the front end's units), (J,).
    shifts : ndarray
        Each window's shift per SE over (the fit's names in ln x, T in degC), (J, W, L).
    prior_moved : bool
        The temperature's prior is the front end's temperature, moved with it: its
        variance is counted here.
    failed : tuple of str
        Parameters whose moved take a window's model could not play (their shifts NaN).
    correlation : ndarray or None
        The correlation of the parameters' errors, (J, J) (None: independent).
    """

    names: tuple[str, ...]
    se: np.ndarray
    shifts: np.ndarray
    prior_moved: bool
    failed: tuple[str, ...] = ()
    correlation: np.ndarray | None = None

    def _r(self) -> np.ndarray:
        n = len(self.names)
        return np.eye(n) if self.correlation is None else np.asarray(self.correlation, float)

    def window(self, i: int) -> np.ndarray:
        """Window i's front-end covariance over (names, T), (L, L): ``D^T R D``."""
        d = self.shifts[:, i, :]
        return d.T @ self._r() @ d

    def temperature_se(self) -> float:
        """The front end's share of the take's temperature, degC."""
        if not self.names:
            return 0.0
        d = self.shifts[:, 0, -1]
        return float(math.sqrt(max(d @ self._r() @ d, 0.0)))


def frontend_shares(take, state, blocks, weight: float, front, calibration) -> FrontendShares:
    """The shares (see the module docstring) at the fit's solution.

    Parameters
    ----------
    take : TakeProblem
        The fit's windows and shards (their Jacobians at ``state``).
    state : FitState
        The solution.
    blocks : Blocks
        The windows' blocks there.
    weight : float
        The windows' weight, 1/Pa^2.
    front : FrontEnd
        The front end's estimate and SEs.
    calibration : Calibration
        The instrument (the re-separation's geometry).
    """
    fs = take.problems[0].target.fs
    spans = fp.Spans.of(front, calibration, fs)
    values = take.shards.split(state.values(take.layout, take.problems))
    args = []
    for (lo, hi), v in zip(take.shards.ranges, values, strict=True):
        mine = take.problems[lo:hi]
        a = min(q.start - q.target.p_history.size for q in mine)
        b = max(q.start + q.target.p.size for q in mine)
        # on whole pieces of the take's grid (fp.long_span_changes): the same changes for
        # any sharding of the windows, so 1 and N workers give one answer
        piece = fp.piece_length(spans)
        a, b = (a // piece) * piece, min(-(-b // piece) * piece, len(front.p0))
        # each shard re-separates its own span: p0, u0 over it and its margin travel
        args.append((v, state.t, (a, b), front_slice(front, a, b, spans.margin), spans))
    parts = take.shards.call("frontend", args)
    names = tuple(n for n in fp.FRONTEND_NAMES if n in parts[0])
    n_windows, width = len(take.problems), len(take.layout.names) + 1
    if not names:
        return FrontendShares((), np.zeros(0), np.zeros((0, n_windows, width)), False)
    mean, se_prior = take.prior
    se_t = float(front.level_se[0])
    moved_prior = "temperature" in names and math.isclose(se_prior, se_t, rel_tol=1e-9)
    info = np.array([[1.0 / se_prior**2]])
    notes = np.array([q.note for q in take.problems], dtype=int)
    shifts, failed = [], []
    for name in names:
        grads = np.concatenate([p[name] for p in parts])
        if not np.isfinite(grads).all():
            failed.append(name)
            shifts.append(np.full((n_windows, width), np.nan))
            continue
        d_prior = np.array([-se_t / se_prior**2 if (name == "temperature" and moved_prior)
                            else 0.0])  # fmt: skip
        # a window fitted given the shared unknowns moves only with them (TakeSystem.given)
        system = TakeSystem(take.sizes, notes, weight * blocks.grams, weight * grads, info,
                            d_prior, take.given())  # fmt: skip
        d_fast, d_slow, d_t = system.step(0.0)
        d_t = np.broadcast_to(d_t, (n_windows, 1))
        shifts.append(np.concatenate([d_fast, d_slow[notes], d_t], axis=1))
    se = np.array([float(front.level_se[fp.FRONTEND_NAMES.index(n)]) for n in names])
    return FrontendShares(names, se, np.array(shifts), moved_prior, tuple(failed),
                          front.correlation(names))  # fmt: skip


def front_slice(front, a: int, b: int, margin: int):
    """``front`` over samples ``a..b`` and ``margin`` each side: ``(offset, FrontEnd)``.

    What :func:`~mpipe.inversion.whole_take.frontend_propagation.span_changes` reads for a
    span ``a..b`` (its margin), so the span's changes computed from the slice are those of
    the whole take.
    """
    lo, hi = max(a - margin, 0), min(b + margin, len(front.p0))
    temps = front.temperature_c
    if np.ndim(temps):
        temps = np.asarray(temps[lo:hi], dtype=float)
    part = dataclasses.replace(front, p0=np.asarray(front.p0[lo:hi], dtype=float),
                               u0=np.asarray(front.u0[lo:hi], dtype=float),
                               temperature_c=temps)  # fmt: skip
    return lo, part


def shard_changes(shard, values, t: float, span, sliced, spans) -> dict:
    """:func:`shard_gradients` for the span ``(a, b)``, its changes from ``front_slice``."""
    (a, b), (lo, front) = span, sliced
    changes = fp.long_span_changes(front, shard.spec.calibration, shard.spec.fs, spans,
                                   a - lo, b - lo, origin=lo)  # fmt: skip
    return shard_gradients(shard, values, t, a, changes)


def shard_gradients(shard, values: np.ndarray, t: float, a: int, changes: dict) -> dict:
    """Each of a shard's windows' gradient change ``J^T dr`` per moved front end, (w, L).

    ``shard``: a :class:`mpipe.inversion.whole_take.take_shards.Shard` at the fit's
    solution (its exact Jacobians there). ``changes``: name -> ``(dp, du)``, the change of
    the take's p (Pa) and u (m^3/s) from sample ``a`` on (over every sample the shard's
    windows and their histories read) when that front-end parameter moves by one SE.
    ``dr`` is the window's residual change on its target so moved, to first order, at
    ``values`` on the kernel at the shard's temperature (the Taylor terms in T do not move
    with the target), every change in one run
    (:class:`~mpipe.inversion.fit.input_tangents.InputTangents`; the model run on each
    moved target gave the same to the change's second order); ``J`` the exact Jacobian
    there with T's column. NaN rows: the model cannot play the window.
    """
    names = list(changes)
    out: dict = {name: [] for name in names}
    for i, x in enumerate(values):
        x = np.asarray(x, float)
        r0, j0 = shard.at(i, x)
        _, d_t = shard.in_t(i, r0, t)
        j = np.concatenate([j0, d_t[:, None]], axis=1)
        q, objective = shard.problems[i], shard.objectives[i]
        w = slice(q.start - q.target.p_history.size - a, q.start + q.target.p.size - a)
        dp = np.array([changes[name][0][w] for name in names])
        du = np.array([changes[name][1][w] for name in names])
        found = None
        if names and objective.evaluator is not None:
            found = InputTangents(objective.evaluator, len(names)).responses(
                objective.reed(x), dp, du)  # fmt: skip
        for k, name in enumerate(names):
            bad = found is None or isinstance(found, str) or not np.all(np.isfinite(found[1][k]))
            out[name].append(np.full(j.shape[1], np.nan) if bad else found[1][k] @ j)
    return {name: np.array(rows) for name, rows in out.items()}


def record(shares: FrontendShares, names) -> dict:
    """The shares for the run's record: per parameter its SE and median shift per SE.

    ``dln_<q>`` for the fit's parameters (median over the windows of ``d ln q``; a note
    constant's shift is its note's), ``dT_c`` the temperature's, degC; ``correlation``: the
    parameter's error correlation with each other one.
    """
    out = {}
    r = shares._r()
    for j, name in enumerate(shares.names):
        d = shares.shifts[j]
        entry = {"se": float(shares.se[j])}
        entry.update({f"dln_{n}": float(np.nanmedian(d[:, k])) for k, n in enumerate(names)})
        entry["dT_c"] = float(d[0, -1])
        entry["correlation"] = {o: float(r[j, k]) for k, o in enumerate(shares.names) if k != j}
        out[name] = entry
    return out


__all__ = [
    "FrontendShares",
    "front_slice",
    "frontend_shares",
    "record",
    "shard_changes",
    "shard_gradients",
]
