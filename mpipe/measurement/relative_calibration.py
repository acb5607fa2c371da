"""Relative calibration H_c of a microphone against microphone 1, measured from recordings.

The wave separation needs H_c to a few hundredths of a dB and tenths of a degree
(physics.md E.6). Two methods: the switching method of Chung & Blaser (1980),
:func:`switching_calibration`, which needs no knowledge of the field; and a known load,
:func:`closed_tube_calibration`, where the microphones sit in a cylinder closed by a rigid
cap at a known position (:func:`closed_tube_ratio`). Both start from the H1 estimate of
:func:`transfer_estimate`, and :func:`smooth` averages the result over frequency.

Convention (that of :func:`mpipe.measurement.calibration_tables.read_mic_calibration`): the
recorded spectrum of microphone m, already scaled by its sensitivity, is ``H_c`` times the
pressure at the microphone as microphone 1 would have measured it; the corrected spectrum is
``P_m = recorded P_m / H_c``.

References
----------
Chung & Blaser 1980, "Transfer function method of measuring in-duct acoustic properties.
I. Theory", JASA 68(3):907-913; ISO 10534-2; physics.md B.4, E.6.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import pandas as pd
import scipy.signal

from mpipe.acoustics.air import Air
from mpipe.acoustics.ducts import propagation
from mpipe.core.errors import UserError


@dataclass(frozen=True)
class SpectralOptions:
    """How both methods estimate H_c over frequency.

    Attributes
    ----------
    band : (float, float)
        Frequencies of the table, Hz (the wave separation needs 20-7250 Hz).
    resolution_hz : float
        Welch resolution, Hz.
    min_coherence : float
        Bins below this squared coherence (pressure nodes, no excitation) are interpolated
        from their neighbours.
    smooth_hz : float
        Width of the running mean applied to H_c, Hz (0: none); see :func:`smooth`.
    """

    band: tuple[float, float] = (20.0, 7250.0)
    resolution_hz: float = 10.0
    min_coherence: float = 0.95
    smooth_hz: float = 100.0


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
    near_node : int
        Bins refused because they lie near a pressure node of the known field (closed
        tube), interpolated from their neighbours.
    warnings : tuple of str
        What makes the result suspect (see :func:`switching_calibration`).
    """

    mic: str
    freqs: np.ndarray
    h: np.ndarray
    valid: np.ndarray
    method: str
    near_node: int = 0
    warnings: tuple[str, ...] = ()

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
            "near_node_fraction": self.near_node / max(self.valid.size, 1),
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
    # the unusable bins are interpolated from the smoothed usable ones, not from the raw
    # bins at a gap's edges (one noisy, possibly biased bin each)
    return _fill(freqs, out, valid) if valid.sum() >= 2 else out


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
    spectral: SpectralOptions | None = None,
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
    spectral : SpectralOptions, optional
        Band, Welch resolution, coherence threshold (a bin below it in either recording is
        interpolated) and smoothing; default :class:`SpectralOptions`.

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
    opt = SpectralOptions() if spectral is None else spectral
    f, h1, c1 = transfer_estimate(first[:, 0], first[:, 1], fs, opt.resolution_hz)
    _, h2, c2 = transfer_estimate(second[:, 0], second[:, 1], fs, opt.resolution_hz)
    sel = _band(f, opt.band)
    f, h1, h2 = f[sel], h1[sel], h2[sel]
    valid = (c1[sel] >= opt.min_coherence) & (c2[sel] >= opt.min_coherence)
    _require(valid, mic, opt.min_coherence)
    product = smooth(f, h1 * h2, opt.smooth_hz, valid)
    phase = np.unwrap(np.angle(product))
    # the branch of the unwrapped phase nearest 0 at the lowest usable bins
    phase -= 2 * np.pi * np.round(np.median(phase[valid][:5]) / (2 * np.pi))
    h = np.sqrt(np.abs(product)) * np.exp(0.5j * phase)
    low = valid & (f < 500.0)
    field = h1[low] / h[low] if low.any() else h1[valid][:5] / h[valid][:5]
    if np.median(field.real) < 0:
        h = -h
    result = RelativeCalibration(mic, f, h, valid, "switching")
    return dataclasses.replace(result, warnings=_switch_warnings(result, h1 / h2, valid))


