"""``skyrig terrain`` end to end on a small simulated town cloud, files read back with laspy / rasterio / pyogrio,
and its refusals of bad input (issue 31's list): no CRS, polygon in another CRS (reprojected) or without one,
interval 0 or larger than the relief, empty polygon, a DSM without vertical reference; never a half-written output."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from skyrig.cli import main

E0, N0 = 500000.0, 5800000.0


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A LAZ of a simulated town (EPSG:25832, ellipsoidal heights) written by skyrig's dense-cloud writer, and
    the truth (scene and classes)."""
    from skyrig.dense.grid import DenseCloud
    from skyrig.georef.eo import WorldFrame
    from skyrig.io.dense_laz import write_dense_cloud
    from _terrain_scene import town_cloud

    d = tmp_path_factory.mktemp("terrain_cli")
    xyz, rgb, truth, scene = town_cloud(seed=4, size=80.0, n_trees=3)
    n = len(xyz)
    m = xyz + [E0, N0, 0.0]
    write_dense_cloud(d / "cloud.laz", DenseCloud(m, rgb, np.zeros((n, 3), np.float32), np.ones(n, np.int16),
                                                  np.full(n, 0.05, np.float32), WorldFrame.map("EPSG:25832"), ""))
    return d, truth, scene


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def test_classify_dtm_contours_volume(files):
    import laspy
    import pyogrio
    import rasterio
    import shapely

    from skyrig.io.dsm_cog import cog_problems
    from skyrig.io.gpkg import write_gpkg
    from skyrig.io.stage import verify_folder

    d, truth, scene = files
    r = run("terrain", "classify", d / "cloud.laz", "-o", d / "cls.laz")
    assert r.exit_code == 0, r.output
    las = laspy.read(d / "cls.laz")
    code = np.asarray(las.classification)
    assert np.mean(code[truth == 2] == 2) > 0.95 and np.mean(code[truth == 6] == 6) > 0.9
    assert las.header.parse_crs() is not None and len(las.points) == len(truth)
    r = run("terrain", "dtm", d / "cls.laz", "--resolution", "1", "-o", d / "dtm")
    assert r.exit_code == 0, r.output
    assert verify_folder(d / "dtm") == []
    assert cog_problems(d / "dtm" / "dtm.tif") == []
    with rasterio.open(d / "dtm" / "dtm.tif") as ds:
        assert ds.descriptions == ("height", "sigma", "ground_points", "source")
        assert ds.tags()["VERTICAL_REFERENCE"] == "ellipsoidal" and ds.tags()["SKYRIG_PRODUCT"] == "dtm"
        h = ds.read(1)
        t = ds.transform
        xs, ys = np.meshgrid(t.c + (np.arange(ds.width) + 0.5) * t.a - E0,
                             t.f + (np.arange(ds.height) + 0.5) * t.e - N0)
    ok = h != ds.nodata
    e = h[ok] - scene.terrain_height(xs[ok], ys[ok])
    assert abs(np.median(e)) < 0.02 and np.sqrt(np.mean(e ** 2)) < 0.1
    r = run("terrain", "contours", d / "dtm" / "dtm.tif", "--interval", "0.5", "-o", d / "c.gpkg")
    assert r.exit_code == 0, r.output
    meta, _, _, fields = pyogrio.raw.read(str(d / "c.gpkg"))
    assert "elevation" in list(meta["fields"]) and len(fields[0]) > 3
    # polygon in WGS84 (EPSG:4326): reprojected into the DTM's CRS; volume above a plane under the whole area
    from pyproj import Transformer

    box = np.array([[10, 10], [70, 10], [70, 70], [10, 70]], float) + [E0, N0]
    lon, lat = Transformer.from_crs("EPSG:25832", "EPSG:4326", always_xy=True).transform(box[:, 0], box[:, 1])
    write_gpkg(d / "area.gpkg", {"area": ([shapely.Polygon(np.column_stack([lon, lat]))], {"name": ["a"]})},
               "EPSG:4326")
    zb = float(scene.terrain_range[0]) - 1.0
    r = run("terrain", "volume", "--top", d / "dtm" / "dtm.tif", "--polygon", d / "area.gpkg", "--base-plane", zb,
            "-o", d / "v.json")
    assert r.exit_code == 0, r.output
    v = json.loads((d / "v.json").read_text())
    # the truth: the terrain above the plane over the 60 x 60 m square (fine midpoint rule)
    g = np.arange(10.05, 70, 0.1)
    gx, gy = np.meshgrid(g, g)
    v_true = float(np.sum(scene.terrain_height(gx, gy) - zb) * 0.01)
    assert abs(v["net_m3"] - v_true) < max(3 * v["sigma_net_m3"], 0.002 * v_true), (v["net_m3"], v_true)
    assert v["cut_m3"] == 0.0


