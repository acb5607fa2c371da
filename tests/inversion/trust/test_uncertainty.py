"""Standard errors of step 2: coloured noise, null directions, combinations, invariance."""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from mpipe.acoustics.reflection import reflection_function
from mpipe.core.filters import apply_lowpass, design_lowpass
from mpipe.inversion.fit.least_squares import trust_region
from mpipe.inversion.fit.objective import F2Objective, ObjectiveSettings, TargetWindow
from mpipe.inversion.trust.combinations import combination_values
from mpipe.inversion.trust.uncertainty import (
    covariance,
    log_jacobian,
    scale_direction,
)
from mpipe.measurement.calibration import load_calibration
from mpipe.reed.bore_kernel import prepare_bore
from mpipe.reed.model import simulate
from mpipe.reed.parameters import ReedParameters

FS = 100_000.0
ROOT = Path(__file__).resolve().parents[3]
TABLE1 = ReedParameters(
    k=8.66e6, S=7.62e-5, y_m=4e-4, p_m=1800.0, lam=0.013, m=0.05, g=3000.0, k_c=8.23e10
)
CLOSURE = dataclasses.replace(TABLE1, y_c=TABLE1.y_m)


def test_coverage_on_lowpassed_noise_matches_monte_carlo():
    """A known nonlinear model, noise white then low-passed by the measurement's FIR.

    Over 40 noise seeds the predicted SE must match the spread of the estimates and 2 SE
    must cover the truth in at least 85 % of them (0.95 expected; the binomial standard
    deviation over 40 draws is 0.034). The white-noise formula, which ignores the colour,
    must fail this check (coverage below 0.75): the test can tell the two apart.
    """
    n = 2000
    t = np.arange(n) / FS
    lp = design_lowpass(FS, 7250.0)
    truth = np.array([800.0, 147.0, 300.0, 1.0, 2500.0])

    def model(x):
        a, f, b, ph, fc = x
        return (
            a * np.sin(2 * np.pi * f * t)
            + b * np.cos(4 * np.pi * f * t + ph)
            + 100 * np.sin(2 * np.pi * fc * t)
        )

    start = truth * np.array([1.05, 1.01, 1.05, 1.05, 1.001])
    est, se, naive = [], [], []
    for seed in range(40):
        rng = np.random.default_rng(seed)
        noise = apply_lowpass(rng.standard_normal(n + 400), lp)[200 : 200 + n]
        target = model(truth) + 30.0 * noise / noise.std()
        res = trust_region(
            lambda x, target=target: target - model(x), start, lower=truth / 3, upper=truth * 3
        )
        cov = covariance(res.jacobian, res.residuals, ("a", "f", "b", "ph", "fc"))
        est.append(np.log(res.x / truth))
        se.append(np.sqrt(np.diag(cov.cov)))
        s2 = np.sum(res.residuals**2) / (n - truth.size)
        naive.append(np.sqrt(np.diag(s2 * np.linalg.inv(res.jacobian.T @ res.jacobian))))
    est, se, naive = map(np.asarray, (est, se, naive))
    coverage = np.mean(np.abs(est) <= 2 * se, axis=0)
    assert np.all(coverage >= 0.85), coverage
    ratio = se.mean(axis=0) / est.std(axis=0)
    assert np.all((ratio > 0.7) & (ratio < 1.6)), ratio
    assert np.all(np.mean(np.abs(est) <= 2 * naive, axis=0) < 0.75)


