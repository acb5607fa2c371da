"""Scores: notes and silences become controls; a bad score is refused in one line."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from mpipe.core.config import ConfigError
from mpipe.reed.controls import play
from mpipe.reed.score import load_score, score_controls, score_from_mapping

ROOT = Path(__file__).resolve().parents[2]

FS = 100_000.0
PHRASE = {
    "end": 0.1,
    "notes": [
        {"duration": 0.25, "p_m": 1800, "tongued": True, "attack": 0.02},
        {"gap": 0.25, "duration": 0.25, "p_m": [[0, 1800], [0.2, 2200]], "y_m": 3.8e-4,
         "release": 0.02, "vibrato": {"rate": 5, "depth": 0.05}},
    ],
}  # fmt: skip


def test_a_score_with_silences_gives_silence_in_p(setup):
    *_, reed, _, kernel = setup
    score = score_from_mapping(PHRASE)
    assert score.duration == pytest.approx(0.85)
    ctl = score_controls(score, reed, FS)
    assert ctl.n_samples == 85_000 and ctl.notes == ((0.03, 0.25), (0.5, 0.75))
    t = ctl.t
    gap = (t >= 0.25) & (t < 0.5)
    assert np.all(ctl.p_m[gap] == 0) and np.all(ctl.p_m[t >= 0.75] == 0)
    # the second note's crescendo, held after its last breakpoint, under its release
    assert ctl.p_m[np.searchsorted(t, 0.5 + 0.2)] == pytest.approx(2200, rel=0.06)
    # y_m: the first note's value through the silence, the second's from its start
    assert ctl.reed["y_m"][np.searchsorted(t, 0.49)] == reed.y_m
    assert ctl.reed["y_m"][np.searchsorted(t, 0.5)] == 3.8e-4
    run = play(reed, kernel, ctl)
    note = np.std(run.p[(t > 0.1) & (t < 0.24)])
    late_gap = np.std(run.p[(t > 0.4) & (t < 0.5)])
    assert late_gap < 0.05 * note, (late_gap, note)
    assert np.std(run.p[(t > 0.6) & (t < 0.74)]) > 0.5 * note
    held = run.tongued
    assert held[np.searchsorted(t, 0.01)] and not held[np.searchsorted(t, 0.031)]


def test_shipped_scores_load(setup):
    *_, reed, _, _ = setup
    for name in ("crescendo", "vibrato", "embouchure", "phrase"):
        score = load_score(ROOT / "examples" / "scores" / f"{name}.yaml")
        ctl = score_controls(score, reed, 10_000.0)
        assert ctl.n_samples == round(score.duration * 1e4)
    phrase = load_score(ROOT / "examples" / "scores" / "phrase.yaml")
    starts = [a for a, _ in phrase.sounding()]
    ends = [b for _, b in phrase.sounding()]
    assert len(starts) == 3 and all(
        a - b == pytest.approx(0.28) for a, b in zip(starts[1:], ends[:-1], strict=True)
    )


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"notes": "x"}, r"s\.yaml: notes: expected a list of notes"),
        ({"notes": []}, r"notes: expected at least one note"),
        ({0: {"p_m": 1800}}, r"notes\[0\]\.duration: missing required key"),
        ({0: {"duration": 0.5, "pm": 1}}, r"notes\[0\]\.pm: unknown key"),
        ({0: {"duration": 0.5, "lam": 0.01}},
         r"notes\[0\]\.lam: unknown key \(did you mean lambda\?"),
        ({0: {"duration": 0.5, "y_m": [[0, 4e-4], [0.1]]}},
         r"notes\[0\]\.y_m\[1\]: expected a pair"),
        ({0: {"duration": 0.5, "p_m": [[0.2, 1800], [0.1, 1900]]}},
         r"notes\[0\]\.p_m: breakpoint times must be"),
        ({0: {"duration": 0.5, "p_m": -3}}, r"notes\[0\]\.p_m: expected a positive"),
        ({0: {"duration": 0.5, "p_m": 1e9}},
         r"notes\[0\]\.p_m: implausible value 1e\+09 Pa; expected a value in \[1, 100000\]"),
        ({0: {"duration": 0.5, "y_m": [[0, 4e-4], [0.2, 0.5]]}},
         r"notes\[0\]\.y_m\[1\]: implausible value 0.5 m"),
        ({0: {"duration": 0.002, "attack": 0, "release": 0}},
         r"notes\[0\]\.duration: 0.002 s sounds for 0.002 s, shorter than 0.03 s"),
        ({0: {"duration": 0.04, "tongued": True}}, r"notes\[0\]\.duration: 0\.04 s leaves"),
        ({0: {"duration": 0.5, "vibrato": {"rate": 500, "depth": 0.1}}},
         r"notes\[0\]\.vibrato\.rate: expected a value in"),
        ({1: {"start": 0.1, "duration": 0.5}}, r"notes\[1\]\.start: 0\.1 s overlaps notes\[0\]"),
        ({1: {"start": 1.0, "gap": 0.1, "duration": 0.5}}, r"notes\[1\]\.gap: give start or"),
    ],
)  # fmt: skip
def test_a_bad_score_is_refused_in_one_line(tmp_path, change, message):
    data = {"notes": [{"duration": 0.5}, {"duration": 0.5}]}
    for key, value in change.items():
        if isinstance(key, int):
            data["notes"][key] = value
        else:
            data[key] = value
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=message) as info:
        load_score(path)
    assert "\n" not in str(info.value)


def test_a_take_shorter_than_its_score_is_refused(setup):
    *_, reed, _, _ = setup
    with pytest.raises(ConfigError, match="shorter than the score"):
        score_controls(score_from_mapping(PHRASE), reed, FS, duration_s=0.5)


def test_a_take_sidecar_score_reads_back_as_a_score():
    # the sidecar's score is keyed as a score file (a reed width `lambda`, not `lam`)
    from mpipe.reed.score import score_mapping

    score = score_from_mapping(
        {"notes": [{"duration": 0.5, "lambda": [[0.0, 0.012], [0.3, 0.014]]}, {"duration": 0.4}]}
    )
    plain = yaml.safe_load(yaml.safe_dump(score_mapping(score)))
    assert "lambda" in plain["notes"][0] and "lam" not in plain["notes"][0]
    assert score_from_mapping(plain) == score
