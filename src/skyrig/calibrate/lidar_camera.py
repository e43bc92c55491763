"""The LiDAR-and-camera system calibrated as a whole (issue 34, paper 002's "calibration of the entire system").

One adjustment holds the camera block (image orientations, tie points, the camera's boresight) and the laser
strips (:mod:`skyrig.adjust.factors.lidar`): laser points on planar patches seen by overlapping strips, laser
points on the local planes of the image block's tie points, and the image stations tied to the same recorded
trajectory as the laser, corrected by the same per-strip offsets and drifts.  Unknowns: the scanner's boresight,
lever arm, range offset and scale, per-strip trajectory corrections (priors: the trajectory's stated accuracy),
the camera's boresight, the stations and the tie points.  Optional control (``JointInputs.control_xyz``: a
reference cloud, e.g. a terrestrial scan registered to the survey's control, or a surveyor's control planes): its
points on the patch planes observe those planes (:mod:`skyrig.adjust.factors.lidar`, point-to-plane with
``JointOptions.control_sigma_m`` per point and ``control_plane_sigma_m`` per plane) and give the block the datum no
calibration without control has (the trajectory's absolute accuracy); each control plane is tested against the
laser's own plane and left out as a blunder when its normalised residual exceeds ``max_control_z``.

:func:`calibrate_lidar_camera` builds the block from the raw inputs (:class:`JointInputs`), adjusts it and returns
a :class:`JointCalibration`: parameters with sigmas, determinability verdicts, the adjusted block.
:func:`georeference_adjusted` applies the result to every laser pulse (the laser cloud after the adjustment).

Layer 2c (imports adjust and lidar); arrays in, dataclasses out.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from skyrig.adjust import AdjustConfig, adjust
from skyrig.adjust.block import Block
from skyrig.adjust.config import Unknowns
from skyrig.adjust.factors.lidar import (LIDAR, SCANNER, SCANNER_COMPONENTS, STRIP, STRIP_COMPONENTS,
                                         ControlResiduals, LidarPoints, control_residuals, georeference,
                                         lidar_unknowns)
from skyrig.camera.frame import FrameCamera
from skyrig.errors import CalibrationFailed, InputFormatError
from skyrig.georef.eo import WorldFrame
from skyrig.lidar.georef import ScannerMount
from skyrig.lidar.pulse_poses import beams, local_poses
from skyrig.lidar.scanner import RawScan
from skyrig.lidar.strips import PatchOptions, find_planar_patches, prepare_observations
from skyrig.orient.triangulation import triangulate_tracks
from skyrig.trajectory.trajectory import Trajectory

logger = logging.getLogger(__name__)

__all__ = ["JointInputs", "JointOptions", "JointCalibration", "adjust_joint_block", "build_joint_block",
           "calibrate_lidar_camera",
           "georeference_adjusted", "joint_inputs_from_flight"]


@dataclass(frozen=True, eq=False)
class JointInputs:
    """Raw data of one flight with a laser scanner and a camera on one platform (metres, seconds, radians).

    ``scan`` (raw pulses with strip ids), ``trajectory`` (recorded), ``mount`` (nominal scanner mount), ``frame``
    (a local tangent frame near the flight: every coordinate of the block), ``camera`` with its nominal
    ``body_from_camera`` and lever arm, the images' exposure times and strips, and the tie-point measurements
    ``obs_image``, ``obs_point``, ``obs_pixel`` (column, row px) with noise ``sigma_px``; optional control points
    ``control_xyz`` (a reference cloud in ``frame``) and ground control points measured in the images (``gcp_*``).
    """

    scan: RawScan
    trajectory: Trajectory
    mount: ScannerMount
    frame: WorldFrame
    camera: FrameCamera
    body_from_camera: NDArray[np.float64]
    camera_lever_arm_m: NDArray[np.float64]
    image_time_s: NDArray[np.float64]
    image_strip: NDArray[np.int64]
    obs_image: NDArray[np.int64]
    obs_point: NDArray[np.int64]
    obs_pixel: NDArray[np.float64]
    sigma_px: float = 0.5
    #: ``(R, 3)`` control points (a reference cloud) in ``frame``, or None
    control_xyz: NDArray[np.float64] | None = None
    #: ground control points measured in the images: ``(G,)`` their tie-point ids (the numbering of ``obs_point``),
    #: ``(G, 3)`` surveyed coordinates in ``frame`` and ``(G, 3)`` sigmas (m), or None
    gcp_point: NDArray[np.int64] | None = None
    gcp_xyz: NDArray[np.float64] | None = None
    gcp_sigma_m: NDArray[np.float64] | None = None


@dataclass(frozen=True)
class JointOptions:
    """The joint adjustment's model: patches, tie planes, stochastic model and priors (SI units)."""

    patches: PatchOptions = field(default_factory=lambda: PatchOptions(cell_m=2.0, max_points_per_strip=24))
    tie_radius_m: float = 0.4  # laser points around a tie point that make its local plane
    tie_points_per_strip: int = 12  # at most this many per strip and tie plane (at random)
    tie_min_points: int = 8
    tie_max_thickness_m: float = 0.06  # RMS distance of the points from their plane before the adjustment
    max_tie_planes: int = 60  # each is a tie point estimated in the reduced part: its images' rows widen
    range_sigma_m: float = 0.02
    angle_sigma_rad: float = 0.0
    #: surface roughness and footprint spread (m): the floor of a point's point-to-plane sigma.  (6 mm was a
    #: workaround for the range scale's bias while the laser rows were linearised at the recorded points; with the
    #: Jacobians at the adjusted observations, 10 seeds of the simulated bridge flight: range scale z mean +0.22 at
    #: 2 mm, +0.66 at 6 mm, sigma0 0.95 / 0.87)
    roughness_m: float = 0.002
    station_position_sigma_m: float = 0.005  # white trajectory noise at the exposures
    station_attitude_sigma_rad: float = 2e-5
    #: prior sigmas of the per-strip corrections (position, position drift, attitude, attitude drift; 12 values in
    #: the order of :data:`~skyrig.adjust.factors.lidar.STRIP_COMPONENTS`): the trajectory's stated accuracy
    strip_sigma: tuple[float, ...] = (0.03, 0.03, 0.05, 5e-4, 5e-4, 8e-4) + tuple(
        np.radians([0.02, 0.02, 0.05, 2e-4, 2e-4, 5e-4]).tolist())
    #: determinability: a parameter is determined when its sigma <= ratio_max x its "a-priori range" (below)
    ratio_max: float = 0.5
    #: the a-priori ranges of the calibration (what the calibration knew before): boresight 0.5 deg, lever 0.1 m,
    #: range offset 0.1 m, range scale 0.002; camera boresight 0.5 deg
    prior_range: tuple[float, ...] = (0.0087, 0.0087, 0.0087, 0.1, 0.1, 0.1, 0.1, 0.002)
    camera_prior_range_rad: float = 0.0087
    max_iterations: int = 30
    max_plane_rms: float = 2.0  # a plane whose normalised residual RMS exceeds this after an adjustment is dropped
    max_point_z: float = 4.5  # a laser point whose normalised residual exceeds this is dropped (data snooping)
    #: control (reference cloud) points: noise across their surface per point, and common to a patch's points (the
    #: reference's registration); a control plane whose normalised residual against the laser exceeds max_control_z
    #: is a blunder and left out
    control_sigma_m: float = 0.003
    control_plane_sigma_m: float = 0.0
    max_control_z: float = 4.0
    seed: int = 0


