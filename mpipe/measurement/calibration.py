"""The calibration file: instrument geometry, air, microphones and reference plane.

One YAML file per measured instrument set-up (see ``calibration/simplified_clarinet.yaml``).
Paths inside it (microphone calibration tables) are relative to the file.

An instrument with tone holes names its fingerings (which holes are open) beside the bore::

    bore:
      segments: [...]
      holes:
        - {name: hole1, position: 0.10, radius: 0.0015, chimney: 0.0017}   # metres
    fingerings:            # name -> the holes that are open
      xxxx: []
      oxxx: [hole1]
    fingering: xxxx        # the default

The loader opens the holes of the chosen fingering (the file's default, or the one given to
:func:`load_calibration`) in ``calibration.bore``, which every stage then uses.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path

from mpipe.acoustics.air import AIR_MODELS, Air, air_properties
from mpipe.acoustics.bore import JOIN_TOLERANCE, Bore
from mpipe.core.config import ConfigError, Where, between, build, load_yaml, positive, spec
from mpipe.measurement.measured_instrument import attach_measured_bore


@dataclass(frozen=True)
class AirSettings:
    """Air conditions assumed in the bore."""

    temperature_c: float = spec(
        "degC", "air temperature in the bore", between(-20.0, 60.0, "degrees Celsius")
    )
    model: str = spec(
        "",
        f"air property formulas, one of {AIR_MODELS}",
        lambda v: None if v in AIR_MODELS else f"expected one of {AIR_MODELS}, got {v!r}",
        default="keefe",
    )
    humidity: float = spec(
        "", "relative humidity in [0, 1] (model 'ernoult' only)", between(0.0, 1.0), default=0.0
    )
    co2_fraction: float = spec(
        "", "molar fraction of CO2 (model 'ernoult' only)", between(0.0, 0.1), default=4.2e-4
    )

    def _check(self, where: Where) -> None:
        if self.model == "keefe" and self.humidity != 0.0:
            raise where.error("humidity", "the 'keefe' air model is for dry air; use 'ernoult'")

    def properties(self, temperature_c: float | None = None) -> Air:
        """Air properties at the configured (or the given) temperature in degC."""
        t = self.temperature_c if temperature_c is None else temperature_c
        return air_properties(t, self.model, self.humidity, self.co2_fraction)


@dataclass(frozen=True)
class Microphone:
    """A pressure microphone in the bore wall."""

    name: str = spec("", "label")
    position: float = spec("m", "axial position from the mouthpiece entry", between(0.0, 5.0))
    channel: int = spec("", "channel in the recording, counted from 1", between(1, 64))
    sensitivity: float = spec(
        "Pa", "pressure per unit of the recorded signal", positive, default=1.0
    )
    sensitivity_se_db: float | None = spec(
        "dB",
        "standard uncertainty of the sensitivity (the first microphone's sets the take's "
        "common scale; null: 0.15 dB assumed, a pistonphone calibration's, see "
        "docs/uncertainty.md)",
        between(0.0, 6.0),
        default=None,
    )
    calibration: str | None = spec(
        "",
        "optional CSV (frequency_hz, magnitude, phase_deg) of the complex relative "
        "calibration H_c of this microphone against microphone 1 (physics.md E.6); "
        "path relative to the calibration file",
        default=None,
    )


@dataclass(frozen=True)
class Fingering:
    """One fingering: a name and the tone holes it opens (the others are closed)."""

    name: str = spec("", "name of the fingering, e.g. oxxx")
    open: tuple[str, ...] = spec("", "names of the holes that are open", default=())


@dataclass(frozen=True)
class Calibration:
    """A measured instrument set-up."""

    name: str = spec("", "human-readable name of the set-up")
    air: AirSettings = spec("", "air conditions")
    bore: Bore = spec("", "bore geometry and termination")
    microphones: tuple[Microphone, ...] = spec(
        "",
        "the wall microphones, upstream first: two or more, all in the cylinder holding the "
        "reference plane (two: exact separation, propagation held; three or more: least "
        "squares, propagation estimated)",
    )
    reference_plane: float = spec("m", "position where p0, u0 are reconstructed", between(0.0, 5.0))
    source: str = spec("", "file the calibration was read from (set by the loader)", default="")
    fingerings: tuple[Fingering, ...] = spec(
        "",
        "the fingerings of an instrument with tone holes, a mapping name -> list of the open "
        "holes (in the file: fingerings: {xxxx: [], oxxx: [hole1]})",
        default=(),
    )
    fingering: str | None = spec(
        "",
        "the fingering played: a name of fingerings, 'auto' (each note's found among them; the "
        "default when the file names fingerings but not this key) or one name per note "
        "separated by commas (--fingering chooses another)",
        default=None,
    )

    def _check(self, where: Where) -> None:
        self._check_fingerings(where)
        length = self.bore.length
        if len(self.microphones) < 2:
            raise where.error(
                "microphones",
                f"expected at least 2 microphones (two waves are unknown), got "
                f"{len(self.microphones)}",
            )
        positions = [m.position for m in self.microphones]
        for i, x in enumerate(positions):
            if not 0.0 < x < length:
                raise where.error(
                    f"microphones[{i}].position",
                    f"microphone at {x:g} m is outside the bore (0 to {length:g} m)",
                )
        if any(b <= a for a, b in zip(positions, positions[1:], strict=False)):
            raise where.error("microphones", "expected positions strictly increasing downstream")
        channels = [m.channel for m in self.microphones]
        if len(set(channels)) != len(channels):
            raise where.error("microphones", f"two microphones share a channel: {channels}")
        if not 0.0 < self.reference_plane < length:
            raise where.error(
                "reference_plane",
                f"reference plane at {self.reference_plane:g} m is outside the bore "
                f"(0 to {length:g} m)",
            )
        # The two-wave field model assumes one uniform duct around the microphones
        # and the reference plane (physics.md E.1).
        lo = min(positions[0], self.reference_plane)
        hi = max(positions[-1], self.reference_plane)
        seg = self.bore.segment_at(lo)
        if not (seg.is_cylinder and hi <= seg.x_end + JOIN_TOLERANCE):
            raise where.error(
                "microphones",
                "the microphones and the reference plane must lie in one cylindrical segment "
                f"(they span {lo:g}-{hi:g} m)",
            )
        for i, hole in enumerate(self.bore.holes):
            if lo - hole.radius < hole.position < hi + hole.radius:
                raise where.error(
                    f"bore.holes[{i}]",
                    f"hole {hole.name!r} at {hole.position:g} m lies between the microphones "
                    f"and the reference plane ({lo:g}-{hi:g} m), where the wave separation needs "
                    "a plain duct; move the microphones or the reference plane off the hole",
                )

    def _check_fingerings(self, where: Where) -> None:
        holes = {h.name for h in self.bore.holes}
        names = [f.name for f in self.fingerings]
        for f in self.fingerings:
            if names.count(f.name) > 1:
                raise where.error(f"fingerings.{f.name}", "this fingering is given twice")
            for hole in f.open:
                if hole not in holes:
                    raise where.error(
                        f"fingerings.{f.name}",
                        f"no hole named {hole!r} in bore.holes (the holes are "
                        f"{sorted(holes) or 'none'})",
                    )
        for name in note_fingerings(self.fingering) or [self.fingering]:
            if name is not None and name != AUTO and name not in names:
                raise where.error("fingering", _unknown_fingering(name, names))
        if self.fingering == AUTO and not names:
            raise where.error("fingering", "auto: the file names no fingerings to choose from")

    def with_fingering(self, name: str) -> Calibration:
        """A copy playing fingering ``name``: its holes open in ``bore``, the others closed.

        Raises
        ------
        ConfigError
            When the calibration has no fingering of that name.
        """
        for f in self.fingerings:
            if f.name == name:
                bore = replace(self.bore, open_holes=tuple(f.open))
                return replace(self, bore=bore, fingering=name)
        names = [f.name for f in self.fingerings]
        raise ConfigError(f"{self.source or 'calibration'}: {_unknown_fingering(name, names)}")

    @property
    def main_radius(self) -> float:
        """Radius in m of the cylinder holding the microphones."""
        return self.bore.segment_at(self.microphones[0].position).radius

    def air_properties(self, temperature_c: float | None = None) -> Air:
        """Air properties at the configured (or the given) temperature in degC."""
        return self.air.properties(temperature_c)

    def calibration_path(self, mic: Microphone) -> Path | None:
        """Absolute path of a microphone's calibration table, or None."""
        if mic.calibration is None:
            return None
        return (Path(self.source).parent / mic.calibration).resolve()

    def with_bore(self, bore: Bore) -> Calibration:
        """A copy with another bore (for example a different termination)."""
        return replace(self, bore=bore)


