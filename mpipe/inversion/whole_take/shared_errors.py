"""Errors shared by every window of a take: the front end's and the microphones' calibration.

Two take-wide components of the uncertainty budget (docs/uncertainty.md), each written per
window as ``<q>_se_<component>`` (same unit as q) for every parameter and combination:

- ``calibration``: a common error ``a`` of the microphones' sensitivity scales p and u
  alike. The reed model with the contact point held is invariant under
  ``p, u, p_m, k, S, m, k_c -> a (...)``, ``lam -> sqrt(a) lam``, ``y_m, g, y_c`` unchanged
  (:data:`SCALE_EXPONENTS`, derived in the docs), so ``se(ln q) = |e_q| se(ln a)``, with
  ``se(ln a) = ln(10) / 20 * se_dB`` the reference microphone's stated sensitivity
  uncertainty (:func:`sensitivity_se_db`). Only a stated uncertainty enters the budget.
  When the calibration states none, nothing measured bounds the absolute scale: the
  component is absent, and the typical uncertainty of a calibrator
  (:data:`ASSUMED_SENSITIVITY_SE_DB`) goes to a column of its own, ``<q>_se_scale``, outside
  ``<q>_se`` (issue 38: an unstated calibration added 1.73 % of p_m to every window).
- ``frontend``: the separation's take-level estimate of theta (temperature, losses, Mach
  number, position of the middle microphone) has standard errors. Each is propagated
  linearly on the windows' own spans (:func:`frontend_linear`,
  :mod:`mpipe.inversion.whole_take.frontend_propagation`): the change of p, u over a few ok
  windows' spans for theta moved by one SE, and the shift of each window's minimum by
  the implicit function theorem, on the kernel at the front end's temperature.
  ``d ln q`` per SE, median over the windows, added in quadrature over theta. (The take's
  joint fit carries the front end's share through its own system instead,
  :mod:`mpipe.inversion.whole_take.frontend_joint`.)
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from mpipe.inversion.preparation.kernel import KernelSource
from mpipe.inversion.preparation.segments import pick_windows
from mpipe.inversion.settings import PARAMETER_NAMES, InversionConfig
from mpipe.inversion.trust.combinations import COMBINATION_NAMES
from mpipe.inversion.trust.uncertainty import SE_PARAMETERS
from mpipe.inversion.whole_take import frontend_propagation as fp
from mpipe.inversion.whole_take.front_end import FrontEnd
from mpipe.measurement.calibration import Calibration
from mpipe.reed.parameters import ReedParameters

logger = logging.getLogger(__name__)

#: Quantities with take-wide components.
QUANTITIES = (*SE_PARAMETERS, *COMBINATION_NAMES)
#: d ln q / d ln a for a common scale a of p and u, the contact point y_c held.
SCALE_EXPONENTS = {"k": 1.0, "S": 1.0, "y_m": 0.0, "p_m": 1.0, "m": 1.0, "g": 0.0,
                   "lam": 0.5, "k_c": 1.0, "y_c": 0.0, "p_M": 1.0, "gamma": 0.0,
                   "zeta": 0.0, "f_r": 0.0, "Q_r": 0.0}  # fmt: skip
#: The typical standard uncertainty of a microphone calibrated with a pistonphone or sound
#: calibrator, dB (0.1-0.2 dB stated by such calibrators): reported as ``<q>_se_scale`` when
#: the calibration states none, never added to ``<q>_se``.
ASSUMED_SENSITIVITY_SE_DB = 0.15
#: Names of the front end's parameters, in the order of :class:`FrontEnd`'s arrays (one
#: definition, the linear propagation's).
FRONTEND_NAMES = fp.FRONTEND_NAMES
#: Ok windows the front end's sensitivity is measured on.
FRONTEND_WINDOWS = 6


def sensitivity_se_db(calibration: Calibration) -> tuple[float, str]:
    """Stated standard uncertainty of the take's common sensitivity scale, dB, and its source.

    The reference microphone's (the first: relative calibrations are against it) stated
    ``sensitivity_se_db``; NaN when it states none (the source says so).
    """
    stated = getattr(calibration.microphones[0], "sensitivity_se_db", None)
    if stated is None:
        return math.nan, (
            "not stated in the calibration file: the absolute scale is not in the error bars; "
            f"a calibrator's typical {ASSUMED_SENSITIVITY_SE_DB:g} dB is in <q>_se_scale"
        )
    return float(stated), "calibration file"


def calibration_columns(
    table: pd.DataFrame, se_db: float, component: str = "calibration"
) -> pd.DataFrame:
    """``<q>_se_<component>`` = ``|q| |e_q| ln(10)/20 se_db`` for every quantity present.

    ``component`` is ``calibration`` for a stated uncertainty (a budget component) and
    ``scale`` for the assumed one of an unstated calibration (its own column, outside the
    combined SE).
    """
    out = table.copy()
    se_ln = math.log(10.0) / 20.0 * se_db
    for name in QUANTITIES:
        if name in out:
            x = pd.to_numeric(out[name], errors="coerce").to_numpy(dtype=float)
            out[f"{name}_se_{component}"] = np.abs(x) * abs(SCALE_EXPONENTS[name]) * se_ln
    return out


def _reed(row) -> ReedParameters:
    return ReedParameters(**{k: float(row[k]) for k in (*PARAMETER_NAMES, "y_c", "alpha")})


@dataclass(frozen=True)
class _Refit:
    """Inputs of the windows' warm re-fits."""

    fs: float
    calibration: Calibration
    config: InversionConfig
    zero_mean: bool
    starts: Sequence[int]
    warm: Sequence[ReedParameters]
    kernels: dict = dataclasses.field(default_factory=dict)  # (T degC, fingering) -> (k, air)
    names: Sequence[str] = ()  # each window's fingering ("" or none: the calibration's)

    def kernel(self, t: float, name: str = ""):
        """The bore kernel and air at ``t`` degC of a fingering, built once each."""
        return KernelSource(self.calibration, self.fs, built=self.kernels).named(t, name)


