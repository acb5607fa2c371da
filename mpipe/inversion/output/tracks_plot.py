"""The parameter tracks of a take as a figure a paper could print (``tracks.png``).

Each panel's y-axis is set by the windows whose status is ok (their estimates and their
±2 SE bands): a window that is not ok, whose estimate may sit on a search bound far from
the playing, is drawn at the axis edge as a triangle pointing off the scale instead of
stretching the axis and flattening the ok data. The bands come from the combined standard
uncertainty ``<q>_se`` of each window. The notes are shaded and labelled with their number,
name, playing frequency in Hz and the fingering.
"""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import pandas as pd

from mpipe.core.units import unit_of
from mpipe.inversion.output.resynthesis import save_figure
from mpipe.inversion.settings import PARAMETER_NAMES
from mpipe.inversion.table.records import flags
from mpipe.inversion.trust.combinations import COMBINATIONS

#: Relative SE above which an ok window's band does not widen the axis (an undetermined
#: quantity's band would span decades and flatten the estimates again).
BAND_LIMIT = 0.5


def ok_limits(x: np.ndarray, ok: np.ndarray, lo=None, hi=None, pad: float = 0.08) -> tuple:
    """The y-range of a panel: the ok windows' estimates and bands, padded.

    Parameters
    ----------
    x : ndarray
        Estimates per window.
    ok : ndarray of bool
        Windows whose status is ok.
    lo, hi : ndarray, optional
        Lower and upper band edges per window (NaN: no band); they widen the range only
        where finite.
    pad : float
        Margin on each side, as a fraction of the range.

    Returns
    -------
    (float, float) or None
        None when no ok window has a finite estimate (the axis is then left to matplotlib).
    """
    x = np.asarray(x, dtype=float)
    vals = [x[ok & np.isfinite(x)]]
    for edge in (lo, hi):
        if edge is not None:
            e = np.asarray(edge, dtype=float)
            vals.append(e[ok & np.isfinite(e)])
    v = np.concatenate(vals)
    if not v.size:
        return None
    a, b = float(v.min()), float(v.max())
    # one value (a fraction that is 0 everywhere): a range around it, not 1e-30 wide
    span = b - a if b > a else (abs(a) * 0.05 if a else 0.5)
    return a - pad * span, b + pad * span


def note_label(row, fingering: str | None = None) -> str:
    """``"note 2: G#2 +10 c, 104.4 Hz, xxoo"``: number, name, playing frequency, fingering."""
    parts = [str(row.get("note", "") or "").strip()]
    f0 = float(row.get("f0_hz", np.nan))
    if np.isfinite(f0):
        parts.append(f"{f0:.1f} Hz")
    own = row.get("fingering", "")
    # a phrase's notes each name their own fingering (segments.csv); else the take's
    fingering = own if isinstance(own, str) and own else fingering
    if fingering:
        parts.append(f"fingering {fingering}")
    return f"note {row['number']}: " + ", ".join(p for p in parts if p)


def note_rows(segments: pd.DataFrame | None) -> pd.DataFrame:
    """The notes of a segments table, numbered from 1 as in the report (``number``)."""
    if segments is None or not len(segments):
        return pd.DataFrame(columns=["number", "segment", "start_s", "end_s"])
    notes = segments[segments["label"] == "note"] if "label" in segments else segments
    notes = notes.reset_index(drop=True).copy()
    notes["number"] = np.arange(1, len(notes) + 1)
    if "end_s" not in notes:
        notes["end_s"] = notes["start_s"] + notes["duration_s"]
    return notes


def plot_tracks(
    table: pd.DataFrame,
    path: str | Path,
    segments: pd.DataFrame | None = None,
    fingering: str | None = None,
) -> Path:
    """Every parameter and combination against window time, axes set by the ok windows.

    The band is the estimate ± 2 combined SE (``<name>_se``), in log space for a positive
    estimate (``x exp(±2 se / x)``, which never crosses zero); lines break between notes
    and across gaps. Determined estimates of ok windows are black dots, undetermined ones
    open red circles, windows not ok grey; a window off the ok windows' scale is a grey
    triangle at the axis edge, pointing the way it left. The notes are shaded and numbered
    in every panel and named (pitch in Hz, fingering) above the figure.

    Parameters
    ----------
    table : pandas.DataFrame
        Per-window results.
    path : str or Path
        PNG file.
    segments : pandas.DataFrame, optional
        The take's segments (``label``, ``start_s``, ``end_s``, ``note``, ``f0_hz``).
    fingering : str, optional
        The fingering played, shown with each note.

    Returns
    -------
    Path
    """
    # margins fixed by tracks_figure: tight_layout's extra draw cost 0.45 of 1.6 s CPU
    return save_figure(tracks_figure(table, segments, fingering), path)


