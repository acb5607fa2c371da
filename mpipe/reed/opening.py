"""The reed's opening h(t) = y_m - y(t), driven by a pressure signal.

The reed of the model (paper App. A, eq. A.1; physics.md G.2) is a mass-spring-damper with
a contact force, driven by the pressure difference across it, ``dp = p_m - p``:

    y[n+1] = a1 y[n] + a2 y[n-1] + b1 dp[n] + a3 max(y[n] - y_c, 0)^alpha

with the coefficients of :func:`mpipe.reed.scheme.reed_coefficients`. Driven by the
mouthpiece pressure the fitted model plays (or by the measured one, which the fit matches
to a fraction of a per cent), it gives the model's reed displacement without running the
bore again. The start state is the reed at rest under the first pressure difference
(``y = dp / k``); the start-up decays with the reed's damping time ``2 / g`` (under a
millisecond for a clarinet reed), so a lead of a few milliseconds before the span of
interest removes it. The opening is ``h = max(y_m - y, 0)``: zero while the reed is shut.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from mpipe.reed.parameters import ReedParameters
from mpipe.reed.scheme import reed_coefficients


@njit(cache=True)
def drive_reed(y, p, p_m, k, coefficients, contact):
    """Reed displacement y (m) driven by the pressure ``p`` (Pa), into ``y`` (len(p) >= 2).

    The one compiled copy of the reed recursion on its own (the lead-in of the inversion's
    history start, :mod:`mpipe.inversion.fit.fastpath`, and :func:`reed_trajectory`):
    ``y[0] = y[1] = (p_m - p[0]) / k`` (the reed at rest under the first pressure
    difference), then ``y[i+1] = a1 y[i] + a2 y[i-1] + b1 (p_m - p[i]) + a3 max(y[i] - y_c,
    0)^alpha``. ``coefficients`` is (a1, a2, a3, b1) of :func:`reed_coefficients`,
    ``contact`` is (y_c, alpha).
    """
    a1, a2, a3, b1 = coefficients
    y_c, alpha = contact
    y0 = (p_m - p[0]) / k
    y[0] = y0
    y[1] = y0
    for i in range(1, p.size - 1):
        c = y[i] - y_c
        force = c**alpha if c > 0.0 else 0.0
        y[i + 1] = a1 * y[i] + a2 * y[i - 1] + b1 * (p_m - p[i]) + a3 * force


def reed_trajectory(reed: ReedParameters, p: np.ndarray, fs: float) -> np.ndarray:
    """Reed displacement (m) at every sample of the mouthpiece pressure ``p`` (Pa).

    Starts from the quasi-static ``y = (p_m - p) / k`` at the first two samples and drives
    the reed update (A.1, contact included) with ``dp = p_m - p``; the start error decays
    as ``exp(-g t / 2)``. The inversion's history start drives it over a lead-in before the
    window (physics.md H).

    Parameters
    ----------
    reed : ReedParameters
        Reed parameters (its ``p_m`` is the mouth pressure, Pa).
    p : ndarray
        Mouthpiece pressure, Pa.
    fs : float
        Sample rate, Hz.

    Returns
    -------
    ndarray
        Displacement at every sample of ``p``, m.

    References
    ----------
    Chatziioannou & van Walstijn 2012, eqs. (9) and (A.1); physics.md G.2, H.
    """
    p = np.ascontiguousarray(p, dtype=float)
    if p.size < 3:
        return (reed.p_m - p) / reed.k
    y = np.empty(p.size)
    drive_reed(y, p, reed.p_m, reed.k, reed_coefficients(reed, fs), (reed.y_c, reed.alpha))
    return y


def reed_displacement(reed: ReedParameters, p: np.ndarray, fs: float) -> np.ndarray:
    """Reed displacement y (m, positive towards closing) driven by mouthpiece pressure ``p``.

    Parameters
    ----------
    reed : ReedParameters
        Reed parameters (its ``p_m`` is the mouth pressure, Pa).
    p : ndarray
        Mouthpiece pressure, Pa.
    fs : float
        Sample rate, Hz.

    Returns
    -------
    ndarray
        y at each sample of ``p`` (sample i is the displacement after dp of sample i - 1).
    """
    p = np.asarray(p, dtype=float)
    if not p.size:
        return np.empty(0)
    # sample i follows dp of sample i - 1: the trajectory of [p0, p0, p] from its third sample
    return reed_trajectory(reed, np.concatenate([p[:1], p[:1], p]), fs)[2:]


def opening(
    reed: ReedParameters, p: np.ndarray, fs: float, start: int, n: int, lead_s: float = 0.005
) -> np.ndarray:
    """Opening h = max(y_m - y, 0) (m) over ``p[start:start + n]``, driven from a lead.

    Parameters
    ----------
    reed : ReedParameters
        Reed parameters.
    p : ndarray
        Mouthpiece pressure of the take, Pa.
    fs : float
        Sample rate, Hz.
    start, n : int
        First sample and length of the span, samples.
    lead_s : float
        Time driven before ``start`` to let the start state decay, s.

    Returns
    -------
    ndarray
        Length ``n``.
    """
    lead = min(int(math.ceil(lead_s * fs)), start)
    y = reed_displacement(reed, p[start - lead : start + n], fs)[lead:]
    return np.maximum(reed.y_m - y, 0.0)


def opening_summary(h: np.ndarray) -> dict[str, float]:
    """``h_mean`` and ``h_min`` (m) and ``closed_fraction`` (the fraction of the time shut)."""
    h = np.asarray(h, dtype=float)
    if not h.size or not np.isfinite(h).all():
        return {"h_mean": math.nan, "h_min": math.nan, "closed_fraction": math.nan}
    return {"h_mean": float(h.mean()), "h_min": float(h.min()),
            "closed_fraction": float(np.mean(h <= 0.0))}  # fmt: skip


__all__ = ["drive_reed", "opening", "opening_summary", "reed_displacement", "reed_trajectory"]
