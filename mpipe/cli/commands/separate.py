"""``mpipe separate``: mouthpiece pressure and flow from a take of two or more microphones.

Outputs in ``DIR``:

``mouthpiece.npz``
    ``fs`` (Hz), ``p`` (Pa) and ``u`` (m^3/s, into the bore) at the mouthpiece entry,
    ``p0`` (Pa) and ``u0`` (m^3/s) at the reference plane, ``temperature_c`` (degC per
    sample), all after the 7.25 kHz low-pass; the noise propagated from the microphones:
    ``u_noise_freq_hz`` (Hz), ``u_noise_psd`` ((m^3/s)^2/Hz) and ``p_noise_psd`` (Pa^2/Hz),
    one-sided power spectral densities at the mouthpiece entry; ``theta_level``,
    ``theta_level_se`` and ``theta_level_cov``, the separation's take-level theta, its
    standard errors and covariance (as ``mpipe run`` writes them). Written block by block
    (the block path of ``mpipe run``: the take's pressures, then the reference-plane
    signals, go to disk as they are made).

The take is resampled to ``--sample-rate`` (the pipeline's ``inversion.sample_rate``,
100 kHz by default) when it was recorded at another rate. The exit status is 1 when the
validation FAILs, 0 for PASS and CANNOT-VERIFY.
``mouthpiece.wav``
    32-bit float, two channels at ``fs``: channel 1 is ``p / 10 kPa``, channel 2 is
    ``u / (1e-3 m^3/s)`` (fixed scales, so files compare across takes).
``blocks.csv``
    The per-block propagation parameters of the wave separation.
``impedance.csv``, ``impedance.png``
    Measured and theoretical normalised input impedance with coherence (paper Fig. 10).
``validation.csv``, ``harmonics.csv``
    What the validation compared: the resonances (measured when the take excites them)
    and the harmonics of a played note.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import tempfile
from pathlib import Path

import numpy as np

from mpipe.cli.commands import add_fingering_option
from mpipe.core.errors import UserError
from mpipe.core.io import check_writable, folder_lock, write_atomic, write_csv
from mpipe.core.signals import open_npz
from mpipe.inversion.conditioning_settings import ConditioningConfig
from mpipe.inversion.preparation.kernel import take_temperature
from mpipe.inversion.settings import ExecutorConfig, InversionConfig
from mpipe.inversion.whole_take.front_end import LEVEL_KEYS
from mpipe.measurement.calibration import load_calibration, per_note
from mpipe.measurement.measured_instrument import bore_description
from mpipe.measurement.separation.settings import SeparationConfig
from mpipe.measurement.separation.streaming import separate_take
from mpipe.measurement.translation import (
    TranslationConfig,
    mouthpiece_noise,
    write_mouthpiece_wav,
)
from mpipe.measurement.translation_stream import translate_to_npz
from mpipe.measurement.validation import ValidationConfig, validate
from mpipe.measurement.validation_result import plot_impedance
from mpipe.pipeline.note_validation import validate_notes
from mpipe.pipeline.settings import load_pipeline

log = logging.getLogger(__name__)

#: Default rate of every command: the default of the pipeline's inversion.sample_rate.
DEFAULT_RATE = InversionConfig().sample_rate

OUTPUTS = (
    "mouthpiece.npz",
    "mouthpiece.wav",
    "blocks.csv",
    "impedance.csv",
    "impedance.png",
    "validation.csv",
    "harmonics.csv",
)


def add_parser(sub) -> None:
    """Register the ``separate`` subcommand."""
    p = sub.add_parser(
        "separate",
        help="wave separation, translation to the mouthpiece and impedance check of a take",
        description="Separate the waves of a take of two or more wall microphones, rebuild "
        "pressure and flow at the mouthpiece entry, and validate them against the theoretical "
        "input impedance.",
    )
    p.add_argument(
        "inputs",
        nargs="+",
        metavar="FILE",
        help="TAKE (one multichannel file) or TAKE1 ... TAKEN (one mono file per "
        "microphone), then CALIBRATION.yaml",
    )
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="output directory")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    add_fingering_option(p)
    p.add_argument(
        "--pipeline",
        metavar="PIPE.yaml",
        help="take the separation, translation and validation settings from this pipeline "
        "file, as `mpipe run` does (default: the settings' defaults)",
    )
    p.add_argument(
        "--sample-rate",
        type=float,
        default=None,
        metavar="HZ",
        help="rate of the outputs; takes at other rates are resampled (default: the "
        f"pipeline's inversion.sample_rate, {DEFAULT_RATE:g} without --pipeline)",
    )
    p.add_argument(
        "--fixed-mach",
        type=float,
        metavar="M",
        help="hold the Mach number of the mean flow at M instead of estimating it (default: "
        "the settings', estimated)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Execute ``mpipe separate``, holding the lock of the output folder."""
    with folder_lock(args.output):
        return _run(args)


