"""The residual's first-order response to changes of the measured signals it reads.

A window's residual ``r = p_target - LP(p_model)`` (:mod:`mpipe.inversion.fit.fastpath`)
reads the measured pressure and flow four ways: the window's pressure (the target), and
from the history before it the bore's history term (a convolution of the forward wave
``p+ = (p + Z0 u) / 2``), the reed's lead-in driven by the measured pressure, the missing
mean flow over the lead-in (a shift of the history's p+ by ``(Z0 + R) c / 2`` and of the
residual by ``R c`` times the filter's edge, R the reference resistance), and the
low-pass's context. A change ``(dp, du)`` of those signals (a realisation of their noise,
:mod:`mpipe.inversion.whole_take.history_noise`) moves r, to first order, by

    ``dr = dp_window - LP([dp_context, T dq])``

where ``dq`` is the change of the history term (the history's share convolved, the
lead-in's and the missing flow's tangents) and ``T`` the model's tangent along the
window: the same compiled kernel (:func:`mpipe.reed.kernels.run`) with one tangent column
per change, its seed zero (no reed parameter moves) and its history term's tangent given.
K changes cost one model run with K tangent columns instead of K runs of the model on K
moved targets, each with its own history convolved (on the 4 s tone of `mpipe run`, 2
workers, the shards' final figures with the 16 draws a window took 2.12 s against 3.06 s,
``mpipe -v run``'s "take fit's shards" line).

The tests compare it with those runs (finite differences of the model on moved targets:
tests/inversion/fit/test_input_tangents.py).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from mpipe.inversion.fit.fastpath import (
    OK,
    REASONS,
    WindowEvaluator,
    history_term,
    measured_lowpass,
    model_residual,
    start_run,
    tangent_start,
)
from mpipe.reed.kernels import run
from mpipe.reed.parameters import ReedParameters, check_stability
from mpipe.reed.scheme import scheme_records
from mpipe.reed.sensitivity import SEED_ROWS, tangent_lines


@njit(cache=True)
def _respond(out_r, win, lp, buffers, cand, tan):
    """Residual of the candidate into ``out_r`` and each change's ``dr`` into ``tan``'s.

    ``win``, ``lp``, ``buffers``, ``cand`` are :func:`fastpath._evaluate`'s records; ``tan``
    = (d, tw, xt, dp_mod, col, conv_t, q_t, dpl, dul, dctx, dpw, out_dr): the zero seed, the
    lead-in's tangents, p+'s, the model pressure's, the low-pass's scratch, the tangents'
    delay lines, the history term's tangent (holding the history's share on entry), and
    per change its lead-in pressure and flow, low-pass context and window pressure; the
    result ``out_dr`` (K, n). Returns a status code (:data:`fastpath.OK` ...).
    """
    x, n0, conv, q_ext, p_mod, pm, work = buffers
    d, tw, xt, dp_mod, col, conv_t, q_t, dpl, dul, dctx, dpw, out_dr = tan
    state, missing = start_run(win, buffers, cand)
    ylead = work[0, : win[2].size]
    tangent, dmiss = tangent_start((d, tw, xt, dp_mod, conv_t, dpl, dul, q_t), ylead, win, cand)
    run(x, n0, cand[0], conv, state, pm, q_ext, p_mod, None, tangent)
    r_dc, edge = win[9], win[10]
    code = model_residual(out_r, p_mod, win, lp, r_dc * missing)
    if code != OK:
        return code
    n = out_r.size
    for j in range(dpl.shape[0]):
        if win[4]:
            measured_lowpass(col, n, dp_mod[j], dctx[j], lp)
        else:
            col[:n] = dp_mod[j, :n]
        for i in range(n):
            out_dr[j, i] = dpw[j, i] - col[i] + r_dc * dmiss[j] * edge[i]
    return OK


def _last(a: np.ndarray, n: int) -> np.ndarray:
    """The last ``n`` columns of ``a`` (K, h), zeros in front when it has fewer."""
    if a.shape[1] >= n:
        return np.ascontiguousarray(a[:, a.shape[1] - n :])
    return np.concatenate([np.zeros((a.shape[0], n - a.shape[1])), a], axis=1)


class InputTangents:
    """A window's residual change for K changes of its measured signals, to first order.

    Holds the K tangents' buffers beside its evaluator's (one per window and thread).

    Parameters
    ----------
    evaluator : WindowEvaluator
        The window's compiled evaluator.
    k : int
        Changes evaluated at once.
    """

    def __init__(self, evaluator: WindowEvaluator, k: int):
        self.ev = evaluator
        self.k = int(k)
        x, _, conv, _, p_mod, _, work = evaluator.buffers
        n = evaluator.target_p.size
        self._buffers = (
            np.zeros((len(SEED_ROWS), self.k)), np.zeros((self.k, work.shape[1])),
            np.zeros((self.k, x.size)), np.empty((self.k, p_mod.size)),
            np.empty(max(n, p_mod.size)), tangent_lines(conv, self.k),
        )  # fmt: skip

    def responses(self, reed: ReedParameters, dp: np.ndarray, du: np.ndarray):
        """The residual (Pa) and each change's ``dr`` (Pa per the change's unit).

        Parameters
        ----------
        reed : ReedParameters
            The candidate (the fit's solution).
        dp, du : ndarray
            Shape (K, h + n): each change of the pressure (Pa) and flow (m^3/s) over the
            last h samples of the window's history and its n samples (zero before them).

        Returns
        -------
        (ndarray, ndarray) or str
            ``r`` (n,) and ``dr`` (K, n); or why the candidate cannot be played.
        """
        ev = self.ev
        kernel, n = ev.kernel, ev.target_p.size
        dp, du = np.atleast_2d(np.asarray(dp, float)), np.atleast_2d(np.asarray(du, float))
        if dp.shape != (self.k, dp.shape[1]) or du.shape != dp.shape or dp.shape[1] < n:
            raise ValueError(f"changes of shape ({self.k}, h + {n}) expected, got "
                             f"{dp.shape} and {du.shape}")  # fmt: skip
        try:
            check_stability(reed, ev.fs)
        except ValueError as exc:
            return f"unstable: {exc}"
        h = dp.shape[1] - n
        hist_p, hist_u = dp[:, :h], du[:, :h]
        n_run = ev.buffers[4].size
        reach = max(kernel.n_taps - 1, 0)
        forward = 0.5 * (_last(hist_p, reach) + kernel.z0 * _last(hist_u, reach))
        q_t = history_term(kernel, forward, n_run)
        n_lead, n_ctx = ev.win[2].size, ev.win[5].size
        tan = (*self._buffers, q_t, _last(hist_p, n_lead), _last(hist_u, n_lead),
               _last(hist_p, n_ctx), np.ascontiguousarray(dp[:, h:]),
               np.empty((self.k, n)))  # fmt: skip
        cand = (scheme_records(reed, ev.fs, ev.lean.h0, kernel.z0, kernel.rho), reed.k, reed.S,
                reed.p_m)  # fmt: skip
        r = np.empty(n)
        with np.errstate(all="ignore"):
            code = _respond(r, ev.win, ev.lp, ev.buffers, cand, tan)
        if code != OK:
            return REASONS.get(int(code), "")
        return r, tan[-1]


__all__ = ["InputTangents"]
