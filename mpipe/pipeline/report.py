"""The HTML report of a take: one self-contained file a scientist can send.

Everything is inside the file: images are embedded as base64 ``data:`` URIs, the style sheet
is inline, there are no scripts and no links to other files. The report opens with a summary
(verdict, parameter medians with their spread, failed and flagged windows); figures and
tables are numbered and captioned, every table header carries its unit (from
:func:`mpipe.core.units.unit_of`) and numbers are rounded to a few significant digits.
"""

from __future__ import annotations

import base64
import html
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from mpipe.core.io import write_text_atomic
from mpipe.core.units import label, unit_of

#: Significant digits of the numbers shown in the report.
DIGITS = 4

_STYLE = """
body { font-family: system-ui, sans-serif; max-width: 1100px; margin: 2em auto; color: #222;
       line-height: 1.45; padding: 0 1em; }
h1 { font-size: 1.6em; margin-bottom: 0.2em; }
h2 { border-bottom: 1px solid #ccc; padding-bottom: 0.2em; margin-top: 2em; }
.meta { color: #666; font-size: 0.9em; }
.verdict { display: inline-block; padding: 0.15em 0.6em; border-radius: 0.3em; font-weight: 600; }
.pass { background: #d9f2d9; color: #145214; }
.fail { background: #f8d7d7; color: #7a1414; }
.check { background: #fbecc6; color: #6b4a00; }
.info { background: #e6eef8; color: #1c3d66; }
.summary { border: 1px solid #ccc; border-radius: 0.4em; padding: 0.5em 1.2em;
           background: #fafafa; }
figure { margin: 1.2em 0; }
figure img { max-width: 100%; border: 1px solid #eee; }
figcaption, caption { font-size: 0.9em; color: #333; text-align: left; padding: 0.3em 0; }
table { border-collapse: collapse; font-size: 0.85em; margin: 0.5em 0; }
th, td { border: 1px solid #ddd; padding: 0.2em 0.5em; text-align: right; }
th { background: #f4f4f4; }
td.text { text-align: left; }
.scroll { max-height: 28em; overflow: auto; }
"""


@dataclass(frozen=True)
class Figure:
    """A figure of the report.

    Attributes
    ----------
    path : Path
        PNG file, embedded into the report.
    caption : str
        What the figure shows, with units (plain text; escaped).
    """

    path: Path
    caption: str = ""


@dataclass(frozen=True)
class Section:
    """One section of the report.

    Attributes
    ----------
    title : str
        Heading.
    text : str
        Paragraph text (plain; escaped); paragraphs are separated by blank lines.
    badge : tuple of (str, str), optional
        ``(label, kind)`` shown after the heading; kind is ``pass``, ``fail``, ``check``
        or ``info``.
    images : tuple of Figure or Path
        Figures, in order; a bare path gets its file name as caption.
    tables : tuple of (str, DataFrame)
        Captioned tables; headers get their units from the column names.
    """

    title: str
    text: str = ""
    badge: tuple[str, str] | None = None
    images: tuple[Figure | Path, ...] = ()
    tables: tuple[tuple[str, pd.DataFrame], ...] = field(default=())


def fmt(value, digits: int = DIGITS) -> str:
    """A number rounded to ``digits`` significant digits; "–" for a missing value."""
    if value is None:
        return "–"
    if isinstance(value, bool | np.bool_):
        return "yes" if value else "no"
    if isinstance(value, int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        v = float(value)
        if not math.isfinite(v):
            return "–"
        if v == int(v) and abs(v) < 10**digits:
            return str(int(v))
        return f"{v:.{digits}g}"
    return str(value)


def html_table(table: pd.DataFrame, caption: str = "", digits: int = DIGITS) -> str:
    """A DataFrame as an HTML table: unit in every header, rounded numbers, escaped text."""
    head = "".join(f"<th>{html.escape(label(str(c)))}</th>" for c in table.columns)
    rows = []
    for values in table.itertuples(index=False):
        cells = []
        for v in values:
            text_cell = isinstance(v, str)
            cls = ' class="text"' if text_cell else ""
            cells.append(f"<td{cls}>{html.escape(fmt(v, digits))}</td>")
        rows.append("<tr>" + "".join(cells) + "</tr>")
    cap = f"<caption>{html.escape(caption)}</caption>" if caption else ""
    return f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{''.join(rows)}</tbody></table>"


def data_uri(path: str | Path) -> str:
    """The file as a ``data:image/png;base64,...`` URI."""
    payload = base64.b64encode(Path(path).read_bytes()).decode("ascii")
    return f"data:image/png;base64,{payload}"


def render(title: str, meta: str, sections: list[Section], summary: Section | None = None) -> str:
    """Render the report as one self-contained HTML string.

    Parameters
    ----------
    title : str
        Page title and heading.
    meta : str
        Line under the title (date, version).
    sections : list of Section
        Body, in order.
    summary : Section, optional
        Shown first, in a box.

    Returns
    -------
    str
    """
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{html.escape(title)}</title><style>{_STYLE}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>",
        f'<p class="meta">{html.escape(meta)}</p>',
    ]
    counters = {"figure": 0, "table": 0}
    for i, s in enumerate(([summary] if summary else []) + list(sections)):
        boxed = summary is not None and i == 0
        if boxed:
            parts.append('<div class="summary">')
        badge = ""
        if s.badge:
            text, kind = s.badge
            badge = f' <span class="verdict {html.escape(kind)}">{html.escape(text)}</span>'
        parts.append(f"<h2>{html.escape(s.title)}{badge}</h2>")
        for para in s.text.split("\n\n") if s.text else ():
            parts.append(f"<p>{html.escape(para)}</p>")
        for caption, table in s.tables:
            counters["table"] += 1
            parts.append('<div class="scroll">')
            parts.append(html_table(table, f"Table {counters['table']}. {caption}"))
            parts.append("</div>")
        for fig in s.images:
            fig = fig if isinstance(fig, Figure) else Figure(Path(fig), Path(fig).stem)
            counters["figure"] += 1
            cap = f"Figure {counters['figure']}. {fig.caption}"
            parts.append(
                f'<figure><img src="{data_uri(fig.path)}" alt="{html.escape(cap)}">'
                f"<figcaption>{html.escape(cap)}</figcaption></figure>"
            )
        if boxed:
            parts.append("</div>")
    parts.append("</body></html>")
    return "\n".join(parts)