def _run(args: argparse.Namespace) -> int:

    takes, cal_path, out, paths = _inputs(args)
    log.info("reading calibration %s", cal_path)
    cal = load_calibration(cal_path, _fingering(args))
    log.info("%s", bore_description(cal))
    log.info("reading take %s", ", ".join(takes))
    sep_cfg, tr_cfg, val_cfg, rate, workers = _settings(args)
    if args.fixed_mach is not None:
        if not -0.05 <= args.fixed_mach <= 0.1:
            raise UserError(
                f"--fixed-mach: expected a value in [-0.05, 0.1], got {args.fixed_mach}"
            )
        sep_cfg = dataclasses.replace(sep_cfg, mach=args.fixed_mach)
    out.mkdir(parents=True, exist_ok=True)
    # the block path of `mpipe run`: the signals go to disk, in blocks, as they are made
    with tempfile.TemporaryDirectory(dir=out, prefix=".separate.") as scratch:
        reference, mouthpiece = Path(scratch) / "reference.npz", Path(scratch) / "mouthpiece.npz"
        try:
            log.info("stage 1/3: wave separation")
            found = separate_take(reference, takes if len(takes) > 1 else takes[0], cal,
                                  sep_cfg, rate, workers)  # fmt: skip
            sep, fs = found["separation"], found["take"].fs
            log.info("stage 2/3: translation to the mouthpiece entry")
            ref = open_npz(reference)
            t_eff = take_temperature(ref["temperature_c"], cal)
            noise = mouthpiece_noise(fs, cal, sep.noise_psd, sep.median_theta(), t_eff, sep_cfg)
            levels = {k: ref[k] for k in LEVEL_KEYS if k in ref}
            translate_to_npz(mouthpiece, ref["p0"], ref["u0"], ref["temperature_c"], fs, cal,
                             tr_cfg, {**noise, **levels})  # fmt: skip
            log.info("stage 3/3: impedance validation")
            mp = open_npz(mouthpiece)
            signals = _Signals(np.asarray(mp["p"]), np.asarray(mp["u"]))
            val = _validation(signals, fs, cal, val_cfg, t_eff, args)
            del signals
        except ValueError as exc:
            raise UserError(f"{takes[0]}: {exc}") from None
        _write_outputs(out, fs, sep, mouthpiece, val, tr_cfg.stopband_hz)
    return _print_summary(sep, val, paths)


@dataclasses.dataclass(frozen=True)
class _Signals:
    """The mouthpiece pressure (Pa) and flow (m^3/s) the validation reads."""

    p: np.ndarray
    u: np.ndarray


def _validation(tr, fs: float, cal, val_cfg, t_eff: float, args):
    """The take's validation; with a fingering per note, each note on its own (the lines)."""
    if not per_note(cal.fingering):
        return validate(tr.p, tr.u, fs, cal, val_cfg, t_eff)
    conditioning = ConditioningConfig()
    if args.pipeline:
        conditioning = load_pipeline(args.pipeline, check_calibration=False).conditioning
    notes = validate_notes(tr.p, tr.u, fs, cal, val_cfg, conditioning, t_eff)
    for line in [f"validation: {notes.verdict} ({notes.reason})", *notes.lines()]:
        print(line)
    shown = notes.shown()
    if shown is None or (shown.verdict == "fail" and notes.verdict != "fail"):
        # nothing the notes could verify: the take's curves, nothing failed
        first = cal.with_fingering(cal.fingerings[0].name)
        whole = shown or validate(tr.p, tr.u, fs, first, val_cfg, t_eff)
        return dataclasses.replace(whole, failures=(), suspects=(), checks=0)
    return shown


def _inputs(args: argparse.Namespace) -> tuple[list[str], str, Path, list[Path]]:
    """The take files, the calibration file, the output folder and the files written there."""
    if len(args.inputs) < 2:
        raise UserError(
            f"expected TAKE CALIBRATION.yaml or TAKE1 ... TAKEN CALIBRATION.yaml, got "
            f"{len(args.inputs)} file(s)"
        )
    *takes, cal_path = args.inputs
    if not cal_path.lower().endswith((".yaml", ".yml")):
        raise UserError(f"{cal_path}: the last argument must be the calibration YAML file")
    out = Path(args.output)
    paths = [out / name for name in OUTPUTS]
    inputs = {f"take {t}": t for t in takes}
    inputs.update({"CALIBRATION": cal_path, "--pipeline": args.pipeline})
    check_writable(paths, args.force, inputs)
    return takes, cal_path, out, paths


