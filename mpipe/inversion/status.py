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
``high-residual``
    The relative residual ||p - p_model|| / ||p|| exceeds ``residual_factor`` times the
    take's best: the model fits this window far worse than others of the same take, so it
    probably sits in another local minimum or the window is not steady. For a window softer
    than the best one (an attack, a release, a diminuendo) the take's best is taken at the
    noise floor: its smallest residual in Pa (``f2``) over the window's own ||p||, when that
    is larger (at most ``residual_factor`` times the best), so a window is not flagged for
    being soft, while one that holds little but noise still is. A window is high-residual
    too when its relative residual exceeds ``residual_limit`` whatever the take's best: the
    model does not play what was played (a whole take in a wrong basin has no better window
    to compare with).

``status_reason`` lists every check that failed, so a window can be both not converged and
at a bound.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from mpipe.inversion.settings import InversionConfig

#: The statuses, best first.
STATUSES = ("ok", "high-residual", "low-dof", "no-errors", "at-bound", "not-converged", "failed")


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
        if name == "y_m" and config.contact == "fixed":
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
            at_yc = name == "y_m" and config.contact == "fixed" and lo <= config.y_c * (1 + 2e-6)
            hits.append(f"{name}={'y_c' if at_yc else 'lower'}")
        elif math.log(hi / value) < tol:
            hits.append(f"{name}=upper")
    return hits


def window_status(row: dict) -> tuple[str, str]:
    """Provisional status of one window from its own row (no comparison with the take).

    Parameters
    ----------
    row : dict
        A row with ``error``, ``optimiser_converged``, ``optimiser_message``,
        ``at_bound`` and, when the window has been through the error analysis, ``dof``
        (NaN: no standard errors) and ``uncertainty_note``.

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
            reasons.append(
                f"n_eff - p = {dof:.3g} < 1: the residual cannot measure the noise, SEs rough"
            )
    return status, "; ".join(reasons)


def _number(value) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def classify(table: pd.DataFrame, config: InversionConfig) -> pd.DataFrame:
    """Final status of every window of a take, comparing its residual with the take's best.

    Parameters
    ----------
    table : pandas.DataFrame
        Per-window rows (``error``, ``optimiser_converged``, ``optimiser_message``,
        ``at_bound``, ``relative_residual``).
    config : InversionConfig
        ``residual_factor``.

    Returns
    -------
    pandas.DataFrame
        A copy with ``status`` and ``status_reason`` set.
    """
    out = table.copy()
    provisional = [window_status(r) for r in out.to_dict("records")]
    status = [s for s, _ in provisional]
    reasons = [r for _, r in provisional]
    rr = pd.to_numeric(out["relative_residual"], errors="coerce").to_numpy(dtype=float)
    f2 = (
        pd.to_numeric(out["f2"], errors="coerce").to_numpy(dtype=float)
        if "f2" in out
        else np.full(rr.size, np.nan)
    )
    clean = np.array([s == "ok" for s in status])
    use = clean if clean.any() else np.array([s != "failed" for s in status])
    pool = rr[use][np.isfinite(rr[use])]
    floor = f2[use][np.isfinite(f2[use])]
    best = float(pool.min()) if pool.size else math.nan
    # the residual a window may have: the take's best relative residual at its own level,
    # and never less than the take's smallest residual in Pa (the noise floor: a soft
    # window of an attack or a release is not worse for being soft)
    with np.errstate(invalid="ignore", divide="ignore"):
        norm_p = f2 / rr
    allowed = np.where(
        np.isfinite(norm_p) & (floor.size > 0),
        np.maximum(best, (floor.min() if floor.size else 0.0) / norm_p),
        best,
    )
    # at most residual_factor x the best: a window so soft that noise is all it holds
    # (the first periods of an attack) determines nothing and is not ok
    allowed = np.minimum(allowed, config.residual_factor * best)
    for i, value in enumerate(rr):
        if status[i] == "failed":
            continue
        why = ""
        if value > config.residual_limit:
            why = (
                f"relative residual {value:.3g} > inversion.residual_limit "
                f"{config.residual_limit:g}: the model does not play what was played"
            )
        elif value > config.residual_factor * allowed[i]:
            floor_note = "" if allowed[i] == best else " (its noise floor at this level)"
            why = (
                f"relative residual {value:.3g} > {config.residual_factor:g} x the take's "
                f"best {allowed[i]:.3g}{floor_note}"
            )
        if why:
            reasons[i] = "; ".join(r for r in (reasons[i], why) if r)
            status[i] = "high-residual" if status[i] == "ok" else status[i]
    out["status"] = status
    out["status_reason"] = reasons
    return out


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
    "STATUSES",
    "classify",
    "count",
    "on_bounds",
    "search_bounds",
    "summary_line",
    "window_status",
]
