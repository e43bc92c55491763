"""COLMAP text models (``cameras.txt``, ``images.txt``, ``points3D.txt``), read and written.

Format (https://colmap.github.io/format.html#text-format; ``#`` starts a comment line)::

    cameras.txt    CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]
    images.txt     IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME        (two lines per image)
                   X Y POINT3D_ID  X Y POINT3D_ID ...                  (POINT3D_ID -1: not triangulated)
    points3D.txt   POINT3D_ID X Y Z R G B ERROR IMAGE_ID POINT2D_IDX ...

COLMAP 3.12+ also writes ``rigs.txt`` and ``frames.txt``; they are not needed (``images.txt`` holds each
image's ``cam_from_world``) and are ignored on reading and not written (COLMAP and pycolmap read a model
without them as one trivial rig per camera).  The binary encoding is :mod:`skyrig.io.colmap_binary`; what
both share (the model, the cameras both ways, the checks) is :mod:`skyrig.io.colmap`.  Writers
(:func:`write_colmap_text`) write numbers with 17 significant digits (a round trip is exact) and one
keypoint per measurement, in the model's order (tracks follow).  An image name with a blank is refused by the
text writer (COLMAP's text reader cuts names at the first blank; the binary encoding keeps them).

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

from os import PathLike
from pathlib import Path

import numpy as np

from skyrig.camera.frame import FrameCamera
from skyrig.errors import InputFormatError, OptionError
from skyrig.io._text import atomic_write, check_output_dir, parse_float, read_text
from skyrig.io.colmap import (COLMAP_CAMERA_MODELS, FIT_TOLERANCE_PX, SKYRIG_FROM_COLMAP_CAMERA, ColmapModel,
                              ImageRecord, PointRecords, assemble_model, block_from_colmap, camera_from_colmap,
                              model_records)

__all__ = ["ColmapModel", "read_colmap_cameras", "read_colmap_text", "write_colmap_text", "write_camera_records_text", "block_from_colmap",
           "COLMAP_CAMERA_MODELS", "SKYRIG_FROM_COLMAP_CAMERA"]


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
        names = COLMAP_CAMERA_MODELS[model][0]
        if len(f) != 4 + len(names):
            raise InputFormatError(f"{model} has {len(names)} parameters ({' '.join(names)}), got {len(f) - 4}",
                                   p, ln, "PARAMS")
        w, h = _int(f[2], p, ln, "WIDTH"), _int(f[3], p, ln, "HEIGHT")
        prm = [parse_float(v, p, ln, n) for n, v in zip(names, f[4:])]
        cam = camera_from_colmap(cid, model, w, h, prm, p, ln, pixel_size_mm)
        if cid in cams:
            raise InputFormatError(f"camera {cid} is defined twice", p, ln, "CAMERA_ID")
        cams[cid] = cam
    return cams


def _read_points(pp: Path) -> PointRecords:
    pid, xyz, rgb, err, tracks, lines = [], [], [], [], [], []
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
        err.append(parse_float(f[7], pp, ln, "ERROR") if f[7].lower() != "nan" else -1.0)
        tr = f[8:]
        tracks.append(np.array([[_int(a, pp, ln, "IMAGE_ID"), _int(b, pp, ln, "POINT2D_IDX")]
                                for a, b in zip(tr[0::2], tr[1::2])], np.int64).reshape(-1, 2))
        lines.append(ln)
    return PointRecords(np.array(pid, np.int64), np.array(xyz, np.float64).reshape(-1, 3),
                        np.array(rgb, np.int64).reshape(-1, 3), np.array(err, np.float64), tracks, lines)


def _isnum(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def _read_images(ip: Path) -> list[ImageRecord]:
    lines = _data_lines(ip)
    # drop trailing blank lines; every image is a header line plus a (possibly empty) points line
    while lines and not lines[-1][1].strip():
        lines.pop()
    out = []
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
        if not all(_isnum(v) for v in f[1:5]):
            raise InputFormatError("quaternion is not numeric", ip, ln, "QW QX QY QZ")
        qv = [float(v) for v in f[1:5]]
        tv = [parse_float(v, ip, ln, n) for v, n in zip(f[5:8], ("TX", "TY", "TZ"))]
        cid = _int(f[8], ip, ln, "CAMERA_ID")
        pts_ln, pts = (lines[k + 1] if k + 1 < len(lines) else (ln + 1, ""))
        k += 2
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
        out.append(ImageRecord(iid, qv, tv, cid, f[9].strip(), xy, p3, ln, pts_ln))
    return out


def read_colmap_text(folder: str | PathLike[str], pixel_size_mm: float = 0.001) -> ColmapModel:
    """Read a COLMAP text model folder (``cameras.txt``, ``images.txt``, ``points3D.txt``).

    Measurements whose ``POINT3D_ID`` is -1 are dropped; an id missing from ``points3D.txt``, an image
    naming an unknown camera, a track that disagrees with ``images.txt``, or a malformed number raise
    :class:`~skyrig.errors.InputFormatError` naming the file, line and field.
    """
    d = Path(folder)
    cams = read_colmap_cameras(d / "cameras.txt", pixel_size_mm)
    points = _read_points(d / "points3D.txt")
    images = _read_images(d / "images.txt")
    return assemble_model(cams, images, points, d / "images.txt", d / "points3D.txt")


def _num(v: float) -> str:
    return repr(float(v))


def write_camera_records_text(path: str | PathLike[str], cams: dict[int, tuple[str, int, int, list[float]]]) -> None:
    """Write ``cameras.txt`` from :func:`skyrig.io.colmap.camera_records` (atomically)."""
    with atomic_write(path) as fh:
        fh.write("# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
                 f"# Number of cameras: {len(cams)}\n# written by skyrig\n")
        for cid, (name, w, h, prm) in cams.items():
            fh.write(f"{cid} {name} {w} {h} {' '.join(_num(v) for v in prm)}\n")


def write_colmap_text(folder: str | PathLike[str], model: ColmapModel, fit_cameras: bool = False,
                      fit_tolerance_px: float = FIT_TOLERANCE_PX) -> list[Path]:
    """Write ``model`` as ``cameras.txt``, ``images.txt``, ``points3D.txt`` in ``folder`` (created; each file
    atomically).  Cameras as :func:`skyrig.io.colmap.colmap_camera` (``fit_cameras``: a camera no COLMAP model
    holds is fitted to FULL_OPENCV, refused above ``fit_tolerance_px`` RMS).  Returns the three paths."""
    blank = [str(n) for n in model.image_name if len(str(n).split()) != 1]
    if blank:
        raise OptionError("image_name", f"image name {blank[0]!r} has a blank: COLMAP's text reader cuts the name "
                          "there; write the binary model (skyrig.io.colmap_binary) or rename the images")
    d = check_output_dir(folder)
    cams, images, points = model_records(model, fit_cameras, fit_tolerance_px)
    paths = [d / "cameras.txt", d / "images.txt", d / "points3D.txt"]
    write_camera_records_text(paths[0], cams)
    with atomic_write(paths[1]) as fh:
        fh.write("# Image list with two lines of data per image:\n"
                 "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n#   POINTS2D[] as (X, Y, POINT3D_ID)\n"
                 f"# Number of images: {len(images)}\n")
        for r in images:
            fh.write(f"{r.image_id} {' '.join(_num(v) for v in (*r.q, *r.t))} {r.camera_id} {r.name}\n")
            fh.write(" ".join(f"{_num(x)} {_num(y)} {int(p)}" for (x, y), p in zip(r.xy, r.point3d_id)) + "\n")
    with atomic_write(paths[2]) as fh:
        fh.write("# 3D point list with one line of data per point:\n"
                 "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n"
                 f"# Number of points: {len(points.point_id)}\n")
        for k in range(len(points.point_id)):
            x, y, z = points.xyz[k]
            r, g, b = points.rgb[k]
            tr = " ".join(f"{int(i)} {int(j)}" for i, j in points.tracks[k])
            fh.write(f"{int(points.point_id[k])} {_num(x)} {_num(y)} {_num(z)} {int(r)} {int(g)} {int(b)} "
                     f"{_num(points.error[k])} {tr}\n")
    return paths
