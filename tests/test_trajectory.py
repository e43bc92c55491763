"""Trajectory interpolation and camera events against analytic truth and pyproj."""

from __future__ import annotations

import numpy as np
import pyproj
import pytest

from skyrig.errors import InputFormatError, OutOfRangeError
from skyrig.geodesy import MapProjection, ecef_from_enu_rotation, ecef_to_geodetic, geodetic_to_ecef
from skyrig.geometry.rotations import ENU_FROM_NED, matrix_from_rpy, quaternion_from_matrix, rot_z, rotvec_from_matrix
from skyrig.trajectory import (
    CameraEvents,
    EventOutOfSpanError,
    Trajectory,
    check_events_in_span,
    interpolate_events,
)

# A level circle flown clockwise (seen from above) around a centre, radius R, angular rate W.
LAT0, LON0, H0 = 46.0, 7.0, 1500.0
R_CIRCLE = 500.0
W = 2.0 * np.pi / 120.0  # rad/s
ROLL0, PITCH0 = np.radians(10.0), np.radians(2.0)
T0 = 345600.0


def _truth(t):
    """Analytic ECEF position, ECEF velocity and ecef_from_body at times ``t`` (seconds after T0)."""
    t = np.asarray(t, dtype=float)
    e = ecef_from_enu_rotation(LAT0, LON0)
    c = geodetic_to_ecef(LAT0, LON0, H0).reshape(3)
    a = W * t
    enu = np.stack([R_CIRCLE * np.sin(a), R_CIRCLE * np.cos(a), np.zeros_like(a)], axis=1)
    venu = np.stack([R_CIRCLE * W * np.cos(a), -R_CIRCLE * W * np.sin(a), np.zeros_like(a)], axis=1)
    pos = c + enu @ e.T
    vel = venu @ e.T
    # heading of the motion in the centre's NED frame is 90 deg + W t; constant roll and pitch
    ned_c_from_body = matrix_from_rpy(np.full_like(a, ROLL0), np.full_like(a, PITCH0), np.pi / 2 + a)
    ecef_from_body = e @ ENU_FROM_NED @ ned_c_from_body
    return pos, vel, ecef_from_body


def _ned_from_ecef(lat, lon):
    return np.swapaxes(ecef_from_enu_rotation(lat, lon) @ ENU_FROM_NED, -1, -2)


def _circle_trajectory(dt=1.0, duration=60.0, with_velocity=False):
    t = np.arange(0.0, duration + 1e-9, dt)
    pos, vel, ecef_from_body = _truth(t)
    lat, lon, h = ecef_to_geodetic(pos)
    ned_from_ecef = _ned_from_ecef(lat, lon)
    ned_from_body = ned_from_ecef @ ecef_from_body
    v_ned = np.einsum("nij,nj->ni", ned_from_ecef, vel) if with_velocity else None
    return Trajectory(T0 + t, lat, lon, h, quaternion_from_matrix(ned_from_body), velocity_ned=v_ned)


def _angle(a, b):
    """Rotation angle (rad) between rotation matrices."""
    return np.linalg.norm(rotvec_from_matrix(np.swapaxes(a, -1, -2) @ b), axis=-1)


def test_linear_error_is_the_chord_sag():
    dt = 1.0
    traj = _circle_trajectory(dt)
    tm = np.arange(0.5, 60.0, dt)
    s = traj.interpolate(T0 + tm, position="linear")
    pos, _, _ = _truth(tm)
    err = np.linalg.norm(s.ecef - pos, axis=1)
    sag = R_CIRCLE * (1.0 - np.cos(W * dt / 2.0))  # distance of a chord's midpoint from the arc
    np.testing.assert_allclose(err, sag, rtol=1e-5)


def test_cubic_error_within_spline_bound():
    dt = 1.0
    traj = _circle_trajectory(dt)
    tm = np.arange(0.5, 60.0, dt)
    s = traj.interpolate(T0 + tm, position="cubic")
    pos, vel, _ = _truth(tm)
    err = np.linalg.norm(s.ecef - pos, axis=1)
    # classical bound for interpolating cubic splines: 5/384 h^4 max|f''''|, |f''''| = R W^4
    bound = 5.0 / 384.0 * dt**4 * R_CIRCLE * W**4
    interior = slice(3, -3)
    assert np.max(err[interior]) <= 1.05 * bound
    assert np.max(err) <= 10.0 * bound  # not-a-knot ends are somewhat worse
    sag = R_CIRCLE * (1.0 - np.cos(W * dt / 2.0))
    assert np.max(err) < sag / 1000.0
    # velocity from the spline derivative, in NED at the sample position
    v_ned = np.einsum("mij,mj->mi", _ned_from_ecef(s.lat_deg, s.lon_deg), vel)
    np.testing.assert_allclose(s.velocity_ned, v_ned, atol=2e-4)


