"""Projection to pixels with analytic Jacobians (for bundle adjustment and calibration).

Model
-----
For a world point ``X`` and a pose ``world_from_camera = (R, C)`` (rotation and projection centre)::

    P     = R^T (X - C)                                  camera frame (x right, y up, z back)
    q     = -f (P_x, P_y) / P_z                          ideal image coordinates rel. to pp, mm
    o     = pp + distort(q, f)                           observed image coordinates, mm
    pixel = (o_x / pitch + (W-1)/2,  -o_y / pitch + (H-1)/2)

Pose perturbation
-----------------
The pose Jacobian ``(N, 2, 6)`` is with respect to ``(C_x, C_y, C_z, dθ_x, dθ_y, dθ_z)`` where the
rotation is perturbed **on the right, in the camera frame**::

    world_from_camera(dθ) = R @ expmap(dθ),   expmap = Rodrigues (skyrig.geometry.matrix_from_rotvec)

so ``dP/dθ = [P]x`` (the skew matrix of the camera-frame point) at ``dθ = 0``.  An optimiser
applies an update as ``C += dC``, ``R = R @ matrix_from_rotvec(dθ)``.

Intrinsics
----------
The intrinsics Jacobian ``(N, 2, 3 + P)`` is with respect to :attr:`FrameCamera.intrinsics`:
``(focal_mm, ppx_mm, ppy_mm, *distortion.params)`` (pixel pitch and image size are constants).

Everything is vectorised with einsum over the N points; a batch of N poses (one per point) is
accepted as well as a single pose.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Iterable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.geometry.pose import Pose
from skyrig.geometry.rotations import skew

if TYPE_CHECKING:
    from skyrig.camera.frame import FrameCamera

__all__ = ["project_camera_with_jacobians", "project_with_jacobians", "JACOBIAN_KINDS"]

#: the Jacobians :func:`project_with_jacobians` can return
JACOBIAN_KINDS = ("point_camera", "point", "pose", "intrinsics")


def project_camera_with_jacobians(
    camera: "FrameCamera", points_camera: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Camera-frame points to pixels with Jacobians w.r.t. the point and the intrinsics.

    Parameters
    ----------
    camera
        The camera.
    points_camera
        ``(N, 3)`` points in the camera frame, metres.  Points with ``P_z >= 0`` give NaN.

    Returns
    -------
    pixels
        ``(N, 2)`` (col, row).
    d_point
        ``(N, 2, 3)`` d(pixel)/d(camera-frame point), px/m.
    d_intrinsics
        ``(N, 2, 3 + P)`` d(pixel)/d(intrinsics), px per unit of each parameter
        (:attr:`FrameCamera.intrinsic_names`).
    """
    p = np.asarray(points_camera, dtype=np.float64).reshape(-1, 3)
    n = p.shape[0]
    f = camera.focal_mm
    z = p[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_z = np.where(z < 0, 1.0 / z, np.nan)
    ideal = -f * p[:, :2] * inv_z[:, None]
    # d ideal / d P  (N, 2, 3)
    dq_dp = np.zeros((n, 2, 3))
    dq_dp[:, 0, 0] = -f * inv_z
    dq_dp[:, 1, 1] = -f * inv_z
    dq_dp[:, :, 2] = -ideal * inv_z[:, None]  # q = -f P_xy / z  =>  dq/dz = f P_xy / z² = -q / z
    obs, j_ideal, j_params, j_focal = camera.distortion.distort_with_jacobians(ideal, f)
    obs = obs + np.array([camera.ppx_mm, camera.ppy_mm])
    pixels = camera.image_to_pixel(obs)
    scale = np.array([1.0 / camera.pixel_size_mm, -1.0 / camera.pixel_size_mm])  # d pixel / d obs (diag)

    d_point = scale[None, :, None] * (j_ideal @ dq_dp)
    n_dist = j_params.shape[2]
    d_intr = np.empty((n, 2, 3 + n_dist))
    # focal: ideal scales with f (dq/df = q / f), and the model may depend on f directly
    d_intr[:, :, 0] = scale * (np.einsum("nij,nj->ni", j_ideal, ideal / f) + j_focal)
    d_intr[:, :, 1] = [scale[0], 0.0]
    d_intr[:, :, 2] = [0.0, scale[1]]
    d_intr[:, :, 3:] = scale[None, :, None] * j_params
    return pixels, d_point, d_intr


def project_with_jacobians(
    camera: "FrameCamera",
    world_from_camera: Pose,
    points_world: ArrayLike,
    want: Iterable[str] = ("point", "pose", "intrinsics"),
) -> tuple[NDArray[np.float64], dict[str, NDArray[np.float64]]]:
    """World points to pixels with analytic Jacobians.

    Parameters
    ----------
    camera
        The camera.
    world_from_camera
        Pose: a single one, or a batch of N (one per point).
    points_world
        ``(N, 3)`` world points, metres.
    want
        Which Jacobians to return, any of :data:`JACOBIAN_KINDS`:

        * ``"point_camera"``: ``(N, 2, 3)`` w.r.t. the camera-frame point;
        * ``"point"``: ``(N, 2, 3)`` w.r.t. the world point;
        * ``"pose"``: ``(N, 2, 6)`` w.r.t. ``(C, dθ)``, ``world_from_camera = R @ expmap(dθ)``
          (module docstring), px/m and px/rad;
        * ``"intrinsics"``: ``(N, 2, 3 + P)`` w.r.t. :attr:`FrameCamera.intrinsics`.

    Returns
    -------
    pixels
        ``(N, 2)`` (col, row); NaN (and NaN Jacobians) for points behind the camera.
    jacobians
        ``{kind: array}`` for the requested kinds.
    """
    kinds = tuple(want)
    bad = [k for k in kinds if k not in JACOBIAN_KINDS]
    if bad:
        raise ValueError(f"unknown Jacobian kind(s) {bad}; choose from {JACOBIAN_KINDS}")
    x = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
    n = x.shape[0]
    R = world_from_camera.rotation
    if R.ndim == 2:  # one pose for all points: plain matrix products broadcast over N
        pc = (x - world_from_camera.translation) @ R
        Rt = R.T
    else:
        if R.shape[0] != n:
            raise ValueError(f"a batch of {R.shape[0]} poses for {n} points")
        pc = np.einsum("nji,nj->ni", R, x - world_from_camera.translation)
        Rt = np.swapaxes(R, -1, -2)
    pixels, d_pc, d_intr = project_camera_with_jacobians(camera, pc)
    out: dict[str, NDArray[np.float64]] = {}
    if "point_camera" in kinds:
        out["point_camera"] = d_pc
    if "point" in kinds or "pose" in kinds:
        d_x = d_pc @ Rt  # dP/dX = R^T
        if "point" in kinds:
            out["point"] = d_x
        if "pose" in kinds:
            d_pose = np.empty((n, 2, 6))
            d_pose[:, :, :3] = -d_x
            d_pose[:, :, 3:] = d_pc @ skew(pc)  # dP/dθ = [P]x
            out["pose"] = d_pose
    if "intrinsics" in kinds:
        out["intrinsics"] = d_intr
    return pixels, out
