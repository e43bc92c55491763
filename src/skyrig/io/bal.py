"""Bundle Adjustment in the Large (BAL) problem files (Agarwal et al. 2010, grail.cs.washington.edu/projects/bal).

Format (whitespace separated text)::

    <num_cameras> <num_points> <num_observations>
    <camera_index> <point_index> <x> <y>          num_observations lines
    <camera parameters>                           9 per camera: rotation vector (3), t (3), f, k1, k2
    <point parameters>                            3 per point

Camera model: ``P = R(w) X + t``, ``p = -P_xy / P_z``, ``uv = f (1 + k1 |p|^2 + k2 |p|^4) p`` (pixels
from the image centre, x right, y up).  In skyrig terms the camera frame is skyrig's (looking along
-z, y up), ``world_from_camera = (R^T, -R^T t)`` and the intrinsics are a
:class:`~skyrig.adjust.block.BalCamera` per image; the BAL cost is ``0.5 * sum(r^2)`` with unit sigma.
"""

from __future__ import annotations

import os
from os import PathLike
from pathlib import Path

import numpy as np

from skyrig.adjust.block import BalCamera, Block
from skyrig.errors import InputFormatError
from skyrig.geometry.rotations import matrix_from_rotvec, rotvec_from_matrix
from skyrig.io._text import output_temp, publish
from skyrig.rig.camera_pose import world_from_camera

__all__ = ["read_bal", "write_bal"]


def read_bal(path: str | PathLike[str]) -> Block:
    """Read a BAL problem into a :class:`Block` (one station, image and camera per BAL camera)."""
    p = Path(path)
    with open(p, "rb") as fh:
        if fh.read(3) != b"\xef\xbb\xbf":  # a UTF-8 byte-order mark (as Excel writes) is skipped
            fh.seek(0)
        head = fh.readline().split()
        if len(head) != 3:
            raise InputFormatError("expected 'num_cameras num_points num_observations'", p, 1)
        try:
            nc, npt, nobs = (int(x) for x in head)
        except ValueError:
            raise InputFormatError("counts must be integers", p, 1) from None
        if min(nc, npt, nobs) <= 0:
            raise InputFormatError("counts must be positive", p, 1)
        try:
            obs = np.loadtxt(fh, max_rows=nobs, dtype=np.float64, ndmin=2)
            params = np.array(fh.read().split(), dtype=np.float64)
        except ValueError as e:
            raise InputFormatError(f"not a number ({e})", p) from None
    if obs.shape != (nobs, 4):
        raise InputFormatError(f"expected {nobs} observation lines of 4 fields, got shape {obs.shape}", p, 2)
    need = 9 * nc + 3 * npt
    if params.size != need:
        raise InputFormatError(f"expected {need} camera and point parameters after the observations, got {params.size}",
                               p, 2 + nobs)
    bad = np.flatnonzero(~np.isfinite(obs).all(axis=1))
    if bad.size:
        raise InputFormatError("non-finite observation", p, 2 + int(bad[0]))
    ci, pi = obs[:, 0].astype(np.int64), obs[:, 1].astype(np.int64)
    for name, idx, n in (("camera_index", ci, nc), ("point_index", pi, npt)):
        b = np.flatnonzero((idx < 0) | (idx >= n))
        if b.size:
            raise InputFormatError(f"index {idx[b[0]]} out of range 0..{n - 1}", p, 2 + int(b[0]), name)
    cam = params[: 9 * nc].reshape(nc, 9)
    X = params[9 * nc:].reshape(npt, 3)
    R = matrix_from_rotvec(cam[:, :3])  # camera_from_world
    Rwc = np.swapaxes(R, 1, 2)
    C = -np.einsum("nij,nj->ni", Rwc, cam[:, 3:6])
    names = np.array([f"c{i}" for i in range(nc)])
    cams = [BalCamera(f"c{i}", float(cam[i, 6]), float(cam[i, 7]), float(cam[i, 8])) for i in range(nc)]
    return Block(cameras=cams, station_name=names, station_rotation=Rwc, station_centre=C, image_name=names,
                 image_station=np.arange(nc), image_camera=np.arange(nc), image_head=np.zeros(nc, np.int64),
                 head_name=np.array(["bal"]), point_name=np.arange(npt).astype(str), point_xyz=X, obs_image=ci,
                 obs_point=pi, obs_pixel=obs[:, 2:], obs_sigma_px=1.0, frame=f"BAL problem {p.name}")


def write_bal(path: str | PathLike[str], block: Block) -> None:
    """Write a block whose cameras are :class:`BalCamera` (one per image, single stations) as a BAL file."""
    if not all(isinstance(c, BalCamera) for c in block.cameras):
        raise ValueError("write_bal needs BalCamera cameras")
    st = block.image_station
    Rs, Cs = world_from_camera(block.station_rotation[st], block.station_centre[st], block.image_rotation,
                               block.image_offset)
    R = np.swapaxes(Rs, 1, 2)
    t = -np.einsum("nij,nj->ni", R, Cs)
    intr = np.array([block.cameras[c].intrinsics for c in block.image_camera])
    cam = np.column_stack([rotvec_from_matrix(R), t, intr])
    p = Path(path)
    fd, tmp = output_temp(p)
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(f"{block.n_images} {block.n_points} {block.n_observations}\n")
            rows = np.column_stack([block.obs_image, block.obs_point, block.obs_pixel])
            fh.writelines(f"{int(a)} {int(b)} {x:.17g} {y:.17g}\n" for a, b, x, y in rows)
            np.savetxt(fh, cam.reshape(-1, 1), fmt="%.17g")
            np.savetxt(fh, block.point_xyz.reshape(-1, 1), fmt="%.17g")
        publish(tmp, p)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
