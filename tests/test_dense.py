"""Dense stage (skyrig.dense, skyrig.pipeline.dense, `skyrig dsm`) against independent answers.

The scene of these tests is ray-cast here, in the test, with its own pinhole formula (no skyrig code): a
textured sloped ground plane with one box-shaped building, seen by a small nadir block.  The DSM must give the
plane and the roof back within the predicted precision; tiled and untiled runs must be bit-identical; every
bad input must be a clear error that leaves no output behind.
"""

from __future__ import annotations

from dataclasses import replace

import json
from pathlib import Path

import numpy as np
import pytest

from skyrig.camera.frame import FrameCamera
from skyrig.dense.fusion import FusionConfig, fuse_grid
from skyrig.dense.grid import GridSpec
from skyrig.dense.pairs import PairConfig, select_pairs
from skyrig.dense.rectify import rectify_pair
from skyrig.dense.sgm import SgmConfig, disparity_window
from skyrig.dense.stereo import block_window, pair_blocks
from skyrig.dense.surface import DenseConfig, dense_surface
from skyrig.errors import SkyrigError
from skyrig.georef.eo import ExteriorOrientations, WorldFrame

CRS = "EPSG:25832"
LOCAL = WorldFrame.local(52.35, 9.73, 0.0)  # the scene lives in this local ENU frame (rigorous, no map scale)
W_PX, H_PX, F_PX = 640, 480, 600.0
HEIGHT = 120.0  # flying height above the plane (m) -> GSD 0.2 m
BOX = (-12.0, -8.0, 10.0, 9.0, 14.0)  # x0, y0, x1, y1 (local m around the origin), roof height above plane


def _plane(x, y):
    return 50.0 + 0.02 * x - 0.01 * y


def _texture(x, y):
    """Deterministic multi-scale texture of world position (0..255)."""
    t = np.zeros_like(x)
    for k, s in enumerate((0.35, 0.9, 2.3, 6.0)):
        t += np.sin(x / s * 1.7 + 0.3 * k) * np.cos(y / s * 1.3 - 0.7 * k) * (1.0 / (k + 1))
        t += 0.6 * np.sin((x + y) / s * 1.1 + k) / (k + 1)
    return np.clip(128 + 45 * t, 0, 255)


def _surface(x, y):
    inside = (x >= BOX[0]) & (x <= BOX[2]) & (y >= BOX[1]) & (y <= BOX[3])
    return np.where(inside, _plane(x, y) + BOX[4], _plane(x, y))


def _render(centre, yaw_rad=0.0):
    """Ray-cast a nadir image (camera x right = east when yaw 0, y up = north, looking down)."""
    cols, rows = np.meshgrid(np.arange(W_PX), np.arange(H_PX))
    # pixel -> camera ray (pinhole, principal point at the image centre, y up)
    xc = (cols - (W_PX - 1) / 2) / F_PX
    yc = -(rows - (H_PX - 1) / 2) / F_PX
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    dx, dy = c * xc - s * yc, s * xc + c * yc  # the ray's z component is -1 (looking down)
    cx, cy, cz = centre
    # roof plane first (box top), then walls are ignored (nadir block, walls thin), then ground
    t_roof = (cz - (50.0 + BOX[4])) / 1.0  # approx, refined below with the sloped plane
    for _ in range(3):
        x, y = cx + dx * t_roof, cy + dy * t_roof
        t_roof = cz - (_plane(x, y) + BOX[4])
    x, y = cx + dx * t_roof, cy + dy * t_roof
    on_roof = (x >= BOX[0]) & (x <= BOX[2]) & (y >= BOX[1]) & (y <= BOX[3])
    t = np.full_like(xc, cz - 50.0)
    for _ in range(4):
        gx, gy = cx + dx * t, cy + dy * t
        t = cz - _plane(gx, gy)
    gx, gy = cx + dx * t, cy + dy * t
    # ground points hidden by the box: the ray passes through the box volume above the plane
    hidden = np.zeros_like(on_roof)
    for frac in np.linspace(0.0, 1.0, 40):
        tz = t_roof + (t - t_roof) * frac
        px, py = cx + dx * tz, cy + dy * tz
        inb = (px >= BOX[0]) & (px <= BOX[2]) & (py >= BOX[1]) & (py <= BOX[3])
        hidden |= inb & (cz - tz > _plane(px, py)) & (cz - tz < _plane(px, py) + BOX[4])
    X = np.where(on_roof, x, gx)
    Y = np.where(on_roof, y, gy)
    val = _texture(X, Y) * np.where(on_roof, 0.8, 1.0)
    val = np.where(hidden & ~on_roof, 60.0 + 0.3 * _texture(gx * 3, gy * 3), val)  # walls: darker, other texture
    img = np.clip(val, 0, 255).astype(np.uint8)
    return np.repeat(img[..., None], 3, axis=2)


def _block():
    """Three strips x four exposures, 80 % / 60 % overlap, small yaw differences."""
    cam = FrameCamera.from_pixels("cam", W_PX, H_PX, F_PX, (W_PX - 1) / 2, (H_PX - 1) / 2, pixel_size_mm=0.005)
    names, centres, rots, imgs = [], [], [], []
    rng = np.random.default_rng(3)
    for i, yy in enumerate((-24.0, 0.0, 24.0)):
        for j, xx in enumerate((-24.0, -8.0, 8.0, 24.0)):
            c = np.array([xx + rng.normal(0, 0.3), yy + rng.normal(0, 0.3), 50.0 + HEIGHT])
            yaw = rng.normal(0, 0.02)
            R = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1.0]])
            names.append(f"s{i}_e{j}.png")
            centres.append(c)
            rots.append(R)
            imgs.append(_render(c, yaw))
    eo = ExteriorOrientations(np.array(names), "cam", np.array(centres), np.array(rots), LOCAL)
    return eo, {"cam": cam}, imgs


def _to_local(frame, x, y, h):
    """Map points (any shape) to the scene's local frame (rigorous, through ECEF)."""
    L = LOCAL.from_ecef(frame.to_ecef(np.stack([np.ravel(x), np.ravel(y), np.ravel(h)], 1)))
    return L[:, 0].reshape(np.shape(x)), L[:, 1].reshape(np.shape(x)), L[:, 2].reshape(np.shape(x))


def _to_map(x, y, h):
    return WorldFrame.map(CRS).from_ecef(LOCAL.to_ecef(np.stack([np.ravel(x), np.ravel(y), np.ravel(h)], 1)))


@pytest.fixture(scope="module")
def block():
    return _block()


