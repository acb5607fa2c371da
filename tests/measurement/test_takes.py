"""Reading takes: round trips to Pa, and one clear error per way a take can be wrong."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
import yaml

from mpipe.core.errors import OutputExistsError, UserError
from mpipe.measurement.calibration import load_calibration
from mpipe.measurement.takes import read_mic_calibration, read_take
from mpipe.reed.recording import virtual_recording
from mpipe.reed.take_files import calibration_mapping, write_mic_calibration, write_virtual_take

FS = 100_000.0
ROOT = Path(__file__).resolve().parents[2]
SHIPPED = ROOT / "calibration" / "simplified_clarinet.yaml"
REED = ROOT / "calibration" / "reed_table1.yaml"


def signals(n=40_000, fs=FS):
    t = np.arange(n) / fs
    env = np.minimum(t / 0.01, 1) * np.minimum((t[-1] - t) / 0.01, 1)
    p = (900 * np.sin(2 * np.pi * 150 * t) + 250 * np.sin(2 * np.pi * 450 * t + 1)) * env
    u = (1e-4 + 8e-5 * np.cos(2 * np.pi * 150 * t - 0.2)) * env
    return p, u


@pytest.fixture(scope="module")
def vtake(shipped_calibration):
    cal = shipped_calibration
    p, u = signals()
    return cal, virtual_recording(
        p,
        u,
        FS,
        cal,
        gain_error_db=(0.4, 0.7, -0.5),
        phase_error_deg=(0.0, 1.5, -2.0),
        bits=24,
        fs_out=48_000.0,
    )


def write_calibration(tmp_path, cal, name="cal.yaml", **mic_changes):
    """Write a calibration file whose microphones take the given per-index changes."""
    mics = list(cal.microphones)
    for key, values in mic_changes.items():
        mics = [dataclasses.replace(m, **{key: v}) for m, v in zip(mics, values, strict=True)]
    path = tmp_path / name
    mapping = calibration_mapping(dataclasses.replace(cal, microphones=tuple(mics)))
    path.write_text(yaml.safe_dump(mapping, sort_keys=False))
    return load_calibration(path)


@pytest.mark.parametrize("ext", [".flac", ".wav", ".aiff"])
def test_round_trip_multichannel_recovers_pa(tmp_path, vtake, ext):
    cal, vt = vtake
    files = write_virtual_take(tmp_path / f"take{ext}", vt, cal, recipe={"test": True})
    take = read_take(files.audio, load_calibration(files.calibration))
    assert take.fs == 48_000.0 and take.pressures.shape == (vt.n_samples, 3)
    assert take.duration == pytest.approx(vt.duration)
    assert take.path == str(files.audio) and take.channels == (1, 2, 3)
    mid = slice(2400, -2400)
    scale = np.max(np.abs(vt.pressures), axis=0)
    err = np.max(np.abs(take.pressures[mid] - vt.pressures[mid]), axis=0) / scale
    # mic 1: 24-bit quantisation only; mics 2, 3: also the constant-phase correction, whose
    # 1/t kernel is cut at the ends of the take
    assert err[0] < 1e-6
    assert np.all(err < 1e-4), err
    truth = np.load(files.truth)
    np.testing.assert_array_equal(truth["p0"], vt.p0)
    assert float(truth["fs"]) == 48_000.0
    sidecar = yaml.safe_load(files.sidecar.read_text())
    assert sidecar["recipe"] == {"test": True} and sidecar["bits"] == 24
    np.testing.assert_allclose(
        sidecar["file_sensitivity_pa"],
        [m.sensitivity for m in load_calibration(files.calibration).microphones],
    )


def test_without_mic_calibration_the_mismatch_stays(tmp_path, vtake):
    cal, vt = vtake
    files = write_virtual_take(tmp_path / "take.flac", vt, cal, mic_calibration=False)
    assert files.mic_calibrations == ()
    take = read_take(files.audio, load_calibration(files.calibration))
    rms = np.sqrt(np.mean(take.pressures**2, axis=0) / np.mean(vt.pressures**2, axis=0))
    # mic 1's gain error is in its sensitivity; mics 2, 3 keep theirs relative to mic 1
    np.testing.assert_allclose(20 * np.log10(rms), [0.0, 0.3, -0.9], atol=1e-3)


def test_no_overwrite_without_force(tmp_path, vtake):
    cal, vt = vtake
    write_virtual_take(tmp_path / "take.flac", vt, cal)
    with pytest.raises(OutputExistsError, match="take.flac exists"):
        write_virtual_take(tmp_path / "take.flac", vt, cal)
    write_virtual_take(tmp_path / "take.flac", vt, cal, force=True)


def test_round_trip_three_mono_files(tmp_path, vtake):
    cal, vt = vtake
    paths = []
    for i in range(3):
        path = tmp_path / f"mic{i + 1}.wav"
        sf.write(path, vt.file_samples[:, i], 48_000, subtype="PCM_24")
        paths.append(path)
    cal2 = write_calibration(tmp_path, cal, sensitivity=vt.file_sensitivity)
    take = read_take(paths, cal2)
    assert take.paths == tuple(str(p) for p in paths)
    mid = slice(2400, -2400)
    np.testing.assert_allclose(take.pressures[mid], vt.signals[mid] * vt.sensitivity, atol=1e-3)


def test_channel_map_and_extra_channels(tmp_path, vtake):
    cal, vt = vtake
    data = np.zeros((vt.n_samples, 5))
    data[:, 4], data[:, 1], data[:, 2] = vt.file_samples.T
    sf.write(tmp_path / "five.wav", data, 48_000, subtype="PCM_24")
    cal2 = write_calibration(tmp_path, cal, channel=(5, 2, 3), sensitivity=vt.file_sensitivity)
    take = read_take(tmp_path / "five.wav", cal2)
    assert take.channels == (5, 2, 3)
    np.testing.assert_allclose(take.pressures, vt.signals * vt.sensitivity, atol=1e-3)


def test_mic_calibration_csv_round_trip(tmp_path):
    f = np.array([0.0, 100.0, 1000.0, 8000.0, 24000.0])
    h = np.array([1.0, 1.01, 0.99, 1.05, 1.1]) * np.exp(1j * np.deg2rad([0, 10, 170, 300, 460]))
    write_mic_calibration(tmp_path / "h.csv", f, h)
    f2, h2 = read_mic_calibration(tmp_path / "h.csv")
    np.testing.assert_allclose(f2, f)
    np.testing.assert_allclose(h2, h, rtol=1e-12)
    # the phase is stored unwrapped, continuous in frequency
    assert np.degrees(np.angle(h2[-1])) == pytest.approx(100.0)
    text = (tmp_path / "h.csv").read_text().splitlines()
    assert text[0] == "frequency_hz,magnitude,phase_deg"
    assert float(text[-1].split(",")[2]) == pytest.approx(460.0)


def test_relative_calibration_is_divided_out(tmp_path, vtake):
    cal, vt = vtake
    # a frequency-dependent H_c on mic 3: a pure delay of 3 samples at 48 kHz
    f = np.linspace(0.0, 24_000.0, 2001)
    h = np.exp(-2j * np.pi * f * 3 / 48_000)
    write_mic_calibration(tmp_path / "mic3.csv", f, h)
    data = vt.file_samples.copy()
    data[:, 2] = np.concatenate([np.zeros(3), data[:-3, 2]])
    sf.write(tmp_path / "take.flac", data, 48_000, subtype="PCM_24")
    cal2 = write_calibration(
        tmp_path, cal, sensitivity=vt.file_sensitivity, calibration=(None, None, "mic3.csv")
    )
    take = read_take(tmp_path / "take.flac", cal2)
    mid = slice(2400, -2400)
    want = vt.signals[mid, 2] * vt.sensitivity[2]
    assert np.max(np.abs(take.pressures[mid, 2] - want)) / np.max(np.abs(want)) < 1e-3


# --- errors -------------------------------------------------------------------------------


def test_wrong_channel_count(tmp_path, shipped_calibration):
    sf.write(tmp_path / "take.flac", np.zeros((48_000, 2)), 48_000)
    with pytest.raises(
        UserError,
        match=r"take.flac: has 2 channels, calibration maps microphones to channels 1, 2, 3",
    ):
        read_take(tmp_path / "take.flac", shipped_calibration)


def test_non_finite_samples(tmp_path, shipped_calibration):
    x = np.zeros((48_000, 3))
    x[1000, 1] = np.nan
    sf.write(tmp_path / "take.wav", x, 48_000, subtype="FLOAT")
    with pytest.raises(UserError, match=r"take.wav: channel 2 \(mic2\): 1 non-finite samples"):
        read_take(tmp_path / "take.wav", shipped_calibration)


def test_clipping_is_reported_per_channel(tmp_path, shipped_calibration):
    rng = np.random.default_rng(0)
    x = 0.1 * rng.standard_normal((48_000, 3))
    x[:100, 2] = 1.0  # 0.21 % of channel 3 at positive full scale
    sf.write(tmp_path / "take.wav", x, 48_000, subtype="PCM_16")
    with pytest.raises(
        UserError, match=r"take.wav: channel 3 \(mic3\): 0.208 % of samples at full"
    ):
        read_take(tmp_path / "take.wav", shipped_calibration)
    # a looser limit accepts it, and the fraction is reported
    take = read_take(tmp_path / "take.wav", shipped_calibration, max_clip_fraction=0.01)
    assert take.clip_fraction[2] == pytest.approx(100 / 48_000)
    assert take.clip_fraction[0] == 0.0


def test_negative_full_scale_counts_as_clipping(tmp_path, shipped_calibration):
    x = np.zeros((48_000, 3))
    x[:50, 0] = -1.0
    sf.write(tmp_path / "take.flac", x, 48_000, subtype="PCM_24")
    with pytest.raises(UserError, match=r"channel 1 \(mic1\).*full scale"):
        read_take(tmp_path / "take.flac", shipped_calibration)


def test_too_short(tmp_path, shipped_calibration):
    sf.write(tmp_path / "take.flac", np.zeros((4_800, 3)), 48_000)
    with pytest.raises(
        UserError, match=r"take.flac: take is 0.1 s long, shorter than one analysis"
    ):
        read_take(tmp_path / "take.flac", shipped_calibration)
    take = read_take(tmp_path / "take.flac", shipped_calibration, min_duration_s=0.05, check=False)
    assert take.duration == pytest.approx(0.1)


def test_sample_rate_too_low(tmp_path, shipped_calibration):
    sf.write(tmp_path / "take.flac", np.zeros((16_000, 3)), 8_000)
    with pytest.raises(UserError, match=r"take.flac: sample rate 8000 Hz is too low .* 15950 Hz"):
        read_take(tmp_path / "take.flac", shipped_calibration)


def test_missing_and_unreadable_files(tmp_path, shipped_calibration):
    with pytest.raises(UserError, match=r"nope.flac: no such file"):
        read_take(tmp_path / "nope.flac", shipped_calibration)
    (tmp_path / "junk.wav").write_text("not audio")
    with pytest.raises(UserError, match=r"junk.wav: cannot read audio"):
        read_take(tmp_path / "junk.wav", shipped_calibration)
    with pytest.raises(UserError, match="one multichannel file or 3 mono files .*got 2"):
        read_take([tmp_path / "a.wav", tmp_path / "b.wav"], shipped_calibration)


def test_mono_files_must_match(tmp_path, shipped_calibration):
    for name, n, fs in [("a", 48_000, 48_000), ("b", 48_000, 48_000), ("c", 47_000, 48_000),
                        ("d", 48_000, 44_100)]:  # fmt: skip
        sf.write(tmp_path / f"{name}.wav", np.zeros(n), fs)
    sf.write(tmp_path / "st.wav", np.zeros((48_000, 2)), 48_000)
    a, b, c, d, st = (tmp_path / f"{x}.wav" for x in ("a", "b", "c", "d", "st"))
    with pytest.raises(UserError, match=r"c.wav: 47000 samples differ from .*a.wav \(48000"):
        read_take([a, b, c], shipped_calibration)
    with pytest.raises(UserError, match=r"d.wav: sample rate 44100 Hz differs from .*a.wav"):
        read_take([a, d, b], shipped_calibration)
    with pytest.raises(UserError, match=r"st.wav: has 2 channels; expected a mono file"):
        read_take([a, b, st], shipped_calibration)


def test_mono_files_need_channels_1_2_3(tmp_path, shipped_calibration):
    for name in "abc":
        sf.write(tmp_path / f"{name}.wav", np.zeros(48_000), 48_000)
    cal = write_calibration(tmp_path, shipped_calibration, channel=(1, 2, 4))
    with pytest.raises(UserError, match="channels 1 to 3, but the calibration maps .* 1, 2, 4"):
        read_take([tmp_path / f"{x}.wav" for x in "abc"], cal)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("freq,mag,phase\n0,1,0\n8000,1,0\n", r"mic2.csv: line 1: expected the header"),
        ("frequency_hz,magnitude,phase_deg\n0,1,0\n100,x,0\n8000,1,0\n",
         r"mic2.csv: line 3: expected numbers"),
        ("frequency_hz,magnitude,phase_deg\n0,1,0\n100,1\n",
         r"mic2.csv: line 3: expected 3 values"),
        ("frequency_hz,magnitude,phase_deg\n0,1,0\n100,0,0\n8000,1,0\n",
         r"mic2.csv: line 3: magnitude must be > 0"),
        ("frequency_hz,magnitude,phase_deg\n0,1,0\n100,nan,0\n8000,1,0\n",
         r"mic2.csv: line 3: non-finite"),
        ("frequency_hz,magnitude,phase_deg\n0,1,0\n100,1,0\n50,1,0\n8000,1,0\n",
         r"mic2.csv: frequencies must increase strictly \(50 Hz follows 100 Hz\)"),
        ("frequency_hz,magnitude,phase_deg\n0,1,0\n5000,1,0\n",
         r"mic2.csv: covers 0-5000 Hz, which does not include the band 20-7250 Hz"),
        ("frequency_hz,magnitude,phase_deg\n100,1,0\n9000,1,0\n",
         r"mic2.csv: covers 100-9000 Hz"),
        ("# only a comment\n", r"mic2.csv: empty"),
    ],
)  # fmt: skip
def test_bad_calibration_tables(tmp_path, shipped_calibration, text, message):
    sf.write(tmp_path / "take.flac", np.zeros((24_000, 3)), 48_000)
    (tmp_path / "mic2.csv").write_text(text)
    cal = write_calibration(tmp_path, shipped_calibration, calibration=(None, "mic2.csv", None))
    with pytest.raises(UserError, match=message):
        read_take(tmp_path / "take.flac", cal)


def test_missing_calibration_table(tmp_path, shipped_calibration):
    sf.write(tmp_path / "take.flac", np.zeros((24_000, 3)), 48_000)
    cal = write_calibration(tmp_path, shipped_calibration, calibration=(None, None, "gone.csv"))
    with pytest.raises(UserError, match=r"gone.csv: cannot read microphone calibration"):
        read_take(tmp_path / "take.flac", cal)


# --- the synth-take command ---------------------------------------------------------------


def run_synth_take(argv):
    import argparse

    from mpipe.cli.commands import synth_take

    parser = argparse.ArgumentParser()
    synth_take.add_parser(parser.add_subparsers())
    args = parser.parse_args(["synth-take", *argv])
    return args.func(args)


def test_synth_take_command_writes_a_readable_reproducible_take(tmp_path):
    argv = [str(SHIPPED), "--reed", str(REED), "--duration", "0.3", "--fs-out", "48000",
            "--snr", "40", "--gain-error-db", "0.2,0.5,-0.3", "--phase-error-deg", "0,0.4,-0.3",
            "--swell", "0.1", "--breath-noise", "10", "--mach", "auto", "--seed", "5",
            "-o", str(tmp_path / "take.flac")]  # fmt: skip
    assert run_synth_take(argv) == 0
    cal = load_calibration(tmp_path / "take.calibration.yaml")
    take = read_take(tmp_path / "take.flac", cal)
    truth = np.load(tmp_path / "take.truth.npz")
    assert take.fs == 48_000.0 and take.n_samples == 14_400
    assert float(truth["reed_k"]) == 8.66e6 and float(truth["mach"]) > 0
    # the SNR is defined over the whole channel (the onset included)
    err = take.pressures - truth["mic_pressures"]
    snr = 10 * np.log10(np.sum(truth["mic_pressures"] ** 2, 0) / np.sum(err**2, 0))
    np.testing.assert_allclose(snr, 40.0, atol=0.5)
    sidecar = yaml.safe_load((tmp_path / "take.yaml").read_text())
    assert sidecar["recipe"]["seed"] == 5 and "--swell 0.1" in sidecar["recipe"]["command"]
    first = (tmp_path / "take.flac").read_bytes()
    with pytest.raises(OutputExistsError, match="take.flac exists"):
        run_synth_take(argv)
    assert run_synth_take([*argv, "--force"]) == 0
    assert (tmp_path / "take.flac").read_bytes() == first


# --- input sanity and the pipeline's rate -------------------------------------------------


def _write_mono_take(tmp_path, vt, cal, columns, *, scale=(1.0, 1.0, 1.0), edit=None):
    """Write the virtual take's channels in the given order, optionally edited."""
    data = vt.file_samples[:, list(columns)].copy()
    if edit is not None:
        data = edit(data)
    sf.write(tmp_path / "take.wav", data, 48_000, subtype="FLOAT")
    sens = tuple(s * k for s, k in zip(vt.file_sensitivity, scale, strict=True))
    return tmp_path / "take.wav", write_calibration(tmp_path, cal, sensitivity=sens)


