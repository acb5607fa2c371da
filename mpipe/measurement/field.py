"""The sound field along the main bore: from the reference plane to the microphones.

The forward model of the measurement chain (physics.md E.1, F.1): spectra at the mouthpiece
entry are carried to the reference plane by the bore's transfer matrix, and from there to
each wall microphone as two plane waves convected by the mean flow. The virtual recording
(:mod:`mpipe.reed.recording`) and the microphone-calibration simulator use it; the wave
separation inverts it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from mpipe.acoustics.air import Air
from mpipe.acoustics.bore import transfer_matrix
from mpipe.acoustics.ducts import invert, propagation
from mpipe.measurement.calibration import Calibration

# A clarinet's breath gives M ~ 0.002 (physics.md E.1); beyond 0.3 the plane-wave
# convected model and the no-flow upstream chain are both meaningless.
MACH_LIMIT = 0.3


def complex_gain(gain_db: Sequence[float], phase_deg: Sequence[float]) -> np.ndarray:
    """Complex gains ``10^(gain_db / 20) exp(j phase_deg pi / 180)`` (dimensionless)."""
    g = np.asarray(gain_db, dtype=float)
    ph = np.deg2rad(np.asarray(phase_deg, dtype=float))
    return 10.0 ** (g / 20.0) * np.exp(1j * ph)


def mouthpiece_to_reference(
    P: np.ndarray, U: np.ndarray, omega: np.ndarray, calibration: Calibration, air: Air
) -> tuple[np.ndarray, np.ndarray]:
    """Carry mouthpiece spectra downstream to the reference plane, without mean flow.

    ``[P0, U0] = T(0 -> x_ref)^{-1} [P, U]``.

    Parameters
    ----------
    P, U : ndarray
        Pressure (Pa) and volume flow (m^3/s) spectra at the mouthpiece entry, shape
        ``(n_freq,)``.
    omega : ndarray
        Angular frequencies, rad/s, shape ``(n_freq,)``.
    calibration : Calibration
        Bore and reference-plane position.
    air : Air
        Air properties.

    Returns
    -------
    P0, U0 : ndarray
        Spectra at the reference plane (Pa, m^3/s).

    References
    ----------
    Chatziioannou & van Walstijn 2012, eq. (16), inverted; physics.md F.1.
    """
    t_inv = invert(transfer_matrix(calibration.bore, omega, air, 0.0, calibration.reference_plane))
    p0 = t_inv[:, 0, 0] * P + t_inv[:, 0, 1] * U
    u0 = t_inv[:, 1, 0] * P + t_inv[:, 1, 1] * U
    return p0, u0


def microphone_field(
    P0: np.ndarray,
    U0: np.ndarray,
    freqs: np.ndarray,
    calibration: Calibration,
    air: Air,
    mach: float,
    positions: Sequence[float] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Pressure and volume flow at positions in the main cylinder, with mean flow.

    Parameters
    ----------
    P0, U0 : array_like
        Pressure (Pa) and volume flow (m^3/s) at the reference plane, broadcastable to
        ``freqs``.
    freqs : array_like
        Frequencies in Hz (>= 0), shape ``(n_freq,)``.
    calibration : Calibration
        Microphone positions, reference plane and the main-bore radius.
    air : Air
        Air properties.
    mach : float
        Mean-flow Mach number, positive towards the bell.
    positions : sequence of float, optional
        Positions in m from the mouthpiece entry; default: the calibration's microphones.

    Returns
    -------
    P, U : ndarray
        Shape ``(n_freq, n_positions)``: pressure in Pa and volume flow in m^3/s.

    References
    ----------
    physics.md E.1 (Jang & Ih 1998): ``P = A e^{-j k+ d} + B e^{+j k- d}``,
    ``k± = k0 / (1 ± M)``, ``k0 = -j Gamma``, ``d = x - x_ref``, ``P0 = A + B``,
    ``U0 = (A - B) / Zc``; each wave carries ``U = ±P / Zc`` also with convection.
    """
    check_mach(mach)
    freqs = np.atleast_1d(np.asarray(freqs, dtype=float))
    if np.any(freqs < 0):
        raise ValueError("frequencies must be >= 0 Hz")
    xs = [m.position for m in calibration.microphones] if positions is None else list(positions)
    gamma, zc = propagation(
        2 * np.pi * freqs, calibration.main_radius, air, calibration.bore.losses
    )
    p0 = np.broadcast_to(np.asarray(P0, dtype=complex), freqs.shape)
    u0 = np.broadcast_to(np.asarray(U0, dtype=complex), freqs.shape)
    a = 0.5 * (p0 + zc * u0)
    b = 0.5 * (p0 - zc * u0)
    d = np.asarray(xs, dtype=float)[None, :] - calibration.reference_plane
    fwd = np.exp(-gamma[:, None] * d / (1.0 + mach))
    bwd = np.exp(gamma[:, None] * d / (1.0 - mach))
    p = a[:, None] * fwd + b[:, None] * bwd
    u = (a[:, None] * fwd - b[:, None] * bwd) / zc[:, None]
    return p, u


def microphone_spectra(
    P0: np.ndarray,
    U0: np.ndarray,
    freqs: np.ndarray,
    calibration: Calibration,
    air: Air,
    mach: float = 0.0,
) -> np.ndarray:
    """True pressure spectra at the microphones from reference-plane spectra.

    Parameters
    ----------
    P0, U0 : array_like
        Pressure (Pa) and volume flow (m^3/s) at the reference plane, broadcastable to
        ``freqs``.
    freqs : array_like
        Frequencies in Hz (>= 0), shape ``(n_freq,)``.
    calibration : Calibration
        Microphone positions and reference plane (all in the main cylinder).
    air : Air
        Air properties.
    mach : float
        Mean-flow Mach number, positive towards the bell.

    Returns
    -------
    ndarray
        Shape ``(n_freq, N)``, complex pressure in Pa, upstream microphone first.

    References
    ----------
    physics.md E.1; see :func:`microphone_field`.
    """
    return microphone_field(P0, U0, freqs, calibration, air, mach)[0]


def check_mach(mach: float) -> None:
    """Refuse (ValueError) a mean-flow Mach number no wind instrument gives."""
    if not abs(mach) < MACH_LIMIT:
        raise ValueError(
            f"Mach number {mach:g} is implausible for a wind instrument (|M| < {MACH_LIMIT}; "
            "a clarinet gives about 0.002)"
        )


__all__ = ["complex_gain", "microphone_field", "microphone_spectra", "mouthpiece_to_reference"]
