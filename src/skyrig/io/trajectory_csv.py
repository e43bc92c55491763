"""The skyrig trajectory CSV format (``# skyrig-trajectory 1``); layout in ``docs/formats/trajectory_csv.md``.

Example::

    # skyrig-trajectory 1
    # crs: EPSG:4979
    # angles: deg
    # heading: true
    # reference: imu
    # time: gps-sow
    time,lat,lon,h,roll,pitch,yaw
    345600.000,45.1000000000,7.2000000000,1200.000,0.5,-1.2,87.3

Every error names the file, the line and the field (column or header key).
"""

from __future__ import annotations

import io
import logging
import os
import re
from dataclasses import dataclass
from typing import Any
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from skyrig.errors import CRSError, ImplausibleAngleError, InputFormatError, UnitError  # noqa: F401 (re-export)
from skyrig.geodesy.crs import WGS84_ECEF, Geoid, MapProjection, ecef_to_geodetic, resolve_crs, transformer
from skyrig.geometry.angles import check_plausible, from_radians, normalize_unit
from skyrig.io._text import atomic_write, read_text
from skyrig.trajectory.trajectory import Trajectory

logger = logging.getLogger(__name__)

__all__ = ["ImplausibleAngleError", "read_trajectory_csv", "write_trajectory_csv", "TIME_SYSTEMS"]

PathLike = str | os.PathLike[str]

FORMAT_VERSION = 1
#: Time systems a file may declare.  ``gps-week-sow`` needs a ``week`` column and is read as ``gps``.
TIME_SYSTEMS = ("gps-sow", "gps-week-sow", "gps", "utc-sod", "utc-unix")
SECONDS_PER_WEEK = 604800.0

_DIRECTIVE = re.compile(r"^([A-Za-z][A-Za-z0-9_-]*)\s*:\s*(.*)$")


# --------------------------------------------------------------------------- shared text machinery
@dataclass
class _Header:
    directives: dict[str, tuple[str, int]]  # key -> (value, line)
    columns: list[str]
    header_line: int
    data: list[tuple[int, str]]  # (line, text)


def _split_file(path: PathLike, magic: str, known: tuple[str, ...]) -> _Header:
    """Split a skyrig CSV file into directives, the column header and data lines."""
    lines = read_text(path).splitlines()
    directives: dict[str, tuple[str, int]] = {}
    seen_magic = False
    columns: list[str] | None = None
    header_line = 0
    data: list[tuple[int, str]] = []
    for no, raw in enumerate(lines, start=1):
        text = raw.strip()
        if not text:
            continue
        if text.startswith("#"):
            if columns is not None:
                continue  # comments among the data are allowed
            body = text[1:].strip()
            if not seen_magic:
                parts = body.split()
                if not parts or parts[0] != magic:
                    raise InputFormatError(f"first line must be '# {magic} {FORMAT_VERSION}'", path, no, magic)
                if len(parts) != 2 or parts[1] != str(FORMAT_VERSION):
                    raise InputFormatError(
                        f"unsupported format version {' '.join(parts[1:])!r}; this reader knows {FORMAT_VERSION}",
                        path, no, magic)
                seen_magic = True
                continue
            m = _DIRECTIVE.match(body)
            if m:
                key = m.group(1).lower()
                if key not in known:
                    raise InputFormatError(
                        f"unknown header key {m.group(1)!r}; known keys: {', '.join(known)}", path, no, m.group(1))
                if key in directives:
                    raise InputFormatError(f"header key {key!r} repeated (first on line {directives[key][1]})",
                                           path, no, key)
                directives[key] = (m.group(2).strip(), no)
            continue
        if not seen_magic:
            raise InputFormatError(f"first line must be '# {magic} {FORMAT_VERSION}'", path, no, magic)
        if columns is None:
            columns = [c.strip().lower() for c in text.split(",")]
            header_line = no
            continue
        data.append((no, raw))
    if not seen_magic:
        raise InputFormatError(f"empty file; expected '# {magic} {FORMAT_VERSION}'", path, 1, magic)
    if columns is None:
        raise InputFormatError("no column header row", path, len(lines) + 1, None)
    for i, c in enumerate(columns):
        if not c:
            raise InputFormatError(f"empty column name (column {i + 1})", path, header_line, None)
        if c in columns[:i]:
            raise InputFormatError(f"column {c!r} appears twice", path, header_line, c)
    return _Header(directives, columns, header_line, data)


