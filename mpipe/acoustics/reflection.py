"""The bore reflection function r_f: impulse response of the entry reflectance.

Computed by frequency sampling (physics.md D.2): evaluate R(omega) on a long FFT grid at
the model rate, inverse-transform, check causality, truncate by an energy criterion with a
short half-Hann fade, and verify that the spectrum of the truncated response reproduces
R in the band of interest.

Index convention
----------------
``h[j]`` is the reflection at a lag of ``j`` samples: ``p^-(n) = sum_j h[j] p^+(n - j)``.
The paper's eq. (A.4), ``p^-(n+1) = sum_i r_f(i) p^+(n - i)``, uses ``r_f(i) = h[i + 1]``:
its tap ``i`` carries a lag of ``i + 1`` samples. :class:`ReflectionFunction` stores
``h`` (with ``h[0]``) and exposes the paper's ``r_f`` as a property.

References
----------
Chatziioannou & van Walstijn 2012, eq. (A.4); physics.md D.2.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mpipe.acoustics.air import Air
from mpipe.acoustics.bore import Bore, reflectance

# DC evaluation frequency, Hz: the loss formulas are singular at omega = 0 (physics.md D.2).
_DC_FREQUENCY = 1e-3


@dataclass(frozen=True)
class ReflectionFunction:
    """Sampled reflection function of a bore.

    Attributes
    ----------
    h : ndarray
        Reflection impulse response; ``h[j]`` is the lag-``j`` tap (dimensionless).
    fs : float
        Sample rate in Hz.
    z0 : float
        Real characteristic impedance of the entry (Pa s/m^3) to which R is referred.
    tail_energy : float
        Energy of the discarded tail relative to the total energy of the response.
    acausal_energy : float
        Energy of the untruncated response in negative time, relative to the total.
    dc_reflectance : float
        R(0) of the bore (before truncation); ``h.sum()`` equals it (the truncated tail's
        DC sum is restored, so the model's DC input impedance is the bore's).
    max_error_db : float
        Largest |Z| error, dB, between the truncated response and the exact reflectance
        in the verification band, over bins where |Z| >= Z0. For a measured bore, the
        difference from the measured impedance (mostly its noise, which the truncation
        removes); no limit is enforced then.
    max_error_reflectance : float
        Largest |delta R| (dimensionless) in the verification band.
    check_band_hz : tuple of float
        The verification band (low, high), Hz.
    """

    h: np.ndarray
    fs: float
    z0: float
    tail_energy: float
    acausal_energy: float
    dc_reflectance: float
    max_error_db: float
    max_error_reflectance: float
    check_band_hz: tuple[float, float]

    @property
    def r_f(self) -> np.ndarray:
        """The paper's r_f(i) = h[i + 1] (eq. A.4: tap i has lag i + 1)."""
        return self.h[1:]

    @property
    def n_taps(self) -> int:
        """Number of taps, including the lag-0 tap."""
        return self.h.size


