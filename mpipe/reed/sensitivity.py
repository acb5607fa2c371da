"""Forward sensitivities of the model's pressure to the reed parameters, run with the model.

The explicit scheme of :mod:`mpipe.reed.kernels` is differentiated step by step (forward
mode): for each parameter theta the tangent ``dy = d y / d theta`` etc. obeys the scheme's
derivative, driven by the derivatives of the coefficients (a1, a2, a3, b1, S fs, y_m, y_c,
p_m, lambda). The bore's history term is a linear convolution of p+, so its tangent is
the same convolution of the tangent of p+: ``dq(n) = sum_{j>=1} h_j dp+(n-j)``, run by the
same direct part and delay lines as the pressure. One run gives the pressure and its
derivative with respect to every parameter (the Jacobian of step 2), exact to rounding
instead of one extra run per parameter by finite differences.

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
from numba import njit

from mpipe.reed.bore_kernel import BoreKernel
from mpipe.reed.kernels import _fdl_tail, _seed, _spread, _step
from mpipe.reed.model import ModelState, _check_length, _load_history
from mpipe.reed.parameters import ReedParameters, check_stability
from mpipe.reed.scheme import reed_coefficients

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


@njit(inline="always")
def _step_tangent(d, j, dq, p_m, y, dy, y_prev, dy_prev, dp, ddp, q, y_new, hh, ur, uf, reed, bore):
    """Tangent of one step of :func:`mpipe.reed.kernels._step` for parameter column ``j``.

    ``d`` is the seed matrix (:func:`coefficient_derivatives`), ``dq`` the tangent of the
    history term, ``p_m`` the mouth pressure (Pa); the other arguments are the step's
    inputs and results. Returns the
    tangents (dy_new, dp+, dp) at n+1.
    """
    a1, a2, a3, b1, y_m, y_c, alpha, square, lam, s_fs = reed
    z0, rho, inv, z0p, two_over_rho = bore
    dy_new = d[0, j] * y + a1 * dy + d[1, j] * y_prev + a2 * dy_prev + d[3, j] * dp + b1 * ddp
    e = y - y_c
    if e > 0.0:
        de = dy - d[6, j]
        if square:
            dy_new += d[2, j] * (e * e) + a3 * (2.0 * e * de)
        else:
            dy_new += d[2, j] * e**alpha + a3 * (alpha * e ** (alpha - 1.0) * de)
    dur = d[4, j] * (y_new - y) + s_fs * (dy_new - dy)
    duf = 0.0
    if hh > 0.0:
        dhh = d[5, j] - dy_new
        lh = lam * hh
        lh2 = lh * lh
        dlh2 = 2.0 * lh * (d[8, j] * hh + lam * dhh)
        big_l = lh2 * z0p / rho
        dbig_l = dlh2 * z0p / rho
        w = 2.0 * q * inv + z0p * ur - p_m
        dw = 2.0 * dq * inv + z0p * dur - d[7, j]
        dbig_g = two_over_rho * (dlh2 * w + lh2 * dw)
        duf = -(2.0 * uf * dbig_l + dbig_g) / (2.0 * (abs(uf) + big_l))
    du = duf + dur
    dpp = (dq + z0 * du) * inv
    return dy_new, dpp, 2.0 * dpp - z0 * du


@njit(cache=True)
def _run_pressure_tangent(
    x, n0, n, head, h0, z0, rho, a1, a2, a3, b1, y_m, y_c, alpha, lam, s_fs, p_m, y,
    y_prev, dp, level1, f1_re, f1_im, work1, level2, f2_re, f2_im, work2, fut, out_p, d,
    dy, dy_prev, ddp, xt, ft1_re, ft1_im, wt1, ft2_re, ft2_im, wt2, fut_t, out_dp, q_ext,
    q_ones, c_t,
):  # fmt: skip
    """:func:`mpipe.reed.kernels._run_pressure` with the tangents of every parameter column.

    The first arguments (up to ``out_p``) are those of ``_run_pressure``, and the pressure
    is computed the same way (the same operations: bit-identical). Then per column j of the
    seed matrix ``d``: the tangent state ``dy[j], dy_prev[j], ddp[j]`` (updated in place),
    the tangent of p+ in ``xt[j]`` (its history before ``n0`` given), the tangent delay
    lines ``ft*_re[j], ft*_im[j]`` (history spectra given) with their scratch ``wt*[j]``,
    the direct part's pending sums ``fut_t[j]``, and the output ``out_dp[j]`` (d p / d
    theta_j, Pa per the parameter's unit). ``q_ext`` is added to the history term as in
    ``_run_pressure``, and ``c_t[j] q_ones`` to its tangent (a history shift whose
    convolution the caller made: the inversion's missing mean flow).
    Returns the final (y, y_prev, dp).
    """
    n_par = d.shape[1]
    _seed(fut, n, x, n0, head)
    for j in range(n_par):
        _seed(fut_t[j], n, xt[j], n0, head)
    blk1 = level1[2].size
    blk2 = level2[2].size
    on1 = level1[0].shape[0] > 0
    on2 = level2[0].shape[0] > 0
    inv = 1.0 / (1.0 - h0)
    bore = (z0, rho, inv, z0 * (1.0 + h0) * inv, 2.0 / rho)
    reed = (a1, a2, a3, b1, y_m, y_c, alpha, alpha == 2.0, lam, s_fs)
    r1 = 0
    r2 = 0
    c1 = 0
    c2 = 0
    for i in range(n):
        m = n0 + i
        if on2 and r2 == 0:
            _fdl_tail(x, n0, c2, level2, f2_re, f2_im, work2)
            for j in range(n_par):
                _fdl_tail(xt[j], n0, c2, level2, ft2_re[j], ft2_im[j], wt2[j])
        if on1 and r1 == 0:
            _fdl_tail(x, n0, c1, level1, f1_re, f1_im, work1)
            for j in range(n_par):
                _fdl_tail(xt[j], n0, c1, level1, ft1_re[j], ft1_im[j], wt1[j])
        q = fut[i]
        if on1:
            q += work1[4, r1]
        if on2:
            q += work2[4, r2]
        q += q_ext[i]
        y_new, hh, ur, uf, _, pp, p = _step(q, p_m, y, y_prev, dp, reed, bore)
        x[m] = pp
        _spread(fut, i, pp, head)
        out_p[i] = p
        for j in range(n_par):
            dq = fut_t[j, i]
            if on1:
                dq += wt1[j, 4, r1]
            if on2:
                dq += wt2[j, 4, r2]
            dq += c_t[j] * q_ones[i]
            dy_new, dpp, dpo = _step_tangent(
                d, j, dq, p_m, y, dy[j], y_prev, dy_prev[j], dp, ddp[j], q, y_new, hh, ur, uf,
                reed, bore,
            )  # fmt: skip
            xt[j, m] = dpp
            _spread(fut_t[j], i, dpp, head)
            out_dp[j, i] = dpo
            dy_prev[j] = dy[j]
            dy[j] = dy_new
            ddp[j] = d[7, j] - dpo
        y_prev = y
        y = y_new
        dp = p_m - p
        r1 += 1
        if r1 == blk1:
            r1 = 0
            c1 += 1
        r2 += 1
        if r2 == blk2:
            r2 = 0
            c2 += 1
    return y, y_prev, dp


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
    n_samples = _check_length(n_samples)
    check_stability(reed, kernel.fs)
    lean = kernel.lean
    n0 = lean.n0
    x = np.zeros(n0 + n_samples)
    if state is None:
        y, y_prev, dp = 0.0, 0.0, float(reed.p_m)
    else:
        y, y_prev, dp = _load_history(x, n0, kernel.n_taps, state)
    d = coefficient_derivatives(reed, kernel.fs, tuple(names), contact_at_closure)
    n_par = d.shape[1]
    # from rest the tangent of dp(0) = p_m is dp_m; from a given state it is 0
    ddp = d[7].copy() if state is None else np.zeros(n_par)
    out = np.empty(n_samples)
    out_dp = np.empty((n_par, n_samples))
    f1_re, f1_im, f2_re, f2_im = lean.history_spectra(x)
    zeros = [np.zeros((n_par, *a.shape)) for a in (f1_re, f1_im, f2_re, f2_im)]
    a1, a2, a3, b1 = reed_coefficients(reed, kernel.fs)
    _run_pressure_tangent(
        x, n0, n_samples, lean.head, lean.h0, kernel.z0, kernel.rho, a1, a2, a3, b1,
        reed.y_m, reed.y_c, reed.alpha, reed.lam, reed.S * kernel.fs, reed.p_m, y, y_prev,
        dp, lean.level1, f1_re, f1_im, np.zeros((5, lean.block1 + 1)), lean.level2, f2_re,
        f2_im, np.zeros((5, lean.block2 + 1)), np.empty(n_samples + lean.head.size), out, d,
        np.zeros(n_par), np.zeros(n_par), ddp, np.zeros((n_par, x.size)), zeros[0], zeros[1],
        np.zeros((n_par, 5, lean.block1 + 1)), zeros[2], zeros[3],
        np.zeros((n_par, 5, lean.block2 + 1)), np.empty((n_par, n_samples + lean.head.size)),
        out_dp, np.zeros(n_samples), np.zeros(n_samples), np.zeros(n_par),
    )  # fmt: skip
    return out, out_dp
