"""Starting the model from the target's own past: the reed's lead-in and the mean flow.

The ``"history"`` start of F2 (:mod:`mpipe.inversion.fit.objective`) needs the reed's state at
the window's first sample: the reed equation (G.2, contact included) is driven by the
target's pressure over a short lead-in, started from the quasi-static estimate ``y = dp/k``
(:func:`mpipe.reed.opening.reed_trajectory`). A measured (zero-mean) flow history lacks
its mean; it is estimated from the candidate's flow over the same lead-in.

References
----------
Chatziioannou & van Walstijn 2012, eqs. (9), (10) and (A.1); physics.md G.2, H, J.
"""

from __future__ import annotations

import numpy as np


def pad_history(x: np.ndarray, n: int) -> np.ndarray:
    """The last ``n`` samples of a history, zeros in front when it is shorter."""
    x = np.asarray(x, dtype=float)
    if x.size >= n:
        return x[-n:]
    return np.concatenate([np.zeros(n - x.size), x])


def lead_in(p, u, start: int, n: int, n_taps: int, lead_s: float, fs: float):
    """The history of the window at ``start`` that the model reads: its last samples only.

    Every use of a window's history (:func:`pad_history` of ``max(n_taps, lead-in)``
    samples, the period estimate over the last ``n``) reads at most
    ``max(n_taps, lead-in, n)`` samples before the window, so handing over those instead
    of the whole take before it gives the same numbers, and a take on disk
    (:class:`mpipe.core.signals.DiskArray`) is read only around its windows.

    Parameters
    ----------
    p, u : array-like
        The take's pressure (Pa) and flow (m^3/s), only sliced.
    start, n : int
        The window's first sample and length.
    n_taps : int
        Taps of the bore kernel's reflection function.
    lead_s : float
        The model's lead-in, s (``inversion.lead_s``).
    fs : float
        Sample rate, Hz.

    Returns
    -------
    (p_history, u_history) : ndarray
    """
    keep = max(n_taps, int(round(lead_s * fs)), 2, n)
    a = max(start - keep, 0)
    return np.asarray(p[a:start], dtype=float), np.asarray(u[a:start], dtype=float)


def missing_mean_flow(reed, dp, y, u_meas, fs, rho) -> float:
    """Mean flow a zero-mean measured flow lacks over a lead-in, m^3/s."""
    # The candidate's flow over the lead-in (reed driven by the measured pressure) minus the
    # measured zero-mean flow over the same samples: the mean the measurement lost. Both
    # means are over the same span, so it need not be a whole number of periods. The first
    # half of the lead-in carries the reed's start transient and is skipped.
    h = np.maximum(reed.y_m - y, 0.0)
    u_f = np.sign(dp) * reed.lam * h * np.sqrt(2.0 * np.abs(dp) / rho)
    u_r = reed.S * np.diff(y, prepend=y[0]) * fs
    half = dp.size // 2
    return float(np.mean((u_f + u_r - u_meas)[half:]))


__all__ = ["lead_in", "missing_mean_flow", "pad_history"]
