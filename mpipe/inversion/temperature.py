"""The temperature of the bore model, fitted to the playing, and its share of the error bars.

The model's reflection function is built at one air temperature (:mod:`mpipe.inversion.kernel`).
The reed parameters are very sensitive to it: on the demo's take, a kernel 1.1 degC too cold
(the wave separation's estimate, 18.9 +- 1.3 degC for a true 20 degC) gave S -21 % and lam
-14 %, against +1.5 % and -1.9 % at the true temperature, because the search bends the reed
to make the model's too-slow bore play the measured period. The same fit is also the
sharpest thermometer available: the total residual of step 2 over a few windows has a
clear minimum in the kernel temperature (0.1 degC wide on that take), where the front end's
estimate from 2 cm of microphone spacing is a degree wide.

:func:`fit_temperature` therefore profiles the step-2 residual over the kernel temperature:
``R(T) = sum over K windows of F2^2`` with each window's reed re-fitted at every T (warm
started from its solution at the nearest temperature already tried), minimised by
successive parabolas from the front end's estimate. Its standard error comes from the
curvature of ``R`` with the residual's noise level per effective degree of freedom (as the
windows' ``residual_sigma``: ``Delta chi^2 = Delta R / (|r|^2 / (n_eff - p)) = 1``),
and :func:`widen_standard_errors` adds the temperature's share to every ``<name>_se``:
``se^2 + (x * dlnx/dT * se_T)^2`` with the sensitivity measured at ``T +- h``.

The fitted temperature is an effective one: it also absorbs small errors of the bore model
(geometry, radiation), which is what keeps them out of the reed parameters. A fit far from
the front end's estimate is reported (``note``), as it points at the calibration.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from mpipe.inversion.budget import combine, component_column
from mpipe.inversion.coldstart import map_tasks
from mpipe.inversion.combinations import COMBINATION_NAMES, combination_values
from mpipe.inversion.kernel import bore_kernel
from mpipe.inversion.segments import pick_by_segment, pick_windows, window_count
from mpipe.inversion.settings import PARAMETER_NAMES, InversionConfig
from mpipe.inversion.tracking import WindowPlan
from mpipe.inversion.uncertainty import SE_PARAMETERS
from mpipe.inversion.window import invert_window
from mpipe.measurement.calibration import Calibration
from mpipe.reed.parameters import ReedParameters

log = logging.getLogger(__name__)

#: Spacing of the coarse and the fine triples of :func:`_settle`, degC.
COARSE_C = 1.0
FINE_C = 0.25
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
        :mod:`mpipe.inversion.coldstart`).
    anchors : dict
        Segment -> its first fitted window's reed at the fitted temperature: the start of
        every window of that segment (a segment missing here gets its own cold start).
    per_segment_c : dict
        Segment -> the temperature its own fitted windows point at (the mean of their
        minima of F2^2 in T), degC: whether one temperature holds over the take's notes.
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
        }

    def line(self) -> str:
        """One console line."""
        if self.source != "fit":
            why = self.note or "inversion.temperature: front-end"
            return (
                f"kernel temperature {self.temperature_c:.2f} degC ({self.source}; not fitted: "
                f"{why}); the standard errors leave out the temperature's uncertainty"
            )
        notes = (
            "; each note's own: " + ", ".join(f"{t:.2f}" for t in self.per_segment_c.values())
            if len(self.per_segment_c) > 1
            else ""
        )
        return (
            f"kernel temperature {self.temperature_c:.2f} +- {self.se_c:.2f} degC, fitted on "
            f"{self.windows} windows (front end {self.front_end_c:.2f} degC){notes}"
            + (f"; {self.note}" if self.note else "")
        )


@dataclass
class _Profile:
    """Memo of ``R(T)``: the windows' solutions at every temperature tried."""

    solve: Callable[[float, Sequence[ReedParameters]], tuple[float, list, list]]
    anchor: list[ReedParameters]
    tried: dict = dataclasses.field(default_factory=dict)  # T -> (R, reeds, rows)

    def __call__(self, t: float) -> float:
        t = round(float(t), 4)
        if t not in self.tried:
            near = min(self.tried, key=lambda s: abs(s - t)) if self.tried else None
            warm = self.anchor if near is None else self.tried[near][1]
            self.tried[t] = self.solve(t, warm)
        return self.tried[t][0]


def _parabola_vertex(x: Sequence[float], y: Sequence[float]) -> tuple[float, float]:
    """Vertex abscissa and curvature ``a`` of the parabola ``a (x - x0)^2 + c`` through 3 points."""
    a, b, _ = np.polyfit(np.asarray(x) - x[1], y, 2)
    if a <= 0:
        return math.nan, a
    return x[1] - b / (2 * a), a


