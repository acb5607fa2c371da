"""The window record and its schema: typed columns that round-trip through CSV and Parquet."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mpipe.core.units import unit_of
from mpipe.inversion.settings import InversionConfig
from mpipe.inversion.table.records import (
    COUNT,
    FLAG,
    FLOAT,
    RECORD_COLUMNS,
    SCHEMA_BY_NAME,
    TEXT,
    WINDOW_SCHEMA,
    Correlation,
    WindowRecord,
    read_windows,
    schema_markdown,
    typed,
    window_frame,
    write_windows,
)
from mpipe.inversion.table.tables import blank_row

_VALUES = {
    FLOAT: st.floats(allow_nan=True, allow_infinity=True, width=64),
    COUNT: st.none() | st.integers(-(2**53), 2**53),
    FLAG: st.booleans(),
    # text a CSV reader could mistake for something else: "True", "nan", "NA", "", commas,
    # quotes, line breaks
    TEXT: st.sampled_from(["", "True", "false", "nan", "NA", "None", "1", "a, b", '"q"', "x\ny"])
    | st.text(st.characters(exclude_categories=("Cs",), exclude_characters="\r\x00")),
}


@st.composite
def _tables(draw):
    names = draw(
        st.lists(st.sampled_from([c.name for c in WINDOW_SCHEMA]), min_size=1, unique=True)
    )
    n = draw(st.integers(0, 4))
    data = {name: [draw(_VALUES[SCHEMA_BY_NAME[name].dtype]) for _ in range(n)] for name in names}
    return typed(pd.DataFrame(data, columns=names))


def _as_csv_keeps_it(table: pd.DataFrame, suffix: str) -> pd.DataFrame:
    """The table as its file keeps it: Parquet exactly, CSV floats to 10 significant digits."""
    if suffix == ".parquet":
        return table
    out = table.copy()
    for name in out.columns:
        if SCHEMA_BY_NAME[name].dtype == FLOAT:
            out[name] = [float(f"{v:.10g}") for v in out[name]]
            out[name] = out[name].astype(float)
    return out


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(table=_tables(), suffix=st.sampled_from([".csv", ".parquet"]))
def test_any_table_of_the_schema_round_trips_exactly(tmp_path_factory, table, suffix):
    path = tmp_path_factory.mktemp("rt") / f"windows{suffix}"
    write_windows(table, path)
    back = read_windows(path)
    # same columns, dtypes and values: NaN as NaN, +-inf, booleans as booleans, "" as "",
    # every float exact (CSV: its 10 written digits exact)
    pd.testing.assert_frame_equal(back, _as_csv_keeps_it(table, suffix), check_exact=True)
    # and writing what was read gives the same table back
    write_windows(back, path)
    pd.testing.assert_frame_equal(read_windows(path), back, check_exact=True)
    for name in table.columns:
        assert str(back[name].dtype) == {TEXT: "object"}.get(
            SCHEMA_BY_NAME[name].dtype, SCHEMA_BY_NAME[name].dtype
        )


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_a_take_of_records_round_trips_with_its_dtypes(tmp_path, suffix):
    config = InversionConfig()
    rows = [blank_row(s, 2000, 100_000.0, config, cold=s == 0) for s in (0, 2000, 4000)]
    rows[1].update(k=8.66e6 + 1 / 3, k_se=np.inf, determined_k=True, n_evaluations=np.int64(34),
                   status="ok", warm=np.bool_(True), at_bound="m=lower;y_m=y_c")  # fmt: skip
    rows[2].update(error='RuntimeError: silent, "no" feasible point\nat all')
    table = window_frame(rows)
    assert list(table.columns) == list(RECORD_COLUMNS)
    write_windows(table, tmp_path / f"w{suffix}")
    back = read_windows(tmp_path / f"w{suffix}")
    pd.testing.assert_frame_equal(back, _as_csv_keeps_it(table, suffix), check_exact=True)
    assert back["k"].iloc[1] == (8.66e6 + 1 / 3 if suffix == ".parquet" else 8660000.333)
    assert back["determined_k"].tolist() == [False, True, False]
    assert back["warm"].dtype == bool and back["optimiser_converged"].dtype == bool
    assert back["n_evaluations"].tolist()[1] == 34 and back["n_evaluations"].isna().sum() == 2
    assert back["k_se"].iloc[1] == np.inf and np.isnan(back["k"].iloc[0])
    assert back["error"].tolist()[:2] == ["", ""] and "\nat all" in back["error"].iloc[2]


def test_every_column_has_a_dtype_unit_and_meaning():
    names = [c.name for c in WINDOW_SCHEMA]
    assert len(names) == len(set(names))
    for c in WINDOW_SCHEMA:
        assert c.dtype in (FLOAT, COUNT, FLAG, TEXT) and c.meaning
        assert c.unit == unit_of(c.name)  # the report's headers use the same table
    assert SCHEMA_BY_NAME["k_c"].unit == "Pa/m^alpha" and SCHEMA_BY_NAME["k_c_se"].unit
    assert "converged" not in names and SCHEMA_BY_NAME["optimiser_converged"].dtype == FLAG


def test_a_column_outside_the_schema_is_an_error(tmp_path):
    with pytest.raises(ValueError, match=r"\['converged'\] are not in the window schema"):
        typed(pd.DataFrame({"status": ["ok"], "converged": [True]}))
    (tmp_path / "w.csv").write_text("status,k_se_pa\nok,1.5\n")
    with pytest.raises(ValueError, match=r"w.csv: columns \['k_se_pa'\]"):
        read_windows(tmp_path / "w.csv")
    with pytest.raises(ValueError, match="flag"):
        typed(pd.DataFrame({"warm": [True, None]}))


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_a_table_of_an_earlier_version_reads_without_its_retired_column(tmp_path, suffix):
    # earlier versions wrote "converged" (status == "ok") beside optimiser_converged, and
    # "retried_cold" (the cold retries, gone)
    old = pd.DataFrame({"status": ["ok", "at-bound"], "converged": [True, False],
                        "optimiser_converged": [True, True],
                        "retried_cold": [False, True]})  # fmt: skip
    path = tmp_path / f"w{suffix}"
    old.to_csv(path, index=False) if suffix == ".csv" else old.to_parquet(path, index=False)
    back = read_windows(path)
    assert list(back.columns) == ["status", "optimiser_converged"]
    assert back["optimiser_converged"].dtype == bool


def test_the_correlation_is_a_typed_field_of_the_record():
    corr = Correlation(("k", "p_m"), np.array([[1.0, 0.3], [0.3, 1.0]]))
    row = WindowRecord({"k": 1.0}, corr)
    again = row.replace(warm=True)
    assert again.correlation is corr and again["warm"] and "warm" not in row
    back = Correlation.from_json(corr.to_json())
    assert back.names == corr.names and np.array_equal(back.matrix, corr.matrix)
    assert Correlation.from_json(None) is None
    assert "correlation" not in row and set(row) == {"k"}


def test_the_docs_reference_is_the_schema():
    page = (Path(__file__).resolve().parents[3] / "docs" / "windows_table.md").read_text()
    assert page.endswith(schema_markdown())
    assert f"({len(WINDOW_SCHEMA)} columns: the first {len(RECORD_COLUMNS)} " in page
