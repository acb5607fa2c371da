"""p0 and u0 as another theta would have separated them: the front end's error, propagated.

The separation rebuilds the reference-plane waves from the microphones with the filters of
theta (:func:`mpipe.measurement.separation.waves.separation_filters`). A theta off by
``d theta`` gives other p0, u0. Without the microphone signals, the microphones' noise-free
part follows from p0, u0 themselves: ``P_m = H(theta) [A, B]`` with ``A, B = (P0 +- Z_c U0)
/ 2`` the two waves at the reference plane. Separating that with the filters of
``theta'`` gives the p0, u0 of ``theta'``; for ``theta' = theta`` it returns P0, U0 exactly
(``H^+ H = I``). The noise the separation mixes in differently is left out: it is part of
the windows' own noise, not of the take-wide error.

:func:`reseparate` does this in one FFT of the take (the map is a filter a fraction of a
millisecond long; ``PAD_S`` of zeros keeps its wrap-around off the signal).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import fft as sfft

from mpipe.measurement.calibration import Calibration
from mpipe.measurement.separation.waves import (
    Geometry,
    Theta,
    model_matrix,
    separation_filters,
    wavenumbers,
    zk_excess,
)

#: Zeros appended before the FFT, s.
PAD_S = 0.01


def _theta(geometry: Geometry, values: Sequence[float]) -> tuple[Theta, Geometry]:
    """``(T degC, eta, M, dx m)`` as the Theta and the corrected geometry of the separation."""
    t, eta, mach, dx = (float(v) for v in values)
    return Theta(geometry.sound_speed(t), eta, mach), geometry.corrected(dx)


def reseparate(
    p0: np.ndarray,
    u0: np.ndarray,
    fs: float,
    calibration: Calibration,
    theta: Sequence[float],
    theta_new: Sequence[float],
    band_hz: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The p0, u0 that ``theta_new`` would have separated where ``theta`` gave ``p0, u0``.

    Parameters
    ----------
    p0, u0 : ndarray
        Pressure (Pa) and flow (m^3/s) at the reference plane, as separated with ``theta``.
    fs : float
        Sample rate, Hz.
    calibration : Calibration
        Microphones and bore.
    theta, theta_new : sequence of float
        ``(temperature degC, eta, Mach, position correction of the middle microphone m)``.
    band_hz : float
        Highest frequency the separation passes (band edge plus its taper), Hz; above it
        p0, u0 are left as they are (the separation set them to zero).

    Returns
    -------
    (p0, u0) of ``theta_new``.
    """
    p0, u0 = np.asarray(p0, dtype=float), np.asarray(u0, dtype=float)
    n = p0.size
    nfft = sfft.next_fast_len(n + int(np.ceil(PAD_S * fs)), real=True)
    freqs = np.fft.rfftfreq(nfft, 1 / fs)
    band = (freqs > 0) & (freqs <= band_hz)
    spec_p, spec_u = np.fft.rfft(p0, nfft), np.fft.rfft(u0, nfft)
    base = Geometry.from_calibration(calibration)
    th, geo = _theta(base, theta)
    fb = freqs[band]
    omega = 2 * np.pi * fb
    excess, zc_ratio = zk_excess(omega, geo, th.c)
    h = model_matrix(*wavenumbers(omega, th, excess), geo.offsets)  # (f, N, 2)
    air = geo.air(th.c)
    zc = air.impedance(np.pi * geo.radius**2) * (1.0 + th.eta * zc_ratio)
    waves = np.stack([spec_p[band] + zc * spec_u[band], spec_p[band] - zc * spec_u[band]], -1)
    mics = np.einsum("fmw,fw->fm", h, 0.5 * waves)
    th_new, geo_new = _theta(base, theta_new)
    g_p, g_u = separation_filters(fb, th_new, geo_new)
    spec_p, spec_u = spec_p.copy(), spec_u.copy()
    spec_p[band] = np.sum(g_p * mics, axis=1)
    spec_u[band] = np.sum(g_u * mics, axis=1)
    return np.fft.irfft(spec_p, nfft)[:n], np.fft.irfft(spec_u, nfft)[:n]


__all__ = ["PAD_S", "reseparate"]