def _check_columns(path: PathLike, hdr: _Header, required: list[str], groups: list[tuple[str, ...]],
                   optional: tuple[str, ...] = ()) -> None:
    allowed = set(required) | set(optional) | {c for g in groups for c in g}
    for c in hdr.columns:
        if c not in allowed:
            raise InputFormatError(f"unknown column {c!r}; allowed: {', '.join(sorted(allowed))}",
                                   path, hdr.header_line, c)
    for c in required:
        if c not in hdr.columns:
            raise InputFormatError(f"required column {c!r} is missing", path, hdr.header_line, c)
    for g in groups:
        present = [c for c in g if c in hdr.columns]
        if present and len(present) != len(g):
            missing = next(c for c in g if c not in hdr.columns)
            raise InputFormatError(f"column {missing!r} is missing (columns {', '.join(g)} go together)",
                                   path, hdr.header_line, missing)


def _numeric_table(path: PathLike, hdr: _Header) -> NDArray[np.float64]:
    """All data cells as floats ``(rows, columns)``; errors name the line and column."""
    ncol = len(hdr.columns)
    if not hdr.data:
        return np.zeros((0, ncol))
    try:
        table = np.loadtxt(io.StringIO("\n".join(t for _, t in hdr.data)), delimiter=",", ndmin=2,
                           dtype=np.float64, comments=None)
        ok = table.shape == (len(hdr.data), ncol)
    except ValueError:
        ok = False
    if not ok:  # slow path, only to say exactly what is wrong where
        for no, text in hdr.data:
            cells = text.split(",")
            if len(cells) != ncol:
                raise InputFormatError(f"expected {ncol} values, found {len(cells)}", path, no, None)
            for c, cell in zip(hdr.columns, cells):
                try:
                    float(cell)
                except ValueError:
                    raise InputFormatError(f"{cell.strip()!r} is not a number", path, no, c) from None
        raise InputFormatError("cannot parse the data rows", path, hdr.data[0][0], None)  # pragma: no cover
    bad = ~np.isfinite(table)
    if np.any(bad):
        r, c = np.argwhere(bad)[0]
        raise InputFormatError(f"{table[r, c]!r} is not a finite number", path, hdr.data[r][0], hdr.columns[c])
    return table


def _angle_unit(path: PathLike, hdr: _Header, required: bool) -> str | None:
    if "angles" not in hdr.directives:
        if required:
            raise InputFormatError("header key 'angles' (deg, rad or gon) is required", path, hdr.header_line,
                                   "angles")
        return None
    value, no = hdr.directives["angles"]
    try:
        return normalize_unit(value)
    except UnitError as exc:
        raise InputFormatError(str(exc), path, no, "angles") from None


def _time_system(path: PathLike, hdr: _Header) -> str:
    value, no = hdr.directives.get("time", ("gps-sow", hdr.header_line))
    v = value.strip().lower()
    if v not in TIME_SYSTEMS:
        raise InputFormatError(f"unknown time system {value!r}; expected one of {', '.join(TIME_SYSTEMS)}",
                               path, no, "time")
    return v


def _choice(path: PathLike, hdr: _Header, key: str, choices: tuple[str, ...]) -> str:
    value, no = hdr.directives.get(key, (choices[0], hdr.header_line))
    v = value.strip().lower()
    if v not in choices:
        raise InputFormatError(f"{key} must be one of {', '.join(choices)}, not {value!r}", path, no, key)
    return v


def _check_angles(path: PathLike, hdr: _Header, table: NDArray[np.float64], col: str, unit: str,
                  turns: float) -> None:
    """Refuse angles beyond ``turns`` full turns in magnitude: the declared unit cannot be right."""
    v = table[:, hdr.columns.index(col)]
    full = {"deg": 360.0, "rad": 2.0 * np.pi, "gon": 400.0}[unit]
    bad = np.abs(v) > turns * full * (1.0 + 1e-12)
    if np.any(bad):
        k = int(np.argmax(bad))
        why = check_plausible(v[k], unit, limit_turns=turns) or f"angle {v[k]!r} impossible in {unit}"
        raise ImplausibleAngleError(f"{why} (declared 'angles: {unit}')", path, hdr.data[k][0], col)


def _check_increasing(path: PathLike, hdr: _Header, t: NDArray[np.float64], field: str = "time") -> None:
    bad = np.diff(t) <= 0
    if np.any(bad):
        k = int(np.argmax(bad)) + 1
        raise InputFormatError(
            f"time {t[k]!r} is not after the previous one ({t[k - 1]!r}); times must be strictly increasing",
            path, hdr.data[k][0], field)


