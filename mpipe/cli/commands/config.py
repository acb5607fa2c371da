"""``mpipe config``: the pipeline settings with unit, meaning and default, as YAML or Markdown."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mpipe.core.errors import UserError
from mpipe.core.io import check_writable, write_text_atomic
from mpipe.pipeline.settings import load_pipeline, pipeline_yaml, settings_markdown


def add_parser(sub) -> None:
    """Register the ``config`` subcommand."""
    p = sub.add_parser(
        "config",
        help="print the pipeline settings a user changes (--all: every one) as commented YAML",
        description="Print a pipeline as commented YAML, each key with its unit and meaning. "
        "Without PIPELINE: the defaults of the user tier, the settings a user changes (a "
        "starting point for a new pipeline file). With PIPELINE: its values of the user tier, "
        "and every other key it sets to a value other than the default. --all prints every "
        "setting of every stage; --markdown the reference page docs/settings.md.",
    )
    p.add_argument("pipeline", nargs="?", help="pipeline YAML to resolve (default: none)")
    p.add_argument(
        "--all",
        action="store_true",
        dest="every",
        help="every setting of every stage, the advanced ones included",
    )
    p.add_argument(
        "--markdown",
        action="store_true",
        help="the reference page of every setting (key, tier, unit, default, meaning) as "
        "Markdown: `mpipe config --all --markdown -o docs/settings.md --force` regenerates it",
    )
    p.add_argument(
        "--calibration",
        metavar="FILE.yaml",
        help="calibration path to write into the output (default: the pipeline's, or a "
        "placeholder)",
    )
    p.add_argument(
        "-o", "--output", metavar="FILE", help="write here instead of stdout (default: stdout)"
    )
    p.add_argument("--force", action="store_true", help="overwrite the output file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Execute ``mpipe config``."""
    if args.markdown and (args.pipeline or args.calibration):
        given = "PIPELINE" if args.pipeline else "--calibration"
        raise UserError(f"--markdown documents the defaults of every setting; it takes no {given}")
    if args.output:
        inputs = {"PIPELINE": args.pipeline, "--calibration": args.calibration}
        check_writable([args.output], args.force, inputs)
    if args.markdown:
        text = settings_markdown()
    else:
        cfg = load_pipeline(args.pipeline, check_calibration=False) if args.pipeline else None
        text = pipeline_yaml(cfg, args.calibration, every=args.every)
    if args.output:
        write_text_atomic(Path(args.output), text)
    else:
        sys.stdout.write(text)
    return 0
