"""The tables of a recording session: one row per note per take, and one row per take.

``OUT/session.csv`` (and ``session.parquet``) holds every note of every take: which take,
its calibration and fingering, when the note sounds, its pitch, each quantity's value and
combined standard uncertainty as the take's own note table (``OUT/<take>/inversion/
segments.csv``) gives them, and the note's verdict. ``OUT/session_takes.csv`` holds one
row per take: its files, calibration, fingering, score and notes, and its state (``ok``,
``check`` or ``failed`` with the reason). Both are made from the takes' folders only, so a
session resumed after a kill writes the same tables as one run through.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd

from mpipe.core.io import write_atomic, write_csv
from mpipe.measurement.calibration import load_calibration, per_note
from mpipe.pipeline.manifest import MANIFEST
from mpipe.pipeline.session import Session, SessionTake
from mpipe.reed.score import Score, load_score

#: The note table's columns kept as they are, renamed (note table -> session table).
PLAYED = {
    "segment": "segment",
    "start_s": "onset_s",
    "end_s": "offset_s",
    "duration_s": "duration_s",
    "f0_hz": "f0_hz",
    "pitch_cents": "pitch_cents",
    "note": "note_name",
    "regime": "regime",
    "spl_db": "spl_db",
    "windows": "windows",
    "ok_windows": "ok_windows",
}
#: A take-level reason that names one note by its number in the take
#: (:mod:`mpipe.inversion.trust.diagnostics`).
NOTE_REASON = re.compile(r"cannot play note (\d+)\b")


def _summary(folder: Path, stage: str) -> dict | None:
    path = folder / stage / MANIFEST
    if not path.is_file():
        return None
    return json.loads(path.read_text())["summary"]


def _shown(path: Path | None, base: Path) -> str:
    """A path as the session table shows it: relative to the session file's folder."""
    return "" if path is None else os.path.relpath(Path(path).resolve(), base.resolve())


def note_verdict(row: Mapping, validation: str, take_checks: list[str]) -> tuple[str, str]:
    """``(PASS | CHECK | FAIL, reason)`` of one note of a take.

    FAIL: none of the note's windows is ok. CHECK: a take-level check names the note (the
    model cannot play it), the validation did not pass, another take-level check holds, or
    some of its windows are not ok. PASS otherwise.
    """
    ok, n = int(row["ok_windows"]), int(row["windows"])
    if ok == 0:
        return "FAIL", f"none of its {n} windows ok"
    number = row["note_number"] if "note_number" in row else row["segment"]
    mine = [c for c in take_checks if (m := NOTE_REASON.search(c)) and int(m[1]) == number]
    if mine:
        return "CHECK", mine[0]
    if validation != "pass":
        return "CHECK", f"the take's impedance validation: {validation.upper()}"
    others = [c for c in take_checks if not NOTE_REASON.search(c)]
    if others:
        return "CHECK", f"the take: {others[0]}"
    if ok < n:
        return "CHECK", f"{ok} of {n} windows ok"
    return "PASS", f"all {n} windows ok"


def take_notes(session: Session, take: SessionTake, out: Path) -> pd.DataFrame:
    """The session table's rows of one finished take (empty when it has no note table)."""
    folder = Path(out) / take.name
    inv = _summary(folder, "inversion")
    notes_path = folder / "inversion" / "segments.csv"
    if inv is None or not notes_path.is_file():
        return pd.DataFrame()
    table = pd.read_csv(notes_path, keep_default_na=False, na_values=[""])
    table = table[table["label"] == "note"].reset_index(drop=True)
    validation = (_summary(folder, "validation") or {}).get("verdict", "?")
    checks = list(inv.get("take_checks", []))
    base = session.source.parent
    rows = pd.DataFrame(
        {
            "take": take.name,
            "note": range(1, len(table) + 1),
            "calibration": _shown(take.calibration, base),
            "fingering": note_fingerings(take, table),
        }
    )
    for old, new in PLAYED.items():
        rows[new] = table[old].to_numpy()
    quantities = [c[: -len("_median")] for c in table.columns if c.endswith("_median")]
    for q in quantities:
        rows[f"{q}_median"] = table[f"{q}_median"].to_numpy(float)
        rows[f"{q}_se"] = table[f"{q}_se"].to_numpy(float)
    verdicts = [note_verdict(r, validation, checks) for _, r in table.iterrows()]
    rows["verdict"] = [v for v, _ in verdicts]
    rows["verdict_reason"] = [r for _, r in verdicts]
    if take.score is not None:
        for name, values in played_columns(load_score(take.score), rows).items():
            rows[name] = values
    return rows


def note_fingerings(take: SessionTake, table: pd.DataFrame) -> list[str]:
    """Each note's own fingering name (not the take's whole list).

    The note table's, else the take's one fingering, else its calibration's default
    (blank for an instrument without fingerings).
    """
    one = None if per_note(take.fingering) else take.fingering
    if one is None:
        default = load_calibration(take.calibration).fingering
        one = None if per_note(default) else default
    own = table["fingering"] if "fingering" in table else pd.Series([""] * len(table))
    return [str(f) if isinstance(f, str) and f else (one or "") for f in own]