def _read_time(path: PathLike, hdr: _Header, table: NDArray[np.float64], system: str) -> tuple[NDArray, str]:
    t = table[:, hdr.columns.index("time")]
    if system == "gps-week-sow":
        week = table[:, hdr.columns.index("week")]
        frac = week != np.round(week)
        if np.any(frac) or np.any(week < 0):
            k = int(np.argmax(frac | (week < 0)))
            raise InputFormatError(f"GPS week {week[k]!r} is not a whole non-negative number", path,
                                   hdr.data[k][0], "week")
        bad = (t < 0) | (t >= SECONDS_PER_WEEK)
        if np.any(bad):
            k = int(np.argmax(bad))
            raise InputFormatError(f"seconds of week {t[k]!r} outside [0, 604800)", path, hdr.data[k][0], "time")
        return week * SECONDS_PER_WEEK + t, "gps"
    return t, system


# --------------------------------------------------------------------------- reader
_KEYS = ("crs", "height", "geoid", "angles", "heading", "reference", "time")
_ANGLE_TURNS = {"roll": 0.5, "pitch": 0.25, "yaw": 1.0, "sroll": 0.25, "spitch": 0.25, "syaw": 0.25}


def _resolve_geoid(path: PathLike, value: str) -> str:
    if os.path.sep in value or "/" in value or value.lower().endswith((".gtx", ".tif", ".tiff")):
        p = Path(value).expanduser()
        if not p.is_absolute():
            p = Path(path).resolve().parent / p
        return str(p)
    return value