def _settings(args: argparse.Namespace):
    """Separation, translation and validation settings, the sample rate (Hz), the workers.

    The workers (processes of the blocks' estimates) are the pipeline's
    ``executor.workers``, one per CPU by default: the same numbers with any number.
    """
    executor = ExecutorConfig()
    if args.pipeline:
        pipe = load_pipeline(args.pipeline, check_calibration=False)
        sep_cfg, tr_cfg, val_cfg = pipe.separation, pipe.translation, pipe.validation
        rate, executor = pipe.inversion.sample_rate, pipe.executor
    else:
        sep_cfg, tr_cfg, val_cfg = SeparationConfig(), TranslationConfig(), ValidationConfig()
        rate = DEFAULT_RATE
    rate = args.sample_rate if args.sample_rate is not None else rate
    if not 1000.0 <= rate <= 1e6:
        raise UserError(f"--sample-rate: expected a rate in Hz (1e3-1e6), got {rate:g}")
    return sep_cfg, tr_cfg, val_cfg, rate, executor.processes


def _write_outputs(out: Path, fs: float, sep, mouthpiece: Path, val, max_hz: float) -> None:
    """Mouthpiece signals (npz, WAV), block and impedance tables and the impedance plot.

    ``mouthpiece``: the ``mouthpiece.npz`` written beside ``out`` (moved into it);
    ``max_hz``: the impedance table's last frequency (the low-pass's stop band, Hz).
    """
    mp = open_npz(mouthpiece)

    def move(path: Path) -> None:
        os.replace(mouthpiece, path)

    steps = [
        (
            out / "mouthpiece.wav",
            lambda path: write_atomic(
                path, lambda t: write_mouthpiece_wav(t, mp["p"], mp["u"], fs)
            ),
        ),
        (out / "mouthpiece.npz", move),
        (out / "blocks.csv", lambda path: write_csv(path, sep.blocks)),
        (out / "impedance.csv", lambda path: write_csv(path, val.table(max_hz))),
        (out / "validation.csv", lambda path: write_csv(path, val.resonances)),
        (out / "harmonics.csv", lambda path: write_csv(path, val.harmonics)),
        (out / "impedance.png", lambda path: write_atomic(path, lambda t: _plot(val, t))),
    ]
    written: list[Path] = []
    try:
        for path, write in steps:
            write(path)
            written.append(path)
    except OSError as exc:
        # all or nothing: a full disk leaves no mix of this run's files and older ones
        for path in written:
            path.unlink(missing_ok=True)
        if exc.filename is None:
            exc.filename = str(path)
        raise


def _plot(val, path: Path) -> None:
    plot_impedance(val, path, 2000.0)


def _print_summary(sep, val, paths: list[Path]) -> int:
    """Propagation parameters over the blocks and the validation; 1 when it failed."""
    b = sep.blocks
    fit = (
        f"median chi2/dof {np.nanmedian(b.residual):.2f}"
        if np.any(np.isfinite(b.residual))
        else f"no residual ({b.theta.iloc[0]})"
    )
    print(
        f"{len(b)} blocks: T {b.temperature_c.median():.2f} +- {b.temperature_se_c.median():.2f}"
        f" degC ({b.temperature_c.min():.2f}..{b.temperature_c.max():.2f}), "
        f"eta {b.loss_scale.median():.3f} +- {b.loss_scale_se.median():.3f}, "
        f"M {b.mach.median():.4f} +- {b.mach_se.median():.4f}, {fit}"
    )
    if sep.track is not None:
        print(sep.track.sentence())
    for line in sep.bound_warnings():
        print(f"warning: {line}")
    print(val.summary())
    print(f"wrote {', '.join(str(p) for p in paths)}")
    if val.verdict == "fail":
        print("validation FAILED: the mouthpiece signals do not match the bore's impedance")
        return 1
    return 0


def _fingering(args: argparse.Namespace) -> str | None:
    """``--fingering``, else the pipeline's ``fingering`` (with ``--pipeline``), else None."""
    if args.fingering is not None or args.pipeline is None:
        return args.fingering

    # its calibration key is not used here (the command names its own): not checked
    return load_pipeline(args.pipeline, check_calibration=False).fingering
