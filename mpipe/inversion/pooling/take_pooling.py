"""Every note of a tracked take fitted as one experiment (``inversion.pooling: note``).

Runs after the per-window fit of :func:`mpipe.inversion.whole_take.tracking.track`, on its table,
note
by note in time order (so the result does not depend on the number of workers): each note
(``segment``), cut into stretches of at most ``inversion.pooling_stretch_s``, is fitted by
:func:`mpipe.inversion.pooling.note_fit.fit_note` from the per-window answers:

- the slow parameters start from the median of the stretch's ``ok`` windows (a stretch with
  fewer than :data:`MIN_OK` of them keeps its per-window answers);
- each window's fast parameters start from its own answer when it is ``ok``, else from the
  nearest ``ok`` window's (a window in a wrong basin gets a start in the right one);
- a window without an estimate, or whose model is infeasible at that start, is left out and
  keeps its per-window row.

Each pooled window's row gets the pooled values, its residual figures, and the noise
component of every quantity from the joint covariance (its fast parameters' own, the slow
ones' shared by the stretch); the model-form component is the per-window fit's (the model's
mismatch is the same in every window and does not average away), the take-wide components
are added later, once (:func:`mpipe.inversion.whole_take.take.invert_take`). The statuses are then
classified again (:func:`mpipe.inversion.trust.status.classify`).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable

import numpy as np
import pandas as pd

from mpipe.inversion.fit.history_start import lead_in
from mpipe.inversion.fit.objective import F2Objective, ObjectiveSettings, TargetWindow
from mpipe.inversion.fit.window import window_bounds
from mpipe.inversion.pooling.note_fit import fit_note, note_covariance, split_names
from mpipe.inversion.settings import InversionConfig
from mpipe.inversion.table.records import reed_from_row, typed
from mpipe.inversion.trust.budget import QUANTITIES, combine_row, component_column
from mpipe.inversion.trust.diagnostics import playing_difference
from mpipe.inversion.trust.status import classify, on_bounds, required_quantities, window_status
from mpipe.inversion.trust.uncertainty import Covariance
from mpipe.inversion.trust.window_errors import window_uncertainty
from mpipe.reed.bore_kernel import BoreKernel

log = logging.getLogger(__name__)

#: Fewest ok windows whose median starts a stretch's slow parameters.
MIN_OK = 3


def stretches(times: np.ndarray, length_s: float) -> list[np.ndarray]:
    """Indices of a note's windows (start times ``times``, s, ascending) cut into stretches.

    The note is cut into the fewest equal stretches no longer than ``length_s``.
    """
    if times.size == 0:
        return []
    span = float(times[-1] - times[0])
    count = max(int(math.ceil(span / length_s - 1e-9)), 1)
    edges = times[0] + span * np.arange(1, count) / count
    cut = np.searchsorted(times, edges, side="right")
    return [part for part in np.split(np.arange(times.size), cut) if part.size]


def pool_notes(
    table: pd.DataFrame,
    p: np.ndarray,
    u: np.ndarray,
    fs: float,
    kernel: BoreKernel | Callable[[str], BoreKernel],
    config: InversionConfig,
    *,
    zero_mean: bool,
) -> pd.DataFrame:
    """The windows table with every note's stretches fitted jointly (see the module docstring).

    Parameters
    ----------
    table : pandas.DataFrame
        The per-window table of :func:`mpipe.inversion.whole_take.tracking.track` (``segment``,
        ``status``, the parameters), in time order.
    p, u : ndarray
        Mouthpiece pressure (Pa) and flow (m^3/s) of the take.
    fs : float
        Sample rate, Hz (the kernel's).
    kernel : BoreKernel or callable
        The bore at the fitted temperature, or a function giving the bore of a fingering's
        name (the table's ``fingering`` column; "" the calibration's own bore).
    config : InversionConfig
        Inversion settings.
    zero_mean : bool
        The flow is zero-mean (measured).

    Returns
    -------
    pandas.DataFrame
        A copy, the pooled windows' rows rewritten and ``pooled`` set, classified again.
    """
    out = table.copy()
    if "pooled" not in out:
        out["pooled"] = ""
    segments = out["segment"].to_numpy() if "segment" in out else np.zeros(len(out), int)
    times = out["t_start_s"].to_numpy(float)
    for g in sorted(set(segments.tolist())):
        idx = np.flatnonzero(segments == g)
        idx = idx[np.argsort(times[idx], kind="stable")]
        bore = kernel
        if callable(kernel):  # the note's own fingering
            name = str(out["fingering"].iloc[idx[0]]) if "fingering" in out else ""
            bore = kernel("" if name in ("", "nan") else name)
        for part in stretches(times[idx], config.pooling_stretch_s):
            _pool_stretch(out, idx[part], p, u, fs, bore, config, zero_mean)
    return typed(classify(out, config, list(segments)))


def _starts(rows: pd.DataFrame, names: tuple[str, ...], n_fast: int) -> np.ndarray | None:
    """Start of each window (columns ``names``): see the module docstring; None: too few ok."""
    ok = (rows["status"].astype(str) == "ok").to_numpy()
    if ok.sum() < MIN_OK:
        return None
    values = rows[list(names)].to_numpy(float)
    t = rows["t_start_s"].to_numpy(float)
    ok_t = t[ok]
    start = values.copy()
    for i in np.flatnonzero(~ok):
        start[i, :n_fast] = values[ok][int(np.argmin(np.abs(ok_t - t[i]))), :n_fast]
    start[:, n_fast:] = np.median(values[ok][:, n_fast:], axis=0)
    return start


def _objective(row, start, p, u, fs, kernel, config, zero_mean, names, n):
    """Window ``row``'s objective over the searched parameters, and its bounds (``names``)."""
    s = int(round(float(row["t_start_s"]) * fs))
    # the history the model reads (its lead-in and the bore's taps), as the window fit's:
    # not the take's whole past, which cost 3.6x the memory on a two-note take
    history = lead_in(p, u, s, n, kernel.n_taps, config.lead_s, fs)
    target = TargetWindow(p[s : s + n], u[s : s + n], *history, fs, zero_mean)
    settings = ObjectiveSettings(
        lead_s=config.lead_s, lowpass=config.lowpass.design(fs) if zero_mean else None
    )
    reed = reed_from_row(row)
    obj = F2Objective(kernel, target, settings, reed, config.search_parameters,
                      contact_at_closure=config.contact == "closure")  # fmt: skip
    box = window_bounds(config, p, s, n, fs)
    order = [config.search_parameters.index(name) for name in names]
    bounds = box[order]
    x = np.clip(start, bounds[:, 0] * (1 + 1e-9), bounds[:, 1] * (1 - 1e-9))
    feasible = obj.jacobian(x[np.argsort(order)]) is not None
    return obj, bounds, feasible


def _pool_stretch(out, index, p, u, fs, kernel, config, zero_mean) -> None:
    """Fit one stretch (rows ``index`` of ``out``) jointly and rewrite its rows in place."""
    t0 = time.perf_counter()
    names_fast, names_slow = split_names(config.search_parameters)
    names, n_fast = (*names_fast, *names_slow), len(names_fast)
    rows = out.iloc[index]
    has = rows["error"].astype(str).eq("") & np.isfinite(rows[list(names)].to_numpy(float)).all(1)
    rows, index = rows[has.to_numpy()], index[has.to_numpy()]
    start = _starts(rows, names, n_fast) if len(rows) and n_fast else None
    if start is None:
        return
    n = int(round(config.window_s * fs))
    built = [
        _objective(row, x, p, u, fs, kernel, config, zero_mean, names, n)
        for (_, row), x in zip(rows.iterrows(), start, strict=True)
    ]
    keep = np.array([b[2] for b in built])
    if keep.sum() < MIN_OK:
        return
    objectives = [b[0] for b, k in zip(built, keep, strict=True) if k]
    bounds = np.array([b[1] for b, k in zip(built, keep, strict=True) if k])
    start, index = start[keep], index[keep]
    fit = fit_note(objectives, start, bounds, n_fast)
    pressures = [o.target.p for o in objectives]
    cov, figures = note_covariance(fit, pressures, fs, config.model_form_floor)
    share = (time.perf_counter() - t0) / len(index)
    log.info(
        "pooled %d windows from %.3f s: sum of squares %.4g -> %.4g Pa^2 in %d steps (%s)",
        len(index), float(rows["t_start_s"].iloc[0]), fit.start_cost, fit.cost,
        fit.n_iterations, fit.message,
    )  # fmt: skip
    for i, row_index in enumerate(index):
        row = out.iloc[row_index].to_dict()
        row.update(_pooled_row(row, fit, cov, figures[i], i, bounds[i], objectives[i], config))
        row["wall_time_s"] = float(row.get("wall_time_s") or 0.0) + share
        row["pooled"] = ";".join(names_slow)
        for key, value in row.items():
            out.at[out.index[row_index], key] = value


def _pooled_row(row, fit, cov, figures, i, bounds, objective, config) -> dict:
    """Window i's columns from the note's fit (the model-form components kept from ``row``)."""
    names = fit.names
    x = fit.x[i]
    values = {name: float(v) for name, v in zip(names, x, strict=True)}
    reed = objective.reed(np.array([values[n] for n in objective.free]))
    r = fit.residuals[i]
    pw = objective.target.p
    hits = on_bounds({n: values[n] for n in objective.free}, _free_order(bounds, names,
                     objective.free), config)  # fmt: skip
    at_bound = ";".join(hits)
    invalid = {h.split("=")[0]: "estimate on a bound" for h in hits}
    n_slow = len(names) - fit.n_fast
    null = np.zeros((cov.null.shape[0], len(names)))
    null[:, fit.n_fast :] = cov.null[:, :n_slow]
    covariance = Covariance(
        names=names, cov=cov.window(i), null=null, singular_values=np.array([]),
        sigma=figures["sigma"], n=r.size, tau=r.size / figures["n_eff"],
        n_eff=figures["n_eff"], dof=figures["dof"],
        noise_residual=figures.get("noise_residual", math.nan),
        model_residual=figures.get("model_residual", math.nan),
    )  # fmt: skip
    all_values = {n: float(getattr(reed, n)) for n in ("k", "S", "y_m", "p_m", "m", "g",
                                                      "lam", "k_c", "y_c")}  # fmt: skip
    new = window_uncertainty(
        covariance, all_values, z_c=objective.kernel.z0, rho=objective.kernel.rho,
        limit=config.determined_limit, scale_gauge=None if config.contact == "fixed" else "lam",
        invalid=invalid, alpha=config.alpha,
    )  # fmt: skip
    for q in QUANTITIES:
        col = component_column(q, "model")
        new[col] = row.get(col, math.nan)
    new.update(all_values)
    f2 = float(np.linalg.norm(r))
    new.update(
        f2=f2,
        relative_residual=f2 / (float(np.linalg.norm(pw)) + 1e-300),
        optimiser_converged=fit.converged,
        optimiser_message=f"pooled over {len(fit.x)} windows: {fit.message}",
        at_bound=at_bound,
        n_iterations=fit.n_iterations,
        error="",
    )
    new.update(playing_difference(pw, pw - r, objective.target.fs))
    combine_row(new, config.determined_limit)
    new["status"], new["status_reason"] = window_status({**row, **new}, required_quantities(config))
    return new


def _free_order(bounds: np.ndarray, names, free) -> np.ndarray:
    """``bounds`` (rows ``names``) reordered to ``free``."""
    return bounds[[list(names).index(n) for n in free]]


__all__ = ["MIN_OK", "pool_notes", "stretches"]
