"""A small YAML score for virtual takes: notes with their controls, silences between them.

A score is a list of notes; each note says when it starts, how long it lasts and how it is
blown, and :func:`score_controls` turns it into the per-sample :class:`Controls` that
:func:`mpipe.reed.controls.play` plays. Example (every key but ``duration`` optional)::

    description: three tongued notes with 0.25 s silences
    end: 0.05                    # s of silence after the last note
    notes:
      - duration: 0.7            # s, from the note's start to the end of its release
        p_m: 1800                # Pa; a number, or [[t, value], ...] breakpoints
        y_m: 4.0e-4              # m; so k, S, lambda, m, g, k_c (default: the reed file)
        attack: 0.02             # s, raised-cosine rise of p_m from 0
        release: 0.03            # s, raised-cosine fall of p_m to 0 at the note's end
        tongued: true            # the tongue holds the reed shut at the start ...
        tongue_hold: 0.03        # ... for this long, s (p_m rises behind it)
        vibrato: {rate: 5, depth: 0.08, delay: 0.2}   # Hz, fraction of p_m, s
        fingering: xxxx          # a name of the calibration's fingerings (default: the
                                 # previous note's; the first: the take's fingering)
      - gap: 0.25                # s of silence before this note (or start: absolute s)
        duration: 0.7
        p_m: [[0, 1800], [0.5, 2400]]   # a crescendo: linear between breakpoints

Breakpoint times are in s from the note's start; before the first and after the last the
curve holds its end value. A note with another fingering than the one before changes it
over ``finger_s`` (a score key, 5 ms by default) ending at the note's start: a slur when
there is no gap (:mod:`mpipe.reed.fingered_bore` says how the bore changes). Between
notes the mouth pressure is 0 (the player breathes) and
the reed parameters keep the previous note's last values. A note is *sounding* from the
end of its tongue hold (or its start) to the end of its release; these spans go into the
take's truth.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mpipe.core.config import ConfigError, Where, between, build, load_yaml, positive, spec
from mpipe.reed.controls import CURVE_FIELDS, Controls
from mpipe.reed.parameters import PLAUSIBLE, ReedParameters

Breakpoints = tuple[tuple[float, ...], ...]
#: Shortest sounding part of a note, s: the default ``conditioning.min_note_s``, below which
#: the pipeline finds no note (a score of 10 000 notes of 2 ms played as one note).
MIN_NOTE_S = 0.03
#: Score keys of the curves (``lambda`` is the reed's ``lam``).
CURVE_KEYS = {"p_m": "p_m", **{("lambda" if f == "lam" else f): f for f in CURVE_FIELDS}}
_UNITS = {"p_m": "Pa", "k": "Pa/m", "S": "m^2", "y_m": "m", "lam": "m", "m": "kg/m^2"}
_UNITS.update({"g": "1/s", "k_c": "Pa/m^alpha"})


def _non_negative(value: float) -> str | None:
    return None if value >= 0 else f"expected a value >= 0, got {value:g}"


@dataclass(frozen=True)
class Vibrato:
    """A sinusoidal vibrato on the mouth pressure: p_m (1 + depth sin(2 pi rate t))."""

    rate: float = spec("Hz", "vibrato rate", between(0.1, 50.0))
    depth: float = spec("", "relative depth on p_m (0.08: ±8 %)", between(0.0, 0.9))
    delay: float = spec("s", "from the note's start to the vibrato's", _non_negative, default=0.0)


@dataclass(frozen=True)
class Note:
    """One note of a score; curves are ``((t, value), ...)`` breakpoints, t from the start."""

    duration: float = spec("s", "from the note's start to the end of its release", positive)
    start: float | None = spec("s", "absolute start (default: after gap)", default=None)
    gap: float = spec("s", "silence before the note", _non_negative, default=0.0)
    attack: float = spec("s", "raised-cosine rise of p_m", _non_negative, default=0.01)
    release: float = spec("s", "raised-cosine fall of p_m", _non_negative, default=0.03)
    tongued: bool = spec("", "the tongue holds the reed shut at the start", default=False)
    tongue_hold: float = spec("s", "length of the tongue hold", positive, default=0.03)
    vibrato: Vibrato | None = spec("", "vibrato on p_m", default=None)
    p_m: Breakpoints | None = spec("Pa", "mouth pressure", default=None)
    k: Breakpoints | None = spec("Pa/m", "reed stiffness", default=None)
    S: Breakpoints | None = spec("m^2", "effective reed area", default=None)
    y_m: Breakpoints | None = spec("m", "rest opening", default=None)
    lam: Breakpoints | None = spec("m", "slit width (key: lambda)", default=None)
    m: Breakpoints | None = spec("kg/m^2", "reed mass per unit area", default=None)
    g: Breakpoints | None = spec("1/s", "damping rate", default=None)
    k_c: Breakpoints | None = spec("Pa/m^alpha", "contact stiffness", default=None)
    fingering: str | None = spec(
        "",
        "the fingering of the note, a name of the calibration's fingerings (null: the "
        "previous note's; the first note: the take's fingering)",
        default=None,
    )

    file_keys = {"lam": "lambda"}  # as in reed files; ``lam`` in code and tables

    def _check(self, where: Where) -> None:
        if self.start is not None and self.gap:
            raise where.error("gap", "give start or gap, not both")
        if self.start is not None and self.start < 0:
            raise where.error("start", f"expected a value >= 0, got {self.start:g} [s]")
        held = self.tongue_hold if self.tongued else 0.0
        if held + self.release >= self.duration:
            raise where.error(
                "duration",
                f"{self.duration:g} s leaves no sounding part after the tongue hold "
                f"({held:g} s) and the release ({self.release:g} s)",
            )
        if self.duration - held < MIN_NOTE_S:
            raise where.error(
                "duration",
                f"{self.duration:g} s sounds for {self.duration - held:g} s, shorter than "
                f"{MIN_NOTE_S:g} s: mpipe finds no note in it (conditioning.min_note_s); "
                "expected a longer note, or one note whose p_m curve plays the fast changes",
            )
        for key, name in CURVE_KEYS.items():
            _check_breakpoints(getattr(self, name), where.child(key), name)

    @property
    def sound_offset(self) -> float:
        """Time from the note's start to the release of the tongue, s (0 if not tongued)."""
        return self.tongue_hold if self.tongued else 0.0