def read_trajectory_csv(path: PathLike) -> Trajectory:
    """Read a skyrig trajectory CSV file (see ``docs/formats/trajectory_csv.md``).

    Parameters
    ----------
    path
        The file.

    Returns
    -------
    Trajectory
        Positions converted to WGS84 geodetic (ellipsoidal heights), yaw to a true heading,
        angles to radians internally.

    Raises
    ------
    InputFormatError
        Naming the file, the line and the field (column or header key) for: a missing or wrong
        format line, unknown header keys, an unknown CRS or unusable geoid, missing, unknown or
        repeated columns, rows of the wrong length, non-numbers, NaN or infinities, times that do not
        increase, latitudes beyond +-90 degrees.
    ImplausibleAngleError
        (an ``InputFormatError`` and a ``UnitError``) for angles impossible in the declared unit.
    """
    hdr = _split_file(path, "skyrig-trajectory", _KEYS)
    unit = str(_angle_unit(path, hdr, required=True))
    tsys = _time_system(path, hdr)
    heading = _choice(path, hdr, "heading", ("true", "grid"))
    reference = _choice(path, hdr, "reference", ("imu", "antenna"))
    height = _choice(path, hdr, "height", ("ellipsoidal", "orthometric"))

    crs_text, crs_line = hdr.directives.get("crs", ("EPSG:4979", hdr.header_line))
    try:
        crs = resolve_crs(crs_text)
    except CRSError as exc:
        raise InputFormatError(exc.args[0], path, crs_line, "crs") from None
    if crs.is_compound:
        raise InputFormatError("give the horizontal CRS only and declare heights with 'height:' and 'geoid:'",
                               path, crs_line, "crs")
    geoid: Geoid | None = None
    if height == "orthometric":
        if "geoid" not in hdr.directives:
            line = hdr.directives.get("height", ("", hdr.header_line))[1]
            raise InputFormatError("orthometric heights need a 'geoid:' header (grid file or PROJ name)",
                                   path, line, "geoid")
        if crs.is_geocentric:
            raise InputFormatError("a geocentric CRS has no orthometric heights", path,
                                   hdr.directives["height"][1], "height")
        gval, gline = hdr.directives["geoid"]
        try:
            geoid = Geoid(_resolve_geoid(path, gval))
        except CRSError as exc:
            raise InputFormatError(exc.args[0], path, gline, "geoid") from None
    elif "geoid" in hdr.directives:
        raise InputFormatError("a geoid is given but heights are declared ellipsoidal ('height: orthometric'?)",
                               path, hdr.directives["geoid"][1], "geoid")

    pos_cols = ["lat", "lon", "h"] if crs.is_geographic else ["x", "y", "z"]
    required = ["time", *pos_cols, "roll", "pitch", "yaw"] + (["week"] if tsys == "gps-week-sow" else [])
    groups = [("vn", "ve", "vd"), ("sx", "sy", "sz"), ("sroll", "spitch", "syaw")]
    _check_columns(path, hdr, required, groups)
    table = _numeric_table(path, hdr)
    if table.shape[0] < 2:
        raise InputFormatError(f"a trajectory needs at least 2 records, found {table.shape[0]}", path,
                               hdr.data[-1][0] if hdr.data else hdr.header_line, None)

    def col(name: str) -> NDArray[np.float64]:
        return table[:, hdr.columns.index(name)]

    for name, turns in _ANGLE_TURNS.items():
        if name in hdr.columns:
            _check_angles(path, hdr, table, name, unit, turns)
    for name in ("sx", "sy", "sz", "sroll", "spitch", "syaw"):
        if name in hdr.columns and np.any(col(name) < 0):
            k = int(np.argmax(col(name) < 0))
            raise InputFormatError(f"standard deviation {col(name)[k]!r} is negative", path, hdr.data[k][0], name)
    time_s, tsys = _read_time(path, hdr, table, tsys)
    _check_increasing(path, hdr, time_s)

    from skyrig.geodesy.frame import WorldFrame
    from skyrig.io.plausibility import check_angle_unit, check_coordinates

    check_angle_unit(np.stack([col("roll"), col("pitch")], axis=1), col("yaw"), unit, path, "roll/pitch/yaw")

    p_cols = [col(c) for c in ((["lon", "lat", "h"]) if crs.is_geographic else pos_cols)]
    check_coordinates(np.stack(p_cols, axis=1), WorldFrame.ecef() if crs.is_geocentric else WorldFrame.map(crs_text),
                      path, [no for no, _ in hdr.data], "camera",
                      ("lon", "lat", "h") if crs.is_geographic else tuple(pos_cols))  # type: ignore[arg-type]
    if crs.is_geographic:
        lat = col("lat")
        if np.any(np.abs(lat) > 90.0):
            k = int(np.argmax(np.abs(lat) > 90.0))
            raise InputFormatError(f"latitude {lat[k]!r} beyond +-90 degrees", path, hdr.data[k][0], "lat")
        xyz = np.stack([col("lon"), lat, col("h")], axis=1)
    else:
        xyz = np.stack([col("x"), col("y"), col("z")], axis=1)

    kwargs = dict(time_system=tsys, reference=reference)
    if "vn" in hdr.columns:
        kwargs["velocity_ned"] = np.stack([col("vn"), col("ve"), col("vd")], axis=1)
    if "sx" in hdr.columns:
        kwargs["sigma_ned_m"] = np.stack([col("sy"), col("sx"), col("sz")], axis=1)
    if "sroll" in hdr.columns:
        kwargs["sigma_rpy"] = np.stack([col("sroll"), col("spitch"), col("syaw")], axis=1)

    if crs.is_geocentric:
        if heading == "grid":
            raise InputFormatError("a geocentric CRS has no grid north", path,
                                   hdr.directives["heading"][1], "heading")
        try:
            ecef = np.stack(transformer(crs, WGS84_ECEF).transform(xyz[:, 0], xyz[:, 1], xyz[:, 2]), axis=1)
        except Exception as exc:  # pyproj errors
            raise InputFormatError(f"cannot transform positions: {exc}", path, crs_line, "crs") from None
        lat, lon, h = ecef_to_geodetic(ecef)
        traj = Trajectory.from_rpy(time_s, lat, lon, h, col("roll"), col("pitch"), col("yaw"), unit, **kwargs)
        _check_heading(path, hdr, traj, col, unit)
        return traj
    try:
        projection = MapProjection(crs, geoid)
        traj = Trajectory.from_map(time_s, xyz, projection, col("roll"), col("pitch"), col("yaw"), unit,
                                   heading_reference=heading, **kwargs)  # type: ignore[arg-type]
    except CRSError as exc:
        field = "geoid" if geoid is not None and "geoid" in str(exc) else pos_cols[0]
        line = hdr.directives["geoid"][1] if field == "geoid" else None
        raise InputFormatError(exc.args[0], path, line, field) from None
    _check_heading(path, hdr, traj, col, unit)
    return traj


