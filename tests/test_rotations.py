"""Tests for skyrig.geometry.rotations against textbook matrices and scipy's independent implementation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from skyrig.errors import SkyrigError
from skyrig.geometry.rotations import (
    ENU_FROM_NED,
    matrix_from_opk,
    matrix_from_quaternion,
    matrix_from_rotvec,
    matrix_from_rpy,
    opk_from_matrix,
    orthonormalize,
    quaternion_from_matrix,
    rot_x,
    rot_y,
    rot_z,
    rotvec_from_matrix,
    rpy_from_matrix,
    skew,
    slerp,
)

RNG_SEED = 20240611


def _rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]], float)


def _ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]], float)


def _rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], float)


def _random_rotations(n, seed=RNG_SEED):
    return Rotation.random(n, random_state=seed).as_matrix()


# --------------------------------------------------------------------------- elementary rotations
def test_elementary_textbook_and_right_handed():
    a = 0.3
    np.testing.assert_allclose(rot_x(a), _rx(a), atol=1e-16)
    np.testing.assert_allclose(rot_y(a), _ry(a), atol=1e-16)
    np.testing.assert_allclose(rot_z(a), _rz(a), atol=1e-16)
    # right-handed: +90 deg about z takes x to y, about x takes y to z, about y takes z to x
    np.testing.assert_allclose(rot_z(math.pi / 2) @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(rot_x(math.pi / 2) @ [0, 1, 0], [0, 0, 1], atol=1e-15)
    np.testing.assert_allclose(rot_y(math.pi / 2) @ [0, 0, 1], [1, 0, 0], atol=1e-15)
    # scipy: active rotations about the axes
    for f, axis in [(rot_x, "x"), (rot_y, "y"), (rot_z, "z")]:
        np.testing.assert_allclose(f(a), Rotation.from_euler(axis, a).as_matrix(), atol=1e-15)


def test_elementary_vectorised_shapes():
    a = np.linspace(-1, 1, 5)
    r = rot_z(a)
    assert r.shape == (5, 3, 3)
    for i in range(5):
        np.testing.assert_allclose(r[i], _rz(a[i]), atol=1e-16)
    assert rot_x(np.zeros((2, 4))).shape == (2, 4, 3, 3)
    assert rot_y(0.1).shape == (3, 3)


def test_enu_from_ned():
    # north (1,0,0)_NED -> (0,1,0)_ENU, east -> (1,0,0), down -> -up
    np.testing.assert_array_equal(ENU_FROM_NED @ [1, 0, 0], [0, 1, 0])
    np.testing.assert_array_equal(ENU_FROM_NED @ [0, 1, 0], [1, 0, 0])
    np.testing.assert_array_equal(ENU_FROM_NED @ [0, 0, 1], [0, 0, -1])
    np.testing.assert_array_equal(ENU_FROM_NED @ ENU_FROM_NED, np.eye(3))


# --------------------------------------------------------------------------- opk / pok / rpy
def test_matrix_from_opk_explicit_product():
    o, p, k = 0.1, -0.2, 2.5
    np.testing.assert_allclose(matrix_from_opk(o, p, k), _rx(o) @ _ry(p) @ _rz(k), atol=1e-15)
    np.testing.assert_allclose(matrix_from_opk(o, p, k, sequence="pok"), _ry(p) @ _rx(o) @ _rz(k), atol=1e-15)
    np.testing.assert_allclose(
        matrix_from_opk(math.degrees(o), math.degrees(p), math.degrees(k), unit="deg"),
        _rx(o) @ _ry(p) @ _rz(k),
        atol=1e-15,
    )
    np.testing.assert_allclose(
        matrix_from_opk(o * 200 / math.pi, p * 200 / math.pi, k * 200 / math.pi, unit="gon", sequence="phi-omega-kappa"),
        _ry(p) @ _rx(o) @ _rz(k),
        atol=1e-15,
    )
    # scipy intrinsic "XYZ" is Rx Ry Rz
    np.testing.assert_allclose(matrix_from_opk(o, p, k), Rotation.from_euler("XYZ", [o, p, k]).as_matrix(), atol=1e-15)
    np.testing.assert_allclose(
        matrix_from_opk(o, p, k, sequence="pok"), Rotation.from_euler("YXZ", [p, o, k]).as_matrix(), atol=1e-15
    )


def test_level_nadir_camera_east_is_identity():
    # documented convention: a level nadir camera with image x to the east has omega = phi = kappa = 0
    np.testing.assert_array_equal(matrix_from_opk(0, 0, 0), np.eye(3))


def test_matrix_from_rpy_explicit_product():
    r, p, y = 0.05, -0.1, 2.0
    np.testing.assert_allclose(matrix_from_rpy(r, p, y), _rz(y) @ _ry(p) @ _rx(r), atol=1e-15)
    # scipy intrinsic "ZYX" (yaw, pitch, roll) is the aerospace sequence
    np.testing.assert_allclose(matrix_from_rpy(r, p, y), Rotation.from_euler("ZYX", [y, p, r]).as_matrix(), atol=1e-15)
    # heading 90 deg: body x (forward) points east in NED
    np.testing.assert_allclose(matrix_from_rpy(0, 0, 90, unit="deg") @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    # pitch up: forward axis gets a negative down component
    assert (matrix_from_rpy(0, 10, 0, unit="deg") @ [1, 0, 0])[2] < 0
    # roll right: right wing (body y) goes down
    assert (matrix_from_rpy(10, 0, 0, unit="deg") @ [0, 1, 0])[2] > 0


@pytest.mark.parametrize("sequence", ["opk", "pok"])
@pytest.mark.parametrize("unit", ["rad", "deg", "gon"])
def test_opk_round_trip(sequence, unit):
    rng = np.random.default_rng(RNG_SEED)
    n = 2000
    o = rng.uniform(-math.pi, math.pi, n)
    p = rng.uniform(-1.5, 1.5, n)  # middle angle away from gimbal lock
    k = rng.uniform(-math.pi, math.pi, n)
    if sequence == "pok":
        o, p = rng.uniform(-1.5, 1.5, n), rng.uniform(-math.pi, math.pi, n)
    scale = {"rad": 1.0, "deg": 180 / math.pi, "gon": 200 / math.pi}[unit]
    R = matrix_from_opk(o * scale, p * scale, k * scale, unit=unit, sequence=sequence)
    o2, p2, k2 = opk_from_matrix(R, unit=unit, sequence=sequence)
    for a, b in [(o, o2), (p, p2), (k, k2)]:
        np.testing.assert_allclose(b / scale, a, rtol=1e-12, atol=1e-12)
    # matrix round trip for arbitrary rotations (angles may differ but the matrix must not)
    Q = _random_rotations(500)
    np.testing.assert_allclose(matrix_from_opk(*opk_from_matrix(Q, sequence=sequence), sequence=sequence), Q, atol=1e-12)


def test_rpy_round_trip():
    rng = np.random.default_rng(RNG_SEED + 1)
    n = 2000
    r, p, y = rng.uniform(-math.pi, math.pi, n), rng.uniform(-1.5, 1.5, n), rng.uniform(-math.pi, math.pi, n)
    r2, p2, y2 = rpy_from_matrix(matrix_from_rpy(r, p, y))
    np.testing.assert_allclose(np.stack([r2, p2, y2]), np.stack([r, p, y]), rtol=1e-12, atol=1e-12)
    r2, p2, y2 = rpy_from_matrix(matrix_from_rpy(np.degrees(r), np.degrees(p), np.degrees(y), unit="deg"), unit="deg")
    np.testing.assert_allclose(np.radians(np.stack([r2, p2, y2])), np.stack([r, p, y]), rtol=1e-12, atol=1e-12)
    # against scipy's decomposition
    Q = _random_rotations(300, seed=3)
    r3, p3, y3 = rpy_from_matrix(Q)
    ypr = Rotation.from_matrix(Q).as_euler("ZYX")
    np.testing.assert_allclose(np.stack([y3, p3, r3], axis=1), ypr, atol=1e-10)


def test_opk_from_matrix_against_scipy():
    Q = _random_rotations(300, seed=5)
    np.testing.assert_allclose(np.stack(opk_from_matrix(Q), axis=1), Rotation.from_matrix(Q).as_euler("XYZ"), atol=1e-10)
    o, p, k = opk_from_matrix(Q, sequence="pok")
    np.testing.assert_allclose(np.stack([p, o, k], axis=1), Rotation.from_matrix(Q).as_euler("YXZ"), atol=1e-10)


def test_unknown_sequence():
    with pytest.raises(SkyrigError):
        matrix_from_opk(0, 0, 0, sequence="kpo")


# --------------------------------------------------------------------------- quaternions, rotvec, slerp
def _same_quat(a, b, atol):
    a, b = np.atleast_2d(a), np.atleast_2d(b)
    sign = np.sign(np.sum(a * b, axis=-1, keepdims=True))
    np.testing.assert_allclose(a, sign * b, atol=atol)


def test_quaternion_vs_scipy():
    Q = _random_rotations(1000, seed=7)
    # include the branch cases: identity, 180 deg turns about each axis, near-180 turns
    special = np.stack([np.eye(3), rot_x(math.pi), rot_y(math.pi), rot_z(math.pi), rot_x(math.pi - 1e-9),
                        Rotation.from_rotvec([1, 1, 0] / np.sqrt(2) * math.pi).as_matrix()])
    Q = np.concatenate([Q, special])
    q = quaternion_from_matrix(Q)
    assert q.shape == (len(Q), 4)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-15)
    assert np.all(q[:, 0] >= 0)
    ref = Rotation.from_matrix(Q).as_quat()  # scalar LAST
    _same_quat(q, np.roll(ref, 1, axis=1), 1e-12)
    np.testing.assert_allclose(matrix_from_quaternion(q), Q, atol=1e-12)
    # quaternion -> matrix for scipy's quaternions (not normalised on purpose)
    np.testing.assert_allclose(matrix_from_quaternion(3.0 * np.roll(ref, 1, axis=1)), Rotation.from_quat(ref).as_matrix(), atol=1e-12)
    # single matrix keeps shape; known value: 90 deg about z -> (cos45, 0, 0, sin45)
    np.testing.assert_allclose(quaternion_from_matrix(rot_z(math.pi / 2)), [math.sqrt(0.5), 0, 0, math.sqrt(0.5)], atol=1e-15)


def test_rotvec_vs_scipy():
    Q = _random_rotations(500, seed=11)
    v = rotvec_from_matrix(Q)
    np.testing.assert_allclose(v, Rotation.from_matrix(Q).as_rotvec(), atol=1e-10)
    np.testing.assert_allclose(matrix_from_rotvec(v), Q, atol=1e-12)
    # tiny and zero angles take the series branch
    small = np.array([[0.0, 0.0, 0.0], [1e-10, -2e-10, 3e-10], [1e-7, 0, 0], [0.0, 2.0, 0.0]])
    np.testing.assert_allclose(matrix_from_rotvec(small), Rotation.from_rotvec(small).as_matrix(), atol=1e-15)
    np.testing.assert_allclose(rotvec_from_matrix(matrix_from_rotvec(small)), small, atol=1e-15)
    # angle in [0, pi]
    assert np.all(np.linalg.norm(v, axis=1) <= math.pi + 1e-12)


def test_skew():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(10, 3)), rng.normal(size=(10, 3))
    np.testing.assert_allclose(np.einsum("nij,nj->ni", skew(a), b), np.cross(a, b), atol=1e-14)


def test_slerp_vs_scipy():
    rng = np.random.default_rng(13)
    key = Rotation.random(2, random_state=13)
    t = rng.uniform(0, 1, 50)
    ref = Slerp([0.0, 1.0], key)(t).as_matrix()
    qk = np.roll(key.as_quat(), 1, axis=1)
    q = slerp(qk[0], qk[1], t)
    np.testing.assert_allclose(matrix_from_quaternion(q), ref, atol=1e-12)
    # short way round: flipping the sign of q1 must not change the result
    np.testing.assert_allclose(matrix_from_quaternion(slerp(qk[0], -qk[1], t)), ref, atol=1e-12)
    # end points and (nearly) identical quaternions
    np.testing.assert_allclose(slerp(qk[0], qk[1], 0.0), qk[0], atol=1e-15)
    _same_quat(slerp(qk[0], qk[1], 1.0), qk[1], 1e-12)
    q_near = quaternion_from_matrix(Rotation.from_quat(np.roll(qk[0], -1)).as_matrix() @ rot_z(1e-9))
    np.testing.assert_allclose(np.linalg.norm(slerp(qk[0], q_near, 0.5)), 1.0, atol=1e-15)
    # batch of pairs
    q0 = quaternion_from_matrix(_random_rotations(20, seed=1))
    q1 = quaternion_from_matrix(_random_rotations(20, seed=2))
    tt = rng.uniform(0, 1, 20)
    out = slerp(q0, q1, tt)
    for i in range(0, 20, 5):
        r = Slerp([0, 1], Rotation.from_quat(np.roll(np.stack([q0[i], q1[i]]), -1, axis=1)))(tt[i]).as_matrix()
        np.testing.assert_allclose(matrix_from_quaternion(out[i]), r, atol=1e-12)


def test_orthonormalize():
    Q = _random_rotations(50, seed=17)
    noisy = Q + 1e-4 * np.random.default_rng(17).normal(size=Q.shape)
    R = orthonormalize(noisy)
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-14)
    np.testing.assert_allclose(R, Q, atol=1e-3)
    np.testing.assert_allclose(orthonormalize(Q[0]), Q[0], atol=1e-14)
    # nearest rotation of a scaled rotation is the rotation
    np.testing.assert_allclose(orthonormalize(2.0 * Q[1]), Q[1], atol=1e-14)
