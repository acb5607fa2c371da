"""The validation of a phrase: each note against its own fingering, what could not be checked.

A take of several notes (or one whose fingering is found per note: ``fingering: auto`` or
a list) is validated note by note: the notes are the conditioning's
(:func:`mpipe.inversion.preparation.segments.segment_take`, the same rule the inversion uses), each
note's fingering is given or found (:func:`mpipe.measurement.fingerings.identify`, from its
harmonic lines), and the note's own span of P and U is compared with the theory of its own
fingering (:func:`mpipe.measurement.validation.validate`, the note's f0 given).

A short note is verified on what it has: its harmonics are read on frames of
:data:`~mpipe.measurement.harmonic_impedance.FRAME_PERIODS` periods
(:mod:`mpipe.measurement.harmonic_impedance`), so a note needs only
:data:`~mpipe.measurement.harmonic_impedance.MIN_FRAMES` half-overlapping frames (10 periods,
96 ms at 104 Hz, at any sample rate); fewer frames widen each harmonic's measured
uncertainty, and so its tolerance. A note shorter than that is CANNOT-VERIFY, with the
length it had and the length it needed. So is a note whose comparison rests on fewer than
``min_checks`` harmonics (a soft note whose lines are too weak, a note whose pitch glides):
a PASS needs ``min_checks``, and one of a phrase's notes does not FAIL the take on less (the
reason names what differed). The take's verdict is FAIL when a verifiable note fails,
PASS when at least one note passes and none fails, CANNOT-VERIFY otherwise, and "no note"
(CANNOT-VERIFY) when the take holds none; its headline counts the notes verified.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from mpipe.core.errors import UserError
from mpipe.core.io import write_csv
from mpipe.inversion.preparation.conditioning import bore_resonances
from mpipe.inversion.preparation.kernel import take_temperature
from mpipe.inversion.preparation.segments import save_segmentation, segment_take
from mpipe.measurement.calibration import AUTO, Calibration, note_fingerings, per_note
from mpipe.measurement.fingerings import NO_FIT_BELOW, FingeringChoice, harmonic_lines, identify
from mpipe.measurement.harmonic_impedance import FRAME_PERIODS, MIN_FRAMES
from mpipe.measurement.measured_instrument import bore_description
from mpipe.measurement.take_checks import check_polarity
from mpipe.measurement.validation import ValidationConfig, validate
from mpipe.measurement.validation_result import ValidationResult, plot_impedance
from mpipe.pipeline.figures import draw_now, path_second

#: Columns of ``notes.csv``.
NOTE_COLUMNS = ("segment", "note_number", "start_s", "end_s", "f0_hz", "fingering",
                "fingering_source", "fingering_probability", "runner_up", "runner_up_probability",
                "fingering_ambiguous", "fingering_fit_p", "fingering_equivalents",
                "verdict", "reason")  # fmt: skip


@dataclass(frozen=True)
class NotesValidation:
    """The per-note validation of a take.

    Attributes
    ----------
    notes : pandas.DataFrame
        One row per note, columns :data:`NOTE_COLUMNS`.
    results : dict
        Segment id to the note's :class:`ValidationResult` (verified notes only).
    verdict : str
        ``"pass"``, ``"fail"`` or ``"cannot-verify"`` for the take.
    reason : str
        One line: why.
    """

    notes: pd.DataFrame
    results: dict
    verdict: str
    reason: str

    def shown(self) -> ValidationResult | None:
        """The result plotted and tabled for the take: a failed note's, else the longest's."""
        if not self.results:
            return None
        verdicts = dict(zip(self.notes["segment"], self.notes["verdict"], strict=True))
        failed = [s for s in self.results if verdicts.get(s) == "fail"]
        if failed:
            return self.results[failed[0]]
        rows = self.notes.set_index("segment")
        return self.results[
            max(self.results, key=lambda s: rows.loc[s, "end_s"] - rows.loc[s, "start_s"])
        ]

    def lines(self) -> list[str]:
        """One line per note: its span, f0, fingering (how sure) and verdict."""
        out = []
        for _, r in self.notes.iterrows():
            out.append(
                f"note {_number(r)} ({r.start_s:.2f}-{r.end_s:.2f} s, {r.f0_hz:.1f} Hz): "
                f"{_choice_line(r)}; validation {str(r.verdict).upper()} ({r.reason})"
            )
        return out


def _number(row) -> int:
    """The note's number in the take (its segment id in a notes.csv written before)."""
    number = getattr(row, "note_number", None)
    return int(row.segment if number is None or number != number else number)