def write_report(
    path: str | Path,
    title: str,
    meta: str,
    sections: list[Section],
    summary: Section | None = None,
) -> Path:
    """Write the report atomically to ``path`` (an ``.html`` file) and return the path."""
    path = Path(path)
    write_text_atomic(path, render(title, meta, sections, summary))
    return path


#: Reed parameters summarised at the top of a take's report, in this order.
SUMMARY_PARAMETERS = ("k", "S", "y_m", "p_m", "lam", "m", "g", "k_c")


def parameter_summary(windows: pd.DataFrame) -> pd.DataFrame:
    """Median and spread of each reed parameter over the windows with status ok.

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
    """Windows whose status is not ok, with the reason (see :mod:`mpipe.inversion.status`).

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
            "reason": [("" if pd.isna(r) else str(r)) for r in bad["status_reason"]],
        }
    )


def overall_verdict(validation: str | bool, windows: pd.DataFrame) -> tuple:
    """``(label, kind)`` of the take: FAIL, CHECK or PASS, with the reason in the label.

    ``validation`` is the validation's verdict (``"pass"``, ``"fail"``, ``"cannot-verify"``)
    or a bool (passed).
    """
    if isinstance(validation, bool):
        validation = "pass" if validation else "fail"
    n = len(windows)
    n_ok = int((windows["status"] == "ok").sum()) if n else 0
    if validation == "fail":
        return "FAIL: the impedance validation failed", "fail"
    if n_ok == 0:
        return "FAIL: no window has status ok (no usable result)", "fail"
    if validation != "pass":
        return "CHECK: the impedance validation could not verify the measurement", "check"
    if n_ok < n:
        return f"CHECK: {n_ok} of {n} windows ok, {n - n_ok} not ok (see their reasons)", "check"
    return f"PASS: validation passed, all {n} windows ok", "pass"


