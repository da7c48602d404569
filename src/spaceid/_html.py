"""HTML tables for the records' notebook views (``_repr_html_``): self-contained, every text escaped."""

from __future__ import annotations

import html

__all__ = ["html_table", "html_view"]


def html_table(headers, rows) -> str:
    """An HTML table of ``rows`` (sequences of cells, shown with ``str``) under ``headers``."""
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in headers)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def html_view(title: str, *sections) -> str:
    """A titled block of ``(heading, html)`` sections (``html`` already escaped, e.g. tables)."""
    parts = "".join(f"<p><b>{html.escape(heading)}</b></p>{content}" for heading, content in sections)
    return f"<div><p><b>{html.escape(title)}</b></p>{parts}</div>"
