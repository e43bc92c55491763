"""``skyrig calibrate lidar-camera`` (issue 34): bad inputs named; on the simulated bridge strip flight (slow) the
injected scanner and camera calibration recovered within 3 predicted sigmas, the laser and image clouds against the
TLS reference."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from skyrig.lidar.scanner import Scanner2D
from skyrig.simulate.lidar import build_lidar_survey, lidar_scenario_spec, strip_truth_vector


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    from skyrig.io.raw_scan_csv import write_raw_scan_csv
    from skyrig.io.trajectory_csv import write_trajectory_csv

    d = tmp_path_factory.mktemp("lidar_camera")
    sv = build_lidar_survey(replace(lidar_scenario_spec("strips-ci", 3), scanner=Scanner2D(step_deg=4.0)))
    write_raw_scan_csv(d / "scan.csv", sv.scan.subset(slice(0, 1500)))
    write_trajectory_csv(d / "traj.csv", sv.trajectory_recorded, crs="EPSG:4979")
    mount = {"format": "skyrig-scanner-mount", "version": 1,
             "body_from_scanner": sv.mount_recorded.body_from_scanner.tolist(),
             "lever_arm_m": sv.mount_recorded.lever_arm_m.tolist()}
    (d / "scanner.json").write_text(json.dumps(mount))
    for name in ("rig.yaml", "events.csv", "meas.csv"):  # read only after the laser inputs were checked
        (d / name).write_text("")
    return d, sv, mount


def _args(d, scan="scan.csv", mount="scanner.json"):
    return ["lidar-camera", "--scan", str(d / scan), "--trajectory", str(d / "traj.csv"), "--scanner-mount",
            str(d / mount), "--rig", str(d / "rig.yaml"), "--events", str(d / "events.csv"), "--measurements",
            str(d / "meas.csv"), "-o", str(d / "out.yaml")]


def test_bad_inputs_are_named(files):
    from skyrig.cli.calibrate import command

    d, sv, mount = files
    left = dict(mount, body_from_scanner=(np.array(mount["body_from_scanner"]) * [[1], [1], [-1]]).tolist())
    (d / "left.json").write_text(json.dumps(left))
    r = CliRunner().invoke(command, _args(d, mount="left.json"))
    assert r.exit_code != 0 and "left-handed" in str(r.exception) and "left.json" in str(r.exception)
    (d / "mm.json").write_text(json.dumps(dict(mount, lever_arm_m=[100.0, -20.0, 150.0])))
    r = CliRunner().invoke(command, _args(d, mount="mm.json"))
    assert r.exit_code != 0 and "millimetres" in str(r.exception) and "lever_arm_m" in str(r.exception)
    lines = (d / "scan.csv").read_text().splitlines()
    head = [i for i, ln in enumerate(lines) if ln and not ln.startswith("#")][0]  # the header row
    k = head + 1 + 700
    late = []
    for i, ln in enumerate(lines[k:]):  # from row 700 on the pulses come after the trajectory's end
        f = ln.split(",")
        f[0] = "%.6f" % (sv.trajectory_recorded.span[1] + 5.0 + 1e-3 * i)
        late.append(",".join(f))
    (d / "late.csv").write_text("\n".join(lines[:k] + late) + "\n")
    r = CliRunner().invoke(command, _args(d, scan="late.csv"))
    msg = str(r.exception)
    assert r.exit_code != 0 and "late.csv" in msg and f"line {k + 1}" in msg and "outside the trajectory" in msg
    r = CliRunner().invoke(command, ["lidar-camera", "-o", str(d / "x.yaml")])
    assert r.exit_code != 0 and "--scan" in r.output


def test_bad_control_file_is_named(files):
    """``--control``: read before the camera's inputs; a LAS without a CRS, a points CSV with a bad row, an empty
    one: each error names the file (and line and field)."""
    import laspy

    from skyrig.cli.calibrate import command

    d, sv, _ = files
    las = laspy.LasData(laspy.LasHeader(point_format=0, version="1.2"))
    las.x, las.y, las.z = [1.0, 2.0], [3.0, 4.0], [5.0, 6.0]
    las.write(str(d / "nocrs.las"))
    r = CliRunner().invoke(command, _args(d) + ["--control", str(d / "nocrs.las")])
    assert r.exit_code != 0 and "nocrs.las" in str(r.exception) and "CRS" in str(r.exception), r.output
    (d / "ctl.csv").write_text("# crs: EPSG:32633\nname,x,y,z\nc1,500000.0,5000000.0,100.0\nc2,500001.0,oops,100.0\n")
    r = CliRunner().invoke(command, _args(d) + ["--control", str(d / "ctl.csv")])
    msg = str(r.exception)
    assert r.exit_code != 0 and "ctl.csv" in msg and "line 4" in msg and "field 'y'" in msg, msg
    r = CliRunner().invoke(command, _args(d) + ["--control-sigma-m", "0"])
    assert r.exit_code != 0 and "--control-sigma-m" in r.output
    r = CliRunner().invoke(command, _args(d) + ["--gcp-sigma-m", "-0.01"])
    assert r.exit_code != 0 and "--gcp-sigma-m" in r.output
    r = CliRunner().invoke(command, _args(d) + ["--gcp", str(d / "no_such_gcp.csv")])
    assert r.exit_code != 0 and "no_such_gcp.csv" in r.output


@pytest.mark.slow
def test_simulated_bridge_flight_recovers_the_injected_calibration(tmp_path):
    """Paper 002's bridge strip flight with its camera (CI size, seed 2): scanner boresight, lever arm, range offset
    and scale and camera boresight within 3 predicted sigmas; the strip-to-strip discrepancies on the patch planes
    reduced to their predicted noise; the rig file holds both sensors."""
    from skyrig.cli.calibrate import command
    from skyrig.io.rig_file import read_calibrated_rig
    from skyrig.io.scanner_record import read_rig_scanners

    out = tmp_path / "rig.yaml"
    r = CliRunner().invoke(command, ["lidar-camera", "--simulate", "strips-ci", "--seed", "2", "-o", str(out)])
    assert r.exit_code == 0, r.output
    rep = json.loads(out.with_suffix(".json").read_text())
    sc = rep["scanner"]
    truth = rep["truth"]["scanner"]
    z = {n: (sc[n]["value"] - t) / sc[n]["sigma"] for n, t in zip(sc, truth)}
    assert all(abs(v) < 3.0 for v in z.values()), z
    cb = rep["camera_boresight_rad"]
    zc = (np.array(cb["value"]) - rep["truth"]["camera_boresight_rad"]) / np.array(cb["sigma"])
    assert np.all(np.abs(zc) < 3.0), zc
    rig, _ = read_calibrated_rig(out)
    assert "camera" in rig.head_names and "lidar" in read_rig_scanners(out)
    assert 0.85 < rep["sigma0"] < 1.15
    dis = rep["strip_discrepancies"]
    assert dis["before"]["normalised_rms"] > 5.0  # the injected errors show
    assert dis["after"]["normalised_rms"] < 1.2 and dis["after"]["rms_m"] < 1.5 * dis["after"]["noise_rms_m"], dis


def test_truth_vector_matches_the_recipe_conventions():
    """The simulator's truth (the corrections' negatives) reproduces the true laser points through the factor's
    georeferencing model: the conventions of the recipe and of the simulation agree (noise only left)."""
    from skyrig.adjust.factors.lidar import LidarPoints, georeference
    from skyrig.lidar.pulse_poses import beams, local_poses

    sv = build_lidar_survey(replace(lidar_scenario_spec("strips-ci", 3), scanner=Scanner2D(step_deg=4.0)))
    sid = sv.scan.strip_id
    ids = np.unique(sid[sid >= 0])
    ep = np.array([0.5 * (sv.scan.time_s[sid == k].min() + sv.scan.time_s[sid == k].max()) for k in ids])
    tv = strip_truth_vector(sv.injected, ep)
    rows = np.flatnonzero(sid >= 0)[::20]
    p, R = local_poses(sv.trajectory_recorded, sv.frame, sv.scan.time_s[rows])
    b, db = beams(sv.scan, rows)
    lp = LidarPoints(sv.scan.time_s[rows], np.searchsorted(ids, sid[rows]), sv.scan.range_m[rows], b, db,
                     np.zeros(len(rows), np.int64), p, R, np.full(1, -1), ep, sv.mount_recorded.body_from_scanner,
                     sv.mount_recorded.lever_arm_m)
    lp.normalise(None)
    X = georeference(lp, tv[:8], tv[8:].reshape(-1, 12))["X"]
    d = X - sv.truth_xyz[rows]
    along = np.einsum("ni,ni->n", d, np.einsum("nij,nj->ni", R, b @ sv.mount_true.body_from_scanner.T))
    across = np.linalg.norm(d - along[:, None] * np.einsum("nij,nj->ni", R, b @ sv.mount_true.body_from_scanner.T),
                            axis=1)
    assert abs(np.std(along) - sv.spec.errors.range_sigma_m) < 0.15 * sv.spec.errors.range_sigma_m
    assert np.sqrt(np.mean(across**2)) < 2e-3  # nothing but range noise (and trajectory interpolation) left


@pytest.mark.slow
def test_tls_control_removes_the_common_shift_on_the_simulated_flight():
    """Paper 002's bridge strip flight (CI size, seed 2): the joint recipe without control keeps the trajectory's
    common error as a shift of the laser cloud against the TLS; with control planes from a sixth of the site's 5 m
    cells of the TLS reference, the cloud's mean offset on the cells NOT used as control is within 3 predicted sigmas
    of zero (the strips' common position offset's sigma), the control planes' normalised residuals about N(0, 1)."""
    from skyrig.calibrate.lidar_camera import calibrate_lidar_camera, georeference_adjusted, joint_inputs_from_flight
    from skyrig.lidar.compare import M3C2Params, m3c2
    from skyrig.simulate.lidar_camera import build_joint_flight

    fl = build_joint_flight("strips-ci", 2)
    sv = fl.survey
    ref = sv.reference_xyz

    def is_control(p):
        ij = np.floor(p[:, :2] / 5.0).astype(np.int64)
        return (ij[:, 0] * 7 + ij[:, 1] * 3) % 6 == 0

    inp = joint_inputs_from_flight(fl)
    rows = np.flatnonzero(sv.scan.strip_id >= 0)
    key = np.floor((ref - ref.min(axis=0)) / 0.5).astype(np.int64)
    core = ref[np.sort(np.unique(key, axis=0, return_index=True)[1])]
    core = core[~is_control(core)]
    params = M3C2Params.pdal(normal_radius=0.5, cylinder_radius=0.25, cylinder_half_length=0.5, min_points=5)
    out = {}
    for name, ctrl in (("free", None), ("control", ref[is_control(ref)])):
        cal = calibrate_lidar_camera(inp if ctrl is None else replace(inp, control_xyz=ctrl))
        xyz = georeference_adjusted(inp, cal.scanner, cal.strips, cal.strip_epoch_s, cal.strip_ids, rows=rows)
        r = m3c2(ref, xyz, core, params)
        ok = np.isfinite(r.distance_m) & (r.std1_m < 0.01) & (np.abs(r.normal[:, 2]) > 0.9)  # level faces: heights
        # the cloud's mean height offset on the held-out cells; its sigma: the strips' common height offset's
        sig = float(np.sqrt(np.mean(cal.strips_sigma[:, 2] ** 2)))
        out[name] = (float(np.mean(r.distance_m[ok] * np.sign(r.normal[ok, 2]))), sig, cal)
    d0, s0, _ = out["free"]
    d1, s1, cal = out["control"]
    assert abs(d1) < 3 * s1 and abs(d1) < 0.3 * abs(d0), (d0, s0, d1, s1)
    assert abs(d0) > 3 * s1  # without control the shift is far beyond the controlled precision (it can fail)
    z = cal.control.z
    assert len(z) >= 10 and abs(np.mean(z)) < 0.5 and 0.6 < np.std(z) < 1.4 and cal.control_rejected is None


