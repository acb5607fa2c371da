"""One figure per note: two periods of measured and resynthesised p and u (Figs. 9, 11).

Also the overlays of whole windows spread over the take (:func:`plot_overlays`), each
titled with its window's status.

For each note the window that shows it best (:func:`mpipe.inversion.output.resynthesis.pick_window`:
ok, in the sustain, nearest the note's middle) is drawn over its last two periods: p(t) and
u(t) with the resynthesis overlaid, and u against p (the loop the reed's flow makes), with
the pressure difference across the reed on the top axis. The title names the note (name,
playing frequency, fingering) and the window with its status, in red when it is not ok.

References
----------
Chatziioannou & van Walstijn 2012, Figs. 9 and 11.
"""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import pandas as pd

from mpipe.inversion.output.resynthesis import (
    fixed_margins,
    pick_window,
    plot_signals,
    save_figure,
    two_periods,
    window_words,
)
from mpipe.inversion.output.tracks_plot import note_label, note_rows


def plot_note(
    signals: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    fs: float,
    row: pd.Series,
    path: str | Path,
    title: str,
    zero_mean: bool = False,
) -> Path:
    """Two periods of one window: p(t), u(t) and u against p, measured and resynthesised.

    Parameters
    ----------
    signals : tuple of ndarray
        Measured p (Pa), u (m^3/s), resynthesised p, u over the window.
    fs : float
        Sample rate, Hz.
    row : pandas.Series
        The window's row (``t_start_s``, ``f0_hz``, ``p_m``, ``status``, ...).
    path : str or Path
        PNG file.
    title : str
        The note's label; the window and its status are added.
    zero_mean : bool
        Whether the flow is zero-mean (its mean lost in the measurement): u is then drawn
        and labelled as the flow's variation about its mean, not as the flow itself.

    Returns
    -------
    Path
    """
    return save_figure(note_figure(signals, fs, row, title, zero_mean), path)


#: A period whose peak-to-peak pressure is below this fraction of the window's median is
#: a tapered (or dying) edge: the two periods shown end before it.
FULL_AMPLITUDE = 0.8


def full_amplitude_end(p: np.ndarray, fs: float, f0_hz: float) -> int:
    """Samples of a window up to its last period at full amplitude.

    Periods are counted back from the window's end; those whose peak-to-peak pressure is
    below :data:`FULL_AMPLITUDE` of the median period's (a tapered edge, a release) are
    dropped, so u against p draws no false branch towards p = 0.
    """
    p = np.asarray(p, dtype=float)
    if not (np.isfinite(f0_hz) and f0_hz > 0):
        return p.size
    n = int(round(fs / f0_hz))
    k = p.size // n if n >= 2 else 0
    if k < 3:
        return p.size
    spans = [p[p.size - (j + 1) * n : p.size - j * n] for j in range(k)]
    pp = np.array([np.ptp(x) for x in spans])
    ref = float(np.median(pp))
    j = 0
    while j < k - 2 and pp[j] < FULL_AMPLITUDE * ref:
        j += 1
    return p.size - j * n


def note_figure(signals, fs: float, row: pd.Series, title: str, zero_mean: bool = False):
    """The figure :func:`plot_note` writes (a matplotlib Figure)."""
    import matplotlib.pyplot as plt

    p, u, p_res, u_res = (np.asarray(x, dtype=float) for x in signals)
    f0 = float(row.get("f0_hz", np.nan))
    end = full_amplitude_end(p, fs, f0)
    part = two_periods(p[:end], fs, f0)
    show = slice(part.start, part.stop)
    t_ms = 1e3 * (np.arange(p.size)[show] / fs)
    t0 = float(row["t_start_s"])
    fig = plt.figure(figsize=(11, 4.6))
    grid = fig.add_gridspec(2, 2, width_ratios=(1.4, 1))
    a_p = fig.add_subplot(grid[0, 0])
    a_u = fig.add_subplot(grid[1, 0], sharex=a_p)
    a_up = fig.add_subplot(grid[:, 1])
    # a zero-mean flow is the flow's variation about its unknown mean: said so, never drawn
    # as the flow itself (it goes negative while the reed is shut)
    u_name = "u − ū [m³/s]" if zero_mean else "u [m³/s]"
    for ax, meas, res, label in ((a_p, p, p_res, "p [Pa]"), (a_u, u, u_res, u_name)):
        ax.plot(t_ms, meas[show], color="0.6", lw=2.2, label="measured")
        ax.plot(t_ms, res[show], color="k", lw=0.9, label="resynthesised")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    a_p.legend(loc="upper right", fontsize=8)
    a_u.set_xlabel(f"time after the window's start {t0:.3f} s [ms]")
    a_up.plot(p[show], u[show], color="0.6", lw=2.2, label="measured")
    a_up.plot(p_res[show], u_res[show], color="k", lw=0.9, label="resynthesised")
    for ax in (a_u, a_up):
        ax.ticklabel_format(axis="y", style="sci", scilimits=(0, 0))  # u in 10^-5 m^3/s
    a_up.set_xlabel("p [Pa]")
    a_up.set_ylabel("u − ū [m³/s] (zero-mean)" if zero_mean else "u [m³/s]")
    a_up.grid(alpha=0.3)
    p_m = float(row.get("p_m", np.nan))
    if np.isfinite(p_m):
        top = a_up.secondary_xaxis("top", functions=(lambda x: p_m - x, lambda x: p_m - x))
        top.set_xlabel("Δp = p_m − p [Pa]", fontsize=8)
    ok = str(row.get("status", "")) == "ok"
    words = textwrap.fill(window_words(row), 150)
    if zero_mean:
        words += "\nzero-mean flow (u − ū): its mean is not measured"
    fig.suptitle(f"{title}\n{words}", fontsize=9, color="k" if ok else "tab:red")
    fixed_margins(fig, 1.0, 0.6, 0.2, 0.45 + 0.16 * (title.count("\n") + words.count("\n") + 2),
                  wspace=0.18, hspace=0.43)  # fmt: skip
    return fig


