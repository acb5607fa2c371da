"""Adaptive wave separation in the main bore from N >= 2 wall microphones.

The calibrated wall pressures (any number N >= 2, all in one cylinder) are split, per
analysis block, into a forward and a backward travelling wave with a lossy, convected
plane-wave model, and recombined into pressure ``p0`` and volume flow ``u0`` at the
reference plane (physics.md E.1-E.5).

Field model (e^{+j omega t}; microphone ``m`` at ``d_m = x_m - x_ref`` metres downstream of
the reference plane)::

    P_m = A exp(-j k+ d_m) + B exp(+j k- d_m),   k+- = k0 / (1 +- M)
    k0  = omega / c + eta (k_ZK(omega) - omega / c_ZK)
    P0  = A + B,   U0 = (A - B) / Z_c

``k_ZK`` is the Zwikker-Kosten wavenumber of the main bore (physics.md B.2) for air at the
effective temperature ``T`` (the calibration's air model gives ``c(T)``); ``eta`` scales its
visco-thermal excess and ``M`` is the Mach number of the mean flow (positive to the bell).

Estimation of theta = (T, eta, M)
---------------------------------
Per block, theta maximises the likelihood of the microphone signals under white sensor
noise of known power spectral density ``D_m`` per channel (measured once per take), the two
wave amplitudes of every bin being eliminated (concentrated likelihood). The residual is
the signal ``e = sum_m n_m * p_m`` filtered from the block (with context on both sides) by
the null filter, normalised to unit noise variance, then Hann-windowed::

    E(f) = n(f)^T P(f) / sqrt(sum_m D_m |n_m(f)|^2),
    n = h+ x h-   (the null vector of the 3 x 2 model matrix, n^T H = 0)

With N > 3 microphones the residual has N - 2 components: the null vectors of the
consecutive triples of microphones (smooth in frequency, spanning the left null space of
the N x 2 model matrix), decorrelated under the sensor noise by the inverse Cholesky
factor of their noise covariance, so that the cost is again the concentrated negative
log-likelihood. With N = 2 there is no redundancy: two microphones determine the two waves
exactly (wherever ``H`` is regular, i.e. away from ``f_n = n c (1 - M^2) / (2 s)``) and
leave no residual, so theta cannot be estimated and is held at the configured values (the
log and the ``theta`` column of the block table say so). The position correction of the
middle microphone (below) exists for N = 3 only; with N > 3 the positions are held.

and the cost is ``sum |r|^2 / kappa`` plus Gaussian priors on T, eta and M about the
configured values. Every bin thus weighs by its own signal-to-noise ratio, so the strong
low harmonics, where the flow's energy is, determine theta. Only bins whose signal exceeds
the noise by ``min_snr_db`` and that lie in ``fmin_hz``..``fmax_hz`` (where the plane-wave
model with the calibrated positions is trusted) are used; the band actually used is
reported per block. ``kappa`` (>= 1) accounts for the correlation of adjacent bins of the
windowed, zero-padded residual (computed from the window, a sandwich estimate), so that the
standard errors from the Gauss-Newton curvature are honest.

Blocks are then combined, with each block's information matrix (the prior counted once),
into a constant, a straight line in time or a weighted local linear regression over
``smooth_s`` seconds, whichever the data support (likelihood-ratio tests at
``drift_level``): a steady take gets one value with the pooled standard error, and a
drift is followed without lag.

Reconstruction has no block seams: every block is multiplied by a periodic Hann window
(hop = half a block, so the windows sum to one), zero-padded on both sides, separated in
the frequency domain with the block's smoothed ``theta`` and overlap-added. With a fixed
``theta`` this equals one linear filtering of the whole take; with a drifting ``theta`` the
filters are cross-faded by the windows.

References
----------
Chatziioannou & van Walstijn 2012, section 4 (three-microphone set-up, adaptive filter).
Jang & Ih 1998 (least squares with more than two microphones).
H.-J. Jang, J.-G. Ih, "On the multiple microphone method for measuring in-duct acoustic
properties in the presence of mean flow", J. Acoust. Soc. Am. 103(3):1520-1526, 1998.
J. Y. Chung, D. A. Blaser, "Transfer function method of measuring in-duct acoustic
properties. I. Theory", J. Acoust. Soc. Am. 68(3):907-913, 1980.
physics.md sections E.1-E.5.

Modules
-------
settings
    :class:`SeparationConfig` and :func:`fixed_config`.
waves
    The plane-wave model: :class:`Theta`, :class:`Geometry`, wavenumbers, the model matrix,
    its null vector, the separation filters and the singular frequencies.
blocks
    The block layout and one block's spectra (:class:`BlockSpectra`, :func:`cross_spectra`).
noise
    The sensor noise level of every channel (:func:`noise_levels`).
residual
    The noise-whitened null-filter residual and its cost (:func:`residual_cost`).
propagation
    The per-block estimate of (T, eta, M, dx): :class:`Prior`, :func:`estimate_block`.
tracking
    theta over the blocks: :func:`estimate_blocks`, :func:`smooth_blocks`.
drift
    Constant, linear or smoothed theta over the take, chosen by the data
    (:func:`choose_track`, :class:`TrackChoice`).
reconstruction
    The overlap-add reconstruction of p0, u0 and :func:`reference_noise`.
result
    :class:`SeparationResult` and the block table (:data:`BLOCK_COLUMNS`).
checks
    :func:`check_band` and :func:`check_channel_order`.
stage
    :func:`separate`, which runs the steps above.

The names below are re-exported here, so ``from mpipe.measurement.separation import
separate`` keeps working.
"""

from mpipe.measurement.separation.blocks import BlockSpectra, cross_spectra, window_correlation
from mpipe.measurement.separation.checks import check_band, check_channel_order
from mpipe.measurement.separation.noise import noise_levels
from mpipe.measurement.separation.propagation import BlockEstimate, Prior, estimate_block
from mpipe.measurement.separation.reconstruction import overlap_add, reference_noise
from mpipe.measurement.separation.residual import residual_cost, residual_vector
from mpipe.measurement.separation.result import BLOCK_COLUMNS, SeparationResult, block_table
from mpipe.measurement.separation.settings import SeparationConfig, fixed_config
from mpipe.measurement.separation.stage import separate
from mpipe.measurement.separation.tracking import BlockFits, estimate_blocks, smooth_blocks
from mpipe.measurement.separation.waves import (
    Geometry,
    Theta,
    model_matrix,
    null_vector,
    projection_residual,
    separation_filters,
    singular_frequencies,
    wavenumbers,
    zk_excess,
)

__all__ = [
    "BLOCK_COLUMNS",
    "BlockEstimate",
    "BlockFits",
    "BlockSpectra",
    "Geometry",
    "Prior",
    "SeparationConfig",
    "SeparationResult",
    "Theta",
    "block_table",
    "check_band",
    "check_channel_order",
    "cross_spectra",
    "estimate_block",
    "estimate_blocks",
    "fixed_config",
    "model_matrix",
    "noise_levels",
    "null_vector",
    "overlap_add",
    "projection_residual",
    "reference_noise",
    "residual_cost",
    "residual_vector",
    "separate",
    "separation_filters",
    "singular_frequencies",
    "smooth_blocks",
    "wavenumbers",
    "window_correlation",
    "zk_excess",
]
