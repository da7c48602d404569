"""A self-contained interactive HTML page (``report.html``): headings, text, sortable tables and
plotly figures, with plotly.js and the page's own style and script inline, so that it opens from
a file with no network access (docs/formats/report-html.md).

The page is assembled from blocks (:class:`Page`) and written atomically. Plotly is imported when
a page with a figure is written (for plotly.js), not with this module.
"""

from __future__ import annotations

import base64
from html import escape
from pathlib import Path

import numpy as np

from .._atomic import write_text_atomic
from .._json import json_line

__all__ = ["Page", "MAX_POINTS", "downsample"]

MAX_POINTS = 4000
"""Points a time-series trace keeps at most (:func:`downsample`): the page stays a few MB and fast
to zoom whatever the log's length."""

# the house colours of spaceid._figure_style, as CSS
MEASURED, MODEL, TRUE, REFERENCE, LIMIT, ANCHOR = "#262626", "#d62728", "#2ca02c", "#8c8c8c", "#ff7f0e", "#1f77b4"

_STYLE = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,Helvetica,Arial,sans-serif;color:#222;margin:0;
 background:#fff;line-height:1.45}
main{max-width:1180px;margin:0 auto;padding:16px 28px 48px}
h1{font-size:1.5em;margin:.6em 0 .2em}h2{font-size:1.2em;margin:1.6em 0 .5em;border-bottom:1px solid #ddd;
 padding-bottom:.2em}
