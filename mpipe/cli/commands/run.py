"""``mpipe run``: the whole pipeline on one or more takes, resumable, with a report per take."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mpipe.core.config import ConfigError
from mpipe.core.errors import UserError
from mpipe.pipeline.settings import load_pipeline


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
        "be joined with commas: mic1.wav,mic2.wav,mic3.wav",
    )
    p.add_argument("-o", "--output", required=True, metavar="OUT", help="output directory")
    p.add_argument(
        "--calibration",
        metavar="FILE.yaml",
        help="calibration file to use instead of the pipeline's (e.g. a virtual take's copy)",
    )
    p.add_argument("--force", action="store_true", help="redo finished stages and windows")
    p.add_argument(
        "--accept-failed-validation",
        action="store_true",
        help="invert a take whose impedance validation FAILs (by default the run stops "
        "before the inversion; the report records that it went on)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Execute ``mpipe run``."""
    from mpipe.core.io import check_output_folder
    from mpipe.core.progress import write
    from mpipe.pipeline.batch import run_takes, summary_lines
    from mpipe.pipeline.orchestration import ValidationFailed, take_name, usable

    cfg = load_pipeline(args.pipeline)
    cal_path = Path(args.calibration) if args.calibration else cfg.calibration_path
    if not cal_path.is_file():
        raise UserError(f"{cal_path}: no such calibration file")
    takes = [[Path(p) for p in t.split(",")] for t in args.takes]
    for t in takes:
        if len(t) == 0 or len(t) > 64:
            raise UserError(
                f"{','.join(map(str, t))}: expected one file or one mono file per microphone"
            )
        for p in t:
            if not p.is_file():
                raise UserError(f"{p}: no such take file")
    # a bad output path fails now, not after the computation
    check_output_folder(args.output)
    for t in takes:
        check_output_folder(Path(args.output) / take_name(t))
    client = None
    if cfg.executor.kind == "dask":
        from mpipe.inversion.execution import connect

        # one client for every take of this call: the takes share the cluster; an
        # unreachable scheduler is one line (exit 2) before any work
        client = connect(cfg.executor.scheduler)
    failed = []
    outcomes = []
    try:
        for t, result, wall in run_takes(
            cfg, cal_path, takes, args.output, args.force, client, say=write,
            accept_failed_validation=args.accept_failed_validation,
        ):  # fmt: skip
            outcomes.append((t, result, wall))
            if isinstance(result, ValidationFailed):  # a result (the measurement is not sound): 1
                failed.append(t[0])
                print(f"mpipe run: {result}", file=sys.stderr)
            elif isinstance(result, Exception):
                if isinstance(result, ConfigError | UserError) and len(takes) == 1:
                    raise result
                failed.append(t[0])
                print(f"[{t[0].stem}] failed: {result}")
            elif not usable(result):
                failed.append(t[0])
                write(f"[{t[0].stem}] failed: no window has status ok (no usable result)")
    finally:
        if client is not None:
            client.close()
    if len(takes) > 1:
        order = {str(t[0]): i for i, t in enumerate(takes)}
        outcomes.sort(key=lambda o: order[str(o[0][0])])
        print(f"{len(takes)} takes:")
        print("\n".join(summary_lines(outcomes)))
    if failed:
        print(f"{len(failed)} of {len(takes)} takes failed: {', '.join(map(str, failed))}")
        return 1
    return 0
