"""Online boresight estimation of a rig (paper 001: "the estimation of boresight angles could be automated and also
performed online"), for the live mode (:mod:`skyrig.pipeline.live`).

The flight is cut into consecutive windows of recent exposures.  Each window is one rig adjustment
(:func:`skyrig.adjust.rig_block.block_from_trajectory`: GNSS/IMU per exposure, every head hanging off its station
through its mounting and boresight) of the tie points matched between the window's images
(:func:`window_tie_points`, :mod:`skyrig.match`), with every head's boresight correction free.  A straight strip
without ground control leaves a rotation of the whole window about the flight line undetermined (GNSS positions on
a line do not fix it), so the window also carries **reference heights**: the tie points intersected with the
direct georeferencing are given the height of a reference surface (a public DEM, or a plane at the terrain
height) with its sigma, and free plan positions (:func:`reference_heights`; points off the surface by more than
3 sigma, roofs, are left without one).  The windows share no observation, so their estimates are independent and
their inverse-variance combination (:func:`combine`) equals a sequential least-squares in which each window takes
the previous estimate as prior.

Angles are rotation vectors of the boresight correction in the camera frame (rad), the unknowns of
:class:`skyrig.adjust.block.Block` (``head_boresight``), relative to the rig given.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.adjust import adjust
from skyrig.adjust.block import AdjustConfig
from skyrig.adjust.config import ReliabilityOptions, StatisticsOptions, Unknowns
from skyrig.adjust.rig_block import block_from_trajectory
from skyrig.camera.frame import FrameCamera
from skyrig.errors import SkyrigError
from skyrig.georef.eo import ExteriorOrientations
from skyrig.georef.ground import forward_intersection
from skyrig.georef.observations import GroundPoints, ImageMeasurements
from skyrig.geometry.pose import Pose
from skyrig.geometry.rotations import matrix_from_rotvec
from skyrig.match.features import FeatureConfig, Features, extract_features
from skyrig.match.matching import MatchConfig, match_pair
from skyrig.match.tracks import build_tracks, thin_tracks, tracks_to_measurements
from skyrig.rig.rig import Rig
from skyrig.trajectory import CameraEvents, Trajectory

__all__ = ["WindowEstimate", "BoresightEstimate", "window_pairs", "window_tie_points", "reference_heights",
           "adjust_window", "estimate_window", "combine", "rig_with_corrections"]


@dataclass(frozen=True)
class WindowEstimate:
    """One window's adjustment: per head the boresight correction (rotation vector, rad, camera frame) and its
    a-posteriori covariance (rad^2), with the window's numbers."""

    exposures: tuple[int, ...]
    correction: dict[str, NDArray[np.float64]]
    covariance: dict[str, NDArray[np.float64]]
    sigma0: float
    n_points: int
    n_height_points: int
    seconds: float = 0.0
    warnings: tuple[str, ...] = ()
    ties: ImageMeasurements | None = None  # the tie-point observations (by :func:`estimate_window`)


@dataclass(frozen=True)
class BoresightEstimate:
    """The combination of the windows so far."""

    correction: dict[str, NDArray[np.float64]] = field(default_factory=dict)
    covariance: dict[str, NDArray[np.float64]] = field(default_factory=dict)
    n_windows: int = 0
    n_exposures: int = 0

    def sigma(self, head: str) -> NDArray[np.float64]:
        return np.sqrt(np.diag(self.covariance[head]))


def window_pairs(exposure: Sequence[int], head: Sequence[str], max_lag: int = 2,
                 cross: Sequence[tuple[str, str]] = ()) -> list[tuple[int, int]]:
    """Image pairs of a window worth matching: the same head up to ``max_lag`` exposures apart, and the head pairs
    in ``cross`` (overlapping fields of view) at the same or the neighbouring exposure."""
    ex = np.asarray(exposure, dtype=np.int64)
    hd = np.asarray(head, dtype=str)
    order = {e: k for k, e in enumerate(sorted(set(ex.tolist())))}
    rank = np.array([order[e] for e in ex.tolist()])
    crossing = {frozenset(c) for c in cross}
    out = []
    for i in range(len(ex)):
        for j in range(i + 1, len(ex)):
            lag = abs(int(rank[i] - rank[j]))
            if hd[i] == hd[j] and 1 <= lag <= max_lag:
                out.append((i, j))
            elif hd[i] != hd[j] and lag <= 1 and frozenset((str(hd[i]), str(hd[j]))) in crossing:
                out.append((i, j))
    return out


