import numpy as np
import pytest
import yaml

from mpipe.measurement.calibration import load_calibration
from mpipe.measurement.fingerings import harmonic_lines, identify
from tests.measurement.fingering_helpers import (
    FOUR_HOLES,
    first_resonance,
    four_holes,
    theory_note,
)

NAMES = ("xxxx", "xxxo", "xxoo", "xooo", "oooo")


@pytest.mark.parametrize("name", NAMES)
def test_each_fingering_is_found_from_its_harmonics(name):
    # notes made from the theory of the fingering played (the truth), at 40 dB SNR and
    # 25 cents below the resonance, on 3 seeds: all 3 must name the fingering played
    cal = four_holes()
    f0 = first_resonance(cal, name) * 2 ** (-25 / 1200)
    fs = 20000.0
    for seed in range(3):
        p, u = theory_note(cal, name, f0, 0.3, fs, np.random.default_rng(seed), snr_db=40)
        choice = identify(f0, cal, harmonic_lines(p, u, fs, f0))
        assert choice.fingering == name
        assert not choice.ambiguous and choice.probability > 0.99
        assert choice.runner_up in NAMES and choice.runner_up != name


@pytest.mark.parametrize("name", NAMES)
def test_the_playing_frequency_alone_names_the_fingering_at_its_resonance(name):
    cal = four_holes()
    choice = identify(first_resonance(cal, name), cal)
    assert choice.fingering == name and choice.harmonics == 0


def test_two_fingerings_with_the_same_bore_are_flagged_ambiguous(tmp_path):
    # "alt" opens the same holes as "xxoo": no data can tell them apart (p = 1/2 each)
    data = yaml.safe_load(FOUR_HOLES.read_text())
    data["fingerings"]["alt"] = ["h3", "h4"]
    path = tmp_path / "cal.yaml"
    path.write_text(yaml.safe_dump(data))
    cal = load_calibration(path, "auto")
    f0 = first_resonance(cal, "xxoo") * 2 ** (-20 / 1200)
    p, u = theory_note(cal, "xxoo", f0, 0.3, 20000.0, np.random.default_rng(0))
    choice = identify(f0, cal, harmonic_lines(p, u, 20000.0, f0))
    assert {choice.fingering, choice.runner_up} == {"xxoo", "alt"}
    assert choice.ambiguous and abs(choice.probability - 0.5) < 0.01
    assert choice.line().startswith("AMBIGUOUS fingering")


def test_auto_is_the_default_without_a_default_fingering_and_lists_are_checked(tmp_path):
    data = yaml.safe_load(FOUR_HOLES.read_text())
    del data["fingering"]
    path = tmp_path / "cal.yaml"
    path.write_text(yaml.safe_dump(data))
    assert load_calibration(path).fingering == "auto"
    assert load_calibration(path, "xxoo,xooo").fingering == "xxoo,xooo"
    assert load_calibration(path, "xxoo").bore.open_holes == ("h3", "h4")


def test_auto_is_refused_when_the_fingerings_differ_upstream_of_the_microphones(tmp_path):
    # a register hole between the mouthpiece and the reference plane, open in one fingering
    # only: the translation takes one fingering per take, so a per-note setting is refused
    from mpipe.core.config import ConfigError

    data = yaml.safe_load(FOUR_HOLES.read_text())
    data["bore"]["holes"].insert(0, {"name": "reg", "position": 0.15, "radius": 0.0015,
                                     "chimney": 0.012})  # fmt: skip
    data["fingerings"]["rxxxx"] = ["reg"]
    path = tmp_path / "cal.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match="reg lie between the mouthpiece and the reference"):
        load_calibration(path, "auto")
    assert load_calibration(path, "xxxx,xxoo").fingering == "xxxx,xxoo"  # they agree there
    assert load_calibration(path, "rxxxx").bore.open_holes == ("reg",)
