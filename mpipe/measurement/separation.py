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

Blocks are then combined by a weighted local linear regression over ``smooth_s`` seconds
with each block's information matrix (the prior counted once), which follows a linear
drift of temperature or flow without lag.

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
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd
from scipy import fft as sfft
from scipy import optimize

from mpipe.acoustics import ducts
from mpipe.acoustics.air import Air, temperature_from_sound_speed
from mpipe.core.config import Where, between, positive, spec
from mpipe.measurement.calibration import Calibration

log = logging.getLogger(__name__)

# Floor of the noise levels relative to the strongest bin of a block's microphone spectra:
# a virtual take without noise (or a 24-bit take of a loud note) would otherwise weigh the
# weakest harmonics by numerical noise far below the accuracy of any propagation model.
_NOISE_FLOOR = 1e-10
# Bin offsets over which the residuals of a Hann-windowed block on the twice zero-padded
# grid are correlated; beyond them the correlation is below 1e-3.
_CORR_BINS = 8


def _width(what: str):
    def check(v: float | None) -> str | None:
        if v is None:
            return None
        return None if v > 0 else f"expected a positive {what} or null (no prior)"

    return check


@dataclass(frozen=True)
class SeparationConfig:
    """Settings of the adaptive wave separation (physics.md E.5).

    All frequencies in Hz, times in s, speeds in m/s, temperatures in degC.
    """

    block_s: float = spec(
        "s",
        "analysis block length; blocks overlap by half (the reconstruction windows sum to one)",
        between(0.005, 2.0),
        default=0.08,
    )
    welch_segment_s: float = spec(
        "s",
        "Welch segment length of the estimate of the sensor noise levels "
        "(segments overlap by half)",
        between(0.001, 2.0),
        default=0.04,
    )
    fmin_hz: float = spec(
        "Hz", "lower edge of the band used to estimate theta", between(1.0, 1e5), default=100.0
    )
    fmax_hz: float = spec(
        "Hz",
        "upper edge of the band used to estimate theta: the plane-wave model with the "
        "calibrated microphone positions and sensitivities must hold below it (a position "
        "error dx shifts a phase by k dx and the microphone's own size averages the field, "
        "both growing with frequency while the harmonics weaken)",
        between(10.0, 1e5),
        default=4000.0,
    )
    min_snr_db: float = spec(
        "dB",
        "a bin enters the estimate when its coherent power exceeds the sensor noise power "
        "by this much (the band used is reported per block)",
        between(-20.0, 100.0),
        default=10.0,
    )
    noise_fmin_hz: float | None = spec(
        "Hz",
        "lower edge of the band above the separation band where the noise level of each "
        "channel is measured (null: 1.1 (band_edge_hz + band_taper_hz)); the band ends at "
        "0.95 of the Nyquist frequency of the recording. When it is narrower than 1 kHz the "
        "noise level is the low quantile of the spectrum in the estimation band",
        positive,
        default=None,
    )
    adaptive: bool = spec(
        "", "estimate theta per block (false: hold it at the prior values)", default=True
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
        "prior mean (and start value) of the effective temperature (null: the calibration file's)",
        between(-20.0, 60.0),
        default=None,
    )
    temperature_prior_c: float | None = spec(
        "degC",
        "standard deviation of the Gaussian prior on the effective temperature (null: none)",
        _width("temperature width"),
        default=5.0,
    )
    loss_scale: float = spec(
        "", "prior mean (and start value) of eta", between(0.1, 10.0), default=1.0
    )
    loss_prior: float | None = spec(
        "",
        "standard deviation of the Gaussian prior on eta (null: none); Zwikker-Kosten "
        "theory holds within a few per cent in smooth tubes",
        _width("width"),
        default=0.2,
    )
    mach_prior: float | None = spec(
        "",
        "standard deviation of the Gaussian prior on M about 0 (null: none); a player's "
        "breath gives |M| ~ 0.002",
        _width("width"),
        default=0.01,
    )
    mic_position_prior_m: float | None = spec(
        "m",
        "standard deviation of the Gaussian prior on the correction to the position of the "
        "middle microphone relative to the outer two, with exactly three microphones (null, "
        "or another count: hold the calibrated positions). A position error, or a delay "
        "between channels, is frequency-linear in phase and otherwise biases the "
        "temperature; it is identifiable from the data because the temperature scales both "
        "spacings alike and this correction moves them oppositely",
        _width("width"),
        default=5e-4,
    )
    mic_position_bounds_m: tuple[float, ...] = spec(
        "m", "bounds of the position correction of the middle microphone", default=(-2e-3, 2e-3)
    )
    temperature_bounds_c: tuple[float, ...] = spec(
        "degC", "lower and upper bound of the effective temperature", default=(-10.0, 50.0)
    )
    loss_bounds: tuple[float, ...] = spec("", "bounds of eta", default=(0.3, 3.0))
    mach_bounds: tuple[float, ...] = spec("", "bounds of M", default=(-0.02, 0.05))
    min_level_db: float = spec(
        "dB",
        "blocks whose energy in the estimation band lies more than this below the median "
        "block are not fitted (silence, fades)",
        between(0.0, 200.0),
        default=30.0,
    )
    max_residual_ratio: float = spec(
        "",
        "fitted blocks whose residual per term (chi^2 / terms) exceeds this multiple of the "
        "median (onsets, clicks: the stationary two-wave model does not hold) are left out "
        "of the smoother",
        between(1.0, 1e6),
        default=4.0,
    )
    smooth_s: float = spec(
        "s",
        "half-width of the tricube kernel of the local linear regression that combines the "
        "blocks' estimates (weighted by their information; twice as wide at the ends of the "
        "take); a linear drift is followed without bias, changes faster than about this "
        "time are smoothed (air temperature and mean flow change over seconds)",
        between(0.0, 1e4),
        default=1.0,
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
        if self.mach is not None and self.mean_flow_m3_s is not None:
            raise where.error("mach", "give either mach or mean_flow_m3_s, not both")
        for key, b in (
            ("temperature_bounds_c", self.temperature_bounds_c),
            ("loss_bounds", self.loss_bounds),
            ("mach_bounds", self.mach_bounds),
            ("mic_position_bounds_m", self.mic_position_bounds_m),
        ):
            if len(b) != 2 or not b[0] < b[1]:
                raise where.error(key, f"expected [lower, upper] with lower < upper, got {b}")
        lo, hi = self.temperature_bounds_c
        if lo < -20.0 or hi > 60.0:
            raise where.error("temperature_bounds_c", "expected bounds within -20..60 degC")

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


@dataclass(frozen=True)
class Geometry:
    """What the separation needs from a calibration.

    Attributes
    ----------
    offsets : ndarray
        Microphone positions relative to the reference plane, m, shape ``(N,)``, N >= 2.
    radius : float
        Radius of the main bore at the microphones, m.
    losses : str
        Loss model of :mod:`mpipe.acoustics.ducts`.
    air_model : str
        Air model name for :func:`mpipe.acoustics.air.air_properties`.
    calibration : Calibration
        The calibration (air model, humidity, CO2).
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

    def temperature(self, c: float) -> float:
        """Effective temperature in degC at which the calibration's air has sound speed c."""
        a = self.calibration.air
        return temperature_from_sound_speed(c, a.model, a.humidity, a.co2_fraction)

    def sound_speed(self, temperature_c: float) -> float:
        """Sound speed in m/s of the calibration's air at ``temperature_c`` degC."""
        return self.calibration.air_properties(temperature_c).c

    def air(self, c: float) -> Air:
        """Air at the effective temperature whose sound speed (calibration's model) is c."""
        t = float(np.clip(self.temperature(c), -19.9, 59.9))
        return self.calibration.air_properties(t)

    def corrected(self, dx: float) -> Geometry:
        """The geometry with the middle microphone moved by ``dx`` metres (+x: downstream)."""
        if dx == 0.0:
            return self
        offsets = self.offsets.copy()
        offsets[int(np.argsort(self.offsets)[1])] += dx
        return replace(self, offsets=offsets)

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
        One row per block, see :data:`BLOCK_COLUMNS`.
    config : SeparationConfig
        The settings used.
    noise_psd : ndarray
        One-sided power spectral density of the white sensor noise of each microphone,
        Pa^2/Hz, shape ``(N,)`` (as measured, before the numerical floor).
    geometry : Geometry
        Microphones and bore used, with the median position correction of the middle
        microphone.
    """

    fs: float
    p0: np.ndarray
    u0: np.ndarray
    blocks: pd.DataFrame
    config: SeparationConfig
    noise_psd: np.ndarray
    geometry: Geometry

    def temperature_track(self) -> np.ndarray:
        """Effective temperature in degC at every sample (linear between block centres)."""
        t = np.arange(self.p0.size) / self.fs
        b = self.blocks
        return np.interp(t, b["time_s"].to_numpy(), b["temperature_c"].to_numpy())

    def median_theta(self) -> Theta:
        """The median of the smoothed parameters over the blocks."""
        b = self.blocks
        return Theta(
            float(np.median(b["c_m_s"])),
            float(np.median(b["loss_scale"])),
            float(np.median(b["mach"])),
        )

    def bound_warnings(self) -> list[str]:
        """One line per parameter whose per-block estimate sat on a bound."""
        out = []
        hits = self.blocks["at_bound"].fillna("").astype(str)
        for name in _NAMES:
            count = int(hits.str.contains(name).sum())
            if count:
                out.append(
                    f"{name} estimate on its bound in {count} of {int(self.blocks.fitted.sum())}"
                    " fitted blocks (see blocks.csv, column at_bound)"
                )
        return out


#: Columns of :attr:`SeparationResult.blocks` with their meaning.
BLOCK_COLUMNS = {
    "time_s": "block centre, s",
    "temperature_c": "smoothed effective temperature used for the reconstruction, degC",
    "temperature_se_c": "its standard error, degC",
    "c_m_s": "sound speed of the calibration's air at that temperature, m/s",
    "loss_scale": "smoothed eta used for the reconstruction",
    "loss_scale_se": "its standard error",
    "mach": "smoothed Mach number used for the reconstruction",
    "mach_se": "its standard error",
    "temperature_raw_c": "this block's own estimate (with the prior), degC; NaN if not fitted",
    "temperature_raw_se_c": "its standard error from the Gauss-Newton curvature, degC",
    "loss_scale_raw": "this block's eta",
    "loss_scale_raw_se": "its standard error",
    "mach_raw": "this block's Mach number",
    "mach_raw_se": "its standard error",
    "mic_position_m": "smoothed correction to the middle microphone's position, m",
    "mic_position_se_m": "its standard error, m",
    "mic_position_raw_m": "this block's own correction, m",
    "at_bound": "parameters whose estimate sits on a bound (a warning), ';'-separated",
    "band_lo_hz": "lowest frequency of the bins used, Hz",
    "band_hi_hz": "highest frequency of the bins used, Hz",
    "bins": "number of bins used (signal over noise by min_snr_db, in fmin_hz..fmax_hz)",
    "residual": "chi^2 per term at the estimate (about 1 when noise explains the misfit)",
    "kappa": "variance inflation from correlated bins",
    "snr_db": "median signal-to-noise ratio of the bins used, dB",
    "evaluations": "residual evaluations of the solver",
    "fitted": "false for blocks over the ends, below min_level_db or without enough bins",
    "trusted": "fitted and residual within max_residual_ratio of the median: enters the smoother",
    "theta": "'estimated' or why theta was held ('held: two microphones, no redundancy', "
    "'held: adaptive false')",
}


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
    """The N x 2 matrices H with rows ``[exp(-j k+ d_m), exp(+j k- d_m)]``, shape ``(n, N, 2)``.

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
    """Least-squares filters from the N >= 2 microphone spectra to P0 and U0.

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
        Shape ``(n, N)``: ``P0 = sum_m g_p[:, m] P_m`` (dimensionless).
    g_u : ndarray
        Shape ``(n, N)``: ``U0 = sum_m g_u[:, m] P_m`` in m^3/(Pa s). Zero at DC, where
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
    pinv = inv @ hh  # (n, 2, N): rows g_A and g_B; with N = 2 the exact inverse of H
    air = geometry.air(theta.c)
    z0 = air.impedance(np.pi * geometry.radius**2)
    zc = z0 * (1.0 + theta.eta * excess[1])
    g_p = pinv[:, 0, :] + pinv[:, 1, :]
    g_u = (pinv[:, 0, :] - pinv[:, 1, :]) / zc[:, None]
    g_u[omega == 0] = 0.0
    return g_p, g_u


def projection_residual(pressures: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Part of the microphone spectra that two plane waves cannot explain, any number >= 2.

    Parameters
    ----------
    pressures : ndarray
        Microphone spectra ``P`` (Pa), shape ``(n, n_mics)``.
    h : ndarray
        Model matrices of :func:`model_matrix`, shape ``(n, n_mics, 2)``.

    Returns
    -------
    ndarray
        ``P - H H^+ P``, shape ``(n, n_mics)``: zero for two microphones (the exact
        solution, wherever H is regular) and for a field of two plane waves; for three
        microphones its squared norm is ``|n^T P|^2 / ||n||^2`` with the null vector
        ``n = h+ x h-`` (physics.md E.3), which generalises to more microphones.
    """
    hh = np.conj(np.swapaxes(h, -1, -2))
    ab = np.linalg.solve(hh @ h, hh @ pressures[..., None])
    return pressures - (h @ ab)[..., 0]


def singular_frequencies(geometry: Geometry, theta: Theta, fmax_hz: float) -> np.ndarray:
    """Frequencies (Hz, up to ``fmax_hz``) where the microphones cannot tell the waves apart.

    ``H`` loses rank where ``exp(j (k+ + k-) (d_i - d_j)) = 1`` for every pair of
    microphones, i.e. (lossless) at ``f = n c (1 - M^2) / (2 s_ij)`` for all spacings
    ``s_ij`` at once. Two microphones ``s`` apart are singular at every multiple of
    ``c (1 - M^2) / (2 s)``; with three or more, only where the spacings are commensurate
    (equal spacings ``s``: at multiples of ``c (1 - M^2) / (2 s)`` still).

    Returns
    -------
    ndarray
        The singular frequencies in Hz, increasing (possibly empty).
    """
    d = np.sort(geometry.offsets)
    spacings = np.abs(d[:, None] - d[None, :])[np.triu_indices(d.size, 1)]
    base = theta.c * (1 - theta.mach**2) / 2.0
    first = base / spacings[0]
    out = []
    for n in range(1, int(fmax_hz / first) + 1):
        f = n * first
        m = f * spacings / base
        if np.all(np.abs(m - np.round(m)) < 1e-6 * np.maximum(m, 1.0)):
            out.append(f)
    return np.array(out)


# ---------------------------------------------------------------------------------------
# Spectra and noise


# Context taken on each side of a block before the null filter is applied, s: longer than
# the filter's impulse response (the delays between microphones, ~0.1 ms, and the tails of
# the visco-thermal terms), so that the residual inside the block is an exact filtering.
_FILTER_MARGIN_S = 0.005


@dataclass(frozen=True)
class BlockSpectra:
    """One block prepared for the estimation: its spectra and the residual filter grid.

    Attributes
    ----------
    freqs : ndarray
        Frequencies in Hz of the estimation bins (``fmin_hz..fmax_hz`` on the grid of the
        windowed residual, an FFT of ``nfft_out`` = twice the block).
    bins : ndarray
        Integer index of each estimation bin on that grid.
    mic_power : ndarray
        ``|X_m(f)|^2`` of the Hann-windowed microphone signals at the estimation bins,
        scaled as :func:`noise_levels` (Pa^2/Hz), shape ``(n, N)``.
    model_freqs : ndarray
        Frequencies (Hz) where the null filter is evaluated, on the grid of ``nfft_in``.
    model_taper : ndarray
        Raised-cosine taper of the null filter over ``model_freqs`` (1 inside the band).
    spectra : ndarray
        Spectra of the unwindowed block with its context on each side, zero-padded, at
        ``model_freqs`` (unnormalised FFT, Pa), shape ``(n_model, N)``.
    window : ndarray
        Periodic Hann window of the block at the reduced rate ``fs / dec``.
    margin : int
        Samples of context on each side at the reduced rate.
    nfft_in, nfft_out : int
        Lengths of the inverse FFT of the residual and of the windowed FFT, at the
        reduced rate.
    fs : float
        Sample rate, Hz.
    scale : float
        Normalisation of the windowed residual to unit noise variance.
    """

    freqs: np.ndarray
    bins: np.ndarray
    mic_power: np.ndarray
    model_freqs: np.ndarray
    model_taper: np.ndarray
    model_index: np.ndarray
    spectra: np.ndarray
    window: np.ndarray
    margin: int
    nfft_in: int
    nfft_out: int
    fs: float
    scale: float = 1.0

    @property
    def hop(self) -> int:
        """Hop between segments (one segment per block), samples."""
        return self.window.size

    @property
    def nfft(self) -> int:
        """FFT length of the windowed residual."""
        return self.nfft_out

    def use(self, noise: np.ndarray, min_snr_db: float) -> np.ndarray:
        """Bins whose coherent power exceeds the noise power by ``min_snr_db`` (bool)."""
        total = float(np.sum(noise))
        trace = np.sum(self.mic_power, axis=1)
        return trace - total >= 10 ** (min_snr_db / 10) * total

    def residual(self, w: np.ndarray, use: np.ndarray) -> np.ndarray:
        """Windowed spectra of the residual signals ``sum_m w_mk * p_m`` at the used bins.

        ``w`` (shape ``(n_model, N, K)``) holds the K = N - 2 noise-whitened null filters
        at ``model_freqs`` (:func:`_null_weights`); the result is the K residual spectra,
        one after the other (component-major), shape ``(K * sum(use),)``. The
        filter is applied to the unwindowed block with context, and the window only
        afterwards, so that a harmonic between two bins is cancelled exactly at the true
        parameters (filtering the windowed segments instead evaluates the model at the
        bin frequency, not at the harmonic's, a bias of the order of the bin width over
        the harmonic's frequency). The residual signal is band-limited by the filter's
        taper, so it is formed at ``fs / decimation`` (exactly, not an approximation).
        Scaled to unit variance for white noise.
        """
        e = np.sum(w * self.spectra[:, :, None], axis=1) * self.model_taper[:, None]
        full = np.zeros((self.nfft_in // 2 + 1, e.shape[1]), dtype=complex)
        full[self.model_index] = e
        sig = sfft.irfft(full, self.nfft_in, axis=0)[self.margin : self.margin + self.window.size]
        out = sfft.rfft(sig * self.window[:, None], self.nfft_out, axis=0)[self.bins[use]]
        return (out * self.scale).T.reshape(-1)


def _taper(f: np.ndarray, lo0: float, lo1: float, hi0: float, hi1: float) -> np.ndarray:
    up = np.clip((f - lo0) / max(lo1 - lo0, 1e-9), 0.0, 1.0)
    down = np.clip((hi1 - f) / max(hi1 - hi0, 1e-9), 0.0, 1.0)
    return 0.25 * (1 - np.cos(np.pi * up)) * (1 - np.cos(np.pi * down))


def cross_spectra(
    block: np.ndarray,
    fs: float,
    fmin_hz: float,
    fmax_hz: float,
    margin: int = 0,
    f_singular_hz: float | None = None,
) -> BlockSpectra:
    """Prepare a block for the estimation (see :class:`BlockSpectra`).

    Parameters
    ----------
    block : ndarray
        Microphone pressures in Pa, shape ``(length + 2 margin, N)``: the block with
        ``margin`` samples of context on each side.
    fs : float
        Sample rate in Hz.
    fmin_hz, fmax_hz : float
        Estimation band, Hz.
    margin : int
        Context samples on each side.
    f_singular_hz : float, optional
        First singular frequency of the microphone spacing, Hz: the null filter's taper
        ends below 0.9 of it.

    Returns
    -------
    BlockSpectra
    """
    lo0, lo1 = 0.5 * fmin_hz, 0.8 * fmin_hz
    hi1 = 1.2 * fmax_hz + 200.0
    cap = 0.45 * fs if f_singular_hz is None else min(0.9 * f_singular_hz, 0.45 * fs)
    hi1 = min(hi1, cap)
    hi0 = min(fmax_hz + 100.0, 0.5 * (fmax_hz + hi1))
    # The residual signal holds nothing above hi1: it is formed at fs / dec, with a
    # Nyquist frequency at least 1.25 hi1 (the window widens its spectrum a little).
    dec = max(int(fs // (2.5 * hi1)), 1)
    skip = margin % dec
    block = block[skip:]
    margin -= skip
    total = block.shape[0]
    length = (total - 2 * margin) // dec * dec
    win_full = np.hanning(length + 1)[:-1]
    nfft_out = 2 * length
    f_out = np.fft.rfftfreq(nfft_out, 1 / fs)
    keep = (f_out >= fmin_hz) & (f_out <= fmax_hz)
    xw = sfft.rfft(block[margin : margin + length] * win_full[:, None], nfft_out, axis=0)[keep]
    power = np.abs(xw) ** 2 / (fs * np.sum(win_full**2))
    n_small = sfft.next_fast_len(-(-2 * total // dec), real=True)
    nfft_in = n_small * dec
    f_in = np.fft.rfftfreq(nfft_in, 1 / fs)
    model = (f_in > lo0) & (f_in < hi1)
    spec_ = sfft.rfft(block, nfft_in, axis=0)[model]
    win = np.hanning(length // dec + 1)[:-1]
    return BlockSpectra(
        freqs=f_out[keep],
        bins=np.flatnonzero(keep),
        mic_power=power,
        model_freqs=f_in[model],
        model_taper=_taper(f_in[model], lo0, lo1, hi0, hi1),
        model_index=np.flatnonzero(model),
        spectra=spec_,
        window=win,
        margin=margin // dec,
        nfft_in=n_small,
        nfft_out=nfft_out // dec,
        fs=float(fs),
        scale=float(1.0 / np.sqrt(fs * dec * np.sum(win**2))),
    )


# Quantile of the per-bin power spectrum taken as the noise floor when there is no band
# above the separation band (bins between the harmonics of a note).
_NOISE_QUANTILE = 0.2


def noise_levels(
    x: np.ndarray, fs: float, config: SeparationConfig, band_limit_hz: float | None = None
) -> np.ndarray:
    """White noise power spectral density of each channel over the whole take.

    Parameters
    ----------
    x : ndarray
        Calibrated microphone pressures in Pa, shape ``(n, N)``, N >= 2.
    fs : float
        Sample rate in Hz.
    config : SeparationConfig
        ``noise_fmin_hz``, the separation and estimation bands, ``welch_segment_s``.
    band_limit_hz : float, optional
        Highest frequency the recording holds, Hz: the Nyquist frequency of the file when
        the take was resampled to a higher rate (default ``fs / 2``).

    Returns
    -------
    ndarray
        Shape ``(N,)``, Pa^2/Hz in the scaling of the diagonal of
        :attr:`BlockSpectra.mic_power` (two-sided: the one-sided PSD is twice this): the
        median incoherent power spectral density between ``noise_fmin_hz`` and 0.95 of
        ``band_limit_hz``, where a played note has little energy left; without such a band,
        the ``_NOISE_QUANTILE`` quantile of the spectrum in the estimation band, i.e. the
        floor between the harmonics.

    Notes
    -----
    Sensor noise is stationary, so one level per channel for the whole take is far more
    precise than a per-block estimate. It is assumed white: where it is not, the weights
    of the estimate are off by the ratio of the noise in the estimation band to the noise
    measured, which moves the standard errors, not the minimum.
    """
    segment = min(max(int(round(config.welch_segment_s * fs)), 16), x.shape[0])
    hop = max(segment // 2, 1)
    win = np.hanning(segment + 1)[:-1]
    freqs = np.fft.rfftfreq(segment, 1 / fs)
    n_mics = x.shape[1]
    cross = np.zeros((freqs.size, n_mics, n_mics), dtype=complex)
    n_seg = 0
    # Running sum rather than one stacked array: a long take at 100 kHz stays small.
    for s0 in range(0, x.shape[0] - segment + 1, hop):
        spec_ = np.fft.rfft(x[s0 : s0 + segment] * win[:, None], axis=0)
        cross += spec_[:, :, None] * np.conj(spec_[:, None, :])
        n_seg += 1
    cross *= 1.0 / (fs * np.sum(win**2) * max(n_seg, 1))
    # Incoherent part of each channel (three-channel method, with the two nearest other
    # channels j, k): the coherent power of channel i is |S_ij| |S_ik| / |S_jk|, so
    # harmonics of the note in the band (a clean take) do not count as noise. With two
    # channels it is |S_12| sqrt(S_ii / S_jj), exact when both channels have the same
    # signal-to-noise ratio (the microphones are a few cm apart in one field).
    diag = np.real(np.einsum("fii->fi", cross))
    psd = np.empty_like(diag)
    # Only bins where all pairs are clearly coherent carry signal: for independent
    # noise, |S_ij|^2 / (S_ii S_jj) of n averages is about 1 / n, and subtracting that
    # random coherent part everywhere would bias the noise level low by ~20 %.
    pairs = [(i, j) for i in range(n_mics) for j in range(i + 1, n_mics)]
    gamma2 = [
        np.abs(cross[:, i, j]) ** 2 / np.maximum(diag[:, i] * diag[:, j], 1e-300) for i, j in pairs
    ]
    signal = np.min(gamma2, axis=0) > 5.0 / max(n_seg, 1)
    for i in range(n_mics):
        others = sorted((j for j in range(n_mics) if j != i), key=lambda j: (abs(j - i), j))
        if n_mics == 2:
            j = others[0]
            coh = np.abs(cross[:, i, j]) * np.sqrt(diag[:, i] / np.maximum(diag[:, j], 1e-300))
        else:
            j, k = others[:2]
            coh = np.abs(cross[:, i, j]) * np.abs(cross[:, i, k])
            coh = coh / np.maximum(np.abs(cross[:, j, k]), 1e-300)
        psd[:, i] = np.maximum(diag[:, i] - np.where(signal, coh, 0.0), 0.0)
    lo = config.noise_fmin_hz
    if lo is None:
        lo = 1.1 * (config.band_edge_hz + config.band_taper_hz)
    top = fs / 2 if band_limit_hz is None else min(band_limit_hz, fs / 2)
    high = (freqs >= lo) & (freqs <= 0.95 * top)
    if np.any(high) and np.ptp(freqs[high]) >= 1000.0:
        return np.median(psd[high], axis=0)
    band = (freqs >= config.fmin_hz) & (freqs <= config.fmax_hz)
    if not np.any(band):
        return np.ones(n_mics)
    return np.quantile(psd[band], _NOISE_QUANTILE, axis=0)


def window_correlation(spectra: BlockSpectra) -> dict[int, np.ndarray]:
    """Correlation of white noise between the bins of a windowed block spectrum.

    Returns
    -------
    dict
        Bin offset ``df`` to ``E[X(f) conj(X(f + df))] / E|X|^2`` for white noise: for a
        window ``w`` on a grid of ``N`` bins, ``sum_n w[n]^2 exp(2 pi j df n / N) /
        sum_n w[n]^2`` (the same for every bin).
    """
    w = spectra.window
    n = np.arange(w.size)
    norm = float(np.sum(w**2))
    return {
        df: complex(np.sum(w**2 * np.exp(2j * np.pi * df * n / spectra.nfft_out)) / norm)
        for df in range(-_CORR_BINS, _CORR_BINS + 1)
    }


# ---------------------------------------------------------------------------------------
# Cost


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


def _fixed_mach(config: SeparationConfig, geometry: Geometry, c: float) -> float | None:
    if config.mach is not None:
        return config.mach
    if config.mean_flow_m3_s is not None:
        return config.mean_flow_m3_s / (np.pi * geometry.radius**2 * c)
    return None


def _null_weights(
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
    w = _null_weights(theta, spectra.model_freqs, geometry, excess, noise)
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


# ---------------------------------------------------------------------------------------
# Estimation per block


@dataclass(frozen=True)
class Prior:
    """Gaussian prior on (T, eta, M) and which of them are free.

    Attributes
    ----------
    mean : ndarray
        Prior means: temperature (degC), eta, Mach number, position correction of the
        middle microphone (m).
    width : ndarray
        Standard deviations (inf: no prior).
    lower, upper : ndarray
        Bounds.
    free : ndarray
        Boolean, which parameters are estimated.
    """

    mean: np.ndarray
    width: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    free: np.ndarray

    @property
    def information(self) -> np.ndarray:
        """Prior information matrix of the free parameters."""
        w = self.width[self.free]
        return np.diag(np.where(np.isfinite(w), 1.0 / w**2, 0.0))

    @classmethod
    def from_config(
        cls, config: SeparationConfig, t0: float, free_mach: bool, n_mics: int = 3
    ) -> Prior:
        """Build the prior of a configuration around the start temperature ``t0`` degC.

        The position correction of the middle microphone is free only with ``n_mics`` = 3
        (and a ``mic_position_prior_m``); with more microphones the positions are held.
        """

        def wid(v: float | None) -> float:
            return np.inf if v is None else float(v)

        bounds = (
            config.temperature_bounds_c,
            config.loss_bounds,
            config.mach_bounds,
            config.mic_position_bounds_m,
        )
        return cls(
            mean=np.array([t0, config.loss_scale, 0.0, 0.0]),
            width=np.array(
                [
                    wid(config.temperature_prior_c),
                    wid(config.loss_prior),
                    wid(config.mach_prior),
                    wid(config.mic_position_prior_m),
                ]
            ),
            lower=np.array([b[0] for b in bounds]),
            upper=np.array([b[1] for b in bounds]),
            free=np.array(
                [
                    True,
                    config.estimate_loss,
                    free_mach,
                    config.mic_position_prior_m is not None and n_mics == 3,
                ]
            ),
        )


@dataclass(frozen=True)
class BlockEstimate:
    """The estimate of one block.

    Attributes
    ----------
    values : ndarray
        Temperature (degC), eta, Mach number, position correction of the middle microphone
        (m); fixed ones at their held values.
    cov : ndarray
        Posterior covariance of the free parameters (data and prior).
    data_information : ndarray
        Information matrix of the data alone (without the prior), free parameters.
    residual : float
        chi^2 per term at the estimate.
    kappa : float
        Variance inflation from correlated residual terms.
    at_bound : tuple of str
        Names of the parameters on a bound.
    evaluations : int
        Residual evaluations.
    """

    values: np.ndarray
    cov: np.ndarray
    data_information: np.ndarray
    residual: float
    kappa: float
    at_bound: tuple[str, ...]
    evaluations: int


_NAMES = ("temperature", "eta", "mach", "position")
# Solver scales: 1 degC, 0.1 of eta, 1e-3 of Mach, 0.1 mm.
_SCALES = np.array([1.0, 0.1, 1e-3, 1e-4])


def _fixed_mach_t(config: SeparationConfig, geometry: Geometry, t: float) -> float | None:
    return _fixed_mach(config, geometry, geometry.sound_speed(t))


def estimate_block(
    spectra: BlockSpectra,
    use: np.ndarray,
    noise: np.ndarray,
    geometry: Geometry,
    start: np.ndarray,
    prior: Prior,
    config: SeparationConfig,
    corr: dict | None = None,
    kappa_start: float = 1.0,
) -> BlockEstimate:
    """Maximum a posteriori (T, eta, M) of one block (bounded Gauss-Newton, trust region).

    Parameters
    ----------
    spectra : BlockSpectra
        Segment spectra of the block.
    use : ndarray
        Bins entering the estimate (bool over ``spectra.freqs``).
    noise : ndarray
        Noise levels of the N >= 3 channels (:func:`noise_levels`), floored.
    geometry : Geometry
        Microphone offsets and bore.
    start : ndarray
        Start values (degC, -, -).
    prior : Prior
        Prior means, widths, bounds and the free parameters.
    config : SeparationConfig
        ``max_evaluations``, the held Mach number.
    corr : dict, optional
        :func:`window_correlation` of the block (computed when omitted).
    kappa_start : float
        First guess of ``kappa`` (the previous block's: it depends mostly on the window,
        so the fit is rarely repeated).

    Returns
    -------
    BlockEstimate

    Notes
    -----
    The real residual vector is ``[sqrt(2 / kappa) Re r, sqrt(2 / kappa) Im r,
    (theta - mean) / width]``, so that half its squared norm is the negative log posterior
    and the inverse Gauss-Newton matrix its covariance. ``kappa`` is found from the
    sandwich ``(2 Re G^H C G)`` against ``(2 Re G^H G)`` at the estimate, ``C`` the
    correlation of the residual terms (:func:`window_correlation`), and the fit is
    repeated once with it. The visco-thermal excess is evaluated at the start
    temperature and again when the estimate moved by more than 0.25 degC: it changes by
    about 0.4 % per degC, which the free ``eta`` would otherwise absorb.
    """
    omega = 2 * np.pi * spectra.model_freqs
    free = prior.free
    idx = np.flatnonzero(free)
    scales = _SCALES[idx]
    lo = prior.lower[idx] / scales
    hi = prior.upper[idx] / scales
    info_prior = prior.information
    has_prior = np.isfinite(prior.width[idx])
    if corr is None:
        corr = window_correlation(spectra)

    def values(z: np.ndarray) -> np.ndarray:
        v = np.array(start, dtype=float)
        v[idx] = z * scales
        held = _fixed_mach_t(config, geometry, v[0])
        if not free[2]:
            v[2] = held if held is not None else start[2]
        return v

    def theta_of(v: np.ndarray) -> Theta:
        return Theta(geometry.sound_speed(float(v[0])), float(v[1]), float(v[2]))

    def geometry_of(v: np.ndarray) -> Geometry:
        return geometry.corrected(float(v[3]))

    current = values(np.clip(np.asarray(start)[idx] / scales, lo, hi))
    kappa = float(kappa_start)
    evals = 0
    res = None
    # N - 2 residual components per used bin
    m = int(np.sum(use)) * max(geometry.offsets.size - 2, 1)
    excess = zk_excess(omega, geometry, geometry.sound_speed(current[0]))[0]
    for _ in range(4):
        z0 = np.clip(current[idx] / scales, lo + 1e-9, hi - 1e-9)
        kappa_fit = kappa

        def fun(z, excess=excess, kappa=kappa_fit):
            v = values(z)
            g = geometry_of(v)
            w = _null_weights(theta_of(v), spectra.model_freqs, g, excess, noise)
            r = np.sqrt(2.0 / kappa) * spectra.residual(w, use)
            pr = ((v[idx] - prior.mean[idx]) / prior.width[idx])[has_prior]
            return np.concatenate([r.real, r.imag, pr])

        res = optimize.least_squares(
            fun,
            z0,
            bounds=(lo, hi),
            method="trf",
            x_scale=1.0,
            diff_step=1e-7,
            # half the cost is the negative log-likelihood: a change of 1e-8 of it, or a
            # step of 1e-6 of a scale unit, is far below one standard error
            xtol=1e-6,
            ftol=1e-8,
            gtol=1e-8,
            max_nfev=config.max_evaluations,
        )
        evals += int(res.nfev) * (1 + z0.size)
        new = values(res.x)
        moved = abs(new[0] - current[0])
        current = new
        # kappa from the sandwich at this estimate (Jacobian per natural unit)
        jac = np.asarray(res.jac)[: 2 * m] / scales[None, :]
        g = (jac[:m] + 1j * jac[m:]) * np.sqrt(kappa_fit / 2.0)
        kappa = _kappa(g, use, corr, prior, idx)
        if moved >= 0.25:
            excess = zk_excess(omega, geometry, geometry.sound_speed(current[0]))[0]
        elif abs(kappa - kappa_fit) <= 0.1 * kappa_fit:
            break
    jac = np.asarray(res.jac)[: 2 * m] / scales[None, :]
    # data information with the final kappa (the Jacobian carries 1 / kappa_fit)
    info_data = (jac.T @ jac) * (kappa_fit / kappa)
    cov = np.linalg.pinv(info_data + info_prior)
    chi2 = float(np.sum(res.fun[: 2 * m] ** 2) / 2.0 * kappa_fit / max(m, 1))
    at = tuple(
        _NAMES[i]
        for j, i in enumerate(idx)
        if min(current[i] - prior.lower[i], prior.upper[i] - current[i])
        <= 1e-6 * max(prior.upper[i] - prior.lower[i], 1e-12)
    )
    return BlockEstimate(current, cov, info_data, chi2, kappa, at, evals)


def _kappa(g: np.ndarray, use: np.ndarray, corr: dict, prior: Prior, idx: np.ndarray) -> float:
    """Variance inflation of correlated residual terms (sandwich over naive), >= 1.

    ``g[f, p]`` is the derivative of the unit-variance residual at the used bins (the
    K components one after the other, as :meth:`BlockSpectra.residual`; the components
    are uncorrelated, the bins of one component correlated by the window).
    """
    p = g.shape[1]
    m = int(np.sum(use))
    naive = np.zeros((p, p))
    sand = np.zeros((p, p))
    n_f = use.size
    for comp in range(g.shape[0] // max(m, 1)):
        full = np.zeros((use.size, p), dtype=complex)
        full[use] = g[comp * m : (comp + 1) * m]
        naive += 2 * np.real(np.conj(full).T @ full)
        for df, c in corr.items():
            f0, f1 = max(0, -df), min(n_f, n_f - df)
            if f1 <= f0:
                continue
            # E[r_i conj(r_j)] = c for j = i + df: G^H C G sums conj(G_i) C_ij G_j
            sand += 2 * np.real(c * (np.conj(full[f0:f1]).T @ full[f0 + df : f1 + df]))
    # Summarise the matrix ratio by a trace weighted with the prior variances (unit-free).
    w = np.where(np.isfinite(prior.width[idx]), prior.width[idx] ** 2, _SCALES[idx] ** 2)
    num = float(np.sum(np.diag(sand) * w))
    den = float(np.sum(np.diag(naive) * w))
    if not den > 0:
        return 1.0
    return float(max(num / den, 1.0))


# ---------------------------------------------------------------------------------------
# Combination of the blocks


def smooth_blocks(
    times: np.ndarray,
    estimates: list[BlockEstimate | None],
    prior: Prior,
    half_width_s: float,
) -> tuple[np.ndarray, np.ndarray]:
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

    Returns
    -------
    values : ndarray
        Shape ``(n_blocks, 4)``: temperature (degC), eta, Mach number, position correction
        of the middle microphone (m).
    se : ndarray
        Shape ``(n_blocks, 4)``: their standard errors (0 for held parameters).

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
        return out, se
    info_p = prior.information
    mu0 = prior.mean[idx]
    hs, infos, ts = [], [], []
    for j, e in enumerate(estimates):
        if e is None:
            continue
        i_j = e.data_information
        post = np.linalg.pinv(e.cov)
        hs.append(post @ e.values[idx] - info_p @ mu0)
        infos.append(i_j)
        ts.append(times[j])
    if not infos:
        out[:, idx] = mu0
        return out, se
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
    lo, hi = prior.lower, prior.upper
    out = np.clip(out, lo, hi)
    return out, se


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
    pressures: np.ndarray,
    fs: float,
    calibration: Calibration,
    config: SeparationConfig,
    band_limit_hz: float | None = None,
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
    n_mics = len(calibration.microphones)
    if x.ndim != 2 or x.shape[1] != n_mics:
        raise ValueError(
            f"expected pressures of shape (n, {n_mics}) for the {n_mics} microphones of the "
            f"calibration, got {x.shape}"
        )
    if not np.all(np.isfinite(x)):
        raise ValueError("pressures contain NaN or infinite samples")
    config.validate()
    geometry = Geometry.from_calibration(calibration)
    t_start = (
        calibration.air.temperature_c if config.temperature_c is None else config.temperature_c
    )
    c_start = geometry.sound_speed(t_start)
    check_band(config, geometry, fs, c_start)
    n = x.shape[0]
    hop, length, starts = _block_layout(n, fs, config.block_s)
    free_mach = _fixed_mach(config, geometry, c_start) is None
    prior = Prior.from_config(config, t_start, free_mach, n_mics)
    held_mach = _fixed_mach(config, geometry, c_start)
    start = prior.mean.copy()
    if held_mach is not None:
        start[2] = held_mach
    # Two microphones determine the two waves exactly: no residual, no estimate of theta.
    can_estimate = config.adaptive and n_mics >= 3
    if not config.adaptive:
        theta_note = "held: adaptive false"
    elif n_mics < 3:
        theta_note = "held: two microphones, no redundancy"
    else:
        theta_note = "estimated"
    log.info(
        "separation: %d microphones, %d blocks of %.0f ms, theta %s",
        n_mics,
        starts.size,
        1e3 * length / fs,
        "estimated per block" if can_estimate else "fixed",
    )
    if config.adaptive and n_mics < 3:
        log.warning(
            "separation: two microphones leave no redundancy; (c, eta, M) are held at "
            "T = %.2f degC, eta = %.3g, M = %.4g (configured values), not estimated",
            t_start,
            start[1],
            start[2],
        )
    if config.mic_position_prior_m is not None and n_mics > 3:
        log.info("separation: %d microphones: positions held at the calibration's", n_mics)

    # 1. Estimate theta per block.
    noise_raw = noise_levels(x, fs, config, band_limit_hz)
    log.info(
        "separation: noise PSD per channel %s Pa^2/Hz (one-sided)",
        np.array2string(2 * noise_raw, precision=3),
    )
    margin = int(np.ceil(_FILTER_MARGIN_S * fs))
    f1 = c_start / (2 * geometry.spacing)
    spectra_list = [
        cross_spectra(
            _block(x, s - margin, length + 2 * margin), fs, config.fmin_hz, config.fmax_hz,
            margin, f1,
        )
        for s in starts
    ]  # fmt: skip
    level = np.array([float(np.sum(sp.mic_power)) for sp in spectra_list])
    floor = np.median(level) * 10 ** (-config.min_level_db / 10)
    inside = (starts >= 0) & (starts + length <= n)
    if not np.any(inside):
        inside[:] = True  # take shorter than one block: use what there is
    peak = max(
        (float(np.max(sp.mic_power, initial=0.0)) for sp in spectra_list),
        default=0.0,
    )
    noise = np.maximum(noise_raw, _NOISE_FLOOR * peak + 1e-300)
    uses = [sp.use(noise, config.min_snr_db) for sp in spectra_list]
    n_free = int(np.sum(prior.free))
    # Blocks hanging over either end hold half silence and an abrupt edge: not fitted.
    fitted = inside & (level > max(floor, 0.0)) & np.array([np.sum(u) >= 3 for u in uses])
    nb = starts.size
    n_par = prior.mean.size
    raw = np.full((nb, n_par), np.nan)
    raw_se = np.full((nb, n_par), np.nan)
    residual = np.full(nb, np.nan)
    kappa = np.full(nb, np.nan)
    evals = np.zeros(nb, dtype=int)
    at_bound = [""] * nb
    band_lo = np.full(nb, np.nan)
    band_hi = np.full(nb, np.nan)
    n_bins = np.zeros(nb, dtype=int)
    snr_db = np.full(nb, np.nan)
    estimates: list[BlockEstimate | None] = [None] * nb
    corr = None
    kappa_start = 1.0
    current = start.copy()
    for b, spectra in enumerate(spectra_list):
        use = uses[b]
        if np.any(use):
            band_lo[b] = float(spectra.freqs[use][0])
            band_hi[b] = float(spectra.freqs[use][-1])
            n_bins[b] = int(np.sum(use))
            snr = np.sum(spectra.mic_power[use], axis=1) / np.sum(noise) - 1.0
            snr_db[b] = float(10 * np.log10(max(np.median(snr), 1e-30)))
        if not fitted[b]:
            continue
        if can_estimate and n_free:
            if corr is None:
                corr = window_correlation(spectra)
            est = estimate_block(
                spectra, use, noise, geometry, current, prior, config, corr, kappa_start
            )
            kappa_start = est.kappa
            estimates[b] = est
            raw[b] = est.values
            cov_full = np.zeros(n_par)
            cov_full[prior.free] = np.diag(est.cov)
            raw_se[b] = np.sqrt(np.maximum(cov_full, 0.0))
            residual[b] = est.residual
            kappa[b] = est.kappa
            evals[b] = est.evaluations
            at_bound[b] = ";".join(est.at_bound)
            current = est.values
        else:
            th = Theta(c_start, start[1], start[2])
            residual[b] = residual_cost(th, spectra, geometry, noise, use)
            raw[b] = start
            raw_se[b] = 0.0
        log.debug("block %d: T %.3f degC, eta %.3f, M %.5f, chi2 %.2f", b, *raw[b], residual[b])
    adaptive = can_estimate and n_free > 0
    if not np.any(fitted) and adaptive:
        raise ValueError(
            "no block has enough signal in the estimation band "
            f"{config.fmin_hz:g}-{config.fmax_hz:g} Hz to estimate the propagation parameters"
        )
    median_j = float(np.median(residual[fitted])) if np.any(fitted) else float("nan")
    trust = fitted & (residual <= config.max_residual_ratio * median_j)
    if not np.any(trust):
        trust = fitted.copy()
    centres = (starts + hop) / fs
    if adaptive:
        kept = [e if trust[j] else None for j, e in enumerate(estimates)]
        smooth, smooth_se = smooth_blocks(centres, kept, prior, config.smooth_s)
    else:
        smooth = np.tile(start, (nb, 1))
        smooth_se = np.zeros((nb, n_par))
    if held_mach is not None:
        smooth[:, 2] = [_fixed_mach_t(config, geometry, t) for t in smooth[:, 0]]
    c_track = np.array([geometry.sound_speed(float(t)) for t in smooth[:, 0]])

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
        th = Theta(c_track[b], smooth[b, 1], smooth[b, 2])
        geo_b = geometry.corrected(float(smooth[b, 3]))
        g_p, g_u = separation_filters(fb, th, geo_b)
        taper = _band_taper(fb, config, geo_b, th)
        g_p *= taper[:, None]
        g_u *= (taper * ramp)[:, None]
        seg = np.zeros((nfft, n_mics))
        seg[pad : pad + length] = _block(x, s, length) * win[:, None]
        spec_ = np.fft.rfft(seg, axis=0)[band]
        y = np.zeros((freqs.size, 2), dtype=complex)
        y[band, 0] = np.sum(g_p * spec_, axis=1)
        y[band, 1] = np.sum(g_u * spec_, axis=1)
        lo = origin + s - pad
        out[lo : lo + nfft] += np.fft.irfft(y, nfft, axis=0)
    p0 = out[origin : origin + n, 0].copy()
    u0 = out[origin : origin + n, 1].copy()

    table = pd.DataFrame(
        {
            "time_s": centres,
            "temperature_c": smooth[:, 0],
            "temperature_se_c": smooth_se[:, 0],
            "c_m_s": c_track,
            "loss_scale": smooth[:, 1],
            "loss_scale_se": smooth_se[:, 1],
            "mach": smooth[:, 2],
            "mach_se": smooth_se[:, 2],
            "temperature_raw_c": raw[:, 0],
            "temperature_raw_se_c": raw_se[:, 0],
            "loss_scale_raw": raw[:, 1],
            "loss_scale_raw_se": raw_se[:, 1],
            "mach_raw": raw[:, 2],
            "mach_raw_se": raw_se[:, 2],
            "mic_position_m": smooth[:, 3],
            "mic_position_se_m": smooth_se[:, 3],
            "mic_position_raw_m": raw[:, 3],
            "at_bound": at_bound,
            "band_lo_hz": band_lo,
            "band_hi_hz": band_hi,
            "bins": n_bins,
            "residual": residual,
            "kappa": kappa,
            "snr_db": snr_db,
            "evaluations": evals,
            "fitted": fitted,
            "trusted": trust,
            "theta": theta_note,
        }
    )
    result = SeparationResult(
        fs=float(fs),
        p0=p0,
        u0=u0,
        blocks=table,
        config=config,
        noise_psd=2 * noise_raw,
        geometry=geometry.corrected(float(np.median(smooth[:, 3]))),
    )
    for line in result.bound_warnings():
        log.warning("separation: %s", line)
    log.info(
        "separation: T %.2f..%.2f degC, eta %.3f..%.3f, M %.4f..%.4f, median chi2/term %.2f",
        table.temperature_c.min(),
        table.temperature_c.max(),
        table.loss_scale.min(),
        table.loss_scale.max(),
        table.mach.min(),
        table.mach.max(),
        median_j,
    )
    return result


def reference_noise(
    freqs: np.ndarray,
    theta: Theta,
    geometry: Geometry,
    noise_psd: np.ndarray,
    config: SeparationConfig,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Power spectral densities of the sensor noise carried into p0 and u0.

    Parameters
    ----------
    freqs : ndarray
        Frequencies, Hz.
    theta : Theta
        Propagation parameters of the separation filters.
    geometry : Geometry
        Microphones and bore.
    noise_psd : ndarray
        One-sided white-noise PSD of each microphone, Pa^2/Hz, shape ``(N,)``.
    config : SeparationConfig
        Band taper and u0 ramp.

    Returns
    -------
    s_pp : ndarray
        One-sided PSD of the noise in p0, Pa^2/Hz.
    s_uu : ndarray
        One-sided PSD of the noise in u0, (m^3/s)^2/Hz.
    s_pu : ndarray
        Their cross-spectral density ``E[N_p conj(N_u)]``, Pa m^3/s/Hz (complex).

    Notes
    -----
    ``N_U0 = sum_m g_u,m N_m`` with independent channel noises, so ``S_uu = sum_m |g_u,m|^2
    D_m``. Below the first resonance of the microphone spacing, ``|g_u| ~ 1 / (Z_c k s)``:
    the noise of u0 rises as 1 / f towards low frequency (physics.md E.4).
    """
    g_p, g_u = separation_filters(np.asarray(freqs, dtype=float), theta, geometry)
    taper = _band_taper(np.asarray(freqs, dtype=float), config, geometry, theta)
    ramp = _u_ramp(np.asarray(freqs, dtype=float), config)
    g_p = g_p * taper[:, None]
    g_u = g_u * (taper * ramp)[:, None]
    d = np.asarray(noise_psd, dtype=float)[None, :]
    s_pp = np.sum(np.abs(g_p) ** 2 * d, axis=1)
    s_uu = np.sum(np.abs(g_u) ** 2 * d, axis=1)
    s_pu = np.sum(g_p * np.conj(g_u) * d, axis=1)
    return s_pp, s_uu, s_pu


def check_channel_order(
    pressures: np.ndarray, fs: float, calibration: Calibration, seconds: float = 1.0
) -> str | None:
    """Whether the channels of a take look like the calibration's microphones in order.

    Two cheap tests on the strongest bins in 50-1000 Hz of (at most) ``seconds`` of the
    take, with the plane-wave field at the calibration's temperature, no loss scaling, no
    flow:

    1. (three or more microphones) the fraction of power two plane waves cannot explain,
       for the given order and for every other order of the channels (up to 5
       microphones; with more, the orders differing by one swap of two channels); an
       order explaining the data 30 times better means channels are swapped;
    2. the direction of the active acoustic power, ``|A|^2 - |B|^2`` over ``|A|^2 + |B|^2``
       summed over those bins: a note played at the reed (or any source at the
       mouthpiece) sends power towards the bell, so a clearly negative value means the
       order is reversed (a mirror image that test 1 cannot see).

    Returns
    -------
    str or None
        A one-line description of the problem, or None (also when no bin is strong
        enough to tell).
    """
    from itertools import permutations

    from scipy import signal

    x = np.asarray(pressures, dtype=float)
    n = min(x.shape[0], int(seconds * fs))
    start = (x.shape[0] - n) // 2
    x = x[start : start + n] - np.mean(x[start : start + n], axis=0)
    nper = min(int(2 ** np.ceil(np.log2(0.1 * fs))), n)
    freqs, s = signal.csd(
        x[:, :, None], x[:, None, :], fs=fs, nperseg=nper, axis=0, window="hann"
    )  # S[f, i, j] = E[conj(X_i) X_j]
    s = np.conj(s)  # E[X_i conj(X_j)]
    band = (freqs >= 50.0) & (freqs <= 1000.0)
    if not np.any(band):
        return None
    trace = np.real(np.einsum("fii->f", s))
    ref = np.median(trace[band])
    idx = np.flatnonzero(band)
    idx = idx[np.argsort(trace[idx])[::-1][:10]]
    idx = idx[trace[idx] > 100 * ref]
    if idx.size == 0:
        return None
    geometry = Geometry.from_calibration(calibration)
    c = calibration.air_properties().c
    theta = Theta(c, 1.0, 0.0)
    f = freqs[idx]
    omega = 2 * np.pi * f
    excess = zk_excess(omega, geometry, c)[0]
    k_p, k_m = wavenumbers(omega, theta, excess)
    h = model_matrix(k_p, k_m, geometry.offsets)
    sb = s[idx]
    n_mics = geometry.offsets.size

    hh = np.conj(np.swapaxes(h, -1, -2))
    pinv = np.linalg.solve(hh @ h, hh)  # (f, 2, N): rows g_A, g_B
    # projector on what two plane waves cannot explain (zero for two microphones)
    proj = np.eye(n_mics)[None] - h @ pinv

    def arranged(order) -> np.ndarray:
        return sb[:, list(order)][:, :, list(order)]

    def unexplained(order) -> float:
        sp = arranged(order)
        quad = np.real(np.einsum("fij,fjk,fik->f", proj, sp, np.conj(proj)))
        return float(np.sum(quad) / np.sum(np.real(np.einsum("fii->f", sp))))

    def power_flow(order) -> float:
        s_ab = np.einsum("fai,fij,fbj->fab", pinv, arranged(order), np.conj(pinv))
        a2, b2 = np.real(s_ab[:, 0, 0]), np.real(s_ab[:, 1, 1])
        return float(np.sum(a2 - b2) / np.sum(a2 + b2))

    identity = tuple(range(n_mics))
    if n_mics <= 5:
        orders = list(permutations(identity))
    else:
        orders = [identity]
        for i in range(n_mics):
            for j in range(i + 1, n_mics):
                o = list(identity)
                o[i], o[j] = o[j], o[i]
                orders.append(tuple(o))
    fits = {o: unexplained(o) for o in orders} if n_mics >= 3 else {identity: 0.0}
    given = fits[identity]
    best = min(fits.values())
    mics = calibration.microphones
    if given > 1e-5 and given > 30 * best:
        # of the equally good orders (mirror images), the one sending power to the bell
        near = [o for o, v in fits.items() if v <= 2 * best]
        order = max(near, key=power_flow)
        chans = ", ".join(str(mics[i].channel) for i in order)
        return (
            f"channels look swapped: two plane waves leave {100 * given:.2g} % of the power "
            f"unexplained in the calibration's order but {100 * best:.2g} % with channels "
            f"{chans} as {', '.join(m.name for m in mics)}; check the channel map"
        )
    ratio = power_flow(identity)
    if ratio < -0.01:
        return (
            f"acoustic power at the microphones flows towards the mouthpiece (net "
            f"{100 * ratio:.2g} % of the wave power); the channels are probably in reverse "
            "order: the calibration lists the microphones from the mouthpiece outwards"
        )
    return None


def fixed_config(config: SeparationConfig, mach: float = 0.0) -> SeparationConfig:
    """The non-adaptive variant of ``config``: theta held at its start values and ``mach``."""
    return replace(config, adaptive=False, mach=mach, mean_flow_m3_s=None)
