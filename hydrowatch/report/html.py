"""A self-contained HTML report: headings, paragraphs, tables and PNG plots embedded as base64."""

from __future__ import annotations

import base64
import html
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

_STYLE = """body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}
table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #bbb;padding:2px 6px;font-size:0.85em}
th{background:#eee}img{max-width:100%;margin:0.5em 0}code{background:#f4f4f4}"""


@dataclass
class Section:
    """One section: a heading, then paragraphs, tables and images in the order added."""

    title: str
    parts: list[str] = field(default_factory=list)

    def text(self, paragraph: str) -> Section:
        """Add a paragraph (escaped)."""
        self.parts.append(f"<p>{html.escape(paragraph)}</p>")
        return self

    def table(self, header: Sequence[Any], rows: Sequence[Sequence[Any]]) -> Section:
        """Add a table; floats are shown with 4 significant digits."""
        head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
        body = "".join("<tr>" + "".join(f"<td>{html.escape(_cell(c))}</td>" for c in row) + "</tr>" for row in rows)
        self.parts.append(f"<table><tr>{head}</tr>{body}</table>")
        return self

    def image(self, png: bytes, alt: str) -> Section:
        """Add a PNG, embedded."""
        data = base64.b64encode(png).decode()
        self.parts.append(f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{data}">')
        return self


def _cell(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    return "" if value is None else str(value)


def write_html(path: str | Path, title: str, sections: Sequence[Section]) -> Path:
    """Write the report to ``path`` (folders created); returns the path."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    body = "".join(f"<h2>{html.escape(s.title)}</h2>{''.join(s.parts)}" for s in sections)
    p.write_text(f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
                 f"<style>{_STYLE}</style></head><body><h1>{html.escape(title)}</h1>{body}</body></html>",
                 encoding="utf-8")
    return p
