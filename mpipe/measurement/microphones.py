"""Microphone calibration from recordings: sensitivity, switching and known-load methods.

Three things a lab needs before its first take (physics.md E.6):

- the absolute ``sensitivity`` of each microphone in Pa per unit of the recorded signal,
  from the data sheet (mV/Pa), the preamplifier/interface gain (dB) and the voltage of the
  interface at digital full scale: :func:`sensitivity_from_chain`;
- the relative calibration H_c of microphone m against microphone 1, which the wave
  separation needs to a few hundredths of a dB and tenths of a degree. Two methods:
  the switching method of Chung & Blaser (1980), :func:`switching_calibration`, which needs
  no knowledge of the field; and a known load, :func:`closed_tube_calibration`, where the
  microphones sit in a cylinder closed by a rigid cap at a known position;
- a warning when a take reads at a level no clarinet plays at: :func:`level_warning`.

Convention (that of :func:`mpipe.measurement.takes.read_mic_calibration`): the recorded spectrum of
microphone m, already scaled by its sensitivity, is ``H_c`` times the pressure at the
microphone as microphone 1 would have measured it; the corrected spectrum is
``P_m = recorded P_m / H_c``.

References
----------
Chung & Blaser 1980, "Transfer function method of measuring in-duct acoustic properties.
I. Theory", JASA 68(3):907-913; ISO 10534-2; physics.md B.4, E.6.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import scipy.signal

from mpipe.acoustics.air import Air
from mpipe.acoustics.ducts import propagation
from mpipe.core.errors import UserError
from mpipe.measurement.calibration import Calibration

log = logging.getLogger(__name__)

#: Peak pressure below which a take cannot be a played clarinet, Pa. Mouthpiece and bore
#: pressures of a played note swing by 1-10 kPa (mouth pressure 1.5-6 kPa); 20 Pa peak is
#: 120 dB SPL, far below any note.
MIN_PLAUSIBLE_PEAK_PA = 20.0
#: Peak pressure above which a take cannot be a played clarinet, Pa (half an atmosphere).
MAX_PLAUSIBLE_PEAK_PA = 5e4


def sensitivity_from_chain(
    mic_mv_per_pa: float, gain_db: float = 0.0, full_scale_v: float = 1.0
) -> float:
    """Sensitivity in Pa per unit of the recorded signal, from the measuring chain.

    A sample of value 1.0 (digital full scale) is ``full_scale_v`` volts at the converter;
    before the gain ``gain_db`` of preamplifier and interface it was
    ``full_scale_v / 10^(gain_db / 20)`` volts at the microphone, that is that voltage
    divided by the microphone's sensitivity in Pa.

    Parameters
    ----------
    mic_mv_per_pa : float
        Microphone sensitivity, mV/Pa (data sheet or pistonphone), > 0.
    gain_db : float
        Total voltage gain between microphone and converter (preamplifier, interface), dB.
    full_scale_v : float
        Peak voltage at the converter input that reads as digital full scale (sample value
        1.0), V. An interface specified in dBu at full scale: ``0.7746 * 10^(dBu/20) *
        sqrt(2)`` V peak.

    Returns
    -------
    float
        Pa per unit of the recorded signal (the calibration file's ``sensitivity``).

    Raises
    ------
    ValueError
        For a non-positive or non-finite sensitivity or voltage, or a non-finite gain.
    """
    for name, v in (("mic_mv_per_pa", mic_mv_per_pa), ("full_scale_v", full_scale_v)):
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"{name}: expected a positive number, got {v!r}")
    if not math.isfinite(gain_db):
        raise ValueError(f"gain_db: expected a finite number, got {gain_db!r}")
    volts_at_mic = full_scale_v / 10.0 ** (gain_db / 20.0)
    return volts_at_mic / (mic_mv_per_pa * 1e-3)


@dataclass(frozen=True)
class RelativeCalibration:
    """A relative calibration H_c of one microphone against microphone 1.

    Attributes
    ----------
    mic : str
        Microphone name.
    freqs : ndarray
        Frequencies, Hz.
    h : ndarray
        Complex H_c (dimensionless); bins where the measurement was unusable are
        interpolated from their neighbours (see ``valid``).
    valid : ndarray of bool
        Bins measured with enough coherence (the others are interpolated).
    method : str
        ``"switching"`` or ``"closed-tube"``.
    """

    mic: str
    freqs: np.ndarray
    h: np.ndarray
    valid: np.ndarray
    method: str

    def summary(self, band: tuple[float, float] = (100.0, 5000.0)) -> dict:
        """Median gain (dB) and phase (deg) of H_c over ``band`` and the share measured."""
        sel = (self.freqs >= band[0]) & (self.freqs <= band[1]) & self.valid
        gain = 20 * np.log10(np.abs(self.h[sel]))
        phase = np.rad2deg(np.unwrap(np.angle(self.h)))[sel]
        return {
            "mic": self.mic,
            "gain_db_median": float(np.median(gain)) if gain.size else float("nan"),
            "phase_deg_median": float(np.median(phase)) if phase.size else float("nan"),
            "measured_fraction": float(self.valid.mean()),
        }

    def table(self) -> pd.DataFrame:
        """The CSV content: ``frequency_hz, magnitude, phase_deg`` (unwrapped)."""
        return pd.DataFrame(
            {
                "frequency_hz": self.freqs,
                "magnitude": np.abs(self.h),
                "phase_deg": np.rad2deg(np.unwrap(np.angle(self.h))),
            }
        )


def transfer_estimate(
    x1: np.ndarray, xm: np.ndarray, fs: float, resolution_hz: float = 10.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """H1 estimate of the transfer function from channel 1 to channel m, with coherence.

    Parameters
    ----------
    x1, xm : ndarray
        Signals of microphone 1 and microphone m (Pa, or any common unit).
    fs : float
        Sample rate, Hz.
    resolution_hz : float
        Welch frequency resolution; the segment is the next power of two >= fs/resolution.

    Returns
    -------
    freqs : ndarray
        Hz.
    h : ndarray
        Xm / X1 (dimensionless): magnitude ``sqrt(S_mm / S_11)``, phase of ``S_1m``.
    coherence : ndarray
        Squared coherence of the two channels.
    """
    nperseg = int(2 ** math.ceil(math.log2(fs / resolution_hz)))
    nperseg = min(nperseg, int(2 ** math.floor(math.log2(x1.size))))
    kw = {"fs": fs, "nperseg": nperseg, "window": "hann", "detrend": False}
    f, s11 = scipy.signal.welch(x1, **kw)
    _, smm = scipy.signal.welch(xm, **kw)
    # scipy's csd(x, y) averages conj(X) Y: S_1m / S_11 is Xm / X1
    _, s1m = scipy.signal.csd(x1, xm, **kw)
    tiny = np.finfo(float).tiny
    # |H| = sqrt(S_mm / S_11) with the phase of S_1m: sensor noise of similar level in
    # both channels biases S_1m / S_11 low (noise on the input) but cancels here
    h = np.sqrt(smm / np.maximum(s11, tiny)) * np.exp(1j * np.angle(s1m))
    coherence = np.abs(s1m) ** 2 / np.maximum(s11 * smm, tiny)
    return f, h, coherence


def smooth(
    freqs: np.ndarray, h: np.ndarray, width_hz: float, valid: np.ndarray | None = None
) -> np.ndarray:
    """Running mean of a complex response over ``width_hz`` (log magnitude, unwrapped phase).

    A microphone mismatch varies slowly with frequency (capsule resonances lie far above
    the band), so averaging neighbouring bins reduces the random error of the estimate.
    Only ``valid`` bins enter the means; the others are then interpolated (:func:`_fill`).
    """
    valid = np.ones(h.shape, dtype=bool) if valid is None else valid
    h = _fill(freqs, h, valid)
    if width_hz <= 0 or freqs.size < 3:
        return h
    n = int(round(width_hz / float(freqs[1] - freqs[0]))) | 1
    if n < 3:
        return h
    kernel = np.ones(n)
    pad = n // 2
    w = valid.astype(float)

    def run(x: np.ndarray) -> np.ndarray:
        def conv(y):
            return np.convolve(np.concatenate([np.zeros(pad), y, np.zeros(pad)]), kernel, "valid")

        return conv(x * w) / np.maximum(conv(w), 1e-12)

    out = np.exp(run(np.log(np.abs(h)))) * np.exp(1j * run(np.unwrap(np.angle(h))))
    # bins with no valid neighbour within the width keep the interpolated value
    lonely = np.convolve(np.concatenate([np.zeros(pad), w, np.zeros(pad)]), kernel, "valid") == 0
    out[lonely] = h[lonely]
    return out


def _fill(freqs: np.ndarray, h: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Interpolate unusable bins (magnitude and unwrapped phase) from the usable ones."""
    if valid.all():
        return h
    if valid.sum() < 2:
        raise ValueError("fewer than two usable frequency bins")
    mag = np.interp(freqs, freqs[valid], np.abs(h[valid]))
    phase = np.interp(freqs, freqs[valid], np.unwrap(np.angle(h[valid])))
    return mag * np.exp(1j * phase)


def switching_calibration(
    first: np.ndarray,
    second: np.ndarray,
    fs: float,
    mic: str = "mic",
    band: tuple[float, float] = (20.0, 7250.0),
    resolution_hz: float = 10.0,
    min_coherence: float = 0.95,
    smooth_hz: float = 100.0,
) -> RelativeCalibration:
    """Relative calibration of microphone m by the two-recording switching method.

    Recording I has microphone 1 at position 1 and microphone m at position m; for
    recording II the two microphones are swapped physically while each stays on its own
    channel. With ``H = S_1m / S_11`` of each, ``H_I = H_c H_field`` and
    ``H_II = H_c / H_field``, so ``H_c^2 = H_I H_II`` whatever the field.

    Parameters
    ----------
    first, second : ndarray
        Shape ``(n, 2)``: channel of microphone 1 and channel of microphone m, scaled by
        their sensitivities (Pa), for recordings I and II (broadband excitation).
    fs : float
        Sample rate, Hz.
    mic : str
        Name of microphone m, for messages.
    band : (float, float)
        Frequencies of the table, Hz (the wave separation needs 20-7250 Hz).
    resolution_hz : float
        Welch resolution, Hz.
    min_coherence : float
        Bins where either recording's squared coherence is below this (pressure nodes,
        no excitation) are interpolated from their neighbours.
    smooth_hz : float
        Width of the running mean applied to H_c, Hz (0: none); see :func:`smooth`.

    Returns
    -------
    RelativeCalibration

    Notes
    -----
    The square root has two branches, ``±H_c``. The phase of ``H_I H_II`` is unwrapped
    along frequency and halved (the branch continuous in frequency), and the sign is the
    one that makes the field ratio ``H_I / H_c`` point the way of a field between two
    close microphones at low frequency (positive real part below 500 Hz, where the
    microphones are far less than a quarter wavelength apart).

    References
    ----------
    Chung & Blaser 1980, JASA 68(3):907-913; physics.md E.6.
    """
    f, h1, c1 = transfer_estimate(first[:, 0], first[:, 1], fs, resolution_hz)
    _, h2, c2 = transfer_estimate(second[:, 0], second[:, 1], fs, resolution_hz)
    sel = _band(f, band)
    f, h1, h2 = f[sel], h1[sel], h2[sel]
    valid = (c1[sel] >= min_coherence) & (c2[sel] >= min_coherence)
    _require(valid, mic, min_coherence)
    product = smooth(f, h1 * h2, smooth_hz, valid)
    phase = np.unwrap(np.angle(product))
    # the branch of the unwrapped phase nearest 0 at the lowest usable bins
    phase -= 2 * np.pi * np.round(np.median(phase[valid][:5]) / (2 * np.pi))
    h = np.sqrt(np.abs(product)) * np.exp(0.5j * phase)
    low = valid & (f < 500.0)
    field = h1[low] / h[low] if low.any() else h1[valid][:5] / h[valid][:5]
    if np.median(field.real) < 0:
        h = -h
    return RelativeCalibration(mic, f, h, valid, "switching")


def closed_tube_ratio(
    positions: np.ndarray, closed_at: float, radius: float, freqs: np.ndarray, air: Air,
    losses: str = "bessel",
) -> np.ndarray:  # fmt: skip
    """Theoretical ``P(x_m) / P(x_1)`` in a cylinder closed rigidly at ``closed_at``.

    With ``U = 0`` at the cap, ``[P(x), U(x)] = T(x -> cap) [P_cap, 0]``, so
    ``P(x) = cosh(Gamma (closed_at - x)) P_cap`` (physics.md B.4, lossy).

    Parameters
    ----------
    positions : array_like
        Microphone positions, m from the mouthpiece entry; the first is the reference.
    closed_at : float
        Position of the rigid cap, m; downstream of every microphone.
    radius : float
        Radius of the cylinder, m.
    freqs : ndarray
        Frequencies, Hz.
    air : Air
        Air in the tube.
    losses : str
        Loss model of :func:`mpipe.acoustics.ducts.propagation`.

    Returns
    -------
    ndarray
        Shape ``(n_freq, n_positions)``, complex; the first column is 1.
    """
    x = np.asarray(positions, dtype=float)
    if np.any(x > closed_at):
        raise ValueError("the cap must lie downstream of every microphone")
    omega = 2 * np.pi * np.maximum(np.asarray(freqs, dtype=float), 1e-3)
    gamma, _ = propagation(omega, radius, air, losses)
    a = np.cosh(gamma[:, None] * (closed_at - x[None, :]))
    return a / a[:, :1]


def closed_tube_calibration(
    recording: np.ndarray,
    fs: float,
    ratio: np.ndarray,
    ratio_freqs: np.ndarray,
    mic: str = "mic",
    band: tuple[float, float] = (20.0, 7250.0),
    resolution_hz: float = 10.0,
    min_coherence: float = 0.95,
    max_node_db: float = 10.0,
    smooth_hz: float = 100.0,
) -> RelativeCalibration:
    """Relative calibration of microphone m against a known field (a rigidly closed tube).

    ``H_c = (S_1m / S_11) / (P_m / P_1)_theory``.

    Parameters
    ----------
    recording : ndarray
        Shape ``(n, 2)``: channels of microphone 1 and m scaled by their sensitivities.
    fs : float
        Sample rate, Hz.
    ratio : ndarray
        Theoretical ``P_m / P_1`` (:func:`closed_tube_ratio`), on ``ratio_freqs``.
    ratio_freqs : ndarray
        Hz.
    mic : str
        Name of microphone m.
    band : (float, float)
        Frequencies of the table, Hz.
    resolution_hz : float
        Welch resolution, Hz.
    min_coherence : float
        Bins below this squared coherence are interpolated.
    max_node_db : float
        Bins where the theoretical ratio is more than this above or below 0 dB (one
        microphone near a pressure node, where a small error of the model is a large
        error of H_c) are interpolated too.
    smooth_hz : float
        Width of the running mean applied to H_c, Hz (0: none); see :func:`smooth`.

    Returns
    -------
    RelativeCalibration
    """
    f, h, coh = transfer_estimate(recording[:, 0], recording[:, 1], fs, resolution_hz)
    sel = _band(f, band)
    f, h, coh = f[sel], h[sel], coh[sel]
    theory = np.interp(f, ratio_freqs, ratio.real) + 1j * np.interp(f, ratio_freqs, ratio.imag)
    level = 20 * np.log10(np.maximum(np.abs(theory), 1e-300))
    valid = (coh >= min_coherence) & (np.abs(level) <= max_node_db)
    _require(valid, mic, min_coherence)
    hc = smooth(f, h / np.where(valid, theory, 1.0), smooth_hz, valid)
    return RelativeCalibration(mic, f, hc, valid, "closed-tube")


def _band(f: np.ndarray, band: tuple[float, float]) -> np.ndarray:
    # one bin beyond each edge, so that the table covers the band
    lo = max(int(np.searchsorted(f, band[0], side="right")) - 1, 0)
    hi = min(int(np.searchsorted(f, band[1], side="left")) + 1, f.size)
    sel = np.zeros(f.size, dtype=bool)
    sel[lo:hi] = True
    sel &= f > 0
    return sel


def _require(valid: np.ndarray, mic: str, min_coherence: float) -> None:
    if valid.mean() < 0.5:
        raise UserError(
            f"{mic}: only {100 * valid.mean():.0f} % of the frequency bins have a squared "
            f"coherence >= {min_coherence:g}; excite the tube with broadband sound (noise or "
            "a sweep) loud enough over the whole band, and check the channels"
        )


def read_channels(
    path: str | Path, calibration: Calibration, mics: tuple[str, str]
) -> tuple[np.ndarray, float]:
    """Read the channels of two microphones from a recording, scaled to Pa.

    Parameters
    ----------
    path : str or Path
        Multichannel audio file.
    calibration : Calibration
        Channel map and sensitivities.
    mics : (str, str)
        Names of microphone 1 (the reference) and microphone m.

    Returns
    -------
    x : ndarray
        Shape ``(n, 2)``, Pa.
    fs : float
        Sample rate, Hz.

    Raises
    ------
    UserError
        Naming the file for an unreadable file, and the microphone or channel that is
        missing.
    """
    import soundfile as sf

    by_name = {m.name: m for m in calibration.microphones}
    for name in mics:
        if name not in by_name:
            raise UserError(
                f"{calibration.source}: no microphone named {name!r}; expected one of "
                f"{', '.join(by_name)}"
            )
    try:
        data, fs = sf.read(str(path), dtype="float64", always_2d=True)
    except (RuntimeError, OSError) as exc:
        raise UserError(f"{path}: cannot read audio: {exc}") from None
    cols = []
    for name in mics:
        m = by_name[name]
        if m.channel > data.shape[1]:
            raise UserError(
                f"{path}: has {data.shape[1]} channel(s), microphone {name} is on channel "
                f"{m.channel}"
            )
        cols.append(data[:, m.channel - 1] * m.sensitivity)
    return np.column_stack(cols), float(fs)


def level_warning(pressures: np.ndarray, what: str = "take") -> str | None:
    """A warning when a take's pressure level cannot be a played clarinet.

    Parameters
    ----------
    pressures : ndarray
        Calibrated pressures, Pa (any shape).
    what : str
        Name of the take, for the message.

    Returns
    -------
    str or None
        The warning, or None when the peak lies between :data:`MIN_PLAUSIBLE_PEAK_PA`
        and :data:`MAX_PLAUSIBLE_PEAK_PA`.
    """
    peak = float(np.max(np.abs(pressures))) if np.size(pressures) else 0.0
    if MIN_PLAUSIBLE_PEAK_PA <= peak <= MAX_PLAUSIBLE_PEAK_PA:
        return None
    side = "below" if peak < MIN_PLAUSIBLE_PEAK_PA else "above"
    return (
        f"{what}: peak pressure {peak:.3g} Pa is far {side} a played clarinet (1-10 kPa in "
        "the bore): check microphones[].sensitivity (Pa per unit of the recorded signal; "
        "`mpipe calibrate sensitivity` computes it) - every result would be wrong"
    )


def simulate_calibration_recording(
    calibration: Calibration,
    positions: tuple[float, ...],
    gains: np.ndarray,
    *,
    load: str = "bore",
    closed_at: float | None = None,
    duration_s: float = 4.0,
    fs: float = 100_000.0,
    snr_db: float = 60.0,
    temperature_c: float | None = None,
    seed: int = 0,
) -> np.ndarray:
    """A virtual calibration recording: broadband sound in the bore, read by given channels.

    The field is stationary random noise: a white volume flow at the mouthpiece entry of
    the calibration's bore (``load="bore"``, the switching method's set-up), or white
    pressure at a rigid cap at ``closed_at`` on the main cylinder (``load="closed"``).

    Parameters
    ----------
    calibration : Calibration
        Bore, reference plane, air and main-bore radius.
    positions : tuple of float
        Position of the microphone on each channel, m from the mouthpiece entry.
    gains : array_like
        Complex gain of each channel's microphone
        (see :func:`mpipe.measurement.field.complex_gain`).
    load : {"bore", "closed"}
        The field, see above.
    closed_at : float, optional
        Cap position, m (``load="closed"``).
    duration_s : float
        Length, s.
    fs : float
        Sample rate, Hz.
    snr_db : float
        Signal-to-noise ratio of each channel (white sensor noise), dB.
    temperature_c : float, optional
        Air temperature, degC (default: the calibration's).
    seed : int
        Random seed.

    Returns
    -------
    ndarray
        Shape ``(n, len(positions))``, Pa as read by each (mismatched) microphone.
    """
    from mpipe.acoustics.bore import input_impedance
    from mpipe.measurement.field import microphone_field, mouthpiece_to_reference

    rng = np.random.default_rng(seed)
    n = int(round(duration_s * fs))
    freqs = np.fft.rfftfreq(n, 1 / fs)
    f_eval = np.maximum(freqs, 1e-3)
    air = calibration.air_properties(temperature_c)
    source = rng.standard_normal(freqs.size) + 1j * rng.standard_normal(freqs.size)
    if load == "bore":
        omega = 2 * np.pi * f_eval
        u = source * 1e-6
        p = input_impedance(calibration.bore, omega, air) * u
        p0, u0 = mouthpiece_to_reference(p, u, omega, calibration, air)
        field, _ = microphone_field(p0, u0, f_eval, calibration, air, 0.0, positions)
    elif load == "closed":
        if closed_at is None:
            raise ValueError("load 'closed' needs closed_at")
        ratio = closed_tube_ratio(
            np.asarray(positions), closed_at, calibration.main_radius, f_eval, air,
            calibration.bore.losses,
        )  # fmt: skip
        field = ratio * (source * 100.0)[:, None]
    else:
        raise ValueError(f"load: expected 'bore' or 'closed', got {load!r}")
    g = np.broadcast_to(np.asarray(gains, dtype=complex), (freqs.size, len(positions))).copy()
    g[0] = np.abs(g[0])  # DC and Nyquist of a real signal are real
    if n % 2 == 0:
        g[-1] = np.abs(g[-1])
    field[0] = field[0].real
    x = np.fft.irfft(field * g, n, axis=0)
    noise = rng.standard_normal(x.shape) * x.std(axis=0) * 10 ** (-snr_db / 20)
    return x + noise


__all__ = [
    "RelativeCalibration",
    "closed_tube_calibration",
    "closed_tube_ratio",
    "level_warning",
    "read_channels",
    "sensitivity_from_chain",
    "simulate_calibration_recording",
    "switching_calibration",
    "transfer_estimate",
]
