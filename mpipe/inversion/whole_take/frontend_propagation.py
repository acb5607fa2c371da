"""The front end's errors, propagated linearly on the windows' own spans.

The ``frontend`` component of the error budget (docs/uncertainty.md) asks how far each
window's estimate moves when the separation's take-level theta (temperature, losses, Mach
number, position of the middle microphone) moves by one standard error. Both steps of the
answer are linear to first order, and both are taken only where a window reads the take:

1. **The signals' change.** Re-separating with the moved theta
   (:func:`mpipe.measurement.separation.perturbation.reseparate`) and translating to the
   mouthpiece are filters: a sample of p, u depends on p0, u0 within the translation's
   context (:class:`mpipe.measurement.translation.TranslationPlan`) plus the low-pass and
   the re-separation's guard. So dp, du over a window's span (its history, the window) are
   computed from p0, u0 over that span widened by :func:`span_margin`, never the take.
2. **The estimate's change.** At the window's estimate ``x`` (the windows table's row),
   ``R = |r|^2 / 2`` has gradient ``g = J^T r`` (``J = d r / d ln x`` from the model's
   forward sensitivities, one model run). The signals' change moves the gradient by
   ``dg``, and the minimum by ``d ln x = -H^-1 dg`` (implicit function theorem), with
   ``H`` the full Hessian (differences of ``g``; Gauss-Newton's ``J^T J`` is not enough: a
   measured window's residual is far from zero, and the model is started from the
   target's own history, so ``J`` moves with the signals too). One model run per
   perturbation and ``k`` for ``H``, instead of a warm re-fit per perturbation.

A kernel temperature fitted to the take would absorb part of a front-end error; given the
kernels at ``-/+`` :data:`KERNEL_STEP_C` it is re-fitted here too, linearly: one more
coordinate ``t`` of each window's normal equations (central differences), shared by the
windows and eliminated by the Schur complement of their own parameters, its shift kept
within two steps. The per-window estimator's budget
(:func:`mpipe.inversion.whole_take.shared_errors.frontend_linear`) holds the kernel at the
front end's temperature; the take's joint fit takes only the signals' changes from here
(:func:`span_changes`, :mod:`mpipe.inversion.whole_take.frontend_joint`). ``d ln q`` per SE
is the median over the windows.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from mpipe.core.filters import apply_lowpass
from mpipe.core.signals import signal_range
from mpipe.inversion.fit.history_start import lead_in
from mpipe.inversion.fit.objective import TargetWindow
from mpipe.inversion.fit.window import window_bounds, window_objective
from mpipe.inversion.settings import PARAMETER_NAMES, InversionConfig
from mpipe.inversion.trust.combinations import COMBINATION_NAMES, combination_values
from mpipe.inversion.trust.uncertainty import SE_PARAMETERS, log_jacobian
from mpipe.measurement.calibration import Calibration
from mpipe.measurement.separation.perturbation import reseparate
from mpipe.measurement.translation import TranslationPlan

#: Quantities with take-wide components (as :mod:`shared_errors` has them).
QUANTITIES = (*SE_PARAMETERS, *COMBINATION_NAMES)
#: Names of the front end's parameters, in the order of ``FrontEnd``'s arrays.
FRONTEND_NAMES = ("temperature", "eta", "mach", "position")
#: p0, u0 read beyond the translation's context for the re-separation, s: its map is short,
#: but the flow's, from the waves' small phase differences at low frequency, has tails.
RESEPARATION_GUARD_S = 0.1
#: Half-spacing of the kernel temperatures of the kernel column, degC.
KERNEL_STEP_C = 0.25


@dataclass(frozen=True)
class Spans:
    """The translation plans of the front end's signals, to translate a span at a time.

    Attributes
    ----------
    base, warm : TranslationPlan
        At the front end's temperatures, and at those plus the temperature's SE.
    margin : int
        Samples of p0, u0 read on each side of a span (translation context, low-pass,
        re-separation guard).
    """

    base: TranslationPlan
    warm: TranslationPlan
    margin: int

    @classmethod
    def of(cls, front, calibration: Calibration, fs: float) -> Spans:
        """The plans of ``front`` (a ``FrontEnd``) at its temperatures and one SE warmer."""
        temps = front.temperature_c
        if np.ndim(temps) == 0:
            lo = hi = float(temps)
        else:
            lo, hi = signal_range(temps)
        dt = _temperature_se(front)
        base = TranslationPlan.of(fs, calibration, front.translation, lo, hi, level=logging.DEBUG)
        warm = TranslationPlan.of(
            fs, calibration, front.translation, lo + dt, hi + dt, level=logging.DEBUG
        )
        return cls(base, warm, span_margin(base, fs))


def span_margin(plan: TranslationPlan, fs: float) -> int:
    """Samples of p0, u0 each side of a span that its translated p, u depend on."""
    return plan.context + plan.lowpass.taps.size + int(math.ceil(RESEPARATION_GUARD_S * fs))


def _temperature_se(front) -> float:
    se = float(front.level_se[0])
    return se if math.isfinite(se) and se > 0 else 0.0


def _temps(front, a: int, b: int) -> np.ndarray:
    t = front.temperature_c
    if np.ndim(t) == 0:
        return np.full(b - a, float(t))
    return np.asarray(t[a:b], dtype=float)


def span_changes(
    front, calibration: Calibration, fs: float, spans: Spans, a: int, b: int
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The change of p (Pa), u (m^3/s) over ``a..b`` for one SE of each front-end parameter.

    Reads p0, u0 over ``a..b`` widened by ``spans.margin`` only; equals the whole take's
    re-separation and translation there up to the translation's truncated tails.
    Parameters without a positive, finite SE are left out.
    """
    n = len(front.p0)
    lp = spans.base.lowpass
    ta, tb = max(a - lp.taps.size, 0), min(b + lp.taps.size, n)
    lo, hi = max(a - spans.margin, 0), min(b + spans.margin, n)
    p0 = np.asarray(front.p0[lo:hi], dtype=float)
    u0 = np.asarray(front.u0[lo:hi], dtype=float)
    temps = _temps(front, ta, tb)
    inner = slice(a - ta, a - ta + b - a)

    def translated(plan, x0, y0, dt):
        p, u = plan.block(x0, y0, temps + dt, ta - lo, tb - lo)
        return apply_lowpass(p, lp)[inner], apply_lowpass(u, lp)[inner]

    base_p, base_u = translated(spans.base, p0, u0, 0.0)
    out = {}
    for j, name in enumerate(FRONTEND_NAMES):
        se = float(front.level_se[j])
        if not (math.isfinite(se) and se > 0):
            continue
        moved = np.array(front.level, dtype=float)
        moved[j] += se
        q0, v0 = reseparate(p0, u0, fs, calibration, front.level, moved, front.band_hz)
        warm = name == "temperature"
        p, u = translated(spans.warm if warm else spans.base, q0, v0, se if warm else 0.0)
        out[name] = (p - base_p, u - base_u)
    return out


