"""The outcome of the impedance validation: its verdict, curves, terminal summary and plot.

:class:`ValidationResult` holds the measured and theoretical normalised impedances, the
metrics per resonance and per harmonic, and the verdict (PASS, FAIL or CANNOT-VERIFY, see
:mod:`mpipe.measurement.validation`); :func:`plot_impedance` draws the paper's Fig. 10.

References
----------
Chatziioannou & van Walstijn 2012, section 4 and Fig. 10; physics.md F.3.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd


@dataclass(frozen=True)
class ValidationResult:
    """Measured and theoretical impedance, metrics and verdict.

    Attributes
    ----------
    freqs : ndarray
        Frequencies in Hz (the Welch grid, DC excluded).
    z_measured, z_theory : ndarray
        Normalised impedances ``Z / Z0`` (complex, dimensionless).
    coherence : ndarray
        Squared coherence of U and P.
    z0 : float
        Real characteristic impedance of the entry, Pa s/m^3.
    temperature_c : float
        Air temperature of the theory, degC.
    resonances : pandas.DataFrame
        Per resonance: ``frequency_theory_hz``, ``frequency_measured_hz`` (zero crossings
        of the phase at the peaks of |z|), ``error_cents``,
        ``level_theory_db``, ``level_measured_db``, ``error_db``, ``coherence``.
    harmonics : pandas.DataFrame
        Per harmonic of the note: ``harmonic``, ``frequency_hz``, ``error_db``,
        ``error_deg``, ``coherence``.
    f0_hz : float
        Playing frequency (NaN for a non-tonal signal).
    band_error_db, band_error_deg : float
        Mean |magnitude error| (dB) and |phase error| (degrees) over coherent bins.
    coherent_fraction : float
        Fraction of the bins in the band with coherence >= ``min_coherence``.
    failures : tuple of str
        Why the verdict is fail (empty when it passes).
    checks : int
        Number of quantities compared (measured resonances and coherent harmonics).
    min_checks : int
        Fewest compared quantities for a PASS.
    suspects : tuple of str
        On a FAIL, the inputs that can produce such errors, most likely first (see
        :func:`mpipe.measurement.validation_suspects.suspect_inputs`).
    theory_hz, theory_z : ndarray
        The theory on a fine grid (Hz; ``Z / Z0``), for the figure: on the Welch grid a
        resonance a few Hz wide falls between bins and its peak is lost (empty: none).
    label : str
        What was compared, for the figure's title (the note and its fingering).
    """

    freqs: np.ndarray
    z_measured: np.ndarray
    z_theory: np.ndarray
    coherence: np.ndarray
    z0: float
    temperature_c: float
    resonances: pd.DataFrame
    harmonics: pd.DataFrame
    f0_hz: float
    band_error_db: float
    band_error_deg: float
    coherent_fraction: float
    failures: tuple[str, ...] = field(default_factory=tuple)
    checks: int = 0
    min_checks: int = 1
    suspects: tuple[str, ...] = field(default_factory=tuple)
    theory_hz: np.ndarray = field(default_factory=lambda: np.empty(0))
    theory_z: np.ndarray = field(default_factory=lambda: np.empty(0, complex))
    label: str = ""

    @property
    def passed(self) -> bool:
        """True when enough quantities were compared and all are within tolerance."""
        return self.verdict == "pass"

    @property
    def verdict(self) -> str:
        """``"pass"``, ``"fail"`` or ``"cannot-verify"`` (too little was measurable)."""
        if self.failures:
            return "fail"
        return "pass" if self.checks >= self.min_checks else "cannot-verify"

    @property
    def reason(self) -> str:
        """One line saying why the verdict is what it is."""
        if self.failures:
            suspects = f"; suspect inputs: {', '.join(self.suspects)}" if self.suspects else ""
            return "; ".join(self.failures) + suspects
        what = f"{self.checks} quantit{'y' if self.checks == 1 else 'ies'} compared"
        if self.verdict == "pass":
            return f"{what}, all within tolerance"
        return (
            f"only {what} (need {self.min_checks}): no resonance was measurable and too few "
            f"harmonics were coherent ({100 * self.coherent_fraction:.2g} % of the bins in the "
            "band reach the coherence threshold)"
        )

    def table(self, max_hz: float | None = None) -> pd.DataFrame:
        """The curves: frequency (Hz), z measured and theoretical (re, im, dB), coherence.

        ``max_hz``: the highest frequency kept (Hz; None: every bin to Nyquist). The
        mouthpiece signals are low-passed by the translation, so above its stop band
        (``TranslationConfig.stopband_hz``) the measured curve is the filter's residue:
        the stages write the table to there (at 100 kHz, 5,242 of 32,769 bins).
        """
        keep = slice(None) if max_hz is None else self.freqs <= max_hz
        z_me, z_th = self.z_measured[keep], self.z_theory[keep]
        return pd.DataFrame(
            {
                "frequency_hz": self.freqs[keep],
                "z_measured_re": z_me.real,
                "z_measured_im": z_me.imag,
                "z_measured_db": db(z_me),
                "z_theory_re": z_th.real,
                "z_theory_im": z_th.imag,
                "z_theory_db": db(z_th),
                "coherence": self.coherence[keep],
            }
        )

    def summary(self) -> str:
        """A few lines for the terminal: verdict, resonances and band errors."""
        lines = [f"impedance validation: {self.verdict.upper()} ({self.reason})"]
        measured = np.isfinite(self.resonances["frequency_measured_hz"].to_numpy(float))
        if measured.any():
            lines.append("  resonance  f_th (Hz)  f_meas (Hz)  cents   L_th (dB)  dL (dB)")
            for i, r in self.resonances[measured].iterrows():
                lines.append(
                    f"  {i + 1:9d}  {r.frequency_theory_hz:9.2f}  {r.frequency_measured_hz:11.2f}"
                    f"  {r.error_cents:6.2f}  {r.level_theory_db:9.2f}  {r.error_db:7.2f}"
                )
        else:
            # a played note excites its harmonics only: no peak of |z| can be located
            theory = ", ".join(f"{f:.0f}" for f in self.resonances["frequency_theory_hz"])
            lines.append(f"  resonances: none measurable (theory at {theory} Hz)")
        if len(self.harmonics):
            lines.append("  harmonic  f (Hz)   dL (dB)  dphi (deg)  coherence")
            for _, h in self.harmonics.iterrows():
                lines.append(
                    f"  {int(h.harmonic):8d}  {h.frequency_hz:7.1f}  {h.error_db:8.2f}"
                    f"  {h.error_deg:10.1f}  {h.coherence:9.2f}"
                )
        lines.append(
            f"  band {self.band_error_db:.2f} dB, {self.band_error_deg:.1f} deg over "
            f"{100 * self.coherent_fraction:.0f} % coherent bins"
            + (f"; note f0 {self.f0_hz:.2f} Hz" if np.isfinite(self.f0_hz) else "")
        )
        lines.extend(f"  fail: {f}" for f in self.failures)
        lines.extend(f"  suspect: {x}" for x in (self.suspects if self.failures else ()))
        return "\n".join(lines)


def db(z: np.ndarray) -> np.ndarray:
    """Level of a complex quantity in dB (20 log10 |z|, floored at 1e-300)."""
    return 20 * np.log10(np.maximum(np.abs(z), 1e-300))


def plot_impedance(result: ValidationResult, path: str | Path, fmax_hz: float | None = None):
    """Draw the paper's Fig. 10: |z| in dB, theory and measurement, coherence below (PNG).

    For a played note the measurement is drawn as points at its harmonics (filled where
    compared, hollow where masked), not as a dense curve that holds only there.

    Uses the Agg canvas directly, so no global pyplot state is touched. The title names
    what was compared (``result.label``: the note and its fingering); the theory is drawn on
    its fine grid (:func:`theory_curve`). Returns the figure.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # lazy: ~0.5 s of start-up
    from matplotlib.figure import Figure

    fmax = fmax_hz if fmax_hz is not None else float(result.freqs[-1])
    sel = result.freqs <= fmax
    f = result.freqs[sel]
    fig = Figure(figsize=(8, 6))
    FigureCanvasAgg(fig)
    ax1, ax2 = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    f_th, z_th = theory_curve(result, fmax)
    ax1.plot(f_th, db(z_th), "k-", lw=1.2, label="theory")
    h = result.harmonics
    if np.isfinite(result.f0_hz) and len(h):
        # A played note measures Z only at its harmonics (between them the ratio is leakage):
        # the measured points there, filled where compared, hollow where the coherence or the
        # line's level masked them.
        fh = h["frequency_hz"].to_numpy(float)
        z_at = np.interp(fh, result.freqs, db(result.z_measured))
        used = h["compared"].astype(bool).to_numpy() & (fh <= fmax)
        ax1.plot(fh[used], z_at[used], "ro", ms=5, label="measured at compared harmonics")
        masked = ~h["compared"].astype(bool).to_numpy() & (fh <= fmax)
        if masked.any():
            ax1.plot(fh[masked], z_at[masked], "o", mfc="none", mec="0.5", ms=5,
                     label="harmonic masked (low coherence or level)")  # fmt: skip
    else:
        ax1.plot(f, db(result.z_measured[sel]), "r--", lw=1.0, label="measured (H1)")
    ax1.set_ylabel("|Z / Z0| (dB)")
    what = f"{result.label}: " if result.label else ""
    ax1.set_title(
        f"Input impedance of {what or 'the take: '}{result.verdict.upper()}, "
        f"T = {result.temperature_c:.2f} degC",
        fontsize=10,
        y=1.0,
    )
    ax1.legend(loc="upper right")
    ax1.grid(alpha=0.3)
    ax2.plot(f, result.coherence[sel], "b-", lw=0.8)
    ax2.set_ylim(0, 1.05)
    ax2.set_ylabel("coherence")
    ax2.set_xlabel("frequency (Hz)")
    ax2.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, format="png", dpi=100)
    return fig


def theory_curve(result: ValidationResult, fmax_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """The theory to draw up to ``fmax_hz`` (Hz): the fine grid, the Welch grid above it."""
    coarse = result.freqs <= fmax_hz
    if not len(result.theory_hz):
        return result.freqs[coarse], result.z_theory[coarse]
    fine = result.theory_hz <= fmax_hz
    above = coarse & (result.freqs > result.theory_hz[-1])
    return (np.concatenate([result.theory_hz[fine], result.freqs[above]]),
            np.concatenate([result.theory_z[fine], result.z_theory[above]]))  # fmt: skip


__all__ = ["ValidationResult", "db", "plot_impedance", "theory_curve"]
