"""``skyrig facades`` end to end on a small rendered scene (one house, four obliques looking at its walls).

The images are rendered by the simulator from known poses; the DSM is the scene's analytic surface in EPSG:25832
(``skyrig.simulate.judge_facades.scene_dsm``), so the buildings the stage extracts and the model it writes are
judged against the scene's truth (footprint corners within a DSM cell's diagonal, eave and ridge heights within a
cell's size); the published folder is checked against its manifest; bad inputs exit 2 naming the input, a DSM with
no building exits 1 and publishes nothing.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyproj
import pytest
from click.testing import CliRunner

from skyrig.cli import main
from skyrig.dense.buildings import BuildingBlock
from skyrig.dense.grid import GridSpec
from skyrig.geodesy.frame import WorldFrame
from skyrig.geometry.pose import Pose
from skyrig.georef.eo import ExteriorOrientations
from skyrig.io.dsm_cog import write_dsm_cog
from skyrig.io.eo_csv import write_eo_csv
from skyrig.io.gltf import glb_problems, read_glb
from skyrig.io.rig_file import write_rig
from skyrig.io.stage import verify_folder
from skyrig.simulate.judge_facades import scene_dsm
from skyrig.simulate.judge_model import judge_model
from skyrig.simulate.render import render_image
from skyrig.simulate.scenarios import scenario_spec
from skyrig.simulate.world import make_scene

CRS = "EPSG:25832"
CELL = 0.25


def _look_at(c: np.ndarray, target: np.ndarray) -> np.ndarray:
    """world_from_camera of a camera at c looking at target (camera x right, y up, looking along -z)."""
    f = (target - c) / np.linalg.norm(target - c)
    x = np.cross(f, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    z = -f
    return np.column_stack([x, np.cross(z, x), z])


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    return make_project(tmp_path_factory.mktemp("facades"))


def make_project(root: Path):
    """The one-house scene in ``root``: rig.yaml, images/ (four obliques), eo.csv, dsm.tif; returns
    ``(root, scene, frame, dsm)``."""
    import cv2

    scene = make_scene(11, (-60.0, -60.0, 60.0, 60.0), n_buildings=1, building_size_m=(10.0, 16.0))
    bl = scene.buildings
    loc = WorldFrame.local(*scene.origin)
    frame = WorldFrame.map(CRS)
    spec = scenario_spec("midas-dsm", "ci", 1)
    write_rig(spec.rig, root / "rig.yaml")
    centre = np.array([bl.cx[0], bl.cy[0], 0.5 * (bl.base_z[0] + bl.eave_z[0]) + 2.0])
    names, cams, cs, rs = [], [], [], []
    (root / "images").mkdir()
    for k, (head, az) in enumerate([("forward", 0.0), ("right", 90.0), ("backward", 180.0), ("left", 270.0)]):
        cam = spec.rig.heads[head].camera
        a = np.radians(az)
        c = centre + np.array([42.0 * np.sin(a), 42.0 * np.cos(a), 40.0])
        r = _look_at(c, centre)
        img = render_image(scene, cam, Pose(r, c, "world", "camera"), noise_dn=1.0, seed=k)
        name = f"img_{head}.png"
        cv2.imwrite(str(root / "images" / name), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        names.append(name)
        cams.append(cam.name)
        cs.append(c)
        rs.append(r)
    eo = ExteriorOrientations(np.array(names), np.array(cams), np.array(cs), np.array(rs), loc).to_frame(frame)
    write_eo_csv(eo, root / "eo.csv")
    c0 = frame.from_ecef(loc.to_ecef(np.array([[-40.0, 40.0, 80.0], [40.0, -40.0, 80.0]])))
    x0, y0 = np.floor(c0[0, 0] / CELL) * CELL, np.ceil(c0[0, 1] / CELL) * CELL
    grid = GridSpec(float(x0), float(y0), CELL, int((c0[1, 0] - x0) / CELL), int((y0 - c0[1, 1]) / CELL))
    dsm = scene_dsm(scene, grid, frame)
    write_dsm_cog(root / "dsm.tif", dsm)
    return root, scene, frame, dsm


def _args(root: Path, out: Path, *extra: str) -> list[str]:
    return ["facades", "--dsm", str(root / "dsm.tif"), "--eo", str(root / "eo.csv"), "--camera", str(root / "rig.yaml"),
            "--images", str(root / "images"), *extra, "-o", str(out)]


@pytest.fixture(scope="module")
def run(project):
    root = project[0]
    out = root / "out"
    res = CliRunner().invoke(main, _args(root, out))
    return res, out


def test_cli_publishes_a_checked_folder(project, run):
    res, out = run
    assert res.exit_code == 0, res.output
    assert "1 buildings" in res.output and "4 of 4 façades textured" in res.output
    assert verify_folder(out) == []
    for f in ("model.glb", "model.glb.json", "model.obj", "model.mtl", "buildings.gpkg", "viewer.html", "facades.json"):
        assert (out / f).is_file(), f
    assert sorted(p.name for p in (out / "facades").iterdir()) == [f"b0_f{k}.png" for k in range(4)]
    assert glb_problems(out / "model.glb") == []
    gltf, _ = read_glb(out / "model.glb")
    side = gltf["asset"]["extras"]["skyrig"]
    assert side["source_frame"] == f"{CRS}; heights: ellipsoidal"
    info = json.loads((out / "facades.json").read_text())
    # each wall faces one of the four obliques head-on: it is seen nearly whole
    assert all(f["coverage"] > 0.9 and f["images"] for f in info["facade_list"]), info["facade_list"]
    page = (out / "viewer.html").read_text()
    assert "data:text/javascript;base64," in page and "__GLB_BASE64__" not in page


def test_buildings_against_the_scene_truth(project, run):
    """The footprint and heights in buildings.gpkg (and in the model) against the scene's house."""
    import shapely
    from pyogrio.raw import read

    root, scene, frame, dsm = project
    res, out = run
    meta, _, geoms, fields = read(str(out / "buildings.gpkg"), layer="buildings")
    crs = pyproj.CRS.from_user_input(meta["crs"])
    assert crs.to_2d().equals(pyproj.CRS(CRS)) and len(crs.axis_info) == 3  # 3D: heights are stated
    cols = dict(zip(meta["fields"], fields))
    rmeta, _, rgeoms, rfields = read(str(out / "buildings.gpkg"), layer="roofs")
    rcols = dict(zip(rmeta["fields"], rfields))
    blocks = []
    for k, g in enumerate(geoms):
        poly = np.asarray(shapely.from_wkb(g).exterior.coords)[:-1, :2]
        gz, ez = float(cols["ground_z"][k]), float(cols["eave_z"][k])
        roofs = tuple(np.asarray(shapely.from_wkb(rg).exterior.coords)[:-1] for rg, b in zip(rgeoms, rcols["building"])
                      if b == cols["id"][k])
        assert all(r.shape[1] == 3 for r in roofs)
        blocks.append(BuildingBlock(int(cols["id"][k]), poly, gz, ez, roofs))
    r = judge_model(blocks, frame, scene)
    print("facades CLI vs truth:", {k: v for k, v in r.items() if k != "per_building"},
          "gabled" if scene.buildings.gabled[0] else "flat")
    assert r["found"] == 1 and r["missed"] == 0 and r["extra"] == 0
    assert r["corner_rms_m"] < np.sqrt(2) * CELL
    assert abs(r["eave_bias_m"]) < CELL and r["ridge_rms_m"] < CELL


