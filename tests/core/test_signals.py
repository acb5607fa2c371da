"""Signals on disk: an npz written in blocks reads back as numpy writes it, by slices."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mpipe.core.signals import (
    DiskArray,
    NpzStream,
    blocks,
    open_npz,
    pairwise_sum,
    signal_median,
    signal_moments,
)


def _write(path, arrays: dict, size: int) -> None:
    with NpzStream(path) as out:
        for name, x in arrays.items():
            with out.signal(name, x.shape, x.dtype) as w:
                for a, b in blocks(x.shape[0], size):
                    w.write(x[a:b])


@settings(max_examples=15, deadline=None)
@given(n=st.integers(1, 5000), size=st.integers(1, 700), seed=st.integers(0, 2**16))
def test_blocks_cover_once_in_order(n, size, seed):
    bounds = list(blocks(n, size))
    assert bounds[0][0] == 0 and bounds[-1][1] == n
    assert all(b1 == a2 for (_, b1), (a2, _) in zip(bounds, bounds[1:], strict=False))
    assert all(0 < b - a <= size for a, b in bounds)


@settings(max_examples=10, deadline=None)
@given(n=st.integers(1, 3000), size=st.integers(1, 1000), seed=st.integers(0, 2**16))
def test_npz_written_in_blocks_is_numpys_npz(tmp_path_factory, n, size, seed):
    rng = np.random.default_rng(seed)
    x, xy = rng.standard_normal(n), rng.standard_normal((n, 3))
    path = tmp_path_factory.mktemp("npz") / "s.npz"
    _write(path, {"x": x, "xy": xy}, size)
    with np.load(path) as ref:  # numpy's own reader: the independent check
        np.testing.assert_array_equal(ref["x"], x)
        np.testing.assert_array_equal(ref["xy"], xy)
    lazy = open_npz(path, lazy_bytes=0)
    assert isinstance(lazy["x"], DiskArray) and lazy["xy"].shape == (n, 3)
    a, b = sorted(rng.integers(-5, n + 5, 2))
    np.testing.assert_array_equal(lazy["x"][a:b], x[a:b])
    np.testing.assert_array_equal(lazy["xy"][a:b, 1], xy[a:b, 1])
    np.testing.assert_array_equal(np.asarray(lazy["x"]), x)
    assert lazy["x"][n - 1] == x[-1] and lazy["x"][-1] == x[-1]


def test_small_and_compressed_members_are_read_at_once(tmp_path):
    x = np.arange(10.0)
    np.savez_compressed(tmp_path / "c.npz", x=np.zeros(300_000), s=x)
    got = open_npz(tmp_path / "c.npz", lazy_bytes=0)
    assert isinstance(got["x"], np.ndarray) and isinstance(got["s"], np.ndarray)
    np.savez(tmp_path / "u.npz", x=np.ones(300_000), s=x)  # numpy's writer, stored
    got = open_npz(tmp_path / "u.npz")
    assert isinstance(got["x"], DiskArray) and isinstance(got["s"], np.ndarray)
    assert float(got["x"][5:9].sum()) == 4.0


def test_disk_array_pickles_as_its_file_not_its_samples(tmp_path):
    _write(tmp_path / "s.npz", {"p": np.arange(200_000.0)}, 4096)
    p = open_npz(tmp_path / "s.npz", lazy_bytes=0)["p"]
    blob = pickle.dumps(p)
    assert len(blob) < 1000
    np.testing.assert_array_equal(pickle.loads(blob)[10:20], np.arange(10.0, 20.0))


def test_member_of_wrong_length_is_refused(tmp_path):
    with NpzStream(tmp_path / "s.npz") as out:
        with pytest.raises(ValueError, match="x: 3 of 5 rows"):
            with out.signal("x", (5,)) as w:
                w.write(np.zeros(3))
        with pytest.raises(ValueError, match="do not fit"):
            with out.signal("y", (2,)) as w:
                w.write(np.zeros(3))


@settings(max_examples=25, deadline=None)
@given(
    n=st.integers(1, 3000),
    seed=st.integers(0, 2**16),
    kind=st.sampled_from(["normal", "few values", "constant", "ramp"]),
)
def test_median_in_blocks_is_numpys(n, seed, kind):
    rng = np.random.default_rng(seed)
    x = {
        "normal": rng.standard_normal(n),
        "few values": rng.integers(0, 3, n).astype(float),
        "constant": np.full(n, 18.5),
        "ramp": np.linspace(18.0, 19.0, n),
    }[kind]
    assert signal_median(x, bins=7, gather=5) == np.median(x)
    assert signal_median(x) == np.median(x)


@settings(max_examples=20, deadline=None)
@given(n=st.integers(1, 20_000), leaf=st.integers(1, 3000), seed=st.integers(0, 2**16))
def test_sums_in_blocks_are_numpys_to_the_last_bit(n, leaf, seed):
    x = np.random.default_rng(seed).standard_normal(n) * 1e3 + 7.0
    assert pairwise_sum(x, leaf=leaf) == np.sum(x)
    mean, std = signal_moments(x, leaf=leaf)
    assert mean == np.mean(x) and std == np.std(x)
