"""The normal equations of a whole take: windows, notes and the take in one system.

A take's joint fit has three tiers of parameters: each window's fast ones (f: p_m, y_m),
each note's slow ones (s: the reed's k, S, lam, m, g, k_c), and the take's own (t: the
bore's temperature). Window i belongs to note ``n(i)``; its weighted residual ``r_i`` and
Jacobian ``J_i = [J_fi, J_si, J_ti]`` (its fast columns, its note's slow ones, the take's)
give the Gauss-Newton normal matrix ``A = sum_i J_i^T J_i`` plus a prior's information on
the take's parameters. ``A`` is sparse with two nested borders:

    window blocks  F_i = J_fi^T J_fi          coupled to their note by C_i = J_fi^T J_si
                                              and to the take by      G_i = J_fi^T J_ti
    note blocks    D_n = sum_{i in n} J_si^T J_si,  coupled to the take by E_n
    the take       H = sum_i J_ti^T J_ti + P (the prior's information)

Eliminating every window's fast block (a Schur complement per window, as in bundle
adjustment's reduced camera system) leaves a system over ``x = (s_1, ..., s_N, t)`` alone,
of size ``N s + t``: a Gauss-Newton step costs W small solves and one solve of that size,
linear in the number of windows.

**One covariance.** The estimate's covariance is the sandwich ``A^-1 B A^-1``, ``B`` the
covariance of the score ``sum_i J_i^T e_i``: block diagonal over windows (``B_i``, each
window's noise gram, :mod:`mpipe.inversion.trust.uncertainty`) plus the prior's own
information. The same elimination gives every block of it without forming ``A^-1``: with
``u_i = J_i^T e_i`` and ``Q_i = [C_i, G_i]``, the reduced unknowns move by
``x = R^-1 sum_i M_i u_i`` (``M_i = [-Q_i^T F_i^-1, I]``, scattered to window i's note and
the take), and window i's fast ones by ``L_i u_i - K_i x_n(i)`` (``L_i = F_i^-1 [I, 0]``,
``K_i = F_i^-1 Q_i``).

**Windows fitted given the shared unknowns.** A window may be ``given`` its note's
constants and the take's: it does not inform them (no share of ``R`` or of its right-hand
side, no score in ``x``), and its fast unknowns are its own least squares at them, so they
still follow ``x`` by ``-K_i x``. Its fast covariance is then ``L_i B_i L_i^T + K_i cov(x)
K_i^T`` (its score is not in ``x``: no cross term), the second term the error the shared
unknowns carry into it: the two-stage estimator's covariance.

References
----------
B. Triggs, P. McLauchlan, R. Hartley, A. Fitzgibbon, "Bundle adjustment - a modern
synthesis", Vision Algorithms: Theory and Practice, Springer 2000, sections 6.1 and 6.2
(the reduced system and its nested form). G. A. F. Seber, C. J. Wild, *Nonlinear
Regression*, Wiley 1989, section 2.1 (the sandwich covariance).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

#: Eigenvalues of the (Jacobi-scaled) reduced system below this fraction of the largest mark
#: a direction the take does not determine (the square of the per-window SVD's
#: :data:`mpipe.inversion.trust.uncertainty.RCOND`: eigenvalues of J^T J are squared singular
#: values).
EIG_RCOND = 1e-6

#: The player's controls, fitted per window.
FAST_PARAMETERS = ("p_m", "y_m")


def split_names(free: Sequence[str]) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The searched parameters ``free`` split into (fast, slow), each in ``free``'s order.

    Fast: the player's controls (:data:`FAST_PARAMETERS`), one value per window; slow: the
    reed's own (k, S, lam, m, g, k_c, y_c), one value per note.
    """
    fast = tuple(n for n in free if n in FAST_PARAMETERS)
    slow = tuple(n for n in free if n not in FAST_PARAMETERS)
    return fast, slow


