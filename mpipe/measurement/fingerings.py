"""Which fingering a note was played with: each of the calibration's, weighed by the data.

A fingering is a bore (its holes open, the others closed), so it has its own input
impedance ``Z_F``. A played note measures the impedance at its harmonics:
``z_k = P(k f0) / U(k f0)`` (the complex amplitudes of the pressure and flow lines over the
note, Hann-windowed), which must equal ``Z_F(k f0)`` for the fingering played. The
log-likelihood of fingering F is

    ln L_F = -1/2 sum_k min(((Re e_k) / s_mag)^2 + ((Im e_k) / s_phase)^2, CAP),
    e_k = ln(z_k / Z_F(k f0)),

over the harmonics whose flow line stands well above the note's weakest (``s_mag`` the
validation's magnitude tolerance, 3 dB as a natural log, ``s_phase`` its phase tolerance,
20 deg; CAP bounds one harmonic's weight, so one bad line cannot decide). Between a
fingering's resonances ``|Z_F|`` is tens of dB below its peaks, so a harmonic that sits on
a peak of one fingering and between the peaks of another tells them apart even when the
two fingerings give nearly the same playing frequency. Without signals (only f0) the
likelihood is the playing frequency's distance from the fingering's nearest resonance
(a clarinet plays at, or a few tens of cents below, a resonance of its bore).

The posterior (equal priors) names the fingering found, its probability and the
runner-up's; a note whose best probability is below :data:`AMBIGUOUS_BELOW` is flagged
ambiguous (the fingering is the most likely one, and the report and the take's checks
say that it could be the runner-up), never chosen silently.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from mpipe.acoustics.bore import input_impedance
from mpipe.measurement.calibration import Calibration

#: Best posterior probability below which a note's fingering is flagged ambiguous.
AMBIGUOUS_BELOW = 0.95
#: Scale of the magnitude error of ln z (3 dB, the validation's harmonic tolerance).
S_MAG = 3.0 * math.log(10.0) / 20.0
#: Scale of the phase error of ln z, rad (20 deg, the validation's harmonic tolerance).
S_PHASE = math.radians(20.0)
#: Largest misfit one harmonic contributes (5 scales).
CAP = 25.0
#: Scale of the playing frequency's distance from a resonance, cents (f0 alone).
S_CENTS = 40.0
#: Harmonics used, and the band's top, Hz.
N_HARMONICS = 10
FMAX_HZ = 2000.0
#: A harmonic counts when its flow line is within this factor of the strongest one.
MIN_LINE = 1e-3


@dataclass(frozen=True)
class FingeringChoice:
    """The fingering of one note and how sure it is.

    Attributes
    ----------
    fingering : str
        The fingering found (or given).
    probability : float
        Its posterior probability (1 when given).
    runner_up : str or None
        The next most likely fingering (None when given or when there is only one).
    runner_up_probability : float
        Its probability.
    source : str
        ``"auto"`` (found from the data) or ``"given"``.
    log_likelihoods : dict
        Fingering name to its log-likelihood (empty when given).
    harmonics : int
        Harmonics the likelihood used (0: the playing frequency alone).
    """

    fingering: str
    probability: float = 1.0
    runner_up: str | None = None
    runner_up_probability: float = 0.0
    source: str = "given"
    log_likelihoods: dict = field(default_factory=dict)
    harmonics: int = 0

    @property
    def ambiguous(self) -> bool:
        """Found, with a posterior probability below :data:`AMBIGUOUS_BELOW`."""
        return self.source == "auto" and self.probability < AMBIGUOUS_BELOW

    def line(self) -> str:
        """``fingering xxoo (p = 0.998; runner-up xooo, p = 0.002)``, ambiguity first."""
        if self.source == "given":
            return f"fingering {self.fingering} (given)"
        other = (
            f"; runner-up {self.runner_up}, p = {self.runner_up_probability:.3f}"
            if self.runner_up
            else ""
        )
        what = "AMBIGUOUS fingering" if self.ambiguous else "fingering"
        return f"{what} {self.fingering} (p = {self.probability:.3f}{other})"


def harmonic_lines(
    p: np.ndarray, u: np.ndarray, fs: float, f0: float, n: int = N_HARMONICS
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frequencies (Hz) and complex amplitudes of P and U at the harmonics ``k f0``.

    Each amplitude is the projection of the Hann-windowed signal on ``exp(-j 2 pi k f0 t)``;
    P and U leak alike when f0 is slightly off, so their ratio stays Z at that frequency.
    """
    p = np.asarray(p, dtype=float)
    u = np.asarray(u, dtype=float)
    w = np.hanning(p.size)
    t = np.arange(p.size) / fs
    k = np.arange(1, n + 1)
    freqs = k * f0
    freqs = freqs[freqs <= min(FMAX_HZ, 0.45 * fs)]
    basis = np.exp(-2j * np.pi * np.outer(freqs, t)) * w
    return freqs, basis @ (p - p.mean()), basis @ (u - u.mean())


