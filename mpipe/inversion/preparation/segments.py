"""A take split into notes and silences, from the mouthpiece pressure alone.

A player's take is a phrase: notes with attacks and releases, silences between them,
sometimes a squeak or a change of register. :func:`segment_take` finds them from the
level and the playing frequency (YIN, :func:`mpipe.measurement.pitch.f0_track`, over
frames 2.2 periods of ``f0_min_hz`` long every ``frame_hop_s``) of the mouthpiece
pressure: notes from the level, its valleys and the periodic frames, and new notes inside
them where the pitch steps (:mod:`mpipe.inversion.preparation.boundaries`; settings in
``conditioning``, docs/playing.md).

Every segment gets its label (``note`` or ``silence``), its playing frequency (median over
its frames), pitch in cents against ``a4_hz``, nearest note, regime (from the bore's
resonances, :func:`mpipe.measurement.pitch.regime`) and sound pressure level (dB re 20 uPa).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from mpipe.core.io import write_atomic, write_npz_atomic
from mpipe.core.signals import as_signal, pairwise_sum
from mpipe.inversion.preparation.boundaries import (
    level_envelope,
    level_threshold,
    note_spans,
    pitch_cuts,
)
from mpipe.inversion.settings import PARAMETER_NAMES
from mpipe.measurement.pitch import f0_track, note_name, pitch_cents, regime
from mpipe.reed.opening import opening, opening_summary
from mpipe.reed.parameters import ReedParameters

#: Reference pressure of the sound pressure level, Pa.
P_REF_PA = 20e-6
#: Columns of :func:`segment_take`'s table.
SEGMENT_COLUMNS = ("segment", "note_number", "start_s", "end_s", "label", "duration_s",
                   "f0_hz", "pitch_cents", "note", "regime", "rms_pa", "spl_db",
                   "blowing_onset_s", "sounding_onset_s")  # fmt: skip


def spl_db(rms_pa):
    """Sound pressure level of an RMS pressure (Pa), dB re 20 uPa (-inf for 0)."""
    with np.errstate(divide="ignore"):
        out = 20.0 * np.log10(np.asarray(rms_pa, dtype=float) / P_REF_PA)
    return float(out) if out.ndim == 0 else out


def note_numbers(segments: pd.DataFrame) -> dict[int, int]:
    """Segment id -> the note's number in the take (1, 2, ... over the notes only).

    The one number a note goes by in the console, the tables and the figures; silences have
    none. Read from the label (a table written before ``note_number`` existed numbers the same).
    """
    if segments is None or not len(segments) or "segment" not in segments:
        return {}
    notes = segments[segments["label"] == "note"] if "label" in segments else segments
    return {int(g): i + 1 for i, g in enumerate(notes["segment"])}


def segment_take(
    p: np.ndarray,
    fs: float,
    conditioning,
    resonances_hz: Sequence[float] = (),
) -> tuple[pd.DataFrame, dict]:
    """Notes and silences of a take (see the module docstring).

    Parameters
    ----------
    p : ndarray
        Mouthpiece pressure, Pa.
    fs : float
        Sample rate, Hz.
    conditioning : mpipe.inversion.settings.ConditioningConfig
        Thresholds (``silence_db``, ``noise_margin_db``, ``edge_db``, ``min_rms_pa``,
        ``min_silence_s``, ``min_note_s``, ``pitch_jump_cents``, ``glide_s``,
        ``frame_hop_s``, ``level_frame_s``, ``f0_min_hz``,
        ``f0_max_hz``, ``a4_hz``).
    resonances_hz : sequence of float
        The bore's input-impedance peaks, Hz (for the regime; empty: regime "").

    Returns
    -------
    (segments, tracks)
        ``segments``: one row per segment in time order, columns :data:`SEGMENT_COLUMNS`,
        covering the whole take; ``tracks``: ``t_level_s, level_pa, t_f0_s, f0_hz,
        threshold_pa, frame_s`` (the tracks the boundaries come from, and the f0 frame).
    """
    c = conditioning
    p = as_signal(p)  # a take on disk is read in blocks and frames
    duration = len(p) / fs
    t_lev, level = level_envelope(p, fs, c.level_frame_s)
    frame = max(2.2 / c.f0_min_hz, 0.02)
    centres, f0, _ = f0_track(p, fs, frame, c.frame_hop_s, c.f0_min_hz, c.f0_max_hz)
    cents = pitch_cents(f0, c.a4_hz) if f0.size else np.array([])
    threshold = level_threshold(t_lev, level, centres, f0, c)
    bounds: list[tuple[float, float, str, float, float]] = []
    edge = 0.0
    spans = note_spans(t_lev, level, threshold, centres, f0, frame, c, duration)
    for start, end, sounding in spans:
        if start > edge:
            bounds.append((edge, start, "silence", math.nan, math.nan))
        cuts = pitch_cuts(start, end, centres, cents, frame, c)
        # the first note of a blowing starts with it; a slurred one at its pitch step
        onsets = [(start, min(max(sounding, start), end)), *[(x, x) for x in cuts]]
        for a, b, onset in zip([start, *cuts], [*cuts, end], onsets, strict=True):
            bounds.append((a, b, "note", *onset))
        edge = end
    if edge < duration:
        bounds.append((edge, duration, "silence", math.nan, math.nan))
    rows = [{**_describe(i, a, b, label, p, fs, centres, f0, c, resonances_hz),
             "blowing_onset_s": blow, "sounding_onset_s": sound}
            for i, (a, b, label, blow, sound) in enumerate(bounds)]  # fmt: skip
    table = pd.DataFrame(rows, columns=list(SEGMENT_COLUMNS))
    is_note = (table["label"] == "note").to_numpy()
    table["note_number"] = np.where(is_note, np.cumsum(is_note), 0).astype(int)
    tracks = {"t_level_s": t_lev, "level_pa": level, "t_f0_s": centres, "f0_hz": f0,
              "threshold_pa": threshold, "frame_s": frame}  # fmt: skip
    return table, tracks


#: The segmentation file's key prefixes: a segments column, a track.
_COLUMN, _TRACK = "segments/", "tracks/"


def save_segmentation(path: str | Path, segments: pd.DataFrame, tracks: dict) -> Path:
    """Write :func:`segment_take`'s ``(segments, tracks)`` to one npz, atomically.

    The take is segmented once (the validation stage, which needs its notes first) and
    read by the stages after it (:func:`load_segmentation`): the same table, exactly.
    Text columns are stored as fixed-width unicode, numbers with their dtype.
    """
    arrays = {_COLUMN + c: np.asarray(segments[c].to_numpy(), dtype=str)
              if segments[c].dtype.kind not in "biuf" else segments[c].to_numpy()
              for c in segments.columns}  # fmt: skip
    arrays.update({_TRACK + k: np.asarray(v) for k, v in tracks.items()})
    return write_npz_atomic(path, **arrays)


def load_segmentation(path: str | Path) -> tuple[pd.DataFrame, dict]:
    """The ``(segments, tracks)`` of :func:`save_segmentation`'s file."""
    with np.load(path, allow_pickle=False) as d:
        columns = {k[len(_COLUMN) :]: d[k] for k in d.files if k.startswith(_COLUMN)}
        tracks = {k[len(_TRACK) :]: d[k] for k in d.files if k.startswith(_TRACK)}
    segments = pd.DataFrame({c: (v.astype(object) if v.dtype.kind == "U" else v)
                             for c, v in columns.items()})  # fmt: skip
    tracks = {k: (float(v) if v.ndim == 0 else v) for k, v in tracks.items()}
    return segments, tracks


