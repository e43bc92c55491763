"""The index page of ``skyrig paper``: every paper run, its tables with skyrig's values next to the paper's,
its figures inline, its checks with their verdicts and its run time.

One self-contained HTML file at the top of the output folder: the figures are ``<img>`` links to the files the
paper modules wrote beside it (relative paths, so the folder can be moved), the style sheet is inline, no script
and nothing loaded from elsewhere.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from skyrig.papers.base import PaperResult, PaperTable
from skyrig.report.html import _CSS, _e

__all__ = ["PaperOutcome", "index_html"]

_EXTRA_CSS = """
.verdict{font-weight:bold}.ok{color:#2a7a2a}.bad{color:var(--bad)}.na{color:#666}
section.paper{margin-bottom:36px}
"""


@dataclass
class PaperOutcome:
    """One paper's run: its result, or the error that stopped it (``error``: one line naming the paper)."""

    paper: str
    title: str
    result: PaperResult | None
    error: str | None = None
    seconds: float = 0.0

    @property
    def failed_checks(self) -> list[str]:
        return [] if self.result is None else [name for name, ok, _ in self.result.checks if not ok]

    @property
    def ok(self) -> bool:
        return self.error is None and not self.failed_checks


def _cell(v: Any) -> str:
    if v is None:
        return "&ndash;"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        if not math.isfinite(v):
            return _e(v)
        a = abs(v)
        return _e(f"{v:.4g}" if a and (a < 1e-3 or a >= 1e5) else f"{v:.4f}".rstrip("0").rstrip(".") if a < 1
                  else f"{v:.3f}".rstrip("0").rstrip(".") if a < 100 else f"{v:.1f}")
    return _e(v)


def _num(v: Any) -> str:
    return " class='num'" if isinstance(v, (int, float)) and not isinstance(v, bool) else ""


def _verdict(ok: bool | None) -> str:
    if ok is None:
        return "<span class='verdict na'>&ndash;</span>"
    return "<span class='verdict ok'>agrees</span>" if ok else "<span class='verdict bad'>differs</span>"


def _table(paper: str, t: PaperTable) -> str:
    head = "".join(f"<th>{_e(c)}</th>" for c in t.columns)
    body = "".join("<tr>" + "".join(f"<td{_num(v)}>{_cell(v)}</td>" for v in row) + "</tr>" for row in t.rows)
    cap = f"<p class='note'>{_e(t.caption)}</p>" if t.caption else ""
    files = f"<p class='note'>files: <a href='{_e(paper)}/{_e(t.key)}.csv'>{_e(t.key)}.csv</a>, " \
            f"<a href='{_e(paper)}/{_e(t.key)}.json'>{_e(t.key)}.json</a></p>"
    return (f"<table id='tab-{_e(paper)}-{_e(t.key)}'><caption>{_e(t.title)}</caption><thead><tr>{head}</tr></thead>"
            f"<tbody>{body}</tbody></table>{cap}{files}")


def _paper(o: PaperOutcome) -> str:
    r = o.result
    status = "<span class='status'>passed</span>" if o.ok else "<span class='status failed'>failed</span>"
    parts = [f"<section class='paper' id='paper-{_e(o.paper)}'><h2>Paper {_e(o.paper)}: {_e(o.title)} {status}</h2>",
             f"<p class='meta'>size {_e(r.size) if r else '&ndash;'}; run time {o.seconds:.1f} s</p>"]
    if o.error:
        parts.append(f"<div class='box error'><h3>not run to the end</h3>{_e(o.error)}</div>")
    if r is None:
        return "".join(parts) + "</section>"
    if r.comparisons:
        rows = "".join(
            f"<tr><td>{_e(c.quantity)}</td><td{_num(c.skyrig)}>{_cell(c.skyrig)}</td><td{_num(c.paper)}>{_cell(c.paper)}"
            f"</td><td>{_e(c.unit)}</td><td>{_verdict(c.agrees)}</td><td>{_e(c.where)}</td><td>{_e(c.explanation)}</td></tr>"
            for c in r.comparisons)
        parts.append("<table class='comparisons'><caption>skyrig next to the paper</caption><thead><tr><th>quantity</th>"
                     "<th>skyrig</th><th>paper</th><th>unit</th><th>verdict</th><th>where</th><th>why they may differ</th>"
                     f"</tr></thead><tbody>{rows}</tbody></table>")
    parts.extend(_table(o.paper, t) for t in r.tables)
    for f in r.figures:
        parts.append(f"<figure id='fig-{_e(o.paper)}-{_e(f.key)}'><img src='{_e(o.paper)}/{_e(f.path)}' "
                     f"alt='{_e(f.title)}'><figcaption><b>{_e(f.title)}</b> {_e(f.caption)}</figcaption></figure>")
    if r.checks:
        rows = "".join(f"<tr><td>{_e(name)}</td><td><span class='verdict {'ok' if ok else 'bad'}'>"
                       f"{'pass' if ok else 'FAIL'}</span></td><td>{_e(why)}</td></tr>" for name, ok, why in r.checks)
        parts.append(f"<table class='checks'><caption>checks</caption><thead><tr><th>check</th><th>verdict</th>"
                     f"<th>measured</th></tr></thead><tbody>{rows}</tbody></table>")
    parts.extend(f"<p class='note'>{_e(n)}</p>" for n in r.notes)
    return "".join(parts) + "</section>"


def index_html(outcomes: list[PaperOutcome], size: str, software: str, created: str) -> str:
    """The index page over ``outcomes`` (in the order run)."""
    nav = "".join(f"<li><a href='#paper-{_e(o.paper)}'>{_e(o.paper)}: {_e(o.title)}</a> "
                  f"({'passed' if o.ok else 'failed'})</li>" for o in outcomes)
    failed = [o.paper for o in outcomes if not o.ok]
    summary = (f"<span class='status failed'>failed: {_e(', '.join(failed))}</span>" if failed
               else "<span class='status'>all checks passed</span>")
    body = "".join(_paper(o) for o in outcomes)
    return ("<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>skyrig: the papers reproduced</title>"
            f"<style>{_CSS}{_EXTRA_CSS}</style></head><body><h1>The papers reproduced by skyrig</h1>"
            f"<p class='meta'>size {_e(size)}; {_e(software)}; {_e(created)} {summary}</p><nav><ol>{nav}</ol></nav>"
            f"{body}<footer>Written by <code>skyrig paper</code>. Each table is also in the paper's folder as CSV and "
            "JSON; the manifest lists every file.</footer></body></html>\n")
