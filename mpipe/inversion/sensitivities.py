"""The Jacobian of F2's residual vector from the model's own forward sensitivities.

:class:`SensitivityEvaluator` extends a window's compiled evaluator
(:class:`mpipe.inversion.fastpath.WindowEvaluator`) with the derivative of the residual
``p_target - p_model`` with respect to every free parameter, in one model run: each step
of the history start is differentiated forward alongside the pressure,

* the reed lead-in driven by the measured pressure (its recursion's tangent);
* the missing mean flow over the lead-in, which shifts the forward-wave history by
  ``Z0 c / 2``, so the tangent of the history's share of the history term is
  ``(Z0 dc / 2) q_ones`` (the window's precomputed convolution of the shift);
* the model run itself with the tangents of every parameter
  (:func:`mpipe.reed.sensitivity._run_pressure_tangent`);
* the measurement's low-pass, which is linear: each tangent goes through the same FIR
  (with zeros for the measured context, which does not depend on the parameters).

The result agrees with central finite differences to about 1e-7 relative
(tests/inversion/test_sensitivities.py) and costs about as much as four model runs
instead of one per parameter.

References
----------
Chatziioannou & van Walstijn 2012, eq. (15) and Appendix A; physics.md G.2-G.4, I.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from mpipe.inversion.fastpath import (
    OK,
    REASONS,
    WindowEvaluator,
    _history_share,
    _lead_in,
    _lowpass,
    _missing_flow,
    _residual,
)
from mpipe.reed.parameters import ReedParameters, check_stability
from mpipe.reed.scheme import reed_coefficients
from mpipe.reed.sensitivity import _run_pressure_tangent, coefficient_derivatives


@njit(cache=True)
def _lead_in_tangent(dyl, ylead, p_lead, d, k, p_m, y_c, alpha, a1, a2, a3, b1):
    """Tangent of :func:`mpipe.inversion.fastpath._lead_in` for every seed column of ``d``."""
    n_lead = p_lead.size
    y0 = ylead[0]
    for j in range(d.shape[1]):
        dy0 = (d[7, j] - y0 * d[9, j]) / k
        dyl[j, 0] = dy0
        dyl[j, 1] = dy0
        for i in range(1, n_lead - 1):
            t = d[0, j] * ylead[i] + a1 * dyl[j, i] + d[1, j] * ylead[i - 1] + a2 * dyl[j, i - 1]
            t += d[3, j] * (p_m - p_lead[i]) + b1 * d[7, j]
            c = ylead[i] - y_c
            if c > 0.0:
                t += d[2, j] * c**alpha + a3 * alpha * c ** (alpha - 1.0) * (dyl[j, i] - d[6, j])
            dyl[j, i + 1] = t


@njit(cache=True)
def _missing_tangent(dmiss, dyl, ylead, p_lead, d, rho, fs, s_area, y_m, p_m, lam):
    """Tangent of :func:`mpipe.inversion.fastpath._missing_flow` per seed column."""
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
            droot = sgn * d[7, j] / (rho * root) if root > 0.0 else 0.0
            duf = sgn * (d[8, j] * h * root + lam * dh * root + lam * h * droot)
            ip = i - 1 if i > 0 else 0
            dur = (d[4, j] / fs * (ylead[i] - ylead[ip]) + s_area * (dyl[j, i] - dyl[j, ip])) * fs
            acc += duf + dur
        dmiss[j] = acc / (n_lead - half)


@njit(cache=True)
def _zero_spectra(ft):
    """Zero the tangents' delay-line spectra (their history is zero: its share is q_ones')."""
    for lvl in range(len(ft)):
        a = ft[lvl]
        for j in range(a.shape[0]):
            for s in range(a.shape[1]):
                for b in range(a.shape[2]):
                    a[j, s, b] = 0.0


# Long on purpose: the compiled Jacobian of F2's residual, kept in one numba frame (see
# fastpath._evaluate about the on-disk cache of functions that call other modules' code).
@njit(cache=True)
def _evaluate_jacobian(
    out_r, out_j, target_p, target_std, p_lead, u_lead, filt, rho, fs, q_base, q_ones, q_ext,
    x, n0, z0, f, head, h0, level1, level2, work1, work2, fut, work, p_mod, p_ctx, fir,
    fir_work, buf, n_taps_fir, k, s_area, y_m, p_m, lam, y_c, alpha, a1, a2, a3, b1, d,
    tw, xt, ft, wt1, wt2, fut_t, dp_mod, ctx0, col,
):  # fmt: skip
    """Residual (``out_r``) and its Jacobian (``out_j``, shape (n, P)) of one candidate.

    The arguments up to ``b1`` are those of :func:`mpipe.inversion.fastpath._evaluate`;
    then the seed matrix ``d`` (:func:`mpipe.reed.sensitivity.coefficient_derivatives`) and
    the tangents' work arrays. Returns the status code of the residual; the Jacobian is
    only written when it is OK.
    """
    n_lead = p_lead.size
    n_par = d.shape[1]
    ylead = work[0, :n_lead]
    _lead_in(ylead, p_lead, k, p_m, y_c, alpha, a1, a2, a3, b1)
    dyl = tw[:, :n_lead]
    _lead_in_tangent(dyl, ylead, p_lead, d, k, p_m, y_c, alpha, a1, a2, a3, b1)
    dmiss = np.zeros(n_par)
    missing = 0.0
    if filt:
        missing = _missing_flow(ylead, p_lead, u_lead, rho, fs, s_area, y_m, p_m, lam)
        _missing_tangent(dmiss, dyl, ylead, p_lead, d, rho, fs, s_area, y_m, p_m, lam)
    _history_share(q_ext, q_base, q_ones, 0.5 * z0 * missing, f)
    c_t = 0.5 * z0 * dmiss
    _zero_spectra(ft)
    dy = dyl[:, n_lead - 1].copy()
    dy_prev = dyl[:, n_lead - 2].copy()
    ddp = d[7].copy()
    _run_pressure_tangent(
        x, n0, p_mod.size, head, h0, z0, rho, a1, a2, a3, b1, y_m, y_c, alpha, lam,
        s_area * fs, p_m, ylead[n_lead - 1], ylead[n_lead - 2], p_m - p_lead[n_lead - 1],
        level1, f[0], f[1], work1, level2, f[2], f[3], work2, fut, p_mod, d, dy, dy_prev,
        ddp, xt, ft[0], ft[1], wt1, ft[2], ft[3], wt2, fut_t, dp_mod, q_ext, q_ones, c_t,
    )  # fmt: skip
    code = _residual(
        out_r, target_p, target_std, p_mod, filt, p_ctx, fir, fir_work, buf, n_taps_fir
    )
    if code != OK:
        return code
    n = target_p.size
    for j in range(n_par):
        if filt:
            _lowpass(col, n, dp_mod[j], ctx0, fir, fir_work, buf, n_taps_fir)
        else:
            col[:n] = dp_mod[j, :n]
        for i in range(n):
            out_j[i, j] = -col[i]
    return OK


class SensitivityEvaluator:
    """Residuals of F2 and their Jacobian for one window, from forward sensitivities.

    Holds work buffers (one per window and thread, like the evaluator it extends).

    Parameters
    ----------
    evaluator : WindowEvaluator
        The window's compiled evaluator (history start).
    names : tuple of str
        Free parameters, in the order of the Jacobian's columns.
    contact_at_closure : bool
        y_c is tied to y_m (``contact: closure``).
    """

    def __init__(
        self, evaluator: WindowEvaluator, names: tuple[str, ...], contact_at_closure: bool
    ):
        self.ev = evaluator
        self.names = tuple(names)
        self.contact_at_closure = bool(contact_at_closure)
        n_par = len(self.names)
        ev = evaluator
        lean = ev.lean
        n = ev.target_p.size
        self.tw = np.zeros((n_par, ev.work.shape[1]))
        self.xt = np.zeros((n_par, ev.x.size))
        self.ft = tuple(np.zeros((n_par, *a.shape)) for a in ev.f)
        self.wt1 = np.zeros((n_par, 5, lean.block1 + 1))
        self.wt2 = np.zeros((n_par, 5, lean.block2 + 1))
        self.fut_t = np.empty((n_par, ev.fut.size))
        self.dp_mod = np.empty((n_par, ev.p_mod.size))
        self.ctx0 = np.zeros(ev.p_ctx.size)
        self.col = np.empty(max(n, ev.p_mod.size))

    def jacobian_into(self, reed: ReedParameters, out_r: np.ndarray, out_j: np.ndarray) -> str:
        """Residuals (Pa) into ``out_r`` and d residual / d theta into ``out_j``.

        Parameters
        ----------
        reed : ReedParameters
            Candidate.
        out_r : ndarray
            Length of the window.
        out_j : ndarray
            Shape (window length, number of free parameters): column j in Pa per the SI
            unit of parameter j. Undefined when infeasible.

        Returns
        -------
        str
            "" for a feasible candidate, else the reason (as
            :meth:`WindowEvaluator.residuals_into`).
        """
        ev = self.ev
        try:
            check_stability(reed, ev.fs)
        except ValueError as exc:
            return f"unstable: {exc}"
        a1, a2, a3, b1 = reed_coefficients(reed, ev.fs)
        d = coefficient_derivatives(reed, ev.fs, self.names, self.contact_at_closure)
        k = ev.kernel
        with np.errstate(all="ignore"):
            code = _evaluate_jacobian(
                out_r, out_j, ev.target_p, ev.target_std, ev.p_lead, ev.u_lead, ev.filt, ev.rho,
                ev.fs, ev.q_base, ev.q_ones, ev.q_ext, ev.x, ev.n0, k.z0, ev.f, ev.lean.head,
                ev.lean.h0, ev.lean.level1, ev.lean.level2, ev.work1, ev.work2, ev.fut,
                ev.work, ev.p_mod, ev.p_ctx, ev.fir, ev.fir_work, ev.buf, ev.n_taps_fir,
                reed.k, reed.S, reed.y_m, reed.p_m, reed.lam, reed.y_c, reed.alpha, a1, a2,
                a3, b1, d, self.tw, self.xt, self.ft, self.wt1, self.wt2, self.fut_t,
                self.dp_mod, self.ctx0, self.col,
            )  # fmt: skip
        return REASONS.get(int(code), "")


__all__ = ["SensitivityEvaluator"]


def load_compiled() -> None:
    """Load (or compile) the inversion's compiled code in this process, on a tiny window.

    Worker processes forked after this call inherit the loaded code instead of each loading
    numba's cache again (about as long as a few hundred model runs per process).
    """
    import types

    from mpipe.core.filters import design_lowpass
    from mpipe.inversion.least_squares import _broyden_update, _normal_equations
    from mpipe.inversion.objective import ObjectiveSettings, TargetWindow
    from mpipe.reed.bore_kernel import prepare_bore

    fs = 100_000.0
    h = np.zeros(1100)
    h[1:] = -0.5 * np.exp(-np.arange(1, 1100) / 100.0) / 100.0
    kernel = prepare_bore(
        types.SimpleNamespace(h=h, fs=fs, z0=1.0e6), types.SimpleNamespace(rho=1.2)
    )
    t = np.arange(2400) / fs
    p = 1000.0 * np.sin(2 * np.pi * 150.0 * t)
    u = 1e-4 * np.cos(2 * np.pi * 150.0 * t)
    target = TargetWindow(p[-400:], u[-400:], p[:-400], u[:-400], fs, True)
    ev = WindowEvaluator(kernel, target, ObjectiveSettings(lowpass=design_lowpass(fs)))
    reed = ReedParameters(
        k=8.66e6, S=7.62e-5, y_m=4e-4, p_m=1800.0, lam=0.013, m=0.05, g=3000.0, k_c=8.23e10
    )
    names = ("k", "S")
    r, jac = np.empty(400), np.empty((400, len(names)))
    ev.residuals_into(reed, r)
    SensitivityEvaluator(ev, names, False).jacobian_into(reed, r, jac)
    _normal_equations(jac, r)
    _broyden_update(jac.copy(), r, np.ones(len(names)))
