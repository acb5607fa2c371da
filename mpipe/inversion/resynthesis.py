"""Resynthesis: the model driven by each window's estimated parameters, and its plots.

Figures (matplotlib, Agg backend, PNG), after the paper:

- target against resynthesis for p and u (Figs. 9 and 11): :func:`plot_signals`;
- flow against pressure difference with the step-1 fits of both branches (Fig. 8):
  :func:`plot_flow_pressure`;
- objective history of step 2 (Fig. 7): :func:`plot_history`;
- parameter tracks over the take: :func:`plot_tracks`.

References
----------
Chatziioannou & van Walstijn 2012, Figs. 7-9 and 11; physics.md J ("Resynthesis").
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import soundfile

from mpipe.core.io import write_atomic  # noqa: E402
from mpipe.core.units import unit_of
from mpipe.inversion.combinations import COMBINATIONS
from mpipe.inversion.flow_fit import flow_signals  # noqa: E402
from mpipe.inversion.objective import (  # noqa: E402
    ObjectiveSettings,
    TargetWindow,
    run_model,
)
from mpipe.inversion.records import flags  # noqa: E402
from mpipe.inversion.settings import PARAMETER_NAMES, InversionConfig  # noqa: E402
from mpipe.inversion.step1 import (
    Step1Result,  # noqa: E402
    step1,
)
from mpipe.reed.bore_kernel import BoreKernel  # noqa: E402
from mpipe.reed.parameters import ReedParameters  # noqa: E402

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Resynthesis:
    """Resynthesised signals over a take.

    Attributes
    ----------
    fs : float
        Sample rate, Hz.
    p : ndarray
        Resynthesised mouthpiece pressure, Pa; NaN outside the inverted windows.
    u : ndarray
        Resynthesised flow, m^3/s (filtered like the target when it is zero-mean).
    """

    fs: float
    p: np.ndarray
    u: np.ndarray


def reed_from_row(row: pd.Series | dict) -> ReedParameters:
    """Reed parameters of one row of the per-window table."""
    return ReedParameters(**{name: float(row[name]) for name in (*PARAMETER_NAMES, "y_c", "alpha")})


def resynthesise(
    table: pd.DataFrame,
    p: np.ndarray,
    u: np.ndarray,
    fs: float,
    kernel: BoreKernel,
    config: InversionConfig,
    zero_mean: bool,
    progress=None,
) -> Resynthesis:
    """Run the model with each window's parameters and stitch the windows together.

    Each window is run the way step 2 ran it (from its history), so the resynthesis shows
    exactly what F2 compared. Failed windows stay NaN.

    Parameters
    ----------
    table : pandas.DataFrame
        Per-window results of :func:`mpipe.inversion.tracking.track`.
    p, u : ndarray
        Target pressure (Pa) and flow (m^3/s) of the take.
    fs : float
        Sample rate, Hz.
    kernel : BoreKernel
        Prepared bore.
    config : InversionConfig
        Start method and filters.
    zero_mean : bool
        Whether the target flow is zero-mean.
    progress : mpipe.core.progress.ProgressBar, optional
        Counted once per window.

    Returns
    -------
    Resynthesis
    """
    p_out = np.full(len(p), np.nan)
    u_out = np.full(len(p), np.nan)
    settings = ObjectiveSettings(
        lead_s=config.lead_s,
        lowpass=config.lowpass.design(fs) if zero_mean else None,
    )
    for _, row in table.iterrows():
        if progress is not None:
            progress.update(1)
        err = row["error"]
        # a table read back from CSV may hold NaN for "no error"
        if (isinstance(err, str) and err) or not np.isfinite(row["k"]):
            continue
        i0 = int(round(row["t_start_s"] * fs))
        i1 = int(round(row["t_end_s"] * fs))
        target = TargetWindow(p[i0:i1], u[i0:i1], p[:i0], u[:i0], fs, zero_mean)
        try:
            reed = reed_from_row(row)
        except ValueError as exc:
            # one unusable window must not stop the resynthesis of the others
            log.warning("window at %.3f s not resynthesised: %s", row["t_start_s"], exc)
            continue
        out = run_model(reed, kernel, target, settings, penalty=np.inf)
        if out.feasible:
            p_out[i0:i1] = out.p
            u_out[i0:i1] = out.u
    return Resynthesis(fs=fs, p=p_out, u=u_out)


def plot_signals(
    t: np.ndarray,
    p: np.ndarray,
    u: np.ndarray,
    p_res: np.ndarray,
    u_res: np.ndarray,
    path: str | Path,
    title: str = "",
) -> Path:
    """Target against resynthesised pressure and flow (paper Figs. 9 and 11).

    Parameters
    ----------
    t : ndarray
        Time, s.
    p, u : ndarray
        Target pressure (Pa) and flow (m^3/s).
    p_res, u_res : ndarray
        Resynthesised pressure and flow.
    path : str or Path
        PNG file, written atomically.
    title : str
        Figure title.

    Returns
    -------
    Path
    """
    fig, (a1, a2) = plt.subplots(2, 1, sharex=True, figsize=(8, 5))
    a1.plot(t, p, color="0.6", lw=2, label="target")
    a1.plot(t, p_res, color="k", lw=0.8, label="resynthesised")
    a1.set_ylabel("pressure [Pa]")
    a1.legend(loc="upper right")
    a2.plot(t, u, color="0.6", lw=2, label="target")
    a2.plot(t, u_res, color="k", lw=0.8, label="resynthesised")
    a2.set_ylabel("flow [m³/s]")
    a2.set_xlabel("time [s]")
    if title:
        a1.set_title(title)
    return _save(fig, path)


def plot_flow_pressure(
    p: np.ndarray,
    u: np.ndarray,
    fs: float,
    s1: Step1Result,
    path: str | Path,
    zero_mean: bool = False,
) -> Path:
    """Flow against pressure difference with the step-1 fits of both branches (Fig. 8).

    Parameters
    ----------
    p, u : ndarray
        Window pressure (Pa) and flow (m^3/s).
    fs : float
        Sample rate, Hz.
    s1 : Step1Result
        Step-1 fits of the window.
    path : str or Path
        PNG file.
    zero_mean : bool
        The flow is zero-mean; the fitted curves are centred like the fit.

    Returns
    -------
    Path
    """
    d = np.column_stack(flow_signals(p, s1.p_m, fs, s1.rho))
    if zero_mean:
        d = d - d.mean(axis=0)
    dp = s1.p_m - np.asarray(p)
    fig, ax = plt.subplots(figsize=(6, 4.5))
    ax.plot(dp, u, ".", color="0.7", ms=3, label="target")
    for name, mask, style in (("closing", d[:, 2] < 0, "k-"), ("opening", d[:, 2] > 0, "k--")):
        fit = s1.branch(name)
        order = np.argsort(dp[mask])
        ax.plot(
            dp[mask][order],
            (d[mask] @ fit.c)[order],
            style,
            lw=1,
            label=f"step 1, {name} (k={fit.k:.3g} Pa/m)",
        )
    ax.set_xlabel("pressure difference p_m - p [Pa]")
    ax.set_ylabel("flow [m³/s]")
    ax.legend(fontsize=8)
    return _save(fig, path)


def plot_history(history: np.ndarray, path: str | Path, f1: float | None = None) -> Path:
    """Objective history of step 2 (Fig. 7, lower plot).

    Parameters
    ----------
    history : ndarray
        Best F2 after each evaluation, Pa.
    path : str or Path
        PNG file.
    f1 : float, optional
        Step-1 F1 of the seed branch, shown in the title.

    Returns
    -------
    Path
    """
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.semilogy(np.arange(1, len(history) + 1), history, "k-")
    ax.set_xlabel("evaluations")
    ax.set_ylabel("F2 [Pa]")
    if f1 is not None:
        ax.set_title(f"step 1 F1 = {f1:.3g} (m³/s)²")
    return _save(fig, path)


def plot_tracks(table: pd.DataFrame, path: str | Path) -> Path:
    """Every parameter and identifiable combination against window time, with error bands.

    The band is the estimate plus or minus two standard errors (``<name>_se`` columns,
    where present), taken in log space for a positive estimate (``x exp(+-2 se / x)``, which
    never crosses zero); the lines break between segments (notes) and across gaps, so no
    line is drawn through a silence. Windows where a quantity is undetermined (relative
    standard error above the limit, or infinite) are drawn as open circles, determined ones
    as filled dots;
    a panel whose quantity is undetermined in most windows says so in its title. Windows
    whose status is not ok are drawn in grey.

    Parameters
    ----------
    table : pandas.DataFrame
        Per-window results.
    path : str or Path
        PNG file.

    Returns
    -------
    Path
    """
    t = (0.5 * (table["t_start_s"] + table["t_end_s"])).to_numpy(dtype=float)
    names = [*PARAMETER_NAMES, "y_c", *(c.name for c in COMBINATIONS), "h_mean",
             "closed_fraction", "relative_residual"]  # fmt: skip
    names = [n for n in names if n in table]
    ncol = 4
    nrow = -(-len(names) // ncol)
    fig, axes = plt.subplots(nrow, ncol, sharex=True, figsize=(13, 2.3 * nrow + 0.6))
    ok = (
        (table["status"].astype(str) == "ok").to_numpy()
        if "status" in table
        else np.ones(len(t), bool)
    )
    brk = _breaks(table, t)
    for ax, name in zip(axes.ravel(), names, strict=False):
        x = pd.to_numeric(table[name], errors="coerce").to_numpy(dtype=float)
        title = f"{name} [{unit_of(name) or '-'}]"
        se_col, det_col = f"{name}_se", f"determined_{name}"
        if se_col in table:
            se = pd.to_numeric(table[se_col], errors="coerce").to_numpy(dtype=float)
            band = np.isfinite(se) & ok
            lo, hi = _band(x, se)
            ax.fill_between(
                _split(t, brk), _split(np.where(band, lo, np.nan), brk),
                _split(np.where(band, hi, np.nan), brk),
                color="tab:blue", alpha=0.25, lw=0, label="±2 SE",
            )  # fmt: skip
            det = flags(table, det_col)
            if np.isnan(se[ok]).all():
                title += " fixed"
                det = np.ones(len(t), bool)
            elif not ok.any() or det[ok].mean() < 0.5:
                title += " UNDETERMINED"
        else:
            det = np.ones(len(t), bool)
        ax.plot(_split(t, brk), _split(x, brk), "-", color="0.6", lw=0.6)
        ax.plot(t[ok & det], x[ok & det], "k.", ms=5)
        ax.plot(t[ok & ~det], x[ok & ~det], "o", mfc="none", mec="tab:red", ms=4)
        ax.plot(t[~ok], x[~ok], ".", color="0.7", ms=4)
        ax.set_title(title, fontsize=9, color="tab:red" if "UNDET" in title else "k")
        ax.tick_params(labelsize=7)
    for ax in axes.ravel()[len(names) :]:
        ax.set_visible(False)
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    fig.suptitle(
        "estimate (dots: determined; open red: undetermined; grey: status not ok), band ±2 SE "
        "(in log space for positive quantities); lines break between notes and at gaps",
        fontsize=9,
    )
    return _save(fig, path)


def _breaks(table: pd.DataFrame, t: np.ndarray) -> np.ndarray:
    """Indices before which a track breaks: a new segment, or a gap over 1.5 hops."""
    if len(t) < 2:
        return np.array([], dtype=int)
    step = np.diff(t)
    gap = step > 1.5 * np.median(step)
    if "segment" in table:
        seg = pd.to_numeric(table["segment"], errors="coerce").to_numpy(dtype=float)
        gap |= np.diff(seg) != 0
    return np.flatnonzero(gap) + 1


def _split(x: np.ndarray, breaks: np.ndarray) -> np.ndarray:
    """``x`` with a NaN inserted at each break (matplotlib draws no line across it)."""
    return np.insert(np.asarray(x, dtype=float), breaks, np.nan)


def _band(x: np.ndarray, se: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ±2 SE band; for a positive estimate in log space, ``x exp(±2 se / x)``.

    A positive quantity (a stiffness, an area, a pressure) has a positive band whatever its
    standard error: the linear band ``x - 2 se`` would cross zero for a relative SE over 50 %.
    """
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        rel = np.where(x > 0, se / x, np.nan)
        lo = np.where(x > 0, x * np.exp(-2 * rel), x - 2 * se)
        hi = np.where(x > 0, x * np.exp(2 * rel), x + 2 * se)
    return lo, hi


