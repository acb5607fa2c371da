"""Safe writing of result files: atomic replacement, and no overwriting without force."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Iterable
from contextlib import contextmanager
from pathlib import Path

from mpipe.errors import OutputExistsError


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def check_writable(paths: Iterable[str | Path], force: bool) -> None:
    """Refuse to overwrite existing outputs unless ``force`` is set.

    Raises
    ------
    OutputExistsError
        Naming the first existing file.
    """
    if force:
        return
    for p in paths:
        if Path(p).exists():
            raise OutputExistsError(f"{p} exists; use --force to overwrite it")


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
    import numpy as np

    save = np.savez_compressed if compressed else np.savez

    def writer(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            save(fh, **{k: np.asarray(v) for k, v in arrays.items()})

    return write_atomic(path, writer)