@pytest.mark.parametrize(
    ("columns", "scale", "edit", "message"),
    [
        ((2, 1, 0), (1, 1, 1), None, r"flows towards the mouthpiece.*reverse order"),
        ((1, 0, 2), (1, 1, 1), None, r"channels look swapped.*channels 2, 1, 3"),
        ((0, 2, 1), (1, 1, 1), None, r"channels look swapped.*channels 1, 3, 2"),
        ((0, 1, 2), (1, 1, 1e3), None, r"channel 3 \(mic3\): RMS pressure .* implausible"),
        ((0, 1, 2), (1e3, 1e3, 1e3), None, r"channel 1 \(mic1\): RMS pressure .*sensitivity"),
        ((0, 1, 2), (1, 1, 1), lambda d: d + [0.0, 0.2, 0.0], r"channel 2 \(mic2\): DC offset"),
        ((0, 1, 2), (1, 1, 1), lambda d: np.clip(d, -0.25, 0.25), r"channel 1 .*flat tops"),
    ],
)
def test_sanity_checks_give_one_line_each(
    tmp_path, shipped_calibration, columns, scale, edit, message
):
    cal = shipped_calibration
    vt = virtual_recording(*signals(), FS, cal, snr_db=50.0, bits=24, fs_out=48_000.0)
    path, cal2 = _write_mono_take(tmp_path, vt, cal, columns, scale=scale, edit=edit)
    with pytest.raises(UserError, match=message) as info:
        read_take(path, cal2)
    assert "\n" not in str(info.value)