@pytest.fixture(scope="module")
def dense_result(block):
    eo, cams, imgs = block
    cfg = DenseConfig(tile_cells=4096, block_px=256, pairs=PairConfig(pairs_per_image=4))
    return dense_surface(eo, cams, lambda i: imgs[i], WorldFrame.map(CRS), (40.0, 75.0), config=cfg)


def test_rectification_is_exact_with_distortion():
    from skyrig.camera.opencv import OpenCVDistortion

    rng = np.random.default_rng(7)
    cam = FrameCamera.from_pixels("c", 800, 600, 700.0, 405.0, 296.0,
                                  distortion=OpenCVDistortion(k1=-0.12, k2=0.04, p1=0.0008, p2=-0.0005, k3=-0.01))
    from skyrig.geometry.rotations import matrix_from_rotvec

    for _ in range(5):
        Rl = matrix_from_rotvec(rng.normal(0, 0.05, 3))
        Rr = matrix_from_rotvec(rng.normal(0, 0.05, 3))
        cl = np.array([0.0, 0.0, 100.0])
        cr = cl + np.array([rng.uniform(20, 40), rng.normal(0, 3), rng.normal(0, 2)])
        r = rectify_pair(cam, Rl, cl, cam, Rr, cr)
        P = np.column_stack([rng.uniform(5, 25, 50), rng.uniform(-20, 20, 50), rng.uniform(-5, 10, 50)])
        pl = cam.project_pixels((P - cl) @ Rl)
        pr = cam.project_pixels((P - cr) @ Rr)
        ul, ur = r.to_rect(0, pl), r.to_rect(1, pr)
        assert np.abs(ul[:, 1] - ur[:, 1]).max() < 1e-8  # same row: exact epipolar geometry
        X, _ = r.triangulate(ul[:, 0], ul[:, 1], ul[:, 0] - ur[:, 0])
        assert np.abs(X - P).max() < 1e-7
        back = r.to_original(0, ul[:, 0], ul[:, 1])
        assert np.abs(back - pl).max() < 1e-8
        # the lattice maps stay within 0.005 px of the exact mapping
        u0, u1, v0, v1 = r.bounds[0]
        ex = np.stack(r.maps(0, u0, v0, u1 - u0, v1 - v0, step=1), -1)
        ap = np.stack(r.maps(0, u0, v0, u1 - u0, v1 - v0), -1)
        inside = (ex[..., 0] > 0) & (ex[..., 0] < 799) & (ex[..., 1] > 0) & (ex[..., 1] < 599)
        assert np.abs(ex - ap)[inside].max() < 0.005


def test_disparity_window_contains_the_scene(block):
    eo, cams, _ = block
    e = eo
    c = e.centre.mean(axis=0)
    box = (c[0] - 40, c[1] - 40, c[2] - HEIGHT - 20, c[0] + 40, c[1] + 40, c[2] - HEIGHT + 30)
    pairs = select_pairs(e, cams, box, PairConfig())
    assert pairs
    p = pairs[0]
    r = rectify_pair(cams["cam"], e.rotation[p.left], e.centre[p.left], cams["cam"], e.rotation[p.right],
                     e.centre[p.right])
    blk = pair_blocks(r, box)[0]
    corners = np.array([[x, y, z] for x in box[0::3] for y in box[1::3] for z in box[2::3]])
    rr = r.to_rect(0, cams["cam"].project_pixels((corners - r.centres[0]) @ r.rotations[0]))
    rt = r.to_rect(1, cams["cam"].project_pixels((corners - r.centres[1]) @ r.rotations[1]))
    d = rr[:, 0] - rt[:, 0]
    w = block_window(r, r.bounds[0][0], r.bounds[0][1], r.bounds[0][2], r.bounds[0][3], box)
    assert w is not None and w[0] <= np.nanmin(d) and w[1] >= np.nanmax(d)
    shift, n = disparity_window(blk.d_min, blk.d_max, SgmConfig())
    assert n % 16 == 0 and shift <= blk.d_min


def test_pair_selection_budget_and_directions(block):
    eo, cams, _ = block
    e = eo
    c = e.centre.mean(axis=0)
    box = (c[0] - 40, c[1] - 40, c[2] - HEIGHT - 20, c[0] + 40, c[1] + 40, c[2] - HEIGHT + 30)
    pairs = select_pairs(e, cams, box, PairConfig(pairs_per_image=3))
    counts = np.bincount([p.left for p in pairs] + [p.right for p in pairs], minlength=len(e))
    assert counts.max() <= 3
    for p in pairs:
        base = np.linalg.norm(e.centre[p.left] - e.centre[p.right])
        assert abs(base - p.base_m) < 1e-9 and p.overlap >= 0.3
    # an image looking the other way (a tilted oblique) never pairs with the nadir images
    tilt = np.array([[1, 0, 0], [0, np.cos(0.8), -np.sin(0.8)], [0, np.sin(0.8), np.cos(0.8)]])
    e2 = ExteriorOrientations(np.r_[e.image, ["obl"]], "cam", np.vstack([e.centre, e.centre[0]]),
                              np.concatenate([e.rotation, (e.rotation[0] @ tilt)[None]]), e.frame)
    assert all(len(e2) - 1 not in (p.left, p.right) for p in select_pairs(e2, cams, box, PairConfig()))


def test_fusion_rules_against_hand_computation():
    g = GridSpec(0.0, 10.0, 1.0, 3, 1)
    # cell 0: pairs 0,1,2 agree near 5.0, pair 3 is off by 3 m; cell 1: one pair only; cell 2: two pairs disagree
    x = np.array([0.5, 0.5, 0.5, 0.5, 0.5, 1.5, 2.5, 2.5])
    y = np.full(8, 9.5)
    h = np.array([5.00, 5.02, 4.99, 5.01, 8.0, 7.0, 3.0, 9.0])
    pair = np.array([0, 0, 1, 2, 3, 0, 0, 1])
    sig = np.array([0.05, 0.05, 0.05, 0.10, 0.05, 0.05, 0.05, 0.05])
    H, N, SP, S = fuse_grid(g, pair, x, y, h, sig, FusionConfig(min_support=2, k_sigma=3.0, min_tol_cells=0.2))
    # independent: per-pair medians 5.01 (pair 0), 4.99, 5.01; weights 1/0.05^2, 1/0.05^2, 1/0.1^2
    v = np.array([5.01, 4.99, 5.01])
    w = 1 / np.array([0.05, 0.05, 0.10]) ** 2
    fused = np.sum(w * v) / np.sum(w)
    assert N[0, 0] == 3 and abs(H[0, 0] - fused) < 1e-5
    assert abs(S[0, 0] - 1 / np.sqrt(w.sum())) < 1e-6
    assert abs(SP[0, 0] - 1.4826 * np.median(np.abs(v - fused))) < 1e-5
    assert np.isnan(H[0, 1]) and N[0, 1] == 0  # no second pair confirms it
    assert np.isnan(H[0, 2])  # two pairs 6 m apart: neither is confirmed


