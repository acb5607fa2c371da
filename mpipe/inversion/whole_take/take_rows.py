"""The take's joint fit as the windows table: each window's values and one covariance.

Every window's row of :func:`mpipe.inversion.whole_take.estimator.fit_take` carries its fast
controls, its note's reed constants and the take's temperature, with standard errors from
the one sandwich covariance of the whole fit
(:meth:`mpipe.inversion.pooling.take_system.TakeSystem.covariance`): each window's noise
gram measured at its note's harmonics as in the paper's per-window fit
(:func:`mpipe.inversion.trust.uncertainty.residual_grams`), the prior's information for
the temperature.

**The budget's columns.** A window's joint covariance over (its reed parameters, T) is split
exactly into the part the temperature explains and the rest: with ``c`` the reed
parameters' covariance with T and ``v`` T's variance, ``C = (C - c c^T / v) + c c^T / v``.
The first is the within-take ``noise`` component (the reed parameters as if T were known),
the second the ``temperature`` component; they add up to the joint covariance, so the
budget's root sum of squares (:mod:`mpipe.inversion.trust.budget`) gives back the joint
SE. The model-form component is the same sandwich with each window's model-form gram.
"""

from __future__ import annotations

import math

import numpy as np

from mpipe.inversion.settings import InversionConfig
from mpipe.inversion.table.records import typed, window_frame
from mpipe.inversion.table.tables import blank_row
from mpipe.inversion.trust.budget import QUANTITIES, component_column
from mpipe.inversion.trust.status import classify, on_bounds, required_quantities, window_status
from mpipe.inversion.trust.uncertainty import SE_PARAMETERS, Covariance
from mpipe.inversion.trust.window_errors import window_uncertainty
from mpipe.inversion.whole_take.estimator import TakeFit
from mpipe.reed.parameters import ReedParameters

#: What the estimator is called in the table's ``optimiser`` column.
ESTIMATOR = "take"


def take_covariances(fit: TakeFit):
    """The fit's noise and model-form covariances.

    Returns
    -------
    (TakeCovariance, TakeCovariance or None)
        The noise sandwich (the prior's information included) and the model-form one
        (None when a window has no period to measure it at).
    """
    w2 = fit.weight**2
    system = fit.system()
    zero = np.zeros_like(system.prior_information)
    # the prior is the front end's temperature: its variance is the front end's share
    moved = fit.frontend is not None and fit.frontend.prior_moved
    cov = system.covariance(np.array([w2 * r["gram"] for r in fit.records]),
                            prior_information=zero if moved else None)  # fmt: skip
    if any(r["excess"] is None for r in fit.records):
        return cov, None
    model = system.covariance(np.array([w2 * r["excess"] for r in fit.records]),
                              prior_information=zero)  # fmt: skip
    return cov, model


def _split(full: np.ndarray, p: int) -> tuple[np.ndarray, np.ndarray, float]:
    """(reed parameters given T, T's share of them, T's variance) of a (p+1)-square cov."""
    theta, c, v = full[:p, :p], full[:p, p], float(full[p, p])
    share = np.outer(c, c) / v if v > 0 else np.zeros((p, p))
    return 0.5 * ((theta - share) + (theta - share).T), share, v


