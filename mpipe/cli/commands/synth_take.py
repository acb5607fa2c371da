"""``mpipe synth-take``: a virtual take of N >= 2 wall microphones with known truth.

Runs the reed model (:mod:`mpipe.reed.model`) on the calibration's bore, records the mouthpiece
signals with the virtual microphones (:mod:`mpipe.reed.recording`) and writes the audio file,
its sidecar, the truth and a calibration copy that fits the file.
"""

from __future__ import annotations

import argparse
import hashlib
import logging
import shlex
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from mpipe.core.config import ConfigError
from mpipe.core.errors import UserError
from mpipe.core.io import check_writable
from mpipe.measurement.calibration import Calibration, load_calibration
from mpipe.reed.recording import VirtualTake, virtual_recording
from mpipe.reed.take_files import TakeFiles, take_file_paths
from mpipe.reed.take_files import write_virtual_take as _write

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SynthOptions:
    """How to synthesise a take.

    Attributes
    ----------
    duration_s : float
        Length of the take, s.
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
    """

    duration_s: float
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


def child_seeds(seed: int) -> tuple[int, int]:
    """Independent seeds for the breath noise and the microphone noise, from one seed."""
    children = np.random.SeedSequence(seed).spawn(2)
    return tuple(int(c.generate_state(1)[0]) for c in children)  # type: ignore[return-value]


