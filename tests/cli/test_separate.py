"""``mpipe separate`` on the block path: the whole-array path's numbers."""

import numpy as np

from mpipe.cli.main import main
from mpipe.cli.virtual_takes import SynthOptions, make_take
from mpipe.measurement.calibration import load_calibration
from mpipe.measurement.separation.settings import SeparationConfig
from mpipe.measurement.separation.stage import separate
from mpipe.measurement.takes import read_take
from mpipe.measurement.translation import TranslationConfig, translate
from tests.cli.test_bad_inputs import CAL, REED


def test_separate_writes_the_whole_array_paths_mouthpiece_signals(tmp_path, monkeypatch):
    # a 0.45 s take at 48 kHz (resampled to 100 kHz when read): the command's signals,
    # separated and translated block by block on disk (the whole-array functions it used
    # are refused), equal the whole-array functions'
    import mpipe.cli.commands.separate as command

    files = make_take(CAL, REED, tmp_path / "take.flac",
                      SynthOptions(duration_s=0.45, seed=5, fs_out=48000.0))  # fmt: skip
    cal = load_calibration(files.calibration)
    take = read_take(files.audio, cal, fs=100_000.0)
    sep = separate(take.pressures, take.fs, cal, SeparationConfig(), take.band_limit_hz)
    tr = translate(sep.p0, sep.u0, take.fs, cal, TranslationConfig(), sep.temperature_track())

    def whole(*args, **kwargs):
        raise AssertionError("the whole-array path")

    for name in ("separate", "translate"):
        monkeypatch.setattr(command, name, whole, raising=False)
    out = tmp_path / "sep"
    assert main(["separate", str(files.audio), str(files.calibration), "-o", str(out)]) == 0
    with np.load(out / "mouthpiece.npz") as got:
        assert float(got["fs"]) == take.fs
        for name in ("p", "u", "p0", "u0", "temperature_c"):
            whole = getattr(tr, name)
            assert got[name].shape == whole.shape, name
            assert np.max(np.abs(got[name] - whole)) <= 1e-9 * np.max(np.abs(whole)), name
        assert "u_noise_psd" in got
    assert not [p.name for p in out.iterdir() if p.name.startswith(".separate")]
