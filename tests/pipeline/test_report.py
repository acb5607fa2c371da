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
    # only the ok windows make the median and the quartiles
    assert params.loc["k", "n_windows"] == 2
    assert params.loc["k", "median"] == pytest.approx(8.65e6)
    assert params.loc["k", "unit"] == "Pa/m"


def test_segment_tables_give_each_note_its_own_line():
    import pandas as pd

    from mpipe.pipeline.report import segment_tables

    segs = pd.DataFrame({
        "segment": [0, 1, 2, 3], "label": ["silence", "note", "silence", "note"],
        "start_s": [0.0, 0.1, 0.5, 0.75], "duration_s": [0.1, 0.4, 0.25, 0.4],
        "note": ["", "G#2 +8 c", "", "G#2 +9 c"], "f0_hz": [np.nan, 104.3, np.nan, 104.4],
        "regime": ["silence", "fundamental", "silence", "fundamental"],
        "spl_db": [110.0, 154.4, 110.0, 156.0], "windows": [0, 17, 0, 19],
        "ok_windows": [0, 13, 0, 15], "p_m_median": [np.nan, 1807.0, np.nan, 2001.0],
        "p_m_se": [np.nan, 3.0, np.nan, np.nan],
    })  # fmt: skip
    played, params = segment_tables(segs)
    assert list(played["segment"]) == [1, 3]
    assert list(played["ok_windows"]) == ["13 of 17", "15 of 19"]
    assert list(params["p_m [Pa]"]) == ["1807 ± 3", "2001"]  # no SE: none is claimed
