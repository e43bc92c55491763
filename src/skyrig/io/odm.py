"""OpenDroneMap text files: ``gcp_list.txt`` and ``geo.txt``.

Both start with a projection line: ``WGS84`` (longitude, latitude in degrees, ellipsoidal heights), a
``WGS84 UTM <zone><N|S>`` name, an ``EPSG:<code>`` or a PROJ string.

``gcp_list.txt`` lines: ``geo_x geo_y geo_z im_x im_y image_name [gcp_name] [extras...]``; pixel coordinates
with the origin at the centre of the top-left pixel (OpenSfM adds 0.5 before normalising), column right,
row down, the same as skyrig's.

``geo.txt`` lines: ``image_name geo_x geo_y [geo_z] [yaw pitch roll] [horz_accuracy vert_accuracy] [extras...]``
with angles in degrees.  ODM uses the angles only for radiometric calibration; skyrig writes and reads them
in the DJI gimbal convention (pitch -90 deg looks straight down, yaw is the heading of the image top; see
:data:`skyrig.geometry.rotations.GIMBAL_FROM_CAMERA`).  The file declares neither unit nor convention: angles
written in gon or as omega-phi-kappa are refused when the cameras' rotation relative to the direction of
travel disagrees between strips flown different ways and the other reading agrees, or when they look at the sky
(:func:`skyrig.io.plausibility.check_attitude_reading`); radians are warned about.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from skyrig.errors import CRSError, ConfigError, InputFormatError
from skyrig.geodesy.crs import resolve_crs
from skyrig.georef.attitude_frames import frame_from_enu_rotation, rotation_from_gimbal_ypr  # noqa: F401 - re-exported
from skyrig.georef.eo import ExteriorOrientations, WorldFrame
from skyrig.georef.observations import GroundPoints, ImageMeasurements
from skyrig.geometry.rotations import ENU_FROM_NED, GIMBAL_FROM_CAMERA, rpy_from_matrix
from skyrig.io._text import PathLike, atomic_write, parse_float, read_text


def odm_crs(text: str, path: PathLike | None = None, line: int = 1) -> str:
    """Translate an ODM projection line into a CRS string PROJ accepts."""
    s = text.strip()
    if s.upper() == "WGS84":
        return "EPSG:4326"
    m = re.fullmatch(r"WGS84\s+UTM\s+(\d{1,2})\s*([NS])", s, flags=re.IGNORECASE)
    if m:
        zone = int(m.group(1))
        return f"EPSG:{32600 + zone if m.group(2).upper() == 'N' else 32700 + zone}"
    try:
        resolve_crs(s)
    except CRSError as exc:
        raise InputFormatError(str(exc), path, line, "projection") from None
    return s


def _data_lines(path: PathLike) -> tuple[str, list[tuple[int, list[str]]]]:
    lines = read_text(path).splitlines()
    out = []
    proj = None
    for i, raw in enumerate(lines, start=1):
        s = raw.strip()
        if not s or s.startswith("#"):
            continue
        if proj is None:
            proj = odm_crs(s, path, i)
            continue
        out.append((i, s.split()))
    if proj is None:
        raise InputFormatError("empty file: the first line must name the projection", path, 1, "projection")
    return proj, out


def read_gcp_list(path: PathLike, geoid: str | None = None) -> tuple[GroundPoints, ImageMeasurements]:
    """Read ``gcp_list.txt``: ground coordinates (one per distinct GCP) and their image measurements.

    GCPs without a name are named after their coordinates.  ``geoid`` makes the heights orthometric.
    """
    return read_gcp_list_lines(path, geoid)[:2]


def read_gcp_list_lines(path: PathLike, geoid: str | None = None) -> tuple[GroundPoints, ImageMeasurements, NDArray]:
    """:func:`read_gcp_list` and the ``(N,)`` 1-based line number of each image measurement (for messages)."""
    crs, rows = _data_lines(path)
    frame = WorldFrame.map(crs, geoid)
    gname, gxyz, mp, mi, mpx = [], [], [], [], []
    seen: dict[str, tuple[int, NDArray]] = {}
    for line, f in rows:
        if len(f) < 6:
            raise InputFormatError(f"expected at least 6 fields, found {len(f)}", path, line)
        xyz = np.array([parse_float(f[k], path, line, n) for k, n in enumerate(("geo_x", "geo_y", "geo_z"))])
        px = [parse_float(f[3], path, line, "im_x"), parse_float(f[4], path, line, "im_y")]
        name = f[6] if len(f) >= 7 else "%.4f_%.4f_%.4f" % tuple(xyz)
        if name in seen:
            if np.abs(seen[name][1] - xyz).max() > 1e-6:
                raise InputFormatError(f"GCP {name!r} has other coordinates on line {seen[name][0]}", path, line, "geo_x")
        else:
            seen[name] = (line, xyz)
            gname.append(name)
            gxyz.append(xyz)
        mp.append(name)
        mi.append(f[5])
        mpx.append(px)
    from skyrig.io.plausibility import check_coordinates

    first_line = {n: ln for n, (ln, _) in seen.items()}
    check_coordinates(np.array(gxyz).reshape(-1, 3), frame, path, [first_line[n] for n in gname], "ground",
                      ("geo_x", "geo_y", "geo_z"))
    return (
        GroundPoints(np.array(gname), np.array(gxyz).reshape(-1, 3), frame),
        ImageMeasurements(np.array(mp), np.array(mi), np.array(mpx).reshape(-1, 2)),
        np.array([line for line, _ in rows], dtype=np.int64),
    )


def write_gcp_list(path: PathLike, points: GroundPoints, measurements: ImageMeasurements) -> None:
    """Write ``gcp_list.txt`` (the CRS of ``points.frame``; heights as they are in that frame)."""
    idx = points.index()
    with atomic_write(path) as fh:
        fh.write(f"{points.frame.crs}\n")
        for p, im, px in zip(measurements.point, measurements.image, measurements.pixel):
            if p not in idx:
                raise ValueError(f"measured point {p!r} has no ground coordinates")
            x, y, z = points.xyz[idx[p]]
            fh.write(f"{x:.10g} {y:.10g} {z:.4f} {px[0]:.3f} {px[1]:.3f} {im} {p}\n")


@dataclass(frozen=True)
class ImageGeolocation:
    """What a ``geo.txt`` holds: a position per image, optional gimbal angles and accuracies."""

    image: NDArray[np.str_]
    xyz: NDArray[np.float64]  # (N, 3); z NaN when absent
    frame: WorldFrame
    ypr_deg: NDArray[np.float64] | None  # (N, 3) yaw, pitch, roll (DJI gimbal convention) or None
    accuracy_m: NDArray[np.float64] | None  # (N, 2) horizontal, vertical or None


def read_geo_txt(path: PathLike, geoid: str | None = None) -> ImageGeolocation:
    """Read an ODM ``geo.txt``."""
    crs, rows = _data_lines(path)
    names, xyz, ypr, acc = [], [], [], []
    for line, f in rows:
        if len(f) < 3:
            raise InputFormatError(f"expected at least 3 fields, found {len(f)}", path, line)
        names.append(f[0])
        z = parse_float(f[3], path, line, "geo_z") if len(f) > 3 else np.nan
        xyz.append([parse_float(f[1], path, line, "geo_x"), parse_float(f[2], path, line, "geo_y"), z])
        ypr.append([parse_float(f[4 + k], path, line, n) for k, n in enumerate(("yaw", "pitch", "roll"))] if len(f) >= 7 else [np.nan] * 3)
        acc.append([parse_float(f[7 + k], path, line, n) for k, n in enumerate(("horz_accuracy", "vert_accuracy"))] if len(f) >= 9 else [np.nan] * 2)
    seen: dict[str, int] = {}
    for n, (line, _) in zip(names, rows):
        if n in seen:
            raise InputFormatError(f"image {n!r} appears twice (first on line {seen[n]})", path, line, "image_name")
        seen[n] = line
    frame = WorldFrame.map(crs, geoid)
    xyz_a = np.array(xyz).reshape(-1, 3)
    from skyrig.io.plausibility import check_coordinates

    has_z = np.isfinite(xyz_a[:, 2])
    check_coordinates(np.where(has_z[:, None], xyz_a, np.c_[xyz_a[:, :2], np.zeros(len(xyz_a))]), frame, path,
                      [line for line, _ in rows], "camera", ("geo_x", "geo_y", "geo_z"))
    ypr_a = np.array(ypr).reshape(-1, 3)
    acc_a = np.array(acc).reshape(-1, 2)
    _check_geo_angles(path, frame, xyz_a, ypr_a, [line for line, _ in rows])
    return ImageGeolocation(
        np.array(names), xyz_a, frame,
        None if np.all(np.isnan(ypr_a)) else ypr_a, None if np.all(np.isnan(acc_a)) else acc_a,
    )


def _check_geo_angles(path: PathLike, frame: WorldFrame, xyz: NDArray, ypr: NDArray, lines: list[int]) -> None:
    """The yaw / pitch / roll of a ``geo.txt`` are DJI-gimbal degrees; refuse rows written in gon or as
    omega-phi-kappa (:func:`skyrig.io.plausibility.check_attitude_reading`: the cameras' rotation relative to the
    direction of travel must agree between strips flown different ways; looking at the sky), warn when they look
    like radians."""
    from skyrig.geometry.rotations import matrix_from_opk
    from skyrig.io.plausibility import check_angle_unit, check_attitude_reading

    ok = np.all(np.isfinite(ypr), axis=1)
    if ok.sum() < 3:
        return
    a, c = ypr[ok], np.where(np.isfinite(xyz), xyz, 0.0)[ok]
    ln = [x for x, k in zip(lines, ok) if k]
    declare = ("geo.txt angles are yaw, pitch, roll in degrees, DJI gimbal convention (pitch -90 looks straight "
               "down, yaw the heading of the image top); convert them to that before reading")

    def rotations_of(unit: str, convention: str) -> NDArray[np.float64]:
        deg = a * (0.9 if unit == "gon" else 180.0 / np.pi if unit == "rad" else 1.0)
        if convention == "ypr":
            return rotation_from_gimbal_ypr(frame, c, deg)
        return matrix_from_opk(deg[:, 0], deg[:, 1], deg[:, 2], unit="deg", sequence=convention)

    check_attitude_reading(rotations_of, "deg", "ypr", c, path, ln, ("yaw", "pitch", "roll"), declare,
                           values=a, frame=frame)
    # radians: pitch -pi/2 looks down (the tilt from straight down is pitch + pi/2 in the file's numbers)
    check_angle_unit(np.c_[a[:, 2], a[:, 1] + np.pi / 2.0], a[:, 0], "deg", path, "yaw/pitch/roll")


def gimbal_ypr_from_eo(eo: ExteriorOrientations) -> NDArray[np.float64]:
    """DJI-gimbal (yaw, pitch, roll) in degrees ``(N, 3)`` of exterior orientations in any frame."""
    enu_from_cam = np.swapaxes(frame_from_enu_rotation(eo.frame, eo.centre), -1, -2) @ eo.rotation
    ned_from_gimbal = ENU_FROM_NED @ enu_from_cam @ GIMBAL_FROM_CAMERA.T
    r, p, y = rpy_from_matrix(ned_from_gimbal, unit="deg")
    return np.stack([y, p, r], axis=1)


def write_geo_txt(path: PathLike, eo: ExteriorOrientations, accuracy_m: tuple[float, float] | None = None) -> None:
    """Write ``geo.txt`` from exterior orientations in a map frame (with DJI-gimbal angles)."""
    if eo.frame.kind != "map":
        raise ConfigError("geo.txt needs a map frame (CRS); convert the orientations first")
    ypr = gimbal_ypr_from_eo(eo)
    geographic = eo.frame.projection.crs.is_geographic
    fmt = "%.10f" if geographic else "%.4f"
    with atomic_write(path) as fh:
        fh.write(f"{eo.frame.crs}\n")
        for i in range(len(eo)):
            parts = [eo.image[i], fmt % eo.centre[i, 0], fmt % eo.centre[i, 1], "%.4f" % eo.centre[i, 2]]
            parts += ["%.6f" % v for v in ypr[i]]
            if accuracy_m is not None:
                parts += ["%.3f" % accuracy_m[0], "%.3f" % accuracy_m[1]]
            fh.write(" ".join(parts) + "\n")
