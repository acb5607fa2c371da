"""Statistics of correlated series: how many independent samples a series holds.

Used by the window's covariance (:mod:`mpipe.inversion.trust.uncertainty`) on a residual and by a
note's pooling (:mod:`mpipe.inversion.trust.notes`) on the series of its windows' estimates.
"""

from __future__ import annotations

import math

import numpy as np


def integrated_autocorrelation(r: np.ndarray) -> float:
    """Integrated autocorrelation time ``tau = 1 + 2 sum rho_k`` of a residual, samples.

    The sum is truncated by Geyer's initial positive sequence: pairs
    ``rho_{2m} + rho_{2m+1}`` are added while they are positive. The autocorrelation is
    the biased (divided by n) estimate about the mean, computed by FFT.

    Parameters
    ----------
    r : ndarray
        Residual, any unit.

    Returns
    -------
    float
        tau >= 1 (a negatively correlated residual is not credited with more than n
        samples).

    References
    ----------
    Geyer 1992, section 3.3.
    """
    x = np.asarray(r, dtype=float)
    x = x - x.mean()
    n = x.size
    if n < 4 or not np.any(x):
        return 1.0
    size = 1 << int(math.ceil(math.log2(2 * n)))
    spec = np.fft.rfft(x, size)
    acov = np.fft.irfft(spec * np.conj(spec), size)[:n]
    rho = acov / acov[0]
    pairs = rho[: 2 * (n // 2)].reshape(-1, 2).sum(axis=1)
    stop = np.flatnonzero(pairs <= 0)
    m = int(stop[0]) if stop.size else pairs.size
    return max(-1.0 + 2.0 * float(pairs[:m].sum()), 1.0)


__all__ = ["integrated_autocorrelation"]
