"""The simulated ``uav-bridge-camera`` project (paper 002's camera flight along the bridge).

Independent answers: the bridge's box geometry projected with a pinhole + Brown formula written here
(not skyrig's camera code), so the rendered edges must fall where the collinearity equations and the
pixel convention of docs/frames.md put them (to 0.02 px); normalised cross-correlation between
neighbouring images at the true correspondences (the texture is matchable and the same object texture in
every view); the injected orientation errors against their stated sigmas; files read back with skyrig's
readers and converted between frames through PROJ.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from skyrig.errors import SkyrigError
from skyrig.geometry.pose import Pose
from skyrig.simulate.bridge_camera import (
    BridgeLook, bridge_camera_spec, build_bridge_camera_survey, gt3300c_camera, render_bridge_image,
)
from skyrig.simulate.lidar import GROUND, NO_HIT

# the CI scenario cut to one row of 5 exposures past the pillar at u = 13.5 m, with a sparse reference
SMALL = replace(bridge_camera_spec("ci", 5), u_range_m=(18.9, 8.1), altitudes_m=(4.0,),
                reference_density_per_m2=20.0, reference_ground_density_per_m2=5.0)


@pytest.fixture(scope="module")
def survey():
    return build_bridge_camera_survey(SMALL)


@pytest.fixture(scope="module")
def rendered(survey):
    """Images 2 and 3 (neighbours; image 2 looks straight at the pillar) with their hits."""
    return {k: survey.render(k, return_hits=True) for k in (2, 3)}


# ----------------------------------------------------------------------------- independent projection
def brown_delta(x, y, c):
    """The Brown / Australis correction at OBSERVED image coordinates (mm, from the principal point)."""
    r2 = x * x + y * y
    radial = c["k1"] * r2 + c["k2"] * r2**2 + c["k3"] * r2**3
    dx = x * radial + c["p1"] * (r2 + 2 * x * x) + 2 * c["p2"] * x * y + c["b1"] * x + c["b2"] * y
    dy = y * radial + c["p2"] * (r2 + 2 * y * y) + 2 * c["p1"] * x * y
    return dx, dy


def project(cam, rotation, centre, xyz):
    """World points (N, 3) -> pixels (N, 2): x_ideal = -f X/Z, y_ideal = -f Y/Z in the camera frame (x right,
    y up, looking along -z); observed = ideal - delta(observed) by fixed-point iteration; pixel column right,
    row down, (0, 0) the centre of the top-left pixel."""
    p = (np.asarray(xyz, float) - centre) @ rotation
    assert np.all(p[:, 2] < 0)
    xi, yi = -cam.focal_mm * p[:, 0] / p[:, 2], -cam.focal_mm * p[:, 1] / p[:, 2]
    coef = {k: getattr(cam.distortion, k) for k in ("k1", "k2", "k3", "p1", "p2", "b1", "b2")}
    x, y = xi.copy(), yi.copy()
    for _ in range(60):
        dx, dy = brown_delta(x, y, coef)
        x, y = xi - dx, yi - dy
    col = (x + cam.ppx_mm) / cam.pixel_size_mm + (cam.width - 1) / 2
    row = -(y + cam.ppy_mm) / cam.pixel_size_mm + (cam.height - 1) / 2
    return np.column_stack([col, row])


def bridge_point(scene, u, v, z):
    """Bridge frame (u along the axis, v across to the left, z up) -> local ENU."""
    return np.column_stack(np.broadcast_arrays(u, v, z)).astype(float) @ scene.local_from_bridge.T


def test_skyrig_projection_agrees_with_the_independent_formula(survey):
    rng = np.random.default_rng(0)
    for k in range(len(survey.eo_true)):
        r, c = survey.eo_true.rotation[k], survey.eo_true.centre[k]
        pts = c + rng.uniform(-8, 8, (50, 3)) - 15.0 * r[:, 2]  # in front of the camera
        ours = project(survey.camera, r, c, pts)
        theirs = survey.camera.world_to_pixel(Pose(r, c, "world", "camera"), pts)
        assert np.max(np.abs(ours - theirs)) < 1e-6


def test_camera_flight_and_paper_figures(survey):
    cam = gt3300c_camera()
    assert (cam.width, cam.height, cam.pixel_size_mm) == (3296, 2472, 0.0055)  # paper 002, section 2.3
    ci = bridge_camera_spec("ci").camera
    assert (ci.width, ci.height) == (824, 618) and ci.sensor_size_mm == pytest.approx(cam.sensor_size_mm)
    assert bridge_camera_spec("full").camera.width == 3296
    f = survey.flight
    assert f["forward_overlap_on_deck_side"] >= 0.8  # paper 002: at least 80 % forward overlap
    assert len(survey.eo_true) == 5 and f["base_m"] == pytest.approx(2.7)
    # GSD on the deck side = depth x pixel / focal (15 m / cos 6 deg; 22 um; 20.12 mm)
    assert f["gsd_on_deck_side_m"] == pytest.approx(15.0 / np.cos(np.radians(6.0)) * 0.022 / 20.12)
    # the projection centres: 15 m from the deck side (v = -21 m), 4 m above the ground, within the jitter
    uvz = survey.eo_true.centre @ survey.scene.local_from_bridge
    assert np.all(np.abs(uvz[:, 1] + 21.0) < 0.5) and np.all(np.abs(uvz[:, 2] - 4.0) < 0.4)
    # upright images looking at the bridge: camera y (image up) points up, the view (-z) goes to +v and down
    view = -(survey.scene.local_from_bridge.T @ survey.eo_true.rotation[:, :, 2].T).T
    assert np.all(view[:, 1] > 0.98) and np.all(survey.eo_true.rotation[:, 2, 1] > 0.98)
    with pytest.raises(SkyrigError):
        bridge_camera_spec("huge")
    with pytest.raises(SkyrigError):
        build_bridge_camera_survey(replace(SMALL, forward_overlap=1.0))


def test_rendered_edges_at_projected_box_edges(survey, rendered):
    """The deck's lower south edge (a horizontal line) and the pillar's vertical edges, projected with the
    independent formula: every pixel centre more than 0.02 px on one side sees the right face."""
    img, hits = rendered[2]
    cam, sc = survey.camera, survey.scene
    r, c = survey.eo_true.rotation[2], survey.eo_true.centre[2]
    deck = next(i for i, b in enumerate(sc.boxes) if b.name == "deck")
    pillar = next(i for i, b in enumerate(sc.boxes) if b.name == "pillar_3")
    south = sc.local_from_bridge @ np.array([0.0, -1.0, 0.0])
    tol = 0.02
    # -- the deck's lower south edge (u, -6, 6), away from the pillar (which hides it at 12.1 < u < 14.9)
    u = np.arange(2.0, 25.0, 0.002)
    px = project(cam, r, c, bridge_point(sc, u, -6.0, 6.0))
    cols = np.arange(int(np.ceil(px[:, 0].min())), int(px[:, 0].max()))
    cols = cols[(cols >= 0) & (cols < cam.width)]
    u_at = np.interp(cols, px[:, 0], u)
    cols = cols[np.abs(u_at - 13.5) > 3.0]
    r_edge = np.interp(cols, px[:, 0], px[:, 1])
    cols, r_edge = cols[(r_edge > 2) & (r_edge < cam.height - 3)], r_edge[(r_edge > 2) & (r_edge < cam.height - 3)]
    assert len(cols) > 400
    above = np.floor(r_edge - tol).astype(int)
    below = np.ceil(r_edge + tol).astype(int)
    n_above = hits.normal[above, cols]
    assert np.all(hits.component[above, cols] == deck) and np.all(n_above @ south > 0.999)  # deck side face
    assert np.all(hits.normal[below, cols] @ south < 0.5)  # the underside (camera below it) or beyond
    # the image itself: the sunlit side face is much brighter than the underside in the shade
    grey = img.astype(float).mean(axis=2)
    assert np.mean(grey[above - 1, cols] - grey[below + 1, cols]) > 40.0
    # -- the pillar's vertical edges on its south end face (u = 13.5 -+ 0.7, v = -7.05, 1 m < z < 5 m)
    z = np.arange(1.0, 5.0, 0.001)
    for side, du in ((-1, -0.7), (+1, 0.7)):
        q = project(cam, r, c, bridge_point(sc, 13.5 + du, -7.05, z))
        rows = np.arange(int(np.ceil(q[:, 1].min())), int(q[:, 1].max()))
        order = np.argsort(q[:, 1])
        c_edge = np.interp(rows, q[order, 1], q[order, 0])
        inside = (np.ceil(c_edge + tol) if side < 0 else np.floor(c_edge - tol)).astype(int)
        outside = (np.floor(c_edge - tol) if side < 0 else np.ceil(c_edge + tol)).astype(int)
        assert len(rows) > 150
        assert np.all(hits.component[rows, inside] == pillar)
        assert np.all(hits.component[rows, outside] != pillar)
    # -- a corner: the pillar's south-west foot on the ground
    cx, cy = project(cam, r, c, bridge_point(sc, 12.8, -7.05, 0.0))[0]
    assert hits.component[int(round(cy - 1.5)), int(round(cx + 1.5))] == pillar
    assert hits.component[int(round(cy + 1.5)), int(round(cx - 1.5))] == GROUND


def test_texture_contrast_and_matchability(survey, rendered):
    from scipy.ndimage import uniform_filter

    img, hits = rendered[2]
    g = img.astype(float).mean(axis=2)
    m1 = uniform_filter(g, 5)
    sd = np.sqrt(np.maximum(uniform_filter(g * g, 5) - m1 * m1, 0.0))
    interior = uniform_filter((hits.component >= 0).astype(float), 5) == 1.0  # 5x5 windows on the bridge
    assert interior.sum() > 50_000
    assert np.median(sd[interior]) > 8.0  # DN: plenty for SGM's census / block costs
    near_ground = (hits.component == GROUND) & (hits.range_m < 20.0)
    assert np.median(sd[near_ground & (uniform_filter(near_ground.astype(float), 5) == 1.0)]) > 5.0
    assert np.all(img[hits.component == NO_HIT].mean(axis=1) > 150)  # a bright sky where nothing is hit
    # neighbouring images (2.7 m base, 80 % overlap): NCC of 11 x 11 patches at the true correspondences of
    # points on the deck side face and the pillar; the true position is the unique peak of a +-12 px search
    img2, _ = rendered[3]
    g2 = img2.astype(float).mean(axis=2)
    cam, sc = survey.camera, survey.scene
    e = survey.eo_true
    pts = np.vstack([bridge_point(sc, np.linspace(8.0, 15.0, 8), -6.0, 6.6),
                     bridge_point(sc, np.full(6, 13.2), -7.05, np.linspace(1.0, 5.0, 6))])
    p1 = project(cam, e.rotation[2], e.centre[2], pts)
    p2 = project(cam, e.rotation[3], e.centre[3], pts)
    h = 5

    def patch(im, cr):
        c0, r0 = int(round(cr[0])), int(round(cr[1]))
        a = im[r0 - h:r0 + h + 1, c0 - h:c0 + h + 1]
        return (a - a.mean()) / (a.std() + 1e-9)

    for a, b in zip(p1, p2):
        ref = patch(g, a)
        scores = {}
        for dr in range(-3, 4):
            for dc in range(-12, 13):
                scores[(dr, dc)] = float(np.mean(ref * patch(g2, b + [dc, dr])))
        best = max(scores, key=scores.get)
        assert abs(best[0]) <= 1 and abs(best[1]) <= 1, (a, b, best)
        assert scores[best] > 0.8
        second = max(v for (dr, dc), v in scores.items() if abs(dc) > 2 or abs(dr) > 2)
        assert second < scores[best] - 0.15


def test_render_is_deterministic_and_chunked_consistently(survey, rendered):
    img, _ = rendered[2]
    again = survey.render(2)
    assert np.array_equal(img, again)
    e = survey.eo_true
    pose = Pose(e.rotation[2], e.centre[2], "world", "camera")
    chunked = render_bridge_image(survey.scene, survey.spec.look, survey.camera, pose, survey.spec.noise_dn,
                                  survey.image_seed(2), chunk_rays=100_003)
    assert np.array_equal(img, chunked)
    other = build_bridge_camera_survey(replace(SMALL, seed=6))
    assert np.array_equal(build_bridge_camera_survey(SMALL).eo_true.centre, e.centre)
    assert not np.allclose(other.eo_true.centre, e.centre)  # jitter and adjusted-level errors follow the seed
    assert not np.allclose(other.adjusted_error_m, survey.adjusted_error_m)
    with pytest.raises(SkyrigError):
        BridgeLook(octaves_m=(1.0,))


def test_adjusted_level_orientations_within_the_stated_sigmas():
    from skyrig.geometry.rotations import rotvec_from_matrix

    spec = replace(bridge_camera_spec("ci", 9), u_range_m=(60.0, -60.0), reference_density_per_m2=1.0,
                   reference_ground_density_per_m2=0.1)
    s = build_bridge_camera_survey(spec)
    n = len(s.eo_true)
    assert n >= 80
    dc = s.eo_adjusted.centre - s.eo_true.centre
    dr = rotvec_from_matrix(np.swapaxes(s.eo_true.rotation, -1, -2) @ s.eo_adjusted.rotation)
    assert np.allclose(dc, s.adjusted_error_m) and np.allclose(dr, s.adjusted_error_rad, atol=1e-12)
    sig_m, sig_r = spec.adjusted_sigma_m, np.radians(spec.adjusted_sigma_deg)
    assert np.max(np.abs(dc)) < 5 * sig_m and np.max(np.abs(dr)) < 5 * sig_r
    # sample standard deviations of 3n values: within +-20 % of the sigmas (3n >= 240: about 4.5 standard errors)
    assert 0.8 * sig_m < np.std(dc) < 1.2 * sig_m
    assert 0.8 * sig_r < np.std(dr) < 1.2 * sig_r


def test_project_folder_read_back(tmp_path):
    pytest.importorskip("laspy")
    from skyrig.georef.eo import WorldFrame
    from skyrig.geometry.rotations import rotvec_from_matrix
    from skyrig.io.eo_csv import read_eo_csv
    from skyrig.io.images import read_image
    from skyrig.io.laz import read_las
    from skyrig.io.rig_file import read_rig
    from skyrig.io.truth import read_truth
    from skyrig.pipeline.simulate import write_bridge_camera_project

    spec = replace(SMALL, u_range_m=(16.2, 10.8))
    s = build_bridge_camera_survey(spec)
    info = write_bridge_camera_project(s, tmp_path, workers=1)
    assert info.n_images == 3
    truth = read_truth(tmp_path / "truth" / "truth.json")
    assert truth["scenario"] == "uav-bridge-camera" and truth["crs"] == "EPSG:32633"
    cam = read_rig(tmp_path / "rig.yaml").head("camera").camera
    assert cam == s.camera
    local = read_eo_csv(tmp_path / "truth" / "eo.csv")
    assert local.frame == WorldFrame.local(*spec.origin)
    assert np.abs(local.centre - s.eo_true.centre).max() < 6e-5  # 0.1 mm in the file
    adj = read_eo_csv(tmp_path / "eo.csv")
    tmap = read_eo_csv(tmp_path / "truth" / "eo_map.csv")
    assert adj.frame == tmap.frame == WorldFrame.map("EPSG:32633")
    assert list(adj.image) == list(local.image) == [f"south_r1_{k:03d}.png" for k in range(3)]
    # the map files back in the local frame (through PROJ): truth equal, adjusted within the stated sigmas
    t_back = tmap.to_frame(local.frame)
    assert np.abs(t_back.centre - local.centre).max() < 2e-4
    a_back = adj.to_frame(local.frame)
    dc = a_back.centre - local.centre
    dr = rotvec_from_matrix(np.swapaxes(local.rotation, -1, -2) @ a_back.rotation)
    sig_m, sig_r = truth["errors"]["adjusted_sigma_m"], np.radians(truth["errors"]["adjusted_sigma_deg"])
    assert np.all(np.abs(dc) < 5 * sig_m + 2e-4) and np.all(np.abs(dr) < 5 * sig_r + 1e-8)
    assert np.allclose(dc, truth["injected"]["eo_centre_error_m"], atol=2e-4)
    assert np.allclose(dr, truth["injected"]["eo_rotation_error_rad"], atol=2e-8)
    for name in local.image:
        im = read_image(tmp_path / "images" / name)
        assert im.shape == (618, 824, 3) and im.dtype == np.uint8
    assert np.array_equal(read_image(tmp_path / "images" / local.image[1]), s.render(1))
    las = read_las(tmp_path / "reference" / "tls.laz", require_crs=True)
    ref_local = local.frame.from_ecef(WorldFrame.map("EPSG:32633").to_ecef(las.xyz))
    assert len(las.xyz) == len(s.reference_xyz) and np.abs(ref_local - s.reference_xyz).max() < 2e-3
    assert ref_local[:, 2].min() > -0.02 and ref_local[:, 2].max() < 8.02
    bridge = json.loads((tmp_path / "scene" / "bridge.json").read_text())
    assert [b["name"] for b in bridge["boxes"]] == [b.name for b in s.scene.boxes]
    assert bridge["local_frame"] == list(spec.origin) and bridge["look"]["seed"] == spec.look.seed


def test_cli_lists_and_writes_the_scenario(tmp_path):
    from skyrig.cli.simulate import command

    r = CliRunner().invoke(command, ["--help"])
    assert "uav-bridge-camera" in r.output
    r = CliRunner().invoke(command, ["uav-bridge-camera", str(tmp_path / "p"), "--no-images"])
    assert r.exit_code == 0, r.output + repr(r.exception)
    for f in ("rig.yaml", "eo.csv", "reference/tls.laz", "scene/bridge.json", "truth/eo.csv", "truth/eo_map.csv",
              "truth/truth.json"):
        assert (tmp_path / "p" / f).is_file(), f
    assert not any((tmp_path / "p" / "images").iterdir())


@pytest.mark.slow
def test_ci_project_with_images(tmp_path):
    """The whole CI project through ``simulate_scenario`` (22 images, about 20 s on one core)."""
    from skyrig.io.eo_csv import read_eo_csv
    from skyrig.pipeline.simulate import simulate_scenario

    info = simulate_scenario("uav-bridge-camera", tmp_path, "ci", 1, workers=1)
    assert info.n_images == 22
    eo = read_eo_csv(tmp_path / "eo.csv")
    assert len(eo) == 22 and all((tmp_path / "images" / n).is_file() for n in eo.image)
