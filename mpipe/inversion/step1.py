"""Step 1: closed-form flow fit of a quasi-static reed (paper section 3.1, physics.md H).

With the reed's mass and damping neglected and no contact, y = dp/k and the mouthpiece flow
is linear in three coefficients:

    u = c1 d1 + c2 d2 + c3 d3,
    d1 = sqrt(2/rho) |dp|^(3/2),  d2 = sgn(dp) sqrt(2/rho) |dp|^(1/2),  d3 = dp/dt (of p),
    c1 = -lambda/k,  c2 = lambda y_m,  c3 = -S/k,

with dp = p_m - p. F1 = ||u - X c||^2 is quadratic (convex) in c, so it is minimised exactly
by linear least squares; the paper's Nelder-Mead is kept for comparison. The closing
(dp/dt < 0) and opening (dp/dt > 0) branches are fitted separately.

The mouth pressure p_m is either given, taken as max p over the window (the paper's choice),
or estimated: for a fixed p_m each branch's F1 is an exact linear least-squares problem, so
p_m is found by a bounded 1-D search over the profile of F1 (:func:`estimate_p_m`). The
estimate matters because the fit is steep in p_m: on the paper's Table 1 case max p lies 18 %
below the true p_m, and k, S and y_m come out 30-190 % off.

Samples that violate the model are left out: a shut reed (fitted opening y_m - dp/k <= 0)
and, when the contact displacement y_c is given, a reed in contact with the lay (dp/k > y_c),
where the lay's force makes y smaller than dp/k.

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
        Samples dropped by the refinement (fitted opening <= 0 or, with ``y_c``, contact).
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
        Mouth pressure used, Pa.
    lam : float
        Reed width held fixed, m.
    rho : float
        Air density, kg/m^3.
    closing, opening : BranchFit
        The two branch fits.
    p_m_method : str
        How ``p_m`` was obtained: ``"given"``, ``"max"`` (max p over the window) or
        ``"estimate"`` (profile of F1, :func:`estimate_p_m`).
    max_p : float
        Largest pressure over the window, Pa (the reference of the step-2 p_m bounds).
    """

    p_m: float
    lam: float
    rho: float
    closing: BranchFit
    opening: BranchFit
    p_m_method: str = "max"
    max_p: float = np.nan

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


#: Most refits of the sample-selection refinement; the selection usually settles in 2-6.
MAX_REFITS = 20

PmMethod = Literal["max", "estimate"]


def _regressors(
    p: np.ndarray, p_m: float, fs: float, rho: float, zero_mean: bool
) -> tuple[np.ndarray, np.ndarray]:
    d1, d2, d3 = flow_signals(p, p_m, fs, rho)
    x = np.column_stack([d1, d2, d3])
    if zero_mean:
        x = x - x.mean(axis=0)
    return x, d3


def _branch_mask(d3: np.ndarray, branch: str) -> np.ndarray:
    if branch not in ("closing", "opening"):
        raise ValueError(f"branch must be 'closing' or 'opening', got {branch!r}")
    return d3 < 0 if branch == "closing" else d3 > 0


def _admissible(c: np.ndarray, dp: np.ndarray, lam: float, y_c: float | None) -> np.ndarray:
    """Samples the quasi-static, contact-free model can describe, given a fit ``c``."""
    if not c[0] < 0:  # no finite positive stiffness: nothing to judge the samples by
        return np.ones(dp.shape, dtype=bool)
    y = dp / (-lam / c[0])  # quasi-static displacement dp/k
    keep = c[1] / lam - y > 0  # reed open
    if y_c is not None:
        keep &= y <= y_c  # reed off the lay
    return keep


