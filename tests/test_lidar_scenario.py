"""The simulated ``uav-bridge-lidar`` project (paper 002) through skyrig's LiDAR chain.

Independent answers: the bridge's box geometry (hits lie on the faces, rays of known geometry hit at known
ranges), the analytic true motion (truth points are the ray hits from the pose at each pulse's own time,
computed without the georeferencing kernel), the injected error values and their first-order effect on
the surface (displacement along the true normal), and seeded repeatability.
"""

from __future__ import annotations

import json
import shlex
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from skyrig.errors import GeometryError, SkyrigError
from skyrig.georef.eo import WorldFrame
from skyrig.io.laz import read_las
from skyrig.io.raw_scan_csv import read_raw_scan_csv
from skyrig.io.trajectory_csv import read_trajectory_csv
from skyrig.io.truth import read_truth
from skyrig.lidar.boresight import estimate_boresight
from skyrig.lidar.georef import ScannerMount, georeference_scan
from skyrig.pipeline.simulate import write_lidar_project
from skyrig.simulate.lidar import (
    GROUND, NO_HIT, LidarErrors, build_lidar_survey, lidar_scenario_spec, make_bridge,
)

pytest.importorskip("laspy")


def small(errors: LidarErrors, seed: int = 3, dense: bool = False):
    """The CI scenario shortened to a 9 m pass past the pillar at u = 13.5 m (150 scan lines); unless
    ``dense``, with a sparser reference (120 points/m^2 on the bridge, 40 on the ground instead of 250, 60)."""
    spec = replace(lidar_scenario_spec("ci", seed, errors), pass_u_m=(18.0, 9.0))
    return spec if dense else replace(spec, reference_density_per_m2=120.0, reference_ground_density_per_m2=40.0)


def run_cli(group, args):
    r = CliRunner().invoke(group, args)
    assert r.exit_code == 0, r.output + repr(r.exception)
    return r.output


def georef_cli(outdir, barometric=False):
    from skyrig.cli.lidar import command as lidar

    cmd = json.loads((outdir / "scanner.json").read_text())["georef_command" + ("_barometric" if barometric else "")]
    args = shlex.split(cmd)[3:]  # drop "skyrig lidar georef"
    args = [str(outdir / a) if a in ("raw_scan.csv", "trajectory.csv", "barometric.csv", "georef.laz") else a for a in args]
    run_cli(lidar, ["georef", *args])
    return read_las(outdir / "georef.laz", require_crs=True)


# ------------------------------------------------------------------------------------------ geometry
def test_bridge_cast_known_answers():
    sc = make_bridge(axis_deg=30.0)
    lb = sc.local_from_bridge

    def enu(u, v, z):
        return lb @ np.array([u, v, z], float)

    o = np.array([enu(3, -20, 5), enu(3, -18, 6.5), enu(3, 0, 2), enu(13.5, -18, 3), enu(3, -18, 20), enu(3, -18, 5)])
    d = np.array([[0, 0, -1.0], enu(0, 1, 0), [0, 0, 1.0], enu(0, 1, 0), [0, 0, 1.0], enu(0, 1, 0)])
    rng, nrm, comp = sc.cast(o, d, max_range=30.0)
    names = [b.name for b in sc.boxes]
    # ground below; deck side (y = -6); deck underside (z = 6); pillar face (v = -14.1/2); sky; under the deck
    # between the pillars to the abutment-free far ground: nothing within 30 m at z = 5 looking horizontally
    np.testing.assert_allclose(rng[:4], [5.0, 12.0, 4.0, 18.0 - 7.05], atol=1e-12)
    assert comp[0] == GROUND and names[comp[1]] == "deck" and names[comp[2]] == "deck" and names[comp[3]] == "pillar_3"
    np.testing.assert_allclose(nrm[:4], [[0, 0, 1], enu(0, -1, 0), [0, 0, -1], enu(0, -1, 0)], atol=1e-12)
    assert comp[4] == NO_HIT and np.isinf(rng[4]) and comp[5] == NO_HIT
    with pytest.raises(GeometryError):
        make_bridge(deck_bottom_m=8.0, deck_top_m=7.0)


