"""The HTML report of a take: one self-contained file a scientist can send.

The report opens with a summary (verdict, parameter medians with their IQR, failed and
flagged windows), then the measurement (impedance validation), the reed parameters over
time, the resynthesis and the run. Units come from :func:`mpipe.core.units.unit_of`; the
page itself (embedded figures, numbered tables, rounding) is
:mod:`mpipe.pipeline.html_report`.
"""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd

from mpipe.core.units import unit_of
from mpipe.inversion.table.coverage import summary as uncertainty_summary
from mpipe.inversion.table.records import read_windows
from mpipe.pipeline.budget_table import budget_tables
from mpipe.pipeline.html_report import Figure, Section, fmt, write_report
from mpipe.pipeline.report_windows import WINDOW_CAPTION, reasons, resynthesis_figures, window_table
from mpipe.pipeline.verdict import overall_verdict

#: Reed parameters summarised at the top of a take's report, in this order.
SUMMARY_PARAMETERS = ("k", "S", "y_m", "p_m", "lam", "m", "g", "k_c")


def parameter_summary(windows: pd.DataFrame) -> pd.DataFrame:
    """Median and interquartile range of each reed parameter over the windows with status ok.

    Returns
    -------
    pandas.DataFrame
        Columns ``parameter``, ``unit``, ``median``, ``q25``, ``q75``, ``iqr_pct``
        (interquartile range over the median, %), ``min``, ``max``, ``n_windows``.
    """
    ok = windows[windows["status"] == "ok"]
    rows = []
    for name in SUMMARY_PARAMETERS:
        if name not in ok:
            continue
        v = pd.to_numeric(ok[name], errors="coerce").dropna().to_numpy(dtype=float)
        med = float(np.median(v)) if v.size else float("nan")
        q25, q75 = np.percentile(v, [25, 75]) if v.size else (float("nan"),) * 2
        rows.append(
            {
                "parameter": name,
                "unit": unit_of(name),
                "median": med,
                "q25": float(q25),
                "q75": float(q75),
                "iqr_pct": 100 * float(q75 - q25) / abs(med) if v.size and med else float("nan"),
                "min": float(v.min()) if v.size else float("nan"),
                "max": float(v.max()) if v.size else float("nan"),
                "n_windows": int(v.size),
            }
        )
    return pd.DataFrame(rows)


def flag_windows(windows: pd.DataFrame) -> pd.DataFrame:
    """Windows whose status is not ok, with the reason (see :mod:`mpipe.inversion.trust.status`).

    Parameters
    ----------
    windows : pandas.DataFrame
        The per-window table (columns ``status`` and ``status_reason``).

    Returns
    -------
    pandas.DataFrame
        Columns ``window``, ``t_start_s``, ``status``, ``reason``.
    """
    bad = windows[windows["status"] != "ok"]
    return pd.DataFrame(
        {
            "window": bad["window"].to_numpy(),
            "t_start_s": bad["t_start_s"].to_numpy(),
            "status": bad["status"].to_numpy(),
            "reason": reasons(bad),
        }
    )


def _read_csv(path: Path) -> pd.DataFrame:
    table = pd.read_csv(path, keep_default_na=False, na_values=[""])
    if "error" in table:
        table["error"] = [("" if pd.isna(v) else str(v)) for v in table["error"]]
    if "reason" in table:
        table["reason"] = [("" if pd.isna(v) else str(v)) for v in table["reason"]]
    return table


