"""Reading takes: recordings of two or more wall microphones in Pa, checked before any analysis.

A take is one multichannel audio file (anything soundfile reads: WAV, FLAC, AIFF, ...) or
one mono file per microphone. The calibration maps microphones to channels (``channel``,
counted from 1), gives each microphone's ``sensitivity`` (Pa per unit of the recorded
signal, where a file's digital full scale is 1.0) and, optionally, a table of the complex relative
calibration H_c of the microphone against microphone 1 (physics.md E.6). The corrected
spectrum is ``P_m = sensitivity x recorded P_m / H_c``.

Relative calibration tables
---------------------------
CSV with the header ``frequency_hz,magnitude,phase_deg`` (lines starting with ``#`` are
comments), strictly increasing frequencies in Hz, magnitude > 0 (dimensionless), phase in
degrees. Magnitude and unwrapped phase are interpolated linearly in frequency; outside the
table the end values are held, but the table must cover the analysis band. The correction
is applied to the whole take with one zero-padded FFT; the DC and Nyquist bins, which must
stay real, are divided by the magnitude only.

References
----------
Chung & Blaser 1980, JASA 68(3):907-913 (relative calibration by switching); physics.md E.6;
Chatziioannou & van Walstijn 2012, section 4.
"""

from __future__ import annotations

import csv
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.fft
import soundfile as sf

from mpipe.core.errors import UserError
from mpipe.measurement.calibration import Calibration

log = logging.getLogger(__name__)

#: Upper band edge of the analysis, Hz (the paper's 7.25 kHz low-pass, physics.md E.4, F.2).
BAND_HZ = 7250.0
#: Lowest frequency a relative calibration table must reach, Hz (bins below ~20 Hz are
#: unreliable anyway, physics.md E.4).
BAND_LOW_HZ = 20.0
#: The sample rate must be at least this multiple of the band edge.
FS_FACTOR = 2.2
#: Largest tolerated fraction of samples at full scale, per channel.
MAX_CLIP_FRACTION = 1e-4
#: A channel's mean (DC offset) is refused above this fraction of its standard deviation
#: (and above ``DC_MIN_FULL_SCALE`` of full scale): microphones in a bore record acoustic
#: pressure, whose mean is a few Pa at most, and the separation keeps the pressure's DC.
DC_MAX_RATIO = 0.05
DC_MIN_FULL_SCALE = 1e-3
#: Flat tops: runs of at least this many equal samples at a channel's own maximum or
#: minimum (clipping below full scale, e.g. in a preamplifier), refused above
#: ``MAX_CLIP_FRACTION`` of the samples.
FLAT_RUN = 5
#: Plausible RMS pressure in a played wind instrument, Pa (60 to 180 dB SPL).
LEVEL_RANGE_PA = (0.02, 2.0e4)
#: Largest plausible RMS ratio between two microphones a few cm apart in one bore.
MAX_LEVEL_RATIO = 10.0
#: Shortest take, s: one 100 ms adaptive-estimation block (physics.md E.5) plus the 10 ms
#: discarded at each end after translation (physics.md F.1), with margin.
MIN_DURATION_S = 0.2
# Zero padding of the calibration FFT at each end, s.
_PAD_S = 0.05

_CSV_COLUMNS = ("frequency_hz", "magnitude", "phase_deg")


@dataclass(frozen=True, eq=False)
class Take:
    """A recording of N >= 2 wall microphones in Pa.

    Attributes
    ----------
    pressures : ndarray
        Shape ``(n, N)``: calibrated acoustic pressure at each microphone, Pa, upstream
        microphone first (the calibration's order).
    fs : float
        Sample rate, Hz.
    paths : tuple of str
        The file (one) or the N mono files the take was read from.
    channels : tuple of int
        Channel (counted from 1) of each microphone.
    clip_fraction : tuple of float
        Fraction of samples at digital full scale, per microphone.
    fs_file : float
        Sample rate of the file, Hz (``fs`` differs when the take was resampled).
    """

    pressures: np.ndarray
    fs: float
    paths: tuple[str, ...]
    channels: tuple[int, ...]
    clip_fraction: tuple[float, ...]
    fs_file: float = 0.0

    @property
    def band_limit_hz(self) -> float:
        """Highest frequency the recording holds, Hz: the file's Nyquist frequency."""
        return 0.5 * (self.fs_file or self.fs)

    @property
    def path(self) -> str:
        """The file name (for N mono files: the names joined by ``+``)."""
        return " + ".join(self.paths)

    @property
    def n_samples(self) -> int:
        """Number of samples per microphone."""
        return self.pressures.shape[0]

    @property
    def duration(self) -> float:
        """Duration in s."""
        return self.n_samples / self.fs


