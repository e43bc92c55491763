"""Flight planning against the papers' figures and independent geometry."""

from __future__ import annotations

import numpy as np
import pytest

from skyrig.camera.frame import footprint_on_plane
from skyrig.geometry.pose import Pose
from skyrig.plan import coverage_map, footprints, gsd_per_head, overlap_stats, plan_flight, tumble_schedule
from skyrig.rig.presets import dlr_3k, macs_tumblecam, midas

SQUARE = [[0, 0], [3000, 0], [3000, 3000], [0, 3000]]


def test_3k_swath_and_gsd_match_paper_001():
    # paper 001: at 1000 m above ground 15 cm pixels, the three images cover up to 2.8 km across, FOV max 110 deg
    rig = dlr_3k()
    plan = plan_flight(rig, SQUARE, flying_height_m=1000.0)
    xs = np.concatenate([footprints(plan, rig, h)[0][:, 0] for h in rig.head_names])
    swath = np.ptp(xs)
    assert 2750 < swath < 2900
    half_fov = np.degrees(np.arctan(np.max(np.abs(xs - plan.position[0, 0])) / 1000.0))
    assert 2 * half_fov == pytest.approx(110.0, abs=1.5)
    assert gsd_per_head(plan, rig, "nadir").centre_m[0] == pytest.approx(0.15, abs=0.01)


def test_overlaps_measured_on_footprint_polygons_equal_the_requested_ones():
    rig = midas()
    plan = plan_flight(rig, SQUARE, flying_height_m=600.0, forward_overlap=0.8, side_overlap=0.6, direction_deg=30.0)
    s = overlap_stats(plan, footprints(plan, rig, "nadir"), "nadir").summary()
    assert s["forward_min"] == pytest.approx(0.8, abs=1e-6)
    assert s["side_mean"] == pytest.approx(0.6, abs=1e-6)
    # strips alternate direction and stations are spaced by the speed
    assert np.degrees(plan.track_rad[plan.strip == 0][0]) == pytest.approx(30.0)
    assert np.degrees(plan.track_rad[plan.strip == 1][0]) == pytest.approx(210.0)
    st0 = plan.strip == 0
    np.testing.assert_allclose(np.diff(plan.time_s[st0]), plan.base_m / plan.speed_mps)


def test_gsd_target_gives_flying_height():
    rig = macs_tumblecam()
    plan = plan_flight(rig, [[0, 0], [300, 0], [300, 100], [0, 100]], gsd_m=0.03, frame_rate_hz=1.0, speed_mps=30)
    # paper 000: ~200 m above ground for ~3 cm GSD with 5.5 um / 35 mm
    assert plan.flying_height_m == pytest.approx(0.03 * 35.0 / 0.0055)
    assert 180 < plan.flying_height_m < 210


def test_tumblecam_spiral_without_rotation_about_the_optical_axis():
    rig = macs_tumblecam()
    crab = -10.0
    plan = plan_flight(rig, [[0, -10], [400, -10], [400, 10], [0, 10]], flying_height_m=200.0, direction_deg=90.0,
                       speed_mps=30.0, frame_rate_hz=1.0, rotation_speed_deg_s=45.0, crab_deg=crab, n_strips=1)
    b = np.degrees(plan.beta_rad)
    np.testing.assert_allclose(np.diff(b), 45.0)  # gear steps of 45 deg (paper 000 Fig. 5)
    np.testing.assert_allclose(b[0], crab)  # zero point compensates the crab angle
    poses = plan.camera_poses(rig, "oblique")
    cam = rig.head("oblique").camera
    track = plan.track_rad[0]
    for i in range(8):
        pose = Pose(poses.rotation[i], poses.translation[i], "world", "c")
        # image x axis projected on the ground keeps the heading for every beta: no rotation about the axis
        x_axis = pose.rotation[:, 0]
        az = np.arctan2(x_axis[0], x_axis[1])
        assert np.degrees(np.angle(np.exp(1j * (az - plan.heading_rad[i])))) == pytest.approx(0.0, abs=1e-9)
        # the footprint centre lies at H tan(gamma) in the direction beta_nominal from the track (left of it)
        c = footprint_on_plane(cam, pose, 0.0, pixels=np.array([[(cam.width - 1) / 2, (cam.height - 1) / 2]]))[0]
        off = c[:2] - plan.position[i, :2]
        az_view = np.arctan2(off[0], off[1])
        beta_nom = np.radians(b[i] - crab)
        expected = track - beta_nom
        # eqs 1-2 of paper 000 are a small-angle law: the view azimuth is exact only at beta = k 90 deg and
        # up to ~2 deg off in between (here beta = k 45 deg - 10 deg)
        tol = 3.0
        assert np.degrees(np.angle(np.exp(1j * (az_view - expected)))) == pytest.approx(0.0, abs=tol)
        assert np.hypot(*off) == pytest.approx(200.0 * np.tan(np.radians(30.0)), rel=3e-2)


def test_coverage_map_counts_footprints():
    rig = midas()
    plan = plan_flight(rig, SQUARE, flying_height_m=600.0, forward_overlap=0.6, side_overlap=0.3)
    fp = footprints(plan, rig, "nadir")
    cov = coverage_map([fp], (500, 500, 2500, 2500), 50.0)
    # inside the block every point is seen at least twice along track (60 %) and most cells 2-6 times
    assert cov.count.min() >= 2
    assert cov.count.max() <= 6


def test_tumble_schedule_rejects_zero_rate():
    from skyrig.errors import SkyrigError

    with pytest.raises(SkyrigError):
        tumble_schedule(3, 0.0, 45.0)
