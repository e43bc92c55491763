"""COLMAP binary models (``cameras.bin``, ``images.bin``, ``points3D.bin``), read and written.

Layout (little-endian; COLMAP ``src/colmap/scene/reconstruction_io.cc``, the same since COLMAP 3.0; 3.12+ adds
``rigs.bin`` and ``frames.bin``, which are not needed, ignored on reading and not written: COLMAP and pycolmap
read a model without them as one trivial rig per camera)::

    cameras.bin   uint64 n;  n x { int32 camera_id, int32 model_id, uint64 width, uint64 height,
                                   float64 params[number of the model's parameters] }
    images.bin    uint64 n;  n x { int32 image_id, float64 qw qx qy qz, float64 tx ty tz, int32 camera_id,
                                   char name[] NUL-terminated, uint64 n2,
                                   n2 x { float64 x, float64 y, int64 point3D_id (-1: none) } }
    points3D.bin  uint64 n;  n x { uint64 point3D_id, float64 x y z, uint8 r g b, float64 error,
                                   uint64 track_length, track_length x { int32 image_id, int32 point2D_idx } }

(COLMAP declares the ids ``uint32`` and ``point3D_id`` ``uint64``; the bytes are the same for the ids that
occur, and -1 is ``0xFFFF...``.)  Model ids are :data:`skyrig.io.colmap.COLMAP_MODEL_IDS`.

The conventions (pose, pixel origin, camera models, units, CRS) are those of the text encoding, described
in :mod:`skyrig.io.colmap` and ``docs/formats/colmap.md``.  Errors name the file, the record (``line`` is
the 1-based record number: camera, image or point) and the field; a file that ends early names the record
it ends in.
"""

from __future__ import annotations

import struct
from os import PathLike
from pathlib import Path

import numpy as np

from skyrig.camera.frame import FrameCamera
from skyrig.errors import InputFormatError
from skyrig.io._text import atomic_write, check_output_dir
from skyrig.io.colmap import (COLMAP_CAMERA_MODELS, COLMAP_MODEL_IDS, FIT_TOLERANCE_PX, ColmapModel, ImageRecord,
                              PointRecords, assemble_model, camera_from_colmap, model_records)

__all__ = ["read_colmap_binary", "read_colmap_cameras_binary", "write_colmap_binary", "write_camera_records_binary"]

_MODEL_NAMES = {v: k for k, v in COLMAP_MODEL_IDS.items()}
#: parameters of the models skyrig does not read (to skip them with the right size in errors)
_OTHER_N_PARAMS = {"OPENCV_FISHEYE": 8, "FOV": 5, "SIMPLE_RADIAL_FISHEYE": 4, "RADIAL_FISHEYE": 5,
                   "THIN_PRISM_FISHEYE": 12, "RAD_TAN_THIN_PRISM_FISHEYE": 16}
_IMG_HEAD = np.dtype([("image_id", "<i4"), ("q", "<f8", 4), ("t", "<f8", 3), ("camera_id", "<i4")])
_PT2D = np.dtype([("xy", "<f8", 2), ("p3", "<i8")])
_PT3D_HEAD = np.dtype([("id", "<u8"), ("xyz", "<f8", 3), ("rgb", "u1", 3), ("error", "<f8"), ("n", "<u8")])
_TRACK = np.dtype([("image_id", "<i4"), ("idx", "<i4")])


