"""One self-contained, printable HTML page of a :class:`~skyrig.report.model.ReportData`.

Figures are embedded as ``data:image/png;base64`` URIs; the page has no link to anything outside itself (no
scripts, fonts, style sheets or images by URL).  A print style sheet (A4, no page breaks inside a table row or a
figure, headings kept with what follows) makes the browser's "print to PDF" the signed copy.
"""

from __future__ import annotations

import base64
import html
import os
from typing import Any

from skyrig.report.model import Column, Figure, Note, ReportData, Section, Table, flatten, format_cell

__all__ = ["build_report", "write_report"]

_CSS = """
:root{--bad:#b00020;--warn:#8a5a00;--line:#c8c8c8}
body{font-family:"DejaVu Sans",Arial,Helvetica,sans-serif;font-size:13px;color:#111;max-width:1200px;margin:0 auto;
 padding:16px 24px}
h1{font-size:22px;margin:0 0 4px}h2{font-size:17px;border-bottom:2px solid #335;padding-bottom:2px;margin-top:28px}
.meta{color:#444;margin:0 0 10px}
.status{display:inline-block;padding:2px 10px;border-radius:3px;font-weight:bold;color:#fff;background:#2a7a2a}
.status.failed{background:var(--bad)}
.box{border:2px solid;border-radius:4px;padding:6px 12px;margin:10px 0}
.box h3{margin:2px 0 4px;font-size:15px}
.box.error{border-color:var(--bad);background:#fdecee;color:var(--bad)}
.box.warning{border-color:var(--warn);background:#fff6e0;color:#4a3300}
.box ul{margin:2px 0;padding-left:20px}
table{border-collapse:collapse;margin:8px 0 4px;font-size:12px}
caption{text-align:left;font-weight:bold;padding:2px 0}
td,th{border:1px solid var(--line);padding:2px 6px;vertical-align:top}
th{background:#eef0f5;text-align:center}
th .unit{font-weight:normal;color:#555}
td.num{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
td.hash{font-family:monospace;font-size:11px;word-break:break-all}
tbody tr:nth-child(even){background:#f7f7f9}
p.note{color:#444;font-size:12px;margin:2px 0 10px;max-width:1000px}
figure{margin:10px 0}figure img{max-width:100%;min-width:min(560px,100%);height:auto;border:1px solid #ddd}
figcaption{font-size:12px;color:#333;max-width:900px}
nav ol{columns:3;font-size:12px}
footer{margin-top:30px;color:#666;font-size:11px;border-top:1px solid var(--line)}
@page{size:A4;margin:14mm 12mm}
@media print{
 body{max-width:none;padding:0;font-size:10px}
 nav{display:none}
 h2{page-break-after:avoid;break-after:avoid}
 caption{page-break-after:avoid}
 tr,figure,.box{page-break-inside:avoid;break-inside:avoid}
 thead{display:table-header-group}
 table{font-size:9px}
 figure img{max-height:230mm}
 a{color:inherit;text-decoration:none}
}
"""


def _e(s: Any) -> str:
    return html.escape(str(s), quote=True)


def _num_like(v: Any) -> bool:
    try:
        import numpy as np

        if isinstance(v, np.generic):
            v = v.item()
    except ImportError:  # pragma: no cover
        pass
    return isinstance(v, (int, float)) and not isinstance(v, bool) or isinstance(v, (list, tuple))