def test_a_pair_seeing_a_wall_in_a_cell_gives_it_no_height():
    # one cell: pairs 0 and 1 see the ground at 2 m; the points of pairs 2, 3 and 4 run up a wall (2 .. 9 m, as the
    # wall pixels of a view all project onto the outline): their medians (5.5, 5, 6) are neither roof nor ground.
    # With the range rule (5 cells of 1 m) they are left out and the ground pairs decide alone.
    g = GridSpec(0.0, 10.0, 1.0, 1, 1)
    h = np.array([2.0, 2.02, 2.0, 4.0, 7.0, 9.0, 2.0, 5.0, 8.0, 3.0, 6.0, 9.0])
    pair = np.array([0, 1, 2, 2, 2, 2, 3, 3, 3, 4, 4, 4])
    x, y, sig = np.full(12, 0.5), np.full(12, 9.5), np.full(12, 0.05)
    cfg = FusionConfig(min_support=2, k_sigma=3.0, min_tol_cells=0.2)
    H, N, SP, S = fuse_grid(g, pair, x, y, h, sig, cfg)
    assert N[0, 0] == 2 and abs(H[0, 0] - 2.01) < 1e-5
    # without it the weighted median is a wall's (5 m), which no second pair confirms: the cell stays empty
    H0, N0, _, _ = fuse_grid(g, pair, x, y, h, sig, replace(cfg, max_pair_range_cells=0))
    assert np.isnan(H0[0, 0])


def test_points_on_a_wall_are_found_by_their_neighbourhood_plane():
    from skyrig.dense._kernels import steep_points

    # rectified left camera looking straight down (world_from_rect = I: depth D is -z), f 1000 px, base 1 m;
    # ground at depth 100 m, a building beyond x = 5 m with its roof at depth 90 m: pixels u < 50 see the ground,
    # 50 <= u <= 55.6 the wall x = 5 m (depth 5 f / u), u > 55.6 the roof; disparity f B / D
    f, B = 1000.0, 1.0
    u = np.arange(30, 80, dtype=float)
    D = np.where(u < 50, 100.0, np.where(u <= 5 * f / 90, 5 * f / np.maximum(u, 1), 90.0))
    disp = np.repeat((f * B / D)[None, :], 21, axis=0).astype(np.float32)
    rr, cc = np.nonzero(disp > 0)
    nz = steep_points(disp, rr, cc, 30.0, -10.0, f, B, np.eye(3), 3, 12)
    uu = 30 + cc
    wall = (uu >= 51) & (uu <= 54) & (rr >= 3) & (rr <= 17)  # inside the wall, away from the window's clipping
    far = ((uu <= 45) | (uu >= 61)) & (uu >= 33) & (uu <= 76)  # ground and roof 4+ px from the wall
    assert (nz[wall] < 0.3).all()
    assert (nz[far] > 0.99).all()


def test_neighbour_confirmation_against_hand_computation():
    from skyrig.dense.fusion import confirm_by_neighbours

    g = GridSpec(0.0, 10.0, 1.0, 6, 1)
    # cells 0,1: confirmed by pairs 0+1 at 5.0; cell 2: pair 0 alone at 5.1 (a neighbour 1 cell away agrees);
    # cell 3: pair 2 alone at 9.0 (no confirmed neighbour at that height); cell 4: pairs 0 and 1 disagree
    # (two camps: no one-camp candidate); cell 5: pair 3 alone at 5.05, its nearest confirmed cell 4 cells away
    x = np.array([0.5, 0.5, 1.5, 1.5, 2.5, 3.5, 4.5, 4.5, 5.5])
    y = np.full(9, 9.5)
    h = np.array([5.0, 5.0, 5.0, 5.0, 5.1, 9.0, 5.0, 8.0, 5.05])
    pair = np.array([0, 1, 0, 1, 0, 2, 0, 1, 3])
    sig = np.full(9, 0.05)
    cfg = FusionConfig(min_support=2, k_sigma=3.0, min_tol_cells=0.2, neighbour_cells=2)
    H, N, SP, S, CH, CS, CN, CH2, CS2, CN2 = fuse_grid(g, pair, x, y, h, sig, cfg, candidates=True)
    assert np.isfinite(H[0, :2]).all() and np.isnan(H[0, 2:]).all()
    assert CH[0, 2] == np.float32(5.1) and CN[0, 2] == 1 and abs(CS[0, 2] - 0.05) < 1e-7
    assert CH[0, 3] == np.float32(9.0) and CH[0, 5] == np.float32(5.05)
    assert CH[0, 4] == np.float32(5.0) and CH2[0, 4] == np.float32(8.0) and np.isnan(CH2[0, [0, 1, 2, 3, 5]]).all()
    kept = confirm_by_neighbours(H, N, S, CH, CS, CN, g.cell_m, cfg)  # without the upper camps: no step 5
    # |5.1 - 5.0| = 0.1 <= max(3 * sqrt(0.05^2 + (0.05/sqrt 2)^2) = 0.18, 0.2): kept, with its own pair count
    assert kept.tolist() == [[False, False, True, False, False, False]]
    assert H[0, 2] == np.float32(5.1) and N[0, 2] == 1 and np.isnan(SP[0, 2])
    assert np.isnan(H[0, 3]) and np.isnan(H[0, 5])  # 9 m: no neighbour agrees; 5.05: none within 2 cells
    # the confirmation uses only cells of the pair vote, never a cell it kept itself (no chains)
    H2, N2, SP2, S2, CH2, CS2, CN2 = fuse_grid(g, pair, x, y, h, sig, replace(cfg, neighbour_cells=0), candidates=True)[:7]
    assert not confirm_by_neighbours(H2, N2, S2, CH2, CS2, CN2, g.cell_m, replace(cfg, neighbour_cells=0)).any()