def plot_notes(
    table: pd.DataFrame,
    segments: pd.DataFrame,
    measured: tuple[np.ndarray, np.ndarray],
    resynthesised: tuple[np.ndarray, np.ndarray],
    fs: float,
    folder: str | Path,
    fingering: str | None = None,
    draw=None,
    zero_mean: bool = False,
) -> dict[str, str]:
    """Write ``flow_pressure_note_<n>.png`` for every note with an inverted window.

    Parameters
    ----------
    table : pandas.DataFrame
        Per-window results (``segment``, ``status``, ``phase``, ``error``, ...).
    segments : pandas.DataFrame
        The take's segments (notes numbered from 1 in their order, as in the report).
    measured, resynthesised : tuple of ndarray
        ``(p, u)`` of the take, Pa and m^3/s.
    fs : float
        Sample rate, Hz.
    folder : str or Path
        Output folder.
    fingering : str, optional
        The fingering played.
    draw : callable, optional
        ``draw(fn, *args)`` draws a figure (e.g. in a background process); None: at once.
    zero_mean : bool
        Whether the flow is zero-mean (:func:`plot_note`).

    Returns
    -------
    dict
        Output name (``note_<n>``) -> file name.
    """
    draw = draw or _draw_now
    outputs = {}
    for _, note in note_rows(segments).iterrows():
        row = pick_window(table[table["segment"] == note["segment"]])
        if row is None:
            continue
        i0, i1 = int(round(row["t_start_s"] * fs)), int(round(row["t_end_s"] * fs))
        name = f"flow_pressure_note_{note['number']}.png"
        sig = (measured[0][i0:i1], measured[1][i0:i1],
               resynthesised[0][i0:i1], resynthesised[1][i0:i1])  # fmt: skip
        draw(plot_note, sig, fs, row, Path(folder) / name, note_label(note, fingering), zero_mean)
        outputs[f"note_{note['number']}"] = name
    return outputs


def plot_overlays(
    table: pd.DataFrame,
    measured: tuple[np.ndarray, np.ndarray],
    resynthesised: tuple[np.ndarray, np.ndarray],
    fs: float,
    count: int,
    folder: str | Path,
    draw=None,
) -> dict[str, str]:
    """Write ``overlay_<i>.png``: ``count`` whole windows spread over the take, with status.

    Parameters
    ----------
    table : pandas.DataFrame
        Per-window results; windows with an estimate are picked evenly in time order.
    measured, resynthesised : tuple of ndarray
        ``(p, u)`` of the take, Pa and m^3/s.
    fs : float
        Sample rate, Hz.
    count : int
        Windows to draw (``resynthesis.overlay_windows``).
    folder : str or Path
        Output folder.
    draw : callable, optional
        ``draw(fn, *args)`` draws a figure (e.g. in a background process); None: at once.

    Returns
    -------
    dict
        Output name (``overlay_<i>``) -> file name.
    """
    draw = draw or _draw_now
    ok = table[table["error"] == ""]
    if not len(ok):
        return {}
    outputs = {}
    for j, idx in enumerate(np.unique(np.linspace(0, len(ok) - 1, count).round()).astype(int)):
        row = ok.iloc[idx]
        cut = slice(int(round(row["t_start_s"] * fs)), int(round(row["t_end_s"] * fs)))
        name = f"overlay_{j + 1}.png"
        t = np.arange(cut.start, cut.stop) / fs  # the window's times only, s
        draw(plot_signals, t, measured[0][cut], measured[1][cut], resynthesised[0][cut],
                     resynthesised[1][cut], Path(folder) / name, window_words(row),
                     row["status"])  # fmt: skip
        outputs[f"overlay_{j + 1}"] = name
    return outputs


def _draw_now(fn, *args):
    """Draw a figure at once, in this process."""
    return fn(*args)


__all__ = ["note_figure", "plot_note", "plot_notes", "plot_overlays"]
