"""The calibration file: instrument geometry, air, microphones and reference plane.

One YAML file per measured instrument set-up (see ``calibration/simplified_clarinet.yaml``).
Paths inside it (microphone calibration tables) are relative to the file.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from mpipe.acoustics.air import AIR_MODELS, Air, air_properties
from mpipe.acoustics.bore import JOIN_TOLERANCE, Bore
from mpipe.core.config import ConfigError, Where, between, build, load_yaml, positive, spec


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
    calibration: str | None = spec(
        "",
        "optional CSV (frequency_hz, magnitude, phase_deg) of the complex relative "
        "calibration H_c of this microphone against microphone 1 (physics.md E.6); "
        "path relative to the calibration file",
        default=None,
    )


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

    def _check(self, where: Where) -> None:
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


def load_calibration(path: str | Path) -> Calibration:
    """Read and validate a calibration file.

    Parameters
    ----------
    path : str or Path
        YAML file.

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
    return build(Calibration, data, Where(str(path)))
