"""Pix4D ``1_initial/params`` outputs: calibrated external parameters (OPK), calibrated camera parameters (K, R, t)
and the offset, read and written.

Files (``docs/formats/pix4d.md``)
---------------------------------
* ``<project>_calibrated_external_camera_parameters.txt``: a header ``imageName X Y Z Omega Phi Kappa`` then one
  line per image, blank-separated: projection centre in the output CRS (metres) and omega, phi, kappa in
  **degrees**, Pix4D's "PATB convention".
* ``<project>_calibrated_camera_parameters.txt``: a header block, then per image 10 lines::

      fileName imageWidth imageHeight
      camera matrix K [3x3]                 (3 lines: fx 0 cx / 0 fy cy / 0 0 1, pixels)
      radial distortion [3x1]               (R1 R2 R3)
      tangential distortion [2x1]           (T1 T2)
      camera position t [3x1]               (projection centre minus the offset)
      camera rotation R [3x3]               (3 lines)
      camera model m = K [R|-Rt] X

* ``<project>_offset.xyz``: ``X Y Z`` subtracted from the output CRS coordinates in the file above.

Conventions
-----------
* **OPK**: ``R = Rx(omega) Ry(phi) Rz(kappa)`` is ``world_from_camera`` with the photogrammetric camera frame (x
  right, y up, z backwards), angles in degrees about the output CRS's grid axes: skyrig's ``opk`` sequence
  (:func:`skyrig.geometry.rotations.matrix_from_opk`), unchanged.
* **K, R, t**: ``m = K [R | -R t] X``: ``R`` is camera-from-world with the computer-vision camera frame (x right,
  y down, z forward), ``t`` the centre minus the offset.  Both files describe the same rotation:
  ``R_kRt = F R_opk^T`` (``F = diag(1, -1, -1)``) -- checked on a published pair of Pix4D outputs to 4e-9 (the
  OPK file's 6 decimals), and ``t + offset`` is the OPK file's centre.
* **Camera**: OpenCV's model on the normalised coordinates of that frame: ``k1, k2, k3 = R1, R2, R3`` and
  ``p1, p2 = T1, T2`` (the order in which peers pass them to OpenCV), ``fx = fy`` (else the Brown affinity with no
  distortion, refused with distortion).  **Pixel origin**: the image's top-left corner (the centre of the first
  pixel at 0.5, 0.5): Pix4D's principal point in millimetres (``..._pix4d_calibrated_internal_camera_parameters.cam``
  ``Px, Py``, from the sensor's edge) is ``cx, cy`` times the pixel size exactly, so the pixel coordinates start at
  the same edge; skyrig pixels are Pix4D's minus 0.5.  The tangential order and the pixel origin are not checked
  against Pix4D's own projections (docs/formats/pix4d.md).
* **CRS**: Pix4D's output CRS, not stated in these files (its ``_wkt.prj`` names it): the caller gives it.
"""

from __future__ import annotations

from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from skyrig.camera.aspect import camera_from_fx_fy, fx_fy_px
from skyrig.camera.convert import exact_conversion
from skyrig.camera.distortion import NoDistortion
from skyrig.camera.frame import FrameCamera
from skyrig.camera.opencv import OpenCVDistortion
from skyrig.errors import InputFormatError, OptionError
from skyrig.geodesy.frame import WorldFrame
from skyrig.georef.eo import ExteriorOrientations
from skyrig.geometry.pose import Pose
from skyrig.geometry.rotations import opk_from_matrix
from skyrig.io._text import atomic_write, parse_float, read_text

__all__ = ["Pix4dCameras", "read_pix4d_external", "write_pix4d_external", "read_pix4d_offset",
           "read_pix4d_calibrated_cameras", "write_pix4d_calibrated_cameras"]

F = np.diag([1.0, -1.0, -1.0])
HALF = 0.5  # Pix4D pixel (corner origin) minus skyrig pixel
EXTERNAL_HEADER = ["imageName", "X", "Y", "Z", "Omega", "Phi", "Kappa"]
CCP_HEADER = ["fileName imageWidth imageHeight", "camera matrix K [3x3]", "radial distortion [3x1]",
              "tangential distortion [2x1]", "camera position t [3x1]", "camera rotation R [3x3]",
              "camera model m = K [R|-Rt] X"]


def _rows(path: Path) -> list[tuple[int, list[str]]]:
    return [(i + 1, s.split()) for i, s in enumerate(read_text(path).split("\n")) if s.strip()]


