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
        assert ax.get_title() == "k [Pa/m] (1 off scale)"
        title = fig._suptitle.get_text()
        assert "note 1: G#2 +8 c, 104.3 Hz, fingering xxoo" in title
        assert "note 2: C3 -3 c, 130.6 Hz" in title
    finally:
        plt.close(fig)