def test_cubic_hermite_with_velocities():
    dt = 1.0
    traj = _circle_trajectory(dt, with_velocity=True)
    tm = np.arange(0.5, 60.0, dt)
    s = traj.interpolate(T0 + tm, position="cubic")
    pos, _, _ = _truth(tm)
    err = np.linalg.norm(s.ecef - pos, axis=1)
    # Hermite midpoint error: h^4/384 |f''''|
    bound = dt**4 / 384.0 * R_CIRCLE * W**4
    assert np.max(err) <= 1.05 * bound
    assert np.max(err) >= 0.5 * bound  # the bound is attained at midpoints: the Hermite path was used


def test_slerp_midpoint_equals_analytic_rotation():
    traj = _circle_trajectory(1.0)
    tm = np.arange(0.5, 60.0, 1.0)
    s = traj.interpolate(T0 + tm, position="cubic")
    pos, _, ecef_from_body = _truth(tm)
    # a body turning uniformly about a fixed axis: slerp between samples is exact
    assert np.max(_angle(s.ecef_from_body, ecef_from_body)) < 1e-10
    lat, lon, _ = ecef_to_geodetic(pos)
    ned_true = _ned_from_ecef(lat, lon) @ ecef_from_body
    assert np.max(_angle(s.ned_from_body, ned_true)) < 1e-9
    # the rpy view agrees with the analytic roll (heading of a NED frame at the sample, so compare roll)
    roll, pitch, yaw = s.rpy("rad")
    assert np.allclose(np.hypot(roll, pitch), np.hypot(ROLL0, PITCH0), atol=1e-4)


def test_interpolation_at_samples_returns_samples():
    traj = _circle_trajectory(1.0)
    for method in ("linear", "cubic"):
        s = traj.interpolate(traj.time_s, position=method)
        np.testing.assert_allclose(s.ecef, traj.ecef, atol=1e-6)
        np.testing.assert_allclose(s.lat_deg, traj.lat_deg, atol=1e-11)
        assert np.max(_angle(s.ned_from_body, traj.ned_from_body)) < 1e-10


def test_out_of_span_names_first_time_and_index():
    traj = _circle_trajectory(1.0)
    times = np.array([T0 + 1.0, T0 + 60.5, T0 - 3.0])
    with pytest.raises(OutOfRangeError) as ei:
        traj.interpolate(times)
    msg = str(ei.value)
    assert "index 1" in msg and repr(T0 + 60.5) in msg
    with pytest.raises(OutOfRangeError):
        traj.interpolate([np.nan])
    traj.interpolate([T0, T0 + 60.0])  # both ends are inside


def test_validation_errors():
    t = T0 + np.arange(4.0)
    z = np.zeros(4)
    with pytest.raises(OutOfRangeError, match="strictly increasing"):
        Trajectory.from_rpy(t[[0, 1, 1, 3]], z + 46, z + 7, z, z, z, z)
    with pytest.raises(InputFormatError) as ei:
        Trajectory.from_rpy(t, z + 46, z + 7, z[:3], z, z, z)
    assert ei.value.field == "h_m"
    with pytest.raises(InputFormatError) as ei:
        Trajectory.from_rpy(t, z + 46, z + 7, z, z, np.array([0, np.nan, 0, 0]), z)
    assert ei.value.field == "pitch"
    with pytest.raises(InputFormatError):
        Trajectory.from_rpy(t, z + 95, z + 7, z, z, z, z)
    with pytest.raises(InputFormatError):
        Trajectory.from_rpy(t, z + 46, z + 7, z, z, z, z, reference="gps")
    with pytest.raises(InputFormatError):
        Trajectory.from_rpy(t, z + 46, z + 7, z, z, z, z, velocity_ned=np.zeros((4, 2)))


def test_from_rpy_units_round_trip():
    rng = np.random.default_rng(3)
    n = 20
    r, p, y = rng.uniform(-20, 20, n), rng.uniform(-10, 10, n), rng.uniform(-179, 179, n)
    for unit, f in (("deg", 1.0), ("gon", 400.0 / 360.0), ("rad", np.pi / 180.0)):
        tr = Trajectory.from_rpy(T0 + np.arange(n), np.full(n, 46.0), np.full(n, 7.0), np.zeros(n),
                                 r * f, p * f, y * f, unit)
        rr, pp, yy = tr.rpy("deg")
        np.testing.assert_allclose(np.stack([rr, pp, yy]), np.stack([r, p, y]), atol=1e-9)


