"""The conditioning stage's helpers: a signal's period, which windows are steady, the plan.

- :func:`estimate_period` finds a signal's period (autocorrelation, parabolic peak);
- :func:`relative_residual` and :func:`is_zero_mean` compare and classify signals;
- :func:`steady_windows` tells which windows of a take hold a steady note;
- :func:`plan_take` and :func:`plan_inversion` make the windows table the inversion reads
  (segments, phases, the windows to invert);
- :func:`bore_resonances` lists the bore's resonances a note's regime is named from.

(The paper's rest start synchronised a model run with its target by a lag search,
section 4.2; the history start needs none, and those helpers left with it in issue 45.)
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd
from scipy import signal

from mpipe.core.signals import DiskArray, as_signal, signal_moments
from mpipe.inversion.preparation.segments import assign_windows, segment_take
from mpipe.inversion.preparation.span import check_span, span_samples
from mpipe.measurement.impedance import impedance_curve


def estimate_period(x: np.ndarray, fs: float, fmin: float = 60.0, fmax: float = 2000.0) -> float:
    """Fundamental period of a (quasi-)periodic signal by autocorrelation, in samples.

    Parameters
    ----------
    x : ndarray
        Signal, 1-D, at least two periods of the lowest allowed frequency long.
    fs : float
        Sample rate, Hz.
    fmin, fmax : float
        Range of fundamental frequencies searched, Hz.

    Returns
    -------
    float
        Period in samples, refined between samples by parabolic interpolation (0 when the
        signal has no energy or no period in range).
    """
    x = np.asarray(x, dtype=float)
    x = x - x.mean()
    if not np.any(x):
        return 0.0
    n = x.size
    lo = max(int(fs / fmax), 1)
    hi = min(int(fs / fmin), n - 2)
    if hi <= lo:
        return 0.0
    r = signal.correlate(x, x, mode="full", method="fft")[n - 1 :]
    # Normalise by the overlap, so long lags are not penalised.
    r = r / (n - np.arange(n))
    seg = r[lo : hi + 1]
    # First peak within 90 % of the highest: the fundamental, not a multiple.
    peaks, _ = signal.find_peaks(seg)
    if peaks.size == 0:
        return 0.0
    best = seg[peaks].max()
    j = int(lo + peaks[np.argmax(seg[peaks] >= 0.9 * best)])
    a, b, c = r[j - 1], r[j], r[j + 1]
    den = a - 2 * b + c
    frac = 0.5 * (a - c) / den if den != 0 else 0.0
    return float(j + np.clip(frac, -0.5, 0.5))


def relative_residual(target: np.ndarray, model: np.ndarray) -> float:
    """Return ``||target - model|| / ||target||`` (dimensionless)."""
    t = np.asarray(target, dtype=float)
    d = np.linalg.norm(t - np.asarray(model, dtype=float))
    return float(d / (np.linalg.norm(t) + 1e-300))


def is_zero_mean(u: np.ndarray, threshold: float = 0.2) -> bool:
    """Decide whether a flow signal is zero-mean (measured) or carries its mean (model).

    Parameters
    ----------
    u : ndarray
        Flow, m^3/s.
    threshold : float
        ``|mean(u)| / rms(u - mean(u))`` below this counts as zero-mean. A playing reed's
        mean flow is comparable to its AC amplitude (ratio ~1-3); a high-passed
        measurement gives ~0.

    Returns
    -------
    bool
    """
    if isinstance(u, DiskArray):  # on disk: the moments in blocks (equal to rounding)
        mean, ac = signal_moments(u)
    else:
        u = np.asarray(u, dtype=float)
        mean, ac = float(np.mean(u)), float(np.std(u))
    if ac == 0.0:
        return abs(mean) == 0.0
    return abs(mean) / ac < threshold


def steady_windows(
    p: np.ndarray,
    fs: float,
    starts: list[int],
    window_n: int,
    tolerance: float = 0.02,
    fmin: float = 60.0,
    fmax: float = 2000.0,
    min_rms: float = 50.0,
) -> pd.DataFrame:
    """Classify analysis windows as steady, transient or silent (physics.md J).

    Step 1 needs a time-invariant pressure-flow relation over the window (paper section 5),
    so only windows whose playing period and RMS pressure change by less than
    ``tolerance`` (relative) from both neighbours count as steady.

    Parameters
    ----------
    p : ndarray
        Mouthpiece pressure, Pa.
    fs : float
        Sample rate, Hz.
    starts : list of int
        Window start samples, increasing.
    window_n : int
        Window length, samples.
    tolerance : float
        Largest relative change of period and RMS between neighbouring windows.
    fmin, fmax : float
        Range of playing frequencies searched, Hz.
    min_rms : float
        Windows with a lower RMS pressure (Pa, mean removed) are silent.

    Returns
    -------
    pandas.DataFrame
        Columns ``window, start, t_start_s, t_end_s, f0_hz, rms_pa, steady, reason``.
    """
    p = as_signal(p)  # a take on disk is read window by window
    rows = []
    for i, s in enumerate(starts):
        x = p[s : s + window_n]
        rms = float(np.sqrt(np.mean((x - x.mean()) ** 2)))
        period = estimate_period(x, fs, fmin, fmax) if rms >= min_rms else 0.0
        rows.append(
            {
                "window": i,
                "start": int(s),
                "t_start_s": s / fs,
                "t_end_s": (s + window_n) / fs,
                "f0_hz": fs / period if period > 0 else float("nan"),
                "rms_pa": rms,
            }
        )
    table = pd.DataFrame(
        rows, columns=["window", "start", "t_start_s", "t_end_s", "f0_hz", "rms_pa"]
    )
    f0 = table["f0_hz"].to_numpy()
    rms = table["rms_pa"].to_numpy()
    steady, reason = [], []
    for i in range(len(rows)):
        if rms[i] < min_rms:
            steady.append(False)
            reason.append("silent")
            continue
        if not np.isfinite(f0[i]):
            steady.append(False)
            reason.append("no period found")
            continue
        worst = 0.0
        for j in (i - 1, i + 1):
            if 0 <= j < len(rows) and np.isfinite(f0[j]) and rms[j] >= min_rms:
                worst = max(worst, abs(f0[j] / f0[i] - 1), abs(rms[j] / rms[i] - 1))
            elif 0 <= j < len(rows):
                worst = np.inf
        steady.append(bool(worst <= tolerance))
        if worst <= tolerance:
            reason.append("")
        elif np.isinf(worst):
            reason.append("next to a silent or aperiodic window")
        else:
            reason.append(f"transient (change {worst:.1%})")
    table["steady"] = steady
    table["reason"] = reason
    return table


def plan_take(
    p: np.ndarray,
    fs: float,
    conditioning,
    window_s: float,
    hop_s: float,
    start_s: float | None = None,
    end_s: float | None = None,
    resonances_hz: Sequence[float] = (),
    tracks_out: dict | None = None,
    segmentation: tuple[pd.DataFrame, dict] | None = None,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The take's segments, its windows and which of them are inverted: one rule everywhere.

    Windows of ``window_s`` every ``hop_s`` span ``[start_s, end_s]``, which default to the
    take less ``conditioning.edge_s`` at both ends (the filters' edges). The take is split
    into notes and silences (:func:`mpipe.inversion.preparation.segments.segment_take`); each window
    gets its segment, phase (onset / sustain / release / silence), playing frequency, pitch,
    regime and level (:func:`mpipe.inversion.preparation.segments.assign_windows`), and the paper's
    steadiness test (:func:`steady_windows`, column ``steady``). With
    ``conditioning.select: sounding`` (the default) every window lying wholly inside a note
    after its first ``onset_periods`` periods, with a playing frequency, is inverted: attacks,
    crescendos, vibrato and releases included; whether the model explains it is then the
    window's status. With ``select: steady`` only the steady windows are (and the other
    sounding ones too with ``invert_transients``).

    Parameters
    ----------
    p : ndarray
        Mouthpiece pressure, Pa.
    fs : float
        Sample rate, Hz.
    conditioning : mpipe.inversion.settings.ConditioningConfig
        Segmentation thresholds, steadiness tolerance, playing-frequency range, silence
        level, edges.
    window_s, hop_s : float
        Window length and hop, s.
    start_s, end_s : float, optional
        Span analysed, s.
    resonances_hz : sequence of float
        The bore's resonances, Hz (the regime of each note; empty: not named).
    tracks_out : dict, optional
        Filled with the level and f0 tracks of the segmentation (for
        :func:`mpipe.inversion.preparation.segments.plot_segments`).
    segmentation : (segments, tracks), optional
        The take's :func:`~mpipe.inversion.preparation.segments.segment_take` with the same
        settings and ``resonances_hz``, made earlier (``mpipe run`` segments a take once,
        in its validation stage); made here otherwise.

    Returns
    -------
    (plan, segments)
        ``plan``: the columns of :func:`steady_windows`, ``segment, phase, inside,
        pitch_cents, regime, spl_db`` and ``invert``; ``segments``: the table of
        :func:`mpipe.inversion.preparation.segments.segment_take`.

    Raises
    ------
    ValueError
        When the span lies outside the take or holds no window (naming the span, the
        take's length and ``edge_s`` or ``window_s``).
    """
    c = conditioning
    n = len(p)
    check_span(n, fs, c.edge_s, window_s, start_s, end_s)
    first, last = span_samples(n, fs, c.edge_s, start_s, end_s)
    window_n = int(round(window_s * fs))
    hop = max(int(round(hop_s * fs)), 1)
    starts = list(range(first, last - window_n + 1, hop))
    table = steady_windows(
        p, fs, starts, window_n, c.steady_tolerance, c.f0_min_hz, c.f0_max_hz, c.min_rms_pa
    )
    segments, tracks = segmentation or segment_take(p, fs, c, resonances_hz)
    if tracks_out is not None:
        tracks_out.update(tracks)
    if len(table):
        table = assign_windows(table, segments, c, tracks)
    else:
        for col in ("segment", "note_number", "phase", "inside", "pitch_cents", "regime", "spl_db"):
            table[col] = pd.Series(dtype=object)
    if c.select == "steady":
        table["invert"] = table["steady"] | (c.invert_transients & (table["reason"] != "silent"))
    else:
        sounding = table["inside"].astype(bool) & (table["rms_pa"] >= c.min_rms_pa)
        table["invert"] = sounding & np.isfinite(table["f0_hz"].to_numpy(float))
    return table, segments


def plan_inversion(
    p: np.ndarray,
    fs: float,
    conditioning,
    window_s: float,
    hop_s: float,
    start_s: float | None = None,
    end_s: float | None = None,
    resonances_hz: Sequence[float] = (),
) -> pd.DataFrame:
    """The window plan of :func:`plan_take` (its segments are in the ``segment`` column)."""
    return plan_take(p, fs, conditioning, window_s, hop_s, start_s, end_s, resonances_hz)[0]


def bore_resonances(calibration, count: int = 8, fmax_hz: float = 6000.0) -> list[float]:
    """Frequencies of the first input-impedance peaks of a calibration's bore, Hz.

    The regime of a note is named from them (:func:`mpipe.measurement.pitch.regime`).
    """
    curve = impedance_curve(calibration, fmin=20.0, fmax=fmax_hz, df=1.0)
    return [r.frequency_hz for r in curve.resonances(count)]
