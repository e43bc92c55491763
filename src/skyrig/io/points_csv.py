"""Plain CSV files of ground points (``name,x,y,z``) and image measurements (``point,image,column,row``).

Both have an optional ``#`` comment header; the ground-point file may carry ``# crs:``, ``# heights:`` and
``# geoid:`` lines like the EO CSV (``docs/formats/eo_csv.md``), or, as skyrig writes it, no ``#`` line and the
frame in the side-car ``NAME.csv.json`` next to GDAL's ``NAME.csvt`` / ``NAME.prj`` (:mod:`skyrig.io.table_meta`),
so that GDAL reads the table as 3D points in its CRS.  Pixel coordinates: column right, row down,
origin at the centre of the top-left pixel.
"""

from __future__ import annotations

import csv
import io

import numpy as np

from skyrig.errors import InputFormatError
from skyrig.georef.eo import WorldFrame
from skyrig.georef.observations import GroundPoints, ImageMeasurements
from skyrig.io._text import PathLike, atomic_write, float_column, no_cyclic_gc, read_text
from skyrig.io.table_meta import frame_of_meta, meta_path, read_table_meta, write_table_meta


#: Extra columns skyrig writes next to ground points (read back and ignored).
POINT_EXTRAS = ["n_rays", "rms_px", "image_column", "image_row", "sx", "sy", "sz", "role", "rays", "given_x", "given_y",
                "given_z", "vx", "vy", "vz"]
#: Optional columns on the target painted at a ground point (``skyrig measure`` reads them, others ignore them):
#: ``code`` the ring code of a circular coded target, ``target_radius_m`` the target's radius (a coded target's
#: centre dot) in metres; an empty field: not known.
POINT_TARGET_COLUMNS = ["code", "target_radius_m"]


def _header_line(path: PathLike) -> int:
    """The line number of a table's column header (the first line that is neither blank nor a comment)."""
    for k, line in enumerate(read_text(path).splitlines(), start=1):
        if line.strip() and not line.lstrip().startswith("#"):
            return k
    return 1


def _table(path: PathLike, required: list[str], optional: list[str] = ()) -> tuple[dict, list[int], dict[str, list[str]]]:
    with no_cyclic_gc():
        return _table_body(path, required, optional)


def _table_body(path: PathLike, required: list[str], optional: list[str]) -> tuple[dict, list[int], dict[str, list[str]]]:
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
    body_text = "\n".join(lines[start:])
    spaced = any(ch in body_text for ch in " \t\r\f\v")  # fields to strip (most files have none)
    rd = csv.reader(io.StringIO(body_text))
    del lines, body_text
    header = [h.strip().lower() for h in next(rd)]
    for c in required:
        if c not in header:
            raise InputFormatError("missing column", path, start + 1, c)
    for c in header:
        if c not in required and c not in optional:
            raise InputFormatError(f"unknown column {c!r}", path, start + 1, c)
    rows = list(rd)
    n = len(header)
    lens = np.fromiter(map(len, rows), np.int64, len(rows))
    k_ok = np.flatnonzero(lens > 0)  # csv gives [] for an empty line
    bad = k_ok[lens[k_ok] != n]
    if bad.size:
        raise InputFormatError(f"expected {n} fields, found {lens[bad[0]]}", path, start + 2 + int(bad[0]))
    if k_ok.size < len(rows):
        rows = [rows[k] for k in k_ok]
    cols: dict[str, list[str]] = ({c: [v.strip() for v in vals] if spaced else list(vals)
                                   for c, vals in zip(header, zip(*rows))} if rows else {c: [] for c in header})
    n_rows = len(rows)
    del rows
    blank = np.ones(n_rows, bool)  # rows of empty fields only (",,,") are left out like empty lines
    for vals in cols.values():
        blank &= np.fromiter(map(len, vals), np.int64, len(vals)) == 0
    if blank.any():
        keep = np.flatnonzero(~blank)
        cols = {c: [vals[k] for k in keep] for c, vals in cols.items()}
        k_ok = k_ok[keep]
    line_no = (k_ok + start + 2).tolist()
    return meta, line_no, cols


_HEADER_KEYS = ("crs", "heights", "height", "geoid")