def write_take_report(
    root: Path, name: str, take_paths, cal_path, records: dict, version: str, when: str
) -> Path:
    """Write ``root/report.html`` for one take of ``mpipe run``.

    Parameters
    ----------
    root : Path
        The take's folder, ``OUT/<take>``, with the stage folders.
    name : str
        Take name.
    take_paths : sequence of Path
        The take's audio files.
    cal_path : Path
        Calibration file used.
    records : dict
        Stage name to :class:`mpipe.pipeline.manifest.StageRecord`.
    version : str
        mpipe version, shown in the header.
    when : str
        Date and time shown in the header.

    Returns
    -------
    Path
    """
    windows = read_windows(root / "inversion" / "windows.csv")
    resonances = _read_csv(root / "validation" / "validation.csv")
    harmonics = _read_csv(root / "validation" / "harmonics.csv")
    plan = _read_csv(root / "conditioning" / "plan.csv")
    seg_path = root / "inversion" / "segments.csv"
    segments = _read_csv(seg_path) if seg_path.exists() else pd.DataFrame()
    summary = _summary_section(records, windows, segments)
    sections = [
        _measurement_section(root, records, resonances, harmonics),
        _parameters_section(root, records, windows, segments),
        _resynthesis_section(root, records),
        _run_section(records, take_paths, cal_path, version, plan),
    ]
    return write_report(root / "report.html", f"mpipe report: {name}", when, sections, summary)


#: Quantities of the per-segment summary, in this order.
SEGMENT_QUANTITIES = ("p_m", "p_M", "gamma", "zeta", "k", "S", "y_m", "lam")


