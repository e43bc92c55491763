"""Multi-view triangulation of tie-point tracks and space resection of single images (layer 2b: arrays in, arrays out).

Rotations are ``world_from_camera`` ``(N, 3, 3)``, centres ``(N, 3)`` in one Cartesian world frame (metres),
pixels in skyrig's convention (origin at the centre of the top-left pixel, ``(N, 2)``).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from skyrig.camera.frame import FrameCamera
from skyrig.camera.opencv import OpenCVDistortion
from skyrig.geometry.rotations import rotvec_from_matrix

__all__ = ["triangulate_tracks", "resect"]

#: OpenCV camera frame (x right, y down, z forward) -> skyrig camera frame (x right, y up, z back)
_SKYRIG_FROM_CV = np.diag([1.0, -1.0, -1.0])


def _rays_world(camera: FrameCamera, R: NDArray, pixel: NDArray) -> NDArray[np.float64]:
    """``(N, 3)`` unit world rays for pixels ``(N, 2)`` seen by per-row rotations ``R`` ``(N, 3, 3)``."""
    d = camera.rays_from_pixels(pixel)
    return np.einsum("nij,nj->ni", R, d)


def _spread_ok(d: NDArray, track: NDArray, n_tracks: int, min_angle_deg: float) -> NDArray[np.bool_]:
    """``(T,)`` bool: track has >= 2 rays and its unit ray directions ``d`` ``(N, 3)`` span at least
    ``min_angle_deg`` (twice the widest angle of a ray from the tracks' mean direction)."""
    mean_d = np.zeros((n_tracks, 3))
    np.add.at(mean_d, track, d)
    mean_d /= np.maximum(np.linalg.norm(mean_d, axis=1, keepdims=True), 1e-12)
    min_cos = np.ones(n_tracks)
    np.minimum.at(min_cos, track, np.einsum("ni,ni->n", d, mean_d[track]))
    ang = 2.0 * np.degrees(np.arccos(np.clip(min_cos, -1, 1)))
    return (np.bincount(track, minlength=n_tracks) >= 2) & (ang >= min_angle_deg)


def _track_pairs(track: NDArray) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """All pairs ``(a, b)``, ``a < b``, of rows of one track, for ``(N,)`` track indices sorted ascending;
    returned in lexicographic order of ``(a, b)``."""
    start = np.r_[0, np.flatnonzero(np.diff(track)) + 1]
    cnt = np.diff(np.r_[start, len(track)])
    rows_a, rows_b = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
    for m in range(2, int(cnt.max(initial=0)) + 1):
        s = start[cnt == m]
        for a in range(m):
            for b in range(a + 1, m):
                rows_a.append(s + a)
                rows_b.append(s + b)
    ra, rb = np.concatenate(rows_a), np.concatenate(rows_b)
    order = np.lexsort((rb, ra))
    return ra[order], rb[order]


def triangulate_tracks(
    camera: FrameCamera, R: NDArray, C: NDArray, obs_track: NDArray, obs_image: NDArray, obs_pixel: NDArray,
    n_tracks: int, min_angle_deg: float = 1.0,
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Multi-view midpoint triangulation of tracks from oriented images (vectorised).

    Parameters
    ----------
    camera
        Camera of all images.
    R, C
        ``(I, 3, 3)`` ``world_from_camera`` and ``(I, 3)`` centres (metres); rows of unoriented images are
        ignored if no observation refers to them.
    obs_track, obs_image, obs_pixel
        ``(N,)``, ``(N,)``, ``(N, 2)`` observations (only those of oriented images).
    n_tracks
        T.
    min_angle_deg
        Minimum largest angle between two rays of a track.

    Returns
    -------
    xyz
        ``(T, 3)`` points (NaN where not determined).
    ok
        ``(T,)`` bool: >= 2 rays, intersection angle large enough, in front of every camera.
    """
    d = _rays_world(camera, R[obs_image], obs_pixel)
    P = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    A = np.zeros((n_tracks, 3, 3))
    b = np.zeros((n_tracks, 3))
    np.add.at(A, obs_track, P)
    np.add.at(b, obs_track, np.einsum("nij,nj->ni", P, C[obs_image]))
    ok = _spread_ok(d, obs_track, n_tracks, min_angle_deg)
    xyz = np.full((n_tracks, 3), np.nan)
    if ok.any():
        A_ok = A[ok] + 1e-12 * np.eye(3)
        xyz[ok] = np.linalg.solve(A_ok, b[ok][:, :, None])[:, :, 0]
    # in front of every camera (camera looks along -z)
    pc = np.einsum("nji,nj->ni", R[obs_image], np.nan_to_num(xyz[obs_track]) - C[obs_image])
    behind = np.zeros(n_tracks, bool)
    np.logical_or.at(behind, obs_track, pc[:, 2] >= 0)
    ok &= ~behind
    xyz[~ok] = np.nan
    return xyz, ok


def _reproject(camera: FrameCamera, R: NDArray, C: NDArray, X: NDArray) -> NDArray[np.float64]:
    pc = np.einsum("nji,nj->ni", R, X - C)
    with np.errstate(invalid="ignore", divide="ignore"):
        return camera.project_pixels(pc)


def _rotation_angle_deg(Ra: NDArray, Rb: NDArray) -> NDArray[np.float64]:
    """Angle of ``Ra^T Rb`` per row (deg)."""
    return np.degrees(np.linalg.norm(rotvec_from_matrix(np.swapaxes(Ra, -1, -2) @ Rb), axis=-1))


def _k_matrix(camera: FrameCamera) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """OpenCV camera matrix ``(3, 3)`` and distortion coefficients of ``camera`` (OpenCV pixel origin = skyrig's)."""
    f = camera.focal_px
    cx, cy = camera.principal_point_px
    dist = (np.asarray(camera.distortion.params, float) if isinstance(camera.distortion, OpenCVDistortion)
            else np.zeros(5))
    return np.array([[f, 0, cx], [0, f, cy], [0, 0, 1.0]]), dist


def resect(camera: FrameCamera, xyz: NDArray, pixel: NDArray, threshold_px: float, min_inliers: int,
           seed: int = 0) -> tuple[NDArray, NDArray, NDArray[np.bool_]] | None:
    """Space resection by ``cv2.solvePnPRansac`` (EPnP in RANSAC, then Levenberg-Marquardt on the inliers).

    Returns ``(world_from_camera (3, 3), centre (3,), inlier mask (N,))`` or None when fewer than
    ``min_inliers`` inliers support a pose.
    """
    import cv2

    if len(xyz) < max(min_inliers, 6):
        return None
    K, dist = _k_matrix(camera)
    cv2.setRNGSeed(seed)
    ok, rvec, tvec, inl = cv2.solvePnPRansac(
        np.ascontiguousarray(xyz, np.float64), np.ascontiguousarray(pixel, np.float64), K, dist,
        iterationsCount=2000, reprojectionError=float(threshold_px), confidence=0.999, flags=cv2.SOLVEPNP_EPNP)
    if not ok or inl is None or len(inl) < min_inliers:
        return None
    mask = np.zeros(len(xyz), bool)
    mask[inl[:, 0]] = True
    rvec, tvec = cv2.solvePnPRefineLM(np.ascontiguousarray(xyz[mask]), np.ascontiguousarray(pixel[mask]), K, dist,
                                      rvec, tvec)
    R_cv, _ = cv2.Rodrigues(rvec)
    R = R_cv.T @ _SKYRIG_FROM_CV
    C = -R_cv.T @ tvec[:, 0]
    # re-evaluate inliers with the refined pose
    px = _reproject(camera, np.broadcast_to(R, (len(xyz), 3, 3)), np.broadcast_to(C, (len(xyz), 3)), xyz)
    err = np.linalg.norm(px - pixel, axis=1)
    mask = np.nan_to_num(err, nan=np.inf) < threshold_px
    if mask.sum() < min_inliers:
        return None
    return R, C, mask