#: Columns of the per-window table shown in a take's report.
WINDOW_COLUMNS = ("window", "t_start_s", "status", "k", "S", "y_m", "p_m", "m", "g", "lam",
                  "k_c", "f2", "relative_residual", "n_evaluations", "status_reason")  # fmt: skip


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
    val = records["validation"].summary
    inv = records["inversion"].summary
    res = records["resynthesis"].summary
    sep = records["separation"].summary
    windows = _read_csv(root / "inversion" / "windows.csv")
    resonances = _read_csv(root / "validation" / "validation.csv")
    plan = _read_csv(root / "conditioning" / "plan.csv")
    flags = flag_windows(windows)
    verdict = overall_verdict(str(val["verdict"]), windows)
    params = parameter_summary(windows)
    med_res = inv.get("relative_residual_median")
    summary_text = (
        f"Impedance validation: {val['verdict'].upper()} (band error "
        f"{fmt(val['band_error_db'], 3)} dB). {inv.get('status_line', '')}. A window is ok "
        "when the search met its tolerance, no parameter sits on a search bound and its "
        "residual is within a few times the take's best. Median relative residual of the "
        f"model pressure {fmt(med_res, 3)}. Effective air temperature "
        f"{fmt(val['temperature_c'], 4)} °C. "
        "The spread is the interquartile range (q25–q75) over the ok windows."
    )
    if val.get("failures"):
        summary_text += "\n\nValidation failures: " + "; ".join(val["failures"]) + "."
    from mpipe.inversion.coverage import summary as uncertainty_summary

    uncertainty = uncertainty_summary(windows)
    if len(uncertainty):
        uncertainty.insert(1, "unit", [unit_of(n) for n in uncertainty["name"]])
    summary_tables = [
        ("Reed parameters over the take (ok windows): median, interquartile spread.", params),
        (
            "Uncertainty (ok windows): median, spread over windows (1.4826 × median absolute "
            "deviation), median standard error of one window, and the fraction of windows "
            "where the quantity is determined (relative standard error below "
            "inversion.determined_limit). An undetermined quantity is not measured by this "
            "take; see uncertainty_note in windows.csv. p_M = k y_m, γ = p_m / p_M, "
            "ζ = Z_c λ y_m √(2 / (ρ p_M)), f_r = √(k/m) / 2π, Q_r = 2π f_r / g.",
            uncertainty,
        ),
    ]
    if len(flags):
        summary_tables.append(("Windows that are not ok, with the reason.", flags))
    summary = Section("Summary", summary_text, verdict, (), tuple(summary_tables))

    inv_root = root / "inversion"
    captions = {
        "tracks.png": "Reed parameters per window from step 2 against time (s); each panel "
        "in its SI unit (k Pa/m, S m², y_m m, p_m Pa, λ m, m kg/m², g 1/s, k_c Pa/m²).",
        "flow_pressure.png": "First inverted window: volume flow u (m³/s) against the "
        "pressure difference Δp = p_m − p (Pa), with the step-1 fits of the closing and "
        "opening branches (paper Fig. 8).",
        "history.png": "First inverted window: best step-2 objective F2 (Pa) after each "
        "model evaluation (paper Fig. 7).",
    }
    inv_figs = tuple(
        Figure(inv_root / f, c) for f, c in captions.items() if (inv_root / f).exists()
    )
    overlays = tuple(
        Figure(p, "Target (measured) and resynthesised mouthpiece pressure (Pa) and flow "
               f"(m³/s) over one window ({p.stem.replace('_', ' ')}; paper Figs. 9, 11).")
        for p in sorted((root / "resynthesis").glob("overlay_*.png"))
    )  # fmt: skip
    show = [c for c in WINDOW_COLUMNS if c in windows.columns]
    timings = pd.DataFrame(
        [{"stage": k, "status": r.status, "wall_s": r.wall_s} for k, r in records.items()]
    )
    t_lo, t_hi = sep["temperature_c_range"]
    sections = [
        Section(
            "Measurement: impedance validation",
            f"The measured input impedance P/(Z0 U) at the mouthpiece is compared with the "
            f"theory of the calibration's bore. Effective temperature from the wave separation "
            f"{fmt(val['temperature_c'])} °C (blocks span {fmt(t_lo)}–{fmt(t_hi)} °C), loss "
            f"scale {fmt(sep['loss_scale_median'], 3)}, Mach number {fmt(sep['mach_median'], 2)}"
            f"{'' if sep.get('theta', 'estimated') == 'estimated' else ' (' + sep['theta'] + ')'}. "
            f"Verdict: {val['verdict'].upper()}"
            + (f" ({val['reason']})" if val.get("reason") else "")
            + "."
            + "".join(f"\nWarning: {w}." for w in sep.get("warnings", []))
            + (
                "\nThe validation FAILED; the inversion was run anyway "
                "(--accept-failed-validation)."
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
                    "scale η (–) and Mach number of the mean flow (–), against time (s).",
                ),
            ),  # fmt: skip
            (
                (
                    "Resonances: theory against measurement (empty cells: no measured peak "
                    "within the matching distance).",
                    resonances,
                ),
            ),  # fmt: skip
        ),
        Section(
            "Reed parameters over time",
            f"Flow treated as "
            f"{'zero-mean (measured)' if inv['zero_mean_flow'] else 'carrying its mean (model)'}.",
            None,
            inv_figs,
            (("Per-window results.", windows[show]),),
        ),
        Section(
            "Resynthesis",
            "Relative residual of the resynthesised pressure over the inverted windows: "
            f"{fmt(res['relative_residual_p'], 3)}. The resynthesised pressure is in "
            "resynthesis/resynthesis.wav.",
            None,
            overlays,
        ),
        Section(
            "Run",
            f"Take: {', '.join(str(p) for p in take_paths)}. Calibration: {cal_path}.",
            ("mpipe " + version, "info"),
            (),
            (("Stage timings.", timings), ("Window plan (conditioning).", plan)),
        ),
    ]
    return write_report(root / "report.html", f"mpipe report: {name}", when, sections, summary)


__all__ = [
    "Figure",
    "Section",
    "data_uri",
    "flag_windows",
    "fmt",
    "html_table",
    "overall_verdict",
    "parameter_summary",
    "render",
    "write_report",
    "write_take_report",
]
