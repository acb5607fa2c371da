"""The take's temperature as the inversion reports it: the bore model's air, with its SE.

The take's one fit (:mod:`mpipe.inversion.whole_take.estimator`) estimates the temperature
with the reed (``source = "take fit"``); the per-window estimator (``inversion.estimator:
window``, the paper's method) inverts at the front end's estimate (``"front end"``) or the
calibration's (``"calibration"``). The kernel-temperature fit of the per-window estimator,
its profile, its restarts and the notes' own temperatures are gone (issue 45): one
estimate of the temperature, the take's fit's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class TemperatureFit:
    """The temperature of a take's bore model.

    Attributes
    ----------
    temperature_c : float
        Temperature the bore kernel is built at, degC.
    se_c : float
        Its standard error, degC (NaN when not estimated: the temperature's share of the
        error bars is then not in them).
    source : str
        ``"take fit"`` (estimated with the reed, :mod:`mpipe.inversion.whole_take.estimator`),
        ``"front end"`` (the wave separation's estimate, carried with the signals) or
        ``"calibration"``.
    front_end_c : float
        The temperature the signals carried (or the calibration's), degC.
    windows : int
        Windows the temperature was estimated on (0: not estimated).
    note : str
        A warning about it; "" when there is nothing to say.
    cold_starts_agreeing : int or None
        How many of the take's cold start's short searches reached its minimum (see
        :mod:`mpipe.inversion.fit.coldstart`).
    """

    temperature_c: float
    se_c: float
    source: str
    front_end_c: float
    windows: int = 0
    note: str = ""
    cold_starts_agreeing: int | None = None

    def summary(self) -> dict:
        """JSON-ready record for manifests and the report."""
        return {
            "temperature_c": self.temperature_c,
            "temperature_se_c": None if math.isnan(self.se_c) else self.se_c,
            "source": self.source,
            "front_end_c": self.front_end_c,
            "windows": self.windows,
            "note": self.note,
            "cold_starts_agreeing": self.cold_starts_agreeing,
        }

    def line(self) -> str:
        """One console line."""
        if self.source == "take fit":
            return (
                f"take temperature {self.temperature_c:.2f} +- {self.se_c:.2f} degC, fitted "
                f"with the reed on {self.windows} windows (front end {self.front_end_c:.2f} degC)"
                + (f"; {self.note}" if self.note else "")
            )
        return (
            f"kernel temperature {self.temperature_c:.2f} degC ({self.source}; not estimated "
            "by inversion.estimator: window): the standard errors leave out its uncertainty"
            + (f"; {self.note}" if self.note else "")
        )


__all__ = ["TemperatureFit"]
