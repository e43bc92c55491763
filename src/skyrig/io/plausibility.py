"""Plausibility checks for what the readers read: units, axis order and the CRS's area of use.

A file can be well formed and still wrong: heights in millimetres, easting and northing swapped, latitude and
longitude swapped, a lever arm in millimetres read as metres, coordinates in another CRS than the one the
header names.  The readers call these checks after parsing; each either

* refuses (:class:`~skyrig.errors.InputFormatError` naming file, line and field) when the values cannot be
  what the file says (a ground height of 50 km, a latitude of 500 deg, x/y that only fall inside the CRS's area
  of use when swapped, a lever arm of 100 m), or
* warns in words (:class:`~skyrig.errors.PlausibilityWarning`, shown by the CLI as ``warning: ...``) when the
  values are unusual but possible (positions outside the area of use PROJ states for the CRS, a lever arm of
  more than 10 m).  A ground point more than :data:`AREA_REFUSE_DEG` outside the CRS's area of use is refused
  (projection centres and trajectories when all of them are), with or without a side-car (the CRS named, with its
  area and where the position would be; a row with x and y swapped said so).

Limits (metres): ground points between :data:`GROUND_MIN_M` and :data:`GROUND_MAX_M` (the Dead Sea shore and
Everest with the geoid's range added), projection centres up to :data:`CAMERA_MAX_M` (a refused value gives
the height it would have in mm or cm), lever arms refused above :data:`LEVER_ARM_MAX_M`, warned above
:data:`LEVER_ARM_WARN_M`.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.errors import CRSError, InputFormatError, PlausibilityWarning
from skyrig.geodesy.frame import WorldFrame
from skyrig.io._text import PathLike

__all__ = ["GROUND_MIN_M", "GROUND_MAX_M", "CAMERA_MAX_M", "LEVER_ARM_MAX_M", "LEVER_ARM_WARN_M",
           "check_coordinates", "check_lever_arm", "check_same_frame", "area_of_use", "warn"]

#: Lowest / highest plausible ground height (m, ellipsoidal or orthometric): Dead Sea -430 m, geoid -106 m.
GROUND_MIN_M = -600.0
#: Everest 8849 m plus the geoid's largest undulation (+85 m), rounded up.
GROUND_MAX_M = 9000.0
#: Highest plausible projection centre or trajectory point (m): far above any aerial survey (about 20 km).
CAMERA_MAX_M = 50_000.0
#: Lever arms (m) above this are refused (a rig is not 50 m long; millimetres or centimetres read as metres).
LEVER_ARM_MAX_M = 50.0
#: Lever arms (m) above this are warned about.
LEVER_ARM_WARN_M = 10.0
#: Margin (deg) around a CRS's area of use within which positions pass without a warning.
AREA_MARGIN_DEG = 2.0
#: Distance (deg) outside a CRS's area of use beyond which a position is refused (a CRS for another region: UTM
#: coordinates declared Lambert-93 land 6 deg south of France, 1,400 km from its centre; a row with x/y swapped).
AREA_REFUSE_DEG = 5.0
#: Earth radius window for ECEF positions (m): the centre of the Earth to 50 km above it.
_ECEF_RANGE_M = (6_300_000.0, 6_450_000.0)
_SAMPLE = 2000  # positions looked at for the area of use (evenly spread over a long file)


def warn(message: str) -> None:
    """Emit a :class:`PlausibilityWarning` (the CLI prints it as ``warning: message``)."""
    warnings.warn(message, PlausibilityWarning, stacklevel=3)


def _line(lines: Sequence[int] | NDArray | None, k: int) -> int | None:
    if lines is None or len(lines) <= k:
        return None
    return int(lines[k])


def area_of_use(frame: WorldFrame) -> tuple[float, float, float, float, str] | None:
    """``(west, south, east, north, name)`` in degrees of the area PROJ states for a map frame's CRS, or None
    (ECEF, local frames, CRSs without an area of use)."""
    if frame.kind != "map":
        return None
    try:
        crs = frame.projection.crs
    except CRSError:
        return None
    aou = crs.area_of_use
    if aou is None:
        return None
    return (float(aou.west), float(aou.south), float(aou.east), float(aou.north), str(aou.name))


def _lonlat(frame: WorldFrame, xy: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Longitude, latitude (deg) of map positions; NaN where PROJ gives none."""
    crs = frame.projection.crs
    if crs.is_geographic:
        lon, lat = xy[:, 0].copy(), xy[:, 1].copy()
    else:
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            lon, lat = frame.projection._inv.transform(xy[:, 0], xy[:, 1])  # noqa: SLF001 (the frame's own PROJ)
        lon, lat = np.asarray(lon, float), np.asarray(lat, float)
    bad = ~(np.isfinite(lon) & np.isfinite(lat)) | (np.abs(lat) > 90.0) | (np.abs(lon) > 540.0)
    lon[bad] = np.nan
    lat[bad] = np.nan
    return lon, lat


