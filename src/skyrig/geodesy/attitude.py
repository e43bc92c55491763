"""IMU angles (roll, pitch, yaw) <-> photogrammetric angles (omega, phi, kappa) in a projected CRS.

Frames (see ``docs/frames.md``)
-------------------------------
* **body**: the IMU body frame, x forward, y right, z down.  ``ned_from_body`` is given by roll,
  pitch, yaw (heading from *geographic* north, clockwise) with
  :func:`skyrig.geometry.rotations.matrix_from_rpy` (``Rz(yaw) Ry(pitch) Rx(roll)``).
* **NED**: local north-east-down at the exposure position (down = ellipsoid normal; the deflection
  of the vertical is ignored, as every IMU/GNSS post-processor does when it outputs these angles).
* **grid**: (grid east, grid north, up) at the exposure position, the frame in which photogrammetric
  software gives omega, phi, kappa for a projected CRS; kappa counts from *grid* north.
  ``grid_from_enu = rot_z(convergence)`` where the meridian convergence is the azimuth of grid north
  clockwise from true north (PROJ's ``meridian_convergence``, :meth:`skyrig.geodesy.MapProjection.factors`).
* **camera**: photogrammetric, x right in the image, y up, z towards the viewer (looks along -z).
  ``body_from_camera`` is the boresight/mount rotation.  A standard nadir camera with image x along
  the flight direction has ``body_from_camera = diag(1, -1, -1)`` (:data:`NADIR_BODY_FROM_CAMERA`).

The conversion is::

    grid_from_camera = rot_z(convergence) @ ENU_FROM_NED @ ned_from_body(roll, pitch, yaw) @ body_from_camera

and omega, phi, kappa are the angles of ``grid_from_camera`` in the chosen sequence
(:func:`skyrig.geometry.rotations.matrix_from_opk`).

Known answer (derived by hand): level flight heading north, nadir mount, convergence ``c``:
``ENU_FROM_NED @ diag(1,-1,-1) = [[0,-1,0],[1,0,0],[0,0,1]] = rot_z(90 deg)``, so
``grid_from_camera = rot_z(c) rot_z(90 deg)``: omega = phi = 0, kappa = 90 deg + c.  More generally,
for level flight with heading ``psi``, ``ENU_FROM_NED rot_z(psi) ENU_FROM_NED = rot_z(-psi)`` and
kappa = 90 deg - (psi - c), where ``psi - c`` is the grid bearing of the flight direction.
Pitching the nose up by ``t`` on a northward heading gives omega = ``t``; rolling the right wing down
by ``r`` gives phi = ``r``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.errors import GeometryError
from skyrig.geometry.rotations import (
    ENU_FROM_NED,
    NADIR_BODY_FROM_CAMERA,
    matrix_from_opk,
    matrix_from_rpy,
    opk_from_matrix,
    rot_z,
    rpy_from_matrix,
)


Angles = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]


def _check_rotation(matrix: ArrayLike, name: str) -> NDArray[np.float64]:
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape[-2:] != (3, 3):
        raise GeometryError(f"{name} must have shape (3, 3) or (N, 3, 3), got {m.shape}")
    eye = np.swapaxes(m, -1, -2) @ m
    if not np.allclose(eye, np.eye(3), atol=1e-6) or np.any(np.linalg.det(m) <= 0):
        raise GeometryError(f"{name} is not a rotation matrix (orthonormal, determinant +1)")
    return m


def grid_from_ned_rotation(convergence_rad: ArrayLike) -> NDArray[np.float64]:
    """``grid_from_ned = rot_z(convergence) @ ENU_FROM_NED``, shape ``(..., 3, 3)``.

    Parameters
    ----------
    convergence_rad
        Meridian convergence in radians (azimuth of grid north clockwise from true north), scalar or ``(N,)``.
    """
    return rot_z(convergence_rad) @ ENU_FROM_NED


def grid_from_camera_from_rpy(
    roll: ArrayLike,
    pitch: ArrayLike,
    yaw: ArrayLike,
    body_from_camera: ArrayLike,
    convergence_rad: ArrayLike,
    unit: str = "deg",
) -> NDArray[np.float64]:
    """Photogrammetric rotation ``grid_from_camera`` from IMU angles.

    ``grid_from_camera = rot_z(convergence) @ ENU_FROM_NED @ ned_from_body(roll, pitch, yaw) @ body_from_camera``.

    Parameters
    ----------
    roll, pitch, yaw
        IMU angles in ``unit``, scalar or ``(N,)``; yaw is the heading from geographic north, clockwise.
    body_from_camera
        Mount (boresight) rotation, ``(3, 3)`` or ``(N, 3, 3)``; :data:`NADIR_BODY_FROM_CAMERA` for a
        standard nadir camera.
    convergence_rad
        Meridian convergence at the exposure position in **radians**, scalar or ``(N,)``
        (:meth:`skyrig.geodesy.MapProjection.factors`); 0 for a local ENU frame at the exposure.
    unit
        Unit of roll, pitch, yaw: ``"deg"``, ``"rad"`` or ``"gon"``.

    Returns
    -------
    numpy.ndarray
        ``(3, 3)`` or ``(N, 3, 3)`` rotation matrices.
    """
    b = _check_rotation(body_from_camera, "body_from_camera")
    return grid_from_ned_rotation(convergence_rad) @ matrix_from_rpy(roll, pitch, yaw, unit) @ b


def ned_from_body_from_grid_from_camera(
    grid_from_camera: ArrayLike, body_from_camera: ArrayLike, convergence_rad: ArrayLike
) -> NDArray[np.float64]:
    """Inverse of :func:`grid_from_camera_from_rpy` at the matrix level: ``ned_from_body``.

    ``ned_from_body = ENU_FROM_NED @ rot_z(-convergence) @ grid_from_camera @ body_from_camera^T``;
    shapes as in :func:`grid_from_camera_from_rpy`.
    """
    b = _check_rotation(body_from_camera, "body_from_camera")
    g = np.asarray(grid_from_camera, dtype=np.float64)
    return ENU_FROM_NED @ rot_z(-np.asarray(convergence_rad, dtype=np.float64)) @ g @ np.swapaxes(b, -1, -2)


def opk_from_rpy(
    roll: ArrayLike,
    pitch: ArrayLike,
    yaw: ArrayLike,
    convergence_rad: ArrayLike,
    unit: str = "deg",
    sequence: str = "opk",
    body_from_camera: ArrayLike = NADIR_BODY_FROM_CAMERA,
) -> Angles:
    """Photogrammetric angles (omega, phi, kappa) in a projected CRS from IMU roll, pitch, yaw.

    Parameters
    ----------
    roll, pitch, yaw
        IMU angles (``ned_from_body``, body x forward, y right, z down; yaw = heading from geographic
        north, clockwise) in ``unit``, scalar or ``(N,)``.
    convergence_rad
        Meridian convergence in radians at each exposure, scalar or ``(N,)``.
    unit
        Unit of the input and the output angles (``"deg"``, ``"rad"``, ``"gon"``).
    sequence
        ``"opk"`` (omega-phi-kappa) or ``"pok"`` (phi-omega-kappa) for the output.
    body_from_camera
        Mount rotation ``(3, 3)`` or ``(N, 3, 3)``; default the standard nadir mount ``diag(1, -1, -1)``.

    Returns
    -------
    tuple of numpy.ndarray
        ``(omega, phi, kappa)`` in ``unit``; kappa counts from grid north.  Level flight heading north
        gives omega = phi = 0 and kappa = 90 deg + convergence.

    Notes
    -----
    Singular (gimbal lock) where the middle angle of ``sequence`` is +-90 deg.
    """
    r = grid_from_camera_from_rpy(roll, pitch, yaw, body_from_camera, convergence_rad, unit)
    return opk_from_matrix(r, unit, sequence)


def rpy_from_opk(
    omega: ArrayLike,
    phi: ArrayLike,
    kappa: ArrayLike,
    convergence_rad: ArrayLike,
    unit: str = "deg",
    sequence: str = "opk",
    body_from_camera: ArrayLike = NADIR_BODY_FROM_CAMERA,
) -> Angles:
    """IMU roll, pitch, yaw from photogrammetric angles in a projected CRS; inverse of :func:`opk_from_rpy`.

    Parameters are those of :func:`opk_from_rpy` with the roles of the angle triples swapped.  Returns
    ``(roll, pitch, yaw)`` in ``unit``; pitch in [-90, 90] deg, roll and yaw in [-180, 180] deg.
    Singular where pitch is +-90 deg.
    """
    g = matrix_from_opk(omega, phi, kappa, unit, sequence)
    return rpy_from_matrix(ned_from_body_from_grid_from_camera(g, body_from_camera, convergence_rad), unit)
