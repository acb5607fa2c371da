"""Figures off the critical path: drawn in a separate process while the run goes on.

A stage writes its tables, hands its figures to a :class:`FigureQueue` and returns; one
background process draws them (each figure written atomically, as before) while the next
stages run. ``mpipe run`` waits for every figure before it writes the report, which shows
them. The tables do not depend on the figures, so they are the same either way.

Drawing costs about 3 s of CPU on a 2 s take (the inversion's tracks and note figures,
the segmentation's and the separation's plots). In the background the separation's,
validation's and conditioning's figures overlap the inversion, and the inversion's the
resynthesis; the resynthesis's own figures, and whatever of the inversion's is left, are
still waited for at the end. The drawing processes are as many as the run's local workers
and run at a lower priority (:data:`NICE`): while the inversion's workers are busy they take
what CPU those leave, and the tail after the resynthesis, when nothing else runs, is drawn
on every core (measured on a 4 s tone, 2 workers, quiet machine: one process drew the
tail's figures for 2.5 s while the run waited, with the parent and a core idle).
"""

from __future__ import annotations

import logging
import multiprocessing
import os
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from pathlib import Path

from mpipe.core.io import write_atomic
from mpipe.core.workers import worker_init

#: Niceness added to each drawing process: figures yield the CPU to the stages' workers.
NICE = 10

log = logging.getLogger(__name__)


def draw_now(fn: Callable, *args, **kwargs):
    """Draw a figure in this process (the default of every ``draw`` argument)."""
    return fn(*args, **kwargs)


def path_second(fn: Callable, first, path: str | Path, *rest) -> Path:
    """``fn(first, tmp, *rest)`` into a temporary file, then renamed to ``path``.

    For the plotting functions that write to the path they are given
    (``plot_blocks``, ``plot_impedance``): the file appears whole or not at all.
    """
    return write_atomic(Path(path), lambda tmp: fn(first, tmp, *rest))


def _init_drawing(parent_pid: int) -> None:
    """Initializer of a drawing process: it ends with its parent and yields to the workers."""
    worker_init(parent_pid)
    try:
        os.nice(NICE)
    except (OSError, AttributeError):  # not permitted, or not on this system: full priority
        pass


class FigureQueue:
    """Figures drawn by background processes, handed over in order, awaited all at once.

    Parameters
    ----------
    background : bool
        False: draw each figure at once in this process (``draw`` is :func:`draw_now`).
    processes : int
        Drawing processes (the run's local workers; at least one).

    Notes
    -----
    The process is started as the inversion's local workers are (the platform's default:
    ``fork`` on Linux, so no imports to repeat and no ``__main__`` guard needed in a
    script that calls :func:`mpipe.pipeline.orchestration.run_take`), on the first figure
    (the separation's, before any compiled kernel or worker pool exists in the parent).
    The arguments travel by pickling: a take on disk (``DiskArray``) as its file name.
    """

    def __init__(self, background: bool = True, processes: int = 1) -> None:
        self.background = background
        self.processes = max(1, int(processes))
        self._pool: ProcessPoolExecutor | None = None
        self._pending: list[tuple[str, Future]] = []

    def draw(self, fn: Callable, *args, **kwargs) -> None:
        """Draw ``fn(*args, **kwargs)``: in the background process, or at once."""
        if not self.background:
            fn(*args, **kwargs)
            return
        if self._pool is None:
            self._pool = ProcessPoolExecutor(
                self.processes, mp_context=multiprocessing.get_context(),
                initializer=_init_drawing, initargs=(os.getpid(),),
            )  # fmt: skip
        future = self._pool.submit(fn, *args, **kwargs)
        self._pending.append((getattr(fn, "__name__", "figure"), future))

    def wait(self) -> None:
        """Wait for every figure handed over so far; raise the first drawing error."""
        pending, self._pending = self._pending, []
        error = None
        for name, future in pending:
            try:
                future.result()
            except Exception as exc:  # every figure is awaited before the first error is raised
                log.warning("figure %s not drawn: %s", name, exc)
                error = error or exc
        if error is not None:
            raise error

    def close(self) -> None:
        """Wait for the figures, then stop the background process."""
        try:
            self.wait()
        finally:
            if self._pool is not None:
                self._pool.shutdown(wait=True)
                self._pool = None

    def __enter__(self) -> FigureQueue:
        return self

    def __exit__(self, kind, value, tb) -> None:
        if kind is None:
            self.close()
            return
        # the run failed: its error is the one to see; the figures still finish
        try:
            self.close()
        except Exception as exc:
            log.warning("figures not drawn after the run failed: %s", exc)


__all__ = ["NICE", "FigureQueue", "draw_now", "path_second"]
