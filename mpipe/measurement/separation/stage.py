"""The separation stage: :func:`separate`, from wall pressures to p0 and u0 (physics.md E).

:func:`separate` turns the calibrated wall pressures (Pa) of N >= 2 microphones into the
pressure p0 (Pa) and volume flow u0 (m^3/s) at the reference plane, with the per-block
table of theta.

Its steps, in order: check the input and plan the blocks (:func:`_plan`), measure the
sensor noise and prepare every block's spectra (:func:`_prepare_blocks`), estimate theta
per block (:func:`mpipe.measurement.separation.tracking.estimate_blocks`), choose the
trusted blocks and smooth theta over them (:func:`_smoothed_track`), rebuild p0 and u0 by
overlap-add (:func:`mpipe.measurement.separation.reconstruction.overlap_add`) and tabulate
the blocks (:func:`mpipe.measurement.separation.result.block_table`).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from mpipe.core.signals import as_signal, blocks
from mpipe.measurement.calibration import Calibration
from mpipe.measurement.separation.blocks import (
    FILTER_MARGIN_S,
    block_layout,
    cross_spectra,
    padded_block,
)
from mpipe.measurement.separation.checks import check_band
from mpipe.measurement.separation.drift import TrackChoice, choose_track, overlap_correlation
from mpipe.measurement.separation.noise import NOISE_FLOOR, noise_levels
from mpipe.measurement.separation.propagation import Prior, fixed_mach, fixed_mach_at
from mpipe.measurement.separation.reconstruction import overlap_add
from mpipe.measurement.separation.result import SeparationResult, block_table
from mpipe.measurement.separation.settings import SeparationConfig
from mpipe.measurement.separation.tracking import (
    BlockFits,
    estimate_blocks,
    hold_blocks,
    smooth_blocks,
)
from mpipe.measurement.separation.waves import Geometry

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class _Plan:
    """What a separation starts from.

    Attributes
    ----------
    geometry : Geometry
        Microphones and bore of the calibration.
    prior : Prior
        Prior, bounds and free parameters of theta.
    start : ndarray
        Start values of theta (degC, -, -, m), with the held Mach number.
    held_mach : float or None
        The Mach number held by the configuration (None: estimated).
    t_start, c_start : float
        Start temperature (degC) and its sound speed (m/s).
    hop, length : int
        Hop and length of the blocks, samples.
    starts : ndarray
        First sample of every block (the first ones start before the take).
    can_estimate : bool
        Whether theta is estimated (adaptive and N >= 3).
    theta_note : str
        Column ``theta`` of the block table.
    """

    geometry: Geometry
    prior: Prior
    start: np.ndarray
    held_mach: float | None
    t_start: float
    c_start: float
    hop: int
    length: int
    starts: np.ndarray
    can_estimate: bool
    theta_note: str


def checked_pressures(pressures, calibration: Calibration):
    """The pressures as a float array of shape ``(n, N)``, all samples finite.

    A DiskArray stays on disk (checked block by block).
    """
    x = as_signal(pressures)
    n_mics = len(calibration.microphones)
    if x.ndim != 2 or x.shape[1] != n_mics:
        raise ValueError(
            f"expected pressures of shape (n, {n_mics}) for the {n_mics} microphones of the "
            f"calibration, got {x.shape}"
        )
    if not all(np.all(np.isfinite(x[a:b])) for a, b in blocks(x.shape[0])):
        raise ValueError("pressures contain NaN or infinite samples")
    return x


def _theta_note(config: SeparationConfig, n_mics: int) -> str:
    """Whether theta is estimated, or why it is held."""
    if not config.adaptive:
        return "held: adaptive false"
    if n_mics < 3:
        return "held: two microphones, no redundancy"
    return "estimated"


def _plan(x: np.ndarray, fs: float, calibration: Calibration, config: SeparationConfig) -> _Plan:
    """Validate the settings against the calibration and lay out the blocks and the prior."""
    n_mics = x.shape[1]
    config.validate()
    geometry = Geometry.from_calibration(calibration)
    t_start = (
        calibration.air.temperature_c if config.temperature_c is None else config.temperature_c
    )
    c_start = geometry.sound_speed(t_start)
    check_band(config, geometry, fs, c_start)
    hop, length, starts = block_layout(x.shape[0], fs, config.block_s)
    free_mach = fixed_mach(config, geometry, c_start) is None
    prior = Prior.from_config(config, t_start, free_mach, n_mics)
    held_mach = fixed_mach(config, geometry, c_start)
    start = prior.mean.copy()
    if held_mach is not None:
        start[2] = held_mach
    return _Plan(
        geometry=geometry,
        prior=prior,
        start=start,
        held_mach=held_mach,
        t_start=t_start,
        c_start=c_start,
        hop=hop,
        length=length,
        starts=starts,
        # Two microphones determine the two waves exactly: no residual, no estimate of theta.
        can_estimate=config.adaptive and n_mics >= 3,
        theta_note=_theta_note(config, n_mics),
    )


def _log_plan(plan: _Plan, config: SeparationConfig, n_mics: int, fs: float) -> None:
    log.info(
        "separation: %d microphones, %d blocks of %.0f ms, theta %s",
        n_mics,
        plan.starts.size,
        1e3 * plan.length / fs,
        "estimated per block" if plan.can_estimate else "fixed",
    )
    if config.adaptive and n_mics < 3:
        log.warning(
            "separation: two microphones leave no redundancy; (c, eta, M) are held at "
            "T = %.2f degC, eta = %.3g, M = %.4g (configured values), not estimated",
            plan.t_start,
            plan.start[1],
            plan.start[2],
        )
    if config.mic_position_prior_m is not None and n_mics > 3:
        log.info("separation: %d microphones: positions held at the calibration's", n_mics)


class BlockSpectraSequence(Sequence):
    """Every block's :class:`BlockSpectra`, computed when asked for and not kept.

    The estimate reads the blocks once, in order; computing each one then (the same FFTs
    of the same samples) instead of holding all of them keeps the separation's memory
    bounded by a block, with the same numbers. ``x`` is only sliced (a take on disk is
    read block by block).
    """

    def __init__(self, x, fs: float, plan: _Plan, config: SeparationConfig) -> None:
        self.x, self.fs, self.plan, self.config = x, fs, plan, config
        self.margin = int(np.ceil(FILTER_MARGIN_S * fs))
        self.f1 = plan.c_start / (2 * plan.geometry.spacing)

    def __len__(self) -> int:
        return int(self.plan.starts.size)

    def __getitem__(self, b):
        if isinstance(b, slice):
            return [self[i] for i in range(len(self))[b]]
        s, length, m = int(self.plan.starts[b]), self.plan.length, self.margin
        c = self.config
        block = padded_block(self.x, s - m, length + 2 * m)
        return cross_spectra(block, self.fs, c.fmin_hz, c.fmax_hz, m, self.f1)


def _prepare_blocks(
    x, fs: float, plan: _Plan, noise_raw: np.ndarray, config: SeparationConfig
) -> tuple[BlockSpectraSequence, np.ndarray, list[np.ndarray], np.ndarray]:
    """Every block's spectra (computed when read), the noise levels, bins used, fitted blocks.

    Returns
    -------
    spectra : BlockSpectraSequence
        One per block.
    noise : ndarray
        ``noise_raw`` floored at ``NOISE_FLOOR`` of the strongest bin, Pa^2/Hz.
    uses : list of ndarray
        Per block, the bins entering the estimate (bool).
    fitted : ndarray
        Per block, whether it is fitted (bool).
    """
    n, length, starts = x.shape[0], plan.length, plan.starts
    spectra_list = BlockSpectraSequence(x, fs, plan, config)
    level, traces, peak = np.zeros(starts.size), [], 0.0
    for j, sp in enumerate(spectra_list):  # a first pass: what the choice of bins needs
        level[j] = float(np.sum(sp.mic_power))
        peak = max(peak, float(np.max(sp.mic_power, initial=0.0)))
        traces.append(np.sum(sp.mic_power, axis=1))  # BlockSpectra.use's trace
    floor = np.median(level) * 10 ** (-config.min_level_db / 10)
    inside = (starts >= 0) & (starts + length <= n)
    if not np.any(inside):
        inside[:] = True  # take shorter than one block: use what there is
    noise = np.maximum(noise_raw, NOISE_FLOOR * peak + 1e-300)
    total = float(np.sum(noise))
    # BlockSpectra.use, from the traces kept
    uses = [t - total >= 10 ** (config.min_snr_db / 10) * total for t in traces]
    # Blocks hanging over either end hold half silence and an abrupt edge: not fitted.
    fitted = inside & (level > max(floor, 0.0)) & np.array([np.sum(u) >= 3 for u in uses])
    return spectra_list, noise, uses, fitted


def _trusted_blocks(
    fitted: np.ndarray, residual: np.ndarray, adaptive: bool, config: SeparationConfig
) -> tuple[np.ndarray, float]:
    """The blocks entering the smoother, and the median chi^2 per dof of the fitted ones."""
    if not np.any(fitted) and adaptive:
        raise ValueError(
            "no block has enough signal in the estimation band "
            f"{config.fmin_hz:g}-{config.fmax_hz:g} Hz to estimate the propagation parameters"
        )
    median_j = float(np.median(residual[fitted])) if np.any(fitted) else float("nan")
    trust = fitted & (residual <= config.max_residual_ratio * median_j)
    if not np.any(trust):
        trust = fitted.copy()
    return trust, median_j


def _smoothed_track(
    plan: _Plan,
    centres: np.ndarray,
    fits: BlockFits,
    trust: np.ndarray,
    adaptive: bool,
    config: SeparationConfig,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, TrackChoice]:
    """Theta per block for the reconstruction under the model the data support.

    Returns the values, their standard errors, the sound speed (m/s) and the
    :class:`TrackChoice` (constant, linear or smoothed, and the take-level values).
    """
    nb = centres.size
    if adaptive:
        kept = [e if trust[j] else None for j, e in enumerate(fits.estimates)]
        smoothed = smooth_blocks(centres, kept, plan.prior, config.smooth_s, dof=True)
        rho = overlap_correlation(plan.length, plan.hop)
        choice = choose_track(centres, kept, plan.prior, smoothed, rho, config.drift_level)
    else:
        held = np.tile(plan.start, (nb, 1))
        zeros = np.zeros(plan.prior.mean.size)
        choice = TrackChoice(
            "held", held, np.zeros_like(held), plan.start.copy(), zeros, zeros, zeros,
            1.0, 1.0, 0.0,
        )  # fmt: skip
    smooth, smooth_se = choice.values.copy(), choice.se
    geometry = plan.geometry
    if plan.held_mach is not None:
        smooth[:, 2] = [fixed_mach_at(config, geometry, t) for t in smooth[:, 0]]
    c_track = np.array([geometry.sound_speed(float(t)) for t in smooth[:, 0]])
    return smooth, smooth_se, c_track, choice


def noise_line(psd: np.ndarray) -> str:
    """The console's line of the channels' one-sided noise PSD (Pa^2/Hz), in 3 digits.

    Each value in scientific notation (a fixed-point print showed 1e-9 as ``0.``); a take
    without measurable noise (a noiseless synthetic take) says so instead of a row of zeros.
    """
    psd = np.asarray(psd, dtype=float)
    if not np.any(psd > 0):
        return "separation: no noise measured in the channels (noise PSD 0: a noiseless take)"
    values = ", ".join(f"{v:.3g}" for v in psd)
    return f"separation: noise PSD per channel {values} Pa^2/Hz (one-sided)"


def _log_outcome(result: SeparationResult, median_j: float) -> None:
    for line in result.bound_warnings():
        log.warning("separation: %s", line)
    table = result.blocks
    log.info(
        "separation: T %.2f..%.2f degC, eta %.3f..%.3f, M %.4f..%.4f, median chi2/dof %.2f",
        table.temperature_c.min(),
        table.temperature_c.max(),
        table.loss_scale.min(),
        table.loss_scale.max(),
        table.mach.min(),
        table.mach.max(),
        median_j,
    )
    if result.track is not None:
        log.info("separation: %s", result.track.sentence())


def separate(
    pressures: np.ndarray,
    fs: float,
    calibration: Calibration,
    config: SeparationConfig,
    band_limit_hz: float | None = None,
    workers: int = 1,
) -> SeparationResult:
    """Separate the waves of a take of N >= 2 microphones and rebuild p0, u0 at the reference plane.

    With N >= 3 theta is estimated per block (``config.adaptive``); with N = 2 it is held
    at the configured values (two microphones leave no residual to estimate it from).

    Parameters
    ----------
    pressures : ndarray
        Calibrated microphone pressures in Pa, shape ``(n, N)``, upstream microphone first
        (the order of ``calibration.microphones``).
    fs : float
        Sample rate in Hz.
    calibration : Calibration
        Geometry, air and microphone positions.
    config : SeparationConfig
        Settings.
    band_limit_hz : float, optional
        Highest frequency the recording holds (the file's Nyquist frequency when the take
        was resampled to ``fs``), Hz; the sensor noise is measured below it.
    workers : int
        Processes the blocks' estimates are spread over (the same numbers with any number).

    Returns
    -------
    SeparationResult
        ``p0`` in Pa and ``u0`` in m^3/s at the reference plane, and the block table.

    Raises
    ------
    ValueError
        For a wrong shape, a non-finite sample or a band reaching the singular frequency.

    References
    ----------
    physics.md E.1-E.5; Jang & Ih 1998; Chatziioannou & van Walstijn 2012, section 4.
    """
    x = checked_pressures(pressures, calibration)
    est = estimate(x, fs, calibration, config, band_limit_hz, workers)
    # 2. Separate every windowed block with its smoothed theta, overlap-add.
    plan = est.plan
    p0, u0 = overlap_add(x, fs, plan.starts, plan.length, est.smooth, est.c_track,
                         plan.geometry, config)  # fmt: skip
    return est.result(p0, u0)


@dataclass(frozen=True)
class Estimate:
    """What the first pass of the separation found: theta over the take, before p0, u0.

    :meth:`result` makes the :class:`SeparationResult` once p0 and u0 are rebuilt (by
    :func:`mpipe.measurement.separation.reconstruction.overlap_add`, or block by block into
    a file by :func:`mpipe.measurement.separation.streaming.separate_to_npz`).
    """

    plan: _Plan
    fs: float
    config: SeparationConfig
    smooth: np.ndarray
    c_track: np.ndarray
    table: object
    noise_raw: np.ndarray
    track: TrackChoice | None
    median_j: float

    def result(self, p0, u0, log_outcome: bool = True) -> SeparationResult:
        """The separation's result with these p0 (Pa) and u0 (m^3/s), its outcome logged."""
        result = SeparationResult(
            fs=float(self.fs),
            p0=p0,
            u0=u0,
            blocks=self.table,
            config=self.config,
            noise_psd=2 * self.noise_raw,
            geometry=self.plan.geometry.corrected(float(np.median(self.smooth[:, 3]))),
            track=self.track,
        )
        if log_outcome:
            _log_outcome(result, self.median_j)
        return result


