"""Pix4D ground control points and their image marks (GCP/MTP), written and read.

Files (as Pix4D documents them: "Tie points (GCPs, CPs) import format - PIX4Dmatic" and "How to import and export
Tie Points marks - PIX4Dmatic", support.pix4d.com; PIX4Dmapper's GCP/MTP Manager reads and writes the same)
-----------------------------------------------------------------------------------------------------------------
* **GCP file** (``.txt`` / ``.csv``, no header): one point per line, comma-separated, four or six columns::

      label,coordinate1,coordinate2,z[,accuracy_horizontal,accuracy_vertical]

  The coordinates in the order of the axes of the CRS chosen on import (EPSG:25832: easting then northing;
  EPSG:4326: latitude then longitude, decimal degrees); ``z`` and the accuracies in the CRS's unit (metres).
  Pix4D does not store the CRS in the file: skyrig writes the frame into the table's side-car
  (``NAME.json``, :mod:`skyrig.io.table_meta`) and the reader takes it from there or from the caller.
* **Marks file** (``.txt`` / ``.csv``, no header, "Data Delimiter - Comma"): one mark per line::

      image_name,point_label,x,y[,accuracy_px]

  ``x`` to the right and ``y`` down from the image's **top-left corner** (Pix4D's image coordinate system), in
  pixels: skyrig's pixel coordinates (origin at the centre of the top-left pixel) plus 0.5
  (:data:`skyrig.io.pix4d.HALF`, the convention of the calibrated camera files); ``accuracy`` the mark's standard
  deviation in pixels (skyrig writes its ``sigma_px`` when known, else the given default).

Checks on reading: four or six GCP columns (five: a missing accuracy), numbers where numbers belong, a label
twice; four or five mark columns, a mark outside any plausible image (negative), a mark twice on one image.
Every refusal names the file, the line and the field.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.errors import InputFormatError
from skyrig.geodesy.frame import WorldFrame
from skyrig.georef.observations import GroundPoints, ImageMeasurements
from skyrig.io._text import atomic_write, parse_float, read_text

__all__ = ["write_pix4d_gcps", "read_pix4d_gcps", "write_pix4d_marks", "read_pix4d_marks", "axes_swapped"]

HALF = 0.5  # Pix4D pixel (corner origin) minus skyrig pixel (centre origin), as in skyrig.io.pix4d
GCP_FIELDS = ("label", "coordinate1", "coordinate2", "z", "accuracy_horizontal", "accuracy_vertical")
MARK_FIELDS = ("image", "label", "x", "y", "accuracy")


def axes_swapped(frame: WorldFrame) -> bool:
    """True when the CRS's first axis is north (latitude or northing): Pix4D's coordinate1 is then y."""
    if frame.kind != "map":
        return False
    info = frame.projection.crs.axis_info
    return bool(info) and info[0].direction.lower() in ("north", "south")


def _fmt(v: float) -> str:
    return repr(float(v))


def write_pix4d_gcps(path: str | PathLike[str], points: GroundPoints,
                     accuracy_m: ArrayLike | None = None) -> Path:
    """Write ``points`` as a Pix4D GCP file (``label,c1,c2,z[,acc_h,acc_v]``, axes in the CRS's order), with the
    frame in the side-car.  ``accuracy_m``: ``(2,)`` horizontal and vertical accuracy for every point, or
    ``(N, 2)``; None: four columns."""
    from skyrig.io.table_meta import write_table_meta

    p = Path(path)
    xyz = np.asarray(points.xyz, dtype=np.float64)
    swap = axes_swapped(points.frame)
    acc = None if accuracy_m is None else np.broadcast_to(np.asarray(accuracy_m, dtype=np.float64), (len(xyz), 2))
    lines = []
    for k, name in enumerate(points.name):
        if "," in str(name) or "\n" in str(name):
            raise InputFormatError(f"point name {str(name)!r} holds a comma or a line end (Pix4D's separator)", p,
                                   None, "label")
        c1, c2 = (xyz[k, 1], xyz[k, 0]) if swap else (xyz[k, 0], xyz[k, 1])
        cells = [str(name), _fmt(c1), _fmt(c2), _fmt(xyz[k, 2])]
        if acc is not None:
            cells += [_fmt(acc[k, 0]), _fmt(acc[k, 1])]
        lines.append(",".join(cells))
    with atomic_write(p) as fh:
        fh.write("\n".join(lines) + "\n")
    cols = {f: {"type": "String" if f == "label" else "Real"} for f in GCP_FIELDS[:4 if acc is None else 6]}
    write_table_meta(p, points.frame, cols, "pix4d-gcp 1",
                     {"axes": "coordinate1 = y (the CRS's first axis is north)" if swap else "coordinate1 = x"})
    return p


def _rows(path: Path) -> list[tuple[int, list[str]]]:
    text = read_text(path)
    out = []
    for no, line in enumerate(text.splitlines(), 1):
        if line.strip():
            out.append((no, [c.strip() for c in line.split(",")]))
    if not out:
        raise InputFormatError("empty file", path, None)
    return out


def read_pix4d_gcps(path: str | PathLike[str], frame: WorldFrame | None = None
                    ) -> tuple[GroundPoints, NDArray[np.float64] | None]:
    """Read a Pix4D GCP file: the points (in ``frame``, else the side-car's) and the ``(N, 2)`` accuracies (None
    for a four-column file)."""
    from skyrig.io.table_meta import frame_of_meta, read_table_meta

    p = Path(path)
    if frame is None:
        meta = read_table_meta(p)
        frame = None if meta is None else frame_of_meta(meta, p)
    if frame is None:
        raise InputFormatError("a Pix4D GCP file states no CRS: give it (or write the side-car)", p, None, "crs")
    rows = _rows(p)
    ncol = len(rows[0][1])
    if ncol not in (4, 6):
        raise InputFormatError(f"expected 4 or 6 comma-separated columns (label, two coordinates, z and optionally "
                               f"the horizontal and vertical accuracy), found {ncol}", p, rows[0][0],
                               GCP_FIELDS[min(ncol, 5)])
    names, vals, seen = [], [], {}
    for no, cells in rows:
        if len(cells) != ncol:
            raise InputFormatError(f"expected {ncol} columns like line {rows[0][0]}, found {len(cells)}", p, no,
                                   GCP_FIELDS[min(len(cells), 5)])
        if cells[0] in seen:
            raise InputFormatError(f"point {cells[0]!r} twice (first on line {seen[cells[0]]})", p, no, "label")
        if not cells[0]:
            raise InputFormatError("empty label", p, no, "label")
        seen[cells[0]] = no
        names.append(cells[0])
        vals.append([parse_float(c, p, no, f) for c, f in zip(cells[1:], GCP_FIELDS[1:])])
    v = np.array(vals)
    xyz = v[:, [1, 0, 2]] if axes_swapped(frame) else v[:, :3]
    acc = v[:, 3:5] if ncol == 6 else None
    if acc is not None and np.any(acc < 0):
        k = int(np.argmax(np.any(acc < 0, axis=1)))
        raise InputFormatError("a negative accuracy", p, rows[k][0], "accuracy_horizontal")
    from skyrig.io.plausibility import check_coordinates

    check_coordinates(xyz, frame, p, [no for no, _ in rows], "ground",
                      ("coordinate2", "coordinate1", "z") if axes_swapped(frame) else ("coordinate1", "coordinate2", "z"))
    return GroundPoints(np.array(names), xyz, frame), acc


def write_pix4d_marks(path: str | PathLike[str], measurements: ImageMeasurements,
                      accuracy_px: ArrayLike | float | None = None) -> Path:
    """Write image measurements as a Pix4D marks file (``image,label,x,y[,accuracy]``, corner origin).
    ``accuracy_px``: one standard deviation (pixels) for all, or one per measurement (NaN: the column left
    empty is not Pix4D's, so NaN is refused); None: four columns."""
    p = Path(path)
    px = np.asarray(measurements.pixel, dtype=np.float64) + HALF
    acc = None if accuracy_px is None else np.broadcast_to(np.asarray(accuracy_px, dtype=np.float64), (len(px),))
    if acc is not None and not np.all(np.isfinite(acc) & (acc > 0)):
        raise InputFormatError("every mark needs a positive accuracy (pixels) when the column is written", p, None,
                               "accuracy")
    lines = []
    for k, (pt, im) in enumerate(zip(measurements.point, measurements.image)):
        for what, s in (("image", im), ("label", pt)):
            if "," in str(s) or "\n" in str(s):
                raise InputFormatError(f"{what} {str(s)!r} holds a comma or a line end (Pix4D's separator)", p,
                                       None, what)
        cells = [str(im), str(pt), _fmt(px[k, 0]), _fmt(px[k, 1])]
        if acc is not None:
            cells.append(_fmt(acc[k]))
        lines.append(",".join(cells))
    with atomic_write(p) as fh:
        fh.write("\n".join(lines) + "\n")
    return p


def read_pix4d_marks(path: str | PathLike[str]) -> tuple[ImageMeasurements, NDArray[np.float64] | None]:
    """Read a Pix4D marks file: skyrig image measurements (centre origin) and the accuracies (pixels; None for
    a four-column file).  An image name with a folder keeps only its file name (Pix4D's "Image Directory"
    option writes the folder)."""
    p = Path(path)
    rows = _rows(p)
    ncol = len(rows[0][1])
    if ncol not in (4, 5):
        raise InputFormatError(f"expected 4 or 5 comma-separated columns (image, label, x, y and optionally the "
                               f"accuracy in pixels), found {ncol}", p, rows[0][0], MARK_FIELDS[min(ncol, 4)])
    pts, ims, xy, acc, seen = [], [], [], [], {}
    for no, cells in rows:
        if len(cells) != ncol:
            raise InputFormatError(f"expected {ncol} columns like line {rows[0][0]}, found {len(cells)}", p, no,
                                   MARK_FIELDS[min(len(cells), 4)])
        image = cells[0].replace("\\", "/").rsplit("/", 1)[-1]
        key = (image, cells[1])
        if key in seen:
            raise InputFormatError(f"point {cells[1]!r} marked twice on {image} (first on line {seen[key]})", p, no,
                                   "label")
        seen[key] = no
        x, y = (parse_float(cells[j], p, no, MARK_FIELDS[j]) for j in (2, 3))
        for v, f in ((x, "x"), (y, "y")):
            if v < 0:
                raise InputFormatError(f"{f} {v!r} px is left of or above the image's corner (Pix4D's origin)", p,
                                       no, f)
        if ncol == 5:
            a = parse_float(cells[4], p, no, "accuracy")
            if not a > 0:
                raise InputFormatError(f"accuracy {a!r} px must be > 0", p, no, "accuracy")
            acc.append(a)
        ims.append(image)
        pts.append(cells[1])
        xy.append((x - HALF, y - HALF))
    meas = ImageMeasurements(np.array(pts), np.array(ims), np.array(xy, dtype=np.float64))
    return meas, (np.array(acc) if ncol == 5 else None)
