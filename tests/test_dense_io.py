"""DSM COG and dense-cloud LAZ outputs, read back with GDAL (rasterio) and laspy directly."""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pyproj
import pytest
import rasterio
from PIL import Image

from skyrig.dense.grid import DenseCloud, DsmGrid, GridSpec
from skyrig.errors import CRSError, InputFormatError
from skyrig.georef.eo import WorldFrame
from skyrig.io import dense_laz, dsm_cog
from skyrig.io.dense_laz import read_dense_cloud, write_dense_cloud
from skyrig.io.dsm_cog import cog_problems, hillshade, read_dsm_cog, write_dsm_cog, write_hillshade_png

GRID = GridSpec(x0=512_000.0, y0=5_402_000.0, cell_m=0.5, width=700, height=600)


def make_dsm(frame: WorldFrame) -> DsmGrid:
    rng = np.random.default_rng(7)
    x, y = GRID.cell_centres()
    h = (250.0 + 0.01 * (x - GRID.x0) - 0.02 * (GRID.y0 - y) + rng.normal(0, 0.05, GRID.shape)).astype(np.float32)
    h[100:140, 200:260] = np.nan  # a hole
    valid = np.isfinite(h)
    support = np.where(valid, rng.integers(1, 7, GRID.shape), 0).astype(np.int16)
    spread = np.where(support >= 2, 0.03, np.nan).astype(np.float32)
    sigma = np.where(valid, 0.04, np.nan).astype(np.float32)
    filled = np.zeros(GRID.shape, bool)
    filled[300:310, 300:310] = True
    return DsmGrid(GRID, frame, h, support, spread, sigma, filled, "test heights", {"pairs": 12})


def make_cloud(frame: WorldFrame, n: int = 2000) -> DenseCloud:
    rng = np.random.default_rng(3)
    xyz = np.column_stack([rng.uniform(512_000, 512_350, n), rng.uniform(5_401_700, 5_402_000, n),
                           rng.uniform(240, 280, n)])
    xyz[0] = [512_123.4567, 5_401_890.1234, 251.2345]
    nrm = rng.normal(size=(n, 3)).astype(np.float32)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    rgb = rng.integers(0, 256, (n, 3)).astype(np.uint8)
    rgb[0] = [255, 0, 128]
    return DenseCloud(xyz, rgb, nrm, rng.integers(1, 9, n).astype(np.int16), rng.uniform(0.01, 0.1, n).astype(np.float32),
                      frame)


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


@pytest.fixture
def frame_ell() -> WorldFrame:
    return WorldFrame.map("EPSG:25832")


@pytest.fixture
def frame_geoid(egm96_grid: Path) -> WorldFrame:
    return WorldFrame.map("EPSG:32631", str(egm96_grid))


# ------------------------------------------------------------------------------------------------ COG


def check_cog_common(path: Path, dsm: DsmGrid) -> None:
    with rasterio.open(path) as ds:
        assert ds.driver == "GTiff" and ds.count == 5 and ds.dtypes[0] == "float32"
        assert ds.descriptions == dsm_cog.DSM_BANDS
        assert ds.units[0] == "metre" and ds.units[3] == "metre"
        assert ds.tags(ns="IMAGE_STRUCTURE")["LAYOUT"] == "COG"
        assert all(b == (256, 256) for b in ds.block_shapes)
        assert ds.overviews(1) == [2, 4]
        assert ds.nodata == dsm_cog.DSM_NODATA
        assert tuple(ds.transform)[:6] == GRID.transform
        # a known cell at a known map coordinate: cell (row 250, col 400)
        x, y = GRID.x0 + (400 + 0.5) * GRID.cell_m, GRID.y0 - (250 + 0.5) * GRID.cell_m
        assert ds.index(x, y) == (250, 400)
        (v,) = next(ds.sample([(x, y)], indexes=1))
        assert v == dsm.height[250, 400]
        # nodata honoured
        hm = ds.read(1, masked=True)
        assert np.array_equal(hm.mask, ~np.isfinite(dsm.height))
        (hole,) = next(ds.sample([(GRID.x0 + 220 * 0.5, GRID.y0 - 120 * 0.5)], indexes=1, masked=True))
        assert np.ma.is_masked(hole)
        np.testing.assert_array_equal(ds.read(2), dsm.support)
        np.testing.assert_array_equal(ds.read(5) > 0.5, dsm.filled)
        assert ds.overviews(1) and ds.read(1, out_shape=(150, 175)).shape == (150, 175)
    assert cog_problems(path) == []
    assert leftovers(path.parent) == [path.name]  # no side-car .aux.xml, no temporary
    assert (path.stat().st_mode & 0o777) != 0o600  # published with normal permissions


