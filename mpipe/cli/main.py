"""Command-line interface: ``mpipe <command> ...``.

Each command lives in ``mpipe/cli/commands/<name>.py`` and exposes ``add_parser(subparsers)``,
which registers its arguments and sets ``func`` to a callable taking the parsed arguments
and returning an exit code. Errors the user can fix (bad files, bad keys, bad values) are
raised as :class:`mpipe.core.errors.UserError` or :class:`mpipe.core.config.ConfigError` and printed
as one line, without a traceback.
"""

from __future__ import annotations

import argparse
import atexit
import errno
import importlib
import logging
import multiprocessing
import os
import sys
import threading

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
    "session",
)


# Errors of writing a file that the user can fix (the disk, the quota, the permissions).
_WRITE_ERRORS = (errno.ENOSPC, errno.EDQUOT, errno.EACCES, errno.EROFS, errno.EFBIG)


class DefaultsFormatter(argparse.HelpFormatter):
    """Help that shows every option's default (unless its text already does, or it has none)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if not action.option_strings or any(default is v for v in (None, False, argparse.SUPPRESS)):
            return text
        shown = f"({default:g})" if isinstance(default, float) else f"({default})"
        if "%(default)" in text or "default" in text.lower() or shown in text:
            return text
        return f"{text} (default: %(default)s)"


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """Assemble the argument parser from the command modules.

    With ``argv`` naming a command, only that command's module is imported: each imports
    what its command runs (numba, scipy's solvers, pandas, ...), and a command should not
    pay for the others' at start-up. Without one (``mpipe --help``, a typo), all of them.
    """
    chosen = _chosen_command(argv)
    parser = argparse.ArgumentParser(
        prog="mpipe",
        description="Clarinet reed parameters from in-bore multi-microphone recordings.",
    )
    parser.add_argument("--version", action="version", version=f"mpipe {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    parser.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in (chosen,) if chosen else COMMANDS:
        importlib.import_module(f"mpipe.cli.commands.{name}").add_parser(sub)
    for command in sub.choices.values():
        command.formatter_class = DefaultsFormatter
        for group in command._subparsers._group_actions if command._subparsers else ():
            for nested in group.choices.values():  # mpipe calibrate sensitivity, ...
                nested.formatter_class = DefaultsFormatter
    return parser


def _chosen_command(argv: list[str] | None) -> str | None:
    """The command module ``argv`` names (its first word that is not an option), if any."""
    for word in argv or ():
        if not word.startswith("-"):
            name = word.replace("-", "_")
            return name if name in COMMANDS else None
    return None


#: Options whose values may start with a minus sign (``--time-convention -jwt``): argparse
#: would read such a value as an option.
_DASH_VALUES = ("--time-convention",)


def _join_dash_values(argv: list[str]) -> list[str]:
    """``--opt -value`` as ``--opt=-value`` for the options of :data:`_DASH_VALUES`."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        if argv[i] in _DASH_VALUES and i + 1 < len(argv) and argv[i + 1].startswith("-"):
            out.append(f"{argv[i]}={argv[i + 1]}")
            i += 2
        else:
            out.append(argv[i])
            i += 1
    return out


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the process exit code.

    Errors the user can fix exit with status 2 and one line; so does a file that cannot be
    written (a full disk, a refused permission), after the command removed what it had
    written. Ctrl-C exits with 130 and one line: finished outputs (and an interrupted
    `mpipe run`'s finished stages and windows) are kept, so the same command resumes.
    """
    words = _join_dash_values(sys.argv[1:] if argv is None else list(argv))
    parser = build_parser(words)
    args = parser.parse_args(words)
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
    except KeyboardInterrupt:
        print(
            f"mpipe {args.command}: interrupted; finished files are kept and no file is "
            "half-written: run the same command again to resume",
            file=sys.stderr,
        )
        return 130
    except OSError as exc:
        if exc.errno not in _WRITE_ERRORS:
            raise
        where = f"{exc.filename}: " if exc.filename else ""
        if exc.errno == errno.EACCES:
            what = "permission denied"
        else:
            what = f"cannot write: {exc.strerror or exc}; no file was left half-written"
        print(f"mpipe {args.command}: error: {where}{what}", file=sys.stderr)
        return 2


def entry() -> None:
    """The ``mpipe`` command: :func:`main`, then the process ends with its exit code.

    When the command is done (every output written and closed, every worker pool ended)
    the process ends without the interpreter's teardown: freeing the modules a run loads
    (numpy, scipy, pandas, numba's compiled kernels) took 0.3-0.5 s after every command,
    measured on the 4 s tone of the speed benchmark (main returned at 18.78 s, the process
    ended at 19.27 s). The exit functions still run and the streams are flushed; with a
    thread or a child process still alive the ordinary exit waits for them as before.
    """
    code = main()
    others = [t for t in threading.enumerate() if t is not threading.main_thread()]
    if any(not t.daemon for t in others) or multiprocessing.active_children():
        sys.exit(code)
    run_exit_functions = getattr(atexit, "_run_exitfuncs", None)
    if run_exit_functions is None:  # not CPython: the ordinary exit
        sys.exit(code)
    run_exit_functions()
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


if __name__ == "__main__":
    entry()
