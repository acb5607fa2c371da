"""The report's parts about single windows: the per-window table and the note figures.

Kept apart from :mod:`mpipe.pipeline.report` (which lays the sections out) so that the
tables a take's report prints can be tested on their own. A window's line gives its note
(numbered as in the report's notes table), phase, playing frequency in Hz and nearest note
name, its status, the reed parameters and the combinations p_M, gamma, zeta each as
``value ± SE`` (the combined standard uncertainty ``<q>_se`` of the window), the relative
residual and, for a window that is not ok, the reason in words
(:func:`mpipe.inversion.trust.status_words.reason_words`).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from mpipe.inversion.trust.status_words import reason_words
from mpipe.measurement.pitch import note_name
from mpipe.pipeline.html_report import Figure, fmt

#: No-break space: a value and its SE, or a note and its cents, stay on one line of a cell.
NBSP = "\u00a0"

#: Caption of the per-window table.
WINDOW_CAPTION = (
    "Per-window results: the window's note (numbered as in the notes table), phase, playing "
    "frequency (Hz) and nearest note, status, each quantity as value ± its combined "
    "standard uncertainty (undetermined: infinite; no ± where the quantity is held fixed), "
    "the relative residual of the model pressure, and why a window is not ok."
)

#: Quantities of the per-window table, shown as value ± SE, in this order.
WINDOW_QUANTITIES = ("p_m", "p_M", "gamma", "zeta", "k", "S", "y_m", "lam", "m", "g", "k_c")


def value_se(value: float, se: float) -> str:
    """``"1800 ± 26"``, ``"(8.83 ± 0.12)×10⁶"``; ``"3136 (undetermined)"`` for an infinite SE.

    The SE keeps two significant digits and the value is given to the same decimal place
    (the GUM's practice); values outside 0.01 to 99999 share a power of ten with their SE.
    Without an SE (a fixed quantity) the value alone, to four significant digits. The parts
    are joined by no-break spaces (:data:`NBSP`).
    """
    if value is None or not np.isfinite(value):
        return "–"
    value = float(value)
    if se is None or math.isnan(float(se)):
        return fmt(value, 4)
    se = float(se)
    if math.isinf(se):
        return f"{fmt(value, 4)}{NBSP}(undetermined)"
    if se <= 0 or value == 0:
        return f"{fmt(value, 4)}{NBSP}±{NBSP}{fmt(se, 2)}"
    power = math.floor(math.log10(abs(value)))
    scale = 0 if -2 <= power <= 4 else power
    v, e = value / 10.0**scale, se / 10.0**scale
    places = min(max(1 - math.floor(math.log10(e)), 0), 12)
    text = f"{v:.{places}f}{NBSP}±{NBSP}{e:.{places}f}"
    return text if scale == 0 else f"({text})×10{str(scale).translate(_SUPERSCRIPT)}"


_SUPERSCRIPT = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")


def pitch_name(f0_hz: float, pitch_cents: float) -> str:
    """Nearest note of ``f0_hz``, its reference A4 taken from the window's own cents."""
    if not (np.isfinite(f0_hz) and np.isfinite(pitch_cents) and f0_hz > 0):
        return ""
    a4 = f0_hz / 2.0 ** (pitch_cents / 1200.0)
    return note_name(f0_hz, a4).replace(" ", NBSP)


def note_numbers(windows: pd.DataFrame, segments: pd.DataFrame | None) -> list:
    """Each window's note number (1, 2, ... in the take's order of notes; "" outside one)."""
    if segments is None or not len(segments) or "segment" not in windows:
        return [""] * len(windows)
    notes = segments[segments["label"] == "note"] if "label" in segments else segments
    number = {int(s): i + 1 for i, s in enumerate(notes["segment"])}
    seg = pd.to_numeric(windows["segment"], errors="coerce")
    return [number.get(int(s), "") if np.isfinite(s) else "" for s in seg]


def window_table(windows: pd.DataFrame, segments: pd.DataFrame | None = None) -> pd.DataFrame:
    """The per-window table of the report.

    Parameters
    ----------
    windows : pandas.DataFrame
        The windows table (``windows.csv``).
    segments : pandas.DataFrame, optional
        The take's segments, to number the notes as the report does.

    Returns
    -------
    pandas.DataFrame
        Columns ``window``, ``t_start_s``, ``note``, ``phase``, ``f0_hz``, ``pitch``,
        ``status``, one text column per quantity of :data:`WINDOW_QUANTITIES` present
        (``value ± SE``, named by the quantity so that its header carries the unit),
        ``relative_residual`` and ``reason``.
    """
    out = pd.DataFrame({"window": windows["window"].astype(int).to_numpy()})
    out["t_start_s"] = windows["t_start_s"].to_numpy(float)
    out["note"] = note_numbers(windows, segments)
    out["phase"] = _text(windows, "phase")
    f0 = _floats(windows, "f0_hz")
    out["f0_hz"] = f0
    cents = _floats(windows, "pitch_cents")
    out["pitch"] = [pitch_name(f, c) for f, c in zip(f0, cents, strict=True)]
    out["status"] = _text(windows, "status")
    for name in WINDOW_QUANTITIES:
        if name not in windows:
            continue
        se = _floats(windows, f"{name}_se")
        out[name] = [value_se(v, e) for v, e in zip(_floats(windows, name), se, strict=True)]
    out["relative_residual"] = _floats(windows, "relative_residual")
    out["reason"] = reasons(windows)
    return out


def reasons(windows: pd.DataFrame) -> list[str]:
    """Each window's status reason in words.

    (:func:`mpipe.inversion.trust.status_words.reason_words`)
    """
    return [reason_words(r) for _, r in windows.iterrows()]


def resynthesis_figures(folder: Path) -> tuple[Figure, ...]:
    """The resynthesis's figures with their captions: each note's two periods, the overlays.

    Parameters
    ----------
    folder : Path
        The take's ``resynthesis`` folder (``flow_pressure_note_<n>.png``, ``overlay_<i>.png``).
    """
    notes = sorted(
        folder.glob("flow_pressure_note_*.png"), key=lambda p: int(p.stem.split("_")[-1])
    )
    per_note = tuple(
        Figure(p, f"Note {p.stem.split('_')[-1]}: two periods of the measured and "
               "resynthesised mouthpiece pressure p (Pa) and flow u (m³/s) against time, and u "
               "against p (Δp = p_m − p on the top axis), of the ok window nearest the middle "
               "of the note's sustain; the title names the note and the window with its "
               "status (red when not ok; paper Figs. 9, 11).")
        for p in notes
    )  # fmt: skip
    overlays = tuple(
        Figure(p, "Target (measured) and resynthesised mouthpiece pressure (Pa) and flow "
               f"(m³/s) over a whole window ({p.stem.replace('_', ' ')}, windows spread over "
               "the take); the title gives the window's status and, when not ok, why.")
        for p in sorted(folder.glob("overlay_*.png"))
    )  # fmt: skip
    return per_note + overlays


def _floats(table: pd.DataFrame, name: str) -> np.ndarray:
    if name not in table:
        return np.full(len(table), np.nan)
    return pd.to_numeric(table[name], errors="coerce").to_numpy(dtype=float)


def _text(table: pd.DataFrame, name: str) -> list[str]:
    if name not in table:
        return [""] * len(table)
    return [("" if pd.isna(v) else str(v)) for v in table[name]]


__all__ = [
    "WINDOW_CAPTION",
    "WINDOW_QUANTITIES",
    "note_numbers",
    "pitch_name",
    "reasons",
    "resynthesis_figures",
    "value_se",
    "window_table",
]
