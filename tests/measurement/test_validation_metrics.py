"""Metrics of the impedance validation: resonance frequencies at the phase's zero crossing."""

import numpy as np
import pandas as pd

from mpipe.measurement.validation import ValidationConfig
from mpipe.measurement.validation_metrics import harmonic_errors, phase_zero, resonance_errors


def _mode(freqs, f_r=150.0, q=30.0):
    """One resonance: z = 1 / (1 + j Q (f / f_r - f_r / f)), phase zero at f_r."""
    return 1.0 / (1.0 + 1j * q * (freqs / f_r - f_r / freqs))


def test_phase_zero_interpolates_between_bins():
    freqs = np.arange(100.0, 200.0, 7.0)  # f_r = 150 Hz lies between two bins
    assert abs(phase_zero(freqs, _mode(freqs), 149.0) - 150.0) < 1.0
    # no crossing near the peak: the peak frequency itself
    assert phase_zero(freqs, np.ones(freqs.size), 121.0) == 121.0


def test_a_matching_measurement_has_no_resonance_error():
    freqs = np.arange(50.0, 400.0, 0.5)
    z = _mode(freqs)
    band = np.ones(freqs.size, dtype=bool)
    coh = np.ones(freqs.size)
    config = ValidationConfig(n_resonances=1)
    rows = resonance_errors(freqs, z, z, coh, band, config)
    assert len(rows) == 1
    assert abs(rows.error_cents[0]) < 1e-9 and abs(rows.error_db[0]) < 1e-9
    # not measurable (a played note): the theory only
    rows = resonance_errors(freqs, z, z, coh, band, config, measurable=False)
    assert np.isnan(rows.error_cents[0])


def test_no_note_no_harmonics():
    freqs = np.arange(1.0, 100.0)
    zeros = np.zeros(freqs.size)
    rows = harmonic_errors(freqs, zeros, zeros, zeros, zeros, zeros, float("nan"), None)
    assert isinstance(rows, pd.DataFrame) and rows.empty and "compared" in rows.columns
