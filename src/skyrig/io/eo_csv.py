"""skyrig exterior-orientation CSV (format ``skyrig-eo``, version 1).  See ``docs/formats/eo_csv.md``.

Example::

    # skyrig-eo 1
    # crs: EPSG:25832
    # heights: orthometric
    # geoid: /data/grids/egm96_15.gtx
    # angles: deg
    # convention: opk
    image,camera,x,y,z,omega,phi,kappa,time,head,exposure
    e0001_nadir.tif,nadir,500123.412,5700321.118,1012.337,0.1021,-0.2210,90.0132,345600.125,nadir,1

Header keys (``# key: value`` lines before the column row; all required except ``geoid`` and ``rotation``):

``crs``
    ``EPSG:4978`` for ECEF, ``local <lat_deg> <lon_deg> <h_m>`` for a local ENU frame, or any CRS PROJ knows
    (EPSG code, WKT on one line, PROJ string): then x, y are map coordinates (longitude, latitude in degrees
    for a geographic CRS) and rotations refer to the grid axes at each projection centre.
``heights``
    ``ellipsoidal`` or ``orthometric`` (then ``geoid`` names the PROJ grid, a path or a grid name).
``angles``
    ``deg``, ``rad`` or ``gon``.
``convention``
    ``opk`` (omega-phi-kappa, R = Rx Ry Rz), ``pok`` (phi-omega-kappa, R = Ry Rx Rz), both giving
    ``frame_from_camera``; or ``ypr`` (columns ``yaw,pitch,roll``: attitude of a virtual platform carrying the
    camera in the standard nadir mount, heading from geographic north, see
    :mod:`skyrig.georef.attitude_frames`).

Columns: ``image, camera, x, y, z`` and the three angle columns are required; ``time`` (s), ``head`` and
``exposure`` (integer) are optional.  Unknown columns are an error.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from skyrig.errors import CRSError, ConfigError, InputFormatError, UnitError
from skyrig.georef.attitude_frames import ypr_from_rotation
from skyrig.georef.eo import ExteriorOrientations, WorldFrame
from skyrig.geometry.angles import check_plausible, normalize_unit
from skyrig.geometry.rotations import opk_from_matrix
from skyrig.io._text import PathLike, atomic_write, parse_float, read_text
from skyrig.io.table_meta import frame_of_meta, meta_path, read_table_meta, write_table_meta

MAGIC = "skyrig-eo"
VERSION = 1
_ANGLES = {"opk": ("omega", "phi", "kappa"), "pok": ("omega", "phi", "kappa"), "ypr": ("yaw", "pitch", "roll")}
_OPTIONAL = ("time", "head", "exposure")


def frame_from_header(crs: str, heights: str, geoid: str | None, path: PathLike, line: int) -> WorldFrame:
    """Build the :class:`WorldFrame` a file header describes (errors name file and line)."""
    try:
        if crs.strip().lower().startswith("local"):
            parts = crs.split()
            if len(parts) != 4:
                raise InputFormatError("expected 'local <lat_deg> <lon_deg> <h_m>'", path, line, "crs")
            for p_ in parts[1:]:
                parse_float(p_, path, line, "crs")
        elif crs.strip().upper() not in ("EPSG:4978", "ECEF"):
            if heights not in ("ellipsoidal", "orthometric"):
                raise InputFormatError(f"heights must be 'ellipsoidal' or 'orthometric', not {heights!r}", path, line,
                                       "heights")
            if heights == "orthometric" and not geoid:
                raise InputFormatError("orthometric heights need a '# geoid:' header line", path, line, "geoid")
        frame = WorldFrame.from_fields(crs, heights, geoid, base=Path(path).parent)
        if frame.geoid:
            frame.projection  # noqa: B018  (validates the grid now)
        return frame
    except InputFormatError:
        raise
    except CRSError as exc:  # before ValueError: a CRSError is one
        raise InputFormatError(str(exc), path, line, "crs" if "grid" not in str(exc) else "geoid") from None
    except ValueError as exc:
        raise InputFormatError(str(exc), path, line, "crs") from None


def _parse_header(path: PathLike, lines: list[str]) -> tuple[dict[str, tuple[int, str]], int]:
    meta: dict[str, tuple[int, str]] = {}
    i = 0
    for i, raw in enumerate(lines):
        s = raw.strip()
        if not s:
            continue
        if not s.startswith("#"):
            return meta, i
        body = s[1:].strip()
        if ":" in body:
            k, v = body.split(":", 1)
            meta[k.strip().lower()] = (i + 1, v.strip())
        elif body:
            meta.setdefault("_magic", (i + 1, body))
    return meta, len(lines)


_HEADER_KEYS = ("crs", "heights", "geoid", "angles", "convention", "frame", "rotation", "time")


def _check_keys(meta: dict[str, tuple[int, str]], path: PathLike) -> None:
    """Refuse a header key that is a misspelling of a known one (``# angels: deg``, ``# hieghts: orthometric``):
    passed over, it would leave the file read with a default."""
    import difflib

    for key, (line, _) in meta.items():
        if key in _HEADER_KEYS or key.startswith("_") or not key.replace("_", "").replace("-", "").isalpha():
            continue
        near = difflib.get_close_matches(key, _HEADER_KEYS, n=1, cutoff=0.7)
        if near:
            raise InputFormatError(f"unknown header key {key!r} (did you mean {near[0]!r}?)", path, line or None, key)


def read_eo_csv(path: PathLike) -> ExteriorOrientations:
    """Read a ``skyrig-eo`` CSV file."""
    text = read_text(path)
    lines = text.splitlines()
    meta, start = _parse_header(path, lines)
    frame = None
    if not meta:  # no '#' header: the statement is in the side-car NAME.csv.json
        side = read_table_meta(path)
        if side is None:
            raise InputFormatError(f"first line must be '# {MAGIC} {VERSION}', or the table needs its side-car "
                                   f"{meta_path(path).name}", path, 1)
        where = str(meta_path(path))
        meta = {"_magic": (1, str(side.get("table", ""))), **{k: (0, str(side[k])) for k in ("angles", "convention")
                                                               if k in side}}
        frame = frame_of_meta(side, path)
        if frame is None:
            raise InputFormatError("the side-car states no frame", where, None, "frame")
        path_hdr = where
    else:
        path_hdr = path
    if "height" in meta and "heights" not in meta:  # the trajectory format's spelling, accepted here too
        meta["heights"] = meta.pop("height")
    _check_keys(meta, path_hdr)
    magic = meta.get("_magic", (1, ""))[1].split()
    if len(magic) != 2 or magic[0] != MAGIC:
        raise InputFormatError(f"first line must be '# {MAGIC} {VERSION}'", path_hdr, 1)
    if magic[1] != str(VERSION):
        raise InputFormatError(f"unsupported {MAGIC} version {magic[1]!r} (this skyrig reads {VERSION})", path_hdr, 1)
    for key in ("crs", "angles", "convention"):
        if key not in meta and not (key == "crs" and frame is not None):
            raise InputFormatError("missing header line", path_hdr, None, key)
    try:
        unit = normalize_unit(meta["angles"][1])
    except UnitError as exc:
        raise InputFormatError(str(exc), path_hdr, meta["angles"][0] or None, "angles") from None
    conv = meta["convention"][1].lower()
    if conv not in _ANGLES:
        raise InputFormatError(f"convention must be opk, pok or ypr, not {conv!r}", path_hdr,
                               meta["convention"][0] or None, "convention")
    if frame is None:
        heights = meta.get("heights", (0, "ellipsoidal"))
        frame = frame_from_header(meta["crs"][1], heights[1], meta.get("geoid", (0, None))[1], path, meta["crs"][0])
    if start >= len(lines):
        raise InputFormatError("no column header row", path, len(lines))
    reader = csv.reader(io.StringIO("\n".join(lines[start:])))
    header = [h.strip() for h in next(reader)]
    header_line = start + 1
    required = ["image", "camera", "x", "y", "z", *_ANGLES[conv]]
    for col in header:
        if col not in required and col not in _OPTIONAL:
            raise InputFormatError(f"unknown column {col!r}", path, header_line, col)
    for col in required:
        if col not in header:
            raise InputFormatError("missing column", path, header_line, col)
    pos = {c: header.index(c) for c in header}
    rows: list[list[str]] = []
    line_no: list[int] = []
    for k, row in enumerate(reader):
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) != len(header):
            raise InputFormatError(f"expected {len(header)} fields, found {len(row)}", path, header_line + 1 + k)
        rows.append(row)
        line_no.append(header_line + 1 + k)
    if not rows:
        raise InputFormatError("no data rows", path, header_line)
    num_cols = ["x", "y", "z", *_ANGLES[conv]] + (["time"] if "time" in pos else [])
    values = {c: np.array([parse_float(r[pos[c]], path, ln, c) for r, ln in zip(rows, line_no)]) for c in num_cols}
    for c in _ANGLES[conv]:
        why = check_plausible(values[c], unit)
        if why:
            bad = int(np.argmax(np.abs(values[c])))
            raise InputFormatError(why, path, line_no[bad], c)
    names = np.array([r[pos["image"]].strip() for r in rows])
    seen: dict[str, int] = {}
    for n, ln in zip(names, line_no):
        if n in seen:
            raise InputFormatError(f"duplicate image {n!r} (first on line {seen[n]})", path, ln, "image")
        seen[n] = ln
    centre = np.stack([values["x"], values["y"], values["z"]], axis=1)
    from skyrig.io.plausibility import angle_readings, check_angle_unit, check_attitude_reading, check_coordinates

    check_coordinates(centre, frame, path, line_no, "camera")
    a = _ANGLES[conv]
    tilt_cols, head_col = (a[1:], a[0]) if conv == "ypr" else (a[:2], a[2])
    check_angle_unit(np.stack([values[c] for c in tilt_cols], axis=1), values[head_col], unit, path, "/".join(a))
    cols3 = np.stack([values[c] for c in a], axis=1)
    rotations_of = angle_readings(frame, centre, cols3)
    rot = rotations_of(unit, conv)
    check_attitude_reading(rotations_of, unit, conv, centre, path, line_no, a,
                           "declare them with the header lines '# angles: ...' and '# convention: ...' (or the "
                           "side-car's \"angles\" and \"convention\" keys)",
                           groups=[r[pos["camera"]].strip() for r in rows],
                           order=values.get("time"), values=cols3, frame=frame)
    exposure = None
    if "exposure" in pos:
        try:
            exposure = np.array([int(r[pos["exposure"]]) for r in rows])
        except ValueError:
            bad = next(i for i, r in enumerate(rows) if not r[pos["exposure"]].strip().lstrip("-").isdigit())
            raise InputFormatError("exposure must be an integer", path, line_no[bad], "exposure") from None
    return ExteriorOrientations(
        names,
        np.array([r[pos["camera"]].strip() for r in rows]),
        centre,
        rot,
        frame,
        time_s=values.get("time"),
        head=np.array([r[pos["head"]].strip() for r in rows]) if "head" in pos else None,
        exposure=exposure,
    )


def write_eo_csv(eo: ExteriorOrientations, path: PathLike, unit: str = "deg", convention: str = "opk",
                 sidecar: bool = True) -> None:
    """Write exterior orientations as a ``skyrig-eo`` CSV (atomically).

    ``sidecar`` (default): a plain CSV that GDAL reads as it is, the header keys in ``NAME.csv.json`` with GDAL's
    ``NAME.csvt`` / ``NAME.prj`` (:mod:`skyrig.io.table_meta`); False: the ``#`` header lines in the file.
    """
    unit = normalize_unit(unit)
    convention = convention.lower()
    if convention not in _ANGLES:
        raise ConfigError(f"convention must be opk, pok or ypr, not {convention!r}")
    f = eo.frame
    if convention == "ypr":
        a = ypr_from_rotation(f, eo.centre, eo.rotation, unit=unit)
    else:
        a = opk_from_matrix(eo.rotation, unit=unit, sequence=convention)
    geographic = f.kind == "map" and f.projection.crs.is_geographic
    xy_fmt = "%.10f" if geographic else "%.4f"
    cols = ["image", "camera", "x", "y", "z", *_ANGLES[convention]]
    opt = [c for c, v in (("time", eo.time_s), ("head", eo.head), ("exposure", eo.exposure)) if v is not None]
    with atomic_write(path, newline="") as fh:
        if not sidecar:
            fh.write(f"# {MAGIC} {VERSION}\n")
            fh.write("".join(f"# {k}: {v}\n" for k, v in f.fields().items()))
            fh.write(f"# frame: {f.describe()}\n# angles: {unit}\n# convention: {convention}\n")
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(cols + opt)
        for i in range(len(eo)):
            row = [eo.image[i], eo.camera[i], xy_fmt % eo.centre[i, 0], xy_fmt % eo.centre[i, 1], "%.4f" % eo.centre[i, 2]]
            row += ["%.10f" % a[j][i] for j in range(3)]
            if eo.time_s is not None:
                row.append("%.6f" % eo.time_s[i])
            if eo.head is not None:
                row.append(eo.head[i])
            if eo.exposure is not None:
                row.append(str(int(eo.exposure[i])))
            w.writerow(row)
    if not sidecar:
        stale = meta_path(path)
        if stale.exists():
            stale.unlink()
        return
    xyu = "degree" if geographic else "metre"
    axes = ("longitude", "latitude") if geographic else ("x (grid east)", "y (grid north)")
    au = {"deg": "degree", "rad": "radian", "gon": "gon"}[unit]
    columns: dict[str, dict[str, str]] = {
        "image": {"type": "String"}, "camera": {"type": "String"},
        "x": {"type": "Point(X)", "unit": xyu, "axis": axes[0] if f.kind == "map" else "x"},
        "y": {"type": "Point(Y)", "unit": xyu, "axis": axes[1] if f.kind == "map" else "y"},
        "z": {"type": "Point(Z)", "unit": "metre", "axis": f"height ({f.heights})" if f.kind == "map" else "z"},
        **{c: {"type": "Real", "unit": au} for c in _ANGLES[convention]},
        **{c: t for c, t in (("time", {"type": "Real", "unit": "second"}), ("head", {"type": "String"}),
                               ("exposure", {"type": "Integer"})) if c in opt},
    }
    write_table_meta(path, f, columns, f"{MAGIC} {VERSION}", {
        "angles": unit, "convention": convention,
        "rotation": "frame_from_camera; map frames: grid axes (grid east, grid north, ellipsoid normal up) at "
                    "each projection centre"})
