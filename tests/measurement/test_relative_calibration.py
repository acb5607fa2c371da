"""Relative microphone calibration: the switching and closed-tube methods, and their command."""

import numpy as np
import pytest
import soundfile as sf

from mpipe.cli.main import main
from mpipe.measurement.calibration_recordings import simulate_calibration_recording
from mpipe.measurement.calibration_tables import read_mic_calibration
from mpipe.measurement.field import complex_gain
from mpipe.measurement.relative_calibration import (
    closed_tube_calibration,
    closed_tube_ratio,
    switching_calibration,
)
from tests.conftest import SHIPPED

GAIN_DB, PHASE_DEG = 0.5, 2.0
# the method needs only the 20-7250 Hz band: 20 kHz keeps the simulations quick; 67 dB SNR
# over 10 kHz is the noise density of 60 dB SNR over the 50 kHz of a 100 kHz recording
FS = 20_000.0
SNR = 67.0


def _errors(result, band=(20.0, 7250.0)):
    sel = (result.freqs >= band[0]) & (result.freqs <= band[1])
    gain = 20 * np.log10(np.abs(result.h[sel])) - GAIN_DB
    phase = np.rad2deg(np.unwrap(np.angle(result.h)))[sel] - PHASE_DEG
    return gain, phase


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_switching_recovers_a_half_db_two_degree_mismatch(shipped_calibration, seed):
    # all three noise seeds must pass
    cal = shipped_calibration
    x1, x2 = cal.microphones[0].position, cal.microphones[1].position
    g = complex_gain([0.0, GAIN_DB], [0.0, PHASE_DEG])
    first = simulate_calibration_recording(
        cal, (x1, x2), g, duration_s=4, fs=FS, snr_db=SNR, seed=seed
    )
    # recording II: the two microphones swapped in the wall, each on its own channel
    second = simulate_calibration_recording(
        cal, (x2, x1), g, duration_s=4, fs=FS, snr_db=SNR, seed=seed + 50
    )
    result = switching_calibration(first, second, FS, "mic2")
    gain, phase = _errors(result)
    assert abs(np.median(gain)) < 0.05 and abs(np.median(phase)) < 0.2
    # and bin by bin over most of the band (the rest: pressure minima of the bore)
    assert np.mean(np.abs(gain) < 0.05) > 0.9 and np.mean(np.abs(phase) < 0.2) > 0.9


def test_switching_resolves_the_square_root_branch_of_a_swapped_polarity(shipped_calibration):
    cal = shipped_calibration
    x1, x3 = cal.microphones[0].position, cal.microphones[2].position
    g = complex_gain([0.0, -1.0], [0.0, 180.0 + 5.0])  # wired with inverted polarity
    first = simulate_calibration_recording(
        cal, (x1, x3), g, duration_s=2, fs=FS, snr_db=SNR, seed=3
    )
    second = simulate_calibration_recording(
        cal, (x3, x1), g, duration_s=2, fs=FS, snr_db=SNR, seed=4
    )
    result = switching_calibration(first, second, FS, "mic3")
    sel = (result.freqs > 100) & (result.freqs < 5000)
    phase = np.rad2deg(np.angle(result.h[sel] / g[1]))
    assert np.median(np.abs(phase)) < 0.5


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_closed_tube_recovers_the_mismatch_against_the_known_field(shipped_calibration, seed):
    # both seeds must pass
    cal = shipped_calibration
    x = np.array([cal.microphones[0].position, cal.microphones[1].position])
    cap = 0.45
    g = complex_gain([0.0, GAIN_DB], [0.0, PHASE_DEG])
    rec = simulate_calibration_recording(
        cal, tuple(x), g, load="closed", closed_at=cap, duration_s=4, fs=FS, snr_db=SNR, seed=seed
    )
    freqs = np.fft.rfftfreq(4096, 1 / FS)
    ratio = closed_tube_ratio(x, cap, cal.main_radius, freqs, cal.air_properties())
    result = closed_tube_calibration(rec, FS, ratio[:, 1], freqs, "mic2")
    gain, phase = _errors(result)
    # every bin of the table within 0.05 dB and 0.2 deg over 20-7250 Hz at the defaults
    # (0.041 dB, 0.18 deg measured); the bins on the flanks of the tube's pressure nodes,
    # where the spectral estimate is biased against the field at the bin's centre, are
    # refused and interpolated, and counted
    assert np.max(np.abs(gain)) < 0.05 and np.max(np.abs(phase)) < 0.2
    assert 0.2 < result.summary()["near_node_fraction"] < 0.6