# ------------------------------------------------------------------------------------------ perfect sensors
@pytest.fixture(scope="module")
def perfect(tmp_path_factory):
    """The (shortened) CI scenario with perfect sensors, written as a project."""
    out = tmp_path_factory.mktemp("bridge-perfect")
    survey = build_lidar_survey(small(LidarErrors()))
    write_lidar_project(survey, out)
    return survey, out


def test_truth_points_lie_on_the_bridge_surfaces(perfect):
    survey, _ = perfect
    sc, x, n, c = survey.scene, survey.truth_xyz, survey.truth_normal, survey.truth_component
    assert len(survey.scan) > 50_000 and np.mean(c >= 0) > 0.05  # the bridge is seen, not only the ground
    g = c == GROUND
    np.testing.assert_allclose(x[g, 2], sc.ground_z, atol=1e-9)
    for k, b in enumerate(sc.boxes):
        m = c == k
        if not m.any():
            continue
        q = (x[m] - b.centre) @ b.local_from_box  # box coordinates
        on_face = np.abs(np.abs(np.einsum("ij,ij->i", q, n[m] @ b.local_from_box)) - np.abs(n[m] @ b.local_from_box) @ b.half_size)
        assert on_face.max() < 1e-9
        assert np.all(np.abs(q) <= b.half_size + 1e-9)
    # the ranges are the distances from the scanner origin (true pose at the pulse's own time)
    assert np.all((survey.true_range_m >= 0.1) & (survey.true_range_m <= 30.0))
    # the reference covers every hit: a reference point within 0.4 m (ground 40 points/m^2)
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(survey.reference_xyz).query(x[::20])
    assert dist.max() < 0.4
    # no reference point inside a solid (beyond 6 sigma of its 3 mm noise)
    for b in sc.boxes:
        q = np.abs((survey.reference_xyz - b.centre) @ b.local_from_box)
        assert not np.any(np.all(q < b.half_size - 0.018, axis=1))


def test_perfect_sensors_georeference_to_truth(perfect):
    survey, out = perfect
    # in memory: the kernel reproduces the analytic truth; the rest is the interpolation of 200 Hz navigation
    pts = georeference_scan(survey.scan, survey.trajectory_recorded, survey.mount_recorded, survey.frame)
    err = np.linalg.norm(pts.xyz - survey.truth_xyz, axis=1)
    assert err.max() < 3e-6, err.max()
    # from the files: raw CSV (0.1 mm ranges) and trajectory CSV, against truth/points.laz (0.1 mm steps)
    scan, hdr = read_raw_scan_csv(out / "raw_scan.csv")
    traj = read_trajectory_csv(out / "trajectory.csv")
    truth = read_las(out / "truth" / "points.laz", require_crs=True)
    frame = WorldFrame.map(read_truth(out / "truth" / "truth.json")["crs"])
    mount = json.loads((out / "scanner.json").read_text())
    pf = georeference_scan(scan, traj, ScannerMount(np.array(mount["body_from_scanner"]), mount["lever_arm_m"]), frame)
    assert np.abs(pf.xyz - truth.xyz).max() < 2.5e-4
    np.testing.assert_allclose(truth.gps_time, scan.time_s, atol=1e-6)
    # skyrig lidar georef with the command line recorded in scanner.json (LAS 1 mm steps)
    las = georef_cli(out)
    assert las.xyz.shape == truth.xyz.shape
    assert np.abs(las.xyz - truth.xyz).max() < 1.2e-3


