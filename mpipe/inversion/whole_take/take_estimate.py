"""``inversion.estimator: take``: the take's joint fit as :func:`invert_take` reports it.

Runs :func:`mpipe.inversion.whole_take.estimator.fit_take` and gives what the per-window
path gives: the windows table (:mod:`mpipe.inversion.whole_take.take_rows`), the one
temperature of the take as a :class:`mpipe.inversion.whole_take.temperature.TemperatureFit`
(``source = "take fit"``), and the bore at that temperature.

**The temperature's prior.** The front end's estimate of the take's air temperature with
its standard error (the wave separation's take-level theta, ``FrontEnd.level``), when it
measured one; otherwise the calibration's temperature with :data:`PRIOR_SE_C`, a weak prior
(the playing determines the bore's temperature to a few hundredths of a degree on the
shipped instrument, so it only keeps the fit within the air of a room).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from dataclasses import dataclass

import numpy as np
import pandas as pd

from mpipe.inversion.table.tables import blank_row
from mpipe.inversion.trust.window_errors import CORRELATION_COLUMNS, correlation_records
from mpipe.inversion.whole_take.estimator import TakeData
from mpipe.inversion.whole_take.frontend_joint import record as frontend_record
from mpipe.inversion.whole_take.prior_conflict import PriorMoves, prior_moves
from mpipe.inversion.whole_take.rivals import RIVAL_MARGIN
from mpipe.inversion.whole_take.take_fit import fit_take
from mpipe.inversion.whole_take.take_rows import window_rows
from mpipe.inversion.whole_take.temperature import TemperatureFit
from mpipe.inversion.whole_take.tracking import Tracking, WindowPlan

log = logging.getLogger(__name__)

#: Standard uncertainty of the temperature's prior when the front end measured none, degC
#: (a room's air: not stated by any calibration; wide enough never to decide the fit).
PRIOR_SE_C = 5.0


@dataclass(frozen=True)
class JointResult:
    """What the take's joint fit gives :func:`mpipe.inversion.whole_take.take.invert_take`.

    Attributes
    ----------
    tracking : Tracking
        The windows table (no step-2 histories, no correlation table).
    temperature : TemperatureFit
        The take's one temperature and its SE.
    checks : tuple of str
        The fit's own reasons why the take should not pass (:func:`rival_checks`).
    shared : dict
        The front end's share for the run's record (``frontend``: per parameter its SE and
        the solution's median shift; ``frontend_failed``), empty without a front end.
    prior : PriorMoves, optional
        The temperature prior's conflict with the data and the results' moves without it,
        for the record against the finished table's SEs
        (:func:`mpipe.inversion.whole_take.prior_conflict.prior_figures`); None when the
        prior is no measurement (the calibration's temperature).
    """

    tracking: Tracking
    temperature: TemperatureFit
    checks: tuple[str, ...] = ()
    shared: dict = dataclasses.field(default_factory=dict)
    prior: PriorMoves | None = None


def rival_checks(rivals) -> tuple[str, ...]:
    """A reason when the take's fit found two minima its data barely tell apart.

    ``rivals``: the cost of each run (:attr:`TakeFit.rivals`); the lowest is the estimate.
    """
    costs = np.sort(np.asarray(rivals, float))
    if costs.size < 2 or not costs[1] - costs[0] < RIVAL_MARGIN:
        return ()
    return (f"the take's fit from its cold starts ended in two minima whose costs differ "
            f"by {costs[1] - costs[0]:.2g} (< {RIVAL_MARGIN:g}, chi-square units): the data "
            "barely prefer the one reported",)  # fmt: skip


def temperature_prior(front_c: float, front_se_c: float | None) -> tuple[float, float]:
    """The prior on the take's temperature: mean and standard error, degC."""
    if front_se_c is not None and math.isfinite(front_se_c) and front_se_c > 0:
        return float(front_c), float(front_se_c)
    return float(front_c), PRIOR_SE_C


def estimate_take(
    data: TakeData, *, front_c: float, front_se_c: float | None, carried: bool,
    executor=None, workers: int = 1,
) -> JointResult:  # fmt: skip
    """The take's joint fit and its table (see the module docstring).

    Parameters
    ----------
    data : TakeData
        The take's signals, its windows and the settings.
    front_c : float
        The temperature the signals carry (or the calibration's), degC.
    front_se_c : float or None
        Its standard error, degC (None: not measured).
    carried : bool
        The signals carried a temperature (the front end's), not the calibration's.
    executor : ExecutorConfig, optional
        Where the cold start's searches run.
    workers : int
        Worker processes the windows are spread over.
    """
    fs, plan, config = data.fs, data.windows, data.config
    prior = temperature_prior(front_c, front_se_c if carried else None)
    reach = config.temperature_range_c
    clock = time.perf_counter()
    fit, cold, cold_row = fit_take(data, prior=prior, t_range=(front_c - reach, front_c + reach),
                                   executor=executor, workers=workers)  # fmt: skip
    table, t_se, correlations = window_rows(fit, cold, config, fs)
    # the fit is one computation: each window is charged its share of its wall time
    table["wall_time_s"] = (time.perf_counter() - clock) / max(len(table), 1)
    table = _with_plan_columns(table, fit, plan, fs, config)
    table = _with_excluded(table, fit, plan, fs, config)
    if len(table) and "cold_starts_agreeing" in cold_row:
        table.loc[table.index[0], "cold_starts_agreeing"] = cold_row["cold_starts_agreeing"]
    agreeing = cold_row.get("cold_starts_agreeing")
    temperature = TemperatureFit(
        temperature_c=fit.temperature_c, se_c=t_se, source="take fit", front_end_c=front_c,
        windows=len(fit.problems),
        note="" if fit.converged else f"the take's fit did not converge: {fit.message}",
        cold_starts_agreeing=None if agreeing is None or agreeing != agreeing else int(agreeing),
    )  # fmt: skip
    # each window's F2 over the take's fit, by its number in the table
    number = {float(t): int(w) for t, w in zip(table["t_start_s"], table["window"], strict=True)}
    histories = {number[q.start / fs]: fit.history[:, i] for i, q in enumerate(fit.problems)}
    records = [row for t, names, matrix in correlations
               for row in correlation_records(number[t], t, names, matrix)]  # fmt: skip
    frame = pd.DataFrame(records, columns=list(CORRELATION_COLUMNS))
    tracking = Tracking(table, histories, data.zero_mean, frame)
    shared = {}
    if fit.frontend is not None:
        shared["frontend"] = frontend_record(fit.frontend, fit.names)
        if fit.frontend.failed:
            log.warning("front-end component not measured: the model cannot play the take "
                        "with %s moved by one SE", ", ".join(fit.frontend.failed))  # fmt: skip
            shared["frontend_failed"] = list(fit.frontend.failed)
    moves = prior_moves(fit, fs) if carried else None
    return JointResult(tracking, temperature, rival_checks(fit.rivals), shared, moves)


def _with_plan_columns(table, fit, plan: WindowPlan, fs: float, config) -> pd.DataFrame:
    """The plan's segment, note number and fingering of every fitted window."""
    by_start = {s: i for i, s in enumerate(plan.starts)}
    idx = [by_start[q.start] for q in fit.problems]
    out = table.copy()
    out["segment"] = [plan.segment_ids[i] for i in idx]
    out["note_number"] = [plan.note_ids[i] for i in idx]
    out["fingering"] = [q.fingering for q in fit.problems]
    return out


def _with_excluded(table, fit, plan: WindowPlan, fs: float, config) -> pd.DataFrame:
    """Rows for the windows the fit left out (failed, with the reason), in time order."""
    if not fit.excluded:
        out = table
    else:
        n = int(round(config.window_s * fs))
        by_start = {s: i for i, s in enumerate(plan.starts)}
        rows = []
        for start, why in fit.excluded.items():
            row = blank_row(start, n, fs, config, cold=False)
            row["error"], row["status_reason"] = why, why
            i = by_start[start]
            row.update(segment=plan.segment_ids[i], note_number=plan.note_ids[i],
                       fingering=(plan.fingerings or ("",) * len(plan.starts))[i])  # fmt: skip
            rows.append(row.as_dict())
        out = pd.concat([table, pd.DataFrame(rows)], ignore_index=True)
    out = out.sort_values("t_start_s", kind="stable").reset_index(drop=True)
    out["window"] = np.arange(len(out))
    return out


__all__ = ["JointResult", "PRIOR_SE_C", "RIVAL_MARGIN", "estimate_take", "rival_checks",
           "temperature_prior"]  # fmt: skip