def _table(t: Table) -> str:
    head = "".join(f"<th>{_e(c.name)}" + (f"<br><span class='unit'>({_e(c.unit)})</span>" if c.unit else "") + "</th>"
                   for c in t.columns)
    body = []
    for row in t.rows:
        cells = []
        for c, v in zip(t.columns, row):
            cls = " class='num'" if _num_like(v) else ""
            cells.append(f"<td{cls}>{_e(format_cell(v, c.decimals, c.style))}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    note = f"<p class='note'>{_e(t.note)}</p>" if t.note else ""
    return (f"<table id='tab-{_e(t.key)}'><caption>{_e(t.title)}</caption><thead><tr>{head}</tr></thead>"
            f"<tbody>{''.join(body)}</tbody></table>{note}")


def _figure(f: Figure) -> str:
    b64 = base64.b64encode(f.png).decode("ascii")
    return (f"<figure id='fig-{_e(f.key)}'><img src='data:image/png;base64,{b64}' alt='{_e(f.alt or f.caption)}'>"
            f"<figcaption>{_e(f.caption)}</figcaption></figure>")


def _note(n: Note) -> str:
    if n.level in ("warning", "error"):
        return f"<div class='box {n.level}'>{_e(n.text)}</div>"
    return f"<p class='note'>{_e(n.text)}</p>"


def _section(s: Section) -> str:
    parts = [f"<section id='sec-{_e(s.key)}'><h2>{_e(s.title)}</h2>"]
    for b in s.blocks:
        parts.append(_table(b) if isinstance(b, Table) else _figure(b) if isinstance(b, Figure) else _note(b))
    parts.append("</section>")
    return "".join(parts)


def _run_sections(d: ReportData) -> tuple[Section, Section]:
    inputs = Table("inputs", "Input files", [Column("path"), Column("SHA-256"), Column("size", "bytes")],
                   [[i.path, i.sha256 or "(not readable)", i.size] for i in d.inputs])
    opts = Table("options", "Options", [Column("option"), Column("value")],
                 [[k, _option_text(v)] for k, v in flatten(d.options).items()])
    blocks: list[Any] = [Table("software", "Software and date", [Column("item"), Column("value")],
                               [["software", d.software], ["created (UTC)", d.created]])]
    blocks.append(inputs if d.inputs else Note("No input files recorded."))
    return (Section("run", "Run: software, date and inputs", blocks),
            Section("options", "Options of the run", [opts if d.options else Note("No options recorded.")]))


def _option_text(v: Any) -> str:
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_option_text(x) for x in v) + "]"
    return str(v)


def build_report(data: ReportData) -> str:
    """The HTML text of ``data`` (pure: no file is read or written)."""
    failed = bool(data.failures)
    status = ("<span class='status failed'>FAILED - not to be trusted</span>" if failed
              else f"<span class='status'>{_e(data.accepted)}</span>")
    top = []
    if data.failures:
        top.append("<div class='box error' id='failures'><h3>The result must not be trusted</h3><ul>"
                   + "".join(f"<li>{_e(f)}</li>" for f in data.failures) + "</ul></div>")
    if data.warnings:
        top.append(f"<div class='box warning' id='warnings'><h3>Warnings ({len(data.warnings)})</h3><ul>"
                   + "".join(f"<li>{_e(w)}</li>" for w in data.warnings) + "</ul></div>")
    run, options = _run_sections(data)
    sections = [run, *data.sections, options]
    toc = "<nav><ol>" + "".join(f"<li><a href='#sec-{_e(s.key)}'>{_e(s.title)}</a></li>" for s in sections) \
        + "</ol></nav>"
    head = (f"<header><h1>{_e(data.title)}</h1><p class='meta'>{_e(data.software)} &middot; {_e(data.created)} "
            f"&middot; {status}</p></header>")
    body = head + "".join(top) + toc + "".join(_section(s) for s in sections) + \
        f"<footer>Written by {_e(data.software)} on {_e(data.created)}.</footer>"
    return (f"<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>"
            f"<meta name='viewport' content='width=device-width, initial-scale=1'>"
            f"<title>{_e(data.title)}</title><style>{_CSS}</style></head><body>{body}</body></html>\n")


def write_report(path: str | os.PathLike[str], data: ReportData) -> None:
    """Write :func:`build_report` of ``data`` to ``path`` atomically (temp file and rename; mode 0666 less umask)."""
    from skyrig.io._text import atomic_write

    text = build_report(data)
    with atomic_write(path) as fh:
        fh.write(text)


def add_stage_warnings(text: str, warnings: list[str]) -> str:
    """``text`` (a report page) with a warning box listing the stage's ``warnings`` that the page does not already
    show, right after its header (after ``<body>`` in a page without one); unchanged when there are none."""
    new = [w for w in dict.fromkeys(warnings) if w and _e(w) not in text]
    if not new:
        return text
    box = (f"<div class='box warning' id='stage-warnings' style='border:1px solid #c80;background:#fff6e0;"
           f"padding:0.5em 1em'><h3>Warnings while the stage ran ({len(new)})</h3><ul>"
           + "".join(f"<li>{_e(w)}</li>" for w in new) + "</ul></div>")
    for mark in ("</header>", "<body>"):
        k = text.find(mark)
        if k >= 0:
            k += len(mark)
            return text[:k] + box + text[k:]
    return box + text
