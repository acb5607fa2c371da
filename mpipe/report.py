"""A static HTML report per take: opens from the file system, no server, no scripts.

Images are linked by paths relative to the report, so the report and the stage folders
move together.
"""

from __future__ import annotations

import html
import os
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from mpipe.io import write_text_atomic

_STYLE = """
body { font-family: system-ui, sans-serif; max-width: 1100px; margin: 2em auto; color: #222;
       line-height: 1.45; padding: 0 1em; }
h1 { font-size: 1.6em; margin-bottom: 0.2em; }
h2 { border-bottom: 1px solid #ccc; padding-bottom: 0.2em; margin-top: 2em; }
.meta { color: #666; font-size: 0.9em; }
.verdict { display: inline-block; padding: 0.15em 0.6em; border-radius: 0.3em; font-weight: 600; }
.pass { background: #d9f2d9; color: #145214; }
.fail { background: #f8d7d7; color: #7a1414; }
.info { background: #e6eef8; color: #1c3d66; }
img { max-width: 100%; border: 1px solid #eee; margin: 0.5em 0; }
table { border-collapse: collapse; font-size: 0.85em; margin: 0.5em 0; }
th, td { border: 1px solid #ddd; padding: 0.2em 0.5em; text-align: right; }
th { background: #f4f4f4; }
.scroll { max-height: 28em; overflow: auto; }
"""


@dataclass(frozen=True)
class Section:
    """One section of the report.

    Attributes
    ----------
    title : str
        Heading.
    text : str
        Paragraph text (plain; escaped).
    badge : tuple of (str, str), optional
        ``(label, kind)`` shown after the heading; kind is ``pass``, ``fail`` or ``info``.
    images : tuple of Path
        PNG files to show, in order.
    tables : tuple of (str, DataFrame)
        Captioned tables.
    """

    title: str
    text: str = ""
    badge: tuple[str, str] | None = None
    images: tuple[Path, ...] = ()
    tables: tuple[tuple[str, pd.DataFrame], ...] = field(default=())


def render(title: str, meta: str, sections: list[Section], base: Path) -> str:
    """Render the report as one HTML string; image paths become relative to ``base``."""
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{html.escape(title)}</title><style>{_STYLE}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>",
        f'<p class="meta">{html.escape(meta)}</p>',
    ]
    for s in sections:
        badge = ""
        if s.badge:
            label, kind = s.badge
            badge = f' <span class="verdict {html.escape(kind)}">{html.escape(label)}</span>'
        parts.append(f"<h2>{html.escape(s.title)}{badge}</h2>")
        if s.text:
            for para in s.text.split("\n\n"):
                parts.append(f"<p>{html.escape(para)}</p>")
        for img in s.images:
            rel = Path(os.path.relpath(img, base)).as_posix()
            parts.append(f'<img src="{html.escape(rel)}" alt="{html.escape(Path(img).stem)}">')
        for caption, table in s.tables:
            parts.append(f"<h3>{html.escape(caption)}</h3>")
            parts.append('<div class="scroll">')
            parts.append(table.to_html(index=False, float_format=lambda v: f"{v:.6g}", border=0))
            parts.append("</div>")
    parts.append("</body></html>")
    return "\n".join(parts)


def write_report(path: str | Path, title: str, meta: str, sections: list[Section]) -> Path:
    """Write the report atomically to ``path`` (an ``.html`` file) and return the path."""
    path = Path(path)
    write_text_atomic(path, render(title, meta, sections, path.parent))
    return path