def test_bad_inputs(files, tmp_path):
    import laspy
    import rasterio
    import shapely

    from skyrig.io.gpkg import write_gpkg

    d, _, _ = files
    # a cloud without CRS
    las = laspy.LasData(laspy.LasHeader(point_format=3, version="1.2"))
    las.x, las.y, las.z = np.arange(10.0), np.arange(10.0), np.zeros(10)
    las.write(tmp_path / "nocrs.las")
    r = run("terrain", "classify", tmp_path / "nocrs.las", "-o", tmp_path / "out.laz")
    assert r.exit_code == 2 and "no CRS" in r.output and "nocrs.las" in r.output
    assert not (tmp_path / "out.laz").exists()
    if not (d / "dtm" / "dtm.tif").exists():
        run("terrain", "dtm", d / "cloud.laz", "--classify", "-o", d / "dtm")
    dtm = d / "dtm" / "dtm.tif"
    for interval, words in (("0", "positive"), ("500", "larger than the relief")):
        r = run("terrain", "contours", dtm, "--interval", interval, "-o", tmp_path / "c.gpkg")
        assert r.exit_code == 2 and "--interval" in r.output and words in r.output, r.output
        assert not (tmp_path / "c.gpkg").exists()
    # an empty polygon file (a layer of points), a polygon without CRS, a polygon far away
    write_gpkg(tmp_path / "pts.gpkg", {"p": ([shapely.Point(E0, N0)], {"a": [1]})}, "EPSG:25832")
    with pytest.warns(UserWarning, match="crs"):  # GDAL's own warning about the file made here without a CRS
        write_gpkg(tmp_path / "nocrs.gpkg", {"a": ([shapely.box(E0, N0, E0 + 10, N0 + 10)], {"a": [1]})}, None)
    write_gpkg(tmp_path / "far.gpkg", {"a": ([shapely.box(0, 0, 10, 10)], {"a": [1]})}, "EPSG:25832")
    for poly, words in (("pts.gpkg", "polygon"), ("nocrs.gpkg", "CRS"), ("far.gpkg", "covers no cell")):
        r = run("terrain", "volume", "--top", dtm, "--polygon", tmp_path / poly, "--base-plane", "0",
                "-o", tmp_path / "v.json")
        assert r.exit_code == 2 and words in r.output, r.output
        assert not (tmp_path / "v.json").exists()
    r = run("terrain", "volume", "--top", dtm, "--polygon", tmp_path / "far.gpkg", "-o", tmp_path / "v.json")
    assert r.exit_code == 2 and "exactly one base" in r.output
    # a DSM / DTM without vertical reference: a plain GeoTIFF in a 2D CRS without skyrig's tags
    plain = tmp_path / "plain.tif"
    with rasterio.open(dtm) as src:
        prof = dict(driver="GTiff", width=src.width, height=src.height, count=1, dtype="float32", crs=src.crs,
                    transform=src.transform)
        with rasterio.open(plain, "w", **prof) as dst:
            dst.write(src.read(1), 1)
    r = run("terrain", "contours", plain, "--interval", "0.5", "-o", tmp_path / "c.gpkg")
    assert r.exit_code == 2 and "vertical reference" in r.output and "plain.tif" in r.output
    r = run("terrain", "dtm", d / "cls.laz" if (d / "cls.laz").exists() else d / "cloud.laz", "--classify",
            "--dsm", plain, "-o", tmp_path / "dtm2")
    assert r.exit_code == 2 and "vertical reference" in r.output and "--dsm" in r.output
    assert not (tmp_path / "dtm2").exists()
    # an unclassified cloud without --classify
    r = run("terrain", "dtm", d / "cloud.laz", "-o", tmp_path / "dtm3")
    assert r.exit_code == 2 and "classify" in r.output and not (tmp_path / "dtm3").exists()


