"""COPC output (issue 31: classified clouds for web viewers), read back by an independent reader: laspy's
``CopcReader`` (its own octree walk and LAZ decompression).  Every point exactly once with its class and colour, the
CRS kept, a box query equal to the points in that box, and the root level an even sample (one point per cell of
its grid)."""

from __future__ import annotations

import numpy as np
import pytest

laspy = pytest.importorskip("laspy")
pytest.importorskip("copclib", reason="copclib (copc-lib) is not installed")


def _cloud(n=120_000, seed=1):
    rng = np.random.default_rng(seed)
    xyz = np.c_[rng.uniform(500000, 500400, n), rng.uniform(5800000, 5800300, n), rng.normal(100, 5, n)]
    return np.round(xyz, 3), rng.integers(1, 7, n).astype(np.uint8), rng.integers(0, 65535, (n, 3))


def test_copc_round_trip_query_and_root_sample(tmp_path):
    from pyproj import CRS

    from skyrig.io.copc import write_copc

    xyz, cls, rgb = _cloud()
    wkt = CRS.from_epsg(25832).to_wkt()
    info = write_copc(tmp_path / "c.copc.laz", xyz, cls, rgb, wkt, max_node_points=10_000, grid=64)
    assert info["points"] == len(xyz) and info["depth"] >= 1
    assert not list(tmp_path.glob(".*partial"))
    # the CRS is in an extended VLR (LAS 1.4), which laspy's COPC reader does not load: read as plain LAZ
    assert laspy.read(tmp_path / "c.copc.laz").header.parse_crs().to_epsg() == 25832
    with laspy.CopcReader.open(tmp_path / "c.copc.laz") as r:
        pts = r.query()
        X = np.c_[pts.x, pts.y, pts.z]
        assert len(X) == len(xyz)
        a, b = np.lexsort(xyz.T), np.lexsort(np.round(X, 3).T)
        assert np.abs(xyz[a] - np.round(X, 3)[b]).max() < 1e-9
        assert np.array_equal(cls[a], np.asarray(pts.classification)[b])
        assert np.array_equal(rgb[a], np.c_[pts.red, pts.green, pts.blue][b])
        lo, hi = np.array([500100.0, 5800100.0, 0.0]), np.array([500150.0, 5800160.0, 200.0])
        q = r.query(laspy.copc.Bounds(mins=lo, maxs=hi))
        inside = np.all((xyz >= lo) & (xyz <= hi), axis=1)
        assert len(q) == int(inside.sum())
        root = r.query(level=0)
        R = np.c_[root.x, root.y, root.z]
    # the root cube (centre, half size) as written: one point per cell of its 64^3 grid
    c, h = (xyz.min(0) + xyz.max(0)) / 2, max((xyz.max(0) - xyz.min(0)).max() / 2, 1.0) * 1.0001
    cell = np.floor((R - (c - h)) / (2 * h / 64)).astype(int)
    assert len(np.unique(cell, axis=0)) == len(R) and 0 < len(R) < len(xyz)


def test_terrain_classify_writes_copc_and_refuses_bad_input(tmp_path):
    from click.testing import CliRunner

    from skyrig.cli import main
    from skyrig.errors import InputFormatError
    from skyrig.io.copc import write_copc

    xyz, cls, rgb = _cloud(20_000, seed=2)
    hdr = laspy.LasHeader(point_format=7, version="1.4")
    hdr.scales, hdr.offsets = np.full(3, 0.001), np.floor(xyz.min(0))
    from pyproj import CRS

    hdr.add_crs(CRS.from_epsg(25832))
    las = laspy.LasData(hdr)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.red, las.green, las.blue = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    las.write(tmp_path / "in.laz")
    r = CliRunner().invoke(main, ["terrain", "classify", str(tmp_path / "in.laz"), "-o", str(tmp_path / "cls.laz"),
                                  "--copc", str(tmp_path / "cls.copc.laz")], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    plain = laspy.read(tmp_path / "cls.laz")
    with laspy.CopcReader.open(tmp_path / "cls.copc.laz") as rd:
        p = rd.query()
        assert len(p) == len(plain.points)
        a = np.lexsort(np.c_[plain.x, plain.y, plain.z].T)
        b = np.lexsort(np.c_[p.x, p.y, p.z].T)
        assert np.array_equal(np.asarray(plain.classification)[a], np.asarray(p.classification)[b])
    with pytest.raises(InputFormatError, match="finite"):
        write_copc(tmp_path / "bad.copc.laz", np.array([[0.0, 0.0, np.nan]]))
    with pytest.raises(InputFormatError, match="classification"):
        write_copc(tmp_path / "bad.copc.laz", xyz, cls[:5])
    assert not (tmp_path / "bad.copc.laz").exists()
