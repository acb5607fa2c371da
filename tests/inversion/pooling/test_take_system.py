"""The take's nested elimination against the dense joint system (exact algebra)."""

import dataclasses

import numpy as np
import pytest

from mpipe.inversion.pooling.take_system import TakeSystem, TierSizes, pseudo_inverse

SIZES = TierSizes(fast=2, slow=3, take=1)


def _problem(seed: int, notes=(0, 0, 1, 1, 1, 2), n: int = 30):
    """Random windows of three notes; the dense Jacobian built independently."""
    rng = np.random.default_rng(seed)
    f, s, t = SIZES.fast, SIZES.slow, SIZES.take
    w, n_notes = len(notes), max(notes) + 1
    jacs = [rng.normal(size=(n, SIZES.local)) for _ in notes]
    res = [rng.normal(size=n) for _ in notes]
    grams = []
    for _ in notes:
        q = rng.normal(size=(SIZES.local, SIZES.local))
        grams.append(q @ q.T)
    size = w * f + n_notes * s + t
    dense = np.zeros((w * n, size))
    index = []
    for i, (j, note) in enumerate(zip(jacs, notes, strict=True)):
        cols = np.concatenate([i * f + np.arange(f), w * f + note * s + np.arange(s),
                               w * f + n_notes * s + np.arange(t)])  # fmt: skip
        dense[i * n : (i + 1) * n, cols] = j
        index.append(cols)
    return jacs, res, np.asarray(grams), dense, index


def _prior(t_value: float = 0.7, information: float = 4.0):
    return np.array([[information]]), np.array([information * t_value])


def _dense_normal(dense, res, prior):
    """The dense normal matrix and gradient, the prior on the last (the take's) unknown."""
    info, grad = prior
    a = dense.T @ dense
    g = dense.T @ np.concatenate(res)
    a[-1, -1] += info[0, 0]
    g[-1] += grad[0]
    return a, g


@pytest.mark.parametrize("mu", [0.0, 0.25])
def test_the_nested_step_equals_the_dense_solve(mu):
    jacs, res, _, dense, _ = _problem(1)
    notes = (0, 0, 1, 1, 1, 2)
    prior = _prior()
    system = TakeSystem.of(jacs, res, notes, SIZES, prior=prior)
    a, g = _dense_normal(dense, res, prior)
    expected = np.linalg.solve(a + mu * np.diag(np.diag(a)), -g)
    d_fast, d_slow, d_take = system.step(mu)
    got = np.concatenate([d_fast.ravel(), d_slow.ravel(), d_take])
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-12)


def test_the_predicted_fall_is_the_quadratic_model():
    jacs, res, _, dense, _ = _problem(2)
    notes = (0, 0, 1, 1, 1, 2)
    prior = _prior()
    system = TakeSystem.of(jacs, res, notes, SIZES, prior=prior)
    rng = np.random.default_rng(5)
    d_fast, d_slow, d_take = rng.normal(size=(6, 2)), rng.normal(size=(3, 3)), rng.normal(size=1)
    d = np.concatenate([d_fast.ravel(), d_slow.ravel(), d_take])
    a, g = _dense_normal(dense, res, prior)
    assert system.predicted_fall(d_fast, d_slow, d_take) == pytest.approx(-(2 * g @ d + d @ a @ d))


def test_the_covariance_equals_the_dense_sandwich():
    jacs, res, grams, dense, index = _problem(3)
    notes = (0, 0, 1, 1, 1, 2)
    prior = _prior()
    info = prior[0]
    system = TakeSystem.of(jacs, res, notes, SIZES, prior=prior)
    a, _ = _dense_normal(dense, res, prior)
    b = np.zeros_like(a)
    for cols, gram in zip(index, grams, strict=True):
        b[np.ix_(cols, cols)] += gram
    b[-1, -1] += info[0, 0]
    a_inv = np.linalg.inv(a)
    expected = a_inv @ b @ a_inv
    cov = system.covariance(grams)
    for i, cols in enumerate(index):
        np.testing.assert_allclose(cov.window(i), expected[np.ix_(cols, cols)], rtol=1e-8,
                                   atol=1e-12)  # fmt: skip