def test_linear_gaussian_limit_bars_neither_too_wide_nor_too_narrow():
    """A linear model whose true covariance is known, under the noise of a measured take.

    The columns are the note's harmonics (147 Hz and up, as a reed's signature); the noise
    is mostly below 300 Hz (a strongly correlated AR(1), tau ~ 100 samples, as the
    mouthpiece pressure's noise through the wave separation) plus a white floor. The true
    covariance is ``(J^T J)^-1 J^T Sigma J (J^T J)^-1`` with Sigma from the AR(1) and the
    floor. Over 150 noise draws the RMS of z = (estimate - truth) / SE must lie in
    [0.85, 1.15] and 2 SE must cover the truth in 0.92-0.98 of the draws, for every
    parameter; the predicted SE must match the true one within 15 % (median). The uniform
    inflation by tau (mpipe <= 0.3) fails this test: its bars on the upper harmonics are
    more than 2x too wide.
    """
    n, phi, floor = 2000, 0.98, 0.3
    t = np.arange(n) / FS
    j = np.column_stack(
        [np.sin(2 * np.pi * 147.0 * h * t + h) for h in (1, 2, 3, 5)]
        + [np.cos(2 * np.pi * 147.0 * t)]
    )
    lag = np.abs(np.subtract.outer(np.arange(n), np.arange(n)))
    sigma = phi**lag / (1 - phi**2) + floor**2 * np.eye(n)
    a_inv = np.linalg.inv(j.T @ j)
    true_se = np.sqrt(np.diag(a_inv @ j.T @ sigma @ j @ a_inv))
    chol = np.linalg.cholesky(sigma)
    rng = np.random.default_rng(11)
    z, z_tau, ratio = [], [], []
    for _ in range(150):
        e = chol @ rng.standard_normal(n)
        theta = a_inv @ j.T @ e  # the least-squares estimate; the truth is 0
        r = e - j @ theta  # the residual at the estimate
        cov = covariance(-j, r, [f"x{i}" for i in range(j.shape[1])])
        se = np.sqrt(np.diag(cov.cov))
        z.append(theta / se)
        ratio.append(se / true_se)
        z_tau.append(theta / (cov.sigma * np.sqrt(np.diag(a_inv))))
    z, z_tau = np.array(z), np.array(z_tau)
    rms = np.sqrt(np.mean(z**2, axis=0))
    coverage = np.mean(np.abs(z) < 2, axis=0)
    assert np.all((rms > 0.85) & (rms < 1.15)), rms
    assert np.all((coverage >= 0.92) & (coverage <= 0.98)), coverage
    assert np.all(np.abs(np.median(ratio, axis=0) - 1) < 0.15), np.median(ratio, axis=0)
    # the uniform inflation by tau fails the first check: its bars on the harmonics that sit
    # above the noise are > 2x too wide
    assert np.min(np.sqrt(np.mean(z_tau**2, axis=0))) < 0.5


def test_null_direction_gives_infinite_se_but_invariant_combinations_stay_finite():
    rng = np.random.default_rng(0)
    base = rng.standard_normal((500, 2))
    # columns 0 and 1 enter only through their sum: e = (1, -1, 0) is invisible
    jac = np.column_stack([base[:, 0], base[:, 0], base[:, 1]])
    r = rng.standard_normal(500)
    cov = covariance(jac, r, ("a", "b", "c"))
    assert cov.null.shape == (1, 3)
    assert abs(abs(cov.null[0] @ np.array([1, -1, 0])) / math.sqrt(2) - 1) < 1e-9
    assert math.isinf(cov.log_se(np.array([1.0, 0.0, 0.0])))
    # a + b is determined: the same SE as the reduced model's (one column fewer: the
    # residual's degrees of freedom differ by one in about 500)
    reduced = covariance(np.column_stack([base[:, 0], base[:, 1]]), r, ("a+b", "c"))
    assert cov.log_se(np.array([1.0, 1.0, 0.0])) == pytest.approx(
        math.sqrt(reduced.cov[0, 0]), rel=5e-3
    )
    assert cov.log_se(np.array([0.0, 0.0, 1.0])) == pytest.approx(
        math.sqrt(reduced.cov[1, 1]), rel=5e-3
    )


@pytest.fixture(scope="module")
def kernel():
    cal = load_calibration(ROOT / "calibration" / "simplified_clarinet.yaml")
    air = cal.air_properties()
    return prepare_bore(reflection_function(cal.bore, air, fs=FS), air)


