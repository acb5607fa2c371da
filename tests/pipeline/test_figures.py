"""Figures drawn off the critical path: by another process, awaited before the report."""

import os
import shutil
from pathlib import Path

import pytest

from mpipe.pipeline.figures import FigureQueue, path_second

pytestmark = pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs /proc")


def _pid(path: Path) -> int:
    """The ``Pid:`` line of a copy of ``/proc/self/status``."""
    line = next(s for s in path.read_text().splitlines() if s.startswith("Pid:"))
    return int(line.split()[1])


def test_figures_are_drawn_by_another_process_and_awaited(tmp_path):
    # the "figure" copies the drawing process's own status: its pid says where it was drawn
    with FigureQueue() as figures:
        figures.draw(path_second, shutil.copyfile, "/proc/self/status", tmp_path / "a.txt")
        figures.wait()
        assert _pid(tmp_path / "a.txt") != os.getpid()
    with FigureQueue(background=False) as figures:  # executor.workers: 1, in this process
        figures.draw(path_second, shutil.copyfile, "/proc/self/status", tmp_path / "b.txt")
        assert _pid(tmp_path / "b.txt") == os.getpid()


def test_a_figure_that_fails_is_raised_when_awaited_and_leaves_no_file(tmp_path):
    figures = FigureQueue()
    figures.draw(path_second, shutil.copyfile, tmp_path / "missing", tmp_path / "a.png")
    with pytest.raises(FileNotFoundError):
        figures.close()
    assert not (tmp_path / "a.png").exists()