def segment_tables(segments: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The notes of a take: what was played, and each note's medians with their SEs.

    Returns
    -------
    (played, parameters)
        ``played``: segment, start, duration, note, f0, regime, SPL, ok windows of windows;
        ``parameters``: segment and ``"median ± SE"`` of :data:`SEGMENT_QUANTITIES` over the
        note's ok windows (the note's combined standard uncertainty, see
        :func:`mpipe.inversion.trust.notes.note_summary`).
    """
    notes = segments[segments["label"] == "note"] if "label" in segments else segments
    played = pd.DataFrame({
        "note": np.arange(1, len(notes) + 1),
        "segment": notes["segment"].astype(int).to_numpy(),
        "start_s": notes["start_s"].to_numpy(float),
        "duration_s": notes["duration_s"].to_numpy(float),
        "pitch": notes["note"].fillna("").astype(str).to_numpy(),
        "f0_hz": notes["f0_hz"].to_numpy(float),
        "regime": notes["regime"].fillna("").astype(str).to_numpy(),
        "spl_db": notes["spl_db"].to_numpy(float),
        "ok_windows": [f"{int(a)} of {int(b)}" for a, b in zip(notes["ok_windows"],
                                                             notes["windows"], strict=True)],
    })  # fmt: skip
    params = {"note": played["note"], "segment": played["segment"]}
    for name in SEGMENT_QUANTITIES:
        if f"{name}_median" not in notes:
            continue
        med, se = notes[f"{name}_median"].to_numpy(float), notes[f"{name}_se"]
        unit = unit_of(name)
        header = f"{name} [{unit}]" if unit and unit != "–" else name
        params[header] = [_median_se(m, e) for m, e in zip(med, se.to_numpy(float), strict=True)]
    return played, pd.DataFrame(params)


def _median_se(median: float, se: float) -> str:
    """``"1807 ± 3"``; ``"1807 ± ∞ (undetermined)"`` for an infinite SE.

    The value alone when no SE is claimed (NaN: a quantity held fixed, or no ok window).
    """
    if math.isinf(se):
        return f"{fmt(median, 4)} ± ∞ (undetermined)"
    return f"{fmt(median, 4)} ± {fmt(se, 2)}" if np.isfinite(se) else fmt(median, 4)


def _summary_section(
    records: dict, windows: pd.DataFrame, segments: pd.DataFrame | None = None
) -> Section:
    """Verdict, each note's result, words, take-level parameters, uncertainty, flags.

    The take-level parameter table is given for a take of one note only.
    """
    val = records["validation"].summary
    inv = records["inversion"].summary
    flags = flag_windows(windows)
    verdict = overall_verdict(str(val["verdict"]), windows, inv.get("take_checks", ()))
    params = parameter_summary(windows)
    med_res = inv.get("relative_residual_median")
    summary_text = (
        f"Impedance validation: {val.get('headline', val['verdict'].upper())} (band error "
        f"{fmt(val['band_error_db'], 3)} dB). {inv.get('status_line', '')}. A window is ok "
        "when the search met its tolerance, no parameter sits on a search bound and its "
        "residual is within a few times the take's best. Median relative residual of the "
        f"model pressure {fmt(med_res, 3)}. Air temperature: {_temperature_words(val, inv)}"
    )
    if val.get("failures"):
        summary_text += "\n\nValidation failures: " + "; ".join(val["failures"]) + "."
    if inv.get("take_checks"):
        summary_text += "\n\nTake-level checks: " + "; ".join(inv["take_checks"]) + "."
    uncertainty = uncertainty_summary(windows)
    if len(uncertainty):
        uncertainty.insert(1, "unit", [unit_of(n) for n in uncertainty["name"]])
    segments = pd.DataFrame() if segments is None else segments
    notes = segments[segments["label"] == "note"] if "label" in segments else segments
    summary_tables = []
    if len(notes):
        played, per_note = segment_tables(segments)
        summary_tables += [
            ("What was played, note by note: start (s), duration (s), nearest note and its "
             "deviation (cents), playing frequency (Hz), regime (from the bore's resonances), "
             "sound pressure level in the mouthpiece (dB re 20 µPa), ok windows.", played),
            ("Each note's own result: median over the note's ok windows ± its combined "
             "standard uncertainty (the budget of each note follows).", per_note),
            *budget_tables(notes),
        ]  # fmt: skip
    if len(notes) > 1:
        summary_text += (
            f"\n\nThe take holds {len(notes)} notes: each has its own result in the tables "
            "below; a median over the whole take would describe none of them and is not given (the "
            "uncertainty table below gives only each quantity's typical standard error of "
            "one window)."
        )
        if len(uncertainty):
            uncertainty = uncertainty.drop(
                columns=[c for c in ("median", "mad_sigma") if c in uncertainty]
            )
    else:
        summary_tables.append(
            (
                "Reed parameters over the take (ok windows): median, quartiles q25 and q75, "
                "interquartile range over the median (iqr_pct, %), extremes.",
                params,
            )
        )
    summary_tables += [
        (
            "Uncertainty (ok windows): median, mad_sigma (the scatter over windows: 1.4826 × "
            "their median absolute deviation), median standard error of one window, and the "
            "fraction of windows "
            "where the quantity is determined (relative standard error below "
            "inversion.determined_limit). An undetermined quantity is not measured by this "
            "take; see uncertainty_note in windows.csv. p_M = k y_m, γ = p_m / p_M, "
            "ζ = Z_c λ y_m √(2 / (ρ p_M)), f_r = √(k/m) / 2π, Q_r = 2π f_r / g.",
            uncertainty,
        ),
    ]
    if len(flags):
        summary_tables.append(("Windows that are not ok, with the reason.", flags))
    return Section("Summary", summary_text, verdict, (), tuple(summary_tables))


def _temperature_words(val: dict, inv: dict) -> str:
    """The two temperatures of a take in words: the front end's and the bore model's."""
    fit = inv.get("temperature") or {}
    front = f"{fmt(val['temperature_c'], 4)} °C from the wave separation"
    note = f" Note: {fit['note']}." if fit.get("note") else ""
    if fit.get("source") == "take fit":
        return (
            f"{front}; the bore model's, fitted to the playing with the reed in one fit of the "
            f"take, {fmt(fit['temperature_c'], 4)} ± {fmt(fit['temperature_se_c'], 2)} °C (used "
            "by the inversion and the resynthesis; its share of every standard error is the "
            f"budget's temperature component).{note}"
        )
    if fit.get("source") == "fit":
        return (
            f"{front}; the bore model's, fitted to the playing, {fmt(fit['temperature_c'], 4)}"
            f" ± {fmt(fit['temperature_se_c'], 2)} °C (used by the inversion and the "
            f"resynthesis; its uncertainty is in every standard error).{note}"
        )
    return (
        f"{front}, used by the inversion too: not fitted, so the standard errors leave out "
        f"the temperature's uncertainty.{note}"
    )


def _measurement_section(
    root: Path, records: dict, resonances: pd.DataFrame, harmonics: pd.DataFrame
) -> Section:
    """The impedance validation: verdict, propagation parameters, figures, compared values."""
    val = records["validation"].summary
    sep = records["separation"].summary
    t_lo, t_hi = sep["temperature_c_range"]
    return Section(
        "Measurement: impedance validation",
        f"The measured input impedance P/(Z0 U) at the mouthpiece is compared with the "
        f"calibration's bore ({val.get('bore', 'the theory of its geometry')}). Effective "
        "temperature from the wave separation "
        f"{fmt(val['temperature_c'])} °C (blocks span {fmt(t_lo)}–{fmt(t_hi)} °C), loss "
        f"scale {fmt(sep['loss_scale_median'], 3)}, Mach number {fmt(sep['mach_median'], 2)}"
        f"{'' if sep.get('theta', 'estimated') == 'estimated' else ' (' + sep['theta'] + ')'}. "
        + (f"{sep['drift_sentence']} " if sep.get("drift_sentence") else "")
        + f"Verdict: {val.get('headline', val['verdict'].upper())}"
        + (f" ({val['reason']})" if val.get("reason") else "")
        + "."
        + "".join(f"\nNote {line}." for line in val.get("note_lines", []))
        + _resonance_words(resonances)
        + "".join(f"\nWarning: {w}." for w in sep.get("warnings", []))
        + (
            "\nThe validation FAILED; the inversion was run anyway (--accept-failed-validation)."
            if val["verdict"] == "fail"
            else ""
        ),
        (val["verdict"].upper(), "pass" if val["passed"] else "fail"),
        (
            Figure(
                root / "validation" / "impedance.png",
                "Measured (H1 estimate) and "
                "theoretical normalised input impedance |Z/Z0| (dB) against frequency (Hz), "
                "with the squared coherence of p and u (–; paper Fig. 10).",
            ),
            Figure(
                root / "separation" / "blocks.png",
                "Propagation parameters tracked "
                "by the wave separation per block: effective temperature (°C), loss "
                "scale η (–) and Mach number of the mean flow (–), against time (s), with "
                "± 1 standard error bands: constant over the take when the data show no "
                "drift (one value with the pooled standard error), a line or a smoothed "
                "track when they do (the title says which).",
            ),
        ),  # fmt: skip
        _validation_tables(resonances, harmonics),
    )


def _validation_tables(resonances: pd.DataFrame, harmonics: pd.DataFrame) -> tuple:
    """The quantities the verdict compared: measured resonances and the note's harmonics."""
    tables = []
    measured = (
        "frequency_measured_hz" in resonances and resonances["frequency_measured_hz"].notna().any()
    )
    if measured:
        tables.append(("Resonances: theory against measurement (empty cells: no measured "
                       "peak within the matching distance).", resonances))  # fmt: skip
    if len(harmonics):
        tables.append(("Harmonics of the note: measured against theoretical impedance, "
                       "level (dB) and phase (°) errors, coherence; 'compared' marks those "
                       "the verdict counts.", harmonics))  # fmt: skip
    return tuple(tables)