#: Median |ln(H_I / H_II)| below which the two recordings are the same (not swapped).
SAME_RECORDINGS = 1e-3
#: A relative calibration beyond these medians (dB, deg) is implausible for two
#: microphones of one type on matched channels.
PLAUSIBLE_GAIN_DB, PLAUSIBLE_PHASE_DEG = 6.0, 30.0


def _switch_warnings(result: RelativeCalibration, field2: np.ndarray, valid: np.ndarray):
    """Why a switching result is suspect: the same recording twice, or an implausible H_c."""
    warnings = []
    # H_I / H_II is the field ratio squared: 1 only when nothing was swapped
    if np.median(np.abs(np.log(field2[valid]))) < SAME_RECORDINGS:
        warnings.append(
            f"{result.mic}: the two recordings give the same transfer function: the "
            "microphones were not swapped between them (or one file was given twice); H_c "
            "then holds the sound field, not the microphones"
        )
    s = result.summary()
    if (
        abs(s["gain_db_median"]) > PLAUSIBLE_GAIN_DB
        or abs(s["phase_deg_median"]) > PLAUSIBLE_PHASE_DEG
    ):
        warnings.append(
            f"{result.mic}: H_c {s['gain_db_median']:+.2f} dB, {s['phase_deg_median']:+.1f} deg is "
            f"implausible for matched microphones (expected within {PLAUSIBLE_GAIN_DB:g} dB "
            f"and {PLAUSIBLE_PHASE_DEG:g} deg): check the recordings, the channels and the "
            "sensitivities"
        )
    return tuple(warnings)


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
    spectral: SpectralOptions | None = None,
    max_node_db: float = 10.0,
    max_change: float = 0.1,
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
    spectral : SpectralOptions, optional
        Band, Welch resolution, coherence threshold (bins below it are interpolated) and
        smoothing; default :class:`SpectralOptions`.
    max_node_db : float
        Bins where the theoretical ratio is more than this above or below 0 dB (one
        microphone near a pressure node, where a small error of the model is a large
        error of H_c) are interpolated too.
    max_change : float
        Bins where the theoretical ratio changes by more than this fraction over one
        ``spectral.resolution_hz`` (the flanks of a pressure node) are interpolated too: the
        spectral estimate averages the field over its resolution, so there it is biased
        against the ratio at the bin's centre (0.45 dB and 2 deg with the cap at 0.45 m
        and 10 Hz resolution, without this test).

    Returns
    -------
    RelativeCalibration
        ``near_node`` counts the bins refused near the tube's pressure nodes.
    """
    opt = SpectralOptions() if spectral is None else spectral
    resolution_hz = opt.resolution_hz
    f, h, coh = transfer_estimate(recording[:, 0], recording[:, 1], fs, resolution_hz)
    sel = _band(f, opt.band)
    f, h, coh = f[sel], h[sel], coh[sel]
    theory = np.interp(f, ratio_freqs, ratio.real) + 1j * np.interp(f, ratio_freqs, ratio.imag)
    level = 20 * np.log10(np.maximum(np.abs(theory), 1e-300))
    log_theory = np.log(np.where(np.abs(theory) > 0, theory, 1e-300))
    change = np.abs(np.gradient(log_theory.real + 1j * np.unwrap(log_theory.imag), f))
    node = (np.abs(level) > max_node_db) | (change * resolution_hz > max_change)
    valid = (coh >= opt.min_coherence) & ~node
    _require(valid, mic, opt.min_coherence)
    hc = smooth(f, h / np.where(valid, theory, 1.0), opt.smooth_hz, valid)
    return RelativeCalibration(mic, f, hc, valid, "closed-tube", int(node.sum()))


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


__all__ = [
    "RelativeCalibration",
    "SpectralOptions",
    "closed_tube_calibration",
    "closed_tube_ratio",
    "smooth",
    "switching_calibration",
    "transfer_estimate",
]