def read_pix4d_external(path: str | PathLike[str], frame: WorldFrame, camera: str = "pix4d") -> ExteriorOrientations:
    """Read ``..._calibrated_external_camera_parameters.txt`` into orientations in ``frame`` (Pix4D's output CRS;
    the file does not state it).  All images get the camera name ``camera``."""
    p = Path(path)
    rows = _rows(p)
    if not rows or [h.lower() for h in rows[0][1][:7]] != [h.lower() for h in EXTERNAL_HEADER]:
        raise InputFormatError(f"the first line must be '{' '.join(EXTERNAL_HEADER)}' (not a Pix4D external "
                               "parameters file?)", p, rows[0][0] if rows else None)
    names, vals = [], []
    for ln, f in rows[1:]:
        if len(f) != 7:
            raise InputFormatError(f"expected 7 fields, got {len(f)}", p, ln)
        names.append(f[0])
        vals.append([parse_float(v, p, ln, n) for v, n in zip(f[1:], EXTERNAL_HEADER[1:])])
    if not names:
        raise InputFormatError("no image after the header", p, rows[0][0])
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise InputFormatError(f"image {dup!r} appears twice", p, rows[1 + names.index(dup)][0], "imageName")
    v = np.array(vals)
    big = np.abs(v[:, 3:]).max(axis=1) > 360.0
    if big.any():
        k = int(np.argmax(big))
        raise InputFormatError("an angle beyond 360: Pix4D writes degrees (another unit?)", p, rows[1 + k][0],
                               "Omega Phi Kappa")
    from skyrig.io.plausibility import angle_readings, check_attitude_reading

    rotations_of = angle_readings(frame, v[:, :3], v[:, 3:6])
    check_attitude_reading(rotations_of, "deg", "opk", v[:, :3], p, [ln for ln, _ in rows[1:]],
                           ("Omega", "Phi", "Kappa"), "Pix4D's external parameters are omega, phi, kappa in "
                           "degrees: convert the angles, or give the orientations as a skyrig EO CSV that "
                           "declares them ('# angles: gon', '# convention: ypr')", values=v[:, 3:6], frame=frame)
    rot = rotations_of("deg", "opk")
    return ExteriorOrientations(np.array(names), np.full(len(names), camera), v[:, :3], rot, frame)


def write_pix4d_external(path: str | PathLike[str], eo: ExteriorOrientations) -> Path:
    """Write orientations (in a map frame: OPK about its grid axes) as Pix4D's external parameters file."""
    if eo.frame.kind != "map":
        raise OptionError("frame", f"Pix4D's OPK are about a map CRS's grid axes; the orientations are in "
                          f"{eo.frame.describe()}: convert them first")
    o, ph, k = opk_from_matrix(eo.rotation, unit="deg", sequence="opk")
    with atomic_write(path) as fh:
        fh.write(" ".join(EXTERNAL_HEADER) + "\n")
        for i in range(len(eo)):
            c = eo.centre[i]
            fh.write(f"{eo.image[i]} {c[0]:.6f} {c[1]:.6f} {c[2]:.6f} {o[i]:.9f} {ph[i]:.9f} {k[i]:.9f}\n")
    return Path(path)


def read_pix4d_offset(path: str | PathLike[str]) -> NDArray[np.float64]:
    """``(3,)`` the offset of ``..._offset.xyz``."""
    p = Path(path)
    rows = _rows(p)
    if len(rows) != 1 or len(rows[0][1]) != 3:
        raise InputFormatError("expected one line 'X Y Z'", p, rows[0][0] if rows else None)
    return np.array([parse_float(v, p, rows[0][0], n) for v, n in zip(rows[0][1], "XYZ")])


@dataclass
class Pix4dCameras:
    """The images of a ``..._calibrated_camera_parameters.txt``: one camera per distinct interior orientation.

    Attributes
    ----------
    cameras
        ``{camera id: FrameCamera}`` (ids ``pix4d-1``, ``pix4d-2``... in order of appearance).
    image_name, image_camera_id
        ``(I,)``.
    world_from_camera
        ``(I,)`` poses (skyrig camera frame), centres with the offset added back.
    """

    cameras: dict[str, FrameCamera]
    image_name: NDArray[np.str_]
    image_camera_id: NDArray[np.str_]
    world_from_camera: Pose


def _nums(rows: list[tuple[int, list[str]]], k: int, n: int, p: Path, what: str) -> NDArray[np.float64]:
    if k >= len(rows):
        raise InputFormatError(f"the file ends inside an image block (expected {what})", p, rows[-1][0] if rows else None)
    ln, f = rows[k]
    if len(f) != n:
        raise InputFormatError(f"expected {n} numbers ({what}), got {len(f)}", p, ln, what)
    return np.array([parse_float(v, p, ln, what) for v in f])


