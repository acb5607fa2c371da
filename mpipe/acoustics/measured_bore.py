"""A measured input impedance standing in for the bore's theory (physics.md D.5).

When the calibration's ``bore`` names a ``measured`` impedance file, the bore's input
impedance, reflectance and reflection function come from the measurement inside its band,
and from a fitted *equivalent bore* outside it: the calibration's own geometry (segments,
holes, fingering, radiation) whose last segment's end is moved so that its impedance best
matches the measured one in the band (least squares on log Z). Across the band edges the
two are cross-faded linearly over ``EDGE_FRACTION`` of the band, a convex combination that
keeps Re Z >= 0. The misfit of the equivalent bore inside the band (rms and largest |Z|
error in dB, largest resonance error in cents) is the stated error of the extension.

A change of air temperature is carried over by the sound speed: the normalised impedance
at temperature T is the measured one at the frequency f c(T_m) / c(T) (the wavelengths are
the same), times the real entry impedance Z0(T); the visco-thermal losses are kept as
measured (their change, ~0.3 %/degC in the peak widths, is neglected).

The file is read (with its declared layout) and the fit done by
:func:`mpipe.measurement.calibration.load_calibration`; this module holds the data and the
blending, with no file access.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import optimize

from mpipe.acoustics.air import Air

# Width of the cross-fade at each band edge, as a fraction of the measured band's width
# at the top and of its lower edge at the bottom.
EDGE_FRACTION = 0.05


@dataclass(frozen=True, eq=False)
class MeasuredInput:
    """A measured input impedance with its fitted equivalent bore.

    Attributes
    ----------
    freqs : ndarray
        Measured frequencies, Hz, increasing.
    z_norm : ndarray
        Measured Z / Z0(T_m), dimensionless, e^{+jwt}.
    temperature_c : float
        Air temperature of the measurement, degC.
    c_measured : float
        Sound speed at that temperature, m/s.
    source : str
        The file.
    entry_radius : float
        Radius of the entry whose Z0 = rho c / (pi r^2) normalises ``z_norm``, m.
    equivalent : object
        The fitted equivalent bore (a :class:`mpipe.acoustics.bore.Bore` without
        ``measured_input``), used outside the band.
    equivalent_length : float
        Length of the equivalent bore, m.
    misfit_rms_db, misfit_max_db : float
        Rms and largest |Z| error of the equivalent bore in the band, dB, over the bins
        where |Z| >= Z0.
    misfit_cents : float
        Largest difference of the resonance frequencies in the band, cents.
    """

    freqs: np.ndarray
    z_norm: np.ndarray
    temperature_c: float
    c_measured: float
    source: str
    entry_radius: float
    equivalent: object = None
    equivalent_length: float = float("nan")
    misfit_rms_db: float = float("nan")
    misfit_max_db: float = float("nan")
    misfit_cents: float = float("nan")

    @property
    def band_hz(self) -> tuple[float, float]:
        """The measured band (low, high), Hz."""
        return float(self.freqs[0]), float(self.freqs[-1])

    def summary(self) -> str:
        """One line for consoles and reports."""
        lo, hi = self.band_hz
        return (
            f"measured input impedance {self.source} ({lo:g}-{hi:g} Hz at "
            f"{self.temperature_c:g} degC), extended outside the band by an equivalent bore of "
            f"length {self.equivalent_length:.4f} m whose in-band misfit is "
            f"{self.misfit_rms_db:.2f} dB rms, {self.misfit_max_db:.2f} dB max, resonances "
            f"within {self.misfit_cents:.1f} cents"
        )

    def blend(self, omega: np.ndarray, air: Air, z_equivalent: np.ndarray) -> np.ndarray:
        """Input impedance, Pa s/m^3, at ``omega`` (rad/s) and ``air``.

        Parameters
        ----------
        omega : ndarray
            Angular frequencies, rad/s.
        air : Air
            Air at the temperature wanted.
        z_equivalent : ndarray
            The equivalent bore's Z_in at ``omega`` and ``air``, Pa s/m^3.

        Returns
        -------
        ndarray
            The measurement inside its band (scaled to ``air``), the equivalent bore
            outside, cross-faded at the edges.
        """
        z0 = self._z0(air)
        f = np.asarray(omega, dtype=float) / (2 * np.pi) * (self.c_measured / air.c)
        lo, hi = self.band_hz
        inside = (f >= lo) & (f <= hi)
        z_meas = np.zeros(f.shape, dtype=complex)
        z_meas[inside] = z0 * (
            np.interp(f[inside], self.freqs, self.z_norm.real)
            + 1j * np.interp(f[inside], self.freqs, self.z_norm.imag)
        )
        w = np.clip(
            np.minimum(
                (f - lo) / (EDGE_FRACTION * lo),
                (hi - f) / (EDGE_FRACTION * (hi - lo)),
            ),
            0.0,
            1.0,
        )
        return w * z_meas + (1.0 - w) * z_equivalent

    def _z0(self, air: Air) -> float:
        return float(air.rho * air.c / (np.pi * self.entry_radius**2))


def fit_equivalent_length(
    impedance_of: Callable[[float], np.ndarray],
    z_measured: np.ndarray,
    bounds: tuple[float, float],
    n_grid: int = 121,
) -> tuple[float, float]:
    """Length of the equivalent bore that best matches a measured impedance.

    Minimises the mean of ``|log(Z_model / Z_measured)|^2`` over the measured bins: a grid
    search over ``bounds`` (the misfit has a local minimum at every resonance alignment),
    then Brent's bounded search around the best grid point.

    Parameters
    ----------
    impedance_of : callable
        ``impedance_of(length) -> Z`` at the measured frequencies, Pa s/m^3.
    z_measured : ndarray
        The measured Z at the same frequencies, Pa s/m^3.
    bounds : (float, float)
        Range of lengths searched, m.
    n_grid : int
        Points of the grid search.

    Returns
    -------
    length : float
        The fitted length, m.
    misfit : float
        The mean squared log misfit there (dimensionless).
    """

    def misfit(length: float) -> float:
        return float(np.mean(np.abs(np.log(impedance_of(length) / z_measured)) ** 2))

    grid = np.linspace(bounds[0], bounds[1], n_grid)
    values = [misfit(x) for x in grid]
    i = int(np.argmin(values))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, n_grid - 1)]
    res = optimize.minimize_scalar(misfit, bounds=(lo, hi), method="bounded",
                                   options={"xatol": 1e-7})  # fmt: skip
    return float(res.x), float(res.fun)
