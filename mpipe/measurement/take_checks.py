"""Sanity checks of a take: limits a recording of a played instrument must meet.

Each check raises a :class:`~mpipe.core.errors.UserError` of one line naming the file,
channel and what is wrong, before any long work. :func:`mpipe.measurement.takes.read_take`
runs them on the recorded samples (full scale 1.0) and on the pressures in Pa.

References
----------
physics.md E.4-E.6, F.1.
"""

from __future__ import annotations

import numpy as np

from mpipe.core.errors import UserError
from mpipe.measurement.calibration import Calibration
from mpipe.measurement.separation.checks import check_channel_order

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
#: A take holds a note when some channel oscillates by at least this, Pa rms about its mean,
#: for ``NOTE_MIN_S`` (frames of ``NOTE_FRAME_S``): the default ``conditioning.min_rms_pa``,
#: below which the pipeline calls a window silent (a played clarinet's mouthpiece: 1-5 kPa).
#: Not one frame: the bore rings for a few tens of ms when a mouth pressure under the
#: blowing threshold starts or stops.
NOTE_MIN_RMS_PA = 10.0
NOTE_FRAME_S = 0.025
NOTE_MIN_S = 0.1
#: Shortest take, s: one 100 ms adaptive-estimation block (physics.md E.5) plus the 10 ms
#: discarded at each end after translation (physics.md F.1), with margin.
MIN_DURATION_S = 0.2


def check_rate_and_duration(
    name: str, fs: float, n_samples: int, band_hz: float, fs_factor: float, min_duration_s: float
) -> None:
    """A sample rate of at least ``fs_factor x band_hz`` and a take of ``min_duration_s``."""
    if fs < fs_factor * band_hz:
        raise UserError(
            f"{name}: sample rate {fs:g} Hz is too low for the {band_hz:g} Hz band "
            f"(need at least {fs_factor:g} x {band_hz:g} = {fs_factor * band_hz:g} Hz)"
        )
    duration = n_samples / fs
    if duration < min_duration_s:
        raise UserError(
            f"{name}: take is {duration:.3g} s long, shorter than one analysis block "
            f"(minimum {min_duration_s:g} s)"
        )


def check_finite(x: np.ndarray, where: str, fs: float) -> None:
    """Every sample of one channel is finite (the first bad one is named, with its time)."""
    bad = np.flatnonzero(~np.isfinite(x))
    if bad.size:
        raise UserError(
            f"{where}: {bad.size} non-finite samples (first at sample {bad[0]}, "
            f"t = {bad[0] / fs:.6g} s)"
        )


def clip_fraction(x: np.ndarray, subtype: str, where: str, max_clip_fraction: float) -> float:
    """Fraction of one channel's samples at digital full scale, refused above the limit."""
    frac = float(np.mean(np.abs(x) >= full_scale_threshold(subtype)))
    if frac > max_clip_fraction:
        raise UserError(
            f"{where}: {100 * frac:.3g} % of samples at full scale (limit "
            f"{100 * max_clip_fraction:.3g} %); the take is clipped"
        )
    return frac


def full_scale_threshold(subtype: str) -> float:
    """Smallest |sample| counted as digital full scale for a soundfile subtype.

    For an N-bit integer format the largest positive code reads as 1 - 2^(1-N) and the
    most negative as -1; half a step below the former counts. A float file (``FLOAT``,
    ``DOUBLE``) has no full scale: samples beyond 1.0 are stored as they are, so none counts
    (a clipped float take is caught by its flat tops, :func:`check_channel`). Other formats
    use 1.0.
    """
    if subtype in ("FLOAT", "DOUBLE"):
        return float("inf")
    bits = {"PCM_S8": 8, "PCM_U8": 8, "PCM_16": 16, "PCM_24": 24, "PCM_32": 32}.get(subtype)
    if bits is None:
        return 1.0
    return 1.0 - 1.5 * 2.0 ** (1 - bits)


def check_channel(x: np.ndarray, where: str, max_fraction: float) -> None:
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


