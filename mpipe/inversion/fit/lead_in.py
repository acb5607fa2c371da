"""The reed's lead-in before a window and the mean flow it finds missing, with tangents.

The inversion's history start (physics.md H; :mod:`mpipe.inversion.fit.fastpath`) drives
the reed over a lead-in before each window with the measured pressure
(:func:`mpipe.reed.opening.drive_reed`), and estimates the mean flow the measurement lost
(``c``: the candidate's flow less the measured one, averaged over the lead-in's second
half), which shifts the history's forward wave by ``(Z0 + R) c / 2`` (R the reference
resistance: the measured pressure also lacks ``R c``). Here both, and their
tangents: per reed parameter (the seed matrix's columns, for the Jacobian,
:mod:`mpipe.inversion.fit.sensitivities`) and per change of the measured lead-in
(:mod:`mpipe.inversion.fit.input_tangents`), in one function each.

Records (``win``, ``cand``) are :func:`mpipe.inversion.fit.fastpath._evaluate`'s.
"""

from __future__ import annotations

import math

from numba import njit

from mpipe.reed.opening import drive_reed


@njit(cache=True)
def lead_in(ylead, p_lead, cand):
    """The reed's lead-in driven by the measured pressure (:func:`drive_reed`), m."""
    reed = cand[0][0]
    coefficients = (reed[0], reed[1], reed[2], reed[3])
    drive_reed(ylead, p_lead, cand[3], cand[1], coefficients, (reed[5], reed[6]))


@njit(cache=True)
def missing_flow(ylead, win, cand):
    """The candidate's flow less the measured one over the lead-in's second half, m^3/s.

    As :func:`mpipe.inversion.fit.history_start.missing_mean_flow`.
    """
    p_lead, u_lead, fs = win[2], win[3], win[8]
    y_m, lam, rho = cand[0][0][4], cand[0][0][8], cand[0][1][1]
    s_area, p_m = cand[2], cand[3]
    n_lead = p_lead.size
    half = n_lead // 2
    acc = 0.0
    for i in range(half, n_lead):
        dp = p_m - p_lead[i]
        h = y_m - ylead[i]
        if h < 0.0:
            h = 0.0
        sgn = 1.0 if dp > 0.0 else (-1.0 if dp < 0.0 else 0.0)
        uf = sgn * lam * h * math.sqrt(2.0 * abs(dp) / rho)
        prev = ylead[i - 1] if i > 0 else ylead[0]
        ur = s_area * (ylead[i] - prev) * fs
        acc += uf + ur - u_lead[i]
    return acc / (n_lead - half)


@njit(cache=True)
def lead_in_tangent(dyl, ylead, p_lead, d, dpl, cand):
    """Tangent of :func:`lead_in` for every seed column of ``d``.

    ``dpl[j]``: column j's change of the measured lead-in pressure (zeros for a reed
    parameter's column; :mod:`mpipe.inversion.fit.input_tangents` moves the signals).
    """
    reed = cand[0][0]
    a1, a2, a3, b1, y_c, alpha = reed[0], reed[1], reed[2], reed[3], reed[5], reed[6]
    k, p_m = cand[1], cand[3]
    n_lead = p_lead.size
    y0 = ylead[0]
    for j in range(d.shape[1]):
        dy0 = (d[7, j] - dpl[j, 0] - y0 * d[9, j]) / k
        dyl[j, 0] = dy0
        dyl[j, 1] = dy0
        for i in range(1, n_lead - 1):
            t = d[0, j] * ylead[i] + a1 * dyl[j, i] + d[1, j] * ylead[i - 1] + a2 * dyl[j, i - 1]
            t += d[3, j] * (p_m - p_lead[i]) + b1 * (d[7, j] - dpl[j, i])
            c = ylead[i] - y_c
            if c > 0.0:
                t += d[2, j] * c**alpha + a3 * alpha * c ** (alpha - 1.0) * (dyl[j, i] - d[6, j])
            dyl[j, i + 1] = t


@njit(cache=True)
def missing_tangent(dmiss, dyl, ylead, d, dpl, dul, win, cand):
    """Tangent of :func:`missing_flow` per seed column.

    ``dpl``, ``dul``: each column's change of the measured lead-in pressure and flow (as
    :func:`lead_in_tangent`'s).
    """
    p_lead, fs = win[2], win[8]
    y_m, lam, rho = cand[0][0][4], cand[0][0][8], cand[0][1][1]
    s_area, p_m = cand[2], cand[3]
    n_lead = p_lead.size
    half = n_lead // 2
    for j in range(d.shape[1]):
        acc = 0.0
        for i in range(half, n_lead):
            dp = p_m - p_lead[i]
            h = y_m - ylead[i]
            dh = d[5, j] - dyl[j, i] if h > 0.0 else 0.0
            if h < 0.0:
                h = 0.0
            sgn = 1.0 if dp > 0.0 else (-1.0 if dp < 0.0 else 0.0)
            root = math.sqrt(2.0 * abs(dp) / rho)
            droot = sgn * (d[7, j] - dpl[j, i]) / (rho * root) if root > 0.0 else 0.0
            duf = sgn * (d[8, j] * h * root + lam * dh * root + lam * h * droot)
            ip = i - 1 if i > 0 else 0
            dur = (d[4, j] / fs * (ylead[i] - ylead[ip]) + s_area * (dyl[j, i] - dyl[j, ip])) * fs
            acc += duf + dur - dul[j, i]
        dmiss[j] = acc / (n_lead - half)


__all__ = ["lead_in", "lead_in_tangent", "missing_flow", "missing_tangent"]
