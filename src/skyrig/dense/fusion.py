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

Cloud fusion (:func:`fuse_cloud`): points of all pairs are binned in voxels (grid cells x height slices); a voxel
becomes one point when ``min_support`` distinct pairs have points in it: precision-weighted mean position,
mean colour and normal, the number of pairs as support.

Every step is a deterministic function of the points in a cell (or voxel), so a cell gets the same value
whichever ground tile it was computed in.  The loops run compiled (:mod:`skyrig.dense._kernels`): a counting
sort by cell, then small sorts inside each cell.
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
    from skyrig.dense._kernels import counting_order, fuse_grid_cells

    H, W = grid.shape
    out_h = np.full(H * W, np.nan, np.float32)
    out_n = np.zeros(H * W, np.int16)
    out_sp = np.full(H * W, np.nan, np.float32)
    out_s = np.full(H * W, np.nan, np.float32)
    row, col = grid.cell_of(x, y)
    ok = (row >= 0) & (row < H) & (col >= 0) & (col < W) & np.isfinite(h) & (sigma > 0)
    if ok.any():
        cell = (row[ok] * W + col[ok]).astype(np.int64)
        order, start = counting_order(cell, H * W)
        fuse_grid_cells(order, start, np.asarray(pair, np.int64)[ok], np.asarray(h, np.float64)[ok],
                        np.asarray(sigma, np.float64)[ok], float(cfg.k_sigma), float(cfg.min_tol_cells * grid.cell_m),
                        int(cfg.min_support), float(cfg.min_support_ratio), out_h, out_n, out_sp, out_s)
    shape = grid.shape
    return out_h.reshape(shape), out_n.reshape(shape), out_sp.reshape(shape), out_s.reshape(shape)


def fuse_cloud(grid: GridSpec, voxel_z_m: float, pair: NDArray[np.int64], xyz: NDArray[np.float64],
               sigma: NDArray[np.float64], rgb: NDArray[np.uint8], normal: NDArray[np.float32],
               cfg: FusionConfig = FusionConfig()
               ) -> tuple[NDArray[np.float64], NDArray[np.uint8], NDArray[np.float32], NDArray[np.int16], NDArray[np.float32]]:
    """Fuse points of several pairs in voxels: the cells of ``grid`` x height slices of ``voxel_z_m``
    (slices counted from height 0).  Points outside the grid are ignored.

    Returns
    -------
    xyz, rgb, normal, support, sigma
        One row per kept voxel, ordered by cell, then height.
    """
    from skyrig.dense._kernels import counting_order, fuse_voxels

    H, W = grid.shape
    row, col = grid.cell_of(xyz[:, 0], xyz[:, 1]) if len(xyz) else (np.zeros(0, np.int64), np.zeros(0, np.int64))
    ok = (row >= 0) & (row < H) & (col >= 0) & (col < W) & np.all(np.isfinite(xyz), axis=1)
    n = int(ok.sum())
    o_xyz = np.empty((n, 3))
    o_rgb = np.empty((n, 3), np.uint8)
    o_n = np.empty((n, 3), np.float32)
    o_sup = np.empty(n, np.int16)
    o_sig = np.empty(n, np.float32)
    if n == 0:
        return o_xyz, o_rgb, o_n, o_sup, o_sig
    cell = (row[ok] * W + col[ok]).astype(np.int64)
    p = np.ascontiguousarray(xyz[ok], np.float64)
    kz = np.floor(p[:, 2] / voxel_z_m).astype(np.int64)
    order, start = counting_order(cell, H * W)
    k = fuse_voxels(order, start, kz, np.asarray(pair, np.int64)[ok], p, np.asarray(sigma, np.float64)[ok],
                    np.ascontiguousarray(rgb[ok]), np.ascontiguousarray(normal[ok], np.float32), int(cfg.min_support),
                    o_xyz, o_rgb, o_n, o_sup, o_sig)
    return o_xyz[:k], o_rgb[:k], o_n[:k], o_sup[:k], o_sig[:k]
