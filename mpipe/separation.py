"""Adaptive three-microphone wave separation in the main bore.

The three calibrated wall pressures are split, per analysis block, into a forward and a
backward travelling wave with a lossy, convected plane-wave model, and recombined into
pressure ``p0`` and volume flow ``u0`` at the reference plane (physics.md E.1-E.5).

Field model (e^{+j omega t}; microphone ``m`` at ``d_m = x_m - x_ref`` metres downstream of
the reference plane)::

    P_m = A exp(-j k+ d_m) + B exp(+j k- d_m),   k+- = k0 / (1 +- M)
    k0  = omega / c + eta (k_ZK(omega) - omega / c_ZK)
    P0  = A + B,   U0 = (A - B) / Z_c

``k_ZK`` is the Zwikker-Kosten wavenumber of the main bore (physics.md B.2) for air at the
effective temperature that has sound speed ``c``; ``eta`` scales its visco-thermal excess
and ``M`` is the Mach number of the mean flow (positive towards the bell).

The propagation parameters ``theta = (c, eta, M)`` are estimated per block by minimising
the least-squares residual of predicting the three microphones (physics.md E.3, E.5)::

    J(theta) = sum_omega w(omega) n^T S_PP conj(n) / ||n||^2,   n = h+ x h-

where ``h+-`` are the columns of the 3 x 2 model matrix and ``S_PP`` is the 3 x 3 Welch
cross-spectral matrix of the block. Spatially white sensor noise adds a constant to every
term (``n^T sigma^2 I conj(n) / ||n||^2 = sigma^2``), so it does not move the minimum.

Reconstruction has no block seams: every block is multiplied by a periodic Hann window
(hop = half a block, so the windows sum to one), zero-padded on both sides, separated in
the frequency domain with the block's smoothed ``theta`` and overlap-added. With a fixed
``theta`` this equals one linear filtering of the whole take; with a drifting ``theta`` the
filters are cross-faded by the windows.

References
----------
Chatziioannou & van Walstijn 2012, section 4 (three-microphone set-up, adaptive filter).
H.-J. Jang, J.-G. Ih, "On the multiple microphone method for measuring in-duct acoustic
properties in the presence of mean flow", J. Acoust. Soc. Am. 103(3):1520-1526, 1998.
J. Y. Chung, D. A. Blaser, "Transfer function method of measuring in-duct acoustic
properties. I. Theory", J. Acoust. Soc. Am. 68(3):907-913, 1980.
physics.md sections E.1-E.5.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd
from scipy import fft as sfft
from scipy import ndimage, optimize

from mpipe import ducts
from mpipe.air import Air, temperature_from_sound_speed
from mpipe.calibration import Calibration
from mpipe.config import Where, between, positive, spec

log = logging.getLogger(__name__)

# Floor of the coherence weight, so that a block without coherent bins still has a cost.
# Cap of the coherent-to-incoherent power ratio in the weights (clean data: all bins alike).
_MAX_SNR_WEIGHT = 1e4
_MIN_COHERENCE_WEIGHT = 1e-3


@dataclass(frozen=True)
class SeparationConfig:
    """Settings of the adaptive wave separation (physics.md E.5).

    All frequencies in Hz, times in s, speeds in m/s.
    """

    block_s: float = spec(
        "s",
        "analysis block length; blocks overlap by half (the reconstruction windows sum to one)",
        between(0.005, 2.0),
        default=0.08,
    )
    welch_segment_s: float = spec(
        "s",
        "Welch segment length inside a block for the 3x3 cross-spectral matrix "
        "(segments overlap by half)",
        between(0.001, 2.0),
        default=0.04,
    )
    fmin_hz: float = spec(
        "Hz", "lower edge of the band used to estimate theta", between(1.0, 1e5), default=100.0
    )
    fmax_hz: float = spec(
        "Hz", "upper edge of the band used to estimate theta", between(10.0, 1e5), default=7000.0
    )
    envelope_hz: float = spec(
        "Hz",
        "width of the running mean of the spectral envelope that whitens the cost; bins "
        "between harmonics then weigh little, the harmonics of all orders alike",
        positive,
        default=300.0,
    )
    weighting: str = spec(
        "",
        "cost weights over the spectral envelope: 'coherence' (gamma^2) or 'snr' "
        "(gamma^2 / (1 - gamma^2), drops noise-dominated bins)",
        lambda v: None if v in ("coherence", "snr") else "expected 'coherence' or 'snr'",
        default="coherence",
    )
    noise_model: str = spec(
        "",
        "sensor noise in the cost: 'white' (estimate one white noise level per channel "
        "over the whole take and divide each bin's residual by the noise power it carries, "
        "a generalised least squares that makes the noise part of J independent of theta) "
        "or 'none' (plain least squares, physics.md E.3)",
        lambda v: None if v in ("white", "none") else "expected 'white' or 'none'",
        default="white",
    )
    noise_fmin_hz: float | None = spec(
        "Hz",
        "lower edge of the band above the separation band where the noise level of each "
        "channel is measured (null: 1.1 (band_edge_hz + band_taper_hz)); the band ends at "
        "0.95 of the Nyquist frequency. When it is narrower than 1 kHz the noise level is "
        "the low quantile of the spectrum in the estimation band (between the harmonics)",
        positive,
        default=None,
    )
    adaptive: bool = spec(
        "", "estimate theta per block (false: hold it at the start values)", default=True
    )
    estimate_loss: bool = spec("", "estimate the loss scale eta (false: hold it)", default=True)
    mach: float | None = spec(
        "",
        "hold the Mach number at this value (null: estimate it per block)",
        between(-0.05, 0.1),
        default=None,
    )
    mean_flow_m3_s: float | None = spec(
        "m^3/s",
        "hold the Mach number at mean_flow / (S c) from this mean volume flow (null: unused)",
        between(-1e-2, 1e-2),
        default=None,
    )
    temperature_c: float | None = spec(
        "degC",
        "start value of the effective temperature (null: the calibration file's)",
        between(-20.0, 60.0),
        default=None,
    )
    loss_scale: float = spec("", "start value of eta", between(0.1, 10.0), default=1.0)
    c_bounds_m_s: tuple[float, ...] = spec(
        "m/s", "lower and upper bound of the effective sound speed", default=(330.0, 365.0)
    )
    loss_bounds: tuple[float, ...] = spec("", "bounds of eta", default=(0.5, 3.0))
    mach_bounds: tuple[float, ...] = spec("", "bounds of M", default=(-0.01, 0.05))
    min_level_db: float = spec(
        "dB",
        "blocks whose energy in the estimation band lies more than this below the median "
        "block are not fitted (silence, fades); they take the estimates of their neighbours",
        between(0.0, 200.0),
        default=30.0,
    )
    max_residual_ratio: float = spec(
        "",
        "fitted blocks whose residual J exceeds this multiple of the median J (onsets, "
        "clicks: the stationary two-wave model does not hold) are not trusted and take "
        "their neighbours' estimates",
        between(1.0, 1e6),
        default=4.0,
    )
    pool_s: float = spec(
        "s",
        "with noise_model 'white': blocks whose fitted residual is within "
        "pool_residual_ratio of the residual that sensor noise alone leaves are fitted "
        "together, over consecutive stretches of this length (the cost is summed over the "
        "blocks, weighted by the signal-to-noise ratio of each bin rather than whitened); "
        "one 80 ms block at 40 dB SNR holds too little information to fix theta",
        between(0.01, 1e4),
        default=4.0,
    )
    pool_residual_ratio: float = spec(
        "",
        "a block counts as noise-dominated when its residual J is below this multiple of "
        "the residual expected from the sensor noise levels",
        between(1.0, 1e6),
        default=3.0,
    )
    smooth_blocks: int = spec(
        "",
        "length (odd, blocks) of the centred running median applied to the estimates",
        between(1, 101),
        default=5,
    )
    max_evaluations: int = spec(
        "",
        "iterations (residual evaluations) per block of the least-squares solver",
        between(5, 10000),
        default=100,
    )
    pad_s: float = spec(
        "s",
        "zero padding on each side of a block before the FFT; must exceed the length of "
        "the separation filters' impulse responses (set by the low-frequency ramp of u0)",
        between(0.0, 2.0),
        default=0.1,
    )
    u_highpass_hz: float = spec(
        "Hz",
        "u0 is unmeasurable at DC (physics.md E.4): its filter rises from 0 at half this "
        "frequency to 1 at this frequency (raised cosine)",
        between(0.5, 1000.0),
        default=20.0,
    )
    band_edge_hz: float = spec(
        "Hz",
        "the separation filters fall to zero above this frequency (raised cosine over "
        "band_taper_hz), before the singularity f1 = c (1 - M^2) / (2 s)",
        positive,
        default=8000.0,
    )
    band_taper_hz: float = spec(
        "Hz", "width of the raised-cosine taper above band_edge_hz", positive, default=400.0
    )

    def _check(self, where: Where) -> None:
        if self.fmax_hz <= self.fmin_hz:
            raise where.error("fmax_hz", f"expected fmax_hz > fmin_hz = {self.fmin_hz:g} Hz")
        if self.welch_segment_s > self.block_s:
            raise where.error("welch_segment_s", "expected a segment no longer than block_s")
        if self.smooth_blocks % 2 == 0:
            raise where.error("smooth_blocks", "expected an odd number of blocks")
        if self.mach is not None and self.mean_flow_m3_s is not None:
            raise where.error("mach", "give either mach or mean_flow_m3_s, not both")
        for key, b in (
            ("c_bounds_m_s", self.c_bounds_m_s),
            ("loss_bounds", self.loss_bounds),
            ("mach_bounds", self.mach_bounds),
        ):
            if len(b) != 2 or not b[0] < b[1]:
                raise where.error(key, f"expected [lower, upper] with lower < upper, got {b}")

    def validate(self) -> SeparationConfig:
        """Run the cross-field checks on an instance built in Python; returns it."""
        self._check(Where("SeparationConfig"))
        return self


@dataclass(frozen=True)
class Theta:
    """Propagation parameters of one block.

    Attributes
    ----------
    c : float
        Effective sound speed in m/s.
    eta : float
        Scale of the Zwikker-Kosten visco-thermal excess (dimensionless, 1 = theory).
    mach : float
        Mach number of the mean flow, positive towards the bell (dimensionless).
    """

    c: float
    eta: float = 1.0
    mach: float = 0.0

    @property
    def temperature_c(self) -> float:
        """Effective temperature in degC from ``c`` (inverse Keefe fit, physics.md A.2)."""
        return temperature_from_sound_speed(self.c)


@dataclass(frozen=True)
class Geometry:
    """What the separation needs from a calibration.

    Attributes
    ----------
    offsets : ndarray
        Microphone positions relative to the reference plane, m, shape ``(3,)``.
    radius : float
        Radius of the main bore at the microphones, m.
    losses : str
        Loss model of :mod:`mpipe.ducts`.
    air_model : str
        Air model name for :func:`mpipe.air.air_properties`.
    """

    offsets: np.ndarray
    radius: float
    losses: str
    air_model: str
    calibration: Calibration

    @classmethod
    def from_calibration(cls, calibration: Calibration) -> Geometry:
        """Extract the geometry of the microphones from a calibration."""
        x = np.array([m.position for m in calibration.microphones], dtype=float)
        return cls(
            offsets=x - calibration.reference_plane,
            radius=calibration.main_radius,
            losses=calibration.bore.losses,
            air_model=calibration.air.model,
            calibration=calibration,
        )

    def air(self, c: float) -> Air:
        """Air at the effective temperature whose Keefe sound speed is ``c`` (m/s)."""
        t = float(np.clip(temperature_from_sound_speed(c), -19.9, 59.9))
        return self.calibration.air_properties(t)

    @property
    def spacing(self) -> float:
        """Smallest distance between two microphones, m."""
        return float(np.min(np.diff(np.sort(self.offsets))))


@dataclass(frozen=True)
class SeparationResult:
    """Waves at the reference plane and the per-block parameter track.

    Attributes
    ----------
    fs : float
        Sample rate in Hz.
    p0 : ndarray
        Pressure at the reference plane, Pa, shape ``(n,)``.
    u0 : ndarray
        Volume flow at the reference plane, m^3/s, positive towards the bell; zero mean
        (unmeasurable at DC).
    blocks : pandas.DataFrame
        One row per block: ``time_s`` (block centre), ``temperature_c``, ``c_m_s``,
        ``loss_scale``, ``mach`` (smoothed values used for the reconstruction),
        ``residual`` (fraction of the weighted microphone energy the model cannot
        explain), ``coherence`` (mean pairwise squared coherence in the estimation band),
        the raw estimates ``c_raw_m_s``, ``loss_scale_raw``, ``mach_raw`` (NaN where the
        block was not fitted), ``evaluations``, ``fitted`` (false for blocks over the
        ends of the take or below ``min_level_db``) and ``trusted`` (fitted with a
        residual within ``max_residual_ratio`` of the median); the other blocks take
        the values of their trusted neighbours.
    config : SeparationConfig
        The settings used.
    """

    fs: float
    p0: np.ndarray
    u0: np.ndarray
    blocks: pd.DataFrame
    config: SeparationConfig

    def temperature_track(self) -> np.ndarray:
        """Effective temperature in degC at every sample (linear between block centres)."""
        t = np.arange(self.p0.size) / self.fs
        b = self.blocks
        return np.interp(t, b["time_s"].to_numpy(), b["temperature_c"].to_numpy())


# ---------------------------------------------------------------------------------------
# Propagation model


def zk_excess(omega: np.ndarray, geometry: Geometry, c: float) -> tuple[np.ndarray, np.ndarray]:
    """Visco-thermal excess of the wavenumber and the lossy characteristic impedance ratio.

    Parameters
    ----------
    omega : ndarray
        Angular frequency in rad/s.
    geometry : Geometry
        Bore radius, loss and air models.
    c : float
        Effective sound speed in m/s (sets the air properties).

    Returns
    -------
    excess : ndarray
        ``k_ZK(omega) - omega / c_air`` in rad/m (complex; imaginary part negative).
    zc_ratio : ndarray
        ``Z_c / Z0 - 1`` (complex, dimensionless), the lossy excess of the characteristic
        impedance over the real ``rho c / S``.

    References
    ----------
    physics.md B.2 and E.5.
    """
    air = geometry.air(c)
    gamma, zc = ducts.propagation(omega, geometry.radius, air, geometry.losses)
    k = -1j * gamma
    w = np.maximum(omega, ducts.OMEGA_FLOOR)
    z0 = air.impedance(np.pi * geometry.radius**2)
    return k - w / air.c, zc / z0 - 1.0


def wavenumbers(
    omega: np.ndarray, theta: Theta, excess: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Forward and backward wavenumbers k+ and k- in rad/m (physics.md E.1, E.5).

    ``k0 = omega / c + eta * excess`` and ``k+- = k0 / (1 +- M)``.
    """
    k0 = omega / theta.c + theta.eta * excess
    return k0 / (1.0 + theta.mach), k0 / (1.0 - theta.mach)


