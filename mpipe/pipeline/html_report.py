"""A self-contained HTML report: sections of text, numbered figures and captioned tables.

Everything is inside the file: images are embedded as base64 ``data:`` URIs, the style sheet
is inline, there are no scripts and no links to other files. Figures and tables are numbered
and captioned, every table header carries its unit (from :func:`mpipe.core.units.label`)
and numbers are rounded to a few significant digits (:func:`fmt`). What a take's report
holds is in :mod:`mpipe.pipeline.report`.
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
from mpipe.core.units import label

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
    """A number rounded to ``digits`` significant digits; "–" missing, "∞" infinite.

    An infinite value is an undetermined standard error: never "–", which means not evaluated.
    """
    if value is None:
        return "–"
    if isinstance(value, bool | np.bool_):
        return "yes" if value else "no"
    if isinstance(value, int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        v = float(value)
        if math.isinf(v):
            return "∞" if v > 0 else "−∞"
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


__all__ = ["Figure", "Section", "data_uri", "fmt", "html_table", "render", "write_report"]
