"""Virtual three-microphone recording: field, microphone errors, noise, quantisation, drift.

Every check compares against a reference computed independently of mpipe.reed.recording: the
analytic forward/backward waves of physics.md E.1 written out here, transfer matrices
applied with numpy.linalg.solve, or plain statistics of the output.
"""

import dataclasses

import numpy as np
import pytest

from mpipe.acoustics.bore import transfer_matrix
from mpipe.acoustics.ducts import propagation
from mpipe.reed.recorder import RecorderOptions
from mpipe.reed.recording import virtual_recording

FS = 100_000.0


def ramp(n, fs=FS, rise_s=0.01):
    """Raised-cosine fade in and out, so the input starts and ends at rest."""
    env = np.ones(n)
    k = int(rise_s * fs)
    env[:k] = 0.5 * (1 - np.cos(np.pi * np.arange(k) / k))
    env[-k:] = env[:k][::-1]
    return env


def tone(f0, P, U, duration=0.2, fs=FS):
    """p, u of a single frequency with complex amplitudes P (Pa), U (m^3/s), e^{+j w t}."""
    n = int(duration * fs)
    t = np.arange(n) / fs
    e = np.exp(2j * np.pi * f0 * t)
    env = ramp(n, fs)
    return (P * e).real * env, (U * e).real * env


def amplitude(x, f0, fs, t0, t1):
    """Complex amplitude of x at f0 over [t0, t1) (an integer number of periods)."""
    i0, i1 = int(round(t0 * fs)), int(round(t1 * fs))
    t = np.arange(i0, i1) / fs
    w = np.exp(-2j * np.pi * f0 * t)
    x = np.asarray(x)[i0:i1]
    return 2.0 * np.tensordot(w, x, axes=(0, 0)) / (i1 - i0)


def analytic_mics(cal, air, f0, P, U, mach):
    """Microphone pressures from mouthpiece amplitudes, written out from physics.md E.1."""
    w = np.array([2 * np.pi * f0])
    t = transfer_matrix(cal.bore, w, air, 0.0, cal.reference_plane)[0]
    p0, u0 = np.linalg.solve(t, [P, U])
    gamma, zc = propagation(w, cal.main_radius, air, cal.bore.losses)
    gamma, zc = gamma[0], zc[0]
    a, b = (p0 + zc * u0) / 2, (p0 - zc * u0) / 2
    out = []
    for mic in cal.microphones:
        d = mic.position - cal.reference_plane
        kp, km = -1j * gamma / (1 + mach), -1j * gamma / (1 - mach)
        out.append(a * np.exp(-1j * kp * d) + b * np.exp(1j * km * d))
    return np.array(out), p0, u0


@pytest.mark.parametrize("mach", [0.0, 0.01, -0.005])
def test_single_frequency_matches_analytic_waves(shipped_calibration, shipped_air, mach):
    cal, air = shipped_calibration, shipped_air
    f0, P, U = 1000.0, 800.0 * np.exp(0.3j), 6e-5 * np.exp(-1.1j)
    p, u = tone(f0, P, U)
    vt = virtual_recording(p, u, FS, cal, mach=mach)
    got = amplitude(vt.pressures, f0, FS, 0.06, 0.14)
    want, p0, u0 = analytic_mics(cal, air, f0, P, U, mach)
    np.testing.assert_allclose(got, want, rtol=1e-8)
    np.testing.assert_allclose(amplitude(vt.p0, f0, FS, 0.06, 0.14), p0, rtol=1e-8)
    np.testing.assert_allclose(amplitude(vt.u0, f0, FS, 0.06, 0.14), u0, rtol=1e-8)
    # unit sensitivity, no errors: the recorded signal is the pressure itself
    np.testing.assert_array_equal(vt.signals, vt.pressures)


