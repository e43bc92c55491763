"""Tests for skyrig.geodesy.attitude: IMU roll/pitch/yaw <-> photogrammetric omega/phi/kappa in a projected CRS."""

from __future__ import annotations

import math

import numpy as np
import pyproj
import pytest
from scipy.spatial.transform import Rotation

from skyrig.errors import GeometryError
from skyrig.geodesy.attitude import (
    NADIR_BODY_FROM_CAMERA,
    grid_from_camera_from_rpy,
    grid_from_ned_rotation,
    ned_from_body_from_grid_from_camera,
    opk_from_rpy,
    rpy_from_opk,
)
from skyrig.geodesy.crs import MapProjection
from skyrig.geodesy.local import TangentialFrame
from skyrig.geometry.rotations import ENU_FROM_NED, matrix_from_opk


def _wrap_deg(a):
    return (np.asarray(a) + 180.0) % 360.0 - 180.0


# --------------------------------------------------------------------------- hand-derived known answers
def test_level_north_nadir_zero_convergence():
    # ned_from_body = I; ENU_FROM_NED @ diag(1,-1,-1) = [[0,-1,0],[1,0,0],[0,0,1]] = rot_z(+90 deg):
    # image x (flight direction) points north = grid y, image y points west, camera z up.
    o, p, k = opk_from_rpy(0.0, 0.0, 0.0, 0.0)
    assert (float(o), float(p), float(k)) == pytest.approx((0.0, 0.0, 90.0), abs=1e-12)
    np.testing.assert_allclose(
        grid_from_camera_from_rpy(0, 0, 0, NADIR_BODY_FROM_CAMERA, 0.0), [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-15
    )
    o, p, k = opk_from_rpy(0.0, 0.0, 100.0, 0.0, unit="gon")  # heading east (100 gon): image x east, kappa 0
    assert (float(o), float(p), float(k)) == pytest.approx((0.0, 0.0, 0.0), abs=1e-12)


@pytest.mark.parametrize("conv_deg", [-2.5, 0.0, 1.0, 2.18])
@pytest.mark.parametrize("heading", [0.0, 30.0, 135.0, -100.0])
def test_level_flight_kappa(conv_deg, heading):
    # level flight with heading psi: ENU_FROM_NED rot_z(psi) ENU_FROM_NED = rot_z(-psi), so
    # grid_from_camera = rot_z(c) rot_z(-psi) rot_z(90) and kappa = 90 - psi + c
    o, p, k = opk_from_rpy(0.0, 0.0, heading, math.radians(conv_deg))
    assert float(o) == pytest.approx(0.0, abs=1e-12)
    assert float(p) == pytest.approx(0.0, abs=1e-12)
    assert float(_wrap_deg(k - (90.0 - heading + conv_deg))) == pytest.approx(0.0, abs=1e-10)


def test_pitch_and_roll_known_answers():
    # heading north, nose up by t: body x in ENU = (0, cos t, sin t), camera y = -east, camera z = (0, -sin t, cos t)
    # R = [[0,-1,0],[cos t,0,-sin t],[sin t,0,cos t]]: sin(phi) = R[0,2] = 0, -sin(omega) = R[1,2] -> omega = t
    o, p, k = opk_from_rpy(0.0, 5.0, 0.0, 0.0)
    assert (float(o), float(p), float(k)) == pytest.approx((5.0, 0.0, 90.0), abs=1e-12)
    # heading north, right wing down by r: camera y = (-cos r, 0, sin r), camera z = (sin r, 0, cos r)
    # R = [[0,-cos r,sin r],[1,0,0],[0,sin r,cos r]]: sin(phi) = sin r, omega = 0, kappa = 90
    o, p, k = opk_from_rpy(3.0, 0.0, 0.0, 0.0)
    assert (float(o), float(p), float(k)) == pytest.approx((0.0, 3.0, 90.0), abs=1e-12)
    # and back
    r, p_, y = rpy_from_opk(0.0, 3.0, 90.0, 0.0)
    assert (float(r), float(p_), float(y)) == pytest.approx((3.0, 0.0, 0.0), abs=1e-12)


def test_grid_from_camera_explicit_product():
    # written independently with scipy: ned_from_body = intrinsic ZYX(yaw, pitch, roll)
    rng = np.random.default_rng(1)
    n = 20
    roll, pitch, yaw = rng.uniform(-20, 20, n), rng.uniform(-20, 20, n), rng.uniform(-180, 180, n)
    conv = rng.uniform(-0.05, 0.05, n)
    mount = Rotation.random(n, random_state=2).as_matrix()
    got = grid_from_camera_from_rpy(roll, pitch, yaw, mount, conv)
    ned_from_body = Rotation.from_euler("ZYX", np.stack([yaw, pitch, roll], axis=1), degrees=True).as_matrix()
    c, s = np.cos(conv), np.sin(conv)
    rz = np.zeros((n, 3, 3))
    rz[:, 0, 0], rz[:, 0, 1], rz[:, 1, 0], rz[:, 1, 1], rz[:, 2, 2] = c, -s, s, c, 1.0
    enu_from_ned = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]])
    np.testing.assert_allclose(got, rz @ enu_from_ned @ ned_from_body @ mount, atol=1e-14)
    np.testing.assert_allclose(grid_from_ned_rotation(conv), rz @ enu_from_ned, atol=1e-15)
    # radians give the same
    got_rad = grid_from_camera_from_rpy(np.radians(roll), np.radians(pitch), np.radians(yaw), mount, conv, unit="rad")
    np.testing.assert_allclose(got_rad, got, atol=1e-14)


