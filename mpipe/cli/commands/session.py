"""``mpipe session``: every take of a recording session, resumable, and the session's tables."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import pandas as pd

from mpipe.core.cluster import check_scheduler
from mpipe.core.errors import UserError
from mpipe.core.io import check_output_folder, folder_lock
from mpipe.core.progress import write
from mpipe.inversion.fit.execution import connect
from mpipe.inversion.settings import ExecutorConfig
from mpipe.pipeline.batch import run_takes, summary_lines
from mpipe.pipeline.orchestration import ValidationFailed, usable
from mpipe.pipeline.session import Session, load_session
from mpipe.pipeline.session_table import write_session_tables


def add_parser(sub) -> None:
    """Register the ``session`` subcommand."""
    p = sub.add_parser(
        "session",
        help="every take of a recording session (a session file), and one table of its notes",
        description="Run every stage on each take a session file lists (each with its own "
        "calibration and fingering), side by side on local workers or a Dask cluster, into "
        "OUT/<take>/, then write OUT/session.csv (one row per note per take) and "
        "OUT/session_takes.csv (one row per take). Finished takes are not redone when run "
        "again, so an interrupted session resumes. See docs/sessions.md.",
    )
    p.add_argument("session", help="session YAML (docs/sessions.md)")
    p.add_argument("-o", "--output", required=True, metavar="OUT", help="output directory")
    where = p.add_mutually_exclusive_group()
    where.add_argument(
        "--workers",
        type=int,
        metavar="N",
        help="takes side by side on N local worker processes (default: the pipeline's "
        "executor; 1: one take after the other in this process)",
    )
    where.add_argument(
        "--scheduler",
        metavar="ADDR",
        help="takes side by side on the Dask cluster at ADDR (tcp://HOST:PORT); the takes, "
        "calibrations and OUT must be on a file system its workers see (default: none, the "
        "pipeline's executor)",
    )
    p.add_argument("--force", action="store_true", help="redo finished stages and windows")
    p.add_argument(
        "--accept-failed-validation",
        action="store_true",
        help="invert a take whose impedance validation FAILs (by default that take stops "
        "before its inversion; the other takes go on)",
    )
    p.set_defaults(func=run)


def _executor(session: Session, args: argparse.Namespace) -> Session:
    """The session with ``--workers`` or ``--scheduler`` in place of the pipeline's executor."""
    executor = session.pipeline.executor
    if args.workers is not None:
        if not 1 <= args.workers <= 4096:
            raise UserError(f"--workers: expected a number in 1-4096, got {args.workers}")
        executor = ExecutorConfig(kind="local", workers=args.workers)
    if args.scheduler is not None:
        # malformed: one line now; not answering: when connecting, before any work
        check_scheduler(args.scheduler, executor.connect_timeout_s, "--scheduler")
        executor = dataclasses.replace(executor, kind="dask", scheduler=args.scheduler)
    pipeline = dataclasses.replace(session.pipeline, executor=executor)
    return dataclasses.replace(session, pipeline=pipeline)


def run(args: argparse.Namespace) -> int:
    """Execute ``mpipe session``."""
    session = _executor(load_session(args.session), args)
    out = Path(args.output)
    check_output_folder(out)
    for take in session.takes:
        check_output_folder(out / take.name)
    cfg = session.pipeline
    client = None
    if cfg.executor.kind == "dask":
        option = "--scheduler" if args.scheduler else "executor.scheduler"
        client = connect(cfg.executor.scheduler, cfg.executor.connect_timeout_s, option)
    results: dict = {}
    takes = [list(t.files) for t in session.takes]
    names = [t.name for t in session.takes]
    n = len(session.takes)
    write(f"session {session.source}: {n} takes into {out}")
    try:
        # the session's own tables: one session at a time in OUT
        with folder_lock(out):
            outcomes = run_takes(
                [session.config_of(t) for t in session.takes],
                [t.calibration for t in session.takes], takes, out, args.force, client,
                say=write, accept_failed_validation=args.accept_failed_validation, names=names,
            )  # fmt: skip
            order = {id(t): i for i, t in enumerate(takes)}
            done = []
            for t, result, wall in outcomes:
                name = names[order[id(t)]]
                results[name] = result
                done.append((order[id(t)], t, result, wall))
                if isinstance(result, Exception):
                    first = str(result).splitlines()[0] if str(result) else type(result).__name__
                    write(f"[{name}] failed: {first}")
                elif not usable(result):
                    write(f"[{name}] failed: no window has status ok (no usable result)")
            written = write_session_tables(session, out, results)
    finally:
        if client is not None:
            client.close()
    done.sort(key=lambda d: d[0])
    print(f"{n} takes:")
    # the state session_takes.csv gives each take (ok, check or failed), not a second opinion
    table = pd.read_csv(written["takes"], keep_default_na=False)
    states = dict(zip(table["take"].astype(str), table["state"].astype(str), strict=True))
    print("\n".join(summary_lines([d[1:] for d in done], [names[d[0]] for d in done], states)))
    failed = [
        name
        for name, r in results.items()
        if isinstance(r, Exception | ValidationFailed) or not usable(r)
    ]
    print(f"session table: {written['notes']} ({_rows(written['notes'])} notes), takes: "
          f"{written['takes']}")  # fmt: skip
    if failed:
        print(f"{len(failed)} of {n} takes have no usable result: {', '.join(sorted(failed))}")
    return 1 if failed else 0


def _rows(path: Path) -> int:
    with open(path) as f:
        return max(sum(1 for _ in f) - 1, 0)
