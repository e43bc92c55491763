"""The dense chain's speed work must not change what it computes (issue 10, bench/dense.py).

* the compiled left-right check and content masks (:func:`skyrig.dense._kernels.check_disparities`) against a
  plain numpy statement of the same rules on random disparity maps;
* a block matched on its tight crop (:func:`skyrig.dense.stereo.block_crop`: only the columns that can reach the
  right image, context only where both images carry content) against the same block matched on a wide crop
  (context and search width on every side, zeros beyond the images), on the ray-cast scene of ``test_dense``;
* blocks of a pair: the fewest of at most ``block_px``, equal within a pixel, tiling the rectified bounds;
* a ground tile's grid and cloud fused from one sort of its blocks' points (:class:`skyrig.dense.fusion.CellSorter`)
  against :func:`skyrig.dense.fusion.fuse_grid` and the voxel rule in plain Python.
"""

from __future__ import annotations

import numpy as np
import pytest

from skyrig.dense.sgm import SgmConfig, disparity_window, match_crop


def _reference_check(d16, e16, vl, vr, tol, shift, full):
    """The rules in numpy, as match_crop stated them before they were compiled."""
    H, W = vl.shape
    d = np.full((H, W), np.nan, np.float32)
    d[:, :d16.shape[1]] = np.where(d16 >= 0, d16.astype(np.float32) / 16.0, np.nan)
    if full:
        e = np.where(e16 >= 0, e16.astype(np.float32) / 16.0, np.nan)
        jr = np.arange(W)[None, :] - d
        ok = np.isfinite(jr) & (jr >= 0) & (jr <= W - 1)
        ji = np.clip(np.round(np.nan_to_num(jr, nan=0.0)).astype(np.int64), 0, W - 1)
        with np.errstate(invalid="ignore"):
            ok &= np.abs(np.take_along_axis(e, ji, axis=1) - d) <= max(tol, 0.5)
        d[~ok] = np.nan
    d[~vl] = np.nan
    cols = np.arange(W)[None, :] - d
    ci = np.clip(np.round(np.nan_to_num(cols, nan=-1)).astype(np.int64), 0, W - 1)
    d[~(np.take_along_axis(vr, ci, axis=1) & np.isfinite(cols) & (cols >= 0))] = np.nan
    return d + shift


@pytest.mark.parametrize("full", [True, False])
def test_compiled_check_equals_numpy_rules(full):
    from skyrig.dense._kernels import check_disparities

    rng = np.random.default_rng(7)
    H, W, n = 50, 160, 32
    wd = W - n if full else W
    d16 = rng.integers(-40, 16 * n, (H, wd)).astype(np.int16)
    e16 = rng.integers(-40, 16 * n, (H, W)).astype(np.int16)
    for r, c in zip(rng.integers(0, H, 3000), rng.integers(0, wd, 3000)):  # many consistent pairs, some off by <= 2
        if d16[r, c] >= 0 and c - d16[r, c] / 16.0 >= 0:
            e16[r, int(np.round(c - d16[r, c] / 16.0))] = d16[r, c] + rng.integers(-32, 33)
    vl = rng.random((H, W)) > 0.05
    vr = rng.random((H, W)) > 0.05
    got = check_disparities(d16, e16, vl, vr, np.float32(1.0), 5, full)
    want = _reference_check(d16, e16, vl, vr, 1.0, 5, full)
    assert np.isfinite(want).sum() > 500
    assert np.array_equal(got, want, equal_nan=True)


def _voxels_plain(x0, y0, cell, H, W, pair, xyz, sigma, rgb, min_support):
    """The voxel rule of skyrig.dense.fusion in plain Python: points grouped by (cell, floor(z / cell)); a group
    with points of >= min_support pairs -> precision-weighted mean position, mean colour, number of pairs."""
    groups: dict = {}
    for i, (x, y, z) in enumerate(xyz):
        col, row = np.floor((x - x0) / cell), np.floor((y0 - y) / cell)
        if 0 <= col < W and 0 <= row < H:
            groups.setdefault((int(row), int(col), int(np.floor(z / cell))), []).append(i)
    out = []
    for idx in groups.values():
        if len(set(pair[idx])) >= min_support:
            w = 1.0 / np.maximum(sigma[idx].astype(np.float64), 1e-9) ** 2
            out.append([*(w[:, None] * xyz[idx]).sum(axis=0) / w.sum(), *np.floor(rgb[idx].mean(axis=0) + 0.5),
                        len(set(pair[idx]))])
    return np.array(sorted(map(tuple, out)))


