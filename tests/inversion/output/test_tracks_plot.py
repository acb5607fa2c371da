"""The tracks figure: axes from the ok windows, off-scale marks, bands, notes labelled."""

import numpy as np
import pandas as pd
import pytest

from mpipe.inversion.output.tracks_plot import _band, _breaks, _split, ok_limits, tracks_figure


def test_track_bands_stay_positive_and_lines_break_between_notes():
    x = np.array([1.0, 2.0, 4.0])
    se = np.array([0.001, 2.0, 40.0])  # relative SE 0.1 %, 100 %, 1000 %
    lo, hi = _band(x, se)
    assert np.all(lo > 0)  # a linear band would reach -2, -76
    np.testing.assert_allclose([lo[0], hi[0]], [1 - 0.002, 1 + 0.002], rtol=1e-5)  # linear
    np.testing.assert_allclose(lo * hi, x**2)  # symmetric in log space
    neg_lo, _ = _band(np.array([-1.0]), np.array([0.1]))
    assert neg_lo[0] == pytest.approx(-1.2)  # not positive: the linear band
    table = pd.DataFrame({"segment": [1, 1, 1, 3, 3, 3]})
    t = np.array([0.1, 0.12, 0.14, 0.5, 0.52, 0.58])
    np.testing.assert_array_equal(_breaks(table, t), [3, 5])  # a new note; a 60 ms gap
    assert np.isnan(_split(t, _breaks(table, t))[[3, 6]]).all()


def test_axis_limits_come_from_the_ok_windows_only():
    x = np.array([8.6e6, 8.8e6, 6e7, np.nan])
    ok = np.array([True, True, False, True])
    lo, hi = ok_limits(x, ok, pad=0.0)
    assert (lo, hi) == (8.6e6, 8.8e6)  # the not-ok 6e7 does not stretch the axis
    lo, hi = ok_limits(x, ok, x - 1e5, x + np.array([1e5, 1e5, 1e9, np.nan]), pad=0.0)
    assert (lo, hi) == (8.5e6, 8.9e6)  # the ok windows' bands widen it
    assert ok_limits(x, np.zeros(4, bool)) is None  # no ok window: matplotlib decides


def _table():
    t0 = np.array([0.1, 0.12, 0.14, 0.5, 0.52, 0.54])
    k = np.array([8.6e6, 8.7e6, 6e7, 8.9e6, 9.0e6, 8.8e6])  # window 2 ran to a bound
    return pd.DataFrame({
        "window": range(6), "t_start_s": t0, "t_end_s": t0 + 0.02, "segment": [1, 1, 1, 3, 3, 3],
        "k": k, "k_se": 0.01 * k, "determined_k": True,
        "status": ["ok", "ok", "at-bound", "ok", "ok", "ok"],
    })  # fmt: skip


def test_tracks_figure_scales_to_ok_windows_and_names_the_notes():
    import matplotlib.pyplot as plt

    segments = pd.DataFrame({
        "segment": [0, 1, 2, 3], "label": ["silence", "note", "silence", "note"],
        "start_s": [0.0, 0.08, 0.3, 0.48], "end_s": [0.08, 0.3, 0.48, 0.6],
        "note": ["", "G#2 +8 c", "", "C3 -3 c"], "f0_hz": [np.nan, 104.3, np.nan, 130.6],
    })  # fmt: skip
    fig = tracks_figure(_table(), segments, "xxoo")
    try:
        ax = fig.axes[0]
        lo, hi = ax.get_ylim()
        assert hi < 1e7 and lo > 8e6  # 6e7 would flatten the five ok windows to a line
        assert ax.get_title() == "k [Pa/m] (1 off scale) ×1e6"
        title = fig._suptitle.get_text()
        assert "note 1: G#2 +8 c, 104.3 Hz, fingering xxoo" in title
        assert "note 2: C3 -3 c, 130.6 Hz" in title
    finally:
        plt.close(fig)


def test_tracks_axes_lines_fixed_panels_and_tiny_fractions_read_right():
    # issue 42: an ok-but-undetermined k_c at 7e12 stretched its axis, closed_fraction showed
    # 1e-33, a fixed y_c's panel was empty, grey lines joined not-ok windows into spikes,
    # and the axis multiplier overlapped the titles
    import matplotlib.pyplot as plt

    table = _table()
    k_c = np.array([8.2e10, 8.3e10, 8.1e10, 7e12, 8.4e10, 8.2e10])
    table = table.assign(
        k_c=k_c, k_c_se=0.05 * k_c, determined_k_c=[True, True, True, False, True, True],
        y_c=4e-4, y_c_se=np.nan, closed_fraction=1e-33,
    )  # fmt: skip
    table.loc[3, "status"] = "ok"
    fig = tracks_figure(table)
    try:
        fig.canvas.draw()
        axes = {ax.get_title().split(" [")[0]: ax for ax in fig.axes if ax.get_visible()}
        assert axes["k_c"].get_ylim()[1] < 1e11  # the determined windows' range
        lo, hi = axes["closed_fraction"].get_ylim()
        assert lo <= 0.0 <= hi and hi - lo > 0.05  # a reed that never shut: 0, not 1e-33
        texts = [t.get_text() for t in axes["y_c"].texts]
        assert texts == ["held fixed at 0.0004"], texts
        grey = [ln for ln in axes["k"].lines if ln.get_color() == "0.6"]
        (line,) = grey
        y = np.asarray(line.get_ydata(), dtype=float)
        assert np.isnan(y[2]) and np.isfinite(y[[0, 1]]).all()  # window 2 (at-bound) unjoined
        for ax in axes.values():
            assert ax.yaxis.get_offset_text().get_text() == "", ax.get_title()
    finally:
        plt.close(fig)
