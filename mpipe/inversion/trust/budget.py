"""The uncertainty budget of every reported quantity: its components and their combination.

For each quantity q (the parameters of :data:`mpipe.inversion.trust.uncertainty.SE_PARAMETERS`
and the combinations of :data:`mpipe.inversion.trust.combinations.COMBINATION_NAMES`) the windows
table holds one column per component, ``<q>_se_<component>`` (q's unit), and the combined
standard uncertainty ``<q>_se`` (GUM u_c, JCGM 100:2008 section 5.1: the components are
taken as uncorrelated):

    u_c(q) = sqrt(sum over the components that apply of u_i(q)^2).

The combination is done here only (:func:`combine`, :func:`combine_row`). A component adds
its columns before the combination runs and its name to :data:`COMPONENTS` (the order of
the shared convention: noise, model, rate, temperature, frontend, calibration).

What a value of a component column means:

- finite: its standard uncertainty;
- NaN: the component does not apply to this window or quantity (not fitted, not measured,
  the column absent), and is left out; but a NaN **noise** component means the window has
  no standard error at all (a fixed parameter, a failed window, an estimate on a bound),
  and the combined one is NaN too;
- inf: the data do not determine q; the combined one is inf.

Take-wide components (rate, temperature, and those of the front end and the calibration)
are the same for every window of a take: pooling windows into a note must add them once,
never divide them by sqrt(n). They are not the window's: a window's status and its
``determined_<q>`` judge the **within-take** uncertainty (:data:`WITHIN_TAKE`, noise and
model form, :func:`within_take`), so no quantity is called undetermined because of an error
every window of the take shares (issue 38).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, MutableMapping

import numpy as np
import pandas as pd

from mpipe.inversion.trust.combinations import COMBINATION_NAMES
from mpipe.inversion.trust.uncertainty import SE_PARAMETERS

#: The components, in the shared convention's order (add a new one at its place).
COMPONENTS = (
    "noise",
    "model",
    "rate",
    "temperature",
    "frontend",
    "calibration",
)

#: The quantities that carry a budget, in the table's order.
QUANTITIES = (*SE_PARAMETERS, *COMBINATION_NAMES)

#: Components computed per window (the others are shared by a take or a note).
WINDOW_COMPONENTS = ("noise", "model")
#: The components a window's status and ``determined_<q>`` judge: the within-take ones.
WITHIN_TAKE = WINDOW_COMPONENTS


def component_column(quantity: str, component: str) -> str:
    """Name of the column of ``quantity``'s ``component``: ``<q>_se_<component>``."""
    return f"{quantity}_se_{component}"


def combined(components: Mapping[str, float]) -> float:
    """Root-sum-square of one quantity's components (see the module docstring for NaN/inf).

    Parameters
    ----------
    components : mapping
        Component name -> standard uncertainty (q's unit); missing or NaN: does not apply,
        except ``noise``, whose NaN (or absence) makes the result NaN.

    Returns
    -------
    float
    """
    noise = float(components.get("noise", math.nan))
    if math.isnan(noise):
        return math.nan
    total = 0.0
    for value in components.values():
        v = float(value)
        if math.isnan(v):
            continue
        if math.isinf(v):
            return math.inf
        total += v * v
    return math.sqrt(total)


def within_take(row: Mapping, quantity: str) -> float:
    """One window's within-take SE of ``quantity``: its :data:`WITHIN_TAKE` components.

    Falls back to ``<q>_se`` when the row has no ``<q>_se_noise`` (a table made before the
    budget). NaN: no SE; inf: undetermined by the window's data.
    """
    if component_column(quantity, "noise") not in row:
        return _float(row.get(f"{quantity}_se", math.nan))
    return combined({c: _float(row.get(component_column(quantity, c), math.nan))
                     for c in WITHIN_TAKE})  # fmt: skip


def combine_row(row: MutableMapping, limit: float, values: Mapping | None = None) -> None:
    """Set ``<q>_se`` and ``determined_<q>`` of one window's row from its components.

    ``row`` holds ``<q>_se_<component>`` for the components it has, and q itself unless
    ``values`` gives it; q stays determined when its within-take SE (:func:`within_take`)
    over ``|q|`` is below ``limit``.
    """
    values = {**row, **(values or {})}
    for q in QUANTITIES:
        parts = {c: row[component_column(q, c)] for c in COMPONENTS
                 if component_column(q, c) in row}  # fmt: skip
        row[f"{q}_se"] = combined(parts)
        se = within_take(row, q)
        value = _float(values.get(q, math.nan))
        det = f"determined_{q}"
        if det in row:
            within = math.isfinite(se) and value != 0 and se / abs(value) < limit
            row[det] = bool(row[det]) and within


def _float(value) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def combine(table: pd.DataFrame, limit: float) -> pd.DataFrame:
    """Every window's ``<q>_se`` from its component columns, and ``determined_<q>`` again.

    Parameters
    ----------
    table : pandas.DataFrame
        Windows table holding ``<q>_se_noise`` and any other component columns.
    limit : float
        Relative SE under which a quantity is determined (``inversion.determined_limit``).

    Returns
    -------
    pandas.DataFrame
        A copy; a quantity without a noise column is left as it was. ``determined_<q>``
        can only turn false (the data decide what is determined, the within-take SE
        whether it is still within the limit; a take-wide component never turns it).
    """
    out = table.copy()
    for q in QUANTITIES:
        noise_col = component_column(q, "noise")
        if noise_col not in out or q not in out:
            continue
        noise = pd.to_numeric(out[noise_col], errors="coerce").to_numpy(dtype=float)
        out[f"{q}_se"] = _root_sum_square(out, q, COMPONENTS, noise)
        det = f"determined_{q}"
        if det in out:
            se = _root_sum_square(out, q, WITHIN_TAKE, noise)
            x = np.abs(pd.to_numeric(out[q], errors="coerce").to_numpy(dtype=float))
            with np.errstate(invalid="ignore", divide="ignore"):
                within = np.isfinite(se) & (se / x < limit)
            out[det] = out[det].astype(bool).to_numpy() & within
    return out


def _root_sum_square(table: pd.DataFrame, q: str, components, noise: np.ndarray) -> np.ndarray:
    """The root sum of squares of ``components`` of ``q`` (NaN where the noise is NaN)."""
    total = np.zeros(len(table))
    for c in components:
        col = component_column(q, c)
        if col not in table:
            continue
        v = pd.to_numeric(table[col], errors="coerce").to_numpy(dtype=float)
        total += np.where(np.isnan(v), 0.0, v * v)
    return np.where(np.isnan(noise), np.nan, np.sqrt(total))


__all__ = [
    "COMPONENTS",
    "QUANTITIES",
    "WINDOW_COMPONENTS",
    "WITHIN_TAKE",
    "combine",
    "combine_row",
    "combined",
    "component_column",
    "within_take",
]