def test_white_noise_sandwich_is_the_inverse_information():
    # B_i = J_i^T J_i (unit white noise) and the prior's own information: A^-1 B A^-1 = A^-1
    jacs, res, _, dense, index = _problem(4)
    notes = (0, 0, 1, 1, 1, 2)
    prior = _prior()
    system = TakeSystem.of(jacs, res, notes, SIZES, prior=prior)
    a, _ = _dense_normal(dense, res, prior)
    cov = system.covariance(system.grams)
    a_inv = np.linalg.inv(a)
    for i, cols in enumerate(index):
        np.testing.assert_allclose(cov.window(i), a_inv[np.ix_(cols, cols)], rtol=1e-8,
                                   atol=1e-12)  # fmt: skip


def test_an_undetermined_direction_is_named_and_not_moved():
    # the take's column is zero in every window and there is no prior: t is undetermined
    jacs, res, _, _, _ = _problem(5)
    jacs = [np.concatenate([j[:, :-1], np.zeros((j.shape[0], 1))], axis=1) for j in jacs]
    system = TakeSystem.of(jacs, res, (0, 0, 1, 1, 1, 2), SIZES)
    _, _, d_take = system.step(0.0)
    assert d_take[0] == 0.0
    cov = system.covariance(system.grams)
    assert cov.null.shape[0] == 1
    assert abs(cov.null[0, -1]) == pytest.approx(1.0)


def test_pseudo_inverse_of_a_badly_scaled_matrix_is_its_inverse():
    # units 1e5 apart (ln parameters beside degrees Celsius) are not a null direction
    rng = np.random.default_rng(6)
    q = rng.normal(size=(4, 4))
    a = q @ q.T + np.eye(4)
    scale = np.diag([1e3, 1.0, 1e-2, 1.0])
    inv, null = pseudo_inverse(scale @ a @ scale)
    assert null.shape[0] == 0
    # the scaled inverse, unscaled, is the inverse of the well-scaled matrix
    np.testing.assert_allclose(scale @ inv @ scale, np.linalg.inv(a), rtol=1e-9)


def test_a_held_unknown_does_not_move_and_the_rest_solve_without_it():
    # independent: the dense system with the held unknowns' rows and columns deleted
    jacs, res, _, dense, _ = _problem(7)
    notes = (0, 0, 1, 1, 1, 2)
    prior = _prior()
    system = TakeSystem.of(jacs, res, notes, SIZES, prior=prior)
    fast = np.zeros((6, 2), bool)
    fast[1, 0] = True
    slow = np.zeros((3, 3), bool)
    slow[1, 2] = True
    take = np.array([True])
    d_fast, d_slow, d_take = system.frozen(fast, slow, take).step(0.0)
    assert d_fast[1, 0] == 0.0 and d_slow[1, 2] == 0.0 and d_take[0] == 0.0
    a, g = _dense_normal(dense, res, prior)
    held = np.concatenate([fast.ravel(), slow.ravel(), take])
    free = ~held
    expected = np.linalg.solve(a[np.ix_(free, free)], -g[free])
    got = np.concatenate([d_fast.ravel(), d_slow.ravel(), d_take])[free]
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-12)


