"""The report a surveyor signs: one self-contained, printable HTML page (layer 3).

::

    from skyrig.report import report_data_from_adjustment, write_report, make_section

    data = report_data_from_adjustment(result, title="block 7", inputs=["block.json"], frame=frame,
                                       map_frame=WorldFrame.map("EPSG:25832"))
    data.add(make_section("dsm", dsm=heights, cell_m=0.2))          # a later stage adds its section
    write_report("report.html", data)                                # atomic, 0666 less umask

:func:`build_report` is pure (``ReportData`` -> HTML text).  Sections come from builders registered with
:func:`register_section` (:mod:`skyrig.report.adjustment`: summary, calibration, control, orientation, cameras,
images, points, normalised, distances, rejected; :mod:`skyrig.report.dense`: dsm, ortho); a stage adds its own
by registering a builder and calling ``data.add(make_section(key, ...))``.
"""

import os
from pathlib import Path
from typing import Any

from skyrig.report.model import (
    SECTION_BUILDERS,
    Column,
    Figure,
    InputFile,
    Note,
    ReportData,
    Section,
    Table,
    make_section,
    register_section,
)
from skyrig.report.html import build_report, write_report
from skyrig.report.adjustment import (
    block_file_inputs,
    input_files,
    report_data_from_adjustment,
    report_data_from_uav,
)
from skyrig.report import dense as _dense  # noqa: F401 - registers the dsm / ortho sections
from skyrig.report.dense import dsm_section, ortho_section

__all__ = ["ReportData", "Section", "Table", "Column", "Figure", "Note", "InputFile", "build_report", "write_report",
           "report_data_from_adjustment", "report_data_from_uav", "register_section", "make_section",
           "SECTION_BUILDERS", "input_files", "block_file_inputs", "dsm_section", "ortho_section",
           "write_adjustment_report"]


def write_adjustment_report(outdir: str | os.PathLike[str], result: Any, rep: dict[str, Any], title: str,
                            **kw: Any) -> dict[str, Path]:
    """``report.json`` (the tables of :func:`skyrig.adjust.report.adjustment_report`) and the self-contained
    ``report.html`` of ``result`` in ``outdir``; ``kw`` go to :func:`report_data_from_adjustment`.  Returns
    ``{"json": path, "html": path}``."""
    from skyrig.io.report_html import write_report_json

    d = Path(outdir)
    write_report_json(d / "report.json", rep)
    kw.setdefault("folder", d)
    write_report(d / "report.html", report_data_from_adjustment(result, title=title, rep=rep, **kw))
    return {"json": d / "report.json", "html": d / "report.html"}