@dataclass(frozen=True, eq=False)
class JointCalibration:
    """Result of :func:`calibrate_lidar_camera`.

    ``scanner`` / ``scanner_sigma`` ``(8,)`` (components of ``lidar_scanner``), ``camera_boresight_rad`` /
    ``camera_boresight_sigma_rad`` ``(3,)``, ``strips`` / ``strips_sigma`` ``(K, 12)``, ``strip_epoch_s`` ``(K,)``
    and ``strip_ids``; ``verdicts``: per calibration parameter ``(name, value, sigma, "determined" | "not
    determinable", words)``; ``result``: the adjustment; ``n_patch_planes``, ``n_tie_planes``, ``n_laser_points``;
    ``control``: the control planes' residuals (:class:`~skyrig.adjust.factors.lidar.ControlResiduals`) when the
    inputs had control, ``control_rejected`` the blunders left out.
    """

    scanner: NDArray[np.float64]
    scanner_sigma: NDArray[np.float64]
    camera_boresight_rad: NDArray[np.float64]
    camera_boresight_sigma_rad: NDArray[np.float64]
    strips: NDArray[np.float64]
    strips_sigma: NDArray[np.float64]
    strip_epoch_s: NDArray[np.float64]
    strip_ids: NDArray[np.int64]
    verdicts: tuple[tuple[str, float, float, str, str], ...]
    result: Any
    block: Block
    n_patch_planes: int
    n_tie_planes: int
    n_laser_points: int
    sigma0: float
    n_dropped_planes: int = 0
    n_dropped_points: int = 0
    #: strip-to-strip discrepancies on the patch planes with the nominal calibration and the recorded trajectory,
    #: and after the joint adjustment (:func:`strip_discrepancies`)
    discrepancies_before: dict[str, float] | None = None
    discrepancies_after: dict[str, float] | None = None
    #: each control plane against the laser after the adjustment (None: no control), and those left out as
    #: blunders (tested in the adjustment they were left out of)
    control: ControlResiduals | None = None
    control_rejected: ControlResiduals | None = None
    #: ground control points in the images: residuals (adjusted minus surveyed, m, ``(G, 3)``) and normalised
    #: residuals (``(G, 3)``, the adjustment's own test), or None
    gcp_residual_m: NDArray[np.float64] | None = None
    gcp_normalised: NDArray[np.float64] | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "scanner": {n: {"value": float(v), "sigma": float(s)} for n, v, s in
                        zip(SCANNER_COMPONENTS, self.scanner, self.scanner_sigma)},
            "camera_boresight_rad": {"value": self.camera_boresight_rad.tolist(),
                                     "sigma": self.camera_boresight_sigma_rad.tolist()},
            "strips": [{"strip": int(i), "epoch_s": float(e), **{n: {"value": float(v), "sigma": float(s)}
                                                                 for n, v, s in zip(STRIP_COMPONENTS, row, srow)}}
                       for i, e, row, srow in zip(self.strip_ids, self.strip_epoch_s, self.strips, self.strips_sigma)],
            "determinability": [{"parameter": n, "value": v, "sigma": s, "verdict": vd, "words": w}
                                for n, v, s, vd, w in self.verdicts],
            "planes": {"patch": self.n_patch_planes, "tie": self.n_tie_planes},
            "laser_points_used": self.n_laser_points, "sigma0": self.sigma0,
            "strip_discrepancies": {"before": self.discrepancies_before, "after": self.discrepancies_after},
            **({} if self.control is None else {"control": {
                **self.control.to_dict(),
                "rejected_as_blunders": [] if self.control_rejected is None else
                self.control_rejected.to_dict().get("control_planes", [])}}),
            **({} if self.gcp_residual_m is None else {"ground_control": {
                "units": "m, adjusted minus surveyed (block frame)", "residual_m": self.gcp_residual_m.tolist(),
                "normalised": None if self.gcp_normalised is None else self.gcp_normalised.tolist()}}),
        }


