"""The bore kernel of a take's inversion, built at one documented temperature.

Every door into the inversion (``mpipe run``, ``mpipe invert`` on the output of
``mpipe separate``, and the Python API) builds the model's reflection function the same
way, so the same take gives the same numbers whichever is used:

* the air temperature is the median, over the take, of the effective temperature that the
  wave separation estimated (carried with the mouthpiece signals as ``temperature_c``, one
  value per sample);
* signals that carry no such track (model output of ``mpipe simulate``) use the
  calibration's ``air.temperature_c``;
* from there, the take's one fit (``inversion.estimator: take``) estimates the temperature
  with the reed (:mod:`mpipe.inversion.whole_take.estimator`); the table records it as
  ``kernel_temperature_c`` and the resynthesis reads it back (:func:`table_temperature`).

The air model (``keefe`` or ``ernoult``) is the calibration's.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from mpipe.acoustics.air import Air
from mpipe.acoustics.bore import mean_flow_resistance
from mpipe.acoustics.reflection import reflection_function
from mpipe.core.signals import DiskArray, signal_median, signal_range
from mpipe.measurement.calibration import Calibration
from mpipe.reed.bore_kernel import BoreKernel, prepare_bore


def take_temperature(temperature_c: np.ndarray | float | None, calibration: Calibration) -> float:
    """The one air temperature of a take's inversion, degC.

    Parameters
    ----------
    temperature_c : ndarray, float or None
        The separation's effective temperature per sample (or one value), degC; None when
        the signals carry none.
    calibration : Calibration
        Supplies the temperature when ``temperature_c`` is None or empty.

    Returns
    -------
    float
        Median of the finite values of ``temperature_c``, else the calibration's.
    """
    if isinstance(temperature_c, DiskArray):
        lo, hi = signal_range(temperature_c)  # NaN when a sample is not finite
        if np.isfinite(lo) and np.isfinite(hi):  # on disk and finite: the median in blocks
            return signal_median(temperature_c)
    if temperature_c is not None:
        values = np.asarray(temperature_c, dtype=float).ravel()
        values = values[np.isfinite(values)]
        if values.size:
            return float(np.median(values))
    return float(calibration.air.temperature_c)


def bore_kernel(
    calibration: Calibration, fs: float, temperature_c: float
) -> tuple[BoreKernel, Air]:
    """Prepared bore (reflection function and Z0) for the inversion and the resynthesis.

    Parameters
    ----------
    calibration : Calibration
        Bore geometry and air model.
    fs : float
        Sample rate of the signals, Hz.
    temperature_c : float
        Air temperature, degC (see :func:`take_temperature`).

    Returns
    -------
    (BoreKernel, Air)
        The kernel carries the bore's steady-flow resistance from its entry to the
        calibration's reference plane (``reference_resistance``): the separation takes the
        pressure's mean there, and the translation of a zero-mean flow cannot add the mean
        flow's drop over it (benchmarks.md, tenth session).
    """
    air = calibration.air_properties(temperature_c)
    kernel = prepare_bore(reflection_function(calibration.bore, air, fs=fs), air)
    resistance = mean_flow_resistance(calibration.bore, air, 0.0, calibration.reference_plane)
    return dataclasses.replace(kernel, reference_resistance=resistance), air


def fingered(calibration: Calibration, fingering: str | None) -> Calibration:
    """The calibration playing ``fingering`` (None or "": the calibration as it is)."""
    return calibration.with_fingering(fingering) if fingering else calibration


@dataclass(frozen=True)
class KernelSource:
    """The bore kernel of each window: its note's fingering at a temperature, built once.

    Attributes
    ----------
    calibration : Calibration
        The instrument (its fingerings).
    fs : float
        Sample rate, Hz.
    fingerings : mapping of int to str
        A window's first sample to its note's fingering (empty, or a window missing from it:
        the calibration's own bore).
    build : callable, optional
        Builds a kernel, ``build(calibration, fs, T) -> (kernel, air)``; default
        :func:`bore_kernel`.
    """

    calibration: Calibration
    fs: float
    fingerings: Mapping[int, str] = field(default_factory=dict)
    built: dict = field(default_factory=dict)  # (T degC, fingering) -> (kernel, air)
    build: Callable | None = None  # (calibration, fs, T) -> (kernel, air); None: bore_kernel

    def fingering(self, start: int | None) -> str:
        """The fingering of the window starting at ``start`` ("" the calibration's)."""
        return self.fingerings.get(int(start), "") if start is not None else ""

    def at(self, t: float, start: int | None = None) -> tuple[BoreKernel, Air]:
        """The kernel and air of the window starting at ``start`` at ``t`` degC."""
        return self.named(t, self.fingering(start))

    def named(self, t: float, name: str = "") -> tuple[BoreKernel, Air]:
        """The kernel and air of fingering ``name`` ("" the calibration's) at ``t`` degC."""
        key = (round(float(t), 6), name)
        if key not in self.built:
            build = self.build or bore_kernel
            self.built[key] = build(fingered(self.calibration, name), self.fs, key[0])
        return self.built[key]

    @property
    def names(self) -> list[str]:
        """The fingerings played, in order of first appearance ("" for the calibration's)."""
        return list(dict.fromkeys(self.fingerings.values())) or [""]


def table_temperature(
    table, temperature_c: np.ndarray | float | None, calibration: Calibration
) -> float:
    """The kernel temperature a windows table was inverted at, degC.

    The resynthesis must drive the model on the same kernel as the inversion: the table's
    ``kernel_temperature_c`` (the fitted temperature) when it has one, else
    :func:`take_temperature` of the signals (a table written before the fit existed).

    Parameters
    ----------
    table : pandas.DataFrame
        Windows table of the inversion.
    temperature_c : ndarray, float or None
        The temperature the signals carry, degC.
    calibration : Calibration
        Supplies the temperature when neither has one.
    """
    if "kernel_temperature_c" in table:
        values = np.asarray(table["kernel_temperature_c"], dtype=float)
        values = values[np.isfinite(values)]
        if values.size:
            return float(values[0])
    return take_temperature(temperature_c, calibration)


__all__ = ["KernelSource", "bore_kernel", "fingered", "table_temperature", "take_temperature"]
