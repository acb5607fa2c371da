"""Sanity checks before a separation: the band and the order of the channels.

:func:`check_band` refuses a separation band (Hz) reaching the first singular frequency of
the microphone spacing or the Nyquist frequency; :func:`check_channel_order` tells whether
the channels of a take look like the calibration's microphones in order (swapped or
reversed channels).
"""

from __future__ import annotations

from itertools import permutations

import numpy as np
from scipy import signal

from mpipe.measurement.calibration import Calibration
from mpipe.measurement.separation.settings import SeparationConfig
from mpipe.measurement.separation.waves import (
    Geometry,
    Theta,
    model_matrix,
    wavenumbers,
    zk_excess,
)


def check_band(config: SeparationConfig, geometry: Geometry, fs: float, c: float) -> None:
    """Check that the separation band stays below the first singular frequency.

    Raises
    ------
    ValueError
        When ``band_edge_hz + band_taper_hz`` reaches ``0.98 c / (2 s)`` (physics.md E.4)
        or the Nyquist frequency.
    """
    f1 = c / (2 * geometry.spacing)
    top = config.band_edge_hz + config.band_taper_hz
    if top >= 0.98 * f1:
        raise ValueError(
            f"separation band ends at {top:g} Hz, too close to the first singular frequency "
            f"{f1:.0f} Hz of microphones {geometry.spacing * 100:.2f} cm apart; lower "
            "band_edge_hz"
        )
    if top >= fs / 2:
        raise ValueError(
            f"separation band ends at {top:g} Hz, above the Nyquist frequency {fs / 2:g} Hz"
        )


def check_channel_order(
    pressures: np.ndarray, fs: float, calibration: Calibration, seconds: float = 1.0
) -> str | None:
    """Whether the channels of a take look like the calibration's microphones in order.

    Two cheap tests on the strongest bins in 50-1000 Hz of (at most) ``seconds`` of the
    take, with the plane-wave field at the calibration's temperature, no loss scaling, no
    flow:

    1. (three or more microphones) the fraction of power two plane waves cannot explain,
       for the given order and for every other order of the channels (up to 5
       microphones; with more, the orders differing by one swap of two channels); an
       order explaining the data 30 times better means channels are swapped;
    2. the direction of the active acoustic power, ``|A|^2 - |B|^2`` over ``|A|^2 + |B|^2``
       summed over those bins: a note played at the reed (or any source at the
       mouthpiece) sends power towards the bell, so a clearly negative value means the
       order is reversed (a mirror image that test 1 cannot see).

    Returns
    -------
    str or None
        A one-line description of the problem, or None (also when no bin is strong
        enough to tell).
    """
    strong = _strongest_cross_spectra(pressures, fs, seconds)
    if strong is None:
        return None
    f, sb = strong
    pinv, proj = _plane_wave_operators(f, calibration)
    n_mics = len(calibration.microphones)
    identity = tuple(range(n_mics))
    orders = _candidate_orders(n_mics)
    fits = {o: _unexplained(sb, proj, o) for o in orders} if n_mics >= 3 else {identity: 0.0}
    given = fits[identity]
    best = min(fits.values())
    mics = calibration.microphones
    if given > 1e-5 and given > 30 * best:
        # of the equally good orders (mirror images), the one sending power to the bell
        near = [o for o, v in fits.items() if v <= 2 * best]
        order = max(near, key=lambda o: _power_flow(sb, pinv, o))
        chans = ", ".join(str(mics[i].channel) for i in order)
        return (
            f"channels look swapped: two plane waves leave {100 * given:.2g} % of the power "
            f"unexplained in the calibration's order but {100 * best:.2g} % with channels "
            f"{chans} as {', '.join(m.name for m in mics)}; check the channel map"
        )
    ratio = _power_flow(sb, pinv, identity)
    if ratio < -0.01:
        return (
            f"acoustic power at the microphones flows towards the mouthpiece (net "
            f"{100 * ratio:.2g} % of the wave power); the channels are probably in reverse "
            "order: the calibration lists the microphones from the mouthpiece outwards"
        )
    return None


