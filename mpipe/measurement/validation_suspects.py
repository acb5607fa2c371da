"""What a failed validation points at: the inputs to suspect, most likely first.

A validation that FAILs names its suspects (``ValidationResult.suspects``):
the bore's length or the air when a resonance is misplaced, the microphones' relative
calibration when the errors are small and at the right frequencies, and another listed
fingering when the note's harmonics fit it better.
"""

from __future__ import annotations

import numpy as np

from mpipe.measurement.calibration import Calibration
from mpipe.measurement.fingerings import harmonic_lines, identify
from mpipe.measurement.validation_result import ValidationResult


def suspect_inputs(result: ValidationResult, calibration: Calibration) -> tuple[str, ...]:
    """The inputs that can make a validation FAIL the way ``result`` does, most likely first.

    Resonances at the wrong frequency, harmonics tens of degrees or a band several dB off
    point at the bore's length or the air temperature first; smaller level and phase
    errors at the right frequencies at what scales P against U: the
    microphones' relative calibration tables (H_c off by 0.1 dB / 0.5 deg moves the measured
    impedance by far more near its minima), their positions and the entry radius.

    Parameters
    ----------
    result : ValidationResult
        A failed validation.
    calibration : Calibration
        The calibration used (its microphone tables are named).

    Returns
    -------
    tuple of str
    """
    text = "; ".join(result.failures)
    tables = [
        str(calibration.calibration_path(m).name)
        for m in calibration.microphones
        if calibration.calibration_path(m) is not None
    ]
    scale = []
    if tables:
        scale.append(
            "the microphones' relative calibration tables ("
            + ", ".join(tables)
            + "): re-measure them (mpipe calibrate closed or switch)"
        )
    else:
        scale.append("the microphones' mismatch (no relative calibration table is given)")
    scale.append("the microphones' positions and the bore's entry radius")
    frequency = ["the bore's length and geometry", "the air temperature"]
    # a misplaced resonance, tens of degrees or several dB are more than a table's error
    phases = result.harmonics["error_deg"] if "error_deg" in result.harmonics else []
    gross = (
        "cents" in text
        or result.band_error_db > 3.0
        or bool(np.any(np.abs(np.asarray(phases, dtype=float)) > 20.0))
    )
    return tuple(frequency + scale if gross else scale + frequency)


def other_fingering(p, u, fs, f0, calibration: Calibration, t: float) -> tuple[str, ...]:
    """The fingering, first of the suspects, when another of the calibration's fits better.

    A note validated against the wrong fingering (a register hole closed in the theory and
    open on the instrument, a phrase of several fingerings) fails at its harmonics as a
    wrong bore does; the note's harmonic lines weigh every fingering
    (:func:`mpipe.measurement.fingerings.identify`), and one more likely than the one
    validated is named.
    """
    if len(calibration.fingerings) < 2:
        return ()
    choice = identify(f0, calibration, harmonic_lines(p, u, fs, f0), t)
    if choice.fingering == calibration.fingering or choice.probability < 0.5:
        return ()
    return (
        f"the fingering: the note's harmonics fit {choice.fingering} (p = "
        f"{choice.probability:.3f}), not {calibration.fingering}: give --fingering "
        f"{choice.fingering}, or auto",
    )


__all__ = ["other_fingering", "suspect_inputs"]
