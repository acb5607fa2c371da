"""``mpipe run``: the whole pipeline on one or more takes, resumable, with a report per take."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Sequence
from pathlib import Path

import soundfile as sf

from mpipe.cli.commands import add_fingering_option
from mpipe.core.config import ConfigError
from mpipe.core.errors import UserError
from mpipe.core.io import check_output_folder
from mpipe.core.progress import write
from mpipe.inversion.fit.execution import connect
from mpipe.inversion.preparation.span import check_span
from mpipe.measurement.calibration import load_calibration
from mpipe.pipeline.batch import run_takes, summary_lines
from mpipe.pipeline.orchestration import ValidationFailed, usable
from mpipe.pipeline.settings import load_pipeline
from mpipe.pipeline.take_calibration import own_calibration, take_calibrations


def add_parser(sub) -> None:
    """Register the ``run`` subcommand."""
    p = sub.add_parser(
        "run",
        help="every stage on one or more takes: separation to resynthesis, with a report",
        description="Run separation, translation, validation, conditioning, per-window "
        "inversion and resynthesis on each take. Finished stages and windows are skipped "
        "when run again, so an interrupted run resumes.",
    )
    p.add_argument("pipeline", help="pipeline YAML (pipelines/simplified_clarinet.yaml)")
    p.add_argument(
        "takes",
        nargs="+",
        metavar="TAKE",
        help="multichannel take files; the mono files of one take (one per microphone) may "
        "be joined with commas: mic1.wav,mic2.wav,mic3.wav (a file whose name holds a comma "
        "is taken whole). Takes sharing a file name get the folder <dir>_<name>",
    )
    p.add_argument("-o", "--output", required=True, metavar="OUT", help="output directory")
    p.add_argument(
        "--calibration",
        metavar="FILE.yaml",
        help="calibration file for the takes without their own (TAKE.calibration.yaml beside "
        "TAKE, as synth-take writes, is always used for its take; a FILE that differs from a "
        "take's own is refused). Default: the pipeline's",
    )
    p.add_argument("--force", action="store_true", help="redo finished stages and windows")
    add_fingering_option(p)
    p.add_argument(
        "--accept-failed-validation",
        action="store_true",
        help="invert a take whose impedance validation FAILs (by default the run stops "
        "before the inversion; the report records that it went on)",
    )
    p.set_defaults(func=run)


def take_arguments(arg: str) -> list[Path]:
    """The files of one TAKE argument.

    An existing file is taken as it is (commas in its name and all); otherwise the argument
    holds the comma-separated mono files of one take.
    """
    if Path(arg).is_file():
        return [Path(arg)]
    files = [Path(p) for p in arg.split(",")] if "," in arg else [Path(arg)]
    if len(files) > 64:
        raise UserError(f"{arg}: expected one file or one mono file per microphone")
    for p in files:
        if not p.is_file():
            raise UserError(f"{p}: no such take file" + (f" (in {arg})" if len(files) > 1 else ""))
    return files


def take_names(takes: Sequence[Sequence[str | Path]]) -> list[str]:
    """Folder names of the takes of one run, distinct: takes sharing a stem are told apart.

    A take's name is its file's stem; when several takes of the run share it, each is
    named ``<folder>_<stem>`` after its file's folder, or ``<stem>_<suffix>`` when they lie
    in one folder (``take.wav`` and ``take.flac``); names still alike get ``_1``, ``_2``, ...

    Raises
    ------
    UserError
        When one file is given as two takes.
    """
    files = [Path(t[0]).resolve() for t in takes]
    for i, f in enumerate(files):
        if f in files[:i]:
            raise UserError(f"{takes[i][0]}: given twice as a take")
    stems = [Path(t[0]).stem for t in takes]
    names = []
    for t, stem in zip(takes, stems, strict=True):
        first = Path(t[0])
        if stems.count(stem) == 1:
            names.append(stem)
        elif (
            sum(
                Path(o[0]).stem == stem and Path(o[0]).resolve().parent == first.resolve().parent
                for o in takes
            )
            > 1
        ):
            names.append(f"{stem}_{first.suffix.lstrip('.')}")
        else:
            names.append(f"{first.resolve().parent.name}_{stem}")
    # still alike (a/x/take.wav and b/x/take.wav): numbered, so no two takes share a folder
    return [f"{n}_{names[:i].count(n) + 1}" if names.count(n) > 1 else n
            for i, n in enumerate(names)]  # fmt: skip


def _check_lengths(takes: list[list[Path]], cfg) -> None:
    """Refuse, before any work, a take too short for one window within conditioning.edge_s."""
    for t in takes:
        try:
            info = sf.info(str(t[0]))
        except (RuntimeError, OSError):
            continue  # an unreadable file is named when the take is read
        try:
            check_span(info.frames, info.samplerate, cfg.conditioning.edge_s,
                       cfg.inversion.window_s, None, None)  # fmt: skip
        except ValueError as exc:
            raise UserError(f"{t[0]}: {exc}") from None


def run(args: argparse.Namespace) -> int:
    """Execute ``mpipe run``."""
    cfg = load_pipeline(args.pipeline, check_calibration=args.calibration is None)
    if args.fingering is not None:
        cfg = dataclasses.replace(cfg, fingering=args.fingering)
    given = Path(args.calibration) if args.calibration else None
    if given is not None and not given.is_file():
        raise UserError(f"{given}: no such calibration file")
    takes = [take_arguments(t) for t in args.takes]
    names = take_names(takes)
    # each take's own calibration beside it, else the one given, else the pipeline's; a
    # mix the command line cannot resolve is refused before any work
    cals = take_calibrations(takes, given, cfg.calibration_path, cfg.fingering)
    for cal_path in dict.fromkeys(cals):
        if not cal_path.is_file():
            raise UserError(f"{cal_path}: no such calibration file")
        # a bad calibration or fingering: one line before any work, not one per take
        load_calibration(cal_path, cfg.fingering)
    for name, take, cal_path in zip(names, takes, cals, strict=True):
        if cal_path == own_calibration(take):
            write(f"[{name}] read with its own calibration {cal_path} (beside the take)")
    _check_lengths(takes, cfg)
    # a bad output path fails now, not after the computation
    check_output_folder(args.output)
    for name in names:
        check_output_folder(Path(args.output) / name)
    client = None
    if cfg.executor.kind == "dask":
        # one client for every take of this call: the takes share the cluster; an
        # unreachable scheduler is one line (exit 2) before any work
        client = connect(cfg.executor.scheduler, cfg.executor.connect_timeout_s)
    failed, checked = [], []
    outcomes = []
    try:
        name_of = {id(t): name for t, name in zip(takes, names, strict=True)}
        for t, result, wall in run_takes(
            cfg, cals, takes, args.output, args.force, client, say=write,
            accept_failed_validation=args.accept_failed_validation, names=names,
        ):  # fmt: skip
            outcomes.append((t, result, wall))
            name = name_of[id(t)]
            if isinstance(result, ValidationFailed):  # a result (the measurement is not sound): 1
                failed.append(t[0])
                print(f"mpipe run: {result}", file=sys.stderr)
            elif isinstance(result, Exception):
                if isinstance(result, ConfigError | UserError) and len(takes) == 1:
                    raise result
                failed.append(t[0])
                print(f"[{name}] failed: {result}")
            elif not usable(result):
                failed.append(t[0])
                write(f"[{name}] failed: no window has status ok (no usable result)")
            elif result.records["inversion"].summary.get("take_checks"):
                checked.append(t[0])
    finally:
        if client is not None:
            client.close()
    if len(takes) > 1:
        order = {id(t): i for i, t in enumerate(takes)}
        outcomes.sort(key=lambda o: order[id(o[0])])
        print(f"{len(takes)} takes:")
        print("\n".join(summary_lines(outcomes, [names[order[id(o[0])]] for o in outcomes])))
    if failed:
        print(f"{len(failed)} of {len(takes)} takes failed: {', '.join(map(str, failed))}")
    if checked:
        # a take-level reason (the CHECK lines above): the result is not to be used as it is
        print(f"{len(checked)} of {len(takes)} takes CHECK: {', '.join(map(str, checked))}")
    return 1 if failed or checked else 0