def _strongest_cross_spectra(
    pressures: np.ndarray, fs: float, seconds: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """The (at most 10) strongest bins in 50-1000 Hz of the middle ``seconds`` of a take.

    Returns their frequencies (Hz) and cross-spectral matrices ``E[X_i conj(X_j)]``
    (Pa^2/Hz, shape ``(n, N, N)``), or None when no bin is 100 times above the median.
    """
    x = np.asarray(pressures, dtype=float)
    n = min(x.shape[0], int(seconds * fs))
    start = (x.shape[0] - n) // 2
    x = x[start : start + n] - np.mean(x[start : start + n], axis=0)
    nper = min(int(2 ** np.ceil(np.log2(0.1 * fs))), n)
    freqs, s = signal.csd(
        x[:, :, None], x[:, None, :], fs=fs, nperseg=nper, axis=0, window="hann"
    )  # S[f, i, j] = E[conj(X_i) X_j]
    s = np.conj(s)  # E[X_i conj(X_j)]
    band = (freqs >= 50.0) & (freqs <= 1000.0)
    if not np.any(band):
        return None
    trace = np.real(np.einsum("fii->f", s))
    ref = np.median(trace[band])
    idx = np.flatnonzero(band)
    idx = idx[np.argsort(trace[idx])[::-1][:10]]
    idx = idx[trace[idx] > 100 * ref]
    if idx.size == 0:
        return None
    return freqs[idx], s[idx]


def _plane_wave_operators(f: np.ndarray, calibration: Calibration) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares wave amplitudes and the projector on what two plane waves leave.

    The plane-wave field at the calibration's temperature, no loss scaling, no flow, at
    ``f`` Hz: ``pinv`` (shape ``(n, 2, N)``, rows g_A and g_B) and ``proj = I - H pinv``
    (shape ``(n, N, N)``, zero for two microphones).
    """
    geometry = Geometry.from_calibration(calibration)
    c = calibration.air_properties().c
    theta = Theta(c, 1.0, 0.0)
    omega = 2 * np.pi * f
    excess = zk_excess(omega, geometry, c)[0]
    k_p, k_m = wavenumbers(omega, theta, excess)
    h = model_matrix(k_p, k_m, geometry.offsets)
    n_mics = geometry.offsets.size

    hh = np.conj(np.swapaxes(h, -1, -2))
    pinv = np.linalg.solve(hh @ h, hh)  # (f, 2, N): rows g_A, g_B
    # projector on what two plane waves cannot explain (zero for two microphones)
    proj = np.eye(n_mics)[None] - h @ pinv
    return pinv, proj


def _candidate_orders(n_mics: int) -> list[tuple[int, ...]]:
    """Every order of the channels up to 5; beyond, the given one and its single swaps."""
    identity = tuple(range(n_mics))
    if n_mics <= 5:
        return list(permutations(identity))
    orders = [identity]
    for i in range(n_mics):
        for j in range(i + 1, n_mics):
            o = list(identity)
            o[i], o[j] = o[j], o[i]
            orders.append(tuple(o))
    return orders


def _arranged(sb: np.ndarray, order) -> np.ndarray:
    """The cross-spectral matrices with the channels in ``order``."""
    return sb[:, list(order)][:, :, list(order)]


def _unexplained(sb: np.ndarray, proj: np.ndarray, order) -> float:
    """Fraction of the power two plane waves cannot explain with the channels in ``order``."""
    sp = _arranged(sb, order)
    quad = np.real(np.einsum("fij,fjk,fik->f", proj, sp, np.conj(proj)))
    return float(np.sum(quad) / np.sum(np.real(np.einsum("fii->f", sp))))


def _power_flow(sb: np.ndarray, pinv: np.ndarray, order) -> float:
    """``sum |A|^2 - |B|^2`` over ``sum |A|^2 + |B|^2`` with the channels in ``order``."""
    s_ab = np.einsum("fai,fij,fbj->fab", pinv, _arranged(sb, order), np.conj(pinv))
    a2, b2 = np.real(s_ab[:, 0, 0]), np.real(s_ab[:, 1, 1])
    return float(np.sum(a2 - b2) / np.sum(a2 + b2))
