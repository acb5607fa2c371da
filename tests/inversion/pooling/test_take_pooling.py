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
