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
   peak at ``-headroom_db`` dBFS.

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
``sensitivity x full_scale`` Pa per digital full-scale unit; :func:`write_virtual_take`
writes a calibration copy holding exactly these sensitivities.

References
----------
Chatziioannou & van Walstijn 2012, section 4 (measurement set-up) and eq. (16);
physics.md E.1 (field with mean flow, after Jang & Ih 1998, JASA 103(3)), E.6 (relative
microphone calibration, after Chung & Blaser 1980, JASA 68(3):907-913), F.1 (translation).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np
import scipy.fft
import soundfile as sf
import yaml
from scipy import signal

from mpipe import __version__
from mpipe.acoustics.air import Air
from mpipe.core.io import check_writable, write_atomic, write_npz_atomic, write_text_atomic
from mpipe.measurement.calibration import Calibration
from mpipe.measurement.field import (
    _check_mach,
    complex_gain,
    microphone_spectra,
    mouthpiece_to_reference,
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
SUPPORTED_BITS = (16, 24, 32)
# Anti-aliasing window of resample_poly. scipy's default (Kaiser beta 5) ripples by ~1e-3 in
# the pass band; beta 10 keeps the gain within 1e-5 up to 12 kHz at 100 -> 48 kHz.
_RESAMPLE_WINDOW = ("kaiser", 10.0)


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
    gain_error_db: Sequence[float] | None = None,
    phase_error_deg: Sequence[float] | None = None,
    snr_db: float | None = None,
    bits: int | None = None,
    fs_out: float | None = None,
    seed: int = 0,
    headroom_db: float = 6.0,
    drift_step_c: float = DRIFT_STEP_C,
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
    gain_error_db : sequence of N float, optional
        Sensitivity error of each microphone, dB (recorded = true x 10^(dB/20)); default 0.
    phase_error_deg : sequence of N float, optional
        Phase error of each microphone, degrees, constant over frequency; default 0.
    snr_db : float, optional
        Add white Gaussian noise with an RMS ``snr_db`` below each channel's RMS.
    bits : {16, 24, 32}, optional
        Quantise to this word length with the peak at ``-headroom_db`` dBFS.
    fs_out : float, optional
        Output sample rate in Hz, a rational multiple of ``fs``; default ``fs``.
    seed : int
        Seed of the noise generator (``numpy.random.default_rng``).
    headroom_db : float
        Peak level below digital full scale, dB.
    drift_step_c : float
        Largest temperature step between the nodes of a drifting temperature, degC.

    Returns
    -------
    VirtualTake
        Recorded signals and the truth, all at ``fs_out``.

    Raises
    ------
    ValueError
        For inputs of the wrong shape, non-finite samples, |M| >= 0.3, an unsupported word
        length or a non-rational rate ratio.

    References
    ----------
    physics.md E.1, F.1; Chatziioannou & van Walstijn 2012, section 4.
    """
    p = np.asarray(p, dtype=float)
    u = np.asarray(u, dtype=float)
    if p.ndim != 1 or p.shape != u.shape or p.size < 2:
        raise ValueError(f"p and u must be 1-D of equal length >= 2, got {p.shape} and {u.shape}")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(u))):
        raise ValueError("p and u must be finite")
    if not fs > 0:
        raise ValueError(f"sample rate must be positive, got {fs} Hz")
    _check_mach(mach)
    n_mics = len(calibration.microphones)
    gains = _per_mic(gain_error_db, n_mics, "gain_error_db")
    phases = _per_mic(phase_error_deg, n_mics, "phase_error_deg")
    if bits is not None and bits not in SUPPORTED_BITS:
        raise ValueError(f"bits must be one of {SUPPORTED_BITS}, got {bits}")
    fs_out = float(fs if fs_out is None else fs_out)
    up, down = _rate_ratio(fs, fs_out)
    temps = _temperatures(temperature_c, calibration)
    sens = tuple(float(m.sensitivity) for m in calibration.microphones)

    airs = [calibration.air_properties(t) for t in temps]
    x_max = max([m.position for m in calibration.microphones] + [calibration.reference_plane])
    c_min = min(a.c for a in airs)
    pad = max(
        int(math.ceil(2.0 * calibration.bore.length / c_min * fs)) + _PAD_MARGIN, int(PAD_S * fs)
    )

    if len(temps) == 1 or temps[0] == temps[1]:
        mics, p0, u0 = _render_span(p, u, fs, 0, p.size, pad, calibration, airs[0], mach)
    else:
        mics, p0, u0 = _render_drift(p, u, fs, pad, calibration, temps, mach, drift_step_c)

    g = complex_gain(gains, phases)
    recorded = _apply_gains(mics / np.asarray(sens), g, pad)

    def resample(x):
        if up == down:
            return x
        return signal.resample_poly(x, up, down, axis=0, window=_RESAMPLE_WINDOW)

    recorded, mics = resample(recorded), resample(mics)
    p_out, u_out, p0, u0 = (resample(x) for x in (p, u, p0, u0))

    noise_rms = (0.0,) * n_mics
    if snr_db is not None:
        rms = np.sqrt(np.mean(recorded**2, axis=0))
        std = rms * 10.0 ** (-snr_db / 20.0)
        noise = np.random.default_rng(seed).standard_normal(recorded.shape) * std
        recorded = recorded + noise
        noise_rms = tuple(float(s) for s in std)

    peak = float(np.max(np.abs(recorded)))
    full_scale = (peak if peak > 0 else 1.0) * 10.0 ** (headroom_db / 20.0)
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


def quantise(x: np.ndarray, full_scale: float, bits: int) -> np.ndarray:
    """Round to the grid of a ``bits``-bit two's-complement converter.

    Parameters
    ----------
    x : ndarray
        Signal in any unit.
    full_scale : float
        Value (same unit) at digital full scale.
    bits : int
        Word length.

    Returns
    -------
    ndarray
        ``x`` rounded to multiples of ``full_scale / 2^(bits - 1)`` and clipped to the
        converter's range; the error is at most half a step inside the range.
    """
    steps = 2.0 ** (bits - 1)
    q = np.clip(np.round(x / full_scale * steps), -steps, steps - 1)
    return q / steps * full_scale


def write_mic_calibration(path: str | Path, freqs: np.ndarray, H: np.ndarray) -> Path:
    """Write a relative microphone calibration table (physics.md E.6) atomically.

    The CSV has the header ``frequency_hz,magnitude,phase_deg`` and one row per frequency;
    the phase is unwrapped. It is the format that a calibration's ``microphones[].calibration``
    points to: the corrected spectrum of microphone m is ``P_m = recorded P_m / H_c``.

    Parameters
    ----------
    path : str or Path
        Output file.
    freqs : array_like
        Strictly increasing frequencies in Hz, >= 0.
    H : array_like
        Complex H_c of the microphone against microphone 1 (dimensionless), one per
        frequency; a scalar is broadcast.

    Returns
    -------
    Path
        The file written.

    References
    ----------
    Chung & Blaser 1980, JASA 68(3):907-913; physics.md E.6.
    """
    freqs = np.asarray(freqs, dtype=float)
    h = np.broadcast_to(np.asarray(H, dtype=complex), freqs.shape)
    if freqs.ndim != 1 or freqs.size < 2:
        raise ValueError("need at least two frequencies")
    if np.any(np.diff(freqs) <= 0) or freqs[0] < 0:
        raise ValueError("frequencies must be >= 0 Hz and strictly increasing")
    if not np.all(np.isfinite(h)) or np.any(h == 0):
        raise ValueError("calibration values must be finite and non-zero")
    phase = np.rad2deg(np.unwrap(np.angle(h)))
    lines = ["frequency_hz,magnitude,phase_deg"]
    lines += [
        f"{f:.10g},{m:.17g},{ph:.17g}" for f, m, ph in zip(freqs, np.abs(h), phase, strict=True)
    ]
    return write_text_atomic(path, "\n".join(lines) + "\n")


@dataclass(frozen=True)
class TakeFiles:
    """Paths of the files that make up a written virtual take.

    Attributes
    ----------
    audio : Path
        The multichannel audio file.
    sidecar : Path
        YAML with everything needed to reproduce the take.
    truth : Path
        ``.npz`` with the true signals and parameters.
    calibration : Path
        Calibration copy whose sensitivities (Pa per digital full-scale unit) and relative
        microphone calibration tables fit the audio file.
    mic_calibrations : tuple of Path
        Relative calibration CSVs written (may be empty).
    """

    audio: Path
    sidecar: Path
    truth: Path
    calibration: Path
    mic_calibrations: tuple[Path, ...] = ()


def take_file_paths(
    audio: str | Path, with_mic_calibration: bool = True, n_mics: int = 3
) -> TakeFiles:
    """The file names that :func:`write_virtual_take` uses beside ``audio``.

    ``n_mics`` is the calibration's microphone count (tables for microphones 2 to N).
    """
    audio = Path(audio)
    stem = audio.with_suffix("")
    mics = (
        tuple(Path(f"{stem}.mic{m}_calibration.csv") for m in range(2, n_mics + 1))
        if with_mic_calibration
        else ()
    )
    return TakeFiles(
        audio=audio,
        sidecar=Path(f"{stem}.yaml"),
        truth=Path(f"{stem}.truth.npz"),
        calibration=Path(f"{stem}.calibration.yaml"),
        mic_calibrations=mics,
    )


def write_virtual_take(
    audio_path: str | Path,
    take: VirtualTake,
    calibration: Calibration,
    *,
    recipe: Mapping[str, Any] | None = None,
    truth_extra: Mapping[str, Any] | None = None,
    mic_calibration: bool = True,
    subtype: str | None = None,
    force: bool = False,
) -> TakeFiles:
    """Write a virtual take: audio, sidecar, truth and a matching calibration copy.

    Files (for ``audio_path = TAKE.flac``): ``TAKE.flac`` (channels as the calibration maps
    them; unused channels are silent), ``TAKE.yaml`` (recipe, package version, scale and
    errors), ``TAKE.truth.npz`` (true p, u at the mouthpiece and p0, u0 at the reference
    plane, true microphone pressures, temperature, Mach number, microphone errors, plus
    ``truth_extra``), ``TAKE.calibration.yaml`` (the calibration with the sensitivities of
    the file, in Pa per full-scale unit) and, when microphones 2 to N have errors relative
    to microphone 1 and ``mic_calibration`` is set, ``TAKE.mic2_calibration.csv`` to
    ``TAKE.micN_calibration.csv`` holding the exact H_c = G_m / G_1 (physics.md E.6).
    Microphone 1's gain error goes into its sensitivity (as a pistonphone would find it); its
    phase error is not calibratable and stays in the data. The original calibration's own
    tables are not carried over: the virtual microphones have exactly the errors requested.

    Parameters
    ----------
    audio_path : str or Path
        Audio file; the format follows the extension (FLAC, WAV, AIFF).
    take : VirtualTake
        The recording.
    calibration : Calibration
        The calibration the take was made with.
    recipe : mapping, optional
        Options that reproduce the take (stored in the sidecar under ``recipe``).
    truth_extra : mapping, optional
        More arrays or numbers for the truth file (for example the reed parameters).
    mic_calibration : bool
        Write the relative calibration tables of microphones 2 to N.
    subtype : str, optional
        soundfile subtype; default ``PCM_24`` (``PCM_16`` / ``PCM_32`` for those ``bits``).
    force : bool
        Overwrite existing files.

    Returns
    -------
    TakeFiles

    Raises
    ------
    OutputExistsError
        When a file exists and ``force`` is not set.
    """
    g = take.mic_gains
    relative = g / g[0]
    need_tables = mic_calibration and bool(np.any(np.abs(relative[1:] - 1.0) > 1e-12))
    files = take_file_paths(audio_path, need_tables, len(calibration.microphones))
    check_writable(
        [files.audio, files.sidecar, files.truth, files.calibration, *files.mic_calibrations], force
    )
    subtype = subtype or {16: "PCM_16", 32: "PCM_32"}.get(take.bits, "PCM_24")

    n_channels = max(m.channel for m in calibration.microphones)
    data = np.zeros((take.n_samples, n_channels))
    for i, mic in enumerate(calibration.microphones):
        data[:, mic.channel - 1] = take.file_samples[:, i]
    fmt = {".flac": "FLAC", ".wav": "WAV", ".aiff": "AIFF", ".aif": "AIFF"}.get(
        files.audio.suffix.lower()
    )
    if fmt is None:
        raise ValueError(f"{files.audio}: unsupported extension; use .flac, .wav or .aiff")
    write_atomic(
        files.audio,
        lambda tmp: sf.write(tmp, data, int(round(take.fs)), subtype=subtype, format=fmt),
    )

    grid = np.linspace(0.0, take.fs / 2.0, 65)
    for path, h in zip(files.mic_calibrations, relative[1:], strict=False):
        write_mic_calibration(path, grid, np.full(grid.shape, h))

    # Sensitivity of the file: Pa per full-scale unit, with mic 1's gain error removed.
    sens = np.asarray(take.file_sensitivity) / abs(g[0])
    mics = []
    for i, mic in enumerate(calibration.microphones):
        table = None
        if files.mic_calibrations and i > 0:
            table = files.mic_calibrations[i - 1].name
        mics.append(dataclasses.replace(mic, sensitivity=float(sens[i]), calibration=table))
    cal_copy = dataclasses.replace(calibration, microphones=tuple(mics))
    header = (
        f"# Calibration for {files.audio.name}, written by mpipe {__version__} (synth-take).\n"
        f"# Copy of {calibration.source or calibration.name} with the sensitivities of the "
        "audio file (Pa per full-scale unit).\n"
    )
    write_text_atomic(
        files.calibration, header + yaml.safe_dump(calibration_mapping(cal_copy), sort_keys=False)
    )

    truth = {
        "fs": take.fs,
        "fs_model": take.fs_model,
        "p": take.p,
        "u": take.u,
        "p0": take.p0,
        "u0": take.u0,
        "mic_pressures": take.pressures,
        "temperature_c": np.atleast_1d(np.asarray(take.temperature_c, dtype=float)),
        "mach": take.mach,
        "gain_error_db": np.asarray(take.gain_error_db),
        "phase_error_deg": np.asarray(take.phase_error_deg),
        "seed": take.seed,
        "reference_plane": calibration.reference_plane,
        "mic_positions": np.asarray([m.position for m in calibration.microphones]),
    }
    truth.update(truth_extra or {})
    write_npz_atomic(files.truth, compressed=True, **truth)

    sidecar = {
        "mpipe_version": __version__,
        "audio": files.audio.name,
        "truth": files.truth.name,
        "calibration": files.calibration.name,
        "mic_calibrations": [p.name for p in files.mic_calibrations],
        "source_calibration": calibration.source,
        "recipe": _plain(dict(recipe or {})),
        "noise_seed": take.seed,
        "fs_hz": take.fs,
        "fs_model_hz": take.fs_model,
        "n_samples": take.n_samples,
        "duration_s": take.duration,
        "subtype": subtype,
        "full_scale": take.full_scale,
        "channels": [m.channel for m in calibration.microphones],
        "file_sensitivity_pa": [float(s) for s in sens],
        "temperature_c": _plain(take.temperature_c),
        "mach": take.mach,
        "gain_error_db": list(take.gain_error_db),
        "phase_error_deg": list(take.phase_error_deg),
        "snr_db": take.snr_db,
        "bits": take.bits,
        "noise_rms_recorded_units": list(take.noise_rms),
        "edge_s": take.edge_s,
        "notes": (
            "Pa = file sample x file_sensitivity_pa (TAKE.calibration.yaml holds the same "
            "values); microphone 1's phase error is not corrected by the calibration copy."
        ),
    }
    write_text_atomic(files.sidecar, yaml.safe_dump(sidecar, sort_keys=False))
    log.info("wrote %s (+ sidecar, truth, calibration)", files.audio)
    return files


def calibration_mapping(calibration: Calibration) -> dict[str, Any]:
    """A YAML-ready mapping of a calibration, accepted by ``load_calibration``.

    ``source`` is left out (the loader sets it) and so are keys whose value is None.
    """

    def convert(obj):
        if dataclasses.is_dataclass(obj):
            out = {}
            for f in dataclasses.fields(obj):
                value = getattr(obj, f.name)
                if value is None or f.name == "source":
                    continue
                out[f.name] = convert(value)
            return out
        if isinstance(obj, list | tuple):
            return [convert(v) for v in obj]
        return obj

    return convert(calibration)


def _plain(obj):
    """Convert tuples and numpy scalars to plain YAML-safe types."""
    if isinstance(obj, Mapping):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    return obj


def _per_mic(values: Sequence[float] | None, n_mics: int, name: str) -> tuple[float, ...]:
    if values is None:
        return (0.0,) * n_mics
    vals = tuple(float(v) for v in values)
    if len(vals) != n_mics or not all(math.isfinite(v) for v in vals):
        raise ValueError(
            f"{name} needs {n_mics} finite numbers, one per microphone of the calibration, "
            f"got {values!r}"
        )
    return vals


def _rate_ratio(fs: float, fs_out: float) -> tuple[int, int]:
    if not fs_out > 0:
        raise ValueError(f"output sample rate must be positive, got {fs_out} Hz")
    ratio = Fraction(fs_out / fs).limit_denominator(10_000)
    if abs(float(ratio) * fs - fs_out) > 1e-9 * fs_out:
        raise ValueError(
            f"output rate {fs_out:g} Hz is not a simple rational multiple of {fs:g} Hz"
        )
    return ratio.numerator, ratio.denominator


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


def _apply_gains(x: np.ndarray, g: np.ndarray, pad: int) -> np.ndarray:
    """Apply complex gains ``g`` (one per column) in the frequency domain.

    DC and Nyquist bins must stay real for a real signal; they get ``|g|``.
    """
    if np.allclose(g, 1.0, rtol=0, atol=0):
        return x.copy()
    n = x.shape[0]
    n_fft = scipy.fft.next_fast_len(n + 2 * pad, real=True)
    spec = scipy.fft.rfft(x, n_fft, axis=0)
    gains = np.broadcast_to(g, spec.shape).copy()
    gains[0] = np.abs(g)
    if n_fft % 2 == 0:
        gains[-1] = np.abs(g)
    return scipy.fft.irfft(spec * gains, n_fft, axis=0)[:n]
