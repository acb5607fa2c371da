"""The status of each inverted window: ok, or why its numbers should not be trusted.

A window is ``ok`` only when the search met its tolerance and the solution passes the
sanity checks. Otherwise, in order of precedence:

``failed``
    No estimate (the window could not be inverted; ``error`` says why).
``not-converged``
    The search stopped on its evaluation budget, not on its tolerance.
``at-bound``
    A free parameter sits on a search bound, or the rest opening y_m on the contact point
    y_c (the reed model needs y_m > y_c): the estimate is set by the bound, not the data.
``no-errors``
    The estimate has no standard errors: its Jacobian or residual was not finite, or the
    SVD of the Jacobian did not converge (``uncertainty_note`` says which).
``low-dof``
    The residual is so coloured that it carries fewer effective samples than one more
    than the free parameters (``dof = n_eff - p < 1``): it cannot measure the noise, and
    the standard errors, computed with one degree of freedom, are rough.
``undetermined``
    None of the window's p_m and p_M (those searched) has a finite within-take standard
    error (noise and model form, :func:`mpipe.inversion.trust.budget.within_take`): the
    data determine neither. "Undetermined" belongs to the quantity: a window whose p_M
    alone has no finite SE stays ``ok`` for its p_m (``determined_p_M`` is false and
    ``status_reason`` names p_M), and a take-wide component (rate, temperature, front end,
    calibration) never makes a window undetermined (issue 38).
``high-residual``
    The window's residual is not explained by its noise plus its note's own model-form
    level. Each window's residual is split at the note's harmonics
    (:mod:`mpipe.inversion.trust.harmonics`): ``noise_residual`` is the relative residual its
    noise alone leaves, ``model_residual`` the relative misfit at the harmonics beyond it.
    Over the windows of a note (``segment``; the take when the note has fewer than
    :data:`MIN_NOTE` windows) the model-form level is robust: its median M and
    ``1.4826 MAD`` s. A window is high-residual when its ``model_residual`` exceeds
    ``residual_factor`` x M, M + :data:`MAD_FACTOR` s, and its own ``noise_residual``: the
    model fits it worse than the note's other windows by more than the noise can explain.
    Both sides scale alike with the model's own misfit (which moves with the sample rate),
    so the rule does not. A window is high-residual too when its relative residual
    ``||p - p_model|| / ||p||`` exceeds ``residual_limit``: the model does not play what was
    played (a whole note in a wrong basin has no better window to compare with). And a
    window is high-residual when its relative residual exceeds ``residual_factor`` x that of
    a neighbour of its note (the window before or after it): a model mismatch changes
    smoothly from window to window, a wrong basin does not. Two guards keep the
    comparison from firing on a window that merely sits beside an unusually good one:
    the difference of the two residuals must exceed :data:`NEIGHBOUR_SD` times its sampling
    standard deviation
    (a residual of ``n_eff`` effective samples has a relative SD of ``1 / sqrt(2 n_eff)``),
    and another minimum must show in the estimates: p_m or p_M must differ from the
    neighbour's by more than :data:`NEIGHBOUR_SE` within-take SEs of the difference
    (when both have finite SEs). This catches a wrong minimum
    whose misfit falls between the measured harmonics (the model's period differs), where
    the split counts it as noise, and a note with too few windows for a robust level.

``status_reason`` lists every check that failed, so a window can be both not converged and
at a bound.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from mpipe.inversion.settings import InversionConfig
from mpipe.inversion.trust.budget import within_take

#: The statuses, best first.
STATUSES = (
    "ok",
    "high-residual",
    "undetermined",
    "low-dof",
    "no-errors",
    "at-bound",
    "not-converged",
    "failed",
)

#: A note with fewer windows than this is judged with the take's windows.
MIN_NOTE = 4

#: Robust standard deviations (1.4826 MAD) above the note's median model-form level.
MAD_FACTOR = 5.0
#: Sampling SDs by which a residual must exceed ``residual_factor`` x its neighbour's.
NEIGHBOUR_SD = 3.0
#: Within-take SEs of the difference by which a window's p_m or p_M must differ from its
#: neighbour's to be another minimum (a wrong basin in the batch test moved p_m by 15 %,
#: hundreds of SEs; a steady clean note's window at +0.05 % was flagged by the residual
#: ratio alone, issue 38).
NEIGHBOUR_SE = 4.0


def required_quantities(config: InversionConfig) -> tuple[str, ...]:
    """The reported quantities a window must give a finite SE to be ok: p_m and p_M if searched."""
    free = set(config.search_parameters)
    out = ["p_m"] if "p_m" in free else []
    if free & {"k", "y_m"}:
        out.append("p_M")
    return tuple(out)


def search_bounds(config: InversionConfig, max_p: float) -> np.ndarray:
    """Search bounds of the free parameters in SI units, shape ``(n_free, 2)``.

    With ``contact: fixed`` the lower bound of y_m is raised to just above y_c: the contact
    must begin before closure. The parameters are those of ``config.search_parameters``.

    Parameters
    ----------
    config : InversionConfig
        Free parameters and their configured bounds.
    max_p : float
        Largest pressure over the window, Pa (scales the p_m bounds).

    Returns
    -------
    ndarray

    Raises
    ------
    ValueError
        When ``max_p`` is not positive (the p_m bounds scale with it).
    """
    if not max_p > 0:
        raise ValueError(
            f"max p over the window is {max_p:g} Pa; expected > 0 (a silent or unplayed window)"
        )
    rows = []
    for name in config.search_parameters:
        lo, hi = config.bounds.absolute(name, max_p)
        if name == "y_m" and config.law == "fixed":
            lo = max(lo, config.y_c * (1 + 1e-6))
        rows.append((lo, hi))
    return np.array(rows, dtype=float)


def on_bounds(values: dict, bounds: np.ndarray, config: InversionConfig) -> list[str]:
    """Free parameters within ``config.bound_tolerance`` (log distance) of a bound.

    Parameters
    ----------
    values : dict
        Searched parameter name to value (SI units), in the order of
        ``config.search_parameters``.
    bounds : ndarray
        Bounds from :func:`search_bounds`.
    config : InversionConfig
        Tolerance and y_c.

    Returns
    -------
    list of str
        Entries such as ``"m=lower"``, ``"p_m=upper"`` or ``"y_m=y_c"``.
    """
    tol = config.bound_tolerance
    hits = []
    for (name, value), (lo, hi) in zip(values.items(), bounds, strict=True):
        if math.log(value / lo) < tol:
            at_yc = name == "y_m" and config.law == "fixed" and lo <= config.y_c * (1 + 2e-6)
            hits.append(f"{name}={'y_c' if at_yc else 'lower'}")
        elif math.log(hi / value) < tol:
            hits.append(f"{name}=upper")
    return hits


def window_status(row: dict, required: tuple[str, ...] = ("p_m", "p_M")) -> tuple[str, str]:
    """Provisional status of one window from its own row (no comparison with the take).

    Parameters
    ----------
    row : dict
        A row with ``error``, ``optimiser_converged``, ``optimiser_message``,
        ``at_bound`` and, when the window has been through the error analysis, ``dof``
        (NaN: no standard errors), ``uncertainty_note`` and the ``<q>_se``.
    required : tuple of str
        Quantities whose combined SE must be finite (:func:`required_quantities`).

    Returns
    -------
    (status, reason)
    """
    if row.get("error"):
        return "failed", str(row["error"])
    reasons = []
    status = "ok"
    if not row.get("optimiser_converged"):
        status = "not-converged"
        reasons.append(f"search stopped: {row.get('optimiser_message') or 'budget spent'}")
    if row.get("at_bound"):
        status = "at-bound" if status == "ok" else status
        reasons.append(f"on a bound: {row['at_bound'].replace(';', ', ')}")
    if "dof" in row:
        dof = _number(row["dof"])
        if not math.isfinite(dof):
            status = "no-errors" if status == "ok" else status
            note = str(row.get("uncertainty_note") or "no standard errors")
            reasons.append(note if note.startswith("no standard errors") else
                           f"no standard errors: {note}")  # fmt: skip
        elif dof < 1:
            status = "low-dof" if status == "ok" else status
            reasons.append(f"dof = {dof:.3g} < 1: the residual cannot measure the noise, SEs rough")
        if math.isfinite(dof):
            bad = [q for q in required if not math.isfinite(within_take(row, q))]
            if bad and len(bad) == len(required):
                status = "undetermined" if status == "ok" else status
            if bad:
                reasons.append(
                    f"no finite within-take standard error for {', '.join(bad)}: "
                    "not determined by the data"
                    + ("" if len(bad) == len(required) else
                       f" (the window's {', '.join(q for q in required if q not in bad)} stands)")
                )  # fmt: skip
    return status, "; ".join(reasons)


def _number(value) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def classify(table: pd.DataFrame, config: InversionConfig, segments=None) -> pd.DataFrame:
    """Final status of every window of a take, judging its residual against its note's.

    Parameters
    ----------
    table : pandas.DataFrame
        Per-window rows (``error``, ``optimiser_converged``, ``optimiser_message``,
        ``at_bound``, ``relative_residual``, and ``model_residual``, ``noise_residual``
        where the residual was split at the harmonics).
    config : InversionConfig
        ``residual_factor``, ``residual_limit`` and the searched parameters.
    segments : sequence of int, optional
        Each row's note (default: the table's ``segment`` column, else one note).

    Returns
    -------
    pandas.DataFrame
        A copy with ``status`` and ``status_reason`` set.
    """
    out = table.copy()
    required = required_quantities(config)
    provisional = [window_status(r, required) for r in out.to_dict("records")]
    status = [s for s, _ in provisional]
    reasons = [r for _, r in provisional]
    rr = _column(out, "relative_residual")
    allowed = _allowed_model_residual(out, status, config, segments)
    neighbour, nearest = _neighbour_residual(rr, status, out, segments)
    records = out.to_dict("records")
    n_eff = _column(out, "n_eff")
    mr, nr = _column(out, "model_residual"), _column(out, "noise_residual")
    for i, value in enumerate(rr):
        if status[i] == "failed":
            continue
        why = ""
        if value > config.residual_limit:
            why = (
                f"relative residual {value:.3g} > inversion.residual_limit "
                f"{config.residual_limit:g}: the model does not play what was played"
            )
        elif mr[i] > allowed[i] and mr[i] > nr[i]:
            why = (
                f"model-form residual {mr[i]:.3g} > {allowed[i]:.3g}, its note's level "
                f"(max of {config.residual_factor:g} x median, median + {MAD_FACTOR:g} MAD), "
                f"and > its noise residual {nr[i]:.3g}"
            )
        elif value > config.residual_factor * neighbour[i] and _another_minimum(
            records, i, nearest[i], required, n_eff, rr
        ):
            why = (
                f"relative residual {value:.3g} > {config.residual_factor:g} x its neighbour's "
                f"{neighbour[i]:.3g} in the note: another minimum"
            )
        if why:
            reasons[i] = "; ".join(r for r in (reasons[i], why) if r)
            status[i] = "high-residual" if status[i] == "ok" else status[i]
    out["status"] = status
    out["status_reason"] = reasons
    return out


def _column(table: pd.DataFrame, name: str) -> np.ndarray:
    if name not in table:
        return np.full(len(table), np.nan)
    return pd.to_numeric(table[name], errors="coerce").to_numpy(dtype=float)


def _neighbour_residual(rr, status, table, segments) -> tuple[np.ndarray, np.ndarray]:
    """Each window's neighbour in its note with the smaller relative residual.

    Returns that residual (inf: none) and the neighbour's row (-1: none).
    """
    if segments is None:
        segments = table["segment"] if "segment" in table else np.zeros(len(table), dtype=int)
    seg = pd.to_numeric(pd.Series(list(segments)), errors="coerce").fillna(-1).to_numpy()
    usable = np.array([s != "failed" for s in status]) & np.isfinite(rr)
    out = np.full(rr.size, np.inf)
    which = np.full(rr.size, -1)
    for i in range(rr.size):
        for j in (i - 1, i + 1):
            if 0 <= j < rr.size and usable[j] and seg[j] == seg[i] and rr[j] < out[i]:
                out[i], which[i] = rr[j], j
    return out, which


def _another_minimum(records, i, j, required, n_eff, rr) -> bool:
    """Whether window i is in another minimum than its better neighbour j.

    Its residual above j's must be beyond their sampling noise and its estimates must
    differ from j's beyond their SEs (see the module docstring).
    """
    if j < 0:
        return False
    # the relative residual of n_eff effective samples has a relative SD 1 / sqrt(2 n_eff)
    sd = math.hypot(rr[i], rr[j]) / math.sqrt(2.0 * max(n_eff[i], 1.0))
    if math.isfinite(sd) and rr[i] - rr[j] <= NEIGHBOUR_SD * sd:
        return False
    jumps = []
    for q in required:
        xi, xj = _number(records[i].get(q)), _number(records[j].get(q))
        se = math.hypot(within_take(records[i], q), within_take(records[j], q))
        if math.isfinite(xi) and math.isfinite(xj) and math.isfinite(se) and se > 0:
            jumps.append(abs(xi - xj) / se)
    # without SEs the residual alone decides (the rule as it was)
    return not jumps or max(jumps) > NEIGHBOUR_SE


def _allowed_model_residual(table, status, config, segments) -> np.ndarray:
    """The model-form residual each window's note allows (NaN: no judgement)."""
    mr = _column(table, "model_residual")
    if segments is None:
        segments = table["segment"] if "segment" in table else np.zeros(len(table), dtype=int)
    seg = pd.to_numeric(pd.Series(list(segments)), errors="coerce").fillna(-1).to_numpy()
    usable = np.array([s != "failed" for s in status]) & np.isfinite(mr)
    factor = config.residual_factor
    take = robust_level(mr[usable], factor) if usable.any() else math.nan
    allowed = np.full(mr.size, np.nan)
    for g in np.unique(seg):
        mine = seg == g
        pool = mr[mine & usable]
        allowed[mine] = robust_level(pool, factor) if pool.size >= MIN_NOTE else take
    return allowed


