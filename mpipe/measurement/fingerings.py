"""Which fingering a note was played with: a goodness-of-fit test of each of the calibration's.

A fingering is a bore (its holes open, the others closed), so it has its own input
impedance ``Z_F``. A played note measures the impedance at its harmonics:
``z_k = P(k f0) / U(k f0)`` (the complex amplitudes of the pressure and flow lines over the
note, Hann-windowed), which must equal ``Z_F(k f0)`` for the fingering played. With
``e_k = ln(z_k / Z_F(k f0))`` the misfit of fingering F is

    chi2_F = sum_k (Re e_k)^2 / s_re,k^2 + (Im e_k)^2 / s_im,k^2

over the harmonics whose flow line stands well above the note's weakest, where each
variance is the sum of

- the **noise** of ``ln z_k`` measured from the note itself: the scatter of ``ln z_k``
  over :data:`BLOCKS` consecutive blocks of the note, divided by their number;
- the **theory's** uncertainty: a frequency-scale error of :data:`THEORY_CENTS` (the
  theory's measured accuracy on a real four-hole tube, physics.md D.3, and the separation's
  temperature) times the slope ``d ln Z_F / d ln f`` at the harmonic, which is large on a
  resonance and small between two;
- a floor for the separation's calibration, :data:`FLOOR_DB` and :data:`FLOOR_DEG`
  (microphone gain and phase errors that a calibration leaves, and the reed model's own
  departure from the linear theory on clean virtual takes, 0.1-0.8 dB and 0.1-10 deg).

The log-likelihood is the Gaussian one, ``-chi2_F / 2 - sum ln(s_re s_im)``, and the
posterior (equal priors) names the fingering found, its probability and the runner-up's.
Then two questions are asked of the data rather than of the list:

- **does the best fingering fit at all?** ``chi2_F`` follows a chi-square law with
  ``2 N`` degrees of freedom when F is right; below a probability of :data:`NO_FIT_BELOW`
  the note's fingering is not in the list ("no listed fingering fits"), however sure the
  posterior is among the wrong ones;
- **which fingerings are the same at these harmonics?** Two whose theories differ by less
  than one standard deviation in all (``sum |ln Z_F - ln Z_G|^2 / s^2 < 1``) cannot be
  told apart by the note: they are one answer (the first listed names it, the others are
  its ``equivalents``), not an ambiguity.

A note whose best probability (with its equivalents) is below :data:`AMBIGUOUS_BELOW` is
flagged ambiguous, never chosen silently. Without signals (only f0) the likelihood is the
playing frequency's distance from the fingering's nearest resonance (a clarinet plays at, or
a few tens of cents below, a resonance of its bore), and no fit is tested.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from mpipe.acoustics.bore import input_impedance
from mpipe.measurement.calibration import Calibration

#: Best posterior probability below which a note's fingering is flagged ambiguous.
AMBIGUOUS_BELOW = 0.95
#: The theory's frequency-scale uncertainty, cents (its accuracy on a measured tube).
THEORY_CENTS = 6.0
#: Floor of the magnitude and phase uncertainty of ln z: the separation's calibration.
FLOOR_DB = 0.5
FLOOR_DEG = 3.0
#: Blocks of the note whose scatter measures the noise of ln z (fewer on a short note).
BLOCKS = 6
#: Shortest block, periods of f0.
BLOCK_PERIODS = 4
#: Goodness-of-fit probability below which no listed fingering fits the note.
NO_FIT_BELOW = 1e-3
#: Total squared distance (in standard deviations) under which two fingerings are one.
EQUIVALENT_BELOW = 1.0
#: Largest misfit (squared standard deviations) the playing frequency alone contributes.
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
    fit_probability : float
        Probability of a misfit at least ``chi2`` if the fingering were right (chi-square
        law, ``2 harmonics`` degrees of freedom); 1 when not tested.
    chi2 : float
        The fingering's misfit, squared standard deviations.
    equivalents : tuple of str
        Other listed fingerings with the same impedance at the note's harmonics (one answer).
    """

    fingering: str
    probability: float = 1.0
    runner_up: str | None = None
    runner_up_probability: float = 0.0
    source: str = "given"
    log_likelihoods: dict = field(default_factory=dict)
    harmonics: int = 0
    fit_probability: float = 1.0
    chi2: float = 0.0
    equivalents: tuple[str, ...] = ()

    @property
    def fits(self) -> bool:
        """False when the best fingering fails the goodness-of-fit test: none listed fits."""
        return not self.fit_probability < NO_FIT_BELOW

    @property
    def ambiguous(self) -> bool:
        """Found, with a posterior probability below :data:`AMBIGUOUS_BELOW`."""
        return self.source == "auto" and self.probability < AMBIGUOUS_BELOW

    def line(self) -> str:
        """``fingering xxoo (p = 0.998; runner-up xooo, p = 0.002)``, a misfit first."""
        if self.source == "given":
            return f"fingering {self.fingering} (given)"
        if not self.fits:
            return (
                f"NO listed fingering fits (the closest, {self.fingering}, misfits by "
                f"chi2 = {self.chi2:.0f} for {2 * self.harmonics} degrees of freedom, "
                f"p = {self.fit_probability:.1g})"
            )
        same = f" = {', '.join(self.equivalents)} at these harmonics" if self.equivalents else ""
        other = (
            f"; runner-up {self.runner_up}, p = {self.runner_up_probability:.3f}"
            if self.runner_up
            else ""
        )
        what = "AMBIGUOUS fingering" if self.ambiguous else "fingering"
        return f"{what} {self.fingering}{same} (p = {self.probability:.3f}{other})"


