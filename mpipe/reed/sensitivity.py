"""Forward sensitivities of the model's pressure to the reed parameters, run with the model.

The explicit scheme of the model is differentiated step by step (forward mode): for each
parameter theta the tangent ``dy = d y / d theta`` etc. obeys the scheme's derivative,
driven by the derivatives of the coefficients (a1, a2, a3, b1, S fs, y_m, y_c, p_m,
lambda). The bore's history term is a linear convolution of p+, so its tangent is
the same convolution of the tangent of p+: ``dq(n) = sum_{j>=1} h_j dp+(n-j)``, run by the
same direct part and delay lines as the pressure. One run gives the pressure and its
derivative with respect to every parameter (the Jacobian of step 2), exact to rounding
instead of one extra run per parameter by finite differences. The tangents run inside the
one compiled kernel (:func:`mpipe.reed.kernels.run` with its ``tangent`` record, each
step by :func:`mpipe.reed.kernels._step_tangent`); this module holds the seed matrix and
the driver.

Derivatives per step (physics.md G.2-G.4, the quantities of :func:`mpipe.reed.kernels._step`):

* ``dy' = da1 y + a1 dy + da2 y_ + a2 dy_ + db1 dp + b1 ddp + da3 e^a + a3 a e^(a-1) (dy - dy_c)``
  (the contact term only while ``e = y - y_c > 0``);
* ``dh = dy_m - dy'`` while the channel is open (0 when shut);
* ``du_r = d(S fs) (y' - y) + S fs (dy' - dy)``;
* u_f solves ``sgn(u_f) u_f^2 + 2 L u_f + G = 0``, so ``du_f = -(2 u_f dL + dG) / (2 (|u_f| + L))``;
* ``dp+ = (dq + Z0 du) / (1 - h0)``, ``dp = 2 dp+ - Z0 du``, ``ddp' = dp_m - dp``.

The corners of the model (the channel shutting, contact starting) make p piecewise smooth;
the derivative there is the one-sided one of the branch taken.

References
----------
Chatziioannou & van Walstijn 2012, Appendix A, eqs. (A.1)-(A.17); physics.md G.2-G.4, D.4.
"""

from __future__ import annotations

import numpy as np

from mpipe.reed.bore_kernel import BoreKernel
from mpipe.reed.kernels import run
from mpipe.reed.model import ModelState, check_length, load_history
from mpipe.reed.parameters import ReedParameters, check_stability
from mpipe.reed.scheme import scheme_records

#: Rows of the seed matrix of :func:`coefficient_derivatives`.
SEED_ROWS = ("a1", "a2", "a3", "b1", "s_fs", "y_m", "y_c", "p_m", "lam", "k")

#: Parameters the kernels can differentiate.
DIFFERENTIABLE = ("k", "S", "y_m", "p_m", "m", "g", "lam", "k_c", "y_c")


def coefficient_derivatives(
    reed: ReedParameters, fs: float, names: tuple[str, ...], contact_at_closure: bool = False
) -> np.ndarray:
    """Derivatives of the scheme's coefficients with respect to each named parameter.

    Parameters
    ----------
    reed : ReedParameters
        Where the derivatives are taken.
    fs : float
        Sample rate, Hz.
    names : tuple of str
        Parameters (some of :data:`DIFFERENTIABLE`), one column each.
    contact_at_closure : bool
        y_c is tied to y_m (``contact: closure``): a change of y_m moves y_c with it.

    Returns
    -------
    ndarray
        Shape ``(len(SEED_ROWS), len(names))``: row r, column j is d(row r) / d(names[j]),
        the rows being a1, a2, a3, b1 (the reed update, physics.md G.2), S fs, y_m, y_c,
        p_m, lambda and k (in each one's SI unit per the parameter's SI unit).

    Raises
    ------
    ValueError
        For a name that is not differentiable.
    """
    t = 1.0 / fs
    k, m, g, k_c = reed.k, reed.m, reed.g, reed.k_c
    den = 2.0 + g * t
    b1 = 2.0 * t * t / (m * den)
    db1_dm = -b1 / m
    db1_dg = -b1 * t / den
    partials = {
        "k": {"a1": -2.0 * t * t / (m * den), "k": 1.0},
        "m": {"a1": 2.0 * k * t * t / (m * m * den), "a3": -k_c * db1_dm, "b1": db1_dm},
        "g": {
            "a1": -(4.0 - 2.0 * k * t * t / m) * t / (den * den),
            "a2": 4.0 * t / (den * den),
            "a3": -k_c * db1_dg,
            "b1": db1_dg,
        },
        "k_c": {"a3": -b1},
        "S": {"s_fs": fs},
        "y_m": {"y_m": 1.0, "y_c": 1.0 if contact_at_closure else 0.0},
        "y_c": {"y_c": 1.0},
        "p_m": {"p_m": 1.0},
        "lam": {"lam": 1.0},
    }
    out = np.zeros((len(SEED_ROWS), len(names)))
    for j, name in enumerate(names):
        if name not in partials:
            raise ValueError(f"cannot differentiate with respect to {name!r}")
        for row, value in partials[name].items():
            out[SEED_ROWS.index(row), j] = value
    return out


