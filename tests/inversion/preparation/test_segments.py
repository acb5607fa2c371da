"""Segments of a take: notes, silences, a legato change and a squeak, found from p alone."""

import numpy as np
import pandas as pd
import pytest

from mpipe.inversion.preparation.conditioning import plan_take
from mpipe.inversion.preparation.segments import segment_take, spl_db, with_played
from mpipe.inversion.settings import ConditioningConfig
from mpipe.inversion.trust.notes import segment_summary

FS = 50_000.0
COND = ConditioningConfig()


def tone(f0, seconds, level_pa, rng, vibrato=0.0, tremolo=0.0):
    """Odd-harmonic tone (even harmonics 30 dB down), 10 ms raised-cosine ends.

    A 5 Hz vibrato (relative f0 swing) and tremolo (relative amplitude swing).
    """
    t = np.arange(int(seconds * FS)) / FS
    phase = 2 * np.pi * f0 * (t - vibrato / (2 * np.pi * 5.0) * np.cos(2 * np.pi * 5.0 * t))
    x = sum((1 / h if h % 2 else 0.03 / h) * np.sin(h * phase + rng.uniform(0, 6.3))
            for h in range(1, 10))  # fmt: skip
    x *= level_pa / np.std(x) * (1 + tremolo * np.sin(2 * np.pi * 5.0 * t))
    ramp = int(0.01 * FS)
    x[:ramp] *= 0.5 * (1 - np.cos(np.pi * np.arange(ramp) / ramp))
    x[-ramp:] *= 0.5 * (1 + np.cos(np.pi * np.arange(ramp) / ramp))
    return x


def phrase(seed):
    """A phrase and the true (start, end, f0) of its notes and pieces.

    0.1 s silence, D3 0.4 s (vibrato, tremolo), 0.25 s silence, E3 0.3 s then legato F#3
    0.3 s, 0.25 s silence, G3 0.3 s squeaking to its fifth harmonic for 0.1 s, 0.2 s
    silence.
    """
    rng = np.random.default_rng(seed)
    z = lambda s: np.zeros(int(s * FS))  # noqa: E731
    parts = [z(0.1), tone(146.8, 0.4, 800, rng, 0.003, 0.08), z(0.25)]
    e3 = tone(164.8, 0.3, 900, rng)
    fs3 = tone(185.0, 0.3, 900, rng)
    parts += [np.concatenate([e3[:-500], fs3[500:]]), z(0.25)]
    g3 = tone(196.0, 0.3, 700, rng)
    squeak = tone(5 * 196.0, 0.1, 700, rng)
    parts += [np.concatenate([g3, squeak]), z(0.2)]
    x = np.concatenate(parts)
    x += rng.standard_normal(x.size) * 800 * 10 ** (-45 / 20)
    truth = [(0.1, 0.5, 146.8), (0.75, 1.04, 164.8), (1.04, 1.33, 185.0), (1.58, 1.88, 196.0),
             (1.88, 1.98, 980.0)]  # fmt: skip
    return x, truth


@pytest.mark.parametrize("seed", range(4))
def test_notes_silences_legato_and_a_squeak(seed):
    # every seed: five sounding segments at the true pitches (within 10 cents), boundaries
    # within 15 ms, silences between; the vibrato and tremolo do not split the first note
    x, truth = phrase(seed)
    segs, _ = segment_take(x, FS, COND, resonances_hz=[170.0, 510.0, 850.0, 1190.0])
    notes = segs[segs["label"] == "note"].reset_index(drop=True)
    assert len(notes) == len(truth), notes
    for (a, b, f), (_, row) in zip(truth, notes.iterrows(), strict=True):
        assert abs(row["start_s"] - a) < 0.015 and abs(row["end_s"] - b) < 0.015, (a, b, row)
        assert abs(1200 * np.log2(row["f0_hz"] / f)) < 10
    assert list(notes["regime"]) == ["fundamental"] * 4 + ["squeak"]
    # the segments tile the take, silences and notes alternate around the phrase
    assert segs["start_s"].iloc[0] == 0.0 and segs["end_s"].iloc[-1] == pytest.approx(x.size / FS)
    np.testing.assert_allclose(segs["start_s"].iloc[1:], segs["end_s"].iloc[:-1])
    assert list(segs["label"].iloc[[0, 2, 3, 5]]) == ["silence", "silence", "note", "silence"]