def scaled(reed: ReedParameters, a: float) -> ReedParameters:
    return dataclasses.replace(
        reed, k=reed.k / a, S=reed.S / a, lam=reed.lam / a, m=reed.m / a,
        y_m=reed.y_m * a, y_c=reed.y_c * a, k_c=reed.k_c / a**2,
    )  # fmt: skip


def test_model_is_scale_invariant_when_contact_starts_at_closure(kernel):
    """k, S, lam, m / a, y_m, y_c * a, k_c / a^2 leave p and u unchanged (exact algebra).

    Scaling y_m but not y_c (contact at a fixed displacement) breaks the invariance as soon
    as the reed touches the lay: the same check on the Table 1 reed must fail.
    """
    n = 30000
    ref = simulate(CLOSURE, kernel, n)
    assert np.ptp(ref.p) > 1000  # playing
    for a in (0.7, 1.3):
        other = simulate(scaled(CLOSURE, a), kernel, n)
        assert np.max(np.abs(other.p - ref.p)) < 1e-8 * np.max(np.abs(ref.p))
        assert np.max(np.abs(other.u - ref.u)) < 1e-8 * np.max(np.abs(ref.u))
    fixed = dataclasses.replace(scaled(TABLE1, 1.3), y_c=TABLE1.y_c)
    diff = simulate(fixed, kernel, n).p - simulate(TABLE1, kernel, n).p
    assert np.max(np.abs(diff)) > 1e-2 * np.max(np.abs(ref.p))


def _objective(kernel, reed, free, closure):
    sim = simulate(reed, kernel, 32000)
    s = 30000
    target = TargetWindow(sim.p[s : s + 2000], sim.u[s : s + 2000], sim.p[:s], sim.u[:s], FS, False)
    return F2Objective(kernel, target, ObjectiveSettings(), reed, free, closure)


def test_svd_finds_the_scale_invariance_in_the_model_jacobian(kernel):
    """The SVD sees the invariance, and only where it exists.

    All eight parameters free with y_c tied to y_m: exactly one null direction, along the
    scale invariance; with contact at the fixed y_c (Table 1) none.
    """
    free = ("k", "S", "y_m", "p_m", "m", "g", "lam", "k_c")
    obj = _objective(kernel, CLOSURE, free, True)
    x = np.array([getattr(CLOSURE, n) for n in free])
    jac = log_jacobian(obj.residuals, x)
    noise = 1e-3 * np.random.default_rng(0).standard_normal(2000)
    cov = covariance(jac, noise, free)
    assert cov.null.shape[0] == 1
    v = scale_direction(free)
    assert abs(cov.null[0] @ v) / np.linalg.norm(v) > 0.99
    assert math.isinf(cov.log_se(np.eye(8)[0]))  # k
    assert math.isfinite(cov.log_se(np.array([1, 0, 1, 0, 0, 0, 0, 0.0])))  # p_M
    obj1 = _objective(kernel, TABLE1, free, False)
    cov1 = covariance(log_jacobian(obj1.residuals, TABLE1.as_vector()), noise, free)
    assert cov1.null.shape[0] == 0