#: The fingering key's value that finds each note's fingering from the data.
AUTO = "auto"


def per_note(fingering: str | None) -> bool:
    """Whether a fingering setting gives a fingering per note (``auto`` or a list)."""
    return fingering is not None and (fingering == AUTO or "," in fingering)


def note_fingerings(fingering: str | None) -> list[str] | None:
    """The names of a per-note list ``"xxoo,xooo"`` (None for ``auto``, one name or None)."""
    if fingering is None or "," not in fingering:
        return None
    return [x.strip() for x in fingering.split(",")]


def _one_translation(cal: Calibration, path) -> None:
    """Refuse a fingering per note when the fingerings differ upstream of the microphones.

    The translation from the reference plane to the mouthpiece passes the holes between
    them, open or closed as the fingering says, and is made once per take: a hole there
    (a register hole) opened by some fingerings and not others needs one fingering per take.
    """
    upstream = [h.name for h in cal.bore.holes_between(0.0, cal.reference_plane)]
    names = note_fingerings(cal.fingering) or [f.name for f in cal.fingerings]
    states = {tuple(h in f.open for h in upstream) for f in cal.fingerings if f.name in names}
    if len(states) > 1:
        raise ConfigError(
            f"{path}: fingering: {cal.fingering}: hole(s) {', '.join(upstream)} lie between "
            "the mouthpiece and the reference plane and the fingerings open them differently; "
            "the translation to the mouthpiece takes one fingering per take: give "
            "--fingering NAME (or fingerings that agree there)"
        )


