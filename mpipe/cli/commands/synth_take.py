"""``mpipe synth-take``: a virtual take of N >= 2 wall microphones with known truth.

The command line of :func:`mpipe.cli.virtual_takes.make_take`: it runs the reed model on the
calibration's bore, records the mouthpiece signals with the virtual microphones and writes the
audio file, its sidecar (with this command line), the truth and a calibration copy.
"""

from __future__ import annotations

import argparse
import math
import os
import shlex

from mpipe.cli.commands import add_fingering_option
from mpipe.cli.virtual_takes import SynthOptions, make_take
from mpipe.core.config import ConfigError
from mpipe.core.errors import UserError
from mpipe.reed.score import load_score


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
    p.add_argument(
        "--duration",
        type=float,
        metavar="SECONDS",
        help="length, s (required without --score; with one, default the score's length)",
    )
    p.add_argument(
        "--score",
        metavar="SCORE.yaml",
        help="notes, silences and control curves to play (p_m, y_m, k, ..., vibrato, "
        "tonguing); examples in examples/scores/ (default: none, one steady note of "
        "--duration)",
    )
    p.add_argument(
        "--chunk",
        type=float,
        default=1e-3,
        metavar="S",
        help="pieces over which varying reed parameters are held, s (0.001)",
    )
    _add_conditions(p)
    _add_microphone_errors(p)
    _add_player(p)
    p.add_argument("--bits", type=int, choices=(16, 24), default=24, help="word length (24)")
    p.add_argument(
        "--no-mic-calibration",
        action="store_true",
        help="do not write the relative calibration tables of microphones 2 to N",
    )
    p.add_argument("--seed", type=int, default=0, help="random seed (0)")
    p.add_argument("-o", "--output", required=True, metavar="TAKE.flac", help="audio file")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    add_fingering_option(p, per_note=False)
    p.set_defaults(func=run)


def _add_conditions(p) -> None:
    """Sample rates, air temperature and mean flow of the virtual recording."""
    p.add_argument(
        "--fs-model",
        type=float,
        default=100_000.0,
        metavar="HZ",
        help="model sample rate in Hz (100000)",
    )
    p.add_argument(
        "--fs-out",
        type=float,
        metavar="HZ",
        help="file sample rate in Hz (default: the model rate)",
    )
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


def _add_microphone_errors(p) -> None:
    """Noise and sensitivity/phase mismatch of the virtual microphones."""
    p.add_argument(
        "--snr",
        type=float,
        metavar="DB",
        help="microphone noise SNR per channel, dB (default: no noise)",
    )
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


def _add_player(p) -> None:
    """How the virtual player blows: swell, breath noise and onset of the mouth pressure."""
    p.add_argument(
        "--swell",
        type=float,
        default=None,
        metavar="FRACTION",
        help="relative rise of the mouth pressure over the take (0.1 = +10 %%; default: 0); "
        "not with --score",
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
        default=None,
        metavar="S",
        help="raised-cosine rise time of the mouth pressure, s (default: 0.01); not with "
        "--score (each note has its attack)",
    )


#: Peak memory of a simulation per model sample, bytes (measured: synth-take at 100 kHz
#: grows by about 30 MB per second of take; see docs/memory.md).
BYTES_PER_MODEL_SAMPLE = 320


def _check_duration(
    duration_s: float, fs_model: float, fs_out: float | None = None, what: str = "--duration"
) -> None:
    """Refuse, before simulating, a duration that is not positive or will not fit in memory.

    ``what`` names the source of the length in the message: ``--duration``, or a score
    (``SCORE.yaml: the score's length``).
    """
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise UserError(f"{what}: expected a positive length in s, got {duration_s:g}")
    # the recording needs two samples at each rate (a 1 us take was an IndexError)
    shortest = 2.0 / min(fs_model, fs_out or fs_model)
    if duration_s < shortest:
        raise UserError(
            f"{what}: {duration_s:g} s holds fewer than two samples at "
            f"{min(fs_model, fs_out or fs_model):g} Hz; expected at least {shortest:.3g} s"
        )
    need = duration_s * fs_model * BYTES_PER_MODEL_SAMPLE
    try:
        have = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        have = 16 * 2**30
    if need > 0.8 * have:
        longest = 0.8 * have / (fs_model * BYTES_PER_MODEL_SAMPLE)
        raise UserError(
            f"{what}: {duration_s:g} s at --fs-model {fs_model:g} Hz needs about "
            f"{need / 2**30:.3g} GiB of memory, this machine has {have / 2**30:.3g} GiB; "
            f"expected at most {longest:.0f} s"
        )


def run(args: argparse.Namespace) -> int:
    """Execute ``mpipe synth-take``."""
    _resolve_player(args)
    if args.duration is not None:
        _check_duration(args.duration, args.fs_model, args.fs_out)
    if args.score is not None:
        # the score's notes and silences set the length: the same memory check, naming it
        score = load_score(args.score)
        _check_duration(score.duration, args.fs_model, args.fs_out,
                        f"{args.score}: the score's length")  # fmt: skip
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
        score=args.score,
        chunk_s=args.chunk,
        fingering=args.fingering,
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


def _resolve_player(args: argparse.Namespace) -> None:
    """Defaults of --swell and --onset, refused in one line beside --score."""
    if not args.chunk > 0:
        raise UserError(f"--chunk: expected a positive duration in s, got {args.chunk:g}")
    if args.score is None:
        if args.duration is None:
            raise UserError("--duration: required without --score (length of the take, s)")
        args.swell = 0.0 if args.swell is None else args.swell
        args.onset = 0.01 if args.onset is None else args.onset
        return
    for flag, value in (("--swell", args.swell), ("--onset", args.onset)):
        if value is not None:
            raise UserError(
                f"{flag}: not with --score {args.score} (the score sets the mouth pressure "
                "and each note's attack)"
            )
    args.swell, args.onset = 0.0, 0.01


def _reconstruct_argv(args: argparse.Namespace) -> list[str]:
    """The options as given, in a canonical order, for the sidecar."""
    out = [args.calibration, "--reed", args.reed]
    if args.duration is not None:
        out += ["--duration", f"{args.duration:g}"]
    if args.score is not None:
        out += ["--score", args.score]
    if args.chunk != 1e-3:
        out += ["--chunk", f"{args.chunk:g}"]
    pairs = [
        ("--fs-model", args.fs_model),
        ("--fs-out", args.fs_out),
        ("--fingering", args.fingering),
        ("--temperature", args.temperature and ",".join(f"{v:g}" for v in args.temperature)),
        ("--mach", args.mach),
        ("--snr", args.snr),
        ("--gain-error-db", args.gain_error_db and ",".join(f"{v:g}" for v in args.gain_error_db)),
        (
            "--phase-error-deg",
            args.phase_error_deg and ",".join(f"{v:g}" for v in args.phase_error_deg),
        ),
        ("--swell", None if args.score else args.swell),
        ("--breath-noise", args.breath_noise),
        ("--onset", None if args.score else args.onset),
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


__all__ = ["add_parser", "run"]