def window_tie_points(eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera],
                      features: Callable[[int], Features], pairs: Sequence[tuple[int, int]],
                      match_config: MatchConfig = MatchConfig(), cells: tuple[int, int] = (6, 4), per_cell: int = 3,
                      prefix: str = "t") -> ImageMeasurements:
    """Tie points of the images of ``eo`` (``features(i)`` for row ``i``): guided matching of ``pairs`` with the
    direct-georeferencing poses, tracks, thinned to ``per_cell`` tracks per cell of a ``cells`` grid per image."""
    feats = [features(i) for i in range(len(eo))]
    matches = {}
    for i, j in pairs:
        ci, cj = cameras[str(eo.camera[i])], cameras[str(eo.camera[j])]
        pm = match_pair(feats[i], feats[j], match_config, ci, _pose(eo, i), cj, _pose(eo, j))
        if pm.ok and len(pm.matches):
            matches[(i, j)] = pm.matches
    tracks = build_tracks([len(f.xy) for f in feats], matches)
    sizes = [(cameras[str(c)].width, cameras[str(c)].height) for c in eo.camera]
    tracks = thin_tracks(tracks, [f.xy for f in feats], sizes, cells=cells, per_cell=per_cell)
    return tracks_to_measurements(tracks, [f.xy for f in feats], [str(n) for n in eo.image], prefix=prefix)


def _pose(eo: ExteriorOrientations, i: int) -> Pose:
    return Pose(eo.rotation[i], eo.centre[i], "world", "camera")


def reference_heights(eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera], measurements: ImageMeasurements,
                      height_at: Callable[[NDArray, NDArray], NDArray], sigma_m: float
                      ) -> GroundPoints:
    """Tie points intersected with the orientations ``eo`` (a map frame) that lie within 3 ``sigma_m`` of the
    reference surface ``height_at(x, y)`` (heights of ``eo.frame``), as ground points at the surface's height (their
    plan position is the intersection's: give it a loose sigma)."""
    if len(measurements) == 0:
        return GroundPoints(np.zeros(0, str), np.zeros((0, 3)), eo.frame)
    inter = forward_intersection(eo, cameras, measurements.point, measurements.image, measurements.pixel, eo.frame)
    ok = inter.valid & np.all(np.isfinite(inter.xyz), axis=1)
    xyz = inter.xyz[ok]
    h = np.asarray(height_at(xyz[:, 0], xyz[:, 1]), dtype=np.float64)
    keep = np.isfinite(h) & (np.abs(xyz[:, 2] - h) < 3.0 * sigma_m)
    pts = np.column_stack([xyz[keep, 0], xyz[keep, 1], h[keep]])
    return GroundPoints(np.asarray(inter.point)[ok][keep], pts, eo.frame)


def adjust_window(trajectory: Trajectory, rig: Rig, events: CameraEvents, measurements: ImageMeasurements,
                  heights: GroundPoints | None, *, height_sigma_m: float, plan_sigma_m: float = 1000.0,
                  gnss_sigma_m: Sequence[float] = (0.05, 0.05, 0.1), imu_sigma_rad: Sequence[float] = (1e-4, 1e-4, 2e-4),
                  sigma_px: float = 0.5, control: GroundPoints | None = None, control_sigma_m: float | None = None,
                  check_points: Sequence[str] = (), variance_components: bool | str = False,
                  snooping: bool = False) -> WindowEstimate:
    """Rig adjustment of one window with every head's boresight correction free.

    ``heights`` are the reference-height points (sigma ``plan_sigma_m`` in plan, ``height_sigma_m`` in height);
    ``control`` (instead of ``heights``) surveyed ground control with ``control_sigma_m`` on every axis (the batch
    calibration).  ``snooping``: Baarda's data snooping (up to 20 non-adjacent image observations rejected per
    round).  With ``variance_components`` the a-priori sigmas of the observation groups (image points,
    GNSS, IMU, heights) are first re-estimated from the window's own residuals
    (:func:`skyrig.adjust.vce.estimate_variance_components`); without it one variance factor (sigma0^2) scales
    every group alike; with ``variance_components="image"`` only the image points' sigma is re-estimated (the
    matcher's precision is what the a-priori ``sigma_px`` does not know) and the GNSS/IMU and height sigmas stay
    as given, the covariance taken at those weights without a further global factor.  Raises :class:`SkyrigError` when the adjustment gives no
    covariance of the boresights."""
    import time

    t0 = time.perf_counter()
    if heights is not None and control is not None:
        raise SkyrigError("adjust_window: give reference heights or ground control, not both")
    ctrl, csig = heights, (plan_sigma_m, plan_sigma_m, height_sigma_m)
    if control is not None:
        ctrl, csig = control, (control_sigma_m,) * 3 if control_sigma_m is not None else (0.02,) * 3
    block, _ = block_from_trajectory(trajectory, rig, events, measurements, ctrl if ctrl is not None and len(ctrl)
                                     else None, gnss_sigma_m=tuple(gnss_sigma_m), imu_sigma_rad=tuple(imu_sigma_rad),
                                     control_sigma_m=csig, sigma_px=sigma_px, check_points=tuple(check_points))
    cfg = AdjustConfig(unknowns=Unknowns(boresight="free"), statistics=StatisticsOptions(compute=True),
                       reliability=ReliabilityOptions(snooping=snooping, per_round=20))
    if variance_components:
        from skyrig.adjust.vce import estimate_variance_components

        split = {"image": ((0, 1),)} if variance_components == "image" else None
        res = estimate_variance_components(block, cfg, split, max_iterations=8, tolerance=0.05).result
    else:
        res = adjust(block, cfg)
    sel = res.selected
    if sel is None:
        raise SkyrigError("the window adjustment gave no covariance of the boresight corrections")
    # the image sigma re-estimated alone: the other groups' sigmas are the stated ones, so the covariance is the
    # cofactor matrix at those weights (a global sigma0^2, ~0.04 here, would shrink the GNSS/IMU sigmas below their
    # noise: bench/live_stats.py)
    scale = 1.0 if variance_components == "image" else res.sigma0 ** 2
    pos = {tuple(lab): k for k, lab in enumerate(sel.labels)}
    corr, cov = {}, {}
    for hi, h in enumerate(res.block.head_name):
        ix = [pos.get(("boresight", str(h), c)) for c in ("rx", "ry", "rz")]
        if any(i is None for i in ix):
            continue
        corr[str(h)] = res.block.head_boresight[hi].copy()
        cov[str(h)] = scale * sel.Qcc[np.ix_(ix, ix)]
    n_h = 0 if ctrl is None else len(ctrl)
    ex = tuple(sorted({int(e) for e in events.exposure_id}))
    return WindowEstimate(ex, corr, cov, float(res.sigma0), int(block.n_points), int(n_h),
                          time.perf_counter() - t0, tuple(res.warnings) + tuple(res.failures))


