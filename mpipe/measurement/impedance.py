"""Theoretical input impedance of a configured instrument: table, CSV and plot.

The pure computation behind ``mpipe impedance`` (physics.md D.1).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from mpipe.acoustics.bore import Radiation, Resonance, find_resonances, input_impedance
from mpipe.core.io import write_atomic
from mpipe.measurement.calibration import Calibration
from mpipe.measurement.impedance_comparison import resonances


@dataclass(frozen=True)
class ImpedanceCurve:
    """Input impedance of an instrument on a frequency grid.

    Attributes
    ----------
    freqs_hz : ndarray
        Frequencies in Hz.
    z : ndarray
        Complex input impedance at the mouthpiece entry, Pa s/m^3.
    z0 : float
        Real characteristic impedance rho c / S of the entry, Pa s/m^3.
    temperature_c : float
        Air temperature used, degC.
    radiation : str
        Termination model used.
    measured : bool
        The curve is a measurement (``bore.measured``): its peaks must stand 3 dB out of
        the curve, so that its noise makes none.
    """

    freqs_hz: np.ndarray
    z: np.ndarray
    z0: float
    temperature_c: float
    radiation: str
    measured: bool = False

    def resonances(self, count: int = 5) -> list[Resonance]:
        """The first ``count`` peaks of |Z|."""
        if not self.measured:
            return find_resonances(self.freqs_hz, self.z, self.z0, count)
        peaks = resonances(self.freqs_hz, self.z, self.z0, count)
        return [
            Resonance(float(f), float(lvl), float(f / bw) if bw > 0 else float("nan"))
            for f, lvl, bw in zip(
                peaks["frequency_hz"], peaks["level_db"], peaks["bandwidth_hz"], strict=True
            )
        ]

    def table(self) -> pd.DataFrame:
        """CSV layout: ``frequency_hz, z_real, z_imag`` (Pa s/m^3) and ``zc`` (real Z0)."""
        return pd.DataFrame(
            {
                "frequency_hz": self.freqs_hz,
                "z_real": self.z.real,
                "z_imag": self.z.imag,
                "zc": np.full(self.freqs_hz.size, self.z0),
            }
        )


def impedance_curve(
    calibration: Calibration,
    fmin: float = 10.0,
    fmax: float = 4000.0,
    df: float = 0.5,
    radiation: str | None = None,
    flange_radius: float | None = None,
    temperature_c: float | None = None,
) -> ImpedanceCurve:
    """Compute the input impedance of a calibration's bore.

    Parameters
    ----------
    calibration : Calibration
        The instrument.
    fmin, fmax, df : float
        Frequency grid in Hz.
    radiation : str, optional
        Override of the configured termination model.
    flange_radius : float, optional
        Outer flange radius in m for ``"finite-flange"``.
    temperature_c : float, optional
        Override of the configured air temperature, degC.

    Returns
    -------
    ImpedanceCurve
    """
    if not (0 < fmin < fmax and df > 0):
        raise ValueError(f"expected 0 < fmin < fmax and df > 0, got {fmin}, {fmax}, {df}")
    if (fmax - fmin) / df > 5e6:
        raise ValueError(f"frequency grid of {(fmax - fmin) / df:.0f} points is too large")
    bore = calibration.bore
    if radiation is not None or flange_radius is not None:
        bore = replace(
            bore,
            radiation=Radiation(
                radiation or bore.radiation.model,
                flange_radius or bore.radiation.flange_radius,
                bore.radiation.hole_model,
            ),
        )
        if bore.radiation.model == "finite-flange" and bore.radiation.flange_radius is None:
            raise ValueError("finite-flange radiation needs a flange radius (--flange-radius, m)")
    air = calibration.air_properties(temperature_c)
    freqs = np.arange(fmin, fmax + df / 2, df)
    z = input_impedance(bore, 2 * np.pi * freqs, air)
    return ImpedanceCurve(
        freqs,
        z,
        bore.entry_impedance(air),
        air.temperature_c,
        bore.radiation.model,
        bore.measured_input is not None,
    )


def format_resonances(resonances: list[Resonance]) -> str:
    """A plain-text table of resonances."""
    lines = [f"{'#':>2}  {'f [Hz]':>9}  {'|Z|/Zc [dB]':>11}  {'Q':>6}"]
    for i, r in enumerate(resonances, start=1):
        lines.append(f"{i:>2}  {r.frequency_hz:9.2f}  {r.level_db:11.2f}  {r.q:6.1f}")
    return "\n".join(lines)


def plot_impedance(curve: ImpedanceCurve, path: str | Path, title: str = "") -> Path:
    """Write magnitude (dB re Z0) and phase of the impedance, resonances marked, as PNG."""
    import matplotlib  # lazy here and below: matplotlib adds ~0.5 s to start-up

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_m, ax_p) = plt.subplots(2, 1, sharex=True, figsize=(8, 5.5), height_ratios=[3, 1.4])
    level = 20 * np.log10(np.abs(curve.z) / curve.z0)
    ax_m.plot(curve.freqs_hz, level, lw=1.2, color="C0")
    for r in curve.resonances(8):
        ax_m.plot(r.frequency_hz, r.level_db, "v", color="C3", ms=5)
        ax_m.annotate(
            f"{r.frequency_hz:.1f}",
            (r.frequency_hz, r.level_db),
            xytext=(3, 4),
            textcoords="offset points",
            fontsize=7,
        )
    ax_m.set_ylabel("|Z_in| / Z_c  [dB]")
    ax_m.grid(alpha=0.3)
    ax_m.set_title(
        title or f"Input impedance ({curve.radiation} end, {curve.temperature_c:g} °C)", y=1.0
    )
    ax_p.plot(curve.freqs_hz, np.degrees(np.angle(curve.z)), lw=1.0, color="C0")
    ax_p.set_ylabel("phase [deg]")
    ax_p.set_xlabel("frequency [Hz]")
    ax_p.set_ylim(-95, 95)
    ax_p.grid(alpha=0.3)
    fig.tight_layout()
    write_atomic(path, lambda tmp: fig.savefig(tmp, dpi=120, format="png"))
    plt.close(fig)
    return Path(path)