def _inside(lon: NDArray, lat: NDArray, box: tuple[float, float, float, float, str], margin: float) -> NDArray:
    w, s, e, n, _ = box
    ok_lat = (lat >= s - margin) & (lat <= n + margin)
    lon_w = (lon - (w - margin) + 180.0) % 360.0 - 180.0 + (w - margin)  # longitude wrapped to start at west
    span = (e - w) % 360.0 if e != w else 360.0
    if span == 0.0 or (e - w) >= 359.0:
        ok_lon = np.isfinite(lon)
    else:
        ok_lon = (lon_w >= w - margin) & (lon_w <= w + span + margin)
    return ok_lat & ok_lon & np.isfinite(lon)


def check_coordinates(xyz: ArrayLike, frame: WorldFrame, path: PathLike, lines: Sequence[int] | NDArray | None = None,
                      what: str = "ground", fields: tuple[str, str, str] = ("x", "y", "z"),
                      lenient: bool = False) -> None:
    """Refuse or warn about positions that cannot be in ``frame`` as stated (module docstring).

    Parameters
    ----------
    xyz
        ``(N, 3)`` positions as read (x, y, height for map frames).
    frame
        The frame the file (or the command line) says they are in.
    path, lines
        The file and the 1-based line of each position, for the messages.
    what
        ``"ground"`` (points on the terrain: heights within :data:`GROUND_MIN_M` .. :data:`GROUND_MAX_M`) or
        ``"camera"`` (projection centres, trajectories: up to :data:`CAMERA_MAX_M`).
    fields
        Names of the three columns in the file, for the messages.
    lenient
        For results skyrig wrote itself (adjusted tie points may hold a wild intersection): implausible heights
        are refused only when every one is (a unit error), a few are warned about.

    Raises
    ------
    InputFormatError
        For heights no point of that kind can have, latitudes beyond 90 deg, ECEF positions far from the
        Earth's surface, x/y (lat/lon) that fall inside the CRS's area of use only when swapped.
    """
    p = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    if len(p) == 0 or frame.kind == "local":
        return
    if frame.kind == "ecef":
        r = np.linalg.norm(p, axis=1)
        bad = np.flatnonzero((r < _ECEF_RANGE_M[0]) | (r > _ECEF_RANGE_M[1]))
        if len(bad):
            k = int(bad[0])
            raise InputFormatError(
                f"ECEF position {r[k] / 1000.0:.1f} km from the centre of the Earth (its surface is about 6371 km); "
                f"these are not geocentric coordinates in metres (latitude, longitude, height? then state that CRS)",
                path, _line(lines, k), fields[0])
        return
    _check_heights(p[:, 2], path, lines, what, fields[2], lenient)
    box = area_of_use(frame)
    try:
        geographic = frame.projection.crs.is_geographic
    except CRSError:
        return
    if geographic:
        big = np.flatnonzero(np.abs(p[:, 1]) > 90.0)
        if len(big):
            k = int(big[0])
            swapped = bool(np.all(np.abs(p[:, 0]) <= 90.0))
            raise InputFormatError(
                f"latitude {p[k, 1]:.6g} beyond +-90 degrees"
                + ("; longitude and latitude swapped? (this CRS's columns are x = longitude, y = latitude)"
                   if swapped else ""), path, _line(lines, k), fields[1])
    if box is None:
        return
    step = max(1, len(p) // _SAMPLE)
    idx = np.arange(0, len(p), step)
    lon, lat = _lonlat(frame, p[idx, :2])
    ok = _inside(lon, lat, box, AREA_MARGIN_DEG)
    if ok.all():
        return
    k = int(idx[np.flatnonzero(~ok)[0]])
    name = frame.projection.crs.name
    region = box[4].split(". ")[0].split(" - ")[0][:60]
    where = f"{name} ({frame.crs}), used for {region} (longitude {box[0]:g} to {box[2]:g}, latitude {box[1]:g} to {box[3]:g} deg)"
    if not ok.any():
        slon, slat = _lonlat(frame, p[idx][:, [1, 0]])
        if _inside(slon, slat, box, AREA_MARGIN_DEG).all():
            axes = "longitude and latitude" if geographic else "x (easting) and y (northing)"
            raise InputFormatError(
                f"({p[k, 0]:.10g}, {p[k, 1]:.10g}) lies outside the area of use of {where}, and inside it with "
                f"{axes} swapped: are the columns {fields[0]} and {fields[1]} exchanged?", path, _line(lines, k), fields[0])
    ll0 = "no valid longitude/latitude" if not np.isfinite(lon[~ok][0]) else \
        f"longitude {lon[~ok][0]:.4f}, latitude {lat[~ok][0]:.4f} deg"
    far = ~_inside(lon, lat, box, AREA_REFUSE_DEG)
    # ground points: any one far away is wrong (a row with x/y swapped); projection centres and trajectories may
    # include a transit from a distant airfield: refused only when every position is far away
    if far.all() or (what == "ground" and far.any()):
        j = int(np.flatnonzero(far)[0])
        f = int(idx[j])
        llf = "no valid longitude/latitude" if not np.isfinite(lon[j]) else \
            f"longitude {lon[j]:.4f}, latitude {lat[j]:.4f} deg"
        if far.all():
            why = "every position lies"
            hint = "the coordinates are in another CRS than the one stated"
        else:
            why = f"{int(far.sum()) * step} of {len(p)} positions lie"
            slon, slat = _lonlat(frame, p[f:f + 1][:, [1, 0]])
            hint = (f"{fields[0]} and {fields[1]} swapped on this line?" if _inside(slon, slat, box, AREA_MARGIN_DEG)[0]
                    else "a position far from the others")
        raise InputFormatError(
            f"({p[f, 0]:.10g}, {p[f, 1]:.10g}) is {llf} in {where}: {why} more than {AREA_REFUSE_DEG:g} deg "
            f"outside that CRS's area of use; {hint}", path, _line(lines, f), fields[0])
    n_out = int((~ok).sum()) * step
    at = "" if lines is None else f" (first on line {_line(lines, k)})"
    pos = "position" if n_out == 1 else f"about {n_out} positions" if step > 1 else f"{n_out} positions"
    warn(f"{path}: {pos} outside the area of use of {where}{at}: {ll0}; is the CRS right?")


def _check_heights(z: NDArray[np.float64], path: PathLike, lines, what: str, field: str, lenient: bool = False) -> None:
    if what == "ground":
        lo, hi = GROUND_MIN_M, GROUND_MAX_M
        kind = "a ground height"
    else:
        lo, hi = GROUND_MIN_M, CAMERA_MAX_M
        kind = "a flying height"
    bad = np.flatnonzero((z < lo) | (z > hi))
    if not len(bad):
        return
    k = int(bad[0])
    v = float(z[k])
    if lenient and len(bad) < len(z):
        at = "" if lines is None else f", first on line {_line(lines, k)}"
        warn(f"{path}: {len(bad)} of {len(z)} heights not plausible ({v:.10g} m{at}); outliers?")
        return
    fits = [f"{unit} ({v / f:.3f} m)" for unit, f in (("millimetres", 1000.0), ("centimetres", 100.0))
            if np.all((z / f >= lo) & (z / f <= hi))]
    hint = f"; heights in {' or '.join(fits)}?" if fits else ""
    raise InputFormatError(f"height {v:.10g} m is not plausible as {kind} (expected {lo:g} to {hi:g} m){hint}",
                           path, _line(lines, k), field)


def lever_arm_problem(vector_m: ArrayLike) -> tuple[str, str] | None:
    """``("refuse" | "warn", words)`` for a lever arm longer than :data:`LEVER_ARM_MAX_M` (with the unit it would
    fit: millimetres, centimetres) or :data:`LEVER_ARM_WARN_M`; None for a plausible one."""
    v = np.asarray(vector_m, dtype=np.float64).reshape(3)
    n = float(np.linalg.norm(v))
    if n > LEVER_ARM_MAX_M:
        fits = [f"{unit} ({n / f:.3f} m)" for unit, f in (("millimetres", 1000.0), ("centimetres", 100.0))
                if n / f <= LEVER_ARM_MAX_M]
        hint = f"; {' or '.join(fits)}?" if fits else ""
        return "refuse", f"lever arm of {n:.6g} m is not plausible on an aircraft (at most {LEVER_ARM_MAX_M:g} m){hint}"
    if n > LEVER_ARM_WARN_M:
        return "warn", f"lever arm of {n:.6g} m is unusually long (more than {LEVER_ARM_WARN_M:g} m); metres meant?"
    return None


def check_lever_arm(vector_m: ArrayLike, path: PathLike, line: int | None, field: str) -> None:
    """Refuse a lever arm longer than :data:`LEVER_ARM_MAX_M`, warn above :data:`LEVER_ARM_WARN_M`."""
    problem = lever_arm_problem(vector_m)
    if problem is None:
        return
    if problem[0] == "refuse":
        raise InputFormatError(problem[1], path, line, field)
    warn(f"{path}" + (f", line {line}" if line else "") + f", field '{field}': {problem[1]}")


def _crs_equal(a: str, b: str) -> bool:
    from skyrig.geodesy.crs import resolve_crs

    try:
        ca, cb = resolve_crs(a), resolve_crs(b)
    except CRSError:
        return a.strip().upper() == b.strip().upper()
    if ca.is_compound:
        ca = ca.sub_crs_list[0]
    if cb.is_compound:
        cb = cb.sub_crs_list[0]
    return bool(ca.equals(cb, ignore_axis_order=False)) or ca.to_wkt() == cb.to_wkt()


def check_same_frame(stated: WorldFrame, given: WorldFrame, path: PathLike, line: int | None, option: str) -> None:
    """Refuse a frame given on the command line (``option``) that contradicts the one the file states.

    Raises
    ------
    InputFormatError
        Naming the file and the header line, with both frames in words.
    """
    if stated.kind != given.kind:
        same = False
    elif stated.kind == "map":
        same = _crs_equal(str(stated.crs), str(given.crs)) and stated.heights == given.heights and \
            (stated.geoid or "") == (given.geoid or "") or (
                _crs_equal(str(stated.crs), str(given.crs)) and stated.heights == given.heights == "orthometric"
                and str(stated.geoid).rsplit("/", 1)[-1] == str(given.geoid).rsplit("/", 1)[-1])
    else:
        same = stated == given
    if not same:
        raise InputFormatError(f"the file states {stated.describe()}, but {option} says {given.describe()}; "
                               f"leave {option} out or fix the file", path, line, "crs")


def check_angle_unit(tilts: ArrayLike, heading: ArrayLike, unit: str, path: PathLike, fields: str) -> None:
    """Warn when attitudes declared in degrees (or gon) look like radians.

    ``tilts``: ``(N, 2)`` roll/pitch or omega/phi; ``heading``: ``(N,)`` yaw or kappa, in the declared ``unit``.
    The signature of radians read as degrees: every tilt below 0.2 (a platform steadier than 0.2 deg over a whole
    flight), headings all within one turn in radians (|h| <= 2 pi) and spread over more than 2.5 (strips flown
    both ways differ by pi).  Values larger than one turn in the declared unit are refused by the readers already
    (:func:`skyrig.geometry.angles.check_plausible`).
    """
    t = np.abs(np.asarray(tilts, dtype=np.float64))
    h = np.asarray(heading, dtype=np.float64).ravel()
    if unit == "rad" or h.size < 5 or not np.all(np.isfinite(t)) or not np.all(np.isfinite(h)):
        return
    if t.max() < 0.2 and np.abs(h).max() <= 2.0 * np.pi + 1e-9 and np.ptp(h) > 2.5:
        warn(f"{path}: every {fields} value would be a plausible attitude in radians (tilts below 0.2, headings "
             f"within +-2 pi spread over {np.ptp(h):.2f}), but the file declares {unit}; radians meant?")