def test_cog_ellipsoidal_25832(tmp_path: Path, frame_ell: WorldFrame) -> None:
    dsm = make_dsm(frame_ell)
    out = tmp_path / "dsm.tif"
    write_dsm_cog(out, dsm)
    check_cog_common(out, dsm)
    with rasterio.open(out) as ds:
        assert pyproj.CRS(ds.crs.to_wkt()) == pyproj.CRS("EPSG:25832")
        tags = ds.tags()
    assert tags["VERTICAL_REFERENCE"] == "ellipsoidal" and "GEOID" not in tags
    assert "EPSG:4937" in tags["VERTICAL_CRS"]  # ETRS89 geographic 3D: the ellipsoid's CRS
    assert pyproj.CRS(tags["CRS_3D_WKT"]) == pyproj.CRS("EPSG:25832").to_3d()
    back = read_dsm_cog(out)
    assert back.frame == frame_ell and back.grid == GRID
    np.testing.assert_array_equal(back.height, dsm.height)
    np.testing.assert_array_equal(back.spread, dsm.spread)
    np.testing.assert_array_equal(back.sigma, dsm.sigma)
    np.testing.assert_array_equal(back.support, dsm.support)
    np.testing.assert_array_equal(back.filled, dsm.filled)
    assert back.vertical_reference == "test heights" and back.metadata == {"pairs": 12}


def test_cog_geoid_32631_compound(tmp_path: Path, frame_geoid: WorldFrame) -> None:
    dsm = make_dsm(frame_geoid)
    out = tmp_path / "dsm.tif"
    write_dsm_cog(out, dsm)
    check_cog_common(out, dsm)
    with rasterio.open(out) as ds:
        crs = pyproj.CRS(ds.crs.to_wkt())
        tags = ds.tags()
    assert crs.is_compound and crs == pyproj.CRS("EPSG:32631+5773")  # UTM 31N + EGM96 height, in the GeoKeys
    assert tags["VERTICAL_REFERENCE"] == "orthometric" and tags["GEOID"] == frame_geoid.geoid
    back = read_dsm_cog(out)
    assert back.frame == frame_geoid
    np.testing.assert_array_equal(back.height, dsm.height)


def test_cog_unidentified_geoid_is_tagged(tmp_path: Path) -> None:
    frame = WorldFrame.map("EPSG:25832", "my_local_geoid_v3.tif")  # a grid name PROJ's database does not know
    dsm = make_dsm(frame)
    out = tmp_path / "dsm.tif"
    write_dsm_cog(out, dsm)
    with rasterio.open(out) as ds:
        assert pyproj.CRS(ds.crs.to_wkt()) == pyproj.CRS("EPSG:25832")
        tags = ds.tags()
    assert tags["VERTICAL_REFERENCE"] == "orthometric" and tags["GEOID"] == "my_local_geoid_v3.tif"
    full = pyproj.CRS(tags["CRS_3D_WKT"])
    assert full.is_compound and full.sub_crs_list[1].to_json_dict()["geoid_model"]["name"] == "my_local_geoid_v3.tif"
    assert read_dsm_cog(out).frame == frame


def test_cog_without_overviews_and_errors(tmp_path: Path, frame_ell: WorldFrame) -> None:
    out = tmp_path / "no_ovr.tif"
    write_dsm_cog(out, make_dsm(frame_ell), overviews=False)
    with rasterio.open(out) as ds:
        assert ds.overviews(1) == []
    assert cog_problems(out, expect_overviews=False) == []
    assert "no internal overviews" in cog_problems(out)
    with pytest.raises(CRSError):
        write_dsm_cog(tmp_path / "x.tif", make_dsm(WorldFrame.ecef()))
    with pytest.raises(InputFormatError, match="blocksize"):
        write_dsm_cog(tmp_path / "x.tif", make_dsm(frame_ell), blocksize=300)
    with pytest.raises(InputFormatError, match="not found"):
        read_dsm_cog(tmp_path / "missing.tif")
    assert leftovers(tmp_path) == ["no_ovr.tif"]


