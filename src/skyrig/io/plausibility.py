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
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.errors import CRSError, InputFormatError, PlausibilityWarning
from skyrig.geodesy.frame import WorldFrame
from skyrig.io._text import PathLike

__all__ = ["GROUND_MIN_M", "GROUND_MAX_M", "CAMERA_MAX_M", "LEVER_ARM_MAX_M", "LEVER_ARM_WARN_M",
           "check_coordinates", "check_lever_arm", "check_same_frame", "area_of_use", "warn",
           "check_attitude_reading", "flight_directions", "attitude_spread", "check_heading_against_track",
           "heading_minus_track", "angle_readings", "check_actuator_cadence"]

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


# ------------------------------------------------------------------------ attitudes: unit and convention
#: A reading of attitudes disagrees with the flight direction when its cameras turn, relative to the direction of
#: travel, by more than this (deg) between strips flown in different directions (crab angles of both signs stay
#: well within it) ...
ATTITUDE_SPREAD_DEG = 6.0
#: ... and another reading agrees better by this factor (its spread below ``spread / factor - 1 deg``).
ATTITUDE_BETTER = 2.0
_UNITS_TO_TRY = {"deg": ("gon",), "gon": ("deg",), "rad": ()}
_CONVENTIONS_TO_TRY = {"opk": ("ypr",), "pok": ("ypr",), "ypr": ("opk",)}


def angle_readings(frame: WorldFrame, centres: ArrayLike, angles: ArrayLike) -> Callable[[str, str], NDArray]:
    """``rotations_of(unit, convention)`` for :func:`check_attitude_reading`: a file's three angle columns
    (``(N, 3)``, in the file's order) read in ``unit`` as omega-phi-kappa (``opk`` / ``pok``) or as yaw-pitch-roll
    of the standard nadir mount (``ypr``, :func:`skyrig.georef.attitude_frames.rotation_from_ypr`)."""
    from skyrig.georef.attitude_frames import rotation_from_ypr
    from skyrig.geometry.rotations import matrix_from_opk

    a = np.asarray(angles, dtype=np.float64)
    c = np.asarray(centres, dtype=np.float64)

    def rotations_of(unit: str, convention: str) -> NDArray[np.float64]:
        if convention == "ypr":
            return rotation_from_ypr(frame, c, a[:, 0], a[:, 1], a[:, 2], unit=unit)
        return matrix_from_opk(a[:, 0], a[:, 1], a[:, 2], unit=unit, sequence=convention)

    return rotations_of


