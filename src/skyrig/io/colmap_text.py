"""COLMAP text models (``cameras.txt``, ``images.txt``, ``points3D.txt``) into skyrig objects.

Format (https://colmap.github.io/format.html#text-format; ``#`` starts a comment line)::

    cameras.txt    CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]
    images.txt     IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME        (two lines per image)
                   X Y POINT3D_ID  X Y POINT3D_ID ...                  (POINT3D_ID -1: not triangulated)
    points3D.txt   POINT3D_ID X Y Z R G B ERROR IMAGE_ID POINT2D_IDX ...

COLMAP 3.12+ also writes ``rigs.txt`` and ``frames.txt``; they are not needed (``images.txt`` holds each
image's ``cam_from_world``) and are ignored.

Conventions mapped onto skyrig's (``docs/frames.md``)
-----------------------------------------------------
* **Pose.** ``(QW, QX, QY, QZ, TX, TY, TZ)`` is ``cam_from_world``: ``X_cam = R(q) X_world + t`` with
  COLMAP's camera frame x right, y down, z forward (OpenCV's).  skyrig's camera frame is x right, y
  up, z backwards: ``X_skyrig = F X_colmap``, ``F = diag(1, -1, -1)``.  So ``world_from_camera`` has
  rotation ``R^T F`` and centre ``-R^T t``.
* **Pixels.** COLMAP's pixel origin is the top-left *corner* of the image (the centre of the top-left
  pixel is ``(0.5, 0.5)``); skyrig's is the centre of the top-left pixel.  Every pixel coordinate
  (principal point, measurements) has 0.5 subtracted.
* **Cameras.** A :class:`~skyrig.camera.frame.FrameCamera` with the distortion from the registry
  (:func:`~skyrig.camera.distortion.distortion_from_dict`).  ``fx != fy`` becomes the Brown affinity
  ``b1 = fy / fx - 1`` with principal distance ``fy`` (:mod:`skyrig.camera.aspect`; exact), for ``PINHOLE`` and
  for ``OPENCV`` / ``FULL_OPENCV`` with all coefficients zero; with non-zero OpenCV coefficients it is refused
  (skyrig's OpenCV model has one focal length), naming the line.
  COLMAP's normalised coordinates and distortion formulas are OpenCV's, so the coefficients pass
  through unchanged:

  ==================  ==========================================  ========================
  COLMAP model        params                                      skyrig distortion
  ==================  ==========================================  ========================
  ``SIMPLE_PINHOLE``  f cx cy                                     none
  ``PINHOLE``         fx fy cx cy                                 none
  ``SIMPLE_RADIAL``   f cx cy k                                   opencv (k1 = k)
  ``RADIAL``          f cx cy k1 k2                               opencv (k1, k2)
  ``OPENCV``          fx fy cx cy k1 k2 p1 p2                     opencv (k1, k2, p1, p2)
  ``FULL_OPENCV``     fx fy cx cy k1 k2 p1 p2 k3 k4 k5 k6         opencv_rational
  ==================  ==========================================  ========================

  Other models (fisheye, FOV, thin-prism...) raise :class:`~skyrig.errors.InputFormatError`.
  ``pixel_size_mm`` is not in the file: cameras get ``pixel_size_mm`` (default 0.001); projections in
  pixels do not depend on it.
"""

from __future__ import annotations

from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.block import Block
from skyrig.camera.aspect import camera_from_fx_fy
from skyrig.camera.distortion import NoDistortion, distortion_from_dict
from skyrig.camera.frame import FrameCamera
from skyrig.errors import InputFormatError
from skyrig.geometry.pose import Pose
from skyrig.geometry.rotations import matrix_from_quaternion
from skyrig.io._text import parse_float, read_text

__all__ = ["ColmapModel", "read_colmap_cameras", "read_colmap_text", "block_from_colmap", "COLMAP_CAMERA_MODELS",
           "SKYRIG_FROM_COLMAP_CAMERA"]

#: skyrig camera frame (x right, y up, z back) from COLMAP's (x right, y down, z forward)
SKYRIG_FROM_COLMAP_CAMERA = np.diag([1.0, -1.0, -1.0])

#: supported COLMAP camera models: parameter names and skyrig distortion model
COLMAP_CAMERA_MODELS: dict[str, tuple[tuple[str, ...], str]] = {
    "SIMPLE_PINHOLE": (("f", "cx", "cy"), "none"),
    "PINHOLE": (("fx", "fy", "cx", "cy"), "none"),
    "SIMPLE_RADIAL": (("f", "cx", "cy", "k1"), "opencv"),
    "RADIAL": (("f", "cx", "cy", "k1", "k2"), "opencv"),
    "OPENCV": (("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"), "opencv"),
    "FULL_OPENCV": (("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"), "opencv_rational"),
}

