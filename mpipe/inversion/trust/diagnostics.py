"""Take-level checks: what the windows' statuses, one by one, cannot see.

Each window's status (:mod:`mpipe.inversion.trust.status`) judges it on its own and against the
take. A take can still be wrong as a whole; :func:`take_checks` lists each such reason in
one line. Every check is judged on every window inverted (not only the ``ok`` ones: a
window above ``residual_limit`` is never ``ok``, so a check on the ok windows alone could
not fire):

- the take's cold start found its minimum with fewer than :data:`MIN_AGREEING` of its
  short local searches (a narrow basin, possibly the wrong one);
- the median relative residual exceeds ``inversion.residual_limit`` (a take whose every
  window sits in the same wrong basin: a wrong bore, fingering or calibration);
- the model's playing frequency or RMS level, median over the windows, departs from the
  measured one by more than ``inversion.pitch_limit_cents`` / ``level_limit_db``
  (per window: :func:`playing_difference`), or cannot be compared in most windows (the
  model silent or aperiodic; a NaN median never passes);
- a note of at least :data:`NOTE_MIN_WINDOWS` windows of which at least half ended
  ``at-bound``, ``failed``, ``not-converged`` or ``high-residual``: the model cannot play
  it (a reed outside the search bounds, another fingering);
- a note whose windows leave, at their harmonics beyond the noise (``model_residual``,
  :mod:`mpipe.inversion.trust.harmonics`), a median misfit above
  ``inversion.model_form_limit``: the model cannot play what was played (a flow no reed
  makes, another instrument); each window's status judges it against its note, so a
  note misfit throughout is seen here (:func:`_misfit_notes`);
- reasons found before the inversion (``extra``: e.g. a take read with a calibration
  other than the one its sidecar records, :mod:`mpipe.pipeline.take_calibration`).

A take with any of them is CHECK, never PASS, and ``mpipe run`` ends with exit status 1;
the reasons go to the console, to the ``take_checks`` column of the windows table, to the
manifest and to the report.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pandas as pd

from mpipe.inversion.preparation.conditioning import estimate_period
from mpipe.inversion.settings import InversionConfig

#: A cold start whose minimum fewer of its short local searches reached is flagged.
MIN_AGREEING = 2
#: A note is judged on its own from this many windows.
NOTE_MIN_WINDOWS = 3
#: Statuses of windows the model did not play: half a note of them and the note is flagged.
UNPLAYED = ("at-bound", "failed", "not-converged", "high-residual")
#: Plausible ``|P(f0)| / (Z_c |U(f0)|)`` at the mouthpiece: a reed plays near a resonance
#: of the bore, where |Z_in| / Z_c is about 3 to 50 (15 on the shipped instrument); a flow
#: in L/s (x1000) or scaled by 0.001 moves it by three decades.
IMPEDANCE_RATIO_RANGE = (0.2, 500.0)
#: Plausible AC RMS of the mouthpiece flow, m^3/s (a clarinet: about 1e-5 to 3e-4).
FLOW_RMS_RANGE = (1e-7, 1e-2)
#: Plausible largest |p| at the mouthpiece, Pa (a player's mouth pressure is at most about
#: 10 kPa; the pressure in the mouthpiece swings about it).
PRESSURE_RANGE = (1.0, 3e4)


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
    cold_starts_agreeing: int | None = None,
    extra: Sequence[str] = (),
) -> list[str]:
    """Reasons, one line each, why a take's result should not pass (empty: none).

    Parameters
    ----------
    table : pandas.DataFrame
        The take's windows (``status``, ``relative_residual``, ``model_f0_cents``,
        ``model_level_db``, ``segment``, ``t_start_s``).
    config : InversionConfig
        ``residual_limit``, ``pitch_limit_cents``,
        ``level_limit_db``.
    cold_starts_agreeing : int or None
        Short searches of the take's cold start that reached its minimum (None: no global
        cold start).
    extra : sequence of str
        Reasons found before the inversion, kept first.

    Returns
    -------
    list of str
    """
    reasons = [r for r in extra if r]
    if cold_starts_agreeing is not None and cold_starts_agreeing < MIN_AGREEING:
        reasons.append(
            f"the cold start's minimum was reached by {cold_starts_agreeing} of its "
            f"{config.local_starts} short searches (fewer than {MIN_AGREEING}): a narrow basin, "
            "possibly a wrong one"
        )
    if not len(table):
        return reasons
    reasons += _playing_checks(table, config)
    reasons += _unplayable_notes(table)
    reasons += _misfit_notes(table, config)
    return reasons


def _playing_checks(table: pd.DataFrame, config: InversionConfig) -> list[str]:
    """Residual, playing frequency and level, judged on every window inverted."""
    reasons = []
    n = len(table)
    residual = _values(table, "relative_residual")
    if not residual.size:
        return [f"no window of {n} has a finite residual: the model plays none of them"]
    median = float(np.median(residual))
    if median > config.residual_limit:
        reasons.append(
            f"median relative residual {median:.3g} of the {residual.size} windows > "
            f"inversion.residual_limit {config.residual_limit:g}: the model does not play "
            "what was played (a wrong basin, or a bore, fingering or flow that does not match)"
        )
    checks = (
        ("model_f0_cents", config.pitch_limit_cents, "cent", "playing frequency",
         "inversion.pitch_limit_cents"),
        ("model_level_db", config.level_limit_db, "dB", "RMS level", "inversion.level_limit_db"),
    )  # fmt: skip
    for column, limit, unit, what, key in checks:
        values = _values(table, column)
        if column in table and 2 * values.size < residual.size:
            reasons.append(
                f"the model's {what} could be compared with the measured one in only "
                f"{values.size} of {residual.size} windows (the model silent or not periodic)"
            )
            continue
        median = float(np.median(values)) if values.size else math.nan
        if abs(median) > limit:
            reasons.append(
                f"the model's {what} departs from the measured one by {median:+.3g} {unit} "
                f"(median over {values.size} windows; {key} {limit:g})"
            )
    return reasons


def _unplayable_notes(table: pd.DataFrame) -> list[str]:
    """Notes of which at least half the windows are at a bound, failed or far off."""
    if "status" not in table:
        return []
    segments = table["segment"] if "segment" in table else pd.Series(0, index=table.index)
    reasons = []
    for g, rows in table.groupby(segments, sort=True):
        if len(rows) < NOTE_MIN_WINDOWS:
            continue
        bad = rows["status"].isin(UNPLAYED)
        if 2 * int(bad.sum()) < len(rows):
            continue
        kinds = rows.loc[bad, "status"].value_counts()
        which = ", ".join(f"{c} {s}" for s, c in kinds.items())
        t0 = pd.to_numeric(rows.get("t_start_s", pd.Series(math.nan)), errors="coerce")
        t1 = pd.to_numeric(rows.get("t_end_s", t0), errors="coerce")
        when = f" ({t0.min():.2f}-{t1.max():.2f} s)" if t0.notna().any() else ""
        reasons.append(
            f"the model cannot play {_which(rows, g)}{when}: {int(bad.sum())} of {len(rows)} "
            f"windows not ok ({which}): a reed outside the search bounds, or a bore or "
            "fingering that does not match this note"
        )
    return reasons


def _which(rows: pd.DataFrame, segment) -> str:
    """``"note 2"`` (the note's number in the take), or ``"segment 3"`` outside a note."""
    number = pd.to_numeric(rows.get("note_number", pd.Series(dtype=float)), errors="coerce")
    number = number[number > 0]
    return f"note {int(number.iloc[0])}" if len(number) else f"segment {segment}"


def note_misfits(table: pd.DataFrame) -> dict:
    """Each note's median model-form residual: group -> (median, windows), a fraction of p.

    Over each note's windows that inform it (``informs_note``; all where the column is
    absent) with a finite ``model_residual``, grouped by ``segment``; notes of fewer than
    :data:`NOTE_MIN_WINDOWS` such windows are left out, unless no note has that many: then
    the take's windows form one group, keyed -1. The median, not the sum: the few windows
    a note cannot hold (a fingering changing within one, a click) are flagged one by one by
    their statuses and do not make the note misfit.
    """
    if "model_residual" not in table:
        return {}
    misfit = pd.to_numeric(table["model_residual"], errors="coerce")
    use = np.isfinite(misfit.to_numpy(dtype=float))
    if "informs_note" in table:
        use &= table["informs_note"].astype(str).str.lower().isin(("true", "1")).to_numpy()
    rows = misfit[use]
    segments = table.loc[use, "segment"] if "segment" in table else pd.Series(0, index=rows.index)
    sizes = segments.map(segments.value_counts())
    big = sizes >= NOTE_MIN_WINDOWS
    groups = segments[big] if big.any() else pd.Series(-1, index=rows.index)
    return {g: (float(np.median(rows[idx])), len(idx))
            for g, idx in groups.groupby(groups, sort=True).groups.items()}  # fmt: skip


def _misfit_notes(table: pd.DataFrame, config: InversionConfig) -> list[str]:
    """Notes whose median model-form residual (:func:`note_misfits`) exceeds the limit."""
    limit = config.model_form_limit
    reasons = []
    for g, (level, n) in note_misfits(table).items():
        if not level > limit:
            continue
        mine = table[table["segment"] == g] if "segment" in table else table
        which = "the take's windows" if g == -1 else _which(mine, g)
        reasons.append(
            f"{which}: the model leaves {100 * level:.2g} % of the pressure at the harmonics "
            f"beyond the noise (median of {n} windows; inversion.model_form_limit "
            f"{100 * limit:g} %): the model cannot play what was played (a flow no reed "
            "makes, another instrument, a wrong bore)"
        )
    return reasons


def _values(table: pd.DataFrame, column: str) -> np.ndarray:
    """The finite values of a column over the windows with a finite residual."""
    if column not in table:
        return np.array([])
    use = pd.to_numeric(table.get("relative_residual", table[column]), errors="coerce")
    values = pd.to_numeric(table[column], errors="coerce").to_numpy(dtype=float)
    values = values[np.isfinite(use.to_numpy(dtype=float))]
    return values[np.isfinite(values)]


__all__ = [
    "FLOW_RMS_RANGE",
    "IMPEDANCE_RATIO_RANGE",
    "MIN_AGREEING",
    "NOTE_MIN_WINDOWS",
    "UNPLAYED",
    "PRESSURE_RANGE",
    "check_plausible",
    "note_misfits",
    "impedance_ratio",
    "playing_difference",
    "take_checks",
]


def impedance_ratio(p: np.ndarray, u: np.ndarray, fs: float, z_c: float) -> float:
    """``|P(f0)| / (Z_c |U(f0)|)`` at the playing frequency of one window (NaN: no note).

    Parameters
    ----------
    p, u : ndarray
        Pressure (Pa) and volume flow (m^3/s) over the window.
    fs : float
        Sample rate, Hz.
    z_c : float
        Characteristic impedance of the mouthpiece entry, Pa s/m^3.
    """
    period = estimate_period(p, fs)
    if not period > 0:
        return math.nan
    t = np.arange(p.size) / fs
    probe = np.exp(-2j * np.pi * (fs / period) * t) * np.hanning(p.size)
    big_p, big_u = abs(probe @ (p - p.mean())), abs(probe @ (u - u.mean()))
    return big_p / (z_c * big_u) if big_u > 0 else math.inf


def check_plausible(
    p: np.ndarray, u: np.ndarray, fs: float, starts, n: int, z_c: float, count: int = 5
) -> None:
    """Refuse mouthpiece signals no clarinet can produce, before any long work.

    Over up to ``count`` of the planned windows: the largest |p| against
    :data:`PRESSURE_RANGE`, the flow's AC RMS against :data:`FLOW_RMS_RANGE`, and the
    median of :func:`impedance_ratio` against :data:`IMPEDANCE_RATIO_RANGE` (the flow's
    scale against the pressure's: orders of magnitude off is a unit error).

    Parameters
    ----------
    p, u : ndarray
        Mouthpiece pressure (Pa) and volume flow (m^3/s) of the take.
    fs : float
        Sample rate, Hz.
    starts : sequence of int
        First samples of the planned windows.
    n : int
        Window length, samples.
    z_c : float
        Characteristic impedance of the mouthpiece entry, Pa s/m^3.
    count : int
        Windows looked at.

    Raises
    ------
    ValueError
        One line naming what is implausible and the likely cause.
    """
    starts = list(starts)
    if not starts:
        return
    picked = [
        starts[i] for i in np.unique(np.linspace(0, len(starts) - 1, count).round().astype(int))
    ]
    windows = [(p[s : s + n], u[s : s + n]) for s in picked]
    peak = max(float(np.max(np.abs(pw))) for pw, _ in windows)
    flow = float(np.median([np.std(uw) for _, uw in windows]))
    ratio = float(np.nanmedian([impedance_ratio(pw, uw, fs, z_c) for pw, uw in windows]))
    lo, hi = PRESSURE_RANGE
    if not lo <= peak <= hi:
        raise ValueError(
            f"implausible mouthpiece pressure: largest |p| {peak:.3g} Pa, a clarinet gives "
            f"{lo:g}-{hi:g} Pa: check the microphones' sensitivity (Pa per unit)"
        )
    lo, hi = FLOW_RMS_RANGE
    if not lo <= flow <= hi:
        raise ValueError(
            f"implausible mouthpiece flow: AC RMS {flow:.3g} m^3/s, a clarinet gives "
            f"{lo:g}-{hi:g} m^3/s: a unit error of the flow (m^3/s expected)?"
        )
    lo, hi = IMPEDANCE_RATIO_RANGE
    if math.isfinite(ratio) and not lo <= ratio <= hi:
        raise ValueError(
            f"implausible flow for the pressure: |p/u| at the playing frequency is {ratio:.3g} "
            f"Z_c of the mouthpiece entry (a reed plays at {lo:g}-{hi:g} Z_c): a unit error of "
            "the flow (m^3/s expected) or of the entry radius"
        )