def test_two_camp_cells_against_hand_computation():
    """Step 5 of skyrig.dense.fusion: a cell whose pairs split into two camps takes the camp that clearly more cells
    of the pair vote around it continue; a tie, a third height or no such neighbour leaves it empty."""
    from skyrig.dense.fusion import confirm_by_neighbours

    g = GridSpec(0.0, 10.0, 1.0, 9, 1)
    cells = {0: [5.0, 5.0], 1: [5.0, 9.0], 2: [9.0, 9.0], 4: [5.0, 5.0], 5: [5.02, 9.0], 6: [5.0, 7.0, 9.0],
             7: [5.0, 9.05], 8: [9.0, 9.0]}  # cell -> height of pair 0, 1 (, 2); cell 3 has no point
    x = np.concatenate([np.full(len(v), c + 0.5) for c, v in cells.items()])
    h = np.concatenate([v for v in cells.values()])
    pair = np.concatenate([np.arange(len(v)) for v in cells.values()])
    sig = np.full(len(h), 0.05)
    cfg = FusionConfig(min_support=2, k_sigma=3.0, min_tol_cells=0.2, neighbour_cells=2)
    H, N, SP, S, CH, CS, CN, CH2, CS2, CN2 = fuse_grid(g, pair, x, np.full(len(h), 9.5), h, sig, cfg, candidates=True)
    assert np.isfinite(H[0, [0, 2, 4, 8]]).all() and np.isnan(H[0, [1, 3, 5, 6, 7]]).all()
    # two camps in cells 1, 5, 7 (lower in CH, upper in CH2); cell 6's 7 m agrees with neither 5 nor 9 m: none
    assert np.isfinite(CH2[0, [1, 5, 7]]).all() and np.isnan(CH[0, 6]) and np.isnan(CH2[0, 6])
    assert (CN[0, [1, 5, 7]] == 1).all() and (CN2[0, [1, 5, 7]] == 1).all()
    with_off = [a.copy() for a in (H, N, S)]
    assert not confirm_by_neighbours(*with_off, CH, CS, CN, g.cell_m, replace(cfg, split_by_neighbours=False),
                                     CH2, CS2, CN2).any()
    kept = confirm_by_neighbours(H, N, S, CH, CS, CN, g.cell_m, cfg, CH2, CS2, CN2)
    # cell 1: cell 0 (5 m) and cell 2 (9 m) one cell away, cell 3 empty: a tie, empty; cell 5: cell 4 at 5 m
    # continues the lower camp, cell 6 is no cell of the vote: 5.02 m; cell 7: cell 8 continues the upper: 9.05 m
    assert kept.tolist() == [[False, False, False, False, False, True, False, True, False]]
    assert H[0, 5] == np.float32(5.02) and H[0, 7] == np.float32(9.05) and N[0, 5] == 1 and N[0, 7] == 1
    assert np.isnan(H[0, [1, 3, 6]]).all() and np.isnan(SP[0, [5, 7]]).all()


def test_foreground_erosion_along_rows_and_background_fill():
    from skyrig.dense.sgm import erode_foreground, fill_background

    d = np.full((5, 10), 10.0, np.float32)
    d[1:4, 4:7] = 20.0  # a foreground square
    e = erode_foreground(d, 2.0, 2, 0)
    # along the rows the square loses 2 px from each side (3 px wide: all of it), across the rows nothing
    assert np.isnan(e[1:4, 4:7]).all() and np.isfinite(e[[0, 4]]).all() and np.isfinite(e[:, :4]).all()
    e = erode_foreground(d, 2.0, 1, 0)
    assert np.isnan(e[1:4, [4, 6]]).all() and (e[1:4, 5] == 20.0).all()
    e = erode_foreground(d, 2.0, 0, 1)  # across only: the top and bottom rows of the square
    assert np.isnan(e[[1, 3], 4:7]).all() and (e[2, 4:7] == 20.0).all()
    # left ends of nearer surfaces: a 10 px wide foreground bar loses 4 px at its left end and 2 at its right end
    w = np.full((3, 20), 10.0, np.float32)
    w[:, 5:15] = 20.0
    e = erode_foreground(w, 2.0, 2, 0, left_px=4)
    assert np.isnan(e[:, 5:9]).all() and np.isnan(e[:, 13:15]).all() and (e[:, 9:13] == 20.0).all()
    assert (e[:, :5] == 10.0).all() and (e[:, 15:] == 10.0).all()
    assert np.array_equal(erode_foreground(w, 2.0, 2, 0, left_px=2), erode_foreground(w, 2.0, 2, 0), equal_nan=True)
    with pytest.raises(SkyrigError, match="across"):
        SgmConfig(edge_erode_left_px=4)
    # fill: the farther (smaller) of the nearest matched row neighbours
    f = np.array([[np.nan, 5.0, np.nan, np.nan, 9.0, np.nan]], np.float32)
    assert fill_background(f).tolist() == [[5.0, 5.0, 5.0, 5.0, 9.0, 9.0]]
    valid = np.array([[True, True, False, True, True, True]])
    assert np.isnan(fill_background(f, valid)[0, 2])


def _occlusion_pair(seed: int = 3, H: int = 160, W: int = 320, db: int = 8, df: int = 24):
    """A seeded rectified pair with known truth: a textured background plane at disparity ``db`` and a textured
    rectangle in front of it at ``df``; returns left, right, true disparities and the occluded left pixels (the
    ``df - db`` background columns left of the rectangle, which the right camera cannot see)."""
    import cv2

    rng = np.random.default_rng(seed)
    bg = cv2.GaussianBlur(rng.uniform(0, 255, (H, W + 64)).astype(np.float32), (0, 0), 1.0)
    fg = cv2.GaussianBlur(rng.uniform(0, 255, (H, W + 64)).astype(np.float32), (0, 0), 1.0)
    r0, r1, a, b = 40, 120, 140, 220
    rows = np.arange(H)[:, None]
    cols = np.arange(W)[None, :]
    in_front = (rows >= r0) & (rows < r1) & (cols >= a) & (cols < b)  # left image
    left = np.where(in_front, fg[:, :W], bg[:, :W])
    right_fg = (rows >= r0) & (rows < r1) & (cols + df >= a) & (cols + df < b)  # right pixel x sees x + d on the left
    right = np.where(right_fg, fg[:, np.clip(cols[0] + df, 0, W + 63)], bg[:, cols[0] + db])
    truth = np.where(in_front, df, db).astype(np.float32)
    occluded = (rows >= r0) & (rows < r1) & (cols >= a - (df - db)) & (cols < a)
    return left.astype(np.uint8), right.astype(np.uint8), truth, occluded


