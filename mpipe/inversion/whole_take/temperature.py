"""The temperature of the bore model, fitted to the playing, and its share of the error bars.

The reed parameters are very sensitive to the temperature the model's reflection function
is built at (:mod:`mpipe.inversion.preparation.kernel`): on the demo's take a kernel 1.1 degC too
cold
gave S -21 % and lam -14 %. The step-2 residual over a few windows has a clear minimum in
that temperature (0.1 degC wide there), the sharpest thermometer available.

:func:`fit_temperature` therefore profiles the step-2 residual over the kernel temperature:
``R(T) = sum over K windows of F2^2`` with each window's reed re-fitted at every T (warm
started from its solution at the nearest temperature already tried), minimised by
successive parabolas from the front end's estimate. Its standard error comes from the
curvature of ``R`` with the residual's noise level per effective degree of freedom (as the
windows' ``residual_sigma``: ``Delta chi^2 = Delta R / (|r|^2 / (n_eff - p)) = 1``),
and :func:`widen_standard_errors` adds the temperature's share to every ``<name>_se``:
``se^2 + (x * dlnx/dT * se_T)^2`` with the sensitivity measured at ``T +- h``.

Each note's own temperature is read from its windows, and a note that disagrees with the
others is left out of the take's (:mod:`mpipe.inversion.trust.note_temperature`). The fitted
temperature is an effective one (it absorbs small errors of the bore model); a fit far from
the front end's estimate is reported (``note``), as it points at the calibration.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from mpipe.inversion.fit.coldstart import map_tasks
from mpipe.inversion.fit.window import invert_window
from mpipe.inversion.preparation.kernel import KernelSource, bore_kernel
from mpipe.inversion.preparation.segments import pick_by_segment, pick_windows, window_count
from mpipe.inversion.settings import PARAMETER_NAMES, InversionConfig
from mpipe.inversion.trust.budget import combine, component_column
from mpipe.inversion.trust.combinations import COMBINATION_NAMES, combination_values
from mpipe.inversion.trust.note_temperature import (
    NoteTemperatures,
    notes_from_triple,
    scatter_se,
    window_minima,
)
from mpipe.inversion.trust.uncertainty import SE_PARAMETERS
from mpipe.inversion.whole_take.temperature_profile import (
    COARSE_C,
    FINE_C,
    Profile,
    cold_starts,
    memo_start,
    same_basin,
    settle,
)
from mpipe.inversion.whole_take.tracking import WindowPlan
from mpipe.measurement.calibration import Calibration
from mpipe.reed.parameters import ReedParameters

log = logging.getLogger(__name__)

#: The fit's cold start is made again at the fitted temperature when the fit ended farther
#: than this from it, degC, at most ``RESTARTS`` times.
RESTART_C = 0.5
RESTARTS = 2
#: Quantities whose standard error the temperature widens.
WIDENED = (*SE_PARAMETERS, *COMBINATION_NAMES)


@dataclass(frozen=True)
class TemperatureFit:
    """The kernel temperature of a take's inversion.

    Attributes
    ----------
    temperature_c : float
        Temperature the bore kernel is built at, degC.
    se_c : float
        Its standard error, degC (NaN when not fitted: then the temperature's share of the
        error bars is unknown and not added).
    source : str
        ``"fit"`` (profiled on the playing), ``"front end"`` (the wave separation's
        estimate, carried with the signals) or ``"calibration"``.
    front_end_c : float
        The temperature the signals carried (or the calibration's), degC.
    sensitivity : dict
        ``d ln x / dT`` (1/degC) of every parameter and combination, median over the
        fitted windows; empty when not fitted.
    windows : int
        Windows used by the fit.
    evaluations : tuple
        ``(T degC, R Pa^2)`` of every temperature tried, in order.
    note : str
        Why the fit was not used, or a warning about it; "" when there is nothing to say.
    anchor : ReedParameters or None
        The first fitted window's reed at the fitted temperature: the take's start for
        every window (it replaces the tracking's own cold start).
    cold_starts_agreeing : int or None
        How many of the cold start's short searches reached its minimum (see
        :mod:`mpipe.inversion.fit.coldstart`).
    anchors : dict
        Segment -> its first fitted window's reed at the fitted temperature: the start of
        every window of that segment (a segment missing here gets its own cold start).
    per_segment_c : dict
        Segment -> the temperature its own fitted windows point at (the inverse-variance
        mean of their minima of F2^2 in T), degC: whether one temperature holds over the
        take's notes.
    notes : NoteTemperatures or None
        Each note's temperature with its SE, their chi-square, and the notes left out of
        the take's temperature (:mod:`mpipe.inversion.trust.note_temperature`).
    """

    temperature_c: float
    se_c: float
    source: str
    front_end_c: float
    sensitivity: Mapping[str, float] = dataclasses.field(default_factory=dict)
    windows: int = 0
    evaluations: tuple[tuple[float, float], ...] = ()
    note: str = ""
    anchor: ReedParameters | None = None
    cold_starts_agreeing: int | None = None
    anchors: Mapping[int, ReedParameters] = dataclasses.field(default_factory=dict)
    per_segment_c: Mapping[int, float] = dataclasses.field(default_factory=dict)
    notes: NoteTemperatures | None = None

    def summary(self) -> dict:
        """JSON-ready record for manifests and the report."""
        return {
            "temperature_c": self.temperature_c,
            "temperature_se_c": None if math.isnan(self.se_c) else self.se_c,
            "source": self.source,
            "front_end_c": self.front_end_c,
            "windows": self.windows,
            "evaluations": [[t, r if math.isfinite(r) else None] for t, r in self.evaluations],
            "note": self.note,
            "cold_starts_agreeing": self.cold_starts_agreeing,
            "per_segment_c": {str(g): t for g, t in self.per_segment_c.items()},
            "notes": None if self.notes is None else self.notes.summary(),
        }

    def line(self) -> str:
        """One console line."""
        if self.source == "take fit":
            return (
                f"take temperature {self.temperature_c:.2f} +- {self.se_c:.2f} degC, fitted "
                f"with the reed on {self.windows} windows (front end {self.front_end_c:.2f} degC)"
                + (f"; {self.note}" if self.note else "")
            )
        if self.source != "fit":
            why = self.note or "inversion.temperature: front-end"
            return (
                f"kernel temperature {self.temperature_c:.2f} degC ({self.source}; not fitted: "
                f"{why}); the standard errors leave out the temperature's uncertainty"
            )
        notes = "" if self.notes is None else self.notes.words()
        return (
            f"kernel temperature {self.temperature_c:.2f} +- {self.se_c:.2f} degC, fitted on "
            f"{self.windows} windows (front end {self.front_end_c:.2f} degC){notes}"
            + (f"; {self.note}" if self.note else "")
        )


def fit_temperature(
    p: np.ndarray,
    u: np.ndarray,
    fs: float,
    calibration: Calibration,
    windows: WindowPlan | Sequence[int],
    config: InversionConfig,
    *,
    zero_mean: bool,
    front_end_c: float,
    source: str = "front end",
) -> TemperatureFit:
    """The kernel temperature that makes the model play the take best, with its SE.

    Parameters
    ----------
    p, u : ndarray
        Mouthpiece pressure (Pa) and flow (m^3/s) of the take.
    fs : float
        Sample rate, Hz.
    calibration : Calibration
        Bore and air model.
    windows : WindowPlan or sequence of int
        The windows planned for inversion (:class:`mpipe.inversion.whole_take.tracking.WindowPlan`),
        or their first samples (one segment). Each segment fitted gets its own start
        (the first cold, later ones warm from the one before when that holds),
        and its windows start from it; the fit prefers steady windows (see
        :func:`pick_by_segment`).
    config : InversionConfig
        Inversion settings (``temperature``, ``temperature_windows``, ...).
    zero_mean : bool
        The flow is zero-mean (measured).
    front_end_c : float
        The temperature carried with the signals (or the calibration's), degC: the start
        of the search, and the kernel temperature when the fit is off or fails.
    source : str
        Where ``front_end_c`` comes from, for the report.

    Returns
    -------
    TemperatureFit
    """
    fallback = TemperatureFit(front_end_c, math.nan, source, front_end_c)
    if config.temperature != "fit":
        return fallback
    plan = WindowPlan.of(windows)
    count = window_count(len(plan.starts), config)
    chosen, groups = pick_by_segment(plan.starts, plan.segment_ids, count, plan.steady)
    if not chosen:
        return dataclasses.replace(fallback, note="no window to fit the temperature on")
    lo, hi = front_end_c - config.temperature_range_c, front_end_c + config.temperature_range_c
    firsts: dict[int, int] = {}  # each segment's first fitted window, in time order
    for s, g in zip(chosen, groups, strict=True):
        firsts.setdefault(g, s)
    # each window on its note's fingering's bore (one bore when the take has one fingering)
    source = KernelSource(calibration, fs, plan.fingering_map(), build=_build)
    cold = functools.partial(cold_starts, p, u, fs, firsts, zero_mean, source)
    solve = functools.partial(_solve, p, u, fs, source, chosen, config, zero_mean)
    runs, error = _profiles(solve, cold, config, groups, front_end_c, lo, hi)
    if not runs:
        return dataclasses.replace(fallback, note="the fit's cold start failed: " + error)

    def inside(run) -> bool:
        return run[1] is not None and run[1][1] > 0 and lo + COARSE_C <= run[1][0] <= hi - COARSE_C

    candidates = [r for r in runs if inside(r)] or runs  # a settled profile before a lower R
    profile, settled, first, t_cold = min(
        candidates, key=lambda r: min(v[0] for v in r[0].tried.values())
    )
    evaluations = tuple(sorted((t, v[0]) for t, v in profile.tried.items()))
    base = dataclasses.replace(fallback, windows=len(chosen), evaluations=evaluations)
    if settled is None or settled[1] <= 0:
        return dataclasses.replace(
            base, note="the residual has no minimum in the kernel temperature here: not fitted"
        )
    best, curvature, centre = settled
    if not lo + COARSE_C <= best <= hi - COARSE_C:
        return dataclasses.replace(
            base, note=f"the fit ran to the edge of its range ({lo:.1f}..{hi:.1f} degC): not used"
        )
    notes = notes_from_triple(_triple(profile, centre), centre, FINE_C, groups)
    first_reeds = profile.tried[round(centre, 4)][1]
    keep = [g not in notes.excluded for g in groups]
    if notes.excluded:
        solve_kept = functools.partial(
            _solve, p, u, fs, source, [s for s, k in zip(chosen, keep, strict=True) if k],
            config, zero_mean,
        )  # fmt: skip
        again = _without(profile, settled, notes, keep, groups, solve_kept, (lo, hi), config)
        if again is None:
            return dataclasses.replace(
                base, note="the fit without the notes left out has no minimum: not fitted",
                notes=notes,
            )  # fmt: skip
        profile, (best, curvature, centre), notes = again
    n_kept = sum(keep)
    se = _standard_error(profile, centre, curvature)
    lower, upper = _triple(profile, centre)[0], _triple(profile, centre)[2]
    note = f"cold start repeated at {t_cold:.2f} degC" if len(runs) > 1 else ""
    if abs(best - front_end_c) > 3.0:
        note = (note + "; " if note else "") + (
            f"{best - front_end_c:+.1f} degC from the temperature the signals carry: check "
            "the calibration's bore geometry"
        )
    log.info("kernel temperature fitted: %.3f +- %.3f degC (%d evaluations on %d windows)",
             best, se, len(profile.tried), n_kept)  # fmt: skip
    # each note's first fitted window's reed: a note left out keeps its own from the first fit
    anchors: dict[int, ReedParameters] = {}
    reeds = iter(profile.tried[round(centre, 4)][1])
    for g, k, reed in zip(groups, keep, first_reeds, strict=True):
        anchors.setdefault(g, next(reeds) if k else reed)
    evaluations = tuple(sorted((t, v[0]) for t, v in profile.tried.items()))
    return TemperatureFit(
        best, se, "fit", front_end_c, _sensitivity(lower, upper, FINE_C), n_kept,
        evaluations, note, anchors[groups[0]], _agreeing(first.row), anchors,
        dict(notes.temperature_c), notes,
    )  # fmt: skip


def _without(profile, settled, notes, keep, groups, solve, bounds, config):
    """``(profile, settled, notes)`` of R(T) over the notes kept, or None without a minimum.

    The new profile starts from the memo of the first (its windows' solutions so far) and
    settles with fine triples only from where the memo puts its minimum, so only the
    temperatures the minimum moved to cost new evaluations (none when it did not move).
    """
    lo, hi = bounds
    sub = profile.subset(keep, solve)
    start = memo_start(sub)
    if not math.isfinite(start):
        return None
    again = settle(sub, start, lo, hi, len(sub.tried) + config.temperature_evaluations, False)
    if again is None or again[1] <= 0 or not lo + COARSE_C <= again[0] <= hi - COARSE_C:
        return None
    kept = [g for g, k in zip(groups, keep, strict=True) if k]
    test = notes_from_triple(_triple(sub, again[2]), again[2], FINE_C, kept)
    notes = dataclasses.replace(
        notes, chi2=test.first_chi2, dof=test.first_dof, p_value=test.first_p
    )
    return sub, again, notes


def _standard_error(profile: Profile, centre: float, curvature: float) -> float:
    """SE of the fitted temperature from the curvature of R, bounded by the windows' scatter."""
    rows = profile.tried[round(centre, 4)][2]
    dofs = [r["dof"] if r.get("dof", 0) > 0 else math.nan for r in rows]
    # as each window's SEs: the residual's degrees of freedom are n_eff - p (a window
    # without them counts as one, never as white)
    dof = float(np.nanmedian(dofs)) if np.isfinite(dofs).any() else 1.0
    sigma2 = profile(centre) / (max(dof, 1.0) * len(rows))
    # R(T) = R0 + a (T - T0)^2 and Delta chi^2 = Delta R / sigma_eff^2 = 1 at 1 SE, with
    # sigma_eff^2 = |r|^2 / (n_eff - p) per window, as the windows' residual_sigma^2
    se = math.sqrt(sigma2 / curvature)
    # Errors of the signals that differ from window to window (the front end's, the model's)
    # move each window's own minimum; their scatter bounds the SE from below when the noise
    # alone would claim more precision than the windows agree to.
    return max(se, scatter_se(window_minima(_triple(profile, centre), centre, FINE_C)[0]))


def _triple(profile: Profile, centre: float) -> list:
    """The windows' rows at ``centre - FINE_C``, ``centre``, ``centre + FINE_C``."""
    return [profile.tried[round(centre + d, 4)][2] for d in (-FINE_C, 0.0, FINE_C)]


def _build(calibration, fs: float, t: float):
    """:func:`bore_kernel`, looked up when called (a seam the tests replace)."""
    return bore_kernel(calibration, fs, t)


def _solve(p, u, fs, source, chosen, config, zero_mean, t: float, warm: Sequence):
    """``R(T)`` (Pa^2), the windows' reeds and rows at kernel temperature ``t`` (degC)."""
    air = source.at(t)[1]
    reeds, rows, total = [], [], 0.0
    # the windows are independent: spread over the workers when there are some
    items = [
        (fs, s, source.at(t, s)[0], air.rho, config, zero_mean, w)
        for s, w in zip(chosen, warm, strict=True)
    ]
    for out in map_tasks(_window_task, items, shared=(p, u)):
        if out.reed is None or not math.isfinite(out.row["f2"]):
            return math.inf, list(warm), rows
        reeds.append(out.reed)
        rows.append({**out.row, **_combinations(out.reed, source.at(t)[0].z0, air.rho)})
        total += float(out.row["f2"]) ** 2
    return total, reeds, rows


def _window_task(shared, item):
    """One window at one kernel temperature (a task of :func:`_solve`); ``shared`` = (p, u)."""
    p, u = shared
    fs, start, kernel, rho, config, zero_mean, warm = item
    return invert_window(p, u, fs, start, kernel, rho, config, zero_mean=zero_mean, warm=warm)


def _profiles(solve, cold, config, groups, t_cold, lo, hi):
    """Profiles of R(T), each from a cold start; ``(profile, settled, cold row, T)`` each.

    The cold start's basin depends on the kernel: one made at a temperature far from the
    fitted one may hold a wrong minimum (m and g collapsed), which warm starts then carry
    along the whole profile. The cold start is made again where the fit ended until the
    fit ends near its own cold start (``RESTART_C``, at most ``RESTARTS`` times), unless
    one cold start there finds the profile's own basin (:func:`same_basin`).
    """
    runs, error = [], ""
    for _ in range(1 + RESTARTS):
        colds = cold(t_cold, config)  # one per segment
        failed = [c for c in colds.values() if c.reed is None]
        if failed:
            error = failed[0].row["error"]
            break
        # the take's agreement is its least agreed note's: one poorly agreed cold start
        # is enough to doubt the take (the first note alone would hide the others)
        first = min(colds.values(), key=lambda c: _agreeing(c.row) or math.inf)
        profile = Profile(solve, [colds[g].reed for g in groups])
        settled = settle(profile, t_cold, lo, hi, config.temperature_evaluations)
        runs.append((profile, settled, first, t_cold))
        if settled is None or abs(settled[0] - t_cold) <= RESTART_C:
            break
        if same_basin(profile, settled[2], cold, config, groups[0]):
            break  # the cold start made again finds the profile's own basin: nothing changes
        t_cold = min(max(settled[0], lo), hi)
    return runs, error


def _agreeing(row: Mapping) -> int | None:
    value = row.get("cold_starts_agreeing")
    return int(value) if value is not None and np.isfinite(value) else None


def _combinations(reed: ReedParameters, z_c: float, rho: float) -> dict[str, float]:
    values = {name: float(getattr(reed, name)) for name in (*PARAMETER_NAMES, "y_c")}
    return {**values, **combination_values(values, z_c, rho)}


def _sensitivity(rows_lo: Sequence[Mapping], rows_hi: Sequence[Mapping], h: float) -> dict:
    """Median over windows of ``d ln x / dT`` from solutions at ``T - h`` and ``T + h``."""
    out = {}
    for name in WIDENED:
        d = [
            (math.log(hi[name]) - math.log(lo[name])) / (2 * h)
            for lo, hi in zip(rows_lo, rows_hi, strict=True)
            if lo.get(name, 0) > 0 and hi.get(name, 0) > 0
        ]
        out[name] = float(np.median(d)) if d else math.nan
    return out


def temperature_components(table: pd.DataFrame, fit: TemperatureFit) -> pd.DataFrame:
    """The kernel temperature's component of every quantity's budget, ``<q>_se_temperature``.

    ``|x| |d ln x / dT| se_T`` (x's unit): the profile estimate's share of the variance,
    ``(d theta / dT)^2 Var(T)``, the same error for every window of the take. NaN (the
    component does not apply) when the temperature was not fitted or a sensitivity is not
    finite. The combination is :func:`mpipe.inversion.trust.budget.combine`.

    Parameters
    ----------
    table : DataFrame
        Windows table of :func:`mpipe.inversion.whole_take.tracking.track`.
    fit : TemperatureFit
        The take's kernel temperature.

    Returns
    -------
    DataFrame
        A copy with ``kernel_temperature_c``, ``kernel_temperature_se_c`` (degC) and the
        component columns.
    """
    out = table.copy()
    out["kernel_temperature_c"] = fit.temperature_c
    out["kernel_temperature_se_c"] = fit.se_c
    fitted = fit.source == "fit" and math.isfinite(fit.se_c)
    for name in WIDENED:
        col = component_column(name, "temperature")
        sens = fit.sensitivity.get(name, math.nan) if fitted else math.nan
        if name not in out or not math.isfinite(sens):
            out[col] = math.nan
            continue
        x = pd.to_numeric(out[name], errors="coerce").to_numpy(dtype=float)
        out[col] = np.abs(x) * abs(sens) * fit.se_c
    return out


def widen_standard_errors(table: pd.DataFrame, fit: TemperatureFit, limit: float) -> pd.DataFrame:
    """:func:`temperature_components`, then :func:`mpipe.inversion.trust.budget.combine`."""
    out = temperature_components(table, fit)
    for name in WIDENED:
        # a table without its budget (an earlier mpipe's): its SE is the window's own
        noise = component_column(name, "noise")
        if noise not in out and f"{name}_se" in out:
            out[noise] = out[f"{name}_se"]
    return combine(out, limit)


__all__ = [
    "TemperatureFit",
    "fit_temperature",
    "pick_by_segment",
    "pick_windows",
    "temperature_components",
    "widen_standard_errors",
    "window_count",
]