def read_take(
    paths: str | Path | Sequence[str | Path],
    calibration: Calibration,
    *,
    min_duration_s: float = MIN_DURATION_S,
    max_clip_fraction: float = MAX_CLIP_FRACTION,
    band_hz: float = BAND_HZ,
    band_low_hz: float = BAND_LOW_HZ,
    fs_factor: float = FS_FACTOR,
    fs: float | None = None,
    check: bool = True,
) -> Take:
    """Read a take, check it, calibrate it to Pa and bring it to the pipeline's rate.

    Parameters
    ----------
    paths : path or sequence of N paths
        One multichannel file, or one mono file per microphone (N, the calibration's
        microphone count) given in channel order (the first is channel 1); then the
        calibration must map the microphones to channels 1 to N.
    calibration : Calibration
        Channel map, sensitivities (Pa per unit) and optional relative calibration tables.
    min_duration_s : float
        Shortest acceptable take, s.
    max_clip_fraction : float
        Refuse a channel with a larger fraction of samples at digital full scale.
    band_hz : float
        Upper edge of the analysis band, Hz; the sample rate must be at least
        ``fs_factor x band_hz`` and calibration tables must reach it.
    band_low_hz : float
        Lowest frequency calibration tables must reach, Hz.
    fs_factor : float
        Required ratio of sample rate to ``band_hz``.
    fs : float, optional
        Sample rate of the pipeline, Hz: a take recorded at another rate is resampled to
        it (:func:`resample`, after the checks and the calibration), so that every command
        works at one rate whatever the interface recorded. None keeps the file's rate.
    check : bool
        Run the input sanity checks (:func:`check_take`).

    Returns
    -------
    Take
        Pressures in Pa, upstream microphone first.

    Raises
    ------
    UserError
        Naming the file (and channel) for: a missing or unreadable file, a wrong channel
        count, mono files of different lengths or rates, a sample rate too low for the band,
        a take too short, non-finite samples, clipping (at or below full scale), a DC
        offset, an implausible pressure level, channels in the wrong order, or a malformed
        calibration table or one that does not cover the band.
    """
    target = fs
    if isinstance(paths, str | Path):
        files = [Path(paths)]
    else:
        files = [Path(p) for p in paths]
    mics = calibration.microphones
    n_mics = len(mics)
    if len(files) not in (1, n_mics):
        raise UserError(
            f"a take is one multichannel file or {n_mics} mono files (one per microphone of "
            f"{calibration.source or 'the calibration'}), got {len(files)} files"
        )
    channels = tuple(m.channel for m in mics)

    if len(files) == 1:
        data, fs, subtype = _read_audio(files[0])
        name = str(files[0])
        if data.shape[1] < max(channels):
            raise UserError(
                f"{name}: has {data.shape[1]} channel{'s' if data.shape[1] != 1 else ''}, "
                f"calibration maps microphones to channels {_list(channels)}"
            )
        if data.shape[1] > max(channels):
            log.info("%s: channels beyond %d are not used", name, max(channels))
        fs_file = fs
        names = {c: name for c in channels}
        subtypes = {c: subtype for c in channels}
    else:
        if sorted(channels) != list(range(1, n_mics + 1)):
            raise UserError(
                f"{n_mics} mono files are read as channels 1 to {n_mics}, but the calibration maps "
                f"microphones to channels {_list(channels)}"
            )
        columns, rates, names, subtypes = [], [], {}, {}
        for c, f in enumerate(files, start=1):
            d, fs_c, subtype = _read_audio(f)
            if d.shape[1] != 1:
                raise UserError(
                    f"{f}: has {d.shape[1]} channels; expected a mono file when {n_mics} files "
                    "are given"
                )
            columns.append(d[:, 0])
            rates.append(fs_c)
            names[c], subtypes[c] = str(f), subtype
        for c in range(2, n_mics + 1):
            if rates[c - 1] != rates[0]:
                raise UserError(
                    f"{files[c - 1]}: sample rate {rates[c - 1]:g} Hz differs from "
                    f"{files[0]} ({rates[0]:g} Hz)"
                )
            if columns[c - 1].size != columns[0].size:
                raise UserError(
                    f"{files[c - 1]}: {columns[c - 1].size} samples differ from "
                    f"{files[0]} ({columns[0].size} samples)"
                )
        data, fs_file = np.column_stack(columns), rates[0]
        name = " + ".join(str(f) for f in files)

    fs = fs_file
    if fs < fs_factor * band_hz:
        raise UserError(
            f"{name}: sample rate {fs:g} Hz is too low for the {band_hz:g} Hz band "
            f"(need at least {fs_factor:g} x {band_hz:g} = {fs_factor * band_hz:g} Hz)"
        )
    duration = data.shape[0] / fs
    if duration < min_duration_s:
        raise UserError(
            f"{name}: take is {duration:.3g} s long, shorter than one analysis block "
            f"(minimum {min_duration_s:g} s)"
        )

    raw = np.empty((data.shape[0], n_mics))
    clip = []
    for i, (mic, c) in enumerate(zip(mics, channels, strict=True)):
        x = data[:, c - 1]
        where = f"{names[c]}: channel {c} ({mic.name})"
        bad = np.flatnonzero(~np.isfinite(x))
        if bad.size:
            raise UserError(
                f"{where}: {bad.size} non-finite samples (first at sample {bad[0]}, "
                f"t = {bad[0] / fs:.6g} s)"
            )
        frac = float(np.mean(np.abs(x) >= _full_scale_threshold(subtypes[c])))
        if frac > max_clip_fraction:
            raise UserError(
                f"{where}: {100 * frac:.3g} % of samples at full scale (limit "
                f"{100 * max_clip_fraction:.3g} %); the take is clipped"
            )
        if frac > 0:
            log.warning("%s: %.3g %% of samples at full scale", where, 100 * frac)
        clip.append(frac)
        raw[:, i] = x * mic.sensitivity

    for i, mic in enumerate(mics):
        table = calibration.calibration_path(mic)
        if table is None:
            continue
        freqs, h = read_mic_calibration(table, band=(band_low_hz, band_hz))
        raw[:, i] = _divide_response(raw[:, i], fs, freqs, h)
        log.debug("%s: applied relative calibration %s", mic.name, table)

    if check:
        # after every file-format and calibration-table error: these are about the signal
        for mic, c in zip(mics, channels, strict=True):
            _check_channel(
                data[:, c - 1], f"{names[c]}: channel {c} ({mic.name})", max_clip_fraction
            )
        check_take(raw, fs, calibration, name)
    from mpipe.measurement.microphones import (
        level_warning,  # plausible, yet no clarinet plays there
    )

    if (warning := level_warning(raw, name)) is not None:
        log.warning("%s", warning)
    out_fs = float(fs)
    if target is not None and abs(target - fs) > 1e-9 * fs:
        log.info("%s: resampling %g Hz -> %g Hz (the pipeline's rate)", name, fs, target)
        raw = resample(raw, fs, target)
        out_fs = float(target)
    return Take(
        pressures=raw,
        fs=out_fs,
        paths=tuple(str(f) for f in files),
        channels=channels,  # type: ignore[arg-type]
        clip_fraction=tuple(clip),  # type: ignore[arg-type]
        fs_file=float(fs),
    )


