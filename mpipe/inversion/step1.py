"""Step 1: closed-form flow fit of a quasi-static reed (paper section 3.1, physics.md H).

With the reed's mass and damping neglected and no contact, y = dp/k and the mouthpiece flow
is linear in three coefficients:

    u = c1 d1 + c2 d2 + c3 d3,
    d1 = sqrt(2/rho) |dp|^(3/2),  d2 = sgn(dp) sqrt(2/rho) |dp|^(1/2),  d3 = dp/dt (of p),
    c1 = -lambda/k,  c2 = lambda y_m,  c3 = -S/k,

with dp = p_m - p. F1 = ||u - X c||^2 is quadratic (convex) in c, so it is minimised exactly
by linear least squares; the paper's Nelder-Mead is kept for comparison. The closing
(dp/dt < 0) and opening (dp/dt > 0) branches are fitted separately.

References
----------
Chatziioannou & van Walstijn 2012, eqs. (9)-(14).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy import optimize

log = logging.getLogger(__name__)

Branch = Literal["closing", "opening"]
Solver = Literal["lstsq", "nelder-mead"]


@dataclass(frozen=True)
class BranchFit:
    """Step-1 fit of one branch.

    Attributes
    ----------
    branch : str
        ``"closing"`` (dp/dt < 0) or ``"opening"`` (dp/dt > 0).
    k : float
        Reed stiffness per unit area, Pa/m.
    S : float
        Effective reed area, m^2.
    y_m : float
        Rest opening, m.
    c : ndarray
        Coefficients (c1, c2, c3), each in the unit that makes ``c_i d_i`` a flow in m^3/s
        (c2 in m^2, c3 in m^3/Pa); see the module docstring.
    f1 : float
        F1 = ||u - X c||^2 over the samples used, (m^3/s)^2.
    relative_residual : float
        ||u - X c|| / ||u|| over the samples used.
    n_samples : int
        Samples used in the final fit.
    n_dropped : int
        Samples dropped by the refinement (fitted opening h <= 0).
    n_iterations : int
        Solver iterations (1 for the exact least-squares solve).
    solver : str
        ``"lstsq"``, ``"lsq_linear"`` (bounded) or ``"nelder-mead"``.
    """

    branch: str
    k: float
    S: float
    y_m: float
    c: np.ndarray
    f1: float
    relative_residual: float
    n_samples: int
    n_dropped: int
    n_iterations: int
    solver: str


@dataclass(frozen=True)
class Step1Result:
    """Step-1 estimates of both branches.

    Attributes
    ----------
    p_m : float
        Mouth pressure used, Pa (``max p`` unless given).
    lam : float
        Reed width held fixed, m.
    rho : float
        Air density, kg/m^3.
    closing, opening : BranchFit
        The two branch fits.
    """

    p_m: float
    lam: float
    rho: float
    closing: BranchFit
    opening: BranchFit

    def branch(self, name: Branch) -> BranchFit:
        """Return the fit of branch ``name`` ("closing" or "opening")."""
        if name not in ("closing", "opening"):
            raise ValueError(f"branch must be 'closing' or 'opening', got {name!r}")
        return self.closing if name == "closing" else self.opening


def flow_signals(
    p: np.ndarray, p_m: float, fs: float, rho: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return the regressors d1, d2, d3 of the quasi-static flow.

    Parameters
    ----------
    p : ndarray
        Mouthpiece pressure, Pa (already low-passed for measured data).
    p_m : float
        Mouth pressure, Pa.
    fs : float
        Sample rate, Hz.
    rho : float
        Air density, kg/m^3.

    Returns
    -------
    d1 : ndarray
        ``sqrt(2/rho) |dp|^(3/2)``, (m^3/kg)^(1/2) Pa^(3/2).
    d2 : ndarray
        ``sgn(dp) sqrt(2/rho) |dp|^(1/2)``, m/s.
    d3 : ndarray
        ``dp/dt`` by central differences, Pa/s.

    References
    ----------
    Chatziioannou & van Walstijn 2012, eqs. (10) and (12), with the signs of physics.md H.
    """
    p = np.asarray(p, dtype=float)
    dp = p_m - p
    q = np.sqrt(2.0 / rho)
    a = np.abs(dp)
    d1 = q * a**1.5
    d2 = np.sign(dp) * q * np.sqrt(a)
    d3 = np.gradient(p) * fs
    return d1, d2, d3


