"""Side-cars of skyrig's CSV tables: the table stays a plain CSV (one header row, then data) that GDAL's CSV
driver (QGIS's default) reads as it is, and what the old ``#`` header lines said moves next to it.

For ``NAME.csv`` skyrig writes

``NAME.csv.json``
    skyrig's own statement, read back by skyrig's readers::

        {"format": "skyrig-table", "version": 1, "table": "skyrig-eo 1",
         "frame": "EPSG:25832; heights: ellipsoidal",           (WorldFrame text form)
         "crs_wkt": "...",                                        (horizontal + vertical CRS, WKT2)
         "vertical": "ellipsoidal heights (ETRS89 ellipsoid, EPSG:4937)",
         "columns": {"x": {"type": "Real", "unit": "metre", "axis": "easting"}, ...},
         ... table keys (angles, convention, ...)}

``NAME.csvt``
    GDAL's column types (``"String"``, ``"Real"``, ``"Integer"``; ``"Point(X)"``, ``"Point(Y)"``,
    ``"Point(Z)"`` for the coordinate columns so that GDAL builds 3D points);
``NAME.prj``
    the CRS as WKT (GeoCSV convention GDAL reads): a compound CRS (horizontal + vertical CRS from the EPSG
    registry) for orthometric heights PROJ identifies, else the 3D CRS (ellipsoidal heights) or a compound
    CRS with a custom vertical CRS naming the geoid.  No ``.prj`` for a local tangent frame (no CRS PROJ
    can state; the frame is in the JSON).

Every file is written atomically; the JSON last, so a table with a JSON next to it is complete.  The JSON
records the table's size and SHA-256 as it stood when its side-cars were written (``"table_size"``,
``"table_sha256"``), and :func:`read_table_meta` warns, naming both files, when the table no longer matches
(edited since).  A run killed between writing a new table and its side-cars cannot pair the new table with the
previous run's side-cars: :func:`skyrig.io._text.atomic_write` removes a table's side-cars (JSON first) just
before it renames a new ``NAME.csv`` into place, so such a kill leaves a table without side-cars (skyrig's
readers then ask for the side-car; GDAL reads it without a CRS rather than in the old one).  Side-cars written
before the checksum keys existed are read with a warning (they cannot be checked).
"""

from __future__ import annotations

import hashlib
import json
import warnings
from pathlib import Path
from typing import Any, Mapping

from skyrig.errors import InputFormatError, SideCarMismatchWarning  # noqa: F401 - SideCarMismatchWarning re-exported
from skyrig.geodesy.frame import WorldFrame
from skyrig.geodesy.statement import crs_statement
from skyrig.io._text import PathLike, atomic_write, read_text

__all__ = ["FORMAT", "SideCarMismatchWarning", "meta_path", "write_table_meta", "read_table_meta", "frame_of_meta",
           "crs_statement", "table_checksum"]

FORMAT = "skyrig-table"
VERSION = 1


def table_checksum(path: PathLike) -> tuple[int, str]:
    """``(size in bytes, hex SHA-256)`` of a file."""
    h = hashlib.sha256()
    n = 0
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
            n += len(chunk)
    return n, h.hexdigest()


def meta_path(path: PathLike) -> Path:
    """``NAME.csv.json`` of a table ``NAME.csv``."""
    p = Path(path)
    return p.with_name(p.name + ".json")