def test_plain_geotiff_is_not_a_cog(tmp_path: Path) -> None:
    p = tmp_path / "plain.tif"
    with rasterio.open(p, "w", driver="GTiff", width=600, height=600, count=1, dtype="float32",
                       crs="EPSG:25832", transform=rasterio.Affine(1, 0, 0, 0, -1, 600)) as ds:
        ds.write(np.zeros((600, 600), np.float32), 1)
    problems = cog_problems(p)
    assert any("not tiled" in s for s in problems) and any("structural" in s for s in problems)


def test_cog_failure_leaves_nothing(tmp_path: Path, frame_ell: WorldFrame, monkeypatch: pytest.MonkeyPatch) -> None:
    dsm = make_dsm(frame_ell)
    out = tmp_path / "dsm.tif"
    # 1) failure after GDAL wrote the whole temporary file (the layout check rejects it)
    monkeypatch.setattr(dsm_cog, "cog_problems", lambda *a, **k: ["simulated"])
    with pytest.raises(InputFormatError, match="simulated"):
        write_dsm_cog(out, dsm)
    assert leftovers(tmp_path) == []
    monkeypatch.undo()
    # 2) failure in the middle of GDAL's copy, with an older file at the path: it stays untouched
    out.write_bytes(b"old")
    import rasterio.shutil

    def half_copy(src, dst, **kw):
        Path(dst).write_bytes(b"II*\x00partial")
        raise rasterio.errors.RasterioIOError("disk full (simulated)")

    monkeypatch.setattr(rasterio.shutil, "copy", half_copy)
    with pytest.raises(rasterio.errors.RasterioIOError, match="simulated"):
        write_dsm_cog(out, dsm)
    assert leftovers(tmp_path) == ["dsm.tif"] and out.read_bytes() == b"old"


# ------------------------------------------------------------------------------------------- hillshade


def test_hillshade_formula_against_sun_vector() -> None:
    """Horn/Burrough shading of tilted planes equals the cosine between surface normal and sun (az 315, alt 45)."""
    cell = 2.0
    sun = np.array([np.cos(np.radians(45)) * np.sin(np.radians(315)), np.cos(np.radians(45)) * np.cos(np.radians(315)),
                    np.sin(np.radians(45))])
    x, y = GridSpec(0.0, 100.0, cell, 20, 20).cell_centres()
    for gx, gy in [(0.3, 0.0), (-0.3, 0.0), (0.0, 0.5), (0.0, -0.5), (0.4, 0.4), (-1.0, 1.0)]:
        z = gx * x + gy * y  # plane rising gx per metre east, gy per metre north
        n = np.array([-gx, -gy, 1.0]) / np.sqrt(1 + gx * gx + gy * gy)
        want = max(float(n @ sun), 0.0)
        np.testing.assert_allclose(hillshade(z, cell)[5:15, 5:15], want, atol=1e-12)
    assert hillshade(np.zeros((3, 3)), 1.0)[1, 1] == pytest.approx(np.cos(np.radians(45)))


def test_hillshade_png(tmp_path: Path, frame_ell: WorldFrame) -> None:
    dsm = make_dsm(frame_ell)
    out = tmp_path / "hs.png"
    write_hillshade_png(out, dsm)
    img = Image.open(out)
    assert img.mode == "LA" and img.size == (GRID.width, GRID.height)
    a = np.asarray(img)
    assert np.all(a[120, 220, 1] == 0)  # hole transparent
    assert a[400, 500, 1] == 255 and 100 < a[400, 500, 0] < 255
    assert leftovers(tmp_path) == ["hs.png"]


# ------------------------------------------------------------------------------------------------ LAZ


def check_laz_common(path: Path, cloud: DenseCloud) -> laspy.LasData:
    las = laspy.read(path)
    assert las.header.version == laspy.header.Version(1, 4) and las.header.point_format.id == 7
    assert las.header.point_count == len(cloud)
    x, y, z = np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)
    sx, sy, sz = las.header.scales
    assert abs(x[0] - 512_123.4567) <= sx / 2 + 1e-9 and abs(y[0] - 5_401_890.1234) <= sy / 2 + 1e-9
    assert abs(z[0] - 251.2345) <= sz / 2 + 1e-9
    assert np.max(np.abs(np.column_stack([x, y, z]) - cloud.xyz)) <= max(sx, sy, sz) / 2 + 1e-9
    assert (las.red[0], las.green[0], las.blue[0]) == (65535, 0, 128 * 257)
    np.testing.assert_array_equal(np.column_stack([las.red, las.green, las.blue]), cloud.rgb.astype(np.uint16) * 257)
    assert list(las.point_format.extra_dimension_names) == ["support", "sigma", "normal_x", "normal_y", "normal_z"]
    assert las.point_format.dimension_by_name("support").dtype == np.int16
    assert las.point_format.dimension_by_name("sigma").dtype == np.float32
    np.testing.assert_array_equal(np.asarray(las["support"]), cloud.support)
    np.testing.assert_array_equal(np.asarray(las["sigma"]), cloud.sigma)
    np.testing.assert_array_equal(np.asarray(las["normal_z"]), cloud.normal[:, 2])
    assert leftovers(path.parent) == [path.name]
    return las


