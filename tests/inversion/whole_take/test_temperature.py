"""The kernel temperature fitted to the playing: the search, the SE and its share of the errors."""

import dataclasses
import math
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from mpipe.inversion.trust.note_temperature import (
    notes_from_triple,
    parabola_vertex,
    scatter_se,
    window_minima,
)
from mpipe.inversion.whole_take.temperature import (
    TemperatureFit,
    pick_windows,
    widen_standard_errors,
)
from mpipe.inversion.whole_take.temperature_profile import COARSE_C, FINE_C, Profile, settle


def test_parabola_vertex_and_curvature_are_exact_on_a_parabola():
    x = (19.0, 19.5, 20.5)
    y = [3.0 * (t - 19.8) ** 2 + 7.0 for t in x]
    vertex, a = parabola_vertex(x, y)
    assert vertex == pytest.approx(19.8, abs=1e-9) and a == pytest.approx(3.0, rel=1e-9)
    vertex, a = parabola_vertex(x, [-v for v in y])  # a maximum is not a minimum
    assert math.isnan(vertex) and a < 0


def test_pick_windows_spreads_over_the_take():
    assert pick_windows(range(0, 110, 10), 3) == [0, 50, 100]
    assert pick_windows([5, 7], 6) == [5, 7]


def test_the_fit_spreads_over_every_note_and_grows_with_the_take():
    from mpipe.inversion.preparation.segments import pick_by_segment, window_count
    from mpipe.inversion.settings import InversionConfig

    cfg = InversionConfig()  # 6 windows at least, 1 per second, 24 at most; hop 20 ms
    assert window_count(100, cfg) == 6  # a 2 s take
    assert window_count(1000, cfg) == 20  # 20 s: 20 windows
    assert window_count(5000, cfg) == 24
    # three notes of 30, 10 and 20 windows: every note at least one, shares by length
    starts = list(range(60))
    segs = [1] * 30 + [3] * 10 + [5] * 20
    chosen, groups = pick_by_segment(starts, segs, 6)
    assert sorted(set(groups)) == [1, 3, 5] and groups.count(1) == 3 and groups.count(5) == 2
    assert chosen == sorted(chosen)
    # steady windows are preferred; a note without enough takes its central half
    steady = [i % 2 == 0 for i in range(30)] + [False] * 30
    chosen, groups = pick_by_segment(starts, segs, 6, steady)
    first = [s for s, g in zip(chosen, groups, strict=True) if g == 1]
    assert all(s % 2 == 0 for s in first)
    third = [s for s, g in zip(chosen, groups, strict=True) if g == 5]
    assert all(45 <= s < 55 for s in third)  # windows 5..14 of the note's 20


def _quadratic_profile(t_true: float, noise: float = 0.0, seed: int = 0):
    rng = np.random.default_rng(seed)

    def solve(t, warm):
        r = 1e6 * (t - t_true) ** 2 + 5e5 + noise * rng.standard_normal()
        return r, list(warm), []

    return Profile(solve, [None])


@pytest.mark.parametrize("t0", [14.0, 18.5, 20.0, 23.0])
def test_settle_finds_the_minimum_from_either_side(t0):
    profile = _quadratic_profile(20.3)
    vertex, curvature, centre = settle(profile, t0, t0 - 8, t0 + 8, 30)
    assert vertex == pytest.approx(20.3, abs=1e-6) and curvature == pytest.approx(1e6)
    assert abs(centre - vertex) <= FINE_C / 2
    # coarse steps of COARSE_C, then one or two fine triples
    assert len(profile.tried) <= 3 + int(abs(t0 - 20.3) / COARSE_C) + 6


def test_settle_tolerates_a_noisy_profile_and_reports_no_minimum_on_a_ramp():
    # noise of 1 % of the rise over one fine step moves the vertex by a few hundredths
    noisy = _quadratic_profile(20.3, noise=0.01 * 1e6 * FINE_C**2, seed=1)
    vertex, _, _ = settle(noisy, 19.0, 11.0, 27.0, 30)
    assert vertex == pytest.approx(20.3, abs=0.05)

    def ramp(t, warm):
        return 1e5 * t + 1e6, list(warm), []

    # falling towards low T: the search walks to the edge, where fit_temperature refuses it
    settled = settle(Profile(ramp, [None]), 20.0, 12.0, 28.0, 30)
    assert settled is None or not 12.0 + COARSE_C <= settled[0] <= 28.0 - COARSE_C


def _table():
    return pd.DataFrame(
        {
            "k": [8e6, 9e6],
            "k_se": [0.4e6, 0.45e6],
            "determined_k": [True, True],
            "S": [7e-5, 7e-5],
            "S_se": [1e-6, math.inf],
            "determined_S": [True, False],
        }
    )


