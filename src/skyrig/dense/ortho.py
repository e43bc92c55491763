"""True orthophotos and orthomosaics: backward projection of oriented images onto a DSM, with occlusion.

Every output cell is a point of the surface (map ``x, y`` and the DSM's height there).  It is projected into the
images with their full camera model; an image gives the cell its colour only where it **sees** the cell: the DSM,
drawn as a triangle surface into a depth buffer of that image (:mod:`skyrig.dense._ortho_kernels`), must not hide
it.  So a roof stands on its own footprint (no leaning buildings) and ground hidden behind a building in one image
takes its colour from another one.

The mosaic is planned on the DSM's grid (:func:`plan_ortho`), then produced tile by tile (:func:`run_ortho_tile`,
any number of workers; :func:`assemble_ortho` puts the tiles together):

1. **views** (one per image, on the DSM grid): the depth buffer, the visible cells, and a cost per visible cell:
   ``tan(off-nadir angle) + gsd_weight * max(0, gsd / gsd_ref - 1)`` (lean of what the DSM misses, and
   resolution), and colours at a sparse lattice for the radiometric balance;
2. **best view and seamlines**: each ground cell takes the visible image of least cost; each **elevated object**
   (connected cells more than ``elevated_m`` above the ground estimate, grown by ``seam_margin_m``) takes one image
   as a whole - the one of least mean cost that sees all of it - so seamlines run on the ground around buildings and
   trees, never through them;
3. **radiometric balance**: one gain per image and channel from the mean colours of every overlapping pair on
   visible ground (least squares, pulled to 1 as OpenCV's ``GainCompensator`` does);
4. **tiles** at the output resolution: heights bilinear from the DSM, the depth buffer of each contributing image
   redrawn around the tile, colours by ``cv2.remap`` (bilinear), blended with feathered weights (box-filtered
   region masks, ``feather_m`` wide, times visibility); cells no labelled image sees at full resolution take the
   best other image that sees them; cells that the depth buffers hide from every image but lie within a pixel of an
   occluding edge (rays grazing an eave) are settled by marching their rays through the surface
   (``occlusion_slack_px``).

Layer 2c: arrays and orientations in, arrays out; the files are :mod:`skyrig.pipeline.ortho`'s job.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Iterator, Mapping, Protocol

import numpy as np
from numpy.typing import NDArray

from skyrig.camera.frame import FrameCamera
from skyrig.dense.grid import DsmGrid, GridSpec
from skyrig.dense.rectify import WindowedImage, sampled_window
from skyrig.errors import EmptyMosaicError, SkyrigError  # noqa: F401 - EmptyMosaicError re-exported
from skyrig.geodesy.crs import check_metric_projected
from skyrig.geodesy.frame import WorldFrame, local_frame_for
from skyrig.georef.eo import ExteriorOrientations

logger = logging.getLogger(__name__)


class ImageLoader(Protocol):
    def __call__(self, i: int) -> NDArray[np.uint8]: ...


@dataclass(frozen=True)
class OrthoConfig:
    """Options of the orthomosaic.

    Attributes
    ----------
    cell_m
        Output cell size (metres); None: the images' median ground sample distance.
    tile_cells
        Tile size in output cells.
    max_off_nadir_deg
        Cells seen more obliquely than this from an image do not take that image (60 deg: nadir mosaics; raise it
        for mosaics of oblique heads).
    gsd_weight
        Weight of the resolution term of the cost.
    elevated_m
        Height above the ground estimate that makes a cell part of an elevated object (buildings, trees).
    ground_window_m
        Size of the window of the ground estimate (larger than the largest building).
    seam_margin_m
        Elevated objects are grown by this much before they are given one image (seamlines keep this distance).
    feather_m
        Width of the blend across seamlines; None: 6 output cells.
    min_region_m
        Regions of one image smaller than this squared (m^2) are merged into a neighbour (no speckled seamlines).
    occlusion_tol_cells
        Depth tolerance of the visibility test in DSM cells (times ``1 + tan`` of the off-nadir angle).
    occlusion_slack_px
        Last resort for cells that no image sees: the depth buffer is drawn at the images' pixel centres and a cell
        is tested at the pixel nearest its projection, so a cell within a pixel of an occluding edge (a ray grazing
        an eave, or the foot of a wall) is decided by where the pixel centres fall rather than by the surface.  Such
        cells, hidden from every image by the buffer, are tested again in the images whose buffer lets them through
        when taken as its largest depth within this many pixels: the ray from the cell to the image is marched
        through the surface itself (:func:`_rays_clear`, the squared buildings' walls on their outlines) and the
        image gives the cell its colour where nothing stands above the ray.  0: no last resort.
    balance
        Radiometric balance between images (per-image, per-channel gains).
    balance_sigma_gain
        Prior standard deviation of a gain around 1.
    balance_sigma_noise
        Standard deviation of the mean colour difference of an overlap (digital numbers).
    square_buildings
        Square the buildings' edges in the surface the images are projected on (:func:`square_buildings`): a
        matched DSM rounds roof edges off, so that roof cells next to the eaves project onto the wall and the ground
        beyond it, and the ground next to the wall onto the roof (roofs lean and fray).  Buildings are extracted
        from the DSM (:func:`skyrig.dense.buildings.extract_buildings`); each footprint takes its roof planes and
        the elevated cells in a band of ``square_band_m`` around it the ground, where the roof planes explain the
        DSM inside the footprint (median absolute residual <= ``square_max_residual_m``; trees are left alone).
    square_refine
        Before the buildings are drawn, move their walls onto the roof outline seen in the images
        (:func:`skyrig.dense.facades.refine_walls`, steep views): the DSM's footprints are off by a few tenths of a
        metre, the images show the outline sharply.
    square_band_m, square_max_residual_m
        See ``square_buildings``.
    square_sharp
        Put the squared buildings' edges where their outlines are, not where the DSM's cells put them: the output
        cells near an outline take the roof planes inside it and the ground outside (:func:`sharp_heights`), and
        the depth buffers draw the walls on the outline (:func:`snap_lattice`).  Without it, a roof edge in the
        mosaic moves to and fro by up to a DSM cell along the wall.
    """

    cell_m: float | None = None
    tile_cells: int = 2048
    max_off_nadir_deg: float = 60.0
    gsd_weight: float = 0.5
    elevated_m: float = 2.0
    ground_window_m: float = 60.0
    seam_margin_m: float | None = None
    feather_m: float | None = None
    min_region_m: float = 2.0
    occlusion_tol_cells: float = 1.5
    occlusion_slack_px: int = 1
    balance: bool = True
    balance_sigma_gain: float = 0.1
    balance_sigma_noise: float = 10.0
    square_buildings: bool = True
    square_refine: bool = True
    square_band_m: float = 2.5
    square_max_residual_m: float = 0.5
    square_sharp: bool = True

    @property
    def max_tan(self) -> float:
        """tan of ``max_off_nadir_deg``."""
        return float(np.tan(np.radians(self.max_off_nadir_deg)))


@dataclass(frozen=True)
class View:
    """What one image contributes on the DSM grid (``window`` rows/cols of the DSM grid)."""

    image: int
    window: tuple[int, int, int, int]
    cost: NDArray[np.float32]  # inf where not visible / too oblique / outside
    samples: NDArray[np.uint8]  # (h', w', 3) colours at the balance lattice of the window
    sample_ok: NDArray[np.bool_]
    step: int = 1  # balance lattice: every step-th DSM cell of the window


@dataclass(frozen=True)
class OrthoPlan:
    """Everything :func:`run_ortho_tile` needs (no pixels).

    Attributes
    ----------
    eo
        Orientations in the working local frame.
    cameras
        Camera name -> camera.
    dsm
        The DSM (map frame); ``height`` here is hole-filled, NaN only outside the surface.
    to_local
        Map frame -> working local frame (polynomial checked against PROJ, see ``FrameMap``).
    grid
        The output grid (map frame).
    label
        ``(rows, cols)`` int32 on the DSM grid: the image each DSM cell takes (-1: none sees it).
    windows
        Per image, its DSM-grid window ``(row0, col0, height, width)`` (zero size when unused).
    gains
        ``(n_images, 3)`` gains applied to the images' colours.
    tiles
        ``(row0, col0, height, width)`` windows of the output grid.
    gsd_m
        Reference ground sample distance of the images (metres).
    config
        The options.
    stats
        Counts of the planning.
    sharp, outside
        The buildings drawn into ``dsm`` by :func:`square_buildings` and the surface without them (their footprints'
        cells at the ground): the tiles' heights near their outlines come from these (:func:`sharp_heights`).
    """

    eo: ExteriorOrientations
    cameras: Mapping[str, FrameCamera]
    dsm: DsmGrid
    to_local: Callable[[NDArray[np.float64]], NDArray[np.float64]]
    grid: GridSpec
    label: NDArray[np.int32]
    windows: tuple[tuple[int, int, int, int], ...]
    gains: NDArray[np.float64]
    tiles: tuple[tuple[int, int, int, int], ...]
    gsd_m: float
    config: OrthoConfig
    stats: dict = field(default_factory=dict)
    sharp: tuple[SharpBuilding, ...] = ()
    outside: DsmGrid | None = None

    @property
    def zrange(self) -> tuple[float, float]:
        h = self.dsm.height
        return float(np.nanmin(h)), float(np.nanmax(h))


@dataclass(frozen=True)
class SharpBuilding:
    """A building drawn into the surface by :func:`square_buildings`: its outline ``(N, 2)`` (map x, y) and roof
    planes ``(P, 3)`` (``z = a x + b y + c``; the roof is their lower envelope)."""

    outline: NDArray[np.float64]
    planes: NDArray[np.float64]


def _inside_polygon(x: NDArray, y: NDArray, poly: NDArray) -> NDArray[np.bool_]:
    """Even-odd test of points against a closed polygon ``(N, 2)``."""
    inside = np.zeros(x.shape, bool)
    xa, ya = poly[:, 0], poly[:, 1]
    xb, yb = np.roll(xa, -1), np.roll(ya, -1)
    for x1, y1, x2, y2 in zip(xa, ya, xb, yb):
        if y1 == y2:
            continue
        cross = (y1 > y) != (y2 > y)
        inside ^= cross & (x < (x2 - x1) * (y - y1) / (y2 - y1) + x1)
    return inside


def _polygon_nearest(x: NDArray, y: NDArray, poly: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """Distance of points from a closed polygon's outline and the nearest outline point (x, y)."""
    d = np.full(x.shape, np.inf)
    nx, ny = np.array(x, float, copy=True), np.array(y, float, copy=True)
    for p, q in zip(poly, np.roll(poly, -1, axis=0)):
        e = q - p
        ee = float(e @ e)
        t = np.clip(((x - p[0]) * e[0] + (y - p[1]) * e[1]) / max(ee, 1e-12), 0.0, 1.0)
        fx, fy = p[0] + t * e[0], p[1] + t * e[1]
        de = np.hypot(x - fx, y - fy)
        closer = de < d
        d = np.where(closer, de, d)
        nx, ny = np.where(closer, fx, nx), np.where(closer, fy, ny)
    return d, nx, ny


def _polygon_distance(x: NDArray, y: NDArray, poly: NDArray) -> NDArray[np.float64]:
    """Distance of points from a closed polygon's outline."""
    return _polygon_nearest(x, y, poly)[0]


def snap_lattice(xx: NDArray[np.float64], yy: NDArray[np.float64], buildings: Iterable[SharpBuilding],
                 reach_m: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Positions of DSM lattice points (cell centres ``xx, yy``, map) for a depth buffer with the drawn buildings'
    walls where their outlines are: the points within ``reach_m`` of an outline (inside or out) move onto it,
    keeping their heights.  Drawn between cell centres, a wall slants across a cell and hides the ground just
    outside the true wall from the images that look at it."""
    X, Y = np.array(xx, float, copy=True), np.array(yy, float, copy=True)
    if X.size == 0:
        return X, Y
    best = np.full(X.shape, np.inf)
    for _, P, idx in _outlines_near(buildings, xx, yy, reach_m):
        d, nx, ny = _polygon_nearest(xx[idx], yy[idx], P)
        mv = (d <= reach_m) & (d < best[idx])
        r_, c_ = idx[0][mv], idx[1][mv]
        X[r_, c_], Y[r_, c_], best[r_, c_] = nx[mv], ny[mv], d[mv]
    return X, Y


def _outlines_near(buildings: Iterable[Any], xx: NDArray[np.float64], yy: NDArray[np.float64],
                   margin_m: float) -> Iterator[tuple[Any, NDArray[np.float64], tuple[NDArray[np.intp], ...]]]:
    """``(building, outline, idx)`` for each building whose outline's box, grown by ``margin_m``, meets the points
    ``xx, yy`` (non-empty), ``idx`` (``np.nonzero``) the points inside that grown box."""
    xlo, xhi, ylo, yhi = float(xx.min()), float(xx.max()), float(yy.min()), float(yy.max())
    for b in buildings:
        P = b.outline
        if (P[:, 0].max() + margin_m < xlo or P[:, 0].min() - margin_m > xhi or P[:, 1].max() + margin_m < ylo
                or P[:, 1].min() - margin_m > yhi):
            continue
        box = ((xx >= P[:, 0].min() - margin_m) & (xx <= P[:, 0].max() + margin_m)
               & (yy >= P[:, 1].min() - margin_m) & (yy <= P[:, 1].max() + margin_m))
        yield b, P, np.nonzero(box)


def sharp_heights(xx: NDArray[np.float64], yy: NDArray[np.float64], zz: NDArray[np.float64],
                  buildings: Iterable[SharpBuilding], outside: DsmGrid, band_m: float) -> NDArray[np.float64]:
    """Heights ``zz`` at map points ``xx, yy`` (from the squared surface, bilinear) with the drawn buildings' edges
    put where their outlines are, not where the DSM's cells put them.

    Interpolating a surface with a wall in it spreads the wall over a cell: points just inside the roof get a
    height part way down the wall and points just outside part way up, so that an image looking across the eaves
    shows wall there and the roof's edge in the orthophoto moves by up to a DSM cell, to and fro along the edge as
    the cells fall.  Within ``band_m`` of a building's outline, a point inside it takes the roof planes' height at
    the point, a point outside it the surface ``outside`` (the squared surface with the footprints' cells set to
    the ground) there."""
    out = np.array(zz, np.float64, copy=True)
    if xx.size == 0:
        return out
    ins_any = np.zeros(xx.shape, bool)
    z_out = None
    for b, P, idx in _outlines_near(buildings, xx, yy, band_m):
        x, y = xx[idx], yy[idx]
        near = _polygon_distance(x, y, P) <= band_m
        if not near.any():
            continue
        ins = _inside_polygon(x, y, P) & near
        roof = np.min(b.planes[:, 0][None] * x[:, None] + b.planes[:, 1][None] * y[:, None] + b.planes[:, 2][None],
                      axis=1)
        if z_out is None:
            z_out = _bilinear_dsm(outside, xx, yy)
        sel = near & ~ins
        if sel.any():  # outside this building, unless inside another one (drawn before or after)
            r_, c_ = idx[0][sel], idx[1][sel]
            free = ~ins_any[r_, c_]
            out[r_[free], c_[free]] = z_out[r_[free], c_[free]]
        if ins.any():
            out[idx[0][ins], idx[1][ins]] = roof[ins]
            ins_any[idx[0][ins], idx[1][ins]] = True
    return out


@dataclass
class OrthoTile:
    """One output tile: colours, validity, surface (cells with a DSM height), source image per cell (-1 no surface,
    -2 seen by no image)."""

    window: tuple[int, int, int, int]
    rgb: NDArray[np.uint8]
    valid: NDArray[np.bool_]
    surface: NDArray[np.bool_]
    source: NDArray[np.int16]
    fallback_cells: int
    seconds: float
    slack_cells: int = 0  # cells coloured only by the last resort (:attr:`OrthoConfig.occlusion_slack_px`)


@dataclass(frozen=True)
class Orthomosaic:
    """An orthomosaic in a map frame.

    Attributes
    ----------
    grid, frame
        Where the cells are (``frame``: the DSM's map frame).
    rgb
        ``(rows, cols, 3)`` uint8.
    valid
        ``(rows, cols)`` bool: cells with a colour.
    surface
        ``(rows, cols)`` bool: cells with a DSM height (a cell of the surface no image sees is ``surface & ~valid``).
    source
        ``(rows, cols)`` int16 index into ``images`` of the image that gives most of the cell's colour; -1 no
        surface (outside the DSM), -2 a surface no image sees.
    images
        Image names.
    label
        The seamline regions on the DSM grid (``dsm_grid``): the image of each region (-1 none).
    dsm_grid
        The DSM grid of ``label``.
    gains
        ``(n_images, 3)`` radiometric gains applied.
    stats
        Counts and timings.
    """

    grid: GridSpec
    frame: WorldFrame
    rgb: NDArray[np.uint8]
    valid: NDArray[np.bool_]
    surface: NDArray[np.bool_]
    source: NDArray[np.int16]
    images: tuple[str, ...]
    label: NDArray[np.int32]
    dsm_grid: GridSpec
    gains: NDArray[np.float64]
    vertical_reference: str = ""
    stats: dict = field(default_factory=dict)


# ----------------------------------------------------------------------------------------------- geometry
def _project(plan_eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera], i: int, p_local: NDArray[np.float64]
             ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Pixels (col, row), depth along the viewing axis and tan(off-nadir angle) of local points ``(N, 3)``."""
    cam = cameras[str(plan_eo.camera[i])]
    c = plan_eo.centre[i]
    rel = p_local - c
    pc = rel @ plan_eo.rotation[i]
    depth = -pc[:, 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        uv = cam.project_pixels(pc)
        up = -rel[:, 2]  # camera above the point: (C - P)_z > 0
        horiz = np.hypot(rel[:, 0], rel[:, 1])
        tan = np.where(up > 0, horiz / up, np.inf)
    bad = ~(depth > 0)
    uv[bad] = np.nan
    return uv[:, 0], uv[:, 1], depth, tan


def _zbuffer_for(u: NDArray, v: NDArray, d: NDArray, cam: FrameCamera, pad: int = 2
                 ) -> tuple[NDArray[np.float32], int, int]:
    """Depth buffer of a projected lattice ``(H, W)`` over the image part it covers."""
    from skyrig.dense._ortho_kernels import zbuffer

    ok = np.isfinite(u) & np.isfinite(v) & (d > 0)
    if not ok.any():
        return np.full((1, 1), np.inf, np.float32), 0, 0
    u0 = int(max(np.floor(np.nanmin(u[ok])) - pad, 0))
    v0 = int(max(np.floor(np.nanmin(v[ok])) - pad, 0))
    u1 = int(min(np.ceil(np.nanmax(u[ok])) + pad, cam.width - 1))
    v1 = int(min(np.ceil(np.nanmax(v[ok])) + pad, cam.height - 1))
    if u1 < u0 or v1 < v0:
        return np.full((1, 1), np.inf, np.float32), 0, 0
    zb = np.full((v1 - v0 + 1, u1 - u0 + 1), np.inf, np.float32)
    max_px = 0.25 * max(cam.width, cam.height)
    zbuffer(np.ascontiguousarray(u), np.ascontiguousarray(v), np.ascontiguousarray(d, np.float64), zb, u0, v0,
            max_px)
    return zb, u0, v0


def _visible(u: NDArray, v: NDArray, d: NDArray, tol: NDArray, zb: NDArray[np.float32], u0: int, v0: int
             ) -> NDArray[np.bool_]:
    from skyrig.dense._ortho_kernels import visible

    shape = u.shape
    out = np.zeros(u.size, np.bool_)
    visible(np.ascontiguousarray(u, np.float64).ravel(), np.ascontiguousarray(v, np.float64).ravel(),
            np.ascontiguousarray(d, np.float64).ravel(), np.ascontiguousarray(tol, np.float64).ravel(), zb, u0, v0,
            out)
    return out.reshape(shape)


def fill_surface(dsm: DsmGrid, step_m: float = 2.0) -> NDArray[np.float64]:
    """DSM heights with every hole inside the measured area filled; NaN only outside it.

    A hole whose rim spans more than ``step_m`` of height (it touches a building and the ground: typically ground that
    one image of each stereo pair could not see) is filled at the low part of its rim (20th percentile), so it is not
    a ramp from the eaves that would hide the ground next to the building; other holes are inpainted smoothly."""
    from scipy import ndimage

    from skyrig.dense.surface import fill_holes

    h = np.asarray(dsm.height, np.float32)
    ok = np.isfinite(h)
    if not ok.any():
        raise SkyrigError("the DSM has no valid height: nothing to orthorectify onto")
    if ok.all():
        return h.astype(np.float64)
    inside = ndimage.binary_fill_holes(ndimage.binary_closing(ok, iterations=3, border_value=0)) | ok
    filled, _ = fill_holes(h, max(h.shape))
    out = np.where(inside, filled, np.nan).astype(np.float64)
    holes, n = ndimage.label(inside & ~ok)
    if n:
        objs = ndimage.find_objects(holes)
        for k, sl in enumerate(objs, start=1):
            sl = tuple(slice(max(a.start - 1, 0), a.stop + 1) for a in sl)
            m = holes[sl] == k
            rim = ndimage.binary_dilation(m) & ~m & ok[sl]
            if not rim.any():
                continue
            zr = h[sl][rim]
            lo, hi = np.percentile(zr, [20, 90])
            if hi - lo > step_m:
                sub = out[sl]
                sub[m] = lo
    return out


def eo_steep_axis(eo: ExteriorOrientations, dsm: DsmGrid) -> NDArray[np.float64]:
    """Vertical component of every image's viewing axis in a local frame at the DSM's centre (-1: straight down)."""
    xb0, yb0, xb1, yb1 = dsm.grid.bounds
    h = np.asarray(dsm.height, np.float64)
    z = float(np.nanmedian(h)) if np.isfinite(h).any() else 0.0
    local = local_frame_for(dsm.frame.to_ecef(np.array([[0.5 * (xb0 + xb1), 0.5 * (yb0 + yb1), z]])))
    return -eo.to_frame(local).rotation[:, 2, 2]


def square_buildings(height: NDArray[np.float64], dsm: DsmGrid, *, band_m: float = 2.5, max_residual_m: float = 0.5,
                     ground: NDArray[np.float64] | None = None, blocks: list | None = None,
                     drawn_out: list | None = None) -> tuple[NDArray[np.float64], dict[str, int]]:
    """The surface ``height`` (on ``dsm``'s grid, holes filled) with square building edges.

    A matched DSM rounds roof edges off over a few cells (the matching windows straddle the eaves): cells just inside
    a roof are too low and project, in an image looking across the eaves, onto the wall or the ground beyond it; the
    ground cells just outside are too high and take the roof's colour.  The orthophoto then shows the roof shrunk on
    one side and spilled on the other (lean).  Here every building block (``blocks``, default
    :func:`skyrig.dense.buildings.extract_buildings` of ``dsm`` - footprints from the half-height crossing of the
    ramp, roof planes fitted away from the edges - also blocks cut by the DSM's border) whose roof planes explain
    the DSM inside its footprint (median absolute residual <= ``max_residual_m``; a tree crown is not a plane and is
    left as matched) is drawn into the surface: the footprint's cells take the roof planes (a gable: the lower
    envelope of its two planes), and the cells in a band of ``band_m`` around the footprint that are higher than
    1 m (or 30 % of the eave height, if less) above the ground take the ground (``ground``, default the block's
    ground height).

    Returns the new heights and counts ``{"buildings": blocks drawn, "cells": cells changed by more than 1 cm}``.
    ``drawn_out``: a list that gets one :class:`SharpBuilding` per drawn block (its exact outline and roof planes,
    for :func:`sharp_heights`) and, last, the DSM-grid mask of the drawn footprints' cells.
    """
    import cv2
    from scipy import ndimage

    from skyrig.dense.buildings import ExtractionConfig, extract_buildings

    h0 = np.asarray(height, np.float64)
    if blocks is None:
        blocks = extract_buildings(DsmGrid(dsm.grid, dsm.frame, np.asarray(dsm.height, np.float32), dsm.support,
                                           dsm.spread, dsm.sigma, dsm.filled, dsm.vertical_reference, dsm.metadata),
                                   config=ExtractionConfig(max_outside=1.0))
    g = dsm.grid
    H, W = h0.shape
    h = h0.copy()
    meas = np.isfinite(np.asarray(dsm.height))
    masks = []
    k = 5  # cells whose centre is inside the footprint: filled at 5 x 5 sub-cells, the middle one read
    for b in blocks:
        fp = np.asarray(b.footprint, float)
        cf, rf = (fp[:, 0] - g.x0) / g.cell_m, (g.y0 - fp[:, 1]) / g.cell_m
        r0, c0 = max(int(np.floor(rf.min())) - 1, 0), max(int(np.floor(cf.min())) - 1, 0)
        r1, c1 = min(int(np.ceil(rf.max())) + 1, H), min(int(np.ceil(cf.max())) + 1, W)
        m = np.zeros((H, W), bool)
        if r1 > r0 and c1 > c0:
            fine = np.zeros(((r1 - r0) * k, (c1 - c0) * k), np.uint8)
            pts = np.c_[(cf - c0) * k - 0.5, (rf - r0) * k - 0.5]
            cv2.fillPoly(fine, [np.round(pts * 256).astype(np.int32)], 1, lineType=cv2.LINE_8, shift=8)
            m[r0:r1, c0:c1] = fine[k // 2::k, k // 2::k].astype(bool)
        masks.append(m & np.isfinite(h0))
    inside_any = np.any(masks, axis=0) if masks else np.zeros((H, W), bool)
    band = max(1, int(round(band_m / g.cell_m)))
    drawn = 0
    drawn_mask = np.zeros((H, W), bool)
    for b, m in zip(blocks, masks):
        rows, cols = np.nonzero(m)
        if len(rows) < 9:
            continue
        r0, r1 = max(rows.min() - band - 1, 0), min(rows.max() + band + 2, H)
        c0, c1 = max(cols.min() - band - 1, 0), min(cols.max() + band + 2, W)
        sl = (slice(r0, r1), slice(c0, c1))
        xx = g.x0 + (np.arange(c0, c1) + 0.5) * g.cell_m
        yy = g.y0 - (np.arange(r0, r1) + 0.5) * g.cell_m
        X, Y = np.meshgrid(xx, yy)
        roof = np.full(X.shape, np.inf)
        planes = []
        for poly in b.roof:
            P = np.asarray(poly, float)
            coef, *_ = np.linalg.lstsq(np.c_[P[:, 0], P[:, 1], np.ones(len(P))], P[:, 2], rcond=None)
            roof = np.minimum(roof, coef[0] * X + coef[1] * Y + coef[2])
            planes.append(coef)
        ms = m[sl]
        core = ndimage.binary_erosion(ms, iterations=2) & meas[sl]
        if core.sum() < 6 or not np.all(np.isfinite(roof[ms])):
            continue
        if float(np.median(np.abs(h0[sl][core] - roof[core]))) > max_residual_m:
            continue  # not a roof of planes (vegetation, a complex roof): keep the matched surface
        hs = h[sl]
        hs[ms] = roof[ms]
        ring = ndimage.binary_dilation(ms, iterations=band) & ~ms & ~inside_any[sl] & np.isfinite(hs)
        gz = ground[sl] if ground is not None else np.full(ms.shape, b.ground_z)
        spill = ring & (hs > gz + min(1.0, 0.3 * (b.eave_z - b.ground_z)))
        hs[spill] = gz[spill]
        drawn += 1
        drawn_mask[sl] |= ms
        if drawn_out is not None:
            drawn_out.append(SharpBuilding(np.asarray(b.footprint, float)[:, :2], np.asarray(planes, float)))
    if drawn_out is not None:
        drawn_out.append(drawn_mask)
    changed = int(np.sum(np.abs(np.nan_to_num(h - h0)) > 0.01))
    return h, {"buildings": drawn, "cells": changed}


def ground_estimate(height: NDArray[np.float64], cell_m: float, window_m: float) -> NDArray[np.float64]:
    """Ground under the surface: a grey opening (minimum then maximum filter, a disc of ``window_m``) of the DSM,
    smoothed over the same window; NaN where the DSM has none.  Computed on the DSM reduced by block minima to at
    most ~31 cells per window (the ground is smooth at that scale) and interpolated back."""
    import cv2

    ok = np.isfinite(height)
    hi = float(np.nanmax(height))
    h = np.where(ok, height, hi).astype(np.float32)
    f = max(1, int(np.ceil(window_m / cell_m / 31.0)))
    H, W = h.shape
    if f > 1:
        Hp, Wp = -(-H // f) * f, -(-W // f) * f
        hp = np.pad(h, ((0, Hp - H), (0, Wp - W)), mode="edge")
        small = hp.reshape(Hp // f, f, Wp // f, f).min(axis=(1, 3))
    else:
        small = h
    k = max(3, int(round(window_m / (cell_m * f))) | 1)
    se = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
    opened = cv2.dilate(cv2.erode(small, se), se)
    ground = cv2.blur(opened, (k, k))
    if f > 1:
        # cell centres of the small grid sit at (f - 1) / 2 of the fine grid
        ys = (np.arange(H) - (f - 1) / 2.0) / f
        xs = (np.arange(W) - (f - 1) / 2.0) / f
        mx, my = np.meshgrid(xs.astype(np.float32), ys.astype(np.float32))
        ground = cv2.remap(ground, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return np.where(ok, np.minimum(ground, height), np.nan)


def _footprint_window(eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera], i: int, dsm_grid: GridSpec,
                      to_map: Callable, z_lo: float, z_hi: float, max_tan: float) -> tuple[int, int, int, int]:
    """DSM-grid window that image ``i`` can see between two local heights, within the off-nadir limit."""
    cam = cameras[str(eo.camera[i])]
    n = 9
    cc, rr = np.meshgrid(np.linspace(-0.5, cam.width - 0.5, n), np.linspace(-0.5, cam.height - 0.5, n))
    rays = cam.rays_from_pixels(np.stack([cc.ravel(), rr.ravel()], 1)) @ eo.rotation[i].T
    c = eo.centre[i]
    pts = []
    for z in (z_lo, z_hi):
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (z - c[2]) / rays[:, 2]
        ok = (t > 0) & (rays[:, 2] < 0)
        p = c + rays[ok] * t[ok, None]
        if len(p) == 0:
            continue
        tan = np.hypot(p[:, 0] - c[0], p[:, 1] - c[1]) / np.maximum(c[2] - z, 1e-9)
        # the off-nadir limit clips the footprint to a disc around the nadir point
        lim = max_tan * max(c[2] - z, 0.0)
        far = tan > max_tan
        if far.any():
            dxy = p[far, :2] - c[:2]
            p[far, :2] = c[:2] + dxy * (lim / np.linalg.norm(dxy, axis=1))[:, None]
        pts.append(p)
    if not pts:
        return (0, 0, 0, 0)
    m = to_map(np.concatenate(pts))
    r_a, c_a = dsm_grid.cell_of(np.array([m[:, 0].min(), m[:, 0].max()]), np.array([m[:, 1].max(), m[:, 1].min()]))
    r0, r1 = max(int(r_a[0]) - 2, 0), min(int(r_a[1]) + 3, dsm_grid.height)
    c0, c1 = max(int(c_a[0]) - 2, 0), min(int(c_a[1]) + 3, dsm_grid.width)
    if r1 <= r0 or c1 <= c0:
        return (0, 0, 0, 0)
    return (r0, c0, r1 - r0, c1 - c0)


def _window_local(plan_like: "OrthoPlan | _Base", r0: int, c0: int, h: int, w: int,
                  sharp: tuple[SharpBuilding, ...] = ()) -> NDArray[np.float64]:
    """Local coordinates ``(h, w, 3)`` of DSM cells of a window (the lattice points near the outlines of
    ``sharp`` buildings moved onto them, :func:`snap_lattice`)."""
    g = plan_like.dsm.grid.window(r0, c0, h, w)
    xx, yy = g.cell_centres()
    if sharp:
        xx, yy = snap_lattice(xx, yy, sharp, g.cell_m)
    zz = plan_like.dsm.height[r0:r0 + h, c0:c0 + w]
    p = np.stack([xx.ravel(), yy.ravel(), np.nan_to_num(zz.ravel(), nan=np.nanmean(zz) if np.isfinite(zz).any()
                                                                 else 0.0)], 1)
    out = plan_like.to_local(p).reshape(h, w, 3)
    out[~np.isfinite(zz)] = np.nan
    return out


@dataclass(frozen=True)
class _Base:
    eo: ExteriorOrientations
    cameras: Mapping[str, FrameCamera]
    dsm: DsmGrid
    to_local: Callable
    windows: tuple[tuple[int, int, int, int], ...]
    gsd_m: float
    config: OrthoConfig
    step: int
    elevated: NDArray[np.bool_]


def compute_view(base: _Base, i: int, loader: ImageLoader) -> View:
    """The view of image ``i`` on the DSM grid: visibility, cost, balance samples."""
    import cv2

    r0, c0, h, w = base.windows[i]
    empty = View(i, (r0, c0, 0, 0), np.zeros((0, 0), np.float32), np.zeros((0, 0, 3), np.uint8),
                 np.zeros((0, 0), bool), base.step)
    if h < 2 or w < 2:
        return empty
    cam = base.cameras[str(base.eo.camera[i])]
    p = _window_local(base, r0, c0, h, w).reshape(-1, 3)
    u, v, d, tan = _project(base.eo, base.cameras, i, p)
    u, v, d, tan = (a.reshape(h, w) for a in (u, v, d, tan))
    zb, zu0, zv0 = _zbuffer_for(u, v, d, cam)
    tol = base.config.occlusion_tol_cells * base.dsm.grid.cell_m * (1.0 + np.minimum(tan, 10.0))
    vis = _visible(u, v, d, tol, zb, zu0, zv0) & cam.in_image(np.stack([u, v], -1)) & (tan <= base.config.max_tan)
    if not vis.any():
        return empty
    gsd = d / cam.focal_px * np.sqrt(1.0 + tan ** 2)
    cost = (tan + base.config.gsd_weight * np.maximum(gsd / base.gsd_m - 1.0, 0.0)).astype(np.float32)
    cost[~vis] = np.inf
    s = base.step  # the balance lattice: DSM rows and columns that are multiples of s
    a, b = (-r0) % s, (-c0) % s
    us, vs = u[a::s, b::s].astype(np.float32), v[a::s, b::s].astype(np.float32)
    ok = vis[a::s, b::s] & ~base.elevated[r0 + a:r0 + h:s, c0 + b:c0 + w:s]
    img = loader(i)
    smp = cv2.remap(img, np.nan_to_num(us, nan=-10), np.nan_to_num(vs, nan=-10), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_CONSTANT)
    if smp.ndim == 2:
        smp = np.repeat(smp[..., None], 3, axis=2)
    return View(i, (r0, c0, h, w), cost, smp, ok, s)


class _ViewJob:
    def __init__(self, base: _Base, loader: ImageLoader) -> None:
        self.base, self.loader = base, loader

    def __call__(self, i: int) -> View:
        return compute_view(self.base, i, self.loader)


# ----------------------------------------------------------------------------------------------- planning
def solve_gains(views: list[View], n_images: int, sigma_gain: float, sigma_noise: float,
                min_cells: int = 20) -> tuple[NDArray[np.float64], int]:
    """Per-image, per-channel gains from the mean colours of every overlapping pair on visible ground.

    Minimises ``sum_ij n_ij (g_i m_ij - g_j m_ji)^2 / sigma_noise^2 + sum_i 0.01 n_i (g_i - 1)^2 / sigma_gain^2``
    (``m_ij``: mean colour of image i over the cells both see).  Returns the gains and the number of pairs used."""
    gains = np.ones((n_images, 3))
    A = np.zeros((3, n_images, n_images))
    b = np.zeros((3, n_images))
    npairs = 0
    vs = [v for v in views if v.samples.size and v.sample_ok.any()]
    for a in range(len(vs)):
        va = vs[a]
        for bb in range(a + 1, len(vs)):
            vb = vs[bb]
            com = _common_samples(va, vb)
            if com is None:
                continue
            ca, cb = com
            n = len(ca)
            if n < min_cells:
                continue
            ma, mb = ca.mean(axis=0), cb.mean(axis=0)
            i, j = va.image, vb.image
            for k in range(3):
                w = n / sigma_noise ** 2
                A[k, i, i] += w * ma[k] ** 2
                A[k, j, j] += w * mb[k] ** 2
                A[k, i, j] -= w * ma[k] * mb[k]
                A[k, j, i] -= w * ma[k] * mb[k]
            npairs += 1
    if npairs == 0:
        return gains, 0
    for v in vs:
        # the prior only holds the overall brightness (the gauge) and images with few overlaps: 1 % of the cells
        n = 0.01 * float(v.sample_ok.sum())
        for k in range(3):
            A[k, v.image, v.image] += n / sigma_gain ** 2
            b[k, v.image] += n / sigma_gain ** 2
    used = sorted({v.image for v in vs})
    for k in range(3):
        sub = np.ix_(used, used)
        gains[used, k] = np.linalg.solve(A[k][sub], b[k, used])
    return gains, npairs


def _common_samples(va: View, vb: View) -> tuple[NDArray, NDArray] | None:
    """Colours of two views at the DSM cells both see that lie on both views' balance lattices."""
    ra, ca_, ha, wa = va.window
    rb, cb_, hb, wb = vb.window
    r0, r1 = max(ra, rb), min(ra + ha, rb + hb)
    c0, c1 = max(ca_, cb_), min(ca_ + wa, cb_ + wb)
    if r1 <= r0 or c1 <= c0:
        return None
    s = va.step
    rows = np.arange(r0 + (-r0) % s, r1, s)
    cols = np.arange(c0 + (-c0) % s, c1, s)
    if len(rows) == 0 or len(cols) == 0:
        return None
    ia, ja = np.ix_((rows - ra - (-ra) % s) // s, (cols - ca_ - (-ca_) % s) // s)
    ib, jb = np.ix_((rows - rb - (-rb) % s) // s, (cols - cb_ - (-cb_) % s) // s)
    ok = va.sample_ok[ia, ja] & vb.sample_ok[ib, jb]
    if not ok.any():
        return None
    return va.samples[ia, ja][ok].astype(np.float64), vb.samples[ib, jb][ok].astype(np.float64)


def plan_ortho(eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera], dsm: DsmGrid, loader: ImageLoader, *,
               area: tuple[float, float, float, float] | None = None, config: OrthoConfig = OrthoConfig(),
               map_fn: Callable | None = None, buildings: list | None = None) -> OrthoPlan:
    """Plan an orthomosaic: views of every image on the DSM grid, best-view regions, seamlines, gains, tiles.

    Parameters
    ----------
    eo
        Orientations (any frame).
    cameras
        Camera name -> camera.
    dsm
        The surface, in a map frame (its CRS and height reference are the mosaic's).
    loader
        ``loader(i)`` -> image of ``eo`` row ``i`` (uint8 RGB or grey).
    area
        ``(xmin, ymin, xmax, ymax)`` in the DSM's CRS; None: the DSM's extent.
    config
        Options.
    map_fn
        ``map_fn(func, items)`` to run the per-image views (e.g. an executor's map); None: builtin map.
    buildings
        With ``config.square_buildings``: the building blocks (:class:`skyrig.dense.buildings.BuildingBlock`, in the
        DSM's frame) to square, instead of those extracted from the DSM.

    Raises
    ------
    SkyrigError
        On a DSM that is not in a map frame, an empty area, no image that sees the area, or too many cells.
    """
    from scipy import ndimage

    from skyrig.dense.surface import FrameMap

    t0 = time.perf_counter()
    if dsm.frame.kind != "map":
        raise SkyrigError("the orthophoto needs a DSM in a map frame (a projected CRS)")
    check_metric_projected(dsm.frame.crs, "an orthomosaic (its DSM)")
    if len(eo) == 0:
        raise SkyrigError("no oriented image")
    missing = sorted(set(eo.camera.tolist()) - set(cameras))
    if missing:
        raise SkyrigError(f"no camera for {', '.join(missing)} (cameras given: {', '.join(sorted(cameras))})")
    height = fill_surface(dsm)
    squared = {"buildings": 0, "cells": 0}
    drawn: list = []
    outside = None
    if config.square_buildings:
        from skyrig.dense.buildings import ExtractionConfig, extract_buildings

        blocks = (list(buildings) if buildings is not None
                  else extract_buildings(dsm, config=ExtractionConfig(max_outside=1.0)))
        # the outline in steep views only (an oblique's outline moves one for one with an error of the eave height)
        steep = np.flatnonzero(-eo_steep_axis(eo, dsm) > np.cos(np.radians(30.0)))
        if config.square_refine and blocks and len(steep):
            from skyrig.dense.facades import refine_walls

            blocks = refine_walls(blocks, eo.subset(steep), cameras, lambda k: loader(int(steep[k])), dsm)
        gr = ground_estimate(height, dsm.grid.cell_m, config.ground_window_m)
        height, squared = square_buildings(height, dsm, blocks=blocks, band_m=config.square_band_m,
                                           max_residual_m=config.square_max_residual_m, ground=gr, drawn_out=drawn)
        if squared["buildings"] and config.square_sharp:
            foot = drawn.pop()
            outside = DsmGrid(dsm.grid, dsm.frame, np.where(foot, gr, height).astype(np.float32), dsm.support,
                              dsm.spread, dsm.sigma, dsm.filled, dsm.vertical_reference, dsm.metadata)
        else:
            drawn = []
    dsm_f = DsmGrid(dsm.grid, dsm.frame, height.astype(np.float32), dsm.support, dsm.spread, dsm.sigma, dsm.filled,
                    dsm.vertical_reference, dsm.metadata)
    zlo, zhi = float(np.nanmin(height)), float(np.nanmax(height))
    xb0, yb0, xb1, yb1 = dsm.grid.bounds
    ctr = np.array([[0.5 * (xb0 + xb1), 0.5 * (yb0 + yb1), 0.5 * (zlo + zhi)]])
    local = local_frame_for(dsm.frame.to_ecef(ctr))
    box_map = (xb0, yb0, zlo - 1.0, xb1, yb1, zhi + 1.0)
    to_local = FrameMap(dsm.frame, local, box_map)
    to_map = FrameMap(local, dsm.frame, _local_box(dsm.frame, local, box_map))
    eo_l = eo.to_frame(local)
    zl = to_local(np.array([[ctr[0, 0], ctr[0, 1], zlo], [ctr[0, 0], ctr[0, 1], zhi]]))[:, 2]
    if np.any(eo_l.centre[:, 2] <= zl[1]):
        below = [str(n) for n in eo_l.image[eo_l.centre[:, 2] <= zl[1]]][:5]
        raise SkyrigError(f"projection centres below the top of the DSM ({', '.join(below)}): the orientations and "
                          "the DSM do not share a height reference (check their CRS / geoid)")
    # reference GSD: steep views at the mid height
    gs = []
    for i in range(len(eo_l)):
        cam = cameras[str(eo_l.camera[i])]
        axis = -eo_l.rotation[i][:, 2]
        if axis[2] < -np.cos(np.radians(20)):
            gs.append((eo_l.centre[i, 2] - 0.5 * (zl[0] + zl[1])) / abs(axis[2]) / cam.focal_px)
    if not gs:
        gs = [np.linalg.norm(eo_l.centre[i] - to_local(ctr)[0]) / cameras[str(eo_l.camera[i])].focal_px
              for i in range(len(eo_l))]
    gsd_m = float(np.median(gs))
    max_tan = config.max_tan
    windows = tuple(_footprint_window(eo_l, cameras, i, dsm.grid, to_map, zl[0], zl[1], max_tan)
                    for i in range(len(eo_l)))
    # elevated objects
    ground = ground_estimate(height, dsm.grid.cell_m, config.ground_window_m)
    with np.errstate(invalid="ignore"):
        elev0 = (height - ground) > config.elevated_m
    margin = config.seam_margin_m if config.seam_margin_m is not None else 2.0 * dsm.grid.cell_m
    grow = max(1, int(round(margin / dsm.grid.cell_m)))
    elevated = ndimage.binary_dilation(elev0, iterations=grow) & np.isfinite(height)
    comp, ncomp = ndimage.label(elevated)
    ncells = int(np.isfinite(height).sum())
    step = max(1, int(np.ceil(np.sqrt(ncells / 250_000.0))))
    base = _Base(eo_l, dict(cameras), dsm_f, to_local, windows, gsd_m, config, step, elevated)
    fn = map_fn or (lambda f, items: list(map(f, items)))
    views: list[View] = list(fn(_ViewJob(base, loader), list(range(len(eo_l)))))
    # best view per ground cell, one image per elevated object
    H, W = dsm.grid.shape
    best = np.full((H, W), np.inf, np.float32)
    label = np.full((H, W), -1, np.int32)
    comp_cost = np.zeros((len(eo_l), ncomp + 1))
    comp_seen = np.zeros((len(eo_l), ncomp + 1), np.int64)
    core = np.where(elev0 & elevated, comp, 0)  # the object itself, without the margin around it
    comp_size = np.bincount(core.ravel(), minlength=ncomp + 1)
    for v in views:
        r0, c0, h, w = v.window
        if h == 0 or w == 0:
            continue
        sl = (slice(r0, r0 + h), slice(c0, c0 + w))
        better = v.cost < best[sl]
        best[sl] = np.where(better, v.cost, best[sl])
        label[sl] = np.where(better, v.image, label[sl])
        if ncomp:
            cc = core[sl]
            seen = np.isfinite(v.cost) & (cc > 0)
            comp_cost[v.image] = np.bincount(cc[seen], weights=v.cost[seen], minlength=ncomp + 1)
            comp_seen[v.image] = np.bincount(cc[seen], minlength=ncomp + 1)
    objects_whole = 0
    if ncomp:
        with np.errstate(invalid="ignore", divide="ignore"):
            mean_cost = comp_cost / comp_seen
        full = comp_seen >= (comp_size[None, :] * 0.99)
        score = np.where(full, mean_cost, np.inf)
        # objects no image sees whole: the image that sees most of it
        partial = np.where(comp_seen > 0, -comp_seen + mean_cost * 1e-6, np.inf)
        choice = np.where(np.isfinite(score).any(axis=0), np.argmin(score, axis=0), np.argmin(partial, axis=0))
        objects_whole = int(np.isfinite(score[:, 1:]).any(axis=0).sum())
        # a cell of an object takes the object's image only where that image sees it
        img_of = choice[comp]
        sees = np.zeros((H, W), bool)
        for v in views:
            r0, c0, h, w = v.window
            if h == 0 or w == 0:
                continue
            sl = (slice(r0, r0 + h), slice(c0, c0 + w))
            sees[sl] |= (img_of[sl] == v.image) & np.isfinite(v.cost) & (comp[sl] > 0)
        label = np.where(sees, img_of, label).astype(np.int32)
    min_region = max(4, int(round((config.min_region_m / dsm.grid.cell_m) ** 2)))
    label, merged = clean_regions(label, min_region)
    gains = np.ones((len(eo_l), 3))
    npairs = 0
    if config.balance:
        gains, npairs = solve_gains(views, len(eo_l), config.balance_sigma_gain, config.balance_sigma_noise)
    # output grid
    if area is None:
        ax0, ay0, ax1, ay1 = dsm.grid.bounds
    else:
        ax0, ay0, ax1, ay1 = (float(a) for a in area)
        if not (ax1 > ax0 and ay1 > ay0):
            raise SkyrigError(f"empty area {area} (option: area)")
    cell = float(config.cell_m) if config.cell_m else gsd_m
    if not (cell > 0 and np.isfinite(cell)):
        raise SkyrigError(f"cell size must be positive, got {config.cell_m} (option: resolution)")
    grid = GridSpec.covering(ax0, ay0, ax1, ay1, cell)
    if grid.width * grid.height > 2e9:
        raise SkyrigError(f"a {cell:g} m grid over the area has {grid.width * grid.height:.3g} cells (option: resolution)")
    tiles = grid.tiles(config.tile_cells)
    seen_any = np.isfinite(best)
    if not seen_any.any():
        raise EmptyMosaicError("no image sees the DSM (check that the orientations and the DSM are of the same place, "
                               "CRS and height reference)")
    stats = {"images": len(eo_l), "images_used": int(len(np.unique(label[label >= 0]))),
             "objects": int(ncomp), "objects_one_image": objects_whole,
             "small_regions_merged": merged, "balance_pairs": npairs,
             "dsm_cells_seen": int(seen_any.sum()), "dsm_cells": ncells, "plan_seconds": time.perf_counter() - t0,
             "gsd_m": gsd_m, "cell_m": cell, "buildings_squared": squared["buildings"],
             "cells_squared": squared["cells"]}
    return OrthoPlan(eo_l, dict(cameras), dsm_f, to_local, grid, label, windows, gains, tiles, gsd_m, config,
                     stats, tuple(drawn), outside)


def clean_regions(label: NDArray[np.int32], min_cells: int) -> tuple[NDArray[np.int32], int]:
    """Merge regions (4-connected cells of one image) smaller than ``min_cells`` into the neighbouring image that
    borders them most, so that seamlines are few and long rather than speckle.  Returns the labels and the number of
    regions merged.  Cells the new image does not see take another image in the tiles (their fallback)."""
    from scipy import ndimage

    out = label.copy()
    merged = 0
    for _ in range(3):
        changed = 0
        for k in np.unique(out[out >= 0]):
            comp, n = ndimage.label(out == k)
            if n == 0:
                continue
            sizes = np.bincount(comp.ravel())
            small = np.flatnonzero(sizes[1:] < min_cells) + 1
            if len(small) == 0:
                continue
            objs = ndimage.find_objects(comp)
            for c in small:
                sl = objs[c - 1]
                sl = tuple(slice(max(a.start - 1, 0), a.stop + 1) for a in sl)
                m = comp[sl] == c
                ring = ndimage.binary_dilation(m) & ~m
                nb = out[sl][ring]
                nb = nb[(nb >= 0) & (nb != k)]
                if len(nb) == 0:
                    continue
                out[sl][m] = np.bincount(nb).argmax()
                changed += 1
        merged += changed
        if not changed:
            break
    return out, merged


def _local_box(frame: WorldFrame, local: WorldFrame, box_map: tuple[float, ...]) -> tuple[float, ...]:
    x0, y0, z0, x1, y1, z1 = box_map
    c = np.array([[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)])
    cl = local.from_ecef(frame.to_ecef(c))
    lo, hi = cl.min(axis=0) - 1.0, cl.max(axis=0) + 1.0
    return (*lo, *hi)


# ----------------------------------------------------------------------------------------------- tiles
def _bilinear_dsm(dsm: DsmGrid, xx: NDArray, yy: NDArray) -> NDArray[np.float64]:
    import cv2

    g = dsm.grid
    mx = ((xx - g.x0) / g.cell_m - 0.5).astype(np.float32)
    my = ((g.y0 - yy) / g.cell_m - 0.5).astype(np.float32)
    h = np.asarray(dsm.height, np.float32)
    out = cv2.remap(h, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    # cv2 propagates NaN from any of the 4 neighbours; nearest where bilinear is NaN but the cell itself is valid
    near = cv2.remap(h, mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    return np.where(np.isfinite(out), out, near).astype(np.float64)


def _map_to_local_jacobian(plan: OrthoPlan, g: GridSpec) -> NDArray[np.float64]:
    """d(local)/d(map) at the middle of grid ``g`` (map -> local is affine to far below a millimetre over a tile's
    rays)."""
    xb0, yb0, xb1, yb1 = g.bounds
    zlo, zhi = plan.zrange
    m0 = np.array([0.5 * (xb0 + xb1), 0.5 * (yb0 + yb1), 0.5 * (zlo + zhi)])
    pts = plan.to_local(np.vstack([m0, m0 + np.eye(3)]))
    return (pts[1:] - pts[0]).T


def _rays_clear(plan: OrthoPlan, x: NDArray, y: NDArray, z: NDArray, p_local: NDArray, centre: NDArray,
                jac: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Whether the straight rays from surface points (map ``x, y, z``; local ``p_local``) to a projection centre
    (local) pass above the surface: the surface (the DSM as the tiles sample it, with the squared buildings' walls on
    their outlines, :func:`sharp_heights`) is sampled along each ray every tenth of a DSM cell, from a fifth of a
    cell away up to the top of the DSM, and must stay below the ray (tolerance a tenth of a cell)."""
    dg = plan.dsm.grid
    zhi = plan.zrange[1]
    d_map = np.linalg.solve(jac, (centre[None, :] - p_local).T).T  # ray directions in the map frame
    horiz = np.hypot(d_map[:, 0], d_map[:, 1])
    rise = d_map[:, 2] / np.maximum(horiz, 1e-12)  # metres up per metre across
    out = rise > 0
    step = 0.1 * dg.cell_m
    tol = 0.1 * dg.cell_m
    length = np.where(out, np.clip((zhi + tol - z) / np.where(rise > 0, rise, 1.0), 0.0, None), 0.0)
    ux, uy = d_map[:, 0] / np.maximum(horiz, 1e-12), d_map[:, 1] / np.maximum(horiz, 1e-12)
    # every ray's samples at once (the rays are short: they leave the DSM's top after (zhi - z) / rise)
    s0 = 0.2 * dg.cell_m
    nstep = np.where(out, np.ceil(np.maximum(length - s0, 0.0) / step).astype(np.int64) + 1, 0)
    # rays in chunks of at most ~1M samples (bounded memory)
    csum = np.cumsum(nstep)
    lo = 0
    while lo < len(x):
        hi = int(np.searchsorted(csum, csum[lo] - nstep[lo] + 1_000_000, side="right"))
        hi = max(hi, lo + 1)
        idx = np.arange(lo, hi)
        lo = hi
        ray = np.repeat(idx, nstep[idx])
        if len(ray) == 0:
            continue
        first = np.cumsum(nstep[idx]) - nstep[idx]
        dist = s0 + step * (np.arange(len(ray)) - np.repeat(first, nstep[idx]))
        xs, ys, zr = x[ray] + ux[ray] * dist, y[ray] + uy[ray] * dist, z[ray] + rise[ray] * dist
        n = len(ray)
        w = 256 if n > 256 else n  # 2-D blocks for cv2.remap (at most 32767 columns)
        padn = (-n) % w
        xb = np.concatenate([xs, np.repeat(xs[-1:], padn)]).reshape(-1, w)
        yb = np.concatenate([ys, np.repeat(ys[-1:], padn)]).reshape(-1, w)
        zs = _bilinear_dsm(plan.dsm, xb, yb)
        if plan.sharp and plan.outside is not None:
            zs = sharp_heights(xb, yb, zs, plan.sharp, plan.outside, 2.0 * dg.cell_m)
        zs = zs.ravel()[:n]
        hit = np.isfinite(zs) & (zs > zr + tol)
        out[np.unique(ray[hit])] = False
    return out


def _remap_points(img: NDArray[np.uint8], u: NDArray, v: NDArray, c0: int = 0, r0: int = 0) -> NDArray[np.float64]:
    """Bilinear colours ``(n, 3)`` of an image at pixel positions ``u, v`` (1-D); ``img`` may be a window of the
    image with its origin at ``(c0, r0)`` (:func:`skyrig.dense.rectify.sampled_window`)."""
    import cv2

    n = len(u)
    w = 256 if n > 256 else max(n, 1)
    padn = (-n) % w
    ub = np.concatenate([u, np.zeros(padn)]).reshape(-1, w).astype(np.float32) - np.float32(c0)
    vb = np.concatenate([v, np.zeros(padn)]).reshape(-1, w).astype(np.float32) - np.float32(r0)
    col = cv2.remap(img, ub, vb, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
    if col.ndim == 2:
        col = col[..., None].repeat(3, axis=2)
    return col.reshape(-1, 3)[:n]


def run_ortho_tile(plan: OrthoPlan, k: int, loader: ImageLoader) -> OrthoTile:
    """Orthorectify and blend one output tile (``plan.tiles[k]``)."""
    import cv2

    t0 = time.perf_counter()
    r0, c0, h, w = plan.tiles[k]
    cfg = plan.config
    fe_m = cfg.feather_m if cfg.feather_m is not None else 6.0 * plan.grid.cell_m
    fr = max(1, int(round(0.5 * fe_m / plan.grid.cell_m)))
    pad = 2 * fr + 1
    R0, C0 = r0 - pad, c0 - pad
    Hh, Ww = h + 2 * pad, w + 2 * pad
    g = plan.grid.window(R0, C0, Hh, Ww)
    xx, yy = g.cell_centres()
    zz = _bilinear_dsm(plan.dsm, xx, yy)
    if plan.sharp and plan.outside is not None:
        zz = np.where(np.isfinite(zz), sharp_heights(xx, yy, zz, plan.sharp, plan.outside,
                                                     2.0 * plan.dsm.grid.cell_m), zz)
    okz = np.isfinite(zz)
    rgb_out = np.zeros((h, w, 3), np.uint8)
    valid_out = np.zeros((h, w), bool)
    src_out = np.full((h, w), -1, np.int16)
    if not okz.any():
        return OrthoTile((r0, c0, h, w), rgb_out, valid_out, valid_out.copy(), src_out, 0, time.perf_counter() - t0)
    p = plan.to_local(np.stack([xx.ravel(), yy.ravel(), np.where(okz, zz, 0.0).ravel()], 1))
    # labels at the output cells (nearest DSM cell)
    dg = plan.dsm.grid
    lr, lc = dg.cell_of(xx, yy)
    inside = (lr >= 0) & (lr < dg.height) & (lc >= 0) & (lc < dg.width)
    lab = np.full((Hh, Ww), -1, np.int32)
    lab[inside] = plan.label[lr[inside], lc[inside]]
    lab[~okz] = -1
    # DSM window for the depth buffers: the tile grown by how far the surface's relief can hide along a ray
    zlo, zhi = plan.zrange
    reach = (zhi - zlo) * min(cfg.max_tan, 4.0) + 2 * dg.cell_m
    xb0, yb0, xb1, yb1 = g.bounds
    ra, ca = dg.cell_of(np.array([xb0 - reach, xb1 + reach]), np.array([yb1 + reach, yb0 - reach]))
    dr0, dr1 = max(int(ra[0]), 0), min(int(ra[1]) + 2, dg.height)
    dc0, dc1 = max(int(ca[0]), 0), min(int(ca[1]) + 2, dg.width)
    dsm_local = (_window_local(plan, dr0, dc0, dr1 - dr0, dc1 - dc0, plan.sharp if plan.outside is not None else ())
                 if (dr1 > dr0 and dc1 > dc0) else None)

    acc = np.zeros((Hh, Ww, 3), np.float64)
    wsum = np.zeros((Hh, Ww), np.float64)
    wmax = np.zeros((Hh, Ww), np.float64)
    src = np.full((Hh, Ww), -1, np.int16)
    box = cv2.blur
    done: set[int] = set()

    xcol, yrow = xx[0, :], yy[:, 0]
    p3 = p.reshape(Hh, Ww, 3)
    windowed = getattr(loader, "windowed_image", None)  # large images read window by window (ImageFiles)

    def source(i: int) -> NDArray | WindowedImage:
        wi = windowed(i) if windowed is not None else None
        return loader(i) if wi is None else wi

    def footprint(i: int) -> tuple[slice, slice] | None:
        """The part of the padded tile inside image i's DSM window (what it can see)."""
        wr0, wc0, wh, ww = plan.windows[i]
        if wh == 0 or ww == 0:
            return None
        xa, xb = dg.x0 + wc0 * dg.cell_m, dg.x0 + (wc0 + ww) * dg.cell_m
        ya, yb = dg.y0 - (wr0 + wh) * dg.cell_m, dg.y0 - wr0 * dg.cell_m
        cols = np.flatnonzero((xcol >= xa) & (xcol <= xb))
        rows = np.flatnonzero((yrow >= ya) & (yrow <= yb))
        if len(cols) == 0 or len(rows) == 0:
            return None
        return slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1)

    edges: dict[int, tuple[NDArray, NDArray, NDArray, NDArray]] = {}

    def add(i: int, weight_region: NDArray[np.float64] | None) -> None:
        sl_i = footprint(i)
        if sl_i is None or dsm_local is None:
            return
        cam = plan.cameras[str(plan.eo.camera[i])]
        hh_, ww_ = sl_i[0].stop - sl_i[0].start, sl_i[1].stop - sl_i[1].start
        u, v, d, tan = _project(plan.eo, plan.cameras, i, p3[sl_i].reshape(-1, 3))
        u, v, d, tan = (a.reshape(hh_, ww_) for a in (u, v, d, tan))
        # depth buffer from the DSM cells of the tile's reach that the image can see
        wr0, wc0, wh, ww = plan.windows[i]
        zr0, zr1 = max(dr0, wr0) - dr0, min(dr1, wr0 + wh) - dr0
        zc0, zc1 = max(dc0, wc0) - dc0, min(dc1, wc0 + ww) - dc0
        if zr1 - zr0 < 2 or zc1 - zc0 < 2:
            return
        dl = dsm_local[zr0:zr1, zc0:zc1]
        du, dv, dd, _ = _project(plan.eo, plan.cameras, i, dl.reshape(-1, 3))
        shp = dl.shape[:2]
        zb, zu0, zv0 = _zbuffer_for(du.reshape(shp), dv.reshape(shp), dd.reshape(shp), cam)
        tol = cfg.occlusion_tol_cells * dg.cell_m * (1.0 + np.minimum(tan, 10.0))
        frame_ok = cam.in_image(np.stack([u, v], -1)) & okz[sl_i] & (tan <= cfg.max_tan)
        vis = _visible(u, v, d, tol, zb, zu0, zv0) & frame_ok
        if cfg.occlusion_slack_px > 0:
            # cells hidden only at the buffer's resolution: visible against the farthest surface within
            # occlusion_slack_px pixels (kept for the last resort below)
            from scipy import ndimage

            zbm = ndimage.maximum_filter(zb, size=2 * cfg.occlusion_slack_px + 1, mode="nearest")
            edge = _visible(u, v, d, tol, zbm, zu0, zv0) & frame_ok & ~vis
            if edge.any():
                er, ec = np.nonzero(edge)
                edges[i] = ((er + sl_i[0].start) * Ww + ec + sl_i[1].start, u[edge], v[edge], tan[edge])
        if not vis.any():
            return
        img, wc0, wr0 = sampled_window(source(i), np.where(vis, u, np.nan), np.where(vis, v, np.nan))
        # float32 first, then the window's origin (exact): the whole image's samples bit for bit where vis (the
        # other cells get no weight)
        col = cv2.remap(img, np.where(vis, u, -10).astype(np.float32) - np.float32(wc0),
                        np.where(vis, v, -10).astype(np.float32) - np.float32(wr0),
                        cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
        if col.ndim == 2:
            col = np.repeat(col[..., None], 3, axis=2)
        col *= plan.gains[i][None, None, :]
        # a small weight wherever the image sees the cell, leaning to steep views: cells that no labelled image
        # sees at full resolution take their colour from the images that do
        pref = 1e-6 / (1.0 + np.minimum(tan, 10.0)) ** 4
        if weight_region is None:  # an image not labelled in this tile: only where nothing else gives colour
            wgt = np.where(vis & (wsum[sl_i] <= 0), pref, 0.0)
        else:
            wgt = (weight_region[sl_i] + pref) * vis
        acc[sl_i] += col * wgt[..., None]
        wsum[sl_i] += wgt
        better = wgt > wmax[sl_i]
        src[sl_i][better] = i
        wmax[sl_i] = np.maximum(wmax[sl_i], wgt)

    labelled = [int(i) for i in np.unique(lab) if i >= 0]
    k_size = (2 * fr + 1, 2 * fr + 1)
    for i in labelled:
        region = (lab == i).astype(np.float32)
        feather = box(box(region, k_size, borderType=cv2.BORDER_REPLICATE), k_size, borderType=cv2.BORDER_REPLICATE)
        add(i, feather.astype(np.float64))
        done.add(i)
    # fallback: cells with a surface that no labelled image sees at full resolution
    need = okz & (wsum <= 0)
    fallback = int(need[pad:pad + h, pad:pad + w].sum())
    if need.any():
        cands = []
        xc, yc = xx[need], yy[need]
        rr, cc_ = dg.cell_of(xc, yc)
        for i, (wr0, wc0, wh, ww) in enumerate(plan.windows):
            if i in done or wh == 0:
                continue
            hit = (rr >= wr0) & (rr < wr0 + wh) & (cc_ >= wc0) & (cc_ < wc0 + ww)
            if hit.any():
                cam = plan.cameras[str(plan.eo.camera[i])]
                d = np.linalg.norm(plan.eo.centre[i] - p.reshape(Hh, Ww, 3)[need].mean(axis=0)) / cam.focal_px
                cands.append((d, i))
        for _, i in sorted(cands):
            add(i, None)
            if not (okz & (wsum <= 0)).any():
                break
    # last resort: cells within a pixel of an occluding edge in every image (see occlusion_slack_px): their rays
    # marched through the surface, steep views first
    need = okz & (wsum <= 0)
    slack_cells = 0
    if edges and need.any():
        jac = _map_to_local_jacobian(plan, g)
        flat_need = need.ravel()
        order = sorted(edges, key=lambda i: float(np.median(edges[i][3])))
        got = np.zeros(Hh * Ww, bool)
        for i in order:
            idx, ue, ve, te = edges[i]
            keep = flat_need[idx] & ~got[idx]
            if not keep.any():
                continue
            idx, ue, ve, te = idx[keep], ue[keep], ve[keep], te[keep]
            r_, c_ = np.divmod(idx, Ww)
            clear = _rays_clear(plan, xx[r_, c_], yy[r_, c_], zz[r_, c_], p3[r_, c_], plan.eo.centre[i], jac)
            if not clear.any():
                continue
            idx, ue, ve, r_, c_ = idx[clear], ue[clear], ve[clear], r_[clear], c_[clear]
            img, wc0, wr0 = sampled_window(source(i), ue, ve)
            col = _remap_points(img, ue, ve, wc0, wr0) * plan.gains[i][None, :]
            acc[r_, c_] = col * 1e-9  # the weight of a last resort (any other image's weight wins)
            wsum[r_, c_] = 1e-9
            src[r_, c_] = i
            got[idx] = True
        slack_cells = int((got.reshape(Hh, Ww) & need)[pad:pad + h, pad:pad + w].sum())
    ok = wsum > 0
    out = np.zeros((Hh, Ww, 3), np.float64)
    out[ok] = acc[ok] / wsum[ok, None]
    sl = (slice(pad, pad + h), slice(pad, pad + w))
    rgb_out = np.clip(out[sl] + 0.5, 0, 255).astype(np.uint8)
    valid_out = ok[sl]
    src_out = np.where(valid_out, src[sl], np.where(okz[sl], -2, -1)).astype(np.int16)
    return OrthoTile((r0, c0, h, w), rgb_out, valid_out, okz[sl], src_out, fallback, time.perf_counter() - t0,
                     slack_cells)


class _OrthoTileJob:
    def __init__(self, plan: OrthoPlan, loader: ImageLoader) -> None:
        self.plan, self.loader = plan, loader

    def __call__(self, k: int) -> OrthoTile:
        return run_ortho_tile(self.plan, k, self.loader)


def assemble_ortho(plan: OrthoPlan, tiles: Iterable[OrthoTile]) -> Orthomosaic:
    """Put the tiles together."""
    H, W = plan.grid.shape
    rgb = np.zeros((H, W, 3), np.uint8)
    valid = np.zeros((H, W), bool)
    surface = np.zeros((H, W), bool)
    source = np.full((H, W), -1, np.int16)
    secs = 0.0
    fallback = slack = 0
    for t in tiles:
        r0, c0, h, w = t.window
        rgb[r0:r0 + h, c0:c0 + w] = t.rgb
        valid[r0:r0 + h, c0:c0 + w] = t.valid
        surface[r0:r0 + h, c0:c0 + w] = t.surface
        source[r0:r0 + h, c0:c0 + w] = t.source
        secs += t.seconds
        fallback += t.fallback_cells
        slack += t.slack_cells
    stats = dict(plan.stats)
    stats.update({"tiles": len(plan.tiles), "tile_seconds": secs, "fallback_cells": fallback,
                  "edge_slack_cells": slack,
                  "cells_valid": int(valid.sum()), "cells_surface": int(surface.sum()), "cells": int(valid.size),
                  "gain_min": float(plan.gains.min()), "gain_max": float(plan.gains.max())})
    return Orthomosaic(plan.grid, plan.dsm.frame, rgb, valid, surface, source, tuple(str(n) for n in plan.eo.image),
                       plan.label, plan.dsm.grid, plan.gains, plan.dsm.vertical_reference, stats)


def orthomosaic(eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera], dsm: DsmGrid, loader: ImageLoader, *,
                area: tuple[float, float, float, float] | None = None, config: OrthoConfig = OrthoConfig(),
                map_fn: Callable | None = None, buildings: list | None = None) -> Orthomosaic:
    """:func:`plan_ortho`, :func:`run_ortho_tile` for every tile through ``map_fn`` (default builtin map),
    :func:`assemble_ortho`."""
    plan = plan_ortho(eo, cameras, dsm, loader, area=area, config=config, map_fn=map_fn, buildings=buildings)
    fn = map_fn or (lambda f, items: list(map(f, items)))
    return assemble_ortho(plan, fn(_OrthoTileJob(plan, loader), list(range(len(plan.tiles)))))
