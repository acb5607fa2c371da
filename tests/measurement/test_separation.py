"""Tests of the adaptive three-microphone wave separation (physics.md E).

The reference fields are built independently of mpipe.measurement.separation: the waves at the
reference plane are carried to the microphones with the cylinder transfer matrices of
mpipe.acoustics.ducts (no flow), or with the convected two-wave field written out (with flow).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from mpipe.acoustics import ducts
from mpipe.measurement.calibration import load_calibration
from mpipe.measurement.separation import (
    BLOCK_COLUMNS,
    Geometry,
    SeparationConfig,
    Theta,
    cross_spectra,
    fixed_config,
    null_vector,
    residual_cost,
    separate,
    separation_filters,
    wavenumbers,
    zk_excess,
)

CAL = load_calibration(Path(__file__).parents[2] / "calibration" / "simplified_clarinet.yaml")
FS = 25_000.0


def _offsets():
    return np.array([m.position for m in CAL.microphones]) - CAL.reference_plane


def mic_spectra(P0, U0, freqs, temperature_c=20.0, mach=0.0):
    """Microphone spectra of the field with P0, U0 at the reference plane."""
    air = CAL.air_properties(temperature_c)
    omega = 2 * np.pi * np.asarray(freqs, dtype=float)
    d = _offsets()
    if mach == 0.0:
        out = []
        for x in d:
            t_inv = ducts.invert(ducts.cylinder_matrix(omega, CAL.main_radius, x, air))
            out.append(t_inv[:, 0, 0] * P0 + t_inv[:, 0, 1] * U0)
        return np.stack(out, axis=-1)
    gamma, zc = ducts.propagation(omega, CAL.main_radius, air)
    k0 = -1j * gamma
    a, b = (P0 + zc * U0) / 2, (P0 - zc * U0) / 2
    kp, km = k0 / (1 + mach), k0 / (1 - mach)
    return a[:, None] * np.exp(-1j * kp[:, None] * d) + b[:, None] * np.exp(1j * km[:, None] * d)


def random_take(n, temperature_c=20.0, mach=0.0, seed=0):
    """Periodic band-limited random p0, u0 (20 Hz - 7.5 kHz) and the microphone signals."""
    rng = np.random.default_rng(seed)
    freqs = np.fft.rfftfreq(n, 1 / FS)
    z0 = CAL.air_properties(temperature_c).impedance(np.pi * CAL.main_radius**2)
    shape = ((freqs > 20) & (freqs < 7500)).astype(float)
    P0 = 1e-1 * shape * (rng.normal(size=freqs.size) + 1j * rng.normal(size=freqs.size))
    U0 = 1e-1 * shape * (rng.normal(size=freqs.size) + 1j * rng.normal(size=freqs.size)) / z0
    x = np.fft.irfft(mic_spectra(P0, U0, freqs, temperature_c, mach), n, axis=0)
    return x, np.fft.irfft(P0, n), np.fft.irfft(U0, n)


def band_nrmse(est, ref, fs=FS, lo=50.0, hi=7000.0, trim_s=0.05):
    """RMS error over RMS reference, both band-passed (zero phase), ends trimmed."""
    sos = signal.butter(4, [lo, hi], "bandpass", fs=fs, output="sos")
    trim = int(trim_s * fs)
    e = signal.sosfiltfilt(sos, est - ref)[trim:-trim]
    r = signal.sosfiltfilt(sos, ref)[trim:-trim]
    return float(np.sqrt(np.mean(e**2) / np.mean(r**2)))


def test_single_frequency_fields_separate_exactly():
    geo = Geometry.from_calibration(CAL)
    freqs = np.array([100.0, 440.0, 1234.5, 3000.0, 6999.0])
    P0 = np.array([1.0, 2.0 - 1j, 0.5j, 3.0, -1.0])
    U0 = np.array([1e-5, -2e-6j, 4e-6, 1e-6 + 1e-6j, 3e-7])
    for mach in (0.0, 0.01):
        th = Theta(CAL.air_properties(20.0).c, 1.0, mach)
        g_p, g_u = separation_filters(freqs, th, geo)
        mics = mic_spectra(P0, U0, freqs, 20.0, mach)
        np.testing.assert_allclose(np.sum(g_p * mics, axis=1), P0, rtol=1e-7, atol=1e-12)
        np.testing.assert_allclose(np.sum(g_u * mics, axis=1), U0, rtol=1e-7, atol=1e-16)


def test_flow_is_unmeasurable_at_dc():
    geo = Geometry.from_calibration(CAL)
    g_p, g_u = separation_filters(np.array([0.0, 50.0]), Theta(343.0), geo)
    assert np.all(g_u[0] == 0)
    # a uniform static pressure is reproduced
    np.testing.assert_allclose(np.sum(g_p[0]), 1.0, atol=1e-6)


@pytest.mark.parametrize("temperature_c, mach", [(20.0, 0.0), (27.0, 0.008)])
def test_residual_minimum_at_true_theta(temperature_c, mach):
    x, _, _ = random_take(4000, temperature_c, mach)
    geo = Geometry.from_calibration(CAL)
    margin = 125
    sp = cross_spectra(x[500 - margin : 2500 + margin], FS, 100.0, 7000.0, margin)
    true = Theta(CAL.air_properties(temperature_c).c, 1.0, mach)
    j0 = residual_cost(true, sp, geo)
    assert j0 < 1e-9 * np.mean(sp.mic_power)
    for d in (
        (0.3, 0, 0),
        (-0.3, 0, 0),
        (0, 0.1, 0),
        (0, -0.1, 0),
        (0, 0, 0.002),
        (0, 0, -0.002),
    ):
        other = Theta(true.c + d[0], true.eta + d[1], true.mach + d[2])
        assert residual_cost(other, sp, geo) > 100 * j0


def test_clean_take_reconstructs_and_estimates_theta():
    # (a) and (c) in short: air 5 degC off the configuration and Mach 0.01
    x, p0, u0 = random_take(int(0.6 * FS), temperature_c=25.0, mach=0.01)
    res = separate(x, FS, CAL, SeparationConfig())
    b = res.blocks[res.blocks.trusted]
    assert abs(np.median(b.temperature_c) - 25.0) < 0.1
    assert abs(np.median(b.mach) - 0.01) < 5e-4
    assert band_nrmse(res.p0, p0) < 5e-3
    assert band_nrmse(res.u0, u0) < 5e-3
    for col in BLOCK_COLUMNS:
        assert col in res.blocks
    assert (b.band_hi_hz <= SeparationConfig().fmax_hz).all() and (b.bins > 10).all()


def test_fixed_theta_matches_true_field():
    x, p0, u0 = random_take(int(0.4 * FS))
    res = separate(x, FS, CAL, fixed_config(SeparationConfig()))
    assert np.allclose(res.blocks.temperature_c, 20.0)
    assert band_nrmse(res.p0, p0) < 1e-3
    assert band_nrmse(res.u0, u0) < 1e-3


def test_drifting_temperature_is_tracked():
    # (d) in short: the take is cut from two fields 3 degC apart, cross-faded linearly
    n = int(1.2 * FS)
    a, _, _ = random_take(n, 20.0, seed=3)
    b, _, _ = random_take(n, 23.0, seed=3)
    w = np.linspace(0, 1, n)[:, None]
    x = (1 - w) * a + w * b
    res = separate(x, FS, CAL, SeparationConfig(mach=0.0))
    bl = res.blocks[res.blocks.trusted]
    truth = 20.0 + 3.0 * bl.time_s / (n / FS)
    # a cross-fade of two temperatures is not one temperature; allow for that
    assert np.max(np.abs(bl.temperature_c - truth)) < 0.4
    assert bl.temperature_c.iloc[-1] - bl.temperature_c.iloc[0] > 2.4


def test_config_checks_and_bad_input():
    with pytest.raises(ValueError, match="fmax_hz"):
        SeparationConfig(fmin_hz=5000.0, fmax_hz=100.0).validate()
    with pytest.raises(ValueError, match="temperature_bounds_c"):
        SeparationConfig(temperature_bounds_c=(30.0, 10.0)).validate()
    with pytest.raises(ValueError, match="shape"):
        separate(np.zeros((100, 2)), FS, CAL, SeparationConfig())
    with pytest.raises(ValueError, match="singular"):
        separate(
            np.zeros((1000, 3)),
            FS,
            CAL,
            dataclasses.replace(SeparationConfig(), band_edge_hz=8500.0),
        )


def _noisy(x, snr_db, seed, ratios=(1.0, 1.05, 0.93)):
    rng = np.random.default_rng(seed)
    std = np.sqrt(np.mean(x**2, axis=0)) * 10 ** (-snr_db / 20) * np.array(ratios)
    return x + rng.normal(size=x.shape) * std


def test_noisy_estimates_are_right_within_their_standard_errors():
    # Broadband field at 24 degC, 40 dB SNR, channel noise levels a few per cent apart.
    # For at least 4 of 5 noise seeds: every smoothed temperature is within 3 of its
    # standard errors of the truth, eta within 3 standard errors of 1, and the standard
    # errors are honest: the scatter of the raw per-block estimates is within a factor
    # 2.5 of their stated standard error (the curvature of the likelihood).
    x, _, _ = random_take(int(0.6 * FS), temperature_c=24.0, seed=7)
    ok = 0
    for seed in range(5):
        res = separate(_noisy(x, 40.0, seed), FS, CAL, SeparationConfig(mach=0.0))
        b = res.blocks[res.blocks.trusted]
        err = np.abs(b.temperature_c - 24.0)
        ratio = float(np.std(b.temperature_raw_c) / np.median(b.temperature_raw_se_c))
        ok += bool(
            np.all(err < 3 * b.temperature_se_c + 0.02)
            and np.median(b.temperature_se_c) < 0.3
            and abs(np.median(b.loss_scale) - 1.0) < 3 * np.median(b.loss_scale_se)
            and 0.4 < ratio < 2.5
        )
    assert ok >= 4


def test_estimate_on_a_bound_is_a_warning(caplog):
    # the true loss scale 1 lies outside these bounds: eta sits on its upper bound
    x, _, _ = random_take(int(0.4 * FS), seed=2)
    cfg = SeparationConfig(mach=0.0, loss_bounds=(0.5, 0.8), loss_prior=None)
    with caplog.at_level("WARNING"):
        res = separate(x, FS, CAL, cfg)
    b = res.blocks[res.blocks.fitted]
    assert b.at_bound.str.contains("eta").all()
    assert res.bound_warnings() and "eta estimate on its bound" in caplog.text


def test_temperature_uses_the_calibrations_air_model():
    # an 'ernoult' calibration: the field is made with its air, and the estimate is read
    # back with its own inverse (the Keefe inverse would be ~0.6 degC off)
    cal = dataclasses.replace(CAL, air=dataclasses.replace(CAL.air, model="ernoult"))
    air = cal.air_properties(22.0)
    n = int(0.4 * FS)
    rng = np.random.default_rng(4)
    freqs = np.fft.rfftfreq(n, 1 / FS)
    shape = ((freqs > 20) & (freqs < 7500)).astype(float)
    P0 = 0.1 * shape * (rng.normal(size=freqs.size) + 1j * rng.normal(size=freqs.size))
    U0 = P0 * rng.normal(size=freqs.size) / air.impedance(np.pi * CAL.main_radius**2)
    omega = 2 * np.pi * freqs
    out = []
    for d in _offsets():
        t_inv = ducts.invert(ducts.cylinder_matrix(omega, CAL.main_radius, d, air))
        out.append(t_inv[:, 0, 0] * P0 + t_inv[:, 0, 1] * U0)
    x = np.fft.irfft(np.stack(out, axis=-1), n, axis=0)
    res = separate(x, FS, cal, SeparationConfig(mach=0.0))
    b = res.blocks[res.blocks.trusted]
    assert abs(np.median(b.temperature_c) - 22.0) < 0.05
    assert np.allclose(b.c_m_s, [cal.air_properties(t).c for t in b.temperature_c])


@pytest.mark.parametrize("seed", [0, 1])
def test_flow_noise_psd_matches_the_noise_through_the_chain(seed):
    # White noise alone on the three microphones, separated and translated with fixed
    # propagation parameters: the Welch PSD of the resulting u matches the propagated
    # u_noise_psd (an independent, empirical second method) within 25 % over 100-5000 Hz,
    # and rises towards low frequency (the 1 / (k s) amplification).
    from mpipe.measurement.translation import TranslationConfig, mouthpiece_noise, translate

    rng = np.random.default_rng(seed)
    n = int(1.0 * FS)
    std = np.array([1.0, 1.1, 0.9])
    x = rng.normal(size=(n, 3)) * std
    cfg = fixed_config(SeparationConfig())
    res = separate(x, FS, CAL, cfg)
    tr = translate(res.p0, res.u0, FS, CAL, TranslationConfig(), 20.0)
    f, pxx = signal.welch(tr.u[2000:-2000], FS, nperseg=1024)
    noise = mouthpiece_noise(FS, CAL, 2 * std**2 / FS, res.median_theta(), 20.0, cfg)
    want = np.interp(f, noise["u_noise_freq_hz"], noise["u_noise_psd"])
    band = (f > 100) & (f < 5000)
    # averaged over 5 bins (~120 Hz): the Welch estimate of ~45 averages scatters by ~15 %
    ratio = np.convolve(pxx[band] / want[band], np.ones(5) / 5, "valid")
    assert 0.85 < np.median(ratio) < 1.15
    assert np.all((ratio > 0.7) & (ratio < 1.4))
    # the measured noise level of the separation agrees with what was added
    np.testing.assert_allclose(res.noise_psd, 2 * std**2 / FS, rtol=0.1)
    low = np.interp(100.0, noise["u_noise_freq_hz"], noise["u_noise_psd"])
    mid = np.interp(1000.0, noise["u_noise_freq_hz"], noise["u_noise_psd"])
    assert low > 10 * mid


def _field(offsets, P0, U0, freqs, temperature_c=20.0):
    """Analytic two-wave field at any positions (cylinder transfer matrices, no flow)."""
    air = CAL.air_properties(temperature_c)
    omega = 2 * np.pi * np.asarray(freqs, dtype=float)
    out = []
    for x in offsets:
        t_inv = ducts.invert(ducts.cylinder_matrix(omega, CAL.main_radius, x, air))
        out.append(t_inv[:, 0, 0] * P0 + t_inv[:, 0, 1] * U0)
    return np.stack(out, axis=-1)


@pytest.mark.parametrize("offsets", [(0.0, 0.02), (0.0, 0.02, 0.04), (0.0, 0.013, 0.031, 0.05)])
def test_any_number_of_microphones_separates_the_analytic_field(offsets):
    # Held propagation parameters (the configured ones): 2 microphones give the exact
    # solution, 3 and 4 the least-squares one; all reproduce P0 and U0 of the analytic field
    # away from the singular frequencies, and leave no projection residual.
    from mpipe.measurement.separation import model_matrix, projection_residual, singular_frequencies

    geo = dataclasses.replace(Geometry.from_calibration(CAL), offsets=np.array(offsets))
    th = Theta(CAL.air_properties(20.0).c, 1.0, 0.0)
    rng = np.random.default_rng(len(offsets))
    freqs = np.sort(rng.uniform(30.0, 7000.0, 40))
    sing = singular_frequencies(geo, th, 20_000.0)
    freqs = freqs[np.all(np.abs(freqs[:, None] - sing[None, :]) > 200.0, axis=1)]
    P0 = rng.normal(size=freqs.size) + 1j * rng.normal(size=freqs.size)
    U0 = (rng.normal(size=freqs.size) + 1j * rng.normal(size=freqs.size)) * 1e-5
    mics = _field(offsets, P0, U0, freqs)
    g_p, g_u = separation_filters(freqs, th, geo)
    np.testing.assert_allclose(np.sum(g_p * mics, axis=1), P0, rtol=1e-7, atol=1e-10)
    np.testing.assert_allclose(np.sum(g_u * mics, axis=1), U0, rtol=1e-7, atol=1e-15)
    omega = 2 * np.pi * freqs
    ex = zk_excess(omega, geo, th.c)[0]
    h = model_matrix(*wavenumbers(omega, th, ex), geo.offsets)
    res = projection_residual(mics, h)
    assert np.max(np.abs(res)) < 1e-9 * np.max(np.abs(mics))
    # random data: zero residual for 2 microphones (exact), the null-vector form for 3
    noise = rng.normal(size=mics.shape) + 1j * rng.normal(size=mics.shape)
    r = projection_residual(noise, h)
    if len(offsets) == 2:
        assert np.max(np.abs(r)) < 1e-9
        # singular every c / (2 s): 8.6, 17.2 kHz for 2 cm at 20 degC
        np.testing.assert_allclose(sing, [th.c / 0.04, th.c / 0.02], rtol=1e-12)
    elif len(offsets) == 3:
        n = null_vector(h)
        want = np.abs(np.sum(n * noise, axis=1)) ** 2
        np.testing.assert_allclose(np.sum(np.abs(r) ** 2, axis=1), want, rtol=1e-9)
        np.testing.assert_allclose(sing, [th.c / 0.04, th.c / 0.02], rtol=1e-12)  # equal
    else:
        assert sing.size == 0  # incommensurate spacings: never singular below 20 kHz
        assert np.all(np.sum(np.abs(r) ** 2, axis=1) > 0)