def frontend_linear(
    p,
    u,
    calibration: Calibration,
    front: FrontEnd,
    refit: _Refit,
    *,
    kernel_c: float,
) -> dict[str, np.ndarray]:
    """``d ln q`` per SE of each front-end parameter, propagated linearly on the windows' spans.

    :mod:`mpipe.inversion.whole_take.frontend_propagation`: dp, du over each window's span,
    one Jacobian and one residual per perturbation per window, on the kernel at
    ``kernel_c`` degC (held: the per-window fit's temperature is the front end's). Reads p,
    u, p0, u0 around the windows only.

    Returns
    -------
    dict
        Front-end parameter name -> array over :data:`QUANTITIES` (only the parameters with
        a positive, finite SE).
    """
    fs, config = refit.fs, refit.config
    spans = fp.Spans.of(front, calibration, fs)
    n = int(round(config.window_s * fs))
    lead = int(round(config.lead_s * fs))
    names = list(refit.names) or [""] * len(refit.starts)
    windows, airs = [], []
    for start, warm, name in zip(refit.starts, refit.warm, names, strict=True):
        kernel, air = refit.kernel(kernel_c, name)
        keep = max(kernel.n_taps, lead, 2, n)
        a, b = max(start - keep, 0), start + n
        changes = fp.span_changes(front, calibration, fs, spans, a, b)
        lin = fp.linearise(
            np.asarray(p[a:b], dtype=float), np.asarray(u[a:b], dtype=float), fs, start, warm,
            lambda dt, kernel=kernel: kernel if dt == 0.0 else None, config, changes,
            zero_mean=refit.zero_mean, span_start=a,
        )  # fmt: skip
        if lin is not None:
            windows.append(lin)
            airs.append((kernel.z0, air.rho))
    out = {}
    closure = config.law == "closure"
    for j, name in enumerate(FRONTEND_NAMES):
        se = float(front.level_se[j])
        if not (math.isfinite(se) and se > 0) or not windows:
            continue
        dlnx, _ = fp.shifts(windows, name, len(config.search_parameters))
        logs = [
            fp.log_changes(w, d, config.search_parameters, (z, z), closure)
            for w, d, z in zip(windows, dlnx, airs, strict=True)
        ]
        out[name] = np.nanmedian(np.array(logs), axis=0)
    return out