def _tie_planes(inputs: JointInputs, xyz_nominal: NDArray, strip_of: NDArray, used_time: NDArray,
                tie_xyz: NDArray, opt: JointOptions) -> tuple[list[NDArray[np.int64]], list[int]]:
    """Pulse rows of the local laser plane of each tie point (points not already in a patch), and the tie points."""
    rng = np.random.default_rng(opt.seed)
    ok = (strip_of >= 0) & ~np.isin(inputs.scan.time_s, used_time)
    cand = np.flatnonzero(ok)
    tree = cKDTree(xyz_nominal[cand])
    good = np.flatnonzero(np.isfinite(tie_xyz).all(axis=1))
    rng.shuffle(good)
    rows_out: list[NDArray[np.int64]] = []
    pts: list[int] = []
    for j in good:
        if len(pts) >= opt.max_tie_planes:
            break
        nb = cand[np.asarray(tree.query_ball_point(tie_xyz[j], opt.tie_radius_m), np.int64)]
        if len(nb) < opt.tie_min_points:
            continue
        keep = []
        for k in np.unique(strip_of[nb]):
            s = nb[strip_of[nb] == k]
            keep.append(rng.choice(s, min(len(s), opt.tie_points_per_strip), replace=False))
        sel = np.concatenate(keep)
        if len(sel) < opt.tie_min_points:
            continue
        d = xyz_nominal[sel] - xyz_nominal[sel].mean(axis=0)
        w, v = np.linalg.eigh(d.T @ d / len(sel))
        if np.sqrt(max(w[0], 0.0)) > opt.tie_max_thickness_m or np.sqrt(w[1]) < 0.1 * opt.tie_radius_m:
            continue
        rows_out.append(np.sort(sel))
        pts.append(int(j))
    return rows_out, pts


