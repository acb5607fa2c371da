"""Resynthesis: the model driven by each window's estimated parameters, and its plots.

Figures (matplotlib, Agg backend, PNG), after the paper:

- target against resynthesis for p and u (Figs. 9 and 11): :func:`plot_signals`;
- flow against pressure difference with the step-1 fits of both branches (Fig. 8):
  :func:`plot_flow_pressure`;
- objective history of step 2 (Fig. 7): :func:`plot_history`;
- parameter tracks over the take: :mod:`mpipe.inversion.output.tracks_plot`;
- one or two periods of each note: :mod:`mpipe.inversion.output.note_figures`.

References
----------
Chatziioannou & van Walstijn 2012, Figs. 7-9 and 11; physics.md J ("Resynthesis").
"""

from __future__ import annotations

import logging
import textwrap
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import soundfile

from mpipe.core.io import write_atomic
from mpipe.inversion.fit.flow_fit import flow_signals
from mpipe.inversion.fit.history_start import lead_in
from mpipe.inversion.fit.objective import (
    ObjectiveSettings,
    TargetWindow,
    run_model,
)
from mpipe.inversion.fit.step1 import (
    Step1Result,
    step1,
)
from mpipe.inversion.settings import InversionConfig
from mpipe.inversion.table.records import reed_from_row
from mpipe.inversion.trust.status_words import reason_words
from mpipe.reed.bore_kernel import BoreKernel

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


def pyplot():
    """The pyplot of matplotlib on the Agg backend, imported on the first figure.

    Not at the module's import: the inversion stage imports this module in the run's
    process, and matplotlib costs about 0.5 s there that its figures (drawn by the
    background processes of :mod:`mpipe.pipeline.figures`) never need.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def resynthesise(
    table: pd.DataFrame,
    p: np.ndarray,
    u: np.ndarray,
    fs: float,
    kernel: BoreKernel | Callable[[pd.Series], BoreKernel],
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
        Per-window results of :func:`mpipe.inversion.whole_take.tracking.track`.
    p, u : ndarray
        Target pressure (Pa) and flow (m^3/s) of the take.
    fs : float
        Sample rate, Hz.
    kernel : BoreKernel or callable
        Prepared bore, or ``kernel(row)`` giving each window's (its note's fingering).
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
        history = lead_in(p, u, i0, i1 - i0, kernel.n_taps, config.lead_s, fs)
        target = TargetWindow(p[i0:i1], u[i0:i1], *history, fs, zero_mean)
        try:
            reed = reed_from_row(row)
        except ValueError as exc:
            # one unusable window must not stop the resynthesis of the others
            log.warning("window at %.3f s not resynthesised: %s", row["t_start_s"], exc)
            continue
        bore = kernel(row) if callable(kernel) else kernel
        out = run_model(reed, bore, target, settings, penalty=np.inf)
        if out.feasible:
            p_out[i0:i1] = out.p
            u_out[i0:i1] = out.u
    return Resynthesis(fs=fs, p=p_out, u=u_out)


def two_periods(p: np.ndarray, fs: float, f0_hz: float, periods: int = 2) -> slice:
    """The last ``periods`` periods of a window, from an upward zero crossing of its p.

    The end of a window is shown rather than its start, where the model's resynthesis
    settles from its history. The slice starts at the latest upward crossing of the mean
    that leaves ``periods`` periods before the window's end (without one, the slice is the
    window's last ``periods`` periods); without a playing frequency, or when the window
    holds fewer periods, it is the whole window.

    Parameters
    ----------
    p : ndarray
        Pressure over the window, Pa.
    fs : float
        Sample rate, Hz.
    f0_hz : float
        Playing frequency, Hz (NaN: unknown).
    periods : int
        Periods to show.

    Returns
    -------
    slice
    """
    p = np.asarray(p, dtype=float)
    if not (np.isfinite(f0_hz) and f0_hz > 0):
        return slice(0, p.size)
    n = int(round(periods * fs / f0_hz))
    if n >= p.size:
        return slice(0, p.size)
    x = p - np.mean(p)
    up = np.flatnonzero((x[:-1] < 0) & (x[1:] >= 0)) + 1
    up = up[up + n <= p.size]
    start = int(up[-1]) if up.size else p.size - n
    return slice(start, start + n)


def plot_signals(
    t: np.ndarray,
    p: np.ndarray,
    u: np.ndarray,
    p_res: np.ndarray,
    u_res: np.ndarray,
    path: str | Path,
    title: str = "",
    status: str = "ok",
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
        Figure title: which window, and its status (see
        :func:`mpipe.inversion.output.note_figures.window_words`).
    status : str
        The window's status; a window that is not ok gets its title in red.

    Returns
    -------
    Path
    """
    fig, (a1, a2) = pyplot().subplots(2, 1, sharex=True, figsize=(8, 5))
    a1.plot(t, p, color="0.6", lw=2, label="target")
    a1.plot(t, p_res, color="k", lw=0.8, label="resynthesised")
    a1.set_ylabel("pressure [Pa]")
    a1.legend(loc="upper right")
    a2.plot(t, u, color="0.6", lw=2, label="target")
    a2.plot(t, u_res, color="k", lw=0.8, label="resynthesised")
    a2.set_ylabel("flow [m³/s]")
    a2.set_xlabel("time [s]")
    if title:
        color = "k" if status == "ok" else "tab:red"
        a1.set_title(textwrap.fill(title, 110), fontsize=9, color=color, y=1.0)
    fixed_margins(fig, 1.0, 0.6, 0.15, 0.4, hspace=0.19)
    return save_figure(fig, path)


