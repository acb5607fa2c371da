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

from mpipe.reed.parameters import ReedParameters
from mpipe.reed.scheme import reed_coefficients


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
    a1, a2, a3, b1 = reed_coefficients(reed, fs)
    dp = reed.p_m - np.asarray(p, dtype=float)
    y = np.empty(dp.size)
    y_prev = y_cur = dp[0] / reed.k if dp.size else 0.0
    y_c, alpha = reed.y_c, reed.alpha
    for i in range(dp.size):
        contact = a3 * (y_cur - y_c) ** alpha if y_cur > y_c else 0.0
        y_new = a1 * y_cur + a2 * y_prev + b1 * dp[i - 1 if i else 0] + contact
        y_prev, y_cur = y_cur, y_new
        y[i] = y_new
    return y


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


__all__ = ["opening", "opening_summary", "reed_displacement"]