def _rms(p, a: int, b: int) -> float:
    """``sqrt(mean((x - mean x)^2))`` of ``x = p[a:b]`` (Pa), numpy's numbers, read in blocks."""
    if b <= a:
        return 0.0
    m = pairwise_sum(p, None, a, b) / (b - a)
    return float(np.sqrt(pairwise_sum(p, lambda v: (v - m) ** 2, a, b) / (b - a)))


def _describe(i, a, b, label, p, fs, centres, f0, c, resonances_hz) -> dict:
    """One segment's row: its f0 (median over frames inside it), pitch, regime and level."""
    i0, i1 = int(round(a * fs)), max(int(round(b * fs)), int(round(a * fs)) + 1)
    rms = _rms(p, i0, min(i1, len(p)))
    f = math.nan
    if label == "note":
        inside = (centres >= a) & (centres <= b) & np.isfinite(f0)
        f = float(np.median(f0[inside])) if inside.any() else math.nan
    return {
        "segment": i, "note_number": 0, "start_s": float(a), "end_s": float(b), "label": label,
        "duration_s": float(b - a), "f0_hz": f, "pitch_cents": pitch_cents(f, c.a4_hz),
        "note": note_name(f, c.a4_hz),
        "regime": regime(f, resonances_hz) if label == "note" else "silence",
        "rms_pa": rms, "spl_db": spl_db(rms),
    }  # fmt: skip