def tracks_figure(
    table: pd.DataFrame, segments: pd.DataFrame | None = None, fingering: str | None = None
):
    """The figure :func:`plot_tracks` writes (a matplotlib Figure), one panel per quantity."""
    import matplotlib.pyplot as plt

    t = (0.5 * (table["t_start_s"] + table["t_end_s"])).to_numpy(dtype=float)
    names = [*PARAMETER_NAMES, "y_c", *(c.name for c in COMBINATIONS), "h_mean",
             "closed_fraction", "relative_residual"]  # fmt: skip
    names = [n for n in names if n in table]
    ncol = 4
    nrow = -(-len(names) // ncol)
    notes = note_rows(segments)
    fig, axes = plt.subplots(nrow, ncol, sharex=True, squeeze=False,
                             figsize=(13, 2.3 * nrow + 1.2))  # fmt: skip
    ok = (table["status"].astype(str) == "ok").to_numpy() if "status" in table else None
    ok = np.ones(len(t), bool) if ok is None else ok
    brk = _breaks(table, t)
    for ax, name in zip(axes.ravel(), names, strict=False):
        _panel(ax, table, name, t, ok, brk)
        _shade_notes(ax, notes)
    for ax in axes.ravel()[len(names) :]:
        ax.set_visible(False)
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    labels = "; ".join(note_label(r, fingering) for _, r in notes.iterrows())
    key = (
        "dots: ok, determined; open red: ok, undetermined; grey: status not ok; grey "
        "triangles: not ok and off the ok windows' scale (axes from the ok windows); band "
        "±2 combined SE (log space for positive quantities); lines break between notes"
    )
    title = textwrap.fill(labels, 150) + "\n" + textwrap.fill(key, 150)
    fig.suptitle(title, fontsize=9)
    height = fig.get_figheight()  # inches: the title's lines and the x labels take fixed room
    lines = title.count("\n") + 1
    fig.subplots_adjust(left=0.07, right=0.99, bottom=0.5 / height, wspace=0.32, hspace=0.3,
                        top=1 - (0.45 + 0.17 * lines) / height)  # fmt: skip
    return fig


#: Quantities that are fractions (0..1): values below TINY_FRACTION are drawn as 0 (a
#: closed fraction of 1e-33 is a reed that never shut, not a number worth an axis).
FRACTIONS = ("closed_fraction",)
TINY_FRACTION = 1e-9


def _panel(ax, table, name, t, ok, brk) -> None:
    """One quantity: band, line, points by status, axis from the ok windows, off-scale marks.

    The axis is set by the ok windows whose estimate is determined (an ok but undetermined
    window may sit decades away); the line joins ok windows only and breaks at every window
    that is not ok (those are markers, never joined into spikes); a quantity held fixed
    gets its value written in the panel instead of an empty plot.
    """
    x = pd.to_numeric(table[name], errors="coerce").to_numpy(dtype=float)
    if name in FRACTIONS:
        x = np.where(np.abs(x) < TINY_FRACTION, 0.0, x)
    title = f"{name} [{unit_of(name) or '-'}]"
    lo = hi = None
    det = np.ones(len(t), bool)
    se_col = f"{name}_se"
    if se_col in table:
        se = pd.to_numeric(table[se_col], errors="coerce").to_numpy(dtype=float)
        if np.isnan(se[ok]).all() and _held_fixed(ax, x, ok, title):
            return
        band = np.isfinite(se) & ok
        lo, hi = _band(x, se)
        lo, hi = np.where(band, lo, np.nan), np.where(band, hi, np.nan)
        ax.fill_between(_split(t, brk), _split(lo, brk), _split(hi, brk),
                        color="tab:blue", alpha=0.25, lw=0)  # fmt: skip
        det = flags(table, f"determined_{name}")
        if np.isnan(se[ok]).all():
            det = np.ones(len(t), bool)
        elif not ok.any() or det[ok].mean() < 0.5:
            title += " UNDETERMINED"
        with np.errstate(invalid="ignore", divide="ignore"):
            narrow = np.abs(se) <= BAND_LIMIT * np.abs(x)
        lo, hi = np.where(narrow, lo, np.nan), np.where(narrow, hi, np.nan)
    elif not np.isfinite(x).any() and _held_fixed(ax, x, ok, title):
        return
    scale_ok = ok & det if (ok & det & np.isfinite(x)).any() else ok
    limits = ok_limits(x, scale_ok, lo, hi)
    shown = x.copy()
    if limits is not None:
        shown = np.clip(x, *limits)
        off = np.isfinite(x) & (x != shown)
        for side, marker, y in ((limits[1], "^", 0.975), (limits[0], "v", 0.025)):
            at = off & (shown == side)
            ax.plot(t[at], np.full(at.sum(), y), marker, color="0.45", ms=6, ls="none",
                    transform=ax.get_xaxis_transform())  # fmt: skip
        if off.any():
            title += f" ({int(off.sum())} off scale)"
        ax.set_ylim(*limits)
    line = np.where(ok, shown, np.nan)  # not-ok windows break the line
    ax.plot(_split(t, brk), _split(line, brk), "-", color="0.6", lw=0.6)
    ax.plot(t[ok & det], x[ok & det], "k.", ms=5)
    ax.plot(t[ok & ~det], x[ok & ~det], "o", mfc="none", mec="tab:red", ms=4)
    inside = ~ok & (shown == x)
    ax.plot(t[inside], x[inside], ".", color="0.7", ms=4)
    title += _plain_ticks(ax, limits)
    ax.set_title(title, fontsize=9, color="tab:red" if "UNDET" in title else "k", y=1.0)
    ax.tick_params(labelsize=7)


def _held_fixed(ax, x: np.ndarray, ok: np.ndarray, title: str) -> bool:
    """Write "held fixed at <value>" in a panel whose quantity has no SE and one value."""
    values = np.unique(x[ok & np.isfinite(x)]) if ok.any() else np.unique(x[np.isfinite(x)])
    if values.size > 1:
        return False
    what = f"held fixed at {values[0]:.4g}" if values.size else "held fixed (not estimated)"
    ax.text(0.5, 0.5, what, transform=ax.transAxes, ha="center", va="center", fontsize=9)
    ax.set_yticks([])
    ax.set_title(title + " fixed", fontsize=9, y=1.0)
    ax.tick_params(labelsize=7)
    return True


def _plain_ticks(ax, limits) -> str:
    """Tick labels without matplotlib's offset text (it overlapped the title).

    Values beyond 1e4 or below 1e-2 are labelled in units of a power of ten, given in the
    title (``" ×1e6"``); the labels carry the digits that tell neighbouring ticks apart.
    """
    if limits is None:
        ax.ticklabel_format(axis="y", useOffset=False, style="plain")
        return ""
    big = max(abs(limits[0]), abs(limits[1]))
    power = int(np.floor(np.log10(big))) if big > 0 else 0
    power = 0 if -2 <= power <= 4 else power
    ax.yaxis.set_major_formatter(_plain_formatter(10.0**power))
    return f" ×1e{power}" if power else ""


def _plain_formatter(scale: float):
    """Tick labels ``v / scale`` with the decimals that tell the ticks apart.

    The places are found once per set of ticks (matplotlib hands the formatter its
    ticks before labelling them), not once per label.
    """
    from matplotlib.ticker import Formatter

    class Plain(Formatter):
        places = 0

        def set_locs(self, locs):
            super().set_locs(locs)
            ticks = np.asarray(locs, float)
            step = np.min(np.diff(ticks)) / scale if ticks.size > 1 else 0.0
            if ticks.size == 1:
                step = abs(ticks[0] / scale) or 1.0
            self.places = min(max(0, -int(np.floor(np.log10(step)))), 12) if step > 0 else 0

        def __call__(self, v, pos=None):
            return f"{v / scale:.{self.places}f}"

    return Plain()


def _shade_notes(ax, notes: pd.DataFrame) -> None:
    """Shade every other note lightly and put its number at the top of the panel."""
    for i, (_, r) in enumerate(notes.iterrows()):
        a, b = float(r["start_s"]), float(r["end_s"])
        if i % 2 == 0:
            ax.axvspan(a, b, color="0.93", lw=0, zorder=0)
        ax.text(0.5 * (a + b), 0.97, str(r["number"]), transform=ax.get_xaxis_transform(),
                ha="center", va="top", fontsize=7, color="0.35")  # fmt: skip


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


__all__ = ["BAND_LIMIT", "note_label", "note_rows", "ok_limits", "plot_tracks", "tracks_figure"]