def build_joint_block(inputs: JointInputs, options: JointOptions = JointOptions()
                      ) -> tuple[Block, AdjustConfig, dict[str, Any]]:
    """The joint block (stations = exposures on the recorded trajectory, tie points triangulated from them, the
    laser points on patch and tie planes) and its configuration.

    Raises
    ------
    InputFormatError
        Images with a strip the scan does not have, or inconsistent measurement arrays.
    OutOfRangeError
        A pulse or an exposure outside the trajectory's time span (named).
    GeometryError
        No planar patch seen by two strips.
    """
    scan, frame, cam = inputs.scan, inputs.frame, inputs.camera
    lever = np.asarray(inputs.camera_lever_arm_m, float)
    if lever.shape != (3,) or np.abs(lever).max() > 10.0:
        raise InputFormatError(f"camera lever arm {lever.tolist()} is not 3 values in metres (over 10 m: given in mm?)",
                               field="camera_lever_arm_m")
    if np.abs(inputs.mount.lever_arm_m).max() > 10.0:
        raise InputFormatError(f"scanner lever arm {inputs.mount.lever_arm_m.tolist()} is over 10 m: lever arms are in "
                               "metres (given in mm?)", field="lever_arm_m")
    xyz, strip_of = prepare_observations(scan, inputs.trajectory, inputs.mount, frame)
    control = None
    if inputs.control_xyz is not None:
        control = np.asarray(inputs.control_xyz, float)
        if control.ndim != 2 or control.shape[1] != 3 or not np.isfinite(control).all():
            raise InputFormatError(f"control points must be finite (R, 3) coordinates, got shape {control.shape}",
                                   field="control_xyz")
    patches = find_planar_patches(scan, inputs.trajectory, inputs.mount, frame, options=options.patches, xyz=xyz,
                                  control=control)
    if control is not None and not (patches.control_count >= 3).any():
        raise InputFormatError(f"none of the {len(control)} control points lies on a planar patch of the laser strips "
                               f"(within {options.patches.max_thickness_m:g} m of a patch, {options.patches.cell_m:g} m "
                               "cells): is the control in the same frame (CRS, vertical reference) as the flight?",
                               field="control_xyz")
    ids = [int(v) for v in patches.strip_ids]
    bad = [int(s) for s in np.unique(inputs.image_strip) if int(s) not in ids]
    if bad:
        raise InputFormatError(f"images on strip(s) {bad} that no laser patch has (strips {ids})", field="image_strip")
    k_of = {s: k for k, s in enumerate(ids)}
    # the image block on the recorded trajectory
    n_img = len(inputs.image_time_s)
    pos, rot = local_poses(inputs.trajectory, frame, np.asarray(inputs.image_time_s, float))
    M = np.asarray(inputs.body_from_camera, float)
    Rc = rot @ M
    Cc = pos + np.einsum("nij,j->ni", rot, lever)
    n_pts = int(inputs.obs_point.max()) + 1
    tie_xyz, _ = triangulate_tracks(cam, Rc, Cc, inputs.obs_point, inputs.obs_image, inputs.obs_pixel, n_pts)
    ok_pt: NDArray[np.bool_] = np.asarray(np.isfinite(tie_xyz).all(axis=1), bool)
    keep_obs = ok_pt[inputs.obs_point]
    newp = np.cumsum(ok_pt) - 1
    # laser: patch planes, then the tie planes of the (triangulated) tie points
    used_time = patches.dt_s + patches.strip_epoch_s[patches.strip]
    tie_rows, tie_pts = _tie_planes(inputs, xyz, strip_of, used_time, tie_xyz, options)
    trow = np.concatenate(tie_rows) if tie_rows else np.zeros(0, np.int64)
    tplane = np.concatenate([np.full(len(r), patches.n_planes + q) for q, r in enumerate(tie_rows)]) if tie_rows \
        else np.zeros(0, np.int64)
    tpos, trot = local_poses(inputs.trajectory, frame, scan.time_s[trow])
    tb, tdb = beams(scan, trow)
    tstrip = np.array([k_of[int(s)] for s in strip_of[trow]], np.int64)
    q_tie = len(tie_pts)
    ctrl: dict[str, Any] = {} if control is None else {
        "control_count": np.concatenate([patches.control_count, np.zeros(q_tie)]),
        "control_sum": np.concatenate([patches.control_sum, np.zeros((q_tie, 3))]),
        "control_sum2": np.concatenate([patches.control_sum2, np.zeros((q_tie, 3, 3))]),
        "control_ref": np.concatenate([patches.centre, np.zeros((q_tie, 3))]),
        "control_sigma_m": options.control_sigma_m, "control_plane_sigma_m": options.control_plane_sigma_m}
    lp = LidarPoints(
        time_s=np.concatenate([used_time, scan.time_s[trow]]), strip=np.concatenate([patches.strip, tstrip]),
        range_m=np.concatenate([patches.range_m, scan.range_m[trow]]), beam=np.concatenate([patches.beam_s, tb]),
        beam_dangle=np.concatenate([patches.dbeam_s, tdb]), plane=np.concatenate([patches.plane, tplane]),
        position_m=np.concatenate([patches.position, tpos]), rotation=np.concatenate([patches.rotation, trot]),
        plane_point=np.concatenate([np.full(patches.n_planes, -1), newp[np.asarray(tie_pts, np.int64)]]),
        strip_epoch_s=patches.strip_epoch_s, body_from_scanner=inputs.mount.body_from_scanner,
        lever_arm_m=inputs.mount.lever_arm_m, range_sigma_m=options.range_sigma_m,
        angle_sigma_rad=options.angle_sigma_rad, roughness_m=options.roughness_m,
        station=np.arange(n_img), station_strip=np.array([k_of[int(s)] for s in inputs.image_strip], np.int64),
        station_time_s=inputs.image_time_s, station_position_m=pos, station_rotation=rot,
        station_position_sigma_m=options.station_position_sigma_m,
        station_attitude_sigma_rad=options.station_attitude_sigma_rad, **ctrl)
    # the roughness as an error of the range needs each point's n . beam at a starting plane: the patch planes' own
    # normals for their points (as the laser-only strip adjustment), the default fit for the tie planes' points
    lp.normalise(None)  # type: ignore[arg-type]
    inc = np.array(lp.incidence(), dtype=np.float64)
    n_b = np.einsum("nji,nj->ni", patches.rotation, patches.normal[patches.plane]) @ inputs.mount.body_from_scanner
    inc[:len(patches.plane)] = np.einsum("ni,ni->n", n_b, patches.beam_s)
    lp.incidence0 = inc
    gcp: dict[str, Any] = {}
    if inputs.gcp_point is not None:
        gp = np.asarray(inputs.gcp_point, np.int64).reshape(-1)
        gx = np.asarray(inputs.gcp_xyz, float).reshape(len(gp), 3)
        gs = np.broadcast_to(np.asarray(inputs.gcp_sigma_m if inputs.gcp_sigma_m is not None else 0.01, float),
                             (len(gp), 3))
        bad_g = [int(j) for j in gp if not (0 <= j < n_pts and ok_pt[j])]
        if bad_g:
            raise InputFormatError(f"ground control point(s) {bad_g[:5]} are not tie points measured in 2 or more "
                                   "images of the block", field="gcp_point")
        if not (np.isfinite(gx).all() and np.isfinite(gs).all() and (gs > 0).all()):
            raise InputFormatError("ground control coordinates and sigmas must be finite, sigmas positive",
                                   field="gcp_xyz")
        gcp = {"control_point": newp[gp], "control_xyz": gx, "control_sigma": np.array(gs)}
    block = Block(
        cameras=[cam], station_name=[f"exp{i}" for i in range(n_img)], station_rotation=rot, station_centre=pos,
        station_time=inputs.image_time_s, image_name=[f"img{i}" for i in range(n_img)],
        image_station=np.arange(n_img), image_camera=np.zeros(n_img, np.int64),
        image_rotation=np.broadcast_to(M, (n_img, 3, 3)), image_offset=np.broadcast_to(lever, (n_img, 3)),
        head_name=["camera"], point_name=[f"t{j}" for j in range(int(ok_pt.sum()))], point_xyz=tie_xyz[ok_pt],
        obs_image=inputs.obs_image[keep_obs], obs_point=newp[inputs.obs_point[keep_obs]],
        obs_pixel=inputs.obs_pixel[keep_obs], obs_sigma_px=np.full((int(keep_obs.sum()), 2), inputs.sigma_px),
        observations={"lidar": lp}, frame=frame, **gcp)
    unk = lidar_unknowns(Unknowns(poses="free", points="free", boresight="free", intrinsics="fixed"),
                         strip_sigma=options.strip_sigma)
    cfg = AdjustConfig(unknowns=unk)
    cfg = replace(cfg, solver=replace(cfg.solver, max_iterations=options.max_iterations))
    info = {"n_patch_planes": patches.n_planes, "n_tie_planes": len(tie_pts), "strip_ids": patches.strip_ids,
            "n_points_searched": patches.n_points_total, "n_laser_points": len(lp),
            "n_control_planes": int(lp.has_control.sum()), "n_gcp": len(gcp.get("control_point", []))}
    return block, cfg, info


