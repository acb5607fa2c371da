"""The concentrated-likelihood residual of one block (physics.md E.3, E.5).

The null filters of the consecutive microphone triples (``n^T H = 0``) cancel the two
waves; whitened under the sensor noise they leave residuals of unit variance at the true
theta, whose squared norm is the negative log-likelihood with the wave amplitudes
eliminated (:func:`residual_vector`, :func:`residual_cost`).
"""

from __future__ import annotations

import numpy as np

from mpipe.measurement.separation.blocks import BlockSpectra
from mpipe.measurement.separation.waves import Geometry, Theta, wavenumbers, zk_excess


def _null_components(
    theta: Theta, freqs: np.ndarray, geometry: Geometry, excess: np.ndarray | None
) -> np.ndarray:
    """Null vectors of the consecutive microphone triples, shape ``(n, N, N - 2)``.

    Column ``k`` is ``h+ x h-`` over microphones ``k, k + 1, k + 2`` (zero elsewhere):
    ``n_k^T H = 0``, smooth in frequency, and the N - 2 columns are independent (each
    brings in one more microphone), so they span the left null space of ``H``.
    """
    omega = 2 * np.pi * freqs
    if excess is None:
        excess = zk_excess(omega, geometry, theta.c)[0]
    k_p, k_m = wavenumbers(omega, theta, excess)
    d = geometry.offsets
    hp = np.exp(-1j * k_p[:, None] * d[None, :])
    hm = np.exp(1j * k_m[:, None] * d[None, :])
    out = np.zeros((freqs.size, d.size, max(d.size - 2, 0)), dtype=complex)
    # h+ x h- written out: this is the inner loop of the optimiser, and np.cross on
    # complex arrays is several times slower.
    for k in range(d.size - 2):
        a, b, c = k, k + 1, k + 2
        out[:, a, k] = hp[:, b] * hm[:, c] - hp[:, c] * hm[:, b]
        out[:, b, k] = hp[:, c] * hm[:, a] - hp[:, a] * hm[:, c]
        out[:, c, k] = hp[:, a] * hm[:, b] - hp[:, b] * hm[:, a]
    return out


def null_weights(
    theta: Theta, freqs: np.ndarray, geometry: Geometry, excess: np.ndarray | None, noise
) -> np.ndarray:
    """Null filters whitened under the sensor noise, shape ``(n, N, N - 2)``.

    The residuals ``r = N^T P`` have the noise covariance ``G = N^T D conj(N)``; with its
    Cholesky factor ``G = L L^H`` the filters ``W = N L^{-T}`` give residuals
    ``L^{-1} r`` of unit, uncorrelated variance. For N = 3 this is ``n / sqrt(sum_m D_m
    |n_m|^2)``.
    """
    nv = _null_components(theta, freqs, geometry, excess)
    d = np.asarray(noise, dtype=float)
    if nv.shape[2] == 1:
        norm = np.sqrt(np.sum(d[None, :] * np.abs(nv[:, :, 0]) ** 2, axis=1))
        return nv / np.maximum(norm, 1e-300)[:, None, None]
    if nv.shape[2] == 0:
        return nv
    gram = np.einsum("fmk,m,fml->fkl", nv, d, np.conj(nv))
    chol = np.linalg.cholesky(gram)
    # W^T = L^{-1} N^T
    wt = np.linalg.solve(chol, np.swapaxes(nv, 1, 2))
    return np.swapaxes(wt, 1, 2)


def residual_vector(
    theta: Theta,
    spectra: BlockSpectra,
    geometry: Geometry,
    noise: np.ndarray,
    use: np.ndarray | None = None,
    excess: np.ndarray | None = None,
) -> np.ndarray:
    """Unit-variance residuals at the used bins (complex), see :meth:`BlockSpectra.residual`.

    The residual signal is ``sum_m n_m * p_m / sqrt(sum_m D_m |n_m|^2)`` with the null
    vector ``n = h+ x h-`` (``n^T H = 0``, physics.md E.3): the two waves cancel and, under
    white sensor noise of power spectral densities ``noise`` (:func:`noise_levels`
    scaling), ``E |r|^2 = 1`` at the true theta. ``sum |r|^2`` is the negative
    log-likelihood with the wave amplitudes eliminated. ``excess``: :func:`zk_excess` on
    ``spectra.model_freqs``.
    """
    use = np.ones(spectra.freqs.size, bool) if use is None else use
    w = null_weights(theta, spectra.model_freqs, geometry, excess, noise)
    return spectra.residual(w, use)


def residual_cost(
    theta: Theta,
    spectra: BlockSpectra,
    geometry: Geometry,
    noise: np.ndarray | None = None,
    use: np.ndarray | None = None,
) -> float:
    """Residual per term ``mean |r|^2`` of :func:`residual_vector` (dimensionless).

    About 1 when the sensor noise explains the misfit; with ``noise`` None (equal unit
    noise) it is the mean energy of the microphones that two waves cannot explain.
    """
    if geometry.offsets.size < 3:
        return float("nan")  # two microphones: the two waves explain everything
    d = np.ones(geometry.offsets.size) if noise is None else noise
    r = residual_vector(theta, spectra, geometry, d, use)
    return float(np.mean(np.abs(r) ** 2)) if r.size else float("nan")
