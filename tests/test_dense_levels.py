"""Issue 35: the dense chain's image scale (pyramid levels) and its hierarchical disparity search.

Independent truths: OpenCV's ``pyrDown`` geometry (a blob's centroid), the seeded synthetic block of
``test_dense`` (its surface is known), and coarse disparities made by hand."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skyrig.camera.distortion import distortion_from_dict
from skyrig.camera.frame import FrameCamera
from skyrig.dense.levels import (MIN_SPLIT_PX, auto_image_scale, coarse_level, level_of_scale, pyramid, refine_windows,
                                 scaled_camera)
from skyrig.dense.pairs import PairConfig
from skyrig.dense.surface import DenseConfig, dense_surface
from skyrig.errors import SkyrigError
from skyrig.georef.eo import WorldFrame
from test_dense import BOX, CRS, _block, _surface, _to_local


def test_pyramid_level_camera_follows_pyrdown_geometry():
    """A blob at a non-integer full-resolution pixel lands where the level's camera projects its ray."""
    cam = FrameCamera.from_pixels("c", 401, 301, 350.0, 203.3, 148.9, pixel_size_mm=0.004,
                                  distortion=distortion_from_dict({"model": "opencv", "k1": -0.08, "k2": 0.01}))
    ray = np.array([[0.11, -0.07, -1.0]])
    c, r = cam.project_pixels(ray)[0]
    cc, rr = np.meshgrid(np.arange(cam.width), np.arange(cam.height))
    img = (250 * np.exp(-((cc - c) ** 2 + (rr - r) ** 2) / (2 * 6.0 ** 2))).astype(np.float32)
    for level in (1, 2):
        small = pyramid(img, level)
        lc = scaled_camera(cam, level)
        assert (lc.width, lc.height) == (small.shape[1], small.shape[0])
        w = small / small.sum()
        yy, xx = np.mgrid[:small.shape[0], :small.shape[1]]
        centroid = np.array([(w * xx).sum(), (w * yy).sum()])
        assert np.allclose(lc.project_pixels(ray)[0], centroid, atol=0.02)
        assert np.allclose(lc.project_pixels(ray)[0], np.array([c, r]) / 2 ** level, atol=1e-9)


def test_auto_scale_and_levels():
    assert auto_image_scale(0.017, None) == 1.0
    assert auto_image_scale(0.017, 0.017) == 1.0
    assert auto_image_scale(0.017, 0.07) == 0.25  # 4 GSD cells: a quarter of the pixels
    assert auto_image_scale(0.017, 0.035) == 0.5
    assert auto_image_scale(0.017, 0.03) == 1.0  # half scale would have 0.034 m pixels, coarser than the cell
    assert auto_image_scale(0.017, 5.0) == 0.0625
    assert auto_image_scale(0.017, 0.01) == 1.0  # finer than the images: full resolution
    assert auto_image_scale(0.017, None, 4000) == 0.5 and auto_image_scale(0.017, None, 640) == 1.0
    assert auto_image_scale(0.017, None, 20000) == 0.0625 and auto_image_scale(0.017, 0.017, 4000) == 1.0
    assert level_of_scale(0.125) == 3
    with pytest.raises(SkyrigError, match="image_scale"):
        level_of_scale(0.3)
    assert coarse_level(1200, 512) == 2 and coarse_level(300, 512) == 1


