"""The dense stage written tile by tile (skyrig.pipeline.dense_stream) against the whole-array path.

The reference is the path the stage had before: every tile's result collected, :func:`assemble` on whole
grids, and the whole-array writers (``write_dsm_cog``, ``write_hillshade_png``, ``write_dense_cloud``).  The
streamed stage (:func:`run_dsm`) must give the same DSM bands and tags, the same hillshade pixels, the same cloud
points (records, in order) and the same summary figures, on a block cut into several tiles (so that the
neighbour confirmation and the hillshade cross tile edges), with and without hole filling, and whatever order
the tiles come in.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from test_dense import CRS, _block, _to_map

from skyrig.dense.pairs import PairConfig
from skyrig.dense.surface import DenseConfig, _TileJob, assemble, plan_dense
from skyrig.georef.eo import WorldFrame

RANGE = (40.0, 75.0)


@pytest.fixture(scope="module")
def small_block(tmp_path_factory):
    import cv2

    eo, cams, imgs = _block()
    keep = np.flatnonzero(np.isin(eo.image, ["s0_e1.png", "s0_e2.png", "s1_e1.png", "s1_e2.png"]))
    eo, imgs = eo.subset(keep), [imgs[i] for i in keep]
    d = tmp_path_factory.mktemp("stream_images")
    paths = []
    for n, im in zip(eo.image, imgs):
        assert cv2.imwrite(str(d / n), im[..., ::-1])
        paths.append(str(d / n))
    c = _to_map(np.array([-14.0, 14.0]), np.array([-11.0, 11.0]), np.array([50.0, 50.0]))
    return eo, cams, paths, (c[0, 0], c[0, 1], c[1, 0], c[1, 1])


def _whole_path(eo, cams, paths, area, cfg, out: Path):
    """The stage as it was: all tile results in memory, whole-array assembly and writers."""
    from skyrig.io.dense_laz import write_dense_cloud
    from skyrig.io.dsm_cog import write_dsm_cog, write_hillshade_png
    from skyrig.pipeline.dense import ImageFiles

    loader = ImageFiles(paths, [(cams["cam"].width, cams["cam"].height)] * len(paths))
    plan = plan_dense(eo, cams, WorldFrame.map(CRS), RANGE, area, cfg)
    job = _TileJob(plan, loader)
    tiles = [job(k) for k in range(len(plan.tiles))]
    dsm, cloud, _ = assemble(plan, tiles)
    out.mkdir()
    write_dsm_cog(out / "dsm.tif", dsm)
    write_hillshade_png(out / "dsm_hillshade.png", dsm)
    write_dense_cloud(out / "cloud.laz", cloud)
    valid = np.isfinite(dsm.height)
    return plan, tiles, {"cells_valid": int(valid.sum()), "height_sigma_median_m": float(np.nanmedian(dsm.sigma)),
                         "support_median": float(np.median(dsm.support[valid])), "cloud_points": len(cloud)}


def _config(fill: bool) -> DenseConfig:
    # 50-cell tiles: 3 x 3 of them, so that the confirmation, the filling and the hillshade cross tile edges
    return DenseConfig(tile_cells=50, block_px=256, pairs=PairConfig(pairs_per_image=4), fill_holes=fill,
                       fill_max_cells=6)


@pytest.fixture(scope="module", params=[False, True], ids=["no-fill", "fill"])
def whole(request, small_block, tmp_path_factory):
    eo, cams, paths, area = small_block
    out = tmp_path_factory.mktemp("whole") / "out"
    return (out, request.param, *_whole_path(eo, cams, paths, area, _config(request.param), out))


def _same_products(a: Path, b: Path) -> None:
    import laspy
    import rasterio
    from PIL import Image

    with rasterio.open(a / "dsm.tif") as x, rasterio.open(b / "dsm.tif") as y:
        assert x.descriptions == y.descriptions and x.units == y.units and x.crs == y.crs
        assert x.transform == y.transform and x.tags() == y.tags() and x.nodata == y.nodata
        assert x.overviews(1) == y.overviews(1) and x.block_shapes == y.block_shapes
        assert np.array_equal(x.read(), y.read())
    ha, hb = (np.asarray(Image.open(p / "dsm_hillshade.png")) for p in (a, b))
    assert ha.shape == hb.shape and ha.shape[-1] == 2 and np.array_equal(ha, hb)
    la, lb = laspy.read(a / "cloud.laz"), laspy.read(b / "cloud.laz")
    for k in ("scales", "offsets", "mins", "maxs", "point_count"):
        assert np.array_equal(getattr(la.header, k), getattr(lb.header, k)), k
    assert la.header.parse_crs() == lb.header.parse_crs()
    assert la.points.array.tobytes() == lb.points.array.tobytes()  # bit for bit (NaN sigmas included)


def test_streamed_stage_writes_what_the_whole_arrays_give(small_block, whole, tmp_path):
    from skyrig.pipeline.dense import run_dsm

    eo, cams, paths, area = small_block
    ref, fill, plan, _, figures = whole
    assert len(plan.tiles) >= 6
    (tmp_path / ".streamed.scratch-killed").mkdir()  # what a killed run left: cleared
    res = run_dsm(eo, cams, paths, WorldFrame.map(CRS), RANGE, tmp_path / "streamed", area=area,
                  config=_config(fill), executor="serial")
    _same_products(ref, tmp_path / "streamed")
    summary = json.loads((tmp_path / "streamed" / "dense.json").read_text())
    for k, v in figures.items():
        assert summary[k] == v, k
    assert 0.3 < figures["cells_valid"] / summary["cells"] < 1.0
    if fill:
        import rasterio

        with rasterio.open(tmp_path / "streamed" / "dsm.tif") as ds:
            assert ds.read(5).sum() > 0  # holes were filled, across tiles as in the whole grid
    assert not [p for p in tmp_path.iterdir() if "scratch" in p.name]  # the scratch folder is gone
    assert res.cloud is not None and res.summary["cloud_points"] == figures["cloud_points"]


def test_tiles_in_any_order_give_the_same_products(whole, tmp_path):
    """A cluster hands tiles over as they finish: written in reverse order, the products are the same."""
    from skyrig.pipeline.dense_stream import StreamedDsm

    ref, _, plan, tiles, figures = whole
    out = tmp_path / "reversed"
    (tmp_path / "scratch").mkdir()
    out.mkdir()
    with StreamedDsm(plan, tmp_path / "scratch") as s:
        for k in reversed(range(len(plan.tiles))):
            s.add(k, tiles[k])
        s.finish()
        assert (s.cells_valid, s.sigma_median, s.support_median) == (
            figures["cells_valid"], figures["height_sigma_median_m"], figures["support_median"])
        assert s.publish(out / "dsm.tif", out / "dsm_hillshade.png", out / "cloud.laz") == figures["cloud_points"]
    _same_products(ref, out)


@pytest.mark.parametrize("n", [1, 2, 7, 1000, 100001])
def test_streamed_median_is_numpys(n):
    """The two-look median of float32 values in pieces equals ``np.nanmedian`` of them all (ties, negative
    values, NaN, even and odd counts)."""
    from skyrig.pipeline.dense_stream import _Kth

    rng = np.random.default_rng(n)
    v = rng.lognormal(-3, 1, n).astype(np.float32)
    v[: n // 3] = np.round(v[: n // 3], 2)  # ties
    v[n // 2: n // 2 + n // 5] *= -1
    v = np.concatenate([v, np.full(5, np.nan, np.float32)])
    pieces = np.array_split(rng.permutation(v), 7)
    k = _Kth()
    for p in pieces:
        k.count(p[np.isfinite(p)])
    k.refine(iter(pieces))
    assert k.median() == float(np.nanmedian(v))
