"""OpenSfM (and OpenDroneMap) reconstructions: ``reconstruction.json``, camera files and ``tracks.csv``, both ways.

Files (OpenSfM ``doc/source/geometry.rst`` and ``dataset.rst``; ``docs/formats/opensfm.md``)
---------------------------------------------------------------------------------------------
* ``reconstruction.json``: a JSON **list** of reconstructions, each ``{"cameras": {id: camera}, "shots":
  {image name: shot}, "points": {id: {"coordinates": [x, y, z], "color": [r, g, b]}}, "reference_lla":
  {"latitude", "longitude", "altitude"}, ...}`` (``reference_lla`` may instead be a ``reference_lla.json``
  beside it, as older versions write).  A shot is ``{"rotation": [rx, ry, rz], "translation": [tx, ty, tz],
  "camera": id, ...}``; its other keys (``gps_position``, ``capture_time``, ...) are kept in
  :attr:`OpenSfMReconstruction.shot_extra` and written back.  Rigs (``rig_cameras``, ``rig_instances``) and
  ``biases`` are ignored on reading; the writer writes one trivial rig camera per shot, as OpenSfM does.
* ``camera_models.json`` / ``camera_models_overrides.json`` / ODM's ``cameras.json``: ``{id: camera}``
  (:func:`read_opensfm_cameras`, :func:`write_opensfm_cameras`).
* ``tracks.csv``: ``OPENSFM_TRACKS_VERSION_v2`` (or ``_v1``, or no header: v0) then tab-separated
  ``image track_id feature_id x y [scale] r g b [segmentation instance]`` in normalised coordinates
  (:func:`read_opensfm_tracks`, :func:`write_opensfm_tracks`).

Conventions
-----------
* **Pose.** ``rotation`` is the angle-axis vector (radians) of ``R`` and ``X_cam = R X_world + t``
  (world to camera); OpenSfM's camera frame is x right, y down, z forward (OpenCV's).  skyrig's camera frame
  is x right, y up, z backwards: ``world_from_camera`` has rotation ``R^T F`` (``F = diag(1, -1, -1)``) and
  centre ``-R^T t``.
* **Image coordinates.** *Normalised*: origin at the image centre, x right, y down, the larger image side is
  1: ``col = x max(w, h) + (w - 1) / 2``, ``row = y max(w, h) + (h - 1) / 2`` in pixels whose origin is the
  centre of the top-left pixel (skyrig's and OpenCV's).  Focal lengths and principal points are normalised
  the same way (``focal_px = focal max(w, h)``).
* **Cameras** (distortion on ``X/Z, Y/Z``, then ``focal * distorted + c``; OpenSfM's ``DistoBrown`` is
  OpenCV's ``k1 k2 p1 p2 k3``, so the coefficients pass to skyrig's ``opencv`` model unchanged):

  =================  ============================================  ==========================================
  projection_type    keys                                          skyrig
  =================  ============================================  ==========================================
  ``perspective``    focal, k1, k2                                 opencv (k1, k2); principal point the centre
  ``simple_radial``  focal_x, focal_y, c_x, c_y, k1                opencv (k1)
  ``radial``         focal_x, focal_y, c_x, c_y, k1, k2            opencv (k1, k2)
  ``brown``          focal_x, focal_y, c_x, c_y, k1, k2, p1, p2,   opencv (k1, k2, p1, p2, k3)
                     k3
  =================  ============================================  ==========================================

  ``focal_x != focal_y`` is the Brown affinity of :mod:`skyrig.camera.aspect` when there is no distortion,
  refused otherwise; fisheye, spherical and the other models are refused, naming the camera and the field.
  The writer writes ``perspective`` for a camera with only k1, k2 and its principal point at the centre,
  ``brown`` otherwise; a camera OpenSfM cannot hold (Brown / Australis, forward, the rational model) is
  refused, or fitted to ``brown`` with ``fit_cameras=True`` (residual reported, bounded by
  ``fit_tolerance_px``).  ``width`` and ``height`` are the image size in pixels.
* **World frame / CRS.** With ``reference_lla`` the world is OpenSfM's *topocentric* frame: x east, y north,
  z up, metres, origin at the WGS84 latitude, longitude and ellipsoidal altitude of ``reference_lla``:
  :attr:`OpenSfMReconstruction.frame` is ``WorldFrame.local(lat, lon, alt)`` (the same tangent frame).
  Without it the frame is the reconstruction's own (``frame`` None).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.block import Block
from skyrig.camera.aspect import camera_from_fx_fy, fx_fy_px
from skyrig.camera.convert import exact_conversion
from skyrig.camera.distortion import NoDistortion
from skyrig.camera.frame import FrameCamera
from skyrig.camera.opencv import OpenCVDistortion
from skyrig.errors import InputFormatError, OptionError
from skyrig.geodesy.frame import WorldFrame
from skyrig.geometry.pose import Pose
from skyrig.geometry.rotations import matrix_from_rotvec, rotvec_from_matrix
from skyrig.io._camera_fit import FIT_TOLERANCE_PX, fit_or_refuse
from skyrig.io._text import atomic_write, read_text
from skyrig.io.colmap import block_camera_poses, block_from_colmap

__all__ = ["OpenSfMReconstruction", "OPENSFM_PROJECTIONS", "read_opensfm", "write_opensfm", "read_opensfm_cameras",
           "write_opensfm_cameras", "read_opensfm_tracks", "write_opensfm_tracks", "camera_from_opensfm",
           "opensfm_camera", "block_from_opensfm", "opensfm_from_block", "normalised_to_pixels",
           "pixels_to_normalised"]

F = np.diag([1.0, -1.0, -1.0])

#: supported projection types and their parameter keys (besides width, height, projection_type)
OPENSFM_PROJECTIONS: dict[str, tuple[str, ...]] = {
    "perspective": ("focal", "k1", "k2"),
    "simple_radial": ("focal_x", "focal_y", "c_x", "c_y", "k1"),
    "radial": ("focal_x", "focal_y", "c_x", "c_y", "k1", "k2"),
    "brown": ("focal_x", "focal_y", "c_x", "c_y", "k1", "k2", "p1", "p2", "k3"),
}
_TRACK_HEADERS = {"OPENSFM_TRACKS_VERSION_v1": 1, "OPENSFM_TRACKS_VERSION_v2": 2}
_TRACK_COLUMNS = {0: 8, 1: 9, 2: 11}


@dataclass
class OpenSfMReconstruction:
    """One reconstruction of a ``reconstruction.json`` in skyrig's conventions (attribute names as
    :class:`skyrig.io.colmap.ColmapModel`, so :func:`skyrig.io.colmap.block_from_colmap` takes it too).

    Attributes
    ----------
    cameras
        ``{OpenSfM camera id: FrameCamera}``.
    image_name, image_camera_id
        ``(I,)`` shot names (image file names) and their camera ids.
    world_from_camera
        Batch pose ``(I,)``: world from skyrig camera frame.
    point_id, point_xyz, point_rgb
        ``(P,)`` point ids (strings), ``(P, 3)`` coordinates, ``(P, 3)`` colours (0-255, float as written).
    obs_image, obs_point, obs_pixel
        Measurements ``(N,)``, ``(N,)``, ``(N, 2)`` skyrig pixels: empty unless a ``tracks.csv`` was read
        (:func:`read_opensfm_tracks`).
    frame
        ``WorldFrame.local`` at ``reference_lla`` (topocentric ENU), or None.
    shot_extra
        ``(I,)`` the shots' other keys (kept for writing back).
    """

    cameras: dict[str, FrameCamera]
    image_name: NDArray[np.str_]
    image_camera_id: NDArray[np.str_]
    world_from_camera: Pose
    point_id: NDArray[np.str_]
    point_xyz: NDArray[np.float64]
    point_rgb: NDArray[np.float64]
    frame: WorldFrame | None = None
    shot_extra: list[dict[str, Any]] = field(default_factory=list)
    obs_image: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    obs_point: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    obs_pixel: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 2)))
    fit_reports: dict[str, Any] = field(default_factory=dict)


# ---------------------------------------------------------------------------------------------- coordinates
def normalised_to_pixels(xy: NDArray[np.float64], width: int, height: int) -> NDArray[np.float64]:
    """OpenSfM normalised image coordinates ``(N, 2)`` to skyrig pixels ``(N, 2)`` (column, row)."""
    s = max(width, height)
    return np.asarray(xy, np.float64) * s + [(width - 1) / 2.0, (height - 1) / 2.0]


def pixels_to_normalised(px: NDArray[np.float64], width: int, height: int) -> NDArray[np.float64]:
    """skyrig pixels ``(N, 2)`` to OpenSfM normalised image coordinates ``(N, 2)``."""
    s = max(width, height)
    return (np.asarray(px, np.float64) - [(width - 1) / 2.0, (height - 1) / 2.0]) / s


# ---------------------------------------------------------------------------------------------- cameras
def _number(v: Any, path: Path | None, where: str, key: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise InputFormatError(f"{where}: {v!r} is not a finite number", path, None, key)
    return float(v)


def camera_from_opensfm(cid: str, data: dict[str, Any], path: str | PathLike[str] | None = None,
                        pixel_size_mm: float = 0.001) -> FrameCamera:
    """A :class:`FrameCamera` named ``cid`` from an OpenSfM camera dictionary (module docstring)."""
    p = None if path is None else Path(path)
    where = f"camera {cid!r}"
    if not isinstance(data, dict):
        raise InputFormatError(f"{where} is not an object", p, None, cid)
    kind = data.get("projection_type")
    if kind not in OPENSFM_PROJECTIONS:
        raise InputFormatError(f"{where}: projection_type {kind!r} is not supported (supported: "
                               f"{', '.join(OPENSFM_PROJECTIONS)})", p, None, "projection_type")
    keys = OPENSFM_PROJECTIONS[kind]
    for k in ("width", "height") + keys:
        if k not in data:
            raise InputFormatError(f"{where} ({kind}) has no {k!r}", p, None, k)
    w, h = data["width"], data["height"]
    for k, v in (("width", w), ("height", h)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or v != int(v) or v <= 0:
            raise InputFormatError(f"{where}: {k} must be a positive whole number of pixels, got {v!r}", p, None, k)
    w, h = int(w), int(h)
    prm = {k: _number(data[k], p, where, k) for k in keys}
    s = max(w, h)
    fx = prm.get("focal", prm.get("focal_x"))
    fy = prm.get("focal", prm.get("focal_y"))
    for k, v in (("focal_x" if kind != "perspective" else "focal", fx), ("focal_y", fy)):
        if not v > 0:
            raise InputFormatError(f"{where}: focal length must be positive, got {v}", p, None, k)
    d = OpenCVDistortion(**{k: prm.get(k, 0.0) for k in ("k1", "k2", "p1", "p2", "k3")})
    if not np.any(d.params):
        d = NoDistortion()
    cx = (w - 1) / 2.0 + prm.get("c_x", 0.0) * s
    cy = (h - 1) / 2.0 + prm.get("c_y", 0.0) * s
    try:
        return camera_from_fx_fy(cid, w, h, fx * s, fy * s, cx, cy, pixel_size_mm=pixel_size_mm, distortion=d)
    except ValueError as e:
        raise InputFormatError(f"{where}: {e}", p, None, "focal_y") from None


def opensfm_camera(camera: FrameCamera) -> dict[str, Any]:
    """The OpenSfM camera dictionary holding ``camera`` exactly (``perspective`` when it can, else ``brown``);
    :class:`OptionError` for a distortion OpenSfM has no model for."""
    w, h = int(camera.width), int(camera.height)
    s = max(w, h)
    d = camera.distortion
    cx, cy = camera.principal_point_px
    c_x, c_y = (cx - (w - 1) / 2.0) / s, (cy - (h - 1) / 2.0) / s
    fxy = fx_fy_px(camera)
    if fxy is not None:
        fx, fy, c = fxy[0] / s, fxy[1] / s, dict.fromkeys(("k1", "k2", "p1", "p2", "k3"), 0.0)
    elif isinstance(d, NoDistortion) or type(d) is OpenCVDistortion:
        fx = fy = camera.focal_px / s
        c = {k: float(getattr(d, k, 0.0)) for k in ("k1", "k2", "p1", "p2", "k3")}
    elif (ex := exact_conversion(camera, "opencv")) is not None and ex.distortion.name != d.name:
        return opensfm_camera(ex)  # e.g. Metashape's model without K4, B1, B2
    else:
        raise OptionError("fit_cameras", f"camera {camera.name!r}: OpenSfM has no camera model for the {d.name!r} "
                          "distortion; convert it to 'opencv' first (skyrig convert --camera), or write with "
                          "fit_cameras=True")
    if fx == fy and c_x == 0.0 and c_y == 0.0 and c["p1"] == c["p2"] == c["k3"] == 0.0:
        return {"projection_type": "perspective", "width": w, "height": h, "focal": fx, "k1": c["k1"],
                "k2": c["k2"]}
    return {"projection_type": "brown", "width": w, "height": h, "focal_x": fx, "focal_y": fy, "c_x": c_x,
            "c_y": c_y, **c}


def _load_json(path: Path) -> Any:
    try:
        return json.loads(read_text(path))
    except json.JSONDecodeError as e:
        raise InputFormatError(f"not valid JSON: {e.msg}", path, e.lineno) from None


def read_opensfm_cameras(path: str | PathLike[str], pixel_size_mm: float = 0.001) -> dict[str, FrameCamera]:
    """Read ``camera_models.json``, ``camera_models_overrides.json`` or ODM's ``cameras.json``:
    ``{camera id: FrameCamera}``."""
    p = Path(path)
    data = _load_json(p)
    if not isinstance(data, dict):
        raise InputFormatError("expected an object {camera id: camera}", p)
    return {str(k): camera_from_opensfm(str(k), v, p, pixel_size_mm) for k, v in data.items()}


def _cameras_json(cameras: dict[str, FrameCamera], fit_cameras: bool, tolerance: float,
                  reports: dict[str, Any]) -> dict[str, Any]:
    out = {}
    for k, cam in cameras.items():
        try:
            out[str(k)] = opensfm_camera(cam)
        except OptionError:
            if not fit_cameras:
                raise
            fitted, reports[str(k)] = fit_or_refuse(cam, OpenCVDistortion(), tolerance, "OpenSfM")
            out[str(k)] = opensfm_camera(fitted)
    return out


def write_opensfm_cameras(path: str | PathLike[str], cameras: dict[str, FrameCamera], fit_cameras: bool = False,
                          fit_tolerance_px: float = FIT_TOLERANCE_PX) -> dict[str, Any]:
    """Write ``{camera id: FrameCamera}`` as ``camera_models_overrides.json`` (or any OpenSfM camera file),
    atomically.  Returns the fit reports of fitted cameras (``fit_cameras``: as :func:`write_opensfm`)."""
    reports: dict[str, Any] = {}
    data = _cameras_json(cameras, fit_cameras, fit_tolerance_px, reports)
    with atomic_write(path) as fh:
        json.dump(data, fh, indent=4)
        fh.write("\n")
    return reports


# ---------------------------------------------------------------------------------------------- reconstructions
def _vec3(v: Any, path: Path, where: str, key: str) -> list[float]:
    if not isinstance(v, list) or len(v) != 3:
        raise InputFormatError(f"{where}: {key} must be a list of 3 numbers, got {v!r}", path, None, key)
    return [_number(x, path, where, key) for x in v]


def _reference_frame(rec: dict[str, Any], path: Path) -> WorldFrame | None:
    ref = rec.get("reference_lla")
    if ref is None and (path.parent / "reference_lla.json").is_file():
        ref = _load_json(path.parent / "reference_lla.json")
    if ref is None:
        return None
    if not isinstance(ref, dict) or any(k not in ref for k in ("latitude", "longitude", "altitude")):
        raise InputFormatError("reference_lla must have latitude, longitude and altitude", path, None, "reference_lla")
    lat, lon, alt = (_number(ref[k], path, "reference_lla", k) for k in ("latitude", "longitude", "altitude"))
    if not (-90 <= lat <= 90 and -180 <= lon <= 360):
        raise InputFormatError(f"latitude {lat} / longitude {lon} out of range (degrees expected)", path, None,
                               "reference_lla")
    return WorldFrame.local(lat, lon, alt)


def _parse_reconstruction(rec: Any, path: Path, k: int, pixel_size_mm: float) -> OpenSfMReconstruction:
    if not isinstance(rec, dict) or "shots" not in rec or "cameras" not in rec:
        raise InputFormatError(f"reconstruction {k} has no 'cameras' and 'shots' (not an OpenSfM reconstruction?)",
                               path, None, f"[{k}]")
    cams = {str(c): camera_from_opensfm(str(c), v, path, pixel_size_mm) for c, v in rec["cameras"].items()}
    names, cam_ids, rv, tv, extra = [], [], [], [], []
    for name, shot in rec["shots"].items():
        where = f"shot {name!r}"
        if not isinstance(shot, dict):
            raise InputFormatError(f"{where} is not an object", path, None, name)
        for key in ("rotation", "translation", "camera"):
            if key not in shot:
                raise InputFormatError(f"{where} has no {key!r}", path, None, key)
        r = _vec3(shot["rotation"], path, where, "rotation")
        if np.linalg.norm(r) > 2 * np.pi + 1e-6:
            raise InputFormatError(f"{where}: rotation {r} is longer than 2 pi (an angle-axis vector in radians "
                                   "is expected; degrees?)", path, None, "rotation")
        if str(shot["camera"]) not in cams:
            raise InputFormatError(f"{where} names unknown camera {shot['camera']!r}", path, None, "camera")
        names.append(str(name))
        cam_ids.append(str(shot["camera"]))
        rv.append(r)
        tv.append(_vec3(shot["translation"], path, where, "translation"))
        extra.append({q: v for q, v in shot.items() if q not in ("rotation", "translation", "camera")})
    R_cw = matrix_from_rotvec(np.array(rv, np.float64).reshape(-1, 3))
    R_wc = np.swapaxes(R_cw, 1, 2)
    pose = Pose(R_wc @ F, -np.einsum("nij,nj->ni", R_wc, np.array(tv, np.float64).reshape(-1, 3)), "world",
                "camera")
    pid, xyz, rgb = [], [], []
    for name, pt in rec.get("points", {}).items():
        where = f"point {name!r}"
        if not isinstance(pt, dict) or "coordinates" not in pt:
            raise InputFormatError(f"{where} has no 'coordinates'", path, None, "coordinates")
        pid.append(str(name))
        xyz.append(_vec3(pt["coordinates"], path, where, "coordinates"))
        rgb.append(_vec3(pt.get("color", [0, 0, 0]), path, where, "color"))
    return OpenSfMReconstruction(cams, np.array(names, dtype=str), np.array(cam_ids, dtype=str), pose,
                                 np.array(pid, dtype=str), np.array(xyz, np.float64).reshape(-1, 3),
                                 np.array(rgb, np.float64).reshape(-1, 3), _reference_frame(rec, path), extra)


def read_opensfm(path: str | PathLike[str], pixel_size_mm: float = 0.001) -> list[OpenSfMReconstruction]:
    """Read ``reconstruction.json``: every reconstruction of the list, in order (the first is the largest in
    OpenSfM's output)."""
    p = Path(path)
    data = _load_json(p)
    if isinstance(data, dict) and "shots" in data:
        data = [data]
    if not isinstance(data, list):
        raise InputFormatError("expected a list of reconstructions", p)
    return [_parse_reconstruction(r, p, k, pixel_size_mm) for k, r in enumerate(data)]


def _reconstruction_json(rec: OpenSfMReconstruction, fit_cameras: bool, tolerance: float) -> dict[str, Any]:
    R = rec.world_from_camera.rotation.reshape(-1, 3, 3)
    C = rec.world_from_camera.translation.reshape(-1, 3)
    R_cw = np.swapaxes(R @ F, 1, 2)
    t = -np.einsum("nij,nj->ni", R_cw, C)
    r = rotvec_from_matrix(R_cw).reshape(-1, 3)
    extra = rec.shot_extra or [{} for _ in rec.image_name]
    shots = {}
    for i, name in enumerate(rec.image_name):
        shots[str(name)] = {"rotation": r[i].tolist(), "translation": t[i].tolist(),
                            "camera": str(rec.image_camera_id[i]), **extra[i]}
    points = {str(k): {"coordinates": x.tolist(), "color": c.tolist()}
              for k, x, c in zip(rec.point_id, rec.point_xyz, np.asarray(rec.point_rgb, np.float64))}
    out: dict[str, Any] = {"cameras": _cameras_json(rec.cameras, fit_cameras, tolerance, rec.fit_reports),
                           "shots": shots, "points": points}
    out["rig_cameras"] = {str(k): {"rotation": [0.0, 0.0, 0.0], "translation": [0.0, 0.0, 0.0]}
                          for k in rec.cameras}
    out["rig_instances"] = {str(i): {"rotation": r[i].tolist(), "translation": t[i].tolist(),
                                     "rig_camera_ids": {str(n): str(rec.image_camera_id[i])}}
                            for i, n in enumerate(rec.image_name)}
    if rec.frame is not None:
        if rec.frame.kind != "local" or rec.frame.origin is None:
            raise OptionError("frame", f"OpenSfM's world is a topocentric frame; the reconstruction is in "
                              f"{rec.frame.describe()}: convert it to a local frame first")
        lat, lon, alt = rec.frame.origin
        out["reference_lla"] = {"latitude": lat, "longitude": lon, "altitude": alt}
    return out


def write_opensfm(path: str | PathLike[str], reconstructions: list[OpenSfMReconstruction] | OpenSfMReconstruction,
                  fit_cameras: bool = False, fit_tolerance_px: float = FIT_TOLERANCE_PX) -> Path:
    """Write ``reconstruction.json`` (atomically).  ``fit_cameras``: a camera OpenSfM has no model for is
    replaced by its ``brown`` fit over the frame (:mod:`skyrig.io._camera_fit`), refused above
    ``fit_tolerance_px`` RMS; the reports go to each reconstruction's ``fit_reports``."""
    recs = [reconstructions] if isinstance(reconstructions, OpenSfMReconstruction) else list(reconstructions)
    data = [_reconstruction_json(r, fit_cameras, fit_tolerance_px) for r in recs]
    with atomic_write(path) as fh:
        json.dump(data, fh, indent=4)
        fh.write("\n")
    return Path(path)


# ---------------------------------------------------------------------------------------------- tracks
def read_opensfm_tracks(path: str | PathLike[str], rec: OpenSfMReconstruction) -> OpenSfMReconstruction:
    """``rec`` with the measurements of ``tracks.csv`` (rows of its shots and points; others are skipped),
    in skyrig pixels of each shot's camera.  The header names the version (v0: none, v1, v2)."""
    p = Path(path)
    lines = read_text(p).split("\n")
    version = 0
    start = 0
    if lines and lines[0].startswith("OPENSFM_TRACKS_VERSION"):
        head = lines[0].strip()
        if head not in _TRACK_HEADERS:
            raise InputFormatError(f"unknown tracks version {head!r} (known: {', '.join(_TRACK_HEADERS)})", p, 1,
                                   "version")
        version, start = _TRACK_HEADERS[head], 1
    ncol = _TRACK_COLUMNS[version]
    shot = {str(n): i for i, n in enumerate(rec.image_name)}
    point = {str(n): i for i, n in enumerate(rec.point_id)}
    oi, op, xy = [], [], []
    for ln in range(start, len(lines)):
        s = lines[ln]
        if not s.strip():
            continue
        f = s.split("\t")
        if len(f) != ncol:
            raise InputFormatError(f"expected {ncol} tab-separated fields (tracks version v{version}), got {len(f)}",
                                   p, ln + 1)
        i, k = shot.get(f[0]), point.get(f[1])
        if i is None or k is None:
            continue
        try:
            xy.append((float(f[3]), float(f[4])))
        except ValueError:
            raise InputFormatError("x or y is not a number", p, ln + 1, "x y") from None
        oi.append(i)
        op.append(k)
    oi_a = np.array(oi, np.int64)
    xy_a = np.array(xy, np.float64).reshape(-1, 2)
    px = np.empty_like(xy_a)
    for i in np.unique(oi_a):
        cam = rec.cameras[str(rec.image_camera_id[i])]
        sel = oi_a == i
        px[sel] = normalised_to_pixels(xy_a[sel], cam.width, cam.height)
    out = OpenSfMReconstruction(**{k: getattr(rec, k) for k in rec.__dataclass_fields__})
    out.obs_image, out.obs_point, out.obs_pixel = oi_a, np.array(op, np.int64), px
    return out


def write_opensfm_tracks(path: str | PathLike[str], rec: OpenSfMReconstruction) -> Path:
    """Write ``rec``'s measurements as ``tracks.csv`` version 2 (feature id = the measurement's index in its
    image, scale 0, colour of the point, segmentation and instance -1), atomically."""
    with atomic_write(path) as fh:
        fh.write("OPENSFM_TRACKS_VERSION_v2\n")
        count: dict[int, int] = {}
        for i, k, px in zip(rec.obs_image, rec.obs_point, rec.obs_pixel):
            cam = rec.cameras[str(rec.image_camera_id[i])]
            x, y = pixels_to_normalised(px[None], cam.width, cam.height)[0]
            fid = count.get(int(i), 0)
            count[int(i)] = fid + 1
            r, g, b = (int(round(v)) for v in np.asarray(rec.point_rgb[k], float))
            fh.write(f"{rec.image_name[i]}\t{rec.point_id[k]}\t{fid}\t{float(x)!r}\t{float(y)!r}\t0\t{r}\t{g}\t{b}\t-1\t-1\n")
    return Path(path)


# ---------------------------------------------------------------------------------------------- blocks
def block_from_opensfm(rec: OpenSfMReconstruction, sigma_px: float = 1.0, min_track_length: int = 2) -> Block:
    """An adjustment :class:`Block` of a reconstruction with its tracks (:func:`read_opensfm_tracks`), as
    :func:`skyrig.io.colmap.block_from_colmap`; the frame named is the topocentric one when known."""
    frame = rec.frame.describe() if rec.frame is not None else "OpenSfM reconstruction frame"
    return block_from_colmap(rec, sigma_px, min_track_length, frame)  # type: ignore[arg-type]


def opensfm_from_block(block: Block, frame: WorldFrame | None = None) -> OpenSfMReconstruction:
    """An :class:`OpenSfMReconstruction` of ``block`` (shots named after its images, camera ids the camera
    names, point ids its point names, its measurements as tracks).  ``frame``: the block's frame when it is a
    topocentric (``WorldFrame.local``) one, written as ``reference_lla``."""
    pose = block_camera_poses(block)
    names = [c.name for c in block.cameras]
    if len(set(names)) != len(names):
        raise OptionError("cameras", f"camera names must be unique for OpenSfM's camera ids, got {names}")
    n_p = len(block.point_name)
    return OpenSfMReconstruction(
        {c.name: c for c in block.cameras}, np.asarray(block.image_name, dtype=str),
        np.array([names[c] for c in block.image_camera], dtype=str), pose, np.asarray(block.point_name, dtype=str),
        block.point_xyz.copy(), np.full((n_p, 3), 128.0), frame, [],
        np.asarray(block.obs_image, np.int64), np.asarray(block.obs_point, np.int64),
        np.asarray(block.obs_pixel, np.float64))
