"""Bridge between georef data (map / ECEF frames) and a :class:`Block` in a local tangential frame.

:func:`block_from_georef` transforms exterior orientations, ground control and GNSS/IMU data given in
any :class:`~skyrig.georef.WorldFrame` rigorously (through ECEF, PROJ for map projections and geoids)
into a local ENU (tangential) frame at the block, builds the block there, and
:func:`eo_from_block` / :func:`points_to_frame` carry the adjusted values back.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.block import Block, BlockError
from skyrig.camera.frame import FrameCamera
from skyrig.geodesy.crs import ecef_to_geodetic
from skyrig.georef.eo import ExteriorOrientations, WorldFrame
from skyrig.georef.ground import forward_intersection
from skyrig.georef.observations import GroundPoints, ImageMeasurements
from skyrig.rig.camera_pose import world_from_camera

__all__ = ["local_frame_at", "block_from_georef", "eo_from_block", "points_to_frame"]


def local_frame_at(points_ecef: NDArray[np.float64], height: float | None = None) -> WorldFrame:
    """Local ENU frame at the centroid of ECEF points (on the ellipsoid, or at ``height``)."""
    lat, lon, h = ecef_to_geodetic(np.asarray(points_ecef, float).mean(axis=0, keepdims=True))
    return WorldFrame.local(float(lat[0]), float(lon[0]), float(h[0]) if height is None else float(height))


def block_from_georef(
    eo: ExteriorOrientations,
    cameras: Mapping[str, FrameCamera],
    measurements: ImageMeasurements,
    control: GroundPoints | None = None,
    *,
    start_eo: ExteriorOrientations | None = None,
    gnss_sigma_m: float | tuple[float, float, float] | None = 0.05,
    imu_sigma_rad: float | tuple[float, float, float] | None = 1e-4,
    control_sigma_m: float | tuple[float, float, float] = 0.02,
    check_points: tuple[str, ...] = (),
    sigma_px: float = 0.5,
    frame: WorldFrame | None = None,
    min_rays: int = 2,
    eo_pivot_m: float | None = None,
) -> tuple[Block, WorldFrame]:
    """A block in a local frame from exterior orientations, measurements and control.

    Parameters
    ----------
    eo
        Exterior orientations of (at least) the measured images, any frame.  With ``gnss_sigma_m`` /
        ``imu_sigma_rad`` their centres / rotations enter as GNSS / IMU observations of the cameras.
    cameras
        Camera name -> camera.
    measurements
        Image measurements of tie and control points; images not in ``eo`` raise :class:`BlockError`.
    control
        Ground control points (any frame); those named in ``check_points`` are check points.
    start_eo
        Starting values of the orientations (default ``eo``).
    frame
        Local frame to adjust in (default: ENU at the centroid of the projection centres, on the ellipsoid).
    min_rays
        Tie points measured in fewer images (and not control) are dropped.
    eo_pivot_m
        When given, the GNSS observation of each orientation is not its projection centre ``C`` but the
        point ``C + R @ (0, 0, -eo_pivot_m)`` on its optical axis ``eo_pivot_m`` metres in front of the
        camera (about the ground for the flying height), as a fixed GNSS lever arm.  Use it when the
        "GNSS/IMU" observations are themselves *adjusted* orientations (an earlier aerial triangulation):
        such orientations fix where each image looks on the ground far better than how that is split
        between centre and attitude (a centre shift ``dX`` with a tilt ``-dX / H`` leaves the footprint
        in place).  With ``gnss_sigma_m`` then the sigma of that ground point and ``imu_sigma_rad`` the
        attitude sigma, the implied prior of the centre has the strong centre/attitude correlation of an
        adjusted orientation (horizontal sigma ``sqrt(gnss^2 + (eo_pivot_m * imu)^2)``) instead of
        independent centre and attitude errors.  Single-camera blocks only (the lever arm is in the camera
        frame, which looks along -z).

    Returns
    -------
    block, frame
        Starting object points come from a forward intersection with the starting orientations.
    """
    idx = eo.index()
    unknown = sorted(set(measurements.image.tolist()) - set(idx))
    if unknown:
        raise BlockError(f"measurements name {len(unknown)} image(s) without an exterior orientation, e.g. "
                         f"{unknown[0]!r}")
    imgs = np.unique(measurements.image)
    rows = np.array([idx[i] for i in imgs])
    eo_sel = eo.subset(rows)
    if frame is None:
        frame = local_frame_at(eo_sel.frame.to_ecef(eo_sel.centre))
    obs_l = eo_sel.to_frame(frame)
    st = (start_eo if start_eo is not None else eo)
    st_idx = st.index()  # once: a dict per image made this quadratic (66 s at 2,940 images)
    st_l = st.subset(np.array([st_idx[i] for i in imgs])).to_frame(frame)
    cam_names = sorted(set(obs_l.camera.tolist()))
    missing = [c for c in cam_names if c not in cameras]
    if missing:
        raise BlockError(f"no camera model for camera {missing[0]!r}")
    cam_idx = {c: k for k, c in enumerate(cam_names)}
    # points: tie points with enough rays, control points
    m_point, m_image, m_pixel, pnames = _kept_measurements(measurements, control, min_rays)
    pidx = {p: k for k, p in enumerate(pnames)}
    X0 = _intersected(st_l, cameras, m_point, m_image, m_pixel, frame, pidx)
    ctrl_kw: dict = {}
    if control is not None:
        ctrl_kw = _control_rows(control, frame, pidx, X0, control_sigma_m, check_points)
    if not np.isfinite(X0).all():
        k = int(np.flatnonzero(~np.isfinite(X0).all(axis=1))[0])
        raise BlockError(f"point {pnames[k]!r} could not be intersected from the starting orientations")
    img_index = {n: k for k, n in enumerate(imgs)}
    n = len(imgs)
    kw = _gnss_imu_rows(obs_l, gnss_sigma_m, imu_sigma_rad, eo_pivot_m)
    block = Block(
        cameras=[cameras[c] for c in cam_names], station_name=imgs, station_rotation=st_l.rotation,
        station_centre=st_l.centre, image_name=imgs, image_station=np.arange(n),
        image_camera=np.array([cam_idx[c] for c in obs_l.camera]), image_head=np.array([cam_idx[c] for c in obs_l.camera]),
        head_name=np.array(cam_names), point_name=pnames, point_xyz=X0,
        obs_image=np.array([img_index[i] for i in m_image], dtype=np.int64),
        obs_point=np.array([pidx[p] for p in m_point], dtype=np.int64), obs_pixel=m_pixel,
        obs_sigma_px=np.asarray(sigma_px, dtype=np.float64),
        frame=frame, **ctrl_kw, **kw,
    )
    return block, frame


def _kept_measurements(measurements: ImageMeasurements, control: GroundPoints | None, min_rays: int
                       ) -> tuple[NDArray, NDArray, NDArray[np.float64], NDArray]:
    """The measurements of points seen in ``min_rays`` images or more, or that are control: point, image, pixel,
    and the kept point names (sorted)."""
    ctrl_names = set() if control is None else set(control.name.tolist())
    pnames, pid, counts = np.unique(measurements.point, return_inverse=True, return_counts=True)
    keep_pt = (counts >= min_rays) | np.isin(pnames, list(ctrl_names))
    keep_obs = keep_pt[pid]
    return (measurements.point[keep_obs], measurements.image[keep_obs], measurements.pixel[keep_obs],
            pnames[keep_pt])


def _intersected(st_l: ExteriorOrientations, cameras: Mapping[str, FrameCamera], m_point: NDArray, m_image: NDArray,
                 m_pixel: NDArray[np.float64], frame: WorldFrame, pidx: dict[Any, int]) -> NDArray[np.float64]:
    """Starting object points ``(P, 3)``: the forward intersection with the starting orientations (NaN where a
    point cannot be intersected)."""
    inter = forward_intersection(st_l, cameras, m_point, m_image, m_pixel, frame)
    X0 = np.full((len(pidx), 3), np.nan)
    ii = {p: k for k, p in enumerate(inter.point)}
    for p, k in pidx.items():
        if p in ii:
            X0[k] = inter.xyz[ii[p]]
    return X0


def _control_rows(control: GroundPoints, frame: WorldFrame, pidx: dict[Any, int], X0: NDArray[np.float64],
                  control_sigma_m: float | tuple[float, float, float], check_points: tuple[str, ...]
                  ) -> dict[str, Any]:
    """The block's control fields for the measured ground points (in ``frame``); a control point that could not be
    intersected starts at its surveyed position (``X0`` is updated)."""
    c_local = frame.from_ecef(control.frame.to_ecef(control.xyz))
    sel = np.array([n in pidx for n in control.name])
    cp = np.array([pidx[n] for n in control.name[sel]], dtype=np.int64)
    bad = ~np.isfinite(X0[cp]).all(axis=1)
    X0[cp[bad]] = c_local[sel][bad]
    return dict(control_point=cp, control_xyz=c_local[sel], control_sigma=control_sigma_m,
                control_check=np.isin(control.name[sel], list(check_points)))


def _gnss_imu_rows(obs_l: ExteriorOrientations, gnss_sigma_m: float | tuple[float, float, float] | None,
                   imu_sigma_rad: float | tuple[float, float, float] | None, eo_pivot_m: float | None
                   ) -> dict[str, Any]:
    """The block's GNSS / IMU fields: the orientations' centres (or pivots, ``eo_pivot_m``) and rotations as
    observations of their own stations."""
    n = len(obs_l)
    kw: dict[str, Any] = {}
    if gnss_sigma_m is not None:
        if eo_pivot_m is None:
            kw.update(gnss_station=np.arange(n), gnss_xyz=obs_l.centre, gnss_sigma=gnss_sigma_m)
        else:
            if not np.isfinite(eo_pivot_m) or eo_pivot_m <= 0:
                raise BlockError(f"eo_pivot_m must be a positive distance in metres, not {eo_pivot_m!r}")
            lever = np.array([0.0, 0.0, -float(eo_pivot_m)])
            kw.update(gnss_station=np.arange(n), gnss_xyz=obs_l.centre + obs_l.rotation @ lever,
                      gnss_sigma=gnss_sigma_m, lever_arm=lever)
    if imu_sigma_rad is not None:
        kw.update(imu_station=np.arange(n), imu_rotation=obs_l.rotation, imu_sigma_rad=imu_sigma_rad)
    return kw


def eo_from_block(block: Block, frame: WorldFrame, to: WorldFrame | None = None) -> ExteriorOrientations:
    """Exterior orientations of the block's images (``world_from_camera``) in ``frame``, optionally converted."""
    from skyrig.geometry.rotations import matrix_from_rotvec

    st = block.image_station
    R, C = world_from_camera(block.station_rotation[st], block.station_centre[st], block.image_rotation,
                             block.image_offset)
    R = R @ matrix_from_rotvec(block.head_boresight[block.image_head])
    cams = np.array([block.cameras[c].name for c in block.image_camera])
    eo = ExteriorOrientations(block.image_name, cams, C, R, frame)
    return eo if to is None else eo.to_frame(to)


def points_to_frame(xyz: NDArray[np.float64], frame: WorldFrame, to: WorldFrame) -> NDArray[np.float64]:
    """Points ``(N, 3)`` from one world frame to another (through ECEF)."""
    return to.from_ecef(frame.to_ecef(xyz))