# Anti-aliasing window of resample_poly: scipy's default (Kaiser beta 5) ripples by ~1e-3 in
# the pass band; beta 10 keeps the gain within 1e-5 over the analysis band.
_RESAMPLE_WINDOW = ("kaiser", 10.0)


def resample(x: np.ndarray, fs_from: float, fs_to: float) -> np.ndarray:
    """Resample signals along axis 0 with a polyphase filter (``scipy.signal.resample_poly``).

    The one place where mpipe changes a sample rate, shared by every command: takes at
    the pipeline's rate, mouthpiece signals at the inversion's rate.

    Parameters
    ----------
    x : ndarray
        Signals, time along axis 0.
    fs_from, fs_to : float
        Sample rates in Hz; their ratio must be rational with a denominator below 10000
        (any pair of integer rates in Hz up to 10 MHz qualifies after reduction).

    Returns
    -------
    ndarray
        ``round(n fs_to / fs_from)`` samples (up to one sample more from the filter).

    Raises
    ------
    ValueError
        When the ratio is not such a fraction (e.g. a non-integer rate in Hz).
    """
    from fractions import Fraction

    from scipy import signal

    ratio = Fraction(fs_to / fs_from).limit_denominator(10_000)
    if abs(float(ratio) - fs_to / fs_from) > 1e-9 * fs_to / fs_from:
        raise ValueError(
            f"cannot resample {fs_from:g} Hz to {fs_to:g} Hz: the ratio is not a simple fraction"
        )
    if ratio == 1:
        return np.array(x, dtype=float)
    return signal.resample_poly(
        x, ratio.numerator, ratio.denominator, axis=0, window=_RESAMPLE_WINDOW
    )


