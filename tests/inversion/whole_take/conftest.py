"""A short separated take and its front end, shared by the front-end share's tests."""

import dataclasses

import numpy as np
import pytest

from mpipe.cli.examples import EXAMPLE_CALIBRATION, EXAMPLE_REED
from mpipe.cli.virtual_takes import SynthOptions, make_take
from mpipe.core.config import Where
from mpipe.inversion.settings import InversionConfig
from mpipe.inversion.whole_take.estimator import TakeData
from mpipe.inversion.whole_take.front_end import FrontEnd, MouthpieceNoise
from mpipe.inversion.whole_take.take_fit import fit_take
from mpipe.inversion.whole_take.tracking import WindowPlan
from mpipe.measurement.calibration import load_calibration
from mpipe.measurement.separation.settings import SeparationConfig
from mpipe.measurement.separation.stage import separate
from mpipe.measurement.takes import read_take
from mpipe.measurement.translation import TranslationConfig, mouthpiece_noise, translate
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
    noise = mouthpiece_noise(take.fs, cal, sep.noise_psd, sep.median_theta(),
                             float(np.median(tr.temperature_c)), sep_cfg,
                             TranslationConfig())  # fmt: skip
    front = FrontEnd(tr.p0, tr.u0, tr.temperature_c, sep.track.level, sep.track.level_se,
                     sep_cfg.band_edge_hz + sep_cfg.band_taper_hz, TranslationConfig(),
                     sep.track.level_cov, MouthpieceNoise.of(noise))  # fmt: skip
    with np.load(files.truth) as d:
        truth = {k[5:]: float(d[k]) for k in d.files if k.startswith("reed_") and d[k].ndim == 0}
    return cal, take.fs, tr, front, reed_from_mapping(truth, Where("truth"))


@pytest.fixture(scope="session")
def short_fit(short_take):
    """The short take's windows, one every window length, and a take fit of them on any p, u.

    Returns ``(config, t0, fit)``: ``fit(p, u, with_front=True, mean=t0)`` fits the take
    fit to ``p, u`` with the front end (or none) and the temperature's prior at ``mean``.
    """
    cal, fs, tr, front, _ = short_take
    config = dataclasses.replace(InversionConfig(), sample_rate=fs, contact="fixed")
    n = int(round(config.window_s * fs))
    plan = WindowPlan.of(list(range(int(0.15 * fs), len(tr.p) - int(0.05 * fs) - n, n)))
    t0, se_t = float(np.median(tr.temperature_c)), float(front.level_se[0])

    def fit(p, u, with_front=True, mean=t0):
        data = TakeData(p, u, fs, cal, plan, config, True, front=front if with_front else None)
        return fit_take(data, prior=(mean, se_t), t_range=(t0 - 5, t0 + 5))

    return config, t0, fit