def _fit_mask(x: np.ndarray, u: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, float, str]:
    c, used = _solve_lstsq(x[mask], u[mask])
    r = u[mask] - x[mask] @ c
    return c, float(r @ r), used


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
    y_c: float | None = None,
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
        Drop the samples the model cannot describe and refit, until the selection no
        longer changes (at most :data:`MAX_REFITS` refits): a shut reed (fitted opening
        ``y_m - dp/k <= 0``, physics.md H, refinement) and, with ``y_c``, contact.
    y_c : float, optional
        Displacement where reed-lay contact begins, m. With ``refine``, samples with
        ``dp/k > y_c`` (fitted k) are dropped: there the lay pushes back, y < dp/k, and the
        step-1 model (no contact) does not hold. Default: contact samples are kept.
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
    x, d3 = _regressors(p, p_m, fs, rho, zero_mean)
    branch_mask = _branch_mask(d3, branch)
    if branch_mask.sum() < 3:
        raise ValueError(f"the {branch} branch has {int(branch_mask.sum())} samples; need >= 3")
    mask = _select(x, u, p_m - p, branch_mask, lam, y_c, refine)
    if mask.sum() < 0.1 * branch_mask.sum():
        # The drop-and-refit loop runs away when p_m is far off (e.g. max p well below
        # the true p_m): every refit lowers k, which flags more samples as contact.
        log.warning(
            "step 1: the refinement kept %d of %d samples of the %s branch; p_m %.1f Pa is "
            "probably wrong",
            int(mask.sum()),
            int(branch_mask.sum()),
            branch,
            p_m,
        )
    c, used_solver = _solve_lstsq(x[mask], u[mask])
    n_iter = 1
    if solver == "nelder-mead":
        c, n_iter = _solve_nelder_mead(x[mask], u[mask], _nm_start(c), nm_xtol)
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
        n_dropped=int(branch_mask.sum() - mask.sum()),
        n_iterations=n_iter,
        solver=used_solver,
    )


def _select(
    x: np.ndarray,
    u: np.ndarray,
    dp: np.ndarray,
    branch_mask: np.ndarray,
    lam: float,
    y_c: float | None,
    refine: bool,
) -> np.ndarray:
    """Samples of one branch kept by the refinement (a fixed point of fit-and-drop)."""
    mask = branch_mask
    if not refine:
        return mask
    for _ in range(MAX_REFITS):
        c, _, _ = _fit_mask(x, u, mask)
        keep = branch_mask & _admissible(c, dp, lam, y_c)
        if keep.sum() < 3 or np.array_equal(keep, mask):
            break
        mask = keep
    return mask


def _nm_start(c_exact: np.ndarray) -> np.ndarray:
    # The paper started its simplex from literature values; we start from a point 30 %
    # away from the exact minimiser, in every coordinate, so that the comparison with the
    # exact solve measures the search and not a lucky start.
    start = c_exact * 1.3
    start[start == 0] = 1e-12
    return start


def estimate_p_m(
    p: np.ndarray,
    u: np.ndarray,
    fs: float,
    *,
    rho: float,
    lam: float,
    zero_mean: bool = False,
    refine: bool = True,
    y_c: float | None = None,
    bounds: tuple[float, float] = (1.0, 2.0),
    xtol: float = 1e-2,
) -> float:
    """Mouth pressure that minimises the step-1 misfit, profiled over the flow coefficients.

    For a fixed p_m, each branch's F1 is minimised exactly by linear least squares, so p_m
    is a 1-D bounded search (Brent) over the profile

        L(p_m) = n_c log F1_c(p_m) + n_o log F1_o(p_m),

    the negative log-likelihood (up to constants) of Gaussian residuals with a separate,
    unknown variance on each branch (n_b samples, F1_b the branch's least-squares misfit).
    One p_m serves both branches, and the branch the model fits better weighs more; summing
    the two F1 instead lets the worse-fitting closing branch pull p_m away (+1.6 % against
    +0.7 % on the Table 1 case). The samples of each branch are fixed during a search and
    re-selected (shut reed, contact) at the new p_m; search and selection alternate until
    the selection settles (at most :data:`MAX_REFITS` rounds).

    Parameters
    ----------
    p : ndarray
        Mouthpiece pressure over the window, Pa.
    u : ndarray
        Mouthpiece flow into the bore over the window, m^3/s.
    fs : float
        Sample rate, Hz.
    rho : float
        Air density, kg/m^3.
    lam : float
        Reed width, m.
    zero_mean, refine, y_c
        As in :func:`fit_branch`.
    bounds : tuple of float
        Search interval as factors of max p over the window (dimensionless).
    xtol : float
        Absolute tolerance of the search, Pa.

    Returns
    -------
    float
        Estimated mouth pressure, Pa.

    Raises
    ------
    ValueError
        If either branch has fewer than 4 samples, max p <= 0, or the bounds are not
        ``0 < lower < upper``.

    Notes
    -----
    The profile is well defined when the window holds both branches of a periodic
    oscillation: too low a p_m makes dp small where the flow is large, too high a p_m
    overshoots the curvature of u(dp). A minimum at a bound is logged as a warning.

    References
    ----------
    Chatziioannou & van Walstijn 2012, section 3.1 (p_m = max p there); physics.md H.
    """
    p = np.asarray(p, dtype=float)
    u = np.asarray(u, dtype=float)
    lo_f, hi_f = bounds
    if not 0 < lo_f < hi_f:
        raise ValueError(f"bounds must satisfy 0 < lower < upper, got {bounds}")
    max_p = float(np.max(p))
    if not max_p > 0:
        raise ValueError(f"max p over the window is {max_p:g} Pa; expected > 0")
    lo, hi = lo_f * max_p, hi_f * max_p
    d3 = np.gradient(p) * fs
    branch_masks = [_branch_mask(d3, b) for b in ("closing", "opening")]
    if min(int(m.sum()) for m in branch_masks) < 4:
        raise ValueError("estimating p_m needs at least 4 samples on each branch")
    masks = list(branch_masks)

    def profile(pm: float) -> float:
        x, _ = _regressors(p, pm, fs, rho, zero_mean)
        total = 0.0
        for m in masks:
            f1 = _fit_mask(x, u, m)[1]
            total += m.sum() * np.log(max(f1, 1e-300))
        return total

    p_m = 0.5 * (lo + hi)
    for _ in range(MAX_REFITS):
        res = optimize.minimize_scalar(
            profile, bounds=(lo, hi), method="bounded", options={"xatol": xtol}
        )
        p_m = float(res.x)
        x, _ = _regressors(p, p_m, fs, rho, zero_mean)
        new = [_select(x, u, p_m - p, bm, lam, y_c, refine) for bm in branch_masks]
        if all(np.array_equal(a, b) for a, b in zip(new, masks, strict=True)):
            break
        masks = new
    if min(p_m - lo, hi - p_m) < 10 * xtol:
        log.warning(
            "step 1: the p_m estimate %.1f Pa lies at a search bound [%.1f, %.1f] Pa", p_m, lo, hi
        )
    return p_m