def check_note(pressures: np.ndarray, fs: float, calibration: Calibration, name: str) -> None:
    """Refuse a take in which no note sounds, naming the level found and the threshold.

    The level is the one the take holds for ``NOTE_MIN_S``: the RMS about its own mean of
    each ``NOTE_FRAME_S`` frame (the loudest channel's), the ``NOTE_MIN_S``-th loudest
    frame's, Pa. A breath or a mouth pressure under the blowing threshold stays far below
    ``NOTE_MIN_RMS_PA``. Checked before the DC offset, which such a take (a static pressure
    and no oscillation) would otherwise be blamed on.

    Raises
    ------
    UserError
        When the take does not oscillate by ``NOTE_MIN_RMS_PA`` for ``NOTE_MIN_S``.
    """
    frame = max(int(round(NOTE_FRAME_S * fs)), 2)
    n = pressures.shape[0] // frame
    need = max(int(round(NOTE_MIN_S / NOTE_FRAME_S)), 1)
    if n < need:
        return  # too short to tell (refused as too short anyway)
    frames = np.asarray(pressures[: n * frame]).reshape(n, frame, -1)
    levels = np.max(np.std(frames, axis=1), axis=1)
    level = float(np.sort(levels)[-need])
    if level < NOTE_MIN_RMS_PA:
        sens = ", ".join(f"{m.sensitivity:g}" for m in calibration.microphones)
        raise UserError(
            f"{name}: no note found: the take oscillates by {level:.3g} Pa rms at most over "
            f"{NOTE_MIN_S:g} s, below the {NOTE_MIN_RMS_PA:g} Pa of a sounding note "
            "(conditioning.min_rms_pa's default); expected a played note (or check the "
            f"microphones' sensitivities, {sens} Pa per full-scale unit)"
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


#: Frames of the polarity check, s (two periods of the lowest clarinet note).
POLARITY_FRAME_S = 0.02
#: A beating reed holds the flow at its minimum (closed) for at least this fraction of the
#: sounding time; the polarity is called inverted when the flow's maximum holds instead,
#: ``POLARITY_RATIO`` times longer than its minimum.
POLARITY_PLATEAU = 0.15
POLARITY_RATIO = 3.0


def plateau_fractions(u: np.ndarray, p: np.ndarray, fs: float) -> tuple[float, float]:
    """Fractions of the sounding time the flow spends near its minimum and its maximum.

    Per ``POLARITY_FRAME_S`` frame whose pressure oscillates by ``NOTE_MIN_RMS_PA``: the
    samples within 10 % of the frame's range of its minimum, and of its maximum. A beating
    reed, shut for part of each period, holds the flow into the instrument at its minimum
    (zero, the zero-mean flow's lowest value): a long floor and short peaks. Inverting the
    sign of every channel inverts p and u alike and leaves ``Z = P / U`` (the validation)
    unchanged, but turns the floor into a ceiling.
    """
    frame = max(int(round(POLARITY_FRAME_S * fs)), 4)
    n = min(u.size, p.size) // frame
    if n == 0:
        return 0.0, 0.0
    uf = np.asarray(u[: n * frame], dtype=float).reshape(n, frame)
    sounding = np.std(np.asarray(p[: n * frame], dtype=float).reshape(n, frame), axis=1)
    uf = uf[sounding >= NOTE_MIN_RMS_PA]
    if uf.size == 0:
        return 0.0, 0.0
    lo, hi = uf.min(axis=1, keepdims=True), uf.max(axis=1, keepdims=True)
    band = 0.1 * (hi - lo)
    return float(np.mean(uf <= lo + band)), float(np.mean(uf >= hi - band))


def check_polarity(u: np.ndarray, p: np.ndarray, fs: float, name: str) -> None:
    """Refuse mouthpiece signals whose every channel was recorded with inverted polarity.

    Raises
    ------
    UserError
        When the flow holds its maximum (:func:`plateau_fractions`) for at least
        ``POLARITY_PLATEAU`` of the sounding time and ``POLARITY_RATIO`` times longer than
        its minimum.
    """
    floor, ceiling = plateau_fractions(u, p, fs)
    if ceiling >= POLARITY_PLATEAU and ceiling >= POLARITY_RATIO * floor:
        raise UserError(
            f"{name}: all channels' polarity inverted: the mouthpiece flow holds its maximum "
            f"for {100 * ceiling:.0f} % of the sounding time and its minimum for "
            f"{100 * floor:.0f} % (a beating reed, shut, holds it at its minimum); invert "
            "every channel (or the sign of every microphones[].sensitivity)"
        )
