"""Which calibration each take of ``mpipe run`` is read with, and whether it is the take's own.

A take may come with its own calibration beside it: ``TAKE.calibration.yaml`` for
``TAKE.flac`` (a virtual take's copy, :func:`mpipe.reed.take_files.take_file_paths`, or a
recording session's file written the same way). Its sensitivities fit that file only: a
take read with another take's calibration gets pressures, flows, p_m and p_M scaled by the
ratio of the sensitivities (two takes of one batch came out p_m -35 %), and nothing in the
signals shows it (the validation compares P/U, which a common scale leaves alone).

The rule (:func:`take_calibrations`):

1. a take with its own calibration beside it is read with it;
2. a take without one is read with ``--calibration FILE`` when given, else with the
   pipeline file's ``calibration``;
3. ``--calibration FILE`` given while a take has a different calibration of its own beside
   it is refused (one line, exit 2, before any work): the command line cannot say which
   one was meant. (Two calibrations are the same when they are one file, or when they
   describe the same instrument and microphones, relative tables included.)

A take's sidecar (``TAKE.yaml``, written with a virtual take) records the sensitivities it
was written with; a take read with others is CHECK (:func:`sidecar_check`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import yaml

from mpipe.core.config import ConfigError
from mpipe.core.errors import UserError
from mpipe.measurement.calibration import Calibration, load_calibration
from mpipe.reed.take_files import calibration_mapping, take_file_paths

#: Sensitivities agree when their ratio is within this of 1 (the file holds 17 digits).
SENSITIVITY_TOLERANCE = 1e-6


def own_calibration(take: Sequence[str | Path]) -> Path | None:
    """The calibration beside a take's (first) file, ``TAKE.calibration.yaml``, if any."""
    path = take_file_paths(Path(take[0])).calibration
    return path if path.is_file() else None


def same_calibration(a: Path, b: Path, fingering: str | None = None) -> bool:
    """Whether two calibration files describe the same instrument and microphones."""
    if Path(a).resolve() == Path(b).resolve():
        return True
    return _content(a, fingering) == _content(b, fingering)


def _content(path: Path, fingering: str | None) -> dict:
    """The calibration as data, each relative microphone table by its contents."""
    try:
        cal = load_calibration(path, fingering)
    except (ConfigError, OSError) as exc:
        raise UserError(str(exc).splitlines()[0]) from None
    data = calibration_mapping(cal)
    for mic, entry in zip(cal.microphones, data.get("microphones", []), strict=False):
        table = cal.calibration_path(mic)
        if table is not None:
            entry["calibration"] = table.read_bytes() if table.is_file() else str(table)
    data.pop("name", None)
    return data


def take_calibrations(
    takes: Sequence[Sequence[Path]],
    given: Path | None,
    pipeline: Path,
    fingering: str | None = None,
) -> list[Path]:
    """Each take's calibration by the module's rule; refuses a mix it cannot resolve.

    Parameters
    ----------
    takes : sequence of sequences of Path
        The files of each take.
    given : Path or None
        ``--calibration``.
    pipeline : Path
        The pipeline file's calibration.
    fingering : str or None
        The fingering played (for loading the calibrations compared).

    Raises
    ------
    UserError
        One line naming the take, its own calibration and the one given.
    """
    out = []
    for take in takes:
        own = own_calibration(take)
        if own is not None and given is not None and not same_calibration(own, given, fingering):
            raise UserError(
                f"{take[0]}: has its own calibration {own} beside it, and --calibration "
                f"{given} differs from it; leave --calibration out to read each take with "
                "its own, or move the take's copy away to read it with the one given"
            )
        out.append(own or given or pipeline)
    return out


def sidecar_check(take: Sequence[str | Path], calibration: Calibration) -> str:
    """Why a take is read with sensitivities other than its sidecar's ("" when it is not).

    The sidecar (``TAKE.yaml`` with ``file_sensitivity_pa``, Pa per full-scale unit, one
    per microphone in the calibration's order) is written with a virtual take; a take
    without one is not checked.
    """
    path = take_file_paths(Path(take[0])).sidecar
    try:
        recorded = yaml.safe_load(path.read_text()) if path.is_file() else None
    except (OSError, yaml.YAMLError):
        return ""
    if not isinstance(recorded, dict) or not isinstance(recorded.get("file_sensitivity_pa"), list):
        return ""
    want = [float(v) for v in recorded["file_sensitivity_pa"]]
    used = [float(m.sensitivity) for m in calibration.microphones]
    if len(want) == len(used) and all(
        math.isclose(w, u, rel_tol=SENSITIVITY_TOLERANCE) for w, u in zip(want, used, strict=True)
    ):
        return ""
    ratio = used[0] / want[0] if want and want[0] else math.nan
    return (
        f"the take is read with microphone sensitivities ({', '.join(f'{v:.4g}' for v in used)} "
        f"Pa per unit, from {calibration.source}) other than those its sidecar {path.name} "
        f"records ({', '.join(f'{v:.4g}' for v in want)}): another take's calibration? "
        f"Pressures, p_m and p_M scale by {ratio:.3g}"
    )


def calibration_inputs(cal: Calibration, cal_path: Path) -> dict:
    """The files a calibration reads (every stage's inputs): itself, a measured bore, tables."""
    found = {"calibration": cal_path}
    if cal.bore.measured_input is not None:
        found["measured_impedance"] = Path(cal.bore.measured_input.source)
    for mic in cal.microphones:
        path = cal.calibration_path(mic)
        if path is not None:
            found[f"mic_calibration_{mic.name}"] = path
    return found


def conditioning_config(cfg) -> dict:
    """The settings the conditioning stage depends on (its manifest's configuration)."""
    return {"conditioning": cfg.conditioning, "window_s": cfg.inversion.window_s,
            "hop_s": cfg.inversion.hop_s, "signal": cfg.inversion.signal}  # fmt: skip


def present(**paths: Path) -> dict:
    """The paths that exist (an optional input of a stage)."""
    return {k: v for k, v in paths.items() if v.exists()}


__all__ = [
    "calibration_inputs",
    "conditioning_config",
    "present",
    "SENSITIVITY_TOLERANCE",
    "own_calibration",
    "same_calibration",
    "sidecar_check",
    "take_calibrations",
]
