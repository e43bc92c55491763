"""LiDAR strip adjustment (issue 34) on the simulated uav-bridge-lidar strip flight.

Independent answers: the injected values of the seeded simulation (every calibration parameter within 3 predicted
sigmas, the per-strip corrections within 4), the predicted noise of the strip-to-strip discrepancies, finite
differences of the residual functions, and the file/field named by every refused input.
The 20-seed statistics (normalised errors ~ N(0, 1)) and the 1-km flight are in bench/lidar_strips.py.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner
from numpy.typing import NDArray

from conftest import grazing_ground_beams
from skyrig.errors import InputFormatError
from skyrig.georef.eo import WorldFrame

from skyrig.lidar.georef import ScannerMount
from skyrig.lidar.scanner import RawScan, Scanner2D
from skyrig.lidar.strips import (
    CALIBRATION_NAMES, PatchOptions, PlanarPatches, StripModel, adjust_strips, find_planar_patches, patch_discrepancies,
    plane_residuals,
)
from skyrig.simulate.lidar import build_lidar_survey, lidar_scenario_spec, strip_truth_vector


def _model(err) -> StripModel:
    return StripModel(range_sigma_m=err.range_sigma_m, strip_position_sigma_m=err.strip_position_sigma_m,
                      strip_position_drift_sigma_mps=err.strip_position_drift_sigma_mps,
                      strip_attitude_sigma_rad=err.strip_attitude_sigma_rad,
                      strip_attitude_drift_sigma_radps=err.strip_attitude_drift_sigma_radps)


@pytest.fixture(scope="module")
def flight():
    """Four 22 m strips past a pillar (1 deg scanner steps: 0.2 million returns), TLS control, seed 3."""
    spec = replace(lidar_scenario_spec("strips-ci", 3), scanner=Scanner2D(step_deg=1.0), reference_density_per_m2=60.0,
                   reference_ground_density_per_m2=15.0)
    sv = build_lidar_survey(spec)
    model = _model(spec.errors)
    patches = find_planar_patches(sv.scan, sv.trajectory_recorded, sv.mount_recorded, sv.frame, control=sv.reference_xyz,
                                  options=PatchOptions(min_points_per_strip=12, max_points_per_strip=24))
    res = adjust_strips(patches, sv.mount_recorded, model=model)
    return sv, model, patches, res


def test_recovers_injected_errors_within_predicted_sigmas(flight):
    sv, model, patches, res = flight
    truth = strip_truth_vector(sv.injected, res.strip_epoch_s)
    z = (res.value - truth) / res.sigma
    assert res.held == ()
    assert np.all(np.abs(z[:len(CALIBRATION_NAMES)]) < 3.0), dict(zip(CALIBRATION_NAMES, np.round(z[:8], 2)))
    assert np.all(np.abs(z[len(CALIBRATION_NAMES):]) < 4.0)
    assert 0.85 < res.sigma0 < 1.15
    # the nominal values (no adjustment) would fail the same test: it can fail
    assert np.sum(np.abs(truth[:8]) > 3 * res.sigma[:8]) >= 6
    # the corrected mount is the recorded one with the estimates applied
    assert np.allclose(res.mount.lever_arm_m, sv.mount_recorded.lever_arm_m + res.calibration[3:6])


def test_strip_discrepancies_reduced_to_noise(flight):
    sv, model, patches, res = flight
    before = patch_discrepancies(patches, sv.mount_recorded, model)
    after = patch_discrepancies(patches, sv.mount_recorded, model, res)
    assert before["normalised_rms"] > 10.0
    assert after["normalised_rms"] < 1.5
    assert after["rms_m"] < 2.0 * after["noise_rms_m"]


def test_residual_jacobians_match_finite_differences(flight):
    sv, model, patches, res = flight
    rows = np.arange(0, len(patches), 97)
    k = patches.n_strips
    # at zero rotations the analytic Jacobians (perturbations of the rotations) equal the derivatives of the
    # parameters exactly; elsewhere they differ by O(angle), which only slows Gauss-Newton down
    cal, strips = res.calibration.copy(), res.strips.copy()
    cal[0:3] = 0.0
    strips[:, 6:12] = 0.0
    base = plane_residuals(patches, sv.mount_recorded, cal, strips, res.normal, res.offset, model, rows)
    h = 1e-7
    for j in range(len(CALIBRATION_NAMES)):
        c2 = cal.copy()
        c2[j] += h
        num = (plane_residuals(patches, sv.mount_recorded, c2, strips, res.normal, res.offset, model, rows)["r"]
               - base["r"]) / h
        assert np.allclose(num, base["J_cal"][:, j], rtol=1e-4, atol=1e-5 * np.abs(num).max())
    for j in range(12):
        s2 = strips.copy()
        s2[:, j] += h
        num = (plane_residuals(patches, sv.mount_recorded, cal, s2, res.normal, res.offset, model, rows)["r"]
               - base["r"]) / h
        assert np.allclose(num, base["J_strip"][:, j], rtol=1e-4, atol=1e-5 * np.abs(num).max() + 1e-9)
    assert k == 4


def test_undeterminable_parameter_is_held_and_said(flight):
    sv, model, patches, res = flight
    # a lever-arm prior of 1 mm: the strips cannot halve it -> held at the prior, in words
    tight = adjust_strips(patches, sv.mount_recorded, model=replace(model, lever_sigma_m=0.001))
    assert set(tight.held) >= {"lever_x", "lever_z"}
    v = next(v for v in tight.verdicts if v.name == "lever_z")
    assert v.held and "held at its prior" in v.words() and "lever arm" in v.words()
    i = CALIBRATION_NAMES.index("lever_z")
    assert tight.calibration[i] == 0.0 and tight.calibration_sigma[i] == 0.0


def test_bad_inputs_are_named(flight):
    sv, model, patches, res = flight
    no_strip = RawScan(sv.scan.time_s[:10], sv.scan.range_m[:10], sv.scan.alpha_rad[:10])
    with pytest.raises(InputFormatError, match="strip"):
        find_planar_patches(no_strip, sv.trajectory_recorded, sv.mount_recorded, sv.frame)
    with pytest.raises(InputFormatError, match="local tangent frame"):
        find_planar_patches(sv.scan, sv.trajectory_recorded, sv.mount_recorded, WorldFrame.ecef())
    with pytest.raises(InputFormatError, match="integers"):
        RawScan(np.zeros(2), np.ones(2), np.zeros(2), strip_id=np.array([0.0, 0.5]))


# ------------------------------------------------------------------------------------------ files and CLI
def _mini_project(tmp_path, sv, n=2000):
    from skyrig.io.raw_scan_csv import write_raw_scan_csv
    from skyrig.io.trajectory_csv import write_trajectory_csv

    write_raw_scan_csv(tmp_path / "scan.csv", sv.scan.subset(slice(0, n)))
    write_trajectory_csv(tmp_path / "traj.csv", sv.trajectory_recorded, crs="EPSG:4979")
    mount = {"format": "skyrig-scanner-mount", "version": 1, "body_from_scanner": sv.mount_recorded.body_from_scanner.tolist(),
             "lever_arm_m": sv.mount_recorded.lever_arm_m.tolist()}
    (tmp_path / "scanner.json").write_text(json.dumps(mount))
    return mount


def test_raw_scan_strip_column_round_trip(tmp_path, flight):
    from skyrig.io.raw_scan_csv import read_raw_scan_csv

    sv = flight[0]
    _mini_project(tmp_path, sv, 500)
    back, _ = read_raw_scan_csv(tmp_path / "scan.csv")
    assert np.array_equal(back.strip_id, sv.scan.strip_id[:500])
    text = (tmp_path / "scan.csv").read_text().splitlines()
    text[5] = text[5].rsplit(",", 1)[0] + ",1.5"
    (tmp_path / "bad.csv").write_text("\n".join(text) + "\n")
    with pytest.raises(InputFormatError, match=r"bad\.csv.*line 6.*strip|strip.*line 6"):
        read_raw_scan_csv(tmp_path / "bad.csv")


def test_cli_refuses_bad_scanner_and_times(tmp_path, flight):
    from skyrig.cli.lidar import command as lidar

    sv = flight[0]
    mount = _mini_project(tmp_path, sv)
    base = ["strips", "--scan", str(tmp_path / "scan.csv"), "--trajectory", str(tmp_path / "traj.csv"),
            "-o", str(tmp_path / "rig.yaml")]
    # a left-handed scanner frame
    left = dict(mount, body_from_scanner=(np.array(mount["body_from_scanner"]) * [[1], [1], [-1]]).tolist())
    (tmp_path / "left.json").write_text(json.dumps(left))
    r = CliRunner().invoke(lidar, [*base, "--mount", str(tmp_path / "left.json")])
    assert r.exit_code != 0 and "left-handed" in str(r.exception) and "left.json" in str(r.exception)
    assert "body_from_scanner" in str(r.exception)
    # a lever arm in millimetres
    mm = dict(mount, lever_arm_m=[100.0, -20.0, 150.0])
    (tmp_path / "mm.json").write_text(json.dumps(mm))
    r = CliRunner().invoke(lidar, [*base, "--mount", str(tmp_path / "mm.json")])
    assert r.exit_code != 0 and "millimetres" in str(r.exception) and "lever_arm_m" in str(r.exception)
    # laser times outside the trajectory: the file, the line and the field
    lines = (tmp_path / "scan.csv").read_text().splitlines()
    f = lines[4 + 1000].split(",")
    f[0] = "%.6f" % (sv.trajectory_recorded.span[1] + 5.0)
    tail = [ln.split(",") for ln in lines[4 + 1001:]]
    for t in tail:
        t[0] = "%.6f" % (sv.trajectory_recorded.span[1] + 6.0)
    (tmp_path / "late.csv").write_text("\n".join(lines[:4 + 1000] + [",".join(f)] + [",".join(t) for t in tail]) + "\n")
    r = CliRunner().invoke(lidar, [*base[:2], str(tmp_path / "late.csv"), *base[3:], "--mount", str(tmp_path / "scanner.json")])
    msg = str(r.exception)
    assert r.exit_code != 0 and "late.csv" in msg and "line 1005" in msg and "outside the trajectory" in msg


def test_scanner_record_in_rig_file(tmp_path, flight):
    from skyrig.io.rig_file import read_rig
    from skyrig.io.scanner_record import read_rig_scanners, read_scanner_mount, write_scanner_record

    sv, model, patches, res = flight
    rec = {"name": "lidar", "body_from_scanner": res.mount.body_from_scanner.tolist(),
           "lever_arm_m": res.mount.lever_arm_m.tolist(), "range_offset_m": float(res.calibration[6]),
           "calibration": {"held": [], "provenance": {"recipe": "test"}}}
    write_scanner_record(tmp_path / "rig.yaml", rec)
    mount, extra = read_scanner_mount(tmp_path / "rig.yaml")
    assert np.allclose(mount.body_from_scanner, res.mount.body_from_scanner)
    assert extra["range_offset_m"] == pytest.approx(res.calibration[6])
    with pytest.raises(InputFormatError, match="laser scanners only"):
        read_rig(tmp_path / "rig.yaml")
    text = (tmp_path / "rig.yaml").read_text().replace("range_offset_m:", "range_ofset_m:")
    (tmp_path / "typo.yaml").write_text(text)
    with pytest.raises(InputFormatError, match=r"typo\.yaml.*line \d+.*range_ofset_m"):
        read_rig_scanners(tmp_path / "typo.yaml")


@pytest.mark.parametrize("roughness_in_data", [False, True])
def test_adjusted_jacobians_uncorrelated_with_residuals_at_grazing_beams(roughness_in_data):
    """At the true parameters the rows linearised at the adjusted observations must be uncorrelated with the
    residuals (else least squares is biased: errors-in-variables).  Ground points seen from 5 m at 10-80 deg
    depression, range noise 2 cm, a model with the 2 mm roughness floor; the data's roughness either absent or
    where a rough surface puts it (along the beam).  The statistic sum(J r / s^2) over its own spread is N(0, 1)
    when unbiased (the plane's offset column projected out): range scale -0.3 / -0.2 here; with the roughness's share
    along the normal (the range left as measured) -57 / -55; the recorded-point Jacobians -82."""
    m, h, sr, rough = 20000, 5.0, 0.02, 0.002
    rho, u = grazing_ground_beams(roughness_in_data, m, h, sr, rough)
    patches = PlanarPatches(
        WorldFrame.local(45.0, 7.0, 0.0), np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]), np.zeros(m, np.intp),
        np.zeros(m, np.intp), np.zeros(m), rho, u, np.column_stack([-u[:, 1], u[:, 0], np.zeros(m)]),
        np.tile([0.0, 0.0, h], (m, 1)), np.broadcast_to(np.eye(3), (m, 3, 3)), np.zeros(1), np.zeros(1, np.int64),
        np.zeros(1), np.zeros((1, 3)), np.zeros((1, 3, 3)))
    mount = ScannerMount(np.eye(3))
    model = StripModel(range_sigma_m=sr, roughness_m=rough)

    def stat(linearise: str) -> NDArray:
        res = plane_residuals(patches, mount, np.zeros(8), np.zeros((1, 12)), patches.normal, np.zeros(1), model,
                              linearise=linearise)
        w = 1.0 / res["sigma"] ** 2
        j = np.column_stack([res["J_cal"], res["J_plane"][:, :2]])
        j = j - (w @ j) / w.sum()  # the plane's offset column projected out (its reduced rows)
        g = j * (res["r"] * w)[:, None]
        return g.sum(axis=0) / np.sqrt((g**2).sum(axis=0))

    z = stat("adjusted")
    assert np.all(np.abs(z[[6, 7, 8, 9]]) < 4.0), np.round(z, 1)  # range offset, range scale, plane tilts
    assert abs(stat("observed")[7]) > 20.0  # the recorded-point rows: the bias this test can see
