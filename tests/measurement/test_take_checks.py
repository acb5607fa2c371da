"""Sanity checks of a take: one clear error per way a recording can be wrong."""

import numpy as np
import pytest
import soundfile as sf

from mpipe.core.errors import UserError
from mpipe.measurement.takes import read_take
from mpipe.reed.recorder import RecorderOptions
from mpipe.reed.recording import virtual_recording
from tests.measurement.take_helpers import FS, signals, write_calibration


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
    vt = virtual_recording(
        *signals(), FS, cal, recorder=RecorderOptions(snr_db=50.0, bits=24, fs_out=48_000.0)
    )
    path, cal2 = _write_mono_take(tmp_path, vt, cal, columns, scale=scale, edit=edit)
    with pytest.raises(UserError, match=message) as info:
        read_take(path, cal2)
    assert "\n" not in str(info.value)


def test_sanity_checks_pass_a_good_take_at_any_snr(tmp_path, shipped_calibration):
    # no false alarm on physical takes: several seeds and noise levels, 16-bit included
    cal = shipped_calibration
    p, u = signals()
    for seed, snr, bits in ((0, 30.0, 16), (1, 45.0, 24), (2, 70.0, 24)):
        vt = virtual_recording(
            p,
            u,
            FS,
            cal,
            recorder=RecorderOptions(snr_db=snr, bits=bits, seed=seed, fs_out=48_000.0),
        )
        path, cal2 = _write_mono_take(tmp_path, vt, cal, (0, 1, 2))
        read_take(path, cal2)


def test_a_float_file_above_one_is_not_clipped(tmp_path, shipped_calibration):
    # Issue 19: a float WAV holds samples beyond 1.0 as they are: a take peaking at 3 x
    # full scale (sensitivities a third) reads as the same pressures, no clipping reported.
    cal = shipped_calibration
    vt = virtual_recording(
        *signals(), FS, cal, recorder=RecorderOptions(snr_db=50.0, bits=24, fs_out=48_000.0)
    )
    path, cal_ok = _write_mono_take(tmp_path, vt, cal, (0, 1, 2))
    ref = read_take(path, cal_ok)
    (tmp_path / "big").mkdir()
    big, cal_big = _write_mono_take(
        tmp_path / "big", vt, cal, (0, 1, 2), scale=(1 / 3, 1 / 3, 1 / 3), edit=lambda d: 3 * d
    )
    assert np.max(np.abs(sf.read(big)[0])) > 1.0
    take = read_take(big, cal_big)
    assert take.clip_fraction == (0.0, 0.0, 0.0)
    np.testing.assert_allclose(take.pressures, ref.pressures, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("snr", [None, "40"])
def test_a_take_with_no_note_says_no_note_found(tmp_path, capsys, snr):
    # a synth-take whose mouth pressure (300 Pa) stays under the blowing threshold: the bore
    # holds a static pressure (blamed as a DC offset) and rings only at the onset
    from pathlib import Path

    from mpipe.cli.main import main

    root = Path(__file__).resolve().parents[2]
    reed = (root / "calibration" / "reed_table1.yaml").read_text()
    (tmp_path / "soft.yaml").write_text(reed.replace("p_m: 1800.0", "p_m: 300.0"))
    argv = ["synth-take", str(root / "calibration" / "simplified_clarinet.yaml"), "--reed",
            str(tmp_path / "soft.yaml"), "--duration", "0.3", "--fs-model", "50000",
            "-o", str(tmp_path / "q.flac")]  # fmt: skip
    assert main(argv + (["--snr", snr] if snr else [])) == 0
    capsys.readouterr()
    pipe = root / "pipelines" / "simplified_clarinet.yaml"
    assert main(["run", str(pipe), str(tmp_path / "q.flac"), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "q.flac: no note found" in err, err
    assert "below the 10 Pa" in err and "DC offset" not in err and "suspect" not in err
    level = float(err.split("oscillates by ")[1].split(" Pa")[0])
    assert level < 1.0  # the truth: no oscillation past the onset


def test_all_channels_inverted_is_named_as_the_cause(tmp_path, capsys):
    # a synth-take with every channel's sign flipped: Z = P / U (the validation) is unchanged
    # and the inversion blamed the reed; the shut reed's flow floor becomes a ceiling
    from pathlib import Path

    from mpipe.cli.main import main

    root = Path(__file__).resolve().parents[2]
    argv = ["synth-take", str(root / "calibration" / "simplified_clarinet.yaml"), "--reed",
            str(root / "calibration" / "reed_table1.yaml"), "--duration", "0.3",
            "--fs-model", "50000", "-o", str(tmp_path / "t.flac")]  # fmt: skip
    assert main(argv) == 0
    x, fs = sf.read(tmp_path / "t.flac")
    sf.write(tmp_path / "n.flac", -x, fs, subtype="PCM_24")
    (tmp_path / "n.calibration.yaml").write_text((tmp_path / "t.calibration.yaml").read_text())
    capsys.readouterr()
    pipe = root / "pipelines" / "simplified_clarinet.yaml"
    assert main(["run", str(pipe), str(tmp_path / "n.flac"), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "all channels' polarity inverted" in err, err
    assert not (tmp_path / "out" / "n" / "inversion" / "windows.csv").exists()
    # the same take as recorded passes the check (its floor, not its ceiling, holds)
    from mpipe.measurement.take_checks import plateau_fractions

    truth = np.load(tmp_path / "t.truth.npz")
    floor, ceiling = plateau_fractions(truth["u"], truth["p"], float(truth["fs"]))
    assert floor > 3 * ceiling