@pytest.mark.parametrize("lr_check", ["opencv", "full"])
def test_left_right_check_rejects_occluded_pixels(lr_check):
    """Either left-right check (OpenCV's internal one on the same cost volume, or the full second matching from the
    right image) leaves the occluded pixels of a seeded pair without a match, keeps the visible ones, and they are
    right; with the check switched off (a tolerance wider than the search: OpenCV takes 0 and negative values as 1)
    the matcher gives the occluded pixels disparities.  Uniqueness and speckle filters are off: the check alone."""
    from skyrig.dense.sgm import match_rectified

    left, right, truth, occluded = _occlusion_pair()
    visible = ~occluded
    visible[:, :40] = False  # the first columns have no right pixel within the search window
    base = SgmConfig(uniqueness=0, speckle_window=0, lr_check=lr_check)
    d = match_rectified(left, right, 0.0, 31.0, base)
    off = match_rectified(left, right, 0.0, 31.0, replace(base, lr_max_diff=10_000))
    ok, ok_off = np.isfinite(d), np.isfinite(off)
    assert ok_off[occluded].mean() > 0.95  # without the check nearly every occluded pixel gets a (wrong) match
    assert ok[occluded].mean() < 0.15, f"{lr_check}: {100 * ok[occluded].mean():.1f} % of occluded pixels kept"
    assert ok[visible].mean() > 0.98
    with np.errstate(invalid="ignore"):
        assert (np.abs(d - truth) <= 1.0)[visible & ok].mean() > 0.99


def test_points_carry_their_intersection_angle_and_precision(block):
    """Every triangulated pixel: the world point lies on its left pixel's ray at the depth ``f B / d``, and its
    intersection angle (computed on demand from the world point and the pair's centres) equals the angle of the
    normal case in the rectified frame, ``acos(p . (p - B e_x) / (|p| |p - B e_x|))`` with
    ``p = (u D / f, -v D / f, -D)``."""
    from skyrig.dense.stereo import Block, block_points

    eo, cams, _ = block
    i, j = list(eo.image).index("s1_e1.png"), list(eo.image).index("s1_e2.png")
    rect = rectify_pair(cams["cam"], eo.rotation[i], eo.centre[i], cams["cam"], eo.rotation[j], eo.centre[j])
    u0, u1, v0, v1 = (int(x) for x in rect.bounds[0])
    u0, v0 = u0 + 20, v0 + 20
    blk = Block(u0, u0 + 40, v0, v0 + 30, 1.0, 400.0)
    rng = np.random.default_rng(5)
    disp = (rect.focal_px * rect.base_m / (HEIGHT + rng.uniform(-5, 5))) * np.ones((30, 40), np.float32)
    disp[rng.random(disp.shape) < 0.2] = np.nan
    pp = block_points(rect, blk, disp, np.zeros((30, 40, 3), np.uint8), SgmConfig(wall_max_nz=0))
    assert len(pp) == np.isfinite(disp).sum()  # a plane seen straight: every matched pixel is a point
    rr, cc = np.nonzero(np.isfinite(disp))
    d = disp[rr, cc].astype(np.float64)
    D = rect.focal_px * rect.base_m / d
    p = np.stack([(u0 + cc) * D / rect.focal_px, -(v0 + rr) * D / rect.focal_px, -D], 1)
    assert np.allclose(pp.xyz, rect.centres[0] + p @ rect.rotation.T, atol=1e-9)
    q = p - np.array([rect.base_m, 0.0, 0.0])
    ang = np.degrees(np.arccos(np.sum(p * q, 1) / (np.linalg.norm(p, axis=1) * np.linalg.norm(q, axis=1))))
    assert np.allclose(pp.angle_deg, ang, atol=1e-4)
    assert pp.sigma_h.dtype == np.float32 and np.all(pp.sigma_h > 0)
    sub = pp.subset(np.arange(3))
    assert np.array_equal(sub.angle_deg, pp.angle_deg[:3])


def test_dsm_of_the_synthetic_block(dense_result, block):
    dsm, cloud, stats = dense_result
    assert dsm.frame.crs == CRS and "ellipsoidal" in dsm.vertical_reference
    xx, yy = dsm.grid.cell_centres()
    lx, ly, lz = _to_local(dsm.frame, xx, yy, np.where(np.isfinite(dsm.height), dsm.height, 50.0))
    truth = _surface(lx, ly)
    inner = (np.abs(lx) < 30) & (np.abs(ly) < 22)
    bx = (lx > BOX[0] - 1) & (lx < BOX[2] + 1) & (ly > BOX[1] - 1) & (ly < BOX[3] + 1)
    edge = bx & ~((lx > BOX[0] + 1) & (lx < BOX[2] - 1) & (ly > BOX[1] + 1) & (ly < BOX[3] - 1))
    flat = inner & ~edge
    err = np.where(np.isfinite(dsm.height), lz - truth, np.nan)
    v = err[flat & np.isfinite(err)]
    gsd = stats.gsd_m
    assert abs(gsd - (50.0 + HEIGHT - 0.5 * (40.0 + 75.0)) / F_PX) < 0.005  # GSD at the middle of the height range
    assert np.isfinite(err[flat]).mean() > 0.95
    assert abs(np.median(v)) < 0.2 * gsd
    nmad = 1.4826 * np.median(np.abs(v - np.median(v)))
    # predicted precision of the fused heights (from the disparity sigma) vs measured: same order
    pred = np.nanmedian(dsm.sigma[flat])
    assert nmad < 1.0 * gsd and 0.2 < nmad / pred < 5.0
    assert np.mean(np.abs(v) > 5 * gsd) < 0.01
    roof = inner & (lx > BOX[0] + 1.5) & (lx < BOX[2] - 1.5) & (ly > BOX[1] + 1.5) & (ly < BOX[3] - 1.5)
    assert np.nanmedian(np.abs(err[roof])) < 0.5 * gsd
    assert cloud is not None and len(cloud) > 1000 and cloud.support.min() >= 2
    cx, cy, czz = _to_local(cloud.frame, cloud.xyz[:, 0], cloud.xyz[:, 1], cloud.xyz[:, 2])
    cz = czz - _surface(cx, cy)
    assert np.median(np.abs(cz)) < gsd


