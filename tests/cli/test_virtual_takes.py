"""Virtual takes: rates an audio file cannot store are refused before any work."""

import pytest

from mpipe.cli.virtual_takes import SynthOptions, make_take
from tests.conftest import SHIPPED

REED = SHIPPED.parent / "reed_table1.yaml"


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
