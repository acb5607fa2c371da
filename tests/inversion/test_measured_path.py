"""Recovery of the Table 1 reed through the path users take, over several noise seeds.

Each take is a short virtual three-microphone recording (70 dB SNR); it goes through the
adaptive wave separation and the translation (so the flow is zero-mean, as measured), then
the inversion with its global cold start: the path a user's take follows.
"""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from mpipe.cli.virtual_takes import SynthOptions, make_take
from mpipe.inversion.preparation.conditioning import plan_inversion
from mpipe.inversion.settings import ExecutorConfig
from mpipe.inversion.whole_take.front_end import FrontEnd
from mpipe.inversion.whole_take.take import invert_take
from mpipe.measurement.calibration import load_calibration
from mpipe.measurement.separation.stage import separate
from mpipe.measurement.takes import read_take
from mpipe.measurement.translation import translate
from mpipe.pipeline.settings import load_pipeline

ROOT = Path(__file__).resolve().parents[2]
TRUTH = dict(k=8.66e6, S=7.62e-5, y_m=4e-4, p_m=1800.0, m=0.05, g=3000.0, lam=0.013, k_c=8.23e10)
SEEDS = (0, 1, 2, 3, 4)


def measured_path(seed: int, tmp: Path):
    """Mouthpiece signals and the inversion of one steady window of a 0.5 s take."""
    take_files = make_take(
        ROOT / "calibration" / "simplified_clarinet.yaml",
        ROOT / "calibration" / "reed_table1.yaml",
        tmp / f"seed{seed}.flac",
        SynthOptions(duration_s=0.5, snr_db=70.0, seed=seed),
    )
    pipe = load_pipeline(ROOT / "pipelines" / "simplified_clarinet.yaml")
    cal = load_calibration(take_files.calibration)
    take = read_take(take_files.audio, cal, fs=pipe.inversion.sample_rate)
    sep = separate(take.pressures, take.fs, cal, pipe.separation, take.band_limit_hz)
    tr = translate(sep.p0, sep.u0, take.fs, cal, pipe.translation, sep.temperature_track())
    conditioning = replace(pipe.conditioning, edge_s=0.3)
    plan = plan_inversion(tr.p, take.fs, conditioning, 0.02, 0.02, end_s=0.34)
    starts = plan.loc[plan["invert"], "start"].tolist()
    front = FrontEnd(tr.p0, tr.u0, tr.temperature_c, sep.track.level, sep.track.level_se,
                     pipe.separation.band_edge_hz + pipe.separation.band_taper_hz,
                     pipe.translation)  # fmt: skip
    return invert_take(tr.p, tr.u, take.fs, cal, pipe.inversion, ExecutorConfig(workers=1),
                       windows=starts, temperature_c=tr.temperature_c, front_end=front)  # fmt: skip


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("seeds")
    return {seed: measured_path(seed, tmp) for seed in SEEDS}


def test_the_seeds_land_in_the_right_basin(results):
    # every window of every seed ok (zero-mean flow); k, y_m, p_m and lam within 5 % on at
    # least 4 of the 5 seeds (the front end's estimate adds a seed-dependent error of a few
    # per cent at this length; a wrong minimum is 15-45 % off)
    misses = {}
    for seed, done in results.items():
        result = done.tracking
        t = result.table
        assert result.zero_mean and len(t) >= 1
        # ok, or (at 70 dB the residual is mostly a periodic model error, with few
        # effective samples) low-dof: never a bound, a failed search or a high residual
        assert set(t["status"]) <= {"ok", "low-dof"}, (seed, t["status_reason"].tolist())
        assert (t["status"] == "ok").any(), seed
        for name in ("k", "y_m", "p_m", "lam"):
            err = float(t[name].median()) / TRUTH[name] - 1
            assert abs(err) < 0.1, (seed, name, err)  # never a wrong basin
            if abs(err) >= 0.05:
                misses.setdefault(seed, {})[name] = err
    assert len(misses) <= 1, misses


def test_the_cold_start_is_not_one_lucky_search(results):
    # on every seed several of the eight short local searches reach the same minimum
    agreeing = [r.temperature.cold_starts_agreeing for r in results.values()]
    assert min(agreeing) >= 2, agreeing


def test_mass_damping_and_contact_are_off_their_bounds(results):
    # the degenerate minimum of issue 10 had m, g and k_c on their lower bounds
    for done in results.values():
        t = done.tracking.table
        assert (t["at_bound"] == "").all()
        for name in ("m", "g", "k_c"):
            assert np.all(np.abs(np.log(t[name] / TRUTH[name])) < np.log(1.5)), name


def test_the_kernel_temperature_is_fitted_to_the_playing(results):
    # the takes are played at 20 degC; the front end's estimate is a degree wide on 0.5 s
    for seed, done in results.items():
        fit = done.temperature
        print(seed, fit.line())
        assert fit.source == "take fit", (seed, fit.note)  # one fit of the take, reed and air
        assert abs(fit.temperature_c - 20.0) < 0.3, (seed, fit.line())
        # its SE holds the front end's share (the take's fit: z 0.3-1.8 on these seeds)
        assert abs(fit.temperature_c - 20.0) < 3 * fit.se_c, (seed, fit.line())


def test_the_error_bars_are_neither_too_wide_nor_too_narrow(results):
    # z = (estimate - truth) / SE in log space over every ok window of the five seeds,
    # pooled over k, y_m, p_m, p_M and gamma: honest bars give RMS z = 1. The bars of
    # mpipe <= 0.3 (residual inflated uniformly by its autocorrelation time) were about
    # twice too wide: RMS z < 0.6 fails. At 70 dB the noise's share is small and the front
    # end's own error of each take (not in the SEs) shows: 1.69 measured on these five
    # seeds (about 45 pairs). These takes are made by the model at the rate it inverts at, so
    # they carry no discretisation error: the budget's rate component (a real reed's,
    # docs/uncertainty.md) is taken out. The front end is passed as mpipe run passes it, so
    # the budget's frontend component is in the bars, propagated with the take's fitted
    # temperature moving with it (which absorbs part of the front end's error). The take's
    # one fit (estimator: take) gives RMS z 2.67 on these seeds (with the temperature held
    # in that propagation 2.09; the per-window fit without the front end 2.14): the noise of
    # the measured history that drives each window's model is not yet in the bars (issue
    # 45). Bars more than 3x too narrow, or too wide, fail: [0.6, 3.0].
    from mpipe.inversion.trust.combinations import combination_values

    z = []
    for done in results.values():
        t = done.tracking.table
        ok = t[t["status"] == "ok"]
        truth = {**TRUTH, **combination_values(TRUTH, done.kernel.z0, done.air.rho)}
        for name in ("k", "y_m", "p_m", "p_M", "gamma"):
            x, se = ok[name].to_numpy(float), ok[f"{name}_se"].to_numpy(float)
            rate = np.nan_to_num(ok[f"{name}_se_rate"].to_numpy(float))
            se = np.sqrt(se**2 - rate**2)
            z += list(np.log(x / truth[name]) / (se / x))
    rms = float(np.sqrt(np.mean(np.square(z))))
    print(f"RMS z over {len(z)} (window, quantity) pairs: {rms:.2f}")
    assert 0.6 <= rms <= 3.0, rms
