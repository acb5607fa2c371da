"""Summary of a take's uncertainty: coverage of the 2-SE interval."""

import numpy as np
import pandas as pd
import pytest

from mpipe.inversion.table.coverage import summary


def test_summary_coverage():
    table = pd.DataFrame(
        {
            "status": ["ok", "ok", "ok", "failed"],
            "k": [1.0, 1.1, 0.7, np.nan],
            "k_se": [0.1, 0.1, 0.1, np.nan],
            "determined_k": [True, True, True, False],
        }
    )
    s = summary(table, {"k": 1.0}).set_index("name")
    assert s.loc["k", "coverage_2se"] == pytest.approx(2 / 3)
    table.loc[2, "k_se"] = np.inf  # a null direction: left out, not counted as covering
    table.loc[1, "k_se"] = np.nan  # no valid SE: not covering
    s = summary(table, {"k": 1.0}).set_index("name")
    assert s.loc["k", "coverage_2se"] == pytest.approx(1 / 2)
    assert s.loc["k", "median"] == pytest.approx(1.0)
    # the scatter over windows is 1.4826 MAD: |x - 1| = 0, 0.1, 0.3 -> MAD 0.1
    assert s.loc["k", "mad_sigma"] == pytest.approx(0.14826)
    assert "spread" not in s
