"""A simulated project folder in the documented formats: files read back, georeferenced, GeoPackage opens."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from skyrig.georef.direct import direct_georeference
from skyrig.io.eo_csv import read_eo_csv
from skyrig.io.events_csv import read_events_csv
from skyrig.io.points_csv import read_measurements_csv, read_points_csv
from skyrig.io.rig_file import read_rig
from skyrig.io.trajectory_csv import read_trajectory_csv
from skyrig.io.truth import read_truth


def test_project_files_georeference_to_truth(tmp_path):
    pyogrio = pytest.importorskip("pyogrio")
    from skyrig.pipeline.simulate import simulate_scenario

    out = tmp_path / "se"
    simulate_scenario("southeast", out, "ci", seed=4, images=False)
    truth = read_truth(out / "truth" / "truth.json")
    assert truth["scenario"] == "southeast"
    eo_true = read_eo_csv(out / "truth" / "eo.csv")
    eo = direct_georeference(read_trajectory_csv(out / "truth" / "trajectory.csv"), read_rig(out / "truth" / "rig.yaml"),
                             read_events_csv(out / "truth" / "events.csv"), eo_true.frame)
    # the CSV files round positions to 0.1 mm / angles to 1e-9 deg or so: agreement at that level
    assert np.max(np.linalg.norm(eo.centre - eo_true.centre, axis=1)) < 2e-3
    # recorded data carry the Tab. 4 datum shift: about 7.5 m off
    eo_rec = direct_georeference(read_trajectory_csv(out / "trajectory.csv"), read_rig(out / "rig.yaml"),
                                 read_events_csv(out / "events.csv"), eo_true.frame)
    d = np.linalg.norm(eo_rec.centre - eo_true.centre, axis=1)
    assert 6.0 < np.median(d) < 9.5
    gcp = read_points_csv(out / "gcp" / "ground_points.csv")
    assert gcp.frame.crs == "EPSG:3763"
    m = read_measurements_csv(out / "gcp" / "image_measurements.csv")
    assert len(m) > 0 and set(m.point) <= set(gcp.name) | set(read_points_csv(out / "gcp" / "check_points.csv").name)
    layers = [str(x[0]) for x in pyogrio.list_layers(out / "plan.gpkg")]
    assert {"stations", "footprints", "strips"} <= set(layers)
    assert pyogrio.read_info(out / "plan.gpkg", layer="stations")["features"] == 12
    assert (out / "scene" / "dsm.tif").exists() and (out / "scene" / "orthophoto.tif").exists()


def test_cli_plan_writes_gpkg_and_png(tmp_path):
    pytest.importorskip("pyogrio")
    pytest.importorskip("matplotlib")
    from skyrig.cli.plan import command

    area = tmp_path / "area.txt"
    area.write_text("0 0\n2000 0\n2000 1500\n0 1500\n")
    out = tmp_path / "plan.gpkg"
    r = CliRunner().invoke(command, ["--rig", "dlr-3k", "--area", str(area), "--crs", "EPSG:25832", "--height", "1000",
                                     "-o", str(out)])
    assert r.exit_code == 0, r.output
    assert out.exists() and out.with_suffix(".png").exists()
    assert "GSD nadir: centre 0.144" in r.output


def test_cli_simulate_rejects_unknown_scenario(tmp_path):
    from skyrig.cli.simulate import command

    r = CliRunner().invoke(command, ["nosuch", str(tmp_path / "x")])
    assert r.exit_code != 0


def test_given_dsm_and_orthophoto_as_the_scene(tmp_path):
    """Issue 3 item 2: a project's own scene rasters loaded back as a RasterScene and flown again."""
    from dataclasses import replace

    from skyrig.geometry.pose import Pose
    from skyrig.pipeline.simulate import load_raster_scene, write_project
    from skyrig.simulate.render import WALL, cast_rays, render_image
    from skyrig.simulate.scenarios import build_survey, scenario_spec, with_scene

    s = build_survey(scenario_spec("midas", "ci", 2))
    write_project(s, tmp_path, workers=1, images=False)
    rs = load_raster_scene(tmp_path / "scene" / "dsm.tif", tmp_path / "scene" / "orthophoto.tif")
    assert rs.origin == pytest.approx(s.scene.origin)
    # heights: the bilinear DSM equals the analytic surface at the cell centres
    rng = np.random.default_rng(0)
    cell = rs.dsm_cell
    i, j = rng.integers(2, rs.dsm.shape[0] - 2, 300), rng.integers(2, rs.dsm.shape[1] - 2, 300)
    xc, yc = rs.dsm_x0 + (j + 0.5) * cell, rs.dsm_ytop - (i + 0.5) * cell
    np.testing.assert_allclose(rs.terrain_height(xc, yc), s.scene.surface_height(xc, yc), atol=1e-4)
    # the first intersection along oblique rays (ray marching): a ray aimed at a wall hits the raster surface
    # within a cell or two of the analytic hit, not some later crossing behind the building
    o = s.eo_true.centre[0]
    t = cast_rays(s.scene, o, rng.normal([0, 0, -1], 0.4, (4000, 3)))
    d = (t.xyz - o)[np.isfinite(t.t)]
    tr = cast_rays(rs, o, d)
    walls = t.kind[np.isfinite(t.t)] == WALL
    assert walls.sum() > 5
    err = np.abs(tr.t - np.linalg.norm(d, axis=1))
    assert np.median(err) < 0.05 and np.percentile(err[walls], 90) < 4 * cell
    # a survey over the given scene renders; its image resembles the analytic one
    spec = with_scene(scenario_spec("midas", "ci", 2), rs)
    s2 = build_survey(spec)
    k = 0
    cam = s.rig_true.head(str(s.eo_true.head[k])).camera
    cam = cam.with_(width=160, height=107, pixel_size_mm=cam.pixel_size_mm * 4)
    pose = Pose(s.eo_true.rotation[k], s.eo_true.centre[k], "world", "camera")
    a = render_image(s.scene, cam, pose).astype(float).mean(axis=2)
    b = render_image(s2.scene, cam, pose).astype(float).mean(axis=2)
    assert np.corrcoef(a.ravel(), b.ravel())[0, 1] > 0.8
    assert s2.scene.targets is not None and len(s2.measurements["point"]) > 0
    with pytest.raises(Exception, match="origin"):
        build_survey(replace(spec, origin=(0.0, 0.0, 0.0)))


