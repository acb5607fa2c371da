"""The take fit's cold starts and the choice between their runs (take_fit.py)."""

from types import SimpleNamespace

import numpy as np
import pytest

from mpipe.inversion.whole_take.cold_starts import cold_windows
from mpipe.inversion.whole_take.rivals import rival_costs
from mpipe.inversion.whole_take.take_fit import THIN, THIN_MIN, thinned


def _problem(start: int, amplitude: float):
    t = np.arange(200) / 1.0e4
    return SimpleNamespace(start=start, target=SimpleNamespace(p=amplitude * np.sin(2e3 * t)))


def _run(starts, rr, weight, t, prior=(20.0, 0.5), given=()):
    problems = tuple(SimpleNamespace(start=s, informs=s not in given) for s in starts)
    return SimpleNamespace(take=SimpleNamespace(problems=problems, prior=prior),
                           blocks=SimpleNamespace(rr=np.asarray(rr, float)), weight=weight,
                           state=SimpleNamespace(t=t))  # fmt: skip


def test_cold_windows_are_the_first_the_loudest_and_the_middle_steady_window():
    problems = [_problem(100 * i, a) for i, a in enumerate([900.0, 1000.0, 3000.0, 2000.0])]
    assert cold_windows(problems, [False, True, False, True]) == [1, 3]
    assert cold_windows(problems, [True, True, True, True]) == [0, 2]  # the middle is loudest
    # the first steady window is the loudest and the middle: one cold start
    assert cold_windows(problems, [False, False, True, False]) == [2]
    five = [_problem(100 * i, a) for i, a in enumerate([900.0, 1000.0, 1100.0, 3000.0, 2000.0])]
    assert cold_windows(five, [True] * 5) == [0, 3, 2]


def test_rival_costs_compare_on_the_first_runs_weight_and_the_windows_both_kept():
    first = _run([0, 10, 20], [4.0, 1.0, 1.0], weight=2.0, t=20.5)
    # the second run left out window 10 and weighs its own windows differently
    second = _run([0, 20], [2.0, 1.0], weight=7.0, t=20.0)
    costs = rival_costs([first, second])
    # windows 0 and 20 only, at the first run's weight, plus the prior's term
    assert costs == pytest.approx([2.0 * (4.0 + 1.0) + 1.0, 2.0 * (2.0 + 1.0) + 0.0])
    assert int(np.argmin(costs)) == 1
    # a window fitted given the shared unknowns is in neither run's cost
    first = _run([0, 10, 20], [4.0, 1.0, 1.0], weight=2.0, t=20.5, given=(0,))
    second = _run([0, 20], [2.0, 1.0], weight=7.0, t=20.0, given=(0,))
    assert rival_costs([first, second]) == pytest.approx([2.0 * 1.0 + 1.0, 2.0 * 1.0 + 0.0])


def test_the_thinned_take_keeps_every_note_and_every_thin_th_window_of_a_long_one():
    notes = [0] * 40 + [1] * 3 + [2] * 9
    problems = [SimpleNamespace(note=n) for n in notes]
    kept = thinned(problems)
    by_note = {n: [i for i in kept if notes[i] == n] for n in (0, 1, 2)}
    assert by_note[0] == list(range(0, 40, THIN))  # a long note: every THIN-th window
    assert by_note[1] == [40, 41, 42]  # a note shorter than THIN_MIN: all of it
    # a note too short for THIN_MIN windows at every THIN-th: THIN_MIN spread over it
    assert len(by_note[2]) == THIN_MIN and by_note[2][0] == 43 and by_note[2][-1] == 51
    assert kept == sorted(kept) and len(set(kept)) == len(kept)


def test_a_chains_first_window_keeps_the_lower_of_its_two_minima():
    # window 0 (a note's onset) has two basins: x = 1 (sum of squares 1.0), where its only
    # start leads, and x = 3 (0.1), where its successor's controls lead; the later windows
    # have one basin each. Warmed forward alone, window 0 stays at 1; fitted again from
    # window 1's controls it takes 3. A second chain whose first window's own minimum is
    # the lower (0.2 against 0.5 from its successor's controls) keeps it.
    from mpipe.inversion.whole_take.take_shards import Shard

    def fast_fit(i, x0, slow):
        x0 = float(np.ravel(x0)[0])
        if i == 0:
            return (np.array([1.0]), 1.0) if x0 < 2 else (np.array([3.0]), 0.1)
        if i == 2:
            return (np.array([4.5]), 0.5) if x0 > 3.5 else (np.array([3.5]), 0.2)
        return np.array([3.0 + 1.5 * (i == 3)]), 0.2

    shard = SimpleNamespace(problems=[None] * 4, fast_fit=fast_fit)
    out = Shard.warm(shard, [[0, 1], [2, 3]], [[np.array([1.0])], [np.array([3.0])]],
                     [None, None])  # fmt: skip
    assert [float(x[0][0]) for x in out] == [3.0, 3.0, 3.5, 4.5]
    assert [x[1] for x in out] == [0.1, 0.2, 0.2, 0.2]


