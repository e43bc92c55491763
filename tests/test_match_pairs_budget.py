"""Per-image pair budget of guided matching (skyrig.match.pairs.budget_pairs) on seeded simulated MIDAS blocks.

Independent answers: the simulation's own strips and heads (the cross-strip / cross-head links that must survive
are found here by a plain loop over the candidate pairs), the graph's connectivity, and the truth of the seeded
block: a bundle adjustment of the tie points the budgeted pairs can give is compared with one of the tie points
every overlapping pair gives, both against the truth and in units of the adjustment's predicted sigma.

Tie points of a pair selection: every simulated object point seen by a set of images is "matched" in a selected
pair of two of those images with probability 0.5 (seeded, the same draws for both selections), and the tracks are
the connected components of those matches (as build_tracks joins pairwise matches), one object point each; a
track of one image is lost.  So fewer pairs give shorter, split or lost tracks, as in real matching.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from skyrig.adjust import AdjustConfig, adjust
from skyrig.adjust.synthetic import synthetic_block
from skyrig.geodesy.frame import WorldFrame
from skyrig.georef.eo import ExteriorOrientations
from skyrig.match.pairs import budget_pairs, footprint_pairs, image_strips, pair_graph_components
from skyrig.rig.presets import midas

BUDGET = 12


def _block(n_strips: int, n_per_strip: int, n_points: int = 1500):
    b, truth = synthetic_block(seed=5, n_strips=n_strips, n_per_strip=n_per_strip, n_points=n_points, rig=midas(),
                               height_m=500.0, n_control=0, relief_m=10.0)
    st = b.image_station
    rot = truth.station_rotation[st] @ b.image_rotation
    centre = truth.station_centre[st] + np.einsum("nij,nj->ni", truth.station_rotation[st], b.image_offset)
    cams = {f"c{k}": c for k, c in enumerate(b.cameras)}
    eo = ExteriorOrientations(b.image_name, np.array([f"c{k}" for k in b.image_camera]), centre, rot,
                              WorldFrame.local(50.0, 10.0, 0.0), time_s=b.station_time[st], exposure=st)
    pairs, overlap = footprint_pairs(eo, cams, 0.0, min_overlap=0.1)
    return b, truth, eo, pairs, overlap


@pytest.fixture(scope="module")
def small():
    return _block(3, 6)


@pytest.fixture(scope="module")
def large():
    return _block(5, 10)


def test_strips_from_event_times_are_the_flown_strips(large):
    b, _, eo, _, _ = large
    assert np.array_equal(image_strips(eo), b.station_strip[b.image_station])
    no_time = dataclasses.replace(eo, time_s=None)
    assert np.all(image_strips(no_time) == -1)


def test_budget_bounds_pairs_per_image_keeps_the_block_connected_and_every_link_kind(small, large):
    per_image = {}
    for name, (b, _, eo, pairs, overlap) in (("small", small), ("large", large)):
        n = b.n_images
        strip = b.station_strip[b.image_station]  # the simulation's strips, not image_strips
        keep = budget_pairs(pairs, overlap, n, BUDGET, eo.camera, image_strips(eo))
        kept = pairs[keep]
        deg_all = np.bincount(pairs.ravel(), minlength=n)
        deg = np.bincount(kept.ravel(), minlength=n)
        per_image[name] = (deg_all.mean(), deg.mean())
        # bounded: the budget plus at most one forced link per kind (3 strip sides x the heads)
        assert deg.max() <= BUDGET + 3 * len(b.cameras), name
        assert pair_graph_components(pairs, n) == 1
        assert pair_graph_components(kept, n) == 1, f"{name}: the budgeted pair graph falls apart"
        # every image keeps a link of every kind it has among the candidates: same / lower / higher strip x head
        kinds_all: dict[int, set] = {i: set() for i in range(n)}
        kinds_kept: dict[int, set] = {i: set() for i in range(n)}
        for (i, j), k in zip(pairs, keep):
            for a, c in ((i, j), (j, i)):
                kind = (int(b.image_camera[c]), int(np.sign(strip[c] - strip[a])))
                kinds_all[a].add(kind)
                if k:
                    kinds_kept[a].add(kind)
        missing = [(i, kinds_all[i] - kinds_kept[i]) for i in range(n) if kinds_all[i] - kinds_kept[i]]
        assert not missing, f"{name}: images lost a link kind, e.g. {missing[:3]}"
        cross = sum(any(s != 0 for _, s in kinds_kept[i]) for i in range(n))
        assert cross == sum(any(s != 0 for _, s in kinds_all[i]) for i in range(n))
        # the strongest pairs are the ones kept: the kept pairs' overlap is above the dropped ones' on average
        assert overlap[keep].mean() > overlap[~keep].mean()
    # every overlapping pair grows with the block (obliques see several strips); the budget does not
    assert per_image["large"][0] > 1.2 * per_image["small"][0]
    assert per_image["large"][1] < 0.5 * per_image["large"][0]
    assert per_image["large"][1] <= 1.15 * per_image["small"][1]


def test_no_budget_keeps_every_pair(small):
    b, _, eo, pairs, overlap = small
    assert budget_pairs(pairs, overlap, b.n_images, 0).all()
    assert budget_pairs(pairs, overlap, b.n_images, None).all()
    with pytest.raises(ValueError):
        budget_pairs(pairs, overlap[:-1], b.n_images, BUDGET)


def _tie_points_of(b, pairs: np.ndarray, p_match: float = 0.5, seed: int = 7):
    """The block with the tracks a pair selection gives (module docstring)."""
    n = b.n_images
    code = set((pairs[:, 0] * n + pairs[:, 1]).tolist())
    order = np.argsort(b.obs_point, kind="stable")
    op, oi = b.obs_point[order], b.obs_image[order]
    starts = np.flatnonzero(np.r_[True, op[1:] != op[:-1]])
    stops = np.r_[starts[1:], len(op)]
    rng = np.random.default_rng(seed)
    ea, eb = [], []
    for a, z in zip(starts, stops):
        for u in range(a, z):
            for v in range(u + 1, z):
                i, j = sorted((int(oi[u]), int(oi[v])))
                if rng.random() < p_match and i * n + j in code:  # the same draws whatever the selection
                    ea.append(u)
                    eb.append(v)
    m = len(op)
    _, lab = connected_components(coo_matrix((np.ones(len(ea)), (ea, eb)), shape=(m, m)), directed=False)
    ok = np.bincount(lab)[lab] >= 2
    track = np.unique(lab[ok], return_inverse=True)[1]
    src = np.zeros(track.max() + 1, np.int64)
    src[track] = op[ok]
    idx = order[ok]
    return dataclasses.replace(b, obs_image=b.obs_image[idx], obs_point=track, obs_pixel=b.obs_pixel[idx],
                               obs_sigma_px=b.obs_sigma_px[idx], point_xyz=b.point_xyz[src],
                               point_name=np.array([f"t{k}" for k in range(len(src))]))


def test_budgeted_block_adjusts_as_precisely_and_accurately_as_all_pairs(small):
    b, truth, eo, pairs, overlap = small
    keep = budget_pairs(pairs, overlap, b.n_images, BUDGET, eo.camera, image_strips(eo))
    assert keep.mean() < 0.75  # the budget does drop pairs on this block
    res = {}
    for name, sel in (("all", pairs), ("budget", pairs[keep])):
        bb = _tie_points_of(b, sel)
        r = adjust(bb, AdjustConfig())
        assert r.info.converged, name
        res[name] = r
    sig = {k: r.pose_sigma[:, :3] for k, r in res.items()}
    # precision: the predicted sigma of the centres grows by less than 5 %
    ratio = np.sqrt(np.mean(sig["budget"] ** 2)) / np.sqrt(np.mean(sig["all"] ** 2))
    assert ratio < 1.05, f"centre sigma x {ratio:.3f} with the budget"
    # accuracy: errors vs truth within the predicted sigma (no normalised error beyond 4, RMS not above 1 + band)
    n_err = 3 * b.n_stations
    for name, r in res.items():
        e = (r.block.station_centre - truth.station_centre) / sig[name]
        assert np.abs(e).max() < 4.0, name
        assert np.sqrt(np.mean(e**2)) < 1.0 + 4.0 / np.sqrt(2.0 * n_err), name
    # and the two solutions differ by a small part of the predicted sigma
    d = (res["budget"].block.station_centre - res["all"].block.station_centre) / sig["all"]
    assert np.sqrt(np.mean(d**2)) < 0.5, f"budget vs all pairs: RMS {np.sqrt(np.mean(d**2)):.2f} sigma apart"
