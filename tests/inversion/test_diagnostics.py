"""Take-level checks: each way a take can be wrong as a whole makes it CHECK, never PASS."""

import numpy as np
import pandas as pd
import pytest

from mpipe.inversion.diagnostics import (
    check_plausible,
    impedance_ratio,
    playing_difference,
    take_checks,
)
from mpipe.inversion.settings import InversionConfig
from mpipe.pipeline.report import overall_verdict

CFG = InversionConfig()
FS = 100_000.0


def _tone(f0, amplitude, n=2000):
    t = np.arange(n) / FS
    return amplitude * (np.sin(2 * np.pi * f0 * t) + 0.3 * np.sin(4 * np.pi * f0 * t + 1.0))


def test_playing_difference_measures_cents_and_decibels():
    p = _tone(147.0, 1000.0)
    out = playing_difference(p, _tone(147.0 * 2 ** (30 / 1200), 1000.0 * 10 ** (-2 / 20)), FS)
    assert abs(out["model_f0_cents"] - 30.0) < 3.0
    assert abs(out["model_level_db"] + 2.0) < 0.1  # 2.9 periods: not whole ones
    same = playing_difference(p, p, FS)
    assert same == {"model_f0_cents": 0.0, "model_level_db": 0.0}
    assert np.isnan(playing_difference(p, np.zeros_like(p), FS)["model_level_db"])


def _windows(n=5, **columns):
    table = pd.DataFrame({"status": ["ok"] * n, "relative_residual": 0.005,
                          "model_f0_cents": 0.5, "model_level_db": 0.02})  # fmt: skip
    for key, value in columns.items():
        table[key] = value
    return table


def _verdict(checks):
    return overall_verdict("pass", _windows(), checks)


def test_a_sound_take_passes():
    checks = take_checks(_windows(), CFG, temperature_source="fit", cold_starts_agreeing=6)
    assert checks == []
    assert _verdict(checks)[1] == "pass"


def test_each_take_level_fault_gives_check_with_its_reason():
    cases = {
        "fell back": dict(temperature_source="front end",
                          temperature_note="the fit ran to the edge of its range"),
        "short searches": dict(temperature_source="fit", cold_starts_agreeing=1),
    }  # fmt: skip
    for words, kw in cases.items():
        checks = take_checks(_windows(), CFG, **kw)
        assert len(checks) == 1 and words in checks[0], checks
        label, kind = _verdict(checks)
        assert kind == "check" and words in label
    tables = {
        "playing frequency": _windows(model_f0_cents=[-30.0, -25.0, -28.0, 2.0, -40.0]),
        "RMS level": _windows(model_level_db=2.5),
        # a take all in one wrong basin: every window equally bad, none worse than the best
        "relative residual": _windows(relative_residual=[0.2, 0.21, 0.22, 0.2, 0.25]),
    }
    for words, table in tables.items():
        checks = take_checks(table, CFG, temperature_source="fit", cold_starts_agreeing=6)
        assert len(checks) == 1 and words in checks[0], checks
        assert _verdict(checks)[1] == "check"


def test_a_front_end_temperature_asked_for_is_no_fallback():
    config = InversionConfig(temperature="front-end")
    assert take_checks(_windows(), config, temperature_source="front end") == []


def test_windows_not_ok_count_in_the_medians_so_each_check_can_fire():
    # mpipe <= 0.4 judged the ok windows only: a window above residual_limit is never ok,
    # so a take all in a wrong basin (every window high-residual) passed
    table = _windows(relative_residual=0.2)
    table["status"] = "high-residual"
    checks = take_checks(table, CFG, temperature_source="fit")
    assert any("median relative residual 0.2 " in c for c in checks), checks
    level = _windows(model_level_db=[0.0, 0.0, 1.5, 1.5, 1.5])
    level.loc[2:, "status"] = "at-bound"
    assert any("RMS level" in c for c in take_checks(level, CFG, temperature_source="fit"))


def test_a_nan_median_does_not_pass():
    # the model silent (no level, no period) in every window: never a pass
    table = _windows(model_f0_cents=np.nan, model_level_db=np.nan)
    checks = take_checks(table, CFG, temperature_source="fit")
    assert any("playing frequency could be compared" in c for c in checks), checks
    assert any("RMS level could be compared" in c for c in checks), checks
    table = _windows(relative_residual=np.nan)
    assert any("finite residual" in c for c in take_checks(table, CFG, temperature_source="fit"))


def test_impedance_ratio_and_the_plausibility_of_the_flows_scale():
    z_c = 2.3e6  # Pa s/m^3, about the shipped entry's
    u = _tone(147.0, 2e-5)
    p = 15 * z_c * u  # a reed playing near a resonance: |p/u| = 15 Z_c
    assert impedance_ratio(p, u, FS, z_c) == pytest.approx(15.0, rel=1e-6)
    starts, n = [0, 1000], 2000
    p_long, u_long = np.tile(p, 2), np.tile(u, 2)
    check_plausible(p_long, u_long, FS, starts, n, z_c)  # no error
    # a flow 250x too large but within the flow's own range: |p/u| gives it away
    with pytest.raises(ValueError, match=r"\|p/u\| .* 0\.06 Z_c .* unit error"):
        check_plausible(p_long, 250 * u_long, FS, starts, n, z_c)
    with pytest.raises(ValueError, match="implausible mouthpiece flow"):
        check_plausible(p_long, 1000 * u_long * 1000, FS, starts, n, z_c)
    with pytest.raises(ValueError, match="implausible mouthpiece pressure"):
        check_plausible(1e3 * p_long, u_long, FS, starts, n, z_c)
