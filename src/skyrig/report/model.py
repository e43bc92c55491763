"""The content of a report as plain data: tables, figures, notes, sections and the section registry.

A :class:`ReportData` is everything :func:`skyrig.report.build_report` needs to write the page; nothing in it
refers to a file (figures hold their PNG bytes).  Sections are kept in the order of their ``order`` number, so
that a later stage adds its section (``data.add(make_section("dsm", ...))``) and it lands in its place.

Section registry
----------------
:func:`register_section` names a *builder* (a function returning a :class:`Section`) and its place on the page;
:func:`make_section` calls it.  The adjustment builders live in :mod:`skyrig.report.adjustment`, the previews of
the dense stage in :mod:`skyrig.report.dense`; the calibration stage registers its own the same way::

    @register_section("calibration-recipe", order=25)
    def recipe_section(result) -> Section:
        return Section("calibration-recipe", "Calibration recipe", [Table(...)])
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable

__all__ = ["Column", "Table", "Figure", "Note", "Section", "InputFile", "ReportData", "register_section",
           "make_section", "SECTION_BUILDERS", "section_order", "format_cell", "key_value_table", "flatten"]


@dataclass(frozen=True)
class Column:
    """A table column: heading, unit (shown under the heading; "" for none), decimals of a number and its
    style: ``"f"`` fixed point, ``"e"`` scientific (``decimals`` digits after the point)."""

    name: str
    unit: str = ""
    decimals: int = 3
    style: str = "f"


@dataclass
class Table:
    """A table: ``rows`` of cells (numbers are formatted with their column's decimals; NaN/None show as "n/a").

    ``key`` becomes the HTML id ``tab-<key>`` (stable, for tests and links); ``note`` is printed under it.
    """

    key: str
    title: str
    columns: list[Column]
    rows: list[list[Any]]
    note: str = ""


@dataclass
class Figure:
    """A PNG figure (bytes, embedded as a data URI) with a caption."""

    key: str
    caption: str
    png: bytes
    alt: str = ""


@dataclass
class Note:
    """A paragraph of text; ``level`` "info", "warning" or "error" (the latter two are boxed)."""

    text: str
    level: str = "info"


Block = Table | Figure | Note


@dataclass
class Section:
    """One section of the page: ``key`` (HTML id ``sec-<key>``), heading and its blocks in order."""

    key: str
    title: str
    blocks: list[Block] = field(default_factory=list)
    order: float | None = None

    def tables(self) -> dict[str, Table]:
        return {b.key: b for b in self.blocks if isinstance(b, Table)}

    def figures(self) -> dict[str, Figure]:
        return {b.key: b for b in self.blocks if isinstance(b, Figure)}


@dataclass(frozen=True)
class InputFile:
    """An input of the run: path as given, SHA-256 (hex) and size in bytes (None when it could not be read)."""

    path: str
    sha256: str | None
    size: int | None = None


@dataclass
class ReportData:
    """Everything on the page.

    Attributes
    ----------
    title
        Page title.
    software
        ``"skyrig 0.1.0"``.
    created
        Date and time of the run (ISO 8601, UTC).
    inputs
        The input files with their checksums.
    options
        The options of the run (name -> value; nested dicts are flattened with dots when shown).
    failures
        Why the result must not be trusted (shown first, in red); empty for a good run.
    warnings
        Remarks in words (shown at the top, boxed).
    sections
        The sections, kept sorted by ``order``.
    accepted
        The status shown for a run without failures (e.g. ``"orthomosaic written"``).
    """

    title: str
    software: str
    created: str
    inputs: list[InputFile] = field(default_factory=list)
    options: dict[str, Any] = field(default_factory=dict)
    failures: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    sections: list[Section] = field(default_factory=list)
    accepted: str = "adjustment accepted"

    def add(self, section: Section) -> "ReportData":
        """Insert ``section`` at its place (replacing a section with the same key); returns self."""
        if section.order is None:
            section.order = section_order(section.key)
        self.sections = [s for s in self.sections if s.key != section.key]
        self.sections.append(section)
        self.sections.sort(key=lambda s: (s.order if s.order is not None else math.inf))
        return self

    def section(self, key: str) -> Section:
        """The section named ``key`` (KeyError when absent)."""
        for s in self.sections:
            if s.key == key:
                return s
        raise KeyError(key)


#: builders by section key: (order on the page, function returning a Section)
SECTION_BUILDERS: dict[str, tuple[float, Callable[..., Section]]] = {}


def register_section(key: str, order: float) -> Callable[[Callable[..., Section]], Callable[..., Section]]:
    """Decorator: register a section builder under ``key`` at position ``order`` (smaller = higher up)."""

    def deco(fn: Callable[..., Section]) -> Callable[..., Section]:
        SECTION_BUILDERS[key] = (order, fn)
        return fn

    return deco


def section_order(key: str) -> float:
    """The registered position of ``key`` (sections without a builder go to the end)."""
    return SECTION_BUILDERS[key][0] if key in SECTION_BUILDERS else 1000.0


def make_section(key: str, *args: Any, **kwargs: Any) -> Section:
    """Build the registered section ``key`` (its builder's arguments)."""
    if key not in SECTION_BUILDERS:
        raise KeyError(f"no report section {key!r}; registered: {', '.join(sorted(SECTION_BUILDERS))}")
    order, fn = SECTION_BUILDERS[key]
    s = fn(*args, **kwargs)
    if s.order is None:
        s.order = order
    return s


def flatten(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested dicts flattened with dotted keys."""
    out: dict[str, Any] = {}
    for k, v in d.items():
        name = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(flatten(v, name + "."))
        else:
            out[name] = v
    return out


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def format_cell(v: Any, decimals: int = 3, style: str = "f") -> str:
    """The text of a cell (no HTML escaping): numbers with ``decimals``, NaN/None as "n/a", sequences joined."""
    if v is None:
        return "n/a"
    try:
        import numpy as np

        if isinstance(v, np.generic):
            v = v.item()
        elif isinstance(v, np.ndarray):
            v = v.tolist()
    except ImportError:  # pragma: no cover
        pass
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            return "n/a"
        text = f"{v:.{decimals}e}" if style == "e" else f"{v:.{decimals}f}"
        if text.startswith("-") and float(text) == 0.0:
            text = text[1:]  # no "-0.000"
        return text
    if isinstance(v, (list, tuple)) and not isinstance(v, str):
        return ", ".join(format_cell(x, decimals, style) for x in v)
    return str(v)


def key_value_table(key: str, title: str, mapping: dict[str, Any], decimals: int = 4, note: str = "",
                    units: dict[str, str] | None = None) -> Table:
    """A two- or three-column table (item, value[, unit]) of a flat mapping."""
    units = units or {}
    if units:
        return Table(key, title, [Column("item"), Column("value", decimals=decimals), Column("unit")],
                     [[k, v, units.get(k, "")] for k, v in mapping.items()], note)
    return Table(key, title, [Column("item"), Column("value", decimals=decimals)],
                 [[k, v] for k, v in mapping.items()], note)
