"""A whole take's inversion: one door, two estimators, one budget.

The one function every door into the inversion calls (``mpipe run``, ``mpipe invert`` and
the Python API ``mpipe.invert_take``), so that the same mouthpiece signals give the same
table whichever is used:

1. the temperature the signals carry (the wave separation's estimate, else the
   calibration's; :func:`mpipe.inversion.preparation.kernel.take_temperature`);
2. ``inversion.estimator: take`` (the default): the take's one fit of every window's
   controls, each note's reed and the take's temperature, with one covariance
   (:mod:`mpipe.inversion.whole_take.take_estimate`); ``window``: the paper's per-window
   fit, every note from its own cold start, on the kernel at that temperature
   (:func:`mpipe.inversion.whole_take.tracking.track`);
3. the uncertainty budget: the windows' own components (noise, model form; the take's fit
   adds the temperature's share), the model's discretisation at fs
   (:mod:`mpipe.inversion.trust.discretisation`) and the take-wide components of the front
   end and the microphones' calibration (:mod:`mpipe.inversion.whole_take.shared_errors`),
   combined into every ``<q>_se`` (:func:`mpipe.inversion.trust.budget.combine`);
4. the take-level checks (:func:`mpipe.inversion.trust.diagnostics.take_checks`, with the
   run's own, :attr:`~mpipe.inversion.whole_take.tracking.RunOptions.checks`): each reason
   in :attr:`TakeInversion.checks` and in the table's ``take_checks`` column;
5. the fitted reed's opening in every window: ``h_mean``, ``h_min`` (m) and
   ``closed_fraction`` (:func:`mpipe.inversion.preparation.segments.reed_openings`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
from threadpoolctl import threadpool_limits

from mpipe.acoustics.air import Air
from mpipe.core.signals import DiskArray, as_signal
from mpipe.inversion.fit.execution import stage_workers
from mpipe.inversion.preparation.kernel import KernelSource, take_temperature
from mpipe.inversion.preparation.segments import reed_openings
from mpipe.inversion.settings import ExecutorConfig, InversionConfig
from mpipe.inversion.trust.budget import combine
from mpipe.inversion.trust.diagnostics import check_plausible, take_checks
from mpipe.inversion.trust.discretisation import rate_errors
from mpipe.inversion.whole_take.contact_law import choose_contact
from mpipe.inversion.whole_take.estimator import TakeData
from mpipe.inversion.whole_take.front_end import FrontEnd
from mpipe.inversion.whole_take.prior_conflict import prior_figures
from mpipe.inversion.whole_take.shared_errors import shared_components
from mpipe.inversion.whole_take.take_estimate import estimate_take
from mpipe.inversion.whole_take.temperature import TemperatureFit
from mpipe.inversion.whole_take.tracking import (
    RunOptions,
    Tracking,
    WindowPlan,
    detect_zero_mean,
    track,
)
from mpipe.measurement.calibration import Calibration
from mpipe.reed.bore_kernel import BoreKernel


@dataclass(frozen=True)
class TakeInversion:
    """Result of :func:`invert_take`.

    Attributes
    ----------
    tracking : Tracking
        Every window (its table carries ``kernel_temperature_c``, ``kernel_temperature_se_c``
        and the widened ``<name>_se``).
    temperature : TemperatureFit
        The kernel temperature and how it was found.
    kernel : BoreKernel
        The bore kernel at that temperature (for the resynthesis).
    air : Air
        The air at that temperature.
    checks : tuple of str
        Why the take as a whole should not pass, one line each (empty: nothing found); see
        :mod:`mpipe.inversion.trust.diagnostics`.
    shared : dict
        The take-wide components' inputs
        (:func:`mpipe.inversion.whole_take.shared_errors.shared_components`):
        the sensitivity's uncertainty and the front end's parameters with their effects.
    """

    tracking: Tracking
    temperature: TemperatureFit
    kernel: BoreKernel
    air: Air
    checks: tuple[str, ...] = ()
    shared: dict = dataclasses.field(default_factory=dict)


# More than ten parameters: the public door of a take's inversion; what the front end found
# (its temperature, its estimate's SEs, checks before the inversion) is keyword-only.
def invert_take(
    p: np.ndarray,
    u: np.ndarray,
    fs: float,
    calibration: Calibration,
    config: InversionConfig,
    executor: ExecutorConfig | None = None,
    *,
    windows: WindowPlan | Sequence[int] | pd.DataFrame,
    temperature_c: np.ndarray | float | None = None,
    options: RunOptions | None = None,
    front_end: FrontEnd | None = None,
) -> TakeInversion:
    """Invert the planned windows of a take (see the module docstring for the steps).

    Parameters
    ----------
    p, u : ndarray
        Mouthpiece pressure (Pa) and volume flow (m^3/s).
    fs : float
        Sample rate, Hz.
    calibration : Calibration
        The instrument (bore, air model).
    config : InversionConfig
        Inversion settings; its ``sample_rate`` is set to ``fs``.
    executor : ExecutorConfig, optional
        Local processes (default) or Dask.
    windows : WindowPlan, sequence of int or DataFrame
        The windows to invert (:class:`mpipe.inversion.whole_take.tracking.WindowPlan`: first
        samples,
        each window's note, which are steady), their first samples only (one note), or the
        conditioning stage's plan table (its ``invert`` rows). Each note gets its own cold
        start; the temperature is fitted on steady windows where a note has enough.
    temperature_c : ndarray, float or None
        The temperature the signals carry, degC (the separation's, per sample); None: the
        calibration's.
    options : RunOptions, optional
        Progress bar, Dask client, checkpoint folder and the reasons found before the
        inversion why the take should not pass (e.g. a calibration other than the take's
        own), kept first among its checks
        (:class:`mpipe.inversion.whole_take.tracking.RunOptions`).
    front_end : FrontEnd, optional
        The front end's estimate with its SEs: its share of every SE (``<q>_se_frontend``)
        is measured; None leaves that component out.

    Returns
    -------
    TakeInversion

    Raises
    ------
    ValueError
        When the signals are not what a clarinet can produce (a unit error), before any
        window is inverted (:func:`mpipe.inversion.trust.diagnostics.check_plausible`).
    """
    # every matrix of the windows' searches and errors is small: a threaded BLAS only
    # stalls on a busy machine (the pool's workers limit theirs; this covers one worker,
    # the fit's cold start and the take-wide re-fits that run in this process)
    with threadpool_limits(limits=1, user_api="blas"):
        config = dataclasses.replace(config, sample_rate=fs)
        front = take_temperature(temperature_c, calibration)
        carried = temperature_c is not None and (
            isinstance(temperature_c, DiskArray)
            or np.isfinite(np.asarray(temperature_c, float)).any()
        )
        z_c = calibration.bore.entry_impedance(calibration.air_properties(front))
        plan = WindowPlan.of(windows)
        check_plausible(p, u, fs, list(plan.starts), int(round(config.window_s * fs)), z_c)
        zero_mean = detect_zero_mean(u, config.signal, config.zero_mean_ratio)
        executor = executor or ExecutorConfig()
        # a take on disk (DiskArray) stays there: every step below reads only its windows
        p, u = as_signal(p), as_signal(u)
        law, cold = config.contact, {}
        # one pool of workers for the contact law's searches and the take's fit (the
        # window estimator spreads its windows over pools of its own)
        pool = (stage_workers((p, u), executor, _stage_count(executor, options))
                if config.estimator == "take" else contextlib.nullcontext())  # fmt: skip
        with pool:
            if law == "auto":  # the data choose the contact law before anything is fitted
                order = np.argsort(np.asarray(plan.starts), kind="stable")
                steady = None if plan.steady is None else [plan.steady[i] for i in order]
                source = KernelSource(calibration, fs, plan.fingering_map())
                choice = choose_contact(p, u, fs, source, [plan.starts[i] for i in order],
                                        steady, config, zero_mean=zero_mean, t_c=front)  # fmt: skip
                config, law = dataclasses.replace(config, contact=choice.law), choice.law
                cold = {choice.start: choice.outcome}  # the take fit's cold start, reused
            data = TakeData(p, u, fs, calibration, plan, config, zero_mean, cold)
            done = _invert(data, executor, front, carried, front_end, options)
        table = done.tracking.table.assign(contact=law)
        return dataclasses.replace(done, tracking=dataclasses.replace(done.tracking, table=table))


def _stage_count(executor: ExecutorConfig, options: RunOptions | None) -> int:
    """The local workers of the take's fit: 1 on Dask (its tasks run here, one by one)."""
    if (options is not None and options.client is not None) or executor.kind != "local":
        return 1
    return executor.processes


def _invert(data: TakeData, executor, front, carried, front_end, options) -> TakeInversion:
    """:func:`invert_take` once its settings are concrete (the contact law chosen)."""
    extra_checks = tuple(options.checks) if options is not None else ()
    p, u, fs, calibration, plan = data.p, data.u, data.fs, data.calibration, data.windows
    config, zero_mean = data.config, data.zero_mean
    # the fit's cold start and its windows spread over the workers (the same answer)
    if config.estimator == "take":
        run = (executor, _stage_count(executor, options))
        return _invert_jointly(data, front, carried, front_end, extra_checks, run)
    # the paper's per-window fit (estimator: window) at the front end's temperature
    fit = TemperatureFit(front, math.nan, "front end" if carried else "calibration", front)
    source = KernelSource(calibration, fs, plan.fingering_map())
    kernel, air = source.at(fit.temperature_c, plan.starts[0] if plan.starts else None)
    result = _track_fingerings(p, u, fs, source, fit, config, executor, plan, options)
    # the budget: the take-wide components beside the windows' own, then one combination
    table = result.table.assign(kernel_temperature_c=fit.temperature_c,
                                kernel_temperature_se_c=math.nan)  # fmt: skip
    table, shared = shared_components(
        p, u, fs, table, calibration, config, zero_mean=zero_mean, kernel_c=fit.temperature_c,
        front=front_end,
    )  # fmt: skip
    table = rate_errors(table, fs)  # the model's discretisation at fs
    table = combine(table, config.determined_limit)
    openings, _ = reed_openings(table, p, fs, whole=False)  # what the reed did: time shut
    table = pd.concat([table, openings], axis=1)
    checks = take_checks(table, config, cold_starts_agreeing=_first_agreeing(table),
                         extra=extra_checks)  # fmt: skip
    table["take_checks"] = "; ".join(checks)
    return TakeInversion(
        dataclasses.replace(result, table=table), fit, kernel, air, tuple(checks), shared
    )


def _invert_jointly(data, front, carried, front_end, extra_checks, run) -> TakeInversion:
    """The take's joint fit (``inversion.estimator: take``), then the take-wide budget."""
    p, u, fs, calibration, plan = data.p, data.u, data.fs, data.calibration, data.windows
    config, zero_mean = data.config, data.zero_mean
    source = KernelSource(calibration, fs, plan.fingering_map())
    se = None
    if front_end is not None and len(front_end.level_se) and front_end.level_se[0] > 0:
        se = float(front_end.level_se[0])
    if front_end is not None:  # its share through the fit's own system (frontend_joint)
        data = dataclasses.replace(data, front=front_end)
    joint = estimate_take(data, front_c=front, front_se_c=se, carried=carried,
                          executor=run[0], workers=run[1])  # fmt: skip
    fit = joint.temperature
    kernel, air = source.at(fit.temperature_c, plan.starts[0] if plan.starts else None)
    # the calibration's share; the front end's came with the fit (its rows' frontend columns)
    table, shared = shared_components(
        p, u, fs, joint.tracking.table, calibration, config, zero_mean=zero_mean,
        kernel_c=fit.temperature_c, front=None,
    )  # fmt: skip
    shared.update(joint.shared)
    table["kernel_temperature_se_c"] = fit.se_c
    table = rate_errors(table, fs)
    table = combine(table, config.determined_limit)
    openings, _ = reed_openings(table, p, fs, whole=False)
    table = pd.concat([table, openings], axis=1)
    # whether the take's minimum was found is the fit's own test (its runs from two cold
    # starts, joint.checks), not the agreement of one window's short searches
    figures = prior_figures(table, joint.prior)  # how far the fit leans on its prior
    if figures:
        shared["temperature_prior"] = figures
    checks = take_checks(table, config, extra=(*extra_checks, *joint.checks))
    table["take_checks"] = "; ".join(checks)
    tracking = dataclasses.replace(joint.tracking, table=table)
    return TakeInversion(tracking, fit, kernel, air, tuple(checks), shared)


def _track_fingerings(p, u, fs, source, fit, config, executor, plan, options) -> Tracking:
    """:func:`track` on each fingering's windows with its own bore, merged in time order.

    One fingering (the usual take) is one call. With several, each fingering's windows are
    tracked on their bore at the one fitted temperature, each note from its own start;
    the tables are merged by time (``window`` renumbered, histories re-keyed) and each row
    names its ``fingering``.
    """
    anchors = None  # every note gets its own cold start
    names = source.names if plan.fingerings is not None else [""]
    if len(names) == 1:
        kernel, air = source.at(fit.temperature_c, plan.starts[0])
        result = track(p, u, fs, kernel, air.rho, config, executor, windows=plan,
                       anchor=anchors, options=options)  # fmt: skip
        return dataclasses.replace(result, table=result.table.copy().assign(fingering=names[0]))
    parts = []
    for name in names:
        sub = plan.only(name)
        kernel, air = source.at(fit.temperature_c, sub.starts[0])
        opts = options
        if options is not None and options.checkpoint is not None:
            # one checkpoint folder per fingering: the windows are numbered per call
            folder = f"{options.checkpoint}/{name or 'default'}"
            opts = dataclasses.replace(options, checkpoint=folder)
        mine = (
            None
            if anchors is None
            else {g: anchors[g] for g in set(sub.segment_ids) if g in anchors}
        )
        res = track(p, u, fs, kernel, air.rho, config, executor, windows=sub,
                    anchor=mine or None, options=opts)  # fmt: skip
        parts.append(dataclasses.replace(res, table=res.table.copy().assign(fingering=name)))
    return merge_trackings(parts)


def merge_trackings(parts: Sequence[Tracking]) -> Tracking:
    """Trackings of disjoint windows as one, in time order."""
    tables, histories, corr = [], {}, []
    for k, part in enumerate(parts):
        t = part.table.copy()
        t["_old"], t["_part"] = t["window"], k
        tables.append(t)
    table = pd.concat(tables, ignore_index=True).sort_values("t_start_s", kind="stable")
    table = table.reset_index(drop=True)
    table["window"] = np.arange(len(table))
    new = {
        (int(k), int(old)): int(w)
        for k, old, w in zip(table["_part"], table["_old"], table["window"], strict=True)
    }
    for k, part in enumerate(parts):
        histories.update({new[(k, int(i))]: h for i, h in part.histories.items()})
        c = part.correlations.copy()
        if len(c):
            c["window"] = [new[(k, int(i))] for i in c["window"]]
        corr.append(c)
    correlations = pd.concat(corr, ignore_index=True).sort_values("t_start_s", kind="stable")
    table = table.drop(columns=["_old", "_part"])
    return Tracking(table, histories, parts[0].zero_mean, correlations.reset_index(drop=True))


def _first_agreeing(table) -> int | None:
    """The least agreement of the take's own cold starts (one per note), if it had any."""
    if "cold_starts_agreeing" not in table:
        return None
    own = table["warm"].eq(False) if "warm" in table else pd.Series(True, index=table.index)
    values = table.loc[own, "cold_starts_agreeing"].dropna()
    return int(values.min()) if len(values) else None


__all__ = ["RunOptions", "TakeInversion", "WindowPlan", "invert_take", "merge_trackings"]
