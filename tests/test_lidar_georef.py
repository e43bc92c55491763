"""Scanner georeferencing on a simulated UAV flight along a bridge (paper 002's scanner and geometry).

Truth comes from ray casting the bridge's boxes from poses given by ``Trajectory.interpolate`` (the
independent, general-purpose path); skyrig's per-pulse kernel must reproduce it to numerical precision,
invert back to the raw ranges and angles, show injected errors with their predicted magnitudes in a
cloud-to-cloud comparison against a reference sampled from the surfaces, and recover injected boresight
and heading errors within their standard deviations.
"""

from __future__ import annotations

import numpy as np
import pytest

from skyrig.errors import GeometryError, InputFormatError, OutOfRangeError
from skyrig.geodesy.local import LocalTangentFrame
from skyrig.georef.eo import WorldFrame
from skyrig.lidar.boresight import estimate_boresight
from skyrig.lidar.compare import cloud_to_cloud
from skyrig.lidar.georef import (
    PulseGeoreferencer,
    ScannerMount,
    georeference_scan,
    invert_points,
    rotation_from_angles,
    with_barometric_height,
    with_yaw_correction,
)
from skyrig.lidar.scanner import HOKUYO_UTM_30LX_EW, RawScan, polar_from_sensor, sensor_from_polar
from skyrig.trajectory.trajectory import Trajectory

ORIGIN = (51.0275, 13.7258, 150.0)  # Dresden, ellipsoidal height of the ground
# boxes (lo, hi) in the local ENU frame: ground slab, deck, two pillars (paper 002: 12 m wide, 8 m high;
# pillars 14.1 m x 1.4 m)
BOXES = [
    ((-200.0, -200.0, -1.0), (200.0, 200.0, 0.0)),
    ((0.0, 0.0, 6.0), (40.0, 12.0, 8.0)),
    ((14.3, -1.05, 0.0), (15.7, 13.05, 6.0)),
    ((24.3, -1.05, 0.0), (25.7, 13.05, 6.0)),
]
# scanner x (alpha = 0) along body y (right), scanner y (alpha = +90 deg) along body z (down)
BODY_FROM_SCANNER = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
LEVER = np.array([0.10, -0.02, 0.15])
T0 = 5000.0


