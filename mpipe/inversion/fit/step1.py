"""Step 1: closed-form flow fit of a quasi-static reed (paper section 3.1, physics.md H).

With the reed's mass and damping neglected and no contact, y = dp/k and the mouthpiece flow
is linear in three coefficients (c1 = -lambda/k, c2 = lambda y_m, c3 = -S/k), fitted
exactly by linear least squares on the closing (dp/dt < 0) and opening (dp/dt > 0)
branches separately (:mod:`mpipe.inversion.fit.flow_fit`); the paper searched it by Nelder-Mead.

The mouth pressure p_m is either given, taken as max p over the window (the paper's choice),
or estimated: for a fixed p_m each branch's F1 is an exact linear least-squares problem, so
p_m is found by a bounded 1-D search over the profile of F1
(:func:`mpipe.inversion.fit.mouth_pressure.estimate_p_m`). The estimate matters because the
fit is steep in p_m: on the paper's Table 1 case max p lies 18 % below the true p_m, and
k, S and y_m come out 30-190 % off.

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

from mpipe.inversion.fit.flow_fit import Branch, BranchFit, fit_branch
from mpipe.inversion.fit.mouth_pressure import estimate_p_m

log = logging.getLogger(__name__)

PmMethod = Literal["max", "estimate"]


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
        ``"estimate"`` (profile of F1, :func:`mpipe.inversion.fit.mouth_pressure.estimate_p_m`).
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


def step1(
    p: np.ndarray,
    u: np.ndarray,
    fs: float,
    *,
    rho: float,
    lam: float,
    p_m: float | PmMethod | None = "max",
    zero_mean: bool = False,
    refine: bool = True,
    y_c: float | None = None,
    where: str = "",
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
        [max p, 2 max p] (:func:`mpipe.inversion.fit.mouth_pressure.estimate_p_m`).
    zero_mean : bool
        The flow is zero-mean (measured data); see
        :func:`mpipe.inversion.fit.flow_fit.fit_branch`.
    refine : bool
        Drop shut-reed (and, with ``y_c``, contact) samples and refit.
    y_c : float, optional
        Displacement where reed-lay contact begins, m; see
        :func:`mpipe.inversion.fit.flow_fit.fit_branch`.
    where : str
        Which window this is, for the console (a p_m estimate at a search bound names it).

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
        pm = estimate_p_m(p, u, fs, rho=rho, lam=lam, zero_mean=zero_mean, refine=refine,
                          y_c=y_c, where=where)  # fmt: skip
        method = "estimate"
    elif isinstance(p_m, str):
        raise ValueError(f"p_m must be a pressure in Pa, 'max' or 'estimate', got {p_m!r}")
    else:
        pm, method = float(p_m), "given"
    kwargs = dict(p_m=pm, rho=rho, lam=lam, zero_mean=zero_mean, refine=refine, y_c=y_c)
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


__all__ = ["PmMethod", "Step1Result", "quasi_static_flow", "step1"]
