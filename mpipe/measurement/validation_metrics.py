"""Metrics of the impedance validation: resonances matched, and errors at the harmonics.

:func:`resonance_errors` matches the first peaks of the theoretical ``|z_th|`` to peaks of
the measured ``|z|`` (frequencies in cents, at the zero crossings of the phase found by
:func:`phase_zero`, and levels in dB); :func:`harmonic_errors` reads the magnitude and phase
errors at a played note's harmonics. Impedances are normalised (``Z / Z0``, dimensionless),
frequencies in Hz.

References
----------
Chatziioannou & van Walstijn 2012, section 4 and Fig. 10; physics.md F.3.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
from scipy import ndimage

from mpipe.acoustics.bore import find_resonances

if TYPE_CHECKING:
    from mpipe.measurement.validation import ValidationConfig


def resonance_errors(
    freqs, z_me, z_th, coh, band, config: ValidationConfig, measurable: bool = True
) -> pd.DataFrame:
    """Theoretical resonances in ``band`` and, when ``measurable``, the measured ones.

    One row per resonance of ``z_th`` (``config.n_resonances``), with the nearest measured
    peak within ``config.match_cents`` where the bin is coherent; see
    :class:`mpipe.measurement.validation_result.ValidationResult` for the columns.
    """
    f_b = freqs[band]
    th = find_resonances(f_b, z_th[band], 1.0, count=config.n_resonances)
    mag = np.abs(z_me[band])
    if config.smoothing_bins > 1:
        mag = np.convolve(mag, np.ones(config.smoothing_bins) / config.smoothing_bins, "same")
    me = find_resonances(f_b, mag, 1.0, count=10**6)
    z_b_th, z_b_me = z_th[band], z_me[band]
    rows = []
    for r in th:
        i = int(np.argmin(np.abs(f_b - r.frequency_hz)))
        f_th = phase_zero(f_b, z_b_th, r.frequency_hz)
        c = float(coh[band][i])
        row = {
            "frequency_theory_hz": f_th,
            "frequency_measured_hz": np.nan,
            "error_cents": np.nan,
            "level_theory_db": r.level_db,
            "level_measured_db": np.nan,
            "error_db": np.nan,
            "coherence": c,
        }
        if measurable and me and c >= config.min_coherence:
            cents = np.array([1200 * np.log2(m.frequency_hz / r.frequency_hz) for m in me])
            j = int(np.argmin(np.abs(cents)))
            if abs(cents[j]) <= config.match_cents:
                f_me = phase_zero(f_b, z_b_me, me[j].frequency_hz)
                row.update(
                    frequency_measured_hz=f_me,
                    error_cents=float(1200 * np.log2(f_me / f_th)),
                    level_measured_db=me[j].level_db,
                    error_db=me[j].level_db - r.level_db,
                )
        rows.append(row)
    return pd.DataFrame(rows, columns=list(rows[0]) if rows else None)


def phase_zero(freqs: np.ndarray, z: np.ndarray, f_peak: float) -> float:
    """Resonance frequency as the +/- zero crossing of arg z nearest a |z| peak (Hz).

    The phase crosses zero steeply at a resonance, so linear interpolation between two
    bins locates it far better than the top of a peak that window smoothing flattens.
    Falls back to ``f_peak`` when there is no crossing within three bins.
    """
    i = int(np.argmin(np.abs(freqs - f_peak)))
    ph = np.angle(z)
    best = None
    for j in range(max(i - 3, 0), min(i + 3, freqs.size - 1)):
        if ph[j] >= 0 > ph[j + 1]:
            f = freqs[j] + (freqs[j + 1] - freqs[j]) * ph[j] / (ph[j] - ph[j + 1])
            if best is None or abs(f - f_peak) < abs(best - f_peak):
                best = float(f)
    return best if best is not None else float(f_peak)


def harmonic_errors(
    freqs, err_db, err_deg, coh, s_pp, s_uu, f0, config: ValidationConfig
) -> pd.DataFrame:
    """Errors at the note's harmonics.

    ``compared`` marks the coherent harmonics whose flow is a line at least 20 dB above its
    surroundings (a harmonic the note does not play has only window leakage there, coherent
    but not the impedance at that bin).
    """
    columns = ["harmonic", "frequency_hz", "error_db", "error_deg", "coherence", "compared"]
    if f0 is None or not np.isfinite(f0) or config.n_harmonics == 0:
        return pd.DataFrame(columns=columns)
    rows = []
    df = freqs[1] - freqs[0]
    local = ndimage.median_filter(s_uu, size=max(int(f0 / df), 3), mode="nearest")
    for h in range(1, config.n_harmonics + 1):
        f = h * f0
        if f > config.fmax_hz:
            break
        # strongest bin within +-2 bins of the nominal harmonic
        near = np.flatnonzero(np.abs(freqs - f) <= 2 * df)
        if near.size == 0:
            continue
        i = int(near[np.argmax(s_pp[near])])
        line = bool(s_uu[i] > 100 * local[i])
        rows.append(
            [h, float(freqs[i]), float(err_db[i]), float(err_deg[i]), float(coh[i]),
             line and coh[i] >= config.min_coherence]
        )  # fmt: skip
    return pd.DataFrame(rows, columns=columns)


__all__ = ["harmonic_errors", "phase_zero", "resonance_errors"]
