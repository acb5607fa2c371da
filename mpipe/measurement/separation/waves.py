"""The lossy, convected plane-wave model of the main bore (physics.md E.1-E.4).

Microphone ``m`` at ``d_m = x_m - x_ref`` metres downstream of the reference plane sees
(e^{+j omega t})::

    P_m = A exp(-j k+ d_m) + B exp(+j k- d_m),   k+- = k0 / (1 +- M)
    k0  = omega / c + eta (k_ZK(omega) - omega / c_ZK)
    P0  = A + B,   U0 = (A - B) / Z_c

Here: the propagation parameters :class:`Theta` (c in m/s, eta, M), the microphones and bore
:class:`Geometry` (offsets in m), the Zwikker-Kosten excess (:func:`zk_excess`), the
wavenumbers, the N x 2 model matrix ``H``, its null vector, the least-squares separation
filters to P0 (Pa) and U0 (m^3/s), the projection residual and the singular frequencies.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from mpipe.acoustics import ducts
from mpipe.acoustics.air import Air, temperature_from_sound_speed
from mpipe.measurement.calibration import Calibration


@dataclass(frozen=True)
class Theta:
    """Propagation parameters of one block.

    Attributes
    ----------
    c : float
        Effective sound speed in m/s.
    eta : float
        Scale of the Zwikker-Kosten visco-thermal excess (dimensionless, 1 = theory).
    mach : float
        Mach number of the mean flow, positive towards the bell (dimensionless).
    """

    c: float
    eta: float = 1.0
    mach: float = 0.0


@dataclass(frozen=True)
class Geometry:
    """What the separation needs from a calibration.

    Attributes
    ----------
    offsets : ndarray
        Microphone positions relative to the reference plane, m, shape ``(N,)``, N >= 2.
    radius : float
        Radius of the main bore at the microphones, m.
    losses : str
        Loss model of :mod:`mpipe.acoustics.ducts`.
    air_model : str
        Air model name for :func:`mpipe.acoustics.air.air_properties`.
    calibration : Calibration
        The calibration (air model, humidity, CO2).
    """

    offsets: np.ndarray
    radius: float
    losses: str
    air_model: str
    calibration: Calibration

    @classmethod
    def from_calibration(cls, calibration: Calibration) -> Geometry:
        """Extract the geometry of the microphones from a calibration."""
        x = np.array([m.position for m in calibration.microphones], dtype=float)
        return cls(
            offsets=x - calibration.reference_plane,
            radius=calibration.main_radius,
            losses=calibration.bore.losses,
            air_model=calibration.air.model,
            calibration=calibration,
        )

    def temperature(self, c: float) -> float:
        """Effective temperature in degC at which the calibration's air has sound speed c."""
        a = self.calibration.air
        return temperature_from_sound_speed(c, a.model, a.humidity, a.co2_fraction)

    def sound_speed(self, temperature_c: float) -> float:
        """Sound speed in m/s of the calibration's air at ``temperature_c`` degC."""
        return self.calibration.air_properties(temperature_c).c

    def air(self, c: float) -> Air:
        """Air at the effective temperature whose sound speed (calibration's model) is c."""
        t = float(np.clip(self.temperature(c), -19.9, 59.9))
        return self.calibration.air_properties(t)

    def corrected(self, dx: float) -> Geometry:
        """The geometry with the middle microphone moved by ``dx`` metres (+x: downstream)."""
        if dx == 0.0:
            return self
        offsets = self.offsets.copy()
        offsets[int(np.argsort(self.offsets)[1])] += dx
        return replace(self, offsets=offsets)

    @property
    def spacing(self) -> float:
        """Smallest distance between two microphones, m."""
        return float(np.min(np.diff(np.sort(self.offsets))))


def zk_excess(omega: np.ndarray, geometry: Geometry, c: float) -> tuple[np.ndarray, np.ndarray]:
    """Visco-thermal excess of the wavenumber and the lossy characteristic impedance ratio.

    Parameters
    ----------
    omega : ndarray
        Angular frequency in rad/s.
    geometry : Geometry
        Bore radius, loss and air models.
    c : float
        Effective sound speed in m/s (sets the air properties).

    Returns
    -------
    excess : ndarray
        ``k_ZK(omega) - omega / c_air`` in rad/m (complex; imaginary part negative).
    zc_ratio : ndarray
        ``Z_c / Z0 - 1`` (complex, dimensionless), the lossy excess of the characteristic
        impedance over the real ``rho c / S``.

    References
    ----------
    physics.md B.2 and E.5.
    """
    air = geometry.air(c)
    gamma, zc = ducts.propagation(omega, geometry.radius, air, geometry.losses)
    k = -1j * gamma
    w = np.maximum(omega, ducts.OMEGA_FLOOR)
    z0 = air.impedance(np.pi * geometry.radius**2)
    return k - w / air.c, zc / z0 - 1.0


