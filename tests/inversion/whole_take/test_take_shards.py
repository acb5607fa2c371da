"""A shard's blocks at the fit's temperature when its kernels lie at another one."""

import dataclasses

import numpy as np

from mpipe.inversion.preparation.kernel import KernelSource
from mpipe.inversion.settings import InversionConfig
from mpipe.inversion.whole_take.estimator import layout_of, problems_of
from mpipe.inversion.whole_take.take_shards import Shard, ShardSpec


def _shard(short_take, t_kernels: float, windows: int = 3):
    cal, fs, tr, _, reed = short_take
    config = dataclasses.replace(InversionConfig(), sample_rate=fs, contact="fixed")
    n = int(round(config.window_s * fs))
    starts = [int(0.25 * fs) + k * n for k in range(windows)]
    n_taps = KernelSource(cal, fs, {}).named(t_kernels, "")[0].n_taps
    problems = problems_of(tr.p0, tr.u0, fs, starts, [0] * windows, [""] * windows, config,
                           True, n_taps)  # fmt: skip
    layout = layout_of(config)
    spec = ShardSpec(tuple(problems), cal, fs, {}, reed, config, layout, t_kernels)
    values = np.array([[getattr(reed, name) for name in layout.names]] * windows)
    free = np.array([layout.free_values(v[: layout.n_fast], v[layout.n_fast :]) for v in values])
    return Shard(spec), free


def test_measured_blocks_lie_at_the_fits_temperature_not_the_kernels(short_take):
    """The quadratic in T about kernels 0.2 degC away gives the blocks of kernels at T.

    Independent: a second shard whose kernels are built at the fit's T itself. The
    measure once took its blocks at the kernels' T (the slopes' passes of the take's fit
    then started 17 % above the point's sum of squares); the test's own scale shows that
    error would fail it (the two temperatures' sums of squares differ far more).
    """
    t_fit = float(np.median(short_take[2].temperature_c))
    off, free = _shard(short_take, t_fit + 0.2)
    on, _ = _shard(short_take, t_fit)
    measured = off.measure(free, t_fit)
    direct = on.measure(free, t_fit)
    at_kernels = off.measure(free)
    scale = np.abs(at_kernels.rr - direct.rr)
    assert np.all(scale > 0)
    assert np.all(np.abs(measured.rr - direct.rr) < 0.02 * scale)  # measured: 0.3 %
    np.testing.assert_allclose(measured.grads, direct.grads, rtol=0.02,
                               atol=0.02 * np.abs(direct.grads).max())  # fmt: skip
    np.testing.assert_allclose(measured.n_eff, direct.n_eff, rtol=1e-3)  # at_kernels: 3e-3 off