def test_widened_se_adds_the_temperature_share_in_quadrature():
    fit = TemperatureFit(20.0, 0.1, "fit", 19.0, {"k": 0.03, "S": 0.2}, 6)
    out = widen_standard_errors(_table(), fit, limit=0.10)
    # k: its fit SE and x * dlnx/dT * se_T, in quadrature
    assert out["k_se"][0] == pytest.approx(math.hypot(0.4e6, 8e6 * 0.03 * 0.1))
    assert out["S_se"][0] == pytest.approx(math.hypot(1e-6, 7e-5 * 0.2 * 0.1))
    assert math.isinf(out["S_se"][1]) and not out["determined_S"][1]
    assert (out["kernel_temperature_c"] == 20.0).all()
    assert (out["kernel_temperature_se_c"] == 0.1).all()
    # a wide temperature SE widens k's combined SE past 10 %, but a take-wide term does not
    # make k undetermined: its within-take SE is 5 % (issue 38)
    wide = widen_standard_errors(_table(), TemperatureFit(20.0, 3.0, "fit", 19.0, {"k": 0.03}), 0.1)
    assert (wide["k_se"] / wide["k"] > 0.1).all()
    assert wide["determined_k"].all()


def test_nothing_is_widened_when_the_temperature_was_not_fitted():
    fit = TemperatureFit(19.0, math.nan, "front end", 19.0)
    out = widen_standard_errors(_table(), fit, limit=0.10)
    pd.testing.assert_series_equal(out["k_se"], _table()["k_se"])
    assert math.isnan(out["kernel_temperature_se_c"][0])


class _FakeWorld:
    """Two basins of step 2, as on a short 45 dB take.

    The right one (m = 0.05) has R minimal at 20 degC; a collapsed one (m = 0.01) has a
    higher minimum at 21.4 degC and is what a cold start finds on a kernel more than
    1.5 degC off.
    """

    def __init__(self):
        from mpipe.reed.parameters import ReedParameters

        base = ReedParameters(
            k=8.66e6, S=7.62e-5, y_m=4e-4, p_m=1800.0, lam=0.013, m=0.05, g=3000.0, k_c=8.23e10
        )
        self.right, self.wrong = base, dataclasses.replace(base, m=0.01, g=400.0)
        self.cold_starts = []
        self.calls = 0

    def bore_kernel(self, calibration, fs, t):
        return SimpleNamespace(t=t, z0=4e6), SimpleNamespace(rho=1.2)

    def invert_window(self, p, u, fs, start, kernel, rho, config, *, zero_mean, warm=None):
        self.calls += 1
        if warm is None:
            self.cold_starts.append(kernel.t)
            warm = self.wrong if abs(kernel.t - 20.0) > 1.5 else self.right
        if warm.m == self.right.m:
            r = 1e5 + 1e6 * (kernel.t - 20.0) ** 2
        else:
            r = 3e5 + 1e6 * (kernel.t - 21.4) ** 2
        reed = dataclasses.replace(warm, S=self.right.S * (1 + 0.2 * (kernel.t - 20.0)))
        row = {
            "f2": math.sqrt(r),
            "n_eff": 100.0,
            "dof": 92.0,
            "cold_starts_agreeing": 5.0,
            "error": "",
            "optimiser_converged": True,
            "relative_residual": math.sqrt(r) / 1e4,
        }
        return SimpleNamespace(reed=reed, row=row)


def _faked(monkeypatch):
    from mpipe.inversion.whole_take import temperature, temperature_profile

    world = _FakeWorld()
    for module in (temperature, temperature_profile):
        monkeypatch.setattr(module, "invert_window", world.invert_window)
    monkeypatch.setattr(temperature, "bore_kernel", world.bore_kernel)
    return world, temperature


@pytest.mark.parametrize("restarts", [0, 2])
def test_a_cold_start_far_from_the_fitted_temperature_is_made_again(monkeypatch, restarts):
    from mpipe.inversion.settings import InversionConfig

    world, temperature = _faked(monkeypatch)
    monkeypatch.setattr(temperature, "RESTARTS", restarts)
    fit = temperature.fit_temperature(
        np.zeros(10_000), np.zeros(10_000), 1e5, None, [0, 2000, 4000], InversionConfig(),
        zero_mean=True, front_end_c=22.7,
    )  # fmt: skip
    if restarts:  # the second cold start, at ~21.4 degC, finds the right basin
        assert fit.temperature_c == pytest.approx(20.0, abs=0.01)
        assert fit.anchor.m == world.right.m and "cold start repeated" in fit.note
        assert len(world.cold_starts) >= 2
    else:  # the first basin is kept: a wrong minimum, as without the restart
        assert fit.temperature_c == pytest.approx(21.4, abs=0.01)
        assert fit.anchor.m == world.wrong.m
    slope = 0.2 / (1 + 0.2 * (fit.temperature_c - 20))  # d ln S / dT of the fake
    assert fit.sensitivity["S"] == pytest.approx(slope, rel=0.05)