p.meta{color:#666;font-size:.85em;margin-top:0}
.warn{background:#fff4e5;border-left:4px solid #ff7f0e;padding:.4em .8em;margin:.5em 0}
table{border-collapse:collapse;font-size:13px;margin:.4em 0}
td,th{padding:2px 10px;border-bottom:1px solid #eee;text-align:right;vertical-align:top}
td.t,th.t{text-align:left}
th{background:#f6f6f6;position:sticky;top:0}
table.sortable th{cursor:pointer;user-select:none}
table.sortable th[aria-sort=ascending]::after{content:" \\25B2";font-size:.7em}
table.sortable th[aria-sort=descending]::after{content:" \\25BC";font-size:.7em}
td.def{max-width:26em;overflow-wrap:anywhere;font-family:monospace;font-size:12px}
div.scroll{max-height:36em;overflow:auto;border:1px solid #eee}
figure{margin:1em 0 1.6em}figcaption{color:#444;font-size:.9em;margin-top:.2em}
img.static{max-width:100%}
code{font-size:.92em}
"""

# Sort a table.sortable by the clicked column: a cell with data-v by that number, else by its text
# (pi2 before pi10); a second click reverses. Cells without a value go last.
_SORT_SCRIPT = """
document.querySelectorAll("table.sortable").forEach(function(table){
  var heads = table.tHead.rows[0].cells;
  Array.prototype.forEach.call(heads, function(th, col){
    th.addEventListener("click", function(){
      var body = table.tBodies[0], rows = Array.prototype.slice.call(body.rows);
      var up = th.getAttribute("aria-sort") !== "ascending";
      Array.prototype.forEach.call(heads, function(h){ h.removeAttribute("aria-sort"); });
      th.setAttribute("aria-sort", up ? "ascending" : "descending");
      function key(row){
        var cell = row.cells[col], v = cell.getAttribute("data-v");
        return v === null ? cell.textContent.trim() : (v === "" ? null : parseFloat(v));
      }
      rows.sort(function(a, b){
        var x = key(a), y = key(b);
        if (x === null || y === null) return (x === null) - (y === null);
        var c = typeof x === "number" && typeof y === "number" ? x - y
                : String(x).localeCompare(String(y), undefined, {numeric: true});
        return up ? c : -c;
      });
      rows.forEach(function(r){ body.appendChild(r); });
    });
  });
});
"""

_CONFIG = {"displaylogo": False, "responsive": True, "toImageButtonOptions": {"format": "png", "scale": 2}}


_SCRIPT_UNSAFE = {"<": "\\u003c", ">": "\\u003e", "/": "\\u002f", "\u2028": "\\u2028", "\u2029": "\\u2029"}


def _script_json(value) -> str:
    """``value`` as compact JSON (:func:`~spaceid._json.json_line`) that is safe inside a ``<script>``: the
    characters Plotly's own writer escapes there escaped (a name holding ``</script>`` cannot end it)."""
    text = json_line(value)
    for char, escaped in _SCRIPT_UNSAFE.items():
        text = text.replace(char, escaped)
    return text


def downsample(t, *ys, max_points: int = MAX_POINTS) -> tuple:
    """Every series thinned to at most ``max_points`` samples, keeping the extremes: the time span
    cut into ``max_points / 2`` equal bins of samples, each bin's smallest and largest value of the
    first series ``ys[0]`` kept (in time order), so that peaks and spikes stay visible.

    Parameters
    ----------
    t : array_like of shape (n,)
    *ys : array_like of shape (n,)
    max_points : int

    Returns
    -------
    tuple
        ``(t, *ys, shown)``: the kept samples of each and whether any was dropped.
    """
    t = np.asarray(t, float)
    ys = [np.asarray(y, float) for y in ys]
    if t.size <= max_points:
        return (t, *ys, False)
    bins = np.array_split(np.arange(t.size), max_points // 2)
    lead = np.nan_to_num(ys[0], nan=0.0) if ys else t
    keep = np.unique(np.concatenate([[b[np.argmin(lead[b])], b[np.argmax(lead[b])]] for b in bins]))
    return (t[keep], *(y[keep] for y in ys), True)


def thinning_note(n_total: int, n_shown: int) -> str:
    """The caption's note on a thinned series (empty when nothing was dropped)."""
    if n_shown >= n_total:
        return ""
    return (f" Time series thinned for the page: {n_shown} of {n_total} samples shown per trace (the smallest and "
            f"largest of each of {MAX_POINTS // 2} equal bins); the CSV files hold every sample.")


def number(x, digits: int = 6) -> str:
    """A number as a table shows it ('-' for none or not finite)."""
    if x is None or (isinstance(x, (float, np.floating)) and not np.isfinite(x)):
        return "-"
    if isinstance(x, (bool, np.bool_)):
        return str(bool(x))
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    if isinstance(x, (float, np.floating)):
        return f"{x:.{digits}g}"
    if isinstance(x, dict):
        return ", ".join(f"{k} {number(v, digits)}" for k, v in x.items())
    if isinstance(x, (list, tuple, np.ndarray)):
        return ", ".join(number(v, digits) for v in np.asarray(x, dtype=object).reshape(-1).tolist())
    return str(x)


def _cell(value) -> str:
    """A table cell: numbers carry their value (``data-v``) for sorting and are right-aligned."""
    if isinstance(value, tuple):  # (shown text, sort value)
        shown, v = value
        v = "" if v is None or not np.isfinite(v) else repr(float(v))
        return f'<td data-v="{v}">{escape(shown)}</td>'
    if isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_)):
        v = repr(float(value)) if np.isfinite(value) else ""
        return f'<td data-v="{v}">{escape(number(value))}</td>'
    return f'<td class="t">{escape(number(value))}</td>'


SHORT = 90
"""Characters of a long text cell (a definition) shown before it is folded."""


def _long_cell(text: str) -> str:
    """A cell of long text: folded after :data:`SHORT` characters, unfolded by a click."""
    if len(text) <= SHORT:
        return f'<td class="t def">{escape(text)}</td>'
    return (f'<td class="t def"><details><summary>{escape(text[:SHORT])}...</summary>{escape(text)}</details>'
            "</td>")


class Page:
    """An HTML report page built block by block, written by :meth:`write`."""

    def __init__(self, title: str, subtitle: str = ""):
        self.title, self.subtitle = title, subtitle
        self._blocks: list = []
        self._figures = 0

    def heading(self, text: str) -> None:
        self._blocks.append(f"<h2>{escape(text)}</h2>")

    def text(self, text: str, *, warning: bool = False) -> None:
        """A paragraph (``warning``: set apart as one)."""
        self._blocks.append(f'<p{" class=warn" if warning else ""}>{escape(text)}</p>')

    def bullets(self, items) -> None:
        self._blocks.append("<ul>" + "".join(f"<li>{escape(i)}</li>" for i in items) + "</ul>")

    def table(self, header, rows, *, sortable: bool = True, text_columns: int = 1, wide_columns=()) -> None:
        """A table; ``rows`` of values (numbers are right-aligned and sort by value; a pair
        ``(text, value)`` shows the text and sorts by the value; text is left-aligned); the first
        ``text_columns`` headers are left-aligned; ``wide_columns``: indices of long text
        (definitions), folded after :data:`SHORT` characters."""
        head = "".join(f'<th{" class=t" if i < text_columns else ""} scope="col">{escape(h)}</th>'
                       for i, h in enumerate(header))
        body = []
        for row in rows:
            cells = [_cell(v) if i not in wide_columns else _long_cell(str(v))
                     for i, v in enumerate(row)]  # fmt: skip
            body.append("<tr>" + "".join(cells) + "</tr>")
        cls = ' class="sortable"' if sortable else ""
        table = f"<table{cls}><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"
        self._blocks.append(f'<div class="scroll">{table}</div>' if len(rows) > 25 else table)

    def figure(self, fig, caption: str) -> None:
        """A plotly figure, Plotly's plain dict ``{"data": [...], "layout": {...}}`` (NumPy arrays allowed) or a
        graph object, drawn by the page's one plotly.js: the ``Plotly.newPlot`` call that ``plotly.io.to_html``
        writes, with the JSON made safe inside a script as it does, without importing Plotly's graph objects
        for it (0.08 s of a first ``identify``'s page)."""
        self._figures += 1
        fig = fig if isinstance(fig, dict) else fig.to_plotly_json()
        key = f"figure-{self._figures}"
        height = fig.get("layout", {}).get("height")
        args = ", ".join(_script_json(v) for v in (key, fig.get("data", []), fig.get("layout", {}), _CONFIG))
        div = (f'<div id="{key}" class="plotly-graph-div" style="height:{f"{height}px" if height else "100%"}; '
               f'width:100%;"></div><script type="text/javascript">Plotly.newPlot({args})</script>')
        self._blocks.append(f'<figure class="plot">{div}<figcaption>{escape(caption)}</figcaption></figure>')

    def image(self, path, caption: str) -> None:
        """A PNG figure embedded in the page (a figure with no interactive form)."""
        data = base64.b64encode(Path(path).read_bytes()).decode("ascii")
        self._blocks.append(f'<figure><img class="static" alt="{escape(caption)}" src="data:image/png;base64,{data}">'
                            f"<figcaption>{escape(caption)}</figcaption></figure>")

    def html(self) -> str:
        """The whole page: one plotly.js bundle in the head when the page has a figure."""
        from importlib.metadata import version

        bundle = ""
        if self._figures:
            from plotly.offline import get_plotlyjs

            bundle = f'<script type="text/javascript">{get_plotlyjs()}</script>'
        sub = f'<p class="meta">{escape(self.subtitle)}</p>' if self.subtitle else ""
        return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><meta name="viewport" '
                f'content="width=device-width,initial-scale=1"><meta name="generator" content="spaceid '
                f'{escape(version("spaceid"))}"><title>{escape(self.title)}</title><style>{_STYLE}</style>{bundle}</head>'
                f"<body><main><h1>{escape(self.title)}</h1>{sub}{''.join(self._blocks)}</main>"
                f"<script>{_SORT_SCRIPT}</script></body></html>\n")

    def write(self, path) -> Path:
        """Write the page to ``path`` atomically; returns the path."""
        path = Path(path)
        write_text_atomic(path, self.html())
        return path
