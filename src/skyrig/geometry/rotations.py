"""Rotation matrices, quaternions and the attitude angle conventions of photogrammetry and navigation.

Conventions (used everywhere in skyrig)
---------------------------------------
* A rotation matrix is named ``dst_from_src``: it maps coordinates of a vector given in frame *src*
  to coordinates in frame *dst*: ``x_dst = R @ x_src``.
* ``rot_x``, ``rot_y``, ``rot_z`` are the elementary right-handed matrices
  (``rot_z(a) = [[cos a, -sin a, 0], [sin a, cos a, 0], [0, 0, 1]]``).
* **Photogrammetric angles** omega, phi, kappa give ``world_from_camera``:

  - sequence ``"opk"`` (omega-phi-kappa, the default): ``R = rot_x(omega) @ rot_y(phi) @ rot_z(kappa)``
  - sequence ``"pok"`` (phi-omega-kappa): ``R = rot_y(phi) @ rot_x(omega) @ rot_z(kappa)``

  The world frame is a right-handed (East, North, Up)-like frame: a projected CRS grid with heights
  (kappa then counts from grid north / grid east axes), a local tangent plane ENU, or the tangential
  frame.  The camera frame is the photogrammetric one: x to the right of the image, y up in the image,
  z towards the viewer, so the camera looks along -z.  A level nadir camera with x to the east has
  omega = phi = kappa = 0.
* **Navigation angles** roll, pitch, yaw (heading) give ``ned_from_body`` with the body frame
  (x forward, y right, z down) and the local North-East-Down frame:
  ``R = rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)`` (aerospace z-y'-x'' sequence).  Yaw is the heading
  from geographic north, clockwise.
* Quaternions are Hamilton, scalar first ``(w, x, y, z)``, unit norm, ``w >= 0`` on output.

All functions are vectorised: angles of shape ``(N,)`` give matrices ``(N, 3, 3)``; scalars give ``(3, 3)``.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.errors import SkyrigError
from skyrig.geometry.angles import to_radians, from_radians

Sequence = Literal["opk", "pok"]

#: ``enu_from_ned`` (and its own inverse): swaps north/east and flips the vertical.
ENU_FROM_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def _elementary(angle: ArrayLike, axis: int) -> NDArray[np.float64]:
    a = np.asarray(angle, dtype=np.float64)
    c, s = np.cos(a), np.sin(a)
    out = np.zeros(a.shape + (3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    out[..., axis, axis] = 1.0
    out[..., i, i] = c
    out[..., j, j] = c
    out[..., i, j] = -s
    out[..., j, i] = s
    return out


def rot_x(angle_rad: ArrayLike) -> NDArray[np.float64]:
    """Right-handed rotation about x by ``angle_rad`` (radians); shape ``(..., 3, 3)``."""
    return _elementary(angle_rad, 0)


def rot_y(angle_rad: ArrayLike) -> NDArray[np.float64]:
    """Right-handed rotation about y by ``angle_rad`` (radians); shape ``(..., 3, 3)``."""
    return _elementary(angle_rad, 1)


def rot_z(angle_rad: ArrayLike) -> NDArray[np.float64]:
    """Right-handed rotation about z by ``angle_rad`` (radians); shape ``(..., 3, 3)``."""
    return _elementary(angle_rad, 2)


def _check_sequence(sequence: str) -> str:
    s = sequence.lower().replace("-", "").replace("_", "")
    s = {"omegaphikappa": "opk", "phiomegakappa": "pok"}.get(s, s)
    if s not in ("opk", "pok"):
        raise SkyrigError(f"unknown rotation sequence {sequence!r}; expected 'opk' or 'pok'")
    return s


def matrix_from_opk(
    omega: ArrayLike, phi: ArrayLike, kappa: ArrayLike, unit: str = "rad", sequence: str = "opk"
) -> NDArray[np.float64]:
    """``world_from_camera`` from photogrammetric angles.

    Parameters
    ----------
    omega, phi, kappa
        Angles, shape ``(N,)`` or scalar, in ``unit``.
    unit
        ``"rad"``, ``"deg"`` or ``"gon"``.
    sequence
        ``"opk"``: ``Rx(omega) Ry(phi) Rz(kappa)``; ``"pok"``: ``Ry(phi) Rx(omega) Rz(kappa)``.
    """
    o, p, k = (to_radians(v, unit) for v in (omega, phi, kappa))
    if _check_sequence(sequence) == "opk":
        return rot_x(o) @ rot_y(p) @ rot_z(k)
    return rot_y(p) @ rot_x(o) @ rot_z(k)


def opk_from_matrix(
    world_from_camera: ArrayLike, unit: str = "rad", sequence: str = "opk"
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Inverse of :func:`matrix_from_opk`: ``(omega, phi, kappa)`` in ``unit``.

    Angles are in (-pi, pi] except the middle one of the sequence, which is in [-pi/2, pi/2].
    """
    r = np.asarray(world_from_camera, dtype=np.float64)
    if _check_sequence(sequence) == "opk":
        # R = Rx(o) Ry(p) Rz(k): R[0,2] = sin p, R[1,2] = -sin o cos p, R[2,2] = cos o cos p,
        # R[0,0] = cos p cos k, R[0,1] = -cos p sin k
        phi = np.arcsin(np.clip(r[..., 0, 2], -1.0, 1.0))
        omega = np.arctan2(-r[..., 1, 2], r[..., 2, 2])
        kappa = np.arctan2(-r[..., 0, 1], r[..., 0, 0])
    else:
        # R = Ry(p) Rx(o) Rz(k): R[1,2] = -sin o, R[0,2] = sin p cos o, R[2,2] = cos p cos o,
        # R[1,0] = cos o sin k, R[1,1] = cos o cos k
        omega = np.arcsin(np.clip(-r[..., 1, 2], -1.0, 1.0))
        phi = np.arctan2(r[..., 0, 2], r[..., 2, 2])
        kappa = np.arctan2(r[..., 1, 0], r[..., 1, 1])
    return from_radians(omega, unit), from_radians(phi, unit), from_radians(kappa, unit)