def calibrate_lidar_camera(inputs: JointInputs, options: JointOptions = JointOptions()) -> JointCalibration:
    """Build the joint block, adjust it and judge every calibration parameter's determinability.

    Raises
    ------
    CalibrationFailed
        The adjustment did not converge (its failures named).
    """
    block, cfg, info = build_joint_block(inputs, options)
    res, block, snoop = adjust_joint_block(block, cfg, options)
    info["n_dropped_points"], info["n_dropped_planes"] = snoop["dropped_points"], snoop["dropped_planes"]
    s0 = float(res.sigma0) if np.isfinite(res.sigma0) and res.sigma0 > 0 else 1.0
    sig = {k_: v / s0 for k_, v in res.sigma_reduced().items()}  # a-priori sigmas (the model's own precision)
    sc = np.asarray(res.block.parameters[SCANNER][0], float)
    sc_s = np.array([sig.get((SCANNER, "scanner", c), np.nan) for c in SCANNER_COMPONENTS])
    k = len(info["strip_ids"])
    st = np.asarray(res.block.parameters[STRIP], float)
    st_s = np.array([[sig.get((STRIP, f"strip{i}", c), np.nan) for c in STRIP_COMPONENTS] for i in range(k)])
    cb = np.asarray(res.block.head_boresight[0], float)
    cb_s = np.array([sig.get(("boresight", "camera", c), np.nan) for c in ("rx", "ry", "rz")])
    verdicts = []
    names = list(SCANNER_COMPONENTS) + ["camera_bore_x_rad", "camera_bore_y_rad", "camera_bore_z_rad"]
    ranges = list(options.prior_range) + [options.camera_prior_range_rad] * 3
    for n, v, s, pr in zip(names, np.concatenate([sc, cb]), np.concatenate([sc_s, cb_s]), ranges):
        det = bool(np.isfinite(s) and s <= options.ratio_max * pr)
        words = (f"sigma {s:.3g} is {s / pr:.2f} x its a-priori range {pr:g}" + ("" if det else
                 ": not determinable by this flight (fly strips in opposite headings at different ranges over "
                 "surfaces of several orientations)"))
        verdicts.append((n, float(v), float(s), "determined" if det else "not determinable", words))
    lp = block.observations["lidar"]
    n_tie = int((lp.plane_point >= 0).sum())
    before = strip_discrepancies(lp, np.zeros(len(sc)), np.zeros_like(st))
    after = strip_discrepancies(lp, sc, st)
    logger.info("strip-to-strip discrepancies on %d patch/strip pairs: RMS %.4f -> %.4f m (normalised %.2f -> %.2f)",
                after["pairs"], before["rms_m"], after["rms_m"], before["normalised_rms"], after["normalised_rms"])
    return JointCalibration(sc, sc_s, cb, cb_s, st, st_s, np.asarray(lp.strip_epoch_s),
                            np.asarray(info["strip_ids"], np.int64), tuple(verdicts), res, res.block,
                            lp.n_planes - n_tie, n_tie, len(lp), float(res.sigma0), info["n_dropped_planes"],
                            info["n_dropped_points"], before, after, snoop["control"], snoop["control_rejected"],
                            *_gcp_residuals(res))


