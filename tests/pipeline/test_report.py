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
        "p_m_median_se": [np.nan, 3.0, np.nan, np.nan],
    })  # fmt: skip
    played, params = segment_tables(segs)
    assert list(played["segment"]) == [1, 3]
    assert list(played["ok_windows"]) == ["13 of 17", "15 of 19"]
    assert list(params["p_m [Pa]"]) == ["1807 ± 3", "2001"]  # no SE: none is claimed


def test_window_table_gives_each_value_with_its_se_note_pitch_and_reason_in_words():
    from mpipe.pipeline.report_windows import window_table

    windows = pd.DataFrame({
        "window": [3, 4], "t_start_s": [0.29, 0.71], "segment": [1, 3],
        "phase": ["sustain", "release"], "f0_hz": [104.3, 221.0],
        "pitch_cents": [1200 * np.log2(104.3 / 440), 1200 * np.log2(221 / 442)],
        "status": ["ok", "low-dof"], "p_m": [1800.4, 1927.0], "p_m_se": [26.3, np.inf],
        "p_M": [3468.0, np.nan], "p_M_se": [88.0, np.nan], "gamma": [0.5184, 0.6],
        "gamma_se": [0.0056, np.nan], "relative_residual": [0.005, 0.2],
        "n_eff": [20.0, 5.71], "dof": [12.0, -2.29],
        "status_reason": ["", "n_eff - p = -2.29 < 1: the residual cannot measure the noise"],
    })  # fmt: skip
    segments = pd.DataFrame({"segment": [0, 1, 2, 3],
                             "label": ["silence", "note", "silence", "note"]})  # fmt: skip
    table = window_table(windows, segments).replace("\u00a0", " ", regex=True)  # no-break
    assert list(table["note"]) == [1, 2]  # numbered as the notes table numbers them
    assert list(table["p_m"]) == ["1800 ± 26", "1927 (undetermined)"]
    assert list(table["p_M"]) == ["3468 ± 88", "–"]
    assert list(table["gamma"]) == ["0.5184 ± 0.0056", "0.6"]  # no SE: none claimed
    # pitch as a note name, with the take's own A4 (442 Hz for the second row)
    assert list(table["pitch"]) == ["G#2 +8 c", "A3 +0 c"]
    assert list(table["f0_hz"]) == [104.3, 221.0]
    # no negative degrees of freedom as a number: what they mean, with both counts
    reason = table["reason"].iloc[1]
    assert "-2.29" not in reason and "n_eff - p" not in reason
    assert reason.startswith("fewer effective residual samples (5.7) than free parameters (8)")
    assert reason.endswith("the residual cannot measure the noise")


def test_reason_words_keep_a_positive_shortfall_and_other_reasons():
    from mpipe.inversion.status_words import reason_words

    row = {"status_reason": "dof = 0.812 < 1: SEs rough; relative residual 0.159 > 0.1",
           "n_eff": 8.812, "dof": 0.812}  # fmt: skip
    words = reason_words(row)
    assert words.startswith("less than one residual degree of freedom (8.8 effective samples "
                            "for 8 free parameters): SEs rough")  # fmt: skip
    assert words.endswith("relative residual 0.159 > 0.1")
    assert reason_words({"status_reason": "on a bound: k=upper"}) == "on a bound: k=upper"
    assert reason_words({"status_reason": np.nan}) == ""