def assign_windows(
    plan: pd.DataFrame, segments: pd.DataFrame, conditioning, tracks: dict
) -> pd.DataFrame:
    """Each window's segment, phase, playing frequency, pitch, regime and level.

    A window belongs to the segment holding its centre. Its phase is ``onset`` when it
    starts within ``onset_s`` of its note's start, ``release`` when it ends within
    ``release_s`` of its end, ``sustain`` otherwise, and ``silence`` in a silence. Its f0
    is the median of the YIN frames centred inside it (at a take's edge, where none is, the
    nearest frame that overlaps it).

    Returns
    -------
    pandas.DataFrame
        ``plan`` with ``segment, phase, inside`` (the window lies wholly inside its note,
        after ``onset_periods`` periods), ``f0_hz`` (replaced), ``pitch_cents``, ``regime``
        and ``spl_db``.
    """
    c = conditioning
    out = plan.copy()
    t0 = out["t_start_s"].to_numpy(float)
    t1 = out["t_end_s"].to_numpy(float)
    mid = 0.5 * (t0 + t1)
    starts = segments["start_s"].to_numpy(float)
    idx = np.clip(np.searchsorted(starts, mid, side="right") - 1, 0, len(segments) - 1)
    seg = segments.iloc[idx].reset_index(drop=True)
    note = (seg["label"] == "note").to_numpy()
    s0, s1 = seg["start_s"].to_numpy(float), seg["end_s"].to_numpy(float)
    skip = c.onset_periods / seg["f0_hz"].to_numpy(float)
    skip = np.where(np.isfinite(skip), skip, 0.0)
    phase = np.where(t0 < s0 + c.onset_s, "onset", np.where(t1 > s1 - c.release_s, "release",
                     "sustain"))  # fmt: skip
    out["segment"] = seg["segment"].to_numpy(int)
    numbers = note_numbers(segments)
    out["note_number"] = [numbers.get(int(g), 0) for g in out["segment"]]
    out["phase"] = np.where(note, phase, "silence")
    out["inside"] = note & (t0 >= s0 + skip - 1e-9) & (t1 <= s1 + 1e-9)
    cf, f0 = tracks["t_f0_s"], tracks["f0_hz"]
    med = []
    reach = 0.5 * tracks.get("frame_s", 0.0)
    for a, b in zip(t0, t1, strict=True):
        sel = f0[(cf >= a) & (cf <= b)]
        if not sel.size and cf.size:  # at a take's edge no frame is centred inside
            near = int(np.argmin(np.abs(cf - 0.5 * (a + b))))
            sel = f0[[near]] if a - reach <= cf[near] <= b + reach else sel
        sel = sel[np.isfinite(sel)]
        med.append(float(np.median(sel)) if sel.size else math.nan)
    out["f0_hz"] = med
    out["pitch_cents"] = pitch_cents(np.asarray(med), c.a4_hz)
    out["regime"] = np.where(note, seg["regime"].to_numpy(), "silence")
    out["spl_db"] = spl_db(out["rms_pa"].to_numpy(float))
    return out


