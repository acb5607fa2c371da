"""Signals on disk: written block by block, read by slices, so memory does not grow with a take.

A stage's signals (p0, u0, p, u, ... at the pipeline's rate: 8 bytes per sample, 480 MB
per signal for a 10-minute take at 100 kHz) stay in an ``.npz`` file whose members are
stored uncompressed. :class:`NpzStream` writes such a file member by member, each
signal block by block; :func:`open_npz` opens one, giving the small members as arrays and
the long ones as :class:`DiskArray`: an object with the shape and dtype of the array
whose slices (``x[a:b]``) are read from the file when asked for, each a fresh ndarray.
Nothing is memory-mapped, so the resident memory holds only the slices in use (the
pages of a mapping stay resident once touched). A DiskArray pickles as its file, offset
and shape: a worker process reads its own slices.

The block interface every streaming stage uses is that of a 1-D array: ``len(x)``,
``x.size``, ``x.shape``, ``x[a:b]``; :func:`blocks` gives the block bounds.
``np.asarray(x)`` on a DiskArray reads the whole signal (a correct result, the memory of
the whole-array path): streaming code must not call it on a long signal.
"""

from __future__ import annotations

import struct
import zipfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

#: Members of at least this many bytes are opened as :class:`DiskArray` by :func:`open_npz`;
#: smaller ones are read at once.
LAZY_BYTES = 1 << 20

#: Samples per block of the streaming stages (8 MiB of float64).
BLOCK = 2**20


def blocks(n: int, size: int | None = None, start: int = 0) -> Iterator[tuple[int, int]]:
    """Bounds ``(a, b)`` of consecutive blocks of ``size`` samples covering ``start..n``.

    The last block is shorter when ``size`` (default :data:`BLOCK`) does not divide the
    length.
    """
    size = BLOCK if size is None else size
    if size < 1:
        raise ValueError(f"block size must be at least 1 sample, got {size}")
    for a in range(start, n, size):
        yield a, min(a + size, n)


def signal_range(x) -> tuple[float, float]:
    """Smallest and largest value of a signal (array or DiskArray), read in blocks."""
    lo, hi = np.inf, -np.inf
    for a, b in blocks(len(x)):
        part = x[a:b]
        lo, hi = min(lo, float(np.min(part))), max(hi, float(np.max(part)))
    return lo, hi


def pairwise_sum(x, f=None, a: int = 0, b: int | None = None, leaf: int | None = None) -> float:
    """``np.sum(f(x[a:b]))`` to the last bit, reading at most ``leaf`` samples at a time.

    numpy sums a contiguous float array pairwise: a stretch longer than 128 samples is
    split at half its length rounded down to a multiple of 8, and the halves' sums added.
    Splitting the same way down to stretches of at most ``leaf`` samples, and summing
    each with numpy, adds the same numbers in the same order. ``f`` is an elementwise
    function (e.g. ``lambda v: (v - m) ** 2``), applied to each stretch read.
    """
    b = len(x) if b is None else b
    leaf = BLOCK if leaf is None else leaf
    n = b - a
    if n <= max(leaf, 128):
        part = np.asarray(x[a:b], dtype=float)
        return float(np.sum(part if f is None else f(part)))
    half = n // 2
    half -= half % 8
    return pairwise_sum(x, f, a, a + half, leaf) + pairwise_sum(x, f, a + half, b, leaf)


def signal_moments(x, leaf: int | None = None) -> tuple[float, float]:
    """``np.mean`` and ``np.std`` of a signal (array or DiskArray), read in blocks, exactly."""
    n = len(x)
    mean = pairwise_sum(x, leaf=leaf) / n
    var = pairwise_sum(x, lambda v: (v - mean) * (v - mean), leaf=leaf) / n
    return mean, float(np.sqrt(var))


def _inside(part: np.ndarray, lo: float, hi: float, closed: bool) -> np.ndarray:
    return part[(part >= lo) & ((part <= hi) if closed else (part < hi))]


