"""Plain CSV files of ground points (``name,x,y,z``) and image measurements (``point,image,column,row``).

Both have an optional ``#`` comment header; the ground-point file may carry ``# crs:``, ``# heights:`` and
``# geoid:`` lines like the EO CSV (``docs/formats/eo_csv.md``).  Pixel coordinates: column right, row down,
origin at the centre of the top-left pixel.
"""

from __future__ import annotations

import csv
import io

import numpy as np

from skyrig.errors import InputFormatError
from skyrig.georef.eo import WorldFrame
from skyrig.georef.observations import GroundPoints, ImageMeasurements
from skyrig.io._text import PathLike, atomic_write, parse_float, read_text


#: Extra columns skyrig writes next to ground points (read back and ignored).
POINT_EXTRAS = ["n_rays", "rms_px", "image_column", "image_row", "sx", "sy", "sz"]


def _table(path: PathLike, required: list[str], optional: list[str] = ()) -> tuple[dict, list[int], dict[str, list[str]]]:
    lines = read_text(path).splitlines()
    meta: dict[str, tuple[int, str]] = {}
    start = 0
    while start < len(lines) and (not lines[start].strip() or lines[start].lstrip().startswith("#")):
        body = lines[start].strip()[1:].strip()
        if ":" in body:
            k, v = body.split(":", 1)
            meta[k.strip().lower()] = (start + 1, v.strip())
        start += 1
    if start >= len(lines):
        raise InputFormatError("no column header row", path, len(lines))
    rd = csv.reader(io.StringIO("\n".join(lines[start:])))
    header = [h.strip().lower() for h in next(rd)]
    for c in required:
        if c not in header:
            raise InputFormatError("missing column", path, start + 1, c)
    for c in header:
        if c not in required and c not in optional:
            raise InputFormatError(f"unknown column {c!r}", path, start + 1, c)
    cols: dict[str, list[str]] = {c: [] for c in header}
    line_no = []
    for k, row in enumerate(rd):
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) != len(header):
            raise InputFormatError(f"expected {len(header)} fields, found {len(row)}", path, start + 2 + k)
        for c, v in zip(header, row):
            cols[c].append(v.strip())
        line_no.append(start + 2 + k)
    return meta, line_no, cols


def read_points_csv(path: PathLike, frame: WorldFrame | None = None) -> GroundPoints:
    """Read ``name,x,y,z``; the frame comes from the header or from ``frame``."""
    from skyrig.io.eo_csv import frame_from_header

    meta, ln, cols = _table(path, ["name", "x", "y", "z"], POINT_EXTRAS)
    if frame is None:
        if "crs" not in meta:
            raise InputFormatError("no '# crs:' header line and no CRS given", path, 1, "crs")
        frame = frame_from_header(meta["crs"][1], meta.get("heights", (0, "ellipsoidal"))[1],
                                  meta.get("geoid", (0, None))[1], path, meta["crs"][0])
    xyz = np.array([[parse_float(cols[c][i], path, ln[i], c) for c in "xyz"] for i in range(len(ln))]).reshape(-1, 3)
    return GroundPoints(np.array(cols["name"]), xyz, frame)


def read_measurements_csv(path: PathLike) -> ImageMeasurements:
    """Read ``point,image,column,row`` (extra columns of skyrig's own output are accepted and ignored)."""
    return read_measurements_csv_lines(path)[0]


def read_measurements_csv_lines(path: PathLike) -> tuple[ImageMeasurements, np.ndarray]:
    """:func:`read_measurements_csv` and the ``(N,)`` 1-based line number of each measurement (for messages)."""
    _, ln, cols = _table(path, ["point", "image", "column", "row"],
                         ["measured_column", "measured_row", "dcolumn", "drow", "x", "y", "z"])
    px = np.array([[parse_float(cols[c][i], path, ln[i], c) for c in ("column", "row")] for i in range(len(ln))])
    m = ImageMeasurements(np.array(cols["point"]), np.array(cols["image"]), px.reshape(-1, 2))
    return m, np.array(ln, dtype=np.int64)


def write_measurements_csv(
    path: PathLike, m: ImageMeasurements, measured: np.ndarray | None = None, header_lines: list[str] = ()
) -> None:
    """Write ``point,image,column,row`` (+ measured and residual columns when ``measured`` is given)."""
    with atomic_write(path, newline="") as fh:
        for h in header_lines:
            fh.write(f"# {h}\n")
        w = csv.writer(fh, lineterminator="\n")
        cols = ["point", "image", "column", "row"]
        if measured is not None:
            cols += ["measured_column", "measured_row", "dcolumn", "drow"]
        w.writerow(cols)
        for i in range(len(m)):
            row = [m.point[i], m.image[i], "%.3f" % m.pixel[i, 0], "%.3f" % m.pixel[i, 1]]
            if measured is not None:
                d = m.pixel[i] - measured[i]
                row += ["%.3f" % measured[i, 0], "%.3f" % measured[i, 1], "%.3f" % d[0], "%.3f" % d[1]]
            w.writerow(row)


def write_points_csv(path: PathLike, points: GroundPoints, extra: dict[str, np.ndarray] | None = None) -> None:
    """Write ``name,x,y,z`` with the frame in the header (+ extra numeric columns)."""
    f = points.frame
    geographic = f.kind == "map" and f.projection.crs.is_geographic
    fmt = "%.10f" if geographic else "%.4f"
    extra = extra or {}
    with atomic_write(path, newline="") as fh:
        if f.kind == "map":
            fh.write(f"# crs: {f.crs}\n# heights: {'ellipsoidal' if f.geoid is None else 'orthometric'}\n")
            if f.geoid:
                fh.write(f"# geoid: {f.geoid}\n")
        elif f.kind == "ecef":
            fh.write("# crs: EPSG:4978\n")
        else:
            fh.write("# crs: local %.12f %.12f %.6f\n" % f.origin)  # type: ignore[str-format]
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["name", "x", "y", "z", *extra])
        for i in range(len(points)):
            w.writerow([points.name[i], fmt % points.xyz[i, 0], fmt % points.xyz[i, 1], "%.4f" % points.xyz[i, 2],
                        *("%.4f" % extra[k][i] for k in extra)])
