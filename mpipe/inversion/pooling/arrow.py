"""The joint normal equations of a note's windows: a block-arrow system and its covariance.

A note of W windows has, per window i, f fast parameters (p_m, y_m) of its own and s slow
ones shared by all windows. Window i's residual ``r_i`` (Pa) and Jacobian ``J_i = dr_i/dz``
(columns: its fast parameters, then the slow ones; ``z`` the log parameters) give the
blocks of the Gauss-Newton normal matrix ``A = sum_i J_i^T J_i`` and gradient
``g = sum_i J_i^T r_i``:

    A = [ F_1            C_1   ]      F_i = J_fi^T J_fi   (f x f)
        [      ...       ...   ]      C_i = J_fi^T J_si   (f x s)
        [           F_W  C_W   ]      D   = sum_i J_si^T J_si   (s x s)
        [ C_1^T ... C_W^T  D   ]

(bordered block-diagonal: "block arrow"). Eliminating each window's fast block gives the
Schur complement ``S = D - sum_i C_i^T F_i^-1 C_i`` (s x s), so a Gauss-Newton step costs
W small solves and one s x s solve: linear in W, where the dense system of size
``W f + s`` costs ``(W f + s)^3``.

The covariance of the estimate is the sandwich ``A^-1 B A^-1`` with ``B`` block diagonal
over windows (each window's noise is its own; ``B_i`` is window i's noise gram, see
:mod:`mpipe.inversion.trust.uncertainty`). The same elimination gives it in linear cost: with
``u_i = J_i^T e_i`` (``cov u_i = B_i``), the slow estimate moves by
``S^-1 sum_i M_i u_i``, ``M_i = [-C_i^T F_i^-1, I]``, and window i's fast one by
``L_i u_i - K_i ds``, ``L_i = F_i^-1 [I, 0]``, ``K_i = F_i^-1 C_i``.

References
----------
B. Triggs, P. McLauchlan, R. Hartley, A. Fitzgibbon, "Bundle adjustment - a modern
synthesis", Vision Algorithms: Theory and Practice, Springer 2000, section 6.1 (the reduced
camera system: the same elimination). G. A. F. Seber, C. J. Wild, *Nonlinear Regression*,
Wiley 1989, section 2.1 (the sandwich covariance).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

#: Eigenvalues of the Schur complement below this fraction of the largest mark a slow
#: direction the note does not determine (the square of the per-window SVD's
#: :data:`mpipe.inversion.trust.uncertainty.RCOND`: eigenvalues of J^T J are squared singular
#: values).
EIG_RCOND = 1e-6


@dataclass(frozen=True)
class ArrowSystem:
    """The block-arrow normal equations of a note (see the module docstring).

    Attributes
    ----------
    f_blocks : ndarray
        ``F_i``, shape (W, f, f), Pa^2.
    c_blocks : ndarray
        ``C_i``, shape (W, f, s), Pa^2.
    d_blocks : ndarray
        Each window's ``J_si^T J_si``, shape (W, s, s), Pa^2 (``D`` is their sum).
    g_fast : ndarray
        ``J_fi^T r_i``, shape (W, f), Pa^2.
    g_slow : ndarray
        Each window's ``J_si^T r_i``, shape (W, s), Pa^2.
    """

    f_blocks: np.ndarray
    c_blocks: np.ndarray
    d_blocks: np.ndarray
    g_fast: np.ndarray
    g_slow: np.ndarray

    @classmethod
    def of(cls, jacobians: Sequence[np.ndarray], residuals: Sequence[np.ndarray], n_fast: int):
        """The system of W windows: ``jacobians[i]`` (n_i, f + s), fast columns first."""
        fb, cb, db, gf, gs = [], [], [], [], []
        for j, r in zip(jacobians, residuals, strict=True):
            jf, js = j[:, :n_fast], j[:, n_fast:]
            fb.append(jf.T @ jf)
            cb.append(jf.T @ js)
            db.append(js.T @ js)
            gf.append(jf.T @ r)
            gs.append(js.T @ r)
        return cls(*(np.asarray(x, dtype=float) for x in (fb, cb, db, gf, gs)))

    @property
    def n_fast(self) -> int:
        """f, fast parameters per window."""
        return self.f_blocks.shape[1]

    @property
    def n_slow(self) -> int:
        """s, shared parameters."""
        return self.d_blocks.shape[1]

    def dense(self) -> tuple[np.ndarray, np.ndarray]:
        """The whole normal matrix and gradient, windows' fast blocks first, slow last."""
        w, f, s = len(self.f_blocks), self.n_fast, self.n_slow
        a = np.zeros((w * f + s, w * f + s))
        for i in range(w):
            a[i * f : (i + 1) * f, i * f : (i + 1) * f] = self.f_blocks[i]
            a[i * f : (i + 1) * f, w * f :] = self.c_blocks[i]
            a[w * f :, i * f : (i + 1) * f] = self.c_blocks[i].T
        a[w * f :, w * f :] = self.d_blocks.sum(axis=0)
        return a, np.concatenate([self.g_fast.ravel(), self.g_slow.sum(axis=0)])

    def step(self, mu: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """The Levenberg-Marquardt step ``(A + mu diag A) d = -g`` by the Schur complement.

        Returns the fast steps (W, f) and the slow step (s,). With ``mu = 0`` and a
        singular Schur complement, the slow step is the minimum-norm one over the
        determined directions.
        """
        f_inv = _damped_inverses(self.f_blocks, mu)
        d = self.d_blocks.sum(axis=0)
        d = d + mu * np.diag(_floored_diagonal(d))
        kc = f_inv @ self.c_blocks  # K_i = F_i^-1 C_i
        schur = d - np.einsum("wfs,wft->st", self.c_blocks, kc)
        rhs = -self.g_slow.sum(axis=0) + np.einsum("wfs,wf->s", kc, self.g_fast)
        inv, _ = _pseudo_inverse(schur)
        d_slow = inv @ rhs
        d_fast = -np.einsum("wfg,wg->wf", f_inv, self.g_fast) - kc @ d_slow
        return d_fast, d_slow

    def predicted_fall(self, d_fast: np.ndarray, d_slow: np.ndarray) -> float:
        """Fall of the sum of squares the linear model predicts for a step, Pa^2."""
        lin = float(np.sum(self.g_fast * d_fast) + self.g_slow.sum(axis=0) @ d_slow)
        quad = float(
            np.einsum("wf,wfg,wg->", d_fast, self.f_blocks, d_fast)
            + 2 * np.einsum("wf,wfs,s->", d_fast, self.c_blocks, d_slow)
            + d_slow @ self.d_blocks.sum(axis=0) @ d_slow
        )
        return -(2.0 * lin + quad)

    def covariance(self, grams: np.ndarray) -> ArrowCovariance:
        """The joint sandwich covariance given each window's noise gram ``B_i`` (W, p, p)."""
        f = self.n_fast
        f_inv = _damped_inverses(self.f_blocks, 0.0)
        kc = f_inv @ self.c_blocks
        schur = self.d_blocks.sum(axis=0) - np.einsum("wfs,wft->st", self.c_blocks, kc)
        s_inv, null = _pseudo_inverse(schur)
        w, s = len(f_inv), self.n_slow
        m = np.concatenate([-np.transpose(kc, (0, 2, 1)), np.broadcast_to(np.eye(s), (w, s, s))], 2)
        lmat = np.concatenate([f_inv, np.zeros((w, f, s))], axis=2)
        mbm = np.einsum("wsp,wpq,wtq->st", m, grams, m)
        cov_s = s_inv @ mbm @ s_inv
        lbm = np.einsum("wfp,wpq,wsq->wfs", lmat, grams, m) @ s_inv  # cov(L_i u_i, ds)
        cov_fs = lbm - kc @ cov_s
        lbl = np.einsum("wfp,wpq,wgq->wfg", lmat, grams, lmat)
        kct = np.transpose(kc, (0, 2, 1))
        cov_f = lbl - lbm @ kct - np.transpose(lbm @ kct, (0, 2, 1)) + kc @ cov_s @ kct
        return ArrowCovariance(0.5 * (cov_s + cov_s.T), cov_f, cov_fs, null)


@dataclass(frozen=True)
class ArrowCovariance:
    """The joint covariance's blocks (log parameters).

    Attributes
    ----------
    slow : ndarray
        Covariance of the slow parameters, (s, s).
    fast : ndarray
        Each window's fast covariance, (W, f, f).
    fast_slow : ndarray
        Each window's fast-slow cross covariance, (W, f, s).
    null : ndarray
        Unit slow directions the note does not determine, (n_null, s).
    """

    slow: np.ndarray
    fast: np.ndarray
    fast_slow: np.ndarray
    null: np.ndarray

    def window(self, i: int) -> np.ndarray:
        """Window i's covariance over its fast then slow parameters, (f + s, f + s)."""
        top = np.concatenate([self.fast[i], self.fast_slow[i]], axis=1)
        bottom = np.concatenate([self.fast_slow[i].T, self.slow], axis=1)
        out = np.concatenate([top, bottom], axis=0)
        return 0.5 * (out + out.T)


def _floored_diagonal(a: np.ndarray) -> np.ndarray:
    diag = np.diagonal(a, axis1=-2, axis2=-1)
    top = np.max(diag, axis=-1, keepdims=True)
    return np.maximum(diag, 1e-12 * np.maximum(top, 1e-300))


def _damped_inverses(blocks: np.ndarray, mu: float) -> np.ndarray:
    """``(F_i + mu diag F_i)^-1`` per window (pseudo-inverse when singular)."""
    damped = blocks + mu * (np.eye(blocks.shape[1]) * _floored_diagonal(blocks)[:, None, :])
    return np.linalg.pinv(damped, rcond=1e-12, hermitian=True)


def _pseudo_inverse(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pseudo-inverse of a symmetric matrix over its determined directions, and the rest."""
    sym = 0.5 * (a + a.T)
    vals, vecs = np.linalg.eigh(sym)
    top = float(np.max(np.abs(vals))) if vals.size else 0.0
    keep = vals > EIG_RCOND * max(top, 1e-300)
    inv = (vecs[:, keep] / vals[keep]) @ vecs[:, keep].T
    return inv, vecs[:, ~keep].T


__all__ = ["EIG_RCOND", "ArrowCovariance", "ArrowSystem"]