#: Per-window columns of the plan carried into the windows table (what was played).
PLAYED_COLUMNS = ("note_number", "phase", "f0_hz", "pitch_cents", "regime", "rms_pa", "spl_db")


def with_played(table: pd.DataFrame, plan: pd.DataFrame) -> pd.DataFrame:
    """The windows table with each window's phase, f0, pitch, regime and level from the plan."""
    cols = [c for c in PLAYED_COLUMNS if c in plan]
    extra = plan[["t_start_s", *cols]].copy()
    extra["_key"] = extra["t_start_s"].round(9)
    out = table.drop(columns=[c for c in cols if c in table]).copy()
    out["_key"] = out["t_start_s"].round(9)
    merged = out.merge(extra.drop(columns="t_start_s"), on="_key", how="left")
    return merged.drop(columns="_key")


def reed_openings(
    table: pd.DataFrame, p, fs: float, whole: bool = True
) -> tuple[pd.DataFrame, np.ndarray | None]:
    """The fitted reed's opening in every window, driven by the measured pressure.

    Each window's reed (its row's parameters) is driven by the mouthpiece pressure from
    5 ms before the window (:func:`mpipe.reed.opening.opening`); the fit matches that
    pressure to a fraction of a per cent, so this is the fitted model's opening.

    Returns
    -------
    (columns, h)
        ``columns``: ``h_mean``, ``h_min`` (m) and ``closed_fraction`` (fraction of the
        window, so of each period, the reed is shut) per row of ``table``; ``h``: the
        opening at every sample of the take (m), NaN outside the windows with an estimate;
        None when ``whole`` is False (``p`` is then only sliced: a take on disk is read
        around its windows).
    """
    h_all = np.full(len(p), np.nan) if whole else None
    rows = []
    for _, row in table.iterrows():
        i0, i1 = int(round(row["t_start_s"] * fs)), int(round(row["t_end_s"] * fs))
        try:
            reed = ReedParameters(**{k: float(row[k]) for k in (*PARAMETER_NAMES, "y_c", "alpha")})
            h = opening(reed, p, fs, i0, i1 - i0)
        except (ValueError, TypeError, KeyError):  # no estimate in this window
            rows.append(opening_summary(np.array([np.nan])))
            continue
        if h_all is not None:
            h_all[i0:i1] = h
        rows.append(opening_summary(h))
    return pd.DataFrame(
        rows, index=table.index, columns=["h_mean", "h_min", "closed_fraction"]
    ), h_all


def pick_windows(starts: Sequence[int], count: int) -> list[int]:
    """``count`` window starts spread evenly over ``starts`` (all of them when fewer)."""
    starts = list(starts)
    if len(starts) <= count:
        return starts
    idx = np.unique(np.round(np.linspace(0, len(starts) - 1, count)).astype(int))
    return [starts[i] for i in idx]


def note_label(row) -> str:
    """A note's label on the plots: its number in the take, name and f0 in Hz.

    (``"1: G#2 +8 c, 104.0 Hz"``; the number is ``note_number``, the one the console and
    the tables use, not the segment id.)
    """
    f0 = float(row["f0_hz"])
    hz = f", {f0:.1f} Hz" if math.isfinite(f0) else ""
    number = row.get("note_number", row.get("segment"))
    return f"{int(number)}: {row['note']}{hz}"