def _settle(profile: _Profile, t0: float, lo: float, hi: float, max_evaluations: int):
    """Minimum of ``profile`` by parabolas through three points.

    R(T) is close to a parabola near its minimum (a sum of squares of residuals nearly
    linear in T there). A coarse triple ``t0 + (-1, 0, 1) degC`` is walked downhill until it
    brackets the minimum; a fine triple of half-spacing ``FINE_C`` around the coarse
    parabola's vertex then gives the vertex, the curvature and the sensitivities, and is
    re-centred while the vertex moves by more than ``FINE_C / 2``.

    Returns
    -------
    (vertex degC, curvature Pa^2/degC^2, centre of the fine triple degC) or None
    """
    mid = t0
    while True:  # coarse: bracket the minimum
        triple = (max(mid - COARSE_C, lo), mid, min(mid + COARSE_C, hi))
        values = [profile(t) for t in triple]
        best = triple[int(np.argmin(values))]
        if best == mid or best in (lo, hi) or len(profile.tried) >= max_evaluations:
            break
        mid = best
    vertex, _ = _parabola_vertex(triple, values)
    centre = mid if not math.isfinite(vertex) else min(max(vertex, triple[0]), triple[2])
    for step in range(3):  # fine: settle the vertex
        triple = (centre - FINE_C, centre, centre + FINE_C)
        values = [profile(t) for t in triple]
        vertex, curvature = _parabola_vertex(triple, values)
        if not all(math.isfinite(v) for v in values) or not math.isfinite(vertex):
            return None
        # never further than the triple's reach from its (evaluated) centre
        vertex = min(max(vertex, centre - 2 * FINE_C), centre + 2 * FINE_C)
        if abs(vertex - centre) <= FINE_C / 2 or len(profile.tried) >= max_evaluations:
            break
        if step < 2:
            centre = vertex  # the last triple's centre stays the evaluated one
    return vertex, curvature, centre


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
        The windows planned for inversion (:class:`mpipe.inversion.tracking.WindowPlan`),
        or their first samples (one segment). Each segment fitted gets its own cold start,
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
    cold = functools.partial(_cold_starts, p, u, fs, firsts, zero_mean)
    solve = functools.partial(_solve, p, u, fs, calibration, chosen, config, zero_mean)
    runs, error = _profiles(solve, cold, calibration, fs, config, groups, front_end_c, lo, hi)
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
    rows = profile.tried[round(centre, 4)][2]
    dofs = [r["dof"] if r.get("dof", 0) > 0 else math.nan for r in rows]
    # as each window's SEs: the residual's degrees of freedom are n_eff - p (a window
    # without them counts as one, never as white)
    dof = float(np.nanmedian(dofs)) if np.isfinite(dofs).any() else 1.0
    sigma2 = profile(centre) / (max(dof, 1.0) * len(chosen))
    # R(T) = R0 + a (T - T0)^2 and Delta chi^2 = Delta R / sigma_eff^2 = 1 at 1 SE, with
    # sigma_eff^2 = |r|^2 / (n_eff - p) per window, as the windows' residual_sigma^2
    se = math.sqrt(sigma2 / curvature)
    # Errors of the signals that differ from window to window (the front end's, the model's)
    # move each window's own minimum; their scatter bounds the SE from below when the noise
    # alone would claim more precision than the windows agree to.
    se = max(se, _scatter_se(profile, centre))
    lower, upper = (
        profile.tried[round(centre - FINE_C, 4)][2],
        profile.tried[round(centre + FINE_C, 4)][2],
    )
    note = f"cold start repeated at {t_cold:.2f} degC" if len(runs) > 1 else ""
    if abs(best - front_end_c) > 3.0:
        note = (note + "; " if note else "") + (
            f"{best - front_end_c:+.1f} degC from the temperature the signals carry: check "
            "the calibration's bore geometry"
        )
    log.info("kernel temperature fitted: %.3f +- %.3f degC (%d evaluations on %d windows)",
             best, se, len(evaluations), len(chosen))  # fmt: skip
    reeds = profile.tried[round(centre, 4)][1]
    anchors = {}
    for g, reed in zip(groups, reeds, strict=True):
        anchors.setdefault(g, reed)  # each segment's first fitted window
    return TemperatureFit(
        best, se, "fit", front_end_c, _sensitivity(lower, upper, FINE_C), len(chosen),
        evaluations, note, reeds[0], _agreeing(first.row), anchors,
        _per_segment(profile, centre, groups),
    )  # fmt: skip