def test_grid_and_cloud_in_one_sort_equal_the_rules():
    """CellSorter (the ground tile's fusion: blocks added one by one, the tile's bounds, points without a height
    precision in the cloud only) against fuse_grid (tested by hand elsewhere) and the voxel rule in plain Python."""
    from skyrig.dense.fusion import CellSorter, FusionConfig, fuse_grid
    from skyrig.dense.grid import GridSpec

    rng = np.random.default_rng(3)
    g = GridSpec(100.0, 200.0, 0.5, 37, 23)  # not a multiple of the sorter's 16-cell blocks
    n = 6000
    pair = rng.integers(0, 5, n)
    pair.sort()  # blocks arrive pair by pair
    xyz = np.stack([rng.uniform(99.0, 120.0, n), rng.uniform(187.0, 201.0, n),
                    rng.choice([10.0, 10.3, 14.0], n) + rng.normal(0, 0.05, n)], axis=1)
    sh = rng.uniform(0.02, 0.1, n).astype(np.float32)
    sh[rng.random(n) < 0.1] = np.nan  # wall points: cloud only
    s3 = rng.uniform(0.02, 0.1, n).astype(np.float32)
    rgb = rng.integers(0, 256, (n, 3)).astype(np.uint8)
    nrm = rng.normal(size=(n, 3)).astype(np.float32)
    cfg = FusionConfig()
    srt = CellSorter(g, g.cell_m, cloud=True)
    for p in range(5):
        k = pair == p
        srt.add(p, xyz[k], sh[k], s3[k], rgb[k], nrm[k], bounds=g.bounds)
    layers, cloud = srt.fuse(cfg)
    want = fuse_grid(g, pair, xyz[:, 0], xyz[:, 1], xyz[:, 2], sh.astype(np.float64), cfg, candidates=True)
    assert np.isfinite(want[0]).sum() > 100
    for a, b in zip(layers, want):
        assert np.array_equal(a, b, equal_nan=True)
    got = np.array(sorted(map(tuple, np.concatenate([cloud[0], cloud[1].astype(np.float64),
                                                     cloud[3][:, None].astype(np.float64)], axis=1))))
    ref = _voxels_plain(g.x0, g.y0, g.cell_m, g.height, g.width, pair, xyz, s3, rgb, cfg.min_support)
    assert len(got) == len(ref) > 100
    assert np.allclose(got, ref, rtol=0, atol=1e-9)


@pytest.fixture(scope="module")
def pair():
    """Two exposures of the ray-cast scene of ``test_dense`` (independent of skyrig's geometry), 16 m apart."""
    from test_dense import F_PX, H_PX, HEIGHT, W_PX, _render

    from skyrig.camera.frame import FrameCamera
    from skyrig.dense.rectify import rectify_pair

    cam = FrameCamera.from_pixels("cam", W_PX, H_PX, F_PX, (W_PX - 1) / 2, (H_PX - 1) / 2, pixel_size_mm=0.005)
    views = []
    for x, yaw in ((-8.0, 0.01), (8.0, -0.015)):
        c = np.array([x, 1.0, 50.0 + HEIGHT])
        R = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1.0]])
        views.append((c, R, _render(c, yaw)))
    r = rectify_pair(cam, views[0][1], views[0][0], cam, views[1][1], views[1][0])
    box = (-60.0, -60.0, 35.0, 60.0, 60.0, 80.0)
    return r, views[0][2], views[1][2], box


def test_blocks_are_equal_and_tile_the_bounds(pair):
    from skyrig.dense.stereo import pair_blocks

    r, _, _, box = pair
    u0, u1, v0, v1 = (int(x) for x in r.bounds[0])
    for px in (100, 256, 10_000):
        bl = pair_blocks(r, box, px)
        us = sorted({(b.u0, b.u1) for b in bl})
        vs = sorted({(b.v0, b.v1) for b in bl})
        assert us[0][0] == u0 and us[-1][1] == u1 and vs[0][0] == v0 and vs[-1][1] == v1
        assert all(a[1] == b[0] for a, b in zip(us, us[1:])) and all(a[1] == b[0] for a, b in zip(vs, vs[1:]))
        assert len(us) == -(-(u1 - u0) // px) and len(vs) == -(-(v1 - v0) // px)
        w = [b - a for a, b in us]
        assert max(w) <= px and max(w) - min(w) <= 1


def test_tight_crop_matches_like_a_wide_crop(pair):
    import cv2

    from skyrig.dense.stereo import block_crop, match_block, pair_blocks

    r, L, R, box = pair
    cfg = SgmConfig(edge_erode_px=2, edge_erode_across_px=0)
    for blk in pair_blocks(r, box, 256):
        d, colour, valid = match_block(r, L, R, blk, cfg)
        crop = block_crop(r, blk, cfg)
        assert crop is not None
        shift, n, a, b = crop[:4]
        assert (shift, n) == disparity_window(blk.d_min, blk.d_max, cfg)
        # columns no right pixel can reach stay empty
        assert np.isnan(d[:, :a - blk.u0]).all() and np.isnan(d[:, b - blk.u0:]).all()
        # the wide crop: full margins and the search width on both sides, zeros beyond the images
        m = cfg.margin_px
        cu0, cv0 = blk.u0 - m - n, blk.v0 - m
        w, h = blk.u1 + m + n - cu0, blk.v1 + m - cv0
        lc, lv = r.remap(0, L, cu0, cv0, w, h)
        rc, rv = r.remap(1, R, cu0 - shift, cv0, w, h)
        grey = (lambda x: cv2.cvtColor(x, cv2.COLOR_RGB2GRAY)) if L.ndim == 3 else (lambda x: x)
        ref = match_crop(grey(lc), grey(rc), shift, n, cfg, lv, rv)[m:m + blk.v1 - blk.v0, m + n:m + n + blk.u1 - blk.u0]
        both = np.isfinite(d) & np.isfinite(ref)
        either = np.isfinite(d) | np.isfinite(ref)
        assert both.sum() > 0.5 * d.size
        assert both.sum() >= 0.97 * either.sum()
        assert np.mean(np.abs(d[both] - ref[both]) <= 1.0) >= 0.99