def identify(
    f0: float,
    calibration: Calibration,
    lines: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    temperature_c: float | None = None,
    names: Sequence[str] | None = None,
) -> FingeringChoice:
    """The fingering of a note among the calibration's, from its f0 and harmonics.

    Parameters
    ----------
    f0 : float
        Playing frequency, Hz.
    calibration : Calibration
        The instrument and its fingerings.
    lines : (freqs, P, U), optional
        The note's harmonic lines (:func:`harmonic_lines`); None: f0 alone.
    temperature_c : float, optional
        Air temperature of the theory, degC (default the calibration's).
    names : sequence of str, optional
        The candidates (default every fingering of the calibration).

    Returns
    -------
    FingeringChoice

    Raises
    ------
    ValueError
        When the calibration has no fingerings or f0 is not a positive number.
    """
    names = list(names or [f.name for f in calibration.fingerings])
    if not names:
        raise ValueError("no fingerings to choose from: the calibration names none")
    if not (math.isfinite(f0) and f0 > 0):
        raise ValueError(f"f0: expected a positive frequency, got {f0!r} Hz")
    t = calibration.air.temperature_c if temperature_c is None else float(temperature_c)
    air = calibration.air_properties(t)
    used = 0
    logl = {}
    for name in names:
        bore = calibration.with_fingering(name).bore
        if lines is not None:
            logl[name], used = _harmonic_loglik(bore, air, lines)
        else:
            logl[name] = _pitch_loglik(bore, air, f0)
    order = sorted(names, key=lambda x: -logl[x])
    top = max(logl.values())
    weights = {x: math.exp(v - top) for x, v in logl.items()}
    total = sum(weights.values())
    best = order[0]
    second = order[1] if len(order) > 1 else None
    return FingeringChoice(
        best,
        weights[best] / total,
        second,
        weights[second] / total if second else 0.0,
        "auto",
        logl,
        used,
    )


def _harmonic_loglik(bore, air, lines) -> tuple[float, int]:
    """Log-likelihood of a bore from the note's harmonic lines, and the lines used."""
    freqs, pk, uk = lines
    strong = np.abs(uk) >= MIN_LINE * np.max(np.abs(uk)) if uk.size else np.zeros(0, bool)
    strong &= np.abs(pk) > 0
    if not strong.any():
        return 0.0, 0
    z_th = input_impedance(bore, 2 * np.pi * freqs[strong], air)
    e = np.log(pk[strong] / uk[strong] / z_th)
    misfit = np.minimum((e.real / S_MAG) ** 2 + (e.imag / S_PHASE) ** 2, CAP)
    return float(-0.5 * misfit.sum()), int(strong.sum())


def _pitch_loglik(bore, air, f0: float) -> float:
    """Log-likelihood of a bore from the playing frequency alone: cents to a resonance."""
    grid = np.arange(20.0, FMAX_HZ, 0.5)
    z = np.abs(input_impedance(bore, 2 * np.pi * grid, air))
    peaks = grid[1:-1][(z[1:-1] > z[:-2]) & (z[1:-1] >= z[2:])]
    if not peaks.size:
        return -CAP
    cents = 1200 * np.log2(f0 / peaks)
    return float(-0.5 * min(np.min((cents / S_CENTS) ** 2), CAP))


__all__ = ["AMBIGUOUS_BELOW", "FingeringChoice", "harmonic_lines", "identify"]
