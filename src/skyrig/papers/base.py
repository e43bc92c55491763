"""What a paper's reproduction hands back: tables, figures and values next to the paper's own.

Every ``skyrig.papers.pNNN.run(out_dir, size)`` writes its figures (PNG or SVG) under ``out_dir`` and
returns a :class:`PaperResult`; the command (``skyrig paper``) writes the tables (CSV + JSON) and one
index page over all papers run.  ``size`` is ``"ci"`` (reduced scenario, minutes at most, what the tests
run) or ``"full"`` (the paper's conditions as far as the simulator reproduces them).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

__all__ = ["Size", "Comparison", "PaperTable", "Figure", "PaperResult"]

Size = Literal["ci", "full"]


@dataclass(frozen=True)
class Comparison:
    """One value computed by skyrig next to the value the paper prints (None: the paper prints none).

    ``explanation`` says why the two may differ (the scenario's stated assumptions); ``agrees`` is the
    judgement of the module that computed it (within the stated tolerance), None when no judgement applies.
    """

    quantity: str
    skyrig: float | str
    paper: float | str | None
    unit: str
    explanation: str = ""
    agrees: bool | None = None
    where: str = ""  # the paper's table / figure / section, e.g. "Tab. 2", "Sec. 4.1"


@dataclass(frozen=True)
class PaperTable:
    """A table of the paper recomputed: ``columns`` names, ``rows`` of cells (numbers or words)."""

    key: str  # file stem: <out>/<paper>/<key>.csv
    title: str  # e.g. "Tab. 11: bundle adjustment results"
    columns: tuple[str, ...]
    rows: tuple[tuple[float | int | str | None, ...], ...]
    caption: str = ""


@dataclass(frozen=True)
class Figure:
    """A figure file written by the paper's module (path relative to the paper's folder)."""

    key: str
    title: str  # e.g. "Fig. 8: boresight corrections over beta"
    path: str
    caption: str = ""


@dataclass
class PaperResult:
    """Everything one paper's reproduction produced."""

    paper: str  # '000'..'004'
    title: str
    size: Size
    tables: list[PaperTable] = field(default_factory=list)
    figures: list[Figure] = field(default_factory=list)
    comparisons: list[Comparison] = field(default_factory=list)
    #: named checks with their verdict and a sentence (e.g. "reference camera did not move", True, "0.02 px")
    checks: list[tuple[str, bool, str]] = field(default_factory=list)
    seconds: float = 0.0
    notes: list[str] = field(default_factory=list)
