"""Multi-view fusion in object space: per DSM cell and per point-cloud voxel.

Grid fusion (:func:`fuse_grid`), for every cell:

1. each stereo pair contributes one height: the median of its points in the cell (with their predicted
   height precision ``sigma``) - unless its points in the cell span more than ``max_pair_range_cells`` cells
   of height: then the pair sees a wall or a depth edge inside the cell and contributes nothing;
2. the pairs' heights are combined robustly: the precision-weighted median ``m``; a pair *supports* the
   cell when ``|h - m| <= max(k * sqrt(sigma^2 + sigma_m^2), min_tol)``;
3. the cell is kept when at least ``min_support`` pairs support it (a height that no second pair confirms
   is rejected); its height is the precision-weighted mean of the supporting heights, its ``sigma`` the
   propagated precision of that mean, its ``spread`` 1.4826 x the median absolute deviation of the
   supporting heights (NaN with one supporting pair);
4. neighbour confirmation (:func:`confirm_by_neighbours`, on the assembled grid): a cell that fails step 3
   only for want of pairs (all its pairs agree, but fewer than ``min_support`` see it) is kept when a cell
   kept in step 3 within ``neighbour_cells`` has the same height within the same tolerance - the second
   pair confirms the surface next to the cell.  Next to building edges most views are occluded or their
   matches eroded, so a roof rim or the ground at a wall is often seen by one pair only, while the roof or
   ground it continues is confirmed a cell or two away.
5. two camps (:func:`confirm_by_neighbours`, ``split_by_neighbours``): a cell rejected in step 3 because its
   pairs split into exactly two groups - every pair agrees with the lowest or with the highest pair height, none
   with both: at a building edge the pairs that see the ground and those whose view of the cell is the roof rim
   (or its fattened edge) - takes the camp that clearly more cells of steps 1-3 around it continue (ring by ring,
   at least twice the other camp's count); a cell between two equally supported surfaces stays empty.  Bench
   (midas-dsm, adjusted orientations, ``bench/dense_edges.py --eo adjusted``): cells within 2 GSD of building
   outlines valid 80.0 -> 83.0 %, within 5 GSD of the truth 68.4 -> 70.4 %, off by more 11.5 -> 12.6 %; cells off
   by more than 5 GSD 0.42 -> 0.45 % of all valid cells, edge RMSE 14.0 -> 14.4 GSD; flat cells unchanged.  A
   simple majority (84.6 % valid, 0.48 %, 14.7 GSD) or a camp of 2 pairs at least (81.8 %, 0.44 %, 14.4 GSD)
   were measured too.

Cloud fusion (:func:`fuse_cloud`): points of all pairs are binned in voxels (grid cells x height slices); a voxel
becomes one point when ``min_support`` distinct pairs have points in it: precision-weighted mean position,
mean colour and normal, the number of pairs as support.

Every step is a deterministic function of the points in a cell (or voxel), so a cell gets the same value
whichever ground tile it was computed in.  The loops run compiled (:mod:`skyrig.dense._kernels`): a counting
sort by cell, then small sorts inside each cell.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass
from typing import Iterator

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
    neighbour_cells
        Radius (cells, square window) of the neighbour confirmation of cells with too few pairs; 0 disables.
    split_by_neighbours
        Step 5 of the module docstring (a cell whose pairs split into two camps takes the camp its fused
        neighbours continue).
    max_pair_range_cells
        A pair whose own points in a cell span more height than this many cell sizes gives the cell no height
        (0 disables).  Next to a building, the wall pixels of a view (matched correctly) all project onto the
        outline, with every height from the ground to the eaves, into the cells the outline crosses, and the
        pair's median is a height of neither the roof nor the ground.  On midas-dsm (true orientations, bench/
        dense_edges.py --points) 69 % of the points more than 5 GSD too high in ground cells next to a building
        are such wall points, and 90 % of the points more than 5 GSD too low in roof cells at the outline; with
        5 cells the cells within 2 GSD of a building outline go from 75.2 to 77.4 % valid (61.3 to 64.7 % within
        5 GSD of the truth), cells off by more than 5 GSD from 0.53 to 0.49 %, flat cells unchanged.
    """

    min_support: int = 2
    k_sigma: float = 3.0
    min_tol_cells: float = 1.0
    min_support_ratio: float = 0.5
    neighbour_cells: int = 2
    max_pair_range_cells: float = 5.0
    split_by_neighbours: bool = True


