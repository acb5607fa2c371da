"""Note boundaries under real playing: slurs, glides, quiet notes, breath, tongued gaps, squeaks.

Each take is built from known notes (phase-continuous odd-harmonic tones following a known
f0 curve); the segmentation must find each note within 15 ms of its construction and at its
own f0 within 10 cents, for every seed.
"""

import numpy as np
import pytest
from scipy.signal import butter, sosfilt

from mpipe.inversion.preparation.boundaries import level_envelope, runs
from mpipe.inversion.preparation.segments import segment_take
from mpipe.inversion.settings import ConditioningConfig

FS = 40_000.0
COND = ConditioningConfig()
LOUD = 3000.0  # Pa: a loud note's level in a clarinet's mouthpiece


def voice(f_inst, rms_pa, rng, harmonics=9):
    """Odd-harmonic tone (even ones 30 dB down) following ``f_inst`` (Hz per sample)."""
    phase = 2 * np.pi * np.cumsum(f_inst) / FS
    x = sum((1 / h if h % 2 else 0.03 / h) * np.sin(h * phase + rng.uniform(0, 6.3))
            for h in range(1, harmonics + 1) if h * f_inst.max() < 0.45 * FS)  # fmt: skip
    return x / np.std(x) * rms_pa


def take(notes, seconds, rng, noise_db=-70.0):
    """Notes ``(start s, end s, f0 from, f0 to, glide s, level dB re LOUD)`` over noise.

    A note whose two f0 differ changes at its middle, instantly (glide 0) or along a glide
    of that length centred there; every note has 5 ms raised-cosine ends.
    """
    x = rng.standard_normal(int(seconds * FS)) * LOUD * 10 ** (noise_db / 20)
    for a, b, f_a, f_b, glide, db in notes:
        i0, i1 = int(a * FS), int(b * FS)
        t = np.arange(i1 - i0) / FS - (b - a) / 2
        w = np.clip(t / glide + 0.5, 0, 1) if glide > 0 else (t >= 0).astype(float)
        y = voice(f_a * (f_b / f_a) ** w, LOUD * 10 ** (db / 20), rng)
        r = int(0.005 * FS)
        ramp = 0.5 * (1 - np.cos(np.pi * np.arange(r) / r))
        y[:r] *= ramp
        y[-r:] *= ramp[::-1]
        x[i0:i1] += y
    return x


def breath(n, rms_pa, rng):
    """Breath noise: white noise band-passed to 300-3000 Hz."""
    b = sosfilt(butter(2, (300.0, 3000.0), btype="bandpass", fs=FS, output="sos"),
                rng.standard_normal(n))  # fmt: skip
    return b / np.std(b) * rms_pa


def assert_notes(x, truth, cond=COND):
    """The notes found match ``truth`` [(start, end, f0)] within 15 ms and 10 cents."""
    segs, _ = segment_take(x, FS, cond)
    notes = segs[segs["label"] == "note"]
    found = list(zip(notes["start_s"], notes["end_s"], notes["f0_hz"], strict=True))
    assert len(found) == len(truth), found
    for (a, b, f), (a1, b1, f1) in zip(truth, found, strict=True):
        assert abs(a1 - a) < 0.015 and abs(b1 - b) < 0.015, (truth, found)
        assert abs(1200 * np.log2(f1 / f)) < 10, (truth, found)


@pytest.mark.parametrize("cents", [80, 120])
@pytest.mark.parametrize("seed", range(2))
def test_an_instant_slur_of_a_semitone_splits_at_the_step(cents, seed):
    # 80-120 cents used to make one note with an f0 between the two
    f2 = 200.0 * 2 ** (cents / 1200)
    x = take([(0.1, 0.7, 200.0, f2, 0.0, 0.0)], 0.8, np.random.default_rng(seed))
    assert_notes(x, [(0.1, 0.4, 200.0), (0.4, 0.7, f2)])


@pytest.mark.parametrize("glide", [0.03, 0.05])
def test_a_glided_slur_splits_at_the_glides_middle(glide):
    f2 = 180.0 * 2 ** (200 / 1200)
    x = take([(0.1, 0.7, 180.0, f2, glide, 0.0)], 0.8, np.random.default_rng(3))
    assert_notes(x, [(0.1, 0.4, 180.0), (0.4, 0.7, f2)])


@pytest.mark.parametrize("db", [-30.0, -40.0])
def test_a_note_40_db_below_the_loudest_is_one_note_with_its_own_edges(db):
    rng = np.random.default_rng(4)
    x = take([(0.1, 0.4, 200.0, 200.0, 0, 0.0), (0.6, 0.9, 250.0, 250.0, 0, db)], 1.0, rng)
    assert_notes(x, [(0.1, 0.4, 200.0), (0.6, 0.9, 250.0)])


@pytest.mark.parametrize("seed", range(2))
def test_breath_noise_in_a_gap_is_not_a_note_nor_part_of_one(seed):
    rng = np.random.default_rng(seed)
    x = take([(0.1, 0.4, 200.0, 200.0, 0, 0.0), (0.55, 0.85, 230.0, 230.0, 0, -3.0)], 1.0, rng)
    gap = slice(int(0.4 * FS), int(0.55 * FS))
    x[gap] += breath(x.size, LOUD * 10 ** (-25 / 20), rng)[gap]
    assert_notes(x, [(0.1, 0.4, 200.0), (0.55, 0.85, 230.0)])


