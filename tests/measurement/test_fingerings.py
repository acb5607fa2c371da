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


def test_two_fingerings_with_the_same_bore_are_one_answer_not_an_ambiguity(tmp_path):
    # "alt" opens the same holes as "xxoo": no data can tell them apart, so they are one
    # answer (the first listed names it, the other is its equivalent), not a coin toss
    data = yaml.safe_load(FOUR_HOLES.read_text())
    data["fingerings"]["alt"] = ["h3", "h4"]
    path = tmp_path / "cal.yaml"
    path.write_text(yaml.safe_dump(data))
    cal = load_calibration(path, "auto")
    f0 = first_resonance(cal, "xxoo") * 2 ** (-20 / 1200)
    p, u = theory_note(cal, "xxoo", f0, 0.3, 20000.0, np.random.default_rng(0))
    choice = identify(f0, cal, harmonic_lines(p, u, 20000.0, f0))
    assert {choice.fingering, *choice.equivalents} == {"xxoo", "alt"}
    assert choice.runner_up not in ("xxoo", "alt")
    assert not choice.ambiguous and choice.probability > 0.99 and choice.fits
    assert "at these harmonics" in choice.line()


def _reed_note(name, seconds=0.45):
    """A note of the reed model (synth-take's engine) on fingering ``name``: p, u, fs, f0."""
    from mpipe.cli.virtual_takes import SynthOptions, synthesize
    from mpipe.reed.parameters import load_reed

    cal = four_holes(name)
    reed = load_reed(FOUR_HOLES.parent / "reed_table1.yaml")
    _, run, _ = synthesize(cal, reed, SynthOptions(duration_s=seconds, snr_db=None, seed=0))
    fs = run.fs
    p, u = run.p[int(0.2 * fs) :], run.u[int(0.2 * fs) :]  # the steady part
    rng = np.random.default_rng(1)  # 40 dB of noise on both
    p = p + rng.normal(0, 0.01 * p.std(), p.size)
    u = u + rng.normal(0, 0.01 * u.std(), u.size)
    spectrum = np.abs(np.fft.rfft((p - p.mean()) * np.hanning(p.size), 16 * p.size))
    freqs = np.fft.rfftfreq(16 * p.size, 1 / fs)
    band = (freqs > 80) & (freqs < 400)
    return p, u, fs, float(freqs[band][np.argmax(spectrum[band])])


@pytest.mark.parametrize("name", ["xxoo", "xooo"])
def test_a_note_whose_fingering_is_left_out_fits_no_listed_fingering(name):
    # the reed model plays the note (not the linear theory the test weighs it with): with
    # its fingering listed it is named and fits; left out, "no listed fingering fits",
    # where the posterior alone named a wrong one at p = 1.000
    p, u, fs, f0 = _reed_note(name)
    cal = four_holes()
    lines = harmonic_lines(p, u, fs, f0)
    right = identify(f0, cal, lines)
    assert right.fingering == name and right.fits and right.fit_probability > 0.05
    others = [x for x in NAMES if x != name]
    wrong = identify(f0, cal, lines, names=others)
    assert not wrong.fits and wrong.fit_probability < 1e-6
    assert wrong.line().startswith("NO listed fingering fits")


def test_the_noise_of_ln_z_is_measured_from_the_note():
    # the blocks' scatter predicts the scatter of the whole note's ln(P/U) over 40 noise
    # draws (a second method) within a factor 2 at the strong harmonics; the validation's
    # tolerances (3 dB, 20 deg) are no noise scale
    cal = four_holes()
    f0 = first_resonance(cal, "xxxx") * 2 ** (-25 / 1200)
    fs = 20000.0
    logs, predicted = [], []
    for seed in range(40):
        rng = np.random.default_rng(100 + seed)
        p, u = theory_note(cal, "xxxx", f0, 0.3, fs, rng, snr_db=30)
        lines = harmonic_lines(p, u, fs, f0)
        logs.append(np.log(lines.p / lines.u))
        predicted.append(lines.var_re + lines.var_im)
    logs = np.array(logs)
    phase = np.angle(np.exp(1j * (logs.imag - np.angle(np.mean(np.exp(1j * logs.imag), 0)))))
    observed = np.var(logs.real, axis=0) + np.var(phase, axis=0)
    # the odd harmonics, where a closed cylinder's pressure lines stand well above the noise
    ratio = np.mean(predicted, axis=0)[[0, 2, 4]] / observed[[0, 2, 4]]
    assert np.all((ratio > 0.5) & (ratio < 2.0)), ratio


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
