"""The take's temperature prior against its playing: their conflict and its pull on results.

The take's fit weighs the front end's temperature ``T_p`` (SE ``s_p``) against the reed's
data as one more residual, ``(T - T_p) / s_p``. Two statistics of that one fit say whether
this pseudo-observation is at odds with the rest and whether it matters.

**The conflict.** In the fit's linear model, with ``C = R^-1`` the Gauss-Newton covariance
of the shared unknowns (``R``: the take's reduced information, the prior's ``b = 1/s_p^2``
included) and ``c = C_TT``, the fit's ``T`` departs from its prior by
``T - T_p = (1 - b c) (T_d - T_p)``, ``T_d`` the data's own estimate; when both hold,
``T - T_p`` has variance ``s_p^2 - c`` (the prior's variance less the fit's), so
``z = (T - T_p) / sqrt(s_p^2 - c)`` is a standard normal deviate under the model: the
prior-data conflict statistic (Evans & Moshonov 2006).

**The pull.** Leaving the prior out moves the shared unknowns by one Newton step on the
data's cost alone; the prior is rank one, so by the Sherman-Morrison identity

    dx = b (T - T_p) C e_T / (1 - b c),

and every window's controls follow by ``-K_i dx`` (refitted,
:meth:`mpipe.inversion.pooling.take_system.TakeSystem.refitted`). Divided by a result's
standard error (the take's finished one, every component of its budget in it, so that
PASS keeps meaning the results hold within the uncertainty stated for them), that is how
far the prior holds the result from where the data alone put it. A conflict alone is no
wrong result: when the data outweigh the prior the fit follows them and the pull is small
(the independent simulator's tone-hole tube puts ``T`` 2.5 degC below the front end with
the reed right). A pull alone is no wrong result either: a tight prior in agreement with
the data moves the results by chance when left out. Both at once say the results sit
where a temperature the data contradict holds them. On a noise-free take every noise SE
is tiny and any bias of the bore model's T is a conflict: the budget's other components
(the model's rate among them) then decide whether it matters.

References
----------
M. Evans, H. Moshonov, "Checking for prior-data conflict", Bayesian Analysis 1(4), 2006.
R. D. Cook, "Detection of influential observation in linear regression", Technometrics
19(1), 1977 (the change of an estimate when one observation is left out).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.stats import norm

from mpipe.inversion.pooling.take_system import TakeSystem, pseudo_inverse

log = logging.getLogger(__name__)

#: A conflict this improbable under the model (two-sided) counts: the validation's
#: false-alarm rate (``validation.false_alarm``'s default).
CONFLICT_P = 1e-3

#: A result the prior holds more than this many of its standard errors from the data's
#: own estimate is held wrong: a bias of one SE already lifts a result's RMS z to 1.41,
#: beyond what an honest error bar allows (issue 45's [0.8, 1.25]).
PULL_LIMIT = 1.0


@dataclass(frozen=True)
class PriorConflict:
    """The temperature prior's conflict with the data and its pull on the solution.

    Attributes
    ----------
    z : float
        ``(T - T_p) / sqrt(s_p^2 - C_TT)``: standard normal under the model (NaN when the
        data do not inform T).
    shift_c : float
        How far T moves when the prior is left out, degC.
    fast : ndarray
        Each window's fast unknowns' move (ln units), (W, f).
    slow : ndarray
        Each note's slow unknowns' move (ln units), (N, s).
    """

    z: float
    shift_c: float
    fast: np.ndarray
    slow: np.ndarray

    def window(self, system: TakeSystem, i: int) -> np.ndarray:
        """Window i's move over its fast and its note's slow unknowns, (f + s,)."""
        return np.concatenate([self.fast[i], self.slow[int(system.notes[i])]])


def prior_conflict(system: TakeSystem, t_c: float, prior: tuple[float, float]) -> PriorConflict:
    """The prior's conflict and the solution's move without it (see the module docstring).

    Parameters
    ----------
    system : TakeSystem
        The take's weighted normal equations at the solution, the prior included
        (one take unknown: the temperature, degC).
    t_c : float
        The fit's temperature, degC.
    prior : tuple of float
        The prior's mean and standard error, degC.
    """
    mean, se = prior
    f, s = system.sizes.fast, system.sizes.slow
    n_w, n_n = len(system.notes), system.n_notes
    none = PriorConflict(math.nan, 0.0, np.zeros((n_w, f)), np.zeros((n_n, s)))
    if system.sizes.take != 1 or not (math.isfinite(se) and se > 0):
        return none
    cov, _ = pseudo_inverse(system.shared_information())
    t = n_n * s
    c = float(cov[t, t])
    b = 1.0 / se**2
    kept = 1.0 - b * c  # the data's share of T's information
    if not kept > 1e-9:  # the data do not inform T: nothing to contradict
        return none
    z = (t_c - mean) / math.sqrt(se**2 - c)
    dx = b * (t_c - mean) * cov[:, t] / kept
    fast = system.refitted(dx)
    return PriorConflict(float(z), float(dx[t]), fast, dx[:t].reshape(n_n, s))


@dataclass(frozen=True)
class PriorMoves:
    """The prior's conflict and each fitted window's results' moves without it.

    Attributes
    ----------
    z : float
        The conflict statistic (:attr:`PriorConflict.z`).
    shift_c : float
        T's move without the prior, degC.
    prior : tuple of float
        The prior's mean and standard error, degC.
    t_c : float
        The fit's temperature, degC.
    moves : pandas.DataFrame
        One row per fitted window: ``t_start_s`` and the relative move of each result
        (its ln; ``p_M`` that of ``k y_m``).
    """

    z: float
    shift_c: float
    prior: tuple[float, float]
    t_c: float
    moves: pd.DataFrame


def prior_moves(fit, fs: float) -> PriorMoves:
    """:func:`prior_conflict` of a take's fit, per window (``fit``: its ``TakeFit``)."""
    system = fit.system()
    conflict = prior_conflict(system, fit.temperature_c, fit.prior)
    names = list(fit.names)
    moves = np.array([conflict.window(system, i) for i in range(len(fit.problems))])
    moves = moves.reshape(len(fit.problems), len(names))
    frame = pd.DataFrame(moves, columns=names)
    if {"k", "y_m"} <= set(names):  # p_M = k y_m: its ln moves by the sum
        frame["p_M"] = frame["k"] + frame["y_m"]
    frame.insert(0, "t_start_s", [q.start / fs for q in fit.problems])
    return PriorMoves(conflict.z, conflict.shift_c, tuple(fit.prior), fit.temperature_c, frame)