def broadband(n, seed=3):
    """Band-limited noise below ~8 kHz, faded in and out, as p (Pa) and u (m^3/s)."""
    rng = np.random.default_rng(seed)
    spec = rng.standard_normal((2, n // 2 + 1)) + 1j * rng.standard_normal((2, n // 2 + 1))
    f = np.fft.rfftfreq(n, 1 / FS)
    spec *= 1.0 / (1.0 + (f / 8000.0) ** 8)
    x = np.fft.irfft(spec, n) * ramp(n)
    x /= np.std(x, axis=1, keepdims=True)
    return 500.0 * x[0], 5e-5 * x[1]


def test_no_flow_microphones_equal_transfer_matrices_from_reference_plane(
    shipped_calibration, shipped_air
):
    cal, air = shipped_calibration, shipped_air
    n = 30_000
    p, u = broadband(n)
    vt = virtual_recording(p, u, FS, cal)
    # reference: FFT of the reference-plane truth, carried with T(x_ref -> x_m)^{-1} by solve
    pad = 25_000
    n_fft = n + 2 * pad
    f = np.fft.rfftfreq(n_fft, 1 / FS)
    P0 = np.fft.rfft(np.pad(vt.p0, pad), n_fft)
    U0 = np.fft.rfft(np.pad(vt.u0, pad), n_fft)
    mid = slice(5000, n - 5000)
    scale = np.max(np.abs(vt.pressures))
    for i, mic in enumerate(cal.microphones):
        t = transfer_matrix(cal.bore, 2 * np.pi * f, air, cal.reference_plane, mic.position)
        pu = np.linalg.solve(t, np.stack([P0, U0], axis=-1)[..., None])[..., 0]
        ref = np.fft.irfft(pu[:, 0], n_fft)[pad : pad + n]
        err = np.max(np.abs(vt.pressures[mid, i] - ref[mid])) / scale
        assert err < 1e-6, (mic.name, err)
    # and the forward chain carries the reference plane back to the mouthpiece (F.1)
    t = transfer_matrix(cal.bore, 2 * np.pi * f, air, 0.0, cal.reference_plane)
    pu = t @ np.stack([P0, U0], axis=-1)[..., None]
    p_back = np.fft.irfft(pu[:, 0, 0], n_fft)[pad : pad + n]
    assert np.max(np.abs(p_back[mid] - p[mid])) / np.max(np.abs(p)) < 1e-6


def test_gain_and_phase_errors_appear_as_specified(shipped_calibration):
    f0 = 1500.0
    p, u = tone(f0, 600.0, 4e-5 * np.exp(0.7j))
    gains, phases = (0.0, 0.8, -1.3), (0.0, 2.5, -4.0)
    vt = virtual_recording(
        p,
        u,
        FS,
        shipped_calibration,
        recorder=RecorderOptions(gain_error_db=gains, phase_error_deg=phases),
    )
    ratio = amplitude(vt.signals, f0, FS, 0.06, 0.14) / amplitude(vt.pressures, f0, FS, 0.06, 0.14)
    np.testing.assert_allclose(20 * np.log10(np.abs(ratio)), gains, atol=1e-4)
    np.testing.assert_allclose(np.degrees(np.angle(ratio)), phases, atol=1e-3)


def test_sensitivity_divides_the_pressure(shipped_calibration):
    mics = tuple(
        dataclasses.replace(m, sensitivity=s)
        for m, s in zip(shipped_calibration.microphones, (2.0, 0.5, 10.0), strict=True)
    )
    cal = dataclasses.replace(shipped_calibration, microphones=mics)
    p, u = tone(700.0, 500.0, 3e-5)
    vt = virtual_recording(p, u, FS, cal)
    np.testing.assert_allclose(vt.signals * [2.0, 0.5, 10.0], vt.pressures, rtol=1e-12)


@pytest.mark.parametrize("snr_db", [20.0, 45.0])
def test_noise_snr_within_half_a_db(shipped_calibration, snr_db):
    p, u = broadband(20_000)
    clean = virtual_recording(p, u, FS, shipped_calibration)
    noisy = virtual_recording(
        p, u, FS, shipped_calibration, recorder=RecorderOptions(snr_db=snr_db, seed=7)
    )
    noise = noisy.signals - clean.signals
    snr = 10 * np.log10(np.sum(clean.signals**2, axis=0) / np.sum(noise**2, axis=0))
    np.testing.assert_allclose(snr, snr_db, atol=0.5)
    # same seed, same noise; another seed, other noise
    again = virtual_recording(
        p, u, FS, shipped_calibration, recorder=RecorderOptions(snr_db=snr_db, seed=7)
    )
    np.testing.assert_array_equal(again.signals, noisy.signals)
    other = virtual_recording(
        p, u, FS, shipped_calibration, recorder=RecorderOptions(snr_db=snr_db, seed=8)
    )
    assert not np.allclose(other.signals, noisy.signals)


@pytest.mark.parametrize("bits", [16, 24])
def test_quantisation_error_below_half_an_lsb(shipped_calibration, bits):
    p, u = broadband(20_000)
    exact = virtual_recording(p, u, FS, shipped_calibration)
    q = virtual_recording(p, u, FS, shipped_calibration, recorder=RecorderOptions(bits=bits))
    lsb = q.full_scale / 2 ** (bits - 1)
    assert q.full_scale == pytest.approx(exact.full_scale)
    err = np.abs(q.signals - exact.signals)
    assert np.max(err) <= 0.5 * lsb * (1 + 1e-9)
    assert np.max(err) > 0.2 * lsb  # it did quantise
    codes = q.file_samples * 2 ** (bits - 1)
    np.testing.assert_allclose(codes, np.round(codes), atol=1e-6)
    # peak at -6 dBFS
    peak_db = 20 * np.log10(np.max(np.abs(q.file_samples)))
    assert peak_db == pytest.approx(-6.0, abs=0.01)


def test_resampling_keeps_amplitude_and_truth_aligned(shipped_calibration):
    f0 = 1000.0
    p, u = tone(f0, 800.0, 5e-5)
    full = virtual_recording(p, u, FS, shipped_calibration)
    vt = virtual_recording(p, u, FS, shipped_calibration, recorder=RecorderOptions(fs_out=48_000.0))
    assert vt.fs == 48_000.0 and vt.fs_model == FS
    assert vt.signals.shape == (9600, 3) and vt.p.shape == (9600,)
    for a, b in [(vt.pressures, full.pressures), (vt.p, full.p), (vt.u0, full.u0)]:
        np.testing.assert_allclose(
            amplitude(a, f0, 48_000.0, 0.06, 0.14), amplitude(b, f0, FS, 0.06, 0.14), rtol=1e-4
        )


def test_drift_blocks_reduce_to_the_constant_temperature(shipped_calibration):
    p, u = broadband(20_000)
    const = virtual_recording(p, u, FS, shipped_calibration, temperature_c=21.0)
    # a negligible drift takes the block path (two cross-faded blocks)
    blocks = virtual_recording(p, u, FS, shipped_calibration, temperature_c=(21.0, 21.0 + 1e-9))
    scale = np.max(np.abs(const.pressures))
    assert np.max(np.abs(blocks.pressures - const.pressures)) / scale < 1e-6
    assert np.max(np.abs(blocks.p0 - const.p0)) / np.max(np.abs(const.p0)) < 1e-6


def test_drift_follows_the_temperature_line(shipped_calibration):
    f0 = 2000.0
    p, u = tone(f0, 800.0, 5e-5 * np.exp(0.4j), duration=0.5)
    drift = virtual_recording(p, u, FS, shipped_calibration, temperature_c=(20.0, 23.0))
    assert drift.temperature_c == (20.0, 23.0)
    for t_mid in (0.15, 0.25, 0.35):
        window = (t_mid - 0.01, t_mid + 0.01)
        temp = float(drift.temperature_at(t_mid))
        assert temp == pytest.approx(20.0 + 3.0 * t_mid / (drift.duration - 1 / FS))
        const = virtual_recording(p, u, FS, shipped_calibration, temperature_c=temp)
        start = virtual_recording(p, u, FS, shipped_calibration, temperature_c=20.0)
        got = amplitude(drift.pressures, f0, FS, *window)
        want = amplitude(const.pressures, f0, FS, *window)
        off = amplitude(start.pressures, f0, FS, *window)
        assert np.max(np.abs(got - want) / np.abs(want)) < 1e-3
        assert np.max(np.abs(off - want) / np.abs(want)) > 5e-3


def test_edge_and_input_checks(shipped_calibration):
    p, u = tone(500.0, 100.0, 1e-5, duration=0.05)
    vt = virtual_recording(p, u, FS, shipped_calibration)
    # the farthest microphone over c
    assert vt.edge_s == pytest.approx(0.2882 / shipped_calibration.air_properties().c)
    with pytest.raises(ValueError, match="Mach"):
        virtual_recording(p, u, FS, shipped_calibration, mach=0.5)
    with pytest.raises(ValueError, match="bits"):
        virtual_recording(p, u, FS, shipped_calibration, recorder=RecorderOptions(bits=12))
    with pytest.raises(ValueError, match="3 finite numbers, one per microphone"):
        virtual_recording(
            p, u, FS, shipped_calibration, recorder=RecorderOptions(gain_error_db=(0.0, 1.0))
        )
    with pytest.raises(ValueError, match="equal length"):
        virtual_recording(p, u[:-1], FS, shipped_calibration)
    with pytest.raises(ValueError, match="rational"):
        virtual_recording(
            p, u, FS, shipped_calibration, recorder=RecorderOptions(fs_out=44_100.123456)
        )