def test_refine_windows_from_hand_made_coarse_disparities():
    """Ground at 100 coarse px, a tower at 220 in one quarter, no match in another, a search of 200 px: the block
    is split, each part's window holds its own surface, the empty quarter is left out, nothing is cut."""
    f = 2
    coarse = np.full((200, 200), 100.0, np.float32)  # coarse pixels (0..200) = full 0..400
    coarse[:100, :100] = 220.0
    coarse[100:, 100:] = np.nan
    parts, cut, trimmed, blind = refine_windows(coarse, f, 0, 0, 0, 400, 0, 400, 100.0, 900.0, 200.0)
    assert cut == 0 and trimmed == 0 and blind == 1 and len(parts) == 3
    full = np.repeat(np.repeat(coarse, f, 0), f, 1) * f
    for u0, u1, v0, v1, d0, d1 in parts:
        truth = full[v0:v1, u0:u1]
        assert np.isfinite(truth).all() and d0 <= truth.min() and truth.max() <= d1 and d1 - d0 <= 200.0
    # a surface deeper than the search everywhere in a part too small to split: cut, and counted
    steep = np.tile(np.linspace(100, 400, MIN_SPLIT_PX, dtype=np.float32), (MIN_SPLIT_PX, 1))
    parts, cut, trimmed, blind = refine_windows(steep, 1, 0, 0, 0, MIN_SPLIT_PX, 0, MIN_SPLIT_PX, 50, 500, 100)
    assert len(parts) == 1 and cut == 1 and parts[0][5] - parts[0][4] == 100


@pytest.fixture(scope="module")
def small_block():
    eo, cams, imgs = _block()
    keep = np.flatnonzero(np.isin(eo.image, ["s0_e1.png", "s0_e2.png", "s1_e1.png", "s1_e2.png"]))
    return eo.subset(keep), cams, [imgs[i] for i in keep]


def _scores(dsm, gsd, edge_m=0.0):
    """Completeness, NMAD and share off by more than 5 GSD of the cells inside the 4 images' common area (those
    farther than ``edge_m`` from the building's outline)."""
    xx, yy = dsm.grid.cell_centres()
    lx, ly, lz = _to_local(dsm.frame, xx, yy, np.where(np.isfinite(dsm.height), dsm.height, 50.0))
    inner = (np.abs(lx) < 14) & (np.abs(ly) < 10)
    if edge_m:
        near = lambda x, e: np.abs(x - e) < edge_m  # noqa: E731
        inner &= ~((near(lx, BOX[0]) | near(lx, BOX[2])) & (ly > BOX[1] - edge_m) & (ly < BOX[3] + edge_m))
        inner &= ~((near(ly, BOX[1]) | near(ly, BOX[3])) & (lx > BOX[0] - edge_m) & (lx < BOX[2] + edge_m))
    err = np.where(np.isfinite(dsm.height), lz - _surface(lx, ly), np.nan)[inner]
    v = err[np.isfinite(err)]
    return np.isfinite(err).mean(), 1.4826 * np.median(np.abs(v - np.median(v))), np.mean(np.abs(v) > 5 * gsd)


@pytest.mark.slow
def test_hierarchical_search_finds_the_surface_a_cut_window_misses(small_block):
    """A height range so wide that the geometric window exceeds the matcher's limit (64 px): cut, the near
    surfaces are lost; with the coarse level predicting each block's window the DSM is as complete and as close to
    the truth as with an unlimited search (512 px)."""
    eo, cams, imgs = small_block
    base = DenseConfig(tile_cells=4096, block_px=256, pairs=PairConfig(pairs_per_image=4), cloud=False)
    out = {}
    for hier, maxd in ((False, 64), (True, 64), (True, 512)):
        cfg = replace(base, hierarchical=hier, sgm=replace(base.sgm, max_disparities=maxd))
        dsm, _, st = dense_surface(eo, cams, lambda i: imgs[i], WorldFrame.map(CRS), (-100.0, 75.0), config=cfg)
        out[hier, maxd] = (_scores(dsm, st.gsd_m), st)
    (c_cut, _, _), st_cut = out[False, 64]
    (c_h, nmad_h, gross_h), st_h = out[True, 64]
    (c_ref, nmad_ref, gross_ref), st_ref = out[True, 512]
    assert st_ref.search.cut == st_ref.search.refined == 0 and st_ref.summary_line() == ""
    assert st_cut.search.cut == st_cut.blocks and st_cut.search.refined == 0
    assert st_h.search.refined == st_h.blocks and st_h.search.cut <= 0.1 * st_h.blocks
    assert "hierarchical" in st_h.summary_line()
    assert c_cut < c_ref - 0.05 and c_h > c_ref - 0.01
    assert nmad_h < max(1.2 * nmad_ref, 0.05 * st_h.gsd_m) and gross_h <= gross_ref + 0.002


