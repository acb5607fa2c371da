"""Virtual takes with known truth: the reed model played on a bore, recorded by wall microphones.

Runs the reed model (:mod:`mpipe.reed.model`) on the calibration's bore, records the mouthpiece
signals with the virtual microphones (:mod:`mpipe.reed.recording`) and writes the audio file,
its sidecar, the truth and a calibration copy that fits the file (:func:`make_take`, what
``mpipe synth-take`` runs).
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from mpipe.acoustics.reflection import reflection_function
from mpipe.cli.commands import load_one_fingering
from mpipe.core.errors import UserError
from mpipe.core.io import check_not_inputs, check_writable
from mpipe.measurement.calibration import Calibration
from mpipe.reed.bore_kernel import prepare_bore
from mpipe.reed.controls import control_curves, make_controls, play
from mpipe.reed.fingered_bore import fingered_bore
from mpipe.reed.parameters import load_reed
from mpipe.reed.recorder import RecorderOptions
from mpipe.reed.recording import VirtualTake, virtual_recording
from mpipe.reed.score import load_score, score_controls, score_mapping
from mpipe.reed.take_files import AUDIO_FORMATS, TakeFiles, take_file_paths
from mpipe.reed.take_files import write_virtual_take as _write

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SynthOptions:
    """How to synthesise a take.

    Attributes
    ----------
    duration_s : float or None
        Length of the take, s; with a score, None takes the score's length.
    fs_model : float
        Sample rate of the model and of the virtual field, Hz.
    fs_out : float or None
        Sample rate of the file, Hz (None: ``fs_model``).
    temperature_c : float, (float, float) or None
        Air temperature in degC, or a linear drift (start, end); None: the calibration's.
        The reed model's reflection function uses the mean temperature.
    mach : float or "auto"
        Mean-flow Mach number at the microphones; "auto" takes it from the simulated mean
        flow, ``M = mean(u) / (S_main c)`` (physics.md E.1).
    snr_db : float or None
        Signal-to-noise ratio of the microphone noise per channel, dB.
    gain_error_db, phase_error_deg : tuple of float or None
        Microphone errors, dB and degrees, one per microphone of the calibration, upstream
        microphone first (None: no error).
    swell : float
        Relative rise of the mouth pressure over the take (0.1: p_m rises linearly to 1.1 p_m).
    breath_noise_pa : float
        Standard deviation of white noise on the mouth pressure, Pa.
    onset_s : float
        Raised-cosine rise time of the mouth pressure, s.
    seed : int
        Master seed; the breath noise and the microphone noise use independent child seeds.
    bits : int
        Word length of the file (16 or 24 for FLAC).
    mic_calibration : bool
        Write the exact relative calibration tables of microphones 2 to N.
    score : str or None
        A score file (:mod:`mpipe.reed.score`): the notes, silences and control curves the
        virtual player plays. Sets the mouth pressure, so ``swell`` must be 0 (each note has
        its own attack; ``onset_s`` is not used).
    chunk_s : float
        Length of the pieces over which reed parameters that vary are held, s
        (:mod:`mpipe.reed.controls`).
    fingering : str or None
        The fingering played (one name of the calibration's fingerings; not ``auto`` nor a
        list: a score gives per-note fingerings); None: its default.
    """

    duration_s: float | None
    fs_model: float = 100_000.0
    fs_out: float | None = None
    temperature_c: float | tuple[float, float] | None = None
    mach: float | str = 0.0
    snr_db: float | None = None
    gain_error_db: tuple[float, ...] | None = None
    phase_error_deg: tuple[float, ...] | None = None
    swell: float = 0.0
    breath_noise_pa: float = 0.0
    onset_s: float = 0.01
    seed: int = 0
    bits: int = 24
    mic_calibration: bool = True
    score: str | None = None
    chunk_s: float = 1e-3
    fingering: str | None = None


def child_seeds(seed: int) -> tuple[int, int]:
    """Independent seeds for the breath noise and the microphone noise, from one seed."""
    children = np.random.SeedSequence(seed).spawn(2)
    return tuple(int(c.generate_state(1)[0]) for c in children)  # type: ignore[return-value]


def synthesize(calibration: Calibration, reed, options: SynthOptions, score=None):
    """Simulate the instrument and record it with the virtual microphones.

    Parameters
    ----------
    calibration : Calibration
        Instrument, microphones and air.
    reed : mpipe.reed.parameters.ReedParameters
        Reed parameters (SI units); ``reed.p_m`` is the mouth pressure at the start.
    options : SynthOptions
        Duration, rates, air, errors, noise and seed.
    score : mpipe.reed.score.Score, optional
        The notes to play (overrides ``options.score``, which is then not read).

    Returns
    -------
    take : VirtualTake
        The recording and its truth.
    run : mpipe.reed.controls.PlayedRun
        The model run at ``options.fs_model`` (``run.controls``: what the player did).
    mach : float
        The Mach number used.

    Notes
    -----
    Without a score the mouth pressure is ``p_m (1 + swell t / T)`` with an onset of
    ``onset_s``, the reed constant: one run of the model, the numbers of mpipe 0.1.

    References
    ----------
    Chatziioannou & van Walstijn 2012, Appendix A (model) and section 4 (measurement).
    """
    if score is None and options.score is not None:
        score = load_score(options.score)
    _check_options(options, score is not None)
    temp = options.temperature_c
    if isinstance(temp, tuple):
        t_model = 0.5 * (temp[0] + temp[1])
    else:
        t_model = calibration.air.temperature_c if temp is None else float(temp)
    air = calibration.air_properties(t_model)
    fs = options.fs_model
    if score is not None:
        controls = score_controls(score, reed, fs, options.duration_s)
        onset = 0.0
    else:
        n = int(round(options.duration_s * fs))
        t = np.arange(1, n + 1) / fs
        controls = make_controls(fs, n, reed.p_m * (1.0 + options.swell * t / options.duration_s))
        onset = options.onset_s
    rf = reflection_function(calibration.bore, air, fs)
    kernel = prepare_bore(rf, air)
    fingered = None if score is None else score_bore(calibration, score, air, fs, controls)
    breath_seed, noise_seed = child_seeds(options.seed)
    n = controls.n_samples
    log.info("simulating %.3g s at %g Hz (air at %g degC)", n / fs, fs, t_model)
    run = play(
        reed,
        kernel,
        controls,
        onset_s=onset,
        noise_std_pa=options.breath_noise_pa,
        seed=breath_seed,
        chunk_s=options.chunk_s,
        fingered=fingered,
    )
    if not np.all(np.isfinite(run.p)):
        raise ValueError("the simulation diverged; check the reed parameters")
    for line in silent_notes(run):
        log.warning("%s", line)
    if options.mach == "auto":
        area = np.pi * calibration.main_radius**2
        mach = float(np.mean(run.u[n // 2 :]) / (area * air.c))
    else:
        mach = float(options.mach)
    take = virtual_recording(
        run.p,
        run.u,
        fs,
        calibration,
        temperature_c=temp,
        mach=mach,
        recorder=RecorderOptions(
            gain_error_db=options.gain_error_db,
            phase_error_deg=options.phase_error_deg,
            snr_db=options.snr_db,
            bits=options.bits,
            fs_out=options.fs_out,
            seed=noise_seed,
        ),
        upstream=upstream_fingerings(calibration, score, fingered, n),
    )
    return take, run, mach


def upstream_fingerings(calibration: Calibration, score, fingered, n: int) -> list:
    """Each fingering's calibration and share of the take, when they differ upstream.

    A hole between the mouthpiece and the reference plane (a register hole) changes the
    transfer to the microphones, so the virtual recording must carry each note through its
    own fingering's bore (empty when every fingering agrees there: one transfer).
    """
    if fingered is None:
        return []
    order = list(dict.fromkeys(score.fingerings(calibration.fingering)))
    cals = [calibration.with_fingering(f) for f in order]
    x_ref = calibration.reference_plane
    ahead = {
        tuple(sorted(h.name for h in c.bore.holes_between(0.0, x_ref) if c.bore.is_open(h)))
        for c in cals
    }
    if len(ahead) < 2:
        return []
    src, tgt, w = fingered.source[:n], fingered.target[:n], np.asarray(fingered.weight[:n])
    return [
        (cal, np.where(src == k, 1.0 - w, 0.0) + np.where(tgt == k, w, 0.0))
        for k, cal in enumerate(cals)
    ]


def score_bore(calibration: Calibration, score, air, fs: float, controls):
    """The fingered bore of a score whose notes change fingering, else None.

    Each fingering's kernel is the calibration's bore with that fingering's holes open
    (:meth:`mpipe.measurement.calibration.Calibration.with_fingering`); the first note
    without a fingering plays the calibration's (the take's) fingering.
    """
    names = score.fingerings(calibration.fingering)
    if len(set(names)) < 2 and names[0] == calibration.fingering:
        return None
    if None in names:
        raise ValueError(
            "score: a note has no fingering and the calibration names none; give the first "
            "note a fingering"
        )
    order = list(dict.fromkeys(names))
    kernels = [
        prepare_bore(reflection_function(calibration.with_fingering(f).bore, air, fs), air)
        for f in order
    ]
    index = [order.index(f) for f in names]
    return fingered_bore(kernels, score.starts(), index, score.finger_s, controls.n_samples)


def _check_options(options: SynthOptions, with_score: bool) -> None:
    """Refuse, in one line, options that contradict each other or cannot be played."""
    if with_score:
        if options.swell != 0.0:
            raise ValueError("swell: not with a score (the score sets the mouth pressure)")
        if options.duration_s is not None and not options.duration_s > 0:
            raise ValueError(f"duration must be positive, got {options.duration_s} s")
    elif options.duration_s is None or not options.duration_s > 0:
        raise ValueError(f"duration must be positive, got {options.duration_s} s")
    if options.swell <= -1.0:
        raise ValueError(f"swell must be > -1, got {options.swell}")
    if not options.chunk_s > 0:
        raise ValueError(f"chunk_s must be positive, got {options.chunk_s} s")


def make_take(
    calibration_path: str | Path,
    reed_path: str | Path,
    out: str | Path,
    options: SynthOptions,
    *,
    force: bool = False,
    command: str | None = None,
) -> TakeFiles:
    """Synthesise a take and write it with its sidecar, truth and calibration copy.

    Parameters
    ----------
    calibration_path : str or Path
        Calibration YAML.
    reed_path : str or Path
        Reed parameter YAML.
    out : str or Path
        Audio file to write (``.flac``, ``.wav`` or ``.aiff``).
    options : SynthOptions
        See :class:`SynthOptions`.
    force : bool
        Overwrite existing outputs.
    command : str, optional
        The command line, recorded in the sidecar.

    Returns
    -------
    TakeFiles
        Paths of everything written.

    Raises
    ------
    OutputExistsError
        Before any work, when an output exists and ``force`` is not set.
    """
    out = Path(out)
    check_file_rate(out, options.fs_out if options.fs_out is not None else options.fs_model)
    planned = take_file_paths(out, options.mic_calibration)
    outputs = [planned.audio, planned.sidecar, planned.truth, planned.calibration]
    inputs = {"CALIBRATION": calibration_path, "--reed": reed_path, "--score": options.score}
    try:
        # the sidecar d.yaml of -o d.flac would overwrite a score d.yaml (also with --force)
        check_not_inputs([*outputs, *planned.mic_calibrations], inputs)
    except UserError as exc:
        raise UserError(
            f"{exc} (-o TAKE.flac also writes TAKE.yaml, TAKE.truth.npz, "
            "TAKE.calibration.yaml and TAKE.micN_calibration.csv beside it)"
        ) from None
    check_writable(outputs, force)
    calibration = load_one_fingering(calibration_path, options.fingering, "mpipe synth-take")
    n_mics = len(calibration.microphones)
    for name, values in (
        ("gain_error_db", options.gain_error_db),
        ("phase_error_deg", options.phase_error_deg),
    ):
        if values is not None and len(values) != n_mics:
            raise UserError(
                f"--{name.replace('_', '-')}: {len(values)} values given, but "
                f"{calibration_path} has {n_mics} microphones (one value per microphone)"
            )
    score = None if options.score is None else load_score(options.score)
    _check_options(options, score is not None)
    if score is not None and options.duration_s is not None:
        if options.duration_s < score.duration - 1e-9:
            raise UserError(
                f"--duration: {options.duration_s:g} s is shorter than the score "
                f"{options.score} ({score.duration:g} s)"
            )
    reed = load_reed(reed_path)
    take, run, mach = synthesize(calibration, reed, options, score)
    breath_seed, noise_seed = child_seeds(options.seed)
    recipe = {
        "command": command,
        "seed": options.seed,
        "calibration": str(Path(calibration_path).resolve()),
        "calibration_sha256": _sha256(calibration_path),
        "reed": str(Path(reed_path).resolve()),
        "reed_sha256": _sha256(reed_path),
        "reed_parameters": reed.to_mapping(),
        "options": asdict(options),
        "mach_applied": mach,
        "breath_noise_seed": breath_seed,
        "microphone_noise_seed": noise_seed,
    }
    if score is not None:
        recipe["score_sha256"] = _sha256(options.score)
        recipe["score"] = score_mapping(score)
    truth = {f"reed_{k}": v for k, v in reed.to_mapping().items()}
    truth["mouth_pressure_model"] = run.mouth_pressure
    truth["swell"] = options.swell
    truth["breath_noise_pa"] = options.breath_noise_pa
    truth.update(played_truth(run, options.chunk_s))
    played = set(score.fingerings(calibration.fingering)) if score is not None else set()
    if len(played) > 1:
        # the take plays several fingerings: its calibration copy names no default, so that
        # mpipe finds each note's (auto) instead of validating every note on one
        calibration = dataclasses.replace(calibration, fingering=None)
    elif played and None not in played and played != {calibration.fingering}:
        # every note plays one fingering, not the calibration's default: the copy names it
        # (a steady xxoo note of the four-hole clarinet was validated on xxxx and FAILed)
        calibration = calibration.with_fingering(played.pop())
    return _write(
        out,
        take,
        calibration,
        recipe=recipe,
        truth_extra=truth,
        mic_calibration=options.mic_calibration,
        force=force,
    )


def played_truth(run, step_s: float) -> dict[str, np.ndarray]:
    """What the virtual player did, for the truth file (compact: float32 curves on a grid).

    Returns the curves of :func:`mpipe.reed.controls.control_curves` on a ``step_s`` grid,
    the reed opening at the model rate (``opening_model``, m, float32), the sounding span of
    each note (``note_start_s``, ``note_end_s``) and the tongue holds (``tongue_start_s``,
    ``tongue_end_s``), in s from the start of the take.
    """
    controls = run.controls
    out = control_curves(run, step_s)
    out["opening_model"] = run.h.astype(np.float32)
    notes = np.asarray(controls.notes, dtype=float).reshape(-1, 2)
    out["note_start_s"], out["note_end_s"] = notes[:, 0], notes[:, 1]
    # sample i is at t = (i + 1) / fs (the model's time axis)
    holds = (np.asarray(controls.tongue, dtype=float).reshape(-1, 2) + 1.0) / controls.fs
    out["tongue_start_s"], out["tongue_end_s"] = holds[:, 0], holds[:, 1]
    return out


#: Oscillation below which a note is silent, Pa rms: the default ``conditioning.min_rms_pa``,
#: under which the pipeline calls a window silent.
SILENT_RMS_PA = 10.0


def silent_notes(run) -> list[str]:
    """A warning for each note of a model run that never sounds.

    A note sounds when the mouthpiece pressure oscillates, over the second half of its
    sounding span (past the attack), by at least ``SILENT_RMS_PA`` rms; below that the
    pipeline finds only silence there (a mouth pressure under the blowing threshold).

    Parameters
    ----------
    run : mpipe.reed.controls.PlayedRun
        The model run (its ``controls.notes`` in s).

    Returns
    -------
    list of str
        One line per silent note, naming it, its span, its oscillation and its p_m.
    """
    fs = run.controls.fs
    out = []
    notes = np.asarray(run.controls.notes, dtype=float).reshape(-1, 2)
    for i, (t0, t1) in enumerate(notes):
        a, b = int(round(0.5 * (t0 + t1) * fs)), int(round(t1 * fs))
        if b - a < 2:
            continue
        rms = float(np.std(run.p[a:b]))
        if rms < SILENT_RMS_PA:
            p_m = float(np.max(run.mouth_pressure[int(round(t0 * fs)) : b]))
            out.append(
                f"notes[{i}] ({t0:.3f}-{t1:.3f} s) never sounds: the mouthpiece pressure "
                f"oscillates by {rms:.3g} Pa rms (below {SILENT_RMS_PA:g} Pa); its mouth "
                f"pressure (up to {p_m:.4g} Pa) is below the reed's blowing threshold"
            )
    return out


#: Highest sample rate a FLAC stream can declare in its header (20-bit field in units of
#: 10 Hz for the streamable subset libsndfile writes), Hz.
FLAC_MAX_RATE_HZ = 655_350


def check_file_rate(path: str | Path, fs: float) -> None:
    """Refuse, before any work, a sample rate the audio file cannot store.

    Every audio container stores an integer rate in Hz; FLAC (as written by libsndfile)
    at most ``FLAC_MAX_RATE_HZ``, and above 65 535 Hz only multiples of 10 Hz.

    Raises
    ------
    ValueError
        Naming the rate and what the format allows, or an extension that names no audio
        format (before any simulation: the file was once refused only when written).
    """
    suffix = Path(path).suffix.lower()
    if suffix not in AUDIO_FORMATS:
        raise ValueError(f"unsupported extension {suffix or '(none)'!r}; use .flac, .wav or .aiff")
    if not fs > 0 or abs(fs - round(fs)) > 1e-9 * fs:
        raise ValueError(
            f"sample rate {fs:g} Hz cannot be stored: audio files hold an integer rate in Hz"
        )
    if Path(path).suffix.lower() == ".flac" and round(fs) > FLAC_MAX_RATE_HZ:
        raise ValueError(
            f"sample rate {fs:g} Hz cannot be stored in FLAC (at most {FLAC_MAX_RATE_HZ} Hz); "
            "use --fs-out for a lower file rate or write .wav"
        )
    if Path(path).suffix.lower() == ".flac" and round(fs) > 65_535 and round(fs) % 10:
        raise ValueError(
            f"sample rate {fs:g} Hz cannot be stored in FLAC (above 65 535 Hz only multiples "
            "of 10 Hz); write .wav"
        )


def _sha256(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


__all__ = [
    "SynthOptions",
    "VirtualTake",
    "check_file_rate",
    "make_take",
    "played_truth",
    "silent_notes",
    "synthesize",
]