def _check_keys(meta: dict[str, tuple[int, str]], path: PathLike) -> None:
    """Refuse a header key that is a misspelling of a known one (``# hieghts:``): it would be passed over."""
    import difflib

    for key, (line, _) in meta.items():
        if key in _HEADER_KEYS or not key.replace("_", "").replace("-", "").isalpha():
            continue
        near = difflib.get_close_matches(key, _HEADER_KEYS, n=1, cutoff=0.7)
        if near:
            raise InputFormatError(f"unknown header key {key!r} (did you mean {near[0]!r}?)", path, line, key)


def read_points_csv(path: PathLike, frame: WorldFrame | None = None, default_frame: WorldFrame | None = None,
                    option: str = "the command line") -> GroundPoints:
    """Read ``name,x,y,z`` in the frame the file states (``#`` header lines or the side-car).

    Parameters
    ----------
    frame
        A frame the caller insists on: when the file states one too, they must agree (else
        :class:`InputFormatError` naming the header line and ``option``); a file that states none is read in it.
    default_frame
        The frame of a file that states none (e.g. the EO's CRS); the file's own statement wins.
    option
        What named ``frame`` (``"--points-crs"``), for the message when file and caller disagree.

    Raises
    ------
    InputFormatError
        Naming file, line and field for malformed rows, duplicate names, heights no ground point can have,
        x/y or longitude/latitude that only fit the CRS's area of use when swapped; a
        :class:`~skyrig.errors.PlausibilityWarning` for positions outside that area.
    """
    from skyrig.io.eo_csv import frame_from_header
    from skyrig.io.plausibility import check_coordinates, check_same_frame

    meta, ln, cols = _table(path, ["name", "x", "y", "z"], POINT_EXTRAS + POINT_TARGET_COLUMNS)
    _check_keys(meta, path)
    if "height" in meta and "heights" not in meta:  # the trajectory format's spelling, accepted here too
        meta["heights"] = meta["height"]
    stated, stated_line, stated_path = None, None, path
    if "crs" in meta:
        stated_line = meta["crs"][0]
        stated = frame_from_header(meta["crs"][1], meta.get("heights", (0, "ellipsoidal"))[1],
                                   meta.get("geoid", (0, None))[1], path, stated_line)
    elif "heights" in meta or "geoid" in meta:
        key = next(k for k in ("heights", "geoid") if k in meta)
        raise InputFormatError(f"'# {key}:' without a '# crs:' line", path, meta[key][0], key)
    else:
        side = read_table_meta(path)
        stated = None if side is None else frame_of_meta(side, path)
        stated_path = meta_path(path) if stated is not None else path
    if stated is not None and frame is not None:
        check_same_frame(stated, frame, stated_path, stated_line, option)
    use = stated or frame or default_frame
    if use is None:
        raise InputFormatError("no '# crs:' header line, no side-car with the frame and no CRS given", path, 1, "crs")
    if not ln:
        raise InputFormatError("no rows after the column header: a points file needs at least one point", path,
                               _header_line(path), None)
    xyz = np.stack([float_column(cols[c], path, ln, c) for c in "xyz"], axis=1).reshape(-1, 3)
    seen: dict[str, int] = {}
    for n, line in zip(cols["name"], ln):
        if not n:
            raise InputFormatError("empty point name", path, line, "name")
        if n in seen:
            raise InputFormatError(f"point {n!r} appears twice (first on line {seen[n]})", path, line, "name")
        seen[n] = line
    check_coordinates(xyz, use, path, ln, "ground", lenient=stated_path != path)  # side-car: skyrig's own output
    return GroundPoints(np.array(cols["name"]), xyz, use)


def read_point_extras(path: PathLike) -> dict[str, list[str]]:
    """The ``name`` column and the text of the :data:`POINT_EXTRAS` columns a points CSV has (e.g. the residuals
    ``vx, vy, vz`` and sigmas of an adjustment's ``ground_control.csv``), by column name."""
    _, _, cols = _table(path, ["name", "x", "y", "z"], POINT_EXTRAS + POINT_TARGET_COLUMNS)
    return {c: cols[c] for c in ["name", *POINT_EXTRAS] if c in cols}


