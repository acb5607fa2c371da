"""The per-window table: a blank row, checkpoints, the files written."""

import json
import math

import numpy as np
import pandas as pd
import pytest

from mpipe.inversion.settings import InversionConfig
from mpipe.inversion.table.records import Correlation, read_windows
from mpipe.inversion.table.tables import (
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
    assert row["status"] == "failed" and not row["warm"]
    assert math.isnan(row["k"]) and row["determined_k"] is False


def test_checkpoint_round_trip(tmp_path):
    row = blank_row(3000, 2000, 100_000.0, InversionConfig(), cold=False)
    row.update(k=np.float64(8.66e6), status="ok", n_evaluations=np.int64(12))
    row.correlation = Correlation(("k", "p_m"), np.array([[1.0, -0.5], [-0.5, 1.0]]))
    save_checkpoint(tmp_path, 3000, row, [3.0, 2.0])
    back, hist = load_checkpoint(tmp_path, 3000)
    assert back["k"] == 8.66e6 and back["status"] == "ok" and back["warm"] is True
    assert back["n_evaluations"] == 12 and math.isnan(back["y_m"])
    assert back.correlation.names == ("k", "p_m")
    np.testing.assert_array_equal(back.correlation.matrix, row.correlation.matrix)
    np.testing.assert_array_equal(hist, [3.0, 2.0])
    assert load_checkpoint(tmp_path, 5000) is None


def test_a_checkpoint_of_another_version_is_not_used(tmp_path):
    # written before the record had a typed correlation (a private "_correlation" key)
    row = blank_row(3000, 2000, 100_000.0, InversionConfig(), cold=True).as_dict()
    row["_correlation"] = {"names": ["k"], "matrix": [[1.0]]}
    (tmp_path / "w0000003000.json").write_text(json.dumps({"row": row, "history": None}))
    assert load_checkpoint(tmp_path, 3000) is None


def test_a_record_refuses_a_column_outside_the_schema():
    row = blank_row(0, 2000, 100_000.0, InversionConfig(), cold=True)
    with pytest.raises(KeyError, match="not a column of the window record"):
        row["_correlation"] = {}
    with pytest.raises(KeyError, match="not a column"):
        row.update(converged=True)


def test_table_histories_and_correlations_files(tmp_path):
    rows = [blank_row(s, 2000, 100_000.0, InversionConfig(), cold=s == 0) for s in (0, 2000)]
    rows[1].correlation = Correlation(("k", "p_m"), np.array([[1.0, 0.25], [0.25, 1.0]]))
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
    for name in ("windows.csv", "windows.parquet"):
        pd.testing.assert_frame_equal(read_windows(tmp_path / name), table)
    assert write_correlations(corr, tmp_path).exists()
