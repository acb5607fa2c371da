"""The virtual multi-microphone recording: a stand-in for a real take, with known truth.

From the pressure p(t) (Pa) and volume flow u(t) (m^3/s) at the mouthpiece entry, as the
reed model produces them, this module computes what the N >= 2 wall microphones of a
:class:`~mpipe.measurement.calibration.Calibration` would record, and what a recorder would store:

1. **Bore, mouthpiece -> reference plane** (no mean flow): the whole signal is transformed
   with one long FFT, zero-padded at both ends by max(2L/c, 0.25 s) so that neither the time
   advance carried by the inverse transfer matrix nor the long visco-thermal tails wrap
   around, and
   ``[P0, U0] = T(0 -> x_ref)^{-1} [P, U]`` (physics.md F.1, read downstream).
2. **Reference plane -> microphones** (main cylinder, optional mean flow of Mach number M):
   the convected plane-wave field of physics.md E.1,
   ``P(x) = A exp(-j k+ (x - x_ref)) + B exp(+j k- (x - x_ref))`` with ``k± = k0 / (1 ± M)``,
   ``k0 = -j Gamma`` (lossy) and ``P0 = A + B``, ``U0 = (A - B) / Zc``. With M = 0 this is
   the transfer matrix of the cylinder between the reference plane and each microphone.
3. **Microphones**: recorded signal = true pressure / sensitivity x G_m, where
   ``G_m = 10^(gain_db / 20) exp(j phase_deg pi / 180)`` is a complex gain constant over
   frequency (the DC and Nyquist bins, which must stay real, get the modulus only).
4. **Recorder**: resampling to the output rate (``scipy.signal.resample_poly``), additive
   white noise at a given SNR per channel (seeded), and quantisation to ``bits`` with the
   peak at ``-headroom_db`` dBFS. Steps 3 and 4 are in :mod:`mpipe.reed.recorder`; writing
   the take to disk is :mod:`mpipe.reed.take_files`.

A temperature that drifts linearly over the take is rendered by overlapping blocks with
cross-fades: the take is cut into K triangular (hat-weighted) blocks whose centres are
equally spaced in time and so lie exactly on the temperature line, at most 0.5 degC apart.
Each block is computed with the air properties of its centre temperature and 0.25 s of the
real signal as context on both sides (the visco-thermal transfer functions have long
t^(-3/2) tails, so short-context blocks would be inaccurate), and the outputs are summed
with hat weights that add up to one. The effective response at time t is the interpolation
of the two neighbouring node responses; for a phase difference delta between them it is off
by at most delta^2 / 8 in magnitude (about 1e-4 at 7.25 kHz over the 0.25 m from the
mouthpiece to the microphones for 0.5 degC nodes), and between the microphones (2-4 cm)
far less.

Units (recorded signal)
-----------------------
``signals`` are in *recorded units*: Pa divided by the microphone's calibration
``sensitivity`` (Pa per unit), with the microphone errors applied. A file stores
``signals / full_scale``, so the sensitivity of the written file is
``sensitivity x full_scale`` Pa per digital full-scale unit;
:func:`mpipe.reed.take_files.write_virtual_take` writes a calibration copy holding exactly
these sensitivities.

References
----------
Chatziioannou & van Walstijn 2012, section 4 (measurement set-up) and eq. (16);
physics.md E.1 (field with mean flow, after Jang & Ih 1998, JASA 103(3)), E.6 (relative
microphone calibration, after Chung & Blaser 1980, JASA 68(3):907-913), F.1 (translation).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.fft

from mpipe.acoustics.air import Air
from mpipe.measurement.calibration import Calibration
from mpipe.measurement.field import (
    check_mach,
    complex_gain,
    microphone_spectra,
    mouthpiece_to_reference,
)
from mpipe.reed.recorder import (
    SUPPORTED_BITS,
    RecorderOptions,
    add_noise,
    apply_gains,
    output_rate_ratio,
    per_microphone,
    quantise,
    resample_by,
)

log = logging.getLogger(__name__)

# Zero padding at each end of the long FFT. 2L/c covers the propagation delays, but the
# visco-thermal transfer functions also have t^(-3/2) tails (boundary-layer memory, from
# exp(-beta sqrt(j omega))), so wrap-around falls only as pad^(-1/2): on a clarinet-like
# signal 2L/c (6 ms) leaves ~1e-3 relative error, 0.05 s ~1e-4, 0.25 s ~1e-5.
_PAD_MARGIN = 256
PAD_S = 0.25
# Largest temperature step between the nodes of a drifting-temperature rendering, degC:
# 0.5 degC keeps the interpolation error below 1e-4 in magnitude up to 7.25 kHz over the
# mouthpiece-to-microphone path (see _render_drift).
DRIFT_STEP_C = 0.5


@dataclass(frozen=True, eq=False)
class VirtualTake:
    """A virtual recording and the truth behind it.

    Attributes
    ----------
    signals : ndarray
        Shape ``(n, N)``: recorded signal of each microphone, upstream first, in recorded
        units (Pa / calibration sensitivity, with microphone errors, noise, quantisation).
    fs : float
        Sample rate of every array here, Hz.
    p, u : ndarray
        Shape ``(n,)``: pressure (Pa) and volume flow (m^3/s, positive into the bore) at the
        mouthpiece entry, resampled to ``fs``.
    p0, u0 : ndarray
        Shape ``(n,)``: pressure (Pa) and volume flow (m^3/s) at the reference plane.
    pressures : ndarray
        Shape ``(n, N)``: true acoustic pressure at the microphones, Pa (no microphone
        error, no noise, no quantisation).
    temperature_c : float or tuple of float
        Air temperature in degC, or ``(start, end)`` of a linear drift over the take.
    mach : float
        Mean-flow Mach number between the reference plane and the microphones (> 0 towards
        the bell).
    gain_error_db, phase_error_deg : tuple of float
        Microphone errors applied, dB and degrees, per microphone.
    snr_db : float or None
        Requested signal-to-noise ratio per channel, dB (None: no noise).
    bits : int or None
        Quantisation word length (None: not quantised).
    full_scale : float
        Recorded units at digital full scale: a file stores ``signals / full_scale``.
    sensitivity : tuple of float
        The calibration sensitivities used, Pa per recorded unit, per microphone.
    noise_rms : tuple of float
        Standard deviation of the added noise, recorded units, per microphone.
    seed : int
        Seed of the noise generator.
    fs_model : float
        Sample rate of the input signals, Hz.
    edge_s : float
        Duration, s, at each end of the take over which the microphone signals depend on
        input outside the given span (the largest microphone distance over c). When the
        input does not start from rest, or stops abruptly, these stretches are not physical.
    """

    signals: np.ndarray
    fs: float
    p: np.ndarray
    u: np.ndarray
    p0: np.ndarray
    u0: np.ndarray
    pressures: np.ndarray
    temperature_c: float | tuple[float, float]
    mach: float
    gain_error_db: tuple[float, ...]
    phase_error_deg: tuple[float, ...]
    snr_db: float | None
    bits: int | None
    full_scale: float
    sensitivity: tuple[float, ...]
    noise_rms: tuple[float, ...]
    seed: int
    fs_model: float
    edge_s: float

    @property
    def n_samples(self) -> int:
        """Number of samples per channel."""
        return self.signals.shape[0]

    @property
    def duration(self) -> float:
        """Duration in s."""
        return self.n_samples / self.fs

    @property
    def file_samples(self) -> np.ndarray:
        """The signals scaled to digital full scale (shape ``(n, N)``, dimensionless)."""
        return self.signals / self.full_scale

    @property
    def file_sensitivity(self) -> tuple[float, float, float]:
        """Pa per digital full-scale unit of the written file, per microphone."""
        return tuple(float(s * self.full_scale) for s in self.sensitivity)

    @property
    def mic_gains(self) -> np.ndarray:
        """Complex gains G_m of the microphone errors, shape ``(N,)``."""
        return complex_gain(self.gain_error_db, self.phase_error_deg)

    def temperature_at(self, t: np.ndarray) -> np.ndarray:
        """Air temperature in degC at times ``t`` (s from the first sample)."""
        t = np.asarray(t, dtype=float)
        if not isinstance(self.temperature_c, tuple):
            return np.full_like(t, self.temperature_c)
        start, end = self.temperature_c
        span = max((self.n_samples - 1) / self.fs, 1e-300)
        return start + (end - start) * np.clip(t / span, 0.0, 1.0)


def virtual_recording(
    p: np.ndarray,
    u: np.ndarray,
    fs: float,
    calibration: Calibration,
    *,
    temperature_c: float | tuple[float, float] | None = None,
    mach: float = 0.0,
    recorder: RecorderOptions | None = None,
    drift_step_c: float = DRIFT_STEP_C,
    upstream: Sequence[tuple[Calibration, np.ndarray]] = (),
) -> VirtualTake:
    """Record mouthpiece signals with the calibration's virtual wall microphones (N >= 2).

    Parameters
    ----------
    p : array_like
        Pressure at the mouthpiece entry, Pa, shape ``(n,)``. Should start from rest; see
        ``VirtualTake.edge_s``.
    u : array_like
        Volume flow at the mouthpiece entry, m^3/s, positive into the bore, shape ``(n,)``.
    fs : float
        Sample rate of ``p`` and ``u`` (the model rate), Hz.
    calibration : Calibration
        Bore, microphone positions and sensitivities, reference plane and air model.
    temperature_c : float or (float, float), optional
        Air temperature in degC; default the calibration's. A pair ``(start, end)`` gives a
        linear drift from the first to the last sample (overlapping blocks, see the module
        docstring).
    mach : float
        Mean-flow Mach number between the reference plane and the microphones, positive for
        breath flowing towards the bell (physics.md E.1).
    recorder : RecorderOptions, optional
        The microphones' gain and phase errors, noise, word length, output rate, noise seed
        and headroom (:class:`mpipe.reed.recorder.RecorderOptions`); default: none of them,
        at ``fs``.
    drift_step_c : float
        Largest temperature step between the nodes of a drifting temperature, degC.
    upstream : sequence of (Calibration, ndarray)
        For a take whose fingerings differ between the mouthpiece and the reference plane
        (a register hole there): each fingering's calibration and its share of every model
        sample (shares summing to one). The field is rendered through each fingering's
        bore and blended sample by sample, as the model blends their reflection functions
        (:mod:`mpipe.reed.fingered_bore`); empty: ``calibration``'s bore throughout.

    Returns
    -------
    VirtualTake
        Recorded signals and the truth, all at the output rate ``recorder.fs_out``.

    Raises
    ------
    ValueError
        For inputs of the wrong shape, non-finite samples, |M| >= 0.3, an unsupported word
        length or a non-rational rate ratio.

    References
    ----------
    physics.md E.1, F.1; Chatziioannou & van Walstijn 2012, section 4.
    """
    p, u = _checked_signals(p, u, fs)
    check_mach(mach)
    recorder = RecorderOptions() if recorder is None else recorder
    n_mics = len(calibration.microphones)
    gains = per_microphone(recorder.gain_error_db, n_mics, "gain_error_db")
    phases = per_microphone(recorder.phase_error_deg, n_mics, "phase_error_deg")
    bits, snr_db, seed = recorder.bits, recorder.snr_db, recorder.seed
    if bits is not None and bits not in SUPPORTED_BITS:
        raise ValueError(f"bits must be one of {SUPPORTED_BITS}, got {bits}")
    fs_out = float(fs if recorder.fs_out is None else recorder.fs_out)
    up, down = output_rate_ratio(fs, fs_out)
    temps = _temperatures(temperature_c, calibration)
    sens = tuple(float(m.sensitivity) for m in calibration.microphones)
    if upstream:
        # each fingering's own transfer to the reference plane, weighted per sample
        parts = [
            (_render(p, u, fs, cal, temps, mach, drift_step_c), np.asarray(w, dtype=float))
            for cal, w in upstream
        ]
        mics = sum(w[:, None] * r[0] for r, w in parts)
        p0 = sum(w * r[1] for r, w in parts)
        u0 = sum(w * r[2] for r, w in parts)
        pad, c_min = parts[0][0][3], parts[0][0][4]
    else:
        mics, p0, u0, pad, c_min = _render(p, u, fs, calibration, temps, mach, drift_step_c)
    recorded = apply_gains(mics / np.asarray(sens), complex_gain(gains, phases), pad)
    recorded, mics, p_out, u_out, p0, u0 = (
        resample_by(x, up, down) for x in (recorded, mics, p, u, p0, u0)
    )
    recorded, noise_rms = add_noise(recorded, snr_db, seed)
    peak = float(np.max(np.abs(recorded)))
    full_scale = (peak if peak > 0 else 1.0) * 10.0 ** (recorder.headroom_db / 20.0)
    if bits is not None:
        recorded = quantise(recorded, full_scale, bits)
    temp_out: float | tuple[float, float] = (
        float(temps[0]) if len(temps) == 1 else (float(temps[0]), float(temps[1]))
    )
    log.debug(
        "virtual recording: %d samples at %g Hz, T=%s degC, M=%g, full scale %.4g",
        recorded.shape[0],
        fs_out,
        temp_out,
        mach,
        full_scale,
    )
    x_max = max([m.position for m in calibration.microphones] + [calibration.reference_plane])
    return VirtualTake(
        signals=recorded,
        fs=fs_out,
        p=p_out,
        u=u_out,
        p0=p0,
        u0=u0,
        pressures=mics,
        temperature_c=temp_out,
        mach=float(mach),
        gain_error_db=gains,
        phase_error_deg=phases,
        snr_db=None if snr_db is None else float(snr_db),
        bits=bits,
        full_scale=full_scale,
        sensitivity=sens,
        noise_rms=noise_rms,
        seed=int(seed),
        fs_model=float(fs),
        edge_s=x_max / c_min,
    )


def _checked_signals(p, u, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """``p`` and ``u`` as float arrays, checked: 1-D, one length >= 2, finite; fs > 0."""
    p = np.asarray(p, dtype=float)
    u = np.asarray(u, dtype=float)
    if p.ndim != 1 or p.shape != u.shape or p.size < 2:
        raise ValueError(f"p and u must be 1-D of equal length >= 2, got {p.shape} and {u.shape}")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(u))):
        raise ValueError("p and u must be finite")
    if not fs > 0:
        raise ValueError(f"sample rate must be positive, got {fs} Hz")
    return p, u


def _render(
    p: np.ndarray,
    u: np.ndarray,
    fs: float,
    calibration: Calibration,
    temps: tuple[float, ...],
    mach: float,
    step_c: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, float]:
    """True microphone pressures (Pa) and p0, u0 at one temperature or over a drift.

    Also returns the zero padding of the long FFT (samples) and the lowest speed of sound
    over the take (m/s).
    """
    airs = [calibration.air_properties(t) for t in temps]
    c_min = min(a.c for a in airs)
    pad = max(
        int(math.ceil(2.0 * calibration.bore.length / c_min * fs)) + _PAD_MARGIN, int(PAD_S * fs)
    )
    if len(temps) == 1 or temps[0] == temps[1]:
        mics, p0, u0 = _render_span(p, u, fs, 0, p.size, pad, calibration, airs[0], mach)
    else:
        mics, p0, u0 = _render_drift(p, u, fs, pad, calibration, temps, mach, step_c)
    return mics, p0, u0, pad, c_min


def _temperatures(temperature_c, calibration: Calibration) -> tuple[float, ...]:
    if temperature_c is None:
        return (calibration.air.temperature_c,)
    if isinstance(temperature_c, Sequence | np.ndarray):
        temps = tuple(float(t) for t in temperature_c)
        if len(temps) != 2:
            raise ValueError(
                "temperature_c must be a number or a (start, end) pair in degC, "
                f"got {temperature_c!r}"
            )
        return temps
    return (float(temperature_c),)


def _render_span(
    p: np.ndarray,
    u: np.ndarray,
    fs: float,
    lo: int,
    hi: int,
    pad: int,
    calibration: Calibration,
    air: Air,
    mach: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Microphone pressures and p0, u0 for output samples ``lo:hi`` at one temperature.

    The input is taken over ``lo - pad : hi + pad`` (zeros outside the signal), so no part of
    the kept output depends on circularly wrapped input when the response is shorter than
    ``pad`` samples either way.
    """
    n = p.size
    length = hi - lo + 2 * pad
    seg_p = np.zeros(length)
    seg_u = np.zeros(length)
    a, b = max(lo - pad, 0), min(hi + pad, n)
    seg_p[a - (lo - pad) : b - (lo - pad)] = p[a:b]
    seg_u[a - (lo - pad) : b - (lo - pad)] = u[a:b]
    n_fft = scipy.fft.next_fast_len(length, real=True)
    P = scipy.fft.rfft(seg_p, n_fft)
    U = scipy.fft.rfft(seg_u, n_fft)
    freqs = np.arange(P.size) * fs / n_fft
    P0, U0 = mouthpiece_to_reference(P, U, 2 * np.pi * freqs, calibration, air)
    Pm = microphone_spectra(P0, U0, freqs, calibration, air, mach)
    keep = slice(pad, pad + hi - lo)
    mics = scipy.fft.irfft(Pm, n_fft, axis=0)[keep]
    p0 = scipy.fft.irfft(P0, n_fft)[keep]
    u0 = scipy.fft.irfft(U0, n_fft)[keep]
    return mics, p0, u0


