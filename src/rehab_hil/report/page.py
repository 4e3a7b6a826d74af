"""One self-contained HTML file: plotly.js inlined (gzip + base64, unpacked by the browser's own
``DecompressionStream``: 1.9 MB instead of 4.8 MB), each figure's JSON, tables, no network.

When every plot is drawn the page sets ``<body data-report="drawn" data-drawn-ms=...>`` (the time
since navigation start); on an error ``data-report="failed"``, the error shown on the page and
logged to the console. Tests and the benchmark read these (``rehab_hil.report.browser``)."""

from __future__ import annotations

import base64
import functools
import gzip
import html
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import plotly.graph_objects as go

from rehab_hil.outputs import replacing

__all__ = ["Page", "plotly_js_gz_b64", "table"]

_LOADER = """
(async () => {
  const body = document.body;
  try {
    if (typeof DecompressionStream === 'undefined')
      throw new Error('this browser cannot unpack the inlined plotly.js (no DecompressionStream): '
                      + 'open the report in a current Chromium, Firefox or Safari');
    const b64 = document.getElementById('plotly-gz').textContent.trim();
    const raw = atob(b64);
    const bytes = new Uint8Array(raw.length);
    for (let i = 0; i < raw.length; i++) bytes[i] = raw.charCodeAt(i);
    const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream('gzip'));
    const js = await new Response(stream).blob();
    body.dataset.unpackedMs = performance.now().toFixed(0);
    const url = URL.createObjectURL(new Blob([js], {type: 'text/javascript'}));
    await new Promise((resolve, reject) => {  // a script from a blob: URL compiles off the main thread
      const s = document.createElement('script');
      s.onload = resolve;
      s.onerror = () => reject(new Error('the unpacked plotly.js did not load'));
      s.src = url;
      document.head.appendChild(s);
    });
    URL.revokeObjectURL(url);
    body.dataset.plotlyMs = performance.now().toFixed(0);
    const divs = [...document.querySelectorAll('div.plot')];
    await Promise.all(divs.map(d => {
      const fig = JSON.parse(document.getElementById(d.id + '-data').textContent);
      return Plotly.newPlot(d, fig.data, fig.layout, {responsive: true, displaylogo: false});
    }));
    body.dataset.plots = String(divs.length);
    body.dataset.drawnMs = performance.now().toFixed(0);
    body.dataset.report = 'drawn';
  } catch (e) {
    body.dataset.report = 'failed';
    document.getElementById('report-error').textContent = 'The plots could not be drawn: ' + e;
    console.error(e);
  }
})();
"""

_STYLE = """
body { font-family: system-ui, sans-serif; margin: 1.5em auto; max-width: 1300px; color: #222; padding: 0 1em; }
h1 { font-size: 1.5em; margin-bottom: 0.2em; } h2 { font-size: 1.2em; margin-top: 1.6em; }
.sub { color: #555; margin-top: 0; }
table { border-collapse: collapse; margin: 0.5em 0; font-size: 0.9em; }
th, td { border: 1px solid #ddd; padding: 3px 8px; text-align: right; }
th { background: #f3f3f3; } td.l, th.l { text-align: left; }
.note { background: #fff7e0; border-left: 4px solid #e0a000; padding: 4px 10px; margin: 4px 0; }
#report-error { color: #b00; font-weight: bold; }
.grid { display: grid; grid-template-columns: max-content auto; gap: 2px 16px; font-size: 0.9em; }
.grid div:nth-child(odd) { color: #555; }
details pre { background: #f6f6f6; padding: 8px; overflow-x: auto; font-size: 0.8em; }
"""


@functools.lru_cache(maxsize=1)
def plotly_js_gz_b64() -> str:
    """plotly.py's own plotly.min.js, gzip'd and base64'd (computed once per process)."""
    from plotly.offline import get_plotlyjs

    return base64.b64encode(gzip.compress(get_plotlyjs().encode("utf-8"), 9, mtime=0)).decode("ascii")


def _fmt(v: Any, digits: int = 4) -> str:
    if isinstance(v, float):
        return "–" if not math.isfinite(v) else f"{v:.{digits}g}"
    if v is None:
        return "–"
    return str(v)


def table(header: Sequence[str], rows: Sequence[Sequence[Any]], left: int = 1) -> str:
    """An HTML table; the first ``left`` columns left-aligned, numbers to 4 significant digits."""
    def cell(tag: str, i: int, v: Any) -> str:
        cls = ' class="l"' if i < left else ""
        return f"<{tag}{cls}>{html.escape(_fmt(v))}</{tag}>"

    head = "".join(cell("th", i, h) for i, h in enumerate(header))
    body = "".join("<tr>" + "".join(cell("td", i, v) for i, v in enumerate(r)) + "</tr>" for r in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


@dataclass
class Page:
    """Build the page in order: headings, text, tables, figures; ``html()`` the file's text."""

    title: str

    def __post_init__(self) -> None:
        self._parts: list[str] = []
        self._figures: list[str] = []

    def heading(self, text: str, level: int = 2) -> None:
        self._parts.append(f"<h{level}>{html.escape(text)}</h{level}>")

    def text(self, text: str, cls: str = "") -> None:
        c = f' class="{cls}"' if cls else ""
        self._parts.append(f"<p{c}>{html.escape(text)}</p>")

    def note(self, text: str) -> None:
        self._parts.append(f'<div class="note">{html.escape(text)}</div>')

    def raw(self, fragment: str) -> None:
        """Trusted HTML built by this package (tables, grids)."""
        self._parts.append(fragment)

    def facts(self, pairs: Sequence[tuple[str, Any]]) -> None:
        """A two-column grid of label and value."""
        cells = "".join(f"<div>{html.escape(k)}</div><div>{html.escape(_fmt(v))}</div>" for k, v in pairs)
        self._parts.append(f'<div class="grid">{cells}</div>')

    def details(self, summary: str, text: str) -> None:
        self._parts.append(f"<details><summary>{html.escape(summary)}</summary><pre>{html.escape(text)}</pre>"
                           "</details>")

    def figure(self, fig: go.Figure) -> None:
        fid = f"fig{len(self._figures)}"
        data = fig.to_json().replace("</", "<\\/")  # never closes the script element early
        self._figures.append(f'<script type="application/json" id="{fid}-data">{data}</script>')
        self._parts.append(f'<div class="plot" id="{fid}"></div>')

    @property
    def n_figures(self) -> int:
        return len(self._figures)

    def html(self) -> str:
        return "\n".join([
            "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
            '<meta name="viewport" content="width=device-width, initial-scale=1">',
            f"<title>{html.escape(self.title)}</title><style>{_STYLE}</style></head>",
            '<body data-report="loading">', f"<h1>{html.escape(self.title)}</h1>",
            '<p id="report-error"></p>', *self._parts, *self._figures,
            f'<script type="application/octet-stream" id="plotly-gz">{plotly_js_gz_b64()}</script>',
            f"<script>{_LOADER}</script>", "</body></html>", ""])

    def write(self, path: str | Path) -> Path:
        """Write the page (``OSError`` is the caller's to word)."""
        path = Path(path)
        html = self.html()
        with replacing(path) as tmp:  # whole or not at all (Ctrl-C, a full disk)
            tmp.write_text(html, encoding="utf-8")
        return path