def model_matrix(k_plus: np.ndarray, k_minus: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """The 3 x 2 matrices H with rows ``[exp(-j k+ d_m), exp(+j k- d_m)]``, shape ``(n, 3, 2)``.

    References
    ----------
    physics.md E.2; Jang & Ih 1998.
    """
    h = np.empty(k_plus.shape + (offsets.size, 2), dtype=complex)
    h[..., 0] = np.exp(-1j * k_plus[:, None] * offsets[None, :])
    h[..., 1] = np.exp(1j * k_minus[:, None] * offsets[None, :])
    return h


def null_vector(h: np.ndarray) -> np.ndarray:
    """Unit bilinear null vector ``n = h+ x h- / ||.||`` with ``n^T H = 0``, shape ``(n, 3)``.

    References
    ----------
    physics.md E.3.
    """
    n = np.cross(h[..., 0], h[..., 1])
    norm = np.sqrt(np.sum(np.abs(n) ** 2, axis=-1, keepdims=True))
    return n / np.maximum(norm, 1e-300)


def separation_filters(
    freqs: np.ndarray,
    theta: Theta,
    geometry: Geometry,
    excess: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares filters from the three microphone spectra to P0 and U0.

    Parameters
    ----------
    freqs : ndarray
        Frequencies in Hz, shape ``(n,)``.
    theta : Theta
        Propagation parameters.
    geometry : Geometry
        Microphone offsets and bore.
    excess : tuple of ndarray, optional
        Output of :func:`zk_excess` on ``2 pi freqs`` (recomputed when omitted).

    Returns
    -------
    g_p : ndarray
        Shape ``(n, 3)``: ``P0 = sum_m g_p[:, m] P_m`` (dimensionless).
    g_u : ndarray
        Shape ``(n, 3)``: ``U0 = sum_m g_u[:, m] P_m`` in m^3/(Pa s). Zero at DC, where
        U0 cannot be measured (physics.md E.4).

    Notes
    -----
    ``[A, B] = (H^H H)^{-1} H^H P`` (physics.md E.2). A tiny Tikhonov term (1e-12 of the
    trace) keeps the exactly singular bins finite; there the minimum-norm solution sets
    A = B, i.e. U0 = 0.
    """
    omega = 2 * np.pi * np.asarray(freqs, dtype=float)
    if excess is None:
        excess = zk_excess(omega, geometry, theta.c)
    k_p, k_m = wavenumbers(omega, theta, excess[0])
    h = model_matrix(k_p, k_m, geometry.offsets)
    hh = np.conj(np.swapaxes(h, -1, -2))
    gram = hh @ h
    reg = 1e-12 * np.real(np.trace(gram, axis1=-2, axis2=-1))
    gram[..., 0, 0] += reg
    gram[..., 1, 1] += reg
    a, b, c, d = gram[..., 0, 0], gram[..., 0, 1], gram[..., 1, 0], gram[..., 1, 1]
    det = a * d - b * c
    inv = np.empty_like(gram)
    inv[..., 0, 0] = d / det
    inv[..., 0, 1] = -b / det
    inv[..., 1, 0] = -c / det
    inv[..., 1, 1] = a / det
    pinv = inv @ hh  # (n, 2, 3): rows g_A and g_B
    air = geometry.air(theta.c)
    z0 = air.impedance(np.pi * geometry.radius**2)
    zc = z0 * (1.0 + theta.eta * excess[1])
    g_p = pinv[:, 0, :] + pinv[:, 1, :]
    g_u = (pinv[:, 0, :] - pinv[:, 1, :]) / zc[:, None]
    g_u[omega == 0] = 0.0
    return g_p, g_u


# ---------------------------------------------------------------------------------------
# Cost


@dataclass(frozen=True)
class BlockSpectra:
    """Cross-spectral statistics of one block in the estimation band.

    Attributes
    ----------
    freqs : ndarray
        Frequencies in Hz.
    s_pp : ndarray
        Cross-spectral matrices ``S[f, i, j] = E[P_i conj(P_j)]``, Pa^2/Hz, ``(n, 3, 3)``.
    weights : ndarray
        Cost weights w(omega) (1/Pa^2 Hz): mean pairwise coherence over the smoothed
        spectral envelope.
    coherence : ndarray
        Mean pairwise squared coherence per bin.
    segments : ndarray
        Scaled segment spectra ``X[s, f, m]`` with ``S = sum_s X X^H``, Pa/Hz^0.5,
        shape ``(n_segments, n, 3)``.
    noise : ndarray
        Relative noise power spectral density of the three channels, shape ``(3,)``,
        mean 1 (dimensionless). The residual of a bin is divided by the noise power it
        carries, ``n^T diag(noise) conj(n)`` (generalised least squares); equal values
        give the plain least-squares residual of physics.md E.3.
    """

    freqs: np.ndarray
    s_pp: np.ndarray
    weights: np.ndarray
    coherence: np.ndarray
    segments: np.ndarray
    noise: np.ndarray = dataclasses.field(default_factory=lambda: np.ones(3))

    @property
    def norm(self) -> float:
        """``sum w tr S``: the weighted microphone energy that normalises J."""
        return float(np.dot(self.weights, np.real(np.einsum("fii->f", self.s_pp))))


def cross_spectra(
    block: np.ndarray,
    fs: float,
    segment: int,
    fmin_hz: float,
    fmax_hz: float,
    envelope_hz: float,
    weighting: str = "coherence",
    noise: np.ndarray | None = None,
) -> BlockSpectra:
    """Welch estimate of the 3 x 3 cross-spectral matrix of a block (Hann, 50 % overlap).

    Parameters
    ----------
    block : ndarray
        Microphone pressures in Pa, shape ``(n, 3)``.
    fs : float
        Sample rate in Hz.
    segment : int
        Welch segment length in samples.
    fmin_hz, fmax_hz : float
        Band kept, Hz.
    envelope_hz : float
        Width of the running mean that gives the spectral envelope, Hz.
    weighting : {"coherence", "snr"}
        Numerator of the weights: the mean pairwise squared coherence, or the coherent-to-
        incoherent power ratio (which drops noise-dominated bins).
    noise : ndarray, optional
        Noise power spectral density of the three channels, Pa^2/Hz, shape ``(3,)``
        (:func:`noise_levels`); only the ratios matter. None: equal noise (plain least
        squares).

    Returns
    -------
    BlockSpectra
    """
    n = block.shape[0]
    segment = min(segment, n)
    hop = max(segment // 2, 1)
    starts = np.arange(0, n - segment + 1, hop)
    win = np.hanning(segment + 1)[:-1]
    segs = np.stack([block[s : s + segment] * win[:, None] for s in starts])
    # Twice the segment length: a denser grid for the same statistics, so that the
    # residual is close to the energy of the filtered signal (physics.md E.3).
    nfft = 2 * segment
    spec_ = np.fft.rfft(segs, nfft, axis=1)
    freqs = np.fft.rfftfreq(nfft, 1 / fs)
    keep = (freqs >= fmin_hz) & (freqs <= fmax_hz)
    x = spec_[:, keep, :]
    scale = 1.0 / (fs * np.sum(win**2) * len(starts))
    x = x * np.sqrt(scale)
    s_pp = np.einsum("sfi,sfj->fij", x, np.conj(x))
    diag = np.real(np.einsum("fii->fi", s_pp))
    coh = []
    for i, j in ((0, 1), (1, 2), (0, 2)):
        coh.append(np.abs(s_pp[:, i, j]) ** 2 / np.maximum(diag[:, i] * diag[:, j], 1e-300))
    coherence = np.mean(coh, axis=0)
    trace = np.sum(diag, axis=1)
    width = max(int(round(envelope_hz / (fs / nfft))), 1)
    envelope = ndimage.uniform_filter1d(trace, min(width, max(trace.size, 1)), mode="nearest")
    tiny = 1e-300 + 1e-12 * float(np.max(trace, initial=0.0))
    # "snr": coherent-to-incoherent power ratio gamma^2 / (1 - gamma^2), capped: with the envelope
    # it weights a bin by about 1 / (noise PSD) where the signal dominates (maximum
    # likelihood for white noise) and drops bins where noise dominates. There the noise
    # floor n^T D conj(n) / ||n||^2 would otherwise pull theta, because sensor noise is
    # never exactly equal in the three channels.
    if weighting == "snr":
        snr = np.minimum(coherence / np.maximum(1.0 - coherence, 1e-12), _MAX_SNR_WEIGHT)
        weights = np.maximum(snr, _MIN_COHERENCE_WEIGHT) / np.maximum(envelope, tiny)
    else:
        weights = np.maximum(coherence, _MIN_COHERENCE_WEIGHT) / np.maximum(envelope, tiny)
    rel = np.ones(3) if noise is None else _relative_noise(noise)
    return BlockSpectra(freqs[keep], s_pp, weights, coherence, x, rel)


# Quantile of the per-bin power spectrum taken as the noise floor when there is no band
# above the separation band (bins between the harmonics of a note).
_NOISE_QUANTILE = 0.2
# Relative noise levels are clipped to this range around their mean: they only reweight
# the channels, and a channel without noise (or a wrong estimate) must not take over.
_NOISE_RATIO_LIMIT = 4.0
# With weighting "noise", a bin counts when its power exceeds this multiple of the noise
# power (trace of S over the summed noise levels); noise alone gives 1 +- about 0.3.
_NOISE_RATIO_THRESHOLD = 2.0


def noise_levels(x: np.ndarray, fs: float, config: SeparationConfig) -> np.ndarray:
    """White noise power spectral density of each channel over the whole take.

    Parameters
    ----------
    x : ndarray
        Calibrated microphone pressures in Pa, shape ``(n, 3)``.
    fs : float
        Sample rate in Hz.
    config : SeparationConfig
        ``noise_fmin_hz``, the separation and estimation bands, ``welch_segment_s``.

    Returns
    -------
    ndarray
        Shape ``(3,)``, Pa^2/Hz in the scaling of the diagonal of
        :attr:`BlockSpectra.s_pp`: the median Welch power spectral density between
        ``noise_fmin_hz`` and 0.95 of the Nyquist frequency, where a played note has
        little energy left; without such a band, the ``_NOISE_QUANTILE`` quantile of the
        spectrum in the estimation band, i.e. the floor between the harmonics.

    Notes
    -----
    Sensor noise is stationary, so one level per channel for the whole take is far more
    precise than a per-block estimate (a block of 80 ms has three Welch segments). The
    levels differ between channels by the sensitivity of each microphone and by its
    relative calibration, typically by several per cent; in plain least squares that
    difference makes the noise floor of J depend on theta (see :func:`residual_cost`).
    """
    segment = min(max(int(round(config.welch_segment_s * fs)), 16), x.shape[0])
    hop = max(segment // 2, 1)
    win = np.hanning(segment + 1)[:-1]
    freqs = np.fft.rfftfreq(segment, 1 / fs)
    cross = np.zeros((freqs.size, 3, 3), dtype=complex)
    n_seg = 0
    # Running sum rather than one stacked array: a long take at 100 kHz stays small.
    for s0 in range(0, x.shape[0] - segment + 1, hop):
        spec_ = np.fft.rfft(x[s0 : s0 + segment] * win[:, None], axis=0)
        cross += spec_[:, :, None] * np.conj(spec_[:, None, :])
        n_seg += 1
    # The scaling of :func:`cross_spectra` (no factor 2 of a one-sided spectrum), so that
    # these levels compare directly with the diagonal of its ``s_pp``.
    cross *= 1.0 / (fs * np.sum(win**2) * max(n_seg, 1))
    # Incoherent part of each channel (three-channel method): the coherent power of
    # channel i is |S_ij| |S_ik| / |S_jk|, so harmonics of the note in the band (a clean
    # take) do not count as noise.
    diag = np.real(np.einsum("fii->fi", cross))
    psd = np.empty_like(diag)
    for i, j, k in ((0, 1, 2), (1, 0, 2), (2, 0, 1)):
        coh = np.abs(cross[:, i, j]) * np.abs(cross[:, i, k])
        coh = coh / np.maximum(np.abs(cross[:, j, k]), 1e-300)
        psd[:, i] = np.maximum(diag[:, i] - coh, 0.0)
    lo = config.noise_fmin_hz
    if lo is None:
        lo = 1.1 * (config.band_edge_hz + config.band_taper_hz)
    high = (freqs >= lo) & (freqs <= 0.95 * fs / 2)
    if np.any(high) and np.ptp(freqs[high]) >= 1000.0:
        return np.median(psd[high], axis=0)
    band = (freqs >= config.fmin_hz) & (freqs <= config.fmax_hz)
    if not np.any(band):
        return np.ones(3)
    return np.quantile(psd[band], _NOISE_QUANTILE, axis=0)


def noise_weighted(spectra: list[BlockSpectra], noise: np.ndarray) -> BlockSpectra:
    """Pool blocks into one cost weighted for sensor noise (maximum likelihood).

    Parameters
    ----------
    spectra : list of BlockSpectra
        Blocks on the same frequency grid.
    noise : ndarray
        Noise levels of :func:`noise_levels`, shape ``(3,)``.

    Returns
    -------
    BlockSpectra
        Summed cross-spectra and all segments. The weights are not whitened by the
        spectral envelope: with the generalised residual every bin carries noise of the
        same variance, so uniform weights are the maximum-likelihood choice and the
        strong harmonics, where theta is best resolved, dominate. Bins whose power does
        not exceed ``_NOISE_RATIO_THRESHOLD`` times the noise are dropped, because they
        only add the random, theta-dependent part of the noise floor.
    """
    s_pp = np.sum([sp.s_pp for sp in spectra], axis=0)
    segments = np.concatenate([sp.segments for sp in spectra], axis=0)
    trace = np.real(np.einsum("fii->f", s_pp)) / len(spectra)
    total = max(float(np.sum(noise)), 1e-300)
    ratio = trace / total
    signal = np.clip((ratio - _NOISE_RATIO_THRESHOLD) / np.maximum(ratio, 1e-300), 0.0, 1.0)
    weights = np.maximum(signal, _MIN_COHERENCE_WEIGHT) / total
    coherence = np.mean([sp.coherence for sp in spectra], axis=0)
    return BlockSpectra(spectra[0].freqs, s_pp, weights, coherence, segments, spectra[0].noise)


def noise_residual(spectra: BlockSpectra, noise: np.ndarray) -> float:
    """Residual J that the sensor noise alone leaves (expectation, any theta).

    With the generalised residual the noise of every bin contributes
    ``n^T N conj(n) / n^T D conj(n) = mean(noise)``, so the expected noise part of
    :func:`residual_cost` is ``mean(noise) sum w / sum w tr S``.
    """
    return float(np.mean(noise) * np.sum(spectra.weights) / max(spectra.norm, 1e-300))


def _relative_noise(noise: np.ndarray) -> np.ndarray:
    """Noise levels scaled to mean 1 and clipped to ``_NOISE_RATIO_LIMIT`` around it."""
    d = np.asarray(noise, dtype=float)
    mean = float(np.mean(d))
    if not np.all(np.isfinite(d)) or mean <= 0:
        return np.ones(3)
    return np.clip(d / mean, 1 / _NOISE_RATIO_LIMIT, _NOISE_RATIO_LIMIT)


def _null_components(
    theta: Theta, freqs: np.ndarray, geometry: Geometry, excess: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    omega = 2 * np.pi * freqs
    if excess is None:
        excess = zk_excess(omega, geometry, theta.c)[0]
    k_p, k_m = wavenumbers(omega, theta, excess)
    d = geometry.offsets
    hp = np.exp(-1j * k_p[:, None] * d[None, :])
    hm = np.exp(1j * k_m[:, None] * d[None, :])
    # n = h+ x h- written out: this is the inner loop of the optimiser, and np.cross on
    # complex arrays is several times slower.
    n0 = hp[:, 1] * hm[:, 2] - hp[:, 2] * hm[:, 1]
    n1 = hp[:, 2] * hm[:, 0] - hp[:, 0] * hm[:, 2]
    n2 = hp[:, 0] * hm[:, 1] - hp[:, 1] * hm[:, 0]
    return n0, n1, n2


def residual_vector(
    theta: Theta, spectra: BlockSpectra, geometry: Geometry, excess: np.ndarray | None = None
) -> np.ndarray:
    """Weighted per-segment, per-bin residuals whose squared norm is :func:`residual_cost`.

    ``r[s, f] = sqrt(w_f / sum w tr S) n(f)^T X_s(f) / sqrt(n(f)^T D conj(n(f)))`` with
    ``D = diag(spectra.noise)`` (complex, dimensionless).
    The least-squares form lets a Gauss-Newton method minimise J in a few iterations.
    """
    n0, n1, n2 = _null_components(theta, spectra.freqs, geometry, excess)
    d = spectra.noise
    norm = np.sqrt(d[0] * np.abs(n0) ** 2 + d[1] * np.abs(n1) ** 2 + d[2] * np.abs(n2) ** 2)
    scale = np.sqrt(spectra.weights / max(spectra.norm, 1e-300)) / np.maximum(norm, 1e-300)
    x = spectra.segments
    return (n0 * x[..., 0] + n1 * x[..., 1] + n2 * x[..., 2]) * scale


def residual_cost(
    theta: Theta, spectra: BlockSpectra, geometry: Geometry, excess: np.ndarray | None = None
) -> float:
    """Normalised least-squares residual J(theta) of predicting the microphones.

    Parameters
    ----------
    theta : Theta
        Propagation parameters.
    spectra : BlockSpectra
        Cross-spectra of the block.
    geometry : Geometry
        Microphone offsets and bore.
    excess : ndarray, optional
        Wavenumber excess of :func:`zk_excess` on the band (recomputed when omitted).

    Returns
    -------
    float
        ``sum w n^T S conj(n) / n^T D conj(n)`` divided by ``sum w tr S``, with
        ``D = diag(spectra.noise)`` of mean 1: about the fraction of the weighted
        microphone energy not explained by two waves (dimensionless).

    References
    ----------
    physics.md E.3 and E.5.
    """
    n0, n1, n2 = _null_components(theta, spectra.freqs, geometry, excess)
    s = spectra.s_pp
    a0, a1, a2 = np.abs(n0) ** 2, np.abs(n1) ** 2, np.abs(n2) ** 2
    quad = (
        a0 * s[:, 0, 0].real
        + a1 * s[:, 1, 1].real
        + a2 * s[:, 2, 2].real
        + 2
        * np.real(
            n0 * np.conj(n1) * s[:, 0, 1]
            + n0 * np.conj(n2) * s[:, 0, 2]
            + n1 * np.conj(n2) * s[:, 1, 2]
        )
    ) / np.maximum(spectra.noise @ np.array([a0, a1, a2]), 1e-300)
    return float(np.dot(spectra.weights, quad) / max(spectra.norm, 1e-300))


# ---------------------------------------------------------------------------------------
# Estimation per block


def _fixed_mach(config: SeparationConfig, geometry: Geometry, c: float) -> float | None:
    if config.mach is not None:
        return config.mach
    if config.mean_flow_m3_s is not None:
        return config.mean_flow_m3_s / (np.pi * geometry.radius**2 * c)
    return None


def estimate_theta(
    spectra: BlockSpectra,
    geometry: Geometry,
    start: Theta,
    config: SeparationConfig,
) -> tuple[Theta, float, int]:
    """Minimise J over theta for one block (bounded Gauss-Newton, trust region).

    Parameters
    ----------
    spectra : BlockSpectra
        Cross-spectra of the block.
    geometry : Geometry
        Microphone offsets and bore.
    start : Theta
        Warm start (the previous block's estimate).
    config : SeparationConfig
        Bounds and which parameters are free.

    Returns
    -------
    theta : Theta
        Estimate.
    cost : float
        J at the estimate.
    evaluations : int
        Number of residual evaluations.

    Notes
    -----
    J is a sum of squares of :func:`residual_vector`, so a trust-region least-squares
    solver converges in a few iterations where Nelder-Mead (physics.md E.5) needs about a
    hundred evaluations. The visco-thermal excess is evaluated at the start temperature
    and once more when the estimate moved by more than 0.25 degC: it changes by about
    0.4 % per degC, which the free ``eta`` would otherwise absorb.
    """
    omega = 2 * np.pi * spectra.freqs
    free_mach = _fixed_mach(config, geometry, start.c) is None
    free_eta = config.estimate_loss
    # Scaled coordinates: 1 unit is 1 m/s, 0.1 of eta, 0.001 of Mach.
    scales = [1.0] + ([0.1] if free_eta else []) + ([1e-3] if free_mach else [])
    lo = [config.c_bounds_m_s[0]] + ([config.loss_bounds[0]] if free_eta else [])
    hi = [config.c_bounds_m_s[1]] + ([config.loss_bounds[1]] if free_eta else [])
    if free_mach:
        lo.append(config.mach_bounds[0])
        hi.append(config.mach_bounds[1])
    scales_a = np.array(scales)
    lo_a, hi_a = np.array(lo) / scales_a, np.array(hi) / scales_a

    def unpack(z: np.ndarray) -> Theta:
        v = z * scales_a
        i = 1
        eta = start.eta
        if free_eta:
            eta = float(v[i])
            i += 1
        c = float(v[0])
        mach = float(v[i]) if free_mach else _fixed_mach(config, geometry, c)
        return Theta(c=c, eta=eta, mach=mach)

    total_evals = 0
    current = start
    for _ in range(3):
        excess = zk_excess(omega, geometry, current.c)[0]
        x0 = (
            [current.c]
            + ([current.eta] if free_eta else [])
            + ([current.mach] if free_mach else [])
        )
        z0 = np.clip(np.array(x0) / scales_a, lo_a + 1e-9, hi_a - 1e-9)

        def fun(z: np.ndarray, excess: np.ndarray = excess) -> np.ndarray:
            r = residual_vector(unpack(z), spectra, geometry, excess).ravel()
            return np.concatenate([r.real, r.imag])

        res = optimize.least_squares(
            fun,
            z0,
            bounds=(lo_a, hi_a),
            method="trf",
            x_scale=1.0,
            diff_step=1e-7,
            xtol=1e-10,
            ftol=1e-12,
            gtol=1e-12,
            max_nfev=config.max_evaluations,
        )
        total_evals += int(res.nfev) * (1 + z0.size)
        new = unpack(res.x)
        moved = abs(new.temperature_c - current.temperature_c)
        current = new
        if moved < 0.25:
            break
    return current, float(2 * res.cost), total_evals


def _smooth(values: np.ndarray, width: int) -> np.ndarray:
    """Centred running median, its window clipped at the ends of the track.

    A centred window follows a linear drift without lag, unlike a causal tracker, and the
    median ignores a single block thrown off by a transient (also the first or last one).
    """
    if width <= 1 or values.size < 3:
        return values.copy()
    half = width // 2
    out = np.empty_like(values)
    n = values.size
    for i in range(n):
        out[i] = np.median(values[max(i - half, 0) : i + half + 1])
    return out


# ---------------------------------------------------------------------------------------
# Stage function


def _block_layout(n: int, fs: float, block_s: float) -> tuple[int, int, np.ndarray]:
    hop = max(int(round(block_s * fs / 2)), 8)
    length = 2 * hop
    # Blocks start half a block before the signal so that the windows sum to one over
    # every sample of it.
    n_blocks = int(np.ceil(n / hop)) + 1
    starts = -hop + hop * np.arange(n_blocks)
    return hop, length, starts


def _block(x: np.ndarray, start: int, length: int) -> np.ndarray:
    out = np.zeros((length, x.shape[1]))
    lo, hi = max(start, 0), min(start + length, x.shape[0])
    if hi > lo:
        out[lo - start : hi - start] = x[lo:hi]
    return out


def _band_taper(
    freqs: np.ndarray, config: SeparationConfig, geometry: Geometry, theta: Theta
) -> np.ndarray:
    # The taper must reach zero before the first singular frequency of this block's theta
    # (physics.md E.4), which moves with temperature and flow.
    f1 = theta.c * (1 - theta.mach**2) / (2 * geometry.spacing)
    hi = min(config.band_edge_hz + config.band_taper_hz, 0.97 * f1)
    lo = min(config.band_edge_hz, hi - 0.5 * config.band_taper_hz)
    x = np.clip((freqs - lo) / (hi - lo), 0.0, 1.0)
    return 0.5 * (1 + np.cos(np.pi * x))


def _u_ramp(freqs: np.ndarray, config: SeparationConfig) -> np.ndarray:
    hi = config.u_highpass_hz
    lo = hi / 2
    x = np.clip((freqs - lo) / (hi - lo), 0.0, 1.0)
    return 0.5 * (1 - np.cos(np.pi * x))


def check_band(config: SeparationConfig, geometry: Geometry, fs: float, c: float) -> None:
    """Check that the separation band stays below the first singular frequency.

    Raises
    ------
    ValueError
        When ``band_edge_hz + band_taper_hz`` reaches ``0.98 c / (2 s)`` (physics.md E.4)
        or the Nyquist frequency.
    """
    f1 = c / (2 * geometry.spacing)
    top = config.band_edge_hz + config.band_taper_hz
    if top >= 0.98 * f1:
        raise ValueError(
            f"separation band ends at {top:g} Hz, too close to the first singular frequency "
            f"{f1:.0f} Hz of microphones {geometry.spacing * 100:.2f} cm apart; lower "
            "band_edge_hz"
        )
    if top >= fs / 2:
        raise ValueError(
            f"separation band ends at {top:g} Hz, above the Nyquist frequency {fs / 2:g} Hz"
        )


def separate(
    pressures: np.ndarray, fs: float, calibration: Calibration, config: SeparationConfig
) -> SeparationResult:
    """Separate the waves of a three-microphone take and rebuild p0, u0 at the reference plane.

    Parameters
    ----------
    pressures : ndarray
        Calibrated microphone pressures in Pa, shape ``(n, 3)``, upstream microphone first
        (the order of ``calibration.microphones``).
    fs : float
        Sample rate in Hz.
    calibration : Calibration
        Geometry, air and microphone positions.
    config : SeparationConfig
        Settings.

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
    x = np.asarray(pressures, dtype=float)
    if x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"expected pressures of shape (n, 3), got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError("pressures contain NaN or infinite samples")
    config.validate()
    geometry = Geometry.from_calibration(calibration)
    t_start = (
        calibration.air.temperature_c if config.temperature_c is None else config.temperature_c
    )
    c_start = calibration.air_properties(t_start).c
    check_band(config, geometry, fs, c_start)
    n = x.shape[0]
    hop, length, starts = _block_layout(n, fs, config.block_s)
    segment = max(int(round(config.welch_segment_s * fs)), 16)
    fixed = _fixed_mach(config, geometry, c_start)
    theta = Theta(c=c_start, eta=config.loss_scale, mach=0.0 if fixed is None else fixed)
    log.info(
        "separation: %d blocks of %.0f ms, theta %s",
        starts.size,
        1e3 * length / fs,
        "estimated per block" if config.adaptive else "fixed",
    )

    # 1. Estimate theta per block, warm-started from the previous block.
    noise = noise_levels(x, fs, config) if config.noise_model == "white" else None
    if noise is not None:
        log.info("separation: noise PSD per channel %s Pa^2/Hz", np.array2string(noise))
    spectra_list = [
        cross_spectra(
            _block(x, s, length),
            fs,
            segment,
            config.fmin_hz,
            config.fmax_hz,
            config.envelope_hz,
            config.weighting,
            noise,
        )
        for s in starts
    ]
    level = np.array([float(np.sum(np.real(np.einsum("fii->f", sp.s_pp)))) for sp in spectra_list])
    floor = np.median(level) * 10 ** (-config.min_level_db / 10)
    inside = (starts >= 0) & (starts + length <= n)
    if not np.any(inside):
        inside[:] = True  # take shorter than one block: use what there is
    # Blocks hanging over either end hold half silence and an abrupt edge; they take the
    # estimates of their neighbours.
    fitted = (
        inside & (level > max(floor, 0.0)) & np.array([sp.freqs.size >= 4 for sp in spectra_list])
    )
    raw = np.full((starts.size, 3), np.nan)
    residual = np.full(starts.size, np.nan)
    coherence = np.array(
        [float(np.mean(sp.coherence)) if sp.coherence.size else np.nan for sp in spectra_list]
    )
    evals = np.zeros(starts.size, dtype=int)
    trusted = theta
    accepted: list[float] = []
    for b, spectra in enumerate(spectra_list):
        if not fitted[b]:
            continue
        if config.adaptive:
            # Warm start from the last trusted block, so that one transient block does not
            # drag the next ones away.
            est, residual[b], evals[b] = estimate_theta(spectra, geometry, trusted, config)
            if not accepted or residual[b] <= config.max_residual_ratio * np.median(accepted):
                trusted = est
                accepted.append(residual[b])
            raw[b] = (est.c, est.eta, est.mach)
        else:
            residual[b] = residual_cost(theta, spectra, geometry)
            raw[b] = (theta.c, theta.eta, theta.mach)
        log.debug("block %d: c %.3f m/s, eta %.3f, M %.5f, J %.2e", b, *raw[b], residual[b])
    if config.adaptive and noise is not None:
        _pool_noisy_blocks(
            spectra_list, fitted, raw, residual, evals, noise, geometry, config, theta
        )
    if not np.any(fitted):
        raise ValueError(
            "no block has enough signal in the estimation band "
            f"{config.fmin_hz:g}-{config.fmax_hz:g} Hz to estimate the propagation parameters"
        )
    median_j = float(np.median(residual[fitted]))
    trust = fitted & (residual <= config.max_residual_ratio * median_j)
    if not np.any(trust):
        trust = fitted
    # Blocks that were not fitted or not trusted take the values of the nearest trusted
    # blocks.
    good = np.flatnonzero(trust)
    filled = np.column_stack(
        [np.interp(np.arange(starts.size), good, raw[good, i]) for i in range(3)]
    )
    smooth = np.column_stack([_smooth(filled[:, i], config.smooth_blocks) for i in range(3)])

    # 2. Separate every windowed block with its smoothed theta, overlap-add.
    pad = int(round(config.pad_s * fs))
    nfft = sfft.next_fast_len(length + 2 * pad, real=True)
    freqs = np.fft.rfftfreq(nfft, 1 / fs)
    band = freqs <= config.band_edge_hz + config.band_taper_hz
    fb = freqs[band]
    ramp = _u_ramp(fb, config)
    win = np.hanning(length + 1)[:-1]  # periodic Hann: shifted copies at hop sum to one
    out = np.zeros((n + 2 * (pad + length), 2))
    origin = pad + length  # index in ``out`` of sample 0
    for b, s in enumerate(starts):
        th = Theta(*smooth[b])
        g_p, g_u = separation_filters(fb, th, geometry)
        taper = _band_taper(fb, config, geometry, th)
        g_p *= taper[:, None]
        g_u *= (taper * ramp)[:, None]
        seg = np.zeros((nfft, 3))
        seg[pad : pad + length] = _block(x, s, length) * win[:, None]
        spec_ = np.fft.rfft(seg, axis=0)[band]
        y = np.zeros((freqs.size, 2), dtype=complex)
        y[band, 0] = np.sum(g_p * spec_, axis=1)
        y[band, 1] = np.sum(g_u * spec_, axis=1)
        lo = origin + s - pad
        out[lo : lo + nfft] += np.fft.irfft(y, nfft, axis=0)
    p0 = out[origin : origin + n, 0].copy()
    u0 = out[origin : origin + n, 1].copy()

    centres = (starts + hop) / fs
    table = pd.DataFrame(
        {
            "time_s": centres,
            "temperature_c": [temperature_from_sound_speed(c) for c in smooth[:, 0]],
            "c_m_s": smooth[:, 0],
            "loss_scale": smooth[:, 1],
            "mach": smooth[:, 2],
            "residual": residual,
            "coherence": coherence,
            "c_raw_m_s": raw[:, 0],
            "loss_scale_raw": raw[:, 1],
            "mach_raw": raw[:, 2],
            "evaluations": evals,
            "fitted": fitted,
            "trusted": trust,
        }
    )
    log.info(
        "separation: T %.2f..%.2f degC, eta %.3f..%.3f, M %.4f..%.4f, median J %.2e",
        table.temperature_c.min(),
        table.temperature_c.max(),
        table.loss_scale.min(),
        table.loss_scale.max(),
        table.mach.min(),
        table.mach.max(),
        float(np.nanmedian(residual)),
    )
    return SeparationResult(fs=float(fs), p0=p0, u0=u0, blocks=table, config=config)


def _pool_noisy_blocks(
    spectra_list: list[BlockSpectra],
    fitted: np.ndarray,
    raw: np.ndarray,
    residual: np.ndarray,
    evals: np.ndarray,
    noise: np.ndarray,
    geometry: Geometry,
    config: SeparationConfig,
    start: Theta,
) -> None:
    """Refit the noise-dominated blocks together, over stretches of ``pool_s`` (in place).

    The fit starts from ``start`` (the configured values), not from the blocks' own
    estimates, which noise has scattered up to the bounds.
    """
    expected = np.array([noise_residual(sp, noise) for sp in spectra_list])
    noisy = fitted & (residual <= config.pool_residual_ratio * expected)
    idx = np.flatnonzero(noisy)
    if idx.size == 0:
        return
    hop_s = config.block_s / 2
    per_pool = max(int(round(config.pool_s / hop_s)), 1)
    n_pools = max(int(round(idx.size / per_pool)), 1)
    for group in np.array_split(idx, n_pools):
        pooled = noise_weighted([spectra_list[b] for b in group], noise)
        est, _, n_eval = estimate_theta(pooled, geometry, start, config)
        raw[group] = (est.c, est.eta, est.mach)
        evals[group[0]] += n_eval
        log.info(
            "separation: %d noise-dominated blocks fitted together: T %.2f degC, eta %.3f, M %.4f",
            group.size,
            est.temperature_c,
            est.eta,
            est.mach,
        )


def fixed_config(config: SeparationConfig, mach: float = 0.0) -> SeparationConfig:
    """The non-adaptive variant of ``config``: theta held at its start values and ``mach``."""
    return replace(config, adaptive=False, mach=mach, mean_flow_m3_s=None)
