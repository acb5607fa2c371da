"""Settings of the adaptive wave separation (physics.md E.5).

:class:`SeparationConfig` holds every setting (frequencies in Hz, times in s, speeds in m/s,
temperatures in degC) with its cross-field checks; :func:`fixed_config` is its non-adaptive
variant (theta held at the start values and a given Mach number).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from mpipe.core.config import Where, between, positive, spec


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
        "Hz",
        "lower edge of the band used to estimate theta = (T, eta, M): the effective air "
        "temperature, the scale of the wall losses and the Mach number of the mean flow",
        between(1.0, 1e5),
        default=100.0,
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
        "0.9 of the Nyquist frequency of the recording (and where a resampler passes 0.9 of "
        "the power). When it is narrower than 1 kHz the noise level is the low quantile of "
        "the spectrum in the estimation band",
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
    drift_level: float = spec(
        "",
        "test level of the choice of the model of (T, eta, M) over the take: a constant, "
        "unless a straight line in time fits better than noise would with this probability "
        "(likelihood ratio), and the smoother (smooth_s) only if it beats the line so; a "
        "steady take gets one value with the pooled standard error (0: always constant, "
        "1: always the smoother)",
        between(0.0, 1.0),
        default=0.01,
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


def fixed_config(config: SeparationConfig, mach: float = 0.0) -> SeparationConfig:
    """The non-adaptive variant of ``config``: theta held at its start values and ``mach``."""
    return replace(config, adaptive=False, mach=mach, mean_flow_m3_s=None)