class _Reader:
    """A cursor over a file's bytes that names the file and record when it runs out."""

    def __init__(self, path: Path) -> None:
        self.path = path
        try:
            self.buf = path.read_bytes()
        except FileNotFoundError:
            raise InputFormatError("file not found", path) from None
        self.pos = 0
        self.record: int | None = None

    def take(self, n: int, field: str) -> memoryview:
        if self.pos + n > len(self.buf):
            raise InputFormatError(f"the file ends early ({len(self.buf)} bytes; {n} more needed at byte {self.pos})",
                                   self.path, self.record, field)
        out = memoryview(self.buf)[self.pos:self.pos + n]
        self.pos += n
        return out

    def array(self, dtype: np.dtype, count: int, field: str) -> np.ndarray:
        return np.frombuffer(self.take(dtype.itemsize * count, field), dtype, count)

    def u64(self, field: str) -> int:
        return int(struct.unpack("<Q", self.take(8, field))[0])

    def count(self, field: str, item_size: int, n: int | None = None) -> int:
        """A count read here (or ``n`` already read), checked to fit in the rest of the file."""
        n = self.u64(field) if n is None else n
        if n * item_size > len(self.buf) - self.pos:
            raise InputFormatError(f"count {n} does not fit in the file (a text file, or another format?)",
                                   self.path, self.record, field)
        return n

    def cstring(self, field: str) -> str:
        end = self.buf.find(b"\0", self.pos)
        if end < 0:
            raise InputFormatError("the file ends inside a name (no NUL)", self.path, self.record, field)
        raw = self.buf[self.pos:end]
        self.pos = end + 1
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            raise InputFormatError("the name is not UTF-8", self.path, self.record, field) from None

    def done(self) -> None:
        if self.pos != len(self.buf):
            raise InputFormatError(f"{len(self.buf) - self.pos} bytes after the last record (another format or "
                                   "version?)", self.path, None)


def read_colmap_cameras_binary(path: str | PathLike[str], pixel_size_mm: float = 0.001) -> dict[int, FrameCamera]:
    """Read ``cameras.bin``: ``{camera id: FrameCamera}`` (models as :mod:`skyrig.io.colmap`)."""
    r = _Reader(Path(path))
    n = r.count("number of cameras", 24)
    cams: dict[int, FrameCamera] = {}
    for k in range(n):
        r.record = k + 1
        cid, mid, w, h = struct.unpack("<iiQQ", r.take(24, "CAMERA_ID MODEL_ID WIDTH HEIGHT"))
        name = _MODEL_NAMES.get(mid)
        if name is None:
            raise InputFormatError(f"unknown camera model id {mid} (another format or version?)", r.path, r.record,
                                   "MODEL_ID")
        if name not in COLMAP_CAMERA_MODELS:
            raise InputFormatError(f"camera model {name} is not supported (supported: "
                                   f"{', '.join(COLMAP_CAMERA_MODELS)})", r.path, r.record, "MODEL_ID")
        prm = r.array(np.dtype("<f8"), len(COLMAP_CAMERA_MODELS[name][0]), "PARAMS")
        if w > 1 << 31 or h > 1 << 31:
            raise InputFormatError(f"image size {w} x {h} is not plausible (another format?)", r.path, r.record,
                                   "WIDTH HEIGHT")
        cam = camera_from_colmap(cid, name, int(w), int(h), prm.tolist(), r.path, r.record, pixel_size_mm)
        if cid in cams:
            raise InputFormatError(f"camera {cid} is defined twice", r.path, r.record, "CAMERA_ID")
        cams[cid] = cam
    r.done()
    return cams


def _read_images(path: Path) -> list[ImageRecord]:
    r = _Reader(path)
    n = r.count("number of images", _IMG_HEAD.itemsize)
    out = []
    for k in range(n):
        r.record = k + 1
        h = r.array(_IMG_HEAD, 1, "IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID")[0]
        name = r.cstring("NAME")
        n2 = r.count("number of points2D", _PT2D.itemsize)
        pts = r.array(_PT2D, n2, "POINTS2D[]")
        out.append(ImageRecord(int(h["image_id"]), h["q"].tolist(), h["t"].tolist(), int(h["camera_id"]), name,
                               pts["xy"].astype(np.float64), pts["p3"].astype(np.int64), k + 1, k + 1))
    r.done()
    return out