def test_control_cloud_keeps_its_own_frame(tmp_path):
    """``read_control_cloud``: a points CSV's and a LAS file's points in the adjustment's local frame (against
    PROJ's own UTM -> ECEF), and the file's frame handed back as a frame (the strip command writes its cloud in it),
    not a description of it."""
    import laspy
    import pyproj

    from skyrig.georef.eo import WorldFrame
    from skyrig.pipeline.lidar import read_control_cloud

    e, n, h = np.array([500010.0, 500020.0, 500030.0]), np.array([5000005.0, 5000015.0, 5000025.0]), np.array([101.0, 102.5, 99.0])
    ecef = np.column_stack(pyproj.Transformer.from_crs("EPSG:32633", "EPSG:4978", always_xy=True).transform(e, n, h))
    local = WorldFrame.local(45.1, 15.0, 100.0)
    (tmp_path / "ctl.csv").write_text("# crs: EPSG:32633\nname,x,y,z\n" + "".join(
        f"c{i},{e[i]:.3f},{n[i]:.3f},{h[i]:.3f}\n" for i in range(3)))
    las = laspy.LasData(laspy.LasHeader(point_format=0, version="1.4"))
    las.header.add_crs(pyproj.CRS("EPSG:32633"))
    las.header.scales = [0.001] * 3
    las.header.offsets = [500000.0, 5000000.0, 0.0]
    las.x, las.y, las.z = e, n, h
    las.write(str(tmp_path / "ctl.las"))
    for name in ("ctl.csv", "ctl.las"):
        xyz, own = read_control_cloud(tmp_path / name, local)
        assert np.abs(local.to_ecef(xyz) - ecef).max() < 2e-3, name  # the LAS file's 1 mm scale
        assert own.kind == "map" and pyproj.CRS(own.crs).to_epsg() == 32633 and own.geoid is None, name
