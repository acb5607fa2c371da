"""Window status: ok only when converged, off the bounds, with valid SEs and a fitting residual."""

import numpy as np
import pandas as pd
import pytest

from mpipe.inversion.settings import InversionConfig
from mpipe.inversion.status import classify, count, on_bounds, search_bounds, summary_line

CFG = InversionConfig()


def test_search_bounds_keep_y_m_above_y_c_and_scale_p_m():
    b = search_bounds(CFG, 1500.0)
    i = CFG.free.index("y_m")
    assert b[i, 0] > CFG.y_c
    j = CFG.free.index("p_m")
    np.testing.assert_allclose(b[j], [0.5 * 1500.0, 2.0 * 1500.0])
    with pytest.raises(ValueError, match="expected > 0"):
        search_bounds(CFG, 0.0)


def test_on_bounds_names_each_parameter_and_side():
    b = search_bounds(CFG, 1500.0)
    values = dict(zip(CFG.free, np.sqrt(b[:, 0] * b[:, 1]), strict=True))
    assert on_bounds(values, b, CFG) == []
    values["m"] = b[CFG.free.index("m"), 0] * (1 + 1e-5)
    values["p_m"] = b[CFG.free.index("p_m"), 1]
    values["y_m"] = b[CFG.free.index("y_m"), 0]
    assert on_bounds(values, b, CFG) == ["y_m=y_c", "p_m=upper", "m=lower"]


def _row(**kw):
    row = dict(error="", optimiser_converged=True, optimiser_message="step below tolerance",
               at_bound="", relative_residual=0.01)  # fmt: skip
    row.update(kw)
    return row


def test_classify_precedence_and_take_relative_residual():
    table = pd.DataFrame(
        [
            _row(),
            _row(relative_residual=0.012),
            _row(relative_residual=0.05),  # 5x the best: high-residual
            _row(at_bound="m=lower;g=lower"),
            _row(
                optimiser_converged=False,
                optimiser_message="evaluation budget spent",
                at_bound="k=upper",
                relative_residual=0.2,
            ),  # fmt: skip
            _row(error="RuntimeError: silent", relative_residual=np.nan),
        ]
    )
    out = classify(table, CFG)
    assert list(out["status"]) == [
        "ok", "ok", "high-residual", "at-bound", "not-converged", "failed",
    ]  # fmt: skip
    # no ambiguous "converged" column: status says whether a window is ok, and
    # optimiser_converged whether its search met its tolerance
    assert "converged" not in out
    reason = out["status_reason"].iloc[4]
    assert "budget" in reason and "k=upper" in reason and "relative residual" in reason
    assert count(out) == {"ok": 2, "high-residual": 1, "low-dof": 0, "no-errors": 0,
                          "at-bound": 1, "not-converged": 1, "failed": 1}  # fmt: skip
    assert summary_line(out).startswith("6 windows: 2 ok")


def test_no_clean_window_compares_with_the_best_unclean_one():
    table = pd.DataFrame([_row(at_bound="m=lower", relative_residual=0.1),
                          _row(at_bound="m=lower", relative_residual=0.5)])  # fmt: skip
    out = classify(table, CFG)
    assert list(out["status"]) == ["at-bound", "at-bound"]
    assert "relative residual" in out["status_reason"].iloc[1]


def test_a_take_all_in_one_bad_basin_is_high_residual_in_absolute_terms():
    # every window equally bad: no window is 3x the take's best, but all exceed the limit
    table = pd.DataFrame([_row(relative_residual=0.3), _row(relative_residual=0.31)])
    out = classify(table, CFG)
    assert list(out["status"]) == ["high-residual", "high-residual"]
    assert "inversion.residual_limit" in out["status_reason"].iloc[0]
    assert list(classify(table, InversionConfig(residual_limit=0.5))["status"]) == ["ok", "ok"]


def test_no_standard_errors_and_too_few_degrees_of_freedom_are_statuses():
    rows = [
        _row(dof=5.0, uncertainty_note=""),
        _row(dof=np.nan, uncertainty_note="no standard errors: SVD did not converge"),
        _row(dof=0.4, uncertainty_note=""),
        _row(dof=0.4, at_bound="m=lower"),  # the worse status wins, both reasons kept
    ]
    out = classify(pd.DataFrame(rows), CFG)
    assert list(out["status"]) == ["ok", "no-errors", "low-dof", "at-bound"]
    assert "SVD" in out["status_reason"].iloc[1]
    assert "n_eff - p = 0.4" in out["status_reason"].iloc[2]
    assert "n_eff - p" in out["status_reason"].iloc[3]


def test_a_soft_window_is_judged_at_the_noise_floor():
    # loud windows (||p|| = 1e5 Pa) with residual 400 Pa (the noise, 0.4 %); an attack's
    # window 4x softer with the same noise in Pa has a relative residual 4x larger: ok, not
    # high-residual (the old rule, 3x the take's best 0.4 %, flagged it); a soft window
    # whose residual is 5x the noise is still high-residual, and so is one 40x softer
    # (the allowance stops at 3x the best: noise is all such a window holds)
    def w(norm_p, f2):
        return _row(relative_residual=f2 / norm_p, f2=f2)

    table = pd.DataFrame([w(1e5, 400.0), w(1e5, 410.0), w(2.5e4, 420.0), w(2.5e4, 2000.0),
                          w(1e5, 1500.0), w(2.5e3, 400.0)])  # fmt: skip
    out = classify(table, CFG)
    assert list(out["status"]) == ["ok", "ok", "ok"] + ["high-residual"] * 3
    assert "noise floor" in out["status_reason"].iloc[3]