def _resonance_words(resonances: pd.DataFrame) -> str:
    """A sentence when no resonance could be measured (a played note), else ""."""
    if "frequency_measured_hz" in resonances and resonances["frequency_measured_hz"].notna().any():
        return ""
    theory = ", ".join(fmt(f) for f in resonances.get("frequency_theory_hz", []))
    return (
        "\nNo resonance is measurable from this take (a played note excites its harmonics "
        f"only; theory at {theory} Hz): the verdict compares the harmonics below."
    )


def _parameters_section(
    root: Path, records: dict, windows: pd.DataFrame, segments: pd.DataFrame | None = None
) -> Section:
    """The reed parameters over time: the inversion's figures and the per-window table."""
    inv = records["inversion"].summary
    inv_root = root / "inversion"
    captions = {
        "tracks.png": "Reed parameters per window from step 2, and their combinations, against "
        "time (s), each panel in its SI unit (k Pa/m, S m², y_m m, p_m Pa, λ m, m kg/m², "
        "g 1/s, k_c Pa/m^alpha), with the fitted reed's mean opening h_mean (m) and the "
        "fraction of the time it is shut. Each axis is set by the ok windows; a window that "
        "is not ok and lies off that scale is a grey triangle at the edge (the panel title "
        "counts them). Bands: ±2 combined standard uncertainties (log space). The notes are "
        "shaded and numbered, and named above the figure with their pitch in Hz.",
        "flow_pressure.png": "Step 1 on a sustained ok window of the first note (its status in "
        "the title): volume flow u (m³/s) against the pressure difference Δp = p_m − p (Pa) "
        "over two periods, with each branch's quasi-static fit (lines) and its fit with the "
        "dp/dt term (dots, crosses) (paper Fig. 8).",
        "history.png": "The same window: best step-2 objective F2 (Pa) after each model "
        "evaluation (paper Fig. 7).",
    }
    inv_figs = tuple(
        Figure(inv_root / f, c) for f, c in captions.items() if (inv_root / f).exists()
    )
    played = root / "conditioning" / "segments.png"
    if played.exists():
        inv_figs = (
            Figure(played, "What was played: the mouthpiece level (dB re 20 µPa) with the "
                   "silence threshold, and the pitch (cents re A4) against time (s); the "
                   "notes found are shaded and numbered as in segments.csv (each note's "
                   "pitch in Hz and its name: the notes table and the tracks)."),
            *inv_figs,
        )  # fmt: skip
    return Section(
        "Reed parameters over time",
        f"Flow treated as "
        f"{'zero-mean (measured)' if inv['zero_mean_flow'] else 'carrying its mean (model)'}.",
        None,
        inv_figs,
        ((WINDOW_CAPTION, window_table(windows, segments)),),
    )