def test_a_cold_start_made_again_in_the_same_basin_settles_no_second_profile(monkeypatch):
    # from 20.8 degC the cold start finds the right basin already; the fit ends at 20.0,
    # 0.8 degC away: one cold start there checks the basin (the same), and the profile of
    # the first run is the answer: every other call is one of its evaluations
    from mpipe.inversion.settings import InversionConfig

    world, temperature = _faked(monkeypatch)
    fit = temperature.fit_temperature(
        np.zeros(10_000), np.zeros(10_000), 1e5, None, [0, 2000, 4000], InversionConfig(),
        zero_mean=True, front_end_c=20.8,
    )  # fmt: skip
    assert fit.temperature_c == pytest.approx(20.0, abs=0.01)
    assert world.cold_starts == pytest.approx([20.8, 20.0])
    assert world.calls == 2 + 3 * len(fit.evaluations)
    assert "cold start repeated" not in fit.note


def test_later_notes_start_from_the_note_before_one_cold_start_per_take(monkeypatch):
    from mpipe.inversion.settings import InversionConfig
    from mpipe.inversion.whole_take.tracking import WindowPlan

    world, temperature = _faked(monkeypatch)
    plan = WindowPlan([0, 2000, 4000, 6000, 8000, 9000], segments=[1, 1, 2, 2, 3, 3])
    fit = temperature.fit_temperature(
        np.zeros(10_000), np.zeros(10_000), 1e5, None, plan, InversionConfig(),
        zero_mean=True, front_end_c=20.0,
    )  # fmt: skip
    assert world.cold_starts == [20.0]  # three notes, one cold start
    assert set(fit.anchors) == {1, 2, 3}
    assert fit.temperature_c == pytest.approx(20.0, abs=0.01)


def test_a_warm_note_start_holds_only_converged_and_near_the_cold_residual():
    from mpipe.inversion.settings import InversionConfig
    from mpipe.inversion.whole_take.temperature_profile import holds

    def fit(converged, residual):
        row = {"optimiser_converged": converged, "relative_residual": residual}
        return SimpleNamespace(reed=object(), row=row)

    first, config = fit(True, 0.01), InversionConfig()
    assert holds(fit(True, 0.029), first, config)
    assert not holds(fit(True, 0.031), first, config)  # residual_factor 3: a wrong basin
    assert not holds(fit(False, 0.01), first, config)
    assert not holds(SimpleNamespace(reed=None, row={}), first, config)


def test_settle_returns_a_fine_triple_that_was_evaluated():
    # a rough profile (warm-start noise) with a generous budget: whatever the search does,
    # the centre it returns and its two neighbours were evaluated (their rows are read).
    # A profile too rough for a convex fine triple gives None (the fit then falls back,
    # which the take's checks report); at least 15 of the 40 settle (19 measured).
    settled_seeds = 0
    for seed in range(40):
        rng = np.random.default_rng(seed)
        phase, t0 = rng.uniform(0, 2 * np.pi), rng.uniform(-3, 3)

        def rough(t, warm, phase=phase, t0=t0):
            return 1 + 0.1 * (t - t0) ** 2 + 0.036 * np.sin(56 * t + phase), list(warm), []

        profile = Profile(rough, [None])
        settled = settle(profile, 0.0, -8.0, 8.0, 20)
        if settled is None:
            continue
        settled_seeds += 1
        _, _, centre = settled
        for d in (-FINE_C, 0.0, FINE_C):
            assert round(centre + d, 4) in profile.tried, seed
    assert settled_seeds >= 15, settled_seeds


def _triple_of(minima, centre, curvature=2.0, floor=1.0, dof=None):
    """The fit's last triple of rows for windows whose F2^2 are parabolas in T."""
    return [
        [
            {
                "f2": math.sqrt(curvature * (t - m) ** 2 + floor),
                **({} if dof is None else {"dof": dof}),
            }
            for m in minima
        ]
        for t in (centre - FINE_C, centre, centre + FINE_C)
    ]


def test_scatter_se_is_the_standard_error_of_the_windows_own_minima():
    # four windows, each a parabola in T with its own minimum: the scatter SE is the SD of
    # the minima over sqrt(4); each window's own SE is sqrt(s^2 / a) with s^2 = F2^2 / dof
    minima = np.array([19.8, 20.1, 20.3, 19.9])
    centre = 20.0
    found, ses = window_minima(_triple_of(minima, centre, dof=4.0), centre, FINE_C)
    assert found == pytest.approx(list(minima), abs=1e-9)
    f2_centre = 2.0 * (centre - minima) ** 2 + 1.0
    assert ses == pytest.approx(list(np.sqrt(f2_centre / 4.0 / 2.0)), rel=1e-9)
    expected = np.std(minima, ddof=1) / 2
    assert scatter_se(found) == pytest.approx(expected, rel=1e-9)
    # fewer than three windows: no scatter to measure
    assert scatter_se(found[:2]) == 0.0


def test_each_notes_own_temperature_is_its_windows_minimum():
    # three windows of two notes whose residuals are parabolas in T with minima at 19.9,
    # 20.1 (note 1) and 20.6 (note 4): each note's own temperature is its windows' mean
    # (equal SEs: the plain mean)
    minima = (19.9, 20.1, 20.6)
    notes = notes_from_triple(_triple_of(minima, 20.0, curvature=1e4), 20.0, FINE_C, [1, 1, 4])
    assert notes.temperature_c[4] == pytest.approx(20.6, abs=1e-9)
    assert 19.9 < notes.temperature_c[1] < 20.1