def test_closure_inversion_flags_the_scale_and_recovers_the_combinations(kernel):
    """The issue's closure case on noise-free model signals, one cold window.

    y_c = y_m and lam configured 15 % off the truth: k, S, y_m, lam, m, k_c undetermined;
    p_M, zeta, gamma and p_m within 2 %.
    """
    from mpipe.inversion.fit.window import invert_window
    from mpipe.inversion.settings import InversionConfig

    sim = simulate(CLOSURE, kernel, 32000)
    config = InversionConfig(
        contact="closure", lam=0.85 * CLOSURE.lam, design_points=32, local_starts=3,
        local_evaluations=150,
    )  # fmt: skip
    out = invert_window(sim.p, sim.u, FS, 30000, kernel, kernel.rho, config, zero_mean=False)
    row = out.row
    assert row["status"] == "ok", row["status_reason"]
    assert row["y_c"] == row["y_m"]
    names = ("k", "y_m", "p_m", "lam", "m", "g")
    truth = combination_values({n: getattr(CLOSURE, n) for n in names}, kernel.z0, kernel.rho)
    for name in ("p_M", "zeta", "gamma"):
        assert row[name] == pytest.approx(truth[name], rel=0.02), name
        assert row[f"determined_{name}"]
    assert row["p_m"] == pytest.approx(CLOSURE.p_m, rel=0.02)
    for name in ("k", "S", "y_m", "lam", "m", "k_c"):
        assert not row[f"determined_{name}"] and math.isinf(row[f"{name}_se"]), name
    # the fit took the scaled reed: k is off by the factor lam is
    assert row["k"] / CLOSURE.k == pytest.approx(0.85, rel=0.03)
    assert "scale invariance" in row["uncertainty_note"]


def test_free_contact_point_is_searched_and_recovered(kernel):
    """contact: free searches y_c, lam holds the scale.

    From a start 10 % off, a warm window recovers y_c of the Table 1 reed within 2 %.
    """
    from mpipe.inversion.fit.window import invert_window
    from mpipe.inversion.settings import InversionConfig
    from mpipe.inversion.trust.status import search_bounds

    config = InversionConfig(contact="free")
    assert config.search_parameters == ("k", "S", "y_m", "p_m", "m", "g", "k_c", "y_c")
    assert search_bounds(config, 1000.0)[-1].tolist() == [2e-5, 1e-3]
    sim = simulate(TABLE1, kernel, 32000)
    start = dataclasses.replace(TABLE1, y_c=1.1 * TABLE1.y_c, k=0.95 * TABLE1.k)
    out = invert_window(
        sim.p, sim.u, FS, 30000, kernel, kernel.rho, config, zero_mean=False, warm=start
    )
    row = out.row
    assert row["status"] == "ok", row["status_reason"]
    assert row["y_c"] == pytest.approx(TABLE1.y_c, rel=0.02)
    assert math.isinf(row["y_c_se"]) and not row["determined_y_c"]  # scale-dependent
    assert row["p_M"] == pytest.approx(TABLE1.k * TABLE1.y_m, rel=0.02)


def test_error_bars_of_the_reed_model_are_honest_under_lowpassed_noise(kernel):
    """Table 1 reed, 30 Pa of low-passed noise on p, six seeds, one warm window each.

    Each of k, y_m, p_m, p_M, gamma, zeta must be within 2 SE of the truth in at least 4 of
    the 6 seeds (0.95 expected per seed; 3 or fewer has probability 0.002), and the errors
    in units of their SE must have an RMS in [0.4, 1.8] (1 for honest error bars; ignoring
    the noise's colour would give about 2.9, inflated SEs well below 0.4).
    """
    from mpipe.inversion.fit.window import invert_window
    from mpipe.inversion.settings import InversionConfig

    sim = simulate(TABLE1, kernel, 32000)
    lp = design_lowpass(FS, 7250.0)
    names = ("k", "y_m", "p_m", "p_M", "gamma", "zeta")
    base = ("k", "y_m", "p_m", "lam", "m", "g")
    truth = {n: getattr(TABLE1, n) for n in base}
    truth.update(combination_values(truth, kernel.z0, kernel.rho))
    start = dataclasses.replace(TABLE1, k=9e6, y_m=3.9e-4)
    z = []
    for seed in range(6):
        noise = apply_lowpass(np.random.default_rng(seed).standard_normal(sim.p.size), lp)
        p = sim.p + 30.0 * noise / noise.std()
        row = invert_window(
            p, sim.u, FS, 30000, kernel, kernel.rho, InversionConfig(), zero_mean=False,
            warm=start,
        ).row  # fmt: skip
        assert row["status"] == "ok", row["status_reason"]
        z.append([(row[n] - truth[n]) / row[f"{n}_se"] for n in names])
    z = np.asarray(z)
    covered = np.sum(np.abs(z) <= 2, axis=0)
    assert np.all(covered >= 4), dict(zip(names, covered, strict=True))
    assert 0.4 < math.sqrt(np.mean(z**2)) < 1.8, z