def frontend_columns(
    table: pd.DataFrame, sensitivity: dict[str, np.ndarray], correlation: np.ndarray | None = None
) -> pd.DataFrame:
    """``<q>_se_frontend`` = ``|q| sqrt(d^T R d)`` per window, d the ``d ln q`` per SE of theta.

    ``correlation``: R over the parameters of ``sensitivity`` in its order
    (:meth:`FrontEnd.correlation`; None: the identity, a root sum of squares).

    A sensitivity that is not finite (every re-fit of that parameter failed) makes the
    component NaN, not measured, for that quantity: mpipe <= 0.5 left it out of the sum,
    counting a failed re-fit as no effect at all (issue 38). :func:`failed_refits` names
    such parameters for the record.
    """
    out = table.copy()
    for i, name in enumerate(QUANTITIES):
        if name not in out:
            continue
        d = np.array([s[i] for s in sensitivity.values()], dtype=float)
        r = np.eye(d.size) if correlation is None else correlation
        rel = float(np.sqrt(max(d @ r @ d, 0.0))) if np.all(np.isfinite(d)) else math.nan
        x = pd.to_numeric(out[name], errors="coerce").to_numpy(dtype=float)
        out[f"{name}_se_frontend"] = np.abs(x) * rel
    return out


def failed_refits(sensitivity: dict[str, np.ndarray]) -> list[str]:
    """The front-end parameters whose re-fits failed for some quantity (not measured)."""
    return [name for name, d in sensitivity.items() if not np.all(np.isfinite(d))]


def shared_components(
    p: np.ndarray,
    u: np.ndarray,
    fs: float,
    table: pd.DataFrame,
    calibration: Calibration,
    config: InversionConfig,
    *,
    zero_mean: bool,
    kernel_c: float,
    front: FrontEnd | None = None,
) -> tuple[pd.DataFrame, dict]:
    """The windows table with the calibration's and (with ``front``) the front end's columns.

    ``<q>_se_calibration`` when the calibration states its uncertainty, else
    ``<q>_se_scale`` (outside the budget, see the module docstring); ``<q>_se_frontend``.

    Parameters
    ----------
    p, u : ndarray
        The take's mouthpiece pressure (Pa) and flow (m^3/s).
    fs : float
        Sample rate, Hz.
    table : pandas.DataFrame
        Windows table (parameters of every window; ``status``).
    calibration : Calibration
        The instrument (microphones' sensitivity uncertainty, bore).
    config : InversionConfig
        Inversion settings of the take.
    zero_mean : bool
        The flow is zero-mean.
    kernel_c : float
        The kernel temperature, degC.
    front : FrontEnd, optional
        The front end's estimate; None: no ``frontend`` component (absent).

    Returns
    -------
    (table, record)
        ``record``: ``sensitivity_se_db``, its source, and per front-end parameter its SE
        and the relative effect on p_m, p_M, gamma and zeta (JSON-ready).
    """
    se_db, source = sensitivity_se_db(calibration)
    if math.isnan(se_db):
        out = calibration_columns(table, ASSUMED_SENSITIVITY_SE_DB, "scale")
    else:
        out = calibration_columns(table, se_db)
    record: dict = {"sensitivity_se_db": None if math.isnan(se_db) else se_db,
                    "sensitivity_se_source": source}  # fmt: skip
    ok = table[table["status"].astype(str) == "ok"] if "status" in table else table
    if front is None or not len(ok):
        return out, record
    rows = [ok.iloc[i] for i in pick_windows(range(len(ok)), FRONTEND_WINDOWS)]
    starts = [int(round(float(r["t_start_s"]) * fs)) for r in rows]
    names = [str(r.get("fingering", "") or "") for r in rows]
    refit = _Refit(fs, calibration, config, zero_mean, starts, [_reed(r) for r in rows],
                   names=names)  # fmt: skip
    sens = frontend_linear(p, u, calibration, front, refit, kernel_c=kernel_c)
    failed = failed_refits(sens)
    if failed:
        logger.warning("front-end component not measured: the propagation of %s failed (NaN)",
                       ", ".join(failed))  # fmt: skip
        record["frontend_failed"] = failed
    record["frontend"] = {
        name: {
            "se": float(front.level_se[FRONTEND_NAMES.index(name)]),
            **{f"dln_{q}": float(d[QUANTITIES.index(q)]) for q in ("p_m", "p_M", "gamma", "zeta")},
        }
        for name, d in sens.items()
    }
    return frontend_columns(out, sens, front.correlation(list(sens))), record


__all__ = [
    "ASSUMED_SENSITIVITY_SE_DB",
    "FRONTEND_NAMES",
    "FRONTEND_WINDOWS",
    "QUANTITIES",
    "SCALE_EXPONENTS",
    "calibration_columns",
    "failed_refits",
    "frontend_columns",
    "frontend_linear",
    "sensitivity_se_db",
    "shared_components",
]