def _gcp_residuals(res: Any) -> tuple[NDArray[np.float64] | None, NDArray[np.float64] | None]:
    """The ground control points' residuals ``(G, 3)`` (m) and normalised residuals, or None without them."""
    g = getattr(res, "residuals", {}).get("control")
    if g is None or not len(g.residual):
        return None, None
    return np.asarray(g.residual, float), None if g.normalised is None else np.asarray(g.normalised, float)


def _scanner_strip_cofactors(res: Any, n_strips: int) -> NDArray[np.float64] | None:
    """The a-priori cofactors ``(8 + 12 K)`` square of the scanner calibration and the strip corrections (the
    groups' component order), or None without a covariance."""
    cov = getattr(res, "covariance", None)
    if cov is None:
        return None
    lab = {l_: i for i, l_ in enumerate(res.layout.labels)}
    idx = [lab.get((SCANNER, "scanner", c), -1) for c in SCANNER_COMPONENTS]
    idx += [lab.get((STRIP, f"strip{k}", c), -1) for k in range(n_strips) for c in STRIP_COMPONENTS]
    ix = np.asarray(idx)
    Q = np.zeros((len(ix), len(ix)))
    ok = ix >= 0
    Q[np.ix_(ok, ok)] = np.asarray(cov.Qcc)[np.ix_(ix[ok], ix[ok])]
    return Q