def matrix_from_rpy(roll: ArrayLike, pitch: ArrayLike, yaw: ArrayLike, unit: str = "rad") -> NDArray[np.float64]:
    """``ned_from_body`` from roll, pitch, yaw (heading) in ``unit``: ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    r, p, y = (to_radians(v, unit) for v in (roll, pitch, yaw))
    return rot_z(y) @ rot_y(p) @ rot_x(r)


def rpy_from_matrix(
    ned_from_body: ArrayLike, unit: str = "rad"
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Inverse of :func:`matrix_from_rpy`: ``(roll, pitch, yaw)`` in ``unit``; pitch in [-90, 90] deg."""
    r = np.asarray(ned_from_body, dtype=np.float64)
    pitch = np.arcsin(np.clip(-r[..., 2, 0], -1.0, 1.0))
    roll = np.arctan2(r[..., 2, 1], r[..., 2, 2])
    yaw = np.arctan2(r[..., 1, 0], r[..., 0, 0])
    return from_radians(roll, unit), from_radians(pitch, unit), from_radians(yaw, unit)


def quaternion_from_matrix(matrix: ArrayLike) -> NDArray[np.float64]:
    """Unit quaternion ``(w, x, y, z)`` (Hamilton, ``w >= 0``) of rotation matrices ``(..., 3, 3)``.

    Uses the numerically stable largest-component branch for every element.
    """
    m = np.asarray(matrix, dtype=np.float64)
    shape = m.shape[:-2]
    m = m.reshape(-1, 3, 3)
    tr = np.trace(m, axis1=1, axis2=2)
    cand = np.stack([tr, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], axis=1)
    best = np.argmax(cand, axis=1)
    q = np.empty((m.shape[0], 4))
    # branch 0: w largest
    s = np.sqrt(np.maximum(1.0 + tr, 0.0)) * 2.0
    b = best == 0
    q[b, 0] = 0.25 * s[b]
    q[b, 1] = (m[b, 2, 1] - m[b, 1, 2]) / s[b]
    q[b, 2] = (m[b, 0, 2] - m[b, 2, 0]) / s[b]
    q[b, 3] = (m[b, 1, 0] - m[b, 0, 1]) / s[b]
    for i in range(3):
        j, k = (i + 1) % 3, (i + 2) % 3
        b = best == i + 1
        s = np.sqrt(np.maximum(1.0 + m[b, i, i] - m[b, j, j] - m[b, k, k], 0.0)) * 2.0
        q[b, 0] = (m[b, k, j] - m[b, j, k]) / s
        q[b, 1 + i] = 0.25 * s
        q[b, 1 + j] = (m[b, j, i] + m[b, i, j]) / s
        q[b, 1 + k] = (m[b, k, i] + m[b, i, k]) / s
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 0] < 0] *= -1.0
    return q.reshape(shape + (4,))


