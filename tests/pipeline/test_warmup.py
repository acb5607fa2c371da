"""The kernels' warm-up: compiled before the inversion, one warm-up at a time."""

import ast
import fcntl
import os
from pathlib import Path

import pytest

from mpipe.pipeline import warmup


@pytest.fixture
def lock(tmp_path, monkeypatch):
    path = tmp_path / "warmup.lock"
    monkeypatch.setattr(warmup, "lock_path", lambda: path)
    return path


def test_the_markers_are_cached_kernels_of_the_package():
    # each marker names an @njit(cache=True) function of its module: the cache check cannot
    # rot into "never cached" (a warm-up on every run) when a kernel is renamed
    for folder, stem in warmup.MARKERS:
        module, name = stem.rstrip("-").split(".")
        tree = ast.parse((warmup.PACKAGE / folder / f"{module}.py").read_text())
        (node,) = [n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == name]
        assert any("cache=True" in ast.unparse(d) for d in node.decorator_list), stem


def test_kernels_cached_reads_numba_s_cache_index(tmp_path, monkeypatch):
    monkeypatch.setattr(warmup, "PACKAGE", tmp_path)
    assert not warmup.kernels_cached()
    for folder, stem in warmup.MARKERS:
        cache = tmp_path / folder / "__pycache__"
        cache.mkdir(parents=True, exist_ok=True)
        (cache / f"{stem}10.py311.nbi").write_bytes(b"")
    assert warmup.kernels_cached()


def test_one_warmup_at_a_time_and_a_waiter_goes_on_when_it_ends(lock, monkeypatch):
    monkeypatch.setattr(warmup, "kernels_cached", lambda: False)
    warmup.wait_for_warmup()  # no warm-up ever: at once
    fd = os.open(lock, os.O_RDWR | os.O_CREAT)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)  # a warm-up compiling
        assert warmup.start_warmup() is None  # a second run starts none of its own
    finally:
        os.close(fd)  # the warm-up ends
    warmup.wait_for_warmup()  # returns: the lock is free


def test_the_warmup_compiles_what_the_pipeline_runs_and_releases_its_lock(lock):
    # in this process (the kernels load from the cache when the suite compiled them)
    fd = os.open(lock, os.O_RDWR | os.O_CREAT)
    fcntl.flock(fd, fcntl.LOCK_EX)
    assert warmup.main(["--fd", str(fd)]) == 0
    assert warmup.kernels_cached()
    probe = os.open(lock, os.O_RDONLY)
    try:
        fcntl.flock(probe, fcntl.LOCK_SH | fcntl.LOCK_NB)  # released: no OSError
    finally:
        os.close(probe)
    with pytest.raises(OSError):
        os.close(fd)  # main closed the lock's descriptor


def test_the_run_and_the_demo_start_it_and_the_inversion_waits_for_it():
    root = Path(warmup.__file__).resolve().parents[1]
    run = (root / "pipeline" / "orchestration.py").read_text()
    stages = (root / "pipeline" / "stage_work.py").read_text()  # the inversion stage's work
    assert "start_warmup()" in run and "wait_for_warmup()" in stages
    assert "start_warmup()" in (root / "cli" / "demo.py").read_text()
