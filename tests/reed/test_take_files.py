"""Writing a virtual take: file names, the calibration copy, truth and sidecar."""

import numpy as np
import pytest
import soundfile as sf
import yaml

from mpipe.measurement.calibration import load_calibration
from mpipe.reed.recorder import RecorderOptions
from mpipe.reed.recording import virtual_recording
from mpipe.reed.take_files import take_file_paths, write_virtual_take

FS = 100_000.0


@pytest.fixture(scope="module")
def take(shipped_calibration):
    n = 5000
    env = np.sin(np.pi * np.arange(n) / n) ** 2  # starts and ends at rest
    t = np.arange(n) / FS
    p, u = env * 500 * np.sin(2 * np.pi * 440 * t), env * 3e-5 * np.cos(2 * np.pi * 440 * t)
    return virtual_recording(
        p,
        u,
        FS,
        shipped_calibration,
        recorder=RecorderOptions(gain_error_db=(1.0, 0.5, -0.5), bits=16, seed=2),
    )


def test_file_names():
    files = take_file_paths("/data/TAKE.flac", n_mics=4)
    assert files.sidecar.name == "TAKE.yaml" and files.truth.name == "TAKE.truth.npz"
    assert files.calibration.name == "TAKE.calibration.yaml"
    assert [p.name for p in files.mic_calibrations] == [
        f"TAKE.mic{m}_calibration.csv" for m in (2, 3, 4)
    ]
    assert take_file_paths("TAKE.wav", with_mic_calibration=False).mic_calibrations == ()


def test_written_take_holds_its_scale_and_truth(tmp_path, take, shipped_calibration):
    files = write_virtual_take(tmp_path / "t.wav", take, shipped_calibration, truth_extra={"k": 2})
    data, fs = sf.read(files.audio, dtype="float64")
    assert fs == FS and data.shape == (take.n_samples, 3)
    np.testing.assert_allclose(data, take.file_samples, atol=2**-15)
    assert len(files.mic_calibrations) == 2  # microphones 2 and 3 differ from microphone 1
    # the copy's sensitivity carries microphone 1's gain error: Pa per full-scale unit
    sens = np.asarray(take.file_sensitivity) / 10 ** (1.0 / 20)
    copy = load_calibration(files.calibration)
    np.testing.assert_allclose([m.sensitivity for m in copy.microphones], sens, rtol=1e-12)
    side = yaml.safe_load(files.sidecar.read_text())
    assert side["subtype"] == "PCM_16" and side["bits"] == 16 and side["noise_seed"] == 2
    np.testing.assert_allclose(side["file_sensitivity_pa"], sens, rtol=1e-12)
    with np.load(files.truth) as truth:
        np.testing.assert_array_equal(truth["p"], take.p)
        assert truth["k"] == 2


def test_unsupported_extension_writes_nothing(tmp_path, take, shipped_calibration):
    with pytest.raises(ValueError, match="unsupported extension"):
        write_virtual_take(tmp_path / "t.mp3", take, shipped_calibration)
    assert list(tmp_path.iterdir()) == []
