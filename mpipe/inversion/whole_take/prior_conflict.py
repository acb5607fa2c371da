"""How far the take's fit leans on its temperature prior: the conflict and the pull.

The take's fit weighs the front end's temperature ``T_p`` (SE ``s_p``) against the reed's
data as one more residual, ``(T - T_p) / s_p``. Two statistics of that one fit say whether
this pseudo-observation is at odds with the rest and how much the results depend on it;
both go to the run's record (``shared_errors.temperature_prior`` of the inversion's
manifest), for the acoustician reading how well the bore model and the microphones agree.

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
finished standard error (every component of the budget in it), that is how far the prior
holds the result from where the reed's data alone put it.

**No verdict.** Neither tells a wrong front end from a bore model that renders the
instrument slightly wrongly: both move the reed's T from the front end's. Measured
(``benchmarks/bench_verdicts.py``, thirteenth session): the air held 3 degC off by a
0.05 degC prior, z -17.6 to -46.1 with pulls 2.6-36 SE (the results wrong); OpenWInD's
tone-hole slur, whose model tone holes put T 2.5 degC low, z -3.8 with a pull of 0.01 SE
at 45 dB but z -37.2 with a pull of 4.9 SE noise-free, its reed right to 0.23 % (held at
the front end's right temperature, the prior is what keeps it right). A temperature the
calibration states wrongly is caught where it is wrong, at the separation
(:class:`mpipe.measurement.separation.drift.PriorConflict`).

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

from mpipe.inversion.pooling.take_system import TakeSystem, pseudo_inverse

log = logging.getLogger(__name__)


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


def prior_figures(table: pd.DataFrame, result: PriorMoves | None) -> dict:
    """The prior's conflict and its largest pull on the finished table, for the record.

    ``table``: the take's finished windows table (``t_start_s``, ``note_number``, each
    result and its combined ``<q>_se``). Returns ``prior_c`` (mean, SE), ``z``,
    ``t_without_c`` (T without the prior), ``largest_pull_se`` and where it is
    (``largest_pull``: the result and its window); empty when ``result`` is None.
    """
    if result is None:
        return {}
    rows = table.set_index("t_start_s")
    moves = result.moves.set_index("t_start_s")
    moves = moves.loc[moves.index.isin(rows.index)]
    names = [n for n in moves.columns if n in rows and f"{n}_se" in rows]
    here = rows.loc[moves.index]
    with np.errstate(divide="ignore", invalid="ignore"):
        relative = np.abs(here[[f"{n}_se" for n in names]].to_numpy(float)
                          / here[names].to_numpy(float))  # fmt: skip
        pulls = np.abs(moves[names].to_numpy(float) / relative)
    pulls = np.where(np.isfinite(pulls), pulls, 0.0)
    top, where = math.nan, ""
    if pulls.size:
        i, j = np.unravel_index(int(np.argmax(pulls)), pulls.shape)
        notes = here["note_number"] if "note_number" in here else pd.Series("?", here.index)
        top = float(pulls[i, j])
        where = f"{names[j]} in the window at {here.index[i]:.3f} s (note {notes.iloc[i]})"
    log.info("temperature prior %.2f +- %.2g degC against the fit's %.3f degC: conflict z "
             "%.3g, T %+.3g degC without it, largest pull %.3g SE (%s)", *result.prior,
             result.t_c, result.z, result.shift_c, top, where)  # fmt: skip
    return {"prior_c": list(result.prior), "z": result.z,
            "t_without_c": result.t_c + result.shift_c, "largest_pull_se": top,
            "largest_pull": where}  # fmt: skip


__all__ = ["PriorConflict", "PriorMoves", "prior_conflict", "prior_figures", "prior_moves"]