def test_footprints_from_a_geopackage_in_another_crs(project, tmp_path):
    import shapely

    from skyrig.io.gpkg import write_gpkg

    root, scene, frame, dsm = project
    bl = scene.buildings
    a = bl.azimuth_rad[0]
    ux, uy = np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)])
    c = np.array([bl.cx[0], bl.cy[0]])
    fp = np.array([c + sx * bl.hl[0] * ux + sy * bl.hw[0] * uy for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
    loc = WorldFrame.local(*scene.origin)
    geo = WorldFrame.map("EPSG:4326").from_ecef(loc.to_ecef(np.column_stack([fp, np.full(4, bl.eave_z[0])])))
    write_gpkg(tmp_path / "fp.gpkg", {"footprints": ([shapely.Polygon(geo[:, :2])], {"name": np.array(["house"])})},
               "EPSG:4326")
    out = tmp_path / "out"
    res = CliRunner().invoke(main, _args(root, out, "--footprints", str(tmp_path / "fp.gpkg")))
    assert res.exit_code == 0, res.output
    from pyogrio.raw import read

    meta, _, geoms, fields = read(str(out / "buildings.gpkg"), layer="buildings")
    poly = np.asarray(shapely.from_wkb(geoms[0]).exterior.coords)[:-1, :2]
    want = frame.from_ecef(loc.to_ecef(np.column_stack([fp, np.full(4, bl.eave_z[0])])))[:, :2]
    d = np.linalg.norm(poly[:, None, :] - want[None], axis=2).min(axis=1)
    assert d.max() < 1e-3  # the given footprint, reprojected from EPSG:4326 by PROJ
    assert dict(zip(meta["fields"], fields))["source"][0] == "fp.gpkg"


def test_bad_inputs_exit_2_and_no_building_exits_1(project, tmp_path):
    root, scene, frame, dsm = project
    runner = CliRunner()
    r = runner.invoke(main, _args(root, tmp_path / "o1", "--texel", "-1"))
    assert r.exit_code == 2 and "--texel" in r.output
    (tmp_path / "nocrs.gpkg").write_bytes(b"not a geopackage")
    r = runner.invoke(main, _args(root, tmp_path / "o2", "--footprints", str(tmp_path / "nocrs.gpkg")))
    assert r.exit_code == 2 and "nocrs.gpkg" in r.output
    imgs = tmp_path / "few"
    imgs.mkdir()
    (imgs / "img_forward.png").write_bytes((root / "images" / "img_forward.png").read_bytes())
    args = _args(root, tmp_path / "o3")
    args[args.index(str(root / "images"))] = str(imgs)
    r = runner.invoke(main, args)
    assert r.exit_code == 2 and "not found" in r.output
    # a DSM of bare terrain: nothing to model -> a failed result, nothing published
    from dataclasses import replace

    flat = replace(dsm, height=np.full_like(dsm.height, float(np.nanmin(dsm.height))))
    write_dsm_cog(tmp_path / "flat.tif", flat)
    args = _args(root, tmp_path / "o4")
    args[args.index(str(root / "dsm.tif"))] = str(tmp_path / "flat.tif")
    r = runner.invoke(main, args)
    assert r.exit_code == 1 and "no buildings" in r.output
    assert not (tmp_path / "o4").exists()
    assert not any(p.name.startswith(".o") for p in tmp_path.iterdir())