def test_from_map_grid_heading_matches_pyproj_finite_difference():
    # UTM zone 32N, 4 degrees east of the central meridian: convergence about 3 degrees
    proj = MapProjection("EPSG:32632")
    lat, lon = 48.3, 13.0
    fwd = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32632", always_xy=True)
    inv = pyproj.Transformer.from_crs("EPSG:32632", "EPSG:4326", always_xy=True)
    geod = pyproj.Geod(ellps="WGS84")
    e0, n0 = fwd.transform(lon, lat)
    grid_yaw = np.array([0.0, 30.0, -120.0])
    xyz = np.array([[e0, n0, 800.0]] * 3)
    traj = Trajectory.from_map(T0 + np.arange(3.0), xyz, proj, [1.0, 2.0, 3.0], [0.5, 0.5, 0.5], grid_yaw,
                               "deg", heading_reference="grid")
    _, _, yaw_true = traj.rpy("deg")
    for k, a in enumerate(np.radians(grid_yaw)):
        # step 1 m along the grid azimuth a, ask PROJ where that is, and take the geodesic azimuth
        lon1, lat1 = inv.transform(e0 + np.sin(a), n0 + np.cos(a))
        az, _, _ = geod.inv(lon, lat, lon1, lat1)
        assert abs(((yaw_true[k] - az) + 180.0) % 360.0 - 180.0) < 1e-5
    np.testing.assert_allclose(traj.lat_deg, lat, atol=1e-9)
    np.testing.assert_allclose(traj.h_m, 800.0, atol=1e-9)
    # and back: to_map gives the grid heading again
    _, _, _, yaw_grid = traj.to_map(proj, "grid", "deg")
    np.testing.assert_allclose(yaw_grid, grid_yaw, atol=1e-9)


# ---------------------------------------------------------------------------- events
def test_events_create_groups_exposures_and_checks():
    ev = CameraEvents.create([T0 + 1, T0 + 1, T0 + 2, T0 + 2, T0 + 3],
                             ["nadir", "oblique", "nadir", "oblique", "nadir"],
                             ["a", "b", "c", "d", "e"], beta_rad=[np.nan, 0.5, np.nan, -0.5, np.nan])
    assert ev.exposure_id.tolist() == [0, 0, 1, 1, 2]
    assert ev.heads == ["nadir", "oblique"]
    assert ev.for_head("oblique").image_name.tolist() == ["b", "d"]
    with pytest.raises(InputFormatError) as ei:
        CameraEvents.create([1.0, 2.0, 3.0], ["h"] * 3, ["x", "y", "x"], source="ev.csv", source_line=[5, 6, 7])
    assert ei.value.line == 7 and ei.value.field == "image"
    with pytest.raises(InputFormatError) as ei:
        CameraEvents.create([1.0, np.nan], ["h"] * 2, ["x", "y"])
    assert ei.value.field == "time"


def test_events_outside_span_name_file_and_line():
    traj = _circle_trajectory(1.0)
    ev = CameraEvents.create([T0 + 5.0, T0 + 61.0], ["h", "h"], ["a", "b"], source="events.csv",
                             source_line=[4, 5])
    with pytest.raises(EventOutOfSpanError) as ei:
        check_events_in_span(ev, traj)
    assert isinstance(ei.value, OutOfRangeError) and isinstance(ei.value, InputFormatError)
    assert (ei.value.path, ei.value.line, ei.value.field) == ("events.csv", 5, "time")
    ok = ev.subset([0])
    s = interpolate_events(traj, ok)
    pos, _, _ = _truth(np.array([5.0]))
    np.testing.assert_allclose(s.ecef, pos, atol=1e-9)  # exactly on a sample
    other = CameraEvents.create([T0 + 5.0], ["h"], ["a"], time_system="gps")
    with pytest.raises(InputFormatError, match="time system"):
        check_events_in_span(other, traj)


def test_yaw_wraps_through_north_by_shortest_way():
    # heading 359 -> 1 deg: the midpoint must be 0 (north), not 180
    tr = Trajectory.from_rpy([0.0, 1.0], [46.0, 46.0], [7.0, 7.0], [0.0, 0.0], [0, 0], [0, 0], [359.0, 1.0])
    s = tr.interpolate([0.5])
    expected = rot_z(0.0)
    assert _angle(s.ned_from_body[0], expected) < 1e-6
