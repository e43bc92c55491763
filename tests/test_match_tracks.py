"""Tracks (against a plain-Python union-find), thinning, pair selection (against brute force) and its linear growth."""

from __future__ import annotations

import numpy as np

from skyrig.camera.frame import FrameCamera
from skyrig.georef.eo import ExteriorOrientations, WorldFrame
from skyrig.geometry.rotations import NADIR_BODY_FROM_CAMERA
from skyrig.match.pairs import exhaustive_pairs, footprint_pairs, gps_pairs
from skyrig.match.tracks import build_tracks, thin_tracks, tracks_to_measurements


def _reference_tracks(n_feat, pm):
    parent = {}

    def find(a):
        while parent.setdefault(a, a) != a:
            a = parent[a]
        return a

    for (i, j), m in pm.items():
        for a, b in m:
            parent[find((i, a))] = find((j, b))
    comps = {}
    for node in parent:
        comps.setdefault(find(node), set()).add(node)
    good = [c for c in comps.values() if len({n[0] for n in c}) == len(c)]
    return {frozenset(c) for c in good}, len(comps) - len(good)


def test_tracks_match_plain_union_find():
    rng = np.random.default_rng(5)
    n_feat = [50, 60, 55, 40]
    pm = {}
    for i, j in exhaustive_pairs(4):
        m = np.column_stack([rng.choice(n_feat[i], 25, replace=False), rng.choice(n_feat[j], 25, replace=False)])
        pm[(int(i), int(j))] = m
    t = build_tracks(n_feat, pm)
    ref, bad = _reference_tracks(n_feat, pm)
    got = {frozenset((int(a), int(b)) for a, b in zip(t.image[t.track == k], t.feature[t.track == k]))
           for k in range(t.n_tracks)}
    assert got == ref
    assert t.n_inconsistent == bad
    assert np.all(t.multiplicity() >= 2)


def test_thinning_keeps_a_spread_and_the_longest_tracks():
    rng = np.random.default_rng(2)
    n = 400
    xy = [rng.uniform(0, 100, (n, 2)), rng.uniform(0, 100, (n, 2)), rng.uniform(0, 100, (n, 2))]
    ids = np.arange(n)
    pm = {(0, 1): np.column_stack([ids, ids]), (1, 2): np.column_stack([ids[:100], ids[:100]])}
    t = build_tracks([n, n, n], pm)
    th = thin_tracks(t, xy, [(100, 100)] * 3, cells=(4, 4), per_cell=2)
    for img in range(2):
        p = xy[img][th.feature[th.image == img]]
        cells = set(map(tuple, (p // 25).astype(int)))
        assert len(cells) == 16  # every cell of images 0 and 1 still has ties
    # in image 2 (all ties there are 3-fold) per-cell selection prefers 3-fold tracks: all kept in image 2 cells
    mult = th.multiplicity()
    assert np.sum(mult == 3) >= min(100, 2 * 16)
    m = tracks_to_measurements(th, xy, ["a", "b", "c"])
    assert len(m) == len(th.track) and set(m.image) == {"a", "b", "c"}


def test_gps_pairs_against_brute_force():
    rng = np.random.default_rng(3)
    c = rng.uniform(0, 500, (40, 3))
    p = gps_pairs(c, k=4)
    d = np.linalg.norm(c[:, None] - c[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    ref = set()
    for i in range(40):
        for j in np.argsort(d[i])[:4]:
            ref.add((min(i, j), max(i, j)))
    assert {tuple(x) for x in p.tolist()} == ref
    h = np.where(np.arange(40) < 20, 0.0, 180.0)
    ph = gps_pairs(c, k=4, heading_deg=h, max_heading_diff_deg=90)
    assert np.all((ph[:, 0] < 20) == (ph[:, 1] < 20))


def _grid_block(nx, ny, spacing=60.0, height=300.0):
    cam = FrameCamera.from_pixels("c", 1000, 800, 1000.0, 499.5, 399.5)
    xs, ys = np.meshgrid(np.arange(nx) * spacing, np.arange(ny) * spacing * 2.0)
    c = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, height)])
    R = np.broadcast_to(np.diag([1.0, 1.0, 1.0]), (len(c), 3, 3))  # level, x east: nadir
    eo = ExteriorOrientations(np.array([f"i{k}" for k in range(len(c))]), "c", c, R, WorldFrame.local(0, 0, 0))
    return eo, {"c": cam}


def test_footprint_pairs_grow_linearly_and_agree_with_brute_force():
    counts = []
    for ny in (2, 4, 8):
        eo, cams = _grid_block(10, ny)
        p, ov = footprint_pairs(eo, cams, 0.0, min_overlap=0.2, grid=11)
        counts.append(len(p) / len(eo))
        # brute force on a dense grid of the true footprint rectangles (300 x 240 m on the ground)
        if ny == 2:
            ref = set()
            for i, j in exhaustive_pairs(len(eo)):
                dx, dy = np.abs(eo.centre[i, :2] - eo.centre[j, :2])
                frac = max(0.0, 1 - dx / 300.0) * max(0.0, 1 - dy / 240.0)
                if frac >= 0.25:
                    ref.add((int(i), int(j)))
                if 0 < frac < 0.12:
                    assert (int(i), int(j)) not in {tuple(x) for x in p.tolist()}
            assert ref <= {tuple(x) for x in p.tolist()}
    assert max(counts) < 1.6 * min(counts)  # pairs per image stay bounded: linear growth
    assert len(p) < 0.25 * len(exhaustive_pairs(len(eo)))
