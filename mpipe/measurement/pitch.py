"""What was played: the fundamental frequency of a note, its pitch and its register.

:func:`yin_f0` estimates the fundamental of a (quasi-)periodic signal with the cumulative
mean normalised difference function of de Cheveigné & Kawahara (2002), "YIN, a fundamental
frequency estimator for speech and music", J. Acoust. Soc. Am. 111(4):1917-1930, steps 2-5:

- the difference function ``d(tau) = sum_j (x_j - x_{j+tau})^2`` over a fixed span of the
  signal (by FFT cross-correlation and cumulative energies);
- its cumulative mean normalisation ``d'(tau) = d(tau) / ((1/tau) sum_{1..tau} d(j))``,
  ``d'(0) = 1``, which removes the dip at zero lag without favouring long lags;
- the *first* lag where ``d'`` dips below an absolute threshold (0.15 by default), then
  the local minimum after it, refined by parabolic interpolation.

Taking the first dip, not the deepest, is what keeps the estimate off the octaves: a
clarinet note's even harmonics are weak, so its spectrum's strongest line may be the third
harmonic and an autocorrelation may peak as high at two periods as at one, but the
difference function is already near zero at one period. No lag shorter than the period
makes it small, since the signal does not repeat there (a sub-harmonic estimate would need
a dip at a *longer* lag that the first-dip rule never reaches first).

:func:`pitch_cents` and :func:`note_name` give the pitch against a reference (A4 = 440 Hz
by default), :func:`regime` the register a playing frequency belongs to from the bore's
resonances.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import signal

from mpipe.core.signals import as_signal

#: Pitch classes from C, equal temperament.
NOTE_NAMES = ("C", "C#", "D", "D#", "E", "F", "F#", "G", "G#", "A", "A#", "B")


def cmnd(x: np.ndarray, max_lag: int) -> np.ndarray:
    """Cumulative mean normalised difference ``d'(tau)`` for ``tau = 0 .. max_lag``.

    Parameters
    ----------
    x : ndarray
        Signal (any unit), 1-D, longer than ``2 * max_lag`` for a full-length span.
    max_lag : int
        Largest lag, samples.

    Returns
    -------
    ndarray
        ``d'`` (dimensionless), length ``max_lag + 1``; ``d'(0) = 1``.
    """
    x = np.asarray(x, dtype=float)
    x = x - x.mean()
    n = x.size
    span = n - max_lag  # each lag compares the same number of samples
    if span < 2 or max_lag < 1:
        raise ValueError(f"signal of {n} samples too short for lags up to {max_lag}")
    head = x[:span]
    r = signal.correlate(x[: span + max_lag], head, mode="valid", method="fft")[: max_lag + 1]
    e = np.concatenate([[0.0], np.cumsum(x * x)])
    lags = np.arange(max_lag + 1)
    energy_lagged = e[span + lags] - e[lags]
    d = np.maximum(r[0] + energy_lagged - 2.0 * r, 0.0)
    out = np.ones(max_lag + 1)
    running = np.cumsum(d[1:])
    with np.errstate(invalid="ignore", divide="ignore"):
        out[1:] = np.where(running > 0, d[1:] * lags[1:] / running, 1.0)
    return out


def yin_f0(
    x: np.ndarray,
    fs: float,
    fmin: float = 60.0,
    fmax: float = 2000.0,
    threshold: float = 0.15,
) -> tuple[float, float]:
    """Fundamental frequency by YIN (see the module docstring) and its aperiodicity.

    Parameters
    ----------
    x : ndarray
        Signal (any unit), 1-D; at least two periods of ``fmin`` long for the full range.
    fs : float
        Sample rate, Hz.
    fmin, fmax : float
        Range searched, Hz.
    threshold : float
        Absolute threshold on ``d'`` (dimensionless; 0.1-0.2 in the paper).

    Returns
    -------
    (f0 Hz, aperiodicity)
        ``f0`` is NaN when no lag in range dips below the threshold (no period: noise or
        silence); the aperiodicity is ``d'`` at the chosen lag (0 for a perfectly periodic
        signal, ~1 for noise).
    """
    x = np.asarray(x, dtype=float)
    lo = max(int(math.floor(fs / fmax)), 2)
    max_lag = min(int(math.ceil(fs / fmin)) + 1, x.size // 2)
    if max_lag <= lo + 2 or not np.any(x - x.mean()):
        return math.nan, 1.0
    d = cmnd(x, max_lag)
    below = np.flatnonzero(d[lo:max_lag] < threshold)
    if below.size == 0:
        return math.nan, float(np.min(d[lo:max_lag]))
    j = lo + int(below[0])
    while j + 1 < max_lag and d[j + 1] < d[j]:
        j += 1  # down to the dip's bottom
    a, b, c = d[j - 1], d[j], d[min(j + 1, max_lag)]
    den = a - 2.0 * b + c
    frac = 0.5 * (a - c) / den if den > 0 else 0.0
    return fs / (j + float(np.clip(frac, -0.5, 0.5))), float(b)


def f0_track(
    x: np.ndarray,
    fs: float,
    frame_s: float,
    hop_s: float,
    fmin: float = 60.0,
    fmax: float = 2000.0,
    threshold: float = 0.15,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """YIN f0 over frames of ``frame_s`` every ``hop_s``.

    Returns
    -------
    (centres s, f0 Hz, aperiodicity)
        One value per frame; f0 NaN where no period was found.
    """
    x = as_signal(x)  # a take on disk is read frame by frame
    n = max(int(round(frame_s * fs)), 8)
    hop = max(int(round(hop_s * fs)), 1)
    starts = np.arange(0, max(len(x) - n, 0) + 1, hop)
    f0 = np.full(starts.size, math.nan)
    ap = np.ones(starts.size)
    for i, s in enumerate(starts):
        f0[i], ap[i] = yin_f0(x[s : s + n], fs, fmin, fmax, threshold)
    return (starts + n / 2) / fs, f0, ap


def pitch_cents(f0_hz, reference_hz: float = 440.0):
    """Pitch of ``f0_hz`` in cents above A4 = ``reference_hz`` (NaN where f0 is not > 0)."""
    f = np.asarray(f0_hz, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = 1200.0 * np.log2(np.where(f > 0, f, np.nan) / reference_hz)
    return float(out) if out.ndim == 0 else out


def note_name(f0_hz: float, reference_hz: float = 440.0) -> str:
    """Nearest equal-tempered note and the deviation, e.g. ``"D3 -12 c"`` ("" for NaN)."""
    cents = pitch_cents(f0_hz, reference_hz)
    if not math.isfinite(cents):
        return ""
    semis = int(round(cents / 100.0))
    midi = 69 + semis
    octave = midi // 12 - 1
    return f"{NOTE_NAMES[midi % 12]}{octave} {cents - 100 * semis:+.0f} c"


def regime(f0_hz: float, resonances_hz) -> str:
    """The register a playing frequency belongs to, from the bore's resonances.

    The note plays on the resonance nearest in log frequency: the first is the
    ``fundamental`` regime, the second ``register 2`` (the clarinet's twelfth, normally
    reached with the register key), any higher one a ``squeak``. Farther than 300 cents from
    every resonance is ``other`` (no resonance explains it); no resonances known gives "".

    Parameters
    ----------
    f0_hz : float
        Playing frequency, Hz.
    resonances_hz : sequence of float
        Frequencies of the bore's input-impedance peaks, Hz, ascending.

    Returns
    -------
    str
    """
    res = np.asarray(resonances_hz, dtype=float)
    res = res[np.isfinite(res) & (res > 0)]
    if not (math.isfinite(f0_hz) and f0_hz > 0):
        return "silence"
    if res.size == 0:
        return ""
    dist = np.abs(1200.0 * np.log2(f0_hz / res))
    i = int(np.argmin(dist))
    if dist[i] > 300.0:
        return "other"
    return ("fundamental", "register 2")[i] if i < 2 else "squeak"


__all__ = ["NOTE_NAMES", "cmnd", "f0_track", "note_name", "pitch_cents", "regime", "yin_f0"]
