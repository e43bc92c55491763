"""A rig block from what a survey flight records: trajectory, camera events, rig, measurements, control.

Every platform exposure becomes one *station* (the IMU body pose at the exposure time); each image hangs
off its station through its head's mounting, boresight and lever arm (``station_from_camera`` fixed,
the head's boresight correction an optional unknown).  The GNSS observation of a station is the
antenna position (through the rig's antenna lever arm), its IMU observation the body attitude - the
rig constraint of paper 003/004: all heads of a rig share one platform pose per exposure, so GNSS/IMU
errors enter once per exposure, not once per head.

The world frame is a local ENU frame (:func:`skyrig.adjust.frames.local_frame_at` unless given), like
:func:`skyrig.adjust.frames.block_from_georef`, whose point and control handling is reused.
"""

from __future__ import annotations

from dataclasses import replace
import logging
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.block import AdjustConfig, Block, BlockError
from skyrig.adjust.frames import block_from_georef
from skyrig.adjust.model import Model, State
from skyrig.georef.direct import georeference_with_platform
from skyrig.georef.eo import ExteriorOrientations, WorldFrame
from skyrig.georef.observations import GroundPoints, ImageMeasurements
from skyrig.rig.camera_pose import antenna_from_body_origin, head_mountings
from skyrig.rig.rig import Rig
from skyrig.trajectory import CameraEvents, Trajectory

__all__ = ["block_from_trajectory"]

logger = logging.getLogger(__name__)


#: fields of the base block that the new stations and heads make wrong: None = filled again by Block.__post_init__
_REFILLED: dict[str, Any] = dict(head_boresight=None, strip_shift=None, strip_drift=None, strip_t0=None,
                                 actuator_correction=None)


def _exposure_stations(events: CameraEvents, base: Block, same_exposure_s: float):
    """The block images' event rows and events, the exposure ids (one station each), each image's station,
    the event times and each station's first image; :class:`BlockError` when an exposure's images are
    farther apart in time than ``same_exposure_s``."""
    ev_index = {str(n): k for k, n in enumerate(events.image_name)}
    rows = np.array([ev_index[str(n)] for n in base.image_name], dtype=np.int64)
    ev = events.subset(rows)
    expo, station_of_image = np.unique(np.asarray(ev.exposure_id), return_inverse=True)
    t = np.asarray(ev.time_s, dtype=np.float64)
    order = np.argsort(station_of_image, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(station_of_image[order]) != 0])
    first = order[starts]  # first image (in block order) of each exposure
    spreads = np.maximum.reduceat(t[order], starts) - np.minimum.reduceat(t[order], starts)
    too_long = np.flatnonzero(spreads > same_exposure_s)
    if too_long.size:
        s, spread = int(too_long[0]), float(spreads[too_long[0]])
        raise BlockError(f"exposure {int(expo[s])}: its images were taken {spread:.6f} s apart (more than "
                         f"{same_exposure_s} s), so they cannot share one platform pose; give them separate "
                         f"exposure ids in {events.source or 'the events'}")
    return rows, ev, expo, station_of_image, t, first


def _gnss_imu_rows(rig: Rig, body: ExteriorOrientations, gnss_sigma_m, imu_sigma_rad) -> dict:
    """The GNSS (antenna) and IMU (body attitude) observation fields of one row per station (None: left out)."""
    kw: dict = {}
    n_st = len(body.rotation)
    if gnss_sigma_m is not None:
        antenna = antenna_from_body_origin(body.rotation, body.centre, rig.antenna_lever_arm_m)
        kw.update(gnss_station=np.arange(n_st), gnss_xyz=antenna,
                  gnss_sigma=np.broadcast_to(np.asarray(gnss_sigma_m, dtype=np.float64), (n_st, 3)).copy())
    if imu_sigma_rad is not None:
        kw.update(imu_station=np.arange(n_st), imu_rotation=body.rotation,
                  imu_sigma_rad=np.broadcast_to(np.asarray(imu_sigma_rad, dtype=np.float64), (n_st, 3)).copy())
    return kw


