"""GNSS-supported bundle adjustment of a UAV image block: ``skyrig match`` tie points + image metadata ->
adjusted exterior orientations, self-calibrated camera and a report.

Stages (:func:`adjust_uav_block` on arrays, :func:`adjust_uav` on a project folder)
-----------------------------------------------------------------------------------
1. **Metadata to a local ENU frame.**  EXIF GPS latitude / longitude / altitude of every image.  The
   altitude is taken as **orthometric above the EGM96 geoid** (DJI writes ``GPSAltitude`` =
   ``drone-dji:AbsoluteAltitude`` above mean sea level) and turned into a WGS84 ellipsoidal height with
   PROJ's EGM96 grid (``h = H + N``; :class:`skyrig.geodesy.crs.Geoid`), unless
   ``UavConfig.altitude == "ellipsoidal"``.  Geodetic -> ECEF -> local ENU at the block centre all go through
   PROJ / :class:`skyrig.geodesy.local.LocalTangentFrame` (:class:`skyrig.georef.eo.WorldFrame`).  DJI XMP
   gimbal yaw / pitch / roll give approximate ``world_from_camera`` rotations.
2. **Which attitudes to trust.**  The metadata attitudes are *checked, not trusted*: the tie points of
   every image are intersected with a horizontal plane at the take-off height (DJI ``RelativeAltitude``)
   using the metadata pose; two overlapping images *agree* when their common tie points land within
   ``agree_fraction`` x flying height of each other (median).  A yaw wrong by 180 deg moves the points by
   twice the base and more.  The largest connected set of agreeing images is the seed.
3. **Growing the block.**  Tie points seen by >= 2 oriented images are triangulated (multi-view midpoint,
   depth and intersection-angle checks), the oriented images are bundle adjusted with GNSS, and every
   remaining image is oriented by space resection (``cv2.solvePnPRansac``) on the triangulated points;
   repeat until no image is left or none can be added.  The attitude found by resection is compared with
   the metadata (a 180 deg yaw error is reported, not silently used).  Without any usable attitude metadata
   (phones), or for a part of the block the tie points do not connect to the rest, the seed is a two-view
   relative orientation (essential matrix), grown by resection in its own frame and then put onto the GNSS
   positions by a similarity transform; GNSS positions that lie on a line leave the roll about that line
   undetermined, which is reported (:class:`UavAdjustError`), not guessed.
4. **Final adjustment.**  GNSS positions (antenna = projection centre, no lever arm known) with a consumer
   GPS sigma (default 2 m horizontal, 4 m vertical), verified gimbal attitudes as weak observations
   (default 5 deg), image observations with Huber weights, self-calibration of focal length (EXIF focal as a
   weighted prior), principal point and OpenCV distortion k1 k2 p1 p2 k3; then residuals above
   ``reject_k`` x robust RMS are removed and the block re-adjusted with full statistics.

   Options (defaults keep the behaviour above): ``focal="exif"`` fixes the focal length at its EXIF value;
   ``focal="auto"`` self-calibrates it but fixes it at EXIF when its formal sigma is not below
   ``focal_determinable`` x the prior sigma (the decision is reported in words in ``summary["focal"]``);
   ``gnss_strip_shift="weighted"`` estimates a GNSS shift per flight strip (:func:`detect_strips`).  On brighton
   (1600-px ties) none of them, nor dropping the attitude prior, changes the 1 m misfit of strip DJI_0018-0023
   (see ``bench/uav.py --variants``), so they stay off by default.

Everything is in the local ENU frame (metres); pixels follow skyrig's convention (origin at the centre of
the top-left pixel).
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal, Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from skyrig.adjust import AdjustConfig, AdjustmentResult, Block, adjust
from skyrig.camera.frame import FrameCamera
from skyrig.camera.opencv import OpenCVDistortion
from skyrig.errors import GeometryError, InputFormatError, SkyrigError
from skyrig.geometry.rotations import rotvec_from_matrix

logger = logging.getLogger(__name__)

__all__ = ["UavConfig", "UavBlockInput", "UavResult", "metadata_block_input", "adjust_uav_block", "adjust_uav",
           "compare_with_reconstruction", "triangulate_tracks", "detect_strips"]

#: OpenCV camera frame (x right, y down, z forward) -> skyrig camera frame (x right, y up, z back)
_SKYRIG_FROM_CV = np.diag([1.0, -1.0, -1.0])


class UavAdjustError(SkyrigError, ValueError):
    """The UAV block cannot be oriented (no seed, too few tie points...); the message says why."""


@dataclass(frozen=True)
class UavConfig:
    """Settings of the UAV GNSS-supported adjustment (frozen; unknown keys are an error)."""

    #: EXIF altitude reference: "egm96" (orthometric, DJI) or "ellipsoidal" (WGS84 h)
    altitude: Literal["egm96", "ellipsoidal"] = "egm96"
    #: geoid grid (path or PROJ name) for altitude "egm96"; None: $SKYRIG_GEOID, ../shared/data/geoid, PROJ's
    geoid: str | None = None
    #: GNSS sigma (east, north, up) in metres: consumer single-frequency GPS + barometric height
    gnss_sigma_m: tuple[float, float, float] = (2.0, 2.0, 4.0)
    #: sigma of verified gimbal attitudes used as observations (deg); None: attitudes not observed
    attitude_sigma_deg: float | None = 5.0
    #: a-priori sigma of a tie-point measurement (px, full resolution)
    pixel_sigma_px: float = 1.0
    #: relative sigma of the EXIF focal length prior (0.1 = 10 %)
    focal_prior_rel: float = 0.1
    #: self-calibrated intrinsics (FrameCamera + OpenCV distortion names)
    self_calibration: tuple[str, ...] = ("focal_mm", "ppx_mm", "ppy_mm", "k1", "k2", "p1", "p2", "k3")
    #: two images agree when their common tie points on the ground plane differ by < this x flying height
    agree_fraction: float = 0.15
    #: a resected image whose metadata attitude differs more than this (deg) is reported as rejected
    max_attitude_error_deg: float = 15.0
    #: common tie points needed to compare two images
    min_common: int = 20
    #: resection: RANSAC threshold (px) and minimum inliers
    pnp_threshold_px: float = 8.0
    pnp_min_inliers: int = 20
    #: minimum intersection angle of a triangulated tie point (deg); small enough for forward motion (a walk:
    #: lund 24 -> 29 of 29 images oriented going from 1.0 to 0.3 deg)
    min_angle_deg: float = 0.3
    #: Huber threshold (units of pixel_sigma_px)
    robust_k: float = 2.0
    #: after the robust adjustment remove observations whose residual exceeds reject_k x robust RMS (>= reject_min_px)
    reject_k: float = 4.0
    reject_min_px: float = 2.0
    #: Levenberg-Marquardt iterations per adjustment
    max_iterations: int = 40
    #: per-strip GNSS shift (strips found from the flight path, see :func:`detect_strips`): "off", or "weighted"
    #: (a shift per strip with prior sigma ``strip_shift_sigma_m``; absorbs a GPS height/position offset per strip)
    gnss_strip_shift: Literal["off", "weighted"] = "off"
    strip_shift_sigma_m: float = 1.0
    #: focal length: "self" (self-calibrated with the EXIF prior), "exif" (fixed at the EXIF value) or "auto"
    #: (self-calibrated, but fixed at the EXIF value when the block cannot determine it: posterior sigma above
    #: ``focal_determinable`` x the prior sigma, e.g. a flat nadir block flown at one height)
    focal: Literal["self", "exif", "auto"] = "self"
    focal_determinable: float = 0.5

    @classmethod
    def from_dict(cls, data: dict, source: str = "config") -> "UavConfig":
        bad = sorted(set(data) - set(cls.__dataclass_fields__))
        if bad:
            raise ValueError(f"{source}: unknown UAV adjustment option(s) {bad}; "
                             f"known: {sorted(cls.__dataclass_fields__)}")
        d = dict(data)
        for k in ("gnss_sigma_m", "self_calibration"):
            if k in d and d[k] is not None:
                d[k] = tuple(d[k])
        return cls(**d)


@dataclass
class UavBlockInput:
    """What the adjustment needs, in the local ENU frame.

    Attributes
    ----------
    names
        ``(I,)`` image names.
    camera
        Starting camera (EXIF focal length, principal point at the centre, OpenCV distortion zero).
    gnss
        ``(I, 3)`` GNSS positions in the local frame, metres.
    rotation
        ``(I, 3, 3)`` metadata ``world_from_camera`` (NaN where unknown).
    ground_height
        Approximate terrain height in the local frame (m), or None.
    obs_track, obs_image, obs_pixel
        Tie-point observations ``(N,)`` track index, ``(N,)`` image index, ``(N, 2)`` pixels.
    track_name
        ``(T,)`` names of the tie points.
    frame
        :class:`skyrig.georef.eo.WorldFrame` of the local coordinates (or None).
    notes
        What was assumed while reading (height reference...).
    """

    names: NDArray[np.str_]
    camera: FrameCamera
    gnss: NDArray[np.float64]
    rotation: NDArray[np.float64]
    ground_height: float | None
    obs_track: NDArray[np.int64]
    obs_image: NDArray[np.int64]
    obs_pixel: NDArray[np.float64]
    track_name: NDArray[np.str_]
    frame: Any = None
    notes: list[str] = field(default_factory=list)


@dataclass
class UavResult:
    """Result of :func:`adjust_uav_block`.

    Attributes
    ----------
    names
        ``(I,)`` image names (input order).
    oriented
        ``(I,)`` bool: image oriented by the adjustment.
    rotation, centre
        ``(I, 3, 3)`` adjusted ``world_from_camera`` and ``(I, 3)`` projection centres (NaN if not oriented).
    camera
        Self-calibrated camera.
    adjustment
        The final :class:`~skyrig.adjust.AdjustmentResult` (its block holds the oriented images only).
    block_image
        ``(I_oriented,)`` index into ``names`` of every image of the adjusted block.
    attitude_check
        Per image: how its metadata attitude was judged ("seed", "resected", "none") and the angle between
        metadata and adjusted attitude (deg).
    summary
        Figures for the report (tie points per image, reprojection RMS, GNSS fit...).
    """

    names: NDArray[np.str_]
    oriented: NDArray[np.bool_]
    rotation: NDArray[np.float64]
    centre: NDArray[np.float64]
    camera: FrameCamera
    adjustment: AdjustmentResult
    block_image: NDArray[np.int64]
    attitude_check: dict[str, dict[str, Any]]
    summary: dict[str, Any]


# ---------------------------------------------------------------------------------------------- geometry
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


# ---------------------------------------------------------------------------------------------- seed
def attitude_agreement(inp: UavBlockInput, cfg: UavConfig) -> tuple[NDArray[np.bool_], NDArray[np.float64]]:
    """Which pairs of images agree under their metadata poses (tie points on the ground plane).

    Returns
    -------
    agree
        ``(I, I)`` bool.
    disagreement
        ``(I, I)`` median ground distance of common tie points (m; NaN: not compared).
    """
    n = len(inp.names)
    agree = np.zeros((n, n), bool)
    dis = np.full((n, n), np.nan)
    have = np.isfinite(inp.rotation.reshape(n, -1)).all(axis=1)
    if inp.ground_height is None or have.sum() < 2:
        return agree, dis
    g = inp.ground_height
    sel = have[inp.obs_image]
    ti, ii, px = inp.obs_track[sel], inp.obs_image[sel], inp.obs_pixel[sel]
    d = _rays_world(inp.camera, inp.rotation[ii], px)
    C = inp.gnss[ii]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (g - C[:, 2]) / d[:, 2]
    good = np.isfinite(t) & (t > 0)
    ground = (C + t[:, None] * d)[:, :2]
    ti, ii, ground = ti[good], ii[good], ground[good]
    height = float(np.median(inp.gnss[have, 2]) - g)
    thr = cfg.agree_fraction * max(height, 1.0)
    order = np.lexsort((ii, ti))
    ti, ii, ground = ti[order], ii[order], ground[order]
    ra, rb = _track_pairs(ti)  # all observation pairs within a track
    if not len(ra):
        return agree, dis
    dist = np.linalg.norm(ground[ra] - ground[rb], axis=1)
    key = ii[ra] * n + ii[rb]
    order = np.argsort(key, kind="stable")
    key, dist = key[order], dist[order]
    uk, first, counts = np.unique(key, return_index=True, return_counts=True)
    for k, f0, c in zip(uk, first, counts):
        if c < cfg.min_common:
            continue
        med = float(np.median(dist[f0:f0 + c]))
        i, j = divmod(int(k), n)
        dis[i, j] = dis[j, i] = med
        agree[i, j] = agree[j, i] = med < thr
    return agree, dis


def _largest_component(agree: NDArray[np.bool_]) -> NDArray[np.int64]:
    n = len(agree)
    if not agree.any():
        return np.zeros(0, np.int64)
    nc, lab = connected_components(coo_matrix(agree.astype(np.int8)), directed=False)
    sizes = np.bincount(lab, weights=agree.any(axis=1).astype(float), minlength=nc)
    best = int(np.argmax(sizes))
    members = np.flatnonzero((lab == best) & agree.any(axis=1))
    return members if len(members) >= 2 else np.zeros(0, np.int64)


def _two_view_seed(inp: UavBlockInput, cfg: UavConfig, allowed: NDArray[np.bool_] | None = None,
                   need_gnss_base: bool = True) -> tuple[NDArray[np.int64], NDArray, NDArray]:
    """Seed without attitude metadata: essential matrix of the best-connected pair with a long enough GNSS
    base; relative rotation, base direction from the images and base length from GNSS.  The frame is provisional
    (the rotation about the base is arbitrary); :func:`_seed_component` replaces it by a similarity onto GNSS.
    With ``need_gnss_base=False`` (the part will be tied to an oriented block through common points, which
    fix the scale) a pair with (nearly) equal GNSS positions may start it, with a nominal base of 1 m."""
    import cv2

    n = len(inp.names)
    K, dist = _k_matrix(inp.camera)
    best = None
    # image pairs by common tie points, most first (ties: first met in (track, image) order)
    order = np.lexsort((inp.obs_image, inp.obs_track))
    im = inp.obs_image[order]
    ra, rb = _track_pairs(inp.obs_track[order])
    key = im[ra] * n + im[rb]
    uk, first, counts = np.unique(key, return_index=True, return_counts=True)
    rank = np.lexsort((first, -counts))
    tried = 0
    for k, c in zip(uk[rank].tolist(), counts[rank].tolist()):
        i, j = divmod(k, n)
        if allowed is not None and not (allowed[i] and allowed[j]):
            continue
        base = float(np.linalg.norm(inp.gnss[i] - inp.gnss[j]))
        if c < 50 or (base < 1.0 and need_gnss_base):
            continue
        if base < 1.0:
            base = 1.0
        mi, mj = inp.obs_image == i, inp.obs_image == j
        _, ci, cj = np.intersect1d(inp.obs_track[mi], inp.obs_track[mj], return_indices=True)
        p1 = cv2.undistortPoints(inp.obs_pixel[mi][ci][:, None], K, dist)[:, 0]
        p2 = cv2.undistortPoints(inp.obs_pixel[mj][cj][:, None], K, dist)[:, 0]
        E, mask = cv2.findEssentialMat(p1, p2, np.eye(3), cv2.RANSAC, 0.999, cfg.pnp_threshold_px / K[0, 0])
        if E is None or E.shape != (3, 3):
            continue
        nin, R21, t21, mask = cv2.recoverPose(E, p1, p2, np.eye(3), mask=mask)
        if nin < cfg.pnp_min_inliers:
            continue
        # a seed needs parallax: rays of a (near) pure rotation pair stay parallel once rotated
        inl = mask.ravel() > 0
        r1 = np.column_stack([p1[inl], np.ones(int(inl.sum()))])
        r2 = np.column_stack([p2[inl], np.ones(int(inl.sum()))]) @ R21  # R21^T x2, row-wise
        cosang = np.sum(r1 * r2, axis=1) / (np.linalg.norm(r1, axis=1) * np.linalg.norm(r2, axis=1))
        score = int(np.sum(cosang < np.cos(np.radians(2.0 * cfg.min_angle_deg))))
        if score < cfg.pnp_min_inliers:
            continue
        if best is None or score > best[5]:
            best = (i, j, R21, t21[:, 0], base, score)
        tried += 1
        if tried >= 12:  # the best-connected candidates; the one with most parallax wins
            break
    if best is None:
        raise UavAdjustError("no image pair with enough matches and GNSS base to start the block")
    i, j, R21, t21, base, _ = best
    # camera 1 (cv) at origin; camera 2: x2 = R21 x1 + t21  -> centre2 = -R21^T t21 (unit), scaled by base
    c2_cv1 = -R21.T @ t21 * base
    # world from cv1: align the base with the GNSS base; roll about the base: image "up" (-y_cv) to world up
    g_base = inp.gnss[j] - inp.gnss[i]
    u = c2_cv1 / np.linalg.norm(c2_cv1)
    w = g_base / np.linalg.norm(g_base) if np.linalg.norm(g_base) > 1e-6 else np.array([1.0, 0.0, 0.0])
    up_cam = np.array([0.0, -1.0, 0.0])
    up_world = np.array([0.0, 0.0, 1.0])

    def frame(a: NDArray, b: NDArray) -> NDArray:
        e1 = a
        e2 = b - a * (a @ b)
        e2 = e2 / max(np.linalg.norm(e2), 1e-12)
        return np.column_stack([e1, e2, np.cross(e1, e2)])

    world_from_cv1 = frame(w, up_world) @ frame(u, up_cam).T
    R = np.full((n, 3, 3), np.nan)
    C = np.full((n, 3), np.nan)
    R[i] = world_from_cv1 @ _SKYRIG_FROM_CV
    C[i] = inp.gnss[i]
    R[j] = world_from_cv1 @ R21.T @ _SKYRIG_FROM_CV
    C[j] = inp.gnss[i] + world_from_cv1 @ c2_cv1
    return np.array([i, j]), R, C


# ---------------------------------------------------------------------------------------------- adjustment
def _build_block(inp: UavBlockInput, camera: FrameCamera, R: NDArray, C: NDArray, X: NDArray,
                 img_sel: NDArray[np.int64], obs_sel: NDArray[np.bool_], cfg: UavConfig, sigma_px: float,
                 imu_images: NDArray[np.int64], strip: NDArray[np.int64] | None = None
                 ) -> tuple[Block, NDArray[np.int64], NDArray[np.int64]]:
    n = len(inp.names)
    img_map = np.full(n, -1)
    img_map[img_sel] = np.arange(len(img_sel))
    ot, oi, op = inp.obs_track[obs_sel], inp.obs_image[obs_sel], inp.obs_pixel[obs_sel]
    tracks, tmap = np.unique(ot, return_inverse=True)
    names = inp.names[img_sel]
    imu = np.array([img_map[k] for k in imu_images if img_map[k] >= 0], np.int64)
    block = Block(
        cameras=[camera], station_name=names, station_rotation=R[img_sel], station_centre=C[img_sel],
        image_name=names, image_station=np.arange(len(img_sel)), image_camera=np.zeros(len(img_sel), np.int64),
        point_name=inp.track_name[tracks], point_xyz=X[tracks], obs_image=img_map[oi], obs_point=tmap,
        obs_pixel=op, obs_sigma_px=sigma_px,
        gnss_station=np.arange(len(img_sel)), gnss_xyz=inp.gnss[img_sel],
        gnss_sigma=np.broadcast_to(np.asarray(cfg.gnss_sigma_m, float), (len(img_sel), 3)),
        imu_station=imu if cfg.attitude_sigma_deg else None,
        imu_rotation=inp.rotation[img_sel[imu]] if cfg.attitude_sigma_deg else None,
        imu_sigma_rad=np.radians(cfg.attitude_sigma_deg or 1.0),
        frame=inp.frame.describe() if inp.frame is not None else "local ENU",
        station_strip=None if strip is None else _renumber_strips(strip[img_sel]),
    )
    return block, tracks, np.flatnonzero(obs_sel)


def _renumber_strips(strip: NDArray[np.int64]) -> NDArray[np.int64]:
    """Strip labels of a subset renumbered 0..T-1 (-1 kept)."""
    out = np.full(len(strip), -1, np.int64)
    ok = strip >= 0
    if ok.any():
        out[ok] = np.unique(strip[ok], return_inverse=True)[1]
    return out


def detect_strips(gnss: NDArray, max_turn_deg: float = 45.0, min_images: int = 3) -> NDArray[np.int64]:
    """Flight strips from GNSS positions in capture order.

    A strip is a run of consecutive images whose horizontal displacement keeps its direction (within
    ``max_turn_deg`` of the strip's first leg).

    Parameters
    ----------
    gnss
        ``(I, 3)`` positions (m) in capture order.
    max_turn_deg
        Direction change that starts a new strip (deg).
    min_images
        Runs shorter than this get no strip.

    Returns
    -------
    ``(I,)`` strip index per image (0..T-1), -1 for images in no strip.
    """
    g = np.asarray(gnss, float)
    n = len(g)
    lab = np.full(n, -1, np.int64)
    if n < 2:
        return lab
    leg = np.diff(g[:, :2], axis=0)
    ang = np.arctan2(leg[:, 1], leg[:, 0])
    start, k = 0, 0
    runs = []
    ref = ang[0]
    for j in range(1, n - 1):  # leg j joins image j and j+1
        d = np.degrees(abs((ang[j] - ref + np.pi) % (2 * np.pi) - np.pi))
        if d > max_turn_deg:
            runs.append((start, j + 1))  # images start..j
            start, ref = j + 1, ang[j + 1] if j + 1 < n - 1 else ang[j]
    runs.append((start, n))
    for a, b in runs:
        if b - a >= min_images:
            lab[a:b] = k
            k += 1
    return lab


def _usable_obs(inp: UavBlockInput, oriented: NDArray[np.bool_], X: NDArray, active: NDArray[np.bool_],
                camera: FrameCamera, R: NDArray, C: NDArray, min_angle_deg: float,
                max_px: float = np.inf) -> NDArray[np.bool_]:
    """Observations that can enter an adjustment: oriented image, active, point finite and in front of the
    camera, reprojecting within ``max_px``, and every point left with >= 2 such rays spanning at least
    ``min_angle_deg``."""
    T = len(inp.track_name)
    X_ok = np.isfinite(X).all(axis=1)
    sel = oriented[inp.obs_image] & X_ok[inp.obs_track] & active
    rows = np.flatnonzero(sel)
    ti, ii = inp.obs_track[rows], inp.obs_image[rows]
    v = X[ti] - C[ii]
    pc = np.einsum("nji,nj->ni", R[ii], v)
    front = pc[:, 2] < -1e-3 * np.linalg.norm(v, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        err = np.linalg.norm(camera.project_pixels(pc) - inp.obs_pixel[rows], axis=1)
    front &= np.nan_to_num(err, nan=np.inf) < max_px
    rows, ti, v = rows[front], ti[front], v[front]
    good_t = _spread_ok(v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12), ti, T, min_angle_deg)
    out = np.zeros(len(inp.obs_track), bool)
    out[rows[good_t[ti]]] = True
    return out


def _image_residuals(b: Block) -> NDArray[np.float64]:
    """``(N, 2)`` reprojection residuals (px, computed minus observed) of a block at its current values, without
    any robust weighting."""
    cam = b.cameras[0]
    R = b.station_rotation[b.image_station[b.obs_image]] @ b.image_rotation[b.obs_image]
    C = b.station_centre[b.image_station[b.obs_image]]
    return _reproject(cam, R, C, b.point_xyz[b.obs_point]) - b.obs_pixel


def _resect_all(inp: UavBlockInput, camera: FrameCamera, X: NDArray, R: NDArray, C: NDArray,
                oriented: NDArray[np.bool_], active: NDArray[np.bool_], cfg: UavConfig,
                check: dict[str, dict[str, Any]]) -> list[int]:
    """Space resection of every unoriented image on the triangulated points ``X``; updates ``R``, ``C``,
    ``oriented``, ``active`` (outlier observations) and ``check`` in place; returns the added images."""
    X_ok = np.isfinite(X).all(axis=1)
    added = []
    for k in np.flatnonzero(~oriented):
        m = (inp.obs_image == k) & X_ok[inp.obs_track] & active
        if m.sum() < cfg.pnp_min_inliers:
            logger.debug("resection of %s: only %d triangulated points", inp.names[k], int(m.sum()))
            continue
        out = resect(camera, X[inp.obs_track[m]], inp.obs_pixel[m], cfg.pnp_threshold_px, cfg.pnp_min_inliers)
        if out is None:
            logger.debug("resection of %s failed on %d triangulated points", inp.names[k], int(m.sum()))
            continue
        Rk, Ck, inl = out
        R[k], C[k] = Rk, Ck
        oriented[k] = True
        rows_k = np.flatnonzero(m)
        active[rows_k[~inl]] = False
        added.append(int(k))
        info = check[str(inp.names[k])]
        if np.isfinite(inp.rotation[k]).all():
            dev = float(_rotation_angle_deg(inp.rotation[k], Rk))
            info["metadata_vs_resection_deg"] = dev
            info["metadata"] = ("rejected: disagrees with tie points; oriented by resection"
                                if dev > cfg.max_attitude_error_deg
                                else "not in the seed; oriented by resection, metadata consistent")
        else:
            info["metadata"] = "no attitude; oriented by resection"
        info["resection_inliers"] = int(inl.sum())
    return added


_MIN_COMMON = 12


def _robust_similarity(src: NDArray[np.float64], dst: NDArray[np.float64]
                       ) -> tuple[float, NDArray[np.float64], NDArray[np.float64], int] | None:
    """Similarity ``dst ~ s R src + t`` with iterative trimming (points farther than 3 x 1.4826 x the median
    distance leave); None if fewer than ``_MIN_COMMON`` points survive or the fit stays poor (inlier residual median above 5 % of the spread)."""
    from skyrig.match.colmap_check import similarity_transform

    keep = np.ones(len(src), bool)
    for _ in range(10):
        if keep.sum() < _MIN_COMMON:
            return None
        sc, Rs, ts = similarity_transform(src[keep], dst[keep])
        res = np.linalg.norm(sc * src @ Rs.T + ts - dst, axis=1)
        thr = 3.0 * 1.4826 * float(np.median(res[keep])) + 1e-9
        new = res <= thr
        if np.array_equal(new, keep):
            break
        keep = new
    spread = float(np.sqrt(np.mean(np.sum((dst[keep] - dst[keep].mean(axis=0)) ** 2, axis=1))))
    if keep.sum() < _MIN_COMMON or not float(np.median(res[keep])) < 0.05 * spread:
        return None
    return float(sc), Rs, ts, int(keep.sum())


def _seed_component(inp: UavBlockInput, cfg: UavConfig, camera: FrameCamera, allowed: NDArray[np.bool_],
                    active: NDArray[np.bool_], check: dict[str, dict[str, Any]],
                    anchor_X: NDArray[np.float64] | None = None,
                    ) -> tuple[NDArray, NDArray, NDArray[np.bool_]]:
    """Orient a connected part of the block among ``allowed`` images without attitude metadata: two-view seed,
    growth by resection in the seed's frame, then a similarity onto the already oriented block through the
    tie points both have triangulated (``anchor_X``, ``(T, 3)``, NaN where not triangulated; at least
    ``_MIN_COMMON`` common points, robust fit), or else onto the GNSS positions.

    Returns ``R (I, 3, 3)``, ``C (I, 3)`` (NaN outside the part) and the ``(I,)`` mask of the part (all False
    when no part of >= 3 images with non-collinear GNSS positions could be made).
    """
    n, T = len(inp.names), len(inp.track_name)
    none = (np.full((n, 3, 3), np.nan), np.full((n, 3), np.nan), np.zeros(n, bool))
    try:
        seed, R, C = _two_view_seed(inp, cfg, allowed, need_gnss_base=anchor_X is None)
    except UavAdjustError as exc:
        logger.info("no two-view seed among the %d remaining images: %s", int(allowed.sum()), exc)
        return none
    part = np.zeros(n, bool)
    part[seed] = True
    # images outside `allowed` are marked as oriented so that resection does not touch them
    blocked = part | ~allowed
    act = active.copy()
    sub_check = {k: dict(v) for k, v in check.items()}
    while True:
        sel = part[inp.obs_image] & act
        X, ok = triangulate_tracks(camera, np.nan_to_num(R), np.nan_to_num(C), inp.obs_track[sel],
                                   inp.obs_image[sel], inp.obs_pixel[sel], T, cfg.min_angle_deg)
        before = blocked.copy()
        added = _resect_all(inp, camera, X, R, C, blocked, act, cfg, sub_check)
        part |= blocked & ~before
        if not added:
            break
    idx = np.flatnonzero(part)
    from skyrig.match.colmap_check import similarity_transform

    if anchor_X is not None and len(idx) >= 2:
        sel = part[inp.obs_image] & act
        Xp, okp = triangulate_tracks(camera, np.nan_to_num(R), np.nan_to_num(C), inp.obs_track[sel],
                                     inp.obs_image[sel], inp.obs_pixel[sel], T, cfg.min_angle_deg)
        common = np.flatnonzero(okp & np.isfinite(anchor_X).all(axis=1) & np.isfinite(Xp).all(axis=1))
        fit = _robust_similarity(Xp[common], anchor_X[common]) if len(common) >= _MIN_COMMON else None
        if fit is None:
            logger.info("part of %d images: %d tie points in common with the oriented block, no robust similarity",
                        len(idx), len(common))
        if fit is not None:
            sc, Rs, ts, n_in = fit
            C[idx] = sc * C[idx] @ Rs.T + ts
            R[idx] = Rs @ R[idx]
            for k in idx:
                check[str(inp.names[k])].update(sub_check[str(inp.names[k])])
                check[str(inp.names[k])]["seeded"] = (f"two-view seed + resection, similarity onto the oriented "
                                                      f"block through {n_in} common tie points")
            logger.info("two-view seed grown to %d images, tied to the oriented block through %d of %d common "
                        "tie points (scale %.3f)", len(idx), n_in, len(common), sc)
            return R, C, part
    if len(idx) < 3:
        return none
    G = inp.gnss[idx] - inp.gnss[idx].mean(axis=0)
    sv = np.linalg.svd(G, compute_uv=False)
    if sv[1] < 0.05 * sv[0]:
        logger.warning("%d images oriented from a two-view seed, but their GNSS positions are (nearly) collinear and "
                       "no attitude metadata is usable: the rotation about the line cannot be determined", len(idx))
        return none
    sc, Rs, ts = similarity_transform(C[idx], inp.gnss[idx])
    C[idx] = sc * C[idx] @ Rs.T + ts
    R[idx] = Rs @ R[idx]
    for k in idx:
        check[str(inp.names[k])].update(sub_check[str(inp.names[k])])
        check[str(inp.names[k])]["seeded"] = "two-view seed + resection, similarity onto GNSS"
    logger.info("two-view seed grown to %d images, aligned to GNSS (scale %.3f)", len(idx), sc)
    return R, C, part


def adjust_uav_block(inp: UavBlockInput, cfg: UavConfig = UavConfig()) -> UavResult:
    """Orient a UAV block from tie points, GNSS and (checked) attitude metadata; see the module docstring.

    Raises
    ------
    UavAdjustError
        No seed (no agreeing images and no pair for a relative orientation), or fewer than three oriented
        images.
    """
    t_start = time.perf_counter()
    n, T = len(inp.names), len(inp.track_name)
    camera = inp.camera
    if not isinstance(camera.distortion, OpenCVDistortion):
        camera = camera.with_(distortion=OpenCVDistortion())
    active = np.ones(len(inp.obs_track), bool)
    agree, dis = attitude_agreement(inp, cfg)
    seed = _largest_component(agree)
    R = np.full((n, 3, 3), np.nan)
    C = np.full((n, 3), np.nan)
    check: dict[str, dict[str, Any]] = {str(nm): {"metadata": "unknown"} for nm in inp.names}
    if len(seed) >= 2:
        R[seed] = inp.rotation[seed]
        C[seed] = inp.gnss[seed]
        trusted_att = seed.copy()
        for k in seed:
            check[str(inp.names[k])]["metadata"] = "agrees with tie points (seed)"
        logger.info("seed: %d images whose metadata attitudes agree with their tie points", len(seed))
    else:
        trusted_att = np.zeros(0, np.int64)
    oriented = np.zeros(n, bool)
    oriented[seed] = True
    if len(trusted_att) == 0:
        R, C, oriented = _seed_component(inp, cfg, camera, ~oriented, active, check)
        if oriented.sum() < 3:
            raise UavAdjustError("no image pair could start the block (no agreeing attitude metadata, no two-view "
                                 "relative orientation with enough GNSS base)")
    sigma_px = max(3.0 * cfg.pixel_sigma_px, 3.0)
    grow_cfg = AdjustConfig(robust="huber", robust_k=cfg.robust_k, statistics=False,
                            max_iterations=cfg.max_iterations, datum="auto")
    X = np.full((T, 3), np.nan)
    rounds = 0
    while True:
        rounds += 1
        sel = oriented[inp.obs_image] & active
        X, ok = triangulate_tracks(camera, np.nan_to_num(R), np.nan_to_num(C), inp.obs_track[sel], inp.obs_image[sel],
                                   inp.obs_pixel[sel], T, cfg.min_angle_deg)
        X[~ok] = np.nan
        gate = 0.05 * max(camera.width, camera.height) if rounds == 1 else 4.0 * cfg.pnp_threshold_px
        obs_sel = _usable_obs(inp, oriented, X, active, camera, R, C, cfg.min_angle_deg, gate)
        img_sel = np.flatnonzero(oriented)
        block, tracks, rows = _build_block(inp, camera, R, C, X, img_sel, obs_sel, cfg, sigma_px,
                                           np.intersect1d(trusted_att, img_sel))
        try:
            res = adjust(block, grow_cfg)
        except SkyrigError as exc:
            raise UavAdjustError(f"adjustment of the {len(img_sel)} oriented images failed: {exc}") from exc
        R[img_sel] = res.block.station_rotation
        C[img_sel] = res.block.station_centre
        X[:] = np.nan
        X[tracks] = res.block.point_xyz
        # drop gross outliers of this round
        r = np.nan_to_num(np.linalg.norm(_image_residuals(res.block), axis=1), nan=np.inf)
        med = float(np.median(r)) if len(r) else 0.0
        bad = r > max(8.0 * 1.4826 * med, 3.0 * cfg.reject_min_px)
        active[rows[bad]] = False
        logger.info("round %d: %d images, %d points, median residual %.2f px, %d observations removed", rounds,
                    len(img_sel), block.n_points, med, int(bad.sum()))
        todo = np.flatnonzero(~oriented)
        if len(todo) == 0:
            break
        added = _resect_all(inp, camera, X, R, C, oriented, active, cfg, check)
        if not added:
            # a part of the block not connected by enough tie points: its own seed, tied in by GNSS
            R2, C2, part = _seed_component(inp, cfg, camera, ~oriented, active, check, anchor_X=X)
            if not part.any():
                break
            R[part], C[part] = R2[part], C2[part]
            oriented |= part
            added = [int(k) for k in np.flatnonzero(part)]
        logger.info("added %d images (resection, or a new seed for a part not tied to the rest): %s", len(added),
                    ", ".join(inp.names[added]))
    if oriented.sum() < 3:
        raise UavAdjustError(f"only {int(oriented.sum())} images could be oriented")
    # ---- final adjustment: self-calibration, Huber, outlier removal, statistics
    f0 = inp.camera.focal_mm
    w_mm = camera.width * camera.pixel_size_mm
    sig = {"focal_mm": cfg.focal_prior_rel * f0, "ppx_mm": 0.05 * w_mm, "ppy_mm": 0.05 * w_mm,
           "k1": 1.0, "k2": 1.0, "k3": 1.0, "p1": 0.1, "p2": 0.1}
    names_cal = tuple(nm for nm in camera.intrinsic_names if nm in cfg.self_calibration
                      and not (nm == "focal_mm" and cfg.focal == "exif"))

    def cal_cfg(names: tuple[str, ...]) -> AdjustConfig:
        return AdjustConfig(intrinsics="weighted" if names else "fixed", intrinsic_names=names or None,
                            intrinsic_sigma=tuple((k, v) for k, v in sig.items() if k in names),
                            robust="huber", robust_k=cfg.robust_k, statistics=False,
                            max_iterations=cfg.max_iterations,
                            strip_shift="weighted" if cfg.gnss_strip_shift == "weighted" else "fixed",
                            strip_shift_sigma_m=cfg.strip_shift_sigma_m)

    final_cfg = cal_cfg(names_cal)
    strip = detect_strips(inp.gnss) if cfg.gnss_strip_shift != "off" else None
    img_sel = np.flatnonzero(oriented)
    imu_imgs = np.intersect1d(trusted_att, img_sel)
    for stage in range(2):
        sel = oriented[inp.obs_image] & active
        X2, ok = triangulate_tracks(camera, np.nan_to_num(R), np.nan_to_num(C), inp.obs_track[sel],
                                    inp.obs_image[sel], inp.obs_pixel[sel], T, cfg.min_angle_deg)
        keep_old = np.isfinite(X).all(axis=1)
        X = np.where(keep_old[:, None], X, X2)
        obs_sel = _usable_obs(inp, oriented, X, active, camera, R, C, cfg.min_angle_deg, 2.0 * cfg.pnp_threshold_px)
        # the focal prior is anchored at the EXIF value in every stage (the prior of a "weighted" group is its
        # starting value)
        block, tracks, rows = _build_block(inp, camera.with_(focal_mm=f0), R, C, X, img_sel, obs_sel, cfg,
                                           cfg.pixel_sigma_px, imu_imgs, strip)
        res = adjust(block, final_cfg)
        camera = res.block.cameras[0]
        R[img_sel] = res.block.station_rotation
        C[img_sel] = res.block.station_centre
        X[:] = np.nan
        X[tracks] = res.block.point_xyz
        r = np.nan_to_num(np.linalg.norm(_image_residuals(res.block), axis=1), nan=np.inf)
        robust_rms = float(np.median(r)) / np.sqrt(np.log(4.0))  # Rayleigh median = sigma sqrt(ln 4)
        lim = max(cfg.reject_k * robust_rms * np.sqrt(2.0), cfg.reject_min_px)
        bad = r > lim
        active[rows[bad]] = False
        logger.info("final stage %d: sigma per axis %.3f px (robust), %d observations above %.2f px removed", stage,
                    robust_rms, int(bad.sum()), lim)
    # last run: plain least squares on the cleaned observations, with statistics
    obs_sel = _usable_obs(inp, oriented, X, active, camera, R, C, cfg.min_angle_deg, lim)
    block, tracks, rows = _build_block(inp, camera.with_(focal_mm=f0), R, C, X, img_sel, obs_sel, cfg,
                                       cfg.pixel_sigma_px, imu_imgs, strip)
    res = adjust(block, final_cfg.with_(robust=None, statistics=True))
    focal_note = ("focal length fixed at the EXIF value (focal='exif')" if cfg.focal == "exif" or
                  "focal_mm" not in cfg.self_calibration else "focal length self-calibrated")
    focal_ratio = float("nan")
    if "focal_mm" in names_cal:
        # formal (a-priori) sigma of the focal length from the block's geometry and the prior, over the prior
        sf = res.sigma_reduced().get(("intrinsics", res.block.cameras[0].name, "focal_mm"))
        focal_ratio = float(sf) / max(res.sigma0, 1e-12) / sig["focal_mm"] if sf is not None else float("nan")
        if cfg.focal == "auto" and not focal_ratio <= cfg.focal_determinable:
            cam_self = res.block.cameras[0]
            f_self = cam_self.focal_mm / cam_self.pixel_size_mm
            names_nf = tuple(nm for nm in names_cal if nm != "focal_mm")
            R[img_sel], C[img_sel] = res.block.station_rotation, res.block.station_centre
            X[:] = np.nan
            X[tracks] = res.block.point_xyz
            block, tracks, rows = _build_block(inp, cam_self.with_(focal_mm=f0), R, C, X, img_sel, obs_sel, cfg,
                                               cfg.pixel_sigma_px, imu_imgs, strip)
            res = adjust(block, cal_cfg(names_nf).with_(robust=None, statistics=True))
            focal_note = (f"focal length not determinable by this block (posterior sigma {focal_ratio:.2f} x the EXIF "
                          f"prior sigma; self-calibrated value {f_self:.0f} px): fixed at the EXIF value")
        elif cfg.focal == "auto":
            focal_note = f"focal length self-calibrated (posterior sigma {focal_ratio:.2f} x the EXIF prior sigma)"
    logger.info(focal_note)
    camera = res.block.cameras[0]
    R[img_sel] = res.block.station_rotation
    C[img_sel] = res.block.station_centre
    Rout = np.full((n, 3, 3), np.nan)
    Cout = np.full((n, 3), np.nan)
    Rout[img_sel], Cout[img_sel] = R[img_sel], C[img_sel]
    for k in range(n):
        info = check[str(inp.names[k])]
        if oriented[k] and np.isfinite(inp.rotation[k]).all():
            info["metadata_vs_adjusted_deg"] = float(_rotation_angle_deg(inp.rotation[k], Rout[k]))
        if not oriented[k]:
            info["metadata"] = info["metadata"] if info["metadata"] != "unknown" else "image not oriented"
    summary = _summary(inp, res, img_sel, camera, oriented, rounds, time.perf_counter() - t_start)
    summary["attitude_pairs_compared"] = int(np.isfinite(dis).sum() // 2)
    summary["attitude_pairs_agreeing"] = int(agree.sum() // 2)
    summary["focal"] = focal_note
    summary["focal_sigma_over_prior"] = focal_ratio
    if strip is not None:
        b = res.block
        summary["strips"] = {int(k): [str(x) for x in inp.names[strip == k]] for k in np.unique(strip[strip >= 0])}
        summary["strip_shift_m"] = np.asarray(b.strip_shift).tolist()
    return UavResult(inp.names, oriented, Rout, Cout, camera, res, img_sel, check, summary)


def _summary(inp: UavBlockInput, res: AdjustmentResult, img_sel: NDArray, camera: FrameCamera,
             oriented: NDArray, rounds: int, wall_s: float) -> dict[str, Any]:
    b = res.block
    img = res.residuals["image"]
    act = img.weight > 0
    v = img.residual[act]
    per_image = np.bincount(b.obs_image[act], minlength=b.n_images)
    gr = res.residuals["gnss"].residual
    return {
        "images": int(len(inp.names)), "oriented": int(oriented.sum()),
        "not_oriented": [str(x) for x in inp.names[~oriented]],
        "tie_points": int(len(np.unique(b.obs_point[act]))), "image_observations": int(act.sum()),
        "tie_points_per_image": {str(b.image_name[k]): int(per_image[k]) for k in range(b.n_images)},
        "reprojection_rms_px": float(np.sqrt(np.mean(v ** 2))) if len(v) else float("nan"),
        "reprojection_rms_xy_px": np.sqrt(np.mean(v ** 2, axis=0)).tolist() if len(v) else [],
        "sigma0": res.sigma0, "gnss_fit_rms_enu_m": np.sqrt(np.mean(gr ** 2, axis=0)).tolist(),
        "gnss_fit_rms_3d_m": float(np.sqrt(np.mean(np.sum(gr ** 2, axis=1)))),
        "camera": dict(zip(camera.intrinsic_names, np.asarray(camera.intrinsics).tolist())),
        "focal_px": camera.focal_mm / camera.pixel_size_mm,
        "focal_px_exif": inp.camera.focal_mm / inp.camera.pixel_size_mm,
        "growth_rounds": rounds, "wall_s": wall_s, "notes": list(inp.notes),
    }


# ---------------------------------------------------------------------------------------------- I/O side
def _geoid_grid(cfg: UavConfig) -> str:
    if cfg.geoid:
        return cfg.geoid
    from skyrig.pipeline.simulate import find_geoid

    g = find_geoid()
    return g if g is not None else "us_nga_egm96_15.tif"


def metadata_block_input(metas: Sequence[Any], measurements: Any, cfg: UavConfig = UavConfig()) -> UavBlockInput:
    """Build a :class:`UavBlockInput` from image metadata (:func:`skyrig.io.image_read.read_image_metadata`) and
    tie points (:class:`skyrig.georef.observations.ImageMeasurements`, e.g. ``tie_points.csv`` of ``skyrig match``).

    Raises
    ------
    InputFormatError
        An image lacks GPS or a focal length (naming the image and the field); a tie point names an unknown
        image.
    """
    from skyrig.geodesy.crs import Geoid, geodetic_to_ecef
    from skyrig.georef.eo import WorldFrame
    from skyrig.io.image_read import camera_from_metadata
    from skyrig.io.odm import rotation_from_gimbal_ypr

    metas = list(metas)
    for m in metas:
        if not m.has_gps or m.alt_m is None:
            raise InputFormatError("no EXIF GPS position with altitude", m.path, None,
                                   "GPSLatitude" if not m.has_gps else "GPSAltitude")
    notes = []
    lat = np.array([m.lat_deg for m in metas], float)
    lon = np.array([m.lon_deg for m in metas], float)
    alt = np.array([m.alt_m for m in metas], float)
    if cfg.altitude == "egm96":
        grid = _geoid_grid(cfg)
        N = Geoid(grid).undulation(lat, lon)
        h = alt + N
        notes.append(f"EXIF GPSAltitude taken as EGM96 orthometric height; h = H + N with N = {N.mean():.2f} m "
                     f"(grid {Path(grid).name})")
    else:
        h = alt
        notes.append("EXIF GPSAltitude taken as WGS84 ellipsoidal height")
    ecef = geodetic_to_ecef(lat, lon, h)
    frame = WorldFrame.local(float(lat.mean()), float(lon.mean()), float(h.mean()))
    gnss = frame.from_ecef(ecef)
    rot = np.full((len(metas), 3, 3), np.nan)
    have = np.array([m.gimbal_ypr_deg is not None for m in metas])
    if have.any():
        ypr = np.array([m.gimbal_ypr_deg for m in metas if m.gimbal_ypr_deg is not None], float)
        rot[have] = rotation_from_gimbal_ypr(frame, gnss[have], ypr)
    rel = [g[2] - m.relative_alt_m for g, m in zip(gnss, metas) if m.relative_alt_m is not None]
    ground = float(np.median(rel)) if rel else None
    cam = camera_from_metadata(metas[0], metas[0].model or "camera")
    sizes = {(m.width, m.height) for m in metas}
    if len(sizes) > 1:
        raise InputFormatError(f"images of different sizes {sorted(sizes)}: one camera per block is supported",
                               metas[0].path)
    cam = cam.with_(distortion=OpenCVDistortion())
    names = np.array([m.name for m in metas], dtype=str)
    meas_image = np.asarray(measurements.image, dtype=str)
    by_name = np.argsort(names, kind="stable")
    pos = np.minimum(np.searchsorted(names[by_name], meas_image), len(names) - 1)
    known = names[by_name][pos] == meas_image
    if not known.all():
        unknown = sorted(set(meas_image[~known].tolist()))
        raise InputFormatError(f"tie points name {len(unknown)} image(s) without metadata, e.g. {unknown[0]!r}")
    track_name, obs_track = np.unique(measurements.point, return_inverse=True)
    obs_image = by_name[pos].astype(np.int64)
    return UavBlockInput(names, cam, gnss, rot, ground, obs_track.astype(np.int64), obs_image,
                         np.asarray(measurements.pixel, float), track_name, frame, notes)


def compare_with_reconstruction(result: UavResult, other_names: Sequence[str], other_centres: NDArray,
                                gnss: NDArray | None = None) -> dict[str, Any]:
    """Camera centres of another reconstruction (e.g. pycolmap's own, arbitrary frame) against the adjusted ones
    after a similarity transform (Umeyama) of the other onto the adjusted; also the other's fit to GNSS.

    Returns a dict with ``common``, ``scale``, ``rms_m``, ``max_m``, ``rms_enu_m`` and, with ``gnss``,
    ``other_gnss_fit_rms_3d_m`` (similarity of the other's centres onto GNSS) and ``ours_gnss_similarity_rms_3d_m``
    (the same for the adjusted centres, for a like-for-like comparison).
    """
    from skyrig.match.colmap_check import similarity_transform

    idx = {str(n): k for k, n in enumerate(result.names)}
    common = [(k, idx[str(n)]) for k, n in enumerate(other_names) if str(n) in idx and result.oriented[idx[str(n)]]]
    if len(common) < 3:
        raise GeometryError("fewer than 3 common oriented images: no similarity transform")
    a = np.asarray(other_centres, float)[[c[0] for c in common]]
    b = result.centre[[c[1] for c in common]]
    s, Rm, t = similarity_transform(a, b)
    d = s * a @ Rm.T + t - b
    out: dict[str, Any] = {
        "common": len(common), "scale": s, "rms_m": float(np.sqrt(np.mean(np.sum(d ** 2, 1)))),
        "max_m": float(np.linalg.norm(d, axis=1).max()), "rms_enu_m": np.sqrt(np.mean(d ** 2, axis=0)).tolist(),
        "per_image_m": {str(result.names[c[1]]): float(np.linalg.norm(d[k])) for k, c in enumerate(common)}}
    if gnss is not None:
        g = np.asarray(gnss, float)[[c[1] for c in common]]
        s2, R2, t2 = similarity_transform(a, g)
        out["other_gnss_fit_rms_3d_m"] = float(np.sqrt(np.mean(np.sum((s2 * a @ R2.T + t2 - g) ** 2, 1))))
        s3, R3, t3 = similarity_transform(b, g)
        out["ours_gnss_similarity_rms_3d_m"] = float(np.sqrt(np.mean(np.sum((s3 * b @ R3.T + t3 - g) ** 2, 1))))
    return out


def adjust_uav(images: str | Path, match_dir: str | Path, out: str | Path | None = None,
               cfg: UavConfig = UavConfig(), pycolmap_workdir: str | Path | None = None,
               pycolmap_max_image_size: int = 1600, pycolmap_max_features: int = 8192,
               pycolmap_mapper: str = "incremental", crs: str | None = None) -> tuple[UavResult, dict[str, Any]]:
    """Project-level stage: images + ``skyrig match`` output -> adjusted EO, camera and report.

    Parameters
    ----------
    images
        Folder of the images (EXIF GPS, DJI XMP).
    match_dir
        Output folder of ``skyrig match`` (``tie_points.csv``).
    out
        If given: ``eo.csv``, ``points.csv`` and ``adjusted.gpkg`` in the project CRS
        (:mod:`skyrig.io.adjust_outputs`), ``report.json``, ``report.html`` and residual plots are written there.
    crs
        Project CRS of the outputs (a compound CRS gives orthometric heights through its geoid); default the
        WGS84 UTM zone of the images' GNSS positions, ellipsoidal heights.
    pycolmap_workdir
        If given, pycolmap's own pipeline (SIFT, exhaustive matching, incremental mapping) runs there on the
        same images and its camera centres / reprojection RMS are compared (needs ``pycolmap``), with SIFT on
        images downscaled to ``pycolmap_max_image_size`` and at most ``pycolmap_max_features`` per image, and
        ``pycolmap_mapper`` "incremental" (COLMAP) or "global" (GLOMAP; forward-moving sequences such as lund).

    Returns
    -------
    result, report
    """
    from skyrig.io.image_read import list_images, read_image_metadata
    from skyrig.io.points_csv import read_measurements_csv

    t0 = time.perf_counter()
    meas = read_measurements_csv(Path(match_dir) / "tie_points.csv")
    metas = [read_image_metadata(p) for p in list_images(images)]  # images without tie points: "not oriented"
    inp = metadata_block_input(metas, meas, cfg)
    res = adjust_uav_block(inp, cfg)
    from skyrig.adjust.report import adjustment_report

    project = uav_project_frame(inp, crs)
    report = adjustment_report(res.adjustment, frames=None if project is None else (inp.frame, project))
    report["uav"] = dict(res.summary)
    report["uav"]["config"] = asdict(cfg)
    report["uav"]["attitude_check"] = res.attitude_check
    if pycolmap_workdir is not None:
        from skyrig.match.colmap_check import reconstruct_with_pycolmap

        t1 = time.perf_counter()
        _, summ = reconstruct_with_pycolmap(images, [str(n) for n in inp.names], pycolmap_workdir,
                                           max_image_size=pycolmap_max_image_size,
                                           max_features=pycolmap_max_features, mapper=pycolmap_mapper,
                                           focal_px=inp.camera.focal_mm / inp.camera.pixel_size_mm)
        if summ is None:
            report["pycolmap"] = {"registered": 0}
        else:
            cmp = compare_with_reconstruction(res, summ.names, summ.centres, inp.gnss)
            report["pycolmap"] = {"registered": int(len(summ.names)), "points": summ.n_points,
                                  "reprojection_rms_px": summ.reprojection_rms_px, "wall_s": time.perf_counter() - t1,
                                  "centre_differences": cmp}
    report["uav"]["total_wall_s"] = time.perf_counter() - t0
    if out is not None:
        _write_outputs(Path(out), res, report, inp, project)
    return res, report


def uav_project_frame(inp: UavBlockInput, crs: str | None = None) -> Any:
    """The project frame of a UAV block's outputs: ``crs`` (:func:`skyrig.geodesy.statement.project_frame`), else
    the WGS84 UTM zone of the GNSS positions (ellipsoidal heights); None when the block has no frame."""
    from skyrig.geodesy.statement import project_frame, utm_frame

    if crs is not None:
        return project_frame(crs)
    if inp.frame is None:
        return None
    from skyrig.geodesy.crs import ecef_to_geodetic

    lat, lon, _ = ecef_to_geodetic(inp.frame.to_ecef(np.nanmean(inp.gnss, axis=0, keepdims=True)))
    return utm_frame(lat, lon)


def _write_outputs(out: Path, res: UavResult, report: dict[str, Any], inp: UavBlockInput,
                   project: Any = None) -> dict[str, Path]:
    """``eo.csv``, ``points.csv`` (tie points with sigmas) and ``adjusted.gpkg`` in the project frame (default
    :func:`uav_project_frame`), ``report.json``, ``report.html`` and residual plots in ``out``."""
    from skyrig.georef.eo import ExteriorOrientations
    from skyrig.io.adjust_outputs import write_adjusted_tables
    from skyrig.io.report_html import write_report

    out.mkdir(parents=True, exist_ok=True)
    k = res.block_image
    paths: dict[str, Path] = {}
    project = project or uav_project_frame(inp)
    if inp.frame is not None and project is not None:
        eo = ExteriorOrientations(res.names[k], np.array([res.camera.name] * len(k)), res.centre[k], res.rotation[k],
                                  inp.frame)
        paths.update(write_adjusted_tables(out, res.adjustment, inp.frame, project, eo_local=eo))
    paths.update(write_report(out, res.adjustment, report, title="skyrig UAV GNSS-supported adjustment"))
    return paths
