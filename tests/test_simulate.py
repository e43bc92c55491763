"""Simulator: truth reproduced by direct georeferencing, injected errors recovered, targets, SIFT, determinism."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skyrig.camera.frame import footprint_on_surface
from skyrig.georef.direct import inverse_georeference
from skyrig.georef.eo import WorldFrame
from skyrig.geometry.pose import Pose
from skyrig.geometry.rotations import rpy_from_matrix
from skyrig.plan import footprints
from skyrig.rig.rig import oblique_mounting
from skyrig.simulate.errors import SensorErrors
from skyrig.simulate.render import TERRAIN, ray_hits_at_pixels, render_image
from skyrig.simulate.scenarios import build_survey, georeference_recorded, scenario_spec
from skyrig.simulate.world import make_scene


@pytest.fixture(scope="module")
def midas_survey():
    return build_survey(scenario_spec("midas", "ci", 3))


@pytest.mark.parametrize("name", ["tumblecam", "midas", "3k", "southeast"])
def test_direct_georeferencing_of_truth_reproduces_true_orientations(name):
    s = build_survey(scenario_spec(name, "ci", 1))
    eo = georeference_recorded(s, true_data=True)
    scale = max(1.0, float(np.max(np.abs(s.eo_true.centre))))
    assert np.max(np.linalg.norm(eo.centre - s.eo_true.centre, axis=1)) < 1e-10 * scale + 1e-6
    assert np.max(np.abs(eo.rotation - s.eo_true.rotation)) < 1e-12


def test_injected_gnss_errors_equal_the_centre_deviations():
    spec = scenario_spec("midas", "ci", 5)
    err = SensorErrors(gnss_noise_m=(0.05, 0.04, 0.08), gnss_bias_m=(0.3, -0.2, 0.5), gnss_strip_shift_sigma_m=0.4,
                       gnss_drift_mps=(0.01, 0.0, -0.02), datum_shift_m=(7.248, 1.714, 0.984))
    s = build_survey(replace(spec, errors=err))
    eo = georeference_recorded(s, rig=s.rig_true)  # recorded trajectory, true rig
    # injected error at the event times (the stations are trajectory samples)
    k = np.searchsorted(s.trajectory_true.time_s, s.events_true.time_s)
    # the IMU attitude is recorded in the NED frame of the (shifted) recorded position, so the ECEF attitude
    # turns with the NED frame, by at most |shift| / (R_earth cos lat) (~2e-6 rad for 8 m at 52 deg N), moving
    # the 1.3 m lever arm by ~3 um: the bound
    shift = np.linalg.norm(s.gnss_error_m[k], axis=1).max()
    tilt = shift / (6.37e6 * np.cos(np.radians(s.spec.origin[0])))
    np.testing.assert_allclose(eo.centre - s.eo_true.centre, s.gnss_error_m[k], atol=1.5 * tilt * 1.4 + 1e-9)
    np.testing.assert_allclose(eo.rotation, s.eo_true.rotation, atol=1.5 * tilt)


def test_injected_boresight_and_antenna_offset_are_recovered(midas_survey):
    # southeast: Tab. 4 boresight (roll, pitch, yaw in gon) and an unknown antenna offset
    s = build_survey(replace(scenario_spec("southeast", "ci", 2), errors=replace(
        scenario_spec("southeast").errors, gnss_noise_m=(0, 0, 0), imu_noise_rad=(0, 0, 0), datum_shift_m=(0, 0, 0))))
    rec = georeference_recorded(s, rig=s.rig_recorded)
    # platform attitude implied by the true images through the recorded (nominal) rig vs the recorded IMU attitude
    a = inverse_georeference(s.eo_true.to_frame(WorldFrame.ecef()), s.rig_recorded)
    b = inverse_georeference(rec.to_frame(WorldFrame.ecef()), s.rig_recorded)
    rel = np.swapaxes(b.ecef_from_body, -1, -2) @ a.ecef_from_body  # body_rec_from_body_implied
    r, p, y = rpy_from_matrix(rel, unit="rad")
    inj = np.array(s.spec.errors.boresight_rpy_rad["camera"])
    np.testing.assert_allclose(np.column_stack([r, p, y]), np.tile(inj, (len(r), 1)), atol=1e-9)
    # the unrecorded antenna offset moves the IMU origin by R_body @ offset in every image
    d = b.imu_ecef - a.imu_ecef
    off = np.einsum("nji,nj->ni", b.ecef_from_body, d)  # in the body frame
    np.testing.assert_allclose(off, np.tile(np.array(s.spec.errors.antenna_lever_error_m), (len(off), 1)), atol=1e-3)


def test_injected_imu_bias_alone_is_the_attitude_deviation():
    bias = np.array([1e-3, -2e-3, 3e-3])  # roll, pitch, yaw (rad)
    s = build_survey(replace(scenario_spec("midas", "ci", 6), errors=SensorErrors(imu_bias_rad=tuple(bias))))
    # the trajectory file's attitudes: recorded minus true roll, pitch, yaw = the bias at every sample
    rt, pt, yt = s.trajectory_true.rpy("rad")
    rr, pr, yr = s.trajectory_recorded.rpy("rad")
    d = np.column_stack([rr - rt, pr - pt, np.angle(np.exp(1j * (yr - yt)))])
    np.testing.assert_allclose(d, np.tile(bias, (len(d), 1)), atol=1e-12)
    np.testing.assert_array_equal(s.trajectory_recorded.ecef, s.trajectory_true.ecef)  # positions untouched
    # through direct georeferencing with the true rig: the implied IMU attitude differs by the bias only
    rec = georeference_recorded(s, rig=s.rig_true)
    a = inverse_georeference(s.eo_true.to_frame(WorldFrame.ecef()), s.rig_true)
    b = inverse_georeference(rec.to_frame(WorldFrame.ecef()), s.rig_true)
    from skyrig.trajectory.trajectory import ecef_from_ned_rotation
    from skyrig.geodesy.crs import ecef_to_geodetic

    lat, lon, _ = ecef_to_geodetic(a.imu_ecef)
    ned = np.swapaxes(ecef_from_ned_rotation(lat, lon), -1, -2)
    ra, pa, ya = rpy_from_matrix(ned @ a.ecef_from_body, unit="rad")
    rb, pb, yb = rpy_from_matrix(ned @ b.ecef_from_body, unit="rad")
    d = np.column_stack([rb - ra, pb - pa, np.angle(np.exp(1j * (yb - ya)))])
    np.testing.assert_allclose(d, np.tile(bias, (len(d), 1)), atol=1e-9)
    np.testing.assert_allclose(b.imu_ecef, a.imu_ecef, atol=1e-6)  # the antenna lever arm turns by ~3 mrad


def test_injected_focal_change_alone_scales_the_image_measurements():
    spec = scenario_spec("midas", "ci", 6)
    df = 0.05  # mm, true minus recorded principal distance of the nadir head
    s = build_survey(replace(spec, errors=SensorErrors(focal_change_mm={"nadir": df})))
    # the orientations are untouched: the recorded data georeference to the true EO (recorded rig = nominal)
    eo = georeference_recorded(s, rig=s.rig_recorded)
    np.testing.assert_allclose(eo.centre, s.eo_true.centre, atol=1e-6)
    np.testing.assert_allclose(eo.rotation, s.eo_true.rotation, atol=1e-12)
    m = s.measurements
    nominal = s.rig_recorded.head("nadir").camera
    f_true = s.rig_true.head("nadir").camera.focal_mm
    assert f_true == pytest.approx(nominal.focal_mm + df)
    idx = s.eo_true.index()
    pts = dict(zip(s.gcp_names, s.gcp_local))
    rows = [i for i, im in enumerate(m["image"]) if str(s.eo_true.head[idx[im]]) == "nadir"]
    assert len(rows) >= 3
    for i in rows:
        k = idx[m["image"][i]]
        pose = Pose(s.eo_true.rotation[k], s.eo_true.centre[k], "world", "camera")
        x_nom = nominal.pixel_to_image(nominal.world_to_pixel(pose, pts[m["point"][i]][None])) - [nominal.ppx_mm, nominal.ppy_mm]
        x_true = nominal.pixel_to_image(m["pixel_true"][i][None]) - [nominal.ppx_mm, nominal.ppy_mm]
        # central projection: image coordinates scale with the principal distance (no distortion in CI midas)
        np.testing.assert_allclose(x_true, x_nom * f_true / nominal.focal_mm, atol=1e-9)


def test_tie_points_with_false_matches(tmp_path):
    from skyrig.io.points_csv import read_measurements_csv
    from skyrig.io.truth import read_truth
    from skyrig.pipeline.simulate import write_project

    err = SensorErrors(tie_points=80, wrong_tie_points=6, measurement_sigma_px=0.5)
    s = build_survey(replace(scenario_spec("midas", "ci", 4), errors=err))
    tie = s.tie_points
    assert len(tie["name"]) > 20 and tie["wrong"].sum() == 6
    # every point is seen at least twice
    _, counts = np.unique(tie["point"], return_counts=True)
    assert counts.min() >= 2
    # independent check of the true positions: the ray back through the pixel hits the surface at the point
    idx = s.eo_true.index()
    xyz = dict(zip(tie["name"], tie["xyz"]))
    for i in range(0, len(tie["point"]), 7):
        k = idx[tie["image"][i]]
        cam = s.rig_true.head(str(s.eo_true.head[k])).camera
        hit = ray_hits_at_pixels(s.scene, cam, Pose(s.eo_true.rotation[k], s.eo_true.centre[k], "world", "camera"),
                                 tie["pixel_true"][i][None])
        np.testing.assert_allclose(hit.xyz[0], xyz[tie["point"][i]], atol=1e-4)
    # noise of the right size on the good observations, false matches far off
    res = np.linalg.norm(tie["pixel"] - tie["pixel_true"], axis=1)
    good = ~tie["wrong"]
    assert 0.5 * 0.85 < np.sqrt(np.mean(res[good] ** 2) / 2) < 0.5 * 1.15
    assert np.all(res[tie["wrong"]] > 3.0)
    # the project holds them, and the truth file names the false matches
    write_project(s, tmp_path, workers=1, images=False)
    obs = read_measurements_csv(tmp_path / "tie" / "image_measurements.csv")
    np.testing.assert_allclose(obs.pixel, tie["pixel"], atol=1e-3)
    t = read_truth(tmp_path / "truth" / "truth.json")
    assert t["injected"]["wrong_tie_measurements"] == np.nonzero(tie["wrong"])[0].tolist()
    assert SensorErrors.from_dict(t["errors"]) == err


def test_scenarios_are_deterministic():
    a = build_survey(scenario_spec("tumblecam", "ci", 7))
    b = build_survey(scenario_spec("tumblecam", "ci", 7))
    c = build_survey(scenario_spec("tumblecam", "ci", 8))
    np.testing.assert_array_equal(a.eo_true.centre, b.eo_true.centre)
    np.testing.assert_array_equal(a.measurements["pixel"], b.measurements["pixel"])
    np.testing.assert_array_equal(a.gcp_surveyed, b.gcp_surveyed)
    assert not np.array_equal(a.measurements["pixel"], c.measurements["pixel"]) or not np.array_equal(
        a.gcp_local, c.gcp_local)
    k = 1
    cam = a.rig_true.head(str(a.eo_true.head[k])).camera.with_(width=160, height=120,
                                                                 pixel_size_mm=a.rig_true.head(str(a.eo_true.head[k])).camera.pixel_size_mm * 4)
    pose = Pose(a.eo_true.rotation[k], a.eo_true.centre[k], "world", "camera")
    np.testing.assert_array_equal(render_image(a.scene, cam, pose, 1.0, 3), render_image(b.scene, cam, pose, 1.0, 3))


def _centroid(img: np.ndarray, c: np.ndarray, half: float) -> np.ndarray:
    g = img.astype(np.float64).mean(axis=2)
    c0, r0 = int(np.floor(c[0] - half)), int(np.floor(c[1] - half))
    c1, r1 = int(np.ceil(c[0] + half)), int(np.ceil(c[1] + half))
    win = g[r0:r1 + 1, c0:c1 + 1]
    w = win - win.min()  # above the black square's level
    rr, cc = np.mgrid[r0:r1 + 1, c0:c1 + 1]
    return np.array([(w * cc).sum() / w.sum(), (w * rr).sum() / w.sum()])


def test_gcp_targets_render_at_their_projected_centres(midas_survey):
    s = midas_survey
    m = s.measurements
    nadir = [i for i, im in enumerate(s.eo_true.image) if "nadir" in im and np.any(m["image"] == im)]
    errs = []
    for k in nadir[:2]:
        cam = s.rig_true.head("nadir").camera
        img = render_image(s.scene, cam, Pose(s.eo_true.rotation[k], s.eo_true.centre[k], "world", "c"))
        sel = m["image"] == s.eo_true.image[k]
        for p in m["pixel_true"][sel]:
            dist = np.linalg.norm(s.gcp_local[0] - s.eo_true.centre[k])
            r_px = s.scene.targets.radius_m / float(cam.gsd(dist))
            errs.append(_centroid(img, p, 1.8 * r_px) - p)
    errs = np.array(errs)
    assert len(errs) >= 3
    assert np.max(np.linalg.norm(errs, axis=1)) < 0.1


def test_planned_footprints_equal_the_rendered_image_corners(midas_survey):
    s = midas_survey
    for head in ("nadir", "forward"):
        fp = footprints(s.plan, s.rig_true, head, s.scene.terrain_height)
        poses = s.plan.camera_poses(s.rig_true, head)
        cam = s.rig_true.head(head).camera
        rows = np.nonzero(s.eo_true.head == head)[0]
        for i in range(2):
            # the flown plan's pose is the true EO of that image
            np.testing.assert_allclose(poses.translation[i], s.eo_true.centre[rows[i]], atol=1e-9)
            hits = ray_hits_at_pixels(s.scene, cam, Pose(s.eo_true.rotation[rows[i]], s.eo_true.centre[rows[i]], "w", "c"),
                                      cam.corner_pixels())
            ok = hits.kind == TERRAIN  # corners that see a roof differ from the terrain footprint by design
            assert ok.sum() >= 2
            np.testing.assert_allclose(hits.xyz[ok], fp[i][ok], atol=2e-3)


def test_two_heads_match_with_sift():
    cv2 = pytest.importorskip("cv2")
    from skyrig.rig.presets import midas
    from skyrig.simulate.scenarios import ci_camera

    rig = midas()
    scene = make_scene(11, (-400, -400, 400, 400), base_height_m=50.0, texture_fine_m=0.12, n_buildings=15,
                       town=(-100, -100, 100, 100))
    H = 150.0
    enu_from_body = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]])  # heading north
    cam_n = ci_camera(rig.head("nadir").camera, 800)
    cam_f = ci_camera(rig.head("forward").camera, 800)
    pn = Pose(enu_from_body @ rig.head("nadir").mounting, np.array([0, 0, 50 + H]), "w", "c")
    pf = Pose(enu_from_body @ rig.head("forward").mounting, np.array([0, -H, 50 + H]), "w", "c")
    img_n, hits_n = render_image(scene, cam_n, pn, 1.0, 1, return_hits=True)
    img_f = render_image(scene, cam_f, pf, 1.0, 2)
    sift = cv2.SIFT_create(4000)
    kn, dn = sift.detectAndCompute(cv2.cvtColor(img_n, cv2.COLOR_RGB2GRAY), None)
    kf, df = sift.detectAndCompute(cv2.cvtColor(img_f, cv2.COLOR_RGB2GRAY), None)
    pairs = cv2.BFMatcher().knnMatch(dn, df, k=2)
    good = [a for a, b in pairs if a.distance < 0.75 * b.distance]
    pn_px = np.array([kn[g.queryIdx].pt for g in good])
    pf_px = np.array([kf[g.trainIdx].pt for g in good])
    # the true geometry: nadir keypoint -> scene point (ray casting) -> forward image (projection)
    hits = ray_hits_at_pixels(scene, cam_n, pn, pn_px)
    pred = cam_f.world_to_pixel(pf, hits.xyz)
    err = np.linalg.norm(pred - pf_px, axis=1)
    correct = err < 2.0
    assert correct.sum() >= 30, (len(good), correct.sum())
    assert correct.mean() > 0.5