def _check_heading(path: PathLike, hdr: Any, traj: Trajectory, col: Any, unit: str) -> None:
    """The yaw column against the direction of travel (:func:`skyrig.io.plausibility.check_heading_against_track`)."""
    from skyrig.io.plausibility import check_heading_against_track

    check_heading_against_track(traj.time_s, traj.lat_deg, traj.lon_deg, col("roll"), col("pitch"), col("yaw"), unit,
                                path, [no for no, _ in hdr.data], "declare the unit with the header line "
                                "'# angles: deg' (or gon, rad)")


# --------------------------------------------------------------------------- writer
_ANGLE_FMT = {"deg": "%.10f", "rad": "%.12f", "gon": "%.10f"}


def write_trajectory_csv(
    path: PathLike,
    trajectory: Trajectory,
    *,
    crs: str | int = "EPSG:4979",
    geoid: str | None = None,
    angles: str = "deg",
    heading: str = "true",
) -> None:
    """Write a trajectory as skyrig trajectory CSV (to a temporary file, then renamed into place).

    Parameters
    ----------
    path
        Output file.
    trajectory
        The trajectory.
    crs
        CRS of the positions: geographic (columns ``lat, lon, h``), projected or geocentric
        (columns ``x, y, z``).
    geoid
        Geoid grid (file path or PROJ name): heights are written orthometric (``h - N``); None writes
        ellipsoidal heights.
    angles
        ``"deg"``, ``"rad"`` or ``"gon"`` for roll, pitch, yaw and their standard deviations.
    heading
        ``"true"`` or ``"grid"`` (yaw from grid north: ``yaw_grid = yaw_true - convergence``).
    """
    unit = normalize_unit(angles)
    c = resolve_crs(crs)
    if c.is_compound:
        raise CRSError("give the horizontal CRS and a geoid, not a compound CRS")
    if heading not in ("true", "grid"):
        raise InputFormatError(f"heading must be 'true' or 'grid', not {heading!r}", field="heading")
    g = None if geoid is None else Geoid(geoid)
    crs_text = c.to_string().replace("\n", " ")
    lines = [f"# skyrig-trajectory {FORMAT_VERSION}", f"# crs: {crs_text}",
             f"# height: {'ellipsoidal' if g is None else 'orthometric'}"]
    if g is not None:
        lines.append(f"# geoid: {g.grid}")
    lines += [f"# angles: {unit}", f"# heading: {heading}", f"# reference: {trajectory.reference}",
              f"# time: {trajectory.time_system}"]
    if c.is_geocentric:
        if g is not None or heading == "grid":
            raise CRSError("a geocentric CRS has neither orthometric heights nor a grid north")
        t = transformer(WGS84_ECEF, c)
        e = trajectory.ecef
        xyz = np.stack(t.transform(e[:, 0], e[:, 1], e[:, 2]), axis=1)
        r, p, y = trajectory.rpy(unit)
    else:
        xyz, r, p, y = trajectory.to_map(MapProjection(c, g), heading, unit)  # type: ignore[arg-type]
    if c.is_geographic:
        names = ["time", "lat", "lon", "h"]
        cols = [trajectory.time_s, xyz[:, 1], xyz[:, 0], xyz[:, 2]]
        fmts = ["%.6f", "%.11f", "%.11f", "%.5f"]
    else:
        names = ["time", "x", "y", "z"]
        cols = [trajectory.time_s, xyz[:, 0], xyz[:, 1], xyz[:, 2]]
        fmts = ["%.6f", "%.5f", "%.5f", "%.5f"]
    names += ["roll", "pitch", "yaw"]
    cols += [r, p, y]
    fmts += [_ANGLE_FMT[unit]] * 3
    if trajectory.velocity_ned is not None:
        names += ["vn", "ve", "vd"]
        cols += list(trajectory.velocity_ned.T)
        fmts += ["%.5f"] * 3
    if trajectory.sigma_ned_m is not None:
        s = trajectory.sigma_ned_m
        names += ["sx", "sy", "sz"]
        cols += [s[:, 1], s[:, 0], s[:, 2]]
        fmts += ["%.5f"] * 3
    if trajectory.sigma_rpy_rad is not None:
        names += ["sroll", "spitch", "syaw"]
        cols += list(from_radians(trajectory.sigma_rpy_rad, unit).T)
        fmts += ["%.9g"] * 3
    table = np.stack(cols, axis=1)
    with atomic_write(path) as fh:
        fh.write("\n".join(lines) + "\n" + ",".join(names) + "\n")
        np.savetxt(fh, table, fmt=fmts, delimiter=",")
