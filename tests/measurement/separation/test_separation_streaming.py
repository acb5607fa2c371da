"""The separation of a take on disk into reference.npz against the whole-array separate()."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import scipy.fft as sfft

from mpipe.core.signals import NpzStream, open_npz
from mpipe.measurement.separation.blocks import block_layout, padded_block
from mpipe.measurement.separation.reconstruction import overlap_add_blocks
from mpipe.measurement.separation.settings import SeparationConfig
from mpipe.measurement.separation.stage import separate
from mpipe.measurement.separation.streaming import write_reference
from mpipe.measurement.separation.waves import Geometry
from tests.measurement.separation.separation_fields import CAL, FS, random_take


@pytest.mark.parametrize("n", [int(0.6 * FS) + 13, 9_001])
def test_reference_on_disk_is_separates(tmp_path, n):
    x, _, _ = random_take(n, temperature_c=23.0, mach=0.005)
    with NpzStream(tmp_path / "x.npz") as out:
        out.add("x", x)
    disk = open_npz(tmp_path / "x.npz", lazy_bytes=0)["x"]
    cfg = SeparationConfig()
    got = write_reference(tmp_path / "reference.npz", disk, FS, CAL, cfg)
    whole = separate(x, FS, CAL, cfg)
    with np.load(tmp_path / "reference.npz") as ref:
        np.testing.assert_array_equal(ref["p0"], whole.p0)
        np.testing.assert_array_equal(ref["u0"], whole.u0)
        np.testing.assert_array_equal(ref["temperature_c"], whole.temperature_track())
        np.testing.assert_array_equal(ref["mic_noise_psd"], whole.noise_psd)
        th = whole.median_theta()
        np.testing.assert_array_equal(ref["theta_median"], [th.c, th.eta, th.mach])
        np.testing.assert_array_equal(ref["theta_level_se"], whole.track.level_se)
    pd.testing.assert_frame_equal(got.blocks, whole.blocks)
    assert not list(tmp_path.glob(".separation.*"))


def _overlap_add_one_buffer(x, fs, starts, length, smooth, c_track, geometry, config):
    """The whole-take buffer of overlap_add before issue 32 (the reference)."""
    from mpipe.measurement.separation.reconstruction import _tapered_filters, _u_ramp
    from mpipe.measurement.separation.waves import Theta

    n, n_mics = x.shape
    pad = int(round(config.pad_s * fs))
    nfft = sfft.next_fast_len(length + 2 * pad, real=True)
    freqs = np.fft.rfftfreq(nfft, 1 / fs)
    band = freqs <= config.band_edge_hz + config.band_taper_hz
    fb = freqs[band]
    ramp = _u_ramp(fb, config)
    win = np.hanning(length + 1)[:-1]
    origin = pad + length
    last = max(origin + n, origin + int(np.max(starts, initial=0)) - pad + nfft)
    out = np.zeros((last, 2))
    for b, s in enumerate(starts):
        th = Theta(c_track[b], smooth[b, 1], smooth[b, 2])
        g_p, g_u = _tapered_filters(fb, th, geometry.corrected(float(smooth[b, 3])), config,
                                    ramp)  # fmt: skip
        seg = np.zeros((nfft, n_mics))
        seg[pad : pad + length] = padded_block(x, s, length) * win[:, None]
        spec_ = np.fft.rfft(seg, axis=0)[band]
        y = np.zeros((freqs.size, 2), dtype=complex)
        y[band, 0] = np.sum(g_p * spec_, axis=1)
        y[band, 1] = np.sum(g_u * spec_, axis=1)
        lo = origin + s - pad
        out[lo : lo + nfft] += np.fft.irfft(y, nfft, axis=0)
    return out[origin : origin + n]


@pytest.mark.parametrize("n", [1, 150, 2_001, 7_919])
def test_overlap_add_in_stretches_is_one_buffers(n):
    # lengths shorter than a block, and not multiples of the hop
    x = np.random.default_rng(n).standard_normal((n, 3))
    cfg = SeparationConfig()
    hop, length, starts = block_layout(n, FS, cfg.block_s)
    smooth = np.tile([20.0, 1.0, 0.0, 0.0], (starts.size, 1))
    geo = Geometry.from_calibration(CAL)
    c = np.full(starts.size, geo.sound_speed(20.0))
    args = (x, FS, starts, length, smooth, c, geo, cfg)
    parts = list(overlap_add_blocks(*args))
    assert [a for a, _, _ in parts][0] == 0 and parts[-1][1] == n
    assert all(b1 == a2 for (_, b1, _), (a2, _, _) in zip(parts, parts[1:], strict=False))
    np.testing.assert_array_equal(np.concatenate([c for _, _, c in parts]),
                                  _overlap_add_one_buffer(*args))  # fmt: skip