def adjust_joint_block(block: Block, cfg: AdjustConfig, options: JointOptions = JointOptions()
                       ) -> tuple[Any, Block, dict[str, Any]]:
    """Adjust the joint block with data snooping: laser points off their plane (``|z| > max_point_z``: edges,
    corners), planes that are not planes (``max_plane_rms``) and control planes that are blunders (``|z| >
    max_control_z`` against the laser, :func:`~skyrig.adjust.factors.lidar.control_residuals`; the worst one a
    round, alone: a large blunder pulls the block towards itself and lifts its neighbours' residuals) are left out
    and the block adjusted again (at most 4 rounds for the laser, 8 in all).  With control (planes or ground control
    points) the block is adjusted without it first and from there with it.

    Returns the adjustment, the block it adjusted and ``{"dropped_points", "dropped_planes", "control" (the control
    planes' residuals at the end, or None), "control_rejected" (the blunders, tested in the adjustment they were
    left out of)}``.

    Raises
    ------
    CalibrationFailed
        The adjustment did not converge (its failures named).
    """
    lp0 = block.observations["lidar"]
    gcp0 = block.observations.get("control")
    has_gcp = gcp0 is not None and len(gcp0) > 0 and not np.all(gcp0.check)
    if lp0.has_control.any() or has_gcp:
        # without the control first, then with it from there: from the nominal calibration the laser points lie
        # decimetres off planes the control holds, where the rows at the adjusted observations are no model of the
        # cost (strips-ci seed 2 with control planes, seed 6 with ground control points: 30 iterations of
        # trust-region steps of a millimetre, no convergence); from the block adjusted without control what is left
        # is the trajectory's common error, centimetres.  (Ground control points are check points meanwhile.)
        obs0 = {**block.observations, "lidar": lp0.without_control(np.ones(lp0.n_planes, bool))}
        if has_gcp:
            obs0["control"] = replace(gcp0, check=np.ones(len(gcp0), bool))
        free = adjust(replace(block, observations=obs0), cfg)
        if free.ok:
            block = replace(free.block, observations={**free.block.observations, "lidar": lp0,
                                                      **({"control": gcp0} if has_gcp else {})})
    res = adjust(block, cfg)
    dropped = [0, 0]
    rejected: list[ControlResiduals] = []
    control: ControlResiduals | None = None
    laser_rounds = 0
    for _ in range(8):  # points off their plane (edges, corners), planes that are not planes and control blunders go
        if not res.ok:
            break
        lp = res.block.observations["lidar"]
        z, rms = LIDAR.normalised_residuals(res.block)
        bad_pt, bad_pl = np.abs(z) > options.max_point_z, rms > options.max_plane_rms
        bad_c = np.zeros(lp.n_planes, bool)
        control = None
        if lp.has_control.any():
            control = control_residuals(lp, np.asarray(res.block.parameters[SCANNER][0], float),
                                        np.asarray(res.block.parameters[STRIP], float),
                                        _scanner_strip_cofactors(res, lp.n_strips), options.max_control_z)
            out = control.blunder & (np.abs(control.z) >= np.max(np.abs(np.where(control.blunder, control.z, 0.0))))
            if out.any():  # the control first: a blunder pulls its plane off the laser points, which go next round
                bad_pt[:], bad_pl[:] = False, False
                bad_c[control.plane[out]] = True
                rejected.append(control.subset(out))
                logger.warning("%d control plane(s) left out as blunders: residuals %s mm (|z| > %g)", int(out.sum()),
                               np.round(control.residual_m[out] * 1e3, 1).tolist(), options.max_control_z)
        if not bad_c.any():
            if laser_rounds == 4 or (not bad_pt.any() and not bad_pl.any()):
                break
            laser_rounds += 1
        lp2 = lp.without_control(bad_c).without(bad_pt, bad_pl)
        dropped[0] += len(lp) - len(lp2)
        dropped[1] += lp.n_planes - lp2.n_planes
        logger.info("%d laser points off their plane (|z| > %g) and %d planes dropped", int(bad_pt.sum()),
                    options.max_point_z, lp.n_planes - lp2.n_planes)
        block = replace(block, observations={**block.observations, "lidar": lp2})
        res = adjust(block, cfg)
        control = None
    if not res.ok:
        raise CalibrationFailed("the joint laser and image adjustment failed: " + "; ".join(res.failures))
    lp = res.block.observations["lidar"]
    if control is None and lp.has_control.any():
        control = control_residuals(lp, np.asarray(res.block.parameters[SCANNER][0], float),
                                    np.asarray(res.block.parameters[STRIP], float),
                                    _scanner_strip_cofactors(res, lp.n_strips), options.max_control_z)
    rej = ControlResiduals.concatenate(rejected) if rejected else None
    return res, block, {"dropped_points": dropped[0], "dropped_planes": dropped[1], "control": control,
                        "control_rejected": rej}


