"""The budget's combination: root-sum-square of the components, NaN and inf as documented."""

import math

import numpy as np
import pandas as pd
import pytest

from mpipe.inversion.table.records import SCHEMA_BY_NAME
from mpipe.inversion.trust.budget import (
    COMPONENTS,
    QUANTITIES,
    combine,
    combine_row,
    combined,
    component_column,
)


def test_the_components_follow_the_convention_and_are_declared():
    order = ("noise", "model", "rate", "temperature", "frontend", "calibration")
    assert COMPONENTS[:2] == ("noise", "model")
    assert list(COMPONENTS) == [c for c in order if c in COMPONENTS]
    for q in QUANTITIES:
        for c in COMPONENTS:
            col = SCHEMA_BY_NAME[component_column(q, c)]
            assert col.unit == SCHEMA_BY_NAME[f"{q}_se"].unit


def test_combination_is_the_root_sum_square_of_the_components():
    assert combined({"noise": 3.0, "model": 4.0}) == pytest.approx(5.0)
    assert combined({"noise": 1.0, "model": 2.0, "temperature": 2.0}) == pytest.approx(3.0)
    # a component that does not apply (NaN) is left out
    assert combined({"noise": 3.0, "model": math.nan, "temperature": 4.0}) == pytest.approx(5.0)


def test_a_nan_or_inf_noise_component_propagates():
    assert math.isnan(combined({"noise": math.nan, "model": 1.0, "temperature": 1.0}))
    assert math.isnan(combined({"model": 1.0}))  # no noise component: no SE
    assert math.isinf(combined({"noise": math.inf, "model": 1.0}))
    assert math.isinf(combined({"noise": 1.0, "model": math.inf}))


def test_the_table_and_the_row_combine_alike():
    rng = np.random.default_rng(0)
    rows = []
    for i in range(6):
        row = {q: 10.0 + i for q in QUANTITIES}
        for q in QUANTITIES:
            row[f"determined_{q}"] = True
            row[component_column(q, "noise")] = [1.0, math.nan, math.inf, 0.5, 2.0, 1.0][i]
            row[component_column(q, "model")] = [math.nan, 1.0, 1.0, 0.5, 2.0, 0.1][i]
            row[component_column(q, "temperature")] = float(rng.uniform(0, 1))
        rows.append(row)
    table = combine(pd.DataFrame(rows), limit=0.2)
    for i, row in enumerate(rows):
        combine_row(row, 0.2)
        for q in ("k", "p_M"):
            a, b = table.loc[i, f"{q}_se"], row[f"{q}_se"]
            assert (math.isnan(a) and math.isnan(b)) or a == pytest.approx(b), (i, q)
            assert bool(table.loc[i, f"determined_{q}"]) == row[f"determined_{q}"]
    assert math.isnan(table.loc[1, "k_se"]) and math.isinf(table.loc[2, "k_se"])
    # 2 + 2 + T: the flag follows the within-take part (noise, model), not the temperature
    assert bool(table.loc[4, "determined_k"]) == (math.hypot(2.0, 2.0) / 14.0 < 0.2)


def test_no_quantity_is_undetermined_because_of_a_take_wide_component():
    # issue 38: a within-take SE of 1 % with a take-wide rate or calibration term of 20 %
    # (or inf, below the lowest rate) stays determined; the combined SE carries them
    row = {q: 100.0 for q in QUANTITIES}
    for q in QUANTITIES:
        row[f"determined_{q}"] = True
        row[component_column(q, "noise")] = 1.0
        row[component_column(q, "rate")] = 20.0
        row[component_column(q, "calibration")] = math.inf if q == "p_M" else 15.0
    table = combine(pd.DataFrame([row]), limit=0.1)
    combine_row(row, 0.1)
    for q in ("p_m", "p_M", "k"):
        assert bool(table.loc[0, f"determined_{q}"]) and row[f"determined_{q}"], q
    assert table.loc[0, "p_m_se"] == pytest.approx(25.02, abs=0.01)
    assert math.isinf(table.loc[0, "p_M_se"]) and math.isinf(row["p_M_se"])
