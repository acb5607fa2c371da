"""The span of a take to invert, in samples (issue 33: a span of exactly one window)."""

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from tests import lengths


@given(
    fs=lengths.rates,
    windows=st.integers(1, 6),
    start_windows=st.integers(0, 40),
    window_ms=st.sampled_from([10, 20, 25, 40]),
)
@settings(max_examples=60, deadline=None)
def test_a_span_of_whole_windows_holds_exactly_that_many(fs, windows, start_windows, window_ms):
    # Issue 33: --start 0.40 --end 0.42 (one 20 ms window) was refused as shorter than one
    # window because 0.42 - 0.40 < 0.02 in floating point. A span given in decimal seconds
    # that is k windows long, starting and ending on window edges, holds exactly k windows
    # (hop = window) at every rate where a window is a whole number of samples (elsewhere
    # the hop, rounded to samples, drifts from k windows' time: one window is tested below).
    from mpipe.inversion.preparation.conditioning import plan_inversion
    from mpipe.inversion.preparation.span import check_span
    from mpipe.inversion.settings import ConditioningConfig

    assume((fs * window_ms / 1000).is_integer())
    window_s = window_ms / 1000
    start_s = round(start_windows * window_s + 0.4, 6)  # 0.40 as typed, not a product
    end_s = round(start_s + windows * window_s, 6)
    n = int(round((end_s + 0.1) * fs))
    check_span(n, fs, 0.05, window_s, start_s, end_s)  # no error
    table = plan_inversion(np.zeros(n), fs, ConditioningConfig(), window_s, window_s,
                           start_s, end_s)  # fmt: skip
    assert len(table) == windows
    # the last window ends on the span's end, to the sample
    assert table["start"].iloc[-1] + int(round(window_s * fs)) == int(round(end_s * fs))


@pytest.mark.parametrize("fs", lengths.RATES)
def test_the_paper_span_of_one_window_and_one_sample_short(fs):
    # 0.40-0.42 s is one 20 ms window; one sample less is refused, naming the span
    from mpipe.inversion.preparation.conditioning import plan_inversion
    from mpipe.inversion.preparation.span import check_span
    from mpipe.inversion.settings import ConditioningConfig

    n = int(fs)
    check_span(n, fs, 0.05, 0.02, 0.40, 0.42)
    table = plan_inversion(np.zeros(n), fs, ConditioningConfig(), 0.02, 0.02, 0.40, 0.42)
    assert len(table) == 1 and table["start"].iloc[0] == round(0.40 * fs)
    with pytest.raises(ValueError, match="shorter than one window"):
        check_span(n, fs, 0.05, 0.02, 0.40, 0.42 - 1.5 / fs)