def pressure_sensitivities(
    reed: ReedParameters,
    kernel: BoreKernel,
    n_samples: int,
    names: tuple[str, ...],
    *,
    state: ModelState | None = None,
    contact_at_closure: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Pressure of :func:`mpipe.reed.model.simulate_pressure` and its parameter derivatives.

    Parameters
    ----------
    reed : ReedParameters
        Reed parameters (SI units); the mouth pressure is ``reed.p_m``.
    kernel : BoreKernel
        Prepared bore.
    n_samples : int
        Number of samples.
    names : tuple of str
        Parameters to differentiate by (some of :data:`DIFFERENTIABLE`).
    state : ModelState, optional
        Start from this history (held fixed: its derivatives are zero) instead of from
        rest.
    contact_at_closure : bool
        y_c moves with y_m (``contact: closure``).

    Returns
    -------
    p : ndarray
        Pressure, Pa, sample i at t = (i + 1) / fs (bit-identical to ``simulate_pressure``).
    dp : ndarray
        Shape ``(len(names), n_samples)``: d p / d theta_j, Pa per the parameter's SI unit.
    """
    n_samples = check_length(n_samples)
    check_stability(reed, kernel.fs)
    lean = kernel.lean
    n0 = lean.n0
    x = np.zeros(n0 + n_samples)
    if state is None:
        y, y_prev, dp = 0.0, 0.0, float(reed.p_m)
    else:
        y, y_prev, dp = load_history(x, n0, kernel.n_taps, state)
    d = coefficient_derivatives(reed, kernel.fs, tuple(names), contact_at_closure)
    n_par = d.shape[1]
    # from rest the tangent of dp(0) = p_m is dp_m; from a given state it is 0
    ddp = d[7].copy() if state is None else np.zeros(n_par)
    out = np.empty(n_samples)
    out_dp = np.empty((n_par, n_samples))
    model = scheme_records(reed, kernel.fs, lean.h0, kernel.z0, kernel.rho)
    conv = lean.conv(x, n_samples)
    tangent = (
        d, np.zeros(n_par), np.zeros(n_par), ddp, np.zeros((n_par, x.size)),
        *tangent_lines(conv, n_par), out_dp, np.zeros((n_par, n_samples)),
    )  # fmt: skip
    pm = np.full(n_samples, reed.p_m)
    run(x, n0, model, conv, (y, y_prev, dp), pm, None, out, None, tangent)
    return out, out_dp


def tangent_lines(conv: tuple, n_par: int) -> tuple:
    """The tangents' direct sums and delay lines beside ``conv``'s, zero history spectra.

    Returns ``(fut_t, line1_t, line2_t)`` for ``n_par`` parameter columns: the pending
    direct sums (one row per column) and each level's (ft_re, ft_im, work) with one set of
    spectra and scratch per column (:func:`mpipe.reed.kernels.run`'s ``tangent``).
    """
    _, fut, *lines = conv
    out = [np.empty((n_par, fut.size))]
    for line in lines:
        out.append(tuple(np.zeros((n_par, *a.shape)) for a in line[1:]))
    return tuple(out)