def test_project_stage_dtm(files, tmp_path):
    """The runner's ``dtm`` stage (after ``dsm``) on a dsm folder (dsm.tif + cloud.laz): classified cloud, DTM on
    the DSM's grid, nDSM equal to the true building heights on roofs."""
    from types import SimpleNamespace

    import rasterio

    from skyrig.dense.grid import DsmGrid, GridSpec
    from skyrig.georef.eo import WorldFrame
    from skyrig.io.dsm_cog import write_dsm_cog
    from skyrig.pipeline.run import STAGES

    d, _, scene = files
    # the DTM stage takes the lidar stage's laser cloud when the project has one, else the DSM stage's cloud
    assert list(STAGES).index("dtm") > list(STAGES).index("dsm") and STAGES["dtm"].requires == ("laser|dsm",)
    dsm_dir = tmp_path / "dsm"
    dsm_dir.mkdir()
    (dsm_dir / "cloud.laz").write_bytes((d / "cloud.laz").read_bytes())
    g = GridSpec(E0, N0 + 80, 0.5, 160, 160)
    xx, yy = g.cell_centres()
    top = scene.surface_height(xx - E0, yy - N0).astype(np.float32)
    z = np.zeros(g.shape, np.float32)
    write_dsm_cog(dsm_dir / "dsm.tif", DsmGrid(g, WorldFrame.map("EPSG:25832"), top, np.ones(g.shape, np.int16),
                                               z, z + 0.05, np.zeros(g.shape, bool)))
    out = tmp_path / "stage"
    out.mkdir()
    opts = {k: v.default for k, v in STAGES["dtm"].options.items()}
    from skyrig.pipeline.project import ExecutorSpec

    ctx = SimpleNamespace(options=opts, need=lambda kind: dsm_dir / "dsm.tif", out=out, upstream={"dsm": "dsm"},
                          project=SimpleNamespace(executor=ExecutorSpec()), progress=lambda done, total: None)
    s = STAGES["dtm"].run(ctx)
    assert s["cells_by_source"]["building"] > 100
    assert {"classified.laz", "dtm.tif", "ndsm.tif", "dtm.json", "dtm_hillshade.png"} <= {p.name for p in out.iterdir()}
    with rasterio.open(out / "ndsm.tif") as ds:
        nd = ds.read(1)
    _, bidx = scene.buildings.top_height(xx - E0, yy - N0)
    true_nd = top - scene.terrain_height(xx - E0, yy - N0)
    roof = bidx >= 0
    assert np.median(np.abs(nd[roof] - true_nd[roof])) < 0.1


def test_dtm_cog_orthometric_like_the_dsm(tmp_path, egm96_grid):
    """A DTM in orthometric heights (EGM96) is stated as the DSM writer states it: the compound CRS
    UTM 31N + EGM96 height in the GeoKeys, VERTICAL_REFERENCE / GEOID tags; read back with its frame, bands and
    mask; the nDSM of a DSM in another frame is refused."""
    import pyproj
    import rasterio

    from skyrig.dense.grid import DsmGrid, GridSpec
    from skyrig.errors import InputFormatError
    from skyrig.georef.eo import WorldFrame
    from skyrig.io.dsm_cog import cog_problems
    from skyrig.io.terrain_files import read_dtm_cog, write_dtm_cog
    from skyrig.terrain.dtm import DtmGrid, normalised_dsm

    frame = WorldFrame.map("EPSG:32631", str(egm96_grid))
    g = GridSpec(500000.0, 4300000.0, 1.0, 300, 200)
    rng = np.random.default_rng(0)
    h = (50 + rng.normal(0, 1, g.shape)).astype(np.float32)
    h[0, :5] = np.nan
    src = rng.integers(0, 5, g.shape).astype(np.uint8)
    dtm = DtmGrid(g, frame, h, np.full(g.shape, 0.05, np.float32), rng.integers(0, 9, g.shape).astype(np.int32), src,
                  "EGM96 height", {"k": 1})
    out = tmp_path / "dtm.tif"
    write_dtm_cog(out, dtm)
    assert cog_problems(out) == []
    with rasterio.open(out) as ds:
        crs = pyproj.CRS(ds.crs.to_wkt())
        tags = ds.tags()
    assert crs == pyproj.CRS("EPSG:32631+5773")
    assert tags["VERTICAL_REFERENCE"] == "orthometric" and tags["GEOID"] == frame.geoid
    back = read_dtm_cog(out)
    assert back.frame == frame and back.metadata["k"] == 1
    np.testing.assert_array_equal(back.height, h)
    np.testing.assert_array_equal(back.source, src)
    np.testing.assert_array_equal(back.ground_points, dtm.ground_points)
    z = np.zeros(g.shape, np.float32)
    ell = DsmGrid(g, WorldFrame.map("EPSG:32631"), h, np.ones(g.shape, np.int16), z, z, np.zeros(g.shape, bool))
    with pytest.raises(InputFormatError, match="different frames"):
        normalised_dsm(ell, back)