def _render_drift(
    p: np.ndarray,
    u: np.ndarray,
    fs: float,
    pad: int,
    calibration: Calibration,
    temps: tuple[float, float],
    mach: float,
    step_c: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Linear temperature drift: cross-faded block renderings at node temperatures.

    The take is split into K overlapping triangular blocks whose centres (the nodes) are
    equally spaced in time and hence in temperature, at most ``step_c`` apart. Each block is
    rendered with ``pad`` samples of the real signal as context on each side (as much as the
    whole-take rendering has zeros), and the blocks are summed with hat weights that add up
    to one. With a phase difference delta between the responses of adjacent nodes, the
    interpolated response differs from the exact one by at most delta^2 / 8 in magnitude.
    """
    n = p.size
    k_nodes = max(int(math.ceil(abs(temps[1] - temps[0]) / step_c - 1e-9)), 1)
    hop = (n - 1) / k_nodes
    mics = np.zeros((n, len(calibration.microphones)))
    p0 = np.zeros(n)
    u0 = np.zeros(n)
    t = np.arange(n)
    for k in range(k_nodes + 1):
        centre = k * hop
        lo = max(int(math.floor(centre - hop)) + 1, 0)
        hi = min(int(math.ceil(centre + hop)), n)
        temp = temps[0] + (temps[1] - temps[0]) * k / k_nodes
        air = calibration.air_properties(temp)
        m_k, p_k, u_k = _render_span(p, u, fs, lo, hi, pad, calibration, air, mach)
        w = np.clip(1.0 - np.abs(t[lo:hi] - centre) / hop, 0.0, None)
        mics[lo:hi] += w[:, None] * m_k
        p0[lo:hi] += w * p_k
        u0[lo:hi] += w * u_k
    return mics, p0, u0