def test_real_dsm_in_a_map_crs_is_resampled_to_the_local_frame(tmp_path):
    rasterio = pytest.importorskip("rasterio")
    from affine import Affine

    from skyrig.georef.eo import WorldFrame
    from skyrig.pipeline.simulate import load_raster_scene

    e0, n0, cell, size = 550_000.0, 5_800_000.0, 1.0, 200
    e = e0 + (np.arange(size) + 0.5) * cell
    n = n0 - (np.arange(size) + 0.5) * cell
    ee, nn = np.meshgrid(e, n)
    h = 100.0 + 0.02 * (ee - e0) - 0.01 * (n0 - nn)  # a tilted plane, ellipsoidal heights
    tr = Affine(cell, 0.0, e0, 0.0, -cell, n0)
    for name, arr, dtype in (("dsm.tif", h[None].astype(np.float32), "float32"),
                             ("ortho.tif", np.stack([np.full_like(h, 100), (ee - e0).astype(float), np.full_like(h, 50)]).astype(np.uint8), "uint8")):
        with rasterio.open(tmp_path / name, "w", driver="GTiff", width=size, height=size, count=arr.shape[0],
                           dtype=dtype, crs="EPSG:32632", transform=tr) as ds:
            ds.write(arr)
    rs = load_raster_scene(tmp_path / "dsm.tif", tmp_path / "ortho.tif")
    # the local surface points mapped by PROJ lie on the plane (the neglected curvature shift is < 1 cm here)
    rng = np.random.default_rng(1)
    x0, y0, x1, y1 = rs.extent
    x, y = rng.uniform(x0 + 2, x1 - 2, 200), rng.uniform(y0 + 2, y1 - 2, 200)
    loc = np.column_stack([x, y, rs.terrain_height(x, y)])
    m = WorldFrame.map("EPSG:32632").from_ecef(WorldFrame.local(*rs.origin).to_ecef(loc))
    np.testing.assert_allclose(m[:, 2], 100.0 + 0.02 * (m[:, 0] - e0) - 0.01 * (n0 - m[:, 1]), atol=0.01)
    # and the texture follows the map position (green channel = metres east of the raster's west edge)
    g = rs.ground_rgb(x, y)[:, 1] * 255.0
    np.testing.assert_allclose(g, np.clip(m[:, 0] - e0 - 0.5, 0, 255), atol=1.0)
