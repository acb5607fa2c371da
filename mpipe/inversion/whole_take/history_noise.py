"""The noise of the measured signals through each window's model: the sandwich's meat.

A window's residual ``r = p - p_model`` reads the measured pressure in the window and the
measured pressure and flow before it, the history that drives the model (the paper's
method: the bore's reflected wave is computed from the measured past). The noise of those
signals enters ``r`` twice: as the pressure's own noise, and through the model's response
to a noisy history, a response the reed's periodic motion modulates. The score
``g = J^T r`` the fit's covariance needs is then not that of a stationary noise in ``r``:
measured on 45 dB crescendos separated with theta held at the truth (the noise known
exactly, ``benchmarks/bench_noise_scores.py``), the spectral gram of the residual's
between-harmonics noise (:func:`mpipe.inversion.trust.uncertainty.residual_grams`) put the
scores' variance 15 times too high for y_m and k_c, 3-6 times for p_m, k and lambda, and the
take's temperature's noise SE at 0.067 degC where the noise moved it by 0.025.

Here the meat is measured by simulation instead, from independent evidence: the
mouthpiece noise the front end propagated from the microphones' sensor noise
(:class:`mpipe.inversion.whole_take.front_end.MouthpieceNoise`, pressure and flow jointly,
coherent at low frequency). :data:`DRAWS` realisations over each window and its history
give ``B_i = mean(g g^T)`` with ``g = J_i^T dr`` and ``dr`` the residual's response to the
realisation at the fit's solution, to first order (errors in variables): all of them in one
model run with a tangent column each (:class:`mpipe.inversion.fit.input_tangents
.InputTangents`; the model run on each moved target, as before, gives the same grams to
the noise's second order: the 9 takes of benchmarks.md's "the meat and the front end's
shifts by tangents" kept their estimates and moved RMS z by at most 0.05). Each window's
draws are its own (seeded by its first sample, so the answer does not depend on the
sharding): the correlation between neighbouring windows' scores, which share samples
through the history, is left out (it lowered the temperature's noise variance by about
20 % on those takes: the bars err wide by ~10 %).
"""

from __future__ import annotations

import numpy as np

from mpipe.inversion.fit.input_tangents import InputTangents

#: Realisations of the noise per window (the meat's relative SE is about sqrt(2 / DRAWS)
#: per window; the note's and the take's constants average it over their windows).
DRAWS = 16
#: The first word of every window's seed (the second is the window's first sample).
SEED = 20121
#: Share of the bore kernel's energy (sum of squared taps) the history's noise is drawn
#: for: older samples reach the window only through the kernel's last taps.
REACH = 1.0 - 1e-6


def reach(taps: np.ndarray, floor: int) -> int:
    """History samples (at least ``floor``) whose taps hold :data:`REACH` of the energy.

    On the shipped instrument at 100 kHz 3,798 of the kernel's 6,822 taps: the noise of the
    older history moves the history term by less than a thousandth of its own (RMS).
    """
    h = np.asarray(taps, dtype=float)
    if h.size == 0:
        return int(floor)
    energy = np.cumsum(h**2)
    k = int(np.searchsorted(energy, REACH * energy[-1])) + 1
    return int(max(k, floor))


def drawn_gram(shard, i: int, x: np.ndarray, j: np.ndarray, noise,
               draws: int = DRAWS) -> tuple[np.ndarray, float] | None:  # fmt: skip
    """Window i's meat ``mean(g g^T)`` over ``draws`` realisations of the noise (Pa^2 ...).

    And the residual's sum of squares the noise makes there, for the window's goodness of
    fit against independent evidence of its noise (``drawn_noise_residual``).

    Parameters
    ----------
    shard : Shard
        The window's shard (its objectives on the kernel at its temperature).
    i : int
        The window's index in the shard.
    x : ndarray
        Its free values at the solution (the objective's, SI units).
    j : ndarray
        Its Jacobian there with the temperature's column, (n, L).
    noise : MouthpieceNoise
        The mouthpiece signals' noise.
    draws : int
        Realisations.

    Returns
    -------
    (ndarray, float) or None
        The meat (L, L), and ``mean ||dr||^2`` (Pa^2), the residual's sum of squares the
        noise alone would make at the solution; None when the model cannot be played at
        ``x`` or a response is not finite.
    """
    q = shard.problems[i]
    target, fs = q.target, shard.spec.fs
    h, n = target.p_history.size, target.p.size
    objective = shard.objectives[i]
    kernel = objective.kernel
    lead = int(round(shard.spec.config.lead_s * fs))
    m = min(reach(kernel.h, max(lead, n)), h)  # the history the noise is drawn over
    rng = np.random.default_rng((SEED, int(q.start)))
    ep, eu = noise.draw(m + n, fs, rng, draws)
    evaluator = objective.evaluator
    if evaluator is None:
        return None
    try:
        out = InputTangents(evaluator, draws).responses(objective.reed(x), ep, eu)
    except ValueError:
        return None
    if isinstance(out, str) or not np.all(np.isfinite(out[1])):
        return None
    g = out[1] @ j
    return g.T @ g / draws, float(np.mean(np.sum(out[1] ** 2, axis=1)))


__all__ = ["DRAWS", "REACH", "SEED", "drawn_gram", "reach"]
