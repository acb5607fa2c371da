"""Reading takes: round trips to Pa, and one clear error per way a file can be wrong."""

import numpy as np
import pytest
import soundfile as sf
import yaml

from mpipe.core.errors import OutputExistsError, UserError
from mpipe.measurement.calibration import load_calibration
from mpipe.measurement.takes import read_take
from mpipe.reed.recording import virtual_recording
from mpipe.reed.take_files import write_virtual_take
from tests.measurement.take_helpers import (
    FS,
    signals,
    virtual_take,
    write_calibration,
)


@pytest.fixture(scope="module")
def vtake(shipped_calibration):
    return shipped_calibration, virtual_take(shipped_calibration)


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


# --- errors -------------------------------------------------------------------------------


def test_wrong_channel_count(tmp_path, shipped_calibration):
    sf.write(tmp_path / "take.flac", np.zeros((48_000, 2)), 48_000)
    with pytest.raises(
        UserError,
        match=r"take.flac: has 2 channels, calibration maps microphones to channels 1, 2, 3",
    ):
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


# --- the pipeline's rate ------------------------------------------------------------------


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


def test_a_take_at_any_rate_is_read(tmp_path, vtake):
    # Issue 19: 93 034 Hz (a simulator's rate) is not a simple fraction of 100 kHz; it is
    # read and resampled, the same pressures as at 48 kHz within the band.
    import soundfile as sf

    cal, vt = vtake
    files = write_virtual_take(tmp_path / "take.flac", vt, cal)
    cal2 = load_calibration(files.calibration)
    ref = read_take(files.audio, cal2, fs=100_000.0)
    data, fs = sf.read(files.audio, always_2d=True)
    from mpipe.core.resampling import resample

    odd = resample(data, fs, 93_034.0)
    sf.write(tmp_path / "odd.wav", odd, 93_034, subtype="FLOAT")
    take = read_take(tmp_path / "odd.wav", cal2, fs=100_000.0)
    assert take.fs == 100_000.0 and take.fs_file == 93_034.0
    n = min(ref.n_samples, take.n_samples)
    mid = slice(5000, n - 5000)
    err = np.max(np.abs(take.pressures[mid] - ref.pressures[mid])) / np.max(np.abs(ref.pressures))
    assert err < 2e-3
