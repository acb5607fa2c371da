"""theta over the blocks of a take: every block's estimate and their combination.

:func:`estimate_blocks` runs :func:`estimate_block` over the blocks in chains (each block
starting from the previous estimate, each chain from the take's start values, so that the
chains may run on several processes) into :class:`BlockFits`; :func:`smooth_blocks`
combines the trusted blocks by a weighted local linear regression over ``smooth_s``
seconds with each block's information matrix (the prior counted once), which follows a
linear drift of temperature (degC) or flow without lag; :func:`smoothed_track` gives theta
per block for the reconstruction.
"""

from __future__ import annotations

import collections
import logging
from dataclasses import dataclass

import numpy as np

from mpipe.core.workers import process_pool
from mpipe.measurement.separation.blocks import BlockSpectra, window_correlation
from mpipe.measurement.separation.propagation import (
    BlockEstimate,
    Prior,
    estimate_block,
)
from mpipe.measurement.separation.residual import residual_cost
from mpipe.measurement.separation.settings import SeparationConfig
from mpipe.measurement.separation.waves import Geometry, Theta

log = logging.getLogger(__name__)


@dataclass
class BlockFits:
    """Per block, its own estimate of theta and what the fit used.

    Attributes
    ----------
    raw, raw_se : ndarray
        Shape ``(n_blocks, 4)``: the estimate (degC, -, -, m), held values where theta is
        held, and its standard errors; NaN for blocks not fitted.
    residual, kappa : ndarray
        chi^2 per degree of freedom and the variance inflation (NaN: not fitted).
    evaluations : ndarray
        Residual evaluations of the solver (int).
    at_bound : list of str
        Parameters on a bound, ';'-separated.
    band_lo, band_hi : ndarray
        Lowest and highest frequency of the bins used, Hz (NaN: none).
    bins : ndarray
        Number of bins used (int).
    snr_db : ndarray
        Median signal-to-noise ratio of the bins used, dB.
    estimates : list
        The :class:`BlockEstimate` of every estimated block, None elsewhere.
    """

    raw: np.ndarray
    raw_se: np.ndarray
    residual: np.ndarray
    kappa: np.ndarray
    evaluations: np.ndarray
    at_bound: list[str]
    band_lo: np.ndarray
    band_hi: np.ndarray
    bins: np.ndarray
    snr_db: np.ndarray
    estimates: list[BlockEstimate | None]

    @classmethod
    def empty(cls, nb: int, n_par: int) -> BlockFits:
        """``nb`` blocks of ``n_par`` parameters, none fitted yet."""
        return cls(
            raw=np.full((nb, n_par), np.nan),
            raw_se=np.full((nb, n_par), np.nan),
            residual=np.full(nb, np.nan),
            kappa=np.full(nb, np.nan),
            evaluations=np.zeros(nb, dtype=int),
            at_bound=[""] * nb,
            band_lo=np.full(nb, np.nan),
            band_hi=np.full(nb, np.nan),
            bins=np.zeros(nb, dtype=int),
            snr_db=np.full(nb, np.nan),
            estimates=[None] * nb,
        )

    def record_band(self, b: int, spectra: BlockSpectra, use: np.ndarray, noise: np.ndarray):
        """The band, bin count and signal-to-noise ratio of the bins block ``b`` uses."""
        if np.any(use):
            self.band_lo[b] = float(spectra.freqs[use][0])
            self.band_hi[b] = float(spectra.freqs[use][-1])
            self.bins[b] = int(np.sum(use))
            snr = np.sum(spectra.mic_power[use], axis=1) / np.sum(noise) - 1.0
            self.snr_db[b] = float(10 * np.log10(max(np.median(snr), 1e-30)))

    def record_estimate(self, b: int, est: BlockEstimate, prior: Prior) -> None:
        """Block ``b``'s estimate; the standard errors of held parameters are 0."""
        n_par = prior.mean.size
        self.estimates[b] = est
        self.raw[b] = est.values
        cov_full = np.zeros(n_par)
        cov_full[prior.free] = np.diag(est.cov)
        self.raw_se[b] = np.sqrt(np.maximum(cov_full, 0.0))
        self.residual[b] = est.residual
        self.kappa[b] = est.kappa
        self.evaluations[b] = est.evaluations
        self.at_bound[b] = ";".join(est.at_bound)


#: Blocks fitted one after another, each from the estimate before it (a chain). Every
#: chain starts from the take's start values, so the chains are independent and run on
#: any number of worker processes with the same numbers (16 blocks of 80 ms: 1.3 s).
CHAIN_BLOCKS = 16


