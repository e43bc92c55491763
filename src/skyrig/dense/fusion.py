"""Multi-view fusion in object space: per DSM cell and per point-cloud voxel.

Grid fusion (:func:`fuse_grid`), for every cell:

1. each stereo pair contributes one height: the median of its points in the cell (with their predicted
   height precision ``sigma``);
2. the pairs' heights are combined robustly: the precision-weighted median ``m``; a pair *supports* the
   cell when ``|h - m| <= max(k * sqrt(sigma^2 + sigma_m^2), min_tol)``;
3. the cell is kept when at least ``min_support`` pairs support it (a height that no second pair confirms
   is rejected); its height is the precision-weighted mean of the supporting heights, its ``sigma`` the
   propagated precision of that mean, its ``spread`` 1.4826 x the median absolute deviation of the
   supporting heights (NaN with one supporting pair).

Cloud fusion (:func:`fuse_cloud`): points of all pairs are binned in voxels on a global lattice; a voxel
becomes one point when ``min_support`` distinct pairs have points in it: precision-weighted mean position,
mean colour and normal, the number of pairs as support.

Every step is a deterministic function of the points in a cell (or voxel), sorted by stable keys, so a cell
gets the same value whichever ground tile it was computed in.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from skyrig.dense.grid import GridSpec


@dataclass(frozen=True)
class FusionConfig:
    """Fusion options.

    Attributes
    ----------
    min_support
        Pairs that must agree for a cell or voxel to be kept (2: every height confirmed by a second pair).
    k_sigma
        Agreement tolerance in combined predicted sigmas.
    min_tol_cells
        Least agreement tolerance in cell sizes (heights vary within a cell on slopes and edges).
    min_support_ratio
        Least share of the pairs with a height in the cell that must support it (a cell where the pairs split
        into camps - typical next to a wall, where some views see the roof and others the ground - is left
        empty rather than guessed).
    """

    min_support: int = 2
    k_sigma: float = 3.0
    min_tol_cells: float = 1.0
    min_support_ratio: float = 0.5


def _group_starts(sorted_keys: NDArray[np.int64]) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Start index and length of runs of equal keys in a sorted array."""
    if len(sorted_keys) == 0:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    starts = np.flatnonzero(np.r_[True, sorted_keys[1:] != sorted_keys[:-1]])
    lengths = np.diff(np.r_[starts, len(sorted_keys)])
    return starts, lengths


def _sort_by(key: NDArray[np.int64], value: NDArray[np.float64]) -> NDArray[np.intp]:
    """Order by integer key, then value (two stable sorts: much faster than ``np.lexsort`` on millions)."""
    o = np.argsort(value, kind="stable")
    return o[np.argsort(key[o], kind="stable")]


def _voxel_keys(ijk: NDArray[np.int64]) -> NDArray[np.int64]:
    """One int64 per voxel index triple (21 bits per axis, +-2^20 voxels around the lattice origin)."""
    off = 1 << 20
    if ijk.size and (ijk.min() < -off or ijk.max() >= off):
        raise ValueError("point cloud spans more than 2^20 voxels along an axis: use a larger voxel")
    q = ijk + off
    return (q[:, 0] << 42) | (q[:, 1] << 21) | q[:, 2]


def _group_median(values: NDArray[np.float64], starts: NDArray[np.intp], lengths: NDArray[np.intp]
                  ) -> NDArray[np.float64]:
    """Median of each run of an array sorted by (group, value)."""
    lo = starts + (lengths - 1) // 2
    hi = starts + lengths // 2
    return 0.5 * (values[lo] + values[hi])


