"""Comparing impedance curves: peaks of |Z|, resonances matched in cents, levels in dB.

:func:`resonances` finds the peaks of |Z| on any (possibly non-uniform) grid, with levels
and -3 dB bandwidths; :func:`compare` matches a measured Z/Zc curve's resonances to a
reference's (theory, or a take's own impedance) and gives the band error;
:func:`plot_comparison` draws the curves (|Z/Zc| in dB and phase in degrees against Hz).

References
----------
physics.md D.1 and F.3 (normalised impedance, resonance metrics).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import scipy.signal

from mpipe.acoustics.bore import half_power_bandwidth


def resonances(freqs: np.ndarray, z: np.ndarray, z0: float, count: int = 8,
               min_prominence_db: float = 3.0) -> pd.DataFrame:  # fmt: skip
    """Peaks of |Z| on any (possibly non-uniform) grid: frequency, level and bandwidth.

    Parameters
    ----------
    freqs : ndarray
        Frequencies, Hz.
    z : ndarray
        Impedance (any unit).
    z0 : float
        Normalising impedance, same unit as ``z``; levels are ``20 log10 |z / z0|``.
    count : int
        At most this many, lowest first.
    min_prominence_db : float
        Peaks must stand out of the curve by this much (measurement noise makes small ones).

    Returns
    -------
    pandas.DataFrame
        ``frequency_hz``, ``level_db`` (parabolic interpolation of the dB curve through the
        grid maximum and its neighbours) and ``bandwidth_hz`` (half-power, -3.01 dB, with its
        crossings interpolated: :func:`mpipe.acoustics.bore.half_power_bandwidth`; NaN when
        not found).
    """
    level = 20 * np.log10(np.maximum(np.abs(z) / z0, 1e-300))
    idx, _ = scipy.signal.find_peaks(level, prominence=min_prominence_db)
    rows = []
    for i in idx[:count]:
        if i == 0 or i == level.size - 1:
            continue
        x, y = freqs[i - 1 : i + 2], level[i - 1 : i + 2]
        coef = np.polyfit(x - x[1], y, 2)
        if coef[0] < 0:
            # vertex of the parabola through the grid maximum and its neighbours
            dx = float(np.clip(-coef[1] / (2 * coef[0]), x[0] - x[1], x[2] - x[1]))
            f, lvl = float(x[1] + dx), float(np.polyval(coef, dx))
        else:
            f, lvl = float(x[1]), float(y[1])
        bw = half_power_bandwidth(freqs, level, i, lvl)
        rows.append({"frequency_hz": f, "level_db": lvl, "bandwidth_hz": bw})
    return pd.DataFrame(rows, columns=["frequency_hz", "level_db", "bandwidth_hz"])


@dataclass(frozen=True)
class ImpedanceComparison:
    """A measured impedance against a reference (theory, or a take's own impedance).

    Attributes
    ----------
    table : pandas.DataFrame
        Per reference resonance: ``frequency_reference_hz``, ``frequency_measured_hz``,
        ``error_cents``, ``level_reference_db``, ``level_measured_db``, ``error_db``
        (NaN when no measured peak lies within ``match_cents``).
    band_error_db : float
        Mean |20 log10 |z_measured / z_reference|| over the compared band, dB.
    band_hz : (float, float)
        The compared band, Hz.
    """

    table: pd.DataFrame
    band_error_db: float
    band_hz: tuple[float, float]


def compare(
    freqs: np.ndarray,
    z_measured: np.ndarray,
    ref_freqs: np.ndarray,
    z_reference: np.ndarray,
    band: tuple[float, float] = (50.0, 2000.0),
    count: int = 6,
    match_cents: float = 50.0,
) -> ImpedanceComparison:
    """Resonance frequencies (cents), peak levels (dB) and band error of two Z/Zc curves.

    Parameters
    ----------
    freqs, z_measured : ndarray
        Measured Z/Zc (dimensionless) on its grid, Hz.
    ref_freqs, z_reference : ndarray
        Reference Z/Zc on its grid, Hz.
    band : (float, float)
        Band of the resonances and of the band error, Hz.
    count : int
        Reference resonances compared.
    match_cents : float
        Largest distance of a matched measured peak, cents.

    Returns
    -------
    ImpedanceComparison
    """
    sel_m = (freqs >= band[0]) & (freqs <= band[1])
    sel_r = (ref_freqs >= band[0]) & (ref_freqs <= band[1])
    ref = resonances(ref_freqs[sel_r], z_reference[sel_r], 1.0, count)
    mea = resonances(freqs[sel_m], z_measured[sel_m], 1.0, 4 * count)
    rows = []
    for _, r in ref.iterrows():
        row = {
            "frequency_reference_hz": r.frequency_hz,
            "frequency_measured_hz": math.nan,
            "error_cents": math.nan,
            "level_reference_db": r.level_db,
            "level_measured_db": math.nan,
            "error_db": math.nan,
        }
        if len(mea):
            cents = 1200 * np.log2(mea["frequency_hz"].to_numpy() / r.frequency_hz)
            j = int(np.argmin(np.abs(cents)))
            if abs(cents[j]) <= match_cents:
                row.update(
                    frequency_measured_hz=float(mea["frequency_hz"].iloc[j]),
                    error_cents=float(cents[j]),
                    level_measured_db=float(mea["level_db"].iloc[j]),
                    error_db=float(mea["level_db"].iloc[j] - r.level_db),
                )
        rows.append(row)
    zr = np.interp(freqs[sel_m], ref_freqs, z_reference.real) + 1j * np.interp(
        freqs[sel_m], ref_freqs, z_reference.imag
    )
    err = np.abs(20 * np.log10(np.abs(z_measured[sel_m]) / np.maximum(np.abs(zr), 1e-300)))
    return ImpedanceComparison(pd.DataFrame(rows), float(np.mean(err)), band)


def plot_comparison(path: str | Path, curves: list[tuple[str, np.ndarray, np.ndarray]],
                    band: tuple[float, float]) -> None:  # fmt: skip
    """Plot |Z/Zc| (dB) and phase (deg) of several curves: ``(label, freqs_hz, z/zc)``."""
    import matplotlib  # lazy here and below: matplotlib adds ~0.5 s to start-up

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(2, 1, sharex=True, figsize=(9, 6),
                                   gridspec_kw={"height_ratios": [3, 2]})  # fmt: skip
    for (label, f, z), style in zip(curves, ("k-", "r--", "b:", "g-."), strict=False):
        sel = (f >= band[0]) & (f <= band[1])
        ax1.plot(f[sel], 20 * np.log10(np.abs(z[sel])), style, lw=1, label=label)
        ax2.plot(f[sel], np.rad2deg(np.angle(z[sel])), style, lw=1)
    ax1.set_ylabel("|Z/Zc| [dB]")
    ax2.set_ylabel("phase [deg]")
    ax2.set_xlabel("frequency [Hz]")
    ax1.legend()
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3)
    ax1.set_title("Input impedance: measured against theory", y=1.0)
    fig.tight_layout()
    fig.savefig(path, dpi=110, format="png")
    plt.close(fig)


__all__ = ["ImpedanceComparison", "compare", "plot_comparison", "resonances"]