def estimate_blocks(
    spectra_list: list[BlockSpectra],
    uses: list[np.ndarray],
    fitted: np.ndarray,
    noise: np.ndarray,
    geometry: Geometry,
    start: np.ndarray,
    prior: Prior,
    config: SeparationConfig,
    *,
    workers: int = 1,
) -> BlockFits:
    """Estimate theta in every fitted block, chain by chain (:data:`CHAIN_BLOCKS`).

    Parameters
    ----------
    spectra_list : list of BlockSpectra
        The blocks, in time order.
    uses : list of ndarray
        Per block, the bins entering the estimate (bool).
    fitted : ndarray
        Per block, whether it is fitted (bool).
    noise : ndarray
        Floored noise levels of the channels (:func:`noise_levels` scaling), Pa^2/Hz.
    geometry : Geometry
        Microphones and bore.
    start : ndarray
        Start values of theta (degC, -, -, m), where every chain starts.
    prior : Prior
        Prior, bounds and free parameters.
    config : SeparationConfig
        Settings of :func:`estimate_block`.
    workers : int
        Worker processes the chains are spread over (1: all here; the same numbers).

    Returns
    -------
    BlockFits

    Notes
    -----
    Within a chain each block starts from the estimate of the block before it, and its
    ``kappa`` from that block's; a chain's first block from ``start`` and ``kappa = 1``.
    The blocks' spectra are made here, in time order, and sent with their chain: at most
    two chains per worker are in flight, so memory stays bounded on a long take.
    """
    fits = BlockFits.empty(len(spectra_list), prior.mean.size)
    chosen = np.flatnonzero(fitted)
    chains = [chosen[i : i + CHAIN_BLOCKS] for i in range(0, chosen.size, CHAIN_BLOCKS)]
    args = (noise, geometry, np.asarray(start, float), prior, config)

    def chain_tasks():
        blocks = iter(range(len(spectra_list)))
        for chain in chains:
            items = []
            for b in blocks:  # every block's band (fitted or not) recorded in time order
                spectra = spectra_list[b]
                fits.record_band(b, spectra, uses[b], noise)
                if fitted[b]:
                    items.append((int(b), spectra, uses[b]))
                if b == chain[-1]:
                    break
            yield items
        for b in blocks:
            fits.record_band(b, spectra_list[b], uses[b], noise)

    for chain in _map_chains(chain_tasks(), args, workers):
        for b, est in chain:
            fits.record_estimate(b, est, prior)
            if log.isEnabledFor(logging.DEBUG):  # T degC, eta, M and, when fitted, mic shift m
                values = ", ".join(f"{v:.5g}" for v in fits.raw[b])
                log.debug("block %d: theta (%s), chi2 %.2f", b, values, fits.residual[b])
    return fits


def hold_blocks(
    spectra_list: list[BlockSpectra],
    uses: list[np.ndarray],
    fitted: np.ndarray,
    noise: np.ndarray,
    geometry: Geometry,
    start: np.ndarray,
    prior: Prior,
    c_start: float,
) -> BlockFits:
    """The blocks with theta held at ``start`` (only the residual evaluated).

    For a take whose theta is not estimated (two microphones, where the residual is NaN,
    or no free parameter). ``c_start``: the sound speed at the start temperature, m/s.
    """
    fits = BlockFits.empty(len(spectra_list), prior.mean.size)
    th = Theta(c_start, start[1], start[2])
    for b, spectra in enumerate(spectra_list):
        fits.record_band(b, spectra, uses[b], noise)
        if fitted[b]:
            fits.residual[b] = residual_cost(th, spectra, geometry, noise, uses[b])
            fits.raw[b] = start
            fits.raw_se[b] = 0.0
    return fits


def fit_chain(chain, noise, geometry, start, prior, config) -> list[tuple[int, BlockEstimate]]:
    """``[(b, estimate)]`` of one chain ``[(b, spectra, use)]`` (see :func:`estimate_blocks`)."""
    out, current, kappa, corr = [], np.array(start, float), 1.0, None
    for b, spectra, use in chain:
        if corr is None:  # the window's (the same for every block)
            corr = window_correlation(spectra)
        est = estimate_block(spectra, use, noise, geometry, current, prior, config, corr, kappa)
        kappa, current = est.kappa, est.values
        out.append((b, est))
    return out


def _map_chains(tasks, args: tuple, workers: int):
    """:func:`fit_chain` of each task, in order: here, or on ``workers`` processes."""
    if workers <= 1:
        for chain in tasks:
            yield fit_chain(chain, *args)
        return
    with process_pool(workers) as pool:
        pending: collections.deque = collections.deque()
        for chain in tasks:
            pending.append(pool.submit(fit_chain, chain, *args))
            if len(pending) >= 2 * workers:
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()


