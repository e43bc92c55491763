"""The compiled grid fusion (``fuse_grid`` -> ``_kernels.fuse_buckets`` / ``_grid_cell``) against a plain numpy
transcription of steps 1-3 of :mod:`skyrig.dense.fusion`, cell by cell, on seeded random cells of 1 to 30 pairs
(per-pair medians of 1-4 points, walls over ``max_pair_range_cells``, outlying pairs, points without a sigma):
heights, support, spread (1.4826 x the median absolute deviation of the supporting pair heights), sigma, and the
candidates of the cells whose pairs all agree but are too few."""

from __future__ import annotations

import numpy as np

from skyrig.dense.fusion import FusionConfig, fuse_grid
from skyrig.dense.grid import GridSpec


def _reference_cell(pair, h, s, cfg: FusionConfig, cell_m: float):  # type: ignore[no-untyped-def]
    """Steps 1-3 for one cell's points: ``("kept", height, support, spread, sigma)``, ``("cand", height, sigma,
    n)`` (all pairs agree, too few), or ``("none",)``."""
    ph, ps = [], []
    for p in np.unique(pair):  # pair ids ascending, as the kernel orders them
        k = pair == p
        hp, sp = h[k], s[k]
        o = np.argsort(hp, kind="stable")
        hp, sp = hp[o], sp[o]
        if cfg.max_pair_range_cells > 0 and hp[-1] - hp[0] > cfg.max_pair_range_cells * cell_m:
            continue
        lo, hi = (len(hp) - 1) // 2, len(hp) // 2
        ph.append(0.5 * (hp[lo] + hp[hi]))
        ps.append(0.5 * (sp[lo] + sp[hi]))
    if not ph:
        return ("none",)
    ph, ps = np.array(ph), np.array(ps)
    pw = 1.0 / ps ** 2
    o = np.argsort(ph, kind="stable")
    cum = np.cumsum(pw[o])
    med_i = o[np.flatnonzero(cum >= 0.5 * pw.sum() * (1 - 1e-12))[0]]
    d = np.abs(ph - ph[med_i])
    sup = (d <= cfg.min_tol_cells * cell_m) | (d <= cfg.k_sigma * np.sqrt(ps ** 2 + ps[med_i] ** 2))
    n = int(sup.sum())
    fused = np.sum(pw[sup] * ph[sup]) / np.sum(pw[sup])
    sigma = 1.0 / np.sqrt(np.sum(pw[sup]))
    if n < cfg.min_support or n < cfg.min_support_ratio * len(ph):
        return ("cand", fused, sigma, n) if n == len(ph) else ("none",)
    spread = 1.4826 * np.median(np.abs(ph[sup] - fused)) if n >= 2 else np.nan
    return ("kept", fused, n, spread, sigma)


def test_grid_fusion_equals_numpy_reference_cell_by_cell():
    rng = np.random.default_rng(35)
    g = GridSpec(1000.0, 2000.0, 0.5, 24, 20)
    cfg = FusionConfig()
    xs, ys, hs, ss, ps = [], [], [], [], []
    cells = []
    for r in range(g.height):
        for c in range(g.width):
            npairs = int(rng.integers(1, 31))
            surface = 50.0 + rng.normal(0, 3)
            pairs = np.sort(rng.choice(60, npairs, replace=False))
            for p in pairs:
                m = int(rng.integers(1, 5))
                sig = rng.uniform(0.02, 0.3)
                hh = surface + rng.normal(0, sig, m)
                u = rng.random()
                if u < 0.1:  # an outlying pair
                    hh += rng.choice([-1, 1]) * rng.uniform(1, 5)
                elif u < 0.15 and m > 1:  # a wall seen by this pair: its points span metres of height
                    hh[0] += 4.0
                sg = np.full(m, sig)
                sg[rng.random(m) < 0.03] = 0.0  # no precision: left out
                xs.append(g.x0 + (c + rng.uniform(0.01, 0.99, m)) * g.cell_m)
                ys.append(g.y0 - (r + rng.uniform(0.01, 0.99, m)) * g.cell_m)
                hs.append(hh)
                ss.append(sg)
                ps.append(np.full(m, p))
            cells.append((r, c))
    x, y, h, s, pair = (np.concatenate(v) for v in (xs, ys, hs, ss, ps))
    order = rng.permutation(len(x))  # the points in any order (each cell's in its pairs' order: pair ids grow)
    order = order[np.argsort(pair[order], kind="stable")]
    x, y, h, s, pair = x[order], y[order], h[order], s[order], pair[order]
    H, N, SP, S, CH, CS, CN = fuse_grid(g, pair, x, y, h, s, cfg, candidates=True)[:7]
    row, col = g.cell_of(x, y)
    kinds = {"kept": 0, "cand": 0, "none": 0}
    for r, c in cells:
        k = (row == r) & (col == c) & (s > 0)
        ref = _reference_cell(pair[k], h[k], s[k], cfg, g.cell_m)
        kinds[ref[0]] += 1
        if ref[0] == "kept":
            _, fh, n, spread, sigma = ref
            assert N[r, c] == n, (r, c)
            np.testing.assert_allclose([H[r, c], S[r, c]], [fh, sigma], rtol=1e-6)
            if n >= 2:
                np.testing.assert_allclose(SP[r, c], spread, rtol=1e-5, atol=1e-7)
            else:
                assert np.isnan(SP[r, c])
        else:
            assert np.isnan(H[r, c]) and N[r, c] == 0, (r, c)
            if ref[0] == "cand":
                np.testing.assert_allclose([CH[r, c], CS[r, c]], ref[1:3], rtol=1e-6)
                assert CN[r, c] == ref[3]
    assert kinds["kept"] > 300 and kinds["cand"] > 10 and kinds["none"] > 5, kinds  # every branch is exercised