def test_a_10_ms_tongued_gap_separates_two_notes():
    x = take([(0.1, 0.4, 200.0, 200.0, 0, 0.0), (0.41, 0.7, 200.0, 200.0, 0, 0.0)], 0.8,
             np.random.default_rng(5))  # fmt: skip
    assert_notes(x, [(0.1, 0.4, 200.0), (0.41, 0.7, 200.0)])
    # the level's 4 ms frame sees the gap well below both notes
    t, level = level_envelope(x, FS, COND.level_frame_s)
    assert level[(t > 0.404) & (t < 0.406)].max() < 0.1 * np.median(level[(t > 0.2) & (t < 0.3)])


def test_a_squeak_at_2400_hz_is_reported_at_its_own_frequency():
    # it used to be reported an octave low (1199 Hz), above the f0 range searched
    x = take([(0.1, 0.6, 200.0, 2400.0, 0.0, 0.0)], 0.7, np.random.default_rng(6))
    assert_notes(x, [(0.1, 0.35, 200.0), (0.35, 0.6, 2400.0)])


def test_runs_gives_first_and_past_the_last():
    assert runs(np.array([0, 1, 1, 0, 1], bool)) == [(1, 3), (4, 5)]
    assert runs(np.zeros(3, bool)) == []


def test_a_slurred_note_20_db_below_both_neighbours_is_kept():
    # a valley that is periodic is a soft note, not a gap: three notes, not two
    rng = np.random.default_rng(5)
    notes = [(0.1, 0.4, 200.0, 200.0, 0, 0.0), (0.4, 0.7, 250.0, 250.0, 0, -20.0),
             (0.7, 1.0, 300.0, 300.0, 0, 0.0)]  # fmt: skip
    x = take(notes, 1.1, rng)
    assert_notes(x, [(0.1, 0.4, 200.0), (0.4, 0.7, 250.0), (0.7, 1.0, 300.0)])


def test_a_subito_piano_keeps_its_soft_part():
    # loud, then 20 dB softer at once at the same pitch and held: the soft part is a note
    # (not the loud note's decay, nor its echo: it does not decay)
    rng = np.random.default_rng(6)
    notes = [(0.1, 0.5, 220.0, 220.0, 0, 0.0), (0.5, 0.9, 220.0, 220.0, 0, -20.0)]
    x = take(notes, 1.0, rng)
    assert_notes(x, [(0.1, 0.5, 220.0), (0.5, 0.9, 220.0)])


def test_a_reverberant_decay_after_a_note_is_still_not_a_note():
    # the same soft sound decaying (exponentially, 20 dB down at the start): an echo
    rng = np.random.default_rng(7)
    x = take([(0.1, 0.5, 220.0, 220.0, 0, 0.0)], 1.0, rng)
    tail = take([(0.5, 0.9, 220.0, 220.0, 0, -20.0)], 1.0, rng)
    t = np.arange(x.size) / FS
    x += tail * np.exp(-np.clip(t - 0.5, 0, None) / 0.05)
    assert_notes(x, [(0.1, 0.5, 220.0)])


def test_each_note_reports_its_blowing_and_its_sounding_onset():
    # the blowing rises over 40 ms (a breath's foot) before the tone sounds: the note's
    # start is the blowing onset, its sounding onset is where the tone reaches its level
    rng = np.random.default_rng(8)
    x = take([(0.2, 0.6, 200.0, 200.0, 0, 0.0)], 0.8, rng)
    foot = slice(int(0.16 * FS), int(0.2 * FS))
    ramp = np.linspace(0, 1, foot.stop - foot.start)
    x[foot] += breath(x.size, LOUD * 10 ** (-12 / 20), rng)[foot] * ramp
    segs, _ = segment_take(x, FS, COND)
    note = segs[segs["label"] == "note"].iloc[0]
    assert abs(note["sounding_onset_s"] - 0.2) < 0.01
    assert note["blowing_onset_s"] <= note["sounding_onset_s"]
    assert note["blowing_onset_s"] == note["start_s"]
    silence = segs[segs["label"] == "silence"]
    assert silence["sounding_onset_s"].isna().all()


@pytest.mark.parametrize("n", [40, 700])
def test_side_medians_equal_a_direct_median_per_frame(n):
    # the Fenwick-tree windows against the direct median of each window (a second method),
    # with unvoiced frames and an uneven frame grid
    from mpipe.inversion.preparation.boundaries import _side_medians

    rng = np.random.default_rng(n)
    times = np.cumsum(rng.uniform(0.003, 0.007, n))
    cents = rng.normal(0, 80, n)
    cents[rng.random(n) < 0.25] = np.nan
    gap, side = 0.03, 0.025
    before, after = _side_medians(times, cents, gap, side)
    for i, t in enumerate(times):
        lo = cents[(times >= t - gap - side) & (times <= t - gap)]
        hi = cents[(times >= t + gap) & (times <= t + gap + side)]
        lo, hi = lo[np.isfinite(lo)], hi[np.isfinite(hi)]
        if lo.size >= 2 and hi.size >= 2:
            assert before[i] == np.median(lo) and after[i] == np.median(hi)
        else:
            assert np.isnan(before[i]) and np.isnan(after[i])
