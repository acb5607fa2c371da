"""Take-level checks: what the windows' statuses, one by one, cannot see.

Each window's status (:mod:`mpipe.inversion.status`) compares it with its own search and
with the take's best window. A take can still be wrong as a whole with every window
``ok``; :func:`take_checks` lists each such reason in one line:

- the kernel temperature was to be fitted and the fit fell back to the temperature the
  signals carry (then the reed parameters carry its error: S -21 % on the demo's take for
  a kernel 1.1 degC off, and the SEs leave it out);
- the take's cold start found its minimum with fewer than :data:`MIN_AGREEING` of its
  short local searches (a narrow basin, possibly the wrong one);
- the model's playing frequency or RMS level, median over the ok windows, departs from the
  measured one by more than ``inversion.pitch_limit_cents`` / ``level_limit_db``
  (per window: :func:`playing_difference`);
- the median relative residual of the ok windows exceeds ``inversion.residual_limit``
  (a take whose every window sits in the same wrong basin has no better window to be
  compared with).

A take with any of them is not PASS (the report's verdict is CHECK); the reasons go to the
console, to the ``take_checks`` column of the windows table and to the report.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from mpipe.inversion.conditioning import estimate_period
from mpipe.inversion.settings import InversionConfig

#: A cold start whose minimum fewer of its short local searches reached is flagged.
MIN_AGREEING = 2


def playing_difference(p: np.ndarray, p_model: np.ndarray, fs: float) -> dict[str, float]:
    """Model minus measured playing frequency (cent) and RMS level (dB) over one window.

    Parameters
    ----------
    p, p_model : ndarray
        Measured and model pressure over the window, Pa.
    fs : float
        Sample rate, Hz.

    Returns
    -------
    dict
        ``model_f0_cents`` (1200 log2(f0_model / f0), NaN when either has no period in
        60-2000 Hz) and ``model_level_db`` (20 log10 of the ratio of the AC RMS values,
        NaN when either is silent).
    """
    period, period_model = estimate_period(p, fs), estimate_period(p_model, fs)
    cents = (
        1200.0 * math.log2(period / period_model) if period > 0 and period_model > 0 else math.nan
    )
    rms = float(np.std(p))
    rms_model = float(np.std(p_model))
    level = 20.0 * math.log10(rms_model / rms) if rms > 0 and rms_model > 0 else math.nan
    return {"model_f0_cents": cents, "model_level_db": level}


def take_checks(
    table: pd.DataFrame,
    config: InversionConfig,
    *,
    temperature_source: str,
    temperature_note: str = "",
    cold_starts_agreeing: int | None = None,
) -> list[str]:
    """Reasons, one line each, why a take's result should not pass (empty: none).

    Parameters
    ----------
    table : pandas.DataFrame
        The take's windows (``status``, ``relative_residual``, ``model_f0_cents``,
        ``model_level_db``).
    config : InversionConfig
        ``temperature`` (was a fit asked for), ``residual_limit``, ``pitch_limit_cents``,
        ``level_limit_db``.
    temperature_source : str
        Where the kernel temperature came from (``"fit"``, ``"front end"``,
        ``"calibration"``).
    temperature_note : str
        Why the fit fell back.
    cold_starts_agreeing : int or None
        Short searches of the take's cold start that reached its minimum (None: no global
        cold start).

    Returns
    -------
    list of str
    """
    reasons = []
    if config.temperature == "fit" and temperature_source != "fit":
        reasons.append(
            "the kernel temperature fit fell back to the "
            f"{temperature_source}'s temperature ({temperature_note or 'not fitted'}): the "
            "reed parameters carry its error and the SEs leave it out"
        )
    if cold_starts_agreeing is not None and cold_starts_agreeing < MIN_AGREEING:
        reasons.append(
            f"the cold start's minimum was reached by {cold_starts_agreeing} of its "
            f"{config.local_starts} short searches (fewer than {MIN_AGREEING}): a narrow basin, "
            "possibly a wrong one"
        )
    ok = table[table["status"].astype(str) == "ok"] if "status" in table else table.iloc[:0]
    if not len(ok):
        return reasons
    checks = (
        ("model_f0_cents", config.pitch_limit_cents, "cent", "playing frequency",
         "inversion.pitch_limit_cents"),
        ("model_level_db", config.level_limit_db, "dB", "RMS level", "inversion.level_limit_db"),
    )  # fmt: skip
    for column, limit, unit, what, key in checks:
        median = _median(ok, column)
        if abs(median) > limit:
            reasons.append(
                f"the model's {what} departs from the measured one by {median:+.3g} {unit} "
                f"(median over the ok windows; {key} {limit:g})"
            )
    residual = _median(ok, "relative_residual")
    if residual > config.residual_limit:
        reasons.append(
            f"median relative residual {residual:.3g} of the ok windows > "
            f"inversion.residual_limit {config.residual_limit:g}: the model does not play "
            "what was played (a wrong basin, or a bore or flow that does not match)"
        )
    return reasons


def _median(table: pd.DataFrame, column: str) -> float:
    if column not in table:
        return math.nan
    values = pd.to_numeric(table[column], errors="coerce").to_numpy(dtype=float)
    values = values[np.isfinite(values)]
    return float(np.median(values)) if values.size else math.nan


__all__ = ["MIN_AGREEING", "playing_difference", "take_checks"]
