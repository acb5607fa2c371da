"""A window's status reason as a reader should see it, for the report, figures and console.

The status check (:mod:`mpipe.inversion.trust.status`) states a window with too few residual
degrees of freedom as ``n_eff - p = -2.29 < 1`` (or ``dof = ...``): a negative number of
degrees of freedom means nothing to a reader. A clean or strongly coloured residual has
fewer effective independent samples ``n_eff`` than the window has free parameters ``p``,
and that is what is said instead, with both counts from the window's own row.
"""

from __future__ import annotations

import math
import re

# "n_eff - p = -2.29 < 1" (mpipe 0.4) or "dof = -2.29 < 1"
_DOF = re.compile(r"(?:n_eff - p|dof) = (-?[0-9.]+(?:e[+-]?[0-9]+)?) < 1")


def dof_words(n_eff: float, dof: float) -> str:
    """The residual's degrees of freedom in words, without a negative number.

    Parameters
    ----------
    n_eff : float
        Effective number of independent residual samples.
    dof : float
        ``n_eff - p``, with ``p`` the window's free parameters.

    Returns
    -------
    str
        E.g. ``"fewer effective residual samples (5.7) than free parameters (8)"``.
    """
    if not (math.isfinite(n_eff) and math.isfinite(dof)):
        return "no residual degrees of freedom known"
    p = int(round(n_eff - dof))
    if dof <= 0:
        return f"fewer effective residual samples ({n_eff:.2g}) than free parameters ({p})"
    return (
        f"less than one residual degree of freedom ({n_eff:.2g} effective samples for "
        f"{p} free parameters)"
    )


def reason_words(row) -> str:
    """``status_reason`` of a row with its degrees-of-freedom clause put in words.

    Parameters
    ----------
    row : mapping
        A window's row: ``status_reason`` and, where present, ``n_eff`` and ``dof``.

    Returns
    -------
    str
    """
    reason = row.get("status_reason", "")
    reason = (
        "" if reason is None or (isinstance(reason, float) and math.isnan(reason)) else str(reason)
    )
    match = _DOF.search(reason)
    if not match:
        return reason
    dof = _number(row.get("dof", match.group(1)))
    n_eff = _number(row.get("n_eff", math.nan))
    if not math.isfinite(n_eff):
        words = (
            "fewer effective residual samples than free parameters"
            if float(match.group(1)) <= 0
            else "less than one residual degree of freedom"
        )
    else:
        words = dof_words(n_eff, dof)
    return reason[: match.start()] + words + reason[match.end() :]


def _number(value) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


__all__ = ["dof_words", "reason_words"]