def _rotation_angle_deg(r: NDArray[np.float64]) -> NDArray[np.float64]:
    c = (np.trace(r, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def flight_directions(xy: ArrayLike, groups: ArrayLike | None = None, order: ArrayLike | None = None
                      ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Direction of travel (unit ``(N, 2)`` in the frame's x/y) at each position, from the next position of the
    same group (camera or head) in ``order`` (time; default the file's order); ``valid`` is False where there is
    no next position in the same strip (a step under 0.5 m or a fifth of the group's median step, or over three
    times it: a stop, a turn; a step that goes another way than both its neighbours: the move to the next strip).
    The last position of a strip takes the direction it arrived in."""
    p = np.asarray(xy, dtype=np.float64)[:, :2]
    n = len(p)
    g = np.zeros(n, dtype=int) if groups is None else np.unique(np.asarray(groups).astype(str), return_inverse=True)[1]
    key = np.arange(n, dtype=np.float64) if order is None else np.asarray(order, dtype=np.float64)
    out = np.full((n, 2), np.nan)
    valid = np.zeros(n, dtype=bool)
    for k in np.unique(g):
        idx = np.flatnonzero(g == k)
        idx = idx[np.argsort(key[idx], kind="stable")]
        if len(idx) < 3:
            continue
        d = p[idx[1:]] - p[idx[:-1]]
        step = np.linalg.norm(d, axis=1)
        moving = step > 0.5
        if not moving.any():
            continue
        med = float(np.median(step[moving]))
        ok = (step > max(0.5, 0.2 * med)) & (step < 3.0 * med)
        u = d / np.maximum(step, 1e-12)[:, None]
        # a segment is along a strip when it goes the way of the segment before or after it (within 20 deg):
        # the move between two strips (across, or the turn) goes another way than both
        same = np.sum(u[1:] * u[:-1], axis=1) > np.cos(np.radians(20.0))
        along = ok & (np.r_[False, same & ok[:-1]] | np.r_[same & ok[1:], False])
        for j in np.flatnonzero(along):
            out[idx[j]], valid[idx[j]] = u[j], True
        last = along & ~np.r_[along[1:], False]
        for j in np.flatnonzero(last):  # the strip's last position: the direction it arrived in
            out[idx[j + 1]], valid[idx[j + 1]] = u[j], True
    return out, valid


def attitude_spread(rotations: ArrayLike, directions: NDArray[np.float64], valid: NDArray[np.bool_],
                    groups: ArrayLike | None = None) -> tuple[float, NDArray[np.float64]] | None:
    """How much the cameras turn relative to the direction of travel between strips flown in different directions.

    Each camera's rotation in a frame along its flight direction (x along track, y to its left, z up); per group
    (camera or head) and direction (45-deg sectors), their chordal mean; returned: the largest angle between two
    directions' means in a group (deg), and each position's angle from its group's mean in the direction holding
    most positions (NaN where not valid).  None when every group was flown one way only (then any reading of the
    angles agrees with the direction of travel) or the positions are too few."""
    r = np.asarray(rotations, dtype=np.float64)
    n = len(r)
    if valid.sum() < 6:
        return None
    g = np.zeros(n, dtype=int) if groups is None else np.unique(np.asarray(groups).astype(str), return_inverse=True)[1]
    f = np.zeros((n, 3, 3))
    dx, dy = np.nan_to_num(directions[:, 0]), np.nan_to_num(directions[:, 1])
    f[:, 0, 0], f[:, 1, 0] = dx, dy  # world_from_flight: x along track,
    f[:, 0, 1], f[:, 1, 1] = -dy, dx  # y to its left,
    f[:, 2, 2] = 1.0  # z up
    rel = np.swapaxes(f, -1, -2) @ r
    sector = np.round(np.degrees(np.arctan2(dy, dx)) / 45.0).astype(int) % 8
    dev = np.full(n, np.nan)
    worst = None
    for k in np.unique(g):
        means = []
        for sc in np.unique(sector[(g == k) & valid]):
            idx = np.flatnonzero((g == k) & valid & (sector == sc))
            if len(idx) < 2:
                continue
            uu, _, vt = np.linalg.svd(rel[idx].sum(axis=0))
            means.append((len(idx), uu @ np.diag([1.0, 1.0, np.linalg.det(uu @ vt)]) @ vt))
        if len(means) < 2:
            continue
        means.sort(key=lambda m: -m[0])
        idx = np.flatnonzero((g == k) & valid)
        dev[idx] = _rotation_angle_deg(means[0][1].T @ rel[idx])
        pair = max(float(_rotation_angle_deg(a[1].T @ b[1])) for i, a in enumerate(means) for b in means[i + 1:])
        worst = pair if worst is None else max(worst, pair)
    if worst is None:
        return None
    return worst, dev


def _upward(rotations: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Cameras whose optical axis (-z of the photogrammetric camera frame) points more than 30 deg above the
    horizontal of the frame (z up)."""
    return -rotations[:, 2, 2] > 0.5


def check_attitude_reading(rotations_of: Callable[[str, str], NDArray[np.float64]], unit: str, convention: str,
                           centres: ArrayLike, path: PathLike, lines: Sequence[int] | NDArray | None,
                           fields: tuple[str, str, str], declare: str, groups: ArrayLike | None = None,
                           order: ArrayLike | None = None, values: NDArray[np.float64] | None = None,
                           frame: WorldFrame | None = None) -> None:
    """Refuse attitudes read in the wrong angle unit (gon as degrees, degrees as gon) or the wrong convention
    (omega-phi-kappa as yaw-pitch-roll and back) when another reading fits much better; warn when cameras look
    up at the sky under every reading.

    ``rotations_of(unit, convention)`` gives the ``frame_from_camera`` rotations of the file's numbers read that
    way (frame: z up).  Two rules:

    * **flight direction**: on a block flown in at least two directions, the cameras of one group (camera or head)
      keep their orientation relative to the direction of travel (the mounting, a crab angle, a few degrees of
      roll and pitch); read in the wrong unit, the heading of strips flown one way is off by a different amount
      (gon read as degrees: 200 gon becomes 200 deg instead of 180) than that of the strips flown back, and read in
      the wrong convention nothing is constant.  The declared reading is refused when its cameras turn by more
      than :data:`ATTITUDE_SPREAD_DEG` relative to the track between directions (:func:`attitude_spread`) and
      another reading turns :data:`ATTITUDE_BETTER` times less;
    * **looking up**: a quarter of the cameras or more pointing 30 deg or more above the horizontal is refused when
      another convention points every one below it (yaw-pitch-roll read as omega-phi-kappa: an omega of 180 looks
      at the sky), warned about otherwise.

    ``declare`` says in words how to declare the unit / convention (a header key, a side-car key, an option);
    ``groups``: the camera (head) of each image; a file that names none (Pix4D's external parameters) and mixes a
    rig's heads is not told apart by the direction rule (the heads' means blur into one);
    ``values``: the file's three angle columns (``(N, 3)``), to leave out a unit they cannot be in; ``frame``: the
    centres' frame (checked in map frames only, whose z is up; geographic: longitude / latitude made metres).
    """
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 3).copy()
    if len(c) < 3 or (frame is not None and frame.kind != "map"):
        return  # ECEF (z is not up), local and model frames (a model frame's z may point anywhere)
    if frame is not None and frame.kind == "map":
        try:
            geographic = frame.projection.crs.is_geographic
        except CRSError:
            return
        if geographic:
            c[:, 0] *= 111_320.0 * np.cos(np.radians(c[:, 1]))
            c[:, 1] *= 110_574.0
    declared = rotations_of(unit, convention)
    readings = [(u, convention) for u in _UNITS_TO_TRY.get(unit, ())]
    readings += [(unit, cv) for cv in _CONVENTIONS_TO_TRY.get(convention, ())]
    readings += [(u, cv) for u in _UNITS_TO_TRY.get(unit, ()) for cv in _CONVENTIONS_TO_TRY.get(convention, ())]

    def fits(u: str, cv: str) -> NDArray[np.float64] | None:
        if values is not None and u in ("deg", "gon"):
            turn = 360.0 if u == "deg" else 400.0
            if np.nanmax(np.abs(values)) > turn:
                return None
        try:
            return rotations_of(u, cv)
        except Exception:  # noqa: BLE001 - a reading that cannot be made is no alternative
            return None

    def words(u: str, cv: str) -> str:
        return ", ".join(x for x in ((f"angles in {u}" if u != unit else ""),
                                     (f"convention {cv}" if cv != convention else "")) if x)

    directions, valid = flight_directions(c, groups, order)
    got = attitude_spread(declared, directions, valid, groups)
    if got is not None and got[0] > ATTITUDE_SPREAD_DEG:
        best = None
        for u, cv in readings:
            r = fits(u, cv)
            alt = None if r is None else attitude_spread(r, directions, valid, groups)
            if alt is not None and alt[0] < got[0] / ATTITUDE_BETTER - 1.0 and (best is None or alt[0] < best[0]):
                best = (alt[0], u, cv)
        if best is not None:
            k = int(np.nanargmax(got[1]))
            raise InputFormatError(
                f"read as {convention} in {unit}, the cameras turn by {got[0]:.1f} deg relative to the direction "
                f"of travel between strips flown in different directions; read with {words(best[1], best[2])} "
                f"they keep it within {best[0]:.2f} deg: "
                f"{declare}", path, _line(lines, k), fields[2] if best[2] == convention else fields[0])
    up = _upward(declared)
    if up.mean() >= 0.25:
        for u, cv in readings:
            r = fits(u, cv)
            if r is not None and not _upward(r).any() and cv != convention:
                k = int(np.flatnonzero(up)[0])
                raise InputFormatError(
                    f"read as {convention} in {unit}, {int(up.sum())} of {len(up)} cameras look 30 deg or more "
                    f"above the horizon; read with {words(u, cv)} none does: {declare}", path, _line(lines, k),
                    fields[0])
        warn(f"{path}: {int(up.sum())} of {len(up)} cameras look 30 deg or more above the horizon as read "
             f"({convention} in {unit}); is the angle convention right? ({declare})")


# ------------------------------------------------------------------------ actuator angles: unit by cadence
#: A tumbling camera's actuator turns by a constant gear step between consecutive frames (paper 000 section 3.2,
#: :func:`skyrig.plan.flight.tumble_schedule`); a step is off when it differs from the head's median step, modulo
#: one turn of the reading's unit, by more than this fraction of the turn (3.6 deg; a crab change within a strip
#: is far smaller, gon read as degrees puts 40 units on every step across the zero, radians 354).
ACTUATOR_STEP_TOL_TURN = 0.01
_TURN = {"deg": 360.0, "gon": 400.0, "rad": 2.0 * np.pi}


def _cadence_off(b: NDArray[np.float64], pairs: NDArray[np.intp], turn: float) -> NDArray[np.bool_]:
    """Steps ``b[j+1] - b[j]`` (``j`` in ``pairs``) that differ from the median step modulo ``turn``."""
    d = np.mod(b[pairs + 1] - b[pairs], turn)
    # the median step on the circle: centre the steps on the first one's value before taking the median
    ref = d[0]
    s = ref + np.median(np.mod(d - ref + turn / 2.0, turn) - turn / 2.0)
    r = np.mod(d - s + turn / 2.0, turn) - turn / 2.0
    return np.abs(r) > ACTUATOR_STEP_TOL_TURN * turn


def check_actuator_cadence(beta: ArrayLike, unit: str, heads: ArrayLike, time_s: ArrayLike, path: PathLike,
                           lines: Sequence[int] | NDArray | None, declare: str, field: str = "beta") -> None:
    """Refuse actuator angles (the tumbling camera's beta, in the file's numbers) declared in the wrong unit.

    Per head with actuator angles, in time order, the steps between consecutive frames (time step within 1.5
    times the head's median, so the gaps of turns between strips are left out) are compared with the head's
    median step modulo one turn of each unit (deg 360, gon 400, rad 2 pi).  A tumbling actuator turns by the same
    gear step every frame, so in the right unit every step agrees, also across the zero of the scale; read in a
    wrong unit each step across the zero is off by the difference of the two turns.  The declared unit is refused
    when two steps or more are off in it and none in another unit (naming the line of the first off step).

    Limits: an actuator that never crosses the zero of its scale (a partial sweep, a few fixed stops that do not
    close the turn), or that moves back and forth, cannot be told: nothing is said.
    """
    b = np.asarray(beta, dtype=np.float64)
    t = np.asarray(time_s, dtype=np.float64)
    h = np.asarray(heads).astype(str)
    if unit not in _TURN:
        return
    for name in np.unique(h[np.isfinite(b)]):
        idx = np.flatnonzero((h == name) & np.isfinite(b))
        idx = idx[np.argsort(t[idx], kind="stable")]
        if len(idx) < 4:
            continue
        dt = np.diff(t[idx])
        pos = dt[dt > 0]
        if pos.size < 3:
            continue
        med = float(np.median(pos))
        pairs = np.flatnonzero((dt > 0.5 * med) & (dt < 1.5 * med))
        if pairs.size < 3:
            continue
        bb = b[idx]
        off = _cadence_off(bb, pairs, _TURN[unit])
        if off.sum() < 2:
            continue
        for alt in ("deg", "gon", "rad"):
            if alt == unit or np.nanmax(np.abs(bb)) > _TURN[alt]:
                continue
            if not _cadence_off(bb, pairs, _TURN[alt]).any():
                j = int(pairs[np.flatnonzero(off)[0]])
                raise InputFormatError(
                    f"head {name!r}: read in {unit}, {int(off.sum())} of {pairs.size} steps of the actuator angle "
                    f"between consecutive frames differ from its gear step (the steps across the zero of the "
                    f"scale); read in {alt} every step is the same: {declare}", path, _line(lines, idx[j + 1]),
                    field)


#: Moving faster than this (m/s) a platform's heading is compared with its track.
TRACK_MIN_SPEED = 3.0
#: Roll (deg) beyond which an aircraft's record is implausible; said when more than 5 % of the moving records have it.
ROLL_MAX_DEG = 60.0
#: Pitch (deg) likewise.
PITCH_MAX_DEG = 45.0
_DEG_PER = {"deg": 1.0, "gon": 0.9, "rad": 180.0 / np.pi}


def _heading_spread(heading_deg: NDArray[np.float64], track_deg: NDArray[np.float64]) -> float | None:
    """Largest difference (deg) between the median heading-minus-track of 45-deg track sectors with 3 records or
    more; None with fewer than two such sectors."""
    d = (heading_deg - track_deg + 180.0) % 360.0 - 180.0
    sector = np.round(track_deg / 45.0).astype(int) % 8
    meds = []
    for sc in np.unique(sector):
        dd = d[sector == sc]
        if len(dd) >= 3:
            ang = np.radians(dd)
            meds.append(np.degrees(np.arctan2(np.median(np.sin(ang)), np.median(np.cos(ang)))))
    if len(meds) < 2:
        return None
    return max(abs((a - b + 180.0) % 360.0 - 180.0) for i, a in enumerate(meds) for b in meds[i + 1:])


def _track(time_s: ArrayLike, lat_deg: ArrayLike, lon_deg: ArrayLike) -> tuple[NDArray[np.bool_], NDArray]:
    """Records moving faster than :data:`TRACK_MIN_SPEED` to the next (mask over all but the last) and their
    track azimuth (deg from north, clockwise)."""
    t = np.asarray(time_s, dtype=np.float64)
    lat, lon = np.radians(np.asarray(lat_deg, dtype=np.float64)), np.radians(np.asarray(lon_deg, dtype=np.float64))
    dt = np.diff(t)
    de = np.diff(np.unwrap(lon)) * 6_378_137.0 * np.cos(lat[:-1])
    dn = np.diff(lat) * 6_356_752.0
    with np.errstate(all="ignore"):
        speed = np.hypot(de, dn) / dt
    moving = np.isfinite(speed) & (speed > TRACK_MIN_SPEED) & (dt > 0)
    return moving, np.degrees(np.arctan2(de, dn))[moving] % 360.0


def heading_minus_track(time_s: ArrayLike, lat_deg: ArrayLike, lon_deg: ArrayLike, heading_deg: ArrayLike
                        ) -> tuple[NDArray[np.int_], NDArray[np.float64]] | None:
    """``(records, heading - track)`` (deg in -180..180) of the records in motion; None with fewer than 6."""
    moving, track = _track(time_s, lat_deg, lon_deg)
    if moving.sum() < 6:
        return None
    h = np.asarray(heading_deg, dtype=np.float64)[:-1][moving]
    return np.flatnonzero(moving), (h - track + 180.0) % 360.0 - 180.0


def check_heading_against_track(time_s: ArrayLike, lat_deg: ArrayLike, lon_deg: ArrayLike, roll: ArrayLike,
                                pitch: ArrayLike, yaw: ArrayLike, unit: str, path: PathLike,
                                lines: Sequence[int] | NDArray | None, declare: str) -> None:
    """Refuse a trajectory's attitudes read in the wrong angle unit (gon as degrees and back): while moving, a
    platform heads along its track up to a crab angle that stays about the same on every track direction; read in
    the wrong unit, the heading of each direction is off by a different amount (200 gon read as 200 deg instead of
    180).  Refused when the heading-minus-track of two track directions differ by more than
    :data:`ATTITUDE_SPREAD_DEG` and the other unit makes that :data:`ATTITUDE_BETTER` times smaller.  Warns when
    more than 5 % of the moving records roll beyond :data:`ROLL_MAX_DEG` or pitch beyond :data:`PITCH_MAX_DEG`
    (not an aircraft's attitude: another unit, or columns exchanged?).  ``roll``, ``pitch``, ``yaw`` as read, in
    ``unit``; ``declare`` says in words how to declare the unit."""
    if len(np.asarray(time_s)) < 6 or unit not in _DEG_PER:
        return
    moving, track = _track(time_s, lat_deg, lon_deg)
    if moving.sum() < 6:
        return
    raw = np.asarray(yaw, dtype=np.float64)[:-1][moving]
    got = _heading_spread(raw * _DEG_PER[unit], track)
    if got is not None and got > ATTITUDE_SPREAD_DEG:
        for alt in _UNITS_TO_TRY.get(unit, ()):
            if np.nanmax(np.abs(raw)) * _DEG_PER[alt] > 360.0 + 1e-9:
                continue
            other = _heading_spread(raw * _DEG_PER[alt], track)
            if other is not None and other < got / ATTITUDE_BETTER - 1.0:
                k = int(np.flatnonzero(moving)[0])
                raise InputFormatError(
                    f"read in {unit}, the heading minus the direction of travel differs by {got:.1f} deg between "
                    f"the directions flown (a crab angle stays about the same); read in {alt} by {other:.2f} deg: "
                    f"{declare}", path, _line(lines, k), "yaw")
    r = np.abs(np.asarray(roll, dtype=np.float64)[:-1][moving]) * _DEG_PER[unit]
    p = np.abs(np.asarray(pitch, dtype=np.float64)[:-1][moving]) * _DEG_PER[unit]
    wild = (r > ROLL_MAX_DEG) | (p > PITCH_MAX_DEG)
    if wild.mean() > 0.05:
        k = int(np.flatnonzero(moving)[np.flatnonzero(wild)[0]])
        at = "" if lines is None else f" (first on line {_line(lines, k)})"
        warn(f"{path}: {int(wild.sum())} of {int(moving.sum())} records in flight roll beyond {ROLL_MAX_DEG:g} deg or "
             f"pitch beyond {PITCH_MAX_DEG:g} deg as read in {unit}{at}: not an aircraft's attitude; another angle "
             f"unit, or the roll / pitch / yaw columns exchanged? ({declare})")
