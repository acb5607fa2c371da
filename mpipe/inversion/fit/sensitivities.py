"""The Jacobian of F2's residual vector from the model's own forward sensitivities.

:class:`SensitivityEvaluator` extends a window's compiled evaluator
(:class:`mpipe.inversion.fit.fastpath.WindowEvaluator`) with the derivative of the residual
``p_target - p_model`` with respect to every free parameter, in one model run: each step
of the history start is differentiated forward alongside the pressure,

* the reed lead-in driven by the measured pressure (its recursion's tangent);
* the missing mean flow over the lead-in, which shifts the forward-wave history by
  ``(Z0 + R) c / 2`` and the residual by ``R c`` times the filter's edge (R the reference
  resistance), so the tangent of the history's share of the history term is
  ``((Z0 + R) dc / 2) q_ones`` (the window's precomputed convolution of the shift) and the
  residual's gets ``R dc`` times the edge;
* the model run itself with the tangents of every parameter (the one compiled kernel,
  :func:`mpipe.reed.kernels.run`, given its ``tangent`` record);
* the measurement's low-pass, which is linear: each tangent goes through the same FIR
  (with zeros for the measured context, which does not depend on the parameters).

The result agrees with central finite differences to about 1e-7 relative
(tests/inversion/fit/test_sensitivities.py) and costs about as much as four model runs
instead of one per parameter. The compiled code is the evaluator's own
(:func:`mpipe.inversion.fit.fastpath._evaluate` given its ``jac`` record); this module holds
the tangents' buffers.

References
----------
Chatziioannou & van Walstijn 2012, eq. (15) and Appendix A; physics.md G.2-G.4, I.
"""

from __future__ import annotations

import types

import numpy as np

from mpipe.core.filters import design_lowpass
from mpipe.inversion.fit.fastpath import WindowEvaluator
from mpipe.inversion.fit.input_tangents import InputTangents
from mpipe.inversion.fit.least_squares import broyden_update, normal_equations
from mpipe.inversion.fit.objective import ObjectiveSettings, TargetWindow
from mpipe.reed.bore_kernel import prepare_bore
from mpipe.reed.parameters import ReedParameters
from mpipe.reed.sensitivity import coefficient_derivatives, tangent_lines


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
        x, _, conv, _, p_mod, _, work = evaluator.buffers
        n = evaluator.target_p.size
        # the tangents' buffers: the lead-in's, p+'s (zero history), the model pressure's,
        # the low-pass's (zero context: the measured context does not depend on theta),
        # the measured lead-in's change (zero: it does not either) and the history term's
        # tangent (zeroed by each run)
        self.buffers = (
            np.zeros((n_par, work.shape[1])), np.zeros((n_par, x.size)),
            np.empty((n_par, p_mod.size)), np.zeros(evaluator.win[5].size),
            np.empty(max(n, p_mod.size)), tangent_lines(conv, n_par),
            np.zeros((n_par, evaluator.win[2].size)), np.zeros((n_par, p_mod.size)),
        )  # fmt: skip

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
        d = coefficient_derivatives(reed, self.ev.fs, self.names, self.contact_at_closure)
        return self.ev.evaluate_into(reed, out_r, (d, out_j, *self.buffers))


__all__ = ["SensitivityEvaluator"]


def load_compiled() -> None:
    """Load (or compile) the inversion's compiled code in this process, on a tiny window.

    Worker processes forked after this call inherit the loaded code instead of each loading
    numba's cache again (about as long as a few hundred model runs per process).
    """
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
    InputTangents(ev, 2).responses(reed, np.zeros((2, 600)), np.zeros((2, 600)))
    normal_equations(jac, r)
    broyden_update(jac.copy(), r, np.ones(len(names)))