def test_laz_ellipsoidal_25832(tmp_path: Path, frame_ell: WorldFrame) -> None:
    cloud = make_cloud(frame_ell)
    out = tmp_path / "cloud.laz"
    write_dense_cloud(out, cloud)
    las = check_laz_common(out, cloud)
    assert tuple(las.header.scales) == (0.001, 0.001, 0.001)
    crs = las.header.parse_crs()
    assert crs == pyproj.CRS("EPSG:25832").to_3d()  # projected CRS + ellipsoidal height axis
    assert crs.axis_info[2].name.lower().startswith("ellipsoidal height")
    back = read_dense_cloud(out)
    assert back.frame == frame_ell and len(back) == len(cloud)
    np.testing.assert_array_equal(back.rgb, cloud.rgb)
    np.testing.assert_array_equal(back.normal, cloud.normal)
    np.testing.assert_array_equal(back.support, cloud.support)
    np.testing.assert_array_equal(back.sigma, cloud.sigma)
    assert np.max(np.abs(back.xyz - cloud.xyz)) <= 0.0005 + 1e-9


def test_laz_geoid_32631_compound(tmp_path: Path, frame_geoid: WorldFrame) -> None:
    cloud = make_cloud(frame_geoid)
    out = tmp_path / "cloud.laz"
    write_dense_cloud(out, cloud)
    las = check_laz_common(out, cloud)
    assert las.header.parse_crs() == pyproj.CRS("EPSG:32631+5773")
    assert read_dense_cloud(out).frame == frame_geoid


def test_laz_geographic_scale(tmp_path: Path) -> None:
    frame = WorldFrame.map("EPSG:4326")
    c = make_cloud(WorldFrame.map("EPSG:25832"))
    lonlat = c.xyz.copy()
    lonlat[:, 0] = 9.0 + (c.xyz[:, 0] - 512_000) * 1e-5
    lonlat[:, 1] = 48.7 + (c.xyz[:, 1] - 5_401_700) * 1e-5
    cloud = DenseCloud(lonlat, c.rgb, c.normal, c.support, c.sigma, frame)
    write_dense_cloud(tmp_path / "geo.laz", cloud)
    las = laspy.read(tmp_path / "geo.laz")
    assert tuple(las.header.scales) == (1e-8, 1e-8, 0.001)
    assert las.header.parse_crs() == pyproj.CRS("EPSG:4979")
    assert np.max(np.abs(np.asarray(las.x) - lonlat[:, 0])) <= 0.5e-8 + 1e-12
    with pytest.raises(CRSError, match="scale"):
        write_dense_cloud(tmp_path / "bad.laz", cloud, scale=0.001)  # 0.001 degree = 111 m
    assert leftovers(tmp_path) == ["geo.laz"]


def test_laz_failure_leaves_nothing(tmp_path: Path, frame_ell: WorldFrame, monkeypatch: pytest.MonkeyPatch) -> None:
    cloud = make_cloud(frame_ell)
    out = tmp_path / "cloud.laz"

    def half_write(self, dest, *a, **k):
        Path(dest).write_bytes(b"LASF partial")
        raise OSError("disk full (simulated)")

    monkeypatch.setattr(laspy.LasData, "write", half_write)
    with pytest.raises(OSError, match="simulated"):
        write_dense_cloud(out, cloud)
    assert leftovers(tmp_path) == []
    bad = DenseCloud(cloud.xyz, cloud.rgb[:5], cloud.normal, cloud.support, cloud.sigma, frame_ell)
    with pytest.raises(InputFormatError, match="rgb"):
        write_dense_cloud(out, bad)
    assert leftovers(tmp_path) == []


def test_coordinate_scale_units() -> None:
    assert dense_laz.coordinate_scale(pyproj.CRS("EPSG:2263").to_3d())[:2] == (0.001, 0.001)  # US survey feet
    assert dense_laz.coordinate_scale(pyproj.CRS("EPSG:4979")) == (1e-8, 1e-8, 0.001)
