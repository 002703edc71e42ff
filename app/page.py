"""The pieces of handeye's self-contained HTML pages (``report.html`` of a calibration, `handeye.app.report`; the
monitor's shift report, `handeye.app.shift_record`): the style sheet (screen and print, A4 or Letter), matplotlib
figures as inline SVG, tables."""

from __future__ import annotations

import html
import io

REPORT_STYLE = """
body{font-family:system-ui,sans-serif;max-width:1100px;margin:1.5em auto;padding:0 1em;color:#222;line-height:1.35}
h1{font-size:1.45em;margin:.8em 0 .2em}h2{font-size:1.15em;margin-top:1.8em;border-bottom:1px solid #ccc}
.sub{color:#555;margin:0 0 1em}
table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #ccc;padding:.25em .6em;text-align:right;
vertical-align:top}th{background:#f3f3f3}td:first-child,th:first-child{text-align:left}
table.kv td:nth-child(2),table.kv th{text-align:left}table:not(.kv) td:not(:first-child){white-space:nowrap}
table.log{width:100%}table.log td,table.log td:not(:first-child),table.log th{white-space:normal;text-align:left}
pre,code{font-family:ui-monospace,Menlo,Consolas,monospace;font-size:.88em}
pre{margin:0;white-space:pre-wrap;overflow-wrap:anywhere}
.verdict{border-radius:6px;padding:.7em 1em;margin:0 0 .5em;border-left:10px solid}
.verdict.pass{background:#e8f5e8;border-color:#2a7d2a}.verdict.warn{background:#fff4d6;border-color:#e0a000}
.verdict.fail{background:#fbe3e3;border-color:#b22}
.verdict .level{font-weight:bold;font-size:1.3em;margin-right:.5em}
.verdict ul{margin:.4em 0 0 1.2em;padding:0}
.use{background:#eef3fb;border-left:4px solid #4a78c2;padding:.4em .8em}
figure.plot{margin:.5em 0}figure.plot svg{max-width:100%;height:auto}
figcaption,.note{color:#555;font-size:.9em}
table.signoff td{height:2.4em;min-width:14em}table.signoff td:first-child{min-width:0}
@page{margin:14mm}
@media print{body{max-width:none;margin:0;padding:0;font-size:10pt}h2{break-after:avoid}
figure.plot,tr,.verdict,.use{break-inside:avoid}figure.plot svg{max-height:120mm;width:auto}
.verdict,.use{-webkit-print-color-adjust:exact;print-color-adjust:exact}}
"""


def figure(*args, **kwargs):
    """``matplotlib.pyplot.subplots(*args, **kwargs)`` on the Agg backend, text kept as text in SVG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # Text as paths would triple the size; the page names no fonts it lacks.
    plt.rcParams["svg.fonttype"] = "none"
    return plt.subplots(*args, **kwargs)


def svg_of(fig) -> str:
    """A matplotlib figure as inline SVG (no XML header), closed afterwards."""
    import matplotlib.pyplot as plt

    buf = io.StringIO()
    fig.savefig(buf, format="svg", bbox_inches="tight")
    plt.close(fig)
    text = buf.getvalue()
    return text[text.index("<svg"):]


class Raw(str):
    """A table cell that is HTML already (escaped where it was built)."""


def table(head: list[str] | None, rows: list[list], cls: str = "") -> str:
    """A table; ``head`` None: no header row; ``cls="kv"``: a two-column table of names and values;
    ``cls="log"``: rows of sentences (alarms, outages) that wrap."""
    cells = "" if head is None else "<tr>" + "".join(f"<th>{html.escape(str(h))}</th>" for h in head) + "</tr>"
    body = "".join("<tr>" + "".join(f"<td>{c if isinstance(c, Raw) else html.escape(str(c))}</td>" for c in r)
                   + "</tr>" for r in rows)
    attr = f' class="{cls}"' if cls else ""
    return f"<table{attr}>{cells}{body}</table>"