def estimate(
    x, fs: float, calibration: Calibration, config: SeparationConfig, band_limit_hz=None,
    workers: int = 1,
) -> Estimate:  # fmt: skip
    """The first pass of :func:`separate`: theta per block, smoothed over the take.

    ``x`` (Pa, shape ``(n, N)``, checked) is only sliced: a take on disk is read block by
    block, each block's spectra computed when the estimate reaches it. ``workers``: the
    processes the blocks' fits are spread over (the same numbers with any number).
    """
    n_mics = x.shape[1]
    plan = _plan(x, fs, calibration, config)
    _log_plan(plan, config, n_mics, fs)
    noise_raw = noise_levels(x, fs, config, band_limit_hz)
    log.info("%s", noise_line(2 * noise_raw))
    spectra_list, noise, uses, fitted = _prepare_blocks(x, fs, plan, noise_raw, config)
    adaptive = plan.can_estimate and int(np.sum(plan.prior.free)) > 0
    if adaptive:
        fits = estimate_blocks(spectra_list, uses, fitted, noise, plan.geometry, plan.start,
                               plan.prior, config, workers=workers)  # fmt: skip
    else:
        fits = hold_blocks(spectra_list, uses, fitted, noise, plan.geometry, plan.start,
                           plan.prior, plan.c_start)  # fmt: skip
    trust, median_j = _trusted_blocks(fitted, fits.residual, adaptive, config)
    centres = (plan.starts + plan.hop) / fs
    smooth, smooth_se, c_track, track = _smoothed_track(
        plan, centres, fits, trust, adaptive, config
    )
    table = block_table(centres, smooth, smooth_se, c_track, fits, fitted, trust, plan.theta_note)
    return Estimate(plan, float(fs), config, smooth, c_track, table, noise_raw, track, median_j)
