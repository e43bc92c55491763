"""Incremental orientation of an image block with GNSS positions (and metadata attitudes when they can be trusted):
attitude check, two-view or metadata seed, growth by triangulation + resection + bundle adjustment, final
self-calibrating adjustment (layer 2b: arrays in, arrays out; no file is opened here).

The algorithm is described in :mod:`skyrig.pipeline.uav` (the file-level wrapper: image metadata and
``skyrig match`` tie points in, EO / points / report files out).  Everything is in one local Cartesian frame
(metres); pixels follow skyrig's convention.
"""

from __future__ import annotations

import logging
import time
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Any, Iterator, Literal

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from skyrig.adjust import AdjustConfig, AdjustmentResult, Block, adjust
from skyrig.adjust.config import SolverOptions, StatisticsOptions, Unknowns
from skyrig.adjust.factors.rolling_shutter import rolling_shutter_unknowns
from skyrig.camera.frame import FrameCamera
from skyrig.camera.opencv import OpenCVDistortion
from skyrig.errors import ConfigError, SkyrigError, UavAdjustError  # noqa: F401 - UavAdjustError re-exported
from skyrig.orient.rolling_shutter import (rolling_shutter_decision, rolling_shutter_summary, velocity_prior,
                                           with_rolling_shutter)
from skyrig.orient.similarity import _MIN_COMMON, _robust_similarity
from skyrig.orient.strips import _renumber_strips, detect_strips
from skyrig.orient.triangulation import (
    _SKYRIG_FROM_CV, _k_matrix, _rays_world, _reproject, _rotation_angle_deg, _spread_ok, _track_pairs, resect,
    triangulate_tracks,
)

logger = logging.getLogger(__name__)

