"""One figure per note: two periods of p and u, measured and resynthesised, with status."""

import numpy as np
import pandas as pd

from mpipe.inversion.output.note_figures import note_figure, plot_notes, plot_overlays

FS = 10_000.0


def test_a_figure_per_note_labelled_with_the_windows_status(tmp_path):
    import matplotlib.pyplot as plt

    n = np.arange(int(0.6 * FS))
    p = 1000.0 * np.sin(2 * np.pi * 100.0 * n / FS)
    u = 4e-5 * np.cos(2 * np.pi * 100.0 * n / FS)
    t0 = np.array([0.1, 0.12, 0.4, 0.42])
    table = pd.DataFrame({
        "window": range(4), "t_start_s": t0, "t_end_s": t0 + 0.03, "segment": [1, 1, 3, 3],
        "error": "", "phase": "sustain", "f0_hz": 100.0, "p_m": 1800.0,
        "relative_residual": [0.01, 0.01, 0.3, 0.2],
        "status": ["ok", "ok", "high-residual", "not-converged"],
        "status_reason": ["", "", "residual 0.3", "the search stopped at its budget"],
    })  # fmt: skip
    segments = pd.DataFrame({
        "segment": [1, 2, 3], "label": ["note", "silence", "note"],
        "start_s": [0.05, 0.3, 0.35], "end_s": [0.3, 0.35, 0.55],
        "note": ["G2 +10 c", "", "G2 +10 c"], "f0_hz": [100.0, np.nan, 100.0],
    })  # fmt: skip
    out = plot_notes(table, segments, (p, u), (0.98 * p, u), FS, tmp_path, "xxxx")
    # whole windows spread over the take: the first and the last with an estimate
    spread = plot_overlays(table.assign(error=["", "", "", "x"]), (p, u), (p, u), FS, 2, tmp_path)
    assert spread == {"overlay_1": "overlay_1.png", "overlay_2": "overlay_2.png"}
    assert (tmp_path / "overlay_2.png").read_bytes()[:4] == b"\x89PNG"
    assert out == {"note_1": "flow_pressure_note_1.png", "note_2": "flow_pressure_note_2.png"}
    assert (tmp_path / out["note_2"]).read_bytes()[:4] == b"\x89PNG"
    # the second note has no ok window: the one with the smaller residual, in red, says why
    row = table.iloc[3]
    fig = note_figure((p[:300], u[:300], p[:300], u[:300]), FS, row, "note 2: G2 +10 c")
    try:
        title = fig._suptitle
        assert "status not-converged (the search stopped at its budget)" in title.get_text()
        assert title.get_color() == "tab:red"
        # two periods of 100 Hz, in ms: the time axis spans 20 ms
        lines = fig.axes[0].get_lines()
        span = np.ptp(lines[0].get_xdata())
        assert 19.0 <= span <= 20.0
    finally:
        plt.close(fig)


def test_a_zero_mean_flow_is_labelled_so_and_a_tapered_edge_is_not_drawn():
    # issue 42: the zero-mean flow was labelled as the flow, and a window's tapered end drew
    # a false branch of u against p towards p = 0
    import matplotlib.pyplot as plt

    n = np.arange(int(0.05 * FS))
    p = 1000.0 * np.sin(2 * np.pi * 100.0 * n / FS)
    taper = np.ones(n.size)
    taper[-200:] = np.linspace(1.0, 0.0, 200)  # the last two periods fade out
    p, u = p * taper, 4e-5 * np.cos(2 * np.pi * 100.0 * n / FS) * taper
    row = pd.Series({"window": 3, "t_start_s": 0.1, "f0_hz": 100.0, "p_m": 1800.0, "status": "ok",
                     "status_reason": "", "relative_residual": 0.01})  # fmt: skip
    fig = note_figure((p, u, p, u), FS, row, "note 1", zero_mean=True)
    try:
        a_p, a_u, a_up = fig.axes[:3]
        # the flow's panels say it is the variation about the mean, the title why
        assert "u − ū" in a_u.get_ylabel() and "zero-mean" in a_up.get_ylabel()
        assert "its mean is not measured" in fig.get_suptitle()
        shown = np.asarray(a_p.lines[0].get_ydata(), dtype=float)
        assert np.ptp(shown[-100:]) > 1900  # the last period shown is at full amplitude
    finally:
        plt.close(fig)
