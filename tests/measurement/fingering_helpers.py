"""Notes made from the linear theory: u a harmonic series, p = Z_F u at each harmonic."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mpipe.acoustics.bore import input_impedance
from mpipe.measurement.calibration import Calibration, load_calibration

ROOT = Path(__file__).resolve().parents[2]
FOUR_HOLES = ROOT / "calibration" / "four_hole_clarinet.yaml"


def four_holes(fingering: str | None = "auto") -> Calibration:
    """The shipped four-hole instrument (every fingering found per note by default)."""
    return load_calibration(FOUR_HOLES, fingering)


def first_resonance(cal: Calibration, name: str) -> float:
    """The first input-impedance peak of a fingering, Hz (0.1 Hz grid; once per bore)."""
    key = (cal.bore.holes, cal.with_fingering(name).bore.open_holes, cal.air.temperature_c)
    if key not in _FIRST:
        _FIRST[key] = _first(cal, name)
    return _FIRST[key]


_FIRST: dict = {}


def _first(cal: Calibration, name: str) -> float:
    grid = np.arange(60.0, 400.0, 0.1)
    air = cal.air_properties(cal.air.temperature_c)
    z = np.abs(input_impedance(cal.with_fingering(name).bore, 2 * np.pi * grid, air))
    return float(grid[np.argmax(z)])


def theory_note(
    cal: Calibration,
    name: str,
    f0: float,
    duration: float,
    fs: float,
    rng: np.random.Generator,
    snr_db: float = 45.0,
    harmonics: int = 12,
) -> tuple[np.ndarray, np.ndarray]:
    """Pressure (Pa) and flow (m^3/s) of a note played on fingering ``name`` (with onsets).

    The flow's harmonics fall as 1/k with random phases; the pressure is the fingering's
    theoretical impedance times the flow at each harmonic, then white noise ``snr_db``
    below each signal's RMS is added to both.
    """
    n = int(round(duration * fs))
    t = np.arange(n) / fs
    air = cal.air_properties(cal.air.temperature_c)
    k = np.arange(1, harmonics + 1)
    freqs = k * f0
    keep = freqs < 0.45 * fs
    uk = (2e-4 / k[keep]) * np.exp(2j * np.pi * rng.random(keep.sum()))
    zk = input_impedance(cal.with_fingering(name).bore, 2 * np.pi * freqs[keep], air)
    phase = np.exp(2j * np.pi * np.outer(t, freqs[keep]))
    u = (phase @ uk).real
    p = (phase @ (zk * uk)).real
    ramp = np.clip(np.minimum(t, t[-1] - t) / 0.01, 0.0, 1.0)  # 10 ms raised edges
    p, u = p * ramp, u * ramp
    p += rng.normal(0.0, np.std(p) * 10 ** (-snr_db / 20), n)
    u += rng.normal(0.0, np.std(u) * 10 ** (-snr_db / 20), n)
    return p, u


def register_hole_take(folder: Path):
    """``(calibration, take)`` of the four-hole clarinet with a register hole at 0.15 m.

    The hole lies upstream of the microphones; the take plays a note of ``xxxx`` then one of
    ``rxxxx`` (the hole open), 0.3 s each, made by synth-take's engine
    (:func:`mpipe.cli.virtual_takes.synthesize`): its truth p0, u0 at the reference plane and
    p, u at the mouthpiece.
    """
    import yaml

    from mpipe.cli.virtual_takes import SynthOptions, synthesize
    from mpipe.reed.parameters import load_reed
    from mpipe.reed.score import score_from_mapping

    data = yaml.safe_load(FOUR_HOLES.read_text())
    data["bore"]["holes"].insert(0, {"name": "reg", "position": 0.15, "radius": 0.0015,
                                     "chimney": 0.012})  # fmt: skip
    data["fingerings"]["rxxxx"] = ["reg"]
    data["fingering"] = "xxxx"
    path = Path(folder) / "reg.yaml"
    path.write_text(yaml.safe_dump(data))
    cal = load_calibration(path)
    score = score_from_mapping({"notes": [
        {"duration": 0.3, "fingering": "xxxx", "p_m": 1800.0, "attack": 0.02},
        {"duration": 0.3, "fingering": "rxxxx", "p_m": 1800.0, "attack": 0.005},
    ]})  # fmt: skip
    reed = load_reed(FOUR_HOLES.parent / "reed_table1.yaml")
    take, _, _ = synthesize(cal, reed, SynthOptions(duration_s=None, seed=0), score)
    return cal, take
