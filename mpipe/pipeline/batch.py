"""A batch of takes side by side: each take's stages on a worker of its own.

``mpipe run PIPE take1 ... takeN`` with several takes and several workers runs whole takes
in parallel: locally one worker process per take at a time (``executor.workers``), on a
Dask cluster one task per take (``executor.kind: dask``). Inside a take the windows then
run one after the other on its worker, so a batch keeps every worker busy with whole takes
instead of spreading one take's windows. One take alone (or one worker) runs as before,
its windows spread over the workers. Every window's answer depends only on its own data
and the take's cold start, so each take's table is the one it gets run alone.

The output folders are those of single runs (``OUT/<take>/<stage>/``), resumable, replaced
only with ``--force``; this process holds every take's folder lock for the whole batch, so
a second run on one of them stops at once. On Dask the workers write the outputs: the
output folder, the takes and the calibration must be on a file system every worker sees
under the same paths (checked before any work).
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import sys
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import as_completed
from pathlib import Path

from threadpoolctl import threadpool_limits

from mpipe.core.errors import UserError
from mpipe.core.io import folder_lock
from mpipe.core.progress import ProgressBar, log_prefix
from mpipe.core.workers import process_pool
from mpipe.inversion.settings import ExecutorConfig
from mpipe.pipeline.orchestration import (
    TakeRun,
    ValidationFailed,
    run_take,
    run_take_unlocked,
    take_name,
    usable,
)
from mpipe.pipeline.settings import PipelineConfig

#: Errors that end one take of a batch (reported per take; the other takes go on).
TAKE_ERRORS = (ValidationFailed, ValueError, OSError, UserError)


def batch_workers(cfg: PipelineConfig, n_takes: int, client=None) -> int:
    """How many takes run side by side: 1 for one take, else one per worker (at most N)."""
    if n_takes < 2:
        return 1
    if client is not None:
        return min(n_takes, max(1, len(client.scheduler_info()["workers"])))
    return min(n_takes, cfg.executor.workers or os.cpu_count() or 1)


def run_takes(
    cfg: PipelineConfig | Sequence[PipelineConfig],
    cal_path: Path | Sequence[Path],
    takes: Sequence[Sequence[Path]],
    out: str | Path,
    force: bool = False,
    client=None,
    say: Callable[[str], None] = print,
    accept_failed_validation: bool = False,
    names: Sequence[str] | None = None,
) -> Iterator[tuple[Sequence[Path], TakeRun | Exception, float]]:
    """Run every take; yield ``(take paths, TakeRun or the error that ended it, wall s)``.

    ``names`` are the takes' folders under ``out`` (default: :func:`take_name` of each);
    ``cal_path`` is one calibration for every take, or one per take (in the takes' order:
    :func:`mpipe.pipeline.take_calibration.take_calibrations`); ``cfg`` likewise one
    pipeline, or one per take (a session's takes differ in their fingering).

    One take, or one worker: one take after the other, as :func:`run_take` (its windows
    spread over the workers or the cluster), and takes of one name (one output folder).
    Several: whole takes side by side, yielded in the order they finish, each take's stage
    lines said when it finishes. With several takes, either way, one bar counts the takes
    (the takes' own bars are not drawn), every line says its take, each take runs with
    one BLAS thread, and any error a take raises ends that take only.
    """
    names = [take_name(t) for t in takes] if names is None else list(names)
    cals = (
        [Path(c) for c in cal_path]
        if isinstance(cal_path, list | tuple)
        else [Path(cal_path)] * len(takes)
    )
    cfgs = list(cfg) if isinstance(cfg, list | tuple) else [cfg] * len(takes)
    n = batch_workers(cfgs[0], len(takes), client)
    if len(set(names)) < len(names):
        n = 1  # two takes of one name write one folder: one after the other, as before
    if n < 2 and len(takes) < 2:
        for t, name, cal, one in zip(takes, names, cals, cfgs, strict=True):
            t0 = time.perf_counter()
            try:
                result = run_take(
                    one, cal, t, out, force, client, say, accept_failed_validation, name
                )
            except TAKE_ERRORS as exc:
                result = exc
            yield t, result, time.perf_counter() - t0
        return
    if n < 2:
        yield from _one_after_another(cfgs, cals, takes, names, out, force, client, say,
                                      accept_failed_validation)  # fmt: skip
        return

    # every take's folder locked by this process for the whole batch: a run on one of them
    # elsewhere stops at once; the workers write under these locks
    with contextlib.ExitStack() as locks:
        for name in names:
            locks.enter_context(folder_lock(Path(out) / name))
        # absolute paths: a worker's working folder is not this process's
        args = (Path(out).resolve(), force, accept_failed_validation)
        paths = [
            ([Path(p).resolve() for p in t], name, cal.resolve(),
             dataclasses.replace(c, executor=ExecutorConfig(kind="local", workers=1)))
            for t, name, cal, c in zip(takes, names, cals, cfgs, strict=True)
        ]  # fmt: skip
        if client is not None:
            done = _on_dask(client, paths, args, say)
        else:
            done = _on_processes(n, paths, args, say)
        for i, result, wall in done:
            yield takes[i], result, wall


def _one_after_another(cfgs, cals, takes, names, out, force, client, say, accept):
    """Several takes in this process, one after the other, under one bar over the takes."""
    bar = ProgressBar(len(takes), desc="takes", unit="take")
    try:
        for t, name, cal, cfg in zip(takes, names, cals, cfgs, strict=True):
            t0 = time.perf_counter()
            bar.describe(f"takes ({name})")
            with _take_scope(name):
                try:
                    result = run_take(cfg, cal, t, out, force, client, say, accept, name)
                except Exception as exc:  # noqa: BLE001 - one take's failure is reported
                    result = exc
            bar.update()
            yield t, result, time.perf_counter() - t0
    finally:
        bar.close()


@contextlib.contextmanager
def _take_scope(name: str) -> Iterator[None]:
    """One take of several: no bars of its own, its name on every log line, one BLAS thread.

    One BLAS thread: the harmonic fits of the uncertainty budget solve (4800, 61) least
    squares; a threaded BLAS on a machine whose cores are taken (the other takes, other
    users) took 1.35 s a solve against 0.02 s on one thread (measured on the shared 2-core
    development machine; a 0.62 s take's inversion stage 374 s against 25 s).
    """
    with (
        contextlib.redirect_stderr(_NotATerminal(sys.stderr)),
        log_prefix(f"[{name}] "),
        threadpool_limits(limits=1, user_api="blas"),
    ):
        yield


def _take_task(take, out, force, accept_failed_validation):
    """One take on a worker (the caller holds its folder lock); its lines are returned."""
    take_paths, name, cal_path, cfg = take
    lines: list[str] = []
    t0 = time.perf_counter()
    # no bars from the workers: the batch's one progress view is the caller's
    with _take_scope(name):
        try:
            result = run_take_unlocked(
                cfg, cal_path, take_paths, out, force, None, lines.append,
                accept_failed_validation, name,
            )  # fmt: skip
        except Exception as exc:  # noqa: BLE001 - one take's failure is reported
            result = exc
    return result, lines, time.perf_counter() - t0


class _NotATerminal:
    """A stream that writes through to another but is never a terminal (no bars drawn)."""

    def __init__(self, stream):
        self._stream = stream

    def write(self, text: str) -> int:
        return self._stream.write(text)

    def flush(self) -> None:
        self._stream.flush()

    def isatty(self) -> bool:
        return False


def _on_processes(n: int, takes, args, say):

    with process_pool(n) as pool:
        futures = {pool.submit(_take_task, t, *args): i for i, t in enumerate(takes)}
        yield from _as_they_end(futures, as_completed(futures), say)


def _on_dask(client, takes, args, say):
    from distributed import as_completed

    check_shared_files(client, [(t, n) for t, n, *_ in takes], [c for *_, c, _ in takes], args[0])
    futures = {
        client.submit(_take_task, t, *args, pure=False, retries=1): i
        for i, t in enumerate(takes)
    }  # fmt: skip
    yield from _as_they_end(futures, as_completed(list(futures), loop=client.loop), say)


def _as_they_end(futures: dict, completed, say):
    """Yield ``(take index, result, wall s)`` as takes end; one bar over the takes."""
    bar = ProgressBar(len(futures), desc="takes", unit="take")
    try:
        for f in completed:
            result, lines, wall = f.result()
            for line in lines:
                say(line)
            bar.update()
            yield futures[f], result, wall
    finally:
        bar.close()


def check_shared_files(client, takes, cal_path: Path | Sequence[Path], out: str | Path) -> None:
    """Raise a one-line UserError unless every Dask worker sees the batch's files.

    The workers read the takes and the calibration and write into ``out``: a file written
    here into ``out`` must be visible to each worker under the same path.
    """
    probe = Path(out) / f".mpipe-probe-{uuid.uuid4().hex}"
    probe.write_text("mpipe\n")
    cals = cal_path if isinstance(cal_path, list | tuple) else [cal_path]
    paths = [str(probe.resolve()), *sorted({str(Path(c).resolve()) for c in cals})]
    paths += [str(Path(p).resolve()) for t, _ in takes for p in t]
    try:
        seen = client.run(_missing, paths)
    finally:
        probe.unlink()
    for worker, missing in seen.items():
        if missing:
            what = "the output folder" if missing[0] == paths[0] else missing[0]
            raise UserError(
                f"{worker}: this Dask worker does not see {what} ({len(missing)} of "
                f"{len(paths)} paths missing); a batch on a cluster needs the takes, the "
                f"calibration and {out} on a file system shared under the same paths"
            )


def _missing(paths: list[str]) -> list[str]:
    return [p for p in paths if not os.path.exists(p)]


def summary_lines(
    outcomes: Sequence[tuple[Sequence[Path], TakeRun | Exception, float]],
    names: Sequence[str] | None = None,
    states: dict[str, str] | None = None,
) -> list:
    """One line per take: its verdict, its windows, its wall time; or why it failed.

    ``states`` (take name to state), when given, says each take's state: a session's
    ``session_takes.csv`` state (``check`` with its take-level checks or a validation
    short of PASS), which the line must not contradict.
    """
    lines = []
    for i, (t, result, wall) in enumerate(outcomes):
        name = take_name(t) if names is None else names[i]
        if isinstance(result, Exception):
            first = str(result).splitlines()[0] if str(result) else type(result).__name__
            lines.append(f"  {name}: failed ({wall:.1f} s): {first}")
            continue
        inv = result.records["inversion"].summary
        verdict = result.records["validation"].summary.get("verdict", "?").upper()
        state = "ok" if usable(result) else "failed: no window has status ok"
        if states and states.get(name) and usable(result):
            state = states[name]
        lines.append(
            f"  {name}: {state}; validation {verdict}; {inv.get('status_line', '')} ({wall:.1f} s)"
        )
    return lines


__all__ = ["TAKE_ERRORS", "batch_workers", "check_shared_files", "run_takes", "summary_lines"]
