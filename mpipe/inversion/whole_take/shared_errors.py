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
  the implicit function theorem, the kernel temperature re-fitted through its shared row.
  ``d ln q`` per SE, median over the windows, added in quadrature over theta. The
  re-separation of the whole take with warm re-fits (:func:`frontend_refit`) is the
  reference it was checked against.
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
from mpipe.inversion.trust.combinations import COMBINATION_NAMES, combination_values
from mpipe.inversion.trust.uncertainty import SE_PARAMETERS
from mpipe.inversion.whole_take import frontend_propagation as fp
from mpipe.inversion.whole_take.cold_starts import cold_fit
from mpipe.inversion.whole_take.front_end import FrontEnd
from mpipe.measurement.calibration import Calibration
from mpipe.measurement.separation.perturbation import reseparate
from mpipe.measurement.translation import translate
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
#: Half-spacing of the kernel temperatures of the re-fit, degC (the linear propagation's).
KERNEL_STEP_C = fp.KERNEL_STEP_C


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


def _logs(refit: _Refit, p, u, t: float) -> tuple[float, np.ndarray]:
    """``R`` (Pa^2) and ``ln q`` (windows x quantities) of the windows re-fitted at ``t`` degC."""
    total, logs = 0.0, []
    names = list(refit.names) or [""] * len(refit.starts)
    source = KernelSource(refit.calibration, refit.fs, built=refit.kernels)  # the same kernels
    for start, warm, name in zip(refit.starts, refit.warm, names, strict=True):
        kernel, air = refit.kernel(t, name)
        # the re-fit's estimate and F2 only (no standard errors)
        out = cold_fit(p, u, refit.fs, source, start, name, t, refit.config, refit.zero_mean,
                       warm)  # fmt: skip
        if out.reed is None or not math.isfinite(out.row["f2"]):
            # this window's re-fit failed: its row is NaN (left out of the median over
            # windows, never a zero change) and the summed residual has no minimum
            total = math.nan
            logs.append(np.full(len(QUANTITIES), np.nan))
            continue
        total += float(out.row["f2"]) ** 2
        values = {k: float(getattr(out.reed, k)) for k in (*PARAMETER_NAMES, "y_c")}
        values.update(combination_values(values, kernel.z0, air.rho))
        with np.errstate(divide="ignore", invalid="ignore"):
            logs.append(np.log([values.get(q, math.nan) for q in QUANTITIES]))
    return total, np.array(logs)


def _at_kernel_minimum(refit: _Refit, p, u, t0: float, refit_kernel: bool) -> np.ndarray:
    """``ln q`` per window where the kernel temperature fits these signals best.

    Three kernels ``t0 + (-h, 0, h)``; the windows' ``ln q`` is interpolated (parabola) at
    the vertex of the summed residual, kept within ``2 h`` of ``t0``. Without
    ``refit_kernel``, or without a minimum, at ``t0``.
    """
    if not refit_kernel:
        return _logs(refit, p, u, t0)[1]
    ts = (t0 - KERNEL_STEP_C, t0, t0 + KERNEL_STEP_C)
    runs = [_logs(refit, p, u, t) for t in ts]
    r = np.array([x[0] for x in runs])
    logs = np.stack([x[1] for x in runs])  # (3, windows, quantities)
    d = 0.0
    a = r[0] + r[2] - 2 * r[1]
    if np.all(np.isfinite(r)) and a > 0:
        d = float(np.clip(0.5 * (r[0] - r[2]) / a, -2.0, 2.0))  # vertex, in steps of h
    # Lagrange weights of the three points at offset d (in units of h)
    w = np.array([0.5 * d * (d - 1), 1 - d * d, 0.5 * d * (d + 1)])
    return np.tensordot(w, logs, axes=1)


def frontend_refit(
    p: np.ndarray,
    u: np.ndarray,
    calibration: Calibration,
    front: FrontEnd,
    refit: _Refit,
    *,
    kernel_c: float,
    refit_kernel: bool,
) -> dict[str, np.ndarray]:
    """``d ln q`` per SE of each front-end parameter by re-separation and warm re-fits.

    The reference method (slow: the whole take re-separated and re-translated for each
    parameter, every window re-fitted at three kernel temperatures each time); the budget
    uses :func:`frontend_linear`, which agrees with it (the tests compare them).

    Returns
    -------
    dict
        Front-end parameter name -> array over :data:`QUANTITIES` (only the parameters with
        a positive, finite SE).
    """
    fs = refit.fs
    base_p, base_u = _translated(front.p0, front.u0, fs, calibration, front, 0.0)
    base = _at_kernel_minimum(refit, p, u, kernel_c, refit_kernel)
    out = {}
    for j, name in enumerate(FRONTEND_NAMES):
        se = float(front.level_se[j])
        if not (math.isfinite(se) and se > 0):
            continue
        moved = np.array(front.level, dtype=float)
        moved[j] += se
        p0, u0 = reseparate(front.p0, front.u0, fs, calibration, front.level, moved,
                            front.band_hz)  # fmt: skip
        dt = se if name == "temperature" else 0.0
        tp, tu = _translated(p0, u0, fs, calibration, front, dt)
        logs = _at_kernel_minimum(refit, p + tp - base_p, u + tu - base_u, kernel_c, refit_kernel)
        out[name] = _median_over_windows(logs - base)
    return out