def _read_points(path: Path) -> PointRecords:
    r = _Reader(path)
    n = r.count("number of points", _PT3D_HEAD.itemsize)
    heads = np.empty(n, _PT3D_HEAD)
    tracks = []
    for k in range(n):
        r.record = k + 1
        heads[k] = r.array(_PT3D_HEAD, 1, "POINT3D_ID X Y Z R G B ERROR TRACK_LENGTH")[0]
        t = r.array(_TRACK, r.count("TRACK_LENGTH", _TRACK.itemsize, int(heads[k]["n"])), "TRACK[]")
        tracks.append(np.column_stack([t["image_id"], t["idx"]]).astype(np.int64))
    r.done()
    return PointRecords(heads["id"].astype(np.int64), heads["xyz"].astype(np.float64), heads["rgb"].astype(np.int64),
                        heads["error"].astype(np.float64), tracks, list(range(1, n + 1)))


def read_colmap_binary(folder: str | PathLike[str], pixel_size_mm: float = 0.001) -> ColmapModel:
    """Read a COLMAP binary model folder (``cameras.bin``, ``images.bin``, ``points3D.bin``): the same
    :class:`~skyrig.io.colmap.ColmapModel` and checks as :func:`skyrig.io.colmap_text.read_colmap_text`."""
    d = Path(folder)
    cams = read_colmap_cameras_binary(d / "cameras.bin", pixel_size_mm)
    points = _read_points(d / "points3D.bin")
    images = _read_images(d / "images.bin")
    return assemble_model(cams, images, points, d / "images.bin", d / "points3D.bin")


def write_camera_records_binary(path: str | PathLike[str], cams: dict[int, tuple[str, int, int, list[float]]]
                                ) -> None:
    """Write ``cameras.bin`` from :func:`skyrig.io.colmap.camera_records` (atomically)."""
    with atomic_write(path, "wb") as fh:
        fh.write(struct.pack("<Q", len(cams)))
        for cid, (name, w, h, prm) in cams.items():
            fh.write(struct.pack("<iiQQ", cid, COLMAP_MODEL_IDS[name], w, h))
            fh.write(np.asarray(prm, "<f8").tobytes())


def write_colmap_binary(folder: str | PathLike[str], model: ColmapModel, fit_cameras: bool = False,
                        fit_tolerance_px: float = FIT_TOLERANCE_PX) -> list[Path]:
    """Write ``model`` as ``cameras.bin``, ``images.bin``, ``points3D.bin`` in ``folder`` (created; each file
    atomically).  Cameras as :func:`skyrig.io.colmap.colmap_camera`; ``fit_cameras`` and ``fit_tolerance_px``
    as :func:`skyrig.io.colmap_text.write_colmap_text`.  Returns the three paths."""
    d = check_output_dir(folder)
    cams, images, points = model_records(model, fit_cameras, fit_tolerance_px)
    paths = [d / "cameras.bin", d / "images.bin", d / "points3D.bin"]
    write_camera_records_binary(paths[0], cams)
    with atomic_write(paths[1], "wb") as fh:
        fh.write(struct.pack("<Q", len(images)))
        for im in images:
            head = np.zeros(1, _IMG_HEAD)
            head["image_id"], head["q"], head["t"], head["camera_id"] = im.image_id, im.q, im.t, im.camera_id
            fh.write(head.tobytes())
            fh.write(im.name.encode("utf-8") + b"\0")
            pts = np.zeros(len(im.xy), _PT2D)
            pts["xy"], pts["p3"] = im.xy, im.point3d_id
            fh.write(struct.pack("<Q", len(pts)))
            fh.write(pts.tobytes())
    with atomic_write(paths[2], "wb") as fh:
        n = len(points.point_id)
        fh.write(struct.pack("<Q", n))
        head = np.zeros(n, _PT3D_HEAD)
        head["id"], head["xyz"], head["rgb"], head["error"] = (points.point_id, points.xyz, points.rgb,
                                                               points.error)
        head["n"] = [len(t) for t in points.tracks]
        for k in range(n):
            fh.write(head[k:k + 1].tobytes())
            tr = np.zeros(len(points.tracks[k]), _TRACK)
            tr["image_id"], tr["idx"] = points.tracks[k][:, 0], points.tracks[k][:, 1]
            fh.write(tr.tobytes())
    return paths