def test_tiled_equals_untiled_bit_for_bit(block):
    """Tiles matching every block that reaches them whole (``tile_crop=False``) give the untiled DSM bit for bit;
    tiles matching only the parts of the blocks that can fall in them (the default) match fewer pixels and give
    the same DSM within the noise SGM's paths leave at the parts' edges (DenseConfig.tile_crop: 0.9 % of the
    cells, by 0.4 mm median, on the 240-image growth block; here none)."""
    eo, cams, imgs = block
    keep = np.flatnonzero(np.isin(eo.image, ["s0_e1.png", "s0_e2.png", "s1_e1.png", "s1_e2.png"]))
    eo, imgs = eo.subset(keep), [imgs[i] for i in keep]
    c = _to_map(np.array([-14.0, 14.0]), np.array([-11.0, 11.0]), np.array([50.0, 50.0]))
    area = (c[0, 0], c[0, 1], c[1, 0], c[1, 1])
    # the third run: tiled and without the cloud (the fusion then keeps only each point's height, not x and y)
    runs = [dense_surface(eo, cams, lambda i: imgs[i], WorldFrame.map(CRS), (40.0, 75.0), area=area,
                          config=DenseConfig(tile_cells=t, block_px=256, cloud=c, tile_crop=crop))
            for t, c, crop in ((4096, True, False), (90, True, False), (90, False, False), (90, True, True))]
    (whole, cloud_whole, s1), (tiled, cloud_tiled, s2), (grid_only, no_cloud, _), (cropped, cloud_cropped, s4) = runs
    assert s1.tiles == 1 and s2.tiles >= 4 and no_cloud is None
    # the cropped tiles: a third fewer pixels matched than whole blocks per tile, the same points within 0.1 %
    assert s4.tiles == s2.tiles and s4.megapixels < 0.67 * s2.megapixels
    assert abs(s4.points - s1.points) <= 1e-3 * s1.points
    va, vc = np.isfinite(whole.height), np.isfinite(cropped.height)
    assert (va != vc).sum() <= 1e-3 * va.sum()
    dz = np.abs(whole.height - cropped.height)[va & vc]
    assert np.mean(dz > 0) < 0.02 and np.quantile(dz, 0.999) < 0.1 * s1.gsd_m
    assert abs(len(cloud_cropped) - len(cloud_whole)) <= 1e-3 * len(cloud_whole)
    assert np.isfinite(whole.height).mean() > 0.5
    for other in (tiled, grid_only):
        for a, b in ((whole.height, other.height), (whole.support, other.support), (whole.sigma, other.sigma),
                     (whole.spread, other.spread)):
            assert np.array_equal(a, b, equal_nan=True)
    assert len(cloud_tiled) == len(cloud_whole)
    assert np.array_equal(np.sort(cloud_whole.xyz, axis=0), np.sort(cloud_tiled.xyz, axis=0))


# --------------------------------------------------------------------------------------------- files and CLI
@pytest.fixture(scope="module")
def project(tmp_path_factory, block):
    import cv2

    from skyrig.io.eo_csv import write_eo_csv
    from skyrig.io.rig_file import write_rig
    from skyrig.rig import Head, Rig

    eo, cams, imgs = block
    d = tmp_path_factory.mktemp("dense_project")
    (d / "images").mkdir()
    for n, im in zip(eo.image, imgs):
        cv2.imwrite(str(d / "images" / n), im)
    write_eo_csv(eo, d / "eo.csv")
    write_rig(Rig("test", [Head("cam", cams["cam"])]), d / "rig.yaml")
    return d


def _dsm(project, out, *extra):
    from click.testing import CliRunner

    from skyrig.cli import main

    args = ["dsm", "--eo", str(project / "eo.csv"), "--camera", str(project / "rig.yaml"), "--images",
            str(project / "images"), "-o", str(out), "--executor", "serial", *extra]
    if "--crs" not in extra:
        args += ["--crs", CRS]
    return CliRunner().invoke(main, args, catch_exceptions=False)


def test_cli_writes_cog_and_laz_that_gdal_and_laspy_read(project, tmp_path):
    import laspy
    import pyproj
    import rasterio

    out = tmp_path / "dsm"
    c = _to_map(np.array([-22.0, 22.0]), np.array([-18.0, 18.0]), np.array([50.0, 50.0]))
    r = _dsm(project, out, "--height-range", "40", "75", "--pairs-per-image", "3", "--area",
             *(str(v) for v in (c[0, 0], c[0, 1], c[1, 0], c[1, 1])))
    assert r.exit_code == 0, r.output
    with rasterio.open(out / "dsm.tif") as ds:
        assert pyproj.CRS(ds.crs.to_wkt()).equals(pyproj.CRS(CRS))
        assert ds.overviews(1) or min(ds.width, ds.height) < 512
        # a known point: the roof centre and a ground point, read with GDAL's own sampling
        loc = np.array([[0.5 * (BOX[0] + BOX[2]), 0.5 * (BOX[1] + BOX[3])], [-20.0, -15.0]])
        true_h = _surface(loc[:, 0], loc[:, 1])
        mp = _to_map(loc[:, 0], loc[:, 1], true_h)  # the true surface points in the map CRS (PROJ)
        vals = np.array([v[0] for v in ds.sample([tuple(q[:2]) for q in mp], indexes=1)])
        gsd = HEIGHT / F_PX
        assert np.abs(vals - mp[:, 2]).max() < gsd
        assert ds.tags().get("VERTICAL_REFERENCE", "").startswith("ellipsoidal")
    las = laspy.read(out / "cloud.laz")
    assert pyproj.CRS.from_wkt(las.header.parse_crs().to_wkt()).to_2d().equals(pyproj.CRS(CRS)) or \
        las.header.parse_crs() is not None
    xyz = np.column_stack([las.x, las.y, las.z])
    lx, ly, lz = _to_local(WorldFrame.map(CRS), xyz[:, 0], xyz[:, 1], xyz[:, 2])
    dz = lz - _surface(lx, ly)
    assert np.median(np.abs(dz)) < gsd and len(las.red) == len(xyz)
    m = json.loads((out / "manifest.json").read_text())
    names = {f["path"] for f in m["files"]}
    assert {"dsm.tif", "cloud.laz", "dsm_hillshade.png", "dense.json"} <= names


@pytest.mark.parametrize("case", ["missing_image", "unoriented_image", "geographic_crs", "huge_grid", "no_overlap",
                                  "no_height_range", "bad_height_range", "negative_window"])
def test_cli_bad_input_is_a_clear_error_and_writes_nothing(project, tmp_path, case):
    import shutil

    import cv2

    out = tmp_path / "out"
    p = project
    extra = ["--height-range", "40", "75"]
    if case == "missing_image":
        q = tmp_path / "p"
        shutil.copytree(p, q)
        (q / "images" / "s1_e2.png").unlink()
        p, want = q, "not found"
    elif case == "unoriented_image":
        stray = tmp_path / "stray.png"
        cv2.imwrite(str(stray), np.zeros((H_PX, W_PX), np.uint8))
        extra += ["--images", str(stray)]
        want = "no orientation"
    elif case == "geographic_crs":
        extra += ["--crs", "EPSG:4326"]
        want = "projected CRS"
    elif case == "huge_grid":
        extra += ["--resolution", "0.0001"]
        want = "resolution"
    elif case == "no_overlap":
        extra = ["--height-range", "40", "75", "--heads", "s0_e0,s2_e3"]  # opposite corners of the block
        want = "no stereo pair"
    elif case == "no_height_range":
        extra = []
        want = "--height-range"
    elif case == "negative_window":
        extra += ["--window-min-mp", "-1"]
        want = "--window-min-mp"
    else:
        extra = ["--height-range", "40000", "75000"]
        want = "height range"
    r = _dsm(p, out, *extra)
    assert r.exit_code != 0
    assert want in r.output, r.output
    assert "Traceback" not in r.output
    assert not out.exists()
    assert not [f for f in tmp_path.iterdir() if f.name.startswith(".out.partial")]