def _check_channel(x: np.ndarray, where: str, max_fraction: float) -> None:
    """DC offset and flat tops of one channel (recorded units, full scale 1)."""
    mean = float(np.mean(x))
    std = float(np.std(x))
    if abs(mean) > DC_MIN_FULL_SCALE and abs(mean) > DC_MAX_RATIO * std:
        raise UserError(
            f"{where}: DC offset of {mean:+.3g} of full scale ({abs(mean) / max(std, 1e-300):.2g}"
            " x its RMS about the mean); expected an AC-coupled pressure signal near 0 "
            "(remove the offset or high-pass the take)"
        )
    hi, lo = float(np.max(x)), float(np.min(x))
    if hi == lo:
        raise UserError(f"{where}: constant signal ({hi:g}); expected a recorded pressure")
    flat = 0
    for value in (hi, lo):
        at = np.concatenate([[False], x == value, [False]])
        edges = np.flatnonzero(np.diff(at.astype(np.int8)))
        runs = edges[1::2] - edges[::2]
        flat += int(np.sum(runs[runs >= FLAT_RUN]))
    if flat > max_fraction * x.size:
        raise UserError(
            f"{where}: {100 * flat / x.size:.3g} % of samples in flat tops at {hi:+.3g} / "
            f"{lo:+.3g} of full scale; the take is clipped below full scale (preamplifier "
            "or converter input)"
        )


def check_take(pressures: np.ndarray, fs: float, calibration: Calibration, name: str) -> None:
    """Input sanity of a calibrated take, each failure one line naming what is wrong.

    Checks (cheap, before any long work): every channel's RMS pressure lies in
    ``LEVEL_RANGE_PA`` and no two differ by more than ``MAX_LEVEL_RATIO`` (a sensitivity
    off by orders of magnitude); and the channels are in the calibration's order
    (:func:`mpipe.measurement.separation.check_channel_order`: the middle microphone lies between
    the others in a smooth low-frequency field, and acoustic power flows towards the
    bell).

    Raises
    ------
    UserError
        On the first failed check.
    """
    from mpipe.measurement.separation.checks import check_channel_order

    mics = calibration.microphones
    rms = np.sqrt(np.mean((pressures - np.mean(pressures, axis=0)) ** 2, axis=0))
    lo, hi = LEVEL_RANGE_PA
    for i, mic in enumerate(mics):
        if not lo <= rms[i] <= hi:
            spl = 20 * np.log10(max(rms[i], 1e-300) / 2e-5)
            raise UserError(
                f"{name}: channel {mic.channel} ({mic.name}): RMS pressure {rms[i]:.3g} Pa "
                f"({spl:.0f} dB SPL) is implausible in a played instrument (expected "
                f"{lo:g}-{hi:g} Pa); check microphones[{i}].sensitivity "
                f"({mic.sensitivity:g} Pa per full-scale unit)"
            )
    j, k = int(np.argmax(rms)), int(np.argmin(rms))
    if rms[j] > MAX_LEVEL_RATIO * rms[k]:
        raise UserError(
            f"{name}: channel {mics[j].channel} ({mics[j].name}) is "
            f"{20 * np.log10(rms[j] / rms[k]):.0f} dB louder than channel {mics[k].channel} "
            f"({mics[k].name}), a few cm apart in one bore; check the sensitivities "
            f"microphones[{j}] and [{k}]"
        )
    problem = check_channel_order(pressures, fs, calibration)
    if problem:
        raise UserError(f"{name}: {problem}")