def _two_stage_map(jacs, dense, index, given, info: float):
    """The linear two-stage estimator as a matrix on its noise, built densely.

    The noise is every window's samples (unit white) and the prior's pseudo-observation
    (unit, scaled by sqrt(info)); the informing windows and the prior are solved jointly
    for their fast unknowns and the shared ones, then each given window for its own fast
    ones with the shared ones held at that solution. Returns the map (unknowns, noise).
    """
    n, f = jacs[0].shape[0], SIZES.fast
    w = len(jacs)
    shared = np.arange(w * f, dense.shape[1])
    rows = np.concatenate([np.arange(i * n, (i + 1) * n) for i in range(w) if not given[i]])
    cols = np.concatenate([np.arange(i * f, (i + 1) * f) for i in range(w) if not given[i]]
                          + [shared])  # fmt: skip
    design = np.zeros((rows.size + 1, cols.size))
    design[:-1] = dense[np.ix_(rows, cols)]
    design[-1, -1] = np.sqrt(info)  # the prior's row, on T
    noise_rows = np.concatenate([rows, [w * n]])
    stage1 = np.zeros((cols.size, w * n + 1))
    stage1[:, noise_rows] = np.linalg.pinv(design)
    out = np.zeros((dense.shape[1], w * n + 1))
    out[cols] = stage1
    for i in np.flatnonzero(given):
        j_f, j_x = jacs[i][:, :f], jacs[i][:, f:]
        own = np.zeros((n, w * n + 1))
        own[:, i * n : (i + 1) * n] = np.eye(n)
        out[i * f : (i + 1) * f] = np.linalg.pinv(j_f) @ (own - j_x @ out[index[i][f:]])
    return out


def test_a_window_fitted_given_the_shared_unknowns_carries_their_error():
    # the two-stage estimator (an attack's windows fitted given their note's constants):
    # the nested covariance with ``given`` against the dense map of the estimator itself;
    # without ``given`` the given windows' fast variances are those of a joint fit
    jacs, res, _, dense, index = _problem(6)
    notes = (0, 0, 1, 1, 1, 2)
    given = np.array([False, True, False, False, True, False])
    prior = _prior()
    system = dataclasses.replace(TakeSystem.of(jacs, res, notes, SIZES, prior=prior), given=given)
    m = _two_stage_map(jacs, dense, index, given, float(prior[0][0, 0]))
    expected = m @ m.T
    cov = system.covariance(system.grams)  # unit white noise: B_i = J_i^T J_i
    for i, cols in enumerate(index):
        np.testing.assert_allclose(cov.window(i), expected[np.ix_(cols, cols)], rtol=1e-8,
                                   atol=1e-12)  # fmt: skip
    joint = TakeSystem.of(jacs, res, notes, SIZES, prior=prior).covariance(system.grams)
    for i in np.flatnonzero(given):
        assert not np.allclose(np.diag(joint.fast[i]), np.diag(cov.fast[i]), rtol=1e-3)


def test_a_given_windows_step_follows_the_shared_ones():
    # the step of the two-stage problem: the informing windows' and the shared unknowns'
    # from their dense solve, each given window's its own Gauss-Newton step at them
    jacs, res, _, dense, index = _problem(7)
    notes = (0, 0, 1, 1, 1, 2)
    given = np.array([True, False, False, True, False, False])
    prior = _prior()
    system = dataclasses.replace(TakeSystem.of(jacs, res, notes, SIZES, prior=prior), given=given)
    d_fast, d_slow, d_take = system.step(0.0)
    f, w = SIZES.fast, len(notes)
    keep = [i for i in range(w) if not given[i]]
    cols = np.concatenate([index[i][:f] for i in keep] + [np.arange(w * f, dense.shape[1])])
    rows = np.concatenate([np.arange(i * 30, (i + 1) * 30) for i in keep])
    a, g = _dense_normal(dense[rows], [res[i] for i in keep], prior)
    d = np.linalg.solve(a[np.ix_(cols, cols)], -g[cols])
    np.testing.assert_allclose(d[-(3 * 3 + 1) :], np.concatenate([d_slow.ravel(), d_take]),
                               rtol=1e-9, atol=1e-12)  # fmt: skip
    x = np.concatenate([d_slow.ravel(), d_take])
    for i in np.flatnonzero(given):
        j_f, j_x = jacs[i][:, :f], jacs[i][:, f:]
        x_i = x[system.reduced_index(notes[i])]
        own = -np.linalg.solve(j_f.T @ j_f, j_f.T @ (res[i] + j_x @ x_i))
        np.testing.assert_allclose(d_fast[i], own, rtol=1e-9, atol=1e-12)