def _unknown_fingering(name: str, names: list[str]) -> str:
    if not names:
        return (
            f"no fingering {name!r}: the file has no fingerings (expected a 'fingerings' mapping)"
        )
    return f"unknown fingering {name!r}; expected one of {', '.join(names)}"


def _fingering_list(data: dict, path: str | Path) -> None:
    """Turn the file's ``fingerings`` mapping into the list :func:`build` reads, in place."""
    bore = data.get("bore")
    if isinstance(bore, Mapping) and "open_holes" in bore:
        raise ConfigError(
            f"{path}: bore.open_holes: set by the loader from the fingering; write "
            "'fingerings' (name -> open holes) and 'fingering' (the default) instead"
        )
    if isinstance(bore, Mapping) and "measured_input" in bore:
        raise ConfigError(f"{path}: bore.measured_input: set by the loader, remove it")
    fingerings = data.get("fingerings")
    if fingerings is None:
        return
    if not isinstance(fingerings, Mapping):
        raise ConfigError(
            f"{path}: fingerings: expected a mapping of name -> list of open holes, "
            "e.g. {xxxx: [], oxxx: [hole1]}"
        )
    out = []
    for name, holes in fingerings.items():
        if holes is None:
            holes = []
        if not isinstance(holes, list) or not all(isinstance(h, str) for h in holes):
            raise ConfigError(
                f"{path}: fingerings.{name}: expected a list of hole names, got {holes!r}"
            )
        out.append({"name": str(name), "open": holes})
    data["fingerings"] = out


def load_calibration(path: str | Path, fingering: str | None = None) -> Calibration:
    """Read and validate a calibration file.

    Parameters
    ----------
    path : str or Path
        YAML file.
    fingering : str, optional
        The fingering to play (a name of the file's ``fingerings``); default: the file's
        ``fingering``. Without fingerings every tone hole is closed.

    Returns
    -------
    Calibration

    Raises
    ------
    ConfigError
        Naming the file, the key path and what was expected.
    """
    data = dict(load_yaml(path))
    if "bore" not in data and {"calibration", "inversion", "separation"} & set(data):
        raise ConfigError(
            f"{path}: this is a pipeline file (it has calibration/inversion/separation); "
            "expected a calibration file here (the instrument: bore, microphones, air)"
        )
    if "source" in data:
        raise ConfigError(f"{path}: source: this key is set by the loader, remove it")
    data["source"] = str(Path(path).resolve())
    _fingering_list(data, path)
    cal = build(Calibration, data, Where(str(path)))
    name = fingering if fingering is not None else cal.fingering
    if name is None and cal.fingerings:
        name = AUTO  # a fingering per note, found from the data
    if per_note(name):
        if name != AUTO and not cal.fingerings:
            raise ConfigError(f"{path}: {_unknown_fingering(name, [])}")
        for each in note_fingerings(name) or ():
            cal.with_fingering(each)  # a one-line error for an unknown name
        cal = replace(cal, fingering=name)
        _one_translation(cal, path)
    elif name is not None:
        cal = cal.with_fingering(name)
    if cal.bore.measured is not None:
        cal = attach_measured_bore(cal, path)
    return cal
