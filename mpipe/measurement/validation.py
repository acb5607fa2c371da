"""Validation of the measured mouthpiece signals against the theoretical input impedance.

The bore is linear and passive, so ``P = Z_in U`` at every frequency. The measured
normalised impedance is the H1 estimate ``z = S_UP / S_UU / Z0`` (Welch, Hann, 50 %
overlap; ``S_UP = E[conj(U) P]``) with the squared coherence of U and P, compared with
``z_th = Z_in / Z0`` of the configured bore and termination (physics.md D.1, F.3), both
with ``Z0 = rho c / S`` real at the entry. Bins where U carries little energy (between the
harmonics of a played note) are unreliable; the coherence marks them.

Metrics (physics.md F.3): resonance frequencies in cents and peak levels in dB at the
first peaks of ``|z_th|`` matched to peaks of ``|z|`` within ``match_cents``; magnitude and
phase errors at the note's harmonics; band-averaged magnitude and phase errors over the
coherent bins. For a played note (a strong spectral line, or ``note_f0_hz`` given) only the
bins at its harmonics count, and the resonances are reported without a measured value: the
note does not excite the bore there. The verdict compares the metrics with the tolerances
of :class:`ValidationConfig`: FAIL when a compared quantity is out of tolerance, PASS when
at least ``min_checks`` quantities (measured resonances and coherent harmonics) were
compared and all are within it, CANNOT-VERIFY otherwise (nothing measurable: silence, a
take without a coherent harmonic, or broadband noise too weak to show a resonance).

References
----------
Chatziioannou & van Walstijn 2012, section 4 and Fig. 10; physics.md D.1 and F.3.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import ndimage, signal

from mpipe.acoustics.bore import input_impedance
from mpipe.core.config import between, positive, spec
from mpipe.core.signals import DiskArray, as_signal
from mpipe.measurement.calibration import Calibration
from mpipe.measurement.harmonic_impedance import compare_harmonics, frame_lines
from mpipe.measurement.pitch import yin_f0
from mpipe.measurement.validation_metrics import harmonic_errors, resonance_errors
from mpipe.measurement.validation_result import ValidationResult, db
from mpipe.measurement.validation_suspects import other_fingering, suspect_inputs

log = logging.getLogger(__name__)

# Fewest Welch averages of the impedance estimate: the squared coherence of n averages
# of two independent signals is about 1/n, far below the 0.9 threshold for n >= 8.
_MIN_AVERAGES = 8


@dataclass(frozen=True)
class ValidationConfig:
    """Settings and tolerances of the impedance validation."""

    resolution_hz: float = spec(
        "Hz",
        "Welch frequency resolution; the segment is the next power of two >= fs / resolution "
        "(at most the length that leaves 8 half-overlapping averages)",
        positive,
        default=1.0,
    )
    fmin_hz: float = spec("Hz", "lower edge of the compared band", positive, default=50.0)
    fmax_hz: float = spec(
        "Hz", "upper edge of the compared band and of the plot", positive, default=2000.0
    )
    n_resonances: int = spec("", "resonances compared", between(1, 50), default=5)
    match_cents: float = spec(
        "cent",
        "largest distance of a measured peak from its theoretical one",
        positive,
        default=50.0,
    )
    min_coherence: float = spec(
        "", "squared coherence for a bin to count as measured", between(0.0, 1.0), default=0.9
    )
    smoothing_bins: int = spec(
        "", "running mean (bins) of |z| before peak picking", between(1, 101), default=1
    )
    trim_s: float = spec(
        "s",
        "discarded at each end of the signals (translation edges)",
        between(0.0, 10.0),
        default=0.01,
    )
    note_f0_hz: float | None = spec(
        "Hz",
        "playing frequency (null: found from the pressure spectrum)",
        positive,
        default=None,
    )
    n_harmonics: int = spec("", "harmonics of the note compared", between(0, 100), default=10)
    max_resonance_cents: float = spec(
        "cent", "tolerance on each resonance frequency", positive, default=15.0
    )
    max_peak_db: float = spec("dB", "tolerance on each peak level", positive, default=2.0)
    max_band_db: float = spec(
        "dB",
        "tolerance on the mean |magnitude error| over coherent bins",
        positive,
        default=1.5,
    )
    false_alarm: float = spec(
        "",
        "false-alarm rate of a played note's harmonic test (its reflection coefficient "
        "against the theory, per harmonic with Bonferroni and summed over the harmonics)",
        between(1e-9, 0.5),
        default=1e-3,
    )
    min_checks: int = spec(
        "",
        "fewest compared quantities (measured resonances plus coherent harmonics) for a "
        "PASS; with fewer and no failure the verdict is CANNOT-VERIFY",
        between(1, 100),
        default=3,
    )


def measured_impedance(
    p: np.ndarray, u: np.ndarray, fs: float, nperseg: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """H1 estimate of ``Z = S_UP / S_UU`` with the squared coherence (physics.md F.3).

    Parameters
    ----------
    p : ndarray
        Pressure in Pa.
    u : ndarray
        Volume flow in m^3/s.
    fs : float
        Sample rate in Hz.
    nperseg : int
        Welch segment length (Hann, 50 % overlap).

    Returns
    -------
    freqs : ndarray
        Hz.
    z : ndarray
        Impedance in Pa s/m^3.
    coherence : ndarray
        Squared coherence (dimensionless).
    """
    freqs, s_uu, s_pp, s_up = welch_spectra(p, u, fs, nperseg)
    z = s_up / np.maximum(s_uu, 1e-300)
    coh = np.abs(s_up) ** 2 / np.maximum(s_uu * s_pp, 1e-300)
    return freqs, z, coh


#: Welch segments averaged per chunk by :func:`welch_spectra` (memory bounded by the chunk:
#: at 100 kHz and 1 Hz resolution a segment is 2^17 samples, and scipy holds each chunk's
#: segments, windowed and transformed, a few times over: 16 keep that near 60 MB, where 256
#: reached about 1 GB for a take longer than 3 minutes).
_SEGMENTS_PER_CHUNK = 16


def welch_spectra(
    p: np.ndarray, u: np.ndarray, fs: float, nperseg: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Welch spectra ``S_UU``, ``S_PP`` and ``S_UP = E[conj(U) P]`` (Hann, 50 % overlap).

    The same numbers as ``scipy.signal.welch`` and ``csd`` over the whole signals (mean of
    the periodograms of every full segment), computed chunk by chunk of
    ``_SEGMENTS_PER_CHUNK`` segments so that memory does not grow with the take.

    Returns
    -------
    freqs : ndarray
        Hz.
    s_uu, s_pp, s_up : ndarray
        One-sided (cross) spectral densities, (m^3/s)^2/Hz, Pa^2/Hz and Pa m^3/s/Hz.
    """
    kw = {"fs": fs, "nperseg": nperseg, "window": "hann", "detrend": "constant"}
    hop = nperseg - nperseg // 2
    n_seg = max((p.size - nperseg) // hop + 1, 1)
    sums, count, freqs = None, 0, None
    for first in range(0, n_seg, _SEGMENTS_PER_CHUNK):
        k = min(_SEGMENTS_PER_CHUNK, n_seg - first)
        a = first * hop
        b = a + (k - 1) * hop + nperseg
        freqs, s_uu = signal.welch(u[a:b], **kw)
        _, s_pp = signal.welch(p[a:b], **kw)
        # scipy's csd(x, y) is E[conj(X) Y]: S_UP with U first.
        _, s_up = signal.csd(u[a:b], p[a:b], **kw)
        part = [k * s_uu, k * s_pp, k * s_up]
        sums = part if sums is None else [x + y for x, y in zip(sums, part, strict=True)]
        count += k
    assert sums is not None and freqs is not None
    return freqs, sums[0] / count, sums[1] / count, sums[2] / count


def _f0(p: np.ndarray, fs: float, freqs: np.ndarray, s_uu: np.ndarray) -> float:
    """The played note's fundamental, Hz, or NaN when no note is played.

    YIN (:func:`mpipe.measurement.pitch.yin_f0`) on frames of the pressure spread over the
    signal, median over the frames that have a period: it takes the first period at which
    the signal repeats, so it cannot lock on the octave or the twelfth of a clarinet note
    whose even harmonics are weak (the strongest spectral line may be the third harmonic).
    A note counts as played when the flow's spectrum has a line at one of the first three
    harmonics 30 dB above its median level in 50-1000 Hz (broadband excitation shows the
    bore's resonances in the pressure, not a line in the flow).
    """
    frame = int(round(2.2 / 50.0 * fs))
    if p.size < frame:
        return float("nan")
    starts = np.linspace(0, p.size - frame, min(15, max(1, p.size // frame))).astype(int)
    estimates = [yin_f0(p[s : s + frame], fs, 50.0, 2000.0)[0] for s in starts]
    estimates = [f for f in estimates if np.isfinite(f)]
    if len(estimates) < max(1, len(starts) // 2):
        return float("nan")
    f0 = float(np.median(estimates))
    band = (freqs >= 50) & (freqs <= 1000)
    if not np.any(band):
        return float("nan")
    floor = float(np.median(s_uu[band]))
    df = freqs[1] - freqs[0]
    for h in (1, 2, 3):
        near = np.abs(freqs - h * f0) <= max(1.5 * df, 0.01 * h * f0)
        if np.any(near) and s_uu[near].max() >= 1e3 * floor:
            return f0
    return float("nan")


def validate(
    p: np.ndarray,
    u: np.ndarray,
    fs: float,
    calibration: Calibration,
    config: ValidationConfig,
    temperature_c: float | None = None,
) -> ValidationResult:
    """Compare the measured impedance of mouthpiece signals with the theory.

    Parameters
    ----------
    p : ndarray
        Pressure at the mouthpiece entry, Pa.
    u : ndarray
        Volume flow into the mouthpiece entry, m^3/s.
    fs : float
        Sample rate in Hz.
    calibration : Calibration
        Bore, termination and air model of the theory.
    config : ValidationConfig
        Band, resolution and tolerances.
    temperature_c : float, optional
        Air temperature of the theory, degC (default the calibration's; pass the effective
        temperature of the wave separation).

    Returns
    -------
    ValidationResult

    Raises
    ------
    ValueError
        For signals of different shapes or shorter than one Welch segment of 64 samples.

    References
    ----------
    physics.md D.1, F.3; Chatziioannou & van Walstijn 2012, Fig. 10.
    """
    p, u, nperseg = _trimmed(p, u, fs, config)
    t = calibration.air.temperature_c if temperature_c is None else float(temperature_c)
    air = calibration.air_properties(t)
    z0 = calibration.bore.entry_impedance(air)
    freqs, z_me, coh, s_pp, s_uu = _measured(p, u, fs, nperseg, z0)
    z_th = input_impedance(calibration.bore, 2 * np.pi * freqs, air) / z0
    band = (freqs >= config.fmin_hz) & (freqs <= config.fmax_hz)
    err_db = db(z_me) - db(z_th)
    err_deg = np.rad2deg(np.angle(z_me / z_th))
    # The excitation (U) shows whether a note is played; P carries the resonances too.
    f0 = config.note_f0_hz if config.note_f0_hz is not None else _f0(p, fs, freqs, s_uu)
    tonal = f0 is not None and np.isfinite(f0)
    good = band & (coh >= config.min_coherence)
    harmonic_failures: list[str] = []
    if tonal:
        good &= _harmonic_bins(freqs, s_uu, f0)[0]
        theory = _Theory(calibration, t, z0)
        lines = frame_lines(p, u, fs, f0, config.n_harmonics, config.fmax_hz)
        harmonics, harmonic_failures = compare_harmonics(lines, theory, config.false_alarm)
    else:
        harmonics = harmonic_errors(freqs, err_db, err_deg, coh, s_pp, s_uu, f0, config)
    band_db = float(np.mean(np.abs(err_db[good]))) if np.any(good) else float("nan")
    band_deg = float(np.mean(np.abs(err_deg[good]))) if np.any(good) else float("nan")
    coherent_fraction = float(np.mean(good[band])) if np.any(band) else 0.0

    resonances = resonance_errors(freqs, z_me, z_th, coh, band, config, measurable=not tonal)
    # a played note is judged on its harmonics' test (harmonic_impedance); the band error in
    # dB is shown, not tested: near an anti-resonance it amplifies any small difference
    failures = _failures(band_db, np.any(good) and not tonal, resonances, config)
    fine = _fine_grid(freqs)
    result = ValidationResult(
        freqs=freqs,
        z_measured=z_me,
        z_theory=z_th,
        coherence=coh,
        z0=float(z0),
        temperature_c=t,
        resonances=resonances,
        harmonics=harmonics,
        f0_hz=float(f0) if f0 is not None else float("nan"),
        band_error_db=band_db,
        band_error_deg=band_deg,
        coherent_fraction=coherent_fraction,
        failures=tuple(failures) + tuple(harmonic_failures),
        checks=int(np.sum(np.isfinite(resonances.error_cents)) if resonances.size else 0)
        + int(harmonics.compared.sum() if len(harmonics) else 0),
        min_checks=config.min_checks,
        theory_hz=fine,
        theory_z=input_impedance(calibration.bore, 2 * np.pi * fine, air) / z0,
        label=_fingering_label(calibration),
    )
    if result.failures:
        suspects = suspect_inputs(result, calibration)
        if tonal:
            suspects = other_fingering(p, u, fs, f0, calibration, t) + suspects
        result = dataclasses.replace(result, suspects=suspects)
    log.info("validation: %s (%s)", result.verdict, result.reason)
    return result


#: The fine theory's step and top, Hz: a clarinet resonance is a few Hz wide (Q ~ 30 at
#: 150 Hz), so its peak on a 0.25 Hz grid is within a small fraction of a dB; the figure
#: shows up to 2 kHz.
FINE_STEP_HZ, FINE_TOP_HZ = 0.25, 2500.0


def _fingering_label(calibration) -> str:
    """``"fingering xxoo"``: the fingering compared, for the figure ("" none named)."""
    name = getattr(calibration, "fingering", None)
    return f"fingering {name}" if isinstance(name, str) and name and name != "auto" else ""


def _fine_grid(freqs: np.ndarray) -> np.ndarray:
    """Frequencies (Hz) of the fine theory: up to the Welch grid's top or FINE_TOP_HZ."""
    top = min(float(freqs[-1]), FINE_TOP_HZ) if len(freqs) else 0.0
    return np.arange(FINE_STEP_HZ, top + FINE_STEP_HZ / 2, FINE_STEP_HZ)


def _trimmed(
    p: np.ndarray, u: np.ndarray, fs: float, config: ValidationConfig
) -> tuple[np.ndarray, np.ndarray, int]:
    """The signals without ``trim_s`` at each end, and the Welch segment length."""
    p, u = as_signal(p), as_signal(u)  # on disk: read segment by segment (welch_spectra)
    if p.ndim != 1 or p.shape != u.shape:
        raise ValueError(f"p and u must be 1-D of equal length, got {p.shape}, {u.shape}")
    trim = int(round(config.trim_s * fs))
    if p.size - 2 * trim >= 128:
        if isinstance(p, DiskArray):
            p, u = p.sub(trim, p.size - trim), u.sub(trim, u.size - trim)
        else:
            p, u = p[trim : p.size - trim], u[trim : u.size - trim]
    if p.size < 64:
        raise ValueError(f"need at least 64 samples to estimate an impedance, got {p.size}")
    nperseg = int(2 ** np.ceil(np.log2(fs / config.resolution_hz)))
    # At least _MIN_AVERAGES half-overlapping segments: with one segment the coherence is
    # identically 1 and every bin would count as measured.
    nperseg = min(nperseg, int(2 ** np.floor(np.log2(2 * p.size / (_MIN_AVERAGES + 1)))))
    return p, u, nperseg


def _measured(
    p: np.ndarray, u: np.ndarray, fs: float, nperseg: int, z0: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Frequencies (DC excluded), ``z = Z / z0``, coherence and the spectra of P and U."""
    freqs, s_uu, s_pp, s_up = welch_spectra(p, u, fs, nperseg)
    z_abs = s_up / np.maximum(s_uu, 1e-300)
    coh = np.abs(s_up) ** 2 / np.maximum(s_uu * s_pp, 1e-300)
    keep = freqs > 0
    freqs, z_abs, coh, s_pp, s_uu = freqs[keep], z_abs[keep], coh[keep], s_pp[keep], s_uu[keep]
    return freqs, z_abs / z0, coh, s_pp, s_uu


def _harmonic_bins(freqs: np.ndarray, s_uu: np.ndarray, f0: float) -> tuple[np.ndarray, np.ndarray]:
    """Bins at the harmonics of a played note whose flow carries energy, and each bin's order.

    A played note excites only its harmonics; between them the H1 ratio is window leakage of
    the harmonics (coherent, yet not Z at that bin), so only bins at the harmonics count.
    """
    df = freqs[1] - freqs[0]
    k = np.round(freqs / f0)
    at = (k >= 1) & (np.abs(freqs - k * f0) <= 0.5 * df)
    # and only harmonics that carry energy: a line 20 dB above its surroundings
    width = max(int(f0 / df), 3)
    local = ndimage.median_filter(s_uu, size=width, mode="nearest")
    return at & (s_uu > 100 * local), k


def _failures(
    band_db: float,
    any_coherent: bool,
    resonances: pd.DataFrame,
    config: ValidationConfig,
) -> list[str]:
    """Why the verdict is FAIL: the band error and the resonances out of tolerance."""
    failures = []
    # No coherent bin is not a failure of the measurement but nothing to compare: the
    # verdict is then CANNOT-VERIFY (see ValidationResult.reason).
    if any_coherent and band_db > config.max_band_db:
        failures.append(f"band error {band_db:.2f} dB > {config.max_band_db:g} dB")
    for i, r in resonances.iterrows():
        if not np.isfinite(r.error_cents):
            continue
        if abs(r.error_cents) > config.max_resonance_cents:
            failures.append(
                f"resonance {i + 1} at {r.frequency_theory_hz:.1f} Hz off by "
                f"{r.error_cents:.1f} cents (> {config.max_resonance_cents:g})"
            )
        if abs(r.error_db) > config.max_peak_db:
            failures.append(
                f"resonance {i + 1} level off by {r.error_db:.2f} dB (> {config.max_peak_db:g})"
            )
    return failures


@dataclass(frozen=True)
class _Theory:
    """``Z / Z0`` of the calibration's bore at ``t + dT`` degC, frequencies scaled by a factor.

    A bore longer by a factor plays its impedance at frequencies lower by it, so the
    length's sensitivity is read at ``f * scale``; ``z0`` (the measurement's) is fixed.
    """

    calibration: Calibration
    temperature_c: float
    z0: float

    @property
    def length_m(self) -> float:
        """The bore's length, m."""
        return float(self.calibration.bore.length)

    def __call__(self, freqs_hz: np.ndarray, d_t: float, scale: float) -> np.ndarray:
        air = self.calibration.air_properties(self.temperature_c + d_t)
        omega = 2 * np.pi * np.asarray(freqs_hz, dtype=float) * scale
        return input_impedance(self.calibration.bore, omega, air) / self.z0
