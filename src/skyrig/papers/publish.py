"""``skyrig paper``'s work: run each paper's reproduction into its own sub-folder of one output folder, write
its tables (CSV + JSON) and one index page, and publish the folder with its manifest written last.

A paper whose module is not installed, or whose run raises, is recorded with a one-line error naming it (the
other papers still run); :attr:`PaperOutcome.ok` is false for it and for a paper with a failed check.
"""

from __future__ import annotations

import csv
import json
import logging
import math
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any, Callable

from skyrig.papers import PAPERS, runner
from skyrig.papers.base import PaperTable, Size
from skyrig.papers.page import PaperOutcome, index_html

__all__ = ["PaperOutcome", "run_papers", "write_table"]

log = logging.getLogger(__name__)


def _json_value(v: Any) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, dict):
        return {str(k): _json_value(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_json_value(x) for x in v]
    if hasattr(v, "item") and not isinstance(v, (str, bytes)):  # numpy scalars
        return _json_value(v.item())
    return v


def write_table(folder: Path, table: PaperTable) -> None:
    """``<key>.csv`` (a header row of the column names) and ``<key>.json`` of ``table``, each written atomically."""
    from skyrig.io._text import atomic_write

    with atomic_write(folder / f"{table.key}.csv", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(table.columns)
        w.writerows(["" if v is None else v for v in row] for row in table.rows)
    doc = {"title": table.title, "caption": table.caption, "columns": list(table.columns),
           "rows": [dict(zip(table.columns, row)) for row in table.rows]}
    with atomic_write(folder / f"{table.key}.json") as fh:
        fh.write(json.dumps(_json_value(doc), indent=1) + "\n")


def _write_result(folder: Path, o: PaperOutcome) -> None:
    from skyrig.io._text import atomic_write

    r = o.result
    for t in r.tables if r else ():
        write_table(folder, t)
    doc: dict[str, Any] = {"paper": o.paper, "title": o.title, "ok": o.ok, "error": o.error, "seconds": o.seconds}
    if r is not None:
        doc.update(size=r.size, comparisons=[asdict(c) for c in r.comparisons],
                   checks=[{"name": n, "ok": ok, "measured": why} for n, ok, why in r.checks],
                   figures=[asdict(f) for f in r.figures], tables=[t.key for t in r.tables], notes=r.notes)
    with atomic_write(folder / "result.json") as fh:
        fh.write(json.dumps(_json_value(doc), indent=1) + "\n")


def _run_one(paper: str, folder: Path, size: Size) -> PaperOutcome:
    module, title = PAPERS[paper]
    t0 = time.perf_counter()
    try:
        run = runner(paper)
    except ImportError as exc:
        if isinstance(exc, ModuleNotFoundError) and exc.name == module:
            return PaperOutcome(paper, title, None, f"paper {paper}: its reproduction ({module}) is not installed")
        return PaperOutcome(paper, title, None, f"paper {paper}: importing {module} failed: {exc}")
    try:
        res = run(folder, size)
    except Exception as exc:  # noqa: BLE001 - recorded on the page and in the exit status, the other papers still run
        log.debug("paper %s raised", paper, exc_info=True)
        return PaperOutcome(paper, title, None, f"paper {paper} raised {type(exc).__name__}: {exc}",
                            time.perf_counter() - t0)
    secs = time.perf_counter() - t0
    res.seconds = secs
    missing = [f.path for f in res.figures if not (folder / f.path).is_file()]
    err = f"paper {paper}: figure file(s) not written: {', '.join(missing)}" if missing else None
    return PaperOutcome(paper, res.title or title, res, err, secs)


def _check_replaceable(out: Path) -> None:
    """The folder is replaced as a whole: refuse one that holds anything but an earlier ``skyrig paper`` output."""
    from skyrig.errors import OutputPathError
    from skyrig.io.stage import MANIFEST

    if not out.is_dir() or not any(out.iterdir()):
        return
    try:
        stage = json.loads((out / MANIFEST).read_text()).get("stage")
    except (OSError, ValueError, AttributeError):
        stage = None
    if stage != "paper":
        raise OutputPathError("holds files that are not an earlier `skyrig paper` output (it would be replaced as a "
                              "whole): give a new or empty folder", out, "--out")


def run_papers(papers: list[str], size: Size, out: str | Path,
               progress: Callable[[str], None] | None = None) -> list[PaperOutcome]:
    """Run ``papers`` ('000'..'004') at ``size`` into ``out/<paper>/`` and write ``out/index.html``; the folder is
    published as a whole (``manifest.json`` last, :func:`skyrig.io.stage.stage_folder`)."""
    from skyrig import __version__
    from skyrig.io._text import atomic_write
    from skyrig.io.stage import stage_folder

    unknown = [p for p in papers if p not in PAPERS]
    if unknown:
        raise KeyError(f"no paper {unknown[0]!r}; known: {', '.join(PAPERS)}")
    _check_replaceable(Path(out))
    outcomes: list[PaperOutcome] = []
    with stage_folder(out, stage="paper", options={"papers": papers, "size": size}) as tmp:
        for p in papers:
            if progress:
                progress(f"paper {p}: {PAPERS[p][1]} ...")
            folder = tmp / p
            folder.mkdir()
            o = _run_one(p, folder, size)
            _write_result(folder, o)
            outcomes.append(o)
            if progress:
                progress(f"paper {p}: {'passed' if o.ok else 'FAILED'} in {o.seconds:.1f} s"
                         + (f" ({o.error})" if o.error else "")
                         + (f" (failed checks: {', '.join(o.failed_checks)})" if o.failed_checks else ""))
        page = index_html(outcomes, size, f"skyrig {__version__}", time.strftime("%Y-%m-%d %H:%M:%S %z"))
        with atomic_write(tmp / "index.html") as fh:
            fh.write(page)
    return outcomes