def test_cli_simulate_writes_the_project(tmp_path):
    from skyrig.cli.simulate import command as simulate

    run_cli(simulate, ["uav-bridge-lidar", str(tmp_path / "p")])
    t = read_truth(tmp_path / "p" / "truth" / "truth.json")
    assert t["scenario"] == "uav-bridge-lidar" and t["size"] == "ci"
    assert LidarErrors.from_dict(t["errors"]) == lidar_scenario_spec("ci").errors  # paper-002 errors by default
    ref = read_las(tmp_path / "p" / "reference" / "tls.laz", require_crs=True)
    scan, _ = read_raw_scan_csv(tmp_path / "p" / "raw_scan.csv")
    assert len(ref) > 100_000 and t["statistics"]["returns"] == len(scan)
    assert np.all(np.diff(scan.time_s) >= 0) and np.all(scan.range_m <= 30.2)
    b = np.loadtxt(tmp_path / "p" / "barometric.csv", delimiter=",", skiprows=1)
    assert b.shape[1] == 2 and np.all(np.diff(b[:, 0]) > 0)


def test_seeded_and_deterministic():
    a = build_lidar_survey(replace(small(lidar_scenario_spec("ci").errors, seed=9), pass_u_m=(15.0, 13.0)))
    b = build_lidar_survey(replace(small(lidar_scenario_spec("ci").errors, seed=9), pass_u_m=(15.0, 13.0)))
    c = build_lidar_survey(replace(small(lidar_scenario_spec("ci").errors, seed=10), pass_u_m=(15.0, 13.0)))
    for name in ("time_s", "range_m", "alpha_rad", "intensity"):
        np.testing.assert_array_equal(getattr(a.scan, name), getattr(b.scan, name))
    np.testing.assert_array_equal(a.reference_xyz, b.reference_xyz)
    assert len(a.scan) != len(c.scan) or not np.array_equal(a.scan.range_m, c.scan.range_m)
    with pytest.raises(SkyrigError):
        lidar_scenario_spec("huge")
    with pytest.raises(SkyrigError):
        LidarErrors.from_dict({"boresight": [0, 0, 0]})


# ------------------------------------------------------------------------------------------ injected errors
def _truth_rotation(survey):
    """local_from_body at the true pulse times from the TRUE trajectory via Trajectory.interpolate."""
    s = survey.trajectory_true.interpolate(survey.true_time_s)
    return survey.frame.tangent.ecef_from_local.T @ s.ecef_from_body


@pytest.mark.parametrize("what", ["lever", "range_bias"])
def test_injected_errors_show_their_magnitude_in_cli_compare(tmp_path, what):
    from skyrig.cli.lidar import command as lidar

    err = LidarErrors(lever_arm_error_m=(0.0, 0.10, 0.0)) if what == "lever" else LidarErrors(range_bias_m=0.05)
    survey = build_lidar_survey(small(err))
    write_lidar_project(survey, tmp_path)
    georef_cli(tmp_path)
    run_cli(lidar, ["compare", "--compared", str(tmp_path / "georef.laz"), "--reference",
                    str(tmp_path / "reference" / "tls.laz"), "--method", "c2c-plane", "--k", "8", "--max-distance", "0.5",
                    "-o", str(tmp_path / "d.laz"), "--stats", str(tmp_path / "s.json")])
    c2c = read_las(tmp_path / "d.laz").extra["distance"]
    stats = json.loads((tmp_path / "s.json").read_text())
    n = survey.truth_normal
    if what == "lever":
        # recorded lever = true - error: every point moves by -R_lb @ error; its component across the surface
        shift = -np.einsum("nij,j->ni", _truth_rotation(survey), np.array(err.lever_arm_error_m))
    else:
        # the beam from the IMU (lever arm of 0.2 m against ranges of metres: a small angle, checked by the
        # tolerance below) to the true surface point
        x0 = survey.frame.from_ecef(survey.trajectory_true.interpolate(survey.true_time_s).ecef)
        beam = survey.truth_xyz - x0
        beam /= np.linalg.norm(beam, axis=1)[:, None]
        shift = err.range_bias_m * beam
    predicted = np.abs(np.einsum("ij,ij->i", shift, n))
    ok = (c2c > -9000) & np.isfinite(c2c)
    assert ok.mean() > 0.95
    diff = np.abs(c2c[ok] - predicted[ok])
    assert np.median(diff) < 0.003 and np.mean(diff < 0.01) > 0.9
    rms_pred = float(np.sqrt(np.mean(predicted[ok] ** 2)))
    assert abs(stats["rms_m"] - rms_pred) < 0.1 * rms_pred
    if what == "lever":
        # faces towards the flight line (normal pointing to the UAV, i.e. across the axis) move by the full 10 cm
        across = np.abs(n[ok] @ survey.scene.local_from_bridge[:, 1]) > 0.99
        assert across.sum() > 1000
        assert abs(np.median(c2c[ok][across]) - 0.10) < 0.005
    else:
        assert 0.5 * err.range_bias_m < stats["mean_m"] <= err.range_bias_m + 0.002