def reflection_function(
    bore: Bore,
    air: Air,
    fs: float = 100_000.0,
    n_fft: int = 2**17,
    tail_tolerance: float = 1e-6,
    max_duration: float = 0.2,
    check_fmin_hz: float = 20.0,
    check_band_hz: float = 7250.0,
    max_error_db: float = 0.1,
    acausal_tolerance: float = 1e-3,
) -> ReflectionFunction:
    """Compute the bore reflection function at sample rate ``fs``.

    Parameters
    ----------
    bore : Bore
        Geometry and termination.
    air : Air
        Air properties.
    fs : float
        Sample rate in Hz.
    n_fft : int
        FFT length; must cover the decay of the response (otherwise it wraps around).
    tail_tolerance : float
        Energy criterion for truncation: the discarded tail holds less than this fraction of
        the energy of the causal response. The length is then doubled (up to
        ``max_duration``) until the truncated response reproduces |Z_in| within
        ``max_error_db`` in the check band.
    max_duration : float
        Upper limit on the truncated length, s.
    check_fmin_hz, check_band_hz : float
        Verification band, Hz. Below ~20 Hz the slowly converging DC sum dominates (its
        effect on the mean mouthpiece pressure is of order 1 Pa), and the measurement
        chain high-passes there anyway.
    max_error_db : float
        Largest allowed |Z| error in the verification band, dB.
    acausal_tolerance : float
        Largest allowed fraction of the energy in negative time. A sharp step in radius
        (the shipped bore has a 0.5 mm step at the cone) echoes as a near-discontinuity
        whose band-limited version rings on both sides of its lag; for the shipped bore
        that pre-ringing carries about 5e-4 of the energy. Wrap-around from too short an
        FFT gives far more.

    Returns
    -------
    ReflectionFunction

    Raises
    ------
    ValueError
        When the response is not causal (energy in negative time above ``acausal_tolerance``) or
        the truncated response misses the reflectance by more than ``max_error_db``.
    """
    if fs <= 0 or n_fft < 256:
        raise ValueError(f"need fs > 0 and n_fft >= 256, got fs={fs}, n_fft={n_fft}")
    freqs = np.arange(n_fft // 2 + 1) * fs / n_fft
    freqs_eval = freqs.copy()
    freqs_eval[0] = _DC_FREQUENCY
    r = reflectance(bore, 2 * np.pi * freqs_eval, air)
    r[0] = r[0].real
    r[-1] = r[-1].real
    h_full = np.fft.irfft(r, n_fft)
    causal = h_full[: n_fft // 2]
    causal_energy = float(np.sum(causal**2))
    acausal = float(np.sum(h_full[n_fft // 2 :] ** 2)) / (causal_energy + 1e-300)
    if acausal > acausal_tolerance:
        raise ValueError(
            f"reflection function is not causal: {acausal:.2e} of its energy lies in negative "
            "time; increase n_fft"
        )
    remaining = 1.0 - np.cumsum(causal**2) / causal_energy
    n_max = min(int(max_duration * fs), causal.size)
    below = np.flatnonzero(remaining[:n_max] < tail_tolerance)
    n_taps = max(int(below[0]) + 1 if below.size else n_max, 16)
    measured = bore.measured_input is not None
    if measured:
        # a measurement's noise floor never meets the energy criterion: the measured bore
        # decays like its equivalent bore, and the taps beyond that length are noise
        n_taps = reflection_function(
            bore.measured_input.equivalent, air, fs, n_fft, tail_tolerance, max_duration,
            check_fmin_hz, check_band_hz, max_error_db, acausal_tolerance,
        ).n_taps  # fmt: skip
    z0 = bore.entry_impedance(air)
    # The energy criterion is dominated by the early reflections; the slow decay of the
    # low resonances holds little energy but sets their peak heights, so the length is
    # doubled until the in-band check passes as well.
    # A measured bore's R carries the measurement's noise, which the truncation removes:
    # its in-band difference is recorded (the stated error), not a numerical failure.
    while True:
        h = _with_dc(_truncate(causal, n_taps), float(r[0].real))
        error_db, error_r = _verify(h, r, freqs, n_fft, check_fmin_hz, check_band_hz)
        if error_db <= max_error_db or n_taps >= n_max or measured:
            break
        n_taps = min(2 * n_taps, n_max)
    if error_db > max_error_db and not measured:
        raise ValueError(
            f"truncated reflection function ({n_taps} taps) misses |Z_in| by {error_db:.3f} dB "
            f"in {check_fmin_hz:g}-{check_band_hz:g} Hz (limit {max_error_db} dB); "
            "raise max_duration or n_fft"
        )
    tail = float(np.sum(causal[n_taps:] ** 2) + np.sum((causal[:n_taps] - h) ** 2)) / causal_energy
    return ReflectionFunction(
        h=h,
        fs=float(fs),
        z0=z0,
        tail_energy=tail,
        acausal_energy=acausal,
        dc_reflectance=float(r[0].real),
        max_error_db=error_db,
        max_error_reflectance=error_r,
        check_band_hz=(float(check_fmin_hz), float(check_band_hz)),
    )


def _truncate(causal: np.ndarray, n_taps: int) -> np.ndarray:
    """First ``n_taps`` samples with a half-Hann fade over the last 10 % (no step at the end)."""
    h = causal[:n_taps].copy()
    n_fade = max(n_taps // 10, 1)
    h[-n_fade:] *= 0.5 * (1 + np.cos(np.pi * np.arange(1, n_fade + 1) / n_fade))
    return h


def _with_dc(h: np.ndarray, dc: float) -> np.ndarray:
    """``h`` with the DC sum of its discarded tail restored: ``sum(h) == dc``.

    The response's slow tail (the bore's losses at the lowest frequencies) holds almost no
    energy, so the energy criterion cuts it at a length that jumps with the rate (47-153 ms
    on the shipped bore), but it carries 0.2-0.5 % of R(0): without it the model's DC input
    impedance, (1 + sum h) / (1 - sum h), was 1.3-1.75 times the bore's, a different factor
    at every rate, and with it the mouthpiece's mean pressure and p_m (a soft note's p_m
    moved by -6.6 % at 96 kHz, issue 38). The missing sum is put back as a Hann-shaped
    bump over the whole response: its spectrum lies below about 2 / duration (40 Hz for
    50 ms), under the band the model is checked and fitted in.
    """
    bump = np.hanning(h.size + 2)[1:-1]
    return h + (dc - float(np.sum(h))) * bump / float(np.sum(bump))


def _verify(h, r, freqs, n_fft, fmin_hz, fmax_hz) -> tuple[float, float]:
    """Errors from using ``h`` instead of R in ``[fmin_hz, fmax_hz]``.

    Returns the largest |Z| error in dB over bins where |Z| >= Z0, and the largest |delta R|.
    In antiresonance troughs |1 + R| is small, so a tiny reflectance error becomes a large
    relative error of Z that says nothing about the model's accuracy; those bins are
    covered by the reflectance error instead.
    """
    r_trunc = np.fft.rfft(h, n_fft)
    band = (freqs >= fmin_hz) & (freqs <= fmax_hz)
    z_exact = (1 + r[band]) / (1 - r[band])
    z_trunc = (1 + r_trunc[band]) / (1 - r_trunc[band])
    strong = np.abs(z_exact) >= 1.0
    error_db = np.abs(20 * np.log10(np.abs(z_trunc[strong]) / np.abs(z_exact[strong])))
    return float(np.max(error_db)), float(np.max(np.abs(r_trunc[band] - r[band])))