def plot_flow_pressure(
    p: np.ndarray,
    u: np.ndarray,
    fs: float,
    s1: Step1Result,
    path: str | Path,
    zero_mean: bool = False,
    f0_hz: float = np.nan,
    title: str = "",
) -> Path:
    """Flow against pressure difference with the step-1 fits of both branches (Fig. 8).

    The measured flow is drawn over the window's last two periods in time order (a loop);
    each branch's fit is drawn as its quasi-static characteristic ``c1 d1 + c2 d2`` (a
    smooth curve of Δp, the reed's steady flow) and, as dots on its own samples, the full
    fit with the ``dp/dt`` term.

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
    f0_hz : float
        Playing frequency, Hz (NaN: the whole window is drawn).
    title : str
        Which window, and its status.

    Returns
    -------
    Path
    """
    d = np.column_stack(flow_signals(p, s1.p_m, fs, s1.rho))
    mean = d.mean(axis=0) if zero_mean else np.zeros(3)
    d = d - mean
    dp = s1.p_m - np.asarray(p)
    show = two_periods(p, fs, f0_hz)
    fig, ax = pyplot().subplots(figsize=(6.5, 4.8))
    ax.plot(dp[show], np.asarray(u)[show], "-", color="0.6", lw=2, label="measured (two periods)")
    grid = np.linspace(dp[show].min(), dp[show].max(), 200)
    g1, g2, _ = flow_signals(s1.p_m - grid, s1.p_m, fs, s1.rho)
    for name, mask, style in (("closing", d[:, 2] < 0, "-"), ("opening", d[:, 2] > 0, "--")):
        fit = s1.branch(name)
        curve = fit.c[0] * (g1 - mean[0]) + fit.c[1] * (g2 - mean[1]) - fit.c[2] * mean[2]
        ax.plot(grid, curve, "k" + style, lw=1,
                label=f"step 1, {name}: quasi-static (k = {fit.k:.3g} Pa/m)")  # fmt: skip
        on = np.zeros(dp.size, bool)
        on[show] = True
        on &= mask
        marker = "k." if name == "closing" else "kx"
        ax.plot(dp[on], d[on] @ fit.c, marker, ms=3, label=f"step 1, {name}: with dp/dt term")
    ax.set_xlabel("pressure difference Δp = p_m − p [Pa]")
    ax.set_ylabel("flow u [m³/s]")
    ax.legend(fontsize=7)
    if title:
        ax.set_title(title, fontsize=9, y=1.0)
    fixed_margins(fig, 0.85, 0.6, 0.15, 0.4)
    return save_figure(fig, path)


def plot_history(history: np.ndarray, path: str | Path, f1: float | None = None,
                 steps: str = "evaluations") -> Path:  # fmt: skip
    """A window's objective over its fit (Fig. 7, lower plot).

    Parameters
    ----------
    history : ndarray
        F2 after each of the fit's ``steps``, Pa: the window fit's best after each model
        evaluation, or, with the take's fit, the window's F2 after each of its steps (which
        may rise as the fit trades one window against the others).
    path : str or Path
        PNG file.
    f1 : float, optional
        Step-1 F1 of the seed branch, shown in the title.
    steps : str
        What the horizontal axis counts.

    Returns
    -------
    Path
    """
    from matplotlib.ticker import NullFormatter

    fig, ax = pyplot().subplots(figsize=(6, 3.5))
    ax.semilogy(np.arange(1, len(history) + 1), history, "k-")
    values = np.asarray(history, float)
    values = values[np.isfinite(values) & (values > 0)]
    if values.size and values.max() < 10 * values.min():
        # within a decade the log axis labels its minor ticks 2.98 x 10^2: plain numbers
        ax.yaxis.set_minor_formatter(NullFormatter())
        ax.set_yticks(np.unique(np.linspace(values.min(), values.max(), 5)))
        ax.yaxis.set_major_formatter("{x:.4g}")
    ax.set_xlabel(steps)
    ax.set_ylabel("F2 [Pa]")
    if f1 is not None:
        ax.set_title(f"step 1 F1 = {f1:.3g} (m³/s)²", y=1.0)
    fixed_margins(fig, 0.95, 0.6, 0.15, 0.35)
    return save_figure(fig, path)


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