@dataclass(frozen=True)
class NoteLines:
    """A note's harmonic lines and the noise of ``ln(P/U)`` at each, measured from the note.

    Unpacks as ``freqs, P, U``.

    Attributes
    ----------
    freqs : ndarray
        Harmonic frequencies ``k f0``, Hz.
    p, u : ndarray
        Complex amplitudes of pressure (Pa) and flow (m^3/s) at them.
    var_re, var_im : ndarray
        Variance of the real and imaginary part of ``ln(P/U)`` (dimensionless, rad^2): the
        scatter over the note's blocks divided by their number; 0 when the note is too
        short for three blocks.
    """

    freqs: np.ndarray
    p: np.ndarray
    u: np.ndarray
    var_re: np.ndarray
    var_im: np.ndarray

    def __iter__(self):
        return iter((self.freqs, self.p, self.u))


def harmonic_lines(
    p: np.ndarray, u: np.ndarray, fs: float, f0: float, n: int = N_HARMONICS
) -> NoteLines:
    """Frequencies (Hz) and complex amplitudes of P and U at the harmonics ``k f0``.

    Each amplitude is the projection of the Hann-windowed signal on ``exp(-j 2 pi k f0 t)``;
    P and U leak alike when f0 is slightly off, so their ratio stays Z at that frequency.
    The same projection on up to :data:`BLOCKS` consecutive blocks of the note gives the
    noise of ``ln(P/U)``: the blocks' sample variance over their number.
    """
    p = np.asarray(p, dtype=float)
    u = np.asarray(u, dtype=float)
    k = np.arange(1, n + 1)
    freqs = k * f0
    freqs = freqs[freqs <= min(FMAX_HZ, 0.45 * fs)]
    pk, uk = _project(p, u, fs, freqs)
    blocks = min(BLOCKS, int(p.size / (BLOCK_PERIODS * fs / f0)))
    var_re = var_im = np.zeros(freqs.size)
    if blocks >= 3:
        size = p.size // blocks
        with np.errstate(divide="ignore", invalid="ignore"):
            lz = np.array([
                np.log(np.divide(*_project(p[i * size:(i + 1) * size],
                                           u[i * size:(i + 1) * size], fs, freqs)))
                for i in range(blocks)
            ])  # fmt: skip
        var_re = np.var(lz.real, axis=0, ddof=1) / blocks
        # the phase's scatter about its circular mean, not across a 2 pi wrap
        var_im = np.var(np.angle(np.exp(1j * (lz.imag - np.angle(pk / uk)))), axis=0, ddof=1)
        var_im = var_im / blocks
    return NoteLines(freqs, pk, uk, var_re, var_im)


def _project(p, u, fs, freqs):
    w = np.hanning(p.size)
    t = np.arange(p.size) / fs
    basis = np.exp(-2j * np.pi * np.outer(freqs, t)) * w
    return basis @ (p - p.mean()), basis @ (u - u.mean())