def _check_breakpoints(points: Breakpoints | None, where: Where, name: str) -> None:
    """Refuse a curve that is not breakpoints of plausible values (as in a reed file)."""
    if points is None:
        return
    if not points:
        raise where.error(None, "expected a number or a list of [t, value] pairs")
    unit = _UNITS.get(name, "")
    lo, hi = PLAUSIBLE[name]
    times = []
    for i, pair in enumerate(points):
        # a constant (one breakpoint) is named by its key alone: notes[0].p_m
        at = where if len(points) == 1 else where.child(i)
        if len(pair) != 2:
            raise at.error(None, f"expected a pair [t, value], got {list(pair)}")
        times.append(pair[0])
        if not pair[1] > 0:
            raise at.error(None, f"expected a positive value, got {pair[1]:g} [{unit}]")
        if not lo <= pair[1] <= hi:
            raise at.error(
                None, f"implausible value {pair[1]:g} {unit}; expected a value in [{lo:g}, {hi:g}]"
            )
    if times[0] < 0 or any(b < a for a, b in zip(times[:-1], times[1:], strict=True)):
        raise where.error(None, "breakpoint times must be >= 0 s and non-decreasing")


@dataclass(frozen=True)
class Score:
    """A phrase: notes in order, and the silence after the last one."""

    notes: tuple[Note, ...] = spec("", "the notes, in order")
    end: float = spec("s", "silence after the last note", _non_negative, default=0.05)
    description: str = spec("", "what the score plays", default="")
    finger_s: float = spec(
        "s",
        "time the fingers take to change from one fingering to the next, ending at the "
        "next note's start (the holes open or close over it)",
        between(0.0, 0.1),
        default=0.005,
    )

    def _check(self, where: Where) -> None:
        if not self.notes:
            raise where.error("notes", "expected at least one note")
        previous_end = 0.0
        for i, (note, t0) in enumerate(zip(self.notes, self.starts(), strict=True)):
            if t0 < previous_end - 1e-12:
                raise (
                    where.child("notes")
                    .child(i)
                    .error(
                        "start",
                        f"{t0:g} s overlaps notes[{i - 1}], which ends at {previous_end:g} s",
                    )
                )
            previous_end = t0 + note.duration

    def starts(self) -> list[float]:
        """Start time of each note, s."""
        out, t = [], 0.0
        for note in self.notes:
            t = note.start if note.start is not None else t + note.gap
            out.append(t)
            t += note.duration
        return out

    @property
    def duration(self) -> float:
        """Length of the take the score plays, s."""
        return self.starts()[-1] + self.notes[-1].duration + self.end

    def fingerings(self, first: str | None) -> list[str | None]:
        """Each note's fingering: its own, else the previous note's (the first: ``first``)."""
        out, current = [], first
        for note in self.notes:
            current = note.fingering if note.fingering is not None else current
            out.append(current)
        return out

    def sounding(self) -> tuple[tuple[float, float], ...]:
        """Sounding span of each note (tongue released, to the end of the release), s."""
        return tuple(
            (t0 + note.sound_offset, t0 + note.duration)
            for note, t0 in zip(self.notes, self.starts(), strict=True)
        )


def load_score(path: str | Path) -> Score:
    """Read a score file (see the module docstring); errors name the file and key."""
    return score_from_mapping(load_yaml(path), str(path))


def score_from_mapping(data: Mapping[str, Any], source: str = "<score>") -> Score:
    """A :class:`Score` from a parsed YAML mapping; ``source`` names it in errors."""
    where = Where(source)
    if not isinstance(data, Mapping):
        raise where.error(None, "expected a mapping with a 'notes' list")
    notes = data.get("notes")
    if not isinstance(notes, list):
        raise where.error("notes", "expected a list of notes")
    data = dict(data)
    data["notes"] = [
        _curves_as_breakpoints(n, where.child("notes").child(i)) for i, n in enumerate(notes)
    ]
    return build(Score, data, where)


