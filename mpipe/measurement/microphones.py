"""Microphone sensitivity: from the measuring chain, and the levels a take can plausibly have.

Before its first take a lab needs (physics.md E.6):

- the absolute ``sensitivity`` of each microphone in Pa per unit of the recorded signal,
  from the data sheet (mV/Pa), the preamplifier/interface gain (dB) and the voltage of the
  interface at digital full scale: :func:`sensitivity_from_chain`;
- the relative calibration H_c of microphone m against microphone 1, measured by the
  switching or the known-load method: :mod:`mpipe.measurement.relative_calibration` (with
  its recordings read or simulated by :mod:`mpipe.measurement.calibration_recordings`);
- a warning when a take reads at a level no clarinet plays at: :func:`level_warning`.

References
----------
Chung & Blaser 1980, "Transfer function method of measuring in-duct acoustic properties.
I. Theory", JASA 68(3):907-913; ISO 10534-2; physics.md B.4, E.6.
"""

from __future__ import annotations

import logging
import math

import numpy as np

log = logging.getLogger(__name__)

#: Peak pressure below which a take cannot be a played clarinet, Pa. Mouthpiece and bore
#: pressures of a played note swing by 1-10 kPa (mouth pressure 1.5-6 kPa); 20 Pa peak is
#: 120 dB SPL, far below any note.
MIN_PLAUSIBLE_PEAK_PA = 20.0
#: Peak pressure above which a take cannot be a played clarinet, Pa (half an atmosphere).
MAX_PLAUSIBLE_PEAK_PA = 5e4


def sensitivity_from_chain(
    mic_mv_per_pa: float, gain_db: float = 0.0, full_scale_v: float = 1.0
) -> float:
    """Sensitivity in Pa per unit of the recorded signal, from the measuring chain.

    A sample of value 1.0 (digital full scale) is ``full_scale_v`` volts at the converter;
    before the gain ``gain_db`` of preamplifier and interface it was
    ``full_scale_v / 10^(gain_db / 20)`` volts at the microphone, that is that voltage
    divided by the microphone's sensitivity in Pa.

    Parameters
    ----------
    mic_mv_per_pa : float
        Microphone sensitivity, mV/Pa (data sheet or pistonphone), > 0.
    gain_db : float
        Total voltage gain between microphone and converter (preamplifier, interface), dB.
    full_scale_v : float
        Peak voltage at the converter input that reads as digital full scale (sample value
        1.0), V. An interface specified in dBu at full scale: ``0.7746 * 10^(dBu/20) *
        sqrt(2)`` V peak.

    Returns
    -------
    float
        Pa per unit of the recorded signal (the calibration file's ``sensitivity``).

    Raises
    ------
    ValueError
        For a non-positive or non-finite sensitivity or voltage, or a non-finite gain.
    """
    for name, v in (("mic_mv_per_pa", mic_mv_per_pa), ("full_scale_v", full_scale_v)):
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"{name}: expected a positive number, got {v!r}")
    if not math.isfinite(gain_db):
        raise ValueError(f"gain_db: expected a finite number, got {gain_db!r}")
    volts_at_mic = full_scale_v / 10.0 ** (gain_db / 20.0)
    return volts_at_mic / (mic_mv_per_pa * 1e-3)


def level_warning(pressures: np.ndarray, what: str = "take") -> str | None:
    """A warning when a take's pressure level cannot be a played clarinet.

    Parameters
    ----------
    pressures : ndarray
        Calibrated pressures, Pa (any shape).
    what : str
        Name of the take, for the message.

    Returns
    -------
    str or None
        The warning, or None when the peak lies between :data:`MIN_PLAUSIBLE_PEAK_PA`
        and :data:`MAX_PLAUSIBLE_PEAK_PA`.
    """
    peak = float(np.max(np.abs(pressures))) if np.size(pressures) else 0.0
    if MIN_PLAUSIBLE_PEAK_PA <= peak <= MAX_PLAUSIBLE_PEAK_PA:
        return None
    side = "below" if peak < MIN_PLAUSIBLE_PEAK_PA else "above"
    return (
        f"{what}: peak pressure {peak:.3g} Pa is far {side} a played clarinet (1-10 kPa in "
        "the bore): check microphones[].sensitivity (Pa per unit of the recorded signal; "
        "`mpipe calibrate sensitivity` computes it) - every result would be wrong"
    )


__all__ = ["level_warning", "sensitivity_from_chain"]