def test_plan_inverts_no_window_in_a_silence_and_waits_for_the_onset():
    x, truth = phrase(0)
    plan, segs = plan_take(x, FS, COND, 0.02, 0.02)
    inverted = plan[plan["invert"]]
    assert len(inverted) > 0.8 * sum(b - a for a, b, _ in truth) / 0.02 - 12
    for _, w in inverted.iterrows():
        inside = [(a, b, f) for a, b, f in truth if a <= w.t_start_s and w.t_end_s <= b + 0.01]
        assert inside, w  # inside a true note
        a, _, f = inside[0]
        assert w.t_start_s >= a + 2 / f - 0.01  # after the first two periods (with slack)
    assert (plan.loc[plan["phase"] == "silence", "invert"] == False).all()  # noqa: E712
    assert set(plan["phase"]) == {"silence", "onset", "sustain", "release"}
    # the first note's phases: onset within 50 ms of its start, release in its last 30 ms
    first = plan[plan["segment"] == 1]
    assert (first.loc[first["phase"] == "onset", "t_start_s"] < 0.1 + 0.05 + 0.01).all()
    assert (first.loc[first["phase"] == "release", "t_end_s"] > 0.5 - 0.03 - 0.015).all()


def test_a_saved_segmentation_plans_the_windows_as_a_fresh_one(tmp_path):
    # mpipe run segments a take once (validation) and plans from the file (conditioning):
    # the file gives back the table and tracks exactly, and the plan made from it is the
    # plan segment_take itself gives
    from mpipe.inversion.preparation.segments import load_segmentation, save_segmentation

    x, _ = phrase(1)
    resonances = [170.0, 510.0, 850.0, 1190.0]
    segs, tracks = segment_take(x, FS, COND, resonances)
    back_segs, back_tracks = load_segmentation(save_segmentation(tmp_path / "s.npz", segs, tracks))
    pd.testing.assert_frame_equal(back_segs, segs)
    assert set(back_tracks) == set(tracks)
    for k, v in tracks.items():
        np.testing.assert_array_equal(back_tracks[k], v)
    fresh = plan_take(x, FS, COND, 0.02, 0.02, resonances_hz=resonances)
    read = plan_take(x, FS, COND, 0.02, 0.02, segmentation=(back_segs, back_tracks))
    pd.testing.assert_frame_equal(read[0], fresh[0])
    pd.testing.assert_frame_equal(read[1], fresh[1])


def test_the_segments_figure_is_drawn(tmp_path):
    from mpipe.inversion.preparation.segments import plot_segments

    x, _ = phrase(2)
    tracks: dict = {}
    _, segs = plan_take(x, FS, COND, 0.02, 0.02, tracks_out=tracks)
    assert set(tracks) == {"t_level_s", "level_pa", "t_f0_s", "f0_hz", "threshold_pa", "frame_s"}
    assert plot_segments(segs, tracks, tmp_path / "s.png").stat().st_size > 10_000


def test_a_note_is_labelled_with_its_f0_in_hz():
    from mpipe.inversion.preparation.segments import note_label

    x, _ = phrase(2)
    _, segs = plan_take(x, FS, COND, 0.02, 0.02)
    notes = segs[segs["label"] == "note"]
    for _, row in notes.iterrows():
        label = note_label(row)
        # the label's Hz is the note's measured f0, and its name that f0's
        assert label.endswith(f"{row['f0_hz']:.1f} Hz") and row["note"] in label
    # the number is the note's in the take (notes only), not its segment id
    assert notes["note_number"].tolist() == list(range(1, len(notes) + 1))
    silent = {"segment": 3, "note_number": 2, "note": "", "f0_hz": float("nan")}
    assert note_label(silent) == "2: "


