"""Step 1's mouth pressure: the p_m that minimises the flow fit's misfit, profiled.

For a fixed p_m each branch's F1 is an exact linear least-squares problem
(:mod:`mpipe.inversion.fit.flow_fit`), so p_m is found by a bounded 1-D search over the profile
of F1. The estimate matters because the fit is steep in p_m: on the paper's Table 1 case
max p lies 18 % below the true p_m, and k, S and y_m come out 30-190 % off.

References
----------
Chatziioannou & van Walstijn 2012, section 3.1 (p_m = max p there); physics.md H.
"""

from __future__ import annotations

import logging

import numpy as np
from scipy import optimize

from mpipe.inversion.fit.flow_fit import (
    MAX_REFITS,
    branch_samples,
    fit_mask,
    regressors,
    select_samples,
)

log = logging.getLogger(__name__)


#: Absolute tolerance of the p_m search, Pa.
XTOL_PA = 1e-2


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
    where: str = "",
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
    the selection settles (at most :data:`mpipe.inversion.fit.flow_fit.MAX_REFITS` rounds).

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
        As in :func:`mpipe.inversion.fit.flow_fit.fit_branch`.
    bounds : tuple of float
        Search interval as factors of max p over the window (dimensionless).
    where : str
        Which window this is (``"window at 0.250-0.300 s"``), named by the warning when the
        estimate lies at a search bound.

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
    branch_masks = [branch_samples(d3, b) for b in ("closing", "opening")]
    if min(int(m.sum()) for m in branch_masks) < 4:
        raise ValueError("estimating p_m needs at least 4 samples on each branch")
    masks = list(branch_masks)

    def profile(pm: float) -> float:
        x, _ = regressors(p, pm, fs, rho, zero_mean)
        total = 0.0
        for m in masks:
            f1 = fit_mask(x, u, m)[1]
            total += m.sum() * np.log(max(f1, 1e-300))
        return total

    p_m = 0.5 * (lo + hi)
    for _ in range(MAX_REFITS):
        res = optimize.minimize_scalar(
            profile, bounds=(lo, hi), method="bounded", options={"xatol": XTOL_PA}
        )
        p_m = float(res.x)
        x, _ = regressors(p, p_m, fs, rho, zero_mean)
        new = [select_samples(x, u, p_m - p, bm, lam, y_c, refine) for bm in branch_masks]
        if all(np.array_equal(a, b) for a, b in zip(new, masks, strict=True)):
            break
        masks = new
    if min(p_m - lo, hi - p_m) < 10 * XTOL_PA:
        log.warning(
            "step 1%s: the p_m estimate %.1f Pa lies at a search bound [%.1f, %.1f] Pa",
            f" ({where})" if where else "",
            p_m,
            lo,
            hi,
        )
    return p_m


__all__ = ["estimate_p_m"]
