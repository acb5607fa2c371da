"""p0, u0 under another theta without the microphones (separation.perturbation)."""

import numpy as np

from mpipe.measurement.separation.perturbation import reseparate
from mpipe.measurement.separation.waves import Geometry, Theta, separation_filters
from tests.measurement.separation.separation_fields import CAL, FS, band_nrmse, random_take

N = 2**14
BAND_HZ = 7500.0


def test_the_same_theta_gives_back_p0_and_u0():
    _, p0, u0 = random_take(N, seed=1)
    theta = (20.0, 1.0, 0.0, 0.0)
    p1, u1 = reseparate(p0, u0, FS, CAL, theta, theta, BAND_HZ)
    assert band_nrmse(p1, p0) < 1e-6 and band_nrmse(u1, u0) < 1e-6


def test_reseparating_matches_separating_the_microphones_with_the_other_theta():
    # the microphones of an independent field (ducts' transfer matrices at 20 degC),
    # separated with the filters of 21 degC and eta 1.1, against reseparate() from the
    # true p0, u0: the change must agree to 2 % of itself
    x, p0, u0 = random_take(N, temperature_c=20.0, seed=2)
    freqs = np.fft.rfftfreq(N, 1 / FS)
    band = (freqs > 0) & (freqs <= BAND_HZ)
    geometry = Geometry.from_calibration(CAL)
    theta = Theta(geometry.sound_speed(21.0), 1.1, 0.0)
    g_p, g_u = separation_filters(freqs[band], theta, geometry)
    mics = np.fft.rfft(x, axis=0)[band]
    spec_p, spec_u = np.zeros(freqs.size, complex), np.zeros(freqs.size, complex)
    spec_p[band], spec_u[band] = np.sum(g_p * mics, 1), np.sum(g_u * mics, 1)
    p_direct, u_direct = np.fft.irfft(spec_p, N), np.fft.irfft(spec_u, N)
    p1, u1 = reseparate(p0, u0, FS, CAL, (20.0, 1.0, 0.0, 0.0), (21.0, 1.1, 0.0, 0.0), BAND_HZ)
    trim = slice(500, -500)  # reseparate zero-pads, the periodic take wraps around
    for new, direct, old in ((p1, p_direct, p0), (u1, u_direct, u0)):
        change = direct - old
        assert np.std(change[trim]) > 1e-3 * np.std(old)  # the other theta changes them
        err = np.std((new - direct)[trim]) / np.std(change[trim])
        assert err < 0.02, err
