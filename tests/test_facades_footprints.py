"""Footprints as an input for buildings the DSM does not hold (issue 11: "footprints may also be given as a
GeoPackage"): a cadastre's polygons with a height attribute -> building blocks -> occlusion surface -> façade
textures from the obliques, judged against the simulator's truth.

* footprints are written from the simulated scene (:mod:`skyrig.simulate.footprints`: the true rectangles
  through ECEF into another CRS, heights above the ground with a seeded 0.3 m error), read back with
  :func:`skyrig.pipeline.facades.read_footprint_layer` (PROJ reprojection, attributes);
* a building beyond the DSM's grid gets its walls from its footprint and heights from the attribute; its textures
  from images rendered at the true orientations match the scene's façade rule within 1 texel (the judge of
  ``tests/test_facades.py``);
* a tall block the DSM missed, given as a footprint, hides part of a wall: burnt into the occlusion surface
  (:func:`skyrig.dense.buildings.surface_with_buildings`), the hidden texels take their colour from images the
  simulator's own ray caster says see the wall; without it they do not;
* bad attributes are refused naming the file, layer, feature and field.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from skyrig.dense.buildings import (BuildingBlock, FootprintHeights, buildings_from_footprints,
                                    surface_with_buildings)
from skyrig.dense.facades import texture_facades, texture_plane
from skyrig.dense.grid import GridSpec
from skyrig.errors import InputFormatError, SkyrigError
from skyrig.georef.eo import WorldFrame
from skyrig.pipeline.facades import _complete, read_footprint_layer
from skyrig.pipeline.simulate import write_scene_footprints
from skyrig.simulate.judge_facades import judge_facades, scene_dsm, true_buildings
from skyrig.simulate.render import WALL, cast_rays
from skyrig.simulate.scenarios import build_survey, scenario_spec
from skyrig.simulate.world import Buildings, make_scene

from test_facades import LazyImages, _grid_around  # noqa: E402 - the façade tests' renderer and grid helper
from test_facades_cli import make_project  # noqa: E402 - the one-house scene of the CLI tests

CRS = WorldFrame.map("EPSG:25832")


@pytest.fixture(scope="module")
def cli_project(tmp_path_factory):
    return make_project(tmp_path_factory.mktemp("facades_footprints"))


@pytest.fixture(scope="module")
def town():
    s = build_survey(scenario_spec("midas-dsm", "ci", 1))
    eo = s.eo_true
    cams = {str(eo.camera[k]): s.rig_true.head(str(eo.head[k])).camera for k in range(len(eo))}
    return s, eo, cams


def test_a_building_beyond_the_dsm_is_textured_from_its_footprint_and_height(town, tmp_path):
    s, eo, cams = town
    bl = s.scene.buildings
    oblique = {str(n) for n, h in zip(eo.image, eo.head) if h != "nadir"}
    # the DSM covers the east of the town only; the footprints (in WGS84 lon/lat) are of two buildings west of it
    east = np.flatnonzero(bl.cx > 75)
    lo = np.array([bl.cx[east].min() - 25, bl.cy[east].min() - 25])
    hi = np.array([bl.cx[east].max() + 25, bl.cy[east].max() + 25])
    dsm = scene_dsm(s.scene, _grid_around(CRS, s.frame, lo, hi, 0.3), CRS)
    west = [int(i) for i in np.argsort(-bl.cx) if bl.cx[i] < lo[0] - 15][:2]
    path = tmp_path / "cadastre.gpkg"
    w = write_scene_footprints(path, s.scene, "EPSG:4326", west, height_sigma_m=0.3, seed=3)
    fl = read_footprint_layer(path, CRS, None, ["eave_m", "ridge_m"], max_height_m=500.0)
    assert fl.layer == "buildings" and fl.labels == ["buildings:1", "buildings:2"]
    truth = {t.id: t for t in true_buildings(s.scene, CRS)}
    for ring, i in zip(fl.rings, west):
        assert len(ring) == 4  # no vertex lost (a closing-vertex test relative to UTM coordinates dropped one)
        assert np.abs(ring - truth[i].footprint).max() < 0.01  # PROJ through ECEF: the eaves' height only
    with pytest.raises(SkyrigError, match="outside the DSM"):
        buildings_from_footprints(fl.rings, dsm)  # no heights: nothing to build them from
    hts = FootprintHeights(fl.heights["eave_m"], fl.heights["ridge_m"], "ground", "eave_m", tuple(fl.labels))
    blocks = buildings_from_footprints(fl.rings, dsm, source="cadastre.gpkg", heights=hts)
    for b, i, k in zip(blocks, west, range(len(west))):
        assert "heights: eave_m" in b.source
        assert b.eave_z - b.ground_z == pytest.approx(fl.heights["eave_m"][k], abs=1e-9)
        # the attribute is the truth + its error; the ground is extrapolated from the DSM's nearest ground
        assert abs(b.eave_z - truth[i].eave_z) <= 4 * 0.3 + abs(b.ground_z - truth[i].ground_z)
        assert len(b.roof) == (2 if bl.gabled[i] else 1)
        if bl.gabled[i]:  # ridge along the long sides, as the scene's houses: the roof planes' vertices
            got = np.concatenate(b.roof)[:, :2]
            want = np.concatenate(truth[i].roof)[:, :2]
            assert max(np.min(np.linalg.norm(got - p, axis=1)) for p in want) < 0.01
    surf = surface_with_buildings(dsm, blocks)
    assert surf.metadata["buildings_burnt"]["cells"] > 0 and surf.grid.bounds[0] < dsm.grid.bounds[0]
    tex = texture_facades(blocks, eo, cams, LazyImages(s.scene, eo, cams), surf)
    judged, summ = judge_facades(s.scene, tex, CRS, oblique)
    seen = [j for j, t in zip(judged, tex) if j.windows and set(t.images) & oblique]
    assert len(seen) >= 2, summ
    assert {j.true_building for j in seen} <= set(west)
    for j in seen:
        assert j.windows_found == j.windows and j.offset_norm_px <= 1.0 and np.median(j.corner_err_px) <= 1.0, j
    assert summ["windows_within_1px"] >= 0.95 * summ["windows_found"], summ
    assert np.std(w["height_error_m"]) > 0  # the heights really were perturbed


def test_a_block_missing_from_the_dsm_hides_a_wall_once_given_as_a_footprint():
    """The occlusion case of tests/test_facades.py, but the DSM missed the tall block in front of the wall: given
    as a footprint with its height, it is burnt into the occlusion surface and the texels it hides come from
    images that see them (simulator's ray caster)."""
    base = build_survey(scenario_spec("midas-dsm", "ci", 1))
    sc = make_scene(5, (-250.0, -250.0, 250.0, 250.0), origin=base.scene.origin, n_buildings=0, relief_m=2.0)
    cx, cy = np.array([108.0, 89.0]), np.array([-12.0, -11.0])
    g = sc.terrain_height(cx, cy)
    sc = replace(sc, buildings=Buildings(cx, cy, np.array([10.0, 1.25]), np.array([8.0, 4.0]),
                                         np.array([np.pi / 2, 0.0]), g - 3.0, g + np.array([8.0, 22.0]),
                                         g + np.array([8.0, 22.0])))
    eo = base.eo_true
    cams = {str(eo.camera[k]): base.rig_true.head(str(eo.head[k])).camera for k in range(len(eo))}
    dsm = scene_dsm(sc, GridSpec(60.0, 20.0, 0.25, 240, 180), base.frame)
    block = true_buildings(sc)[1]
    # the DSM did not measure the block: its cells are holes (a matcher's void), filled with ground when texturing
    xx, yy = dsm.grid.cell_centres()
    _, idx = sc.buildings.top_height(xx.ravel(), yy.ravel())
    holed = replace(dsm, height=np.where((idx == 1).reshape(xx.shape), np.nan, dsm.height).astype(np.float32))
    hts = FootprintHeights(np.array([22.0 + 0.2]), None, "ground", "height")  # cadastre: 0.2 m too high
    given = buildings_from_footprints([block.footprint], holed, heights=hts)
    assert given[0].eave_z == pytest.approx(given[0].ground_z + 22.2)
    surf = surface_with_buildings(holed, given)
    wall = [f for f in true_buildings(sc)[0].facades() if f.normal[0] < -0.99][0]
    loader = LazyImages(sc, eo, cams)
    blind = texture_plane(wall.corners, eo, cams, loader, holed, normal=wall.normal)
    res = texture_plane(wall.corners, eo, cams, loader, surf, normal=wall.normal)
    assert res.stats["occluded_in_best"] > 100 and blind.stats["occluded_in_best"] < 0.1 * res.stats["occluded_in_best"]

    def seen_share(r) -> float:
        H, W = r.valid.shape
        c = wall.corners
        u = (c[1] - c[0]) / np.linalg.norm(c[1] - c[0])
        jj, ii = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
        P = c[3] + (jj.reshape(-1, 1) * r.texel_m) * u - (ii.reshape(-1, 1) * r.texel_m) * np.array([0, 0, 1.0])
        src = r.source.reshape(-1)
        ok = np.zeros(len(P), bool)
        for m, name in enumerate(r.images):
            k = int(np.flatnonzero(eo.image == name)[0])
            sel = np.flatnonzero(src == m)
            d = P[sel] - eo.centre[k]
            hits = cast_rays(sc, eo.centre[k], d)
            ok[sel] = (hits.kind == WALL) & (hits.building == 0) & (np.abs(hits.t - np.linalg.norm(d, axis=1)) < 0.05)
        return float(ok[r.valid.reshape(-1)].mean())

    assert seen_share(res) >= 0.97
    assert seen_share(blind) < seen_share(res) - 0.02  # without the footprint the block's colours come in


def _gpkg(path, polys, fields, crs="EPSG:25832"):
    import shapely

    from skyrig.io.gpkg import write_gpkg

    write_gpkg(path, {"buildings": ([shapely.Polygon(p) for p in polys], fields)}, crs)


def test_bad_footprint_heights_are_refused_in_words(tmp_path):
    x0, y0 = 500000.0, 5800000.0
    sq = [np.array([[x0, y0], [x0 + 10, y0], [x0 + 10, y0 + 8], [x0, y0 + 8]]) + [30.0 * k, 0.0] for k in range(3)]
    grid = GridSpec(x0 - 20, y0 + 30, 0.5, 60, 60)  # covers the first square only
    h = np.full(grid.shape, 50.0, np.float32)
    from skyrig.dense.grid import DsmGrid

    dsm = DsmGrid(grid, CRS, h, np.ones(grid.shape, np.int16), np.zeros(grid.shape, np.float32),
                  np.zeros(grid.shape, np.float32), np.zeros(grid.shape, bool), "ellipsoidal", {})
    p = tmp_path / "fp.gpkg"
    _gpkg(p, sq, {"eave": np.array([6.0, 950.0, 7.0]), "kind": np.array(["a", "b", "c"])})
    with pytest.raises(InputFormatError) as e:
        read_footprint_layer(p, CRS, None, ["height_m"])
    assert "no field 'height_m'" in str(e.value) and "eave" in str(e.value) and str(p) in str(e.value)
    assert "layer 'buildings'" in str(e.value)
    with pytest.raises(InputFormatError) as e:  # 950: centimetres?
        read_footprint_layer(p, CRS, None, ["eave"], max_height_m=500.0)
    assert "feature 2" in str(e.value) and e.value.field == "eave" and e.value.line == 2
    with pytest.raises(InputFormatError, match="not a number"):
        read_footprint_layer(p, CRS, None, ["kind"])
    with pytest.raises(InputFormatError, match="no layer 'roads'"):
        read_footprint_layer(p, CRS, "roads")
    # a missing value (NULL / NaN) for a footprint beyond the DSM: named
    hts = FootprintHeights(np.array([6.0, np.nan, 7.0]), None, "ground", "fp.gpkg field eave",
                           ("fp:1", "fp:2", "fp:3"))
    with pytest.raises(SkyrigError, match=r"fp:2 .* no height was given for it \(fp.gpkg field eave: empty\)"):
        buildings_from_footprints(sq, dsm, heights=hts)
    # implausible above the ground (0.2 m), and a ridge under the eaves
    with pytest.raises(SkyrigError, match=r"fp:2 .*0\.20 m above the ground .* implausible"):
        buildings_from_footprints(sq, dsm, heights=replace(hts, eave_m=np.array([6.0, 0.2, 7.0])))
    with pytest.raises(SkyrigError, match="fp:3 .*ridge height .* below the eaves"):
        buildings_from_footprints(sq, dsm, heights=replace(hts, eave_m=np.array([6.0, 6.0, 7.0]),
                                                           ridge_m=np.array([np.nan, 8.0, 5.0])))
    # absolute heights (the DSM's reference): the same block as above-ground ones; ground from the nearest DSM cell
    a = buildings_from_footprints(sq, dsm, heights=replace(hts, eave_m=np.array([6.0, 56.0, 57.0]),
                                                           reference="absolute"))
    b = buildings_from_footprints(sq, dsm, heights=replace(hts, eave_m=np.array([6.0, 6.0, 7.0])))
    assert [q.eave_z for q in a[1:]] == [q.eave_z for q in b[1:]] == [56.0, 57.0]
    assert a[0].source == "footprints" and "heights" in a[1].source  # the first one lies on the DSM: its heights
    # beyond max_ground_m from any measured cell: refused (give absolute heights)
    with pytest.raises(SkyrigError, match="nearest DSM cell with a ground height is .* m away"):
        buildings_from_footprints([sq[2] + [400.0, 0.0]], dsm, heights=replace(hts, eave_m=np.array([7.0])))


def test_complete_adds_the_footprints_the_dsm_missed_and_replaces_clipped_buildings():
    def blk(i, x, clipped=False):
        fp = np.array([[x, 0.0], [x + 10, 0.0], [x + 10, 8.0], [x, 8.0]])
        return BuildingBlock(i, fp, 0.0, 6.0, (np.column_stack([fp, np.full(4, 6.0)]),), "dsm", clipped)

    extracted = [blk(0, 0.0), blk(3, 30.0, clipped=True)]
    given = [blk(0, 0.5), blk(1, 29.0), blk(2, 60.0)]
    out = _complete(extracted, given)
    assert [b.id for b in out] == [0, 4, 5]
    assert out[0] is extracted[0]  # the DSM's (refined) building is kept
    assert np.allclose(out[1].footprint, given[1].footprint) and np.allclose(out[2].footprint, given[2].footprint)
    assert _complete(extracted, []) == extracted


def test_facades_options_need_footprints():
    from skyrig.errors import OptionError
    from skyrig.pipeline.products import make_facades

    with pytest.raises(OptionError, match="--footprints"):
        make_facades(None, {}, [], "dsm.tif", "out", footprint_eave="eave_m")
    with pytest.raises(OptionError, match="--footprint-eave"):
        make_facades(None, {}, [], "dsm.tif", "out", footprints="x.gpkg", footprint_ridge="ridge_m")
    with pytest.raises(OptionError, match="--footprint-mode"):
        make_facades(None, {}, [], "dsm.tif", "out", footprints="x.gpkg", footprint_mode="merge")


def test_cli_textures_a_house_the_dsm_missed_from_its_footprint(cli_project, tmp_path):
    """``skyrig facades --footprints --footprint-eave --footprint-ridge`` on the one-house scene of
    tests/test_facades_cli.py whose DSM lost the house (its cells are holes): the house comes from the footprint
    with the attribute's heights, its four walls are textured; without a height attribute the run is refused."""
    import shapely
    from click.testing import CliRunner
    from pyogrio.raw import read

    from skyrig.cli import main
    from skyrig.io.dsm_cog import write_dsm_cog

    root, scene, frame, dsm = cli_project
    xx, yy = dsm.grid.cell_centres()
    loc = WorldFrame.local(*scene.origin)
    pts = loc.from_ecef(frame.to_ecef(np.column_stack([xx.ravel(), yy.ravel(), np.asarray(dsm.height).ravel()])))
    _, idx = scene.buildings.top_height(pts[:, 0], pts[:, 1])
    holed = replace(dsm, height=np.where((idx >= 0).reshape(xx.shape), np.nan, dsm.height).astype(np.float32))
    write_dsm_cog(tmp_path / "dsm_holed.tif", holed)
    fp = tmp_path / "cadastre.gpkg"
    w = write_scene_footprints(fp, scene, "EPSG:4326", height_sigma_m=0.3, seed=7)
    args = ["facades", "--dsm", str(tmp_path / "dsm_holed.tif"), "--eo", str(root / "eo.csv"), "--camera",
            str(root / "rig.yaml"), "--images", str(root / "images"), "--footprints", str(fp)]
    bad = CliRunner().invoke(main, [*args, "-o", str(tmp_path / "bad")])
    assert bad.exit_code != 0 and "cadastre.gpkg buildings:1" in bad.output and "no height was given" in bad.output
    assert not (tmp_path / "bad").exists()
    out = tmp_path / "out"
    res = CliRunner().invoke(main, [*args, "--footprint-eave", "eave_m", "--footprint-ridge", "ridge_m",
                                    "-o", str(out)])
    assert res.exit_code == 0, res.output
    assert "4 of 4 façades textured" in res.output and "1 with heights from eave_m" in res.output
    meta, _, geoms, fields = read(str(out / "buildings.gpkg"), layer="buildings")
    cols = dict(zip(meta["fields"], fields))
    assert cols["eave_z"][0] - cols["ground_z"][0] == pytest.approx(w["eave_m"][0], abs=1e-6)
    assert cols["ridge_z"][0] - cols["ground_z"][0] == pytest.approx(w["ridge_m"][0], abs=1e-6)
    assert "heights" in cols["source"][0]
    truth = true_buildings(scene, frame)[0]
    poly = np.asarray(shapely.from_wkb(geoms[0]).exterior.coords)[:-1, :2]
    assert len(poly) == 4 and np.linalg.norm(poly[:, None] - truth.footprint[None], axis=2).min(axis=1).max() < 0.01
    info = json.loads((out / "facades.json").read_text())
    assert info["footprints"]["heights_from_attributes"] == 1 and info["footprints"]["occlusion_cells_burnt"] > 0
    assert all(f["coverage"] > 0.9 for f in info["facade_list"]), info["facade_list"]


def test_project_refuses_a_missing_footprints_file_at_load(tmp_path):
    """``skyrig run``'s project file: a facades stage whose ``footprints`` file is missing is refused when the
    project is loaded (before any stage runs), naming the project file, the line and the option."""
    from skyrig.pipeline.project import load_project

    for name in ("trajectory.csv", "events.csv", "rig.yaml"):
        (tmp_path / name).touch()
    (tmp_path / "images").mkdir()
    text = ("format: skyrig-project\nversion: 1\ncrs: EPSG:25832\ninputs:\n  trajectory: trajectory.csv\n"
            "  events: events.csv\n  rig: rig.yaml\n  images: [images]\nstages:\n  georef: {}\n  dsm: {}\n"
            "  facades: {footprints: cadastre.gpkg, footprint_eave: eave_m}\n")
    p = tmp_path / "project.yaml"
    p.write_text(text)
    with pytest.raises(InputFormatError) as e:
        load_project(p)
    assert e.value.field == "stages.facades.footprints" and e.value.line == 12, str(e.value)
    assert str(p) in str(e.value) and "no such file" in str(e.value) and "cadastre.gpkg" in str(e.value)
    (tmp_path / "cadastre.gpkg").touch()  # present: the file itself is read when the stage runs
    assert [s.name for s in load_project(p).stages] == ["georef", "dsm", "facades"]
