"""The report's uncertainty budget of each note: value, combined SE and its components.

From the note table of :func:`mpipe.inversion.trust.notes.note_summary` (the take's
``inversion/segments.csv``); the components and their combination are described in
docs/uncertainty.md.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from mpipe.core.units import unit_of
from mpipe.inversion.trust.notes import NOTE_COMPONENTS
from mpipe.pipeline.html_report import fmt

#: Quantities of a note's budget table, in this order.
BUDGET_QUANTITIES = ("p_m", "p_M", "gamma", "zeta", "k", "y_m", "S", "lam")

#: What the combined standard uncertainty means (the caption's sentence).
MEANING = (
    "u_c is the combined standard uncertainty (GUM): the root sum of squares of the "
    "components, each a standard deviation in the quantity's unit. noise: the windows' "
    "scatter about the note's median, allowing for windows that err together (never "
    "below their own noise over √n); model: what the model cannot explain, shared by the "
    "note's windows; rate, temperature, frontend, calibration: errors shared by every "
    "window of the take (the model's sample rate, the kernel temperature, the front end's "
    "propagation estimate, the microphones' sensitivity), added once, never averaged. "
    "value ± 2 u_c should hold the true value in about 95 % of notes; – : the component "
    "is not evaluated for this take."
)


def _cell(value: float) -> str:
    if value is None or math.isnan(value):
        return "–"
    return "∞ (undetermined)" if math.isinf(value) else fmt(value, 2)


def budget_table(note: pd.Series) -> pd.DataFrame:
    """One note's budget: a row per quantity of :data:`BUDGET_QUANTITIES` it has.

    Columns: quantity, unit, value, u_c, u_c as % of the value, and one per component of
    :data:`mpipe.inversion.trust.notes.NOTE_COMPONENTS` (same unit as the value; "–" absent).
    """
    rows = []
    for name in BUDGET_QUANTITIES:
        value = float(note.get(f"{name}_median", math.nan))
        if not np.isfinite(value):
            continue
        se = float(note.get(f"{name}_se", math.nan))
        row = {
            "quantity": name,
            "unit": unit_of(name),
            "value": fmt(value, 4),
            "u_c": _cell(se),
            "u_c %": _cell(100 * se / abs(value)) if value else "–",
        }
        for comp in NOTE_COMPONENTS:
            row[comp] = _cell(float(note.get(f"{name}_se_{comp}", math.nan)))
        rows.append(row)
    return pd.DataFrame(rows)


def budget_tables(notes: pd.DataFrame) -> list[tuple[str, pd.DataFrame]]:
    """``(caption, table)`` per note of a note table (rows with ``label == "note"``)."""
    if "label" in notes:
        notes = notes[notes["label"] == "note"]
    out = []
    for number, (_, note) in enumerate(notes.iterrows(), start=1):
        table = budget_table(note)
        if not len(table):
            continue
        # the note's number in the take, as the console and the figures give it (not its
        # segment id)
        parts = [f"from {float(note['start_s']):.3f} s"] if "start_s" in note else []
        if "ok_windows" in note:
            parts.append(f"{int(note['ok_windows'])} ok windows")
        where = f" ({', '.join(parts)})" if parts else ""
        out.append((f"Uncertainty budget of note {number}{where}. {MEANING}", table))
    return out


__all__ = ["BUDGET_QUANTITIES", "MEANING", "budget_table", "budget_tables"]