def plot_segments(segments: pd.DataFrame, tracks: dict, path, a4_hz: float = 440.0):
    """What was played: the level with its silence threshold, and the pitch, notes shaded.

    Parameters
    ----------
    segments : pandas.DataFrame
        :func:`segment_take`'s table.
    tracks : dict
        Its tracks (level, threshold, f0).
    path : str or Path
        PNG file (written atomically).
    a4_hz : float
        A4 of the take, Hz (the segment table's note names and cents already follow it).
    """
    import matplotlib.pyplot as plt

    fig = segments_figure(segments, tracks)
    try:
        return write_atomic(path, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    finally:
        plt.close(fig)


#: Margin of the pitch axis around the notes' playing frequencies (a factor, log axis).
F0_MARGIN = 1.25


def segments_figure(segments: pd.DataFrame, tracks: dict):
    """The figure :func:`plot_segments` writes (a matplotlib Figure).

    The pitch axis is logarithmic and spans the notes' own playing frequencies with a
    margin (a linear axis up to ``f0_max_hz`` flattened the notes); each note's label
    (its number in the take, name, f0) goes on the lowest row where it overlaps none.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_l, ax_p) = plt.subplots(2, 1, sharex=True, figsize=(10, 5))
    ax_l.plot(tracks["t_level_s"], spl_db(np.maximum(tracks["level_pa"], 1e-9)), lw=0.8)
    ax_l.axhline(spl_db(tracks["threshold_pa"]), color="tab:red", lw=0.8, ls="--",
                 label="silence threshold")  # fmt: skip
    ax_l.set_ylabel("level [dB re 20 µPa]")
    ax_l.legend(loc="lower right", fontsize=8)
    # the pitch in Hz (what an acoustician compares with the bore's resonances); each note's
    # label gives its name and its cents against A4 too
    ax_p.plot(tracks["t_f0_s"], tracks["f0_hz"], ".", ms=2, color="k")
    ax_p.set_ylabel("f0 [Hz]")
    ax_p.set_xlabel("time [s]")
    notes = segments[segments["label"] == "note"]
    f0 = pd.to_numeric(notes["f0_hz"], errors="coerce").to_numpy(float)
    f0 = f0[np.isfinite(f0) & (f0 > 0)]
    if f0.size:
        ax_p.set_yscale("log")
        ax_p.set_ylim(f0.min() / F0_MARGIN, f0.max() * F0_MARGIN)
    numbers = note_numbers(segments)
    labels = []
    for _, s in notes.iterrows():
        s = s.copy()
        s["note_number"] = numbers[int(s["segment"])]
        for ax in (ax_l, ax_p):
            ax.axvspan(s["start_s"], s["end_s"], color="tab:green", alpha=0.12, lw=0)
            ax.axvline(s["start_s"], color="tab:green", lw=0.6)
        labels.append(ax_p.annotate(note_label(s), (s["start_s"], 1.0), xytext=(2, -2),
                                    textcoords="offset points", xycoords=("data", "axes fraction"),
                                    va="top", fontsize=7))  # fmt: skip
    for ax in (ax_l, ax_p):
        ax.grid(alpha=0.3)
    fig.tight_layout()
    _stagger(fig, labels)
    return fig


def _stagger(fig, labels: list) -> None:
    """Move each label down a row until it overlaps no label before it (display boxes)."""
    renderer = fig.canvas.get_renderer()
    placed: list = []
    for text in labels:
        row = 0
        while True:
            text.set_position((2, -2 - 9 * row))
            box = text.get_window_extent(renderer)
            if not any(box.overlaps(other) for other in placed) or row > 20:
                break
            row += 1
        placed.append(box)


def note_segments(summary: pd.DataFrame) -> pd.DataFrame:
    """The note rows of a segment table (silences left out)."""
    return summary[summary["label"] == "note"].reset_index(drop=True)


__all__ = [
    "P_REF_PA",
    "PLAYED_COLUMNS",
    "SEGMENT_COLUMNS",
    "assign_windows",
    "level_envelope",
    "note_segments",
    "pick_windows",
    "note_label",
    "note_numbers",
    "plot_segments",
    "segments_figure",
    "reed_openings",
    "load_segmentation",
    "save_segmentation",
    "segment_take",
    "spl_db",
    "with_played",
]