def write_wav(path: str | Path, p: np.ndarray, fs: float, full_scale: float | None = None) -> Path:
    """Write a pressure signal as a floating-point WAV file.

    Parameters
    ----------
    path : str or Path
        WAV file, written atomically.
    p : ndarray
        Pressure, Pa (NaN samples are written as 0).
    fs : float
        Sample rate, Hz.
    full_scale : float, optional
        Pressure in Pa written as 1.0; default ``max |p|``.

    Returns
    -------
    Path
    """
    x = np.nan_to_num(np.asarray(p, dtype=float))
    scale = full_scale or float(np.max(np.abs(x))) or 1.0
    return write_atomic(
        path,
        lambda tmp: soundfile.write(tmp, x / scale, int(round(fs)), subtype="FLOAT", format="WAV"),
    )


def _save(fig, path: str | Path) -> Path:
    fig.tight_layout()
    try:
        return write_atomic(path, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    finally:
        plt.close(fig)


def plot_first_window(
    table: pd.DataFrame,
    histories: dict,
    p: np.ndarray,
    u: np.ndarray,
    fs: float,
    rho: float,
    config: InversionConfig,
    zero_mean: bool,
    folder: str | Path,
) -> dict[str, str]:
    """Figures 7 and 8 of the paper for the first inverted window of a take.

    Writes ``flow_pressure.png`` (flow against pressure difference with both step-1 fits)
    and, when the window's search history is known, ``history.png``.

    Parameters
    ----------
    table : pandas.DataFrame
        Per-window results.
    histories : dict
        Window index -> step-2 objective history (Pa).
    p, u : ndarray
        Mouthpiece pressure (Pa) and flow (m^3/s) of the take.
    fs : float
        Sample rate, Hz.
    rho : float
        Air density, kg/m^3.
    config : InversionConfig
        Step-1 settings.
    zero_mean : bool
        Whether the flow is zero-mean (measured).
    folder : str or Path
        Output folder.

    Returns
    -------
    dict
        Output name -> file name of the figures written.
    """
    folder = Path(folder)
    ok = table[table["error"] == ""]
    if not len(ok):
        return {}
    first = ok.iloc[0]
    i0, i1 = int(round(first["t_start_s"] * fs)), int(round(first["t_end_s"] * fs))
    s1 = step1(
        p[i0:i1], u[i0:i1], fs, rho=rho, lam=config.lam,
        zero_mean=zero_mean, p_m=config.step1_p_m, y_c=config.y_c,
    )  # fmt: skip
    plot_flow_pressure(
        p[i0:i1], u[i0:i1], fs, s1, folder / "flow_pressure.png", zero_mean=zero_mean
    )
    outputs = {"flow_pressure": "flow_pressure.png"}
    w = int(first["window"])
    if w in histories:
        plot_history(histories[w], folder / "history.png")
        outputs["history"] = "history.png"
    return outputs
