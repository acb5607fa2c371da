"""A take's notes pooled: the stretches, and notes left to the per-window fit."""

import numpy as np
import pandas as pd

from mpipe.inversion.pooling.take_pooling import MIN_OK, pool_notes, stretches
from mpipe.inversion.settings import InversionConfig


def test_a_note_is_cut_into_the_fewest_equal_stretches():
    t = np.arange(0.0, 5.0, 0.02)  # a 5 s note
    parts = stretches(t, 2.0)
    assert len(parts) == 3
    assert np.array_equal(np.concatenate(parts), np.arange(t.size))
    sizes = [p.size for p in parts]
    assert max(sizes) - min(sizes) <= 1
    assert [p.size for p in stretches(t[:50], 2.0)] == [50]
    assert stretches(np.array([]), 2.0) == []


def test_a_note_with_too_few_ok_windows_keeps_its_per_window_answers():
    config = InversionConfig(pooling="note")
    n = MIN_OK + 1
    table = pd.DataFrame(
        {
            "window": range(n),
            "t_start_s": 0.02 * np.arange(n),
            "t_end_s": 0.02 * np.arange(1, n + 1),
            "segment": 0,
            "status": ["ok"] * (MIN_OK - 1) + ["high-residual"] * (n - MIN_OK + 1),
            "error": "",
            **{k: 1.0 for k in ("k", "S", "y_m", "p_m", "lam", "m", "g", "k_c", "y_c", "alpha")},
            "relative_residual": 0.01,
            "optimiser_converged": True,
            "at_bound": "",
        }
    )
    out = pool_notes(table, np.zeros(1000), np.zeros(1000), 1e5, None, config, zero_mean=True)
    assert (out["pooled"] == "").all()
    assert np.allclose(out["p_m"], 1.0)


def test_a_pooled_window_reads_the_history_the_window_fit_reads():
    # not the take's whole past p[:s] (3.6x the memory on a two-note take): the lead-in
    # and the bore's taps, as the per-window fit's objective (lead_in)
    from pathlib import Path

    from mpipe.acoustics.reflection import reflection_function
    from mpipe.inversion.fit.history_start import lead_in
    from mpipe.inversion.pooling.take_pooling import _objective
    from mpipe.measurement.calibration import load_calibration
    from mpipe.reed.bore_kernel import prepare_bore
    from mpipe.reed.model import simulate
    from mpipe.reed.parameters import ReedParameters

    fs, n, s = 1e5, 2000, 30000
    cal = load_calibration(Path(__file__).resolve().parents[3] / "calibration"
                           / "simplified_clarinet.yaml")  # fmt: skip
    air = cal.air_properties()
    kernel = prepare_bore(reflection_function(cal.bore, air, fs=fs), air)
    reed = ReedParameters(k=8.66e6, S=7.62e-5, y_m=4e-4, p_m=1800.0, lam=0.013, m=0.05,
                          g=3000.0, k_c=8.23e10)  # fmt: skip
    sim = simulate(reed, kernel, s + n)
    config = InversionConfig(pooling="note")
    row = {"t_start_s": s / fs, **{k: getattr(reed, k) for k in
           ("k", "S", "y_m", "p_m", "lam", "m", "g", "k_c", "y_c", "alpha")}}  # fmt: skip
    names = tuple(config.search_parameters)
    start = np.array([row[k] for k in names])
    obj, _, feasible = _objective(pd.Series(row), start, sim.p, sim.u, fs, kernel, config,
                                  False, names, n)  # fmt: skip
    p_hist, _ = lead_in(sim.p, sim.u, s, n, kernel.n_taps, config.lead_s, fs)
    assert feasible and obj.target.p_history.size == p_hist.size < s
    assert np.array_equal(obj.target.p_history, p_hist)
