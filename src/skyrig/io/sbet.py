"""Applanix SBET (Smoothed Best Estimate of Trajectory) files, as written by POSPac.

Layout
------
No header.  Records of 17 little-endian IEEE float64 (136 bytes), in this order:

====  ====================  =========================================================
 #    field                 unit / meaning
====  ====================  =========================================================
 0    ``time``              GPS seconds of week
 1    ``latitude``          radians (WGS84 or the processing datum)
 2    ``longitude``         radians
 3    ``altitude``          metres, ellipsoidal height
 4    ``x_velocity``        m/s, local-level *wander-angle* frame
 5    ``y_velocity``        m/s, wander-angle frame
 6    ``z_velocity``        m/s, wander-angle frame
 7    ``roll``              radians
 8    ``pitch``             radians
 9    ``heading``           radians, platform (true) heading
 10   ``wander``            radians, wander angle
 11   ``x_acceleration``    m/s^2, body frame
 12   ``y_acceleration``
 13   ``z_acceleration``
 14   ``x_angular_rate``    rad/s, body frame
 15   ``y_angular_rate``
 16   ``z_angular_rate``
====  ====================  =========================================================

Roll, pitch and the platform heading are the aerospace z-y'-x'' angles of the IMU body frame
(x forward, y right, z down) relative to local North-East-Down, the convention of
:func:`skyrig.geometry.rotations.matrix_from_rpy`.

What skyrig assumes and what it leaves alone
--------------------------------------------
Public descriptions of the format agree on the field order and units but not on the axes of the
three velocities (some call x/y east/north, Applanix documents them in the wander-angle frame whose
axes are turned from north by the wander angle, with sign conventions that vary between
descriptions).  :func:`read_sbet` therefore does **not** turn them into ``velocity_ned``: the
trajectory it returns has ``velocity_ned=None`` (cubic interpolation then uses a spline through the
positions, which at SBET rates of 50-200 Hz is accurate to well below a millimetre).  The raw
values of every field are available from :func:`read_sbet_records`.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.errors import InputFormatError
from skyrig.io._text import atomic_write
from skyrig.trajectory.trajectory import Trajectory

__all__ = ["SBET_FIELDS", "SBET_RECORD_SIZE", "read_sbet", "read_sbet_records", "write_sbet"]

PathLike = str | os.PathLike[str]

#: Field names of one SBET record, in file order.
SBET_FIELDS: tuple[str, ...] = (
    "time", "latitude", "longitude", "altitude", "x_velocity", "y_velocity", "z_velocity",
    "roll", "pitch", "heading", "wander", "x_acceleration", "y_acceleration", "z_acceleration",
    "x_angular_rate", "y_angular_rate", "z_angular_rate",
)
SBET_DTYPE = np.dtype([(name, "<f8") for name in SBET_FIELDS])
#: Fastest plausible motion between two records of a survey trajectory (a jet survey aircraft flies < 300 m/s).
MAX_SPEED_M_S = 1000.0
#: Longest plausible time between two records of one SBET (a continuous solution, usually 200 Hz).
MAX_GAP_S = 3600.0
#: Bytes per record.
SBET_RECORD_SIZE = SBET_DTYPE.itemsize  # 136


def read_sbet_records(path: PathLike) -> NDArray[np.void]:
    """All records of an SBET file as a structured array ``(N,)`` with the fields :data:`SBET_FIELDS`.

    Raises
    ------
    InputFormatError
        If the file size is not a multiple of 136 bytes (names the incomplete record, 1-based, as
        ``line``), or the file is empty.
    """
    p = Path(path)
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        raise InputFormatError("file not found", p) from None
    n, rest = divmod(len(raw), SBET_RECORD_SIZE)
    if rest:
        raise InputFormatError(
            f"file size {len(raw)} is not a multiple of the {SBET_RECORD_SIZE}-byte SBET record: record {n + 1} "
            f"is truncated ({rest} bytes); not an SBET file, or a truncated one", p, n + 1, None)
    if n == 0:
        raise InputFormatError("empty SBET file", p, 1, None)
    return np.frombuffer(raw, dtype=SBET_DTYPE)


def read_sbet(path: PathLike, *, reference: str = "imu") -> Trajectory:
    """Read an Applanix SBET file as a :class:`~skyrig.trajectory.Trajectory`.

    Parameters
    ----------
    path
        The ``sbet_*.out`` file.
    reference
        Which point the SBET positions refer to; POSPac usually exports the IMU centre (``"imu"``)
        unless a lever arm to another point was set in the export.

    Returns
    -------
    Trajectory
        ``time_system="gps-sow"``, positions in degrees, heading as true heading, no velocities (see
        the module documentation).

    Raises
    ------
    InputFormatError
        ``line`` is the 1-based record number: truncated file, non-finite value (``field`` names it),
        latitude beyond +-pi/2, times that do not increase (e.g. a week rollover; split the file).
    """
    rec = read_sbet_records(path)
    for name in ("time", "latitude", "longitude", "altitude", "roll", "pitch", "heading"):
        v = rec[name]
        bad = ~np.isfinite(v)
        if np.any(bad):
            k = int(np.argmax(bad))
            raise InputFormatError(f"{name} is not a finite number ({v[k]!r})", path, k + 1, name)
    lat = rec["latitude"]
    bad = np.abs(lat) > np.pi / 2 + 1e-12
    if np.any(bad):
        k = int(np.argmax(bad))
        raise InputFormatError(f"latitude {lat[k]!r} rad beyond +-pi/2 (degrees instead of radians?)", path,
                               k + 1, "latitude")
    blank = (np.abs(rec["latitude"]) < 1e-12) & (np.abs(rec["longitude"]) < 1e-12)
    if np.any(blank):
        k = int(np.argmax(blank))
        raise InputFormatError("latitude and longitude 0 (within 1e-12 rad): a blank record (an interrupted "
                               "export?), not a position", path, k + 1, "latitude")
    for name, limit, words in (("longitude", 2 * np.pi, "rad: degrees instead of radians?"),
                               ("altitude", 1e5, "m: beyond any survey flight"),
                               ("roll", 4 * np.pi, "rad: degrees instead of radians?"),
                               ("pitch", 4 * np.pi, "rad: degrees instead of radians?"),
                               ("heading", 4 * np.pi, "rad: degrees instead of radians?")):
        bad = np.abs(rec[name]) > limit
        if np.any(bad):
            k = int(np.argmax(bad))
            raise InputFormatError(f"{name} {float(rec[name][k])!r} beyond +-{limit:g} {words}", path, k + 1, name)
    low = rec["altitude"] < MIN_ALTITUDE_M
    if np.any(low):
        k = int(np.argmax(low))
        raise InputFormatError(f"altitude {float(rec['altitude'][k])!r} m below {MIN_ALTITUDE_M:g} m: deeper than any "
                               f"land surface below the ellipsoid (feet? another field?)", path, k + 1, "altitude")
    t = rec["time"]
    week = (t < 0) | (t > WEEK_S + MAX_GAP_S * 24)
    if np.any(week):
        k = int(np.argmax(week))
        raise InputFormatError(f"time {float(t[k])!r} s is not GPS seconds of the week (0 to {WEEK_S:g} s; a run "
                               f"past the week's end may go a day beyond): GPS seconds since 1980, or UTC seconds "
                               f"since 1970? (convert to seconds of the week)", path, k + 1, "time")
    bad = np.diff(t) <= 0
    if np.any(bad):
        k = int(np.argmax(bad)) + 1
        raise InputFormatError(f"time {t[k]!r} is not after the previous record's {t[k - 1]!r}", path, k + 1,
                               "time")
    if len(rec) < 2:
        raise InputFormatError("an SBET trajectory needs at least 2 records", path, 1, None)
    gap = np.diff(t) > MAX_GAP_S
    if np.any(gap):
        k = int(np.argmax(gap)) + 1
        raise InputFormatError(f"{float(t[k] - t[k - 1]):.6g} s between records {k} and {k + 1} (more than "
                               f"{MAX_GAP_S:g} s in a continuous navigation solution): a damaged record or two "
                               "files joined", path, k + 1, "time")
    # consecutive records more than MAX_SPEED apart in the time between them: a record from elsewhere
    r = 6.4e6 + rec["altitude"]
    step = np.hypot(np.diff(rec["latitude"]) * r[1:], np.diff(rec["longitude"]) * r[1:] * np.cos(lat[1:]))
    speed = np.hypot(step, np.diff(rec["altitude"])) / np.diff(t)
    bad = speed > MAX_SPEED_M_S
    if np.any(bad):
        k = int(np.argmax(bad)) + 1
        raise InputFormatError(f"record {k + 1} is {float(speed[k - 1]):.4g} m/s from the previous one's position "
                               f"(more than {MAX_SPEED_M_S:g} m/s): a damaged record or a jump", path, k + 1,
                               "latitude")
    _check_raw_fields(rec, path)
    traj = Trajectory.from_rpy(
        t, np.degrees(lat), np.degrees(rec["longitude"]), rec["altitude"], rec["roll"], rec["pitch"],
        rec["heading"], "rad", time_system="gps-sow", reference=reference,
    )
    _check_heading(rec, path)
    return traj


#: Lowest plausible SBET altitude (m, ellipsoidal): the Dead Sea shore with the geoid's lowest undulation, rounded.
MIN_ALTITUDE_M = -1000.0
#: Seconds in a GPS week.
WEEK_S = 604800.0
#: Largest plausible body acceleration (m/s^2, 20 g) and angular rate (rad/s, 573 deg/s) of a survey platform.
MAX_ACCELERATION = 200.0
MAX_ANGULAR_RATE = 10.0
#: Units a speed may have been written in (name, m/s per unit), for the words of a refusal.
_SPEED_UNITS = (("km/h", 1 / 3.6), ("knots", 0.514444), ("ft/s", 0.3048), ("mm/s", 0.001), ("cm/s", 0.01))


def _check_raw_fields(rec: NDArray[np.void], path: PathLike) -> None:
    """The fields skyrig does not turn into the trajectory, checked for their units all the same (a file whose
    velocities are in km/h is not an Applanix SBET): horizontal speed from ``x_velocity`` / ``y_velocity`` against
    the speed between the positions (their magnitude does not depend on the wander angle), accelerations and
    angular rates within a survey platform's.  Fields that are all zero (not exported, or skyrig's own writer)
    are left alone."""
    for names, limit, words in ((("x_acceleration", "y_acceleration", "z_acceleration"), MAX_ACCELERATION,
                                 "m/s^2 (20 g): another unit (mg, ft/s^2)?"),
                                (("x_angular_rate", "y_angular_rate", "z_angular_rate"), MAX_ANGULAR_RATE,
                                 "rad/s (573 deg/s): degrees per second instead of radians?")):
        for name in names:
            v = rec[name]
            bad = ~np.isfinite(v) | (np.abs(v) > limit)
            if np.any(bad):
                k = int(np.argmax(bad))
                raise InputFormatError(f"{name} {float(v[k])!r} beyond +-{limit:g} {words}", path, k + 1, name)
    vx, vy = rec["x_velocity"], rec["y_velocity"]
    if not (np.all(np.isfinite(vx)) and np.all(np.isfinite(vy))):
        name = "x_velocity" if not np.all(np.isfinite(vx)) else "y_velocity"
        k = int(np.argmax(~np.isfinite(rec[name])))
        raise InputFormatError(f"{name} is not a finite number", path, k + 1, name)
    if len(rec) < 3 or not (np.any(vx) or np.any(vy)):
        return
    t, lat, lon = rec["time"], rec["latitude"], rec["longitude"]
    r = 6.4e6 + rec["altitude"]
    ds = np.hypot(np.diff(lat) * r[1:], np.diff(np.unwrap(lon)) * r[1:] * np.cos(lat[1:]))
    moving_speed = ds / np.diff(t)
    given = np.hypot(vx, vy)[1:]
    moving = moving_speed > 2.0
    if moving.sum() >= 3:
        ratio = float(np.median(given[moving] / moving_speed[moving]))
        if not 0.8 <= ratio <= 1.25:
            k = int(np.flatnonzero(moving)[0]) + 1
            fits = [name for name, f in _SPEED_UNITS if 0.8 <= ratio * f <= 1.25]
            hint = f"; the velocities in {' or '.join(fits)}?" if fits else ""
            raise InputFormatError(f"the horizontal speed of x_velocity and y_velocity is {ratio:.3g} times the speed "
                                   f"between the positions (median over {int(moving.sum())} records in motion; m/s "
                                   f"expected){hint}", path, k + 1, "x_velocity")
    # the velocities are in m/s (or not exported): an altitude that changes at another rate is in another unit
    climb = np.diff(rec["altitude"]) / np.diff(t)
    vz = np.abs(rec["z_velocity"][1:])
    climbing = np.abs(climb) > 1.0
    if climbing.sum() >= 3 and np.any(rec["z_velocity"]):
        vr = float(np.median(vz[climbing] / np.abs(climb[climbing])))
        if not 0.8 <= vr <= 1.25:
            k = int(np.flatnonzero(climbing)[0]) + 1
            feet = 0.8 <= vr / 0.3048 <= 1.25
            raise InputFormatError(f"the altitude changes {1 / vr:.3g} times as fast as z_velocity says (median over "
                                   f"{int(climbing.sum())} records climbing or descending)"
                                   + ("; altitude in feet?" if feet else "; altitude or z_velocity in another unit?"),
                                   path, k + 1, "altitude" if feet or moving.sum() >= 3 else "z_velocity")


def _check_heading(rec: NDArray[np.void], path: PathLike) -> None:
    """The platform heading against the direction of travel: a heading relative to the wander-angle frame (the
    wander angle not added) is refused when the heading is more than 10 deg off the track (median in motion) and
    heading plus or minus the wander angle half as far (and within 10 deg); a wander angle under about 10 deg
    cannot be told from a crab angle (a stated limit); roll and pitch beyond an aircraft's are warned about
    (:func:`skyrig.io.plausibility.check_heading_against_track`)."""
    from skyrig.io.plausibility import check_heading_against_track, heading_minus_track

    t, lat, lon = rec["time"], np.degrees(rec["latitude"]), np.degrees(rec["longitude"])
    lines = np.arange(1, len(rec) + 1)
    check_heading_against_track(t, lat, lon, rec["roll"], rec["pitch"], rec["heading"], "rad", path, lines,
                                "an SBET holds radians")
    got = heading_minus_track(t, lat, lon, np.degrees(rec["heading"]))
    if got is None or np.median(np.abs(got[1])) <= 10.0 or not np.any(rec["wander"]):
        return
    off = float(np.median(np.abs(got[1])))
    for sign, words in ((-1.0, "minus"), (1.0, "plus")):
        alt = heading_minus_track(t, lat, lon, np.degrees(rec["heading"] + sign * rec["wander"]))
        if alt is not None and np.median(np.abs(alt[1])) < min(10.0, off / 2.0 - 1.0):
            k = int(got[0][0])
            raise InputFormatError(
                f"the heading differs from the direction of travel by {np.median(np.abs(got[1])):.1f} deg (median "
                f"in motion; a crab angle stays within a few degrees); heading {words} the wander angle follows it "
                f"within {np.median(np.abs(alt[1])):.1f} deg: a heading relative to the wander-angle frame, not the "
                f"platform's true heading (export the true heading)", path, k + 1, "heading")


def write_sbet(path: PathLike, trajectory: Trajectory, extra: Mapping[str, ArrayLike] | None = None) -> None:
    """Write a trajectory as an SBET file (temporary file, then renamed into place).

    Parameters
    ----------
    path
        Output file.
    trajectory
        Must be in GPS seconds of week (``time_system="gps-sow"``).
    extra
        Optional raw values ``(N,)`` for the fields skyrig does not model: ``x_velocity``,
        ``y_velocity``, ``z_velocity``, ``wander``, the accelerations and angular rates, in SBET
        units.  Fields not given are written as 0.
    """
    if trajectory.time_system != "gps-sow":
        raise InputFormatError(f"SBET times are GPS seconds of week, the trajectory is in "
                               f"{trajectory.time_system!r}", path, None, "time")
    n = len(trajectory)
    rec = np.zeros(n, dtype=SBET_DTYPE)
    r, p, y = trajectory.rpy("rad")
    rec["time"] = trajectory.time_s
    rec["latitude"] = np.radians(trajectory.lat_deg)
    rec["longitude"] = np.radians(trajectory.lon_deg)
    rec["altitude"] = trajectory.h_m
    rec["roll"], rec["pitch"], rec["heading"] = r, p, y
    own = {"time", "latitude", "longitude", "altitude", "roll", "pitch", "heading"}
    for name, values in (extra or {}).items():
        if name not in SBET_FIELDS or name in own:
            raise InputFormatError(f"{name!r} is not an extra SBET field", path, None, name)
        v = np.asarray(values, dtype=np.float64)
        if v.shape != (n,):
            raise InputFormatError(f"expected {n} values, got shape {v.shape}", path, None, name)
        rec[name] = v
    with atomic_write(path, "wb") as fh:
        fh.write(rec.tobytes())