def signal_median(x, bins: int = 4096, gather: int = 1 << 20) -> float:
    """``np.median`` of a signal (array or DiskArray), exactly, in block passes.

    Histograms narrow the range down to the bins holding the middle ranks until they
    hold at most ``gather`` samples, which are then sorted: the same middle values as one
    sort of the whole signal.
    """
    n = len(x)
    if n == 0:
        return float("nan")
    ranks = sorted({(n - 1) // 2, n // 2})
    lo, hi = signal_range(x)
    closed, below = True, 0  # the range's top is included; samples under lo
    while True:
        edges = np.linspace(lo, hi, bins + 1) if hi > lo else np.array([lo, hi])
        counts = np.zeros(edges.size - 1, dtype=np.int64)
        for a, b in blocks(n):
            counts += np.histogram(_inside(x[a:b], lo, hi, closed), edges)[0]
        cum = below + np.cumsum(counts)
        first = int(np.searchsorted(cum, ranks[0], side="right"))
        last = int(np.searchsorted(cum, ranks[-1], side="right"))
        new_below = int(cum[first - 1]) if first else below
        top_closed = closed and last == counts.size - 1
        new_lo, new_hi = float(edges[first]), float(edges[last + 1])
        if int(cum[last]) - new_below <= gather or (new_lo, new_hi, top_closed) == (
            lo, hi, closed
        ):  # fmt: skip
            parts = [_inside(x[a:b], new_lo, new_hi, top_closed) for a, b in blocks(n)]
            vals = np.sort(np.concatenate(parts))
            picked = [float(vals[r - new_below]) for r in ranks]
            return picked[0] if len(picked) == 1 else float(np.mean(picked))
        lo, hi, closed, below = new_lo, new_hi, top_closed, new_below


class DiskArray:
    """A C-ordered array stored in a file at a byte offset, read by slices.

    Parameters
    ----------
    path : str or Path
        The file.
    offset : int
        Byte offset of the first element.
    shape : tuple of int
        Shape of the array (the first axis is time).
    dtype : numpy dtype
        Element type.
    """

    def __init__(self, path: str | Path, offset: int, shape: tuple[int, ...], dtype) -> None:
        self.path = str(path)
        self.offset = int(offset)
        self.shape = tuple(int(s) for s in shape)
        self.dtype = np.dtype(dtype)

    def __repr__(self) -> str:
        return f"DiskArray({self.path!r}, shape={self.shape}, dtype={self.dtype})"

    def __reduce__(self):
        # a worker reopens the file: nothing of the signal travels with the task
        return (DiskArray, (self.path, self.offset, self.shape, self.dtype))

    @property
    def ndim(self) -> int:
        """Number of axes."""
        return len(self.shape)

    @property
    def size(self) -> int:
        """Number of elements."""
        return int(np.prod(self.shape, dtype=np.int64))

    def __len__(self) -> int:
        return self.shape[0]

    def sub(self, a: int, b: int) -> DiskArray:
        """Rows ``a..b`` as a DiskArray (nothing read): a stretch of the signal, on disk."""
        n = self.shape[0]
        a, b = max(0, min(a, n)), max(0, min(b, n))
        row = int(np.prod(self.shape[1:], dtype=np.int64)) * self.dtype.itemsize
        return DiskArray(self.path, self.offset + a * row, (max(b - a, 0), *self.shape[1:]),
                         self.dtype)  # fmt: skip

    def rows(self, a: int, b: int) -> np.ndarray:
        """Rows (samples) ``a..b`` along the first axis, clipped to the array, as an ndarray."""
        n = self.shape[0]
        a, b = max(0, min(a, n)), max(0, min(b, n))
        b = max(a, b)
        row = int(np.prod(self.shape[1:], dtype=np.int64)) * self.dtype.itemsize
        out = np.empty((b - a, *self.shape[1:]), dtype=self.dtype)
        if b > a:
            with open(self.path, "rb") as fh:
                fh.seek(self.offset + a * row)
                got = fh.readinto(memoryview(out).cast("B"))
            if got != (b - a) * row:
                raise OSError(f"{self.path}: file shorter than its array header says")
        return out

    def __getitem__(self, key):
        if isinstance(key, tuple) and key and key[0] is Ellipsis and len(key) - 1 == self.ndim:
            key = key[1:]  # x[..., a:b] of a 1-D signal, as the filters slice it
        first, rest = (key[0], key[1:]) if isinstance(key, tuple) else (key, ())
        if isinstance(first, slice):
            a, b, step = first.indices(self.shape[0])
            out = self.rows(a, b) if step == 1 else self.rows(0, self.shape[0])[first]
        elif isinstance(first, int | np.integer):
            i = int(first) + (self.shape[0] if first < 0 else 0)
            if not 0 <= i < self.shape[0]:
                raise IndexError(f"index {first} out of range for {self.shape[0]} samples")
            out = self.rows(i, i + 1)[0]
        else:  # fancy indexing: the whole array (the whole-array path's memory)
            return np.asarray(self)[key]
        if not rest:
            return out
        return out[(slice(None), *rest)] if isinstance(first, slice) else out[rest]

    def __array__(self, dtype=None, copy=None):
        x = self.rows(0, self.shape[0])
        return x if dtype is None else x.astype(dtype, copy=False)


def as_signal(x):
    """A DiskArray as it is (read by slices later), anything else as a float ndarray."""
    return x if isinstance(x, DiskArray) else np.asarray(x, dtype=float)


def _member_offset(fh, info: zipfile.ZipInfo) -> int:
    """Byte offset of a stored member's data: after its local header (its own lengths)."""
    fh.seek(info.header_offset)
    head = fh.read(30)
    if head[:4] != b"PK\x03\x04":
        raise OSError(f"{fh.name}: broken zip member {info.filename}")
    name_len, extra_len = struct.unpack("<HH", head[26:30])
    return info.header_offset + 30 + name_len + extra_len


def open_npz(path: str | Path, lazy_bytes: int = LAZY_BYTES) -> dict:
    """The members of an ``.npz`` file: long uncompressed ones as :class:`DiskArray`.

    Parameters
    ----------
    path : str or Path
        The file (written by :class:`NpzStream`, ``numpy.savez`` or ``savez_compressed``).
    lazy_bytes : int
        Members of at least this many bytes, stored uncompressed, stay on disk.

    Returns
    -------
    dict
        Member name (without ``.npy``) to ndarray or DiskArray.
    """
    path = str(path)
    out: dict = {}
    with zipfile.ZipFile(path) as zf, open(path, "rb") as fh:
        for info in zf.infolist():
            name = info.filename.removesuffix(".npy")
            big = info.file_size >= lazy_bytes and info.compress_type == zipfile.ZIP_STORED
            if not big:
                with zf.open(info) as member:
                    out[name] = np.lib.format.read_array(member, allow_pickle=False)
                continue
            start = _member_offset(fh, info)
            fh.seek(start)
            version = np.lib.format.read_magic(fh)
            read_header = (
                np.lib.format.read_array_header_1_0
                if version == (1, 0)
                else np.lib.format.read_array_header_2_0
            )
            shape, fortran, dtype = read_header(fh)
            if fortran or dtype.hasobject:
                with zf.open(info) as member:
                    out[name] = np.lib.format.read_array(member, allow_pickle=False)
                continue
            out[name] = DiskArray(path, fh.tell(), shape, dtype)
    return out


class NpzStream:
    """Write an ``.npz`` file (members stored uncompressed) member by member, in blocks.

    Use as a context manager on an open path; :meth:`add` writes a whole array,
    :meth:`signal` opens a member of known shape that takes its rows in order through
    ``write(block)``. ``numpy.load`` reads the result as any ``.npz``.

    Parameters
    ----------
    path : str or Path
        The file to write (the caller makes it atomic, e.g. with
        :func:`mpipe.core.io.write_atomic`).
    """

    def __init__(self, path: str | Path) -> None:
        self._zip = zipfile.ZipFile(path, "w", compression=zipfile.ZIP_STORED, allowZip64=True)

    def __enter__(self) -> NpzStream:
        return self

    def __exit__(self, *exc) -> None:
        self._zip.close()

    def add(self, name: str, array) -> None:
        """Write a whole (small) array as member ``name``."""
        with self._zip.open(f"{name}.npy", "w", force_zip64=True) as member:
            np.lib.format.write_array(member, np.asanyarray(array), allow_pickle=False)

    def signal(self, name: str, shape: tuple[int, ...], dtype=np.float64) -> _MemberWriter:
        """A writer of member ``name`` of ``shape``: call ``write(rows)`` until it is full."""
        return _MemberWriter(self._zip, name, tuple(int(s) for s in shape), np.dtype(dtype))


class _MemberWriter:
    """Rows of one ``.npy`` member, written in order; refuses a short or long member."""

    def __init__(self, zf: zipfile.ZipFile, name: str, shape: tuple[int, ...], dtype) -> None:
        self.name, self.shape, self.dtype, self.done = name, shape, dtype, 0
        self._member = zf.open(f"{name}.npy", "w", force_zip64=True)
        header = {"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False,
                  "shape": shape}  # fmt: skip
        np.lib.format.write_array_header_2_0(self._member, header)

    def __enter__(self) -> _MemberWriter:
        return self

    def write(self, rows) -> None:
        """Append ``rows`` (shape ``(k, *shape[1:])``) after the rows written so far."""
        rows = np.ascontiguousarray(rows, dtype=self.dtype)
        if rows.shape[1:] != self.shape[1:] or self.done + rows.shape[0] > self.shape[0]:
            raise ValueError(f"{self.name}: rows {rows.shape} do not fit {self.shape}")
        self._member.write(memoryview(rows).cast("B"))
        self.done += rows.shape[0]

    def __exit__(self, exc_type, *exc) -> None:
        self._member.close()
        if exc_type is None and self.done != self.shape[0]:
            raise ValueError(f"{self.name}: {self.done} of {self.shape[0]} rows written")
