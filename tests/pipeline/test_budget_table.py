"""The report's uncertainty budget per note (mpipe.pipeline.budget_table)."""

import math

import numpy as np
import pandas as pd

from mpipe.inversion.trust.notes import note_summary
from mpipe.pipeline.budget_table import budget_table, budget_tables
from mpipe.pipeline.html_report import Section, render


def _notes() -> pd.DataFrame:
    # one note of 16 identical windows: noise 32 Pa / sqrt(16) = 8 Pa, calibration 60 Pa
    # and frontend 45 Pa shared: u_c = sqrt(8^2 + 60^2 + 45^2) = 75.4 Pa
    segs = pd.DataFrame({"segment": [0, 1], "label": ["silence", "note"],
                         "start_s": [0.0, 0.1]})  # fmt: skip
    n = 16
    table = pd.DataFrame({
        "t_start_s": 0.1 + 0.02 * np.arange(n), "segment": [1] * n, "status": ["ok"] * n,
        "p_M": [3000.0] * n, "p_M_se_noise": [32.0] * n, "p_M_se_calibration": [60.0] * n,
        "p_M_se_frontend": [45.0] * n, "gamma": [0.5] * n, "gamma_se": [np.inf] * n,
    })  # fmt: skip
    return note_summary(segs, table, ("p_M", "gamma"))


def test_the_budget_gives_value_combined_se_and_each_component():
    note = _notes().iloc[1]
    table = budget_table(note).set_index("quantity")
    assert table.loc["p_M", "value"] == "3000" and table.loc["p_M", "unit"] == "Pa"
    assert table.loc["p_M", "u_c"] == "75" and table.loc["p_M", "u_c %"] == "2.5"
    assert math.isclose(note["p_M_se"], math.sqrt(8**2 + 60**2 + 45**2))
    assert table.loc["p_M", "noise"] == "8" and table.loc["p_M", "calibration"] == "60"
    assert table.loc["p_M", "frontend"] == "45" and table.loc["p_M", "model"] == "–"
    assert table.loc["gamma", "u_c"] == "∞ (undetermined)"


def test_the_report_renders_one_budget_per_note_with_its_meaning():
    tables = budget_tables(_notes())
    assert len(tables) == 1  # the silence has none
    caption, _ = tables[0]
    # the note by its number in the take (segment 1 is note 1: one silence before it)
    assert caption.startswith("Uncertainty budget of note 1 (from 0.100 s")
    assert "segment" not in caption
    page = render("t", "m", [Section("Summary", tables=tuple(tables))])
    assert "combined standard uncertainty" in page
    assert '<td class="text">75</td>' in page and '<td class="text">60</td>' in page


def test_the_budget_headers_carry_no_temperature_unit_and_inf_reads_undetermined():
    # the value columns hold each row's quantity in its own unit (p_M in Pa): never °C
    # (issue 42: every budget table headed its value column "u [°C]")
    tables = budget_tables(_notes())
    page = render("t", "m", [Section("Summary", tables=tuple(tables))])
    assert "<th>u_c</th>" in page and "°C" not in page
    assert '<td class="text">Pa</td>' in page
    assert "∞ (undetermined)" in page  # gamma's infinite SE, not a bare value
