"""Safe writing of result files: atomic replacement, and no overwriting without force."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Callable, Iterable, Mapping
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from mpipe.core.errors import OutputExistsError, UserError

try:
    import fcntl
except ImportError:  # Windows
    fcntl = None
    import msvcrt


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def check_writable(
    paths: Iterable[str | Path],
    force: bool,
    inputs: Mapping[str, str | Path | None] | None = None,
) -> None:
    """Check output files before any work: their folders writable, none overwritten.

    Existing files are refused unless ``force`` is set; the folders are created when
    missing, and must be writable (:func:`check_output_folder`). An output that is one of
    the command's ``inputs`` (what names it, e.g. ``--score``, to its path; None: not
    given) is refused even with ``force``: the command would overwrite what it reads.

    Raises
    ------
    OutputExistsError
        Naming the first existing file.
    UserError
        Naming an output that is an input (both paths), an output that is a folder, or a
        folder that cannot be written.
    """
    paths = [Path(p) for p in paths]
    check_not_inputs(paths, inputs or {})
    for p in paths:
        if p.is_dir():
            raise UserError(f"{p}: is a folder; expected an output file name")
        if not force and p.exists():
            raise OutputExistsError(f"{p} exists; use --force to overwrite it")
    for parent in dict.fromkeys(p.parent for p in paths):
        check_output_folder(parent)


def check_not_inputs(
    outputs: Iterable[str | Path], inputs: Mapping[str, str | Path | None]
) -> None:
    """Refuse an output file that is one of the inputs (the same path, or a link to it).

    Raises
    ------
    UserError
        Naming the output and the input (and what names it), whatever ``--force`` says.
    """
    for out in outputs:
        for what, given in inputs.items():
            if given is not None and _same_file(Path(out), Path(given)):
                raise UserError(
                    f"{out}: this output is the input {what} {given}; writing it would "
                    "overwrite what the command reads (also with --force): choose another "
                    "output name"
                )


def _same_file(a: Path, b: Path) -> bool:
    if a.resolve() == b.resolve():
        return True
    try:
        return os.path.samefile(a, b)  # a hard link, or another spelling of one file
    except OSError:
        return False  # one of them does not exist yet


@contextmanager
def atomic_path(path: str | Path):
    """Yield a temporary path beside ``path``; move it into place only on success.

    A crash or an exception leaves any previous file untouched and no partial file behind.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        # mkstemp creates 0600 files; results are meant to be shared like any other file
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_atomic(path: str | Path, writer: Callable[[Path], None]) -> Path:
    """Write a file through ``writer(tmp_path)`` and move it into place atomically."""
    with atomic_path(path) as tmp:
        writer(tmp)
    return Path(path)


def write_text_atomic(path: str | Path, text: str) -> Path:
    """Write text to ``path`` atomically."""
    return write_atomic(path, lambda tmp: tmp.write_text(text))


def write_npz_atomic(path: str | Path, compressed: bool = False, **arrays) -> Path:
    """Write arrays to an ``.npz`` file atomically (never a half-written file).

    Parameters
    ----------
    path : str or Path
        Output file.
    compressed : bool
        Use ``numpy.savez_compressed``.
    **arrays
        Name to array (any units; the caller's docstring names them).
    """
    save = np.savez_compressed if compressed else np.savez

    def writer(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            save(fh, **{k: np.asarray(v) for k, v in arrays.items()})

    return write_atomic(path, writer)


#: Lock file kept in an output folder while a run writes into it.
LOCK_NAME = ".mpipe.lock"


def check_output_folder(path: str | Path) -> Path:
    """Make sure ``path`` is, or can become, a folder this process can write into.

    Called before any computation, so that a bad output path fails at once instead of
    after the work. The folder is created when missing (with its parents).

    Parameters
    ----------
    path : str or Path
        Output folder.

    Returns
    -------
    Path

    Raises
    ------
    UserError
        One line naming the path: it is a file, it cannot be created, or it is not
        writable.
    """
    path = Path(path)
    for parent in (path, *path.parents):
        if parent.exists() and not parent.is_dir():
            raise UserError(f"{parent}: exists and is not a folder; choose another output path")
        if parent.exists():
            break
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{path}: cannot create the output folder ({exc.strerror})") from None
    try:
        fd, probe = tempfile.mkstemp(prefix=".mpipe-probe.", dir=path)
    except OSError as exc:
        raise UserError(f"{path}: output folder is not writable ({exc.strerror})") from None
    os.close(fd)
    os.unlink(probe)
    return path


@contextmanager
def folder_lock(folder: str | Path):
    """Hold an exclusive lock on an output folder while a run writes into it.

    A second run on the same folder (from this or another process on this machine) fails
    at once instead of mixing its results with the first's. The lock is an advisory
    ``flock`` on ``folder/.mpipe.lock``; the kernel releases it when the holding process
    ends for any reason, so a killed run never leaves a stale lock. (Network file systems
    may not honour ``flock`` across machines.) The file is removed when the run ends, so
    a finished folder holds only results; a killed run leaves it, unlocked.

    Raises
    ------
    UserError
        When another run holds the folder, naming it and that run's process id.
    """
    folder = check_output_folder(folder)
    lock_path = folder / LOCK_NAME
    fd = _acquire(lock_path, folder)
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield folder
    finally:
        # unlink while still locked: a run waiting on this file then sees it is gone
        # (_acquire checks) and locks a new one, never a second holder of the folder
        with contextlib.suppress(OSError):
            os.unlink(lock_path)
        _unlock_fd(fd)
        os.close(fd)


def _acquire(lock_path: Path, folder: Path) -> int:
    """An open descriptor of ``lock_path``, locked, and still the file at that path."""
    while True:
        fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o666 & ~_umask())
        try:
            _lock_fd(fd)
        except BlockingIOError:
            holder = os.pread(fd, 64, 0).decode(errors="replace").strip() or "unknown"
            os.close(fd)
            raise UserError(
                f"{folder}: in use by another mpipe run (process {holder}); wait for it to "
                "finish or choose another output folder"
            ) from None
        try:
            same = os.fstat(fd).st_ino == os.stat(lock_path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            return fd
        # the holder removed the file between our open and our lock: take the new one
        _unlock_fd(fd)
        os.close(fd)


def _lock_fd(fd: int) -> None:
    if fcntl is None:  # Windows
        try:
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
        except OSError:
            raise BlockingIOError from None
        return
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)


def _unlock_fd(fd: int) -> None:
    if fcntl is None:  # Windows
        with contextlib.suppress(OSError):
            msvcrt.locking(fd, msvcrt.LK_UNLCK, 1)
        return
    fcntl.flock(fd, fcntl.LOCK_UN)


#: Number format of CSV output: 10 significant digits, far beyond any measured quantity,
#: without the binary noise of 17 digits (0.29999999999999999).
CSV_FLOAT_FORMAT = "%.10g"


def write_csv(path: str | Path, table) -> Path:
    """Write a DataFrame as CSV atomically, numbers to 10 significant digits."""
    return write_atomic(
        path, lambda tmp: table.to_csv(tmp, index=False, float_format=CSV_FLOAT_FORMAT)
    )
