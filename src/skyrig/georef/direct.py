"""Direct georeferencing: exterior orientations of every image of every rig head from GNSS/IMU, and back.

The chain for an event at time t of head h (actuator angle beta for an actuated head)::

    ecef_from_body(t)   = ecef_from_ned(lat, lon) @ ned_from_body(roll, pitch, yaw)   (trajectory, slerp)
    imu_origin(t)       = trajectory position                      (reference "imu"), or
                          antenna position - ecef_from_body @ antenna_lever_arm       (reference "antenna")
    ecef_from_camera    = ecef_from_body @ body_from_camera_h(beta)                   (mounting @ boresight)
    projection centre   = imu_origin + ecef_from_body @ lever_arm_h

computed rigorously in ECEF, then expressed in any :class:`~skyrig.georef.eo.WorldFrame` (a map CRS with
grid-axis omega/phi/kappa, a local tangent/tangential frame, or ECEF).  :func:`inverse_georeference`
runs the chain backwards: from camera exterior orientations to IMU attitudes and antenna positions,
which is what system calibration compares with the recorded GNSS/IMU data.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.errors import ConfigError
from skyrig.geodesy.crs import ecef_to_geodetic
from skyrig.geodesy.local import ecef_from_ned_rotation
from skyrig.georef.eo import ExteriorOrientations, WorldFrame
from skyrig.geometry.rotations import rpy_from_matrix
from skyrig.rig.camera_pose import antenna_from_body_origin, body_origin_from_antenna, camera_poses, head_mountings
from skyrig.rig.rig import Rig
from skyrig.trajectory.events import CameraEvents, interpolate_events
from skyrig.trajectory.trajectory import Trajectory


def direct_georeference(
    trajectory: Trajectory,
    rig: Rig,
    events: CameraEvents,
    frame: WorldFrame,
    position: str = "cubic",
) -> ExteriorOrientations:
    """Exterior orientation of every event's image.

    Parameters
    ----------
    trajectory
        GNSS/IMU trajectory (positions of the IMU origin or of the GNSS antenna, see ``reference``).
    rig
        Heads with lever arms, mountings and boresights; antenna lever arm.
    events
        Exposure times, heads, image names and actuator angles.
    frame
        Output world frame.
    position
        ``"cubic"`` or ``"linear"`` position interpolation (attitude always by slerp).

    Returns
    -------
    ExteriorOrientations with ``time_s``, ``head``, ``exposure`` and ``extra["beta_rad"]`` filled.

    Raises
    ------
    EventOutOfSpanError
        An event lies outside the trajectory's time span (names the events file and line).
    HeadNotFoundError
        An event names a head the rig does not have.
    """
    eo, _ = georeference_with_platform(trajectory, rig, events, position)
    return eo.to_frame(frame)


def georeference_with_platform(trajectory: Trajectory, rig: Rig, events: CameraEvents, position: str = "cubic"
                               ) -> tuple[ExteriorOrientations, PlatformStates]:
    """:func:`direct_georeference` in ECEF together with the platform (IMU body) state of every event that it
    composed the cameras from: one interpolation of the trajectory serves both (a rig block takes its stations'
    poses from the second).  Raises as :func:`direct_georeference`."""
    s = interpolate_events(trajectory, events, position=position)  # type: ignore[arg-type]
    ecef_from_body = s.ecef_from_body
    if s.reference == "antenna":
        imu, antenna = body_origin_from_antenna(ecef_from_body, s.ecef, rig.antenna_lever_arm_m), s.ecef
    else:
        imu, antenna = s.ecef, antenna_from_body_origin(ecef_from_body, s.ecef, rig.antenna_lever_arm_m)
    ecef_from_camera, centre, cam = camera_poses(rig, events.head, events.beta_rad, ecef_from_body, imu)
    eo = ExteriorOrientations(
        events.image_name, cam, centre, ecef_from_camera, WorldFrame.ecef(),
        time_s=events.time_s, head=events.head, exposure=events.exposure_id,
        extra={"beta_rad": np.asarray(events.beta_rad, dtype=np.float64)},
    )
    return eo, PlatformStates(np.asarray(events.image_name), np.asarray(events.head), imu, antenna, ecef_from_body,
                              events.time_s)


@dataclass(frozen=True)
class PlatformStates:
    """Platform (IMU body) states of images: recovered from camera exterior orientations
    (:func:`inverse_georeference`) or interpolated from the trajectory (:func:`georeference_with_platform`).

    Attributes
    ----------
    image, head
        ``(M,)`` image and head names.
    imu_ecef, antenna_ecef
        ``(M, 3)`` IMU origin and GNSS antenna phase centre in ECEF (metres).
    ecef_from_body
        ``(M, 3, 3)`` body attitude in ECEF.
    time_s
        ``(M,)`` event times when the orientations carried them, else None.
    """

    image: NDArray[np.str_]
    head: NDArray[np.str_]
    imu_ecef: NDArray[np.float64]
    antenna_ecef: NDArray[np.float64]
    ecef_from_body: NDArray[np.float64]
    time_s: NDArray[np.float64] | None = None

    def antenna_geodetic(self) -> NDArray[np.float64]:
        """``(M, 3)`` antenna latitude, longitude (degrees) and ellipsoidal height (m)."""
        return np.column_stack(ecef_to_geodetic(self.antenna_ecef))

    def ned_from_body(self, at: str = "imu") -> NDArray[np.float64]:
        """Attitudes in the NED frame at the IMU (``at="imu"``) or antenna position, ``(M, 3, 3)``."""
        lat, lon, _ = ecef_to_geodetic(self.imu_ecef if at == "imu" else self.antenna_ecef)
        return np.swapaxes(ecef_from_ned_rotation(lat, lon), -1, -2) @ self.ecef_from_body

    def rpy(self, unit: str = "deg", at: str = "imu") -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Roll, pitch and yaw (true heading) ``(M,)`` each in ``unit``."""
        return rpy_from_matrix(self.ned_from_body(at), unit=unit)


def inverse_georeference(
    eo: ExteriorOrientations, rig: Rig, head: ArrayLike | None = None, beta_rad: ArrayLike | None = None
) -> PlatformStates:
    """IMU attitudes, IMU origins and antenna positions from camera exterior orientations.

    Parameters
    ----------
    eo
        Camera exterior orientations (any frame).
    rig
        The rig that took the images.
    head, beta_rad
        ``(M,)`` head name and actuator angle per image; default ``eo.head`` and ``eo.extra["beta_rad"]``.
    """
    heads = np.asarray(eo.head if head is None else head, dtype=str)
    if heads.shape != (len(eo),):
        raise ConfigError("inverse georeferencing needs the head of every image (eo.head or head=)")
    beta = beta_rad if beta_rad is not None else eo.extra.get("beta_rad", np.full(len(eo), np.nan))
    beta = np.asarray(beta, dtype=np.float64)
    ecef = eo.to_frame(WorldFrame.ecef())
    rot, lever, _ = head_mountings(rig, heads, beta)
    ecef_from_body = ecef.rotation @ np.swapaxes(rot, -1, -2)  # world_from_camera of skyrig.rig.camera_pose, inverted
    imu = ecef.centre - np.einsum("nij,nj->ni", ecef_from_body, lever)
    antenna = antenna_from_body_origin(ecef_from_body, imu, rig.antenna_lever_arm_m)
    return PlatformStates(eo.image, heads, imu, antenna, ecef_from_body, eo.time_s)