def step1(
    p: np.ndarray,
    u: np.ndarray,
    fs: float,
    *,
    rho: float,
    lam: float,
    p_m: float | PmMethod | None = "max",
    solver: Solver = "lstsq",
    zero_mean: bool = False,
    refine: bool = True,
    y_c: float | None = None,
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
    p_m : float or {"max", "estimate"}, optional
        Mouth pressure: a value in Pa; ``"max"`` (or None), max(p) over the window (the
        paper's choice); ``"estimate"``, the minimiser of the profiled F1 over
        [max p, 2 max p] (:func:`estimate_p_m`).
    solver : {"lstsq", "nelder-mead"}
        See :func:`fit_branch`.
    zero_mean : bool
        The flow is zero-mean (measured data); see :func:`fit_branch`.
    refine : bool
        Drop shut-reed (and, with ``y_c``, contact) samples and refit.
    y_c : float, optional
        Displacement where reed-lay contact begins, m; see :func:`fit_branch`.

    Returns
    -------
    Step1Result

    Raises
    ------
    ValueError
        For an unknown ``p_m`` method.

    References
    ----------
    Chatziioannou & van Walstijn 2012, section 3.1, eqs. (9)-(14).
    """
    p = np.asarray(p, dtype=float)
    max_p = float(np.max(p))
    if p_m is None or (isinstance(p_m, str) and p_m == "max"):
        pm, method = max_p, "max"
    elif isinstance(p_m, str) and p_m == "estimate":
        pm = estimate_p_m(p, u, fs, rho=rho, lam=lam, zero_mean=zero_mean, refine=refine, y_c=y_c)
        method = "estimate"
    elif isinstance(p_m, str):
        raise ValueError(f"p_m must be a pressure in Pa, 'max' or 'estimate', got {p_m!r}")
    else:
        pm, method = float(p_m), "given"
    kwargs = dict(
        p_m=pm, rho=rho, lam=lam, solver=solver, zero_mean=zero_mean, refine=refine, y_c=y_c
    )
    closing = fit_branch(p, u, fs, branch="closing", **kwargs)
    opening = fit_branch(p, u, fs, branch="opening", **kwargs)
    log.debug(
        "step 1 (p_m %s %.1f Pa): closing k=%.3g S=%.3g y_m=%.3g; opening k=%.3g S=%.3g y_m=%.3g",
        method,
        pm,
        closing.k,
        closing.S,
        closing.y_m,
        opening.k,
        opening.S,
        opening.y_m,
    )
    return Step1Result(
        p_m=pm,
        lam=lam,
        rho=rho,
        closing=closing,
        opening=opening,
        p_m_method=method,
        max_p=max_p,
    )


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
