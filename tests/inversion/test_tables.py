"""The per-window table: a blank row, checkpoints, the files written."""

import math

import numpy as np
import pandas as pd

from mpipe.inversion.settings import InversionConfig
from mpipe.inversion.tables import (
    COLUMNS,
    blank_row,
    histories_and_correlations,
    load_checkpoint,
    save_checkpoint,
    window_table,
    write_correlations,
    write_table,
)


def test_blank_row_is_a_failed_window_without_estimate():
    row = blank_row(2000, 2000, 100_000.0, InversionConfig(), cold=True)
    assert set(COLUMNS) <= set(row)
    assert row["t_start_s"] == 0.02 and row["t_end_s"] == 0.04
    assert row["status"] == "failed" and not row["warm"] and not row["retried_cold"]
    assert math.isnan(row["k"]) and row["determined_k"] is False


def test_checkpoint_round_trip(tmp_path):
    row = {"k": np.float64(8.66e6), "status": "ok", "warm": np.bool_(True)}
    save_checkpoint(tmp_path, 3000, row, [3.0, 2.0])
    back, hist = load_checkpoint(tmp_path, 3000)
    assert back == {"k": 8.66e6, "status": "ok", "warm": True}
    np.testing.assert_array_equal(hist, [3.0, 2.0])
    assert load_checkpoint(tmp_path, 5000) is None


def test_table_histories_and_correlations_files(tmp_path):
    rows = [blank_row(s, 2000, 100_000.0, InversionConfig(), cold=s == 0) for s in (0, 2000)]
    rows[1]["_correlation"] = {"names": ["k", "p_m"], "matrix": [[1.0, 0.25], [0.25, 1.0]]}
    results = [(rows[0], None), (rows[1], np.array([2.0, 1.0]))]
    table = window_table(results)
    assert list(table.columns) == list(COLUMNS) and len(table) == 2
    histories, corr = histories_and_correlations(results)
    assert list(histories) == [1]
    assert corr.to_dict("records") == [
        {"window": 1, "t_start_s": 0.02, "parameter_a": "k", "parameter_b": "p_m",
         "correlation": 0.25}
    ]  # fmt: skip
    files = write_table(table, tmp_path)
    assert tmp_path / "windows.csv" in files
    assert pd.read_csv(tmp_path / "windows.csv", keep_default_na=False).shape == table.shape
    assert write_correlations(corr, tmp_path).exists()
