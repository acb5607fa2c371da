"""``mpipe config``: every setting of every stage, with unit and default, as YAML."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mpipe.core.io import check_writable, write_text_atomic
from mpipe.pipeline.settings import load_pipeline, pipeline_yaml


def add_parser(sub) -> None:
    """Register the ``config`` subcommand."""
    p = sub.add_parser(
        "config",
        help="print every pipeline setting with its unit and default, as commented YAML",
        description="Print the resolved pipeline as commented YAML: every key of every "
        "stage with its unit and meaning. Without PIPELINE the defaults are printed (a "
        "starting point for a new pipeline file); with PIPELINE, its values, and missing "
        "keys filled with their defaults.",
    )
    p.add_argument("pipeline", nargs="?", help="pipeline YAML to resolve (default: none)")
    p.add_argument(
        "--calibration",
        metavar="FILE.yaml",
        help="calibration path to write into the output (default: the pipeline's, or a "
        "placeholder)",
    )
    p.add_argument(
        "-o", "--output", metavar="FILE.yaml", help="write here instead of stdout (default: stdout)"
    )
    p.add_argument("--force", action="store_true", help="overwrite the output file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Execute ``mpipe config``."""
    if args.output:
        check_writable([args.output], args.force)
    cfg = load_pipeline(args.pipeline, check_calibration=False) if args.pipeline else None
    text = pipeline_yaml(cfg, args.calibration)
    if args.output:
        write_text_atomic(Path(args.output), text)
    else:
        sys.stdout.write(text)
    return 0