def test_sanity_checks_pass_a_good_take_at_any_snr(tmp_path, shipped_calibration):
    # no false alarm on physical takes: several seeds and noise levels, 16-bit included
    cal = shipped_calibration
    p, u = signals()
    for seed, snr, bits in ((0, 30.0, 16), (1, 45.0, 24), (2, 70.0, 24)):
        vt = virtual_recording(p, u, FS, cal, snr_db=snr, bits=bits, seed=seed, fs_out=48_000.0)
        path, cal2 = _write_mono_take(tmp_path, vt, cal, (0, 1, 2))
        read_take(path, cal2)


def test_takes_are_resampled_to_the_pipeline_rate(tmp_path, vtake):
    # the same take read at 48 kHz and brought to 100 kHz: the pressures agree with the
    # truth recorded at 100 kHz (band-limited to the file's Nyquist frequency)
    cal, vt = vtake
    files = write_virtual_take(tmp_path / "take.flac", vt, cal)
    cal2 = load_calibration(files.calibration)
    take = read_take(files.audio, cal2, fs=100_000.0)
    assert take.fs == 100_000.0 and take.fs_file == 48_000.0
    assert take.band_limit_hz == 24_000.0
    p, u = signals()
    ref = virtual_recording(p, u, FS, cal).pressures
    n = min(ref.shape[0], take.n_samples)
    mid = slice(5000, n - 5000)
    err = np.max(np.abs(take.pressures[mid] - ref[mid])) / np.max(np.abs(ref))
    assert err < 2e-3


def test_resample_refuses_irrational_ratios():
    from mpipe.measurement.takes import resample

    x = np.sin(np.arange(4410) / 10.0)
    assert resample(x, 44_100.0, 100_000.0).size == 10_000
    with pytest.raises(ValueError, match="not a simple fraction"):
        resample(x, 44_100.0, 100_000.0 * np.pi)


def test_synth_take_refuses_rates_flac_cannot_store(tmp_path):
    from mpipe.cli.commands.synth_take import SynthOptions, make_take

    for opts, message in (
        (SynthOptions(duration_s=0.2, fs_out=44_100.5), "integer rate"),
        (SynthOptions(duration_s=0.2, fs_model=700_000.0), "cannot be stored in FLAC"),
    ):
        with pytest.raises(ValueError, match=message):
            make_take(SHIPPED, REED, tmp_path / "t.flac", opts)
    assert not (tmp_path / "t.flac").exists()
