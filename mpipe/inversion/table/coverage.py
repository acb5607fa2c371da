"""Summary of a take's uncertainty: median, MAD sigma, median SE, determined, coverage.

Over the windows of one status, per parameter and combination: the median estimate, its
scatter between windows (``mad_sigma``: 1.4826 times the median absolute deviation, the
standard deviation of a normal scatter), the median standard error, the fraction of windows
where it is determined and, given the truth, the coverage of the 2-SE interval.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
import pandas as pd

from mpipe.inversion.table.records import flags
from mpipe.inversion.trust.combinations import COMBINATION_NAMES
from mpipe.inversion.trust.uncertainty import SE_PARAMETERS


def summary(
    table: pd.DataFrame,
    truth: Mapping[str, np.ndarray | float] | None = None,
    status: str = "ok",
) -> pd.DataFrame:
    """Per parameter and combination: median, MAD sigma, median SE, determined, coverage.

    Parameters
    ----------
    table : pandas.DataFrame
        Per-window table with the uncertainty columns.
    truth : mapping, optional
        Name -> true value (scalar) or per-window array (same length as ``table``); adds
        the coverage: the fraction of windows whose truth lies within 2 SE of the
        estimate. A window without a valid SE (NaN) counts as not covering; windows with
        an infinite SE (not determined at all) are left out, and a quantity with no
        finite SE has coverage NaN.
    status : str
        Windows of this status are summarised ("ok").

    Returns
    -------
    pandas.DataFrame
        Columns ``name, median, mad_sigma, median_se, median_rel_se, determined_fraction``
        (and ``truth_median, coverage_2se`` with a truth). ``mad_sigma`` is 1.4826 times
        the median absolute deviation over the windows (the standard deviation of a normal
        scatter), in the quantity's unit.
    """
    mask = table["status"] == status if "status" in table else slice(None)
    sel = table[mask]
    rows = []
    for name in (*SE_PARAMETERS, *COMBINATION_NAMES):
        if name not in sel or f"{name}_se" not in sel:
            continue
        x = pd.to_numeric(sel[name], errors="coerce").to_numpy(dtype=float)
        se = pd.to_numeric(sel[f"{name}_se"], errors="coerce").to_numpy(dtype=float)
        if not np.isfinite(se).any() and not np.isinf(se).any():
            continue  # a fixed parameter
        det = flags(sel, f"determined_{name}")
        med = float(np.nanmedian(x)) if x.size else math.nan
        row = {
            "name": name,
            "median": med,
            "mad_sigma": float(1.4826 * np.nanmedian(np.abs(x - med))) if x.size else math.nan,
            "median_se": float(np.median(se)) if se.size else math.nan,
            "median_rel_se": float(np.median(se / np.abs(x))) if x.size else math.nan,
            "determined_fraction": float(det.mean()) if det.size else math.nan,
        }
        if truth is not None and name in truth:
            t = np.broadcast_to(np.asarray(truth[name], dtype=float), np.shape(table[name]))
            t = np.asarray(t)[np.asarray(mask)] if not isinstance(mask, slice) else t
            # An infinite SE (a null direction) covers trivially: such windows are left
            # out. A NaN SE (no valid SE) counts as not covering.
            finite = ~np.isinf(se)
            with np.errstate(invalid="ignore"):
                covered = np.abs(x - t)[finite] <= 2.0 * se[finite]
            row["truth_median"] = float(np.median(t)) if t.size else math.nan
            row["coverage_2se"] = float(np.mean(covered)) if covered.size else math.nan
        rows.append(row)
    return pd.DataFrame(rows)


__all__ = ["summary"]