#: Columns of the score's note matched to each measured note (by the longest overlap of
#: their sounding spans): what was played beside what was measured.
PLAYED_COLUMNS = ("played_note", "played_p_m", "p_m_minus_played", "p_m_rel_to_played",
                  "played_fingering", "fingering_as_played")  # fmt: skip


def played_columns(score: Score, rows: pd.DataFrame) -> dict[str, list]:
    """Played vs measured for each measured note: the score's note, p_m (Pa) and fingering.

    ``played_p_m`` is the score's mouth pressure at the middle of the note's sounding span
    (blank when the score leaves it to the reed file); ``p_m_minus_played`` the measured
    ``p_m_median`` less it, Pa, and ``p_m_rel_to_played`` that over it;
    ``fingering_as_played`` whether the note's fingering is the score's.
    """
    spans = np.asarray(score.sounding(), dtype=float).reshape(-1, 2)
    names = score.fingerings(None)
    out: dict[str, list] = {c: [] for c in PLAYED_COLUMNS}
    for _, row in rows.iterrows():
        overlap = np.minimum(spans[:, 1], row["offset_s"]) - np.maximum(spans[:, 0], row["onset_s"])
        j = int(np.argmax(overlap)) if overlap.size and overlap.max() > 0 else None
        note = None if j is None else score.notes[j]
        played = np.nan
        if note is not None and note.p_m:
            t, v = np.asarray(note.p_m, dtype=float).reshape(-1, 2).T
            played = float(np.interp(0.5 * (spans[j, 0] + spans[j, 1]) - score.starts()[j], t, v))
        measured = float(row.get("p_m_median", np.nan))
        fingering = (names[j] or "") if j is not None else ""
        out["played_note"].append(pd.NA if j is None else j + 1)
        out["played_p_m"].append(played)
        out["p_m_minus_played"].append(measured - played)
        out["p_m_rel_to_played"].append((measured - played) / played)
        out["played_fingering"].append(fingering)
        out["fingering_as_played"].append(
            pd.NA if not fingering or not row["fingering"] else fingering == row["fingering"]
        )
    return out


def take_row(session: Session, take: SessionTake, out: Path, result) -> dict:
    """The take's row of ``session_takes.csv``; ``result`` its run or the error that ended it."""
    base = session.source.parent
    folder = Path(out) / take.name
    inv = _summary(folder, "inversion") or {}
    val = _summary(folder, "validation") or {}
    counts = inv.get("status_counts", {})
    row = {
        "take": take.name,
        "files": ";".join(_shown(f, base) for f in take.files),
        "calibration": _shown(take.calibration, base),
        "fingering": take.fingering or "",
        "score": _shown(take.score, base),
        "take_notes": take.notes,
        "validation": str(val.get("verdict", "")).upper(),
        "windows": int(inv.get("windows", 0)),
        "ok_windows": int(counts.get("ok", 0)),
    }
    if isinstance(result, BaseException) or result is None:
        text = str(result).splitlines()[0] if str(result) else type(result).__name__
        state, reason = "failed", "not run" if result is None else text
    elif not row["ok_windows"]:
        state, reason = "failed", "no window has status ok (no usable result)"
    elif row["validation"] != "PASS" or inv.get("take_checks"):
        state = "check"
        reason = "; ".join(inv.get("take_checks", [])) or f"validation {row['validation']}"
    else:
        state, reason = "ok", ""
    return {**row, "state": state, "reason": reason}


def write_session_tables(
    session: Session, out: str | Path, results: Mapping[str, object]
) -> dict[str, Path]:
    """Write ``session.csv``, ``session.parquet`` and ``session_takes.csv`` into ``out``.

    Parameters
    ----------
    session : Session
    out : path
        The session's output folder (each take's folder below it).
    results : mapping
        Take name to its :class:`mpipe.pipeline.orchestration.TakeRun` or the error that
        ended it (a take missing from it is "not run").

    Returns
    -------
    dict
        ``notes``, ``notes_parquet``, ``takes``: the paths written.
    """
    out = Path(out)
    # a take that failed in this run has no rows, whatever an earlier run left in its folder
    parts = [
        take_notes(session, t, out)
        if results.get(t.name) is not None and not isinstance(results[t.name], BaseException)
        else pd.DataFrame()
        for t in session.takes
    ]
    notes = (
        pd.concat([p for p in parts if len(p)], ignore_index=True)
        if any(len(p) for p in parts)
        else pd.DataFrame(columns=["take", "note", "verdict"])
    )
    takes = pd.DataFrame([take_row(session, t, out, results.get(t.name)) for t in session.takes])
    written = {
        "notes": write_csv(out / "session.csv", notes),
        "notes_parquet": write_atomic(
            out / "session.parquet", lambda tmp: notes.to_parquet(tmp, index=False)
        ),
        "takes": write_csv(out / "session_takes.csv", takes),
    }
    return written


__all__ = [
    "NOTE_REASON",
    "PLAYED",
    "note_verdict",
    "take_notes",
    "take_row",
    "write_session_tables",
]