def _harmonic_case(n=2000, f0=150.0):
    """Jacobian columns at a note's harmonics and a measured pressure with that period.

    150 Hz: three whole periods in the window, so a drift at 50 Hz or DC is orthogonal to
    every column (the Jacobian does not see it at all).
    """
    t = np.arange(n) / FS
    rng = np.random.default_rng(0)
    # each column a reed parameter's signature: spread over the first eight harmonics
    j = np.column_stack([
        sum(rng.normal() * np.sin(2 * np.pi * f0 * h * t + rng.uniform(0, 6.3))
            for h in range(1, 9))
        for _ in range(5)
    ])  # fmt: skip
    p = 1000.0 * sum(np.sin(2 * np.pi * f0 * h * t + 0.3 * h) / h for h in range(1, 12))
    return j, p


def test_a_drift_below_the_harmonics_does_not_widen_the_noise_component():
    """White noise (1 Pa) at the harmonics, plus a drift 5x stronger below the first one.

    The drift (a random offset and 50 Hz component, Gaussian) is orthogonal to the
    Jacobian's columns, so the least-squares estimate's true covariance is the white one,
    ``(J^T J)^-1``. The noise component measured at the harmonics must stay honest: RMS z
    in [0.8, 1.25] for every parameter and median SE within 15 % of the true one in each
    of 3 seeds of 100 windows (all must pass), RMS z in [0.9, 1.1] over the 300; while the
    factor n_eff / (n_eff - p) of the residual's autocorrelation (mpipe <= 0.4) widens the
    bars by more than 1.5x.
    """
    j, p = _harmonic_case()
    n = j.shape[0]
    t = np.arange(n) / FS
    drift = np.column_stack([np.ones(n), np.cos(2 * np.pi * 50 * t), np.sin(2 * np.pi * 50 * t)])
    a_inv = np.linalg.inv(j.T @ j)
    true_se = np.sqrt(np.diag(a_inv))
    names = [f"x{i}" for i in range(j.shape[1])]
    pooled = []
    for seed in (1, 2, 3):
        rng = np.random.default_rng(seed)
        z, ratio, widened = [], [], []
        for _ in range(100):
            e = rng.standard_normal(n) + drift @ (5.0 * rng.standard_normal(3))
            theta = a_inv @ j.T @ e
            r = e - j @ theta
            cov = covariance(-j, r, names, pressure=p, fs=FS)
            se = np.sqrt(np.diag(cov.cov))
            z.append(theta / se)
            ratio.append(se / true_se)
            widened.append(np.sqrt(np.diag(covariance(-j, r, names).cov)) / se)
        rms = np.sqrt(np.mean(np.array(z) ** 2, axis=0))
        assert np.all((rms > 0.8) & (rms < 1.25)), (seed, rms)
        assert np.all(np.abs(np.median(ratio, axis=0) - 1) < 0.15), np.median(ratio, axis=0)
        assert np.median(widened) > 1.5, np.median(widened)
        pooled += z
    assert 0.9 < np.sqrt(np.mean(np.array(pooled) ** 2)) < 1.1