def test_cli_lr_check_option_reaches_the_matcher(project, tmp_path, monkeypatch):
    """``skyrig dsm --lr-check full`` runs the second, right-based matching (two SGBM passes per block; OpenCV's
    internal check: one; the banded check, the default: one, and one more per run of row bands with a depth edge),
    records the choice in the manifest, and an unknown value is refused naming the option."""
    from skyrig.dense import sgm

    calls: list[str] = []
    real = sgm._matcher

    class Counting:
        def __init__(self, m, lr):
            self.m, self.lr = m, lr

        def compute(self, a, b):
            calls.append(self.lr)
            return self.m.compute(a, b)

    monkeypatch.setattr(sgm, "_matcher", lambda cfg, n, ch: Counting(real(cfg, n, ch), cfg.lr_check))
    c = _to_map(np.array([-6.0, 6.0]), np.array([-5.0, 5.0]), np.array([50.0, 50.0]))
    area = [str(v) for v in (c[0, 0], c[0, 1], c[1, 0], c[1, 1])]
    counts = {}
    for lr in ("opencv", "banded", "full"):
        calls.clear()
        out = tmp_path / lr
        r = _dsm(project, out, "--height-range", "40", "75", "--pairs-per-image", "2", "--no-cloud", "--area", *area,
                 "--lr-check", lr)
        assert r.exit_code == 0, r.output
        assert set(calls) == {lr} and calls
        counts[lr] = len(calls)
        assert json.loads((out / "manifest.json").read_text())["options"]["lr_check"] == lr
    assert counts["full"] == 2 * counts["opencv"]
    assert counts["opencv"] < counts["banded"]  # the buildings' edges have bands
    r = _dsm(project, tmp_path / "bad", "--height-range", "40", "75", "--lr-check", "both")
    assert r.exit_code != 0 and "--lr-check" in r.output and not (tmp_path / "bad").exists()


def test_lr_band_cols_option_reaches_the_config_and_bad_values_name_the_option(project, block, tmp_path, monkeypatch):
    """``skyrig dsm --lr-band-cols PX`` and the dsm stage's ``lr_band_cols`` set ``SgmConfig.lr_band_cols_px`` (and
    the manifest's options); without it DenseConfig's default; a negative or fractional value is refused naming the
    option (the command line while parsing, the stage's project spelling in make_dsm)."""
    from skyrig.errors import OptionError
    from skyrig.pipeline import dense as pdense
    from skyrig.pipeline.products import make_dsm
    from skyrig.pipeline.run import STAGES, _spelling

    seen: list = []
    monkeypatch.setattr(pdense, "run_dsm", lambda *a, **k: seen.append((k["config"], k["options"])))
    eo, cams, _ = block
    kw = dict(crs=CRS, height_range=(40.0, 75.0))
    for given, want in ((None, DenseConfig().sgm.lr_band_cols_px), (8, 8), (0, 0)):
        seen.clear()
        make_dsm(eo, cams, [project / "images"], tmp_path / "o", lr_band_cols=given, **kw)
        cfg, options = seen[0]
        assert cfg.sgm.lr_band_cols_px == want and options["lr_band_cols"] == want
    for bad in (-1, 2.5, True):
        with pytest.raises(OptionError, match="stages.dsm.lr_band_cols"):
            make_dsm(eo, cams, [project / "images"], tmp_path / "o", lr_band_cols=bad, spell=_spelling("dsm"), **kw)
    assert STAGES["dsm"].options["lr_band_cols"].check(16) == 16
    with pytest.raises(ValueError):
        STAGES["dsm"].options["lr_band_cols"].check(1.5)
    for bad in ("-4", "3.5", "x"):
        r = _dsm(project, tmp_path / "bad", "--height-range", "40", "75", "--lr-band-cols", bad)
        assert r.exit_code != 0 and "--lr-band-cols" in r.output and not (tmp_path / "bad").exists()


def test_cli_on_12_bit_images_gives_the_8_bit_blocks_surface(project, tmp_path):
    """The block's images as 12-bit data in 16-bit PNGs (what aerial cameras deliver, here 16 x the 8-bit value +
    40): ``skyrig dsm`` scales them to 8 bit by the block's levels (OpenCV's own conversion, a shift by 8 bits, leaves
    about 16 grey levels) and gets the 8-bit run's surface: the known points within a GSD of the truth, the same
    cells valid within 2 % and their heights within a tenth of a GSD (median)."""
    import shutil

    import cv2
    import rasterio

    q = tmp_path / "p16"
    shutil.copytree(project, q)
    for f in sorted((q / "images").iterdir()):
        v = cv2.imread(str(f), cv2.IMREAD_UNCHANGED).astype(np.uint16)
        assert cv2.imwrite(str(f), 16 * v + 40)
        assert cv2.imread(str(f), cv2.IMREAD_UNCHANGED).dtype == np.uint16
    c = _to_map(np.array([-22.0, 22.0]), np.array([-18.0, 18.0]), np.array([50.0, 50.0]))
    area = [str(v) for v in (c[0, 0], c[0, 1], c[1, 0], c[1, 1])]
    gsd = HEIGHT / F_PX
    heights = {}
    for name, p in (("8", project), ("16", q)):
        r = _dsm(p, tmp_path / name, "--height-range", "40", "75", "--pairs-per-image", "3", "--no-cloud", "--area",
                 *area)
        assert r.exit_code == 0, r.output
        levels = json.loads((tmp_path / name / "dense.json").read_text())["image_levels_16bit"]
        assert (levels is None) == (name == "8")
        with rasterio.open(tmp_path / name / "dsm.tif") as ds:
            heights[name] = ds.read(1, masked=True).filled(np.nan)
            loc = np.array([[0.5 * (BOX[0] + BOX[2]), 0.5 * (BOX[1] + BOX[3])], [-20.0, -15.0]])
            mp = _to_map(loc[:, 0], loc[:, 1], _surface(loc[:, 0], loc[:, 1]))
            vals = np.array([v[0] for v in ds.sample([tuple(m[:2]) for m in mp], indexes=1)])
            assert np.abs(vals - mp[:, 2]).max() < gsd, name
    v8, v16 = np.isfinite(heights["8"]), np.isfinite(heights["16"])
    assert abs(v16.mean() - v8.mean()) < 0.02, (v8.mean(), v16.mean())
    both = v8 & v16
    assert np.median(np.abs(heights["16"][both] - heights["8"][both])) < 0.1 * gsd


