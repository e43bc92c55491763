"""Descriptor matching with geometric verification; optional search narrowed by predicted epipolar geometry.

* Putative matches: nearest neighbour in descriptor space (OpenCV brute force, L2) with Lowe's ratio test and
  a mutual (cross) check.
* Guided search: when both images have an approximate exterior orientation (direct georeferencing), the
  fundamental matrix predicted from it restricts each feature's candidates to a band around its epipolar
  line before the nearest-neighbour and ratio tests, so repetitive texture far from the line cannot win.
* Verification: fundamental matrix by MAGSAC++ (OpenCV USAC), or the essential matrix when the interior
  orientations are known; a pair with too few inliers is rejected with a stated reason.
* Local consistency (:func:`consistent_matches`): an epipolar model cannot see a false match that slid along its
  epipolar line (tens to hundreds of pixels off, about 0.5-1 % of the inliers on textured terrain); each inlier
  is therefore also predicted from a robust affine fit to its nearest neighbouring inliers (itself left out)
  and dropped when it misses the prediction by more than ``MatchConfig.consistency_px``.

All pixel coordinates are full-resolution skyrig pixels (column, row; origin at the top-left pixel centre).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from skyrig.camera.frame import FrameCamera
from skyrig.geometry.pose import Pose
from skyrig.match.features import Features
from skyrig.errors import ConfigError

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class MatchConfig:
    """Matching and verification settings."""

    #: Lowe's ratio test threshold (nearest / second-nearest descriptor distance).
    ratio: float = 0.8
    #: Keep only matches that are mutual nearest neighbours.
    mutual: bool = True
    #: ``"fundamental"`` (uncalibrated, MAGSAC++) or ``"essential"`` (needs cameras).
    verification: str = "fundamental"
    #: RANSAC inlier threshold in pixels *of the detection level* (scaled to full resolution by the
    #: keypoint-scale ratio automatically through ``threshold_scale``).
    ransac_px: float = 1.0
    #: Multiply ``ransac_px`` by this (use the full-resolution / detection-level factor).
    threshold_scale: float = 1.0
    #: Minimum number of verified inliers for a pair to count as matched.
    min_inliers: int = 20
    #: Half width (full-resolution pixels) of the band around the predicted epipolar line when guided;
    #: it must cover the errors of the approximate orientations.
    epipolar_band_px: float = 100.0
    #: Nearest-neighbour search: ``"flann"`` (kd-trees, fast, approximate) or ``"bruteforce"`` (exact).
    matcher: str = "flann"
    #: Guided search: descriptor candidates per feature screened against the epipolar band.
    candidates: int = 10
    #: When the guided search fails verification, retry without the epipolar band.
    unguided_fallback: bool = True
    #: RANSAC confidence and iteration cap.
    confidence: float = 0.9999
    max_iterations: int = 10000
    #: Local-consistency check after verification: drop an inlier that misses the position predicted by a
    #: robust affine fit to its ``consistency_neighbours`` nearest inliers by more than this many pixels *of the
    #: detection level* (scaled by ``threshold_scale`` like ``ransac_px``).  None switches the check off.
    consistency_px: float | None = 2.0
    #: Neighbouring inliers per local affine fit (at least 5).
    consistency_neighbours: int = 10

    def __post_init__(self) -> None:
        if not 0 < self.ratio <= 1:
            raise ConfigError("ratio must be in (0, 1]")
        if self.verification not in ("fundamental", "essential"):
            raise ConfigError(f"unknown verification {self.verification!r} (fundamental or essential)")
        if self.matcher not in ("flann", "bruteforce"):
            raise ConfigError(f"unknown matcher {self.matcher!r} (flann or bruteforce)")
        if self.min_inliers < 8:
            raise ConfigError("min_inliers must be at least 8")
        if self.consistency_px is not None and not self.consistency_px > 0:
            raise ConfigError("consistency_px must be positive (or None to switch the check off)")
        if self.consistency_neighbours < 5:
            raise ConfigError("consistency_neighbours must be at least 5")


@dataclass(frozen=True)
class PairMatches:
    """Verified matches of one image pair.

    Attributes
    ----------
    matches
        ``(M, 2)`` feature indices (into image 1, into image 2) of the verified inliers.
    F
        ``(3, 3)`` fundamental matrix in full-resolution skyrig pixels (``x2^T F x1 = 0``), NaN if none.
    n_putative
        Number of putative matches before verification.
    guided
        Whether the search was narrowed by a predicted epipolar geometry.
    reason
        Empty when accepted, else why the pair was rejected.
    """

    matches: NDArray[np.int64]
    F: NDArray[np.float64]
    n_putative: int
    guided: bool = False
    reason: str = ""

    @property
    def ok(self) -> bool:
        return not self.reason

    def __len__(self) -> int:
        return len(self.matches)


def _hom(xy: NDArray) -> NDArray:
    return np.column_stack([xy, np.ones(len(xy))])


def predicted_fundamental(
    camera1: FrameCamera, world_from_camera1: Pose, camera2: FrameCamera, world_from_camera2: Pose,
    depth_range_m: tuple[float, float] | None = None,
) -> NDArray[np.float64]:
    """Fundamental matrix ``(3, 3)`` (pixels, ``x2^T F x1 = 0``) predicted from two exterior orientations.

    Built from exact synthetic correspondences (rays of a pixel grid of image 1 at several depths, projected
    into image 2 by the skyrig camera model, normalised 8-point), so it follows skyrig's camera conventions
    exactly for distortion-free cameras and approximately otherwise.

    Raises
    ------
    GeometryError
        The two projection centres coincide (no epipolar geometry).
    """
    import cv2

    from skyrig.errors import GeometryError

    c1, c2 = world_from_camera1.translation, world_from_camera2.translation
    base = float(np.linalg.norm(c2 - c1))
    if base < 1e-6:
        raise GeometryError("coincident projection centres: no epipolar geometry")
    g = np.linspace(0.05, 0.95, 7)
    px = np.stack(np.meshgrid(g * camera1.width, g * camera1.height), -1).reshape(-1, 2)
    rays_c = camera1.rays_from_pixels(px)
    d = world_from_camera1.rotate(rays_c)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    lo, hi = depth_range_m or (base, 50.0 * base)
    x1s, x2s = [], []
    for depth in np.geomspace(lo, hi, 4):
        X = c1 + depth * d
        x2 = camera2.world_to_pixel(world_from_camera2, X)
        ok = np.all(np.isfinite(x2), axis=1)
        x1s.append(px[ok])
        x2s.append(x2[ok])
    x1, x2 = np.concatenate(x1s), np.concatenate(x2s)
    if len(x1) < 8:
        raise GeometryError("too few points in front of both cameras to predict the epipolar geometry")
    F, _ = cv2.findFundamentalMat(x1, x2, cv2.FM_8POINT)
    if F is None or F.shape != (3, 3):
        raise GeometryError("could not predict a fundamental matrix from the orientations")
    return F / np.linalg.norm(F)


def epipolar_distance(F: NDArray, x1: NDArray, x2: NDArray) -> NDArray[np.float64]:
    """Symmetric-free distance ``(N1, N2)`` in image 2 of every ``x2`` from the epipolar line of every ``x1``."""
    lines = _hom(x1) @ F.T  # (N1, 3): l2 = F x1
    norm = np.hypot(lines[:, 0], lines[:, 1])[:, None]
    return np.abs(lines @ _hom(x2).T) / np.maximum(norm, 1e-12)


def _knn_k(d1: NDArray, d2: NDArray, k: int, method: str) -> tuple[NDArray, NDArray]:
    """k nearest neighbours of every row of d1 in d2: ``(N1, k)`` indices (-1 = none) and distances (inf)."""
    import cv2

    k = max(1, min(k, len(d2)))
    if method == "flann":
        m = cv2.FlannBasedMatcher({"algorithm": 1, "trees": 4}, {"checks": 128})
    else:
        m = cv2.BFMatcher(cv2.NORM_L2)
    res = m.knnMatch(d1, d2, k=k)
    idx = np.full((len(d1), k), -1, np.int64)
    dist = np.full((len(d1), k), np.inf)
    for row in res:
        for c, mm in enumerate(row[:k]):
            idx[mm.queryIdx, c] = mm.trainIdx
            dist[mm.queryIdx, c] = mm.distance
    return idx, dist


def _best_two(idx: NDArray, dist: NDArray, allowed: NDArray | None) -> tuple[NDArray, NDArray, NDArray]:
    """Nearest and second-nearest among the allowed candidates of each row."""
    d = np.where(idx >= 0, dist, np.inf)
    if allowed is not None:
        d = np.where(allowed, d, np.inf)
    order = np.argsort(d, axis=1, kind="stable")[:, :2]
    r = np.arange(len(idx))[:, None]
    best = idx[r[:, 0], order[:, 0]]
    d1 = d[r[:, 0], order[:, 0]]
    d2 = d[r[:, 0], order[:, 1]] if d.shape[1] > 1 else np.full(len(d), np.inf)
    best = np.where(np.isfinite(d1), best, -1)
    return best, d1, d2


def _epi_ok(F: NDArray, xa: NDArray, xb_cand: NDArray, band: float) -> NDArray[np.bool_]:
    """Whether candidates ``xb_cand`` ``(N, k, 2)`` lie within ``band`` of the epipolar lines of ``xa`` ``(N, 2)``
    (lines ``F xa``)."""
    lines = _hom(xa) @ F.T  # (N, 3)
    num = lines[:, None, 0] * xb_cand[..., 0] + lines[:, None, 1] * xb_cand[..., 1] + lines[:, None, 2]
    return np.abs(num) <= band * np.maximum(np.hypot(lines[:, 0], lines[:, 1]), 1e-12)[:, None]


def putative_matches(
    f1: Features, f2: Features, config: MatchConfig = MatchConfig(), F_pred: NDArray | None = None
) -> NDArray[np.int64]:
    """Ratio-tested (and mutual) nearest-neighbour matches ``(M, 2)``.

    With ``F_pred`` the search is narrowed to the epipolar band: each feature's ``config.candidates`` nearest
    descriptors are filtered to those within ``config.epipolar_band_px`` of its predicted epipolar line, and
    the ratio test runs among the survivors.
    """
    if len(f1) < 2 or len(f2) < 2:
        return np.zeros((0, 2), np.int64)
    d1 = f1.descriptors.astype(np.float32)
    d2 = f2.descriptors.astype(np.float32)
    k = config.candidates if F_pred is not None else 2
    i12, s12 = _knn_k(d1, d2, k, config.matcher)
    allowed = None
    if F_pred is not None:
        allowed = (i12 >= 0) & _epi_ok(F_pred, f1.xy, f2.xy[np.maximum(i12, 0)], config.epipolar_band_px)
    idx, a, b = _best_two(i12, s12, allowed)
    good = (idx >= 0) & (a < config.ratio * b)
    m = np.column_stack([np.nonzero(good)[0], idx[good]])
    if config.mutual and len(m):
        i21, s21 = _knn_k(d2, d1, k, config.matcher)
        allowed21 = None
        if F_pred is not None:
            allowed21 = (i21 >= 0) & _epi_ok(F_pred.T, f2.xy, f1.xy[np.maximum(i21, 0)], config.epipolar_band_px)
        back, _, _ = _best_two(i21, s21, allowed21)
        m = m[back[m[:, 1]] == m[:, 0]]
    return m.astype(np.int64)


def consistent_matches(
    xy1: NDArray, xy2: NDArray, tol_px: float, k: int = 10, iterations: int = 4,
) -> NDArray[np.bool_]:
    """Which matches agree with their neighbours: ``(N,)`` bool.

    For every match ``i`` the affine map image 1 -> image 2 is fitted (least squares, 6 parameters) to the
    ``k`` matches nearest to it in image 1, *without* match ``i``; neighbours that miss the fit by more than
    ``max(tol_px, 2.5 x`` the median miss ``)`` are dropped and the fit repeated (``iterations`` times), so a
    false neighbour cannot drag the prediction.  Match ``i`` is consistent when its image-2 position is within
    ``tol_px`` of the prediction at its image-1 position and at least 4 neighbours support the fit.

    The affine model is local: on a 3-D scene a match on a small roof among ground matches (a parallax jump)
    can be dropped too; that loses a few true ties but keeps no false ones.

    Parameters
    ----------
    xy1, xy2
        ``(N, 2)`` matched pixels in image 1 and image 2.
    tol_px
        Largest accepted miss, image-2 pixels.
    k
        Neighbours per fit (clipped to ``N - 1``).

    Returns
    -------
    ``(N,)`` True for consistent matches (all True when ``N < 6``: too few to judge).
    """
    from scipy.spatial import cKDTree

    x1 = np.asarray(xy1, dtype=np.float64).reshape(-1, 2)
    x2 = np.asarray(xy2, dtype=np.float64).reshape(-1, 2)
    n = len(x1)
    if n < 6:
        return np.ones(n, bool)
    kk = min(int(k), n - 1)
    _, idx = cKDTree(x1).query(x1, k=kk + 1)
    idx = idx[:, 1:]  # leave the match itself out
    d = x1[idx] - x1[:, None, :]  # (N, k, 2) neighbour offsets from the query point
    scale = np.maximum(np.abs(d).max(axis=(1, 2)), 1e-9)[:, None, None]
    D = np.concatenate([d / scale, np.ones(d.shape[:2] + (1,))], axis=2)  # (N, k, 3), conditioned
    Y = x2[idx]  # (N, k, 2)
    w = np.ones(idx.shape)
    P = np.zeros((n, 3, 2))
    for _ in range(max(1, iterations)):
        WD = D * w[..., None]
        N_ = np.einsum("nki,nkj->nij", WD, D) + 1e-9 * np.eye(3)
        b = np.einsum("nki,nkj->nij", WD, Y)
        P = np.linalg.solve(N_, b)  # (N, 3, 2): rows a_x, a_y (scaled), translation = prediction at the query
        r = np.linalg.norm(Y - np.einsum("nki,nij->nkj", D, P), axis=2)  # (N, k)
        med = np.median(np.where(w > 0, r, np.nan), axis=1)
        w_new = (r <= np.maximum(tol_px, 2.5 * np.nan_to_num(med, nan=0.0))[:, None]).astype(np.float64)
        if np.array_equal(w_new, w):
            break
        w = w_new
    miss = np.linalg.norm(x2 - P[:, 2, :], axis=1)
    return (miss <= tol_px) & (w.sum(axis=1) >= 4)


def verify(
    xy1: NDArray, xy2: NDArray, matches: NDArray, config: MatchConfig = MatchConfig(),
    camera1: FrameCamera | None = None, camera2: FrameCamera | None = None, guided: bool = False,
) -> PairMatches:
    """Geometric verification of putative matches (fundamental by MAGSAC++, or essential with cameras)."""
    import cv2

    nan = np.full((3, 3), np.nan)
    n = len(matches)
    empty = np.zeros((0, 2), np.int64)
    if n < config.min_inliers:
        return PairMatches(empty, nan, n, guided, f"only {n} putative matches (< {config.min_inliers})")
    p1 = np.ascontiguousarray(xy1[matches[:, 0]], dtype=np.float64)
    p2 = np.ascontiguousarray(xy2[matches[:, 1]], dtype=np.float64)
    thr = config.ransac_px * config.threshold_scale
    if config.verification == "essential":
        if camera1 is None or camera2 is None:
            raise ConfigError("essential-matrix verification needs both cameras")
        r1 = camera1.rays_from_pixels(p1)
        r2 = camera2.rays_from_pixels(p2)
        # skyrig camera frame looks along -z with y up: flip y and z to get OpenCV's (x right, y down, z fwd)
        n1 = np.column_stack([r1[:, 0] / -r1[:, 2], -r1[:, 1] / -r1[:, 2]])
        n2 = np.column_stack([r2[:, 0] / -r2[:, 2], -r2[:, 1] / -r2[:, 2]])
    try:  # OpenCV's USAC asserts (cv2.error) on some degenerate sets instead of returning no model
        if config.verification == "essential":
            E, mask = cv2.findEssentialMat(n1, n2, np.eye(3), method=cv2.USAC_MAGSAC, prob=config.confidence,
                                           threshold=thr / camera1.focal_px, maxIters=config.max_iterations)
            F = None  # the essential path does not give F in pixels
        else:
            F, mask = cv2.findFundamentalMat(p1, p2, cv2.USAC_MAGSAC, thr, config.confidence, config.max_iterations)
    except cv2.error as e:
        return PairMatches(empty, nan, n, guided, f"verification found no model ({str(e).strip().splitlines()[-1]})")
    if mask is None:
        return PairMatches(empty, nan, n, guided, "verification found no model")
    inl = mask.reshape(-1).astype(bool)
    k = int(inl.sum())
    if k < config.min_inliers:
        return PairMatches(empty, nan, n, guided, f"only {k} verified inliers of {n} (< {config.min_inliers})")
    F = F[:3] if F is not None and F.ndim == 2 else nan
    kept = matches[inl]
    if config.consistency_px is not None:
        ok = consistent_matches(xy1[kept[:, 0]], xy2[kept[:, 1]], config.consistency_px * config.threshold_scale,
                                config.consistency_neighbours)
        if int(ok.sum()) < config.min_inliers:
            return PairMatches(empty, nan, n, guided, f"only {int(ok.sum())} of {k} verified inliers agree with their "
                               f"neighbours (< {config.min_inliers})")
        kept = kept[ok]
    return PairMatches(kept, np.asarray(F, dtype=np.float64), n, guided)


def match_pair(
    f1: Features, f2: Features, config: MatchConfig = MatchConfig(),
    camera1: FrameCamera | None = None, world_from_camera1: Pose | None = None,
    camera2: FrameCamera | None = None, world_from_camera2: Pose | None = None,
) -> PairMatches:
    """Putative matching (guided when both poses and cameras are given and finite) and verification."""
    F_pred = None
    if (camera1 is not None and camera2 is not None and world_from_camera1 is not None
            and world_from_camera2 is not None
            and np.all(np.isfinite(world_from_camera1.rotation)) and np.all(np.isfinite(world_from_camera2.rotation))):
        from skyrig.errors import GeometryError

        try:
            F_pred = predicted_fundamental(camera1, world_from_camera1, camera2, world_from_camera2)
        except GeometryError as exc:
            logger.info("no predicted epipolar geometry (%s); unguided search", exc)
    m = putative_matches(f1, f2, config, F_pred)
    res = verify(f1.xy, f2.xy, m, config, camera1, camera2, guided=F_pred is not None)
    if F_pred is not None and not res.ok and config.unguided_fallback:
        # the approximate orientations may be wrong by more than the band (e.g. a bad gimbal yaw): retry
        logger.info("guided matching failed (%s); retrying unguided", res.reason)
        res2 = verify(f1.xy, f2.xy, putative_matches(f1, f2, config, None), config, camera1, camera2, guided=False)
        if res2.ok:
            return res2
        return PairMatches(res2.matches, res2.F, res2.n_putative, False, f"guided: {res.reason}; unguided: {res2.reason}")
    return res