def strip_discrepancies(lp: LidarPoints, scanner: NDArray[np.float64], strips: NDArray[np.float64]
                        ) -> dict[str, float]:
    """Strip-to-strip discrepancies on the patch planes of ``lp`` at a calibration ``scanner (8,)`` and strip
    corrections ``strips (K, 12)``: each plane refitted to all its points, then for every plane and pair of strips
    seeing it the difference of the two strips' mean distances from the plane (m) and that difference over its
    predicted sigma (the points' point-to-plane sigmas of the joint model).

    Returns ``pairs``, ``rms_m``, ``p95_abs_m``, ``normalised_rms`` (about 1 at the noise level; a little below
    after an adjustment that fitted the same points) and ``noise_rms_m`` (the predicted sigma's RMS).
    """
    geo = georeference(lp, scanner, strips)
    normal, centre, sig = LIDAR.planes(lp, geo["X"], geo, np.zeros((lp.n_planes, 3)))
    r = np.einsum("ni,ni->n", normal[lp.plane], geo["X"] - centre[lp.plane])
    patch = lp.plane_point[lp.plane] < 0
    k, q = lp.n_strips, lp.n_planes
    g = (lp.plane * k + lp.strip)[patch]
    cnt = np.bincount(g, minlength=q * k).reshape(q, k).astype(float)
    mean = np.bincount(g, r[patch], q * k).reshape(q, k) / np.maximum(cnt, 1.0)
    var = np.bincount(g, sig[patch] ** 2, q * k).reshape(q, k) / np.maximum(cnt, 1.0) ** 2
    a, b = np.triu_indices(k, 1)
    both = (cnt[:, a] > 0) & (cnt[:, b] > 0)  # (Q, pairs)
    dd = (mean[:, a] - mean[:, b])[both]
    vv = (var[:, a] + var[:, b])[both]
    if dd.size == 0:
        return {"pairs": 0, "rms_m": float("nan"), "p95_abs_m": float("nan"), "normalised_rms": float("nan"),
                "noise_rms_m": float("nan")}
    return {"pairs": int(dd.size), "rms_m": float(np.sqrt(np.mean(dd**2))),
            "p95_abs_m": float(np.percentile(np.abs(dd), 95)), "normalised_rms": float(np.sqrt(np.mean(dd**2 / vv))),
            "noise_rms_m": float(np.sqrt(np.mean(vv)))}


def georeference_adjusted(inputs: JointInputs, scanner: NDArray[np.float64], strips: NDArray[np.float64],
                          strip_epoch_s: NDArray[np.float64], strip_ids: NDArray[np.int64],
                          rows: NDArray[np.int64] | None = None, chunk: int = 200_000) -> NDArray[np.float64]:
    """Every laser pulse (or ``rows``) georeferenced in ``inputs.frame`` with a calibration ``scanner (8,)`` and
    strip corrections ``strips (K, 12)`` (epochs and ids of the adjustment); pulses off the strips get none."""
    scan = inputs.scan
    idx = np.arange(len(scan)) if rows is None else np.asarray(rows, np.int64)
    k_of = np.full(int(max(np.max(strip_ids), np.max(scan.strip_id) if scan.strip_id is not None else 0)) + 2, -1)
    k_of[np.asarray(strip_ids)] = np.arange(len(strip_ids))
    sid = scan.strip_id[idx] if scan.strip_id is not None else np.full(len(idx), -1)
    kk = np.where(sid >= 0, k_of[np.clip(sid, 0, None)], -1)
    # pulses of no adjusted strip: a zero correction row appended
    st_ext = np.vstack([strips, np.zeros((1, strips.shape[1]))])
    ep_ext = np.concatenate([strip_epoch_s, [0.0]])
    kk = np.where(kk >= 0, kk, len(strips))
    out = np.empty((len(idx), 3))
    for a in range(0, len(idx), chunk):
        r = idx[a:a + chunk]
        p, R = local_poses(inputs.trajectory, inputs.frame, scan.time_s[r])
        b, db = beams(scan, r)
        lp = LidarPoints(scan.time_s[r], kk[a:a + chunk], scan.range_m[r], b, db, np.zeros(len(r), np.int64), p, R,
                         np.full(1, -1), ep_ext, inputs.mount.body_from_scanner, inputs.mount.lever_arm_m)
        lp.normalise(None)  # type: ignore[arg-type]
        out[a:a + chunk] = georeference(lp, scanner, st_ext)["X"]
    return out


def joint_inputs_from_flight(flight: Any) -> JointInputs:
    """The recipe's inputs from a simulated flight (:class:`skyrig.simulate.lidar_camera.JointFlight`): the recorded
    scan, trajectory and nominal mounts, the images and their measurements (what a user has; no truth)."""
    s = flight.survey
    return JointInputs(s.scan, s.trajectory_recorded, s.mount_recorded, s.frame, flight.camera, flight.body_from_camera,
                       flight.camera_lever_arm_m, flight.image_time_s, flight.image_strip, flight.obs_image,
                       flight.obs_point, flight.obs_pixel, flight.sigma_px)