def _solve_lstsq(x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, str]:
    # Columns differ by ~12 orders of magnitude; scale them to unit norm first.
    scale = np.linalg.norm(x, axis=0)
    scale[scale == 0] = 1.0
    xs = x / scale
    cs, *_ = np.linalg.lstsq(xs, u, rcond=None)
    if cs[0] < 0 and cs[1] > 0 and cs[2] < 0:
        return cs / scale, "lstsq"
    # Unphysical unconstrained fit: c1 < 0, c2 > 0, c3 < 0 enforced (closed bounds with
    # a tiny margin, so that the back-mapping stays finite).
    tiny = 1e-12 * float(np.max(np.abs(cs)) + 1e-300)
    res = optimize.lsq_linear(
        xs, u, bounds=([-np.inf, tiny, -np.inf], [-tiny, np.inf, -tiny]), method="bvls"
    )
    return res.x / scale, "lsq_linear"


def _solve_nelder_mead(
    x: np.ndarray, u: np.ndarray, c_start: np.ndarray, xtol: float
) -> tuple[np.ndarray, int]:
    # Work in units of the start coefficients, so that xatol is a relative change.
    xs = x * c_start

    def f1(v: np.ndarray) -> float:
        r = u - xs @ v
        return float(r @ r)

    # scipy stops when both the simplex size (xatol) and the spread of F1 (fatol) are
    # small; fatol is made relative to F1 at the start.
    res = optimize.minimize(
        f1,
        np.ones(3),
        method="Nelder-Mead",
        options={"xatol": xtol, "fatol": 1e-6 * f1(np.ones(3)), "maxiter": 20000},
    )
    return res.x * c_start, int(res.nit)


def fit_branch(
    p: np.ndarray,
    u: np.ndarray,
    fs: float,
    *,
    branch: Branch,
    p_m: float,
    rho: float,
    lam: float,
    solver: Solver = "lstsq",
    zero_mean: bool = False,
    refine: bool = True,
    nm_xtol: float = 0.01,
) -> BranchFit:
    """Fit the quasi-static flow on one branch of a window.

    Parameters
    ----------
    p : ndarray
        Mouthpiece pressure, Pa.
    u : ndarray
        Mouthpiece volume flow into the bore, m^3/s.
    fs : float
        Sample rate, Hz.
    branch : {"closing", "opening"}
        Samples with dp/dt < 0 (closing) or dp/dt > 0 (opening).
    p_m : float
        Mouth pressure, Pa.
    rho : float
        Air density, kg/m^3.
    lam : float
        Reed width lambda held fixed, m.
    solver : {"lstsq", "nelder-mead"}
        Exact linear least squares (bounded by ``lsq_linear`` when the unconstrained fit
        is unphysical), or the paper's Nelder-Mead.
    zero_mean : bool
        The flow is zero-mean (measured): every regressor is centred by its mean over the
        whole window, which removes the unknown mean flow from the fit.
    refine : bool
        Drop samples whose fitted opening ``y_m - dp/k`` is <= 0 and refit once
        (physics.md H, refinement).
    nm_xtol : float
        Nelder-Mead termination: relative change of the coefficients (the paper's 1 %).

    Returns
    -------
    BranchFit

    Raises
    ------
    ValueError
        If the branch has fewer than 3 samples.

    References
    ----------
    Chatziioannou & van Walstijn 2012, eqs. (10), (11), (13).
    """
    p = np.asarray(p, dtype=float)
    u = np.asarray(u, dtype=float)
    if p.shape != u.shape or p.ndim != 1:
        raise ValueError(f"p and u must be 1-D of equal length, got {p.shape} and {u.shape}")
    d1, d2, d3 = flow_signals(p, p_m, fs, rho)
    x = np.column_stack([d1, d2, d3])
    if zero_mean:
        x = x - x.mean(axis=0)
    if branch not in ("closing", "opening"):
        raise ValueError(f"branch must be 'closing' or 'opening', got {branch!r}")
    mask = d3 < 0 if branch == "closing" else d3 > 0
    dp = p_m - p
    n_dropped = 0
    c = np.zeros(3)
    used_solver = solver
    n_iter = 1
    for attempt in range(2 if refine else 1):
        if attempt == 1:
            k_fit = -lam / c[0]
            keep = mask & (c[1] / lam - dp / k_fit > 0)
            n_dropped = int(mask.sum() - keep.sum())
            if n_dropped == 0 or keep.sum() < 3:
                break
            mask = keep
        if mask.sum() < 3:
            raise ValueError(f"the {branch} branch has {int(mask.sum())} samples; need >= 3")
        xb, ub = x[mask], u[mask]
        c, used_solver = _solve_lstsq(xb, ub)
        n_iter = 1
        if solver == "nelder-mead":
            c_exact = c
            c, n_iter = _solve_nelder_mead(xb, ub, _nm_start(c_exact), nm_xtol)
            used_solver = "nelder-mead"
    xb, ub = x[mask], u[mask]
    r = ub - xb @ c
    f1 = float(r @ r)
    k = -lam / c[0] if c[0] != 0 else np.inf
    return BranchFit(
        branch=branch,
        k=float(k),
        S=float(lam * c[2] / c[0]) if c[0] != 0 else np.nan,
        y_m=float(c[1] / lam),
        c=c,
        f1=f1,
        relative_residual=float(np.sqrt(f1) / (np.linalg.norm(ub) + 1e-300)),
        n_samples=int(mask.sum()),
        n_dropped=n_dropped,
        n_iterations=n_iter,
        solver=used_solver,
    )