def _curves_as_breakpoints(note: Any, where: Where) -> Any:
    """A note mapping with constant curves as one breakpoint."""
    if not isinstance(note, Mapping):
        raise where.error(None, "expected a mapping (duration, p_m, ...)")
    return {
        key: [[0.0, float(value)]] if key in CURVE_KEYS and _is_number(value) else value
        for key, value in note.items()
    }


def _is_number(value: Any) -> bool:
    if isinstance(value, bool):
        return False
    if isinstance(value, int | float):
        return True
    try:
        return isinstance(value, str) and math.isfinite(float(value))
    except ValueError:
        return False


def score_controls(
    score: Score, reed: ReedParameters, fs: float, duration_s: float | None = None
) -> Controls:
    """Per-sample controls of a score, for :func:`mpipe.reed.controls.play`.

    Parameters
    ----------
    score : Score
        The notes.
    reed : ReedParameters
        Values of the curves a note does not give (its ``p_m`` too).
    fs : float
        Model sample rate, Hz.
    duration_s : float, optional
        Length of the take, s; default the score's; longer adds silence at the end.

    Returns
    -------
    Controls

    Raises
    ------
    ConfigError
        When ``duration_s`` is shorter than the score.
    """
    length = score.duration if duration_s is None else float(duration_s)
    if length < score.duration - 1e-9:
        raise ConfigError(f"duration {length:g} s is shorter than the score ({score.duration:g} s)")
    n = int(round(length * fs))
    t = np.arange(1, n + 1) / fs
    starts = score.starts()
    p_m = np.zeros(n)
    given = {name for note in score.notes for name in CURVE_FIELDS if getattr(note, name)}
    curves = {name: np.empty(n) for name in given}
    for i, (note, t0) in enumerate(zip(score.notes, starts, strict=True)):
        span = _samples(t, t0, t0 + note.duration)
        local = t[span] - t0
        level = _curve(note.p_m, local, reed.p_m) * _envelope(note, local)
        if note.vibrato is not None:
            v = note.vibrato
            level *= np.where(
                local >= v.delay,
                1.0 + v.depth * np.sin(2 * np.pi * v.rate * (local - v.delay)),
                1.0,
            )
        p_m[span] = level
        # reed values hold from this note's start to the next note's (first: from t = 0)
        hold_to = starts[i + 1] if i + 1 < len(starts) else math.inf
        reach = _samples(t, -math.inf if i == 0 else t0, hold_to)
        for name in given:
            curves[name][reach] = _curve(getattr(note, name), t[reach] - t0, getattr(reed, name))
    tongue = tuple(
        (t0, t0 + note.tongue_hold)
        for note, t0 in zip(score.notes, starts, strict=True)
        if note.tongued
    )
    spans = tuple(
        (int(np.searchsorted(t, a - 1e-12)), int(np.searchsorted(t, b - 1e-12))) for a, b in tongue
    )
    return Controls(
        fs=float(fs),
        p_m=p_m,
        reed=curves,
        tongue=tuple((a, b) for a, b in spans if b > a),
        notes=score.sounding(),
    )


def _samples(t: np.ndarray, start: float, stop: float) -> slice:
    """Samples with ``start <= t < stop``."""
    return slice(int(np.searchsorted(t, start - 1e-12)), int(np.searchsorted(t, stop - 1e-12)))


def _curve(points: Breakpoints | None, local: np.ndarray, default: float) -> np.ndarray:
    """A breakpoint curve at times ``local`` (s from the note's start), held beyond its ends."""
    if points is None:
        return np.full(local.shape, float(default))
    times = np.array([p[0] for p in points])
    values = np.array([p[1] for p in points])
    return np.interp(local, times, values)


def _envelope(note: Note, local: np.ndarray) -> np.ndarray:
    """Raised-cosine attack from 0 and release to 0 of a note's mouth pressure (0..1)."""
    env = np.ones(local.shape)
    if note.attack > 0:
        rising = local < note.attack
        env[rising] = 0.5 * (1 - np.cos(np.pi * local[rising] / note.attack))
    if note.release > 0:
        left = note.duration - local
        falling = left < note.release
        env[falling] *= 0.5 * (1 - np.cos(np.pi * np.clip(left[falling], 0, None) / note.release))
    return env


def score_mapping(score: Score) -> dict[str, Any]:
    """The score as a plain YAML-ready mapping (for a take's sidecar), keyed as a score file."""
    out = dataclasses.asdict(score)
    out["notes"] = [
        {Note.file_keys.get(key, key): value for key, value in note.items()}
        for note in out["notes"]
    ]
    return out


__all__ = [
    "Note",
    "Score",
    "Vibrato",
    "load_score",
    "score_controls",
    "score_from_mapping",
    "score_mapping",
]
