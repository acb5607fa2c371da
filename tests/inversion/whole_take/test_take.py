"""A whole take's inversion (mpipe.invert_take) by the per-window estimator.

Model output played at 20 degC, inverted with a calibration that says 21.5 degC and carries
no temperature of its own: the paper's per-window fit inverts at the calibration's and
carries its error (the take's one fit finds the playing's: test_estimator.py).
"""

import dataclasses
import math

import numpy as np
import pandas as pd
import pytest

from mpipe.inversion.preparation.kernel import bore_kernel
from mpipe.inversion.settings import ExecutorConfig, InversionConfig
from mpipe.inversion.whole_take.take import invert_take
from mpipe.reed.model import simulate
from mpipe.reed.parameters import ReedParameters

FS = 100_000.0
TABLE1 = ReedParameters(
    k=8.66e6, S=7.62e-5, y_m=4e-4, p_m=1800.0, lam=0.013, m=0.05, g=3000.0, k_c=8.23e10
)
STARTS = [26000, 30000, 34000]
#: The per-window estimator (the paper's method, at the temperature it is given): the take's
#: one fit is tests/inversion/whole_take/test_estimator.py
CONFIG = InversionConfig(estimator="window")


@pytest.fixture(scope="module")
def played(shipped_calibration):
    kernel, _ = bore_kernel(shipped_calibration, FS, 20.0)
    sim = simulate(TABLE1, kernel, 36000 + 2000)
    rng = np.random.default_rng(3)  # 60 dB of white noise on both signals
    p = sim.p + 1e-3 * np.std(sim.p) * rng.standard_normal(sim.p.size)
    u = sim.u + 1e-3 * np.std(sim.u) * rng.standard_normal(sim.u.size)
    air = dataclasses.replace(shipped_calibration.air, temperature_c=21.5)
    warm_cal = dataclasses.replace(shipped_calibration, air=air)
    return p, u, warm_cal


def _run(played, config):
    p, u, cal = played
    return invert_take(p, u, FS, cal, config, ExecutorConfig(workers=1), windows=STARTS)


def test_the_per_window_fit_at_the_calibrations_temperature_carries_its_error(played):
    # the paper's per-window fit (estimator: window) inverts at the temperature it is given:
    # the calibration's 21.5 degC, 1.5 degC off the playing's (the take's one fit finds
    # the playing's: tests/inversion/whole_take/test_estimator.py)
    done = _run(played, CONFIG)
    fit, table = done.temperature, done.tracking.table
    assert fit.source == "calibration" and fit.temperature_c == 21.5 and math.isnan(fit.se_c)
    # a bore 0.26 % too fast: S is off by far more than the take's fit's few per cent
    assert abs(np.median(table["S"]) / TABLE1.S - 1) > 0.2


def test_two_workers_give_the_same_take(played):
    # the notes' cold starts (design points, short local searches) and the windows run on 2
    # worker processes: every column but the timing is that of 1 worker
    from mpipe.inversion.table.tables import COLUMNS

    p, u, cal = played
    one = _run(played, CONFIG)
    two = invert_take(p, u, FS, cal, CONFIG, ExecutorConfig(workers=2), windows=STARTS)
    assert two.temperature.temperature_c == one.temperature.temperature_c
    same = [c for c in COLUMNS if c != "wall_time_s"]
    pd.testing.assert_frame_equal(one.tracking.table[same], two.tracking.table[same])


def test_the_takes_agreement_is_its_least_agreed_notes_own_cold_start():
    # two notes cold-started (warm False): agreement 6 and 1; a warm window's record (0
    # here) does not count
    from mpipe.inversion.whole_take.take import _first_agreeing

    table = pd.DataFrame({
        "warm": [False, True, True, False, True],
        "cold_starts_agreeing": [6.0, np.nan, 0.0, 1.0, np.nan],
    })  # fmt: skip
    assert _first_agreeing(table) == 1
    assert _first_agreeing(table.iloc[:3]) == 6  # one note: its own cold start
    assert _first_agreeing(table.drop(columns="cold_starts_agreeing")) is None


def test_trackings_of_two_fingerings_merge_in_time_order():
    # each fingering's windows are tracked apart and numbered from 0; merged, the windows
    # are in time order, renumbered, and histories and correlations follow their window
    from mpipe.inversion.whole_take.take import merge_trackings
    from mpipe.inversion.whole_take.tracking import Tracking

    def part(starts, name):
        table = pd.DataFrame({"window": range(len(starts)), "t_start_s": starts,
                              "fingering": name})  # fmt: skip
        corr = table[["window", "t_start_s"]].assign(parameter_a="k", parameter_b="S",
                                                     correlation=0.5)  # fmt: skip
        return Tracking(table, {i: [s] for i, s in enumerate(starts)}, True, corr)

    merged = merge_trackings([part([0.0, 0.04], "xxxx"), part([0.02, 0.06], "xxoo")])
    assert list(merged.table["t_start_s"]) == [0.0, 0.02, 0.04, 0.06]
    assert list(merged.table["window"]) == [0, 1, 2, 3]
    assert list(merged.table["fingering"]) == ["xxxx", "xxoo", "xxxx", "xxoo"]
    assert {w: h[0] for w, h in merged.histories.items()} == {0: 0.0, 1: 0.02, 2: 0.04, 3: 0.06}
    assert list(merged.correlations["window"]) == [0, 1, 2, 3]


def test_a_take_on_disk_gives_the_table_of_the_take_in_memory(played, tmp_path):
    # the signals on disk are read by windows and lead-ins only: the same numbers
    from mpipe.core.signals import DiskArray, NpzStream, open_npz

    p, u, cal = played
    with NpzStream(tmp_path / "mp.npz") as out:
        out.add("p", p)
        out.add("u", u)
    disk = open_npz(tmp_path / "mp.npz", lazy_bytes=0)
    assert isinstance(disk["p"], DiskArray)
    args = (FS, cal, CONFIG, ExecutorConfig(workers=1))
    starts = STARTS[2:]
    whole = invert_take(p, u, *args, windows=starts).tracking.table
    streamed = invert_take(disk["p"], disk["u"], *args, windows=starts).tracking.table
    timing = ["wall_time_s"]  # the only column that may differ: the clock
    pd.testing.assert_frame_equal(streamed.drop(columns=timing), whole.drop(columns=timing))
