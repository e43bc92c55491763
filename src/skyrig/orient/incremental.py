"""Incremental orientation of an image block without GNSS (layer 2b: arrays in, arrays out; no file is opened here).

For terrestrial, close-range, UAV or aerial image sets whose exposures carry no usable position: the block is
started from a relative orientation and grown image by image; its datum (position, rotation and scale) comes from
control points, scale bars, a similarity onto approximate positions (e.g. a phone's GPS), or inner constraints.

Stages (:func:`orient_incremental`)
-----------------------------------
1. **Two-view start.**  Image pairs ranked by common tie points; for the best-connected candidates
   (``seed_candidates``) an essential matrix (``cv2.findEssentialMat``, RANSAC, threshold ``pnp_threshold_px``) and
   ``cv2.recoverPose`` give the relative rotation and base direction.  A pair is scored by its inliers times
   ``min(1, median intersection angle / seed_parallax_deg)``: many inliers, and enough parallax that the points
   (and the next resections) are well determined; a (nearly) pure rotation or a short base scores low.  The first
   image is the frame (OpenCV camera axes), the base has length 1.
2. **Growth.**  Tie points seen by >= 2 oriented images are triangulated (multi-view midpoint, angle and depth
   checks, :func:`~skyrig.orient.triangulation.triangulate_tracks`); the unoriented images with the most
   triangulated points are resected (``cv2.solvePnPRansac`` EPnP + LM, :func:`~skyrig.orient.triangulation.resect`);
   a bundle adjustment (:func:`skyrig.adjust.adjust`, Huber weights, inner constraints as datum, camera fixed)
   runs while the block is small and each time it has grown by ``ba_growth`` since the last one; gross residuals
   are removed after each.  An image with too few triangulated points for a resection but many tie points with
   one oriented image (a walk turning a corner: its points are seen by that image only) is tied in by the pair's
   relative orientation: rotation and base direction from the essential matrix, the base length from the
   triangulated points it does see (median, checked by reprojection), refined by resection.  A part of the block
   that neither reaches gets its own two-view start and is tied in by a robust similarity through common points.
   Repeat until no image can be added.
3. **Datum** (``datum``):

   * ``"control"``: a similarity (Umeyama) of the triangulated control points onto their given coordinates (>= 3
     points, checked), then the final adjustment with the control points as weighted observations;
   * ``"scale-bar"``: the block is scaled by the median ratio of the given to the triangulated scale-bar lengths,
     then adjusted with the distances as observations and inner constraints on the poses (6 datum parameters:
     translation and rotation stay those of the relative orientation's frame);
   * ``"positions"``: a robust similarity of the projection centres onto approximate positions (``positions``,
     e.g. EXIF GPS), then a free-network adjustment (7 inner constraints) about that start; the positions are
     *not* observations, so they cannot bend the block; the similarity's residuals are reported;
   * ``"free"``: inner constraints only; scale and frame are those of the relative orientation (base = 1).

4. **Final adjustment.**  Self-calibration (``self_calibration``; focal length with the EXIF prior
   ``focal_prior_rel``), Huber weights, removal of residuals above ``reject_k`` x robust RMS (twice), then plain
   least squares with statistics.  With ``datum="control"`` and ``"scale-bar"`` scale bars and control points
   both enter when given.

Everything is in one Cartesian frame (metres once a datum with scale is given); pixels follow skyrig's convention.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust import AdjustConfig, AdjustmentResult, Block, adjust
from skyrig.adjust.config import SolverOptions, StatisticsOptions, Unknowns
from skyrig.adjust.factors.rolling_shutter import rolling_shutter_unknowns
from skyrig.camera.frame import FrameCamera
from skyrig.camera.distortion import NoDistortion
from skyrig.camera.opencv import OpenCVDistortion
from skyrig.errors import ConfigError, OrientError, SkyrigError  # noqa: F401 - OrientError re-exported
from skyrig.orient.gnss_block import (
    UavResult, _usable_obs, ground_point_summary, hand_rows, intermediate_adjustment, is_hand, spare_hand,
)
from skyrig.orient.rolling_shutter import (rolling_shutter_decision, rolling_shutter_summary, velocity_neighbours,
                                           with_rolling_shutter)
from skyrig.orient.similarity import _robust_similarity
from skyrig.orient.triangulation import (
    _SKYRIG_FROM_CV, _k_matrix, _reproject, _track_pairs, resect, triangulate_tracks,
)

logger = logging.getLogger(__name__)

__all__ = ["OrientConfig", "OrientInput", "OrientError", "orient_incremental", "choose_seed_pair"]

Datum = Literal["control", "scale-bar", "positions", "free"]


@dataclass(frozen=True)
class OrientConfig:
    """Settings of the incremental orientation without GNSS (frozen; unknown keys are an error)."""

    #: "control", "scale-bar", "positions", "free" or "auto" (control if given, else scale bars, else positions,
    #: else free)
    datum: Literal["auto", "control", "scale-bar", "positions", "free"] = "auto"
    #: a-priori sigma of a tie-point measurement (px)
    pixel_sigma_px: float = 1.0
    #: relative sigma of the EXIF / given focal length prior; None: the input's (``OrientInput.focal_prior_rel``,
    #: from the images' metadata, :mod:`skyrig.io.camera_prior`), else 0.1
    focal_prior_rel: float | None = None
    #: self-calibrated intrinsics (FrameCamera + OpenCV distortion names); () keeps the camera fixed
    self_calibration: tuple[str, ...] = ("focal_mm", "ppx_mm", "ppy_mm", "k1", "k2", "p1", "p2", "k3")
    #: two-view start: pairs tried (most common tie points first), minimum common points, parallax for full score
    seed_candidates: int = 30
    seed_min_common: int = 50
    seed_parallax_deg: float = 4.0
    #: resection: RANSAC threshold (px) and minimum inliers
    pnp_threshold_px: float = 4.0
    pnp_min_inliers: int = 20
    #: minimum intersection angle of a triangulated tie point (deg); small enough for forward motion (a walk)
    min_angle_deg: float = 0.3
    #: bundle adjustment during growth: always up to this many images, then each time the block grew by this share
    ba_always_below: int = 8
    ba_growth: float = 0.25
    #: Huber threshold (units of the pixel sigma) and the final outlier removal (reject_k x robust RMS, >= min px)
    robust_k: float = 2.0
    reject_k: float = 4.0
    reject_min_px: float = 2.0
    #: hand measurements (control / check points, scale-bar ends) are never cut by the tie points' rules; one whose
    #: residual exceeds this (px) is left out as a blunder, named in a warning
    hand_cut_px: float = 10.0
    max_iterations: int = 40
    #: positions datum: minimum images with a position
    min_positions: int = 4
    #: determinability of the self-calibration (:mod:`skyrig.adjust.determinability`): an intrinsic whose formal
    #: sigma exceeds ``determinable_ratio`` x its prior sigma or whose prior test |z| exceeds ``prior_conflict_z`` is
    #: held at its prior with a warning, unless named in ``free_anyway``
    determinable_ratio: float = 0.5
    prior_conflict_z: float = 3.0
    #: a parameter determined at least this well (formal sigma / prior sigma) that contradicts its prior overrules it
    #: (kept, with a warning that the metadata is contradicted); above it, the contradiction holds it at the prior
    overrule_ratio: float = 0.3
    free_anyway: tuple[str, ...] = ()
    #: rolling shutter in the final adjustment (:mod:`skyrig.adjust.factors.rolling_shutter`), as in the GNSS path:
    #: "auto" (modelled for the cameras known to read out row by row, :mod:`skyrig.orient.rolling_shutter`), "on"
    #: or "off".  The readout time is held at its prior unless ``estimate_readout``.  Without GNSS the velocity prior
    #: of each image comes from the block's own centres of its neighbours in capture time, with a sigma of
    #: ``velocity_sigma_rel`` x the speed (the frame may have no metric scale); angular rates 0 +- the sigma given.
    rolling_shutter: Literal["auto", "on", "off"] = "auto"
    readout_s: float = 0.03
    readout_sigma_s: float = 0.02
    estimate_readout: bool = False
    velocity_sigma_rel: float = 0.25
    angular_sigma_rad_s: float = 0.05

    def __post_init__(self) -> None:
        if self.rolling_shutter not in ("auto", "on", "off"):
            raise ConfigError(f"rolling_shutter must be 'auto', 'on' or 'off', got {self.rolling_shutter!r}")
        for k in ("readout_s", "readout_sigma_s", "velocity_sigma_rel", "angular_sigma_rad_s"):
            v = getattr(self, k)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise ConfigError(f"{k} must be a positive number, got {v!r}")
        if self.readout_s > 0.2:
            raise ConfigError(f"readout_s {self.readout_s} s: a sensor reads out in milliseconds (e.g. 0.03 s); "
                              "was it given in ms?")

    @classmethod
    def from_dict(cls, data: dict, source: str = "config") -> "OrientConfig":
        bad = sorted(set(data) - set(cls.__dataclass_fields__))
        if bad:
            raise ConfigError(f"{source}: unknown orientation option(s) {bad}; known: {sorted(cls.__dataclass_fields__)}")
        d = dict(data)
        for k in ("self_calibration", "free_anyway"):
            if d.get(k) is not None:
                d[k] = tuple(d[k])
        try:
            return cls(**d)
        except ConfigError as e:
            raise ConfigError(f"{source}: {e}") from None


@dataclass
class OrientInput:
    """What the orientation needs.

    Attributes
    ----------
    names
        ``(I,)`` image names.
    camera
        Starting camera (EXIF or given focal length; OpenCV distortion).
    obs_track, obs_image, obs_pixel, track_name
        Tie-point (and target) observations: ``(N,)`` track index, ``(N,)`` image index, ``(N, 2)`` pixels;
        ``(T,)`` track names.  Control points and scale-bar ends are tracks like any other.
    control_track, control_xyz, control_sigma, control_check
        ``(K,)`` track index of control points, ``(K, 3)`` coordinates, ``(K, 3)`` sigma (m), ``(K,)`` True for a
        check point (compared, not used).
    distance_track, distance_m, distance_sigma_m
        Scale bars: ``(D, 2)`` track indices of the ends, ``(D,)`` lengths and sigmas (m).
    positions
        ``(I, 3)`` approximate projection centres (NaN where none), for ``datum="positions"`` (not observations).
    frame
        :class:`skyrig.georef.eo.WorldFrame` of control / positions (None: an arbitrary Cartesian frame).
    notes
        What was assumed while reading.
    focal_prior_rel
        Relative sigma of the metadata's focal length (None: the config's).
    camera_make, camera_model, times_s
        EXIF make and model (rolling shutter or not) and ``(I,)`` capture times in s (NaN where unknown).
    """

    names: NDArray[np.str_]
    camera: FrameCamera
    obs_track: NDArray[np.int64]
    obs_image: NDArray[np.int64]
    obs_pixel: NDArray[np.float64]
    track_name: NDArray[np.str_]
    control_track: NDArray[np.int64] | None = None
    control_xyz: NDArray[np.float64] | None = None
    control_sigma: NDArray[np.float64] | None = None
    control_check: NDArray[np.bool_] | None = None
    distance_track: NDArray[np.int64] | None = None
    distance_m: NDArray[np.float64] | None = None
    distance_sigma_m: NDArray[np.float64] | None = None
    positions: NDArray[np.float64] | None = None
    frame: Any = None
    notes: list[str] = field(default_factory=list)
    focal_prior_rel: float | None = None
    #: the camera's EXIF make and model (whether it has a rolling shutter) and each image's capture time (s, NaN
    #: where unknown; None: no times)
    camera_make: str = ""
    camera_model: str = ""
    times_s: NDArray[np.float64] | None = None

    def __post_init__(self) -> None:
        self.names = np.asarray(self.names, dtype=str)
        self.track_name = np.asarray(self.track_name, dtype=str)
        self.obs_track = np.asarray(self.obs_track, np.int64)
        self.obs_image = np.asarray(self.obs_image, np.int64)
        self.obs_pixel = np.asarray(self.obs_pixel, float).reshape(-1, 2)
        k = 0 if self.control_track is None else len(self.control_track)
        self.control_track = np.asarray(self.control_track if k else np.zeros(0), np.int64)
        self.control_xyz = np.asarray(self.control_xyz if k else np.zeros((0, 3)), float).reshape(k, 3)
        self.control_sigma = np.broadcast_to(np.asarray(0.01 if self.control_sigma is None else self.control_sigma,
                                                        float), (k, 3)).copy()
        self.control_check = (np.zeros(k, bool) if self.control_check is None
                              else np.asarray(self.control_check, bool).reshape(k))
        d = 0 if self.distance_track is None else len(self.distance_track)
        self.distance_track = np.asarray(self.distance_track if d else np.zeros((0, 2)), np.int64).reshape(d, 2)
        self.distance_m = np.asarray(self.distance_m if d else np.zeros(0), float).reshape(d)
        self.distance_sigma_m = np.broadcast_to(np.asarray(0.001 if self.distance_sigma_m is None
                                                           else self.distance_sigma_m, float), (d,)).copy()
        if self.positions is not None:
            self.positions = np.asarray(self.positions, float).reshape(len(self.names), 3)
        if self.times_s is not None:
            self.times_s = np.asarray(self.times_s, float).reshape(len(self.names))


# ---------------------------------------------------------------------------------------------- two-view start
def _pair_counts(inp: OrientInput, use: NDArray[np.bool_] | None = None
                 ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """Image pairs ``(i, j)`` (i < j) with their common-track counts (observations ``use`` only), most first."""
    n = len(inp.names)
    rows = np.arange(len(inp.obs_track)) if use is None else np.flatnonzero(use)
    order = rows[np.lexsort((inp.obs_image[rows], inp.obs_track[rows]))]
    im = inp.obs_image[order]
    ra, rb = _track_pairs(inp.obs_track[order])
    a, b = np.minimum(im[ra], im[rb]), np.maximum(im[ra], im[rb])
    uk, first, counts = np.unique(a * n + b, return_index=True, return_counts=True)
    rank = np.lexsort((first, -counts))
    return uk[rank] // n, uk[rank] % n, counts[rank]


def choose_seed_pair(inp: OrientInput, cfg: OrientConfig, camera: FrameCamera,
                     allowed: NDArray[np.bool_] | None = None) -> tuple[int, int, NDArray, NDArray, dict[str, Any]]:
    """The start pair: ``(i, j, R21, t21 (unit), info)`` with ``x2 = R21 x1 + t21`` in OpenCV camera axes; both
    images among ``allowed`` when given.

    Raises
    ------
    OrientError
        No pair with ``seed_min_common`` common points whose essential matrix has ``pnp_min_inliers`` inliers.
    """
    import cv2

    K, dist = _k_matrix(camera)
    pi, pj, cnt = _pair_counts(inp)
    best: tuple | None = None
    tried = []
    for i, j, c in zip(pi.tolist(), pj.tolist(), cnt.tolist()):
        if c < cfg.seed_min_common or len(tried) >= cfg.seed_candidates:
            break
        if allowed is not None and not (allowed[i] and allowed[j]):
            continue
        mi, mj = inp.obs_image == i, inp.obs_image == j
        _, ci, cj = np.intersect1d(inp.obs_track[mi], inp.obs_track[mj], return_indices=True)
        p1 = cv2.undistortPoints(inp.obs_pixel[mi][ci][:, None], K, dist)[:, 0]
        p2 = cv2.undistortPoints(inp.obs_pixel[mj][cj][:, None], K, dist)[:, 0]
        cv2.setRNGSeed(0)
        E, mask = cv2.findEssentialMat(p1, p2, np.eye(3), cv2.RANSAC, 0.999, cfg.pnp_threshold_px / K[0, 0])
        if E is None or E.shape != (3, 3):
            tried.append((i, j, c, 0, 0.0))
            continue
        nin, R21, t21, mask = cv2.recoverPose(E, p1, p2, np.eye(3), mask=mask)
        inl = mask.ravel() > 0
        r1 = np.column_stack([p1[inl], np.ones(int(inl.sum()))])
        r2 = np.column_stack([p2[inl], np.ones(int(inl.sum()))]) @ R21  # R21^T x2 row-wise: ray 2 in camera-1 axes
        cosang = np.sum(r1 * r2, axis=1) / (np.linalg.norm(r1, axis=1) * np.linalg.norm(r2, axis=1))
        angle = float(np.degrees(np.median(np.arccos(np.clip(cosang, -1, 1))))) if inl.any() else 0.0
        score = nin * min(1.0, angle / cfg.seed_parallax_deg)
        tried.append((i, j, c, int(nin), angle))
        if nin >= cfg.pnp_min_inliers and (best is None or score > best[0]):
            best = (score, i, j, R21, t21[:, 0] / np.linalg.norm(t21), int(nin), angle, c)
    if best is None:
        raise OrientError(f"no image pair to start from: {len(tried)} pair(s) with >= {cfg.seed_min_common} common "
                          f"tie points, none with >= {cfg.pnp_min_inliers} essential-matrix inliers")
    _, i, j, R21, t21, nin, angle, c = best
    info = {"images": [str(inp.names[i]), str(inp.names[j])], "common": int(c), "inliers": nin,
            "median_intersection_angle_deg": angle, "pairs_tried": len(tried)}
    return i, j, R21, t21, info


# ---------------------------------------------------------------------------------------------- blocks
def _usable(inp: OrientInput, oriented: NDArray[np.bool_], X: NDArray, active: NDArray[np.bool_],
            camera: FrameCamera, R: NDArray, C: NDArray, min_angle_deg: float, max_px: float,
            hand_max_px: float = np.inf, cut: dict[tuple[str, str], float] | None = None) -> NDArray[np.bool_]:
    """Observations that can enter an adjustment (:func:`skyrig.orient.gnss_block._usable_obs`; a point counts as
    in front of a camera from 1e-6 of its distance on: close-range rays may graze the image plane; hand
    measurements within ``hand_max_px``)."""
    return _usable_obs(inp, oriented, X, active, camera, R, C, min_angle_deg, max_px, front_tol=1e-6,
                       hand=hand_rows(inp), hand_max_px=hand_max_px, cut=cut)


def _block(inp: OrientInput, camera: FrameCamera, R: NDArray, C: NDArray, X: NDArray, img_sel: NDArray[np.int64],
           obs_sel: NDArray[np.bool_], sigma_px: float, control: bool, distances: bool
           ) -> tuple[Block, NDArray[np.int64], NDArray[np.int64]]:
    """A :class:`Block` of the images ``img_sel`` and the observations ``obs_sel`` (+ control / distances whose
    points are in it).  Returns the block, the tracks of its points and the rows of its observations."""
    n = len(inp.names)
    img_map = np.full(n, -1)
    img_map[img_sel] = np.arange(len(img_sel))
    ot, oi, op = inp.obs_track[obs_sel], inp.obs_image[obs_sel], inp.obs_pixel[obs_sel]
    tracks, tmap = np.unique(ot, return_inverse=True)
    pmap = np.full(len(inp.track_name), -1)
    pmap[tracks] = np.arange(len(tracks))
    kw: dict[str, Any] = {}
    if control and len(inp.control_track):
        k = np.flatnonzero(pmap[inp.control_track] >= 0)
        kw.update(control_point=pmap[inp.control_track[k]], control_xyz=inp.control_xyz[k],
                  control_sigma=inp.control_sigma[k], control_check=inp.control_check[k])
    if distances and len(inp.distance_track):
        k = np.flatnonzero((pmap[inp.distance_track] >= 0).all(axis=1))
        kw.update(distance_point=pmap[inp.distance_track[k]], distance_m=inp.distance_m[k],
                  distance_sigma_m=inp.distance_sigma_m[k])
    names = inp.names[img_sel]
    block = Block(cameras=[camera], station_name=names, station_rotation=R[img_sel], station_centre=C[img_sel],
                  image_name=names, image_station=np.arange(len(img_sel)),
                  image_camera=np.zeros(len(img_sel), np.int64), point_name=inp.track_name[tracks],
                  point_xyz=X[tracks], obs_image=img_map[oi], obs_point=tmap, obs_pixel=op, obs_sigma_px=sigma_px,
                  frame=inp.frame.describe() if inp.frame is not None else "arbitrary Cartesian frame", **kw)
    return block, tracks, np.flatnonzero(obs_sel)


def _with_rolling_shutter(block: Block, inp: OrientInput, cfg: OrientConfig, camera_name: str, C_sel: NDArray,
                          img_sel: NDArray[np.int64]) -> Block:
    """``block`` with the rolling-shutter data of an orientation without GNSS: each image's velocity prior is the
    difference of the block's own (adjusted) centres of its neighbours in capture time over the time between them
    (a relation between unknowns: it fixes neither the frame nor the scale of a free network), with a sigma of
    ``cfg.velocity_sigma_rel`` x the larger of its starting speed and the median one (a drone's speed changes
    between exposures; a hand-held camera stops for each); images without a time get none (the velocity is then
    the images' alone)."""
    times = None if inp.times_s is None else inp.times_s[img_sel]
    pair, dt = velocity_neighbours(times, len(img_sel))
    ok = pair[:, 0] >= 0
    v = np.full((len(img_sel), 3), np.nan)
    v[ok] = (C_sel[pair[ok, 1]] - C_sel[pair[ok, 0]]) / dt[ok, None]
    speed = np.linalg.norm(v, axis=1)
    ref = float(np.median(speed[ok])) if ok.any() else 0.0
    vs = np.full_like(v, np.nan)
    if ref > 0:
        vs[ok] = cfg.velocity_sigma_rel * np.maximum(speed[ok], ref)[:, None]
    return with_rolling_shutter(block, camera_name, v, vs, cfg.readout_s, cfg.readout_sigma_s,
                                cfg.angular_sigma_rad_s, between=pair, dt_s=np.nan_to_num(dt, nan=1.0))


def _residual_norm(b: Block) -> NDArray[np.float64]:
    cam = b.cameras[0]
    R = b.station_rotation[b.image_station[b.obs_image]] @ b.image_rotation[b.obs_image]
    C = b.station_centre[b.image_station[b.obs_image]]
    r = _reproject(cam, R, C, b.point_xyz[b.obs_point]) - b.obs_pixel
    return np.nan_to_num(np.linalg.norm(r, axis=1), nan=np.inf)


def _triangulate(inp: OrientInput, camera: FrameCamera, R: NDArray, C: NDArray, oriented: NDArray[np.bool_],
                 active: NDArray[np.bool_], min_angle_deg: float) -> NDArray[np.float64]:
    sel = oriented[inp.obs_image] & active
    X, ok = triangulate_tracks(camera, np.nan_to_num(R), np.nan_to_num(C), inp.obs_track[sel], inp.obs_image[sel],
                               inp.obs_pixel[sel], len(inp.track_name), min_angle_deg)
    X[~ok] = np.nan
    return X


def _apply_similarity(s: float, Rs: NDArray, t: NDArray, R: NDArray, C: NDArray, X: NDArray) -> None:
    """``x -> s Rs x + t`` on centres and points, ``R -> Rs R`` on rotations (in place)."""
    C[:] = s * C @ Rs.T + t
    X[:] = s * X @ Rs.T + t
    R[:] = Rs @ R


def _resect_round(inp: OrientInput, cfg: OrientConfig, camera: FrameCamera, X: NDArray, R: NDArray, C: NDArray,
                  oriented: NDArray[np.bool_], active: NDArray[np.bool_], allowed: NDArray[np.bool_],
                  check: dict[str, dict[str, Any]]) -> list[int]:
    """Resect the ``allowed`` unoriented images with the most triangulated points (all with >= 60 % of the best
    count; if none of them works, every other candidate once); updates the arrays in place, returns the added."""
    n = len(inp.names)
    X_ok = np.isfinite(X).all(axis=1)
    counts = np.bincount(inp.obs_image[X_ok[inp.obs_track] & active], minlength=n)
    counts[oriented | ~allowed] = 0
    if counts.max(initial=0) < cfg.pnp_min_inliers:
        return []
    added: list[int] = []
    for k in np.argsort(-counts, kind="stable"):
        if counts[k] < cfg.pnp_min_inliers or (added and counts[k] < 0.6 * counts.max()):
            break
        m = (inp.obs_image == k) & X_ok[inp.obs_track] & active
        out = resect(camera, X[inp.obs_track[m]], inp.obs_pixel[m], cfg.pnp_threshold_px, cfg.pnp_min_inliers)
        if out is None:
            continue
        R[k], C[k], inl = out
        mk = np.flatnonzero(m)
        active[mk[~inl & ~is_hand(inp, mk)]] = False  # a RANSAC verdict is no verdict on a click
        oriented[k] = True
        added.append(int(k))
        check[str(inp.names[k])]["orientation"] = f"resection ({int(inl.sum())} inliers)"
    return added


def _relative_pose(inp: OrientInput, cfg: OrientConfig, camera: FrameCamera, o: int, k: int,
                   active: NDArray[np.bool_]) -> tuple[NDArray, NDArray, NDArray, NDArray, int] | None:
    """Essential matrix between an oriented image ``o`` and image ``k`` on their common active tracks:
    ``(R_ko, t_ko (unit), inlier tracks, their pixels in k, inliers)`` with ``x_k = R_ko x_o + t_ko`` in OpenCV
    camera axes, or None (too few inliers)."""
    import cv2

    K, dist = _k_matrix(camera)
    mo, mk = (inp.obs_image == o) & active, (inp.obs_image == k) & active
    common, co, ck = np.intersect1d(inp.obs_track[mo], inp.obs_track[mk], return_indices=True)
    if len(common) < cfg.pnp_min_inliers:
        return None
    po = cv2.undistortPoints(inp.obs_pixel[mo][co][:, None], K, dist)[:, 0]
    pk = cv2.undistortPoints(inp.obs_pixel[mk][ck][:, None], K, dist)[:, 0]
    cv2.setRNGSeed(0)
    E, mask = cv2.findEssentialMat(po, pk, np.eye(3), cv2.RANSAC, 0.999, cfg.pnp_threshold_px / K[0, 0])
    if E is None or E.shape != (3, 3):
        return None
    nin, R_ko, t_ko, mask = cv2.recoverPose(E, po, pk, np.eye(3), mask=mask)
    if nin < cfg.pnp_min_inliers:
        return None
    inl = mask.ravel() > 0
    return R_ko, t_ko[:, 0] / np.linalg.norm(t_ko), common[inl], inp.obs_pixel[mk][ck][inl], int(nin)


def _resect_relative(inp: OrientInput, cfg: OrientConfig, camera: FrameCamera, X: NDArray, R: NDArray, C: NDArray,
                     oriented: NDArray[np.bool_], active: NDArray[np.bool_], check: dict[str, dict[str, Any]]
                     ) -> list[int]:
    """Orient an image that sees too few triangulated points for a resection but shares many tie points with an
    oriented image (a walk turning a corner: the new view's points are seen by one oriented image only).

    The relative orientation of the pair (essential matrix, RANSAC) gives the new image's rotation and the direction
    of the base from the oriented image; only the base length is left, one unknown, taken as the median over the
    triangulated points the new image sees (each gives it from the condition that its ray passes through the point,
    >= 5 points, checked by their reprojection: >= 60 % within ``pnp_threshold_px``).  The pose is then refined with
    the points of the pair triangulated in the block's frame.  Returns the added image (at most one per call)."""
    n = len(inp.names)
    X_ok = np.isfinite(X).all(axis=1)
    # pairs of an unoriented and an oriented image by common active tracks (most first), the 3 best per image
    pi, pj, cnt = _pair_counts(inp, active)
    one = (oriented[pi] != oriented[pj]) & (cnt >= cfg.seed_min_common)
    ks, os_ = np.where(oriented[pi], pj, pi)[one], np.where(oriented[pi], pi, pj)[one]
    cand: list[tuple[int, int]] = []
    per: dict[int, int] = {}
    for k, o in zip(ks.tolist(), os_.tolist()):
        if per.get(k, 0) < 3:
            per[k] = per.get(k, 0) + 1
            cand.append((k, o))
    for k, o in cand:
        rel = _relative_pose(inp, cfg, camera, o, k, active)
        if rel is None:
            continue
        R_ko, t_ko, tracks_in, px_in, nin = rel
        Fo = R[o] @ _SKYRIG_FROM_CV  # world_from_camera in OpenCV axes of image o
        Rk = Fo @ R_ko.T @ _SKYRIG_FROM_CV  # world_from_camera (skyrig axes) of image k
        b = Fo @ (-R_ko.T @ t_ko)  # unit base direction o -> k in the world
        mk = (inp.obs_image == k) & active & X_ok[inp.obs_track]
        if mk.sum() < 5:
            continue
        Xk, pk = X[inp.obs_track[mk]], inp.obs_pixel[mk]
        d = camera.rays_from_pixels(pk) @ Rk.T
        bd = np.cross(b, d)
        den = np.sum(bd * bd, axis=1)
        ok = den > 1e-12 * np.max(den)
        s_i = np.sum(np.cross(Xk - C[o], d) * bd, axis=1)[ok] / den[ok]
        if len(s_i) < 5:
            continue
        s = float(np.median(s_i))
        if not s > 0:
            continue
        Ck = C[o] + s * b
        px = _reproject(camera, np.broadcast_to(Rk, (len(Xk), 3, 3)), np.broadcast_to(Ck, (len(Xk), 3)), Xk)
        good = np.nan_to_num(np.linalg.norm(px - pk, axis=1), nan=np.inf) < cfg.pnp_threshold_px
        if good.sum() < max(5, 0.6 * len(Xk)):
            logger.info("relative tie-in of %s from %s: base length from %d points, only %d reproject within %.1f px",
                        inp.names[k], inp.names[o], len(Xk), int(good.sum()), cfg.pnp_threshold_px)
            continue
        # refine: the pair's inlier tracks triangulated with the new pose, plus the block's points, by resection
        Rt, Ct = R.copy(), C.copy()
        Rt[k], Ct[k] = Rk, Ck
        pair = np.zeros(n, bool)
        pair[[o, k]] = True
        Xp = _triangulate(inp, camera, Rt, Ct, pair, active, cfg.min_angle_deg)
        Xr = np.where(X_ok[:, None], X, Xp)
        m_all = (inp.obs_image == k) & active & np.isfinite(Xr).all(axis=1)[inp.obs_track]
        out = resect(camera, Xr[inp.obs_track[m_all]], inp.obs_pixel[m_all], cfg.pnp_threshold_px,
                     cfg.pnp_min_inliers)
        if out is not None and np.linalg.norm(out[1] - Ck) < 0.5 * s:
            Rk, Ck = out[0], out[1]
        R[k], C[k] = Rk, Ck
        oriented[k] = True
        check[str(inp.names[k])]["orientation"] = (
            f"relative orientation to {inp.names[o]} ({nin} essential-matrix inliers), base length from "
            f"{int(good.sum())} of {len(Xk)} triangulated points")
        logger.info("relative tie-in of %s from %s: %d inliers, base %.3g from %d of %d points", inp.names[k],
                    inp.names[o], nin, s, int(good.sum()), len(Xk))
        return [k]
    return []


def _seed_part(inp: OrientInput, cfg: OrientConfig, camera: FrameCamera, X_main: NDArray,
               oriented: NDArray[np.bool_], active: NDArray[np.bool_], check: dict[str, dict[str, Any]]
               ) -> tuple[NDArray, NDArray, NDArray[np.bool_], NDArray[np.bool_]] | None:
    """A part of the block the growth could not reach: its own two-view start among the unoriented images, grown by
    resection in its own frame, then put into the block's frame by a robust similarity through the tie points both
    have triangulated (>= 12 in common).  Returns ``(R, C, part mask, active)`` or None."""
    n = len(inp.names)
    allowed = ~oriented
    try:
        i, j, R21, t21, info = choose_seed_pair(inp, cfg, camera, allowed)
    except OrientError:
        return None
    R = np.full((n, 3, 3), np.nan)
    C = np.full((n, 3), np.nan)
    R[i], C[i] = _SKYRIG_FROM_CV, np.zeros(3)
    R[j], C[j] = R21.T @ _SKYRIG_FROM_CV, -R21.T @ t21
    part = np.zeros(n, bool)
    part[[i, j]] = True
    act = active.copy()
    sub = {k: dict(v) for k, v in check.items()}
    while True:
        Xp = _triangulate(inp, camera, R, C, part, act, cfg.min_angle_deg)
        if not _resect_round(inp, cfg, camera, Xp, R, C, part, act, allowed, sub):
            break
    Xp = _triangulate(inp, camera, R, C, part, act, cfg.min_angle_deg)
    common = np.flatnonzero(np.isfinite(Xp).all(axis=1) & np.isfinite(X_main).all(axis=1))
    fit = _robust_similarity(Xp[common], X_main[common]) if len(common) >= 12 else None
    if fit is None:
        logger.info("a part of %d images from %s - %s: %d tie points in common with the block, no similarity",
                    int(part.sum()), *info["images"], len(common))
        return None
    s, Rs, t, n_in = fit
    _apply_similarity(s, Rs, t, R, C, Xp)
    for k in np.flatnonzero(part):
        check[str(inp.names[k])].update(sub[str(inp.names[k])])
        check[str(inp.names[k])]["part"] = (f"own two-view start {info['images'][0]} - {info['images'][1]}, tied to "
                                            f"the block through {n_in} common tie points")
    logger.info("a part of %d images (start %s - %s) tied to the block through %d of %d common tie points",
                int(part.sum()), *info["images"], n_in, len(common))
    return R, C, part, act


# ---------------------------------------------------------------------------------------------- main
def _resolve_datum(inp: OrientInput, cfg: OrientConfig) -> Datum:
    d = cfg.datum
    has_ctrl = int((~inp.control_check).sum()) >= 3
    has_pos = inp.positions is not None and int(np.isfinite(inp.positions).all(axis=1).sum()) >= cfg.min_positions
    if d == "auto":
        d = ("control" if has_ctrl else "scale-bar" if len(inp.distance_track) else "positions" if has_pos
             else "free")
    if d == "control" and not has_ctrl:
        raise OrientError(f"datum 'control' needs >= 3 control points, {int((~inp.control_check).sum())} given")
    if d == "scale-bar" and not len(inp.distance_track):
        raise OrientError("datum 'scale-bar' needs at least one scale bar")
    if d == "positions" and not has_pos:
        raise OrientError(f"datum 'positions' needs >= {cfg.min_positions} images with an approximate position")
    return d  # type: ignore[return-value]


def orient_incremental(inp: OrientInput, cfg: OrientConfig = OrientConfig()) -> UavResult:
    """Orient an image block without GNSS observations (module docstring).  The result has the fields of
    :class:`~skyrig.orient.gnss_block.UavResult` (``summary["datum"]`` says how the datum was fixed).

    Raises
    ------
    OrientError
        No start pair, fewer than three oriented images, or a datum that the data cannot give (control points
        or scale bars not triangulated, control that does not fit a similarity).
    """
    t_start = time.perf_counter()
    datum = _resolve_datum(inp, cfg)
    n, T = len(inp.names), len(inp.track_name)
    # the given camera's own distortion model is kept (a calibrated Brown camera stays Brown); a camera without one
    # gets OpenCV's, the one the self-calibration names refer to.  The start (essential matrix, resection) leaves out
    # a non-OpenCV distortion (triangulation._k_matrix); every adjustment uses the full model.
    camera = inp.camera.with_(distortion=OpenCVDistortion()) if isinstance(inp.camera.distortion, NoDistortion) \
        else inp.camera
    nominal = camera  # the centre of the self-calibration's priors in the final adjustment
    check: dict[str, dict[str, Any]] = {str(nm): {"metadata": "no position or attitude used (orientation without "
                                                  "GNSS)"} for nm in inp.names}
    # ---- 1. two-view start
    i, j, R21, t21, seed_info = choose_seed_pair(inp, cfg, camera)
    R = np.full((n, 3, 3), np.nan)
    C = np.full((n, 3), np.nan)
    R[i], C[i] = _SKYRIG_FROM_CV, np.zeros(3)
    R[j], C[j] = R21.T @ _SKYRIG_FROM_CV, -R21.T @ t21
    oriented = np.zeros(n, bool)
    oriented[[i, j]] = True
    check[str(inp.names[i])]["orientation"] = check[str(inp.names[j])]["orientation"] = "two-view start"
    logger.info("start pair %s - %s: %d inliers, median intersection angle %.1f deg", *seed_info["images"],
                seed_info["inliers"], seed_info["median_intersection_angle_deg"])
    active = np.ones(len(inp.obs_track), bool)
    hand = hand_rows(inp)  # hand measurements (control, check, scale bars)
    hand_cut: dict[tuple[str, str], float] = {}  # those cut as blunders
    # growth adjustments only need to be close (the final one converges): looser tolerances than the default
    grow_cfg = AdjustConfig(solver=SolverOptions(robust="huber", robust_k=cfg.robust_k,
                                                 max_iterations=cfg.max_iterations,
                                                 function_tolerance=1e-4,
                                                 parameter_tolerance=1e-6),
                            statistics=StatisticsOptions(compute=False),
                            unknowns=Unknowns(datum="free"))
    sigma_grow = max(2.0 * cfg.pixel_sigma_px, 2.0)
    X = _triangulate(inp, camera, R, C, oriented, active, cfg.min_angle_deg)
    last_ba, rounds, order = 0, 0, [int(i), int(j)]

    # focal length and radial distortion are self-calibrated during growth from the 3rd image on (an EXIF focal
    # length can be off by a third: lund's phone 995 px in the EXIF, about 730 px by skyrig and pycolmap alike),
    # so that resection and triangulation work with a camera close to the true one
    f0 = inp.camera.focal_mm
    grow_cal = tuple(nm for nm in ("focal_mm", "k1") if nm in cfg.self_calibration and nm in camera.intrinsic_names)
    f_rel = next(x for x in (cfg.focal_prior_rel, inp.focal_prior_rel, 0.1) if x is not None)
    grow_sig = {"focal_mm": f_rel * f0, "k1": 1.0}

    def bundle(X: NDArray) -> NDArray:
        nonlocal camera
        img_sel = np.flatnonzero(oriented)
        gate = 0.05 * max(camera.width, camera.height) if last_ba == 0 else 6.0 * cfg.pnp_threshold_px
        obs = _usable(inp, oriented, X, active, camera, R, C, cfg.min_angle_deg, gate, cfg.hand_cut_px)
        cal = grow_cal if len(img_sel) >= 3 else ()
        # (the prior of a weighted intrinsic is its start value in skyrig.adjust: during growth the prior follows the
        # current estimate; the final adjustment centres the priors on the EXIF camera again)
        block, tracks, rows = _block(inp, camera, R, C, X, img_sel, obs, sigma_grow, False, False)
        gcfg = grow_cfg.with_unknowns(intrinsics="weighted", intrinsic_names=cal,
                                      intrinsic_sigma=tuple((k, grow_sig[k]) for k in cal)) if cal else grow_cfg
        try:
            with intermediate_adjustment():
                res = adjust(block, gcfg)
        except SkyrigError as exc:
            raise OrientError(f"adjustment of the {len(img_sel)} oriented images failed: {exc}") from exc
        camera = res.block.cameras[0]
        R[img_sel], C[img_sel] = res.block.station_rotation, res.block.station_centre
        Xn = np.full((T, 3), np.nan)
        Xn[tracks] = res.block.point_xyz
        r = _residual_norm(res.block)
        med = float(np.median(r)) if len(r) else 0.0
        bad = spare_hand(inp, rows, r > max(6.0 * 1.4826 * med, 3.0 * cfg.reject_min_px), r, hand, cfg.hand_cut_px,
                         hand_cut)
        active[rows[bad]] = False
        logger.info("growth: %d images, %d points, median residual %.2f px, %d observations removed", len(img_sel),
                    block.n_points, med, int(bad.sum()))
        return Xn

    X = bundle(X)
    last_ba = 2
    # ---- 2. growth
    parts = relative = 0
    while not oriented.all():
        rounds += 1
        X_tri = _triangulate(inp, camera, R, C, oriented, active, cfg.min_angle_deg)
        X = np.where(np.isfinite(X).all(axis=1)[:, None], X, X_tri)
        added = _resect_round(inp, cfg, camera, X, R, C, oriented, active, np.ones(n, bool), check)
        if not added:
            # an image sharing many tie points with one oriented image but few triangulated points: relative
            # orientation to that image, the base length from the points it sees
            added = _resect_relative(inp, cfg, camera, X, R, C, oriented, active, check)
            relative += len(added)
        if not added:
            # a part the tie points do not reach through triangulated points: its own start, tied in by common points
            got = _seed_part(inp, cfg, camera, X, oriented, active, check)
            if got is None:
                break
            Rp, Cp, part, act = got
            active[:] = act
            R[part], C[part] = Rp[part], Cp[part]
            oriented |= part
            added = [int(k) for k in np.flatnonzero(part)]
            parts += 1
        order += added
        logger.info("round %d: oriented %s", rounds, ", ".join(inp.names[added]))
        n_or = int(oriented.sum())
        if n_or <= cfg.ba_always_below or n_or >= (1.0 + cfg.ba_growth) * last_ba or oriented.all() or len(added) > 1:
            X = bundle(np.where(np.isfinite(X).all(axis=1)[:, None], X,
                                _triangulate(inp, camera, R, C, oriented, active, cfg.min_angle_deg)))
            last_ba = n_or
    if oriented.sum() < 3:
        raise OrientError(f"only {int(oriented.sum())} images could be oriented")
    X = np.where(np.isfinite(X).all(axis=1)[:, None], X,
                 _triangulate(inp, camera, R, C, oriented, active, cfg.min_angle_deg))
    # ---- 3. datum
    img_sel = np.flatnonzero(oriented)
    datum_info: dict[str, Any] = {"kind": datum}
    if datum == "control":
        use = ~inp.control_check
        ct = inp.control_track[use]
        have = np.isfinite(X[ct]).all(axis=1)
        if have.sum() < 3:
            raise OrientError(f"only {int(have.sum())} of the {int(use.sum())} control points are triangulated "
                              "(measured in >= 2 oriented images): a datum needs 3")
        from skyrig.match.colmap_check import similarity_transform

        src, dst = X[ct[have]], inp.control_xyz[use][have]
        s, Rs, t = similarity_transform(src, dst)
        v = np.linalg.norm(s * src @ Rs.T + t - dst, axis=1)
        spread = float(np.sqrt(np.mean(np.sum((dst - dst.mean(axis=0)) ** 2, axis=1))))
        if spread <= 0 or np.linalg.matrix_rank(dst - dst.mean(axis=0), tol=1e-3 * spread) < 2:
            raise OrientError("the control points are (nearly) collinear: no datum")
        # judged against the control's declared sigmas too: metre-class targets (handheld GNSS, a loose height)
        # leave metres of residual that are no blunder when their sigmas say so
        sig = np.broadcast_to(np.asarray(inp.control_sigma if inp.control_sigma is not None else 0.01, float),
                              inp.control_xyz.shape)[use][have]
        nres = np.max(np.abs(s * src @ Rs.T + t - dst) / np.maximum(sig, 1e-9), axis=1)
        if float(np.median(v)) > 0.05 * spread and float(np.median(nres)) > 5.0:
            raise OrientError(f"the control points do not fit the relative orientation by a similarity (median "
                              f"residual {np.median(v):.3g} m over a spread of {spread:.3g} m, "
                              f"{np.median(nres):.1f} x their declared sigmas): wrong coordinates "
                              "or wrong image measurements")
        _apply_similarity(s, Rs, t, R, C, X)
        datum_info.update(control_points=int(have.sum()), similarity_residual_max_m=float(v.max()))
    elif datum == "scale-bar":
        a, b = inp.distance_track[:, 0], inp.distance_track[:, 1]
        d_model = np.linalg.norm(X[a] - X[b], axis=1)
        ok = np.isfinite(d_model) & (d_model > 0)
        if not ok.any():
            raise OrientError("no scale bar has both ends triangulated (measured in >= 2 oriented images)")
        s = float(np.median(inp.distance_m[ok] / d_model[ok]))
        c0 = np.nanmean(C[img_sel], axis=0)
        _apply_similarity(s, np.eye(3), c0 - s * c0, R, C, X)
        datum_info.update(scale_bars=int(ok.sum()), start_scale=s)
    elif datum == "positions":
        P = inp.positions
        have = np.flatnonzero(oriented & np.isfinite(P).all(axis=1))  # type: ignore[union-attr]
        fit = _robust_similarity(C[have], P[have]) if len(have) >= 12 else None  # type: ignore[index]
        if fit is None:
            from skyrig.match.colmap_check import similarity_transform

            s, Rs, t = similarity_transform(C[have], P[have])  # type: ignore[index]
        else:
            s, Rs, t, _ = fit
        G = P[have] - P[have].mean(axis=0)  # type: ignore[index]
        sv = np.linalg.svd(G, compute_uv=False)
        if sv[1] < 0.05 * sv[0]:
            datum_info["warning"] = ("the approximate positions are (nearly) collinear: the rotation about their line "
                                     "is poorly determined")
        _apply_similarity(s, Rs, t, R, C, X)
    # ---- 4. final adjustment
    w_mm = camera.width * camera.pixel_size_mm
    sig = {"focal_mm": f_rel * f0, "ppx_mm": 0.05 * w_mm, "ppy_mm": 0.05 * w_mm,
           "k1": 1.0, "k2": 1.0, "k3": 1.0, "p1": 0.1, "p2": 0.1, "b1": 0.01, "b2": 0.01}
    names_cal = tuple(nm for nm in camera.intrinsic_names if nm in cfg.self_calibration)
    rs_on, rs_words = rolling_shutter_decision(cfg.rolling_shutter, inp.camera_make, inp.camera_model)
    final_unknowns = Unknowns(intrinsics="weighted" if names_cal else "fixed", intrinsic_names=names_cal or None,
                              intrinsic_sigma=tuple((k, v) for k, v in sig.items() if k in names_cal),
                              datum="auto" if datum == "control" else "free")
    if rs_on:
        final_unknowns = rolling_shutter_unknowns(final_unknowns,
                                                  readout="free" if cfg.estimate_readout else "fixed")
    final_cfg = AdjustConfig(unknowns=final_unknowns,
                             solver=SolverOptions(robust="huber", robust_k=cfg.robust_k,
                                                  max_iterations=cfg.max_iterations),
                             statistics=StatisticsOptions(compute=False))
    use_ctrl = use_dist = datum in ("control", "scale-bar")

    def final_block(Rc: NDArray, Cc: NDArray, Xc: NDArray, obs_sel: NDArray[np.bool_]
                    ) -> tuple[Block, NDArray[np.int64], NDArray[np.int64]]:
        blk, trk, rws = _block(inp, nominal, Rc, Cc, Xc, img_sel, obs_sel, cfg.pixel_sigma_px, use_ctrl, use_dist)
        if rs_on:
            blk = _with_rolling_shutter(blk, inp, cfg, camera.name, Cc[img_sel], img_sel)
        return blk, trk, rws

    use_ctrl = use_dist = datum in ("control", "scale-bar")
    lim = 2.0 * cfg.pnp_threshold_px
    for stage in range(2):
        obs = _usable(inp, oriented, X, active, camera, R, C, cfg.min_angle_deg, lim, cfg.hand_cut_px)
        # the priors are centred on the nominal (EXIF) camera in every stage and the solve starts from the current
        # estimate (``start=``): restarting at the EXIF focal length (lund: 995 px for about 730) walks the weakly
        # determined focal valley again and can end on the function tolerance short of the minimum
        block, tracks, rows = final_block(R, C, X, obs)
        res = adjust(block, final_cfg, start=replace(block, cameras=[camera]))
        camera = res.block.cameras[0]
        R[img_sel], C[img_sel] = res.block.station_rotation, res.block.station_centre
        X[:] = np.nan
        X[tracks] = res.block.point_xyz
        r = _residual_norm(res.block)
        robust_rms = float(np.median(r)) / np.sqrt(np.log(4.0))  # Rayleigh median = sigma sqrt(ln 4)
        lim = max(cfg.reject_k * robust_rms * np.sqrt(2.0), cfg.reject_min_px)
        bad = spare_hand(inp, rows, r > lim, r, hand, cfg.hand_cut_px, hand_cut)
        active[rows[bad]] = False
        logger.info("final stage %d: sigma per axis %.3f px (robust), %d observations above %.2f px removed", stage,
                    robust_rms, int(bad.sum()), lim)
    X = np.where(np.isfinite(X).all(axis=1)[:, None], X,
                 _triangulate(inp, camera, R, C, oriented, active, cfg.min_angle_deg))
    obs = _usable(inp, oriented, X, active, camera, R, C, cfg.min_angle_deg, lim, cfg.hand_cut_px, hand_cut)
    block, tracks, rows = final_block(R, C, X, obs)
    res = adjust(block, final_cfg.with_solver(robust=None).with_statistics(compute=True), start=replace(block, cameras=[camera]))
    verdicts: list[Any] = []
    if names_cal:
        from skyrig.adjust.determinability import hold_undetermined

        def readjust(r: AdjustmentResult, names: tuple[str, ...], start_cam: FrameCamera) -> AdjustmentResult:
            R2, C2 = R.copy(), C.copy()
            R2[img_sel], C2[img_sel] = r.block.station_rotation, r.block.station_centre
            blk, _, _ = final_block(R2, C2, X, obs)
            blk = replace(blk, point_xyz=np.array(r.block.point_xyz, float))  # same observations: same points
            c2 = final_cfg.with_unknowns(intrinsics="weighted" if names else "fixed", intrinsic_names=names or None,
                                         intrinsic_sigma=tuple((k, v) for k, v in sig.items() if k in names)).with_solver(robust=None).with_statistics(compute=True)
            return adjust(blk, c2, start=replace(blk, cameras=[start_cam]))

        res, verdicts, names_cal = hold_undetermined(res, nominal, names_cal, sig, readjust,
                                                     ratio_max=cfg.determinable_ratio, z_max=cfg.prior_conflict_z,
                                                     free_anyway=cfg.free_anyway, strong_ratio=cfg.overrule_ratio)
    camera = res.block.cameras[0]
    R[img_sel], C[img_sel] = res.block.station_rotation, res.block.station_centre
    Rout = np.full((n, 3, 3), np.nan)
    Cout = np.full((n, 3), np.nan)
    Rout[img_sel], Cout[img_sel] = R[img_sel], C[img_sel]
    if datum == "positions":
        P = inp.positions
        have = np.flatnonzero(oriented & np.isfinite(P).all(axis=1))  # type: ignore[union-attr]
        from skyrig.match.colmap_check import similarity_transform

        s, Rs, t = similarity_transform(Cout[have], P[have])  # type: ignore[index]
        v = s * Cout[have] @ Rs.T + t - P[have]  # type: ignore[index]
        datum_info.update(images_with_positions=int(len(have)), similarity_scale=float(s),
                          positions_similarity_rms_3d_m=float(np.sqrt(np.mean(np.sum(v ** 2, axis=1)))),
                          positions_similarity_rms_xyz_m=np.sqrt(np.mean(v ** 2, axis=0)).tolist(),
                          positions_similarity_max_m=float(np.linalg.norm(v, axis=1).max()),
                          per_image_m={str(inp.names[k]): float(np.linalg.norm(v[q])) for q, k in enumerate(have)})
    if datum == "free":
        datum_info["note"] = "inner constraints; frame and scale of the relative orientation (start base = 1)"
    from skyrig.adjust.determinability import rule_words

    summary = _summary(inp, res, oriented, camera, rounds, time.perf_counter() - t_start)
    summary.update(datum=datum_info, seed=seed_info, order=[str(inp.names[k]) for k in order],
                   parts_tied_in=parts, relative_tie_ins=relative,
                   calibration=[v.to_dict() for v in verdicts], calibration_held=[v.name for v in verdicts if v.held],
                   calibration_rule=rule_words(cfg.determinable_ratio, cfg.prior_conflict_z, cfg.overrule_ratio))
    summary.update(ground_point_summary(inp, res.block, hand_cut, cfg.hand_cut_px))
    summary["rolling_shutter"] = rolling_shutter_summary(res, rs_on, rs_words)
    return UavResult(inp.names, oriented, Rout, Cout, camera, res, img_sel, check, summary)


def _summary(inp: OrientInput, res: AdjustmentResult, oriented: NDArray, camera: FrameCamera, rounds: int,
             wall_s: float) -> dict[str, Any]:
    b = res.block
    img = res.residuals["image"]
    act = img.weight > 0
    v = img.residual[act]
    per_image = np.bincount(b.obs_image[act], minlength=b.n_images)
    out: dict[str, Any] = {
        "images": int(len(inp.names)), "oriented": int(oriented.sum()),
        "not_oriented": [str(x) for x in inp.names[~oriented]],
        "tie_points": int(len(np.unique(b.obs_point[act]))), "image_observations": int(act.sum()),
        "tie_points_per_image": {str(b.image_name[k]): int(per_image[k]) for k in range(b.n_images)},
        "reprojection_rms_px": float(np.sqrt(np.mean(v ** 2))) if len(v) else float("nan"),
        "reprojection_rms_xy_px": np.sqrt(np.mean(v ** 2, axis=0)).tolist() if len(v) else [],
        "sigma0": res.sigma0,
        "camera": dict(zip(camera.intrinsic_names, np.asarray(camera.intrinsics).tolist())),
        "distortion_model": camera.distortion.name, "self_calibrated": list(res.config.unknowns.intrinsic_names or ()) if res.config.unknowns.intrinsics != "fixed" else [],
        "focal_px": camera.focal_mm / camera.pixel_size_mm,
        "focal_px_exif": inp.camera.focal_mm / inp.camera.pixel_size_mm,
        "growth_rounds": rounds, "wall_s": wall_s, "notes": list(inp.notes),
    }
    ps = res.pose_sigma
    if ps is not None:  # predicted sigma of the projection centres (m, frame axes), per image
        out["centre_sigma_m"] = {str(b.image_name[k]): ps[b.image_station[k], :3].tolist() for k in range(b.n_images)}
    if "control" in res.residuals and len(res.residuals["control"].residual):
        cr = res.residuals["control"].residual
        chk = np.asarray(b.control_check, bool) if b.control_check is not None else np.zeros(len(cr), bool)
        if (~chk).any():  # control rows only: the check points' differences are the check, not the fit
            out["control_fit_rms_xyz_m"] = np.sqrt(np.mean(cr[~chk] ** 2, axis=0)).tolist()
    if "distance" in res.residuals and len(res.residuals["distance"].residual):
        out["scale_bar_residuals_m"] = np.asarray(res.residuals["distance"].residual).ravel().tolist()
    return out
