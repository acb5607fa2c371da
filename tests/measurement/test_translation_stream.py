"""The translation on disk, block by block, against the whole-array translate()."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mpipe.core.filters import LOWPASS_BLOCK
from mpipe.core.signals import DiskArray, NpzStream, open_npz
from mpipe.measurement.calibration import load_calibration
from mpipe.measurement.translation import TranslationConfig, translate
from mpipe.measurement.translation_stream import signal_moments, translate_to_npz

CAL = load_calibration(Path(__file__).parents[2] / "calibration" / "simplified_clarinet.yaml")
FS = 25_000.0


def test_streamed_translation_equals_the_whole_array_one(tmp_path):
    # longer than one low-pass block and several translation blocks, dividing neither
    n = LOWPASS_BLOCK + 12_345
    rng = np.random.default_rng(3)
    p0, u0 = 100 * rng.standard_normal(n), 1e-4 * rng.standard_normal(n)
    temps = 20.0 + 1.5 * np.sin(np.linspace(0, 3, n))  # drifting: several nodes
    with NpzStream(tmp_path / "reference.npz") as out:
        for name, x in (("p0", p0), ("u0", u0), ("temperature_c", temps)):
            out.add(name, x)
    ref = open_npz(tmp_path / "reference.npz", lazy_bytes=0)
    assert isinstance(ref["p0"], DiskArray)
    cfg = TranslationConfig()
    rms = translate_to_npz(
        tmp_path / "mouthpiece.npz", ref["p0"], ref["u0"], ref["temperature_c"], FS, CAL, cfg,
        extra={"note": np.arange(3)},
    )  # fmt: skip
    whole = translate(p0, u0, FS, CAL, cfg, temps)
    with np.load(tmp_path / "mouthpiece.npz") as got:
        for name in ("p", "u", "p0", "u0", "temperature_c"):
            np.testing.assert_array_equal(got[name], getattr(whole, name), err_msg=name)
        assert float(got["fs"]) == FS and list(got["note"]) == [0, 1, 2]
    np.testing.assert_allclose(rms["p_rms_pa"], np.std(whole.p), rtol=1e-12)
    assert not list(tmp_path.glob(".translation.*"))  # the scratch files are gone


def test_moments_in_blocks_are_numpys():
    x = np.random.default_rng(1).standard_normal(2_500_001) + 3.0
    mean, std = signal_moments(x)
    np.testing.assert_allclose([mean, std], [np.mean(x), np.std(x)], rtol=1e-12)