_HALF = 0.5  # COLMAP pixel (corner origin) minus skyrig pixel (centre-of-first-pixel origin)


@dataclass
class ColmapModel:
    """A COLMAP reconstruction in skyrig's conventions.

    Attributes
    ----------
    cameras
        ``{COLMAP camera id: FrameCamera}``.
    image_id, image_name, image_camera_id
        ``(I,)`` COLMAP image ids, names and camera ids of the registered images.
    world_from_camera
        Batch pose ``(I,)`` world from skyrig camera frame (rotation ``(I, 3, 3)``, centre ``(I, 3)`` in
        the model's units).
    point_id, point_xyz, point_rgb, point_error
        ``(P,)`` COLMAP point ids, ``(P, 3)`` coordinates, ``(P, 3)`` uint8 colours, ``(P,)`` mean
        reprojection error (px; -1 when unknown).
    obs_image, obs_point, obs_pixel
        ``(N,)`` image index, ``(N,)`` point index, ``(N, 2)`` skyrig pixels (column, row; origin the
        centre of the top-left pixel) of every triangulated measurement.
    """

    cameras: dict[int, FrameCamera]
    image_id: NDArray[np.int64]
    image_name: NDArray[np.str_]
    image_camera_id: NDArray[np.int64]
    world_from_camera: Pose
    point_id: NDArray[np.int64]
    point_xyz: NDArray[np.float64]
    point_rgb: NDArray[np.uint8]
    point_error: NDArray[np.float64]
    obs_image: NDArray[np.int64]
    obs_point: NDArray[np.int64]
    obs_pixel: NDArray[np.float64]


def _data_lines(path: Path) -> list[tuple[int, str]]:
    """``(1-based line number, text)`` of the non-comment lines (blank lines kept: images.txt needs them)."""
    return [(i + 1, s) for i, s in enumerate(read_text(path).split("\n")) if not s.lstrip().startswith("#")]