def piece_length(spans: Spans) -> int:
    """Samples of a piece of :func:`long_span_changes`: a block's hop less the taps."""
    return max(spans.base.nfft - 2 * spans.base.context - 2 * spans.base.lowpass.taps.size, 1)


def long_span_changes(
    front, calibration: Calibration, fs: float, spans: Spans, a: int, b: int, origin: int = 0
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """:func:`span_changes` over a span of any length, one translation block at a time.

    A span is translated in one FFT block (:meth:`TranslationPlan.block`), so one longer
    than a block's hop (with the low-pass's taps each side) is cut into pieces that fit,
    each read with its own margin: the same samples, to the translation's truncated tails.
    The cuts lie on a grid of the take's samples (``origin``: the take's sample at index 0
    of ``front``), not of the span: a span's changes are then the same wherever it starts,
    so the take's shards give the numbers of one (the tails of pieces cut at the shards'
    own starts moved the front end's share by 1 % between 1 and 2 workers).
    """
    piece = piece_length(spans)
    first = (a + origin) // piece + 1  # the first grid cut after a
    cuts = [a, *range(first * piece - origin, b, piece), b]
    parts = [span_changes(front, calibration, fs, spans, lo, hi)
             for lo, hi in zip(cuts[:-1], cuts[1:], strict=True) if hi > lo]  # fmt: skip
    return {name: tuple(np.concatenate([part[name][k] for part in parts]) for k in (0, 1))
            for name in parts[0]} if parts else {}  # fmt: skip


#: Step in ln x of the Hessian's differences.
HESSIAN_STEP = 1e-4


@dataclass(frozen=True)
class Linearised:
    """One window's normal equations at its estimate, and their change by each perturbation.

    With ``R = |r|^2 / 2`` over the window and ``z = (ln x, t)`` (the free parameters in
    logs and, when it is re-fitted, the kernel temperature in degC), a minimum moves by
    ``dz = -H^-1 dg`` when the signals change the gradient by ``dg`` (implicit function
    theorem; ``H`` the full Hessian, not Gauss-Newton's ``J^T J``: the residual of a
    measured window is far from zero, and the model reads the target's own history).

    Attributes
    ----------
    hessian : ndarray
        ``d^2 R / dz^2``, shape ``(k, k)`` or ``(k + 1, k + 1)`` with the kernel's row last.
    dg : dict
        Front-end parameter name -> the gradient's change for one SE of it.
    values : dict
        The estimate's parameters (SI).
    """

    hessian: np.ndarray
    dg: dict
    values: dict


def _gradient(objective, x0: np.ndarray, upper) -> tuple[np.ndarray, np.ndarray] | None:
    """``(d R / d ln x, r)`` at ``x0``: the model's sensitivities, else differences."""
    found = objective.jacobian(x0)
    if found is not None:
        r, jac = found[0], found[1] * x0
    else:
        r = objective.residuals(x0)
        jac = log_jacobian(objective.residuals, x0, r0=r, upper=upper)
    if not np.all(np.isfinite(jac)) or float(np.linalg.norm(r)) >= 0.999 * objective.penalty:
        return None
    return jac.T @ r, r


def linearise(
    p, u, fs: float, start: int, reed, kernels, config: InversionConfig, changes: dict,
    *, zero_mean: bool, span_start: int,
) -> Linearised | None:  # fmt: skip
    """The window at ``start`` linearised at ``reed``; None when the model fails there.

    ``p, u``: the span's signals from ``span_start`` (history and window); ``changes``: from
    :func:`span_changes` over the same span; ``kernels``: ``t -> kernel`` at the kernel
    temperature (0) and at ``-/+`` :data:`KERNEL_STEP_C` (None: the kernel is held).
    """
    n = int(round(config.window_s * fs))
    i = start - span_start

    def objective(dp=0.0, du=0.0, dt=0.0):
        pp, uu, kernel = p + dp, u + du, kernels(dt)
        hist = lead_in(pp, uu, i, n, kernel.n_taps, config.lead_s, fs)
        target = TargetWindow(pp[i : i + n], uu[i : i + n], *hist, fs, zero_mean)
        return window_objective(kernel, target, reed, config)

    x0 = np.array([getattr(reed, name) for name in config.search_parameters], dtype=float)
    upper = window_bounds(config, p, i, n, fs)[:, 1]
    base = objective()
    found = _gradient(base, x0, upper)
    if found is None:
        return None
    g0 = found[0]
    k = x0.size
    held = kernels(KERNEL_STEP_C) is None
    hess = np.zeros((k, k) if held else (k + 1, k + 1))
    for j in range(k):
        moved = _gradient(base, x0 * np.exp(HESSIAN_STEP * (np.arange(k) == j)), upper)
        if moved is None:
            return None
        hess[:k, j] = (moved[0] - g0) / HESSIAN_STEP
    h = KERNEL_STEP_C

    def energy(obj):
        return 0.5 * float(np.sum(obj.residuals(x0) ** 2))

    slope0 = 0.0  # d R / d t of the unperturbed window, times 2 h
    if not held:
        g_hot = _gradient(objective(dt=h), x0, upper)
        g_cold = _gradient(objective(dt=-h), x0, upper)
        if g_hot is None or g_cold is None:
            return None
        e_hot, e_cold, e_0 = (0.5 * float(np.sum(g[1] ** 2)) for g in (g_hot, g_cold, found))
        hess[:k, k] = hess[k, :k] = (g_hot[0] - g_cold[0]) / (2 * h)
        hess[k, k] = (e_hot - 2 * e_0 + e_cold) / h**2
        slope0 = e_hot - e_cold
    hess[:k, :k] = 0.5 * (hess[:k, :k] + hess[:k, :k].T)
    if np.linalg.eigvalsh(hess[:k, :k])[0] <= 0:
        return None  # not at a minimum of its own parameters: no shift to follow
    dg = {}
    for name, (dp, du) in changes.items():
        moved = _gradient(objective(dp, du), x0, upper)
        if moved is None:
            return None
        d = moved[0] - g0
        if not held:
            slope = energy(objective(dp, du, h)) - energy(objective(dp, du, -h))
            d = np.append(d, (slope - slope0) / (2 * h))
        dg[name] = d
    values = {q: float(getattr(reed, q)) for q in (*PARAMETER_NAMES, "y_c")}
    return Linearised(hess, dg, values)


def shifts(windows: Sequence[Linearised], name: str, n_free: int) -> tuple[list[np.ndarray], float]:
    """``d ln x`` per window and the kernel temperature's shift (degC) for one SE of ``name``.

    The windows share the kernel temperature: its row is eliminated from each window's
    equations (Schur complement), its shift solved from their sum and kept within two
    :data:`KERNEL_STEP_C`, as the re-fit's parabola kept its vertex.
    """
    k = n_free
    dt = 0.0
    shared = bool(windows) and all(w.hessian.shape[0] == k + 1 for w in windows)
    if shared:
        num = den = 0.0
        for w in windows:
            a, b, c = w.hessian[:k, :k], w.hessian[:k, k], w.hessian[k, k]
            ab = np.linalg.solve(a, b)
            den += c - b @ ab
            num += w.dg[name][k] - ab @ w.dg[name][:k]
        if den > 0:
            dt = float(np.clip(-num / den, -2 * KERNEL_STEP_C, 2 * KERNEL_STEP_C))
    out = []
    for w in windows:
        rhs = w.dg[name][:k] + (dt * w.hessian[:k, k] if shared else 0.0)
        out.append(-np.linalg.solve(w.hessian[:k, :k], rhs))
    return out, dt


def log_changes(
    window: Linearised, dlnx: np.ndarray, free: Sequence[str], z0_rho, contact_at_closure: bool
) -> np.ndarray:
    """``d ln q`` over :data:`QUANTITIES` of a window whose free parameters move by ``dlnx``.

    ``z0_rho``: ``(z0, rho)`` before and after (the kernel temperature's shift moves both).
    """
    before = dict(window.values)
    after = dict(before)
    for name, d in zip(free, dlnx, strict=True):
        after[name] = before[name] * math.exp(float(d))
    if contact_at_closure:
        after["y_c"] = after["y_m"]
    (z_a, rho_a), (z_b, rho_b) = z0_rho
    before.update(combination_values(before, z_a, rho_a))
    after.update(combination_values(after, z_b, rho_b))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.log([after.get(q, math.nan) / before.get(q, math.nan) for q in QUANTITIES])


__all__ = [
    "long_span_changes",
    "FRONTEND_NAMES",
    "KERNEL_STEP_C",
    "HESSIAN_STEP",
    "Linearised",
    "QUANTITIES",
    "RESEPARATION_GUARD_S",
    "Spans",
    "linearise",
    "log_changes",
    "shifts",
    "span_changes",
    "span_margin",
]