def _nm_start(c_exact: np.ndarray) -> np.ndarray:
    # The paper started its simplex from literature values; we start from a point 30 %
    # away from the exact minimiser, in every coordinate, so that the comparison with the
    # exact solve measures the search and not a lucky start.
    start = c_exact * 1.3
    start[start == 0] = 1e-12
    return start


def step1(
    p: np.ndarray,
    u: np.ndarray,
    fs: float,
    *,
    rho: float,
    lam: float,
    p_m: float | None = None,
    solver: Solver = "lstsq",
    zero_mean: bool = False,
    refine: bool = True,
) -> Step1Result:
    """Run step 1 on one window: both branches.

    Parameters
    ----------
    p : ndarray
        Mouthpiece pressure over the window, Pa.
    u : ndarray
        Mouthpiece volume flow into the bore over the window, m^3/s.
    fs : float
        Sample rate, Hz.
    rho : float
        Air density, kg/m^3.
    lam : float
        Reed width lambda, m (held fixed, eq. 11 cannot separate it from k, y_m, S).
    p_m : float, optional
        Mouth pressure, Pa; ``max(p)`` when not given (the paper's choice).
    solver : {"lstsq", "nelder-mead"}
        See :func:`fit_branch`.
    zero_mean : bool
        The flow is zero-mean (measured data); see :func:`fit_branch`.
    refine : bool
        Drop shut-reed samples and refit once.

    Returns
    -------
    Step1Result

    References
    ----------
    Chatziioannou & van Walstijn 2012, section 3.1, eqs. (9)-(14).
    """
    p = np.asarray(p, dtype=float)
    pm = float(np.max(p)) if p_m is None else float(p_m)
    kwargs = dict(p_m=pm, rho=rho, lam=lam, solver=solver, zero_mean=zero_mean, refine=refine)
    closing = fit_branch(p, u, fs, branch="closing", **kwargs)
    opening = fit_branch(p, u, fs, branch="opening", **kwargs)
    log.debug(
        "step 1: closing k=%.3g S=%.3g y_m=%.3g; opening k=%.3g S=%.3g y_m=%.3g",
        closing.k,
        closing.S,
        closing.y_m,
        opening.k,
        opening.S,
        opening.y_m,
    )
    return Step1Result(p_m=pm, lam=lam, rho=rho, closing=closing, opening=opening)


def quasi_static_flow(
    p: np.ndarray, fs: float, *, k: float, S: float, y_m: float, p_m: float, lam: float, rho: float
) -> np.ndarray:
    """Flow of the quasi-static reed, eq. (10), with the opening clipped at zero.

    Parameters
    ----------
    p : ndarray
        Mouthpiece pressure, Pa.
    fs : float
        Sample rate, Hz.
    k, S, y_m, p_m, lam : float
        Stiffness Pa/m, area m^2, rest opening m, mouth pressure Pa, width m.
    rho : float
        Air density, kg/m^3.

    Returns
    -------
    ndarray
        Volume flow into the bore, m^3/s.

    References
    ----------
    Chatziioannou & van Walstijn 2012, eq. (10); physics.md H.
    """
    p = np.asarray(p, dtype=float)
    dp = p_m - p
    h = np.maximum(y_m - dp / k, 0.0)
    u_f = np.sign(dp) * lam * h * np.sqrt(2.0 * np.abs(dp) / rho)
    u_r = -(S / k) * np.gradient(p) * fs
    return u_f + u_r