def _median_over_windows(d: np.ndarray) -> np.ndarray:
    """Median over the windows (rows) of their finite changes; NaN where none is finite."""
    out = np.full(d.shape[1], np.nan)
    for j in range(d.shape[1]):
        col = d[:, j][np.isfinite(d[:, j])]
        if col.size:
            out[j] = float(np.median(col))
    return out


def frontend_linear(
    p,
    u,
    calibration: Calibration,
    front: FrontEnd,
    refit: _Refit,
    *,
    kernel_c: float,
    refit_kernel: bool,
    kernel_shifts: dict | None = None,
) -> dict[str, np.ndarray]:
    """``d ln q`` per SE of each front-end parameter, propagated linearly on the windows' spans.

    :mod:`mpipe.inversion.whole_take.frontend_propagation`: dp, du over each window's span,
    one Jacobian and one residual per perturbation per window, the kernel temperature
    re-fitted through its shared column. Reads p, u, p0, u0 around the windows only.

    ``kernel_shifts``, when given, receives the kernel temperature's shift (degC) per SE of
    each front-end parameter (``refit_kernel``): the front end's share of the take's
    temperature.

    Returns
    -------
    dict
        As :func:`frontend_refit`.
    """
    fs, config = refit.fs, refit.config
    spans = fp.Spans.of(front, calibration, fs)
    n = int(round(config.window_s * fs))
    lead = int(round(config.lead_s * fs))
    names = list(refit.names) or [""] * len(refit.starts)
    offsets = (-fp.KERNEL_STEP_C, 0.0, fp.KERNEL_STEP_C) if refit_kernel else (0.0,)
    windows, airs = [], []
    for start, warm, name in zip(refit.starts, refit.warm, names, strict=True):
        built = {dt: refit.kernel(kernel_c + dt, name) for dt in offsets}
        keep = max(max(k.n_taps for k, _ in built.values()), lead, 2, n)
        a, b = max(start - keep, 0), start + n
        changes = fp.span_changes(front, calibration, fs, spans, a, b)
        lin = fp.linearise(
            np.asarray(p[a:b], dtype=float), np.asarray(u[a:b], dtype=float), fs, start, warm,
            lambda dt, built=built: built[dt][0] if dt in built else None, config, changes,
            zero_mean=refit.zero_mean, span_start=a,
        )  # fmt: skip
        if lin is not None:
            windows.append(lin)
            airs.append({dt: (k.z0, air.rho) for dt, (k, air) in built.items()})
    out = {}
    closure = config.law == "closure"
    for j, name in enumerate(FRONTEND_NAMES):
        se = float(front.level_se[j])
        if not (math.isfinite(se) and se > 0) or not windows:
            continue
        dlnx, dt = fp.shifts(windows, name, len(config.search_parameters))
        if kernel_shifts is not None and refit_kernel:
            kernel_shifts[name] = float(dt)
        logs = [
            fp.log_changes(w, d, config.search_parameters, (z[0.0], _between(z, dt)), closure)
            for w, d, z in zip(windows, dlnx, airs, strict=True)
        ]
        out[name] = np.nanmedian(np.array(logs), axis=0)
    return out


def _between(z: dict, dt: float) -> tuple[float, float]:
    """``(z0, rho)`` at the kernel temperature moved by ``dt`` degC, linear in ``dt``."""
    if dt == 0.0 or len(z) < 3:
        return z[0.0]
    h = fp.KERNEL_STEP_C
    lo, hi = z[-h], z[h]
    return tuple(c + dt * (b - a) / (2 * h) for c, a, b in zip(z[0.0], lo, hi, strict=True))


def _translated(p0, u0, fs, calibration, front: FrontEnd, dt: float):
    temps = np.asarray(front.temperature_c, dtype=float) + dt
    # quiet: the separation stage said the translation once; this repeats it per quantity
    tr = translate(p0, u0, fs, calibration, front.translation, temps, quiet=True)
    return tr.p, tr.u


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
    refit_kernel: bool,
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
    refit_kernel : bool
        The kernel temperature was fitted: re-fit it on the perturbed signals too.
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
    kernel_shifts: dict = {}
    sens = frontend_linear(p, u, calibration, front, refit, kernel_c=kernel_c,
                           refit_kernel=refit_kernel, kernel_shifts=kernel_shifts)  # fmt: skip
    if kernel_shifts:
        record["frontend_kernel_shift_c"] = kernel_shifts
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
    "KERNEL_STEP_C",
    "QUANTITIES",
    "SCALE_EXPONENTS",
    "calibration_columns",
    "failed_refits",
    "frontend_columns",
    "frontend_linear",
    "frontend_refit",
    "sensitivity_se_db",
    "shared_components",
]
