"""Command-line interface: ``mpipe <command> ...``.

Each command lives in ``mpipe/cli/commands/<name>.py`` and exposes ``add_parser(subparsers)``,
which registers its arguments and sets ``func`` to a callable taking the parsed arguments
and returning an exit code. Errors the user can fix (bad files, bad keys, bad values) are
raised as :class:`mpipe.core.errors.UserError` or :class:`mpipe.core.config.ConfigError` and printed
as one line, without a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from mpipe import __version__
from mpipe.core.config import ConfigError
from mpipe.core.errors import UserError
from mpipe.core.progress import logging_redirect
from mpipe.core.workers import exit_on_sigterm

# Command modules under mpipe/cli/commands, in the order `mpipe --help` lists them.
COMMANDS = (
    "config",
    "calibrate",
    "impedance",
    "simulate",
    "synth_take",
    "separate",
    "invert",
    "run",
)


def build_parser() -> argparse.ArgumentParser:
    """Assemble the argument parser from the command modules."""
    parser = argparse.ArgumentParser(
        prog="mpipe",
        description="Clarinet reed parameters from in-bore multi-microphone recordings.",
    )
    parser.add_argument("--version", action="version", version=f"mpipe {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    parser.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        importlib.import_module(f"mpipe.cli.commands.{name}").add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING if args.quiet else (logging.DEBUG if args.verbose else logging.INFO)
    logging.basicConfig(level=level, format="%(message)s")
    # SIGTERM ends the command through SystemExit, so that worker pools are terminated,
    # partial files removed and output-folder locks released
    exit_on_sigterm()
    try:
        # log records are printed above progress bars, never inside them
        with logging_redirect():
            return int(args.func(args) or 0)
    except (ConfigError, UserError) as exc:
        print(f"mpipe {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
