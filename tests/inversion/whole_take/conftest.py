"""A short separated take and its front end, shared by the front-end share's tests."""

import numpy as np
import pytest

from mpipe.cli.examples import EXAMPLE_CALIBRATION, EXAMPLE_REED
from mpipe.cli.virtual_takes import SynthOptions, make_take
from mpipe.core.config import Where
from mpipe.inversion.whole_take.front_end import FrontEnd
from mpipe.measurement.calibration import load_calibration
from mpipe.measurement.separation.settings import SeparationConfig
from mpipe.measurement.separation.stage import separate
from mpipe.measurement.takes import read_take
from mpipe.measurement.translation import TranslationConfig, translate
from mpipe.reed.parameters import reed_from_mapping


@pytest.fixture(scope="session")
def short_take(tmp_path_factory):
    """A 0.6 s take of the example reed through synth-take, separation and translation.

    Returns ``(calibration, fs, translation, front end, true reed)``.
    """
    folder = tmp_path_factory.mktemp("frontend")
    files = make_take(EXAMPLE_CALIBRATION, EXAMPLE_REED, folder / "take.flac",
                      SynthOptions(duration_s=0.6, snr_db=45, seed=1))  # fmt: skip
    cal = load_calibration(files.calibration)
    sep_cfg = SeparationConfig()
    take = read_take(files.audio, cal, fs=44100.0)
    sep = separate(take.pressures, take.fs, cal, sep_cfg, take.band_limit_hz)
    tr = translate(sep.p0, sep.u0, take.fs, cal, TranslationConfig(), sep.temperature_track())
    front = FrontEnd(tr.p0, tr.u0, tr.temperature_c, sep.track.level, sep.track.level_se,
                     sep_cfg.band_edge_hz + sep_cfg.band_taper_hz, TranslationConfig(),
                     sep.track.level_cov)  # fmt: skip
    with np.load(files.truth) as d:
        truth = {k[5:]: float(d[k]) for k in d.files if k.startswith("reed_") and d[k].ndim == 0}
    return cal, take.fs, tr, front, reed_from_mapping(truth, Where("truth"))