def _choice_line(row) -> str:
    choice = FingeringChoice(
        row.fingering, float(row.fingering_probability),
        row.runner_up if isinstance(row.runner_up, str) and row.runner_up else None,
        float(row.runner_up_probability), row.fingering_source,
        fit_probability=_cell(row.fingering_fit_p, 1.0),
        equivalents=tuple(x for x in str(row.fingering_equivalents).split(",") if x),
    )  # fmt: skip
    return choice.line()


def _cell(value, default: float) -> float:
    """A float from a table cell; ``default`` for a blank or missing one."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        return default
    return x if math.isfinite(x) else default


def needed_s(f0_hz: float) -> float:
    """Shortest note the validation can compare, s: :data:`MIN_FRAMES` half-overlapping frames."""
    periods = FRAME_PERIODS + (MIN_FRAMES - 1) * (FRAME_PERIODS // 2)
    return periods / f0_hz


def validate_notes(
    p: np.ndarray,
    u: np.ndarray,
    fs: float,
    calibration: Calibration,
    config: ValidationConfig,
    conditioning,
    temperature_c: float,
    segments: pd.DataFrame | None = None,
) -> NotesValidation:
    """Validate each note of a take against its own fingering.

    Parameters
    ----------
    p, u : ndarray
        Mouthpiece pressure (Pa) and flow (m^3/s).
    fs : float
        Sample rate, Hz.
    calibration : Calibration
        The instrument; its ``fingering`` is one name, ``auto`` or one name per note.
    config : ValidationConfig
        Tolerances (``note_f0_hz`` is set per note).
    conditioning : mpipe.inversion.conditioning_settings.ConditioningConfig
        The segmentation's settings.
    temperature_c : float
        Air temperature of the theory, degC.
    segments : pandas.DataFrame, optional
        The take's segments (:func:`segment_take` with the bore's resonances), when the
        caller already has them; made here otherwise.

    Returns
    -------
    NotesValidation

    Raises
    ------
    UserError
        When a list of fingerings does not give one per note (naming both counts).
    """
    if segments is None:
        segments, _ = segment_take(p, fs, conditioning, bore_resonances(calibration))
    notes = segments[segments["label"] == "note"].reset_index(drop=True)
    given = note_fingerings(calibration.fingering)
    if given is not None and len(given) != len(notes):
        # bad input (exit 2), named as soon as the notes are known: counted on the
        # mouthpiece pressure, as every later stage counts them
        starts = ", ".join(f"{t:.2f}" for t in notes["start_s"])
        raise UserError(
            f"fingering: {len(given)} fingerings given ({calibration.fingering}) for the "
            f"{len(notes)} notes found (starting at {starts or '-'} s); give one per note, "
            "or auto"
        )
    rows, results = [], {}
    trim = int(round(config.trim_s * fs))
    for i, note in notes.iterrows():
        a, b = int(round(note.start_s * fs)) + trim, int(round(note.end_s * fs)) - trim
        f0 = float(note.f0_hz)
        choice = _choose(p[a:b], u[a:b], fs, f0, calibration, given, i, temperature_c)
        row = {"segment": int(note.segment), "note_number": i + 1,
               "start_s": float(note.start_s),
               "end_s": float(note.end_s), "f0_hz": f0, **_choice_columns(choice)}  # fmt: skip
        need = needed_s(f0) if math.isfinite(f0) else math.inf
        if (b - a) / fs < need:
            row["verdict"] = "cannot-verify"
            row["reason"] = (
                f"note too short to verify: {(b - a) / fs * 1e3:.0f} ms, the impedance "
                f"estimate at {f0:.0f} Hz needs {need * 1e3:.0f} ms"
                if math.isfinite(need)
                else "no playing frequency in the note"
            )
        else:
            cal = calibration.with_fingering(choice.fingering) if choice else calibration
            cfg = dataclasses.replace(config, note_f0_hz=f0, trim_s=0.0)
            res = validate(p[a:b], u[a:b], fs, cal, cfg, temperature_c)
            fingering = f", fingering {choice.fingering}" if choice else ""
            res = dataclasses.replace(
                res, label=f"note {i + 1} ({note.start_s:.2f}-{note.end_s:.2f} s{fingering})"
            )
            results[int(note.segment)] = res
            row["verdict"], row["reason"] = res.verdict, res.reason
            if res.verdict == "fail" and res.checks < config.min_checks:
                # a PASS needs min_checks quantities; so does a FAIL of one note of a phrase
                row["verdict"] = "cannot-verify"
                row["reason"] = (
                    f"too few harmonics measurable to verify the note ({res.checks} compared, "
                    f"need {config.min_checks}: too quiet or unsteady); it differs at: "
                    + "; ".join(res.failures)
                )
        if choice is not None and not choice.fits and row["verdict"] != "cannot-verify":
            # the note's fingering is not in the list: no listed bore can check or invert it
            row["verdict"] = "fail"
            row["reason"] = f"{choice.line()}: add the fingering played to the calibration"
        rows.append(row)
    table = pd.DataFrame(rows, columns=list(NOTE_COLUMNS))
    verdict, reason = _take_verdict(table)
    return NotesValidation(table, results, verdict, reason)


def stage_validation(mouthpiece: Path, blocks: Path, cal: Calibration, cfg, draw=None):
    """The work of ``mpipe run``'s validation stage: the take, or each of its notes.

    A take of one note with one fingering is validated as a whole (the take's own spectra);
    a phrase, or a take whose fingering is per note, note by note (:func:`validate_notes`).
    Writes ``impedance.csv``, ``validation.csv``, ``harmonics.csv``, ``impedance.png`` (a
    failed note's, else the longest note's) and ``notes.csv`` (one row per note).
    """

    def work(folder: Path):
        with np.load(mouthpiece) as data:
            mp = {k: data[k] for k in data.files}
        t_eff = take_temperature(mp.get("temperature_c"), cal)
        fs = float(mp["fs"])
        # Z = P / U passes with every channel inverted; the reed's shut phase does not
        check_polarity(mp["u"], mp["p"], fs, str(mouthpiece))
        # the take is segmented once, here: the conditioning reads this file
        segments, tracks = segment_take(mp["p"], fs, cfg.conditioning, bore_resonances(cal))
        save_segmentation(folder / "segmentation.npz", segments, tracks)
        notes = None
        if per_note(cal.fingering) or int((segments["label"] == "note").sum()) != 1:
            # a phrase, or a fingering per note: each note against its own fingering
            notes = validate_notes(mp["p"], mp["u"], fs, cal, cfg.validation,
                                   cfg.conditioning, t_eff, segments)  # fmt: skip
        val = notes.shown() if notes is not None else None
        if val is None:
            val = validate(mp["p"], mp["u"], fs, _one_fingering(cal), cfg.validation, t_eff)
            if notes is not None and val.verdict != "pass" and not _measured_resonance(val):
                # nothing played and no broadband excitation showing a resonance
                val = dataclasses.replace(val, failures=(), suspects=(), checks=0)
        write_csv(folder / "impedance.csv", val.table(cfg.translation.stopband_hz))
        write_csv(folder / "validation.csv", val.resonances)
        write_csv(folder / "harmonics.csv", val.harmonics)
        # at once, or by ``draw(fn, *args)`` (a background process: mpipe.pipeline.figures)
        (draw or draw_now)(path_second, plot_impedance, val, folder / "impedance.png", 2000.0)
        verdict, reason = val.verdict, val.reason
        if notes is not None:
            write_csv(folder / "notes.csv", notes.notes)
            verdict, reason = notes.verdict, notes.reason
        summary = {
            "verdict": verdict,
            "headline": headline(verdict, notes.notes if notes is not None else None),
            "reason": reason,
            "passed": verdict == "pass",
            "failures": list(val.failures) if verdict == "fail" else [],
            "band_error_db": float(val.band_error_db),
            "text": val.summary(),
            "temperature_c": t_eff,
            "bore": bore_description(cal),
            "note_lines": notes.lines() if notes is not None else [],
            "fingering_checks": [] if notes is None else note_fingering_checks(notes.notes),
        }
        outputs = {"impedance": "impedance.csv", "resonances": "validation.csv",
                   "harmonics": "harmonics.csv", "plot": "impedance.png",
                   "segmentation": "segmentation.npz"}  # fmt: skip
        if notes is not None:
            outputs["notes"] = "notes.csv"
        return outputs, summary

    return work


def _measured_resonance(val: ValidationResult) -> bool:
    """Whether a validation measured at least one resonance (broadband excitation)."""
    errors = val.resonances["error_cents"] if len(val.resonances) else []
    return bool(np.isfinite(np.asarray(errors, dtype=float)).any())


def _one_fingering(cal: Calibration) -> Calibration:
    """The calibration of a take validated as a whole: per-note settings play the first."""
    names = note_fingerings(cal.fingering)
    if names:
        return cal.with_fingering(names[0])
    if cal.fingering == AUTO:
        return cal.with_fingering(cal.fingerings[0].name)
    return cal


def with_fingerings(
    segments: pd.DataFrame, plan: pd.DataFrame, notes: Path | pd.DataFrame | None, cal: Calibration
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``segments`` and ``plan`` with a ``fingering`` column (the note's; "" for silences).

    The fingerings are the validation's (``notes.csv``, matched by segment: the same
    segmentation); a take validated as a whole plays the calibration's one fingering.
    """
    segments, plan = segments.copy(), plan.copy()
    one = "" if per_note(cal.fingering) else (cal.fingering or "")
    by_segment: dict = {}
    table = notes if isinstance(notes, pd.DataFrame) else None
    if isinstance(notes, Path) and notes.exists():
        table = pd.read_csv(notes, keep_default_na=False)
    if table is not None:
        by_segment = dict(
            zip(table["segment"].astype(int), table["fingering"].astype(str), strict=True)
        )
    is_note = segments["label"] == "note"
    segments["fingering"] = [
        by_segment.get(int(g), one) if n else ""
        for g, n in zip(segments["segment"], is_note, strict=True)
    ]
    names = dict(zip(segments["segment"].astype(int), segments["fingering"], strict=True))
    plan["fingering"] = [names.get(int(g), "") if g == g else "" for g in plan["segment"]]
    return segments, plan


def _choose(p, u, fs, f0, calibration, given, i, t) -> FingeringChoice | None:
    """The note's fingering: the list's, the calibration's one, or found (auto)."""
    if given is not None:
        return FingeringChoice(given[i])
    if calibration.fingering != AUTO:
        return FingeringChoice(calibration.fingering) if calibration.fingering else None
    if not math.isfinite(f0) or p.size < 16:
        return None
    return identify(f0, calibration, harmonic_lines(p, u, fs, f0), t)


def _choice_columns(choice: FingeringChoice | None) -> dict:
    if choice is None:
        return {"fingering": "", "fingering_source": "", "fingering_probability": math.nan,
                "runner_up": "", "runner_up_probability": math.nan,
                "fingering_ambiguous": False, "fingering_fit_p": math.nan,
                "fingering_equivalents": ""}  # fmt: skip
    return {"fingering": choice.fingering, "fingering_source": choice.source,
            "fingering_probability": choice.probability, "runner_up": choice.runner_up or "",
            "runner_up_probability": choice.runner_up_probability,
            "fingering_ambiguous": choice.ambiguous, "fingering_fit_p": choice.fit_probability,
            "fingering_equivalents": ",".join(choice.equivalents)}  # fmt: skip


def _take_verdict(table: pd.DataFrame) -> tuple[str, str]:
    """The take's verdict from its notes' (see the module docstring)."""
    if not len(table):
        return "cannot-verify", "no note: the take holds no note to compare with the theory"
    counts = table["verdict"].value_counts()
    n_fail, n_pass = int(counts.get("fail", 0)), int(counts.get("pass", 0))
    n_cv = len(table) - n_fail - n_pass
    # the headline counts the notes actually verified: a PASS of 2 of 6 notes says so
    tally = (f"{n_pass} of {len(table)} notes verified (PASS), {n_fail} FAIL, "
             f"{n_cv} CANNOT-VERIFY")  # fmt: skip
    if n_fail:
        first = table[table["verdict"] == "fail"].iloc[0]
        return "fail", f"{tally}; note {_number(first)}: {first.reason}"
    if n_pass:
        unverified = table[table["verdict"] == "cannot-verify"]
        if len(unverified):
            first = unverified.iloc[0]
            return "pass", f"{tally}; note {_number(first)}: {first.reason}"
        return "pass", tally
    return "cannot-verify", f"{tally}; note {_number(table.iloc[0])}: {table.iloc[0].reason}"


def headline(verdict: str, table: pd.DataFrame | None) -> str:
    """The take's validation in a few words: ``PASS (2 of 6 notes verified)``."""
    if table is None or not len(table):
        return verdict.upper()
    n_pass = int((table["verdict"] == "pass").sum())
    return f"{verdict.upper()} ({n_pass} of {len(table)} notes verified)"


def note_fingering_checks(table: pd.DataFrame) -> list[str]:
    """The take-level checks of the notes' fingerings: each ambiguous note, one line."""
    out = []
    if "fingering_fit_p" in table:
        fit = pd.to_numeric(table["fingering_fit_p"], errors="coerce").fillna(1.0)
        for _, r in table[(fit < NO_FIT_BELOW) & (table["verdict"] != "cannot-verify")].iterrows():
            out.append(
                f"note {int(r.segment)}: no listed fingering fits its harmonics (the closest, "
                f"{r.fingering}, at p = {float(r.fingering_fit_p):.1g}): add the fingering played"
            )
    for _, r in table[table["fingering_ambiguous"].astype(bool)].iterrows():
        out.append(
            f"note {_number(r)}: the fingering is ambiguous: {r.fingering} "
            f"(p = {r.fingering_probability:.2f}) or {r.runner_up} "
            f"(p = {r.runner_up_probability:.2f}); give --fingering with one name per note"
        )
    return out


def say_validation(say: Callable[[str], None], name: str, summary: dict) -> None:
    """The validation's verdict, and each note's line (fingering, verdict) of a phrase."""
    say(f"[{name}]     impedance validation: "
        f"{summary.get('headline', summary['verdict'].upper())} "
        f"({summary.get('reason', '')})")  # fmt: skip
    for line in summary.get("note_lines", []):
        say(f"[{name}]       {line}")


__all__ = [
    "say_validation",
    "headline",
    "NOTE_COLUMNS",
    "NotesValidation",
    "needed_s",
    "note_fingering_checks",
    "stage_validation",
    "validate_notes",
]