def read_pix4d_calibrated_cameras(path: str | PathLike[str],
                                  offset: NDArray[np.float64] | tuple[float, float, float] = (0.0, 0.0, 0.0)
                                  ) -> Pix4dCameras:
    """Read ``..._calibrated_camera_parameters.txt`` (module docstring); ``offset``: ``..._offset.xyz``
    (:func:`read_pix4d_offset`), added to the positions."""
    p = Path(path)
    rows = _rows(p)
    k = 0
    while k < len(rows) and rows[k][1][0].lower() in ("filename", "camera", "radial", "tangential"):
        k += 1  # the header block
    off = np.asarray(offset, np.float64).reshape(3)
    cams: dict[str, FrameCamera] = {}
    names, ids, Rs, Cs = [], [], [], []
    while k < len(rows):
        ln, head = rows[k]
        if len(head) != 3:
            raise InputFormatError("expected 'fileName imageWidth imageHeight'", p, ln)
        name = head[0]
        try:
            w, h = int(head[1]), int(head[2])
        except ValueError:
            raise InputFormatError("image size is not two whole numbers", p, ln, "imageWidth imageHeight") from None
        K = np.array([_nums(rows, k + 1 + j, 3, p, "camera matrix K") for j in range(3)])
        rad = _nums(rows, k + 4, 3, p, "radial distortion")
        tan = _nums(rows, k + 5, 2, p, "tangential distortion")
        t = _nums(rows, k + 6, 3, p, "camera position t")
        R = np.array([_nums(rows, k + 7 + j, 3, p, "camera rotation R") for j in range(3)])
        if K[0, 1] != 0 or K[1, 0] != 0 or not np.allclose(K[2], [0, 0, 1]):
            raise InputFormatError("K has skew or is not [fx 0 cx; 0 fy cy; 0 0 1]", p, rows[k + 1][0], "K")
        if np.abs(R @ R.T - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
            raise InputFormatError("R is not a rotation", p, rows[k + 7][0], "R")
        d = OpenCVDistortion(k1=rad[0], k2=rad[1], p1=tan[0], p2=tan[1], k3=rad[2])
        try:
            cam = camera_from_fx_fy("pix4d", w, h, K[0, 0], K[1, 1], K[0, 2] - HALF, K[1, 2] - HALF,
                                    distortion=d if np.any(d.params) else NoDistortion())
        except ValueError as e:
            raise InputFormatError(str(e), p, rows[k + 1][0], "K") from None
        cid = next((c for c, v in cams.items() if v == cam.with_(name=c)), None)
        if cid is None:
            cid = f"pix4d-{len(cams) + 1}"
            cams[cid] = cam.with_(name=cid)
        names.append(name)
        ids.append(cid)
        Rs.append(R.T @ F)
        Cs.append(t + off)
        k += 10
    if not names:
        raise InputFormatError("no image block (not a Pix4D calibrated camera parameters file?)", p)
    return Pix4dCameras(cams, np.array(names, dtype=str), np.array(ids, dtype=str),
                        Pose(np.array(Rs), np.array(Cs), "world", "camera"))


def write_pix4d_calibrated_cameras(path: str | PathLike[str], data: Pix4dCameras,
                                   offset: NDArray[np.float64] | tuple[float, float, float] = (0.0, 0.0, 0.0)) -> Path:
    """Write ``..._calibrated_camera_parameters.txt`` (positions minus ``offset``).  Cameras must be OpenCV
    ``k1 k2 p1 p2 k3`` (or convert exactly to it: none, Metashape without K4/B1/B2, ...), or pinholes with
    ``fx != fy``."""
    off = np.asarray(offset, np.float64).reshape(3)
    R = np.swapaxes(data.world_from_camera.rotation.reshape(-1, 3, 3) @ F, 1, 2)
    C = data.world_from_camera.translation.reshape(-1, 3) - off
    with atomic_write(path) as fh:
        fh.write("\n".join(CCP_HEADER) + "\n")
        for i, name in enumerate(data.image_name):
            cam = data.cameras[str(data.image_camera_id[i])]
            fxy = fx_fy_px(cam)
            if fxy is not None:
                fx, fy, d = fxy[0], fxy[1], OpenCVDistortion()
            else:
                ex = exact_conversion(cam, "opencv")
                if ex is None:
                    raise OptionError("camera", f"camera {cam.name!r}: Pix4D's model (OpenCV k1 k2 k3 p1 p2) cannot "
                                      f"hold the {cam.distortion.name!r} distortion exactly; convert it first "
                                      "(skyrig convert --camera --to-model opencv)")
                fx = fy = ex.focal_px
                d = ex.distortion
            cx, cy = cam.principal_point_px
            fh.write(f"\n{name} {cam.width} {cam.height}\n")
            fh.write(f"{fx!r} 0 {cx + HALF!r}\n0 {fy!r} {cy + HALF!r}\n0 0 1\n")
            fh.write(f"{float(d.k1)!r} {float(d.k2)!r} {float(d.k3)!r}\n{float(d.p1)!r} {float(d.p2)!r}\n")
            fh.write(" ".join(repr(float(v)) for v in C[i]) + "\n")
            for row in R[i]:
                fh.write(" ".join(repr(float(v)) for v in row) + "\n")
    return Path(path)
