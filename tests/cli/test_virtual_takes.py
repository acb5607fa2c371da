"""Virtual takes: rates an audio file cannot store are refused before any work."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from mpipe.cli.virtual_takes import SynthOptions, make_take
from mpipe.core.errors import UserError
from tests.conftest import SHIPPED

REED = SHIPPED.parent / "reed_table1.yaml"
FOUR_HOLES = SHIPPED.parent / "four_hole_clarinet.yaml"


def test_synth_take_refuses_rates_flac_cannot_store(tmp_path):
    for opts, message in (
        (SynthOptions(duration_s=0.2, fs_out=44_100.5), "integer rate"),
        (SynthOptions(duration_s=0.2, fs_model=700_000.0), "cannot be stored in FLAC"),
    ):
        with pytest.raises(ValueError, match=message):
            make_take(SHIPPED, REED, tmp_path / "t.flac", opts)
    assert not (tmp_path / "t.flac").exists()


def test_file_rates_flac_cannot_store_are_refused_before_simulating():
    # Issue 19: libsndfile's FLAC header holds rates above 65 535 Hz in units of 10 Hz, so
    # 93 034 Hz failed with a traceback after the simulation; WAV stores any integer rate.
    from mpipe.cli.virtual_takes import check_file_rate

    with pytest.raises(ValueError, match="multiples of 10 Hz"):
        check_file_rate("take.flac", 93_034.0)
    for path, fs in (("take.wav", 93_034.0), ("take.flac", 96_000.0), ("take.flac", 51_200.0)):
        check_file_rate(path, fs)


def test_an_extension_that_names_no_audio_format_is_refused_before_simulating(tmp_path):
    # a 4 s take was once simulated and only then refused ("take4: take4: unsupported
    # extension"): the check now comes first, and names the path once
    for name in ("take4", "take.mp3"):
        with pytest.raises(ValueError, match="unsupported extension") as caught:
            make_take(SHIPPED, REED, tmp_path / name, SynthOptions(duration_s=1e6))
        assert name not in str(caught.value)  # the CLI names the path, once
    assert not list(tmp_path.iterdir())


def test_the_options_of_mpipe_0_1_give_the_same_take_bit_for_bit(shipped_calibration):
    # the take of the old options, made as mpipe 0.1 made it: one run of the model with the
    # swell, onset and breath noise, then the virtual recording
    from mpipe.acoustics.reflection import reflection_function
    from mpipe.cli.virtual_takes import child_seeds, synthesize
    from mpipe.reed.bore_kernel import prepare_bore
    from mpipe.reed.model import simulate
    from mpipe.reed.parameters import load_reed
    from mpipe.reed.recorder import RecorderOptions
    from mpipe.reed.recording import virtual_recording

    cal, reed = shipped_calibration, load_reed(REED)
    opts = SynthOptions(duration_s=0.15, swell=0.1, breath_noise_pa=10.0, onset_s=0.02,
                        snr_db=40.0, seed=3)  # fmt: skip
    take, run, _ = synthesize(cal, reed, opts)
    air = cal.air_properties()
    kernel = prepare_bore(reflection_function(cal.bore, air, opts.fs_model), air)
    n = 15_000
    t = np.arange(1, n + 1) / opts.fs_model
    breath, noise = child_seeds(3)
    sim = simulate(reed, kernel, n, mouth_pressure=reed.p_m * (1 + 0.1 * t / 0.15),
                   onset_s=0.02, noise_std_pa=10.0, seed=breath)  # fmt: skip
    old = virtual_recording(
        sim.p, sim.u, opts.fs_model, cal, recorder=RecorderOptions(snr_db=40.0, bits=24, seed=noise)
    )
    assert np.array_equal(run.p, sim.p) and np.array_equal(take.signals, old.signals)
    assert run.controls.notes == ((0.0, 0.15),)


def test_synth_take_plays_a_score_and_keeps_its_truth(tmp_path):
    from tests.cli.test_synth_take import run_synth_take

    score = tmp_path / "two.yaml"
    score.write_text(
        "notes:\n"
        "  - {duration: 0.12, p_m: 1800, tongued: true, tongue_hold: 0.02}\n"
        "  - {gap: 0.05, duration: 0.12, p_m: 2000, y_m: [[0, 4.0e-4], [0.1, 3.6e-4]]}\n"
    )
    out = tmp_path / "t.flac"
    base = [str(SHIPPED), "--reed", str(REED), "--score", str(score), "-o", str(out)]
    assert run_synth_take([*base, "--fs-out", "50000"]) == 0
    truth = np.load(tmp_path / "t.truth.npz")
    assert truth["p"].size == 17_000  # 0.29 s of notes and gap, 0.05 s of silence at the end
    np.testing.assert_allclose(truth["note_start_s"], [0.02, 0.17])
    np.testing.assert_allclose(truth["tongue_end_s"], [0.02])
    ym = truth["control_y_m"]
    assert float(truth["control_fs"]) == 1000.0 and ym.dtype == np.float32
    assert ym[100] == np.float32(4e-4) and ym[280] == np.float32(3.6e-4)
    assert np.all(truth["control_p_m"][125:165] == 0)  # the silence between the notes
    sidecar = yaml.safe_load((tmp_path / "t.yaml").read_text())
    assert sidecar["recipe"]["score"]["notes"][1]["gap"] == 0.05
    assert "--score" in sidecar["recipe"]["command"]
    with pytest.raises(UserError, match="--swell: not with --score"):
        run_synth_take([*base, "--swell", "0.1", "--force"])
    with pytest.raises(UserError, match=r"--duration: 0.2 s is shorter than the score .*two"):
        run_synth_take([*base, "--duration", "0.2", "--force"])
    with pytest.raises(UserError, match="--duration: required without --score"):
        run_synth_take([str(SHIPPED), "--reed", str(REED), "-o", str(out), "--force"])


def test_a_register_hole_upstream_of_the_microphones_is_recorded_through_each_notes_bore(
    tmp_path,
):
    # issue 42: the take's field at the microphones was rendered through the take's default
    # fingering for every note, so a note with the register hole (between the mouthpiece
    # and the reference plane) open was recorded as if it were closed, and failed its
    # validation. Carried back through each note's own fingering (the translation, a second
    # module), the truth at the reference plane must give the model's mouthpiece signals.
    from mpipe.core.filters import apply_lowpass
    from mpipe.measurement.translation import TranslationConfig, translate
    from tests.measurement.fingering_helpers import register_hole_take

    cal, take = register_hole_take(tmp_path)
    errors = {}
    for name, span in (("xxxx", (0.15, 0.28)), ("rxxxx", (0.45, 0.58))):
        back = translate(take.p0, take.u0, take.fs, cal.with_fingering(name), TranslationConfig())
        a, b = (int(x * take.fs) for x in span)
        truth = apply_lowpass(take.p, back.lowpass)[a:b]
        errors[name] = np.max(np.abs(back.p[a:b] - truth)) / np.max(np.abs(truth))
    assert errors["xxxx"] < 1e-3 and errors["rxxxx"] < 1e-3, errors


def test_a_take_of_several_fingerings_leaves_each_notes_to_be_found(tmp_path):
    # the verdict corpus (issue 38): a score slurring xxxx -> xxoo was written with the
    # calibration's default xxxx, so mpipe run validated both notes on xxxx and FAILed the
    # correct take; its copy names no default, so each note's fingering is found (auto)
    from mpipe.measurement.calibration import load_calibration

    files = _four_hole_take(tmp_path, ("xxxx", "xxoo"))
    assert "fingering" not in yaml.safe_load(files.calibration.read_text())
    assert load_calibration(files.calibration).fingering == "auto"


def test_a_take_of_one_fingering_names_it_in_its_calibration_copy(tmp_path):
    # the verdict corpus: a steady xxoo note of the four-hole clarinet was written with
    # the calibration's default xxxx, so mpipe run validated it on xxxx and FAILed the
    # correct take at every SNR; its copy names the fingering the score plays
    from mpipe.measurement.calibration import load_calibration

    files = _four_hole_take(tmp_path, ("xxoo",))
    copy = load_calibration(files.calibration)
    assert copy.fingering == "xxoo"
    shipped = load_calibration(FOUR_HOLE).with_fingering("xxoo")
    assert copy.bore.open_holes == shipped.bore.open_holes


FOUR_HOLE = Path(__file__).resolve().parents[2] / "calibration" / "four_hole_clarinet.yaml"


def _four_hole_take(folder, fingerings):
    """A virtual take of the four-hole clarinet, one 0.1 s note per fingering given."""
    reed = FOUR_HOLE.parents[0] / "reed_table1.yaml"
    score = folder / "s.yaml"
    notes = [{"duration": 0.1, "fingering": f, "p_m": 1800.0} for f in fingerings]
    score.write_text(yaml.safe_dump({"notes": notes}))
    options = SynthOptions(duration_s=None, score=str(score), fs_model=50_000.0)
    return make_take(FOUR_HOLE, reed, folder / "t.flac", options)