def identify(
    f0: float,
    calibration: Calibration,
    lines: NoteLines | tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
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
    lines : NoteLines or (freqs, P, U), optional
        The note's harmonic lines (:func:`harmonic_lines`, with their measured noise; a
        bare tuple has the floors only); None: f0 alone.
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
    if lines is None:
        logl = {x: _pitch_loglik(calibration.with_fingering(x).bore, air, f0) for x in names}
        return _choice(names, logl, {}, 0, 1.0, 0.0, ())
    fits = {x: _harmonic_fit(calibration.with_fingering(x).bore, air, lines) for x in names}
    logl = {x: v[0] for x, v in fits.items()}
    best = max(names, key=lambda x: logl[x])
    _, chi2, used, log_z, s_re, s_im = fits[best]
    if used == 0:
        return _choice(names, logl, {}, 0, 1.0, 0.0, ())
    same = tuple(
        x
        for x in names
        if x != best
        and float(np.sum(((fits[x][3] - log_z).real / s_re) ** 2
                         + (_wrap(fits[x][3] - log_z).imag / s_im) ** 2)) < EQUIVALENT_BELOW
    )  # fmt: skip
    p_fit = float(stats.chi2.sf(chi2, 2 * used))
    return _choice(names, logl, same, used, p_fit, chi2, same)


def _wrap(z: np.ndarray) -> np.ndarray:
    """``z`` with its imaginary part (a phase) wrapped to (-pi, pi]."""
    return z.real + 1j * np.angle(np.exp(1j * z.imag))


def _choice(names, logl, same, used, p_fit, chi2, equivalents) -> FingeringChoice:
    """The posterior (equal priors), the equivalents of the best counted as the best."""
    top = max(logl.values())
    weights = {x: math.exp(v - top) for x, v in logl.items()}
    total = sum(weights.values())
    best = max(names, key=lambda x: logl[x])
    p_best = (weights[best] + sum(weights[x] for x in same)) / total
    others = sorted((x for x in names if x != best and x not in same), key=lambda x: -logl[x])
    second = others[0] if others else None
    return FingeringChoice(
        best,
        p_best,
        second,
        weights[second] / total if second else 0.0,
        "auto",
        logl,
        used,
        p_fit,
        chi2,
        equivalents,
    )


def _harmonic_fit(bore, air, lines):
    """Log-likelihood of a bore from the note's lines, its chi2, the lines used, ln Z_F, s.

    The uncertainty of each harmonic: the note's noise, the theory's frequency-scale
    uncertainty times the slope of ln Z_F, and the calibration floor (module docstring).
    """
    freqs, pk, uk = lines
    var_re = getattr(lines, "var_re", np.zeros(freqs.size))
    var_im = getattr(lines, "var_im", np.zeros(freqs.size))
    strong = np.abs(uk) >= MIN_LINE * np.max(np.abs(uk)) if uk.size else np.zeros(0, bool)
    strong &= (np.abs(pk) > 0) & np.isfinite(var_re) & np.isfinite(var_im)
    if not strong.any():
        return 0.0, 0.0, 0, np.zeros(0, complex), np.ones(0), np.ones(0)
    f = freqs[strong]
    step = 1e-4  # relative: the slope d ln Z / d ln f by central differences
    omega = 2 * np.pi * np.concatenate([f, f * (1 + step), f * (1 - step)])
    z_all = input_impedance(bore, omega, air)
    log_z = np.log(z_all[: f.size])
    slope = _wrap(np.log(z_all[f.size : 2 * f.size]) - np.log(z_all[2 * f.size :])) / (2 * step)
    scale = THEORY_CENTS * math.log(2.0) / 1200.0
    floor_re, floor_im = FLOOR_DB * math.log(10.0) / 20.0, math.radians(FLOOR_DEG)
    s_re = np.sqrt(var_re[strong] + floor_re**2 + (slope.real * scale) ** 2)
    s_im = np.sqrt(var_im[strong] + floor_im**2 + (slope.imag * scale) ** 2)
    e = _wrap(np.log(pk[strong] / uk[strong]) - log_z)
    chi2 = float(np.sum((e.real / s_re) ** 2 + (e.imag / s_im) ** 2))
    logl = -0.5 * chi2 - float(np.sum(np.log(s_re * s_im)))
    return logl, chi2, int(strong.sum()), log_z, s_re, s_im


def _pitch_loglik(bore, air, f0: float) -> float:
    """Log-likelihood of a bore from the playing frequency alone: cents to a resonance."""
    grid = np.arange(20.0, FMAX_HZ, 0.5)
    z = np.abs(input_impedance(bore, 2 * np.pi * grid, air))
    peaks = grid[1:-1][(z[1:-1] > z[:-2]) & (z[1:-1] >= z[2:])]
    if not peaks.size:
        return -CAP
    cents = 1200 * np.log2(f0 / peaks)
    return float(-0.5 * min(np.min((cents / S_CENTS) ** 2), CAP))


__all__ = [
    "AMBIGUOUS_BELOW",
    "NO_FIT_BELOW",
    "FingeringChoice",
    "NoteLines",
    "harmonic_lines",
    "identify",
]
