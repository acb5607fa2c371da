"""A recording session: the takes of a lab's day, each with its calibration and fingering.

A session file (YAML, read by :func:`mpipe.core.config.load_yaml`, which refuses a key
given twice) lists the takes::

    pipeline: pipeline.yaml          # required; paths are relative to this file
    calibration: monday.yaml         # optional: the takes' calibration (else each take's
                                     #   own beside it, else the pipeline's)
    fingering: xxxo                  # optional: the takes' fingering (else the pipeline's)
    takes:
      - take: takes/scale_p.flac     # one file, or a list of mono files (one per mic)
        name: scale_p                # optional: its folder under OUT (default: the stem)
        calibration: tuesday.yaml    # optional: this take's own
        fingering: xxoo              # optional
        score: scores/scale.yaml     # optional: what was to be played (a score file)
        notes: "soft reed, p"        # optional: free text, kept in session_takes.csv

Everything is checked by :func:`load_session` before any work, each problem one line
naming the file, the take and the key: unknown keys, missing files, a calibration that
does not load or lacks the fingering, a score that does not load, two takes of one
folder, a take too short for one window, and a calibration given for a take that has a
different one of its own beside it (:mod:`mpipe.pipeline.take_calibration`).
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import soundfile as sf

from mpipe.core.config import ConfigError, load_yaml
from mpipe.core.errors import UserError
from mpipe.inversion.preparation.span import check_span
from mpipe.measurement.calibration import load_calibration
from mpipe.pipeline.settings import PipelineConfig, load_pipeline
from mpipe.pipeline.take_calibration import own_calibration, same_calibration
from mpipe.reed.score import load_score

#: Keys of the session file and of each take.
SESSION_KEYS = ("pipeline", "calibration", "fingering", "takes")
TAKE_KEYS = ("take", "name", "calibration", "fingering", "score", "notes")
#: A take's folder name: letters, digits, ``._-``, not starting with a dot.
NAME = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9._-]*")


@dataclass(frozen=True)
class SessionTake:
    """One take of a session, its paths resolved.

    Attributes
    ----------
    name : str
        Its folder under the output folder.
    files : tuple of Path
        One multichannel file or one mono file per microphone.
    calibration : Path
        The calibration it is read with.
    fingering : str or None
        The fingering played (None: the calibration's default).
    score : Path or None
        What was to be played (a score file), if given.
    notes : str
        Free text about the take.
    """

    name: str
    files: tuple[Path, ...]
    calibration: Path
    fingering: str | None
    score: Path | None = None
    notes: str = ""


@dataclass(frozen=True)
class Session:
    """A session file, checked.

    Attributes
    ----------
    source : Path
        The session file.
    pipeline : PipelineConfig
        The pipeline every take runs with (its fingering is each take's).
    pipeline_path : Path
        The pipeline file.
    takes : tuple of SessionTake
        In the file's order.
    """

    source: Path
    pipeline: PipelineConfig
    pipeline_path: Path
    takes: tuple[SessionTake, ...]

    def config_of(self, take: SessionTake) -> PipelineConfig:
        """The pipeline with the take's fingering."""
        return dataclasses.replace(self.pipeline, fingering=take.fingering)


def _where(source: Path, index: int | None, name: str | None, key: str) -> str:
    if index is None:
        return f"{source}: {key}"
    label = f" ({name})" if name else ""
    return f"{source}: takes[{index}]{label}: {key}"


def _unknown(data: Mapping, allowed: tuple[str, ...], where: str) -> None:
    for key in data:
        if key not in allowed:
            raise UserError(f"{where}{key}: unknown key (expected one of: {', '.join(allowed)})")


def _text(value, where: str, optional: bool = True) -> str | None:
    if value is None and optional:
        return None
    if not isinstance(value, str | int | float) or isinstance(value, bool) or value == "":
        raise UserError(f"{where}: expected a text, got {value!r}")
    return str(value)


def _file(base: Path, value, where: str) -> Path:
    path = base / _text(value, where, optional=False)
    if not path.is_file():
        raise UserError(f"{where}: no such file {path}")
    return path


def load_session(path: str | Path) -> Session:
    """Read and check a session file (see the module docstring).

    Raises
    ------
    UserError
        One line naming the file, the take (its index and name) and the key.
    """
    source = Path(path)
    try:
        data = load_yaml(source)
    except ConfigError as exc:
        raise UserError(str(exc)) from None
    base = source.parent
    _unknown(data, SESSION_KEYS, f"{source}: ")
    pipeline_path = _file(base, data.get("pipeline"), _where(source, None, None, "pipeline"))
    try:
        cfg = load_pipeline(pipeline_path, check_calibration=False)
    except ConfigError as exc:
        raise UserError(f"{source}: pipeline: {exc}") from None
    calibration = data.get("calibration")
    default_cal = (
        None
        if calibration is None
        else _file(base, calibration, _where(source, None, None, "calibration"))
    )
    default_fingering = _text(data.get("fingering"), _where(source, None, None, "fingering"))
    entries = data.get("takes")
    if not isinstance(entries, list) or not entries:
        raise UserError(f"{source}: takes: expected a list of takes (each with a 'take' file)")
    takes, seen, files = [], {}, {}
    for i, entry in enumerate(entries):
        take = _take(source, i, entry, cfg, default_cal, default_fingering)
        # one file twice is not a name clash: renaming one would only meet this refusal
        first = files.setdefault(take.files[0].resolve(), i)
        if first != i:
            raise UserError(
                f"{_where(source, i, take.name, 'take')}: {take.files[0]} is listed twice "
                f"(takes[{first}] lists it too): remove one of the two entries"
            )
        if take.name in seen:
            raise UserError(
                f"{_where(source, i, take.name, 'name')}: takes[{seen[take.name]}] has this "
                "name too (one folder per take): give one of them another 'name'"
            )
        seen[take.name] = i
        takes.append(take)
    checked: dict = {}
    for i, take in enumerate(takes):
        _check_take(source, i, take, cfg, checked)
    return Session(source, cfg, pipeline_path, tuple(takes))


def _take(source, i, entry, cfg, default_cal, default_fingering) -> SessionTake:
    """One entry of ``takes``, its paths resolved (files checked, not yet read)."""
    base = source.parent
    if isinstance(entry, str):
        entry = {"take": entry}
    if not isinstance(entry, Mapping):
        raise UserError(f"{source}: takes[{i}]: expected a mapping with a 'take' file")
    name = _text(entry.get("name"), _where(source, i, None, "name"))
    _unknown(entry, TAKE_KEYS, f"{source}: takes[{i}]{f' ({name})' if name else ''}: ")
    raw = entry.get("take")
    if raw is None:
        raise UserError(f"{_where(source, i, name, 'take')}: missing (the take's file)")
    values = raw if isinstance(raw, list) else [raw]
    files = tuple(_file(base, v, _where(source, i, name, "take")) for v in values)
    name = name or files[0].stem
    if not NAME.fullmatch(name):
        raise UserError(
            f"{_where(source, i, name, 'name')}: {name!r} cannot be a folder name (letters, "
            "digits, '.', '_' and '-')"
        )
    where = _where(source, i, name, "calibration")
    given = entry.get("calibration")
    cal = _file(base, given, where) if given is not None else default_cal
    own = own_calibration(files)
    fingering = _text(entry.get("fingering"), _where(source, i, name, "fingering"))
    fingering = fingering or default_fingering or cfg.fingering
    if cal is not None and own is not None and not same_calibration(own, cal, fingering):
        raise UserError(
            f"{where}: {cal} differs from the take's own calibration {own} beside it; leave "
            "'calibration' out to read the take with its own, or move the copy away"
        )
    score = entry.get("score")
    score_path = None if score is None else _file(base, score, _where(source, i, name, "score"))
    notes = _text(entry.get("notes"), _where(source, i, name, "notes")) or ""
    return SessionTake(
        name, files, cal or own or cfg.calibration_path, fingering, score_path, notes
    )


def _check_take(source: Path, i: int, take: SessionTake, cfg: PipelineConfig, checked) -> None:
    """The take's calibration, fingering, score and length, before any work."""
    key = (take.calibration.resolve(), take.fingering)
    if key not in checked:
        try:
            load_calibration(take.calibration, take.fingering)
        except (ConfigError, OSError) as exc:
            what = "fingering" if take.fingering and "fingering" in str(exc) else "calibration"
            raise UserError(f"{_where(source, i, take.name, what)}: {exc}") from None
        checked[key] = True
    if take.score is not None:
        try:
            load_score(take.score)
        except ConfigError as exc:
            raise UserError(f"{_where(source, i, take.name, 'score')}: {exc}") from None
    try:
        info = sf.info(str(take.files[0]))
    except (RuntimeError, OSError) as exc:
        raise UserError(
            f"{_where(source, i, take.name, 'take')}: {take.files[0]}: not a readable audio "
            f"file ({exc})"
        ) from None
    try:
        check_span(info.frames, info.samplerate, cfg.conditioning.edge_s,
                   cfg.inversion.window_s, None, None)  # fmt: skip
    except ValueError as exc:
        raise UserError(f"{_where(source, i, take.name, 'take')}: {exc}") from None


__all__ = ["NAME", "SESSION_KEYS", "TAKE_KEYS", "Session", "SessionTake", "load_session"]
