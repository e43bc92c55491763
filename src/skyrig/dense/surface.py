"""The dense stage over a block: plan (pairs, rectifications, blocks, ground tiles), run tiles, assemble.

Work is cut twice:

* each stereo pair's left rectified image into fixed *blocks* (bounded memory per SGM run);
* the output grid into ground *tiles*: a tile matches the blocks whose view can reach it, triangulates, keeps
  the points inside it and fuses them.  Tiles are independent (:func:`run_tile`), so any ``map`` runs them:
  the builtin one, a process pool, or a Dask cluster (``skyrig.pipeline.executor``).  A tile matches only the
  part of each block whose pixels can fall in it (:func:`tile_part`), and the tiles' side fits a memory budget
  (:func:`tile_side`); matching whole blocks instead (``DenseConfig.tile_crop=False``), cells are computed from the
  same points in any tiling, so tiled and untiled DSMs are bit-identical.

Frames: matching and triangulation run in a local tangent frame (east, north, up) at the block; points are
then converted rigorously (through ECEF, with the output frame's geoid if any) to the output map frame,
where the DSM grid lives.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from typing import Callable, Iterable, Mapping

import numpy as np
from numpy.typing import NDArray

from skyrig.camera.frame import FrameCamera
from skyrig.dense._phases import phase
from skyrig.dense.fusion import CellSorter, FusionConfig, confirm_by_neighbours, fuse_cloud
from skyrig.dense.grid import DenseCloud, DsmGrid, GridSpec
from skyrig.dense.levels import auto_image_scale, level_of_scale, pyramid, scaled_camera
from skyrig.dense.pairs import PairConfig, StereoPair, select_pairs
from skyrig.dense.rectify import Rectification, WindowedImage, rectify_pair
from skyrig.dense.sgm import SgmConfig
from skyrig.dense.stereo import (Block, ImageLoader, PairPoints, block_ground_bounds, block_points, match_block, pair_blocks,
                                 triangulation_args)
from skyrig.errors import GeometryError, SkyrigError
from skyrig.georef.eo import ExteriorOrientations, WorldFrame, local_frame_for

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class DenseConfig:
    """Options of the dense stage.

    Attributes
    ----------
    cell_m
        DSM cell size (metres); None: the median ground sample distance of the images (1 GSD).
    pairs, sgm, fusion
        Pair selection, matching and fusion options.  The DSM's matcher erodes 2 px of foreground at depth
        jumps along the epipolar lines and none across them (``SgmConfig.edge_erode_px``,
        ``edge_erode_across_px``): without erosion the cells off by more than 5 GSD on the midas-dsm block are
        1.3 % instead of 0.4 %; eroding across the lines as well (a 2 px diamond) cost edge cells (59 % of the
        cells within 2 GSD of building edges instead of 68 %) for few outliers (0.32 % instead of 0.45 %).  The
        fusion's neighbour confirmation (``FusionConfig.neighbour_cells``) brings back roof rims and ground at
        walls seen by one pair only (edge cells 68 -> 76 %, outliers 0.59 %).  The right-based pass of the
        left-right check runs OpenCV's 3-way mode (``SgmConfig.lr_mode``; a third faster than a second 5-path
        pass; on midas-dsm with true orientations edge cells 75.0 -> 75.2 %, outliers 0.56 -> 0.53 %, flat NMAD
        0.166 GSD either way).  Wall pixels (matched correctly, but in a nadir view every height from ground
        to eaves lands on the outline) give no DSM height: a pair whose own points in a cell span more than
        ``FusionConfig.max_pair_range_cells`` cells of height leaves the cell, and points in steep or half-matched
        5 x 5 windows (``SgmConfig.wall_max_nz``, ``wall_window_px``) stay in the cloud only; with adjusted
        orientations edge cells 75.5 -> 80.0 % on midas-dsm, 82.1 -> 91.3 % on tumblecam-dsm, outliers 0.53 ->
        0.42 % (``bench/dense_edges.py --points`` classifies each point by the surface its pixel shows).  A cell
        whose pairs split into two camps (ground and roof rim) takes the camp its fused neighbours clearly continue
        (``FusionConfig.split_by_neighbours``): edge cells 80.0 -> 83.0 % on midas-dsm, 91.3 -> 93.4 % on
        tumblecam-dsm, outliers 0.42 -> 0.45 % and 0.27 -> 0.28 %, edge RMSE 14.0 -> 14.4 and 21.6 -> 21.9 GSD.
        The left-right check is a second, right-based matching on the row bands where the first leaves a depth edge
        (``SgmConfig.lr_check="banded"``; OpenCV's own check on the other rows, where a second matching changes next to
        nothing).  ``bench/dense.py --sizes 16`` (CPU s, median of 4 runs each, the same runs judge the DSM against the
        scene's truth), banded / ``"full"`` (the second matching on every row): chain 3.44 / 3.79, throughput ratio to
        raw StereoSGBM 0.39 / 0.36 (0.38-0.41 / 0.35-0.36), right-based pass 0.65 / 0.94; cells within 2 GSD of
        building outlines valid 38.87 / 38.81 %, off by more than 5 GSD 22.70 / 22.69 %, RMSE 19.11 / 19.07 GSD; flat
        cells NMAD 0.139 GSD both; 32 images (3 runs each): ratio 0.36 / 0.35, right-based pass 1.35 / 1.74, edge cells
        valid 70.71 / 70.70 %, off by more than 5 GSD 18.14 / 18.38 %, RMSE 15.79 / 15.85 GSD.  Inside the bands the
        second matching runs only on the columns within 32 px of a depth edge (``SgmConfig.lr_band_cols_px``, figures
        there: a third less time for the right-based pass, edge figures within their spread).  With that and the fusion's
        buckets (:class:`~skyrig.dense.fusion.CellSorter`), ``bench/dense.py --sizes 16`` (CPU s, medians of 4 runs,
        each against raw StereoSGBM in the same run): chain 3.58 -> 2.94, ratio 0.38 -> 0.455 (0.35-0.40 -> 0.43-0.47);
        32 images (6 runs each): 6.35 -> 5.94, 0.375 -> 0.40 (0.35-0.38 -> 0.35-0.44; on this shared machine the
        noise is about as large as the gain there).  Where the 16 images' time goes now: left matching 0.91, right-based 0.43, triangulation with the wall
        test 0.57, fusion of the 7.0 M points into grid and cloud 0.48, rectification and reading 0.21, so that without
        any triangulation and fusion the chain would reach about 0.68 of raw StereoSGBM.  Issue 35: the columns'
        zone is 8 px (``SgmConfig.lr_band_cols_px``: right-based pass 0.43 -> 0.33 CPU s, edge figures within their
        spread) and the fusion's spread and cell indices cost less (bit-identical products); figures in docs/cli.md
        ("skyrig dsm --lr-band-cols").  The full check
        (``"full"``) stays available; the figures of ``bench/dense_acceptance.py`` and of ``make demo``'s roof corners
        below were measured with it (not re-run with the banded check).  OpenCV's internal check (``"opencv"``: the
        right image's disparities from the left matching's own cost volume) saves that second matching, which costs as
        much time as the left one (``bench/dense.py``, 16 images: 1.9 of 8.1 CPU s; whole-chain throughput ratio to raw
        StereoSGBM 0.35 -> 0.47).  Its price, ``bench/dense_acceptance.py midas tumblecam`` (adjusted orientations),
        full -> opencv: edge completeness 83.0 -> 82.0 % (midas-dsm) and 93.4 -> 91.6 % (tumblecam-dsm), cells off by
        more than 5 GSD 0.45 -> 0.63 % and 0.28 -> 0.34 %, edge RMSE 14.4 -> 15.9 and 21.9 -> 23.7 GSD; flat cells
        unchanged.  The rounder building edges also move squared buildings: on ``make demo``'s town the orthomosaic's
        roof corners go from 100 % within 1 GSD (0.28 GSD RMS) to 96.5 % (0.70 GSD RMS, one corner 4.2 GSD off), so a
        second matching (banded) is the default for products and ``"opencv"`` (``skyrig dsm --lr-check opencv``) the
        option when a DSM is wanted fast.
    block_px
        Side of a rectified block matched in one SGM run (bounds memory: about
        ``(block_px + 2 margin) * (block_px + 2 margin + n_disp) * n_disp * 2`` bytes).
    tile_cells
        Side of a ground tile in cells (the unit of parallel work); with ``tile_memory_mb`` the largest side.
    tile_memory_mb
        Memory budget of one tile's work (MiB, beyond a worker's own: Python, OpenCV, the plan, about 250-500
        MiB): the side is the largest up to ``tile_cells`` whose tiles' predicted points and images fit it
        (:func:`tile_side`, :func:`tile_load`), so that a worker's peak is bounded by the budget, not by the block;
        None: tiles of ``tile_cells``.  On the grown midas-dsm blocks (``bench/run.py --grow 2 3``, 240 and 540
        images at full size, 0.29 m cells, up to 27 predicted points a cell) 1024 MiB gives sides of 1024 and 896 cells
        (4 tiles of 544 x 992, 8 of 720 x 704; before one and two tiles): the workers' peak on a LocalCluster
        690 and 900-920 MiB instead of 1,670 and 2,840 (docs/cli.md).
    tile_crop
        Each tile matches, of every block reaching it, only the part whose pixels can fall in the tile
        (:func:`tile_part`) instead of the whole block: small tiles then match about their own footprint (240-image
        growth block, serial CPU s / block megapixels matched: whole blocks 2048-cell tiles 15.4-16.5 / 40.3,
        1024 18.5-19.7 / 66.8, 512 / 178.7; cropped 1024 15.9-16.3 / 46.3, 768 18.1 / 55.7, 512 21.1-21.7 /
        66.5).  A part is matched with the same context margin as a block, so disparities near a part's edge can
        differ from the whole block's where SGM's paths reach farther: 512-cell tiles against one tile, 0.9 % of
        the valid cells differ (0.4 mm median, 111 of 1.72 M cells by more than 0.1 m), 61 cells change validity,
        cloud points +0.02 %.  False: tiled and untiled DSMs are bit-identical.
    fill_holes
        Interpolate holes of at most ``fill_max_cells`` cells' distance from measured cells (flagged in the
        ``filled`` layer).
    fill_max_cells
        Largest distance (cells) from a measured cell that is filled.
    max_cells
        Refuse grids larger than this (a resolution typo would ask for 10^10 cells).
    cloud
        Also fuse a dense point cloud.
    cloud_voxel_m
        Voxel size of the point cloud (None: the cell size; tiled runs are bit-identical to untiled ones only
        with the cell size).
    min_depth_m
        Nearest depth searched from a camera (None: a quarter of its distance to the scene box's centre).
    image_scale
        Scale of the images the matcher sees: 1 (full resolution), 0.5, 0.25, 0.125 or 0.0625 (ODM's point-cloud
        quality levels ultra, high, medium, low, lowest; :mod:`skyrig.dense.levels`); None: from the DSM cell, the
        smallest scale whose GSD is no larger than ``cell_m``, without ``cell_m`` the largest that keeps the images'
        longer side within 2048 px (:func:`skyrig.dense.levels.auto_image_scale`).  The default cell is the GSD at
        that scale.  A reduced scale reads every
        image whole (no window-by-window reading of large TIFFs).
    hierarchical
        A block whose disparity window (its rays through the scene box) is wider than
        ``SgmConfig.max_disparities`` is matched first on a coarse pyramid level, whose disparities give the window
        of the block or of its parts (paper 001's hierarchical matching, :func:`skyrig.dense.levels.refine_windows`);
        False: such windows are cut (near surfaces missed), as before.  Cuts and refinements are counted
        (:class:`DenseStats`) and reported in one line.  Blocks of images read window by window are not refined.
    orientation_sigma_px
        Relative error of the orientations as a disparity, in full-resolution pixels (e.g. ``sqrt(2)`` times an
        adjustment's reprojection RMS), added in quadrature to the matcher's ``SgmConfig.disparity_sigma_px``
        (pixels of the matched level) for the predicted precision the fusion tolerates (0: the matcher's alone, as
        before).  At full resolution the matcher's 0.3 px is finer than what self-calibrated UAV orientations hold,
        and pairs that disagree by a pixel are left out (brighton, x1 vs x0.25: docs/cli.md, issue 35).
    """

    cell_m: float | None = None
    pairs: PairConfig = field(default_factory=PairConfig)
    sgm: SgmConfig = field(default_factory=lambda: SgmConfig(edge_erode_px=2, edge_erode_across_px=0, lr_mode="3way",
                                                             lr_check="banded",
                                                             lr_band_cols_px=8))
    fusion: FusionConfig = field(default_factory=FusionConfig)
    block_px: int = 768
    tile_cells: int = 2048
    tile_crop: bool = True
    tile_memory_mb: float | None = 1024.0
    fill_holes: bool = False
    fill_max_cells: int = 16
    max_cells: int = 400_000_000
    cloud: bool = True
    cloud_voxel_m: float | None = None
    min_depth_m: float | None = None
    image_scale: float | None = 1.0
    hierarchical: bool = True
    orientation_sigma_px: float = 0.0


@dataclass(frozen=True)
class DensePlan:
    """What :func:`run_tile` needs: everything derived from the orientations, no pixels.

    Attributes
    ----------
    eo
        Orientations in the working local frame.
    cameras
        Camera name -> camera.
    out_frame
        The output map frame (CRS and height reference).
    box
        Scene box in the local frame ``(xmin, ymin, zmin, xmax, ymax, zmax)``.
    grid
        The output grid (map frame).
    gsd_m
        Median ground sample distance of the images (metres).
    pairs, rects, blocks
        Selected pairs, their rectifications and rectified blocks.
    block_bounds
        Per pair, ``(n_blocks, 4)`` map ``(xmin, ymin, xmax, ymax)`` each block can see.
    tiles
        ``(row0, col0, height, width)`` windows of the grid.
    config
        The options.
    to_map
        Local frame -> output map frame.
    image_level
        Pyramid level the images are matched at (``DenseConfig.image_scale`` = ``0.5 ** image_level``); ``cameras``
        and ``rects`` are that level's, ``gsd_m`` is the full images'.
    """

    eo: ExteriorOrientations
    cameras: Mapping[str, FrameCamera]
    out_frame: WorldFrame
    box: tuple[float, float, float, float, float, float]
    grid: GridSpec
    gsd_m: float
    pairs: tuple[StereoPair, ...]
    rects: tuple[Rectification, ...]
    blocks: tuple[tuple[Block, ...], ...]
    block_bounds: tuple[NDArray[np.float64], ...]
    tiles: tuple[tuple[int, int, int, int], ...]
    config: DenseConfig
    to_map: "FrameMap"
    image_level: int = 0

    @property
    def local_frame(self) -> WorldFrame:
        return self.eo.frame


@dataclass
class TileResult:
    """The fused layers of one ground tile, its cloud points and counts."""

    window: tuple[int, int, int, int]
    height: NDArray[np.float32]
    support: NDArray[np.int16]
    spread: NDArray[np.float32]
    sigma: NDArray[np.float32]
    cloud: tuple[NDArray, ...] | None
    points: int
    blocks: int
    megapixels: float
    seconds: float
    cand_height: NDArray[np.float32] | None = None
    cand_sigma: NDArray[np.float32] | None = None
    cand_support: NDArray[np.int16] | None = None
    cand2_height: NDArray[np.float32] | None = None
    cand2_sigma: NDArray[np.float32] | None = None
    cand2_support: NDArray[np.int16] | None = None
    search: "SearchCounts" = field(default_factory=lambda: SearchCounts())


@dataclass(frozen=True)
class SearchCounts:
    """What the disparity search did, in block matchings (a block is matched once per ground tile that needs it).

    ``cut``: windows wider than the matcher's limit narrowed, leaving out near surfaces (without the hierarchy:
    every such block; with it: parts whose narrowed window leaves out more than 1 % of their coarse matches);
    ``refined``: blocks whose windows came from the coarse level (:func:`block_parts`); ``unmatched``: blocks or
    parts left out because the coarse level found no surface in them; ``trimmed``: parts whose window was narrowed
    leaving out at most 1 % of their coarse matches (isolated coarse mismatches)."""

    cut: int = 0
    refined: int = 0
    unmatched: int = 0
    trimmed: int = 0

    def __add__(self, other: "SearchCounts") -> "SearchCounts":
        return SearchCounts(self.cut + other.cut, self.refined + other.refined, self.unmatched + other.unmatched,
                            self.trimmed + other.trimmed)

    def summary_line(self, blocks: int) -> str:
        """One line on the disparity search (empty when no window was wider than the matcher's limit)."""
        if not (self.cut or self.refined):
            return ""
        text = (f"disparity search: {self.refined} of {blocks} block matchings refined on a coarse level "
                f"(hierarchical matching), {self.unmatched} blocks or parts without a coarse match left out, "
                f"{self.trimmed} windows trimmed to 99 % of their coarse matches")
        if self.cut:
            return text + (f"; {self.cut} windows wider than the matcher's limit cut (near surfaces may be missing "
                           "there: a narrower height range, or a smaller image scale)")
        return text + "; no window cut"


def vertical_reference(frame: WorldFrame) -> str:
    """Words for the height reference of a map frame."""
    from skyrig.geodesy.crs import resolve_crs

    if frame.kind != "map":
        return frame.describe()
    crs = resolve_crs(frame.crs)
    if frame.geoid is not None:
        return f"orthometric heights through geoid grid {frame.geoid}"
    datum = crs.geodetic_crs.datum.name if crs.geodetic_crs is not None else "unknown datum"
    ell = crs.ellipsoid.name if crs.ellipsoid is not None else "unknown ellipsoid"
    return f"ellipsoidal heights ({datum}, {ell})"


class FrameMap:
    """Points of the local working frame to the output map frame: a polynomial verified against PROJ, or PROJ.

    Over a block the rigorous conversion (local ENU -> ECEF -> map projection, geoid) is smooth; a cubic in
    (x, y) with quadratic height terms, fitted on a lattice over the scene box, reproduces it to well below
    0.1 mm.  The fit is checked on a second, interleaved lattice; if any point is off by more than
    ``tol_m`` the rigorous path is used instead (e.g. a geoid grid that is not smooth over the box).
    """

    def __init__(self, local: WorldFrame, out: WorldFrame, box: tuple[float, ...], tol_m: float = 1e-4) -> None:
        self.local, self.out = local, out
        lo, hi = np.array(box[:3], float), np.array(box[3:], float)
        self.c = 0.5 * (lo + hi)
        self.s = np.maximum(0.5 * (hi - lo), 1.0)
        g = [np.linspace(-1, 1, 7), np.linspace(-1, 1, 7), np.linspace(-1, 1, 3)]
        fit = np.stack(np.meshgrid(*g, indexing="ij"), -1).reshape(-1, 3)
        h = [np.linspace(-1, 1, 13)[1::2], np.linspace(-1, 1, 13)[1::2], np.array([-1.0, -0.3, 0.4, 1.0])]
        chk = np.stack(np.meshgrid(*h, indexing="ij"), -1).reshape(-1, 3)
        self.coef = None
        try:
            A = self._terms(fit)
            y = self._rigorous(self.c + fit * self.s)
            coef, *_ = np.linalg.lstsq(A, y - self._rigorous(self.c[None])[0], rcond=None)
            self.offset = self._rigorous(self.c[None])[0]
            err = np.abs(self._terms(chk) @ coef + self.offset - self._rigorous(self.c + chk * self.s)).max()
            if np.isfinite(err) and err <= tol_m:
                self.coef = coef
            else:
                logger.info("local->map polynomial off by %.2g m over the box: rigorous conversion used", err)
        except Exception as exc:  # noqa: BLE001 - any failure means: use PROJ
            logger.info("local->map polynomial not usable (%s): rigorous conversion used", exc)

    @staticmethod
    def _terms(q: NDArray[np.float64]) -> NDArray[np.float64]:
        x, y, z = q[:, 0], q[:, 1], q[:, 2]
        one = np.ones_like(x)
        return np.stack([one, x, y, z, x * x, x * y, y * y, x * z, y * z, z * z,
                         x * x * x, x * x * y, x * y * y, y * y * y], axis=1)

    def _rigorous(self, xyz: NDArray[np.float64]) -> NDArray[np.float64]:
        return self.out.from_ecef(self.local.to_ecef(xyz))

    def __call__(self, xyz: NDArray[np.float64]) -> NDArray[np.float64]:
        if self.coef is None:
            return self._rigorous(xyz)
        from skyrig.dense._kernels import poly_map

        return poly_map(np.ascontiguousarray(xyz, np.float64), self.c, self.s, self.coef, self.offset)


def _map_to_local(frame: WorldFrame, local: WorldFrame, xyz: NDArray[np.float64]) -> NDArray[np.float64]:
    return local.from_ecef(frame.to_ecef(xyz))


def _local_to_map(local: WorldFrame, frame: WorldFrame, xyz: NDArray[np.float64]) -> NDArray[np.float64]:
    return frame.from_ecef(local.to_ecef(xyz))


def _sample_rays(eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera], i: int, n: int = 7) -> NDArray:
    cam = cameras[str(eo.camera[i])]
    c = np.linspace(0, 1, n)
    cc, rr = np.meshgrid(c * (cam.width - 1), c * (cam.height - 1))
    return cam.rays_from_pixels(np.stack([cc.ravel(), rr.ravel()], 1)) @ eo.rotation[i].T


def plan_dense(eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera], out_frame: WorldFrame,
               height_range: tuple[float, float], area: tuple[float, float, float, float] | None = None,
               config: DenseConfig = DenseConfig()) -> DensePlan:
    """Plan the dense stage of a block.

    Parameters
    ----------
    eo
        Orientations in any frame.
    cameras
        Camera name -> camera for every ``eo.camera``.
    out_frame
        Output map frame: a projected CRS (metres) and its height reference.
    height_range
        ``(min, max)`` expected surface heights in ``out_frame`` heights (metres); sets the disparity search.
    area
        ``(xmin, ymin, xmax, ymax)`` in ``out_frame`` to compute; None: where the images see the mid height
        (at most 3 flying heights from each projection centre).
    config
        Options.

    Raises
    ------
    SkyrigError
        On a non-projected output CRS, an implausible height range, a grid over ``max_cells``, or a block
        without any stereo pair.
    """
    from skyrig.geodesy.crs import resolve_crs

    if out_frame.kind != "map":
        raise SkyrigError("the DSM needs a map frame (a projected CRS), not a " + out_frame.kind + " frame (option: crs)")
    crs = resolve_crs(out_frame.crs)
    if not crs.is_projected:
        raise SkyrigError(f"the DSM needs a projected CRS with metre cells, not {crs.name} (option: crs)")
    zmin, zmax = (float(v) for v in height_range)
    if not (np.isfinite(zmin) and np.isfinite(zmax) and zmin < zmax):
        raise SkyrigError(f"height range must be two finite heights min < max, got {height_range} (option: height-range)")
    if zmax - zmin > 9000 or min(abs(zmin), abs(zmax)) > 9000:
        raise SkyrigError(f"height range {zmin:g}..{zmax:g} m is not a surface on Earth (heights in mm?) "
                          "(option: height-range)")
    if len(eo) < 2:
        raise SkyrigError("dense matching needs at least two oriented images")
    missing = sorted(set(eo.camera.tolist()) - set(cameras))
    if missing:
        raise SkyrigError(f"no camera for {', '.join(missing)} (cameras given: {', '.join(sorted(cameras))})")
    zmid = 0.5 * (zmin + zmax)
    eo_map = eo.to_frame(out_frame)
    ctr = np.array([[*eo_map.centre[:, :2].mean(axis=0), zmid]])
    local = local_frame_for(out_frame.to_ecef(ctr))
    eo_l = eo.to_frame(local)
    z_plane = float(_map_to_local(out_frame, local, ctr)[0, 2])
    if np.any(eo_l.centre[:, 2] <= z_plane) and area is None:
        raise SkyrigError("some projection centres lie below the expected surface heights: give the area to compute "
                          "(option: area) or check the height range and the orientations' height reference")
    # area and GSD from the rays through the mid-height plane
    gsd, foot = [], []
    for i in range(len(eo_l)):
        rays = _sample_rays(eo_l, cameras, i)
        c = eo_l.centre[i]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (z_plane - c[2]) / rays[:, 2]
        hgt = abs(c[2] - z_plane)
        p = c + rays * t[:, None]
        ok = (t > 0) & (np.hypot(p[:, 0] - c[0], p[:, 1] - c[1]) <= 3 * max(hgt, 1.0))
        foot.append(p[ok])
        cam = cameras[str(eo_l.camera[i])]
        axis = -eo_l.rotation[i][:, 2]
        if axis[2] < -0.2:
            s = (z_plane - c[2]) / axis[2]
            gsd.append((s / cam.focal_px, abs(axis[2])))
    if gsd:
        g = np.array(gsd)
        steep = g[:, 1] > np.cos(np.radians(20))
        gsd_m = float(np.median(g[steep, 0] if steep.any() else g[:, 0]))
    elif area is not None:  # side-looking / terrestrial views of a given area: GSD at the area's centre
        ac = _map_to_local(out_frame, local, np.array([[0.5 * (area[0] + area[2]), 0.5 * (area[1] + area[3]), zmid]]))[0]
        gsd_m = float(np.median([np.linalg.norm(ac - eo_l.centre[i]) / cameras[str(eo_l.camera[i])].focal_px
                                 for i in range(len(eo_l))]))
    else:
        raise SkyrigError("no image looks down onto the expected heights: for side-looking or terrestrial images "
                          "give the area to compute (option: area)")
    if area is None:
        fp = np.concatenate(foot)
        if len(fp) == 0:
            raise SkyrigError("the images see no ground at the expected heights (option: height-range)")
        fm = _local_to_map(local, out_frame, fp)
        area = (float(fm[:, 0].min()), float(fm[:, 1].min()), float(fm[:, 0].max()), float(fm[:, 1].max()))
    xmin, ymin, xmax, ymax = (float(v) for v in area)
    if not (xmax > xmin and ymax > ymin):
        raise SkyrigError(f"empty area {area} (option: area)")
    side = max(max(c.width, c.height) for c in cameras.values())
    scale = auto_image_scale(gsd_m, config.cell_m, side) if config.image_scale is None else float(config.image_scale)
    level = level_of_scale(scale, "image_scale")
    if level:  # match on pyramid level `level`: its cameras (same rays, larger pixels)
        cameras = {name: scaled_camera(cam, level) for name, cam in cameras.items()}
    if config.orientation_sigma_px:
        if not (np.isfinite(config.orientation_sigma_px) and config.orientation_sigma_px > 0):
            raise SkyrigError(f"orientation sigma must be a positive number of pixels, got "
                              f"{config.orientation_sigma_px} (option: orientation_sigma_px)")
        sd = float(np.hypot(config.sgm.disparity_sigma_px, config.orientation_sigma_px * scale))
        config = replace(config, sgm=replace(config.sgm, disparity_sigma_px=sd), orientation_sigma_px=0.0)
    cell = float(config.cell_m) if config.cell_m else gsd_m / scale
    if not (cell > 0 and np.isfinite(cell)):
        raise SkyrigError(f"cell size must be positive, got {config.cell_m} (option: resolution)")
    grid = GridSpec.covering(xmin, ymin, xmax, ymax, cell)
    H, W = grid.shape
    if W * H > config.max_cells:
        raise SkyrigError(f"a {cell:g} m grid over {xmax - xmin:.0f} x {ymax - ymin:.0f} m has {W * H:.3g} cells, more "
                          f"than the limit {config.max_cells:.3g} (option: resolution, or max_cells)")
    corners = np.array([[x, y, z] for x in (xmin, xmax) for y in (ymin, ymax) for z in (zmin, zmax)]
                       + [[0.5 * (xmin + xmax), 0.5 * (ymin + ymax), z] for z in (zmin, zmax)])
    cl = _map_to_local(out_frame, local, corners)
    pad = 2 * cell
    box = (float(cl[:, 0].min() - pad), float(cl[:, 1].min() - pad), float(cl[:, 2].min() - pad),
           float(cl[:, 0].max() + pad), float(cl[:, 1].max() + pad), float(cl[:, 2].max() + pad))
    pairs = select_pairs(eo_l, cameras, box, config.pairs)
    rects, blocks, bounds, kept = [], [], [], []
    for p in pairs:
        try:
            r = rectify_pair(cameras[str(eo_l.camera[p.left])], eo_l.rotation[p.left], eo_l.centre[p.left],
                             cameras[str(eo_l.camera[p.right])], eo_l.rotation[p.right], eo_l.centre[p.right])
        except GeometryError as exc:
            logger.info("pair %s-%s skipped: %s", eo_l.image[p.left], eo_l.image[p.right], exc)
            continue
        box_c = 0.5 * (np.array(box[:3]) + np.array(box[3:]))
        min_depth = config.min_depth_m if config.min_depth_m is not None else \
            0.25 * float(np.linalg.norm(box_c - eo_l.centre[p.left]))
        bl = pair_blocks(r, box, config.block_px, min_depth)
        if not bl:
            continue
        corners_l = []  # the blocks' ground corners, taken to the map all at once below
        for b in bl:
            lb = block_ground_bounds(r, b)
            corners_l.append([[lb[0], lb[1], z_plane], [lb[2], lb[1], z_plane], [lb[0], lb[3], z_plane],
                              [lb[2], lb[3], z_plane]])
        kept.append(p)
        rects.append(r)
        blocks.append(tuple(bl))
        bounds.append(np.array(corners_l, np.float64))
    if not kept:
        raise SkyrigError("no stereo pair: the images do not overlap with a usable base and viewing direction "
                          f"({len(eo)} images; options: pairs.min_overlap, pairs.intersection_deg)")
    cut = np.cumsum([len(q) for q in bounds])[:-1]
    m = _local_to_map(local, out_frame, np.concatenate(bounds).reshape(-1, 3)).reshape(-1, 4, 3)
    bounds = [np.column_stack([m[:, :, 0].min(axis=1) - pad, m[:, :, 1].min(axis=1) - pad,
                               m[:, :, 0].max(axis=1) + pad, m[:, :, 1].max(axis=1) + pad]) for m in np.split(m, cut)]
    px = [cameras[str(c)].width * cameras[str(c)].height for c in eo_l.camera]  # at the matched level
    side, load = tile_side(grid, config, tuple(kept), tuple(rects), tuple(blocks), tuple(bounds), px)
    tiles = ground_tiles(grid, side)
    if config.tile_memory_mb is not None:
        logger.info("dense: ground tiles of %d cells a side (at most %d, memory budget %g MiB a tile): %d tiles, "
                    "predicted at most %.3g M points and %.0f MiB a tile", side, config.tile_cells,
                    config.tile_memory_mb, len(tiles), load[0] / 1e6, load[1] / 2 ** 20)
    return DensePlan(eo_l, dict(cameras), out_frame, box, grid, gsd_m, tuple(kept), tuple(rects), tuple(blocks),
                     tuple(bounds), tiles, config, FrameMap(local, out_frame, box), level)


#: memory a tile's work takes per point (bytes): the fusion's record (pair, x y z, precisions, colour, normal: 53
#: bytes) with its sort and the tile's results; measured 62-82 bytes a point on the 240-image growth block
#: (``bench/run.py --grow 2``, RSS growth over each 768-cell tile's run, 0.5-9.4 M points)
TILE_BYTES_PER_POINT = 80


def ground_tiles(grid: GridSpec, side: int) -> tuple[tuple[int, int, int, int], ...]:
    """``(row0, col0, height, width)`` windows of at most ``side`` cells covering the grid, as few as
    :meth:`GridSpec.tiles` gives along each axis but of about equal size (no sliver of a tile that would read and
    match every image reaching it for a few cells), in multiples of the fusion's 16-cell buckets where ``side`` is
    one."""
    g = 16 if side % 16 == 0 else 1

    def cuts(n: int) -> list[int]:
        k = -(-n // side)  # tiles along the axis
        step = -(-n // k)  # their equal size, rounded up to g
        step = -(-step // g) * g
        return list(range(0, n, step)) + [n]

    rows, cols = cuts(grid.height), cuts(grid.width)
    return tuple((r0, c0, r1 - r0, c1 - c0) for r0, r1 in zip(rows[:-1], rows[1:]) for c0, c1 in zip(cols[:-1], cols[1:]))


def tile_load(grid: GridSpec, tiles: tuple[tuple[int, int, int, int], ...], pairs: tuple[StereoPair, ...],
              rects: tuple[Rectification, ...], blocks: tuple[tuple[Block, ...], ...],
              bounds: tuple[NDArray[np.float64], ...], sgm: SgmConfig, image_px: list[int]
              ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Predicted points and bytes of each tile's work.

    Points: every block's pixels that can match (the columns whose search window reaches the right image,
    :func:`skyrig.dense.stereo.block_crop`) spread evenly over the block's ground bounds, the share inside the tile
    (the overlap times ``(cell / GSD)^2`` of the matched images, where the pairs overlap).  Against the points a
    tile's run triangulates into it: 0.77-1.03 on the 240-image growth block's 768-cell tiles, 0.78-1.05 on the
    loaded tiles of ``tests/test_dense.py``'s block (far less at the grid's corners).  Bytes: :data:`TILE_BYTES_PER_POINT` a point, and the images
    of the pairs reaching the tile whole (RGB and grey at the matched level, ``image_px`` pixels each)."""
    from skyrig.dense.stereo import block_crop

    bb = np.concatenate(bounds) if bounds else np.zeros((0, 4))
    n_px = np.array([float((c[3] - c[2]) * (b.v1 - b.v0)) if (c := block_crop(r, b, sgm)) else 0.0
                     for r, bl in zip(rects, blocks) for b in bl])
    owner = np.repeat(np.arange(len(blocks)), [len(bl) for bl in blocks])
    area = np.maximum(bb[:, 2] - bb[:, 0], 1e-9) * np.maximum(bb[:, 3] - bb[:, 1], 1e-9)
    pts, nbytes = np.zeros(len(tiles)), np.zeros(len(tiles))
    for k, (r0, c0, h, w) in enumerate(tiles):
        x0, y0, x1, y1 = grid.window(r0, c0, h, w).bounds
        ox = np.clip(np.minimum(bb[:, 2], x1) - np.maximum(bb[:, 0], x0), 0, None)
        oy = np.clip(np.minimum(bb[:, 3], y1) - np.maximum(bb[:, 1], y0), 0, None)
        pts[k] = float((n_px * ox * oy / area).sum())
        imgs = {i for p in np.unique(owner[(ox > 0) & (oy > 0)]) for i in (pairs[p].left, pairs[p].right)}
        nbytes[k] = pts[k] * TILE_BYTES_PER_POINT + 4.0 * sum(image_px[i] for i in imgs)
    return pts, nbytes


def tile_side(grid: GridSpec, config: DenseConfig, pairs: tuple[StereoPair, ...], rects: tuple[Rectification, ...],
              blocks: tuple[tuple[Block, ...], ...], bounds: tuple[NDArray[np.float64], ...], image_px: list[int]
              ) -> tuple[int, tuple[float, float]]:
    """The ground tiles' side: ``config.tile_cells``, or with ``config.tile_memory_mb`` the largest side at most
    that whose tiles' predicted work (:func:`tile_load`) fits the budget (multiples of 128 cells, then 64).
    When none fits (the images reaching a tile alone take more: they do not shrink with a tile smaller than their
    footprints), the largest side within 10 % of the smallest predicted work, with a warning.  Returns the side
    and the largest tile's predicted ``(points, bytes)``."""
    side = int(config.tile_cells)
    if config.tile_memory_mb is None:
        return side, (float("nan"), float("nan"))
    budget = float(config.tile_memory_mb) * 2 ** 20
    sides = [side] + [s for s in range(side - side % 128, 127, -128) if s < side] + [s for s in (64,) if s < side]
    seen = []
    for s in sides:
        pts, nbytes = tile_load(grid, ground_tiles(grid, s), pairs, rects, blocks, bounds, config.sgm, image_px)
        k = int(np.argmax(nbytes))
        seen.append((s, float(pts[k]), float(nbytes[k])))
        if nbytes[k] <= budget:
            return s, seen[-1][1:]
    least = min(b for _, _, b in seen)
    s, p, b = next(x for x in seen if x[2] <= 1.1 * least)
    logger.warning("dense: no ground tile of %d to %d cells fits the memory budget of %g MiB (option: tile_memory_mb): "
                   "tiles of %d cells, predicted at most %.0f MiB a tile", sides[-1], sides[0], config.tile_memory_mb,
                   s, b / 2 ** 20)
    return s, (p, b)


def _grid_from_local(plan: DensePlan, at_map: NDArray[np.float64]) -> NDArray[np.float64]:
    """``grid_from_local`` rotation at a map point (for normals)."""
    ecef_from_grid = plan.out_frame.ecef_from_frame_rotation(at_map[None])[0]
    ecef_from_local = plan.local_frame.ecef_from_frame_rotation(np.zeros((1, 3)))[0]
    return ecef_from_grid.T @ ecef_from_local


def run_tile(plan: DensePlan, k: int, loader: ImageLoader) -> TileResult:
    """Match, triangulate and fuse one ground tile (``plan.tiles[k]``).

    ``loader(i)`` gives image ``i`` whole; a loader with a ``windowed_image(i, grey)`` method that returns a
    :class:`~skyrig.dense.rectify.WindowedImage` (not None) has that image read window by window instead (only what
    each block samples: memory bounded by the block, not by the image)."""
    import cv2

    t0 = time.perf_counter()
    r0, c0, h, w = plan.tiles[k]
    tg = plan.grid.window(r0, c0, h, w)
    xb0, yb0, xb1, yb1 = tg.bounds
    images: dict[int, NDArray] = {}
    greys: dict[tuple[int, int], NDArray] = {}

    def image(i: int) -> NDArray:
        if i not in images:
            with phase("read"):
                images[i] = loader(i)
            if plan.image_level:
                with phase("pyramid"):
                    images[i] = pyramid(images[i], plan.image_level)
        return images[i]

    def grey(i: int, up: int = 0) -> NDArray:
        """The image in grey, converted once per tile (a right image is only matched; a pair has a block every
        ``block_px`` pixels, each would convert the whole image again); ``up`` pyramid levels above the plan's
        (the hierarchy's coarse levels)."""
        if (i, up) not in greys:
            if up:
                with phase("pyramid"):
                    greys[i, up] = pyramid(grey(i, up - 1), 1)
            else:
                im = image(i)
                with phase("rectify"):
                    greys[i, 0] = cv2.cvtColor(im, cv2.COLOR_RGB2GRAY) if im.ndim == 3 else im
        return greys[i, up]

    # a loader that reads large images window by window (at full scale only)
    windowed = getattr(loader, "windowed_image", None) if plan.image_level == 0 else None
    windows: dict[tuple[int, bool], WindowedImage | None] = {}

    def window_of(i: int, in_grey: bool) -> WindowedImage | None:
        if (i, in_grey) not in windows:
            windows[i, in_grey] = windowed(i, in_grey) if windowed is not None else None
        return windows[i, in_grey]

    def source(i: int, in_grey: bool) -> NDArray | WindowedImage:
        wi = window_of(i, in_grey)
        if wi is not None:
            return wi
        return grey(i) if in_grey else image(i)

    vox = plan.config.cloud_voxel_m or plan.grid.cell_m
    with_cloud = plan.config.cloud and vox == plan.grid.cell_m  # the cloud's voxels on the grid's cells: one sort
    hits = [np.flatnonzero((bb[:, 0] <= xb1) & (bb[:, 2] >= xb0) & (bb[:, 1] <= yb1) & (bb[:, 3] >= yb0))
            for bb in plan.block_bounds]
    # at most one point per block pixel: the sorter's arrays are reserved once (memory is touched only where written)
    cap = sum((bl[bi].v1 - bl[bi].v0) * (bl[bi].u1 - bl[bi].u0) for bl, hit in zip(plan.blocks, hits) for bi in hit)
    srt = CellSorter(tg, vox if with_cloud else 0.0, cloud=with_cloud, capacity=cap)
    extra: list[tuple[int, PairPoints, NDArray]] = []  # a cloud on its own voxel grid
    npts, nblocks, mpx, counts = 0, 0, 0.0, SearchCounts()
    # the points go straight from the disparities into the sorter where nothing else needs them (no cloud on its
    # own voxel grid) and the local -> map conversion is the polynomial
    fm = plan.to_map
    pad = 2 * plan.grid.cell_m  # as the blocks' ground bounds
    direct = (with_cloud or not plan.config.cloud) and fm.coef is not None
    poly = (fm.c, fm.s, np.ascontiguousarray(fm.coef, np.float64), fm.offset) if direct else ()
    for pid, (pair, rect, bl, hit) in enumerate(zip(plan.pairs, plan.rects, plan.blocks, hits)):
        for bi in hit:
            blk = bl[bi]
            whole = window_of(pair.left, True) is None and window_of(pair.right, True) is None
            parts, cnt = block_parts(rect, blk, plan.config, grey if whole else None, pair.left, pair.right)
            counts = counts + cnt
            nblocks += 1
            for whole_part in parts:
                part = tile_part(rect, whole_part, plan.config.sgm, fm, (xb0, yb0, xb1, yb1), pad) \
                    if plan.config.tile_crop else whole_part
                if part is None:
                    continue
                disp, colour, _ = match_block(rect, source(pair.left, False), source(pair.right, True), part,
                                              plan.config.sgm)
                mpx += disp.size / 1e6
                if direct:  # triangulated straight into the sorter (the same points as block_points + to_map)
                    with phase("triangulate"):
                        npts += srt.add_block(pid, triangulation_args(rect, part, disp, colour, plan.config.sgm),
                                              poly, (xb0, yb0, xb1, yb1))
                    continue
                npts += _add_points(plan, srt, extra, pid, block_points(rect, part, disp, colour, plan.config.sgm),
                                    with_cloud, (xb0, yb0, xb1, yb1))
    rot = _grid_from_local(plan, np.array([0.5 * (xb0 + xb1), 0.5 * (yb0 + yb1), 0.0]))
    with phase("fuse"):
        (hgt, sup, spr, sg, ch, cs, cn, ch2, cs2, cn2), cloud = srt.fuse(plan.config.fusion, True, rot)
    if extra:
        with phase("fuse cloud"):
            vg = GridSpec(tg.x0, tg.y0, vox, int(np.ceil(w * tg.cell_m / vox)), int(np.ceil(h * tg.cell_m / vox)))
            cloud = fuse_cloud(vg, vox, np.concatenate([np.full(len(p[1]), p[0], np.int64) for p in extra]),
                               np.concatenate([p[2] for p in extra]),
                               np.concatenate([p[1].sigma_3d for p in extra]).astype(np.float64),
                               np.concatenate([p[1].rgb for p in extra]), np.concatenate([p[1].normal for p in extra]),
                               plan.config.fusion, rot)
    return TileResult((r0, c0, h, w), hgt, sup, spr, sg, cloud if plan.config.cloud and npts else None, npts, nblocks,
                      mpx, time.perf_counter() - t0, ch, cs, cn, ch2, cs2, cn2, counts)


def tile_part(rect: Rectification, blk: Block, sgm: SgmConfig, to_map: Callable[[NDArray], NDArray],
              bounds: tuple[float, float, float, float], pad_m: float, step: int = 32) -> Block | None:
    """The part of a block whose pixels can give points in a ground tile (map ``bounds`` ``(xmin, ymin, xmax,
    ymax)``), with the block's disparity window; None: no pixel can.

    A pixel's point lies on its ray between the depths of the disparities OpenCV searches for the block
    (:func:`skyrig.dense.sgm.disparity_window`).  Pixels on a lattice of ``step`` are taken along their rays at
    both ends of that range to the map; those whose segment's bounds meet the tile, widened by the largest ground
    distance between neighbours of the lattice and ``pad_m``, span the part, widened by ``step`` pixels.  Every
    pixel whose point can fall in the tile is in it (at a fixed depth the rectified pixels map affinely onto the
    local frame; the map's own curvature over a lattice step is far below ``pad_m``).  The part is matched with
    the same context margin as any block (:func:`skyrig.dense.stereo.block_crop`), so a small ground tile matches
    about its own footprint, not every block that reaches it whole; the disparities of a pixel can then differ
    from the whole block's where SGM's paths reach farther than that margin (figures: ``DenseConfig.tile_cells``).
    The whole block when its far end is unbounded (a window reaching disparity 0)."""
    from skyrig.dense.sgm import disparity_window

    shift, n = disparity_window(blk.d_min, blk.d_max, sgm)
    if shift < 2:
        return blk
    us = np.unique(np.r_[np.arange(blk.u0, blk.u1, step), blk.u1 - 1])
    vs = np.unique(np.r_[np.arange(blk.v0, blk.v1, step), blk.v1 - 1])
    uu, vv = np.meshgrid(us, vs)
    dirs = rect.rect_directions(uu.ravel(), vv.ravel()) @ rect.rotation.T
    fb = rect.focal_px * rect.base_m
    ends = [to_map(rect.centres[0] + dirs * (fb / d)) for d in (shift + n, shift - 1)]  # near, far
    lo = np.minimum(ends[0][:, :2], ends[1][:, :2]).reshape(len(vs), len(us), 2)
    hi = np.maximum(ends[0][:, :2], ends[1][:, :2]).reshape(len(vs), len(us), 2)
    gap = 0.0
    for e in ends:
        g = e[:, :2].reshape(len(vs), len(us), 2)
        for ax in (0, 1):
            if g.shape[ax] > 1:
                gap = max(gap, float(np.hypot(*np.moveaxis(np.diff(g, axis=ax), -1, 0)).max()))
    m = gap + pad_m
    xb0, yb0, xb1, yb1 = bounds
    hit = (lo[..., 0] <= xb1 + m) & (hi[..., 0] >= xb0 - m) & (lo[..., 1] <= yb1 + m) & (hi[..., 1] >= yb0 - m)
    if not hit.any():
        return None
    rows, cols = np.flatnonzero(hit.any(axis=1)), np.flatnonzero(hit.any(axis=0))
    u0, u1 = max(blk.u0, int(us[cols[0]]) - step), min(blk.u1, int(us[cols[-1]]) + step + 1)
    v0, v1 = max(blk.v0, int(vs[rows[0]]) - step), min(blk.v1, int(vs[rows[-1]]) + step + 1)
    return replace(blk, u0=u0, u1=u1, v0=v0, v1=v1)


def _add_points(plan: DensePlan, srt: CellSorter, extra: list, pid: int, pp: PairPoints, with_cloud: bool,
                bounds: tuple[float, float, float, float]) -> int:
    """A block's points into the tile's sorter (those inside the tile: x0 <= x < x1, y0 < y <= y1), and into
    ``extra`` for a cloud on its own voxel grid; returns the points added."""
    if len(pp) == 0:
        return 0
    xb0, yb0, xb1, yb1 = bounds
    with phase("to map"):
        xyz_m = plan.to_map(pp.xyz)
    with phase("fuse"):
        n = srt.add(pid, xyz_m, pp.sigma_h, pp.sigma_3d, pp.rgb, pp.normal, bounds=bounds)
    if plan.config.cloud and not with_cloud:
        inside = (xyz_m[:, 0] >= xb0) & (xyz_m[:, 0] < xb1) & (xyz_m[:, 1] > yb0) & (xyz_m[:, 1] <= yb1)
        if inside.any():
            sel = np.flatnonzero(inside)
            extra.append((pid, pp.subset(sel), xyz_m[sel]))
    return n


def block_parts(rect: Rectification, blk: Block, config: DenseConfig, grey: Callable[[int, int], NDArray] | None,
                left: int, right: int) -> tuple[list[Block], "SearchCounts"]:
    """The block, or its parts, with the disparity windows they are matched with, and what the search did.

    A window that fits ``SgmConfig.max_disparities`` is the block's own.  A wider one, with
    ``config.hierarchical`` and ``grey(image, levels_up)`` given, is refined on a coarse pyramid level
    (:mod:`skyrig.dense.levels`): the block matched there with its geometric window, the parts' windows from the
    coarse disparities.  A function of the pair and the block only (the same in any tiling)."""
    from skyrig.dense.levels import coarse_level, coarse_rectification, refine_windows
    from skyrig.dense.sgm import disparity_window, window_cut

    sgm = config.sgm
    if not window_cut(blk.d_min, blk.d_max, sgm):
        return [blk], SearchCounts()
    if not config.hierarchical or grey is None:
        return [blk], SearchCounts(cut=1)
    up = coarse_level(blk.d_max - blk.d_min, sgm.max_disparities)
    f = 2 ** up
    rc = coarse_rectification(rect, up)
    bc = Block(blk.u0 // f, -(-blk.u1 // f), blk.v0 // f, -(-blk.v1 // f), blk.d_min / f, blk.d_max / f)
    with phase("coarse"):
        dc, _, _ = match_block(rc, grey(left, up), grey(right, up), bc, sgm)
        shift, n = disparity_window(bc.d_min, bc.d_max, sgm)
        with np.errstate(invalid="ignore"):  # stuck at either end of the search: no surface
            dc[(dc < shift + 1.5) | (dc > shift + n - 2.5)] = np.nan
    # the widest window that disparity_window does not cut: its integer ends take up to 2 px more
    wins, n_cut, n_trim, n_blind = refine_windows(dc, f, bc.u0, bc.v0, blk.u0, blk.u1, blk.v0, blk.v1, blk.d_min,
                                                  blk.d_max, sgm.max_disparities - 3)
    return [Block(*w) for w in wins], SearchCounts(n_cut, 1, n_blind, n_trim)


def fill_holes(height: NDArray[np.float32], max_cells: int) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """Fill NaN holes within ``max_cells`` of measured cells by OpenCV's Telea inpainting of the height field.

    Returns the filled heights and the mask of filled cells."""
    import cv2
    from scipy import ndimage

    hole = ~np.isfinite(height)
    if not hole.any() or hole.all():
        return height, np.zeros_like(hole)
    dist = ndimage.distance_transform_edt(hole)
    target = hole & (dist <= max_cells)
    lo = float(np.nanmin(height))
    base = np.where(hole, 0, height - lo).astype(np.float32)
    filled = cv2.inpaint(base, hole.astype(np.uint8), 3, cv2.INPAINT_TELEA) + lo
    out = height.copy()
    out[target] = filled[target]
    return out, target


@dataclass
class DenseStats:
    """Counts and timings of a dense run.

    ``search``: what the disparity search did (:class:`SearchCounts`); ``image_scale``: the scale the images were
    matched at.
    A block is matched once per ground tile that needs it, so these count block matchings, as ``blocks`` does."""

    pairs: int
    tiles: int
    blocks: int
    points: int
    megapixels: float
    seconds: float
    gsd_m: float
    cell_m: float
    image_scale: float = 1.0
    search: SearchCounts = field(default_factory=SearchCounts)

    def summary_line(self) -> str:
        """One line on the disparity search (empty when no window was wider than the matcher's limit)."""
        return self.search.summary_line(self.blocks)


#: the layers of a tile's result that the assembly puts together (:func:`tile_layers`), in this order
TILE_LAYERS = ("height", "support", "spread", "sigma", "cand_height", "cand_sigma", "cand_support", "cand2_height",
               "cand2_sigma", "cand2_support")
_COUNT_LAYERS = ("support", "cand_support", "cand2_support")


def tile_layers(r: TileResult) -> list[NDArray]:
    """The tile's :data:`TILE_LAYERS` (a missing candidate layer as no data: NaN, count 0)."""
    _, _, h, w = r.window
    return [_no_data(n, h, w) if getattr(r, n) is None else getattr(r, n) for n in TILE_LAYERS]


def empty_layers(h: int, w: int) -> list[NDArray]:
    """:data:`TILE_LAYERS` of ``h x w`` cells without data."""
    return [_no_data(n, h, w) for n in TILE_LAYERS]


def _no_data(name: str, h: int, w: int) -> NDArray:
    return np.zeros((h, w), np.int16) if name in _COUNT_LAYERS else np.full((h, w), np.nan, np.float32)


def confirm_reach(config: DenseConfig) -> int:
    """How far (cells) the neighbour confirmation of :func:`confirm_window` looks: a window's cells come out as
    the whole grid's when the layers it is given reach this far beyond it (or to the grid's edge)."""
    return max(0, int(config.fusion.neighbour_cells))


def confirm_window(layers: list[NDArray], inner: tuple[int, int, int, int], cell_m: float, config: DenseConfig
                   ) -> tuple[NDArray[np.float32], NDArray[np.int16], NDArray[np.float32], NDArray[np.float32]]:
    """Step 4 and 5 of the fusion (:func:`skyrig.dense.fusion.confirm_by_neighbours`) on :data:`TILE_LAYERS` of a
    part of the grid, and the ``(rows, cols)`` window ``inner = (row0, col0, rows, cols)`` of it out: height,
    support, spread, sigma.  With :func:`confirm_reach` cells around the window (or the grid's edge) in
    ``layers``, the window's cells are those of the whole grid's confirmation (only cells of steps 1-3 confirm,
    no chains).  ``layers`` are not changed."""
    height, support, spread, sigma = (np.array(a) for a in layers[:4])
    confirm_by_neighbours(height, support, sigma, *layers[4:7], cell_m, config.fusion, *layers[7:10])
    r0, c0, h, w = inner
    sl = (slice(r0, r0 + h), slice(c0, c0 + w))
    return height[sl], support[sl], spread[sl], sigma[sl]


class TileTally:
    """The counts of a dense run, tile result by tile result (:class:`DenseStats`)."""

    def __init__(self) -> None:
        self.blocks = self.points = self.tiles = 0
        self.megapixels = self.seconds = 0.0
        self.search = SearchCounts()

    def add(self, r: TileResult) -> None:
        self.blocks += r.blocks
        self.search = self.search + r.search
        self.points += r.points
        self.megapixels += r.megapixels
        self.seconds += r.seconds
        self.tiles += 1

    def stats(self, plan: DensePlan) -> DenseStats:
        """The counts as :class:`DenseStats`; the disparity search's line logged (a warning when windows were cut)."""
        stats = DenseStats(len(plan.pairs), self.tiles, self.blocks, self.points, self.megapixels, self.seconds,
                           plan.gsd_m, plan.grid.cell_m, 0.5 ** plan.image_level, self.search)
        if stats.summary_line():
            (logger.warning if self.search.cut else logger.info)("dense: %s", stats.summary_line())
        return stats


def assemble(plan: DensePlan, results: Iterable[TileResult]) -> tuple[DsmGrid, DenseCloud | None, DenseStats]:
    """Put tile results together into the DSM (and cloud), whole in memory (``skyrig.pipeline.dense`` writes
    them window by window instead, with the same cells and points)."""
    H, W = plan.grid.shape
    layers: list[NDArray] | None = None
    clouds = []
    tally = TileTally()
    for r in results:
        r0, c0, h, w = r.window
        if layers is None and tuple(r.window) == (0, 0, H, W):  # one tile, the whole grid: its layers as they are
            layers = tile_layers(r)  # (the grid's copies of fresh memory cost 0.05 of the 16-image bench's 2.9 s)
        else:
            if layers is None:
                layers = empty_layers(H, W)
            for a, t in zip(layers, tile_layers(r)):
                a[r0:r0 + h, c0:c0 + w] = t
        if r.cloud is not None:
            clouds.append(r.cloud)
        tally.add(r)
    if layers is None:
        layers = empty_layers(H, W)
    height, support, spread, sigma = confirm_window(layers, (0, 0, H, W), plan.grid.cell_m, plan.config)
    del layers
    filled = np.zeros((H, W), bool)
    if plan.config.fill_holes:
        height, filled = fill_holes(height, plan.config.fill_max_cells)
    vref = vertical_reference(plan.out_frame)
    dsm = DsmGrid(plan.grid, plan.out_frame, height, support, spread, sigma, filled, vref, dsm_metadata(plan))
    cloud = None
    if plan.config.cloud:
        if len(clouds) == 1:  # one tile: its arrays as they are (no copy)
            cat = list(clouds[0])
        elif clouds:
            cat = [np.concatenate([c[k] for c in clouds]) for k in range(5)]
        else:
            cat = [np.zeros((0, 3)), np.zeros((0, 3), np.uint8), np.zeros((0, 3), np.float32), np.zeros(0, np.int16),
                   np.zeros(0, np.float32)]
        cloud = DenseCloud(cat[0], cat[1], cat[2], cat[3], cat[4], plan.out_frame, vref)
    return dsm, cloud, tally.stats(plan)


def dsm_metadata(plan: DensePlan) -> dict:
    """The DSM's metadata (:attr:`DsmGrid.metadata`)."""
    return {"gsd_m": plan.gsd_m, "pairs": len(plan.pairs)}


def dense_surface(eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera], loader: ImageLoader,
                  out_frame: WorldFrame, height_range: tuple[float, float],
                  area: tuple[float, float, float, float] | None = None, config: DenseConfig = DenseConfig(),
                  map_fn: Callable | None = None) -> tuple[DsmGrid, DenseCloud | None, DenseStats]:
    """DSM and dense cloud of a block: :func:`plan_dense`, :func:`run_tile` for every tile through ``map_fn``
    (default: the builtin ``map``), :func:`assemble`.

    ``loader(i)`` returns the image of ``eo`` row ``i`` (uint8, RGB or grey)."""
    plan = plan_dense(eo, cameras, out_frame, height_range, area, config)
    fn = map_fn or (lambda f, items: list(map(f, items)))
    results = fn(_TileJob(plan, loader), range(len(plan.tiles)))
    return assemble(plan, results)


class _TileJob:
    """Picklable ``k -> run_tile(plan, k, loader)``."""

    def __init__(self, plan: DensePlan, loader: ImageLoader) -> None:
        self.plan = plan
        self.loader = loader

    def __call__(self, k: int) -> TileResult:
        return run_tile(self.plan, k, self.loader)