def matrix_from_quaternion(quaternion: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrices ``(..., 3, 3)`` from quaternions ``(..., 4)`` ``(w, x, y, z)`` (normalised here)."""
    q = np.asarray(quaternion, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    out = np.empty(q.shape[:-1] + (3, 3))
    out[..., 0, 0] = 1 - 2 * (y * y + z * z)
    out[..., 0, 1] = 2 * (x * y - w * z)
    out[..., 0, 2] = 2 * (x * z + w * y)
    out[..., 1, 0] = 2 * (x * y + w * z)
    out[..., 1, 1] = 1 - 2 * (x * x + z * z)
    out[..., 1, 2] = 2 * (y * z - w * x)
    out[..., 2, 0] = 2 * (x * z - w * y)
    out[..., 2, 1] = 2 * (y * z + w * x)
    out[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return out


def matrix_from_rotvec(rotvec: ArrayLike) -> NDArray[np.float64]:
    """Rodrigues: rotation matrices ``(..., 3, 3)`` from axis-angle vectors ``(..., 3)`` in radians."""
    v = np.asarray(rotvec, dtype=np.float64)
    theta = np.linalg.norm(v, axis=-1)
    small = theta < 1e-8
    safe = np.where(small, 1.0, theta)
    k = v / safe[..., None]
    kx, ky, kz = k[..., 0], k[..., 1], k[..., 2]
    K = np.zeros(v.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2] = -kz, ky
    K[..., 1, 0], K[..., 1, 2] = kz, -kx
    K[..., 2, 0], K[..., 2, 1] = -ky, kx
    s = np.sin(theta)[..., None, None]
    c = (1 - np.cos(theta))[..., None, None]
    R = np.eye(3) + s * K + c * (K @ K)
    # first-order series for tiny angles: I + [v]x
    Vx = np.zeros_like(K)
    Vx[..., 0, 1], Vx[..., 0, 2] = -v[..., 2], v[..., 1]
    Vx[..., 1, 0], Vx[..., 1, 2] = v[..., 2], -v[..., 0]
    Vx[..., 2, 0], Vx[..., 2, 1] = -v[..., 1], v[..., 0]
    return np.where(small[..., None, None], np.eye(3) + Vx + 0.5 * Vx @ Vx, R)


def rotvec_from_matrix(matrix: ArrayLike) -> NDArray[np.float64]:
    """Axis-angle vectors ``(..., 3)`` (radians, angle in [0, pi]) of rotation matrices."""
    q = quaternion_from_matrix(matrix)
    w = np.clip(q[..., 0], -1.0, 1.0)
    xyz = q[..., 1:]
    n = np.linalg.norm(xyz, axis=-1)
    angle = 2.0 * np.arctan2(n, w)
    scale = np.where(n < 1e-12, 2.0, angle / np.where(n < 1e-12, 1.0, n))
    return xyz * scale[..., None]


def skew(v: ArrayLike) -> NDArray[np.float64]:
    """Cross-product matrices ``[v]x`` of shape ``(..., 3, 3)``."""
    v = np.asarray(v, dtype=np.float64)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def slerp(q0: ArrayLike, q1: ArrayLike, t: ArrayLike) -> NDArray[np.float64]:
    """Spherical linear interpolation between unit quaternions ``(..., 4)`` at fractions ``t`` ``(...)``.

    Takes the short way round (flips ``q1`` where the dot product is negative).
    """
    a = np.asarray(q0, dtype=np.float64)
    b = np.array(q1, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)[..., None]
    d = np.sum(a * b, axis=-1, keepdims=True)
    b = np.where(d < 0, -b, b)
    d = np.abs(d)
    theta = np.arccos(np.clip(d, -1.0, 1.0))
    sin_t = np.sin(theta)
    lin = d > 0.9999995
    safe = np.where(lin, 1.0, sin_t)
    wa = np.where(lin, 1.0 - t, np.sin((1.0 - t) * theta) / safe)
    wb = np.where(lin, t, np.sin(t * theta) / safe)
    q = wa * a + wb * b
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def orthonormalize(matrix: ArrayLike) -> NDArray[np.float64]:
    """Nearest rotation matrices (SVD) of ``(..., 3, 3)`` matrices."""
    m = np.asarray(matrix, dtype=np.float64)
    u, _, vt = np.linalg.svd(m)
    d = np.sign(np.linalg.det(u @ vt))
    u[..., :, 2] *= d[..., None]
    return u @ vt


#: ``body_from_camera`` of the standard nadir mount: image x along the body's forward axis, image y to the
#: left, camera z up (body: x forward, y right, z down).  With it, level flight to the north gives kappa = +90 deg.
NADIR_BODY_FROM_CAMERA = np.diag([1.0, -1.0, -1.0])

#: ``gimbal_from_camera`` for DJI-style gimbal angles (gimbal frame: x along the optical axis, y right,
#: z down; gimbal yaw/pitch/roll give ``ned_from_gimbal``; pitch -90 deg looks straight down with the image
#: top towards the gimbal yaw direction).
GIMBAL_FROM_CAMERA = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
