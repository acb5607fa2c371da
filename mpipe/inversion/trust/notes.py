"""Each note's result with an uncertainty budget that allows for windows that err together.

A note's value of a quantity q is its value **at the note's centre** (the mean of its ok
windows' times) on the straight line fitted to them in time (:func:`trend_value`): a
crescendo, a diminuendo or a slow drift is the playing, not an error, and the median of the
raw windows, which mpipe <= 0.5 reported, is not the centre's value of a note that changes
(its 2-SE coverage on trending notes was 0.39-0.50, issue 38). With fewer than
:data:`MIN_TREND` windows, or without their times, it is their median. Its standard
uncertainty (GUM JCGM 100:2008: the combined standard uncertainty u_c) is the root sum of
squares of components that behave differently under averaging:

- ``noise`` (Type A): the SE of the line's value at the centre with serially correlated
  residuals. The residuals' lag-1 autocorrelation, corrected for its bias after a line is
  removed (about ``-(2 + 4 rho) / n``), gives an AR(1) ``tau = (1 + rho) / (1 - rho)``;
  the residual variance is taken over ``n - 2 tau`` degrees of freedom, the SE is
  ``sqrt(s^2 tau / n)``, and it is widened by ``t_{0.975, n/tau - 2} / 1.96`` so that
  +-2 SE is a 95 % interval although few windows are independent. Measured on simulated
  notes (:func:`trend_value`'s docstring). Without the times: the SE of a median of a
  serially correlated series, ``1.2533 sigma / sqrt(n_eff)`` (``sigma`` = 1.4826 MAD,
  ``n_eff = n / tau``, Geyer's initial positive sequence,
  :func:`mpipe.core.statistics.integrated_autocorrelation`). Either is never below what
  the windows' own noise implies, ``median(se_noise) / sqrt(n)``: a zero scatter
  (identical windows) does not give +-0. Windows whose own SE of q is infinite (q
  undetermined there, the window ok for its other quantities) are left out of q's value;
- ``model`` (Type B): the model-form error is the same mismatch of the same model in every
  window of a steady note, so it is treated as fully correlated within the note: the
  median of the windows' own ``<q>_se_model``, added once, not divided by sqrt(n);
- ``rate``, ``temperature``, ``frontend``, ``calibration`` (Type B, take-wide): one error
  shared by every window of the take, added once (the median of the windows' values).

With the take's one fit (``inversion.estimator: take``) the windows of a note share its
slow parameters (their ``pooled`` column names them) and carry the joint fit's SE of them:
the note's noise component of such a parameter is that SE, not divided by sqrt(n) again
(:mod:`mpipe.inversion.whole_take.estimator`).

A component whose column is absent from the windows table is absent (NaN) in the note's
budget. Before the per-window budget exists (no ``<q>_se_noise``), the windows' noise SE is
taken as ``<q>_se`` with the shared components present removed in quadrature.

See docs/uncertainty.md, "A note's value and its uncertainty".
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pandas as pd
from scipy.stats import t as student_t

from mpipe.core.statistics import integrated_autocorrelation
from mpipe.inversion.trust.combinations import COMBINATION_NAMES

#: Components added once per note (take-wide, or the model form shared within a note).
SHARED = ("rate", "temperature", "frontend", "calibration")
#: Every component of a note's budget, in the order of the windows' (the convention).
NOTE_COMPONENTS = ("noise", "model", *SHARED)
#: Quantities with a note-level budget (the reed's searched parameters and combinations).
BUDGETED = ("k", "S", "y_m", "p_m", "m", "g", "lam", "k_c", *COMBINATION_NAMES)
#: The SE of a median over the SE of a mean for Gaussian scatter: sqrt(pi / 2).
MEDIAN_EFFICIENCY = math.sqrt(math.pi / 2)
#: Fewest windows whose scatter is trusted (fewer: the windows' own noise SE alone).
MIN_SCATTER = 4
#: Fewest windows whose value is read off a fitted line (fewer: their median).
MIN_TREND = MIN_SCATTER + 2
#: Largest lag-1 autocorrelation credited to a note's window series (tau = 39).
MAX_RHO = 0.95
#: Quantities summarised per segment by :func:`segment_summary`.
SUMMARISED = ("p_m", "p_M", "gamma", "zeta", "k", "S", "y_m", "lam", "m", "g", "k_c",
              "h_mean", "closed_fraction")  # fmt: skip


def _numbers(table: pd.DataFrame, column: str) -> np.ndarray:
    if column not in table:
        return np.full(len(table), np.nan)
    return pd.to_numeric(table[column], errors="coerce").to_numpy(dtype=float)


def window_noise_se(table: pd.DataFrame, name: str) -> np.ndarray:
    """Each window's statistical (noise) SE of ``name``, same unit.

    ``<name>_se_noise`` when the windows carry the budget; else ``<name>_se`` with the
    shared components present removed in quadrature (never below 0).
    """
    if f"{name}_se_noise" in table:
        return _numbers(table, f"{name}_se_noise")
    total = _numbers(table, f"{name}_se") ** 2
    for comp in ("model", *SHARED):
        shared = _numbers(table, f"{name}_se_{comp}")
        total = total - np.where(np.isfinite(shared), shared, 0.0) ** 2
    return np.sqrt(np.maximum(total, 0.0))


def trend_value(x: np.ndarray, t: np.ndarray, floor: float = 0.0) -> tuple[float, float, float]:
    """The value at the centre of a line fitted in time, its SE with AR(1) residuals, n_eff.

    Parameters
    ----------
    x : ndarray
        The windows' values in time order (finite), any unit; at least :data:`MIN_TREND`.
    t : ndarray
        Their times, s (not all equal).
    floor : float
        Lower bound of the SE (the windows' own noise over sqrt(n)); NaN: none.

    Returns
    -------
    (value, se, n_eff)
        The least-squares line's value at ``mean(t)``; its SE (see the module docstring);
        ``n / tau``.

    Notes
    -----
    Measured on 1000 simulated notes per case (slopes of 2-10 window SDs over the note,
    AR(1) window errors, no shared term; ``tests/inversion/trust/test_notes.py``): the
    2-SE coverage is 0.90-0.97 for 20-80 windows and rho 0-0.6 (0.91 at 40 windows and
    rho 0.8); it falls to 0.84 with 10 windows and rho 0.6 (a lag-1 estimate from 10
    residuals is poor). The median of mpipe <= 0.5 covered 0.39-0.50.
    """
    x = np.asarray(x, dtype=float)
    t = np.asarray(t, dtype=float)
    n = x.size
    design = np.column_stack([np.ones(n), t - t.mean()])
    coef, *_ = np.linalg.lstsq(design, x, rcond=None)
    resid = x - design @ coef
    ss = float(np.sum(resid**2))
    rho = float(np.sum(resid[1:] * resid[:-1]) / ss) if ss > 0 else 0.0
    # removing a line biases the lag-1 estimate low by about (2 + 4 rho) / n
    rho = min(max(rho + (2.0 + 4.0 * max(rho, 0.0)) / n, 0.0), MAX_RHO)
    tau = (1.0 + rho) / (1.0 - rho)
    s2 = ss / max(n - 2.0 * tau, 1.0)
    n_eff = n / tau
    t_factor = float(student_t.ppf(0.975, max(n_eff - 2.0, 1.0))) / 1.959964
    se = math.sqrt(s2 * tau / n) * t_factor
    return float(coef[0]), (se if math.isnan(floor) else max(se, floor)), n_eff


def scatter_se(
    x: np.ndarray, floor: float = 0.0, t: np.ndarray | None = None
) -> tuple[float, float]:
    """SE of the median of a serially correlated window series, and its n_eff.

    Parameters
    ----------
    x : ndarray
        The windows' values in time order (finite), any unit.
    floor : float
        Lower bound of the SE, same unit (the windows' own noise over sqrt(n)).
    t : ndarray, optional
        The windows' times, s: the scatter is then taken about the straight line through
        them (a crescendo's steady change is the playing, not an error of the windows);
        with fewer than ``MIN_SCATTER + 2`` windows, about the median.

    Returns
    -------
    (se, n_eff)
        ``max(1.2533 sigma / sqrt(n_eff), floor)`` (a NaN floor is no floor, an infinite
        one an undetermined quantity); with fewer than :data:`MIN_SCATTER` values,
        ``floor`` and ``n_eff = n``.
    """
    x = np.asarray(x, dtype=float)
    n = x.size
    if n < MIN_SCATTER:
        return (floor if n else math.nan), float(n)
    resid = x - np.median(x)
    if t is not None and n >= MIN_SCATTER + 2 and np.ptp(t) > 0:
        resid = x - np.polyval(np.polyfit(t, x, 1), t)
    sigma = 1.4826 * float(np.median(np.abs(resid - np.median(resid))))
    tau = integrated_autocorrelation(resid)
    n_eff = n / max(tau, 1.0)
    se = MEDIAN_EFFICIENCY * sigma / math.sqrt(n_eff)
    return (se if math.isnan(floor) else max(se, floor)), n_eff


def _median(values: np.ndarray) -> float:
    v = values[np.isfinite(values)]
    return float(np.median(v)) if v.size else math.nan


def _shared(windows: pd.DataFrame, name: str) -> bool:
    """Whether every window shares ``name`` with its note (``pooled``: the take's one fit)."""
    if "pooled" not in windows or not len(windows):
        return False
    return all(name in str(v).split(";") for v in windows["pooled"])


def note_budget(windows: pd.DataFrame, name: str) -> dict[str, float]:
    """One note's value of ``name`` and its budget, from the note's ok windows in time order.

    Returns
    -------
    dict
        ``<name>_median``, ``<name>_se`` (combined), ``<name>_se_<component>`` for
        :data:`NOTE_COMPONENTS` (NaN when the windows do not carry that component),
        ``<name>_n_eff`` (effective number of independent windows) and
        ``<name>_window_se`` (median of the windows' own combined SE).
    """
    x = _numbers(windows, name)
    all_noise = window_noise_se(windows, name)
    keep = np.isfinite(x)
    if np.any(keep & np.isfinite(all_noise)):
        # a window that does not determine q (SE inf) is ok for its other quantities
        keep &= ~np.isinf(all_noise)
    x = x[keep]
    noise = all_noise[keep]
    # inf (undetermined) counts: a quantity no window determines has no finite SE
    known = noise[~np.isnan(noise)]
    floor = float(np.median(known)) / math.sqrt(x.size) if known.size else math.nan
    t = _numbers(windows, "t_start_s")[keep] if "t_start_s" in windows else None
    value = float(np.median(x)) if x.size else math.nan
    if t is not None and x.size >= MIN_TREND and np.ptp(t) > 0 and not np.isinf(floor):
        value, se_noise, n_eff = trend_value(x, t, floor)
    else:
        se_noise, n_eff = scatter_se(x, floor, t) if x.size else (math.nan, 0.0)
    out = {f"{name}_median": value}
    if x.size and _shared(windows[keep], name):
        # one joint fit gave every window the note's value and its SE: not a mean of n
        se_noise, n_eff = (float(np.median(known)) if known.size else math.nan), float(x.size)
    comps = {"noise": se_noise}
    for comp in ("model", *SHARED):
        col = f"{name}_se_{comp}"
        comps[comp] = _median(_numbers(windows, col)[keep]) if col in windows else math.nan
    present = [v for v in comps.values() if not math.isnan(v)]
    total = math.sqrt(sum(v * v for v in present)) if present else math.nan
    if math.isnan(comps["noise"]):
        total = math.nan  # no statistical part: no combined SE
    out[f"{name}_se"] = total
    out.update({f"{name}_se_{c}": v for c, v in comps.items()})
    if f"{name}_se_scale" in windows:
        # the absolute scale's assumed share (an unstated calibration): beside the budget
        out[f"{name}_se_scale"] = _median(_numbers(windows, f"{name}_se_scale")[keep])
    out[f"{name}_n_eff"] = n_eff
    out[f"{name}_window_se"] = _median(_numbers(windows, f"{name}_se")[keep])
    return out


def note_summary(
    segments: pd.DataFrame, table: pd.DataFrame, quantities: Sequence[str] = BUDGETED
) -> pd.DataFrame:
    """Each segment's windows, ok windows, and per quantity its median and budget.

    Parameters
    ----------
    segments : pandas.DataFrame
        Segment table (``segment`` column).
    table : pandas.DataFrame
        Windows table with ``segment``, ``status`` and the quantities (their ``_se`` and
        ``_se_<component>`` columns where present), in time order.
    quantities : sequence of str
        Quantities to summarise (those absent from ``table`` are skipped).

    Returns
    -------
    pandas.DataFrame
        ``segments`` with ``windows``, ``ok_windows`` and, per quantity, the columns of
        :func:`note_budget` (``<q>_median`` is the note's value; ``<q>_se`` its combined
        standard uncertainty).
    """
    out = segments.copy()
    seg = table["segment"] if "segment" in table else pd.Series(0, index=table.index)
    ok = table["status"].astype(str) == "ok"
    if "t_start_s" in table:
        order = np.argsort(table["t_start_s"].to_numpy(float), kind="stable")
        table, seg, ok = table.iloc[order], seg.iloc[order], ok.iloc[order]
    out["windows"] = [int((seg == g).sum()) for g in out["segment"]]
    out["ok_windows"] = [int(((seg == g) & ok).sum()) for g in out["segment"]]
    rows = []
    for g in out["segment"]:
        sel = table[((seg == g) & ok).to_numpy()]
        row: dict[str, float] = {}
        for name in quantities:
            if name in table:
                row.update(note_budget(sel, name))
        rows.append(row)
    budget = pd.DataFrame(rows, index=out.index)
    return pd.concat([out, budget], axis=1)


def segment_summary(segments: pd.DataFrame, table: pd.DataFrame) -> pd.DataFrame:
    """Each segment's own result: windows, ok windows, and per quantity its value and budget.

    For each quantity of :data:`SUMMARISED` (and f_r, Q_r) over the segment's ``ok``
    windows: ``<name>_median`` (the note's value), ``<name>_se`` (its combined standard
    uncertainty: the windows' scatter with their serial correlation, never below their own
    noise over sqrt(n), and the model-form and take-wide components added once), the
    components ``<name>_se_<component>``, ``<name>_n_eff`` and ``<name>_window_se`` (the
    median of the windows' own SE); see :func:`note_summary`.

    Parameters
    ----------
    segments : pandas.DataFrame
        :func:`mpipe.inversion.preparation.segments.segment_take`'s table.
    table : pandas.DataFrame
        Windows table with a ``segment`` column.

    Returns
    -------
    pandas.DataFrame
        ``segments`` with ``windows, ok_windows`` and the columns above.
    """
    return note_summary(segments, table, (*SUMMARISED, "f_r", "Q_r"))


__all__ = [
    "BUDGETED",
    "MEDIAN_EFFICIENCY",
    "MIN_SCATTER",
    "NOTE_COMPONENTS",
    "SHARED",
    "SUMMARISED",
    "MIN_TREND",
    "note_budget",
    "note_summary",
    "scatter_se",
    "segment_summary",
    "trend_value",
    "window_noise_se",
]