def _cold_starts(p, u, fs, firsts, zero_mean, kernel, rho, config) -> dict:
    """Segment -> the cold start of its first fitted window (stops at the first failure)."""
    out = {}
    for g, start in firsts.items():
        out[g] = invert_window(p, u, fs, start, kernel, rho, config, zero_mean=zero_mean)
        if out[g].reed is None:
            break
    return out


def _solve(p, u, fs, calibration, chosen, config, zero_mean, t: float, warm: Sequence):
    """``R(T)`` (Pa^2), the windows' reeds and rows at kernel temperature ``t`` (degC)."""
    kernel, air = bore_kernel(calibration, fs, t)
    reeds, rows, total = [], [], 0.0
    # the windows are independent: spread over the workers when there are some
    items = [
        (fs, s, kernel, air.rho, config, zero_mean, w) for s, w in zip(chosen, warm, strict=True)
    ]
    for out in map_tasks(_window_task, items, shared=(p, u)):
        if out.reed is None or not math.isfinite(out.row["f2"]):
            return math.inf, list(warm), rows
        reeds.append(out.reed)
        rows.append({**out.row, **_combinations(out.reed, kernel.z0, air.rho)})
        total += float(out.row["f2"]) ** 2
    return total, reeds, rows


def _window_task(shared, item):
    """One window at one kernel temperature (a task of :func:`_solve`); ``shared`` = (p, u)."""
    p, u = shared
    fs, start, kernel, rho, config, zero_mean, warm = item
    return invert_window(p, u, fs, start, kernel, rho, config, zero_mean=zero_mean, warm=warm)


def _profiles(solve, cold, calibration, fs, config, groups, t_cold, lo, hi):
    """Profiles of R(T), each from a cold start; ``(profile, settled, cold row, T)`` each.

    The cold start's basin depends on the kernel: one made at a temperature far from the
    fitted one may hold a wrong minimum (m and g collapsed), which warm starts then carry
    along the whole profile. The cold start is made again where the fit ended until the
    fit ends near its own cold start (``RESTART_C``, at most ``RESTARTS`` times).
    """
    runs, error = [], ""
    for _ in range(1 + RESTARTS):
        kernel, air = bore_kernel(calibration, fs, t_cold)
        colds = cold(kernel, air.rho, config)  # one per segment
        failed = [c for c in colds.values() if c.reed is None]
        if failed:
            error = failed[0].row["error"]
            break
        # the take's agreement is its least agreed note's: one poorly agreed cold start
        # is enough to doubt the take (the first note alone would hide the others)
        first = min(colds.values(), key=lambda c: _agreeing(c.row) or math.inf)
        profile = _Profile(solve, [colds[g].reed for g in groups])
        settled = _settle(profile, t_cold, lo, hi, config.temperature_evaluations)
        runs.append((profile, settled, first, t_cold))
        if settled is None or abs(settled[0] - t_cold) <= RESTART_C:
            break
        t_cold = min(max(settled[0], lo), hi)
    return runs, error


def _window_minima(profile: _Profile, centre: float) -> list[float]:
    """Each fitted window's own minimum of F2^2 in T (degC; NaN where it has none)."""
    triple = [profile.tried[round(centre + d, 4)][2] for d in (-FINE_C, 0.0, FINE_C)]
    minima = []
    for rows in zip(*triple, strict=True):
        vertex, _ = _parabola_vertex(
            (centre - FINE_C, centre, centre + FINE_C), [r["f2"] ** 2 for r in rows]
        )
        minima.append(
            min(max(vertex, centre - 4 * COARSE_C), centre + 4 * COARSE_C)
            if math.isfinite(vertex)
            else math.nan
        )
    return minima


def _scatter_se(profile: _Profile, centre: float) -> float:
    """Standard error of the mean of the windows' own minima in T, degC (0 for < 3 windows)."""
    minima = [m for m in _window_minima(profile, centre) if math.isfinite(m)]
    if len(minima) < 3:
        return 0.0
    return float(np.std(minima, ddof=1) / math.sqrt(len(minima)))


def _per_segment(profile: _Profile, centre: float, groups: Sequence[int]) -> dict[int, float]:
    """Each note's own temperature: the mean of its fitted windows' minima, degC."""
    out: dict[int, list[float]] = {}
    for g, m in zip(groups, _window_minima(profile, centre), strict=True):
        if math.isfinite(m):
            out.setdefault(int(g), []).append(m)
    return {g: float(np.mean(v)) for g, v in out.items()}


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
    finite. The combination is :func:`mpipe.inversion.budget.combine`.

    Parameters
    ----------
    table : DataFrame
        Windows table of :func:`mpipe.inversion.tracking.track`.
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
    """:func:`temperature_components`, then :func:`mpipe.inversion.budget.combine`."""
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