def _resynthesis_section(root: Path, records: dict) -> Section:
    """The resynthesis: its residual, each note's two periods and the overlays."""
    res = records["resynthesis"].summary
    return Section(
        "Resynthesis",
        "Relative residual of the resynthesised pressure over the inverted windows: "
        f"{fmt(res['relative_residual_p'], 3)}. The resynthesised pressure is in "
        "resynthesis/resynthesis.wav.",
        None,
        resynthesis_figures(root / "resynthesis"),
    )


def _run_section(records: dict, take_paths, cal_path, version: str, plan) -> Section:
    """The run: input files, mpipe version, stage timings and the window plan."""
    timings = pd.DataFrame(
        [{"stage": k, "status": r.status, "wall_s": r.wall_s} for k, r in records.items()]
    )
    return Section(
        "Run",
        f"Take: {', '.join(str(p) for p in take_paths)}. Calibration: {cal_path}.",
        ("mpipe " + version, "info"),
        (),
        (("Stage timings.", timings), ("Window plan (conditioning).", plan)),
    )


def plot_blocks(blocks: pd.DataFrame, path: Path, sentence: str = "") -> None:
    """The separation's propagation tracks (T, eta, Mach) with their 1-SE bands, as a PNG.

    ``blocks`` is the separation's ``blocks.csv`` table; ``sentence`` titles the figure
    (whether the data show a drift).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, sharex=True, figsize=(8, 6))
    for ax, col, se_col, label in zip(
        axes,
        ("temperature_c", "loss_scale", "mach"),
        ("temperature_se_c", "loss_scale_se", "mach_se"),
        ("effective temperature [°C]", "loss scale η [-]", "Mach number [-]"),
        strict=True,
    ):
        t, v, se = blocks["time_s"], blocks[col], blocks[se_col]
        ax.fill_between(t, v - se, v + se, alpha=0.3, lw=0, label="± 1 standard error")
        ax.plot(t, v, ".-", lw=1)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("time [s]")
    axes[0].legend(loc="best", fontsize=8)
    title = sentence or "Propagation parameters tracked by the wave separation"
    axes[0].set_title(textwrap.fill(title, 110), fontsize=8, y=1.0)
    fig.tight_layout()
    fig.savefig(path, dpi=110, format="png")
    plt.close(fig)


__all__ = [
    "flag_windows",
    "overall_verdict",
    "parameter_summary",
    "plot_blocks",
    "write_take_report",
]