def write_table_meta(path: PathLike, frame: WorldFrame | None, columns: Mapping[str, Mapping[str, str]],
                     table: str, extra: Mapping[str, Any] | None = None) -> None:
    """Write the side-cars of the CSV table ``path`` (module docstring).

    ``columns``: ``{name: {"type": "String" | "Real" | "Integer" | "Point(X)" ..., "unit": ..., ...}}`` in the
    order of the CSV's columns; ``table``: the table's format and version (``"skyrig-eo 1"``).
    The table must be written (complete, in place) before: its size and SHA-256 go into the JSON.
    """
    p = Path(path)
    try:
        size, sha = table_checksum(p)
    except OSError as exc:
        raise ValueError(f"write_table_meta: the table '{p}' must be written first ({exc.strerror or exc})") from None
    with atomic_write(p.with_suffix(".csvt"), newline="") as fh:
        fh.write(",".join(f'"{c.get("type", "String")}"' for c in columns.values()) + "\n")
    wkt, words = (None, "") if frame is None else crs_statement(frame)
    prj = p.with_suffix(".prj")
    if wkt is not None:
        with atomic_write(prj) as fh:
            fh.write(wkt + "\n")
    elif prj.exists():
        prj.unlink()
    meta: dict[str, Any] = {"format": FORMAT, "version": VERSION, "table": table}
    if frame is not None:
        meta.update(frame=frame.to_text(), frame_words=frame.describe(), crs_wkt=wkt, vertical=words)
    meta.update(extra or {})
    meta.update(table_file=p.name, table_size=size, table_sha256=sha)
    meta["columns"] = {k: dict(v) for k, v in columns.items()}
    with atomic_write(meta_path(p)) as fh:
        json.dump(meta, fh, indent=1)
        fh.write("\n")


def read_table_meta(path: PathLike) -> dict[str, Any] | None:
    """The ``NAME.csv.json`` side-car of ``path`` as a dict, or None when there is none.

    Raises :class:`InputFormatError` (naming the side-car) when it is not a skyrig table statement.  Warns
    (:class:`SideCarMismatchWarning`, naming the table and the side-car) when the table's size or SHA-256
    differs from what the side-car records: the side-car belongs to another version of the table (the table
    edited since, e.g. re-saved by a spreadsheet).  A side-car without a checksum (written by an older skyrig)
    is read with a warning.  (A skyrig write killed between a table and its side-cars leaves the table without
    side-cars, never with the previous ones: :func:`skyrig.io._text.atomic_write` removes them before it puts
    a new ``NAME.csv`` in place.)
    """
    m = meta_path(path)
    if not m.is_file():
        return None
    try:
        meta = json.loads(read_text(m))
    except json.JSONDecodeError as e:
        raise InputFormatError(f"not valid JSON ({e.msg})", m, e.lineno) from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise InputFormatError(f"not a {FORMAT} side-car (need \"format\": \"{FORMAT}\")", m, None, "format")
    if meta.get("version") != VERSION:
        raise InputFormatError(f"unsupported version {meta.get('version')!r} (this skyrig reads {VERSION})", m, None,
                               "version")
    check_table_meta(meta, path)
    return meta


def check_table_meta(meta: Mapping[str, Any], path: PathLike) -> None:
    """Check that the side-car ``meta`` belongs to the table ``path`` (see :func:`read_table_meta`)."""
    p, m = Path(path), meta_path(path)
    want_sha, want_size = meta.get("table_sha256"), meta.get("table_size")
    if want_sha is None and want_size is None:
        warnings.warn(f"{m.name}: no checksum of {p.name} (side-car written by an older skyrig): cannot check that "
                      f"it belongs to this version of the table", stacklevel=3)
        return
    if not p.is_file():
        raise InputFormatError("table not found (its side-car is there)", p)
    size, sha = table_checksum(p)
    if size != want_size or sha != want_sha:
        what = (f"{size} bytes, {m.name} records {want_size}" if size != want_size
                else f"SHA-256 {sha[:12]}..., {m.name} records {str(want_sha)[:12]}...")
        warnings.warn(SideCarMismatchWarning(
            f"{p}: the table does not match its side-car '{m}' ({what}): the side-car (and .prj) were written for "
            f"another version of the table (the table edited since, or written by a program that left the old "
            f"side-cars); the frame they state is used - check it, or write the table again with skyrig"),
            stacklevel=3)


def frame_of_meta(meta: Mapping[str, Any], path: PathLike) -> WorldFrame | None:
    """The :class:`WorldFrame` a side-car states (None when it states none); errors name the side-car."""
    from skyrig.errors import CRSError

    text = meta.get("frame")
    if text is None:
        return None
    m = meta_path(path)
    try:
        frame = WorldFrame.from_text(str(text), base=Path(path).parent)
        if frame.kind == "map" and frame.geoid:
            frame.projection  # noqa: B018  (validates the grid now)
        return frame
    except (CRSError, ValueError) as exc:
        raise InputFormatError(str(exc), m, None, "frame") from None