def synthesize(calibration: Calibration, reed, options: SynthOptions):
    """Simulate the instrument and record it with the virtual microphones.

    Parameters
    ----------
    calibration : Calibration
        Instrument, microphones and air.
    reed : mpipe.reed.parameters.ReedParameters
        Reed parameters (SI units); ``reed.p_m`` is the mouth pressure at the start.
    options : SynthOptions
        Duration, rates, air, errors, noise and seed.

    Returns
    -------
    take : VirtualTake
        The recording and its truth.
    sim : mpipe.reed.model.Simulation
        The model run at ``options.fs_model``.
    mach : float
        The Mach number used.

    References
    ----------
    Chatziioannou & van Walstijn 2012, Appendix A (model) and section 4 (measurement).
    """
    from mpipe.acoustics.reflection import reflection_function
    from mpipe.reed.bore_kernel import prepare_bore
    from mpipe.reed.model import simulate

    if not options.duration_s > 0:
        raise ValueError(f"duration must be positive, got {options.duration_s} s")
    if options.swell <= -1.0:
        raise ValueError(f"swell must be > -1, got {options.swell}")
    temp = options.temperature_c
    if isinstance(temp, tuple):
        t_model = 0.5 * (temp[0] + temp[1])
    else:
        t_model = calibration.air.temperature_c if temp is None else float(temp)
    air = calibration.air_properties(t_model)
    fs = options.fs_model
    rf = reflection_function(calibration.bore, air, fs)
    kernel = prepare_bore(rf, air)
    n = int(round(options.duration_s * fs))
    t = np.arange(1, n + 1) / fs
    mouth = reed.p_m * (1.0 + options.swell * t / options.duration_s)
    breath_seed, noise_seed = child_seeds(options.seed)
    log.info("simulating %.3g s at %g Hz (air at %g degC)", options.duration_s, fs, t_model)
    sim = simulate(
        reed,
        kernel,
        n,
        mouth_pressure=mouth,
        onset_s=options.onset_s,
        noise_std_pa=options.breath_noise_pa,
        seed=breath_seed,
    )
    if not np.all(np.isfinite(sim.p)):
        raise ValueError("the simulation diverged; check the reed parameters")
    if options.mach == "auto":
        area = np.pi * calibration.main_radius**2
        mach = float(np.mean(sim.u[n // 2 :]) / (area * air.c))
    else:
        mach = float(options.mach)
    take = virtual_recording(
        sim.p,
        sim.u,
        fs,
        calibration,
        temperature_c=temp,
        mach=mach,
        gain_error_db=options.gain_error_db,
        phase_error_deg=options.phase_error_deg,
        snr_db=options.snr_db,
        bits=options.bits,
        fs_out=options.fs_out,
        seed=noise_seed,
    )
    return take, sim, mach


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
    from mpipe.reed.parameters import load_reed

    out = Path(out)
    check_file_rate(out, options.fs_out if options.fs_out is not None else options.fs_model)
    planned = take_file_paths(out, options.mic_calibration)
    check_writable([planned.audio, planned.sidecar, planned.truth, planned.calibration], force)
    calibration = load_calibration(calibration_path)
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
    reed = load_reed(reed_path)
    take, sim, mach = synthesize(calibration, reed, options)
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
    truth = {f"reed_{k}": v for k, v in reed.to_mapping().items()}
    truth["mouth_pressure_model"] = sim.mouth_pressure
    truth["swell"] = options.swell
    truth["breath_noise_pa"] = options.breath_noise_pa
    return _write(
        out,
        take,
        calibration,
        recipe=recipe,
        truth_extra=truth,
        mic_calibration=options.mic_calibration,
        force=force,
    )


#: Highest sample rate a FLAC stream can declare in its header (20-bit field in units of
#: 10 Hz for the streamable subset libsndfile writes), Hz.
FLAC_MAX_RATE_HZ = 655_350


def check_file_rate(path: str | Path, fs: float) -> None:
    """Refuse, before any work, a sample rate the audio file cannot store.

    Every audio container stores an integer rate in Hz; FLAC (as written by libsndfile)
    at most ``FLAC_MAX_RATE_HZ``.

    Raises
    ------
    ValueError
        Naming the rate and what the format allows.
    """
    if not fs > 0 or abs(fs - round(fs)) > 1e-9 * fs:
        raise ValueError(
            f"sample rate {fs:g} Hz cannot be stored: audio files hold an integer rate in Hz"
        )
    if Path(path).suffix.lower() == ".flac" and round(fs) > FLAC_MAX_RATE_HZ:
        raise ValueError(
            f"sample rate {fs:g} Hz cannot be stored in FLAC (at most {FLAC_MAX_RATE_HZ} Hz); "
            "use --fs-out for a lower file rate or write .wav"
        )


def _sha256(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _numbers(text: str, count: int | tuple[int, ...], what: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{what}: expected numbers, got {text!r}") from None
    counts = (count,) if isinstance(count, int) else count
    if len(values) not in counts:
        want = " or ".join(str(c) for c in counts)
        raise argparse.ArgumentTypeError(f"{what}: expected {want} comma-separated numbers")
    return values


def add_parser(sub) -> None:
    """Register the ``synth-take`` subcommand."""
    p = sub.add_parser(
        "synth-take",
        help="synthesise a take of the calibration's microphones with known truth",
        description="Simulate the reed model on the calibration's bore, record it with the "
        "calibration's virtual wall microphones (any number >= 2) and write TAKE.flac "
        "(24-bit), TAKE.yaml (how to reproduce it), TAKE.truth.npz (true signals and "
        "parameters) and "
        "TAKE.calibration.yaml (sensitivities of the file, Pa per full-scale unit).",
    )
    p.add_argument("calibration", help="calibration YAML (instrument and microphones)")
    p.add_argument("--reed", required=True, metavar="REED.yaml", help="reed parameter YAML")
    p.add_argument("--duration", required=True, type=float, metavar="SECONDS", help="length, s")
    p.add_argument(
        "--fs-model",
        type=float,
        default=100_000.0,
        metavar="HZ",
        help="model sample rate in Hz (100000)",
    )
    p.add_argument("--fs-out", type=float, metavar="HZ", help="file sample rate in Hz")
    p.add_argument(
        "--temperature",
        type=lambda s: _numbers(s, (1, 2), "--temperature"),
        metavar="C[,C_END]",
        help="air temperature in degC, or start,end of a linear drift (default: calibration)",
    )
    p.add_argument(
        "--mach",
        default="0",
        metavar="M|auto",
        help="mean-flow Mach number at the microphones, or 'auto' from the model's mean flow",
    )
    p.add_argument("--snr", type=float, metavar="DB", help="microphone noise SNR per channel, dB")
    p.add_argument(
        "--gain-error-db",
        type=lambda s: _numbers(s, tuple(range(2, 65)), "--gain-error-db"),
        default=None,
        metavar="A,B,...",
        help="sensitivity errors of the microphones, dB, one per microphone (default 0)",
    )
    p.add_argument(
        "--phase-error-deg",
        type=lambda s: _numbers(s, tuple(range(2, 65)), "--phase-error-deg"),
        default=None,
        metavar="A,B,...",
        help="phase errors of the microphones, degrees, one per microphone (default 0)",
    )
    p.add_argument(
        "--swell",
        type=float,
        default=0.0,
        metavar="FRACTION",
        help="relative rise of the mouth pressure over the take (0.1 = +10 %%)",
    )
    p.add_argument(
        "--breath-noise",
        type=float,
        default=0.0,
        metavar="PA",
        help="standard deviation of white noise on the mouth pressure, Pa",
    )
    p.add_argument(
        "--onset",
        type=float,
        default=0.01,
        metavar="S",
        help="raised-cosine rise time of the mouth pressure, s (0.01)",
    )
    p.add_argument("--bits", type=int, choices=(16, 24), default=24, help="word length (24)")
    p.add_argument(
        "--no-mic-calibration",
        action="store_true",
        help="do not write the relative calibration tables of microphones 2 to N",
    )
    p.add_argument("--seed", type=int, default=0, help="random seed (0)")
    p.add_argument("-o", "--output", required=True, metavar="TAKE.flac", help="audio file")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Execute ``mpipe synth-take``."""
    temp = args.temperature
    if temp is not None:
        temp = temp[0] if len(temp) == 1 else (temp[0], temp[1])
    if args.mach == "auto":
        mach: float | str = "auto"
    else:
        try:
            mach = float(args.mach)
        except ValueError:
            raise UserError(f"--mach: expected a number or 'auto', got {args.mach!r}") from None
    options = SynthOptions(
        duration_s=args.duration,
        fs_model=args.fs_model,
        fs_out=args.fs_out,
        temperature_c=temp,
        mach=mach,
        snr_db=args.snr,
        gain_error_db=None if args.gain_error_db is None else tuple(args.gain_error_db),
        phase_error_deg=None if args.phase_error_deg is None else tuple(args.phase_error_deg),
        swell=args.swell,
        breath_noise_pa=args.breath_noise,
        onset_s=args.onset,
        seed=args.seed,
        bits=args.bits,
        mic_calibration=not args.no_mic_calibration,
    )
    command = "mpipe synth-take " + " ".join(shlex.quote(a) for a in _reconstruct_argv(args))
    try:
        files = make_take(
            args.calibration, args.reed, args.output, options, force=args.force, command=command
        )
    except ConfigError:
        raise  # already names the file and key
    except ValueError as exc:
        raise UserError(f"{args.output}: {exc}") from None
    print(
        f"wrote {files.audio}, {files.sidecar.name}, {files.truth.name}, {files.calibration.name}"
    )
    return 0


def _reconstruct_argv(args: argparse.Namespace) -> list[str]:
    """The options as given, in a canonical order, for the sidecar."""
    out = [args.calibration, "--reed", args.reed, "--duration", f"{args.duration:g}"]
    pairs = [
        ("--fs-model", args.fs_model),
        ("--fs-out", args.fs_out),
        ("--temperature", args.temperature and ",".join(f"{v:g}" for v in args.temperature)),
        ("--mach", args.mach),
        ("--snr", args.snr),
        ("--gain-error-db", args.gain_error_db and ",".join(f"{v:g}" for v in args.gain_error_db)),
        (
            "--phase-error-deg",
            args.phase_error_deg and ",".join(f"{v:g}" for v in args.phase_error_deg),
        ),
        ("--swell", args.swell),
        ("--breath-noise", args.breath_noise),
        ("--onset", args.onset),
        ("--bits", args.bits),
        ("--seed", args.seed),
    ]
    for flag, value in pairs:
        if value is not None:
            out += [flag, f"{value:g}" if isinstance(value, float) else str(value)]
    if args.no_mic_calibration:
        out.append("--no-mic-calibration")
    out += ["-o", args.output]
    return out


__all__ = ["SynthOptions", "VirtualTake", "add_parser", "make_take", "run", "synthesize"]
