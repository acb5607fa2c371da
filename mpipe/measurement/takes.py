"""Reading takes: recordings of two or more wall microphones in Pa, checked before any analysis.

A take is one multichannel audio file (anything soundfile reads: WAV, FLAC, AIFF, ...) or
one mono file per microphone. The calibration maps microphones to channels (``channel``,
counted from 1), gives each microphone's ``sensitivity`` (Pa per unit of the recorded
signal, where a file's digital full scale is 1.0) and, optionally, a table of the complex relative
calibration H_c of the microphone against microphone 1 (physics.md E.6). The corrected
spectrum is ``P_m = sensitivity x recorded P_m / H_c``.

The format of the relative calibration tables and their application are in
:mod:`mpipe.measurement.calibration_tables`; the sanity checks of a take and their limits in
:mod:`mpipe.measurement.take_checks`.

References
----------
Chung & Blaser 1980, JASA 68(3):907-913 (relative calibration by switching); physics.md E.6;
Chatziioannou & van Walstijn 2012, section 4.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import soundfile as sf

from mpipe.core.errors import UserError
from mpipe.core.resampling import rate_ratio, resample_blocks
from mpipe.measurement.calibration import Calibration
from mpipe.measurement.calibration_tables import divide_response_blocks, read_mic_calibration
from mpipe.measurement.microphones import level_warning
from mpipe.measurement.take_checks import (
    BAND_HZ,
    BAND_LOW_HZ,
    FS_FACTOR,
    MAX_CLIP_FRACTION,
    MIN_DURATION_S,
    check_channel,
    check_finite,
    check_note,
    check_rate_and_duration,
    check_take,
    clip_fraction,
)

log = logging.getLogger(__name__)


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
        it (:func:`mpipe.core.resampling.resample`, in blocks, after the checks and the
        calibration), so that every command works at one rate whatever the interface
        recorded. None keeps the file's rate.
    check : bool
        Run the input sanity checks (:func:`mpipe.measurement.take_checks.check_take`).

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
    data, fs, name, names, subtypes = _read_files(files, calibration)
    check_rate_and_duration(name, fs, data.shape[0], band_hz, fs_factor, min_duration_s)
    raw, clip = _to_pascal(data, fs, calibration, names, subtypes, max_clip_fraction)
    _apply_relative_calibration(raw, fs, calibration, (band_low_hz, band_hz))
    mics = calibration.microphones
    channels = tuple(m.channel for m in mics)
    if check:
        # after every file-format and calibration-table error: these are about the signal;
        # no note first (a static pressure alone reads as a DC offset), unless the level
        # says the sensitivities are off (the warning below names them)
        if level_warning(raw, name) is None:
            check_note(raw, fs, calibration, name)
        for mic, c in zip(mics, channels, strict=True):
            check_channel(
                data[:, c - 1], f"{names[c]}: channel {c} ({mic.name})", max_clip_fraction
            )
        check_take(raw, fs, calibration, name)

    if (warning := level_warning(raw, name)) is not None:
        log.warning("%s", warning)
    del data  # the file's samples: not held while the take is resampled
    out_fs = float(fs)
    if target is not None and abs(target - fs) > 1e-9 * fs:
        log.info("%s: resampling %g Hz -> %g Hz (the pipeline's rate)", name, fs, target)
        raw = _resampled(raw, fs, target)
        out_fs = float(target)
    return Take(
        pressures=raw,
        fs=out_fs,
        paths=tuple(str(f) for f in files),
        channels=channels,  # type: ignore[arg-type]
        clip_fraction=tuple(clip),  # type: ignore[arg-type]
        fs_file=float(fs),
    )


def _resampled(raw: np.ndarray, fs: float, target: float) -> np.ndarray:
    """:func:`mpipe.core.resampling.resample`, a block at a time into one array.

    :func:`mpipe.core.resampling.resample_blocks`: the same samples to 1e-12 of the peak,
    with no whole-take intermediates (the polyphase filter's upsampled copy).
    """
    up, down, _ = rate_ratio(fs, target)
    out = np.empty((-(-raw.shape[0] * up // down), raw.shape[1]))
    for j, y in resample_blocks(raw, fs, target):
        out[j : j + y.shape[0]] = y
    return out


def _read_files(
    files: list[Path], calibration: Calibration
) -> tuple[np.ndarray, float, str, dict[int, str], dict[int, str]]:
    """Samples ``(n, channels)`` of one multichannel file or N mono files, full scale 1.0.

    Returns the samples, the rate in Hz, the take's name, and the file name and soundfile
    subtype of each mapped channel.
    """
    n_mics = len(calibration.microphones)
    if len(files) not in (1, n_mics):
        raise UserError(
            f"a take is one multichannel file or {n_mics} mono files (one per microphone of "
            f"{calibration.source or 'the calibration'}), got {len(files)} files"
        )
    channels = tuple(m.channel for m in calibration.microphones)
    if len(files) == 1:
        return _read_multichannel(files[0], channels)
    return _read_mono_files(files, channels)


def _read_multichannel(
    path: Path, channels: tuple[int, ...]
) -> tuple[np.ndarray, float, str, dict[int, str], dict[int, str]]:
    """One file holding (at least) every mapped channel."""
    data, fs, subtype = _read_audio(path)
    name = str(path)
    if data.shape[1] < max(channels):
        raise UserError(
            f"{name}: has {data.shape[1]} channel{'s' if data.shape[1] != 1 else ''}, "
            f"calibration maps microphones to channels {_list(channels)}"
        )
    if data.shape[1] > max(channels):
        log.info("%s: channels beyond %d are not used", name, max(channels))
    names = {c: name for c in channels}
    subtypes = {c: subtype for c in channels}
    return data, fs, name, names, subtypes


def _read_mono_files(
    files: list[Path], channels: tuple[int, ...]
) -> tuple[np.ndarray, float, str, dict[int, str], dict[int, str]]:
    """N mono files of one rate and length, read as channels 1 to N."""
    n_mics = len(files)
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
    name = " + ".join(str(f) for f in files)
    return np.column_stack(columns), rates[0], name, names, subtypes


def _to_pascal(
    data: np.ndarray,
    fs: float,
    calibration: Calibration,
    names: dict[int, str],
    subtypes: dict[int, str],
    max_clip_fraction: float,
) -> tuple[np.ndarray, list[float]]:
    """Each microphone's channel checked (finite, not clipped) and scaled by its sensitivity.

    Returns the pressures ``(n, N)`` in Pa and each microphone's fraction at full scale.
    """
    mics = calibration.microphones
    raw = np.empty((data.shape[0], len(mics)))
    clip = []
    for i, mic in enumerate(mics):
        c = mic.channel
        x = data[:, c - 1]
        where = f"{names[c]}: channel {c} ({mic.name})"
        check_finite(x, where, fs)
        frac = clip_fraction(x, subtypes[c], where, max_clip_fraction)
        if frac > 0:
            log.warning("%s: %.3g %% of samples at full scale", where, 100 * frac)
        clip.append(frac)
        raw[:, i] = x * mic.sensitivity
    return raw, clip


def _apply_relative_calibration(
    raw: np.ndarray, fs: float, calibration: Calibration, band: tuple[float, float]
) -> None:
    """Divide each microphone's pressure (in place) by its relative calibration table."""
    for i, mic in enumerate(calibration.microphones):
        table = calibration.calibration_path(mic)
        if table is None:
            continue
        freqs, h = read_mic_calibration(table, band=band)
        # as a filter, a block at a time: no FFT of the whole take (docs/memory.md)
        raw[:, i] = divide_response_blocks(raw[:, i], fs, freqs, h)
        log.debug("%s: applied relative calibration %s", mic.name, table)


def _read_audio(path: Path) -> tuple[np.ndarray, float, str]:
    """Samples (n, channels) scaled to full scale 1.0, the rate in Hz and the subtype."""
    if not path.exists():
        raise UserError(f"{path}: no such file")
    if not path.is_file():
        raise UserError(f"{path}: not a file")
    try:
        # opened here, not by libsndfile, so that a refused open is named as such (libsndfile
        # says "System error")
        with path.open("rb") as f:
            info = sf.info(f)
            f.seek(0)
            data, fs = sf.read(f, dtype="float64", always_2d=True)
    except PermissionError:
        raise UserError(f"{path}: permission denied (cannot open the file for reading)") from None
    except (RuntimeError, OSError, TypeError, ValueError) as exc:
        # soundfile raises LibsndfileError (a RuntimeError) for unknown or damaged files
        raise UserError(f"{path}: cannot read audio: {exc}") from None
    return data, float(fs), info.subtype


def _list(channels: Sequence[int]) -> str:
    return ", ".join(str(c) for c in channels)