def _int(text: str, path: Path, line: int, field: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise InputFormatError(f"{text!r} is not an integer", path, line, field) from None


def read_colmap_cameras(path: str | PathLike[str], pixel_size_mm: float = 0.001) -> dict[int, FrameCamera]:
    """Read ``cameras.txt``: ``{camera id: FrameCamera}`` (see the module docstring for the models)."""
    p = Path(path)
    cams: dict[int, FrameCamera] = {}
    for ln, s in _data_lines(p):
        f = s.split()
        if not f:
            continue
        if len(f) < 4:
            raise InputFormatError(f"expected 'CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]', got {len(f)} fields", p, ln)
        cid = _int(f[0], p, ln, "CAMERA_ID")
        model = f[1].upper()
        if model not in COLMAP_CAMERA_MODELS:
            raise InputFormatError(f"camera model {f[1]!r} is not supported (supported: "
                                   f"{', '.join(COLMAP_CAMERA_MODELS)})", p, ln, "MODEL")
        names, dist_model = COLMAP_CAMERA_MODELS[model]
        if len(f) != 4 + len(names):
            raise InputFormatError(f"{model} has {len(names)} parameters ({' '.join(names)}), got {len(f) - 4}",
                                   p, ln, "PARAMS")
        w, h = _int(f[2], p, ln, "WIDTH"), _int(f[3], p, ln, "HEIGHT")
        if w <= 0 or h <= 0:
            raise InputFormatError(f"image size must be positive, got {w} x {h}", p, ln,
                                   "WIDTH" if w <= 0 else "HEIGHT")
        prm = {n: parse_float(v, p, ln, n) for n, v in zip(names, f[4:])}
        fx = prm["f"] if "f" in prm else prm["fx"]
        fy = prm["f"] if "f" in prm else prm["fy"]
        if fx <= 0:
            raise InputFormatError(f"focal length must be positive, got {fx}", p, ln, "f" if "f" in prm else "fx")
        if fy <= 0:
            raise InputFormatError(f"focal length must be positive, got {fy}", p, ln, "fy")
        dist = {"model": dist_model, **{k: v for k, v in prm.items() if k not in ("f", "fx", "fy", "cx", "cy")}}
        try:
            d = distortion_from_dict(dist)
        except InputFormatError as e:
            raise InputFormatError(e.reason, p, ln, e.field) from None
        if fx != fy and d.n_params and not np.any(d.params):
            d = NoDistortion()  # an OPENCV camera with zero coefficients is a PINHOLE one
        try:  # fx != fy: the Brown affinity b1 (skyrig.camera.aspect), exact for a pinhole
            cam = camera_from_fx_fy(f"colmap-{cid}", w, h, fx, fy, prm["cx"] - _HALF, prm["cy"] - _HALF,
                                    pixel_size_mm=pixel_size_mm, distortion=d)
        except ValueError as e:
            raise InputFormatError(f"{model}: {e}", p, ln, "fy") from None
        if cid in cams:
            raise InputFormatError(f"camera {cid} is defined twice", p, ln, "CAMERA_ID")
        cams[cid] = cam
    return cams


def read_colmap_text(folder: str | PathLike[str], pixel_size_mm: float = 0.001) -> ColmapModel:
    """Read a COLMAP text model folder (``cameras.txt``, ``images.txt``, ``points3D.txt``).

    Measurements whose ``POINT3D_ID`` is -1 are dropped; an id missing from ``points3D.txt``, an image
    naming an unknown camera, a track that disagrees with ``images.txt``, or a malformed number raise
    :class:`~skyrig.errors.InputFormatError` naming the file, line and field.
    """
    d = Path(folder)
    cams = read_colmap_cameras(d / "cameras.txt", pixel_size_mm)

    # ---------------------------------------------------------------- points3D.txt
    pp = d / "points3D.txt"
    pid, xyz, rgb, err = [], [], [], []
    tracks: list[tuple[int, list[str]]] = []
    for ln, s in _data_lines(pp):
        f = s.split()
        if not f:
            continue
        if len(f) < 8 or (len(f) - 8) % 2:
            raise InputFormatError("expected 'POINT3D_ID X Y Z R G B ERROR' and (IMAGE_ID, POINT2D_IDX) pairs",
                                   pp, ln)
        pid.append(_int(f[0], pp, ln, "POINT3D_ID"))
        xyz.append([parse_float(v, pp, ln, n) for v, n in zip(f[1:4], "XYZ")])
        rgb.append([_int(v, pp, ln, n) for v, n in zip(f[4:7], "RGB")])
        err.append(float(f[7]) if f[7].lower() != "nan" else -1.0)
        tracks.append((ln, f[8:]))
    point_id = np.array(pid, np.int64)
    if len(np.unique(point_id)) != len(point_id):
        u, c = np.unique(point_id, return_counts=True)
        dup = int(u[c > 1][0])
        raise InputFormatError(f"point {dup} is defined twice", pp, tracks[pid.index(dup)][0], "POINT3D_ID")
    index_of_point = {int(k): i for i, k in enumerate(point_id)}

    # ---------------------------------------------------------------- images.txt
    ip = d / "images.txt"
    lines = _data_lines(ip)
    # drop trailing blank lines; every image is a header line plus a (possibly empty) points line
    while lines and not lines[-1][1].strip():
        lines.pop()
    ids, names, cam_ids, q, t = [], [], [], [], []
    oi, op, opx, pt_idx = [], [], [], []
    k = 0
    while k < len(lines):
        ln, s = lines[k]
        if not s.strip():
            k += 1
            continue
        f = s.split(maxsplit=9)
        if len(f) < 10:
            raise InputFormatError("expected 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME'", ip, ln)
        iid = _int(f[0], ip, ln, "IMAGE_ID")
        qv = [float(v) for v in f[1:5]] if all(_isnum(v) for v in f[1:5]) else None
        if qv is None:
            raise InputFormatError("quaternion is not numeric", ip, ln, "QW QX QY QZ")
        tv = [parse_float(v, ip, ln, n) for v, n in zip(f[5:8], ("TX", "TY", "TZ"))]
        cid = _int(f[8], ip, ln, "CAMERA_ID")
        if cid not in cams:
            raise InputFormatError(f"image {iid} names unknown camera {cid}", ip, ln, "CAMERA_ID")
        pts_ln, pts = (lines[k + 1] if k + 1 < len(lines) else (ln + 1, ""))
        k += 2
        if not np.all(np.isfinite(qv)) or np.linalg.norm(qv) < 0.5:
            continue  # not registered (no pose): its measurements cannot be used
        g = pts.split()
        if len(g) % 3:
            raise InputFormatError(f"points line of image {iid} has {len(g)} fields, not a multiple of 3 "
                                   "(X Y POINT3D_ID)", ip, pts_ln)
        a = np.array(g, dtype=object).reshape(-1, 3) if g else np.zeros((0, 3), dtype=object)
        try:
            xy = a[:, :2].astype(np.float64)
            p3 = a[:, 2].astype(np.int64)
        except ValueError:
            raise InputFormatError("points line has a field that is not a number", ip, pts_ln,
                                   "POINTS2D[] (X, Y, POINT3D_ID)") from None
        if not np.isfinite(xy).all():
            raise InputFormatError("non-finite keypoint coordinate", ip, pts_ln, "X Y")
        tri = np.flatnonzero(p3 != -1)
        img_index = len(ids)
        for j in tri:
            pi = index_of_point.get(int(p3[j]))
            if pi is None:
                raise InputFormatError(f"keypoint {j} of image {iid} names point {p3[j]}, which is not in "
                                       "points3D.txt", ip, pts_ln, "POINT3D_ID")
            op.append(pi)
        oi.extend([img_index] * len(tri))
        opx.append(xy[tri] - _HALF)
        pt_idx.extend((iid, int(j)) for j in tri)
        ids.append(iid)
        names.append(f[9].strip())
        cam_ids.append(cid)
        q.append(qv)
        t.append(tv)
    image_id = np.array(ids, np.int64)
    if len(np.unique(image_id)) != len(image_id):
        raise InputFormatError("an IMAGE_ID is used twice", ip, None, "IMAGE_ID")

    # tracks must agree with the images' POINT3D_IDs (each (image, point2D) pair exactly once)
    seen = {(i, j): int(point_id[pi]) for (i, j), pi in zip(pt_idx, op)}
    registered = set(ids)
    for (ln, tr), pid_k in zip(tracks, point_id):
        for a_, b_ in zip(tr[0::2], tr[1::2]):
            key = (_int(a_, pp, ln, "IMAGE_ID"), _int(b_, pp, ln, "POINT2D_IDX"))
            if key[0] in registered and seen.get(key) != int(pid_k):
                raise InputFormatError(f"track of point {pid_k} lists image {key[0]} keypoint {key[1]}, but "
                                       f"images.txt gives that keypoint point {seen.get(key, -1)}", pp, ln, "TRACK")

    R_cw = matrix_from_quaternion(np.array(q, np.float64).reshape(-1, 4))  # COLMAP cam_from_world
    tw = np.array(t, np.float64).reshape(-1, 3)
    R_wc = np.swapaxes(R_cw, 1, 2)
    pose = Pose(R_wc @ SKYRIG_FROM_COLMAP_CAMERA, -np.einsum("nij,nj->ni", R_wc, tw), "world", "camera")
    return ColmapModel(
        cameras=cams, image_id=image_id, image_name=np.array(names, dtype=str),
        image_camera_id=np.array(cam_ids, np.int64),
        world_from_camera=pose, point_id=point_id, point_xyz=np.array(xyz, np.float64).reshape(-1, 3),
        point_rgb=np.array(rgb, np.int64).reshape(-1, 3).clip(0, 255).astype(np.uint8),
        point_error=np.array(err, np.float64), obs_image=np.array(oi, np.int64), obs_point=np.array(op, np.int64),
        obs_pixel=np.concatenate(opx).reshape(-1, 2) if opx else np.zeros((0, 2)),
    )


def _isnum(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def block_from_colmap(model: ColmapModel, sigma_px: float = 1.0, min_track_length: int = 2,
                      frame: str = "COLMAP model frame") -> Block:
    """An adjustment :class:`~skyrig.adjust.block.Block`: one station per registered image (its pose),
    the model's cameras, its points with ``min_track_length`` or more measurements, and the
    measurements with sigma ``sigma_px``.  No datum (no control, GNSS or IMU): adjust it with
    ``AdjustConfig(datum="free")`` or add control first."""
    cam_ids = sorted(model.cameras)
    cam_index = {c: i for i, c in enumerate(cam_ids)}
    n_rays = np.bincount(model.obs_point, minlength=len(model.point_id))
    keep_p = n_rays >= min_track_length
    new_p = np.cumsum(keep_p) - 1
    keep_o = keep_p[model.obs_point]
    n_img = len(model.image_id)
    names = model.image_name
    return Block(
        cameras=[model.cameras[c] for c in cam_ids],
        station_name=names, station_rotation=model.world_from_camera.rotation,
        station_centre=model.world_from_camera.translation, image_name=names, image_station=np.arange(n_img),
        image_camera=np.array([cam_index[int(c)] for c in model.image_camera_id], np.int64),
        image_head=np.array([cam_index[int(c)] for c in model.image_camera_id], np.int64),
        head_name=np.array([f"camera{c}" for c in cam_ids]),
        point_name=model.point_id[keep_p].astype(str), point_xyz=model.point_xyz[keep_p],
        obs_image=model.obs_image[keep_o], obs_point=new_p[model.obs_point[keep_o]],
        obs_pixel=model.obs_pixel[keep_o], obs_sigma_px=sigma_px, frame=frame,
    )