__all__ = ["UavAdjustError", "UavConfig", "UavBlockInput", "UavResult", "attitude_agreement", "adjust_uav_block"]


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
    #: relative sigma of the focal length prior (0.1 = 10 %); None: the sigma of the prior's source
    #: (:mod:`skyrig.io.camera_prior`: 1 % vendor calibration, 3 % EXIF focal + sensor database, 10 % 35-mm value)
    focal_prior_rel: float | None = None
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
    #: hand measurements (control / check points, scale-bar ends) are never cut by the tie points' rules; one whose
    #: residual exceeds this (px) is left out as a blunder, named in a warning
    hand_cut_px: float = 10.0
    #: Levenberg-Marquardt iterations per adjustment.  Self-calibration of a flat single-height block follows a
    #: long curved valley of focal length / principal point / k2 (weakly determined together): brighton's 18
    #: images matched at 1,600 px need 79 iterations; COLMAP's bundle adjustment allows 100 as well
    max_iterations: int = 100
    #: per-strip GNSS shift (strips found from the flight path, see :func:`detect_strips`): "off", or "weighted"
    #: (a shift per strip with prior sigma ``strip_shift_sigma_m``; absorbs a GPS height/position offset per strip)
    gnss_strip_shift: Literal["off", "weighted"] = "off"
    strip_shift_sigma_m: float = 1.0
    #: focal length: "auto" (self-calibrated, held at its prior when the block cannot determine it or contradicts
    #: it: :mod:`skyrig.adjust.determinability`), "self" (self-calibrated whatever the verdict: an explicit choice the
    #: report states) or "exif" (fixed at the prior's value)
    focal: Literal["self", "exif", "auto"] = "auto"
    #: determinability rule for every self-calibrated parameter: determined when its formal sigma is at most
    #: ``determinable_ratio`` x its prior sigma and the prior test |z| <= ``prior_conflict_z``; otherwise held at the
    #: prior with a warning (unless named in ``free_anyway``)
    determinable_ratio: float = 0.5
    prior_conflict_z: float = 3.0
    #: a parameter determined at least this well (formal sigma / prior sigma) that contradicts its prior overrules it
    #: (kept, with a warning that the metadata is contradicted); above it, the contradiction holds it at the prior
    overrule_ratio: float = 0.3
    #: intrinsic names left free even when the block cannot determine them (the report says so)
    free_anyway: tuple[str, ...] = ()
    #: rolling shutter (:mod:`skyrig.adjust.factors.rolling_shutter`): "auto" (modelled for the camera models known to
    #: read out row by row and for phone cameras, :mod:`skyrig.orient.rolling_shutter`), "on" or "off"; the readout
    #: time's prior and sigma (s), the floor of the velocity prior's sigma (m/s; the velocity comes from the GNSS
    #: positions and image times) and the sigma of a zero angular velocity (rad/s, a stabilised gimbal)
    rolling_shutter: Literal["auto", "on", "off"] = "auto"
    #: estimate the readout time (needs velocity priors from capture times and motion in the images' rows; on a flat
    #: GNSS-only block with self-calibration the readout x velocity absorbs the focal / height valley: brighton's
    #: readout runs off to 0.5 s), else held at ``readout_s``
    estimate_readout: bool = False
    readout_s: float = 0.03
    readout_sigma_s: float = 0.02
    velocity_sigma_m_s: float = 1.0
    angular_sigma_rad_s: float = 0.05  # brighton (FC300S on its gimbal): 0.2 rad/s lets it reach 0.28 rad/s median

    @classmethod
    def from_dict(cls, data: dict, source: str = "config") -> "UavConfig":
        d = dict(data)
        if "focal_determinable" in d:  # the old name of determinable_ratio (one release of deprecation)
            logger.warning("%s: option focal_determinable is deprecated; it is now determinable_ratio and applies to "
                           "every self-calibrated parameter", source)
            old = d.pop("focal_determinable")
            d.setdefault("determinable_ratio", old)
        bad = sorted(set(d) - set(cls.__dataclass_fields__))
        if bad:
            raise ConfigError(f"{source}: unknown UAV adjustment option(s) {bad}; "
                              f"known: {sorted(cls.__dataclass_fields__)}")
        fp = d.get("focal_prior_rel")
        if fp is not None and not (isinstance(fp, (int, float)) and np.isfinite(fp) and fp > 0):
            raise ConfigError(f"{source}: focal_prior_rel must be a positive number (relative sigma, e.g. 0.03), "
                              f"got {fp!r}")
        for k in ("gnss_sigma_m", "self_calibration", "free_anyway"):
            if k in d and d[k] is not None:
                d[k] = tuple(d[k])
        if d.get("rolling_shutter", "auto") not in ("auto", "on", "off"):
            raise ConfigError(f"{source}: rolling_shutter must be 'auto', 'on' or 'off', got {d['rolling_shutter']!r}")
        for k in ("readout_sigma_s", "velocity_sigma_m_s", "angular_sigma_rad_s"):
            x = d.get(k, 1.0)
            if not (isinstance(x, (int, float)) and np.isfinite(x) and x > 0):
                raise ConfigError(f"{source}: {k} must be a positive number (a standard deviation), got {x!r}")
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
    intrinsic_sigma
        Prior sigma of the camera's intrinsics by name (camera units: mm for focal_mm / ppx_mm / ppy_mm), from the
        images' metadata (:func:`skyrig.io.camera_prior.camera_prior`); names left out get the defaults of
        :func:`adjust_uav_block`.  The prior's values are ``camera``'s.
    prior_source
        Where the camera prior came from, in words.
    control_track, control_xyz, control_sigma, control_check
        Ground points measured in the images (optional): ``(K,)`` index into ``track_name``, ``(K, 3)`` coordinates
        in the local frame (metres), ``(K, 3)`` sigmas (metres per axis: metre-class targets with a loose height
        are fine) and ``(K,)`` True for a check point (compared afterwards, not used).  A point the block cannot
        intersect (seen in fewer than two oriented images) is left out and reported (``summary["control_left_out"]``).
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
    intrinsic_sigma: dict[str, float] = field(default_factory=dict)
    prior_source: str = ""
    control_track: NDArray[np.int64] | None = None
    control_xyz: NDArray[np.float64] | None = None
    control_sigma: NDArray[np.float64] | None = None
    control_check: NDArray[np.bool_] | None = None
    #: EXIF make / model of the camera ('' when unknown) and ``(I,)`` capture times (s, NaN unknown) or None:
    #: whether the rolling shutter is modelled, and the velocity prior
    camera_make: str = ""
    camera_model: str = ""
    times_s: NDArray[np.float64] | None = None


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
    ctl: dict[str, Any] = {}
    if inp.control_track is not None and len(inp.control_track):
        pos = {int(t): k for k, t in enumerate(tracks)}
        sel = [j for j, t in enumerate(inp.control_track) if int(t) in pos]
        if sel:
            ctl = dict(control_point=np.array([pos[int(inp.control_track[j])] for j in sel], np.int64),
                       control_xyz=np.asarray(inp.control_xyz, float)[sel],
                       control_sigma=np.asarray(inp.control_sigma, float)[sel],
                       control_check=np.asarray(inp.control_check, bool)[sel])
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
        frame=inp.frame if inp.frame is not None else "local ENU",
        station_strip=None if strip is None else _renumber_strips(strip[img_sel]),
        **ctl,
    )
    if rolling_shutter_decision(cfg.rolling_shutter, inp.camera_make, inp.camera_model)[0]:
        v, vs = velocity_prior(inp.gnss, inp.times_s, cfg.gnss_sigma_m, cfg.velocity_sigma_m_s)
        block = with_rolling_shutter(block, camera.name, v[img_sel], vs[img_sel], cfg.readout_s, cfg.readout_sigma_s,
                                     cfg.angular_sigma_rad_s)
    return block, tracks, np.flatnonzero(obs_sel)


