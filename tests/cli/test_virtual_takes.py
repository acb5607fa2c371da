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