def read_point_targets(path: PathLike, bits: int = 12) -> dict[str, tuple[int | None, float]]:
    """``{name: (code, target_radius_m)}`` from the :data:`POINT_TARGET_COLUMNS` of a points CSV (``code`` None and
    the radius NaN where the file has no such column or an empty field); ``{}`` when it has neither column.

    Raises
    ------
    InputFormatError
        Naming file, line and field: a code that is not a whole number whose ``bits``-bit ring has both bright
        and dark sectors (``1 .. 2**bits - 2``), a radius that is not a positive number of metres.
    """
    from skyrig.io._text import parse_float

    _, ln, cols = _table(path, ["name", "x", "y", "z"], POINT_EXTRAS + POINT_TARGET_COLUMNS)
    if not any(c in cols for c in POINT_TARGET_COLUMNS):
        return {}
    out: dict[str, tuple[int | None, float]] = {}
    top = (1 << bits) - 2
    for k, (name, line) in enumerate(zip(cols["name"], ln)):
        code, radius = None, float("nan")
        text = cols.get("code", [""] * len(ln))[k]
        if text:
            try:
                code = int(text)
            except ValueError:
                try:  # a whole number a spreadsheet wrote as 37.0
                    v = float(text)
                    code = int(v) if v.is_integer() else -1
                except (ValueError, OverflowError):
                    code = -1
            if not 1 <= code <= top:
                raise InputFormatError(f"code {text!r} is not a {bits}-bit ring code (a whole number 1 .. {top}: "
                                       f"some sectors bright, some dark)", path, line, "code")
        text = cols.get("target_radius_m", [""] * len(ln))[k]
        if text:
            radius = parse_float(text, path, line, "target_radius_m")
            if not radius > 0.0:
                raise InputFormatError(f"target radius {text!r} m is not positive", path, line, "target_radius_m")
        out[name] = (code, radius)
    return out


def read_measurements_csv(path: PathLike) -> ImageMeasurements:
    """Read ``point,image,column,row`` (extra columns of skyrig's own output are accepted and ignored)."""
    return read_measurements_csv_lines(path)[0]


#: Provenance columns of a measurements file (``skyrig measure`` writes them; other readers ignore them): how the
#: position was found, whether a sub-pixel refinement moved it, its standard deviation, who and when.
MEASUREMENT_PROVENANCE = ["method", "refined", "sigma_px", "operator", "time_utc"]
_MEASUREMENT_EXTRAS = ["measured_column", "measured_row", "dcolumn", "drow", "x", "y", "z", *MEASUREMENT_PROVENANCE]


def read_measurements_csv_lines(path: PathLike) -> tuple[ImageMeasurements, np.ndarray]:
    """:func:`read_measurements_csv` and the ``(N,)`` 1-based line number of each measurement (for messages)."""
    m, ln, _ = read_measurements_table(path)
    return m, ln


def read_measurements_table(path: PathLike) -> tuple[ImageMeasurements, np.ndarray, dict[str, list[str]]]:
    """:func:`read_measurements_csv_lines` and the text of the provenance columns the file has
    (:data:`MEASUREMENT_PROVENANCE`: ``{column: (N,) values}``; a column the file lacks is left out)."""
    _, ln, cols = _table(path, ["point", "image", "column", "row"], _MEASUREMENT_EXTRAS)
    px = np.stack([float_column(cols[c], path, ln, c) for c in ("column", "row")], axis=1)
    with no_cyclic_gc():
        _check_pairs(cols, ln, path)
    m = ImageMeasurements(np.array(cols["point"]), np.array(cols["image"]), px.reshape(-1, 2))
    return m, np.array(ln, dtype=np.int64), {c: cols[c] for c in MEASUREMENT_PROVENANCE if c in cols}


def _check_pairs(cols: dict[str, list[str]], ln: list[int], path: PathLike) -> None:
    """No empty point / image name, no point measured twice in one image (the message names the line)."""
    for c in ("point", "image"):
        empty = np.fromiter(map(len, cols[c]), np.int64, len(ln)) == 0
        if empty.any():
            raise InputFormatError(f"empty {c} name", path, ln[int(np.argmax(empty))], c)
    if len(dict.fromkeys(zip(cols["point"], cols["image"]))) < len(ln):  # a pair twice: find it for the message
        seen: dict[tuple[str, str], int] = {}
        for p_, im, line in zip(cols["point"], cols["image"], ln):
            if (p_, im) in seen:
                raise InputFormatError(f"point {p_!r} is measured twice in image {im!r} (first on line "
                                       f"{seen[p_, im]})", path, line, "point")
            seen[p_, im] = line


