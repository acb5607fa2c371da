"""A take's report: the summary of its windows, parameters and verdict."""

import numpy as np
import pandas as pd
import pytest

from mpipe.pipeline.report import flag_windows, overall_verdict, parameter_summary


def test_summary_lists_windows_that_are_not_ok():
    windows = pd.DataFrame(
        {
            "window": [0, 1, 2, 3],
            "t_start_s": [0.0, 0.02, 0.04, 0.06],
            "k": [8.6e6, 8.7e6, 1e8, np.nan],
            "status": ["ok", "ok", "at-bound", "failed"],
            "status_reason": ["", "", "on a bound: k=upper", "step 1 failed"],
        }
    )
    flags = flag_windows(windows)
    assert flags["window"].tolist() == [2, 3]
    assert flags["status"].tolist() == ["at-bound", "failed"]
    assert "k=upper" in flags["reason"][0]
    assert overall_verdict(True, windows)[1] == "check"
    assert overall_verdict(False, windows)[1] == "fail"
    assert overall_verdict(True, windows.iloc[2:])[1] == "fail"  # no window ok
    assert overall_verdict(True, windows.iloc[:2])[1] == "pass"
    params = parameter_summary(windows).set_index("parameter")
    # only the ok windows make the median and the spread
    assert params.loc["k", "n_windows"] == 2
    assert params.loc["k", "median"] == pytest.approx(8.65e6)
    assert params.loc["k", "unit"] == "Pa/m"
