"""Relative calibration tables: the CSV round trip, their division, one error per fault."""

import numpy as np
import pytest
import soundfile as sf

from mpipe.core.errors import UserError
from mpipe.measurement.calibration_tables import read_mic_calibration
from mpipe.measurement.takes import read_take
from mpipe.reed.take_files import write_mic_calibration
from tests.measurement.take_helpers import virtual_take, write_calibration


@pytest.fixture(scope="module")
def vtake(shipped_calibration):
    return shipped_calibration, virtual_take(shipped_calibration)


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


@pytest.mark.parametrize(("n", "block"), [(3 * 44100 + 17, 1 << 16), (50001, 7777)])
def test_the_relative_calibration_in_blocks_equals_the_whole_takes_fft(n, block):
    # a smooth table, lengths no block divides: the block filter differs from the one FFT
    # of the whole take by less than the whole take's path differs from itself when the
    # take is 5000 samples shorter (its grid, and so its filter, follows the length)
    from mpipe.measurement.calibration_tables import divide_response, divide_response_blocks

    fs = 44100.0
    freqs = np.linspace(20.0, 20000.0, 400)
    h = (1 + 0.1 * np.sin(freqs / 3000)) * np.exp(1j * (0.2 * np.sin(freqs / 2000) + freqs * 2e-6))
    x = np.random.default_rng(1).normal(size=n)
    whole = divide_response(x, fs, freqs, h)
    blocks = divide_response_blocks(x, fs, freqs, h, block=block)
    rms = float(np.sqrt(np.mean(whole**2)))
    err = float(np.sqrt(np.mean((blocks - whole) ** 2)))
    m = n - 5000
    shorter = divide_response(x[:m], fs, freqs, h)[: m - 3000] - whole[: m - 3000]
    assert err < 1e-4 * rms
    assert err < float(np.sqrt(np.mean(shorter**2)))
    assert np.max(np.abs(blocks - whole)) < 1e-4 * np.max(np.abs(whole))