@dataclass(frozen=True)
class TierSizes:
    """How many parameters each tier has.

    Attributes
    ----------
    fast : int
        Per window (f).
    slow : int
        Per note (s).
    take : int
        Of the take (t).
    """

    fast: int
    slow: int
    take: int

    @property
    def local(self) -> int:
        """Columns of one window's Jacobian, f + s + t."""
        return self.fast + self.slow + self.take

    @property
    def shared(self) -> int:
        """A window's reduced unknowns, its note's and the take's: s + t."""
        return self.slow + self.take


@dataclass(frozen=True)
class TakeSystem:
    """The take's normal equations (see the module docstring), window by window.

    Attributes
    ----------
    sizes : TierSizes
        f, s, t.
    notes : ndarray
        Each window's note, 0..N-1 (int, shape (W,)).
    grams : ndarray
        Each window's ``J_i^T J_i``, shape (W, f+s+t, f+s+t).
    gradients : ndarray
        Each window's ``J_i^T r_i``, shape (W, f+s+t).
    prior_information : ndarray
        The prior's information on the take's parameters, (t, t).
    prior_gradient : ndarray
        The prior's gradient ``P (t - t_prior)``, (t,).
    given : ndarray, optional
        Each window is fitted given the shared unknowns (see the module docstring), bool
        (W,); None: none is.
    """

    sizes: TierSizes
    notes: np.ndarray
    grams: np.ndarray
    gradients: np.ndarray
    prior_information: np.ndarray
    prior_gradient: np.ndarray
    given: np.ndarray | None = None

    def _informing(self) -> np.ndarray:
        """1.0 for each window that informs the shared unknowns, else 0.0, (W,)."""
        if self.given is None:
            return np.ones(len(self.notes))
        return (~np.asarray(self.given, bool)).astype(float)

    @classmethod
    def of(
        cls,
        jacobians: Sequence[np.ndarray],
        residuals: Sequence[np.ndarray],
        notes: Sequence[int],
        sizes: TierSizes,
        prior: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> TakeSystem:
        """The system of W windows: ``jacobians[i]`` (n_i, f+s+t), columns fast, slow, take.

        ``prior`` is the take's prior as (information (t, t), gradient (t,)); None: none.
        """
        grams = np.array([j.T @ j for j in jacobians], dtype=float)
        grads = np.array([j.T @ r for j, r in zip(jacobians, residuals, strict=True)], float)
        t = sizes.take
        info, grad = prior if prior is not None else (np.zeros((t, t)), np.zeros(t))
        return cls(sizes, np.asarray(notes, dtype=int), grams, grads,
                   np.asarray(info, float), np.asarray(grad, float))  # fmt: skip

    @property
    def n_notes(self) -> int:
        """N, the notes (one past the largest note index)."""
        return int(self.notes.max()) + 1 if self.notes.size else 0

    @property
    def n_reduced(self) -> int:
        """Size of the reduced system, N s + t."""
        return self.n_notes * self.sizes.slow + self.sizes.take

    def reduced_index(self, note: int) -> np.ndarray:
        """Positions of a note's slow unknowns and the take's in the reduced vector."""
        s, t = self.sizes.slow, self.sizes.take
        take = self.n_notes * s + np.arange(t)
        return np.concatenate([note * s + np.arange(s), take]).astype(int)

    def frozen(self, fast: np.ndarray, slow: np.ndarray, take: np.ndarray) -> TakeSystem:
        """The system with some unknowns held: their rows and columns cut from every gram.

        ``fast`` (W, f), ``slow`` (N, s) and ``take`` (t,) are boolean masks of the unknowns
        held (an estimate on a bound whose step points out of it). A held unknown keeps a
        unit diagonal (split over the windows that share it) and a zero gradient, so its
        step is exactly zero and it couples to nothing: the system of the others alone.
        """
        f, t = self.sizes.fast, self.sizes.take
        held = np.concatenate([np.asarray(fast, bool), np.asarray(slow, bool)[self.notes],
                               np.broadcast_to(np.asarray(take, bool), (len(self.notes), t))],
                              axis=1)  # fmt: skip
        if not held.any():
            return self
        share = np.ones(held.shape)
        counts = np.bincount(self.notes, minlength=self.n_notes).astype(float)
        share[:, f : f + self.sizes.slow] = 1.0 / counts[self.notes][:, None]
        share[:, f + self.sizes.slow :] = 1.0 / len(self.notes)
        keep = (~held).astype(float)
        grams = self.grams * keep[:, :, None] * keep[:, None, :]
        w, c = np.nonzero(held)
        grams[w, c, c] = share[w, c]
        info = self.prior_information * np.outer(~np.asarray(take, bool), ~np.asarray(take, bool))
        grad = np.where(np.asarray(take, bool), 0.0, self.prior_gradient)
        return TakeSystem(self.sizes, self.notes, grams, self.gradients * keep, info, grad,
                          self.given)  # fmt: skip

    def _blocks(self, mu: float):
        """Per window: ``F_i^-1`` (damped), ``Q_i``, and the shared block of its gram."""
        f = self.sizes.fast
        fb = self.grams[:, :f, :f]
        damp = mu * _floored_diagonal(fb)
        f_inv = np.linalg.pinv(fb + damp[:, :, None] * np.eye(f), rcond=1e-12, hermitian=True)
        q = self.grams[:, :f, f:]
        return f_inv, q, self.grams[:, f:, f:]

    def _reduced(self, mu: float):
        """The reduced matrix R (N s + t square), its right-hand side and the blocks.

        Undamped (``mu`` 0) it is made once per system: the covariance, the information and
        the refitted windows all read it (never written to).
        """
        if mu == 0.0:
            return self._undamped
        return self._reduce(mu)

    @functools.cached_property
    def _undamped(self):
        return self._reduce(0.0)

    def _reduce(self, mu: float):
        f_inv, q, shared = self._blocks(mu)
        f = self.sizes.fast
        kq = f_inv @ q  # K_i = F_i^-1 Q_i
        informs = self._informing()[:, None]
        r_win = (shared - np.einsum("wfa,wfb->wab", q, kq)) * informs[:, :, None]
        g_f, g_x = self.gradients[:, :f], self.gradients[:, f:]
        rhs_win = (-g_x + np.einsum("wfa,wf->wa", kq, g_f)) * informs
        shared = shared * informs[:, :, None]
        big = np.zeros((self.n_reduced, self.n_reduced))
        rhs = np.zeros(self.n_reduced)
        diag = np.zeros(self.n_reduced)
        for i, note in enumerate(self.notes):
            idx = self.reduced_index(int(note))
            big[np.ix_(idx, idx)] += r_win[i]
            rhs[idx] += rhs_win[i]
            diag[idx] += np.diagonal(shared[i])
        take = self.n_notes * self.sizes.slow + np.arange(self.sizes.take)
        big[np.ix_(take, take)] += self.prior_information
        diag[take] += np.diagonal(self.prior_information)
        rhs[take] -= self.prior_gradient
        if mu > 0:
            big[np.diag_indices_from(big)] += mu * np.maximum(diag, 1e-12 * max(diag.max(), 1e-300))
        return big, rhs, f_inv, kq

    def shared_information(self) -> np.ndarray:
        """R: the cost's curvature in the shared unknowns, each window's controls eliminated.

        ``d^T R d`` is the rise of the sum of squares (prior included) the linear model
        predicts when the notes' constants and the take's unknowns move by ``d`` (ln x,
        and the take's own units) from a minimum, every window's controls fitted again;
        (N s + t) square.
        """
        return self._reduced(0.0)[0]

    def step(self, mu: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The Levenberg-Marquardt step ``(A + mu diag A) d = -g`` by the two eliminations.

        Returns
        -------
        (ndarray, ndarray, ndarray)
            The windows' fast steps (W, f), the notes' slow steps (N, s) and the take's (t,).
            A direction the reduced system does not determine is not moved
            (minimum-norm step).
        """
        big, rhs, f_inv, kq = self._reduced(mu)
        inv, _ = pseudo_inverse(big)
        x = inv @ rhs
        return self._split(x, f_inv, kq)

    def refitted(self, x: np.ndarray) -> np.ndarray:
        """The windows' fast unknowns' move when the reduced ones move by ``x``, refitted.

        Each window's controls minimise its own linear model again at the shared unknowns'
        new values: ``-K_i x_n(i)`` (``K_i = F_i^-1 Q_i``), (W, f).
        """
        _, _, _, kq = self._reduced(0.0)
        x_win = np.array([np.asarray(x, float)[self.reduced_index(int(n))] for n in self.notes])
        return -np.einsum("wfa,wa->wf", kq, x_win)

    def _split(self, x, f_inv, kq):
        f, s, t = self.sizes.fast, self.sizes.slow, self.sizes.take
        g_f = self.gradients[:, :f]
        x_win = np.array([x[self.reduced_index(int(n))] for n in self.notes])
        d_fast = -np.einsum("wfg,wg->wf", f_inv, g_f) - np.einsum("wfa,wa->wf", kq, x_win)
        n = self.n_notes
        return d_fast, x[: n * s].reshape(n, s), x[n * s : n * s + t]

    def predicted_fall(self, d_fast, d_slow, d_take) -> float:
        """Fall of the sum of squares (prior included) the linear model predicts, Pa^2.

        A window given the shared unknowns counts by its fast step alone (the shared ones
        are not its to move).
        """
        d = self.local_steps(d_fast, d_slow, d_take)
        d[:, self.sizes.fast :] *= self._informing()[:, None]
        lin = float(np.sum(self.gradients * d)) + float(self.prior_gradient @ d_take)
        quad = float(np.einsum("wa,wab,wb->", d, self.grams, d))
        quad += float(d_take @ self.prior_information @ d_take)
        return -(2.0 * lin + quad)

    def local_steps(self, d_fast, d_slow, d_take) -> np.ndarray:
        """Each window's step over its own columns (W, f+s+t)."""
        d_slow = np.asarray(d_slow, float).reshape(self.n_notes, self.sizes.slow)
        take = np.broadcast_to(np.asarray(d_take, float), (len(self.notes), self.sizes.take))
        return np.concatenate([np.asarray(d_fast, float), d_slow[self.notes], take], axis=1)

    def covariance(
        self, grams: np.ndarray, prior_information: np.ndarray | None = None
    ) -> TakeCovariance:
        """The joint sandwich covariance given each window's score covariance ``B_i``.

        Parameters
        ----------
        grams : ndarray
            ``B_i``, shape (W, f+s+t, f+s+t), in the system's (weighted) units.
        prior_information : ndarray, optional
            The prior's score covariance (t, t); default the prior's information (a prior
            of its stated variance).
        """
        big, _, f_inv, kq = self._reduced(0.0)
        r_inv, null = pseudo_inverse(big)
        f, t = self.sizes.fast, self.sizes.take
        shared = self.sizes.shared
        eye = np.broadcast_to(np.eye(shared), (len(kq), shared, shared))
        m = np.concatenate([-np.transpose(kq, (0, 2, 1)), eye], axis=2)
        informs = self._informing()
        mb = (m @ grams) * informs[:, None, None]  # (W, s+t, loc); 0: given
        omega = np.zeros_like(big)
        for i, note in enumerate(self.notes):
            idx = self.reduced_index(int(note))
            omega[np.ix_(idx, idx)] += mb[i] @ m[i].T
        take = self.n_notes * self.sizes.slow + np.arange(t)
        prior = self.prior_information if prior_information is None else prior_information
        omega[np.ix_(take, take)] += prior
        cov_x = r_inv @ omega @ r_inv
        cov_x = 0.5 * (cov_x + cov_x.T)
        lmat = np.concatenate([f_inv, np.zeros((len(f_inv), f, self.sizes.shared))], axis=2)
        fast, fast_shared = [], []
        for i, note in enumerate(self.notes):
            idx = self.reduced_index(int(note))
            cxu = r_inv[:, idx] @ mb[i]  # cov(x, u_i), (N s + t, loc)
            lb = lmat[i] @ grams[i]
            # cov(L u_i, x_n); 0 for a given window (its score is not in x)
            cross = informs[i] * (lb @ (r_inv[np.ix_(idx, idx)] @ m[i]).T)
            k = kq[i]
            cov_f = lb @ lmat[i].T - cross @ k.T - k @ cross.T + k @ cov_x[np.ix_(idx, idx)] @ k.T
            fast.append(0.5 * (cov_f + cov_f.T))
            fast_shared.append(lmat[i] @ cxu.T - k @ cov_x[idx, :])
        return TakeCovariance(self, cov_x, np.array(fast), np.array(fast_shared), null)


@dataclass(frozen=True)
class TakeCovariance:
    """The take's joint covariance, block by block.

    Attributes
    ----------
    system : TakeSystem
        The system it belongs to (its sizes and the windows' notes).
    reduced : ndarray
        Covariance of ``x = (s_1, ..., s_N, t)``, (N s + t, N s + t).
    fast : ndarray
        Each window's fast covariance, (W, f, f).
    fast_reduced : ndarray
        Each window's fast-by-reduced cross covariance, (W, f, N s + t).
    null : ndarray
        Unit directions of ``x`` the take does not determine, (n_null, N s + t).
    """

    system: TakeSystem
    reduced: np.ndarray
    fast: np.ndarray
    fast_reduced: np.ndarray
    null: np.ndarray

    def window(self, i: int) -> np.ndarray:
        """Window i's covariance over its own columns: fast, its note's slow, the take's."""
        idx = self.system.reduced_index(int(self.system.notes[i]))
        top = np.concatenate([self.fast[i], self.fast_reduced[i][:, idx]], axis=1)
        bottom = np.concatenate(
            [self.fast_reduced[i][:, idx].T, self.reduced[np.ix_(idx, idx)]], axis=1
        )
        out = np.concatenate([top, bottom], axis=0)
        return 0.5 * (out + out.T)

    def window_null(self, i: int) -> np.ndarray:
        """The undetermined directions that touch window i, over its own columns."""
        idx = self.system.reduced_index(int(self.system.notes[i]))
        f = self.system.sizes.fast
        rows = [v[idx] for v in self.null if np.linalg.norm(v[idx]) > 1e-6]
        if not rows:
            return np.zeros((0, f + idx.size))
        out = np.zeros((len(rows), f + idx.size))
        out[:, f:] = np.array(rows)
        return out / np.linalg.norm(out, axis=1, keepdims=True)


def pseudo_inverse(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pseudo-inverse of a symmetric matrix over its determined directions, and the rest.

    Determined: an eigenvalue above :data:`EIG_RCOND` times the
    largest. The matrix is first scaled by its diagonal (Jacobi), so that parameters of
    very different units (log parameters beside degrees Celsius) are judged alike.
    """
    sym = 0.5 * (a + a.T)
    d = np.sqrt(np.maximum(np.diagonal(sym), 1e-300))
    scaled = sym / d[:, None] / d[None, :]
    vals, vecs = np.linalg.eigh(scaled)
    top = float(np.max(np.abs(vals))) if vals.size else 0.0
    keep = vals > EIG_RCOND * max(top, 1e-300)
    inv_scaled = (vecs[:, keep] / vals[keep]) @ vecs[:, keep].T
    inv = inv_scaled / d[:, None] / d[None, :]
    null = vecs[:, ~keep].T / d[None, :]
    if null.size:
        null = null / np.linalg.norm(null, axis=1, keepdims=True)
    return inv, null


def _floored_diagonal(a: np.ndarray) -> np.ndarray:
    diag = np.diagonal(a, axis1=-2, axis2=-1)
    top = np.max(diag, axis=-1, keepdims=True)
    return np.maximum(diag, 1e-12 * np.maximum(top, 1e-300))


__all__ = [
    "EIG_RCOND",
    "FAST_PARAMETERS",
    "TakeCovariance",
    "TakeSystem",
    "TierSizes",
    "pseudo_inverse",
    "split_names",
]
