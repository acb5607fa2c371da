"""The verdict of a take: PASS, CHECK or FAIL, with the reason in words.

A window that is not ok is flagged on its own, with its reason
(:mod:`mpipe.inversion.trust.status`); the take's verdict weighs the validation, the
take-level checks (:mod:`mpipe.inversion.trust.diagnostics`) and whether each note rests on
enough of its windows.
How often each verdict fires on correct takes and catches faulty ones is measured by
``benchmarks/bench_verdicts.py`` (issue 38).
"""

from __future__ import annotations

from collections.abc import Sequence

import pandas as pd

#: A note whose result rests on fewer than this fraction of its windows makes the take CHECK.
#: Windows that are not ok are flagged one by one with their reason; the take as a whole asks
#: for a look only where a note's value rests on a minority of its windows (issue 38: the rule
#: "any window not ok" fired on most correct takes, where one or two windows at a note's
#: attack or release sit on a bound).
MIN_NOTE_OK_FRACTION = 0.5
#: Notes with fewer windows than this are not judged by :data:`MIN_NOTE_OK_FRACTION`.
MIN_NOTE_WINDOWS = 3


def _thin_notes(windows: pd.DataFrame) -> list[str]:
    """Each note resting on a minority of its windows, as "note i: a of b windows ok"."""
    if "segment" not in windows or not len(windows):
        return []
    out = []
    groups = windows.groupby("segment", sort=True)
    for i, (_, note) in enumerate(groups, start=1):
        status = note["status"]
        if "note_number" in note and (note["note_number"] > 0).all():
            i = int(note["note_number"].iloc[0])  # the take's note number, as everywhere
        n, ok = len(status), int((status == "ok").sum())
        if n >= MIN_NOTE_WINDOWS and ok < MIN_NOTE_OK_FRACTION * n:
            out.append(f"note {i}: {ok} of {n} windows ok")
    return out


def overall_verdict(
    validation: str | bool, windows: pd.DataFrame, take_checks: Sequence[str] = ()
) -> tuple:
    """``(label, kind)`` of the take: FAIL, CHECK or PASS, with the reason in the label.

    ``validation`` is the validation's verdict (``"pass"``, ``"fail"``, ``"cannot-verify"``)
    or a bool (passed); ``take_checks`` the inversion's take-level reasons
    (:func:`mpipe.inversion.trust.diagnostics.take_checks`), each of which makes the take CHECK.
    A take whose windows are not all ok still PASSes (each such window is flagged with its
    reason) unless a note rests on fewer than :data:`MIN_NOTE_OK_FRACTION` of its windows.
    """
    if isinstance(validation, bool):
        validation = "pass" if validation else "fail"
    n = len(windows)
    n_ok = int((windows["status"] == "ok").sum()) if n else 0
    if validation == "fail":
        return "FAIL: the impedance validation failed", "fail"
    if n_ok == 0:
        return "FAIL: no window has status ok (no usable result)", "fail"
    if validation != "pass":
        return "CHECK: the impedance validation could not verify the measurement", "check"
    if take_checks:
        return "CHECK: " + "; ".join(take_checks), "check"
    thin = _thin_notes(windows)
    if thin:
        return "CHECK: " + "; ".join(thin) + " (see their reasons)", "check"
    if n_ok < n:
        return (f"PASS: validation passed, {n_ok} of {n} windows ok ({n - n_ok} flagged with "
                "their reasons)", "pass")  # fmt: skip
    return f"PASS: validation passed, all {n} windows ok", "pass"


__all__ = ["MIN_NOTE_OK_FRACTION", "MIN_NOTE_WINDOWS", "overall_verdict"]
