"""Compile the numba kernels before the inversion needs them (``make demo``'s first run).

The kernels are compiled with ``cache=True``: once compiled, every later process (the
inversion's workers too) loads them from numba's cache in a fraction of a second. On a
fresh install the compilation takes about 25 s of CPU. :func:`start_warmup` runs it in a
separate process while the first stages (separation, translation, validation,
conditioning: numpy work) run, and :func:`wait_for_warmup`, called where the inversion
starts, waits for it, so that the inversion's worker processes load the kernels from the
cache instead of each compiling them again. ``python -m mpipe.pipeline.warmup`` compiles
them at install time (the Makefile's install step).

The warm-up process holds an exclusive ``flock`` on a lock file while it compiles (the
lock is taken by the parent before the child starts and passed to it, so a waiter can never
miss it); :func:`wait_for_warmup` takes a shared lock, which is granted when the child ends.
No state lives in Python: the lock is the operating system's.
"""

from __future__ import annotations

import fcntl
import hashlib
import logging
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

PACKAGE = Path(__file__).resolve().parents[1]
#: One kernel per cached module: their cache index (``<module>.<kernel>-<line>.py3X.nbi``)
#: in the package's ``__pycache__`` says the kernels have been compiled here before.
MARKERS = (
    ("reed", "kernels.run-"),
    ("inversion/fit", "fastpath._evaluate-"),
    ("inversion/fit", "input_tangents._respond-"),
    ("inversion/fit", "least_squares.normal_equations-"),
    ("reed", "block_fft.rfft_block-"),
    ("reed", "opening.drive_reed-"),
)


def lock_path() -> Path:
    """The lock file of this installation's warm-up (in the temporary directory)."""
    key = hashlib.sha1(str(PACKAGE).encode()).hexdigest()[:12]
    return Path(tempfile.gettempdir()) / f"mpipe-warmup-{key}.lock"


def kernels_cached() -> bool:
    """Whether numba's cache next to the package holds every marker kernel."""
    return all(
        any((PACKAGE / folder / "__pycache__").glob(f"{stem}*.nbi")) for folder, stem in MARKERS
    )


def start_warmup() -> subprocess.Popen | None:
    """Compile the kernels in a background process, unless they are cached already.

    Returns the process (None when nothing is to be done). Its output is discarded: a
    failure only means the kernels compile on first use, as before.
    """
    if kernels_cached():
        return None
    fd = os.open(lock_path(), os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:  # another run is warming them up: wait for that one instead
        os.close(fd)
        return None
    try:
        return subprocess.Popen(
            [sys.executable, "-m", "mpipe.pipeline.warmup", "--fd", str(fd)],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            pass_fds=(fd,), start_new_session=True,
        )  # fmt: skip
    finally:
        os.close(fd)  # the child holds the lock from here on


def wait_for_warmup() -> None:
    """Wait until no warm-up of this installation is compiling (at once when none is)."""
    path = lock_path()
    if not path.exists():
        return
    fd = os.open(path, os.O_RDONLY)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except OSError:
            log.info("waiting for the numba kernels to finish compiling (first run only)")
            fcntl.flock(fd, fcntl.LOCK_SH)
    finally:
        os.close(fd)


def warm_kernels() -> None:
    """Run every cached kernel once, with the argument types the pipeline gives it.

    A short simulated note of the shipped instrument (the reed kernels and the block FFT),
    the reed's opening, and the inversion's window evaluator with its sensitivities on a
    tiny window, with the model's low-pass (a zero-mean flow) and without it
    (:func:`mpipe.inversion.fit.sensitivities.load_compiled` and its full-flow twin).
    """
    from mpipe.acoustics.reflection import reflection_function
    from mpipe.inversion.fit.fastpath import WindowEvaluator
    from mpipe.inversion.fit.objective import ObjectiveSettings, TargetWindow
    from mpipe.inversion.fit.sensitivities import SensitivityEvaluator, load_compiled
    from mpipe.measurement.calibration import load_calibration
    from mpipe.reed.bore_kernel import prepare_bore
    from mpipe.reed.model import simulate
    from mpipe.reed.opening import opening
    from mpipe.reed.parameters import ReedParameters

    fs = 100_000.0
    cal = load_calibration(PACKAGE.parent / "calibration" / "simplified_clarinet.yaml")
    air = cal.air_properties()
    kernel = prepare_bore(reflection_function(cal.bore, air, fs=fs), air)
    reed = ReedParameters(k=8.66e6, S=7.62e-5, y_m=4e-4, p_m=1800.0, lam=0.013, m=0.05,
                          g=3000.0, k_c=8.23e10)  # fmt: skip
    sim = simulate(reed, kernel, 4000)
    opening(reed, sim.p, fs, 3000, 1000)
    load_compiled()
    p, u = np.asarray(sim.p, dtype=float), np.asarray(sim.u, dtype=float)
    target = TargetWindow(p[-400:], u[-400:], p[:-400], u[:-400], fs, False)
    ev = WindowEvaluator(kernel, target, ObjectiveSettings(lowpass=None))
    r, jac = np.empty(400), np.empty((400, 2))
    ev.residuals_into(reed, r)
    SensitivityEvaluator(ev, ("k", "S"), False).jacobian_into(reed, r, jac)


def main(argv: list[str] | None = None) -> int:
    """``python -m mpipe.pipeline.warmup [--fd N]``: compile the kernels (N: the lock held)."""
    argv = sys.argv[1:] if argv is None else argv
    try:
        warm_kernels()
    finally:
        if argv[:1] == ["--fd"]:
            os.close(int(argv[1]))  # releases the lock: the waiters go on
    return 0


__all__ = ["kernels_cached", "lock_path", "start_warmup", "wait_for_warmup", "warm_kernels"]


if __name__ == "__main__":
    sys.exit(main())