def read_mic_calibration(
    path: str | Path, band: tuple[float, float] | None = (BAND_LOW_HZ, BAND_HZ)
) -> tuple[np.ndarray, np.ndarray]:
    """Read a relative microphone calibration table (physics.md E.6).

    Parameters
    ----------
    path : str or Path
        CSV with the header ``frequency_hz,magnitude,phase_deg``.
    band : (float, float), optional
        Frequencies in Hz the table must cover; None skips the check.

    Returns
    -------
    freqs : ndarray
        Frequencies, Hz, strictly increasing.
    H : ndarray
        Complex H_c (dimensionless), with the phase unwrapped along frequency.

    Raises
    ------
    UserError
        Naming the file and line for a missing file, a wrong header, a non-numeric or
        non-finite value, non-increasing frequencies, a magnitude <= 0, or a table that does
        not cover ``band``.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise UserError(f"{path}: cannot read microphone calibration: {exc.strerror}") from None
    rows = []
    header = None
    for lineno, row in enumerate(csv.reader(text.splitlines()), start=1):
        if not row or not "".join(row).strip() or row[0].lstrip().startswith("#"):
            continue
        if header is None:
            header = tuple(c.strip().lower() for c in row)
            if header != _CSV_COLUMNS:
                raise UserError(
                    f"{path}: line {lineno}: expected the header {','.join(_CSV_COLUMNS)}, "
                    f"got {','.join(row)}"
                )
            continue
        if len(row) != 3:
            raise UserError(f"{path}: line {lineno}: expected 3 values, got {len(row)}")
        try:
            values = [float(v) for v in row]
        except ValueError:
            raise UserError(
                f"{path}: line {lineno}: expected numbers, got {','.join(row)}"
            ) from None
        if not all(math.isfinite(v) for v in values):
            raise UserError(f"{path}: line {lineno}: non-finite value")
        if values[1] <= 0:
            raise UserError(f"{path}: line {lineno}: magnitude must be > 0, got {values[1]:g}")
        rows.append(values)
    if header is None:
        raise UserError(f"{path}: empty; expected the header {','.join(_CSV_COLUMNS)}")
    if len(rows) < 2:
        raise UserError(f"{path}: expected at least two rows of data, got {len(rows)}")
    table = np.asarray(rows)
    freqs = table[:, 0]
    if np.any(np.diff(freqs) <= 0):
        i = int(np.flatnonzero(np.diff(freqs) <= 0)[0])
        raise UserError(
            f"{path}: frequencies must increase strictly ({freqs[i + 1]:g} Hz follows "
            f"{freqs[i]:g} Hz)"
        )
    if band is not None and (freqs[0] > band[0] or freqs[-1] < band[1]):
        raise UserError(
            f"{path}: covers {freqs[0]:g}-{freqs[-1]:g} Hz, which does not include the band "
            f"{band[0]:g}-{band[1]:g} Hz"
        )
    phase = np.unwrap(np.deg2rad(table[:, 2]))
    return freqs, table[:, 1] * np.exp(1j * phase)


def _divide_response(x: np.ndarray, fs: float, freqs: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Divide the spectrum of ``x`` by the interpolated H (magnitude, unwrapped phase)."""
    n = x.size
    pad = int(_PAD_S * fs)
    n_fft = scipy.fft.next_fast_len(n + 2 * pad, real=True)
    spec = scipy.fft.rfft(x, n_fft)
    f = np.arange(spec.size) * fs / n_fft
    mag = np.interp(f, freqs, np.abs(h))
    phase = np.interp(f, freqs, np.unwrap(np.angle(h)))
    resp = mag * np.exp(1j * phase)
    # DC and Nyquist of a real signal are real: divide them by the magnitude only
    resp[0] = mag[0]
    if n_fft % 2 == 0:
        resp[-1] = mag[-1]
    return scipy.fft.irfft(spec / resp, n_fft)[:n]


def _read_audio(path: Path) -> tuple[np.ndarray, float, str]:
    """Samples (n, channels) scaled to full scale 1.0, the rate in Hz and the subtype."""
    if not path.exists():
        raise UserError(f"{path}: no such file")
    if not path.is_file():
        raise UserError(f"{path}: not a file")
    try:
        info = sf.info(str(path))
        data, fs = sf.read(str(path), dtype="float64", always_2d=True)
    except (RuntimeError, OSError, TypeError, ValueError) as exc:
        # soundfile raises LibsndfileError (a RuntimeError) for unknown or damaged files
        raise UserError(f"{path}: cannot read audio: {exc}") from None
    return data, float(fs), info.subtype


def _full_scale_threshold(subtype: str) -> float:
    """Smallest |sample| counted as digital full scale for a soundfile subtype.

    For an N-bit integer format the largest positive code reads as 1 - 2^(1-N) and the
    most negative as -1; half a step below the former counts. Float formats use 1.0.
    """
    bits = {"PCM_S8": 8, "PCM_U8": 8, "PCM_16": 16, "PCM_24": 24, "PCM_32": 32}.get(subtype)
    if bits is None:
        return 1.0
    return 1.0 - 1.5 * 2.0 ** (1 - bits)


def _list(channels: Sequence[int]) -> str:
    return ", ".join(str(c) for c in channels)