def _noise_free_fit(tmp_path, score_text: str):
    """The take fit of the model's own noise-free tone (true mouthpiece p and u, full band).

    Returns ``(plan, done, true)``: the conditioning's plan, the inversion and the true k,
    S, lambda.
    """
    import dataclasses

    from mpipe.cli.examples import EXAMPLE_CALIBRATION, EXAMPLE_REED
    from mpipe.cli.virtual_takes import SynthOptions, make_take
    from mpipe.inversion.preparation.conditioning import plan_inversion
    from mpipe.inversion.settings import ConditioningConfig, ExecutorConfig, InversionConfig
    from mpipe.inversion.whole_take.take import invert_take
    from mpipe.measurement.calibration import load_calibration

    score = tmp_path / "score.yaml"
    score.write_text(score_text)
    files = make_take(EXAMPLE_CALIBRATION, EXAMPLE_REED, tmp_path / "take.flac",
                      SynthOptions(duration_s=None, seed=1, score=str(score)))  # fmt: skip
    with np.load(files.truth) as d:
        p, u, fs = d["p"], d["u"], float(d["fs"])
        true = {k: float(d[f"reed_{k}"]) for k in ("k", "S", "lambda")}
    cal = load_calibration(files.calibration)
    config = dataclasses.replace(InversionConfig(), sample_rate=fs, contact="fixed",
                                 estimator="take")  # fmt: skip
    plan = plan_inversion(p, fs, ConditioningConfig(), config.window_s, config.hop_s)
    done = invert_take(p, u, fs, cal, config, ExecutorConfig(workers=1), windows=plan,
                       temperature_c=20.0)  # fmt: skip
    return plan, done, true


def _at_the_truth(done, true) -> None:
    t = done.tracking.table
    assert abs(done.temperature.temperature_c - 20.0) < 0.005
    for q, name in (("k", "k"), ("S", "S"), ("lam", "lambda")):
        assert float(np.median(t[q])) == pytest.approx(true[name], rel=1e-3), q


def test_a_releases_windows_are_fitted_given_the_notes_constants(tmp_path):
    # the window model is exact at the true reed, but over the release (p_m falling within
    # a window, which the model holds) it cannot fit; those windows must not pull the note's
    # constants and T. On this 0.6 s tone with them informing: T -0.138 degC, k +1.5 %,
    # S -2.3 %, lambda -2.3 %; fitted given them, the truth to 1e-5 (on a 2.25 s tone:
    # T -0.051 degC, S -1.02 % against 0.001 %).
    from mpipe.inversion.whole_take.tracking import WindowPlan

    plan, done, true = _noise_free_fit(
        tmp_path, "description: tone\nend: 0.05\nnotes:\n  - duration: 0.6\n"
        "    attack: 0.01\n    release: 0.03\n    p_m: [[0.0, 2100.0]]\n")  # fmt: skip
    assert not all(WindowPlan.of(plan).steady)  # the release's windows are there
    t = done.tracking.table
    assert bool(t["optimiser_converged"].all())  # both stages ended by their tolerance
    # the table says which windows informed the note: all but its build-up's (before its
    # first steady window) and its release's
    windows = WindowPlan.of(plan)
    phases = [str(x) for x in windows.phases]
    first_steady = list(windows.steady).index(True)
    assert "release" in phases
    assert list(t["informs_note"]) == [x != "release" and i >= first_steady
                                       for i, x in enumerate(phases)]  # fmt: skip
    _at_the_truth(done, true)


def test_a_tongued_notes_build_up_is_fitted_given_its_constants(tmp_path):
    # after a tongued attack the sound builds up over 0.1-0.2 s (the steadiness test calls
    # those windows transient: their level grows by more than 2 % a window) while the mean
    # flow rises from nothing, which the front end's high-passed flow cannot carry
    # (take_fit._informs): those windows are fitted given the note, the transient windows
    # after its first steady one inform, and the fit of the model's own noise-free signals
    # (where the build-up is exact too) stays at the truth without them
    from mpipe.inversion.whole_take.tracking import WindowPlan

    plan, done, true = _noise_free_fit(
        tmp_path, "description: tongued\nend: 0.05\nnotes:\n  - gap: 0.05\n"
        "    duration: 0.5\n    tongued: true\n    tongue_hold: 0.03\n"
        "    attack: 0.02\n    release: 0.03\n    p_m: 1800.0\n")  # fmt: skip
    windows = WindowPlan.of(plan)
    t = done.tracking.table
    first_steady = list(windows.steady).index(True)
    assert first_steady >= 3  # the build-up is there
    assert not t["informs_note"].iloc[:first_steady].any()
    later = [i for i, x in enumerate(windows.phases) if i >= first_steady and x != "release"]
    assert bool(t["informs_note"].iloc[later].all())
    _at_the_truth(done, true)


def test_a_window_far_above_its_notes_sum_of_squares_no_longer_informs_it():
    # misfit_windows: per note, the informing windows whose F2 lies above max(3 x median,
    # median + 5 MAD) of the note's; a note of fewer than MIN_NOTE informing windows and a
    # window already fitted given its note are not judged. Noise alone (F2 within a few
    # per cent of each other, 40 windows, 5 seeds) never leaves a window out
    from types import SimpleNamespace as Q

    from mpipe.inversion.whole_take.take_fit import misfit_windows

    problems = [Q(note=0, informs=True) for _ in range(10)] + [Q(note=1, informs=True)] * 3
    problems[4] = Q(note=0, informs=False)  # a release: not judged
    f2 = np.ones(13)
    f2[[2, 4, 11]] = 48.0  # the slur's window, a release far off, a short note's window
    assert misfit_windows(problems, f2**2, 3.0) == [2]
    for seed in range(5):
        rr = (1.0 + 0.03 * np.random.default_rng(seed).standard_normal(40)) ** 2
        assert misfit_windows([Q(note=0, informs=True)] * 40, rr, 3.0) == []