def window_rows(fit: TakeFit, base: ReedParameters, config: InversionConfig, fs: float):
    """The windows table of the take's fit (see the module docstring), classified.

    Parameters
    ----------
    fit : TakeFit
        The take's joint fit.
    base : ReedParameters
        The fixed parameters' values (the cold start's reed).
    config : InversionConfig
        Inversion settings (the determined limit, the contact law, bounds' tolerance).
    fs : float
        Sample rate, Hz.

    Returns
    -------
    (pandas.DataFrame, float, list)
        The table in time order, the temperature's standard error (degC), and each
        window's correlation of its searched parameters (their ln, the joint covariance's,
        T's share included) as ``(t_start_s, names, matrix)``.
    """
    cov, cov_model = take_covariances(fit)
    figures = fit.records
    p = len(fit.names)
    n = int(round(config.window_s * fs))
    closure = config.law == "closure"
    rows, t_se, correlations = [], math.nan, []
    front_t = fit.frontend.temperature_se() if fit.frontend is not None else 0.0
    order = [fit.names.index(name) for name in config.search_parameters]
    for i, q in enumerate(fit.problems):
        reed = fit.reed(i, base, closure)
        full = cov.window(i)
        theta, share, v = _split(full, p)
        correlations.append((q.start / fs, tuple(config.search_parameters),
                             _correlation(full[np.ix_(order, order)])))  # fmt: skip
        t_se = math.sqrt(v + front_t**2) if v > 0 else math.nan
        model = None if cov_model is None else _split(cov_model.window(i), p)[0]
        row = blank_row(q.start, n, fs, config, cold=False)
        row.update(_fit_columns(fit, i, reed, config, figures[i]))
        invalid = {h.split("=")[0]: "estimate on a bound" for h in row["at_bound"].split(";") if h}
        null = cov.window_null(i)[:, :p]
        common = dict(names=fit.names, null=null, singular_values=np.array([]), n=int(n),
                      sigma=figures[i]["sigma"], tau=figures[i]["tau"],
                      n_eff=figures[i]["n_eff"], dof=figures[i]["dof"])  # fmt: skip
        residuals = {k: figures[i].get(k, math.nan) for k in ("noise_residual", "model_residual")}
        values = {name: float(getattr(reed, name)) for name in SE_PARAMETERS}
        kw = dict(z_c=float(fit.z0[i]), rho=float(fit.rho[i]), limit=config.determined_limit,
                  scale_gauge=None if config.law == "fixed" else "lam", invalid=invalid,
                  alpha=config.alpha)  # fmt: skip
        row.update(window_uncertainty(Covariance(cov=theta, cov_model=model, **common,
                                                 **residuals), values, **kw))  # fmt: skip
        by_t = window_uncertainty(Covariance(cov=share, **common), values, **kw)
        for name in QUANTITIES:
            row[component_column(name, "temperature")] = by_t[component_column(name, "noise")]
        if fit.frontend is not None:  # the front end's share (its shifts' outer products)
            by_f = window_uncertainty(Covariance(cov=fit.frontend.window(i)[:p, :p], **common),
                                      values, **kw)  # fmt: skip
            for name in QUANTITIES:
                row[component_column(name, "frontend")] = by_f[component_column(name, "noise")]
        row["kernel_temperature_c"], row["kernel_temperature_se_c"] = fit.temperature_c, t_se
        row["drawn_noise_residual"] = figures[i].get("drawn_noise_residual", math.nan)
        row["pooled"] = ";".join(fit.names[fit.sizes.fast :])  # shared by the note's windows
        row["informs_note"] = bool(q.informs)  # False: fitted given them (two stages)
        row["status"], row["status_reason"] = window_status(row, required_quantities(config))
        rows.append(row)
    table = window_frame(rows)
    return typed(classify(table, config, [q.note for q in fit.problems])), t_se, correlations


def _correlation(cov: np.ndarray) -> np.ndarray:
    """Correlation matrix of a covariance (NaN where a variance is zero)."""
    d = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    with np.errstate(divide="ignore", invalid="ignore"):
        c = cov / np.outer(d, d)
    return np.where(np.outer(d, d) > 0, c, np.nan)


def _fit_columns(fit: TakeFit, i: int, reed: ReedParameters, config, figures) -> dict:
    """Window i's values, residual figures, convergence and bounds."""
    q = fit.problems[i]
    values = {name: float(getattr(reed, name)) for name in SE_PARAMETERS}
    free = {name: values[name] for name in config.search_parameters}
    order = [fit.names.index(name) for name in config.search_parameters]
    hits = on_bounds(free, q.bounds[order], config)
    out = dict(values, alpha=float(reed.alpha))
    out.update(
        f2=figures["f2"],
        relative_residual=figures["relative_residual"],
        optimiser=ESTIMATOR,
        optimiser_converged=fit.converged,
        optimiser_message=f"take fit of {len(fit.problems)} windows: {fit.message}",
        at_bound=";".join(hits),
        n_iterations=fit.n_steps,
        n_evaluations=figures["runs"],
        error="",
    )
    out.update(figures["playing"])
    return out


__all__ = ["ESTIMATOR", "take_covariances", "window_rows"]