def block_from_trajectory(
    trajectory: Trajectory,
    rig: Rig,
    events: CameraEvents,
    measurements: ImageMeasurements,
    control: GroundPoints | None = None,
    *,
    gnss_sigma_m: float | Sequence[float] | None = (0.05, 0.05, 0.08),
    imu_sigma_rad: float | Sequence[float] | None = (1e-4, 1e-4, 2e-4),
    control_sigma_m: float | Sequence[float] = 0.02,
    check_points: Sequence[str] = (),
    sigma_px: float = 0.5,
    frame: WorldFrame | None = None,
    min_rays: int = 2,
    position: str = "cubic",
    same_exposure_s: float = 1e-4,
    max_start_residual_px: float = 100.0,
) -> tuple[Block, WorldFrame]:
    """Rig block (one station per exposure) from the recorded flight and the measurements.

    Parameters
    ----------
    trajectory, rig, events
        As for :func:`skyrig.georef.direct.direct_georeference`; their direct georeferencing gives the
        starting values and the GNSS/IMU observations.
    measurements
        Image measurements of tie and control points (pixels); images must be events.
    control
        Ground points (any frame); those named in ``check_points`` are check points.
    gnss_sigma_m, imu_sigma_rad
        Sigma of the antenna positions (m, per axis E N U of the local frame) and of the body attitudes
        (rad, about the body axes); None leaves the group out.
    control_sigma_m, sigma_px, min_rays, frame
        As for :func:`skyrig.adjust.frames.block_from_georef`.
    position
        Trajectory position interpolation.
    same_exposure_s
        Events of one exposure id must lie within this many seconds of each other (one platform pose);
        otherwise :class:`BlockError`.
    max_start_residual_px
        Tie points that project behind a camera or farther than this from one of their measurements
        with the starting orientations (gross mismatches) are left out; so are points seen from a single
        exposure (no base).

    Returns
    -------
    block, frame
        Station ``k`` is exposure ``block.station_name[k]`` (``"exposure <id>"``); ``block.lever_arm`` is
        the rig's antenna lever arm; heads are the rig's heads (boresight-correction groups).
    """
    eo_ecef, platform = georeference_with_platform(trajectory, rig, events, position)  # the one interpolation
    eo = eo_ecef.to_frame(WorldFrame.ecef())  # as direct_georeference returns it
    cameras = {h.camera.name: h.camera for h in rig}
    base, frame = block_from_georef(eo, cameras, measurements, control, gnss_sigma_m=None, imu_sigma_rad=None,
                                    control_sigma_m=control_sigma_m, check_points=tuple(check_points),  # type: ignore[arg-type]
                                    sigma_px=sigma_px, frame=frame, min_rays=min_rays)
    rows, ev, expo, station_of_image, t, first = _exposure_stations(events, base, same_exposure_s)
    # platform (IMU body) pose per station, in the local frame: the pose the cameras were composed from (all
    # images of an exposure share it, within same_exposure_s)
    at = rows[first]
    names = np.array([f"exposure {int(e)}" for e in expo])
    body = ExteriorOrientations(names, np.array(["body"] * len(expo)), platform.imu_ecef[at],
                                platform.ecef_from_body[at], WorldFrame.ecef()).to_frame(frame)
    # station_from_camera and lever arm of each image
    heads = rig.head_names
    head_idx = {h: k for k, h in enumerate(heads)}
    image_head = np.array([head_idx[str(h)] for h in ev.head], dtype=np.int64)
    beta = np.asarray(ev.beta_rad, dtype=np.float64)
    actuated = np.array([rig.head(h).is_actuated for h in heads], bool)
    image_rotation, image_offset, head_camera = head_mountings(rig, ev.head, beta)  # station_from_camera
    cam_names = np.array([c.name for c in base.cameras])
    wrong = np.flatnonzero(cam_names[base.image_camera] != head_camera)
    if wrong.size:  # pragma: no cover
        i = int(wrong[0])
        raise BlockError(f"image {str(base.image_name[i])!r}: camera does not match head {str(ev.head[i])!r}")
    n_st = len(expo)
    kw = _gnss_imu_rows(rig, body, gnss_sigma_m, imu_sigma_rad)
    block = replace(
        base,
        station_name=names, station_rotation=body.rotation, station_centre=body.centre,
        station_time=t[first], station_strip=np.full(n_st, -1, dtype=np.int64),
        image_station=station_of_image.astype(np.int64), image_rotation=image_rotation, image_offset=image_offset,
        image_head=image_head, head_name=np.array(heads),
        lever_arm=np.asarray(rig.antenna_lever_arm_m, dtype=np.float64).copy(),
        head_actuated=[rig.head(h) if a else None for h, a in zip(heads, actuated)],
        image_beta_rad=np.where(actuated[image_head], beta, np.nan),
        **kw, **_REFILLED,
    )
    block = _drop_points(block, _single_station(block) | _gross_at_start(block, max_start_residual_px))
    return block, frame