def test_a_misfit_at_the_harmonics_gets_a_model_component_that_scales_with_it():
    """A residual with a model mismatch at the harmonics (not along J) on top of white noise.

    Without it the model component is small beside the noise one; with a mismatch whose
    level is about 10x the noise's in the band the model component is several times the
    noise one, and doubling the mismatch doubles it (within 15 %); the noise component does
    not move (within 15 %): the mismatch is at the harmonics, the noise between them.
    Three noise seeds, all must pass.
    """
    j, p = _harmonic_case()
    n = j.shape[0]
    t = np.arange(n) / FS
    names = [f"x{i}" for i in range(j.shape[1])]
    misfit = sum(np.cos(2 * np.pi * 150.0 * h * t + 0.7 * h) for h in range(1, 9))
    misfit -= j @ np.linalg.lstsq(j, misfit, rcond=None)[0]  # the fit absorbs its J part
    misfit *= 10 / np.sqrt(np.mean(misfit**2))  # 10x the noise's RMS (white, 1 Pa)
    for seed in (4, 5, 6):
        noise = np.random.default_rng(seed).standard_normal(n)
        noise -= j @ np.linalg.lstsq(j, noise, rcond=None)[0]
        out = {}
        for a in (0.0, 1.0, 2.0):
            cov = covariance(-j, noise + a * misfit, names, pressure=p, fs=FS)
            out[a] = (np.sqrt(np.diag(cov.cov)), np.sqrt(np.diag(cov.cov_model)))
        assert np.all(out[0.0][1] < 0.5 * out[0.0][0]), out[0.0]
        assert np.all(out[1.0][1] > 3 * out[1.0][0]), out[1.0]
        np.testing.assert_allclose(out[2.0][1] / out[1.0][1], 2.0, rtol=0.15)
        np.testing.assert_allclose(out[1.0][0] / out[0.0][0], 1.0, rtol=0.15)
    # the relative levels the status judges: the misfit is seen, the noise is not moved
    cov = covariance(-j, noise + misfit, names, pressure=p, fs=FS)
    assert cov.model_residual > 5 * cov.noise_residual


def test_the_model_form_floor_is_a_fraction_of_the_pressure_at_the_harmonics():
    j, p = _harmonic_case()
    names = [f"x{i}" for i in range(j.shape[1])]
    r = np.random.default_rng(7).standard_normal(j.shape[0]) * 1e-6  # no noise, no misfit
    se = [np.sqrt(np.diag(covariance(-j, r, names, pressure=p, fs=FS, floor=f).cov_model))
          for f in (0.01, 0.02)]  # fmt: skip
    np.testing.assert_allclose(se[1] / se[0], 2.0, rtol=1e-6)  # linear in the floor
    assert np.all(se[0] > 0)


def test_a_quantity_grazing_a_weak_direction_keeps_a_finite_se_equal_to_the_exact_one():
    """Issue 38: p_M = k y_m was inf because a weakly determined direction grazed it.

    A linear model whose columns a and b are nearly collinear (singular value ratio 6e-4,
    below RCOND) and a quantity e = (1, 1.3, 0) that is not invariant: its SE must be the
    exact least-squares one, s^2 e (J^T J)^-1 e for white noise (no pseudo-inverse), not
    inf; a quantity along an exact invariance stays inf.
    """
    rng = np.random.default_rng(3)
    n = 4000
    base = rng.standard_normal((n, 2))
    eps = 1.2e-3  # singular value ratio eps / 2 = 6e-4
    jac = np.column_stack([base[:, 0], base[:, 0] + eps * rng.standard_normal(n), base[:, 1]])
    r = rng.standard_normal(n)
    cov = covariance(jac, r, ("a", "b", "c"))
    assert cov.null.shape[0] == 1  # below RCOND: reported as a null direction
    e = np.array([1.0, 1.3, 0.0])
    exact = math.sqrt(e @ np.linalg.inv(jac.T @ jac) @ e) * np.std(r)
    se = cov.log_se(e)
    assert math.isfinite(se)
    assert se == pytest.approx(exact, rel=0.1)
    # the direction's orthogonal quantity (a + b) is as before
    assert cov.log_se(np.array([1.0, 1.0, 0.0])) == pytest.approx(
        math.sqrt(np.array([1, 1, 0.0]) @ cov.cov @ np.array([1, 1, 0.0])), rel=1e-6
    )
    same = np.column_stack([base[:, 0], base[:, 0], base[:, 1]])
    assert math.isinf(covariance(same, r, ("a", "b", "c")).log_se(e))
