"""COLMAP sparse models, text and binary, in both directions: the parts both encodings share.

A COLMAP model is a folder with ``cameras``, ``images`` and ``points3D`` files, either ``.txt``
(:mod:`skyrig.io.colmap_text`) or ``.bin`` (:mod:`skyrig.io.colmap_binary`); the format is documented at
https://colmap.github.io/format.html and in ``docs/formats/colmap.md``.  This module holds what the two
encodings share: the model in skyrig's conventions (:class:`ColmapModel`), the camera models both ways
(:func:`camera_from_colmap`, :func:`colmap_camera`), the assembly of parsed records into a model (with the
consistency checks), the block conversions (:func:`block_from_colmap`, :func:`colmap_from_block`) and the
folder-level :func:`read_colmap` / :func:`write_colmap` that pick the encoding.

Conventions (COLMAP -> skyrig)
------------------------------
* **Pose.** ``(QW, QX, QY, QZ, TX, TY, TZ)`` is ``cam_from_world`` (Hamilton quaternion, scalar first):
  ``X_cam = R(q) X_world + t``, COLMAP's camera frame x right, y down, z forward.  skyrig's camera frame is
  x right, y up, z backwards: ``X_skyrig = F X_colmap``, ``F = diag(1, -1, -1)``, so ``world_from_camera``
  has rotation ``R^T F`` and centre ``-R^T t``.  Writers give the quaternion with ``QW >= 0``.
* **Pixels.** COLMAP's origin is the top-left *corner* of the image (the centre of the top-left pixel is
  ``(0.5, 0.5)``); skyrig's is the centre of the top-left pixel: every pixel coordinate (principal point,
  keypoints) differs by 0.5.
* **Units.** The model's world units (arbitrary for a free SfM model; metres when georeferenced); focal
  lengths and principal points in pixels; distortion coefficients dimensionless (normalised coordinates).
* **Cameras.** COLMAP's distortion formulas are OpenCV's (:mod:`skyrig.camera.opencv`), so coefficients pass
  through unchanged: ``SIMPLE_PINHOLE`` / ``PINHOLE`` -> no distortion (``fx != fy``: the Brown affinity
  B1, :mod:`skyrig.camera.aspect`), ``SIMPLE_RADIAL`` / ``RADIAL`` / ``OPENCV`` -> ``opencv``,
  ``FULL_OPENCV`` -> ``opencv_rational``.  Writers choose the smallest COLMAP model that holds the camera
  exactly (:func:`colmap_camera`); a camera no COLMAP model holds (Brown / Australis, the forward model)
  is refused, or with ``fit_cameras=True`` replaced by the best OpenCV ``k1 k2 p1 p2 k3`` fit over the frame
  (:func:`skyrig.camera.convert.convert_camera`, with focal length and principal point; written as
  ``FULL_OPENCV``) whose residual is reported (``ColmapModel.fit_reports``) and bounded by
  ``fit_tolerance_px`` (default 0.01 px RMS).
* **CRS.** None in the files: the world frame is the model's own (a free network, or whatever frame the
  program was given).  :func:`block_from_colmap` names it in ``Block.frame``; :func:`colmap_from_block`
  writes the block's frame coordinates as they are (say the frame with the files).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.block import Block
from skyrig.camera.aspect import camera_from_fx_fy, fx_fy_px
from skyrig.camera.distortion import NoDistortion, distortion_from_dict
from skyrig.camera.frame import FrameCamera
from skyrig.camera.opencv import OpenCVDistortion
from skyrig.errors import InputFormatError, OptionError
from skyrig.geometry.pose import Pose
from skyrig.geometry.rotations import matrix_from_quaternion, matrix_from_rotvec, quaternion_from_matrix
from skyrig.io._camera_fit import FIT_TOLERANCE_PX, fit_or_refuse

__all__ = ["ColmapModel", "COLMAP_CAMERA_MODELS", "COLMAP_MODEL_IDS", "SKYRIG_FROM_COLMAP_CAMERA", "ImageRecord",
           "PointRecords", "camera_from_colmap", "colmap_camera", "assemble_model", "block_from_colmap",
           "colmap_from_block", "read_colmap", "write_colmap", "model_records", "camera_records", "FIT_TOLERANCE_PX"]

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

#: COLMAP's numeric camera model ids (``colmap/sensor/models.h``), as written in ``cameras.bin``
COLMAP_MODEL_IDS: dict[str, int] = {"SIMPLE_PINHOLE": 0, "PINHOLE": 1, "SIMPLE_RADIAL": 2, "RADIAL": 3, "OPENCV": 4,
                                    "OPENCV_FISHEYE": 5, "FULL_OPENCV": 6, "FOV": 7, "SIMPLE_RADIAL_FISHEYE": 8,
                                    "RADIAL_FISHEYE": 9, "THIN_PRISM_FISHEYE": 10, "RAD_TAN_THIN_PRISM_FISHEYE": 11}


HALF = 0.5  # COLMAP pixel (corner origin) minus skyrig pixel (centre-of-first-pixel origin)


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
    fit_reports
        ``{camera id: ConversionReport}`` of the cameras a writer fitted to a COLMAP model
        (``fit_cameras=True``); filled by :func:`write_colmap`, empty otherwise.
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
    fit_reports: dict[int, Any] = field(default_factory=dict)


# ---------------------------------------------------------------------------------------------- cameras
def camera_from_colmap(cid: int, model: str, width: int, height: int, params: list[float] | NDArray[np.float64],
                       path: str | PathLike[str] | None = None, line: int | None = None,
                       pixel_size_mm: float = 0.001) -> FrameCamera:
    """A :class:`FrameCamera` from a COLMAP camera (model name, size, parameters in COLMAP's pixels).

    ``path`` / ``line`` locate the record in errors (the line of ``cameras.txt``, the record number of
    ``cameras.bin``).
    """
    if model not in COLMAP_CAMERA_MODELS:
        raise InputFormatError(f"camera model {model!r} is not supported (supported: "
                               f"{', '.join(COLMAP_CAMERA_MODELS)})", path, line, "MODEL")
    names, dist_model = COLMAP_CAMERA_MODELS[model]
    if len(params) != len(names):
        raise InputFormatError(f"{model} has {len(names)} parameters ({' '.join(names)}), got {len(params)}",
                               path, line, "PARAMS")
    if width <= 0 or height <= 0:
        raise InputFormatError(f"image size must be positive, got {width} x {height}", path, line,
                               "WIDTH" if width <= 0 else "HEIGHT")
    prm = {n: float(v) for n, v in zip(names, params)}
    bad = [n for n, v in prm.items() if not np.isfinite(v)]
    if bad:
        raise InputFormatError("not a finite number", path, line, bad[0])
    fx = prm["f"] if "f" in prm else prm["fx"]
    fy = prm["f"] if "f" in prm else prm["fy"]
    if fx <= 0:
        raise InputFormatError(f"focal length must be positive, got {fx}", path, line, "f" if "f" in prm else "fx")
    if fy <= 0:
        raise InputFormatError(f"focal length must be positive, got {fy}", path, line, "fy")
    dist = {"model": dist_model, **{k: v for k, v in prm.items() if k not in ("f", "fx", "fy", "cx", "cy")}}
    try:
        d = distortion_from_dict(dist)
    except InputFormatError as e:
        raise InputFormatError(e.reason, path, line, e.field) from None
    if fx != fy and d.n_params and not np.any(d.params):
        d = NoDistortion()  # an OPENCV camera with zero coefficients is a PINHOLE one
    try:  # fx != fy: the Brown affinity b1 (skyrig.camera.aspect), exact for a pinhole
        return camera_from_fx_fy(f"colmap-{cid}", width, height, fx, fy, prm["cx"] - HALF, prm["cy"] - HALF,
                                 pixel_size_mm=pixel_size_mm, distortion=d)
    except ValueError as e:
        raise InputFormatError(f"{model}: {e}", path, line, "fy") from None


def colmap_camera(camera: FrameCamera) -> tuple[str, list[float]]:
    """``(COLMAP model name, params)`` holding ``camera`` exactly, in COLMAP's pixels (corner origin).

    The smallest model that holds it: ``SIMPLE_PINHOLE`` (no distortion), ``PINHOLE`` (no distortion but
    the affinity of ``fx != fy``), ``SIMPLE_RADIAL`` (OpenCV k1 only), ``RADIAL`` (k1, k2), ``OPENCV``
    (k1, k2, p1, p2), ``FULL_OPENCV`` (k3 or the rational k4..k6).  Raises :class:`OptionError` for a
    distortion model COLMAP has no equivalent of (Brown / Australis, forward): convert the camera first
    (:func:`skyrig.camera.convert.convert_camera`, or ``fit_cameras=True`` of the writers).
    """
    f = camera.focal_px
    cx, cy = camera.principal_point_px
    cx, cy = cx + HALF, cy + HALF
    d = camera.distortion
    if isinstance(d, NoDistortion):
        return "SIMPLE_PINHOLE", [f, cx, cy]
    fxy = fx_fy_px(camera)
    if fxy is not None:
        return "PINHOLE", [fxy[0], fxy[1], cx, cy]
    if isinstance(d, OpenCVDistortion):  # the rational model is a subclass
        c = {n: float(getattr(d, n, 0.0)) for n in ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")}
        if any(c[k] for k in ("k3", "k4", "k5", "k6")):
            return "FULL_OPENCV", [f, f, cx, cy] + [c[k] for k in ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")]
        if c["p1"] or c["p2"]:
            return "OPENCV", [f, f, cx, cy, c["k1"], c["k2"], c["p1"], c["p2"]]
        if c["k2"]:
            return "RADIAL", [f, cx, cy, c["k1"], c["k2"]]
        return "SIMPLE_RADIAL", [f, cx, cy, c["k1"]]
    from skyrig.camera.convert import exact_conversion

    ex = exact_conversion(camera, "opencv_rational")  # e.g. Metashape's model without K4, B1, B2
    if ex is not None:
        return colmap_camera(ex)
    raise OptionError("fit_cameras", f"camera {camera.name!r}: COLMAP has no camera model for the {d.name!r} distortion; "
                      "convert it to 'opencv' or 'opencv_rational' first (skyrig convert --camera), or write with "
                      "fit_cameras=True")


# ---------------------------------------------------------------------------------------------- records
@dataclass
class ImageRecord:
    """One image of ``images.txt`` / ``images.bin`` as read (COLMAP conventions)."""

    image_id: int
    q: list[float]
    t: list[float]
    camera_id: int
    name: str
    xy: NDArray[np.float64]  # (K, 2) COLMAP pixels
    point3d_id: NDArray[np.int64]  # (K,) -1: not triangulated
    line: int | None  # header line (text) or record number (binary)
    points_line: int | None  # the points line (text) or record number (binary)


@dataclass
class PointRecords:
    """The points of ``points3D.txt`` / ``points3D.bin`` as read."""

    point_id: NDArray[np.int64]
    xyz: NDArray[np.float64]
    rgb: NDArray[np.int64]
    error: NDArray[np.float64]
    tracks: list[NDArray[np.int64]]  # per point (L, 2): image id, point2D index
    lines: list[int]


def assemble_model(cameras: dict[int, FrameCamera], images: list[ImageRecord], points: PointRecords,
                   images_path: Path, points_path: Path) -> ColmapModel:
    """A :class:`ColmapModel` from parsed records, after checking that they agree.

    Images without a pose (a non-finite or zero quaternion) are left out with their measurements.  An id
    missing from the points, an image naming an unknown camera, a track that disagrees with the images'
    POINT3D_IDs, or an id used twice raise :class:`InputFormatError` naming the file, line (record) and
    field.
    """
    pid = points.point_id
    if len(np.unique(pid)) != len(pid):
        u, c = np.unique(pid, return_counts=True)
        dup = int(u[c > 1][0])
        raise InputFormatError(f"point {dup} is defined twice", points_path,
                               points.lines[int(np.flatnonzero(pid == dup)[1])], "POINT3D_ID")
    index_of_point = {int(k): i for i, k in enumerate(pid)}
    ids, names, cam_ids, q, t = [], [], [], [], []
    oi, op, opx = [], [], []
    seen: dict[tuple[int, int], int] = {}
    seen_ids: set[int] = set()
    for rec in images:
        if rec.image_id in seen_ids:
            raise InputFormatError(f"image {rec.image_id} is defined twice", images_path, rec.line, "IMAGE_ID")
        seen_ids.add(rec.image_id)
        if rec.camera_id not in cameras:
            raise InputFormatError(f"image {rec.image_id} names unknown camera {rec.camera_id}", images_path,
                                   rec.line, "CAMERA_ID")
        qv = np.asarray(rec.q, np.float64)
        if not np.all(np.isfinite(qv)) or np.linalg.norm(qv) < 0.5:
            continue  # not registered (no pose): its measurements cannot be used
        if not np.all(np.isfinite(rec.t)):
            raise InputFormatError("non-finite translation", images_path, rec.line, "TX TY TZ")
        if not np.isfinite(rec.xy).all():
            raise InputFormatError("non-finite keypoint coordinate", images_path, rec.points_line, "X Y")
        tri = np.flatnonzero(rec.point3d_id != -1)
        img_index = len(ids)
        for j in tri:
            pi = index_of_point.get(int(rec.point3d_id[j]))
            if pi is None:
                raise InputFormatError(f"keypoint {j} of image {rec.image_id} names point {rec.point3d_id[j]}, "
                                       f"which is not in {points_path.name}", images_path, rec.points_line,
                                       "POINT3D_ID")
            op.append(pi)
            seen[(rec.image_id, int(j))] = int(rec.point3d_id[j])
        oi.extend([img_index] * len(tri))
        opx.append(rec.xy[tri] - HALF)
        ids.append(rec.image_id)
        names.append(rec.name)
        cam_ids.append(rec.camera_id)
        q.append(qv)
        t.append(rec.t)
    registered = set(ids)
    # tracks must agree with the images' POINT3D_IDs (each (image, point2D) pair exactly once)
    for k, (tr, pid_k) in enumerate(zip(points.tracks, pid)):
        for a_, b_ in tr:
            key = (int(a_), int(b_))
            if key[0] in registered and seen.get(key) != int(pid_k):
                raise InputFormatError(f"track of point {pid_k} lists image {key[0]} keypoint {key[1]}, but the "
                                       f"images give that keypoint point {seen.get(key, -1)}", points_path,
                                       points.lines[k], "TRACK")

    R_cw = matrix_from_quaternion(np.array(q, np.float64).reshape(-1, 4))  # COLMAP cam_from_world
    tw = np.array(t, np.float64).reshape(-1, 3)
    R_wc = np.swapaxes(R_cw, 1, 2)
    pose = Pose(R_wc @ SKYRIG_FROM_COLMAP_CAMERA, -np.einsum("nij,nj->ni", R_wc, tw), "world", "camera")
    return ColmapModel(
        cameras=cameras, image_id=np.array(ids, np.int64), image_name=np.array(names, dtype=str),
        image_camera_id=np.array(cam_ids, np.int64), world_from_camera=pose, point_id=pid.astype(np.int64),
        point_xyz=points.xyz.reshape(-1, 3), point_rgb=points.rgb.reshape(-1, 3).clip(0, 255).astype(np.uint8),
        point_error=points.error, obs_image=np.array(oi, np.int64), obs_point=np.array(op, np.int64),
        obs_pixel=np.concatenate(opx).reshape(-1, 2) if opx else np.zeros((0, 2)),
    )


def camera_records(cameras: dict[int, FrameCamera], fit_cameras: bool = False,
                   fit_tolerance_px: float = FIT_TOLERANCE_PX, reports: dict[int, Any] | None = None
                   ) -> dict[int, tuple[str, int, int, list[float]]]:
    """``{camera id: (COLMAP model, width, height, params)}`` of cameras (:func:`colmap_camera`; ``fit_cameras``:
    a camera no COLMAP model holds is replaced by its OpenCV fit, whose report goes to ``reports``)."""
    cams: dict[int, tuple[str, int, int, list[float]]] = {}
    for cid, cam in sorted(cameras.items()):
        try:
            name, prm = colmap_camera(cam)
        except OptionError:
            if not fit_cameras:
                raise
            fitted, rep = fit_or_refuse(cam, OpenCVDistortion(), fit_tolerance_px, "COLMAP")
            if reports is not None:
                reports[cid] = rep
            name, prm = colmap_camera(fitted)
        cams[int(cid)] = (name, int(cam.width), int(cam.height), prm)
    return cams


def model_records(model: ColmapModel, fit_cameras: bool = False, fit_tolerance_px: float = FIT_TOLERANCE_PX
                  ) -> tuple[dict[int, tuple[str, int, int, list[float]]], list[ImageRecord], PointRecords]:
    """The records a writer writes for ``model`` (COLMAP conventions): cameras ``{id: (model, w, h, params)}``,
    images (their keypoints are the model's measurements, in order) and points (tracks from the
    measurements).  ``fit_cameras``: see :func:`colmap_camera`; the fit reports go to ``model.fit_reports``."""
    cams = camera_records(model.cameras, fit_cameras, fit_tolerance_px, model.fit_reports)
    for nm in model.image_name:
        if "\n" in nm or "\r" in nm or "\0" in nm or nm != nm.strip() or not nm:
            raise OptionError("image_name", f"image name {nm!r} cannot be written to a COLMAP model (empty, a line break, a "
                              "NUL or leading/trailing blanks)")
    unknown = set(int(c) for c in model.image_camera_id) - set(cams)
    if unknown:
        raise OptionError("image_camera_id", f"images name cameras {sorted(unknown)} that the model does not have")
    R = model.world_from_camera.rotation.reshape(-1, 3, 3)
    C = model.world_from_camera.translation.reshape(-1, 3)
    R_cw = np.swapaxes(R @ SKYRIG_FROM_COLMAP_CAMERA, 1, 2)
    t = -np.einsum("nij,nj->ni", R_cw, C)
    quat = quaternion_from_matrix(R_cw).reshape(-1, 4)
    order = np.argsort(model.obs_image, kind="stable")
    starts = np.searchsorted(model.obs_image[order], np.arange(len(model.image_id) + 1))
    images = []
    idx_in_image = np.empty(len(model.obs_image), np.int64)
    for i in range(len(model.image_id)):
        sel = order[starts[i]:starts[i + 1]]
        idx_in_image[sel] = np.arange(sel.size)
        images.append(ImageRecord(int(model.image_id[i]), quat[i].tolist(), t[i].tolist(),
                                  int(model.image_camera_id[i]), str(model.image_name[i]),
                                  model.obs_pixel[sel] + HALF, model.point_id[model.obs_point[sel]], None, None))
    porder = np.argsort(model.obs_point, kind="stable")
    pstarts = np.searchsorted(model.obs_point[porder], np.arange(len(model.point_id) + 1))
    tracks = []
    for k in range(len(model.point_id)):
        sel = porder[pstarts[k]:pstarts[k + 1]]
        tracks.append(np.column_stack([model.image_id[model.obs_image[sel]], idx_in_image[sel]]).astype(np.int64))
    pts = PointRecords(model.point_id.astype(np.int64), model.point_xyz.reshape(-1, 3),
                       model.point_rgb.reshape(-1, 3).astype(np.int64), model.point_error.astype(np.float64), tracks,
                       [])
    return cams, images, pts


# ---------------------------------------------------------------------------------------------- blocks
def block_from_colmap(model: ColmapModel, sigma_px: float = 1.0, min_track_length: int = 2,
                      frame: str = "COLMAP model frame") -> Block:
    """An adjustment :class:`~skyrig.adjust.block.Block`: one station per registered image (its pose),
    the model's cameras, its points with ``min_track_length`` or more measurements, and the
    measurements with sigma ``sigma_px``.  No datum (no control, GNSS or IMU): adjust it with
    ``AdjustConfig(unknowns=Unknowns(datum="free"))`` or add control first."""
    cam_ids = sorted(model.cameras)
    cam_index = {c: i for i, c in enumerate(cam_ids)}
    n_rays = np.bincount(model.obs_point, minlength=len(model.point_id))
    keep_p = n_rays >= min_track_length
    new_p = np.cumsum(keep_p) - 1
    keep_o = keep_p[model.obs_point]
    n_img = len(model.image_name)
    names = model.image_name
    return Block(
        cameras=[model.cameras[c] for c in cam_ids],
        station_name=names, station_rotation=model.world_from_camera.rotation,
        station_centre=model.world_from_camera.translation, image_name=names, image_station=np.arange(n_img),
        image_camera=np.array([cam_index[c] for c in model.image_camera_id.tolist()], np.int64),
        image_head=np.array([cam_index[c] for c in model.image_camera_id.tolist()], np.int64),
        head_name=np.array([f"camera{c}" for c in cam_ids]),
        point_name=model.point_id[keep_p].astype(str), point_xyz=model.point_xyz[keep_p],
        obs_image=model.obs_image[keep_o], obs_point=new_p[model.obs_point[keep_o]],
        obs_pixel=model.obs_pixel[keep_o], obs_sigma_px=sigma_px, frame=frame,
    )


def block_camera_poses(block: Block) -> Pose:
    """``world_from_camera`` of every image of ``block`` at its current values: the station pose, the image's
    mounting and offset, and its head's boresight correction (actuated heads are refused: their mounting
    depends on the adjusted actuator model)."""
    if block.head_actuated is not None and any(h is not None for h in block.head_actuated):
        raise OptionError("head_actuated", "the block has actuated heads: export their images after adjustment, from the adjusted "
                          "camera poses")
    Rs = block.station_rotation[block.image_station]
    M = block.image_rotation
    if block.head_boresight is not None and np.any(block.head_boresight):
        M = M @ matrix_from_rotvec(block.head_boresight[block.image_head])
    C = block.station_centre[block.image_station] + np.einsum("nij,nj->ni", Rs, block.image_offset)
    return Pose(Rs @ M, C, "world", "camera")


def colmap_from_block(block: Block) -> ColmapModel:
    """A :class:`ColmapModel` of ``block``: camera ids 1..C in the block's camera order, image ids 1..I,
    point ids 1..P, the block's measurements as keypoints (tracks follow), colours grey, errors unknown
    (-1; COLMAP recomputes them).  Coordinates are the block's frame (:attr:`Block.frame`)."""
    pose = block_camera_poses(block)
    n_p = len(block.point_name)
    return ColmapModel(
        cameras={i + 1: c for i, c in enumerate(block.cameras)}, image_id=np.arange(1, len(block.image_name) + 1),
        image_name=np.asarray(block.image_name, dtype=str), image_camera_id=np.asarray(block.image_camera) + 1,
        world_from_camera=pose, point_id=np.arange(1, n_p + 1, dtype=np.int64), point_xyz=block.point_xyz.copy(),
        point_rgb=np.full((n_p, 3), 128, np.uint8), point_error=np.full(n_p, -1.0),
        obs_image=np.asarray(block.obs_image, np.int64), obs_point=np.asarray(block.obs_point, np.int64),
        obs_pixel=np.asarray(block.obs_pixel, np.float64))