def save_figure(fig, path: str | Path) -> Path:
    """Write a matplotlib figure as a PNG atomically (110 dpi) and close it.

    The figure's margins are its own (:func:`fixed_margins`): ``tight_layout`` would draw
    it once more to measure its labels, a third of its CPU.
    """
    try:
        return write_atomic(path, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    finally:
        pyplot().close(fig)


def fixed_margins(fig, left: float, bottom: float, right: float, top: float, **spacing) -> None:
    """Set the figure's margins in inches (``spacing``: ``wspace``, ``hspace`` as fractions).

    Each figure's margins are what ``tight_layout`` chose on the figures of the speed
    benchmark's 4 s tone, with room for a wider tick label; drawing with ``tight_layout``
    cost 0.19-0.26 s of CPU against 0.15-0.16 s for a two-panel figure (measured on
    2026-12-07), and the figures of the run's last stage are waited for.
    """
    width, height = fig.get_size_inches()
    fig.subplots_adjust(left=left / width, right=1.0 - right / width, bottom=bottom / height,
                        top=1.0 - top / height, **spacing)  # fmt: skip


def pick_window(rows: pd.DataFrame) -> pd.Series | None:
    """The window that shows a note best: ok, in the sustain, nearest the note's middle.

    Falls back to any ok window nearest the middle, then to the inverted window with the
    smallest relative residual (its status then says why it is not ok); None when no
    window of ``rows`` has an estimate.
    """
    rows = rows[rows["error"] == ""] if "error" in rows else rows
    if not len(rows):
        return None
    mid = 0.5 * (rows["t_start_s"].min() + rows["t_end_s"].max())
    ok = rows[rows["status"] == "ok"] if "status" in rows else rows
    steady = ok[ok["phase"] == "sustain"] if "phase" in ok else ok
    for pool in (steady, ok):
        if len(pool):
            return pool.loc[(pool["t_start_s"] - mid).abs().idxmin()]
    return rows.loc[pd.to_numeric(rows["relative_residual"]).idxmin()]


def window_words(row: pd.Series | dict) -> str:
    """``"window 12 at 1.130 s (sustain): status ok"``, with the reason when not ok."""
    phase = str(row.get("phase", "") or "")
    status = str(row.get("status", "") or "")
    reason = reason_words(row)
    head = f"window {int(row['window'])} at {float(row['t_start_s']):.3f} s"
    head += f" ({phase})" if phase and phase != "nan" else ""
    words = f"{head}: status {status}" if status else head
    return words + (f" ({reason})" if status != "ok" and reason and reason != "nan" else "")


def plot_fit_figures(
    table: pd.DataFrame,
    histories: dict,
    p: np.ndarray,
    u: np.ndarray,
    fs: float,
    rho: float,
    config: InversionConfig,
    zero_mean: bool,
    folder: str | Path,
    draw: Callable | None = None,
) -> dict[str, str]:
    """Figures 7 and 8 of the paper for the window that shows the first note best.

    Writes ``flow_pressure.png`` (flow against pressure difference with both step-1 fits,
    over two periods) and, when the window's search history is known, ``history.png``, for
    the window :func:`pick_window` picks from the first note (an ok window in its sustain).

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
    draw : callable, optional
        ``draw(fn, *args)`` draws a figure (e.g. in a background process); None: at once.
        Step 1's fit is made where the figure is drawn.

    Returns
    -------
    dict
        Output name -> file name of the figures written.
    """
    draw = draw or (lambda fn, *args: fn(*args))
    folder = Path(folder)
    rows = table
    if "segment" in table and table["segment"].notna().any():
        rows = table[table["segment"] == table.loc[table["error"] == "", "segment"].min()]
    first = pick_window(rows)
    if first is None:
        return {}
    i0, i1 = int(round(first["t_start_s"] * fs)), int(round(first["t_end_s"] * fs))
    f0 = float(first.get("f0_hz", np.nan))
    draw(plot_step1, (p[i0:i1], u[i0:i1]), fs, rho, config, zero_mean, f0,
         "step 1 of " + window_words(first), folder / "flow_pressure.png")  # fmt: skip
    outputs = {"flow_pressure": "flow_pressure.png"}
    w = int(first["window"])
    if w in histories:
        steps = "steps of the take's fit" if config.estimator == "take" else "evaluations"
        draw(plot_history, histories[w], folder / "history.png", None, steps)
        outputs["history"] = "history.png"
    return outputs


def plot_step1(signals, fs, rho, config, zero_mean, f0, title, path) -> Path:
    """Step 1 on one window (``signals``: its p in Pa, u in m^3/s), drawn as Figure 7."""
    p, u = signals
    s1 = step1(p, u, fs, rho=rho, lam=config.lam, zero_mean=zero_mean, p_m=config.step1_p_m,
               y_c=config.y_c)  # fmt: skip
    return plot_flow_pressure(p, u, fs, s1, path, zero_mean, f0, title)
