"""The prior's conflict and pull against a direct least-squares fit of a linear take."""

import numpy as np
import pandas as pd
import pytest

from mpipe.inversion.pooling.take_system import TakeSystem, TierSizes
from mpipe.inversion.whole_take.prior_conflict import PriorMoves, prior_conflict, prior_figures

SIZES = TierSizes(2, 2, 1)
NOTES = [0, 0, 0, 1, 1, 1]


def _design(jacobians, notes):
    """The global design matrix over (every window's fast, every note's slow, T)."""
    w, n = len(notes), max(notes) + 1
    f, s = SIZES.fast, SIZES.slow
    rows = []
    for i, (j, note) in enumerate(zip(jacobians, notes, strict=True)):
        a = np.zeros((len(j), w * f + n * s + 1))
        a[:, i * f : (i + 1) * f] = j[:, :f]
        a[:, w * f + note * s : w * f + (note + 1) * s] = j[:, f : f + s]
        a[:, -1] = j[:, -1]
        rows.append(a)
    return np.vstack(rows)


def _take(seed, t_true=20.0, prior_offset=0.0, se=0.3, noise=1.0):
    """A linear take: its data, its fit with the prior, its fit without and the system."""
    rng = np.random.default_rng(seed)
    jacobians = [rng.standard_normal((30, 5)) * [1, 1, 1, 1, 0.3] for _ in NOTES]
    a = _design(jacobians, NOTES)
    truth = np.concatenate([rng.normal(0, 1, a.shape[1] - 1), [t_true]])
    y = a @ truth + rng.normal(0.0, noise, a.shape[0])
    t_prior = t_true + prior_offset + float(rng.normal(0.0, se))
    with_prior = np.vstack([a, np.eye(a.shape[1])[-1:] / se])
    fit = np.linalg.lstsq(with_prior, np.concatenate([y, [t_prior / se]]), rcond=None)[0]
    alone = np.linalg.lstsq(a, y, rcond=None)[0]
    r = (a @ fit - y).reshape(len(NOTES), -1)
    b = 1.0 / se**2
    prior = (np.array([[b]]), np.array([b * (fit[-1] - t_prior)]))
    system = TakeSystem.of(jacobians, list(r), NOTES, SIZES, prior=prior)
    return fit, alone, system, (t_prior, se)


@pytest.mark.parametrize("seed", range(4))
def test_the_move_without_the_prior_is_the_data_alone_fit(seed):
    fit, alone, system, prior = _take(seed, prior_offset=2.0)
    c = prior_conflict(system, float(fit[-1]), prior)
    w, f = len(NOTES), SIZES.fast
    assert c.shift_c == pytest.approx(alone[-1] - fit[-1], rel=1e-8)
    np.testing.assert_allclose(c.fast.ravel(), (alone - fit)[: w * f], rtol=1e-7, atol=1e-10)
    np.testing.assert_allclose(c.slow.ravel(), (alone - fit)[w * f : -1], rtol=1e-7, atol=1e-10)


def test_the_conflict_is_a_standard_normal_deviate_when_prior_and_data_agree():
    z = np.array([prior_conflict(s, float(fit[-1]), p).z
                  for fit, _, s, p in (_take(seed) for seed in range(300))])  # fmt: skip
    assert abs(z.mean()) < 0.2  # 300 draws: SE of the mean 0.058
    assert 0.88 < z.std() < 1.12  # SE of the SD about 0.041
    # a prior 10 of its SEs off is a conflict in every seed
    far = [prior_conflict(s, float(fit[-1]), p).z for fit, _, s, p in
           (_take(seed, prior_offset=3.0) for seed in range(5))]  # fmt: skip
    assert all(abs(v) > 3.29 for v in far)


def test_a_prior_the_data_do_not_inform_has_no_conflict():
    fit, _, system, prior = _take(0)
    blind = TakeSystem(system.sizes, system.notes, system.grams * _no_t(), system.gradients,
                       system.prior_information, system.prior_gradient)  # fmt: skip
    c = prior_conflict(blind, float(fit[-1]), prior)
    assert np.isnan(c.z) and c.shift_c == 0.0


def _no_t():
    mask = np.ones((5, 5))
    mask[-1, :] = mask[:, -1] = 0.0
    return mask


def test_the_pull_is_measured_against_the_tables_combined_error_bars():
    moves = pd.DataFrame({"t_start_s": [0.0, 0.02], "k": [0.02, 0.001], "p_M": [0.0, 0.0]})
    result = PriorMoves(z=5.0, shift_c=-1.0, prior=(23.0, 0.05), t_c=22.5, moves=moves)
    columns = {"t_start_s": [0.02, 0.0, 0.04], "note_number": [1, 1, 1], "k": [1e7] * 3,
               "p_M": [3000.0] * 3, "p_M_se": [30.0] * 3}  # fmt: skip
    table = pd.DataFrame(columns)
    # k's 2 % move against a 1 % bar is 2 SE; against a 4 % bar it is half of one
    figures = prior_figures(table.assign(k_se=1e5), result)
    assert figures["largest_pull_se"] == pytest.approx(2.0)
    assert figures["largest_pull"] == "k in the window at 0.000 s (note 1)"
    assert figures["t_without_c"] == pytest.approx(21.5) and figures["z"] == 5.0
    assert prior_figures(table.assign(k_se=4e5), result)["largest_pull_se"] == pytest.approx(0.5)
    assert prior_figures(table, None) == {}