def robust_level(values: np.ndarray, factor: float) -> float:
    """The level a note's windows allow: ``max(factor x median, median + MAD_FACTOR s)``.

    ``s`` is the robust standard deviation ``1.4826 MAD`` of ``values``; the unit is theirs.
    """
    values = np.asarray(values, dtype=float)
    median = float(np.median(values))
    spread = 1.4826 * float(np.median(np.abs(values - median)))
    return max(factor * median, median + MAD_FACTOR * spread)


def count(table: pd.DataFrame) -> dict[str, int]:
    """Windows per status, every status listed (zero included), best first."""
    values = table["status"].value_counts() if "status" in table else pd.Series(dtype=int)
    return {s: int(values.get(s, 0)) for s in STATUSES}


def summary_line(table: pd.DataFrame) -> str:
    """One line such as ``"12 windows: 10 ok, 1 at-bound, 1 high-residual"``."""
    counts = count(table)
    parts = [f"{n} {s}" for s, n in counts.items() if n]
    return f"{len(table)} windows: " + ", ".join(parts) if parts else "0 windows"


__all__ = [
    "MAD_FACTOR",
    "MIN_NOTE",
    "NEIGHBOUR_SD",
    "NEIGHBOUR_SE",
    "STATUSES",
    "classify",
    "count",
    "on_bounds",
    "required_quantities",
    "robust_level",
    "search_bounds",
    "summary_line",
    "window_status",
]
