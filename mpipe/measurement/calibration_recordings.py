"""Recordings for a microphone calibration: the two channels read in Pa, or simulated.

:func:`read_channels` reads the channels of microphone 1 and microphone m from a lab
recording (for :mod:`mpipe.measurement.relative_calibration`);
:func:`simulate_calibration_recording` makes a virtual one (broadband sound in the bore or
in a closed tube, read by mismatched microphones) to test the methods on.

References
----------
Chung & Blaser 1980, JASA 68(3):907-913; physics.md E.6.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import soundfile as sf

from mpipe.acoustics.bore import input_impedance
from mpipe.core.errors import UserError
from mpipe.measurement.calibration import Calibration
from mpipe.measurement.field import microphone_field, mouthpiece_to_reference
from mpipe.measurement.relative_calibration import closed_tube_ratio


def read_channels(
    path: str | Path, calibration: Calibration, mics: tuple[str, str]
) -> tuple[np.ndarray, float]:
    """Read the channels of two microphones from a recording, scaled to Pa.

    Parameters
    ----------
    path : str or Path
        Multichannel audio file.
    calibration : Calibration
        Channel map and sensitivities.
    mics : (str, str)
        Names of microphone 1 (the reference) and microphone m.

    Returns
    -------
    x : ndarray
        Shape ``(n, 2)``, Pa.
    fs : float
        Sample rate, Hz.

    Raises
    ------
    UserError
        Naming the file for an unreadable file, and the microphone or channel that is
        missing.
    """
    by_name = {m.name: m for m in calibration.microphones}
    for name in mics:
        if name not in by_name:
            raise UserError(
                f"{calibration.source}: no microphone named {name!r}; expected one of "
                f"{', '.join(by_name)}"
            )
    try:
        data, fs = sf.read(str(path), dtype="float64", always_2d=True)
    except (RuntimeError, OSError) as exc:
        raise UserError(f"{path}: cannot read audio: {exc}") from None
    cols = []
    for name in mics:
        m = by_name[name]
        if m.channel > data.shape[1]:
            raise UserError(
                f"{path}: has {data.shape[1]} channel(s), microphone {name} is on channel "
                f"{m.channel}"
            )
        cols.append(data[:, m.channel - 1] * m.sensitivity)
    return np.column_stack(cols), float(fs)


def simulate_calibration_recording(
    calibration: Calibration,
    positions: tuple[float, ...],
    gains: np.ndarray,
    *,
    load: str = "bore",
    closed_at: float | None = None,
    duration_s: float = 4.0,
    fs: float = 100_000.0,
    snr_db: float = 60.0,
    temperature_c: float | None = None,
    seed: int = 0,
) -> np.ndarray:
    """A virtual calibration recording: broadband sound in the bore, read by given channels.

    The field is stationary random noise: a white volume flow at the mouthpiece entry of
    the calibration's bore (``load="bore"``, the switching method's set-up), or white
    pressure at a rigid cap at ``closed_at`` on the main cylinder (``load="closed"``).

    Parameters
    ----------
    calibration : Calibration
        Bore, reference plane, air and main-bore radius.
    positions : tuple of float
        Position of the microphone on each channel, m from the mouthpiece entry.
    gains : array_like
        Complex gain of each channel's microphone
        (see :func:`mpipe.measurement.field.complex_gain`).
    load : {"bore", "closed"}
        The field, see above.
    closed_at : float, optional
        Cap position, m (``load="closed"``).
    duration_s : float
        Length, s.
    fs : float
        Sample rate, Hz.
    snr_db : float
        Signal-to-noise ratio of each channel (white sensor noise), dB.
    temperature_c : float, optional
        Air temperature, degC (default: the calibration's).
    seed : int
        Random seed.

    Returns
    -------
    ndarray
        Shape ``(n, len(positions))``, Pa as read by each (mismatched) microphone.
    """
    rng = np.random.default_rng(seed)
    n = int(round(duration_s * fs))
    freqs = np.fft.rfftfreq(n, 1 / fs)
    f_eval = np.maximum(freqs, 1e-3)
    air = calibration.air_properties(temperature_c)
    source = rng.standard_normal(freqs.size) + 1j * rng.standard_normal(freqs.size)
    if load == "bore":
        omega = 2 * np.pi * f_eval
        u = source * 1e-6
        p = input_impedance(calibration.bore, omega, air) * u
        p0, u0 = mouthpiece_to_reference(p, u, omega, calibration, air)
        field, _ = microphone_field(p0, u0, f_eval, calibration, air, 0.0, positions)
    elif load == "closed":
        if closed_at is None:
            raise ValueError("load 'closed' needs closed_at")
        ratio = closed_tube_ratio(
            np.asarray(positions), closed_at, calibration.main_radius, f_eval, air,
            calibration.bore.losses,
        )  # fmt: skip
        field = ratio * (source * 100.0)[:, None]
    else:
        raise ValueError(f"load: expected 'bore' or 'closed', got {load!r}")
    g = np.broadcast_to(np.asarray(gains, dtype=complex), (freqs.size, len(positions))).copy()
    g[0] = np.abs(g[0])  # DC and Nyquist of a real signal are real
    if n % 2 == 0:
        g[-1] = np.abs(g[-1])
    field[0] = field[0].real
    x = np.fft.irfft(field * g, n, axis=0)
    noise = rng.standard_normal(x.shape) * x.std(axis=0) * 10 ** (-snr_db / 20)
    return x + noise


__all__ = ["read_channels", "simulate_calibration_recording"]
