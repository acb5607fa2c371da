"""Reference fields for the tests of the wave separation (physics.md E).

They are built independently of mpipe.measurement.separation: the waves at the reference
plane are carried to the microphones with the cylinder transfer matrices of
mpipe.acoustics.ducts (no flow), or with the convected two-wave field written out (with flow).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy import signal

from mpipe.acoustics import ducts
from mpipe.core.resampling import resample
from mpipe.measurement.calibration import load_calibration
from mpipe.reed.recorder import RecorderOptions
from mpipe.reed.recording import virtual_recording

CAL = load_calibration(Path(__file__).parents[3] / "calibration" / "simplified_clarinet.yaml")
FS = 25_000.0
FS_NOTE = 100_000.0


def mic_offsets():
    """Microphone positions relative to the reference plane of CAL, m."""
    return np.array([m.position for m in CAL.microphones]) - CAL.reference_plane


def mic_spectra(P0, U0, freqs, temperature_c=20.0, mach=0.0):
    """Microphone spectra of the field with P0, U0 at the reference plane."""
    air = CAL.air_properties(temperature_c)
    omega = 2 * np.pi * np.asarray(freqs, dtype=float)
    d = mic_offsets()
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


def noisy(x, snr_db, seed, ratios=(1.0, 1.05, 0.93)):
    """X with white noise snr_db below each channel's RMS (levels scaled by ratios)."""
    rng = np.random.default_rng(seed)
    std = np.sqrt(np.mean(x**2, axis=0)) * 10 ** (-snr_db / 20) * np.array(ratios)
    return x + rng.normal(size=x.shape) * std


def analytic_field(offsets, P0, U0, freqs, temperature_c=20.0):
    """Analytic two-wave field at any positions (cylinder transfer matrices, no flow)."""
    air = CAL.air_properties(temperature_c)
    omega = 2 * np.pi * np.asarray(freqs, dtype=float)
    out = []
    for x in offsets:
        t_inv = ducts.invert(ducts.cylinder_matrix(omega, CAL.main_radius, x, air))
        out.append(t_inv[:, 0, 0] * P0 + t_inv[:, 0, 1] * U0)
    return np.stack(out, axis=-1)


def steady_note(n=50_000, f0=147.0, harmonics=24):
    """A steady note rich in harmonics (1/k amplitudes), p in Pa and u in m^3/s."""
    t = np.arange(n) / FS_NOTE
    env = np.minimum(t / 0.01, 1.0)
    k = np.arange(1, harmonics + 1)[:, None]
    phase = np.sin(1.3 * k)
    p = np.sum(1500.0 / k * np.sin(2 * np.pi * f0 * k * t + phase), axis=0) * env
    u = 1e-4 + np.sum(1e-4 / k * np.cos(2 * np.pi * f0 * k * t + 2 * phase), axis=0) * env
    return p, u


def note_take(snr_db, seed, fs_out=FS_NOTE, temperature_c=None):
    """A virtual take of :func:`steady_note` at 100 kHz, and its noise level.

    Pa signals (resampled from fs_out when that differs) and the added noise's two-sided
    PSD (sigma^2 / fs_out, the scaling of noise_levels).
    """
    p, u = steady_note()
    take = virtual_recording(
        p,
        u,
        FS_NOTE,
        CAL,
        temperature_c=temperature_c,
        recorder=RecorderOptions(snr_db=snr_db, seed=seed, fs_out=fs_out),
    )
    x = take.signals * np.asarray(take.sensitivity)
    # two-sided noise PSD in the scaling of noise_levels: sigma^2 / fs of the file
    truth = (np.asarray(take.noise_rms) * np.asarray(take.sensitivity)) ** 2 / fs_out
    return (resample(x, fs_out, FS_NOTE) if fs_out != FS_NOTE else x), truth