def estimate_window(eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera], features: Callable[[int], Features],
                    trajectory: Trajectory, rig: Rig, events: CameraEvents,
                    height_at: Callable[[NDArray, NDArray], NDArray], height_sigma_m: float, *,
                    cross: Sequence[tuple[str, str]], prefix: str = "t", per_cell: int = 2,
                    variance_components: bool | str = "image", snooping: bool = True) -> WindowEstimate:
    """One window of the online boresight (or the batch calibration: every exposure as one window): tie points of
    consecutive exposures and of the ``cross`` head pairs (:func:`window_pairs`, :func:`window_tie_points`, guided
    by ``eo``), their reference heights (:func:`reference_heights`) and the rig adjustment of the events of
    ``eo``'s images against the nominal ``rig`` (:func:`adjust_window`), the image points' sigma estimated from
    their residuals (``variance_components="image"``: with one global variance factor the sigma was ~2.5 x too
    optimistic against the truth, with this realistic; ``bench/live_stats.py``), with data snooping (a false match left
    in makes the window's sigma0 and so its covariance many times too large, and its estimate wrong: measured
    in ``bench/live_stats.py``)."""
    pairs = window_pairs(eo.exposure, eo.head, max_lag=1, cross=cross)
    m = window_tie_points(eo, cameras, features, pairs, per_cell=per_cell, prefix=prefix)
    hp = reference_heights(eo, cameras, m, height_at, height_sigma_m)
    names = {str(n) for n in eo.image}
    ev = events.subset([k for k in range(len(events)) if str(events.image_name[k]) in names])
    w = adjust_window(trajectory, rig, ev, m, hp, height_sigma_m=height_sigma_m,
                      variance_components=variance_components, snooping=snooping)
    return replace(w, ties=m)


def combine(windows: Sequence[WindowEstimate]) -> BoresightEstimate:
    """Inverse-covariance weighted mean per head of independent window estimates (windows sharing no
    observation), with its covariance."""
    heads = sorted({h for w in windows for h in w.correction})
    corr, cov = {}, {}
    for h in heads:
        N = np.zeros((3, 3))
        b = np.zeros(3)
        for w in windows:
            if h not in w.correction:
                continue
            W = np.linalg.inv(w.covariance[h])
            N += W
            b += W @ w.correction[h]
        C = np.linalg.inv(N)
        corr[h], cov[h] = C @ b, C
    n_ex = len({e for w in windows for e in w.exposures})
    return BoresightEstimate(corr, cov, len(windows), n_ex)


def rig_with_corrections(rig: Rig, correction: Mapping[str, NDArray[np.float64]]) -> Rig:
    """The rig with each head's boresight composed with its correction (rotation vector, camera frame)."""
    heads = [h.with_(boresight=h.boresight @ matrix_from_rotvec(correction[h.name])) if h.name in correction else h
             for h in rig]
    return Rig(rig.name, heads, rig.antenna_lever_arm_m, rig.description)


def features_of(image: NDArray, config: FeatureConfig = FeatureConfig(max_size=None, max_features=1500)) -> Features:
    """SIFT features of one image (full resolution by default: live images are small or already binned)."""
    return extract_features(image, config)