def test_boresight_is_recovered_within_its_sigma():
    injected = np.radians([0.3, -0.4, 0.5])
    survey = build_lidar_survey(small(LidarErrors(boresight_rad=tuple(injected), range_sigma_m=0.03), dense=True))
    assert survey.injected["boresight_rad"] == pytest.approx(injected)
    res = estimate_boresight(survey.scan, survey.trajectory_recorded, survey.mount_recorded, survey.reference_xyz,
                             survey.frame, estimate=("boresight",), max_points=15_000, max_distance=0.5)
    # sigma is from the range noise alone (see skyrig.lidar.boresight): over seeds 10-19 the errors were
    # 0.8, 0.7 and 1.5 sigma RMS about x, y, z (local planes at face edges add a little); 3 sigma is the bound
    assert np.all(np.abs(res.value - injected) < 3 * res.sigma + 1e-5), (np.degrees(res.value), np.degrees(res.sigma))
    assert np.all(np.degrees(res.sigma) < 0.1)
    assert res.rms_after_m < res.rms_before_m


def test_heading_error_is_recovered_within_its_sigma():
    he = np.radians(1.5)
    survey = build_lidar_survey(small(LidarErrors(heading_error_rad=float(he), range_sigma_m=0.03), dense=True))
    res = estimate_boresight(survey.scan, survey.trajectory_recorded, survey.mount_recorded, survey.reference_xyz,
                             survey.frame, estimate=("yaw",), max_points=15_000, max_distance=0.6)
    v, s = res.get("yaw")
    assert survey.injected["heading_correction_rad"] == pytest.approx(-he)
    assert abs(v - (-he)) < 3 * s + 1e-6 and np.degrees(s) < 0.05


def test_barometric_heights_replace_weak_gnss_heights(tmp_path):
    err = LidarErrors(gnss_wander_m=(0.0, 0.0, 0.5), baro_noise_m=0.02)
    survey = build_lidar_survey(small(err))
    write_lidar_project(survey, tmp_path)
    truth = read_las(tmp_path / "truth" / "points.laz").xyz
    gnss = georef_cli(tmp_path).xyz
    baro = georef_cli(tmp_path, barometric=True).xyz
    # without the barometer the vertical errors are the GNSS height errors at the pulse times
    t = survey.trajectory_true
    dh = np.interp(survey.scan.time_s, t.time_s, survey.trajectory_recorded.h_m - t.h_m)
    dz = gnss[:, 2] - truth[:, 2]
    assert np.sqrt(np.mean((dz - dh) ** 2)) < 0.005
    assert np.sqrt(np.mean(dz**2)) > 0.2
    # with it, the barometer's 2 cm noise is what is left (white noise through the cubic spline: about 1 sigma)
    rz = np.sqrt(np.mean((baro[:, 2] - truth[:, 2]) ** 2))
    assert 0.01 < rz < 0.03