# --------------------------------------------------------------------------- convergence sign, checked with PROJ
@pytest.mark.parametrize(("epsg", "lat", "lon"), [(2154, 44.0, 6.0), (2154, 48.5, -3.0), (25832, 60.0, 11.5), (3763, 41.8, -6.8)])
@pytest.mark.parametrize("heading", [0.0, 30.0, 200.0])
def test_kappa_matches_pyproj_grid_bearing(epsg, lat, lon, heading):
    """Level flight with true heading psi: image x (flight direction) must point, in the grid, along the
    grid bearing of a short geodesic with azimuth psi, measured by projecting its end points with PROJ."""
    mp = MapProjection(epsg)
    crs = mp.crs
    fwd = pyproj.Transformer.from_crs(crs.geodetic_crs, crs, always_xy=True)
    geod = crs.get_geod()
    lo1, la1, _ = geod.fwd(lon, lat, heading + 180.0, 1.0)
    lo2, la2, _ = geod.fwd(lon, lat, heading, 1.0)
    x, y = fwd.transform([lo1, lo2], [la1, la2])
    grid_bearing = math.atan2(x[1] - x[0], y[1] - y[0])  # clockwise from grid north
    xc, yc = fwd.transform(lon, lat)
    conv, _ = mp.factors([[xc, yc]])
    g = grid_from_camera_from_rpy(0.0, 0.0, heading, NADIR_BODY_FROM_CAMERA, conv[0])
    image_x = g[:, 0]
    assert math.atan2(image_x[0], image_x[1]) == pytest.approx(grid_bearing, abs=1e-8)
    # hence kappa = 90 deg - grid bearing; for heading 0 that is 90 deg + convergence
    _, _, k = opk_from_rpy(0.0, 0.0, heading, conv[0])
    assert float(_wrap_deg(k - (90.0 - math.degrees(grid_bearing)))) == pytest.approx(0.0, abs=1e-6)
    if epsg == 2154 and lat == 44.0 and heading == 0.0:
        # Lambert-93 at 6 E 44 N: convergence +2.18 deg, so kappa = 92.18 deg
        assert float(k) == pytest.approx(92.18, abs=0.005)


def test_consistent_with_tangential_frame():
    """grid_from_camera carried into the tangential frame equals the IMU attitude carried there through the
    local ENU frame at the exposure (no convergence involved): checks the sign against skyrig.geodesy.local."""
    mp = MapProjection(2154)
    tf = TangentialFrame(mp, (815601.51, 6283629.28, 50.0))
    rng = np.random.default_rng(3)
    n = 10
    centres = np.stack([815601.51 + rng.uniform(-9000, 9000, n), 6283629.28 + rng.uniform(-9000, 9000, n),
                        np.full(n, 1800.0)], axis=1)
    roll, pitch, yaw = rng.uniform(-5, 5, n), rng.uniform(-5, 5, n), rng.uniform(-180, 180, n)
    conv, _ = mp.factors(centres)
    g = grid_from_camera_from_rpy(roll, pitch, yaw, NADIR_BODY_FROM_CAMERA, conv)
    via_grid = tf.tangential_from_grid_rotation(centres) @ g
    geo = mp.to_geodetic(centres)
    ned_from_body = Rotation.from_euler("ZYX", np.stack([yaw, pitch, roll], axis=1), degrees=True).as_matrix()
    via_enu = tf.local.local_from_local_enu_at(geo[:, 0], geo[:, 1]) @ ENU_FROM_NED @ ned_from_body @ NADIR_BODY_FROM_CAMERA
    np.testing.assert_allclose(via_grid, via_enu, atol=1e-12)


# --------------------------------------------------------------------------- round trips
def _oblique_mounts(n, seed):
    """Nadir mount tilted 0-45 deg about body y (forward/backward obliques) and a random boresight."""
    rng = np.random.default_rng(seed)
    tilt = Rotation.from_euler("y", rng.uniform(-45, 45, (n, 1)), degrees=True).as_matrix()
    bore = Rotation.from_rotvec(rng.normal(scale=0.01, size=(n, 3))).as_matrix()
    return tilt @ NADIR_BODY_FROM_CAMERA @ bore