def test_large_tiffs_read_in_windows_give_the_same_surface_bit_for_bit(block, tmp_path):
    """Images read window by window (``ImageFiles.windowed_image``: large aerial TIFFs, here forced on the test
    block's 640 x 480 images) give the DSM and cloud of the whole-image reads bit for bit, no image is read whole,
    and no window is as large as an image."""
    import cv2

    from skyrig.pipeline.dense import ImageFiles

    eo, cams, imgs = block
    paths = []
    for n, im in zip(eo.image, imgs):
        p = tmp_path / (Path(n).stem + ".tif")
        assert cv2.imwrite(str(p), im[..., ::-1])
        paths.append(str(p))
    cfg = DenseConfig(tile_cells=4096, block_px=256, pairs=PairConfig(pairs_per_image=2))
    c = _to_map(np.array([-8.0, 8.0]), np.array([-6.0, 6.0]), np.array([50.0, 50.0]))
    area = (c[0, 0], c[0, 1], c[1, 0], c[1, 1])
    sizes = [(W_PX, H_PX)] * len(paths)
    whole = dense_surface(eo, cams, ImageFiles(paths, sizes), WorldFrame.map(CRS), (40.0, 75.0), area, cfg)

    class Counting(ImageFiles):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            self.whole, self.windows = 0, []

        def __call__(self, i):
            self.whole += 1
            return super().__call__(i)

        def _read_window(self, i, grey, bands, c0, r0, c1, r1):
            self.windows.append((c1 - c0) * (r1 - r0))
            return super()._read_window(i, grey, bands, c0, r0, c1, r1)

    loader = Counting(paths, sizes, window_min_pixels=0)
    win = dense_surface(eo, cams, loader, WorldFrame.map(CRS), (40.0, 75.0), area, cfg)
    assert loader.whole == 0 and loader.windows and max(loader.windows) < W_PX * H_PX
    assert np.isfinite(whole[0].height).mean() > 0.5
    for a, b in ((whole[0].height, win[0].height), (whole[0].support, win[0].support),
                 (whole[0].sigma, win[0].sigma), (whole[0].spread, win[0].spread)):
        assert np.array_equal(a, b, equal_nan=True)
    assert np.array_equal(whole[1].xyz, win[1].xyz) and np.array_equal(whole[1].rgb, win[1].rgb)


def test_tile_side_from_the_memory_budget_and_predicted_points_per_tile(block):
    """With a memory budget the ground tiles' side is the largest (multiples of 128 cells, then 64) whose
    tiles' predicted work fits it; the predicted points of a tile (every block's matchable pixels spread over its
    ground bounds) are, against the points its run triangulates into the tile, an upper bound within a factor
    (0.4-1.1; 0.77-1.03 on the 240-image growth block's 768-cell tiles, where a few points more than predicted
    come from the blocks' uneven spread)."""
    from skyrig.dense.surface import ground_tiles, plan_dense, run_tile, tile_load

    eo, cams, imgs = block
    base = DenseConfig(tile_cells=256, block_px=256, pairs=PairConfig(pairs_per_image=4), tile_memory_mb=None)
    free = plan_dense(eo, cams, WorldFrame.map(CRS), (40.0, 75.0), config=base)
    px = [free.cameras[str(c)].width * free.cameras[str(c)].height for c in free.eo.camera]

    def load(side):
        return tile_load(free.grid, ground_tiles(free.grid, side), free.pairs, free.rects, free.blocks,
                         free.block_bounds, free.config.sgm, px)

    budget = 0.5 * (load(256)[1].max() + load(128)[1].max()) / 2 ** 20  # 256-cell tiles do not fit, 128 do
    plan = plan_dense(eo, cams, WorldFrame.map(CRS), (40.0, 75.0), config=replace(base, tile_memory_mb=budget))
    assert len(free.tiles) < len(plan.tiles) == len(ground_tiles(plan.grid, 128))
    assert max(max(h, w) for _, _, h, w in plan.tiles) <= 128
    pts, nbytes = load(128)
    assert nbytes.max() <= budget * 2 ** 20
    assert (nbytes - pts * 80 > 0).all()  # the images of the pairs reaching a tile are counted too
    got = {k: run_tile(plan, k, lambda i: imgs[i]).points for k in (int(np.argmax(pts)), int(np.argsort(pts)[len(pts) // 2]), 0)}
    for k in (int(np.argmax(pts)), int(np.argsort(pts)[len(pts) // 2])):  # the loaded tiles the budget is about
        assert 0.4 * pts[k] <= got[k] <= 1.1 * pts[k], (k, got[k], pts[k])
    assert got[0] <= 1.1 * pts[0]  # a corner of the grid, where few images reach: far below the bound


def test_an_unreachable_tile_budget_takes_the_least_work_side_and_says_so(block, caplog):
    """The images reaching a tile do not shrink with tiles smaller than their footprints: a budget below them
    takes the largest side within 10 % of the least predicted work, with a warning naming the option."""
    from skyrig.dense.surface import ground_tiles, plan_dense, tile_load

    eo, cams, _ = block
    cfg = DenseConfig(tile_cells=256, block_px=256, pairs=PairConfig(pairs_per_image=4), tile_memory_mb=1.0)
    with caplog.at_level("WARNING", logger="skyrig.dense.surface"):
        plan = plan_dense(eo, cams, WorldFrame.map(CRS), (40.0, 75.0), config=cfg)
    assert "option: tile_memory_mb" in caplog.text
    px = [plan.cameras[str(c)].width * plan.cameras[str(c)].height for c in plan.eo.camera]
    work = {s: tile_load(plan.grid, ground_tiles(plan.grid, s), plan.pairs, plan.rects, plan.blocks,
                         plan.block_bounds, plan.config.sgm, px)[1].max() for s in (256, 128, 64)}
    side = max(max(h, w) for _, _, h, w in plan.tiles)
    chosen = min(s for s in work if s >= side)
    assert work[chosen] <= 1.1 * min(work.values()) and min(work.values()) > 2 ** 20
    assert all(work[s] > 1.1 * min(work.values()) for s in work if s > chosen)


def test_tile_memory_option_is_checked(block, tmp_path):
    """A budget that is not a positive number of MiB names the option (project spelling)."""
    from skyrig.errors import OptionError
    from skyrig.pipeline.products import make_dsm

    eo, cams, _ = block
    for bad in (0, -5.0, float("nan")):
        with pytest.raises(OptionError, match="stages.dsm.tile_memory_mb"):
            make_dsm(eo, cams, [], tmp_path / "dsm", crs=CRS, height_range=(40.0, 75.0), tile_memory_mb=bad,
                     spell=lambda name: f"stages.dsm.{name}")
