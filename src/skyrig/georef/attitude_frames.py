"""Camera attitudes as navigation angles (yaw/pitch/roll) in any world frame.

A camera's "YPR" attitude in skyrig files is the roll, pitch and yaw (heading from geographic north)
of a virtual platform that carries the camera in the standard nadir mount
(:data:`skyrig.geometry.rotations.NADIR_BODY_FROM_CAMERA`)::

    enu_from_camera = ENU_FROM_NED @ Rz(yaw) Ry(pitch) Rx(roll) @ NADIR_BODY_FROM_CAMERA

with ENU the local tangent frame at the projection centre.  In a map frame the meridian convergence
enters through the grid axes (``grid_from_enu = Rz(convergence)``), so YPR and OPK differ in kappa by
about 90 deg minus the convergence for level flight.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.geodesy.attitude import grid_from_camera_from_rpy, ned_from_body_from_grid_from_camera
from skyrig.geodesy.crs import ecef_to_geodetic
from skyrig.geodesy.local import ecef_from_enu_rotation
from skyrig.georef.eo import WorldFrame
from skyrig.geometry.rotations import NADIR_BODY_FROM_CAMERA, rpy_from_matrix


def frame_from_enu_rotation(frame: WorldFrame, centres: ArrayLike) -> NDArray[np.float64]:
    """``frame_from_enu`` ``(N, 3, 3)``: the local ENU axes at points ``(N, 3)`` of ``frame`` in that frame's axes."""
    c = np.atleast_2d(np.asarray(centres, dtype=np.float64))
    lat, lon, _ = ecef_to_geodetic(frame.to_ecef(c))
    return np.swapaxes(frame.ecef_from_frame_rotation(c), -1, -2) @ ecef_from_enu_rotation(lat, lon)


def rotation_from_ypr(
    frame: WorldFrame, centres: ArrayLike, yaw: ArrayLike, pitch: ArrayLike, roll: ArrayLike, unit: str = "deg"
) -> NDArray[np.float64]:
    """``frame_from_camera`` ``(N, 3, 3)`` from camera YPR angles at projection centres ``(N, 3)`` of ``frame``."""
    # ENU is the grid of a frame with zero convergence
    enu_from_cam = grid_from_camera_from_rpy(roll, pitch, yaw, NADIR_BODY_FROM_CAMERA, 0.0, unit=unit)
    return frame_from_enu_rotation(frame, centres) @ enu_from_cam


def ypr_from_rotation(
    frame: WorldFrame, centres: ArrayLike, rotation: ArrayLike, unit: str = "deg"
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Inverse of :func:`rotation_from_ypr`: ``(yaw, pitch, roll)`` in ``unit``."""
    enu_from_cam = np.swapaxes(frame_from_enu_rotation(frame, centres), -1, -2) @ np.asarray(rotation, dtype=np.float64)
    ned_from_body = ned_from_body_from_grid_from_camera(enu_from_cam, NADIR_BODY_FROM_CAMERA, 0.0)
    roll, pitch, yaw = rpy_from_matrix(ned_from_body, unit=unit)
    return yaw, pitch, roll


def rotation_from_gimbal_ypr(frame: WorldFrame, centres: NDArray, ypr_deg: NDArray) -> NDArray[np.float64]:
    """``frame_from_camera`` from DJI-gimbal (yaw, pitch, roll) degrees at projection centres (``ypr_deg (N, 3)``;
    gimbal pitch -90 looks straight down).  Used by the readers of DJI metadata and ODM ``geo.txt`` and by the
    simulator."""
    from skyrig.geometry.rotations import ENU_FROM_NED, GIMBAL_FROM_CAMERA, matrix_from_rpy

    ned_from_gimbal = matrix_from_rpy(ypr_deg[:, 2], ypr_deg[:, 1], ypr_deg[:, 0], unit="deg")
    return frame_from_enu_rotation(frame, centres) @ (ENU_FROM_NED @ ned_from_gimbal @ GIMBAL_FROM_CAMERA)