@pytest.mark.slow
def test_autzen_real_laser_against_the_providers_ground(tmp_path):
    """Real airborne laser data (autzen_trim.laz, Oregon State Plane in international feet: the filter runs in
    metres) classified by ``skyrig terrain classify`` against the data provider's ground class.  The provider's
    class 1 holds many points at ground level (its ground class is thinned), so type II is judged on its class-1
    points more than 1 m above its ground (a TIN of its ground points).  Measured (bench/terrain.py): type I 6.7 %,
    that type II 4.6 %; asked: below 10 % and 8 %, and the DTM from skyrig's class within 5 cm (NMAD) of the DTM from
    the provider's."""
    import laspy
    from scipy.interpolate import LinearNDInterpolator

    from conftest import shared_path
    from skyrig.georef.eo import WorldFrame
    from skyrig.terrain import make_dtm

    src = shared_path("autzen-lidar", "autzen_trim.laz")
    r = run("terrain", "classify", src, "-o", tmp_path / "autzen.laz")
    assert r.exit_code == 0, r.output
    prov = laspy.read(src)
    got = laspy.read(tmp_path / "autzen.laz")
    assert got.header.parse_crs() == prov.header.parse_crs()
    truth = np.asarray(prov.classification) == 2
    g = np.asarray(got.classification) == 2
    xyz = np.column_stack([prov.x, prov.y, prov.z]) * 0.3048
    hag = xyz[:, 2] - LinearNDInterpolator(xyz[truth, :2], xyz[truth, 2])(xyz[:, :2])
    high = ~truth & (np.nan_to_num(hag) > 1.0)
    assert np.mean(~g[truth]) < 0.10 and np.mean(g[high]) < 0.08, (np.mean(~g[truth]), np.mean(g[high]))
    frame = WorldFrame.map("EPSG:32610")  # any metre frame for the arrays
    a = make_dtm(xyz, np.where(g, 2, 1), frame, cell_m=1.0)
    b = make_dtm(xyz, np.where(truth, 2, 1), frame, grid=a.grid)
    both = (a.source == 1) & (b.source == 1)
    e = (a.height - b.height)[both]
    assert 1.4826 * np.median(np.abs(e - np.median(e))) < 0.05 and abs(np.median(e)) < 0.05


def test_volume_cli_epochs_and_toe_points(tmp_path):
    """``skyrig terrain volume`` with the two other bases: a conical stockpile (r 15 m, h 5 m) on a sloped plane as
    epoch 1 and the same pile 1 m higher as epoch 2 on a grid shifted by a fraction of a cell (``--base``): net
    = pi r^2 / 3; and epoch 1 above its toe (``--base-points``, 12 points on a 20 m circle): V = pi r^2 h / 3."""
    import shapely

    from skyrig.dense.grid import GridSpec
    from skyrig.georef.eo import WorldFrame
    from skyrig.georef.observations import GroundPoints
    from skyrig.io.gpkg import write_gpkg
    from skyrig.io.points_csv import write_points_csv
    from skyrig.io.terrain_files import write_dtm_cog
    from skyrig.terrain.dtm import DtmGrid

    frame = WorldFrame.map("EPSG:25832")
    R = 15.0

    def surface(path, h, x0, y0, n):
        g = GridSpec(x0, y0, 0.25, n, n)
        xx, yy = g.cell_centres()
        z = 50 + 0.01 * (xx - E0) + h * np.clip(1 - np.hypot(xx - E0, yy - N0) / R, 0, None)
        write_dtm_cog(path, DtmGrid(g, frame, z.astype(np.float32), np.full(g.shape, 0.02, np.float32),
                                    np.ones(g.shape, np.int32), np.ones(g.shape, np.uint8)))

    surface(tmp_path / "e1.tif", 5.0, E0 - 25, N0 + 25, 200)
    surface(tmp_path / "e2.tif", 6.0, E0 - 25.1, N0 + 25.1, 201)
    write_gpkg(tmp_path / "pile.gpkg", {"pile": ([shapely.Point(E0, N0).buffer(19.0, 64)], {"n": [1]})},
               "EPSG:25832")
    r = run("terrain", "volume", "--top", tmp_path / "e2.tif", "--base", tmp_path / "e1.tif",
            "--polygon", tmp_path / "pile.gpkg", "-o", tmp_path / "dv.json")
    assert r.exit_code == 0, r.output
    dv = json.loads((tmp_path / "dv.json").read_text())
    assert abs(dv["net_m3"] - np.pi * R * R / 3) / (np.pi * R * R / 3) < 0.005, dv["net_m3"]
    ang = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    toe = np.column_stack([E0 + 20 * np.cos(ang), N0 + 20 * np.sin(ang), 50 + 0.01 * 20 * np.cos(ang)])
    write_points_csv(tmp_path / "toe.csv", GroundPoints(np.array([f"t{i}" for i in range(12)]), toe, frame))
    r = run("terrain", "volume", "--top", tmp_path / "e1.tif", "--base-points", tmp_path / "toe.csv",
            "--polygon", tmp_path / "pile.gpkg", "-o", tmp_path / "v.json")
    assert r.exit_code == 0, r.output
    v = json.loads((tmp_path / "v.json").read_text())
    v_true = np.pi * R * R * 5.0 / 3
    assert abs(v["net_m3"] - v_true) / v_true < 0.005 and v["cut_m3"] < 1e-6 * v_true, (v["net_m3"], v_true)
