"""The explicit scheme of the paper's Appendix A written plainly: coefficients and reference.

:func:`reed_coefficients` gives the coefficients of the centred-difference reed update
and :func:`scheme_records` the compiled kernel's records of them; :func:`run_reference` is
the scheme as a plain Python/NumPy loop written directly from the equations (physics.md
G.2-G.4, D.2 step 6): the slow reference of :func:`mpipe.reed.model.simulate`
(``method="numpy"``) against which the one compiled kernel (:func:`mpipe.reed.kernels.run`)
is tested (tests/reed/test_kernels.py).

References
----------
Chatziioannou & van Walstijn 2012, Appendix A, eqs. (A.1)-(A.17); physics.md G.2-G.4.
"""

from __future__ import annotations

import math

import numpy as np

from mpipe.reed.parameters import ReedParameters


def reed_coefficients(reed: ReedParameters, fs: float) -> tuple[float, float, float, float]:
    """Coefficients of the centred-difference reed update.

    Parameters
    ----------
    reed : ReedParameters
        Reed parameters.
    fs : float
        Sample rate, Hz.

    Returns
    -------
    a1, a2, a3, b1 : float
        a1 and a2 dimensionless; a3 in m^(1-alpha), so that a3 [y - y_c]^alpha is in m;
        b1 in m/Pa.

    References
    ----------
    Chatziioannou & van Walstijn 2012, eqs. (A.1)-(A.2); physics.md G.2.
    """
    t = 1.0 / fs
    d = reed.m / t**2 + reed.m * reed.g / (2 * t)
    a1 = (2 * reed.m / t**2 - reed.k) / d
    a2 = -(reed.m / t**2 - reed.m * reed.g / (2 * t)) / d
    a3 = -reed.k_c / d
    b1 = 1.0 / d
    return a1, a2, a3, b1


def scheme_records(reed: ReedParameters, fs: float, h0: float, z0: float, rho: float) -> tuple:
    """The ``model`` record of the compiled kernel (:func:`mpipe.reed.kernels.run`).

    Parameters
    ----------
    reed : ReedParameters
        Reed parameters.
    fs : float
        Sample rate, Hz.
    h0 : float
        Lag-0 tap of the reflection function (dimensionless).
    z0 : float
        Characteristic impedance of the entry, Pa s/m^3.
    rho : float
        Air density, kg/m^3.

    Returns
    -------
    tuple
        ``(reed_record, bore_record)``: (a1, a2, a3, b1, y_m, y_c, alpha, alpha == 2, lam,
        S fs) and (Z0, rho, 1 / (1 - h0), Z0 (1 + h0) / (1 - h0), 2 / rho), SI units.
    """
    a1, a2, a3, b1 = reed_coefficients(reed, fs)
    record = (a1, a2, a3, b1, reed.y_m, reed.y_c, reed.alpha, reed.alpha == 2.0, reed.lam)
    inv = 1.0 / (1.0 - h0)
    bore = (float(z0), float(rho), inv, z0 * (1.0 + h0) * inv, 2.0 / rho)
    return (*record, reed.S * fs), bore


def run_reference(x, n0, h, z0, rho, reed, fs, pm, start):
    """The scheme as a plain Python/NumPy loop, from physics.md G.2-G.4 and D.2 step 6 (slow).

    The reference of the compiled kernel (:func:`mpipe.reed.kernels.run`), written
    independently of it: the history term as a dot product over every tap, the Bernoulli
    flow by the two sign cases of the quadratic as derived.

    Parameters
    ----------
    x : ndarray
        p+ buffer, Pa: ``n0`` samples of history, then the run's (written).
    n0 : int
        History samples in ``x`` (at least ``len(h) - 1``).
    h : ndarray
        Reflection function, h[j] at a lag of j samples.
    z0, rho : float
        Characteristic impedance (Pa s/m^3) and air density (kg/m^3).
    reed : ReedParameters
        Reed parameters.
    fs : float
        Sample rate, Hz.
    pm : ndarray
        Mouth pressure per output sample, Pa; its length is the run's.
    start : tuple
        (y, y_prev, dp) at the start: m, m, Pa.

    Returns
    -------
    out : dict
        "p", "u", "u_f", "u_r", "y", "h", "p_minus" per sample (SI units).
    end : tuple
        The final (y, y_prev, dp).
    """
    y, y_prev, dp = start
    n = pm.size
    a1, a2, a3, b1 = reed_coefficients(reed, fs)
    h0 = h[0]
    taps = h[1:][::-1].copy()  # lags N-1 .. 1
    nt = taps.size
    z0p = z0 * (1 + h0) / (1 - h0)
    out = {k: np.empty(n) for k in ("p", "u", "u_f", "u_r", "y", "h", "p_minus")}
    for i in range(n):
        m = n0 + i
        y_new = a1 * y + a2 * y_prev + b1 * dp + a3 * max(y - reed.y_c, 0.0) ** reed.alpha
        opening = max(reed.y_m - y_new, 0.0)
        ur = reed.S * (y_new - y) * fs
        q = float(np.dot(taps, x[m - nt : m]))
        qp = q / (1 - h0)
        lam_big = (reed.lam * opening) ** 2 * z0p / rho
        gam = 2 * (reed.lam * opening) ** 2 / rho * (2 * qp + z0p * ur - pm[i])
        # the two sign cases of the quadratic, as derived (physics.md G.3)
        if opening == 0.0:
            uf = 0.0
        elif gam <= 0.0:
            uf = -lam_big + math.sqrt(lam_big**2 - gam)
        else:
            uf = lam_big - math.sqrt(lam_big**2 + gam)
        u = uf + ur
        p = 2 * qp + z0p * u
        x[m] = (q + z0 * u) / (1 - h0)
        out["p"][i] = p
        out["u"][i] = u
        out["u_f"][i] = uf
        out["u_r"][i] = ur
        out["y"][i] = y_new
        out["h"][i] = opening
        out["p_minus"][i] = p - x[m]
        y_prev, y, dp = y, y_new, pm[i] - p
    return out, (y, y_prev, dp)