def _single_station(block: Block) -> NDArray[np.bool_]:
    """Points whose rays all come from one exposure (no base: depth undetermined).

    Heads of one rig exposure share (nearly) one projection centre, so a tie between the nadir and an
    oblique image of the same exposure cannot be intersected; a check point seen from one exposure only
    cannot be checked.
    """
    st = block.image_station[block.obs_image]
    pairs = np.unique(np.column_stack([block.obs_point, st]), axis=0)
    return np.bincount(pairs[:, 0], minlength=block.n_points) < 2


def _gross_at_start(block: Block, limit_px: float) -> NDArray[np.bool_]:
    """Points that project behind a camera, or more than ``limit_px`` from a measurement, at the start.

    Such points are mismatches whose forward intersection landed anywhere (above the aircraft, behind
    an oblique camera); they carry no information and would make the normal equations singular.
    """
    f = next(f for f in Model(block, AdjustConfig()).evaluate(State.from_block(block), jacobians=False)
             if f.name == "image")
    res = np.abs(f.r) * block.obs_sigma_px
    bad_obs = (np.zeros(len(res), bool) if f.bad is None else f.bad) | (res.max(axis=1) > limit_px)
    out = np.zeros(block.n_points, bool)
    out[block.obs_point[bad_obs]] = True
    return out


def _drop_points(block: Block, drop: NDArray[np.bool_]) -> Block:
    """Block without the points flagged in ``drop`` (control points used in the adjustment are kept)."""
    is_control = np.zeros(block.n_points, bool)
    is_control[block.control_point[~block.control_check]] = True
    keep = ~drop | is_control
    if keep.all():
        return block
    logger.info("dropped %d of %d points at the start (single exposure or gross start residual)",
                int((~keep).sum()), block.n_points)
    if len(block.distance_point):
        raise BlockError("distance observations with single-exposure points are not supported here")
    new_index = np.cumsum(keep) - 1
    obs_keep = keep[block.obs_point]
    ctrl_keep = keep[block.control_point]
    kw: dict = dict(
        point_name=block.point_name[keep], point_xyz=block.point_xyz[keep],
        obs_image=block.obs_image[obs_keep], obs_point=new_index[block.obs_point[obs_keep]],
        obs_pixel=block.obs_pixel[obs_keep], obs_sigma_px=block.obs_sigma_px[obs_keep],
        control_point=new_index[block.control_point[ctrl_keep]], control_xyz=block.control_xyz[ctrl_keep],
        control_sigma=block.control_sigma[ctrl_keep], control_check=block.control_check[ctrl_keep],
    )
    if block.obs_cov_px2 is not None:
        kw["obs_cov_px2"] = block.obs_cov_px2[obs_keep]
    if block.control_cov_m2 is not None:
        kw["control_cov_m2"] = block.control_cov_m2[ctrl_keep]
    return replace(block, **kw)