def fuse_grid(grid: GridSpec, pair: NDArray[np.int64], x: NDArray[np.float64], y: NDArray[np.float64],
              h: NDArray[np.float64], sigma: NDArray[np.float64], cfg: FusionConfig = FusionConfig(),
              candidates: bool = False) -> tuple[NDArray[np.float32], ...]:
    """Fuse points of several stereo pairs into a grid (steps 1-3 of the module docstring).

    Parameters
    ----------
    grid
        The cells (map coordinates).
    pair
        ``(M,)`` pair id of each point (any non-negative integers).
    x, y, h
        ``(M,)`` map coordinates and heights (metres).
    sigma
        ``(M,)`` predicted height precision of each point (metres, > 0; others are left out).
    cfg
        Fusion options.

    candidates
        Also return the candidates for :func:`confirm_by_neighbours`.

    Returns
    -------
    height, support, spread, sigma
        ``grid.shape`` arrays as :class:`skyrig.dense.grid.DsmGrid` holds them.
    cand_height, cand_sigma, cand_support
        With ``candidates``: for cells whose pairs all agree but are fewer than ``min_support``, their
        precision-weighted mean height, its sigma and the number of pairs (NaN / 0 elsewhere); for cells whose
        pairs split into two camps (see :func:`confirm_by_neighbours`), the lower camp.
    cand2_height, cand2_sigma, cand2_support
        With ``candidates``: the upper camp of a two-camp cell (NaN / 0 elsewhere).
    """
    srt = CellSorter(grid, 0.0, cloud=False, capacity=len(x))
    xyz = np.stack([np.asarray(v, np.float64) for v in (x, y, h)], axis=1).reshape(-1, 3)
    srt.add(np.asarray(pair, np.int64), xyz, np.asarray(sigma, np.float64), test_sigma=True)
    layers, _ = srt.fuse(cfg, grid_layers=True)
    return layers if candidates else layers[:4]


@contextmanager
def _small_pages() -> Iterator[None]:
    """NumPy arrays allocated in the ``with`` body without NumPy's huge-page request (``madvise(MADV_HUGEPAGE)``).

    The tile's point arrays are large and written once, point by point: with transparent huge pages on request
    (the usual ``defrag = madvise`` setting) each first write to a 2 MB page can make the kernel compact memory
    first, which on a machine with fragmented memory stalls the writes (bench block of 64 images: writing the
    points 3.0 -> 1.8 CPU s, the fusion reading them through 4 kB pages 4.65 -> 4.9 s, the fuse phase 8.4 -> 7.6
    CPU s and 35 -> 14 s wall on a shared machine).  NumPy's switch is process-wide and private:
    restored on leaving; without it (another NumPy) nothing changes."""
    try:
        from numpy._core.multiarray import _set_madvise_hugepage  # type: ignore[import-not-found]
    except ImportError:  # pragma: no cover - NumPy < 2
        try:
            from numpy.core.multiarray import _set_madvise_hugepage  # type: ignore[import-not-found,no-redef]
        except ImportError:
            _set_madvise_hugepage = None
    if _set_madvise_hugepage is None:  # pragma: no cover
        yield
        return
    before = _set_madvise_hugepage(False)
    try:
        yield
    finally:
        _set_madvise_hugepage(before)