@pytest.mark.slow
def test_reduced_image_scale_dsm_is_on_the_truth(small_block):
    """Cells of 0.4 m (about 2 GSD): the automatic scale is a half; the DSM is as complete as at full resolution
    and on the truth within a GSD."""
    eo, cams, imgs = small_block
    base = DenseConfig(tile_cells=4096, block_px=256, pairs=PairConfig(pairs_per_image=4), cell_m=0.4, cloud=False)
    res = {}
    for scale in (1.0, None):
        dsm, _, st = dense_surface(eo, cams, lambda i: imgs[i], WorldFrame.map(CRS), (40.0, 75.0),
                                   config=replace(base, image_scale=scale))
        res[scale] = (_scores(dsm, st.gsd_m), _scores(dsm, st.gsd_m, 1.0), st)
    (comp, nmad, gross), (comp_flat, _, _), st = res[None]
    (comp1, _, _), (comp1_flat, _, _), st1 = res[1.0]
    assert st.image_scale == 0.5 and st.cell_m == 0.4 and st1.image_scale == 1.0  # GSD 0.19 m: 0.38 m pixels
    assert st.megapixels < 0.3 * st1.megapixels
    assert comp_flat > comp1_flat - 0.02 and nmad < st.gsd_m and gross < 0.01


def test_image_scale_option_words():
    """skyrig dsm / the dsm stage: ODM's quality names and numbers, auto; anything else names the option."""
    from skyrig.errors import OptionError
    from skyrig.pipeline.products import _image_scale

    spell = lambda name: f"stages.dsm.{name}"  # noqa: E731
    assert _image_scale("auto", spell) is None and _image_scale(None, spell) is None
    assert _image_scale("medium", spell) == 0.25 and _image_scale("0.125", spell) == 0.125
    assert _image_scale(1, spell) == 1.0
    for bad in ("0.3", "best"):
        with pytest.raises(OptionError, match="stages.dsm.image_scale"):
            _image_scale(bad, spell)


def test_orientation_sigma_widens_the_predicted_disparity_sigma_in_level_pixels():
    """0.8 full-resolution px of orientation error at image scale 0.5 is 0.4 level px, added in quadrature to the
    matcher's 0.3 px: 0.5 px; the plan's cameras are the level's (half the focal length in pixels)."""
    from skyrig.dense.surface import plan_dense
    from skyrig.georef.eo import ExteriorOrientations
    from test_dense import F_PX, H_PX, LOCAL, W_PX

    cam = FrameCamera.from_pixels("cam", W_PX, H_PX, F_PX, (W_PX - 1) / 2, (H_PX - 1) / 2, pixel_size_mm=0.005)
    eo = ExteriorOrientations(np.array(["a.png", "b.png"]), "cam", np.array([[-8.0, 0, 170], [8.0, 0, 170]]),
                              np.stack([np.eye(3)] * 2), LOCAL)
    for sigma, scale, want in ((0.8, 0.5, 0.5), (0.0, 0.5, 0.3), (0.4, 1.0, 0.5)):
        plan = plan_dense(eo, {"cam": cam}, WorldFrame.map(CRS), (40.0, 75.0),
                          config=DenseConfig(image_scale=scale, orientation_sigma_px=sigma))
        assert plan.config.sgm.disparity_sigma_px == pytest.approx(want, abs=1e-12)
        assert plan.cameras["cam"].focal_px == pytest.approx(F_PX * scale) and plan.image_level == level_of_scale(scale)
    with pytest.raises(SkyrigError, match="orientation_sigma_px"):
        plan_dense(eo, {"cam": cam}, WorldFrame.map(CRS), (40.0, 75.0), config=DenseConfig(orientation_sigma_px=-1.0))
