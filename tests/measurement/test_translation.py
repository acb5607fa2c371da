"""Tests of the translation from the reference plane to the mouthpiece entry (physics.md F.1)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings

from mpipe.acoustics import ducts
from mpipe.acoustics.bore import input_impedance
from mpipe.core.filters import apply_lowpass, design_lowpass
from mpipe.measurement.calibration import load_calibration
from mpipe.measurement.translation import TranslationConfig, translate
from tests import lengths

CAL = load_calibration(Path(__file__).parents[2] / "calibration" / "simplified_clarinet.yaml")
FS = 25_000.0


def _mouthpiece_field(n, seed=0, temperature_c=20.0):
    """Periodic broadband U at the mouthpiece, P = Z_in U, and the field at x_ref.

    The reference-plane field is obtained segment by segment with the inverse cylinder and
    cone matrices of mpipe.acoustics.ducts, independently of mpipe.acoustics.bore.transfer_matrix.
    """
    rng = np.random.default_rng(seed)
    freqs = np.fft.rfftfreq(n, 1 / FS)
    omega = 2 * np.pi * np.maximum(freqs, 1e-3)
    air = CAL.air_properties(temperature_c)
    U = (
        1e-6
        * ((freqs > 20) & (freqs < 7000))
        * (rng.normal(size=freqs.size) + 1j * rng.normal(size=freqs.size))
    )
    P = input_impedance(CAL.bore, omega, air) * U
    state = np.stack([P, U], axis=-1)[..., None]
    for seg in CAL.bore.between(0.0, CAL.reference_plane):
        t = ducts.cone_matrix(omega, seg.r_in, seg.r_out, seg.length, air)
        state = ducts.invert(t) @ state
    P0, U0 = state[:, 0, 0], state[:, 1, 0]
    return (np.fft.irfft(s, n) for s in (P, U, P0, U0))


def test_translation_reproduces_mouthpiece_field():
    p, u, p0, u0 = _mouthpiece_field(int(0.5 * FS))
    # the circular reference field is periodic; translate three periods, compare the middle
    n = p.size
    res = translate(np.tile(p0, 3), np.tile(u0, 3), FS, CAL, TranslationConfig())
    lp = design_lowpass(FS)
    ref_p = apply_lowpass(np.tile(p, 3), lp)[n : 2 * n]
    ref_u = apply_lowpass(np.tile(u, 3), lp)[n : 2 * n]
    err_p = np.sqrt(np.mean((res.p[n : 2 * n] - ref_p) ** 2) / np.mean(ref_p**2))
    err_u = np.sqrt(np.mean((res.u[n : 2 * n] - ref_u) ** 2) / np.mean(ref_u**2))
    assert err_p < 1e-4
    assert err_u < 1e-4


def test_drifting_temperature_interpolates_between_nodes():
    p, u, p0, u0 = _mouthpiece_field(int(0.3 * FS), temperature_c=22.0)
    n = p.size
    const = translate(np.tile(p0, 3), np.tile(u0, 3), FS, CAL, TranslationConfig(), 22.0)
    ramp = translate(
        np.tile(p0, 3),
        np.tile(u0, 3),
        FS,
        CAL,
        TranslationConfig(temperature_step_c=0.5),
        np.full(3 * n, 22.0) + np.linspace(-1e-9, 1e-9, 3 * n),
    )
    np.testing.assert_allclose(ramp.p, const.p, atol=1e-6 * np.max(np.abs(const.p)))


def test_translation_is_identity_at_reference_plane_length_zero_limit():
    # With the mouthpiece signals low-passed, p0 and u0 come out low-passed as well.
    x = np.random.default_rng(1).normal(size=4000)
    res = translate(x, 1e-6 * x, FS, CAL, TranslationConfig())
    lp = design_lowpass(FS)
    np.testing.assert_allclose(res.p0, apply_lowpass(x, lp))


def test_bad_shapes():
    with pytest.raises(ValueError, match="equal length"):
        translate(np.zeros(10), np.zeros(11), FS, CAL, TranslationConfig())


# --- every length and rate (issue 19) -------------------------------------------------------


@given(
    duration_s=lengths.durations,
    fs=lengths.rates,
    extra=lengths.extras,
)
@settings(max_examples=10, deadline=None)
def test_translation_of_every_length_and_rate(duration_s, fs, extra):
    # A sine at the reference plane comes out at the mouthpiece as the transfer matrix at its
    # frequency says, for takes from 50 ms to 30 s (longer than 2 s: shortened to 2 s plus
    # the drawn remainder, the FFT's padding does not depend on the length) at 8-192 kHz.
    from mpipe.measurement.translation import reference_to_mouthpiece

    n = lengths.samples(duration_s, fs, extra, 2.0)
    cfg = TranslationConfig()
    if cfg.lowpass_hz + cfg.transition_hz >= 0.45 * fs:
        cfg = TranslationConfig(lowpass_hz=0.3 * fs, transition_hz=0.1 * fs)
    f = 40 * fs / 8000.0 if n > 0.2 * fs else 0.0
    t = np.arange(n) / fs
    z0 = CAL.air_properties(20.0).impedance(np.pi * CAL.main_radius**2)
    p0, u0 = 100 * np.cos(2 * np.pi * f * t), 100 / z0 * np.cos(2 * np.pi * f * t + 0.3)
    res = translate(p0, u0, fs, CAL, cfg, 20.0)
    assert res.p.shape == (n,) and res.u.shape == (n,) and res.temperature_c.shape == (n,)
    assert np.all(np.isfinite(res.p)) and np.all(np.isfinite(res.u))
    if f == 0.0:
        return
    m = reference_to_mouthpiece(np.array([f]), CAL, 20.0)[0]
    want_p = m[0, 0] * 100 + m[0, 1] * 100 / z0 * np.exp(0.3j)
    inner = slice(int(0.08 * fs), n - int(0.08 * fs))
    basis = np.column_stack([np.cos(2 * np.pi * f * t[inner]), -np.sin(2 * np.pi * f * t[inner])])
    a, b = np.linalg.lstsq(basis, res.p[inner], rcond=None)[0]
    got = a + 1j * b
    assert abs(got - want_p) < 0.01 * abs(want_p)


def test_a_take_of_several_blocks_has_no_seams():
    # Issue 19: the translation runs in FFT blocks (bounded memory); over a 4 s take (four
    # blocks) a sine comes out as the transfer matrix at its frequency says at every sample
    # away from the ends, the block seams included
    from mpipe.measurement.translation import reference_to_mouthpiece

    fs, f = 100_000.0, 310.0
    t = np.arange(400_000) / fs
    z0 = CAL.air_properties(20.0).impedance(np.pi * CAL.main_radius**2)
    res = translate(
        np.cos(2 * np.pi * f * t), np.cos(2 * np.pi * f * t + 0.3) / z0, fs, CAL,
        TranslationConfig(), 20.0,
    )  # fmt: skip
    m = reference_to_mouthpiece(np.array([f]), CAL, 20.0)[0]
    want = np.real((m[0, 0] + m[0, 1] * np.exp(0.3j) / z0) * np.exp(2j * np.pi * f * t))
    inner = slice(10_000, -10_000)
    assert np.max(np.abs(res.p - want)[inner]) < 2e-3 * np.max(np.abs(want))


def test_each_note_is_translated_through_its_own_fingering(tmp_path):
    # a register hole between the mouthpiece and the reference plane, open in the second
    # note only: one fingering for the take misses the model's p by percents in that note;
    # the translation per note gives it (the take by synth-take's engine, its truth p0, u0)
    from mpipe.core.filters import apply_lowpass
    from mpipe.measurement.translation import TranslationConfig, translate
    from mpipe.measurement.translation_notes import translate_per_note
    from tests.measurement.fingering_helpers import register_hole_take

    cal, take = register_hole_take(tmp_path)
    cfg = TranslationConfig()
    notes = [(0.0, 0.3, "xxxx"), (0.3, 0.6, "rxxxx")]
    per_note = translate_per_note(take.p0, take.u0, take.fs, cal, notes, cfg)
    one = translate(take.p0, take.u0, take.fs, cal, cfg)
    truth = apply_lowpass(take.p, one.lowpass)

    def error(p, span):
        a, b = (int(x * take.fs) for x in span)
        return np.max(np.abs(p[a:b] - truth[a:b])) / np.max(np.abs(truth[a:b]))

    assert error(per_note.p, (0.15, 0.28)) < 1e-3 and error(per_note.p, (0.45, 0.58)) < 1e-3
    assert error(one.p, (0.45, 0.58)) > 0.01  # the register hole matters here


def test_a_quiet_translation_does_not_repeat_its_line_on_the_console(caplog):
    # issue 42: the inversion's front-end budget re-translates the take once per quantity,
    # and each printed "translation: ..." again
    import logging

    from mpipe.measurement.calibration import load_calibration
    from mpipe.measurement.translation import TranslationConfig, translate

    root = Path(__file__).resolve().parents[2]
    cal = load_calibration(root / "calibration" / "simplified_clarinet.yaml")
    x = np.zeros(4096)
    caplog.set_level(logging.INFO, logger="mpipe.measurement.translation")
    translate(x, x, FS, cal, TranslationConfig(), quiet=True)
    assert "translation:" not in caplog.text
    translate(x, x, FS, cal, TranslationConfig())
    said = [r.getMessage() for r in caplog.records if r.getMessage().startswith("translation:")]
    assert len(said) == 1, said