def prior_checks(table: pd.DataFrame, result: PriorMoves | None) -> tuple[tuple, dict]:
    """A reason when the prior contradicts the data and holds a result beyond its SE.

    ``table``: the take's finished windows table (``t_start_s``, ``note_number``, each
    result and its combined ``<q>_se``, every component of the budget in it): a result
    is held wrong when the prior moves it by more than :data:`PULL_LIMIT` of the
    uncertainty the take states for it. Returns the reasons and the figures for the run's
    record (``z``, ``t_without_c``, ``largest_pull_se``; empty when ``result`` is None).
    """
    if result is None:
        return (), {}
    rows = table.set_index("t_start_s")
    moves = result.moves.set_index("t_start_s")
    moves = moves.loc[moves.index.isin(rows.index)]
    names = [n for n in moves.columns if n in rows and f"{n}_se" in rows]
    here = rows.loc[moves.index]
    with np.errstate(divide="ignore", invalid="ignore"):
        relative = np.abs(here[[f"{n}_se" for n in names]].to_numpy(float)
                          / here[names].to_numpy(float))  # fmt: skip
        pulls = moves[names].to_numpy(float) / relative
    notes = here["note_number"] if "note_number" in here else pd.Series("?", index=here.index)
    where = [f"the window at {t:.3f} s (note {n})" for t, n in zip(here.index, notes, strict=True)]
    finite = np.isfinite(pulls)
    top = float(np.max(np.abs(pulls[finite]))) if finite.any() else math.nan
    log.info("temperature prior %.2f +- %.2g degC against the fit's %.3f degC: conflict z "
             "%.3g, T %+.3g degC without it, largest pull %.3g SE", *result.prior, result.t_c,
             result.z, result.shift_c, top)  # fmt: skip
    figures = {"prior_c": list(result.prior), "z": result.z,
               "t_without_c": result.t_c + result.shift_c, "largest_pull_se": top}  # fmt: skip
    return conflict_checks(result.z, pulls, names, where, result.prior, result.t_c), figures


def conflict_checks(z: float, pulls: np.ndarray, names, where, prior, t_c: float) -> tuple:
    """A reason when the prior contradicts the data and holds a result beyond its SE.

    Parameters
    ----------
    z : float
        The conflict statistic (:attr:`PriorConflict.z`).
    pulls : ndarray
        Each window's results' moves without the prior in their standard errors,
        (W, q); NaN: not reported.
    names : sequence of str
        The results' names (q).
    where : sequence of str
        Each window's description, e.g. ``"the window at 0.850 s (note 1)"`` (W).
    prior : tuple of float
        The prior's mean and standard error, degC.
    t_c : float
        The fit's temperature, degC.
    """
    limit = float(norm.isf(CONFLICT_P / 2.0))
    pulls = np.abs(np.asarray(pulls, float))
    pulls = np.where(np.isfinite(pulls), pulls, 0.0)
    if not abs(z) > limit or not pulls.size or not pulls.max() > PULL_LIMIT:
        return ()
    i, j = np.unravel_index(int(np.argmax(pulls)), pulls.shape)
    mean, se = prior
    return (f"the front end's air temperature, {mean:.2f} +- {se:.2g} degC, contradicts the "
            f"reed's data (the take's fit puts the air at {t_c:.2f} degC; conflict z = "
            f"{z:.3g}, |z| > {limit:.2f}) and holds the results where the data do not put "
            f"them: without it {names[j]} would move by {pulls[i, j]:.2g} of its SEs in "
            f"{where[i]}; the temperature, the bore or a microphone's position is not what "
            "the calibration says",)  # fmt: skip


__all__ = ["CONFLICT_P", "PULL_LIMIT", "PriorConflict", "PriorMoves", "conflict_checks",
           "prior_checks", "prior_conflict", "prior_moves"]  # fmt: skip
