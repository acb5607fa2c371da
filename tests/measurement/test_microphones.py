"""Microphone sensitivity: from the measuring chain, and the warning on implausible levels."""

import logging
import math

import numpy as np
import pytest

from mpipe.cli.main import main
from mpipe.measurement.microphones import level_warning, sensitivity_from_chain
from mpipe.measurement.takes import read_take
from tests.conftest import SHIPPED


def test_sensitivity_from_the_measuring_chain():
    # 50 mV/Pa, +20 dB, 1 V at full scale: full scale is 0.1 V at the microphone, i.e. 2 Pa
    assert sensitivity_from_chain(50.0, 20.0, 1.0) == pytest.approx(2.0, rel=1e-12)
    # limit case: no gain, 1 V/Pa microphone, 1 V full scale -> 1 Pa per unit
    assert sensitivity_from_chain(1000.0, 0.0, 1.0) == pytest.approx(1.0, rel=1e-12)
    # 6.0206 dB more gain halves the pressure a full-scale sample stands for
    ratio = sensitivity_from_chain(12.5, 26.0206, 2.0) / sensitivity_from_chain(12.5, 20.0, 2.0)
    assert ratio == pytest.approx(0.5, rel=1e-5)
    with pytest.raises(ValueError, match="mic_mv_per_pa"):
        sensitivity_from_chain(0.0)


def test_sensitivity_command_prints_the_value(capsys):
    assert main(["calibrate", "sensitivity", "--mv-per-pa", "50", "--gain-db", "20",
                 "--full-scale-v", "1"]) == 0  # fmt: skip
    assert "sensitivity: 2   #" in capsys.readouterr().out
    # +4 dBu is 1.228 V RMS, 1.737 V peak at full scale
    assert main(["calibrate", "sensitivity", "--mv-per-pa", "1000", "--full-scale-dbu", "4"]) == 0
    value = float(capsys.readouterr().out.split()[1])
    assert value == pytest.approx(0.7746 * 10**0.2 * math.sqrt(2), rel=1e-4)


def test_implausible_take_level_is_warned(tmp_path, caplog):
    from mpipe.cli.virtual_takes import SynthOptions, make_take
    from mpipe.measurement.calibration import load_calibration

    assert level_warning(np.array([1500.0, -2000.0])) is None
    assert "far below" in level_warning(np.array([0.5, -0.4]), "t.flac")
    assert "far above" in level_warning(np.array([2e5]), "t.flac")
    # docs/python_api.md's trap: a virtual take read with the shipped calibration (sensitivity 1)
    take = make_take(SHIPPED, SHIPPED.parent / "reed_table1.yaml", tmp_path / "t.flac",
                     SynthOptions(duration_s=0.3, seed=1))  # fmt: skip
    with caplog.at_level(logging.WARNING, logger="mpipe.measurement.takes"):
        read_take(take.audio, load_calibration(SHIPPED))
    assert any("check microphones[].sensitivity" in r.message for r in caplog.records)
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="mpipe.measurement.takes"):
        read_take(take.audio, load_calibration(take.calibration))
    assert not any("sensitivity" in r.message for r in caplog.records)
