import numpy as np
import yaml

from mpipe.acoustics.reflection import reflection_function
from mpipe.measurement.calibration import load_calibration
from mpipe.measurement.pitch import yin_f0
from mpipe.reed.bore_kernel import prepare_bore
from mpipe.reed.controls import make_controls, play
from mpipe.reed.fingered_bore import fingered_bore
from mpipe.reed.score import score_from_mapping, score_mapping
from tests.reed.conftest import ROOT

FS = 44_100.0
_BUILT: dict = {}


def _kernels(names):
    """The four-hole instrument's kernels of ``names`` at FS (built once per test session)."""
    cal = load_calibration(ROOT / "calibration" / "four_hole_clarinet.yaml")
    air = cal.air_properties()
    for n in names:
        if n not in _BUILT:
            rf = reflection_function(cal.with_fingering(n).bore, air, fs=FS)
            _BUILT[n] = prepare_bore(rf, air)
    return [_BUILT[n] for n in names]


def test_a_score_with_a_fingering_per_note_round_trips():
    score = score_from_mapping(
        {"finger_s": 0.004, "notes": [{"duration": 0.3, "fingering": "xxoo"},
                                      {"duration": 0.3}, {"duration": 0.3, "fingering": "xooo"}]}
    )  # fmt: skip
    plain = yaml.safe_load(yaml.safe_dump(score_mapping(score)))
    assert score_from_mapping(plain) == score
    assert score.fingerings("xxxx") == ["xxoo", "xxoo", "xooo"]
    assert score_from_mapping({"notes": [{"duration": 0.3}]}).fingerings("xxxx") == ["xxxx"]


def test_a_change_cross_fades_the_kernels_between_the_fingerings():
    a, b = _kernels(["xxxx", "xxoo"])
    n = int(0.1 * FS)
    bore = fingered_bore([a, b], [0.0, 0.05], [0, 1], 0.005, n)
    (ka, kb) = bore.kernels
    assert bore.kernel(0, 100) is ka and bore.kernel(n - 100, n) is kb
    cuts = bore.cuts(n)
    inside = [c for c in cuts if 0.045 * FS <= c <= 0.05 * FS]
    assert len(inside) >= 5  # at least 1 ms pieces over the 5 ms change
    i = int(0.0475 * FS)  # the middle of the change: half of each
    mid = bore.kernel(i - 10, i + 10)
    np.testing.assert_allclose(mid.h, 0.5 * (ka.h + kb.h), atol=2e-3 * np.abs(ka.h).max())


def test_a_slur_plays_each_fingerings_note(setup):
    # the slurred take plays, before and after the change, the note each fingering plays
    # alone (independent single-fingering runs), within 5 cents
    *_, reed, _, _ = setup
    kernels = _kernels(["xxxx", "xxoo"])
    n = int(0.4 * FS)
    ctl = make_controls(FS, n, reed.p_m)
    slur = play(
        reed, kernels[0], ctl, fingered=fingered_bore(kernels, [0.0, 0.2], [0, 1], 0.005, n)
    )
    t = np.arange(1, n + 1) / FS
    for k, (a, b) in zip(kernels, [(0.12, 0.195), (0.32, 0.395)], strict=True):
        alone = play(reed, k, ctl)
        span = (t > a) & (t < b)
        f_slur = yin_f0(slur.p[span], FS, 60.0, 1000.0)[0]
        f_alone = yin_f0(alone.p[span], FS, 60.0, 1000.0)[0]
        assert abs(1200 * np.log2(f_slur / f_alone)) < 5.0, (f_slur, f_alone)