def test_switching_warns_when_nothing_was_swapped_and_when_h_c_is_implausible(
    shipped_calibration,
):
    cal = shipped_calibration
    x1, x2 = cal.microphones[0].position, cal.microphones[1].position
    g = complex_gain([0.0, GAIN_DB], [0.0, PHASE_DEG])
    first = simulate_calibration_recording(
        cal, (x1, x2), g, duration_s=2, fs=FS, snr_db=SNR, seed=5
    )
    second = simulate_calibration_recording(
        cal, (x2, x1), g, duration_s=2, fs=FS, snr_db=SNR, seed=6
    )
    assert switching_calibration(first, second, FS, "mic2").warnings == ()
    same = switching_calibration(first, first, FS, "mic2")
    assert any("not swapped" in w for w in same.warnings), same.warnings
    assert any("implausible" in w for w in same.warnings), same.warnings
    # a channel 10 dB hotter than its sensitivity says: swapped, but implausible
    hot = switching_calibration(first * [1, 3.16], second * [1, 3.16], FS, "mic2")
    assert len(hot.warnings) == 1 and "implausible" in hot.warnings[0]


def test_closed_tube_ratio_limit_cases(shipped_air):
    freqs = np.array([1.0, 100.0, 1000.0])
    # at the cap the ratio of a microphone to itself is 1; lossless quarter-wave node
    r = closed_tube_ratio(np.array([0.1, 0.1]), 0.3, 0.0075, freqs, shipped_air)
    np.testing.assert_allclose(r, 1.0)
    c = shipped_air.c
    f = c / (4 * 0.2)  # x = 0.1 sits a quarter wavelength from the cap at x = 0.3
    r = closed_tube_ratio(np.array([0.3, 0.1]), 0.3, 0.0075, np.array([f]), shipped_air,
                          "lossless")  # fmt: skip
    assert abs(r[0, 1]) < 1e-9


def test_calibrate_command_writes_a_table_the_take_reader_accepts(tmp_path, capsys):
    from mpipe.measurement.calibration import load_calibration

    cal = load_calibration(SHIPPED)
    x1, x2 = cal.microphones[0].position, cal.microphones[1].position
    g = complex_gain([0.0, GAIN_DB], [0.0, PHASE_DEG])
    for name, pos, seed in (("one.wav", (x1, x2), 5), ("two.wav", (x2, x1), 6)):
        x = simulate_calibration_recording(cal, pos, g, duration_s=2, fs=FS, snr_db=SNR, seed=seed)
        sf.write(tmp_path / name, x / 4.0, int(FS), subtype="FLOAT")  # sensitivity 1 Pa/unit
    out = tmp_path / "mic2.csv"
    args = ["calibrate", "switch", str(SHIPPED), "--mic", "mic2", str(tmp_path / "one.wav"),
            str(tmp_path / "two.wav"), "-o", str(out)]  # fmt: skip
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert printed.startswith("mic2: H_c median +0.") and "calibration: " in printed
    freqs, h = read_mic_calibration(out)  # covers the 20-7250 Hz band the reader requires
    sel = (freqs > 100) & (freqs < 5000)
    assert np.median(20 * np.log10(np.abs(h[sel]))) == pytest.approx(GAIN_DB, abs=0.05)
    # refusing to overwrite, and one-line errors naming the problem
    assert main(args) == 2
    assert "exists; use --force" in capsys.readouterr().err
    bad = [*args[:4], "mic9", *args[5:7], "-o", str(tmp_path / "x.csv")]
    assert main(bad) == 2
    assert "no microphone named 'mic9'" in capsys.readouterr().err