def fuse_grid(grid: GridSpec, pair: NDArray[np.int64], x: NDArray[np.float64], y: NDArray[np.float64],
              h: NDArray[np.float64], sigma: NDArray[np.float64], cfg: FusionConfig = FusionConfig()
              ) -> tuple[NDArray[np.float32], NDArray[np.int16], NDArray[np.float32], NDArray[np.float32]]:
    """Fuse points of several stereo pairs into a grid.

    Parameters
    ----------
    grid
        The cells (map coordinates).
    pair
        ``(M,)`` pair id of each point (any non-negative integers).
    x, y, h
        ``(M,)`` map coordinates and heights (metres).
    sigma
        ``(M,)`` predicted height precision of each point (metres, > 0).
    cfg
        Fusion options.

    Returns
    -------
    height, support, spread, sigma
        ``grid.shape`` arrays as :class:`skyrig.dense.grid.DsmGrid` holds them.
    """
    H, W = grid.shape
    out_h = np.full(H * W, np.nan, np.float32)
    out_n = np.zeros(H * W, np.int16)
    out_sp = np.full(H * W, np.nan, np.float32)
    out_s = np.full(H * W, np.nan, np.float32)
    row, col = grid.cell_of(x, y)
    ok = (row >= 0) & (row < H) & (col >= 0) & (col < W) & np.isfinite(h) & (sigma > 0)
    if not ok.any():
        shape = grid.shape
        return out_h.reshape(shape), out_n.reshape(shape), out_sp.reshape(shape), out_s.reshape(shape)
    cell = (row[ok] * W + col[ok]).astype(np.int64)
    pr = np.asarray(pair, np.int64)[ok]
    hv = np.asarray(h, np.float64)[ok]
    sv = np.asarray(sigma, np.float64)[ok]
    npair = int(pr.max()) + 1
    # 1. one height per (cell, pair): the median, with the median sigma
    key = cell * npair + pr
    o = _sort_by(key, hv)
    st, ln = _group_starts(key[o])
    ph = _group_median(hv[o], st, ln)
    so = _sort_by(key, sv)
    ps = _group_median(sv[so], *_group_starts(key[so]))
    pc = key[o][st] // npair
    # 2. per cell: precision-weighted median of the pairs' heights
    o2 = _sort_by(pc, ph)
    pc, ph, ps = pc[o2], ph[o2], ps[o2]
    w = 1.0 / ps ** 2
    cst, cln = _group_starts(pc)
    gid = np.repeat(np.arange(len(cst)), cln)
    cw = np.cumsum(w)
    before = np.r_[0.0, cw][cst]
    total = np.add.reduceat(w, cst)
    within = cw - before[gid]
    # first element of each group whose cumulative weight reaches half the group's weight
    half = within >= 0.5 * total[gid] * (1 - 1e-12)
    first = np.minimum.reduceat(np.where(half, np.arange(len(ph)), len(ph)), cst)
    med = ph[first]
    smed = ps[first]
    tol = np.maximum(cfg.k_sigma * np.sqrt(ps ** 2 + smed[gid] ** 2), cfg.min_tol_cells * grid.cell_m)
    sup = np.abs(ph - med[gid]) <= tol
    ws = np.where(sup, w, 0.0)
    wsum = np.add.reduceat(ws, cst)
    nsup = np.add.reduceat(sup.astype(np.int64), cst)
    with np.errstate(invalid="ignore", divide="ignore"):
        fused = np.add.reduceat(ws * ph, cst) / wsum
        fsig = 1.0 / np.sqrt(wsum)
    # 3. robust spread of the supporting heights: 1.4826 x median |h - fused|
    dev = np.where(sup, np.abs(ph - fused[gid]), np.inf)
    o3 = _sort_by(gid, dev)
    dev_s = dev[o3]
    mad_idx_lo = cst + (nsup - 1) // 2
    mad_idx_hi = cst + nsup // 2
    mad = 0.5 * (dev_s[np.clip(mad_idx_lo, 0, len(dev_s) - 1)] + dev_s[np.clip(mad_idx_hi, 0, len(dev_s) - 1)])
    spread = np.where(nsup >= 2, 1.4826 * mad, np.nan)
    keep = (nsup >= cfg.min_support) & (nsup >= cfg.min_support_ratio * cln)
    cells = pc[cst][keep]
    out_h[cells] = fused[keep]
    out_n[cells] = np.minimum(nsup[keep], np.iinfo(np.int16).max)
    out_sp[cells] = spread[keep]
    out_s[cells] = fsig[keep]
    shape = grid.shape
    return out_h.reshape(shape), out_n.reshape(shape), out_sp.reshape(shape), out_s.reshape(shape)


def fuse_cloud(origin: tuple[float, float, float], voxel_m: float, pair: NDArray[np.int64], xyz: NDArray[np.float64],
               sigma: NDArray[np.float64], rgb: NDArray[np.uint8], normal: NDArray[np.float32],
               cfg: FusionConfig = FusionConfig()
               ) -> tuple[NDArray[np.float64], NDArray[np.uint8], NDArray[np.float32], NDArray[np.int16], NDArray[np.float32]]:
    """Fuse points of several pairs in voxels of side ``voxel_m`` on the lattice through ``origin``.

    Returns
    -------
    xyz, rgb, normal, support, sigma
        One row per kept voxel, ordered by voxel index.
    """
    if len(xyz) == 0:
        return (np.zeros((0, 3)), np.zeros((0, 3), np.uint8), np.zeros((0, 3), np.float32), np.zeros(0, np.int16),
                np.zeros(0, np.float32))
    ijk = np.floor((xyz - np.asarray(origin)) / voxel_m).astype(np.int64)
    vox = _voxel_keys(ijk)
    pr = np.asarray(pair, np.int64)
    o = np.argsort(pr, kind="stable")
    o = o[np.argsort(vox[o], kind="stable")]
    vs, ps = vox[o], pr[o]
    st, ln = _group_starts(vs)
    newpair = np.r_[True, (vs[1:] != vs[:-1]) | (ps[1:] != ps[:-1])]
    npairs = np.add.reduceat(newpair.astype(np.int64), st)
    keep = npairs >= cfg.min_support
    w = 1.0 / np.maximum(np.asarray(sigma, np.float64)[o], 1e-9) ** 2
    wsum = np.add.reduceat(w, st)
    pos = np.stack([np.add.reduceat(w * xyz[o, k], st) for k in range(3)], axis=1) / wsum[:, None]
    col = np.stack([np.add.reduceat(rgb[o, k].astype(np.float64), st) for k in range(3)], axis=1) / ln[:, None]
    nv = np.nan_to_num(normal[o].astype(np.float64))
    nsum = np.stack([np.add.reduceat(nv[:, k], st) for k in range(3)], axis=1)
    nn = np.linalg.norm(nsum, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        nsum = np.where(nn > 0, nsum / nn, np.nan)
    return (pos[keep], np.round(col[keep]).astype(np.uint8), nsum[keep].astype(np.float32),
            np.minimum(npairs[keep], np.iinfo(np.int16).max).astype(np.int16),
            (1.0 / np.sqrt(wsum[keep])).astype(np.float32))
