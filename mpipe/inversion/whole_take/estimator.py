"""One estimator for the take: every window, note and the bore's air in one least-squares fit.

``inversion.estimator: take``. The take's model is fitted to its mouthpiece pressure once,
with its parameters in three tiers (:mod:`mpipe.inversion.pooling.take_system`):

- each window's fast controls, the player's (p_m, y_m), which move within 20 ms;
- each note's slow reed constants (k, S, lam, m, g, k_c; y_c when searched), which change
  over seconds as the reed warms and wets;
- the take's air temperature T (degC), which sets the bore's reflection function, with
  the front end's estimate and its standard error as a Gaussian prior.

**How it runs.** Three cold starts per take, on its first, loudest and middle steady window
(:mod:`mpipe.inversion.whole_take.cold_starts`: the global search of
:mod:`mpipe.inversion.fit.coldstart`), at the prior's temperature, each followed on the
thinned take (every 4th window of a note) and the whole take fitted from the lower one's
minimum (:mod:`mpipe.inversion.whole_take.take_fit`). Every window starts warm from the
window before it in its chain (:data:`mpipe.inversion.whole_take.take_shards.CHAIN`
windows of one note): its fast controls fitted with the reed's constants held, so a
crescendo or a new note is followed without a search. The joint fit is a damped
Gauss-Newton (Levenberg-Marquardt) on the whole take's normal equations, each window's
block eliminated; the windows' residual blocks come from the one compiled recursion with
forward sensitivities, computed where the windows are
(:mod:`mpipe.inversion.whole_take.take_shards`).

**Passes.** The bore's kernel is built at the current temperature ``T_k`` and the
residual taken as a quadratic in T about it (its Taylor terms measured once per pass). A
pass is a damped Gauss-Newton
(:func:`mpipe.inversion.whole_take.gauss_newton.joint_pass`); when T moved by more than
:data:`T_SETTLED_C` the kernels are rebuilt there and a new pass starts from the current
values: a few kernels per take, not one per temperature tried.

**Two stages.** A window of a note's release (the conditioning's phase: p_m falls
within it while the model holds it over the window) does not inform its note's
constants or T when its note has other windows (:func:`informing`): the first stage fits
the shared unknowns and the informing windows' controls, the second every window's
controls at them (:mod:`mpipe.inversion.whole_take.gauss_newton`), and its covariance is
that two-stage estimator's (:class:`mpipe.inversion.pooling.take_system.TakeSystem`,
``given``).

References
----------
Chatziioannou & van Walstijn 2012, eq. (15) and section 3.2; Triggs et al. 2000
(bundle adjustment); K. Levenberg 1944, D. W. Marquardt 1963.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from mpipe.inversion.fit.history_start import lead_in
from mpipe.inversion.fit.objective import TargetWindow
from mpipe.inversion.fit.window import window_bounds
from mpipe.inversion.pooling.take_system import TakeSystem, TierSizes, split_names
from mpipe.inversion.settings import InversionConfig
from mpipe.inversion.whole_take.take_shards import Blocks, Layout
from mpipe.reed.parameters import ReedParameters

log = logging.getLogger(__name__)

#: Most passes (kernels rebuilt at the new temperature).
MAX_PASSES = 4
#: A pass whose temperature moved less than this is the last, degC.
T_SETTLED_C = 0.25


@dataclass(frozen=True)
class TakeData:
    """A take's mouthpiece signals and what of them is inverted, and how.

    Attributes
    ----------
    p, u : array-like
        Mouthpiece pressure (Pa) and flow (m^3/s) of the take (only sliced).
    fs : float
        Sample rate, Hz.
    calibration : Calibration
        The instrument (its bore and fingerings).
    windows : WindowPlan
        The windows, their notes, steadiness and fingerings
        (:class:`mpipe.inversion.whole_take.tracking.WindowPlan`).
    config : InversionConfig
        Inversion settings.
    zero_mean : bool
        The flow is zero-mean (measured).
    cold : dict
        First sample -> a cold start already made there on these settings and at the
        prior's temperature (its ``WindowOutcome``: the contact law's choice), reused.
    front : FrontEnd, optional
        The front end's estimate with its SEs
        (:class:`mpipe.inversion.whole_take.shared_errors.FrontEnd`): its share of every
        estimate is propagated through the fit
        (:mod:`mpipe.inversion.whole_take.frontend_joint`); None: not measured.
    """

    p: object
    u: object
    fs: float
    calibration: object
    windows: object
    config: InversionConfig
    zero_mean: bool
    cold: dict = dataclasses.field(default_factory=dict)
    front: object = None


@dataclass(frozen=True)
class WindowProblem:
    """One window of the take's fit: where it is and what it compares.

    Attributes
    ----------
    start : int
        First sample.
    note : int
        Its note's index in the fit, 0..N-1 (time order).
    fingering : str
        Its note's fingering ("" the calibration's bore).
    target : TargetWindow
        The measured window and the history the model reads.
    bounds : ndarray
        Search bounds of the free parameters in the fit's order (fast then slow), (p, 2).
    informs : bool
        The window informs its note's constants and the temperature. A window of its
        note's release (the player's p_m falls within it, which the model holds over a
        window) or build-up (before its first steady window: the front end's flow lacks
        the mean flow's rise, ``take_fit._informs``) does not, when its note has another:
        its controls are fitted given them (:func:`informing`).
    """

    start: int
    note: int
    fingering: str
    target: TargetWindow
    bounds: np.ndarray
    informs: bool = True


def informing(problems, may) -> list:
    """``problems`` with ``informs`` set: those that ``may``, and every window of a note with none.

    ``may``: each window may inform (the take fit's: all but its note's release's,
    ``take_fit._informs``). On the steady tone's own noise-free signals
    (``benchmarks/bench_estimator.py``) the take fit of all 107 windows ended at T -0.051
    degC, S -1.02 %, lambda -0.78 % from the truth, pulled by the release's, which the
    model (p_m held over a window) cannot fit; without them, at the truth (within 0.001 %).
    """
    may = [bool(s) for s in may]
    has = {q.note for q, s in zip(problems, may, strict=True) if s}
    return [dataclasses.replace(q, informs=s or q.note not in has)
            for q, s in zip(problems, may, strict=True)]  # fmt: skip


def given_mask(problems) -> np.ndarray | None:
    """Each window is fitted given its note's constants and T (bool, (W,)); None: none."""
    given = np.array([not q.informs for q in problems], dtype=bool)
    return given if given.any() else None


@dataclass(frozen=True)
class TakeFit:
    """The take's joint fit at its solution.

    Attributes
    ----------
    names : tuple of str
        The fit's reed parameters, fast then slow.
    sizes : TierSizes
        f, s and t (= 1: the temperature).
    problems : tuple of WindowProblem
        The windows fitted (in time order).
    fast : ndarray
        Each window's fast parameters, SI units, (W, f).
    slow : ndarray
        Each note's slow parameters, SI units, (N, s).
    temperature_c : float
        The take's air temperature, degC.
    blocks : Blocks
        Each window's blocks of the normal equations at the solution (unweighted), over
        (ln fast, ln slow, T degC).
    records : list of dict
        Each window's residual figures and noise grams at the solution
        (:meth:`mpipe.inversion.whole_take.take_shards.Shard.final`).
    weight : float
        The windows' weight, 1/Pa^2.
    prior : tuple of float
        The temperature's prior: mean and standard error, degC.
    n_steps, n_passes : int
        Steps tried over all passes, and the passes.
    converged : bool
        Every pass ended by its tolerance, not by its step limit.
    message : str
        Why the last pass stopped.
    excluded : dict
        First sample -> why that window is not in the fit.
    z0, rho : ndarray
        Each window's entry impedance (Pa s/m^3) and air density (kg/m^3) at the fit's
        temperature, on its fingering's bore.
    history : ndarray
        Each window's F2 (Pa) at every point the fit took, (points, W).
    rivals : tuple of float
        The cost of the fit from each of the take's cold starts that began in a basin of
        its own, this one's among them (``rivals.rival_costs``; empty: one start).
    frontend : FrontendShares, optional
        The solution moved by one SE of each front-end parameter
        (:mod:`mpipe.inversion.whole_take.frontend_joint`); None: not measured.
    """

    names: tuple[str, ...]
    sizes: TierSizes
    problems: tuple[WindowProblem, ...]
    fast: np.ndarray
    slow: np.ndarray
    temperature_c: float
    blocks: Blocks
    records: list
    weight: float
    prior: tuple[float, float]
    n_steps: int
    n_passes: int
    converged: bool
    message: str
    excluded: dict
    z0: np.ndarray
    rho: np.ndarray
    history: np.ndarray
    rivals: tuple = ()
    frontend: object = None

    def system(self) -> TakeSystem:
        """The weighted normal equations at the solution, the prior included."""
        return normal_system(self.blocks, self.weight, self.problems, self.sizes,
                             self.temperature_c, self.prior)  # fmt: skip

    def reed(self, i: int, base: ReedParameters, contact_at_closure: bool) -> ReedParameters:
        """Window i's reed: its fast controls, its note's constants, ``base`` for the rest."""
        q = self.problems[i]
        values = dict(zip(self.names, [*self.fast[i], *self.slow[q.note]], strict=True))
        if contact_at_closure:
            values["y_c"] = values.get("y_m", base.y_m)
        return dataclasses.replace(base, **{k: float(v) for k, v in values.items()})


def layout_of(config: InversionConfig) -> Layout:
    """The fit's names (fast then slow) and their places among the searched parameters."""
    fast, slow = split_names(config.search_parameters)
    names = (*fast, *slow)
    order = np.array([names.index(n) for n in config.search_parameters])
    return Layout(names, len(fast), order)


def problems_of(
    p, u, fs: float, starts: Sequence[int], notes: Sequence[int], fingerings: Sequence[str],
    config: InversionConfig, zero_mean: bool, n_taps: int,
) -> list[WindowProblem]:  # fmt: skip
    """Every window's target and bounds (the fit's order of parameters: fast then slow).

    p_m's upper bound is at least the configured factor times the largest pressure of the
    window's note (:func:`note_peaks`), beside :func:`window_bounds`' context: p_m is one
    mouth pressure a window holds, and a note whose oscillation builds up slowly plays far
    below it for longer than any fixed context (a soft note of p_m 1400 Pa, just above its
    threshold, grew from 50 to 770 Pa peak over 0.8 s: every window's bound lay below the
    truth until its last, the fit ended on it in all 36 and the take FAILed).
    """
    n = int(round(config.window_s * fs))
    order = layout_of(config).names
    index = [config.search_parameters.index(name) for name in order]
    peaks = note_peaks(p, starts, notes, n)
    pm = order.index("p_m") if "p_m" in order else None
    out = []
    for s, g, name in zip(starts, notes, fingerings, strict=True):
        history = lead_in(p, u, s, n, n_taps, config.lead_s, fs)
        target = TargetWindow(np.asarray(p[s : s + n], float), np.asarray(u[s : s + n], float),
                              *history, fs, zero_mean)  # fmt: skip
        bounds = window_bounds(config, p, s, n, fs)[index]
        if pm is not None:
            bounds[pm, 1] = max(bounds[pm, 1], config.bounds.p_m[1] * peaks[g])
        out.append(WindowProblem(int(s), int(g), name, target, bounds))
    return out


def note_peaks(p, starts: Sequence[int], notes: Sequence[int], n: int) -> dict:
    """Each note's largest pressure (Pa) over its windows' samples: note -> max p."""
    spans: dict = {}
    for s, g in zip(starts, notes, strict=True):
        a, b = spans.get(g, (int(s), int(s) + n))
        spans[g] = (min(a, int(s)), max(b, int(s) + n))
    return {g: float(np.max(np.asarray(p[a:b], float))) for g, (a, b) in spans.items()}


def _prior(t: float, prior: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """The temperature prior's information (1x1) and gradient at ``t``."""
    mean, se = prior
    info = 1.0 / se**2
    return np.array([[info]]), np.array([info * (t - mean)])


def normal_system(blocks: Blocks, weight: float, problems, sizes, t, prior,
            given: bool = True) -> TakeSystem:  # fmt: skip
    """The weighted system; ``given``: the windows that do not inform are fitted given."""
    info, grad = _prior(t, prior)
    notes = np.array([q.note for q in problems], dtype=int)
    return TakeSystem(sizes, notes, weight * blocks.grams, weight * blocks.grads, info, grad,
                      given_mask(problems) if given else None)  # fmt: skip


def search_boxes(problems, n_fast: int, n_notes: int, t_range):
    """Log bounds of the fast values (W, f), the slow ones (N, s), and T's (degC)."""
    lo = np.array([np.log(q.bounds[:, 0]) for q in problems])
    hi = np.array([np.log(q.bounds[:, 1]) for q in problems])
    notes = np.array([q.note for q in problems])
    slow_lo = np.array([lo[notes == n, n_fast:].max(axis=0) for n in range(n_notes)])
    slow_hi = np.array([hi[notes == n, n_fast:].min(axis=0) for n in range(n_notes)])
    return (lo[:, :n_fast], hi[:, :n_fast]), (slow_lo, slow_hi), t_range


__all__ = [
    "given_mask",
    "informing",
    "MAX_PASSES",
    "T_SETTLED_C",
    "TakeData",
    "TakeFit",
    "WindowProblem",
    "Layout",
    "search_boxes",
    "layout_of",
    "normal_system",
    "note_peaks",
    "problems_of",
]