def write_measurements_csv(
    path: PathLike, m: ImageMeasurements, measured: np.ndarray | None = None, header_lines: list[str] = (),
    provenance: dict[str, np.ndarray] | None = None,
) -> None:
    """Write ``point,image,column,row`` (+ measured and residual columns when ``measured`` is given, + the
    :data:`MEASUREMENT_PROVENANCE` columns given in ``provenance``, as text, in that order)."""
    prov = {c: [str(v) for v in provenance[c]] for c in MEASUREMENT_PROVENANCE if provenance and c in provenance}
    unknown = set(provenance or {}) - set(MEASUREMENT_PROVENANCE)
    if unknown:
        raise ValueError(f"unknown provenance column(s) {sorted(unknown)} (known: {MEASUREMENT_PROVENANCE})")
    with atomic_write(path, newline="") as fh:
        for h in header_lines:
            fh.write(f"# {h}\n")
        w = csv.writer(fh, lineterminator="\n")
        cols = ["point", "image", "column", "row"]
        if measured is not None:
            cols += ["measured_column", "measured_row", "dcolumn", "drow"]
        cols += list(prov)
        w.writerow(cols)
        for i in range(len(m)):
            row = [m.point[i], m.image[i], "%.3f" % m.pixel[i, 0], "%.3f" % m.pixel[i, 1]]
            if measured is not None:
                d = m.pixel[i] - measured[i]
                row += ["%.3f" % measured[i, 0], "%.3f" % measured[i, 1], "%.3f" % d[0], "%.3f" % d[1]]
            w.writerow(row + [v[i] for v in prov.values()])


def write_points_csv(path: PathLike, points: GroundPoints, extra: dict[str, np.ndarray] | None = None,
                     sidecar: bool = True) -> None:
    """Write ``name,x,y,z`` (+ extra columns: numbers, or strings for ``role``) with the frame in the side-car
    ``NAME.csv.json`` and GDAL's ``NAME.csvt`` / ``NAME.prj`` (``sidecar``, default) or in ``#`` header lines."""
    f = points.frame
    geographic = f.kind == "map" and f.projection.crs.is_geographic
    fmt = "%.10f" if geographic else "%.4f"
    extra = extra or {}
    text = {k for k, v in extra.items() if np.asarray(v).dtype.kind in "USO"}
    with atomic_write(path, newline="") as fh:
        if not sidecar:
            fh.write("".join(f"# {k}: {v}\n" for k, v in f.fields().items()))
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["name", "x", "y", "z", *extra])
        for i in range(len(points)):
            w.writerow([points.name[i], fmt % points.xyz[i, 0], fmt % points.xyz[i, 1], "%.4f" % points.xyz[i, 2],
                        *(str(extra[k][i]) if k in text else "%.4f" % extra[k][i] for k in extra)])
    if not sidecar:
        stale = meta_path(path)
        if stale.exists():
            stale.unlink()
        return
    xyu = "degree" if geographic else "metre"
    columns: dict[str, dict[str, str]] = {
        "name": {"type": "String"}, "x": {"type": "Point(X)", "unit": xyu}, "y": {"type": "Point(Y)", "unit": xyu},
        "z": {"type": "Point(Z)", "unit": "metre", "axis": f"height ({f.heights})" if f.kind == "map" else "z"}}
    for k in extra:
        columns[k] = ({"type": "String"} if k in text else {"type": "Real"} if k in ("n_rays", "rays")
                      else {"type": "Real", "unit": "pixel" if k in ("rms_px", "image_column", "image_row") else "metre"})
    write_table_meta(path, f, columns, "skyrig-points 1", {
        "sigmas": "sx, sy, sz: a-posteriori standard deviations along the frame's axes (map frames: grid east, "
                  "grid north, up at the point)" if {"sx", "sy", "sz"} & set(extra) else None})