def test_steady_selection_keeps_the_papers_rule():
    x, _ = phrase(1)
    cond = ConditioningConfig(select="steady")
    plan, _ = plan_take(x, FS, cond, 0.02, 0.02)
    assert (plan["invert"] == plan["steady"]).all()


def test_segment_summary_gives_each_note_its_own_median():
    segs = pd.DataFrame({"segment": [0, 1, 2], "label": ["note", "silence", "note"]})
    table = pd.DataFrame({
        "segment": [0, 0, 0, 0, 2, 2, 2],
        "status": ["ok", "ok", "ok", "at-bound", "ok", "ok", "ok"],
        "p_m": [1000.0, 1010.0, 990.0, 5000.0, 2000.0, 2020.0, 1980.0],
        "p_m_se": [5.0] * 7,
    })  # fmt: skip
    out = segment_summary(segs, table)
    assert list(out["p_m_median"].iloc[[0, 2]]) == [1000.0, 2000.0]
    assert np.isnan(out["p_m_median"].iloc[1]) and out["windows"].iloc[1] == 0
    assert list(out["ok_windows"]) == [3, 0, 3]
    assert out["p_m_window_se"].iloc[0] == 5.0
    # 3 windows are too few for their scatter: the windows' own SE over sqrt(n)
    assert out["p_m_se"].iloc[0] == pytest.approx(5.0 / np.sqrt(3))


def test_played_columns_join_by_window_start():
    plan = pd.DataFrame({"t_start_s": [0.1, 0.12], "phase": ["onset", "sustain"],
                         "f0_hz": [147.0, 147.5], "rms_pa": [200.0, 2e-5]})  # fmt: skip
    table = pd.DataFrame({"t_start_s": [0.12], "k": [1.0]})
    out = with_played(table, plan)
    assert out["phase"].tolist() == ["sustain"] and out["f0_hz"].tolist() == [147.5]
    assert spl_db(20e-6) == 0.0 and spl_db(2.0) == pytest.approx(100.0)


def test_segments_figure_labels_do_not_overlap_and_the_pitch_axis_fits_the_notes():
    # issue 42: labels of close notes overlapped, and a linear f0 axis up to 1200 Hz
    # flattened notes at 100-200 Hz
    import matplotlib.pyplot as plt

    from mpipe.inversion.preparation.segments import segments_figure

    x, _ = phrase(0)
    _, segs = plan_take(x, FS, COND, 0.02, 0.02)
    tracks = segment_take(x, FS, COND)[1]
    # crowd them: six notes 0.08 s apart (each label is wider than that on the figure)
    start = 0.1 + 0.08 * np.arange(6)
    crowded = pd.DataFrame({
        "segment": range(6), "note_number": range(1, 7), "label": "note", "start_s": start,
        "end_s": start + 0.08, "note": "D3 +0 c", "f0_hz": [146.8, 164.8, 185.0, 196.0, 150, 160],
    })  # fmt: skip
    for table in (segs, crowded):
        fig = segments_figure(table, tracks)
        try:
            ax_p = fig.axes[1]
            renderer = fig.canvas.get_renderer()
            boxes = [t.get_window_extent(renderer) for t in ax_p.texts]
            assert len(boxes) == int((table["label"] == "note").sum())
            assert not any(a.overlaps(b) for i, a in enumerate(boxes) for b in boxes[:i])
            f0 = table.loc[table["label"] == "note", "f0_hz"].to_numpy(float)
            lo, hi = ax_p.get_ylim()
            assert ax_p.get_yscale() == "log"
            assert lo < np.nanmin(f0) and np.nanmax(f0) < hi < 1.5 * np.nanmax(f0)
        finally:
            plt.close(fig)