def wavenumbers(
    omega: np.ndarray, theta: Theta, excess: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Forward and backward wavenumbers k+ and k- in rad/m (physics.md E.1, E.5).

    ``k0 = omega / c + eta * excess`` and ``k+- = k0 / (1 +- M)``.
    """
    k0 = omega / theta.c + theta.eta * excess
    return k0 / (1.0 + theta.mach), k0 / (1.0 - theta.mach)


def model_matrix(k_plus: np.ndarray, k_minus: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """The N x 2 matrices H with rows ``[exp(-j k+ d_m), exp(+j k- d_m)]``, shape ``(n, N, 2)``.

    References
    ----------
    physics.md E.2; Jang & Ih 1998.
    """
    h = np.empty(k_plus.shape + (offsets.size, 2), dtype=complex)
    h[..., 0] = np.exp(-1j * k_plus[:, None] * offsets[None, :])
    h[..., 1] = np.exp(1j * k_minus[:, None] * offsets[None, :])
    return h


def null_vector(h: np.ndarray) -> np.ndarray:
    """Unit bilinear null vector ``n = h+ x h- / ||.||`` with ``n^T H = 0``, shape ``(n, 3)``.

    References
    ----------
    physics.md E.3.
    """
    n = np.cross(h[..., 0], h[..., 1])
    norm = np.sqrt(np.sum(np.abs(n) ** 2, axis=-1, keepdims=True))
    return n / np.maximum(norm, 1e-300)


def separation_filters(
    freqs: np.ndarray,
    theta: Theta,
    geometry: Geometry,
    excess: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares filters from the N >= 2 microphone spectra to P0 and U0.

    Parameters
    ----------
    freqs : ndarray
        Frequencies in Hz, shape ``(n,)``.
    theta : Theta
        Propagation parameters.
    geometry : Geometry
        Microphone offsets and bore.
    excess : tuple of ndarray, optional
        Output of :func:`zk_excess` on ``2 pi freqs`` (recomputed when omitted).

    Returns
    -------
    g_p : ndarray
        Shape ``(n, N)``: ``P0 = sum_m g_p[:, m] P_m`` (dimensionless).
    g_u : ndarray
        Shape ``(n, N)``: ``U0 = sum_m g_u[:, m] P_m`` in m^3/(Pa s). Zero at DC, where
        U0 cannot be measured (physics.md E.4).

    Notes
    -----
    ``[A, B] = (H^H H)^{-1} H^H P`` (physics.md E.2). A tiny Tikhonov term (1e-12 of the
    trace) keeps the exactly singular bins finite; there the minimum-norm solution sets
    A = B, i.e. U0 = 0.
    """
    omega = 2 * np.pi * np.asarray(freqs, dtype=float)
    if excess is None:
        excess = zk_excess(omega, geometry, theta.c)
    k_p, k_m = wavenumbers(omega, theta, excess[0])
    h = model_matrix(k_p, k_m, geometry.offsets)
    hh = np.conj(np.swapaxes(h, -1, -2))
    gram = hh @ h
    reg = 1e-12 * np.real(np.trace(gram, axis1=-2, axis2=-1))
    gram[..., 0, 0] += reg
    gram[..., 1, 1] += reg
    a, b, c, d = gram[..., 0, 0], gram[..., 0, 1], gram[..., 1, 0], gram[..., 1, 1]
    det = a * d - b * c
    inv = np.empty_like(gram)
    inv[..., 0, 0] = d / det
    inv[..., 0, 1] = -b / det
    inv[..., 1, 0] = -c / det
    inv[..., 1, 1] = a / det
    pinv = inv @ hh  # (n, 2, N): rows g_A and g_B; with N = 2 the exact inverse of H
    air = geometry.air(theta.c)
    z0 = air.impedance(np.pi * geometry.radius**2)
    zc = z0 * (1.0 + theta.eta * excess[1])
    g_p = pinv[:, 0, :] + pinv[:, 1, :]
    g_u = (pinv[:, 0, :] - pinv[:, 1, :]) / zc[:, None]
    g_u[omega == 0] = 0.0
    return g_p, g_u


def projection_residual(pressures: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Part of the microphone spectra that two plane waves cannot explain, any number >= 2.

    Parameters
    ----------
    pressures : ndarray
        Microphone spectra ``P`` (Pa), shape ``(n, n_mics)``.
    h : ndarray
        Model matrices of :func:`model_matrix`, shape ``(n, n_mics, 2)``.

    Returns
    -------
    ndarray
        ``P - H H^+ P``, shape ``(n, n_mics)``: zero for two microphones (the exact
        solution, wherever H is regular) and for a field of two plane waves; for three
        microphones its squared norm is ``|n^T P|^2 / ||n||^2`` with the null vector
        ``n = h+ x h-`` (physics.md E.3), which generalises to more microphones.
    """
    hh = np.conj(np.swapaxes(h, -1, -2))
    ab = np.linalg.solve(hh @ h, hh @ pressures[..., None])
    return pressures - (h @ ab)[..., 0]


def singular_frequencies(geometry: Geometry, theta: Theta, fmax_hz: float) -> np.ndarray:
    """Frequencies (Hz, up to ``fmax_hz``) where the microphones cannot tell the waves apart.

    ``H`` loses rank where ``exp(j (k+ + k-) (d_i - d_j)) = 1`` for every pair of
    microphones, i.e. (lossless) at ``f = n c (1 - M^2) / (2 s_ij)`` for all spacings
    ``s_ij`` at once. Two microphones ``s`` apart are singular at every multiple of
    ``c (1 - M^2) / (2 s)``; with three or more, only where the spacings are commensurate
    (equal spacings ``s``: at multiples of ``c (1 - M^2) / (2 s)`` still).

    Returns
    -------
    ndarray
        The singular frequencies in Hz, increasing (possibly empty).
    """
    d = np.sort(geometry.offsets)
    spacings = np.abs(d[:, None] - d[None, :])[np.triu_indices(d.size, 1)]
    base = theta.c * (1 - theta.mach**2) / 2.0
    first = base / spacings[0]
    out = []
    for n in range(1, int(fmax_hz / first) + 1):
        f = n * first
        m = f * spacings / base
        if np.all(np.abs(m - np.round(m)) < 1e-6 * np.maximum(m, 1.0)):
            out.append(f)
    return np.array(out)