def ray_cast(o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest hit distance (inf if none) and outward face normal of rays against BOXES."""
    best = np.full(len(o), np.inf)
    normal = np.zeros((len(o), 3))
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
    for lo, hi in BOXES:
        t1 = (np.array(lo) - o) * inv
        t2 = (np.array(hi) - o) * inv
        tmin3 = np.fmin(t1, t2)
        tmin = tmin3.max(axis=1)
        tmax = np.fmax(t1, t2).min(axis=1)
        hit = (tmax >= tmin) & (tmin > 0) & (tmin < best)
        best[hit] = tmin[hit]
        ax = np.argmax(tmin3, axis=1)
        nrm = np.zeros((len(o), 3))
        nrm[np.arange(len(o)), ax] = -np.sign(d[np.arange(len(o)), ax])
        normal[hit] = nrm[hit]
    return best, normal


def make_trajectory(duration=6.0, rate=100.0):
    t = T0 - 1.0 + np.arange(0, duration + 2.0 + 1e-9, 1.0 / rate)
    s = t - T0
    speed = 2.0
    east = 26.0 - speed * s  # flying west along the bridge, 12 m south of it
    north = -12.0 + 0.05 * np.sin(0.9 * s)
    up = 5.0 + 0.1 * np.sin(0.4 * s)
    tangent = LocalTangentFrame(*ORIGIN)
    lat, lon, h = tangent.to_geodetic(np.c_[east, north, up])
    roll = 3.0 * np.sin(0.7 * s)
    pitch = 2.0 * np.sin(0.5 * s + 1.0)
    yaw = -90.0 + 4.0 * np.sin(0.3 * s)
    return Trajectory.from_rpy(t, lat, lon, h, roll, pitch, yaw, "deg")


def simulate(traj, mount, duration=6.0, lines_per_s=None, seed=0, range_sigma=0.0):
    """Raw scan of the bridge with the *true* trajectory and mount, plus truth points and normals (local ENU)."""
    sc = HOKUYO_UTM_30LX_EW
    n_lines = int(duration * sc.lines_per_s)
    t, alpha = sc.pulse_times_and_angles(T0 + np.arange(n_lines) / sc.lines_per_s)
    s = traj.interpolate(t)  # the independent path
    reb = s.ecef_from_body
    origin = s.ecef + np.einsum("nij,j->ni", reb, mount.lever_arm_m)
    dirs = np.einsum("nij,nj->ni", reb @ mount.body_from_scanner, sensor_from_polar(np.ones_like(t), alpha))
    tangent = LocalTangentFrame(*ORIGIN)
    o = tangent.from_ecef(origin)
    d = dirs @ tangent.ecef_from_local
    rng_true, normal = ray_cast(o, d)
    keep = (rng_true > sc.range_min_m) & (rng_true < sc.range_max_m)
    truth = o[keep] + rng_true[keep, None] * d[keep]
    noise = np.random.default_rng(seed).normal(0.0, range_sigma, keep.sum()) if range_sigma else 0.0
    scan = RawScan(t[keep], rng_true[keep] + noise, alpha[keep])
    return scan, truth, normal[keep], d[keep]


def reference_cloud(spacing=0.1):
    """TLS-like reference: the surfaces seen from the flight line, sampled on a grid."""
    pts = []
    g = np.arange(4.0, 36.0, spacing)
    # ground (up to the bridge's far side)
    yy = np.arange(-30.0, 14.0, spacing)
    x, y = np.meshgrid(g, yy)
    pts.append(np.c_[x.ravel(), y.ravel(), np.zeros(x.size)])
    # deck: south face (y = 0) and bottom (z = 6)
    zz = np.arange(6.0, 8.0 + 1e-9, spacing)
    x, z = np.meshgrid(g, zz)
    pts.append(np.c_[x.ravel(), np.zeros(x.size), z.ravel()])
    yb = np.arange(0.0, 12.0 + 1e-9, spacing)
    x, y = np.meshgrid(g, yb)
    pts.append(np.c_[x.ravel(), y.ravel(), np.full(x.size, 6.0)])
    # pillars: 4 faces each
    for x0 in (14.3, 24.3):
        zp = np.arange(0.0, 6.0 + 1e-9, spacing)
        yp = np.arange(-1.05, 13.05 + 1e-9, spacing)
        xp = np.arange(x0, x0 + 1.4 + 1e-9, spacing)
        for xf in (x0, x0 + 1.4):
            y, z = np.meshgrid(yp, zp)
            pts.append(np.c_[np.full(y.size, xf), y.ravel(), z.ravel()])
        for yf in (-1.05, 13.05):
            x, z = np.meshgrid(xp, zp)
            pts.append(np.c_[x.ravel(), np.full(x.size, yf), z.ravel()])
    return np.concatenate(pts)


@pytest.fixture(scope="module")
def scene():
    traj = make_trajectory()
    mount = ScannerMount(BODY_FROM_SCANNER, LEVER)
    scan, truth, normal, dirs = simulate(traj, mount)
    return traj, mount, scan, truth, normal, dirs


LOCAL = WorldFrame.local(*ORIGIN)


def test_scanner_model_eq1_and_inverse():
    r, a = np.array([1.0, 2.0, 30.0]), np.radians([-135.0, 0.0, 90.0])
    xyz = sensor_from_polar(r, a)
    np.testing.assert_allclose(xyz[:, 2], 0.0)
    np.testing.assert_allclose(xyz[2], [0.0, 30.0, 0.0], atol=1e-12)
    rr, aa, bb = polar_from_sensor(sensor_from_polar(r, a, np.radians([10.0, -20.0, 45.0])))
    np.testing.assert_allclose(rr, r)
    np.testing.assert_allclose(aa, a)
    np.testing.assert_allclose(np.degrees(bb), [10.0, -20.0, 45.0])
    sc = HOKUYO_UTM_30LX_EW
    assert sc.pulses_per_line == 1080  # 270 deg / 0.25 deg (paper 002)
    t, al = sc.pulse_times_and_angles([0.0, 0.025])
    assert t.shape == (2160,) and t[1079] < 0.025 * 0.75 + 1e-12 and t[1080] == 0.025


def test_perfect_sensors_reproduce_truth(scene):
    traj, mount, scan, truth, _, _ = scene
    assert len(scan) > 100_000
    pts = georeference_scan(scan, traj, mount, LOCAL)
    err = np.linalg.norm(pts.xyz - truth, axis=1)
    assert err.max() < 1e-6, err.max()
    # the same through ECEF and a map CRS (UTM 33N, PROJ) agree with truth mapped by PROJ
    ecef = georeference_scan(scan.subset(slice(0, 2000)), traj, mount, WorldFrame.ecef())
    np.testing.assert_allclose(ecef.xyz, LocalTangentFrame(*ORIGIN).to_ecef(truth[:2000]), atol=1e-6, rtol=0)
    utm = WorldFrame.map("EPSG:32633")
    pm = georeference_scan(scan.subset(slice(0, 2000)), traj, mount, utm)
    np.testing.assert_allclose(pm.xyz, utm.from_ecef(ecef.xyz), atol=1e-6, rtol=0)


def test_paper002_linear_pose_interpolation_is_close_but_not_exact(scene):
    traj, mount, scan, truth, _, _ = scene
    lin = georeference_scan(scan, traj, mount, LOCAL, position="linear")
    err = np.linalg.norm(lin.xyz - truth, axis=1)
    # 100 Hz navigation: chord vs spline differs by < a millimetre, but not by nothing
    assert 1e-9 < err.max() < 1e-3


def test_round_trip_to_raw_ranges_and_angles(scene):
    traj, mount, scan, truth, _, _ = scene
    rng, alpha, beta = invert_points(truth, scan.time_s, traj, mount, LOCAL)
    assert np.max(np.abs(rng - scan.range_m)) < 1e-6
    assert np.max(np.abs(alpha - scan.alpha_rad)) < 1e-8
    assert np.max(np.abs(beta)) < 1e-8


@pytest.mark.parametrize(
    "what",
    ["lever", "boresight", "yaw", "noise"],
)
def test_injected_errors_show_their_magnitude_in_cloud_to_cloud(scene, what):
    traj, mount, scan, truth, normal, dirs = scene
    rows = np.arange(0, len(scan), 7)
    sub = scan.subset(rows)
    used_mount, yaw = mount, 0.0
    if what == "lever":
        used_mount = ScannerMount(BODY_FROM_SCANNER, LEVER + [0.0, 0.10, 0.0])  # 10 cm to the right
    elif what == "boresight":
        used_mount = mount.corrected(dboresight_rad=np.radians([0.0, 0.0, 0.5]))  # in the scan plane
    elif what == "yaw":
        yaw = np.radians(1.0)
    else:
        sub = RawScan(sub.time_s, sub.range_m + np.random.default_rng(5).normal(0, 0.03, len(sub)), sub.alpha_rad)
    pts = georeference_scan(sub, traj, used_mount, LOCAL, yaw_correction_rad=yaw)
    delta = pts.xyz - truth[rows]
    predicted = np.abs(np.einsum("ij,ij->i", delta, normal[rows]))  # displacement across the surface
    # max_distance: hits outside the sampled reference area get no distance (CloudCompare: "max dist")
    c2c = cloud_to_cloud(pts.xyz, reference_cloud(), model="plane", k=8, max_distance=0.5).distance_m
    # away from edges the local-plane C2C equals the displacement along the surface normal
    good = np.isfinite(c2c)
    diff = np.abs(c2c[good] - predicted[good])
    assert np.median(diff) < 0.002
    assert np.mean(diff < 0.01) > 0.9
    rms_c2c = np.sqrt(np.mean(c2c[good] ** 2))
    rms_pred = np.sqrt(np.mean(predicted[good] ** 2))
    assert abs(rms_c2c - rms_pred) < 0.05 * rms_pred + 0.002
    # and the magnitudes are those of the injected errors
    if what == "lever":
        on_face = np.abs(normal[rows][good, 1]) > 0.5  # bridge faces towards the flight line (normal -north)
        assert abs(np.median(c2c[good][on_face]) - 0.10) < 0.01
    elif what == "noise":
        assert 0.015 < rms_c2c < 0.031  # 3 cm along the beam, times the cosine of the incidence angle
    elif what == "boresight":
        rng = sub.range_m[good]
        assert np.max(np.linalg.norm(delta[good], axis=1) / rng) == pytest.approx(np.radians(0.5), rel=1e-3)


def test_boresight_is_recovered_within_its_sigma(scene):
    traj, mount, _, _, _, _ = scene
    injected = np.radians([0.3, -0.4, 0.5])
    true_mount = mount.corrected(dboresight_rad=injected)
    scan, _, _, _ = simulate(traj, true_mount, duration=4.0, seed=1, range_sigma=0.03)
    res = estimate_boresight(scan, traj, mount, reference_cloud(0.08), LOCAL, estimate=("boresight",),
                             max_points=20_000, max_distance=0.5)
    est = res.value
    assert np.all(np.abs(est - injected) < 3 * res.sigma + 1e-5), (np.degrees(est), np.degrees(res.sigma))
    assert np.all(np.degrees(res.sigma) < 0.1)
    assert res.rms_after_m < res.rms_before_m


def test_yaw_correction_is_recovered_within_its_sigma(scene):
    traj, mount, _, _, _, _ = scene
    dyaw = np.radians(1.5)
    # the real heading is yaw + dyaw: the recorded trajectory lacks it
    true_traj = with_yaw_correction(traj, dyaw)
    scan, _, _, _ = simulate(true_traj, mount, duration=4.0, seed=2, range_sigma=0.03)
    res = estimate_boresight(scan, traj, mount, reference_cloud(0.08), LOCAL, estimate=("yaw",),
                             max_points=20_000, max_distance=0.5)
    v, s = res.get("yaw")
    assert abs(v - dyaw) < 3 * s + 1e-6 and np.degrees(s) < 0.05
    assert res.yaw_correction_rad == pytest.approx(v)


def test_inseparable_yaw_and_boresight_are_reported(scene):
    traj, mount, scan, _, _, _ = scene
    # a boresight rotation about the scanner axis that points along body z (down) is a heading change
    down_mount = ScannerMount(np.eye(3), LEVER)
    level = Trajectory.from_rpy(traj.time_s, traj.lat_deg, traj.lon_deg, traj.h_m,
                                np.zeros(len(traj)), np.zeros(len(traj)), np.full(len(traj), -90.0))
    sc, _, _, _ = simulate(level, ScannerMount(BODY_FROM_SCANNER, LEVER), duration=2.0)
    with pytest.raises(GeometryError, match="cannot be separated"):
        estimate_boresight(sc, level, ScannerMount(BODY_FROM_SCANNER, LEVER), reference_cloud(0.1), LOCAL,
                           estimate=("boresight", "yaw"), max_points=5000, max_distance=0.5)
    del down_mount


def test_barometric_height_replaces_gnss_height(scene):
    traj, mount, scan, truth, _, _ = scene
    bad = Trajectory(traj.time_s, traj.lat_deg, traj.lon_deg, traj.h_m + 0.8 * np.sin(traj.time_s),
                     traj.ned_from_body_q)  # noisy GNSS heights
    sub = scan.subset(slice(0, 20000))
    worse = georeference_scan(sub, bad, mount, LOCAL)
    assert np.abs(worse.xyz[:, 2] - truth[:20000, 2]).max() > 0.3
    fixed = georeference_scan(sub, bad, mount, LOCAL, barometric=(traj.time_s, traj.h_m))
    # barometer heights are ellipsoidal heights of the IMU: only the horizontal position's tiny
    # effect on the local vertical is left
    assert np.abs(fixed.xyz - truth[:20000]).max() < 1e-6
    with pytest.raises(OutOfRangeError, match="barometric"):
        with_barometric_height(traj, traj.time_s[5:], traj.h_m[5:])


def test_rotation_conventions():
    a = np.array([10.0, -20.0, 30.0])
    np.testing.assert_allclose(rotation_from_angles(a, "zyx"),
                               rotation_from_angles([0, 0, 30.0]) @ rotation_from_angles([0, -20.0, 0]) @ rotation_from_angles([10.0, 0, 0]))
    np.testing.assert_allclose(rotation_from_angles(a, "xyz", passive=True), rotation_from_angles(a, "xyz").T)
    from skyrig.geometry.rotations import matrix_from_rpy
    np.testing.assert_allclose(rotation_from_angles(a, "zyx"), matrix_from_rpy(10.0, -20.0, 30.0, "deg"))
    with pytest.raises(InputFormatError):
        rotation_from_angles(a, "xxz")


def test_bad_input(scene):
    traj, mount, scan, _, _, _ = scene
    with pytest.raises(OutOfRangeError, match="must not decrease"):
        RawScan(np.array([1.0, 2.0, 1.5]), np.ones(3), np.zeros(3))
    late = RawScan(scan.time_s[-3:] + 100.0, scan.range_m[-3:], scan.alpha_rad[-3:])
    with pytest.raises(OutOfRangeError, match="outside the trajectory's time span"):
        georeference_scan(late, traj, mount, LOCAL)
    with pytest.raises(OutOfRangeError, match="strictly increasing"):
        Trajectory.from_rpy([0.0, 2.0, 1.0], [51.0] * 3, [13.0] * 3, [100.0] * 3, [0] * 3, [0] * 3, [0] * 3)
    with pytest.raises(InputFormatError):
        RawScan(np.zeros(3), -np.ones(3), np.zeros(3))
    with pytest.raises(InputFormatError):
        ScannerMount(np.diag([1.0, 1.0, -1.0]))
    geo = PulseGeoreferencer(traj, mount)
    with pytest.raises(InputFormatError):
        geo.ecef(scan.time_s[:3], np.zeros((3, 2)))


def test_compiled_kernel_equals_numpy_path():
    """The numba kernel (when installed) and the numpy path compute the same georeferenced points."""
    import skyrig.lidar.georef as G

    if G._NUMBA_KERNEL is None:
        pytest.skip("numba not installed: only the numpy path exists")
    from skyrig.geodesy.local import LocalTangentFrame
    from skyrig.trajectory.trajectory import Trajectory

    rng = np.random.default_rng(5)
    tt = np.arange(0.0, 20.0, 0.01)
    lat, lon, h = LocalTangentFrame(51.0, 13.7, 150.0).to_geodetic(np.c_[2 * tt, np.sin(tt), 5 + np.cos(tt)])
    traj = Trajectory.from_rpy(tt, lat, lon, h, 3 * np.sin(tt), 2 * np.cos(tt), 90 + 20 * np.sin(0.2 * tt))
    mount = G.ScannerMount(np.array([[0.0, 0, 1], [1, 0, 0], [0, 1, 0]]), np.array([0.1, 0.0, 0.15]))
    t = np.sort(rng.uniform(0.0, 19.99, 20000))
    xs = rng.normal(0, 10, (20000, 3))
    for position in ("cubic", "linear"):
        geo = G.PulseGeoreferencer(traj, mount, position=position)
        fast = geo.ecef(t, xs)
        geo.use_numba = False
        slow = geo.ecef(t, xs)
        assert np.abs(fast - slow).max() < 1e-7