def smooth_blocks(
    times: np.ndarray,
    estimates: list[BlockEstimate | None],
    prior: Prior,
    half_width_s: float,
    dof: bool = False,
):
    """Weighted local linear regression of the blocks' estimates, with the prior once.

    Parameters
    ----------
    times : ndarray
        Block centres, s.
    estimates : list
        Per block its :class:`BlockEstimate`, or None (not fitted or not trusted).
    prior : Prior
        Prior on (T, eta, M, dx); counted once in every local fit.
    half_width_s : float
        Half-width of the tricube kernel, s (0: each block alone with the prior); it grows
        to twice that at the first and last estimated block.
    dof : bool
        Also return the smoother's degrees of freedom: the trace of its hat matrix (how
        much each block's estimate moves its own smoothed value), summed over the blocks
        with an estimate.

    Returns
    -------
    values : ndarray
        Shape ``(n_blocks, 4)``: temperature (degC), eta, Mach number, position correction
        of the middle microphone (m).
    se : ndarray
        Shape ``(n_blocks, 4)``: their standard errors (0 for held parameters).
    dof : float
        Only with ``dof=True``.

    Notes
    -----
    Each block contributes its data alone: the information ``I_j`` and the information
    vector ``h_j = (I_j + P) mu_j - P mu_0`` (its posterior with the prior removed), as a
    Gaussian measurement of ``a + b (t_j - t)``. The local fit minimises
    ``sum_j k_j |y_j - a - b tau_j|^2_{I_j} + |a - mu_0|^2_P``; its covariance is the
    sandwich with the kernel weights.
    """
    idx = np.flatnonzero(prior.free)
    p = idx.size
    n = times.size
    out = np.tile(prior.mean, (n, 1))
    se = np.zeros((n, prior.mean.size))
    for j, e in enumerate(estimates):
        if e is not None:
            out[j, ~prior.free] = e.values[~prior.free]
    if p == 0:
        return (out, se, 0.0) if dof else (out, se)
    info_p = prior.information
    mu0 = prior.mean[idx]
    hs, infos, ts = [], [], []
    own = {}
    for j, e in enumerate(estimates):
        if e is None:
            continue
        i_j = e.data_information
        own[j] = i_j
        post = np.linalg.pinv(e.cov)
        hs.append(post @ e.values[idx] - info_p @ mu0)
        infos.append(i_j)
        ts.append(times[j])
    if not infos:
        out[:, idx] = mu0
        return (out, se, 0.0) if dof else (out, se)
    trace = 0.0
    ts_a = np.array(ts)
    # a weak prior on the slope keeps the local fit regular with one block in reach
    slope_info = np.eye(p) * 1e-12
    t_first, t_last = float(ts_a.min()), float(ts_a.max())
    for b in range(n):
        tau = ts_a - times[b]
        if half_width_s > 0:
            # Near an end the kernel is one-sided; widening it there (up to twice at the
            # end) keeps the number of blocks, so the extrapolated intercept stays precise.
            edge = min(times[b] - t_first, t_last - times[b])
            h = max(half_width_s, 2 * half_width_s - max(edge, 0.0))
            u = np.abs(tau) / h
            k = np.where(u < 1, (1 - u**3) ** 3, 0.0)
        else:
            k = (np.abs(tau) < 1e-12).astype(float)
        m = np.zeros((2 * p, 2 * p))
        rhs = np.zeros(2 * p)
        meat = np.zeros((2 * p, 2 * p))
        for kj, tj, i_j, h_j in zip(k, tau, infos, hs, strict=True):
            if kj <= 0:
                continue
            x = np.hstack([np.eye(p), tj * np.eye(p)])
            m += kj * x.T @ i_j @ x
            rhs += kj * x.T @ h_j
            meat += kj**2 * x.T @ i_j @ x
        m[:p, :p] += info_p
        rhs[:p] += info_p @ mu0
        meat[:p, :p] += info_p
        m[p:, p:] += slope_info
        minv = np.linalg.pinv(m)
        beta = minv @ rhs
        cov = minv @ meat @ minv
        out[b, idx] = beta[:p]
        se[b, idx] = np.sqrt(np.maximum(np.diag(cov)[:p], 0.0))
        if b in own:
            # d(value at b) / d(y_b) = [M^-1]_aa k(0) I_b, k(0) = 1
            trace += float(np.trace(minv[:p, :p] @ own[b]))
    lo, hi = prior.lower, prior.upper
    out = np.clip(out, lo, hi)
    return (out, se, trace) if dof else (out, se)