class _IntermediateFailure(logging.Filter):
    """Demotes the adjustment's "adjustment failed" warning to INFO (see :func:`intermediate_adjustment`)."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno == logging.WARNING and str(record.msg).startswith("adjustment failed"):
            record.levelno, record.levelname = logging.INFO, "INFO"
            record.msg = "intermediate " + str(record.msg) + " (the final adjustment decides)"
            return logging.getLogger(record.name).isEnabledFor(logging.INFO)
        return True


@contextmanager
def intermediate_adjustment() -> Iterator[None]:
    """An adjustment of a growth round: its loose tolerances may stop it at the iteration cap, which is no failure
    of the run (the final adjustment is judged); without this, users read "adjustment failed" in a run that
    succeeded."""
    lg = logging.getLogger("skyrig.adjust.adjust")
    f = _IntermediateFailure()
    lg.addFilter(f)
    try:
        yield
    finally:
        lg.removeFilter(f)


def hand_rows(inp: Any) -> NDArray[np.bool_]:
    """``(N,)`` True for the observation rows measured by hand: image measurements of control and check points
    and of scale-bar ends.  They are judged by their own limit (``hand_cut_px``), never by the tie points'
    outlier rules: a click 2 px off is an ordinary hand measurement, and cutting it silently can take a control
    point out of the block."""
    return is_hand(inp, np.arange(len(inp.obs_track)))


def is_hand(inp: Any, rows: NDArray[np.int64]) -> NDArray[np.bool_]:
    """:func:`hand_rows` for the observation rows ``rows`` only (one image's rows in a resection: no pass over the
    whole block per image)."""
    tracks = [np.asarray(t, np.int64).ravel() for t in (getattr(inp, "control_track", None),
                                                         getattr(inp, "distance_track", None)) if t is not None]
    if not tracks:
        return np.zeros(len(rows), bool)
    return np.isin(inp.obs_track[rows], np.concatenate(tracks))


def spare_hand(inp: Any, rows: NDArray[np.int64], bad: NDArray[np.bool_], r: NDArray[np.float64],
               hand: NDArray[np.bool_], limit_px: float, cut: dict[tuple[str, str], float]) -> NDArray[np.bool_]:
    """``bad`` (per row of ``rows``) without the hand-measured rows whose residual ``r`` is within ``limit_px``.
    The hand rows still cut are recorded in ``cut`` as ``{(point, image): residual px}`` for the warning."""
    h = hand[rows] & bad
    keep = h & (r <= limit_px)
    for q in np.flatnonzero(h & ~keep):
        o = rows[q]
        cut[(str(inp.track_name[inp.obs_track[o]]), str(inp.names[inp.obs_image[o]]))] = float(r[q])
    return bad & ~keep


def hand_words(cut: dict[tuple[str, str], float], limit_px: float) -> list[str]:
    """Warnings naming each hand measurement cut as a blunder."""
    return [f"image measurement of {p} in {i}: residual {v:.1f} px above the {limit_px:g} px limit of hand "
            "measurements: left out as a blunder; check the measurement" for (p, i), v in sorted(cut.items())]


def _usable_obs(inp: Any, oriented: NDArray[np.bool_], X: NDArray, active: NDArray[np.bool_],
                camera: FrameCamera, R: NDArray, C: NDArray, min_angle_deg: float,
                max_px: float = np.inf, front_tol: float = 1e-3, hand: NDArray[np.bool_] | None = None,
                hand_max_px: float = np.inf, cut: dict[tuple[str, str], float] | None = None) -> NDArray[np.bool_]:
    """Observations that can enter an adjustment: oriented image, active, point finite and in front of the
    camera, reprojecting within ``max_px`` (hand-measured rows ``hand``: within ``max(max_px, hand_max_px)``),
    and every point left with >= 2 such rays spanning at least ``min_angle_deg``.  ``cut`` (the final
    selection) records the hand rows left out by their reprojection error, for the warning."""
    T = len(inp.track_name)
    X_ok = np.isfinite(X).all(axis=1)
    sel = oriented[inp.obs_image] & X_ok[inp.obs_track] & active
    rows = np.flatnonzero(sel)
    ti, ii = inp.obs_track[rows], inp.obs_image[rows]
    v = X[ti] - C[ii]
    pc = np.einsum("nji,nj->ni", R[ii], v)
    front = pc[:, 2] < -front_tol * np.linalg.norm(v, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        err = np.linalg.norm(camera.project_pixels(pc) - inp.obs_pixel[rows], axis=1)
    lim = np.full(len(rows), max_px) if hand is None else np.where(hand[rows], max(max_px, hand_max_px), max_px)
    err = np.nan_to_num(err, nan=np.inf)
    if cut is not None and hand is not None:
        for q in np.flatnonzero(front & hand[rows] & (err >= lim)):
            cut[(str(inp.track_name[ti[q]]), str(inp.names[ii[q]]))] = float(err[q])
    front &= err < lim
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
        active[rows_k[~inl & ~is_hand(inp, rows_k)]] = False  # a RANSAC verdict is no verdict on a click
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
    hand = hand_rows(inp)  # hand measurements (control, check, scale bars)
    hand_cut: dict[tuple[str, str], float] = {}  # those cut as blunders
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
    grow_cfg = AdjustConfig(solver=SolverOptions(robust="huber", robust_k=cfg.robust_k,
                                                 max_iterations=cfg.max_iterations),
                            statistics=StatisticsOptions(compute=False),
                            unknowns=Unknowns(datum="auto"))
    X = np.full((T, 3), np.nan)
    rounds = 0
    while True:
        rounds += 1
        sel = oriented[inp.obs_image] & active
        X, ok = triangulate_tracks(camera, np.nan_to_num(R), np.nan_to_num(C), inp.obs_track[sel], inp.obs_image[sel],
                                   inp.obs_pixel[sel], T, cfg.min_angle_deg)
        X[~ok] = np.nan
        gate = 0.05 * max(camera.width, camera.height) if rounds == 1 else 4.0 * cfg.pnp_threshold_px
        obs_sel = _usable_obs(inp, oriented, X, active, camera, R, C, cfg.min_angle_deg, gate, hand=hand,
                              hand_max_px=cfg.hand_cut_px)
        img_sel = np.flatnonzero(oriented)
        block, tracks, rows = _build_block(inp, camera, R, C, X, img_sel, obs_sel, cfg, sigma_px,
                                           np.intersect1d(trusted_att, img_sel))
        try:
            with intermediate_adjustment():
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
        bad = spare_hand(inp, rows, r > max(8.0 * 1.4826 * med, 3.0 * cfg.reject_min_px), r, hand, cfg.hand_cut_px,
                         hand_cut)
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
    # the priors of the self-calibration are centred on the nominal (EXIF) camera in every stage; each stage
    # starts from the previous stage's estimate (``adjust(..., start=)``): restarting from the nominal camera
    # walks the weakly determined focal / principal point valley again, and the function tolerance can end
    # that walk far from the minimum (brighton at 1,600 px: focal 2,542 instead of 3,135 px, cost 2 % higher)
    nominal = camera
    w_mm = camera.width * camera.pixel_size_mm
    sig = {"focal_mm": 0.1 * f0, "ppx_mm": 0.05 * w_mm, "ppy_mm": 0.05 * w_mm,
           "k1": 1.0, "k2": 1.0, "k3": 1.0, "p1": 0.1, "p2": 0.1, "b1": 0.01, "b2": 0.01}
    sig.update(inp.intrinsic_sigma)
    if cfg.focal_prior_rel is not None:
        sig["focal_mm"] = cfg.focal_prior_rel * f0
    names_cal = tuple(nm for nm in camera.intrinsic_names if nm in cfg.self_calibration
                      and not (nm == "focal_mm" and cfg.focal == "exif"))

    rs_on, rs_words = rolling_shutter_decision(cfg.rolling_shutter, inp.camera_make, inp.camera_model)

    def cal_cfg(names: tuple[str, ...]) -> AdjustConfig:
        unk = Unknowns(intrinsics="weighted" if names else "fixed", intrinsic_names=names or None,
                       intrinsic_sigma=tuple((k, v) for k, v in sig.items() if k in names),
                       strip_shift="weighted" if cfg.gnss_strip_shift == "weighted" else "fixed",
                       strip_shift_sigma_m=cfg.strip_shift_sigma_m)
        unk = rolling_shutter_unknowns(unk, readout="free" if cfg.estimate_readout else "fixed") if rs_on else unk
        return AdjustConfig(unknowns=unk,
                            solver=SolverOptions(robust="huber", robust_k=cfg.robust_k,
                                                 max_iterations=cfg.max_iterations),
                            statistics=StatisticsOptions(compute=False))

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
        obs_sel = _usable_obs(inp, oriented, X, active, camera, R, C, cfg.min_angle_deg, 2.0 * cfg.pnp_threshold_px,
                              hand=hand, hand_max_px=cfg.hand_cut_px)
        block, tracks, rows = _build_block(inp, nominal, R, C, X, img_sel, obs_sel, cfg, cfg.pixel_sigma_px,
                                           imu_imgs, strip)
        res = adjust(block, final_cfg, start=replace(block, cameras=[camera]))
        camera = res.block.cameras[0]
        R[img_sel] = res.block.station_rotation
        C[img_sel] = res.block.station_centre
        X[:] = np.nan
        X[tracks] = res.block.point_xyz
        r = np.nan_to_num(np.linalg.norm(_image_residuals(res.block), axis=1), nan=np.inf)
        robust_rms = float(np.median(r)) / np.sqrt(np.log(4.0))  # Rayleigh median = sigma sqrt(ln 4)
        lim = max(cfg.reject_k * robust_rms * np.sqrt(2.0), cfg.reject_min_px)
        bad = spare_hand(inp, rows, r > lim, r, hand, cfg.hand_cut_px, hand_cut)
        active[rows[bad]] = False
        logger.info("final stage %d: sigma per axis %.3f px (robust), %d observations above %.2f px removed", stage,
                    robust_rms, int(bad.sum()), lim)
    # last run: plain least squares on the cleaned observations, with statistics
    obs_sel = _usable_obs(inp, oriented, X, active, camera, R, C, cfg.min_angle_deg, lim, hand=hand,
                          hand_max_px=cfg.hand_cut_px, cut=hand_cut)
    block, tracks, rows = _build_block(inp, nominal, R, C, X, img_sel, obs_sel, cfg, cfg.pixel_sigma_px, imu_imgs,
                                       strip)
    res = adjust(block, final_cfg.with_solver(robust=None).with_statistics(compute=True), start=replace(block, cameras=[camera]))
    verdicts: list[Any] = []
    if names_cal:
        res, verdicts, names_cal = _hold_undetermined(inp, cfg, res, nominal, names_cal, sig, cal_cfg,
                                                      (R, C, X, img_sel, obs_sel, imu_imgs, strip))
    focal_note = _focal_note(cfg, verdicts, names_cal)
    focal_ratio = next((v.ratio for v in verdicts if v.name == "focal_mm"), float("nan"))
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
    summary["calibration"] = [v.to_dict() for v in verdicts]
    summary["calibration_held"] = [v.name for v in verdicts if v.held]
    from skyrig.adjust.determinability import rule_words

    summary["calibration_rule"] = rule_words(cfg.determinable_ratio, cfg.prior_conflict_z, cfg.overrule_ratio)
    summary["camera_prior_source"] = inp.prior_source
    summary["rolling_shutter"] = rolling_shutter_summary(res, rs_on, rs_words)
    summary.update(ground_point_summary(inp, res.block, hand_cut, cfg.hand_cut_px))
    if strip is not None:
        b = res.block
        summary["strips"] = {int(k): [str(x) for x in inp.names[strip == k]] for k in np.unique(strip[strip >= 0])}
        summary["strip_shift_m"] = np.asarray(b.strip_shift).tolist()
    return UavResult(inp.names, oriented, Rout, Cout, camera, res, img_sel, check, summary)


def ground_point_summary(inp: Any, block: Block, hand_cut: dict[tuple[str, str], float],
                         hand_cut_px: float) -> dict[str, Any]:
    """Which control / check points the final block used, which it left out and why, and the hand measurements
    cut as blunders; every point left out and every cut measurement is also logged as a warning (never silent)."""
    out: dict[str, Any] = {}
    for w in hand_words(hand_cut, hand_cut_px):
        logger.warning("%s", w)
    if hand_cut:
        out["hand_measurements_cut"] = {f"{p} in {i}": v for (p, i), v in sorted(hand_cut.items())}
    if inp.control_track is None or not len(inp.control_track):
        return out
    cp = block.control_point
    used = set(block.point_name[cp].tolist()) if cp is not None else set()
    names = [str(inp.track_name[t]) for t in inp.control_track]
    out["control_used"] = sorted(nm for nm, c in zip(names, inp.control_check) if nm in used and not c)
    out["check_used"] = sorted(nm for nm, c in zip(names, inp.control_check) if nm in used and c)
    cut_pts = {p for p, _ in hand_cut}
    out["control_left_out"] = {
        nm: ("seen in fewer than two oriented images" + (" after its measurements above "
             f"{hand_cut_px:g} px were cut as blunders" if nm in cut_pts else "") + ": it cannot be intersected; "
             "left out") for nm in names if nm not in used}
    for nm, why in out["control_left_out"].items():
        logger.warning("ground point %s: %s", nm, why)
    return out


def _hold_undetermined(inp: UavBlockInput, cfg: UavConfig, res: AdjustmentResult, nominal: FrameCamera,
                       names_cal: tuple[str, ...], sig: dict[str, float], cal_cfg: Any, state: tuple
                       ) -> tuple[AdjustmentResult, list[Any], tuple[str, ...]]:
    """:func:`skyrig.adjust.determinability.hold_undetermined` on the final UAV block: a held intrinsic is re-adjusted
    without, from the estimate with it reset to its prior."""
    from skyrig.adjust.determinability import hold_undetermined

    R, C, X, img_sel, obs_sel, imu_imgs, strip = state

    def readjust(r: AdjustmentResult, names: tuple[str, ...], start_cam: FrameCamera) -> AdjustmentResult:
        R2, C2 = R.copy(), C.copy()
        R2[img_sel], C2[img_sel] = r.block.station_rotation, r.block.station_centre
        block, _, _ = _build_block(inp, nominal, R2, C2, X, img_sel, obs_sel, cfg, cfg.pixel_sigma_px, imu_imgs,
                                   strip)
        block = replace(block, point_xyz=np.array(r.block.point_xyz, float))  # same observations: same points
        return adjust(block, cal_cfg(names).with_solver(robust=None).with_statistics(compute=True),
                      start=replace(block, cameras=[start_cam]))

    free_anyway = tuple(cfg.free_anyway) + (("focal_mm",) if cfg.focal == "self" else ())
    return hold_undetermined(res, nominal, names_cal, sig, readjust, ratio_max=cfg.determinable_ratio,
                             z_max=cfg.prior_conflict_z, free_anyway=free_anyway,
                             strong_ratio=cfg.overrule_ratio)


def _focal_note(cfg: UavConfig, verdicts: list[Any], names_cal: tuple[str, ...]) -> str:
    """The focal length's fate in words (report summary ``focal``)."""
    if cfg.focal == "exif" or "focal_mm" not in cfg.self_calibration:
        return "focal length fixed at its prior value (focal='exif' or not self-calibrated)"
    v = next((x for x in verdicts if x.name == "focal_mm"), None)
    if v is None:
        return "focal length self-calibrated"
    return "focal length " + v.words()


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