class CellSorter:
    """Points of several batches (e.g. blocks of stereo pairs) sorted by the cell of a grid they fall in, for
    :meth:`fuse`: each point of a batch that falls in a cell is copied once into the rows of its bucket (a block of
    ``TILE x TILE`` cells), filled in chunks of ``CHUNK`` rows from one pool as the points come (``capacity``: the
    expected number of points; memory is only touched where points are written); :meth:`fuse` then sorts each
    bucket's rows by cell (stable: a cell keeps its points in the order they were added) and fuses the cells.

    A bucket's points lie together in memory (a few chunks, read in order while the bucket is sorted): the fusion
    then reads them from the cache, where a sort of all the points by cell read every cell's points from wherever
    their batch had left them (``bench/dense.py --sizes 16``, 7.0 M points in 0.9 M cells, medians of 4 runs: the
    fuse phase 0.85 -> 0.48 CPU s; triangulation, into the buckets band by band (:meth:`add_block`), 0.61 -> 0.57).

    ``voxel_z_m`` > 0 also bins each point vertically by ``floor(z / voxel_z_m)`` for the cloud; ``cloud`` keeps
    what cloud fusion needs (``sigma_3d``, colour, normal)."""

    #: the buckets' side in cells, a power of two (a bucket's points are sorted by cell in the cache)
    TILE_SHIFT = 4
    TILE = 1 << TILE_SHIFT
    #: rows per chunk of a bucket
    CHUNK = 128

    def __init__(self, grid: GridSpec, voxel_z_m: float, cloud: bool, capacity: int = 0) -> None:
        self.grid, self.voxel_z_m, self.cloud = grid, float(voxel_z_m), cloud
        H, W = grid.shape
        t = self.TILE
        self.nb = -(-H // t) * -(-W // t)
        self.tail = np.full(self.nb, -1, np.int64)  # each bucket's last chunk (-1: none yet) and its rows in use
        self.fill = np.zeros(self.nb, np.int64)
        self.nch = np.zeros(1, np.int64)  # chunks in use
        self.n = 0
        self.capacity = max(int(capacity), 0)
        self.arrays: dict[str, NDArray] = {}
        self.wide_pairs = False

    def rows(self) -> NDArray[np.int64]:
        """The rows in use, bucket by bucket (each bucket's in the order its points came)."""
        cb = self.arrays["chunk_bucket"][:int(self.nch[0])] if self.arrays else np.zeros(0, np.int64)
        out = []
        for k in np.argsort(cb, kind="stable"):
            b = cb[k]
            r0 = int(k) * self.CHUNK
            out.append(np.arange(r0, r0 + (self.fill[b] if k == self.tail[b] else self.CHUNK)))
        return np.concatenate(out) if out else np.zeros(0, np.int64)

    def _reserve(self, m: int, sigma_h: NDArray, sigma_3d: NDArray | None) -> None:
        """Room for ``m`` more points (the arrays' dtypes: the first batch's precisions): chunks for them and one more
        for every bucket they may start a chunk in."""
        ch = self.CHUNK
        used = int(self.nch[0])
        need = used + m // ch + 1 + min(self.nb, m)
        have = len(self.arrays["chunk_bucket"]) if self.arrays else 0
        if self.arrays and need <= have:
            return
        cap = max(need, -(-self.capacity // ch) + self.nb + 1, 2 * have)
        # pair ids in 32 bits where they fit (every byte per point is memory the tile touches once)
        # the grid alone reads a point's height only (its cell holds x, y): 16 bytes a point instead of 32, memory
        # the kernel has to hand out and zero page by page (bench/dense.py --lr-check opencv --no-cloud, 16 images,
        # 7.0 M points: 61 k -> 34 k page faults)
        spec = {"pair": ((), np.int64 if self.wide_pairs else np.int32), "xyz": ((3 if self.cloud else 1,), np.float64),
                "sh": ((), self.arrays["sh"].dtype if self.arrays else np.asarray(sigma_h).dtype)}
        if self.cloud:
            spec.update({"s3": ((), self.arrays["s3"].dtype if self.arrays else np.asarray(sigma_3d).dtype),
                         "rgb": ((3,), np.uint8), "nrm": ((3,), np.float32)})
        with _small_pages():
            # one record per point for the fields the fusion reads (one or two cache lines where separate arrays were
            # one each per field); the points' cells inside their bucket stay apart (the per-bucket sort reads them)
            rec = np.empty(cap * ch, np.dtype([(k, dt, sh) for k, (sh, dt) in spec.items()]))
            new = {k: rec[k] for k in spec}
            new["lc"] = np.empty(cap * ch, np.uint8 if self.TILE ** 2 <= 256 else np.int32)
            new["chunk_bucket"] = np.empty(cap, np.int64)
        for k, a in self.arrays.items():
            n = used if k == "chunk_bucket" else used * ch
            new[k][:n] = a[:n]
        self.arrays = new

    def _chunks(self) -> tuple:
        a = self.arrays
        return a["lc"], self.tail, self.fill, a["chunk_bucket"], self.nch, self.CHUNK

    def add(self, pair: int | NDArray[np.int64], xyz: NDArray[np.float64], sigma_h: NDArray,
            sigma_3d: NDArray | None = None, rgb: NDArray[np.uint8] | None = None,
            normal: NDArray[np.float32] | None = None, test_sigma: bool = False,
            bounds: tuple[float, float, float, float] | None = None) -> int:
        """A batch of points: pair id (one for the batch, or per point), ``(M, 3)`` map coordinates, height precision
        (``test_sigma``: points whose ``sigma_h`` is not > 0 are left out here already), and for a cloud the 3-D
        precision, colour and normal.  ``bounds`` ``(xmin, ymin, xmax, ymax)``: only points with ``xmin <= x < xmax``
        and ``ymin < y <= ymax`` are taken (a ground tile's).  Returns the number of points taken."""
        from skyrig.dense._kernels import take_points

        g = self.grid
        H, W = g.shape
        p = np.ascontiguousarray(xyz, np.float64).reshape(-1, 3)
        m = len(p)
        pa = np.zeros(0, np.int64) if isinstance(pair, (int, np.integer)) else np.ascontiguousarray(pair, np.int64)
        pc = int(pair) if isinstance(pair, (int, np.integer)) else 0
        if not self.wide_pairs and (pc >= 2 ** 31 or (len(pa) and (pa.max() >= 2 ** 31 or pa.min() < -2 ** 31))):
            self.wide_pairs = True
            if self.arrays:
                self.arrays["pair"] = self.arrays["pair"].astype(np.int64)
        self._reserve(m, sigma_h, sigma_3d)
        a = self.arrays
        if self.cloud:
            cl = (np.ascontiguousarray(sigma_3d, a["s3"].dtype), np.ascontiguousarray(rgb, np.uint8),
                  np.ascontiguousarray(normal, np.float32), a["s3"], a["rgb"], a["nrm"])
        else:
            cl = (np.zeros(0, np.float32), np.zeros((0, 3), np.uint8), np.zeros((0, 3), np.float32),
                  np.zeros(0, np.float32), np.zeros((0, 3), np.uint8), np.zeros((0, 3), np.float32))
        k = take_points(p, np.ascontiguousarray(sigma_h, a["sh"].dtype) if not test_sigma else
                        np.ascontiguousarray(sigma_h), pa, pc, cl[0], cl[1], cl[2], a["xyz"], a["sh"], a["pair"], cl[3],
                        cl[4], cl[5], *self._chunks(), test_sigma, float(g.x0), float(g.y0), float(g.cell_m), H, W,
                        self.TILE_SHIFT, np.zeros(0) if bounds is None else np.array(bounds, np.float64))
        self.n += int(k)  # only the points with a cell are kept
        return int(k)

    def add_block(self, pair: int, tri_args: tuple, poly: tuple, bounds: tuple[float, float, float, float]) -> int:
        """A block's matched pixels triangulated straight into the arrays (:func:`skyrig.dense._kernels.
        triangulate_take`): the same rows :meth:`add` takes of ``block_points`` then the local -> map polynomial, with
        no per-block point arrays.  ``tri_args``: :func:`skyrig.dense.stereo.triangulation_args`; ``poly``: the
        polynomial's ``(centre, scale, coef, offset)`` (:class:`skyrig.dense.surface.FrameMap`); ``bounds`` as in
        :meth:`add`.  Returns the number of points taken."""
        from skyrig.dense._kernels import triangulate_take

        g = self.grid
        H, W = g.shape
        disp = tri_args[0]
        f32 = np.zeros(0, np.float32)
        self._reserve(disp.size, f32, f32)  # at most one point per pixel (the sorter's precisions: float32)
        a = self.arrays
        if self.cloud:
            cl = (a["s3"], a["rgb"], a["nrm"])
        else:
            cl = (f32, np.zeros((0, 3), np.uint8), np.zeros((0, 3), np.float32))
        k = triangulate_take(*tri_args, *poly, int(pair), a["xyz"], a["sh"], a["pair"], cl[0], cl[1], cl[2],  # type: ignore[call-arg]
                             *self._chunks(), float(g.x0), float(g.y0), float(g.cell_m), H, W, self.TILE_SHIFT,
                             np.array(bounds, np.float64))
        self.n += int(k)
        return int(k)

    def fuse(self, cfg: FusionConfig, grid_layers: bool = True, normal_rotation: NDArray[np.float64] | None = None
             ) -> tuple[tuple[NDArray, ...] | None, tuple[NDArray, ...] | None]:
        """Grid fusion (with ``grid_layers``: ``(height, support, spread, sigma, cand_height, cand_sigma,
        cand_support, cand2_height, cand2_sigma, cand2_support)``, see :func:`fuse_grid`) and, for a cloud, voxel fusion (``(xyz, rgb, normal, support,
        sigma)``, see :func:`fuse_cloud`; rows ordered by blocks of cells, then cell, then height) of the points
        added, in one pass over the cells."""
        from skyrig.dense._kernels import fuse_buckets

        H, W = self.grid.shape
        n = self.n
        self._reserve(0, np.zeros(0), np.zeros(0, np.float32))
        a = self.arrays
        if self.cloud:
            s3, rgb, nrm = a["s3"], a["rgb"], a["nrm"]
        else:
            s3, rgb, nrm = np.zeros(0, np.float32), np.zeros((0, 3), np.uint8), np.zeros((0, 3), np.float32)
        m = H * W
        out = [np.full(m, np.nan, np.float32), np.zeros(m, np.int16), np.full(m, np.nan, np.float32),
               np.full(m, np.nan, np.float32), np.full(m, np.nan, np.float32), np.full(m, np.nan, np.float32),
               np.zeros(m, np.int16), np.full(m, np.nan, np.float32), np.full(m, np.nan, np.float32),
               np.zeros(m, np.int16)] if grid_layers else [np.zeros(0, np.float32)] * 10
        nc = n if self.cloud else 0
        co = (np.empty((nc, 3)), np.empty((nc, 3), np.uint8), np.empty((nc, 3), np.float32), np.empty(nc, np.int16),
              np.empty(nc, np.float32))
        rot = np.eye(3) if normal_rotation is None else np.ascontiguousarray(normal_rotation, np.float64)
        k = fuse_buckets(*self._chunks(), a["pair"], a["xyz"], a["sh"], self.voxel_z_m if self.voxel_z_m > 0 else 1.0,
                         s3, rgb, nrm, rot, float(cfg.k_sigma), float(cfg.min_tol_cells * self.grid.cell_m),
                         int(cfg.min_support), float(cfg.min_support_ratio),
                         float(cfg.max_pair_range_cells * self.grid.cell_m), grid_layers, self.cloud, *out[:7], *co, W,
                         self.TILE_SHIFT, *out[7:])
        self.arrays, self.n = {}, 0
        self.tail[:] = -1
        self.fill[:] = 0
        self.nch[0] = 0
        layers = tuple(a.reshape(self.grid.shape) for a in out) if grid_layers else None
        cloud = tuple(a[:k] for a in co) if self.cloud else None
        return layers, cloud


def confirm_by_neighbours(height: NDArray[np.float32], support: NDArray[np.int16], sigma: NDArray[np.float32],
                          cand_height: NDArray[np.float32], cand_sigma: NDArray[np.float32],
                          cand_support: NDArray[np.int16], cell_m: float, cfg: FusionConfig = FusionConfig(),
                          cand2_height: NDArray[np.float32] | None = None, cand2_sigma: NDArray[np.float32] | None = None,
                          cand2_support: NDArray[np.int16] | None = None) -> NDArray[np.bool_]:
    """Steps 4 and 5 of the module docstring, in place on ``height``, ``support`` and ``sigma`` (whole grids).

    Step 4: a candidate cell (one camp: all its pairs agree, too few of them) takes its candidate height when a cell
    fused in steps 1-3 within ``cfg.neighbour_cells`` (square window) agrees within
    ``max(k_sigma * sqrt(s_c^2 + s_n^2), min_tol_cells * cell_m)``.

    Step 5 (``cfg.split_by_neighbours`` and ``cand2_*`` given): a two-camp cell (lower camp in ``cand_*``, upper in
    ``cand2_*``) takes the camp that clearly more cells fused in steps 1-3 agree with (same tolerance), counted ring
    by ring (Chebyshev distance 1, then 2, ... up to ``neighbour_cells``): the first ring where one camp has at least
    twice the other's count (and more than 0) decides; otherwise the cell stays empty.

    Only cells of steps 1-3 confirm (no chains), so the result depends on the layers alone, not on any tiling.

    Returns the mask of the cells kept this way (their ``spread`` stays NaN, their ``support`` is their own
    (camp's) number of pairs)."""
    r = int(cfg.neighbour_cells)
    cand = np.isfinite(cand_height) & ~np.isfinite(height)
    if r <= 0 or not cand.any():
        return np.zeros(height.shape, bool)
    split = cand & np.isfinite(cand2_height) if cand2_height is not None else np.zeros(height.shape, bool)
    two = bool(cfg.split_by_neighbours) and cand2_height is not None
    if not two:
        cand &= ~split  # a two-camp cell's lower camp is no one-camp candidate
        if not cand.any():
            return np.zeros(height.shape, bool)
    from skyrig.dense._kernels import confirm_cells

    rr, cc = np.nonzero(cand)  # only the candidates are tested (a few per cent of the grid)
    sp = split[rr, cc] if two else np.zeros(rr.size, bool)
    c2h = cand2_height if two else cand_height
    c2s = cand2_sigma if two else cand_sigma
    hit, upper = confirm_cells(rr, cc, sp, height, sigma, cand_height, cand_sigma, c2h, c2s, r, float(cfg.k_sigma),
                               float(cfg.min_tol_cells * cell_m), two)
    ok = np.zeros(height.shape, bool)
    ok[rr[hit], cc[hit]] = True
    height[ok] = cand_height[ok]
    sigma[ok] = cand_sigma[ok]
    support[ok] = cand_support[ok]
    if two and upper.any():
        assert cand2_sigma is not None and cand2_support is not None
        ur, uc = rr[upper], cc[upper]
        height[ur, uc] = cand2_height[ur, uc]
        sigma[ur, uc] = cand2_sigma[ur, uc]
        support[ur, uc] = cand2_support[ur, uc]
    return ok


def fuse_cloud(grid: GridSpec, voxel_z_m: float, pair: NDArray[np.int64], xyz: NDArray[np.float64],
               sigma: NDArray[np.float64], rgb: NDArray[np.uint8], normal: NDArray[np.float32],
               cfg: FusionConfig = FusionConfig(), normal_rotation: NDArray[np.float64] | None = None
               ) -> tuple[NDArray[np.float64], NDArray[np.uint8], NDArray[np.float32], NDArray[np.int16], NDArray[np.float32]]:
    """Fuse points of several pairs in voxels: the cells of ``grid`` x height slices of ``voxel_z_m``
    (slices counted from height 0).  Points outside the grid are ignored.  ``normal_rotation`` (3, 3), if
    given, rotates the normals before they are averaged.

    Returns
    -------
    xyz, rgb, normal, support, sigma
        One row per kept voxel, ordered by blocks of 16 x 16 cells, then cell, then height.
    """
    srt = CellSorter(grid, voxel_z_m, cloud=True, capacity=len(xyz))
    srt.add(np.asarray(pair, np.int64), xyz, np.zeros(len(xyz)), np.asarray(sigma, np.float64), rgb, normal)
    _, cloud = srt.fuse(cfg, grid_layers=False, normal_rotation=normal_rotation)
    assert cloud is not None
    return cloud  # type: ignore[return-value]