def _assert_angles_close(a, b, unit):
    turn = {"deg": 360.0, "rad": 2 * math.pi, "gon": 400.0}[unit]
    for x, y in zip(a, b):
        d = (np.asarray(x) - np.asarray(y) + turn / 2) % turn - turn / 2
        # 1e-9 relative to the angle, floor 1e-9 of a radian
        tol = 1e-9 * np.maximum(np.abs(y), turn / (2 * math.pi))
        assert np.all(np.abs(d) <= tol), np.max(np.abs(d))


@pytest.mark.parametrize("sequence", ["opk", "pok"])
@pytest.mark.parametrize("unit", ["deg", "rad", "gon"])
@pytest.mark.parametrize("mount", ["nadir", "oblique"])
def test_round_trips(sequence, unit, mount):
    rng = np.random.default_rng(4)
    n = 500
    scale = {"deg": 1.0, "rad": math.pi / 180, "gon": 400 / 360}[unit]
    conv = rng.uniform(-0.06, 0.06, n)  # up to 3.4 deg (UTM zone edge at 60 N)
    b = NADIR_BODY_FROM_CAMERA if mount == "nadir" else _oblique_mounts(n, 5)
    # opk -> rpy -> opk, away from gimbal lock in either convention
    omega, phi, kappa = (rng.uniform(-30, 30, n) * scale, rng.uniform(-30, 30, n) * scale, rng.uniform(-180, 180, n) * scale)
    rpy = rpy_from_opk(omega, phi, kappa, conv, unit=unit, sequence=sequence, body_from_camera=b)
    assert np.max(np.abs(rpy[1])) < 80 * scale  # pitch away from +-90
    back = opk_from_rpy(*rpy, conv, unit=unit, sequence=sequence, body_from_camera=b)
    _assert_angles_close(back, (omega, phi, kappa), unit)
    # rpy -> opk -> rpy
    roll, pitch, yaw = rng.uniform(-30, 30, n) * scale, rng.uniform(-30, 30, n) * scale, rng.uniform(-180, 180, n) * scale
    opk = opk_from_rpy(roll, pitch, yaw, conv, unit=unit, sequence=sequence, body_from_camera=b)
    mid = opk[0] if sequence == "pok" else opk[1]
    assert np.max(np.abs(mid)) < 80 * scale
    _assert_angles_close(rpy_from_opk(*opk, conv, unit=unit, sequence=sequence, body_from_camera=b), (roll, pitch, yaw), unit)
    # and the matrices agree with matrix_from_opk of the angles
    g = grid_from_camera_from_rpy(roll, pitch, yaw, b, conv, unit=unit)
    np.testing.assert_allclose(matrix_from_opk(*opk, unit=unit, sequence=sequence), g, atol=1e-12)
    np.testing.assert_allclose(
        ned_from_body_from_grid_from_camera(g, b, conv),
        Rotation.from_euler("ZYX", np.stack([yaw, pitch, roll], axis=1) / scale, degrees=True).as_matrix(),
        atol=1e-12,
    )


def test_shapes_and_broadcasting():
    o, p, k = opk_from_rpy(1.0, 2.0, 3.0, 0.01)
    assert np.ndim(o) == np.ndim(p) == np.ndim(k) == 0
    o, p, k = opk_from_rpy(np.zeros(4), np.zeros(4), np.array([0.0, 90.0, 180.0, 270.0]), 0.0)
    assert o.shape == (4,)
    np.testing.assert_allclose(np.cos(np.radians(k)), np.cos(np.radians([90.0, 0.0, -90.0, -180.0])), atol=1e-12)
    np.testing.assert_allclose(np.sin(np.radians(k)), np.sin(np.radians([90.0, 0.0, -90.0, -180.0])), atol=1e-12)
    # per-image convergence with a scalar heading
    conv = np.radians([0.0, 1.0, 2.0])
    _, _, k = opk_from_rpy(0.0, 0.0, 0.0, conv)
    np.testing.assert_allclose(k, [90.0, 91.0, 92.0], atol=1e-12)
    assert grid_from_camera_from_rpy(0.0, 0.0, 0.0, np.stack([NADIR_BODY_FROM_CAMERA] * 5), 0.0).shape == (5, 3, 3)


def test_bad_mount_raises():
    with pytest.raises(GeometryError):
        opk_from_rpy(0, 0, 0, 0.0, body_from_camera=np.diag([1.0, 1.0, -1.0]))  # a reflection
    with pytest.raises(GeometryError):
        grid_from_camera_from_rpy(0, 0, 0, 2.0 * np.eye(3), 0.0)
    with pytest.raises(GeometryError):
        rpy_from_opk(0, 0, 0, 0.0, body_from_camera=np.eye(2))
    with pytest.raises(ValueError):  # GeometryError is a ValueError
        rpy_from_opk(0, 0, 0, 0.0, body_from_camera=np.ones((3, 3)))
