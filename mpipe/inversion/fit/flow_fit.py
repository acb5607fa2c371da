"""Step 1's flow fit on one branch: regressors, exact least squares, sample refinement.

With the reed's mass and damping neglected and no contact, y = dp/k and the mouthpiece flow
is linear in three coefficients:

    u = c1 d1 + c2 d2 + c3 d3,
    d1 = sqrt(2/rho) |dp|^(3/2),  d2 = sgn(dp) sqrt(2/rho) |dp|^(1/2),  d3 = dp/dt (of p),
    c1 = -lambda/k,  c2 = lambda y_m,  c3 = -S/k,

with dp = p_m - p. F1 = ||u - X c||^2 is quadratic (convex) in c, so it is minimised exactly
by linear least squares (the paper searched it by Nelder-Mead). The closing
(dp/dt < 0) and opening (dp/dt > 0) branches are fitted separately.

Samples that violate the model are left out: a shut reed (fitted opening y_m - dp/k <= 0)
and, when the contact displacement y_c is given, a reed in contact with the lay (dp/k > y_c),
where the lay's force makes y smaller than dp/k.

References
----------
Chatziioannou & van Walstijn 2012, eqs. (9)-(13); physics.md H.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy import optimize

log = logging.getLogger(__name__)

Branch = Literal["closing", "opening"]


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
        ``"lstsq"`` or ``"lsq_linear"`` (bounded).
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


#: Most refits of the sample-selection refinement; the selection usually settles in 2-6.
MAX_REFITS = 20


def regressors(
    p: np.ndarray, p_m: float, fs: float, rho: float, zero_mean: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Regressor matrix ``[d1 d2 d3]`` (centred for a zero-mean flow) and ``d3`` (Pa/s)."""
    d1, d2, d3 = flow_signals(p, p_m, fs, rho)
    x = np.column_stack([d1, d2, d3])
    if zero_mean:
        x = x - x.mean(axis=0)
    return x, d3


def branch_samples(d3: np.ndarray, branch: str) -> np.ndarray:
    """Samples of a branch: closing (``d3 = dp/dt < 0``, Pa/s) or opening (``d3 > 0``)."""
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


def fit_mask(x: np.ndarray, u: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, float, str]:
    """Least-squares coefficients on the samples ``mask``, their F1 and the solver used."""
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
    zero_mean: bool = False,
    refine: bool = True,
    y_c: float | None = None,
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
    x, d3 = regressors(p, p_m, fs, rho, zero_mean)
    branch_mask = branch_samples(d3, branch)
    if branch_mask.sum() < 3:
        raise ValueError(f"the {branch} branch has {int(branch_mask.sum())} samples; need >= 3")
    mask = select_samples(x, u, p_m - p, branch_mask, lam, y_c, refine)
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
        n_iterations=1,
        solver=used_solver,
    )


def select_samples(
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
        c, _, _ = fit_mask(x, u, mask)
        keep = branch_mask & _admissible(c, dp, lam, y_c)
        if keep.sum() < 3 or np.array_equal(keep, mask):
            break
        mask = keep
    return mask


__all__ = [
    "Branch",
    "BranchFit",
    "MAX_REFITS",
    "branch_samples",
    "fit_branch",
    "fit_mask",
    "flow_signals",
    "regressors",
    "select_samples",
]
