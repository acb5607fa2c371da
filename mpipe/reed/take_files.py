"""Writing a virtual take to disk: audio, sidecar, truth and a matching calibration copy.

:func:`write_virtual_take` stores a :class:`~mpipe.reed.recording.VirtualTake` the way a
recorder and a careful experimenter would: the multichannel audio file at digital full
scale, a YAML sidecar with the recipe and the scale, the true signals in ``.npz``, and a
copy of the calibration whose sensitivities (Pa per full-scale unit) and relative
microphone tables (physics.md E.6) fit the file, so that :func:`mpipe.read_take` recovers
pascals. :func:`take_file_paths` names the files; :func:`write_mic_calibration` and
:func:`calibration_mapping` write the tables and the calibration YAML.

References
----------
Chung & Blaser 1980, JASA 68(3):907-913; physics.md E.6 (relative microphone calibration).
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import soundfile as sf
import yaml

from mpipe import __version__
from mpipe.core.io import check_writable, write_atomic, write_npz_atomic, write_text_atomic
from mpipe.measurement.calibration import Calibration
from mpipe.reed.recording import VirtualTake

log = logging.getLogger(__name__)


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
    _write_audio(files.audio, take, calibration, subtype)
    grid = np.linspace(0.0, take.fs / 2.0, 65)
    for path, h in zip(files.mic_calibrations, relative[1:], strict=False):
        write_mic_calibration(path, grid, np.full(grid.shape, h))
    # Sensitivity of the file: Pa per full-scale unit, with mic 1's gain error removed.
    sens = np.asarray(take.file_sensitivity) / abs(g[0])
    _write_calibration_copy(files, calibration, sens)
    _write_truth(files.truth, take, calibration, truth_extra)
    _write_sidecar(files, take, calibration, recipe, subtype, sens)
    log.debug("wrote %s (+ sidecar, truth, calibration)", files.audio)
    return files


#: The audio files a virtual take is written as: extension -> libsndfile's format.
AUDIO_FORMATS = {".flac": "FLAC", ".wav": "WAV", ".aiff": "AIFF", ".aif": "AIFF"}


def _write_audio(path: Path, take: VirtualTake, calibration: Calibration, subtype: str) -> None:
    """The file samples on the calibration's channels (unused channels silent)."""
    n_channels = max(m.channel for m in calibration.microphones)
    data = np.zeros((take.n_samples, n_channels))
    for i, mic in enumerate(calibration.microphones):
        data[:, mic.channel - 1] = take.file_samples[:, i]
    fmt = AUDIO_FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise ValueError(f"{path}: unsupported extension; use .flac, .wav or .aiff")
    write_atomic(
        path,
        lambda tmp: sf.write(tmp, data, int(round(take.fs)), subtype=subtype, format=fmt),
    )


def _write_calibration_copy(files: TakeFiles, calibration: Calibration, sens: np.ndarray) -> None:
    """The calibration with the file's sensitivities ``sens`` (Pa per full-scale unit).

    Their stated uncertainty is 0 dB: the virtual recorder knows them exactly.
    """
    mics = []
    for i, mic in enumerate(calibration.microphones):
        table = None
        if files.mic_calibrations and i > 0:
            table = files.mic_calibrations[i - 1].name
        # the virtual recording's sensitivities are exact: no calibration uncertainty
        mics.append(dataclasses.replace(mic, sensitivity=float(sens[i]), calibration=table,
                                        sensitivity_se_db=0.0))  # fmt: skip
    cal_copy = dataclasses.replace(calibration, microphones=tuple(mics))
    header = (
        f"# Calibration for {files.audio.name}, written by mpipe {__version__} (synth-take).\n"
        f"# Copy of {calibration.source or calibration.name} with the sensitivities of the "
        "audio file (Pa per full-scale unit).\n"
    )
    write_text_atomic(
        files.calibration, header + yaml.safe_dump(calibration_mapping(cal_copy), sort_keys=False)
    )


def _write_truth(
    path: Path, take: VirtualTake, calibration: Calibration, truth_extra: Mapping | None
) -> None:
    """True signals and parameters of the take, plus ``truth_extra``, as ``.npz``."""
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
    write_npz_atomic(path, compressed=True, **truth)


def _write_sidecar(
    files: TakeFiles,
    take: VirtualTake,
    calibration: Calibration,
    recipe: Mapping[str, Any] | None,
    subtype: str,
    sens: np.ndarray,
) -> None:
    """YAML with everything needed to reproduce the take and to read it in Pa."""
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


def calibration_mapping(calibration: Calibration) -> dict[str, Any]:
    """A YAML-ready mapping of a calibration, accepted by ``load_calibration``.

    ``source`` is left out (the loader sets it) and so are keys whose value is None;
    ``bore.open_holes`` and ``bore.measured_input`` too (the loader sets them from
    ``fingering`` and ``bore.measured``), and the fingerings are written as the file's
    mapping name -> open holes. A ``bore.measured`` path is made absolute (the copy is
    written elsewhere).
    """

    def convert(obj):
        if dataclasses.is_dataclass(obj):
            out = {}
            for f in dataclasses.fields(obj):
                value = getattr(obj, f.name)
                if value is None or f.name in ("source", "open_holes", "measured_input"):
                    continue
                out[f.name] = convert(value)
            return out
        if isinstance(obj, list | tuple):
            return [convert(v) for v in obj]
        return obj

    out = convert(calibration)
    if calibration.bore.measured_input is not None:
        out["bore"]["measured"] = calibration.bore.measured_input.source
    out["fingerings"] = {f.name: list(f.open) for f in calibration.fingerings}
    return out


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
