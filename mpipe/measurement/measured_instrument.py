"""A measured input impedance as the instrument: ``bore: {measured: FILE, ...}``.

The calibration's bore may name an impedance-head measurement of the instrument. The file
is read with the same declared layout as ``mpipe impedance --measured`` (columns,
normalisation, time convention, temperature: :mod:`mpipe.measurement.measured_impedance`),
and the bore's ``segments`` (the duct from the mouthpiece past the microphones, and as much
of the rest as is known) become the *equivalent bore* used outside the measured band: the
last segment's end is fitted so that the geometry's impedance best matches the measurement
(physics.md D.5). Every stage then uses the measurement through ``calibration.bore``:
the validation's theory, the inversion's reflection function, the resynthesis.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from mpipe.acoustics.bore import Bore, Segment, input_impedance
from mpipe.acoustics.measured_bore import MeasuredInput, fit_equivalent_length
from mpipe.core.config import ConfigError
from mpipe.core.errors import UserError
from mpipe.measurement.impedance_comparison import resonances
from mpipe.measurement.measured_impedance import read_measured_impedance

# Fewest measured frequencies, and the narrowest band (Hz), a fit is attempted with.
MIN_POINTS = 50
MIN_BAND_HZ = 200.0
# The equivalent bore's end is searched between these fractions of the geometry's length.
LENGTH_SEARCH = (0.5, 1.6)
# Frequencies used by the fit of the equivalent length (the misfit is reported on all).
FIT_POINTS = 1000


def _stretched(bore: Bore, length: float) -> Bore:
    """The bore with its last segment ending at ``length`` (m), radii kept."""
    last = bore.segments[-1]
    seg = Segment(last.x_start, length, last.radius, last.radius_start, last.radius_end, last.name)
    return replace(bore, segments=(*bore.segments[:-1], seg), measured=None, measured_input=None)


def attach_measured_bore(calibration, source: str | Path):
    """Read the bore's ``measured`` file and fit its equivalent bore.

    Parameters
    ----------
    calibration : Calibration
        Its ``bore.measured`` names the file, relative to ``source``'s folder.
    source : str or Path
        The calibration file, for paths and messages.

    Returns
    -------
    Calibration
        A copy whose ``bore.measured_input`` holds the measurement and the equivalent bore.

    Raises
    ------
    ConfigError
        One line: an unreadable or undeclared file, too few points, fingerings (a
        measurement is of one fingering), a bore too short for the fit.
    """
    bore = calibration.bore
    path = (Path(source).resolve().parent / bore.measured).resolve()
    where = f"{source}: bore.measured"
    if calibration.fingerings:
        raise ConfigError(
            f"{where}: a measured impedance is one fingering; write one calibration file per "
            "measured fingering, without 'fingerings'"
        )
    if not path.is_file():
        raise ConfigError(f"{where}: no such impedance file {path}")
    try:
        m = read_measured_impedance(path)
    except UserError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    keep = m.freqs > 0
    freqs = m.freqs[keep]
    if freqs.size < MIN_POINTS or freqs[-1] - freqs[0] < MIN_BAND_HZ:
        raise ConfigError(
            f"{where}: {path.name} has {freqs.size} frequencies over {freqs[0]:g}-{freqs[-1]:g} "
            f"Hz; expected at least {MIN_POINTS} over {MIN_BAND_HZ:g} Hz"
        )
    temperature = (
        m.layout.temperature_c
        if m.layout.temperature_c is not None
        else calibration.air.temperature_c
    )
    air = calibration.air_properties(temperature)
    z0 = air.impedance(np.pi * bore.entry_radius**2)
    z_abs = m.z[keep]
    if m.layout.normalisation == "Z/Zc":
        z_abs = z_abs * air.impedance(np.pi * (m.layout.entry_radius or bore.entry_radius) ** 2)
    omega = 2 * np.pi * freqs
    lo = max(bore.segments[-1].x_start, *(h.position + h.radius for h in bore.holes), 0.0)
    bounds = (max(lo + 1e-3, LENGTH_SEARCH[0] * bore.length), LENGTH_SEARCH[1] * bore.length)
    # every bin is not needed to place the resonances: at most FIT_POINTS, evenly spread
    sub = np.unique(np.linspace(0, freqs.size - 1, min(FIT_POINTS, freqs.size)).astype(int))
    length, _ = fit_equivalent_length(
        lambda x: input_impedance(_stretched(bore, x), omega[sub], air), z_abs[sub], bounds
    )
    equivalent = _stretched(bore, length)
    z_eq = input_impedance(equivalent, omega, air)
    strong = np.abs(z_abs) >= z0
    err_db = np.abs(20 * np.log10(np.abs(z_eq[strong]) / np.abs(z_abs[strong])))
    cents = _resonance_cents(freqs, z_abs, z_eq)
    measured = MeasuredInput(
        freqs=freqs,
        z_norm=z_abs / z0,
        temperature_c=float(temperature),
        c_measured=air.c,
        source=str(path),
        entry_radius=bore.entry_radius,
        equivalent=equivalent,
        equivalent_length=length,
        misfit_rms_db=float(np.sqrt(np.mean(err_db**2))) if err_db.size else float("nan"),
        misfit_max_db=float(np.max(err_db)) if err_db.size else float("nan"),
        misfit_cents=cents,
    )
    return replace(calibration, bore=replace(bore, measured_input=measured))


def _resonance_cents(freqs: np.ndarray, z_measured: np.ndarray, z_model: np.ndarray) -> float:
    """Largest distance, in cents, from a model resonance to the nearest measured one."""
    # peaks 3 dB prominent: a measurement's noise makes none
    measured, model = (
        resonances(freqs, z, 1.0, count=200)["frequency_hz"].to_numpy()
        for z in (z_measured, z_model)
    )
    if not measured.size or not model.size:
        return float("nan")
    nearest = measured[np.argmin(np.abs(measured[None, :] - model[:, None]), axis=1)]
    return float(np.max(np.abs(1200 * np.log2(model / nearest))))


def bore_description(calibration) -> str:
    """The bore in one line for consoles and reports: measured, or the geometry's theory."""
    measured = calibration.bore.measured_input
    if measured is not None:
        return "the bore is measured: " + measured.summary()
    holes = calibration.bore.holes
    if not holes:
        return "the bore is the theory of the calibration's geometry, without tone holes"
    opened = ", ".join(calibration.bore.open_holes) or "none"
    return (
        f"the bore is the theory of the calibration's geometry with {len(holes)} tone holes, "
        f"fingering {calibration.fingering or 'none (every hole closed)'}, open holes: {opened}"
    )
