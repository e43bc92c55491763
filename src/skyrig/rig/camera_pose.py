"""A camera's pose in the world from the platform's: the one place the rig chain is composed.

For an image of head ``h`` (actuator angle ``beta`` for an actuated head) taken when the platform (IMU body)
had the pose ``world_from_body``, ``body_origin``::

    body_from_camera_h(beta) = mounting_h(beta) @ boresight_h            (skyrig.rig.rig.Head.body_from_camera)
    world_from_camera        = world_from_body @ body_from_camera_h(beta)
    projection centre        = body_origin + world_from_body @ lever_arm_h

and, when the trajectory gives the GNSS antenna rather than the IMU origin,
``body_origin = antenna - world_from_body @ antenna_lever_arm``.  ``world`` is any Cartesian frame (ECEF for
direct georeferencing, the block's local frame in the adjustment, the simulator's scene frame).  The station of
a rig block is such a platform pose, and its images' ``image_rotation`` / ``image_offset`` are the heads'
``body_from_camera`` and lever arms: the adjustment composes its cameras with :func:`world_from_camera` as well.

Arrays: ``(N, 3, 3)`` rotations and ``(N, 3)`` vectors, metres and radians.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.rig.rig import Rig

__all__ = ["world_from_camera", "body_origin_from_antenna", "antenna_from_body_origin", "head_mountings",
           "camera_poses"]


def world_from_camera(world_from_body: NDArray[np.float64], body_origin: NDArray[np.float64],
                      body_from_camera: NDArray[np.float64], lever_arm_m: NDArray[np.float64]
                      ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Camera rotations ``world_from_camera`` ``(N, 3, 3)`` and projection centres ``(N, 3)``.

    ``world_from_body`` ``(N, 3, 3)`` and ``body_origin`` ``(N, 3)``: the platform's pose per image;
    ``body_from_camera`` ``(N, 3, 3)`` and ``lever_arm_m`` ``(N, 3)``: the head's mounting (with boresight)
    and lever arm per image.

    >>> R, C = world_from_camera(np.eye(3)[None], np.zeros((1, 3)), np.eye(3)[None], np.array([[0.0, 0.0, 1.0]]))
    >>> C.tolist()
    [[0.0, 0.0, 1.0]]
    """
    return world_from_body @ body_from_camera, body_origin + np.einsum("nij,nj->ni", world_from_body, lever_arm_m)


def body_origin_from_antenna(world_from_body: NDArray[np.float64], antenna: NDArray[np.float64],
                             antenna_lever_arm_m: ArrayLike) -> NDArray[np.float64]:
    """The IMU body origin ``(N, 3)`` from GNSS antenna positions ``(N, 3)`` (the antenna lever arm in the body)."""
    return antenna - np.einsum("nij,j->ni", world_from_body, np.asarray(antenna_lever_arm_m, dtype=np.float64))


def antenna_from_body_origin(world_from_body: NDArray[np.float64], body_origin: NDArray[np.float64],
                             antenna_lever_arm_m: ArrayLike) -> NDArray[np.float64]:
    """The GNSS antenna positions ``(N, 3)`` of body poses (inverse of :func:`body_origin_from_antenna`)."""
    return body_origin + np.einsum("nij,j->ni", world_from_body, np.asarray(antenna_lever_arm_m, dtype=np.float64))


def head_mountings(rig: Rig, head: ArrayLike, beta_rad: ArrayLike
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.str_]]:
    """``body_from_camera`` rotations ``(M, 3, 3)``, lever arms ``(M, 3)`` and camera names ``(M,)`` of ``M``
    images given their head names and actuator angles (radians; ignored for a fixed head)."""
    head = np.asarray(head)
    beta_rad = np.asarray(beta_rad, dtype=np.float64)
    m = len(head)
    rot = np.empty((m, 3, 3))
    lever = np.empty((m, 3))
    cam = np.empty(m, dtype=object)
    for name in np.unique(head):
        sel = head == name
        h = rig.head(str(name))
        pose = h.body_from_camera(beta_rad[sel] if h.is_actuated else None)
        rot[sel] = pose.rotation
        lever[sel] = pose.translation
        cam[sel] = h.camera.name
    return rot, lever, cam.astype(str)


def camera_poses(rig: Rig, head: ArrayLike, beta_rad: ArrayLike, world_from_body: NDArray[np.float64],
                 position: NDArray[np.float64], reference: str = "imu"
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.str_]]:
    """Camera rotations, projection centres and camera names of images of ``rig`` from platform poses.

    ``position`` ``(N, 3)`` is the IMU body origin (``reference="imu"``) or the GNSS antenna
    (``reference="antenna"``; the rig's antenna lever arm gives the body origin); ``head`` and ``beta_rad`` as for
    :func:`head_mountings`.
    """
    origin = position
    if reference == "antenna":
        origin = body_origin_from_antenna(world_from_body, position, rig.antenna_lever_arm_m)
    rot, lever, cam = head_mountings(rig, head, beta_rad)
    R, C = world_from_camera(world_from_body, origin, rot, lever)
    return R, C, cam
