"""The direct path of a tile's points (``CellSorter.add_block`` / ``_kernels.triangulate_take``) against the path it
replaces: ``block_points`` (triangulation and wall test), the local -> map polynomial (``poly_map``) and
``CellSorter.add`` -- the same rows in every bucket of the sorter, bit for bit, and so the same grid and cloud."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from skyrig.dense.fusion import CellSorter, FusionConfig
from skyrig.dense.grid import GridSpec
from skyrig.dense.sgm import SgmConfig
from skyrig.dense.stereo import Block, block_points, triangulation_args


def _scene(seed: int):  # type: ignore[no-untyped-def]
    """A rectified block looking down at ground (depth 100 m) with a building (roof at 90 m, a wall between), holes,
    noise and colour; a rotated, offset rectified frame; a smooth polynomial standing in for local -> map."""
    rng = np.random.default_rng(seed)
    f, B = 1000.0, 20.0
    u0, v0 = -40, -30
    H, W = 60, 80
    u = np.arange(W, dtype=float) + u0
    D = np.where(u < 0, 100.0, np.where(u <= 8, 100.0 - 1.25 * u, 90.0))  # ground, wall (slanted), roof
    disp = np.repeat((f * B / D)[None, :], H, axis=0) + rng.normal(0, 0.05, (H, W))
    disp = disp.astype(np.float32)
    disp[rng.random(disp.shape) < 0.1] = np.nan
    a = np.radians(20.0)
    R = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    rect = SimpleNamespace(focal_px=f, base_m=B, rotation=R, centres=np.array([[5.0, -3.0, 120.0], [25.0, -3.0, 120.0]]))
    blk = Block(u0, u0 + W, v0, v0 + H, float(np.nanmin(disp)) - 1, float(np.nanmax(disp)) + 1)
    colour = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    coef = np.zeros((14, 3))
    coef[1, 0], coef[2, 1], coef[3, 2] = 50.0, 50.0, 40.0  # ~identity on the box, plus small curvature terms
    coef[4:, :] = rng.normal(0, 1e-3, (10, 3))
    poly = (np.array([0.0, 0.0, 10.0]), np.array([50.0, 50.0, 40.0]), coef, np.array([500000.0, 5.4e6, 47.0]))
    return rect, blk, disp, colour, poly


def _poly(xyz, poly):  # type: ignore[no-untyped-def]
    from skyrig.dense._kernels import poly_map

    return poly_map(np.ascontiguousarray(xyz, np.float64), *poly)


@pytest.mark.parametrize("cloud", [True, False])
@pytest.mark.parametrize("wall", [0.3, 0.0])
def test_direct_points_equal_block_points_then_add(cloud, wall):
    cfg = SgmConfig(wall_max_nz=wall)
    grid = GridSpec(500000.0 - 10.0, 5.4e6 + 14.0, 0.25, 100, 90)
    # a tile's bounds cutting the block's points (some points are left out on every side)
    bounds = (500000.0 - 6.0, 5.4e6 - 6.0, 500000.0 + 12.0, 5.4e6 + 10.0)
    old = CellSorter(grid, 0.2 if cloud else 0.0, cloud=cloud, capacity=10000)
    new = CellSorter(grid, 0.2 if cloud else 0.0, cloud=cloud, capacity=10000)
    n_old = n_new = 0
    for pid, seed in ((0, 1), (3, 2)):
        rect, blk, disp, colour, poly = _scene(seed)
        pp = block_points(rect, blk, disp, colour, cfg)  # type: ignore[arg-type]
        n_old += old.add(pid, _poly(pp.xyz, poly), pp.sigma_h, pp.sigma_3d, pp.rgb, pp.normal, bounds=bounds)
        n_new += new.add_block(pid, triangulation_args(rect, blk, disp, colour, cfg), poly, bounds)  # type: ignore[arg-type]
    assert 0 < n_new == n_old < 2 * 60 * 80 * 0.9  # some points outside the bounds
    # the same points in every bucket, in the same order (the chunks of the buckets may be taken in another order:
    # add_block writes a band of rows bucket by bucket, add point by point)
    ro, rn = old.rows(), new.rows()
    assert len(ro) == len(rn) == n_new
    if wall:
        assert np.isnan(new.arrays["sh"][rn]).any()  # the wall's points lost their DSM height
    for k, a in old.arrays.items():
        if k != "chunk_bucket":
            np.testing.assert_array_equal(new.arrays[k][rn], a[ro], err_msg=k)
    bo = np.repeat(old.arrays["chunk_bucket"], old.CHUNK)[ro]  # each row's bucket
    np.testing.assert_array_equal(np.repeat(new.arrays["chunk_bucket"], new.CHUNK)[rn], bo)
    assert np.all(np.diff(bo) >= 0) and len(np.unique(bo)) > 4
    lo, co = old.fuse(FusionConfig(), True, np.eye(3))
    ln, cn = new.fuse(FusionConfig(), True, np.eye(3))
    assert lo is not None and ln is not None and np.isfinite(lo[0]).sum() > 100
    for a, b in zip(lo, ln):
        np.testing.assert_array_equal(a, b)
    if cloud:
        assert co is not None and cn is not None and len(co[0]) > 100
        for a, b in zip(co, cn):
            np.testing.assert_array_equal(a, b)


def test_block_points_equal_the_ray_formula():
    """The kernels multiply by 1 / f where the formula divides by f (a product per term instead of a division): the
    points stay within a few ulps of the formula computed plainly in NumPy (depth D = f B / d, the rectified ray
    (u D / f, -v D / f, -D), rotated and offset by the left centre) - far below any precision of a point."""
    from skyrig.dense._kernels import triangulate_block

    rect, blk, disp, colour, _ = _scene(5)
    args = triangulation_args(rect, blk, disp, colour, SgmConfig(wall_max_nz=0.0))  # type: ignore[arg-type]
    rr, cc, xyz = triangulate_block(*args[:10])[:3]
    assert 0.5 * np.isfinite(disp).sum() < len(rr) <= np.isfinite(disp).sum()  # grazing pixels dropped
    D = rect.focal_px * rect.base_m / disp[rr, cc].astype(np.float64)
    u, v = blk.u0 + cc, blk.v0 + rr
    ray = np.stack([u * D / rect.focal_px, -v * D / rect.focal_px, -D], axis=1)
    want = rect.centres[0] + ray @ rect.rotation.T
    np.testing.assert_allclose(xyz, want, rtol=0, atol=1e-9)
