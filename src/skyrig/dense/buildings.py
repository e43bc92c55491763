"""Building blocks and façades: the data model shared by building extraction, façade texturing and 3D models.

Coordinates are in the frame of the DSM they came from (``frame``: a map CRS with its height reference, or a
local ENU frame), metres.  Polygons are counter-clockwise seen from above, without a repeated closing vertex.

Making buildings:

* :func:`extract_buildings` ``(dsm) -> list[BuildingBlock]``: from a DSM alone (ground estimate, normalised DSM,
  connected components, regularised footprints, ground / eave heights, flat or gabled roof planes - a gable's
  ridge fitted wherever it runs when the roof was measured in part only, :func:`fit_ridge_gable`);
* :func:`buildings_from_footprints` ``(footprints, dsm, heights=)``: given footprints (e.g. read from a GeoPackage
  by :func:`skyrig.pipeline.facades.read_footprint_layer`, which checks and reprojects the layer's CRS and reads
  a height attribute), heights from the DSM where it measured the roof, else from the given heights
  (:class:`FootprintHeights`: a cadastre's buildings beyond the DSM's coverage);
* :func:`surface_with_buildings`: the DSM as an occlusion surface holding those buildings too.

Texturing them: :func:`skyrig.dense.facades.texture_facades`.  Judges against a simulated scene:
:mod:`skyrig.simulate.judge_facades`.  Figures: ``bench/facades.py``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from numpy.typing import NDArray

from skyrig.dense.grid import DsmGrid, GridSpec
from skyrig.errors import SkyrigError
from skyrig.geodesy.frame import WorldFrame


@dataclass(frozen=True)
class Facade:
    """One vertical wall: the footprint edge ``index`` (vertex ``index`` -> ``index + 1``) of a building.

    Attributes
    ----------
    building
        Id of the building (:attr:`BuildingBlock.id`).
    index
        Edge number in the footprint.
    corners
        ``(4, 3)``: bottom-start, bottom-end, top-end, top-start.  Seen from outside, start is on the left, so the
        outward normal is ``(end - start) x up`` normalised.
    on_border
        The edge lies on the border of the DSM (a building cut by it): not a real wall, it gets no texture.
    outline
        ``(K, 2)`` the wall's shape inside the rectangle ``corners`` as ``(s, z)`` points (``s`` the distance from the
        start corner along the wall, ``z`` the height), counter-clockwise seen from outside; None: the whole
        rectangle.  A wall under a gable end (:meth:`BuildingBlock.facades` with ``to_roof``) reaches up to the
        roof line: its rectangle up to the apex, its outline the ground line, the eave corners and the roof's
        vertices above the edge.
    """

    building: int
    index: int
    corners: NDArray[np.float64]
    on_border: bool = False
    outline: NDArray[np.float64] | None = None

    @property
    def normal(self) -> NDArray[np.float64]:
        """Outward horizontal unit normal."""
        d = self.corners[1] - self.corners[0]
        n = np.array([d[1], -d[0], 0.0])
        return n / np.linalg.norm(n)

    @property
    def width_m(self) -> float:
        return float(np.linalg.norm((self.corners[1] - self.corners[0])[:2]))

    @property
    def height_m(self) -> float:
        return float(self.corners[3, 2] - self.corners[0, 2])


@dataclass(frozen=True)
class BuildingBlock:
    """A building as a prism with a roof.

    Attributes
    ----------
    id
        Building number.
    footprint
        ``(N, 2)`` counter-clockwise polygon (x, y).
    ground_z
        Height of the wall bottoms (terrain at the footprint).
    eave_z
        Height of the wall tops.
    roof
        Roof polygons, each ``(K, 3)``, counter-clockwise seen from above (one for a flat roof, two for a gable ...).
    source
        ``"dsm"`` (extracted) or the file the footprint came from.
    clipped
        The building is cut by the border of the DSM (the grid's edge or the void around the surveyed area): the
        footprint is its part inside the DSM.
    border_edges
        Footprint edges (numbers as :meth:`facades`) that lie on that border: not walls of the building.
    """

    id: int
    footprint: NDArray[np.float64]
    ground_z: float
    eave_z: float
    roof: tuple[NDArray[np.float64], ...] = ()
    source: str = "dsm"
    clipped: bool = False
    border_edges: tuple[int, ...] = ()

    def facades(self, to_roof: bool = False) -> list[Facade]:
        """The walls, one per footprint edge, from ``ground_z`` to ``eave_z``.

        ``to_roof``: a wall under a gable end (roof vertices above ``eave_z`` on its edge, :meth:`gable_ends`)
        reaches up to the roof line instead: its ``corners`` up to the highest of those vertices and its
        :attr:`Facade.outline` the wall polygon (ground line, eave corners, roof vertices), so that one texture
        covers the whole wall of a gabled house's end."""
        out = []
        fp = np.asarray(self.footprint, float)
        high: dict[int, list[tuple[float, float]]] = {}
        if to_roof:
            for i, tri in self.gable_ends():
                a, e = fp[i], fp[(i + 1) % len(fp)]
                s = float(np.linalg.norm(tri[2, :2] - a))
                if 0.0 < s < float(np.linalg.norm(e - a)):
                    high.setdefault(i, []).append((s, float(tri[2, 2])))
        for i in range(len(fp)):
            a, b = fp[i], fp[(i + 1) % len(fp)]
            top = self.eave_z
            outline = None
            if i in high:
                pts = sorted(set(high[i]), key=lambda q: -q[0])  # from the end back to the start
                top = max(z for _, z in pts)
                L = float(np.linalg.norm(b - a))
                outline = np.array([[0.0, self.ground_z], [L, self.ground_z], [L, self.eave_z], *pts,
                                    [0.0, self.eave_z]])
            out.append(Facade(self.id, i, np.array([[a[0], a[1], self.ground_z], [b[0], b[1], self.ground_z],
                                                    [b[0], b[1], top], [a[0], a[1], top]]),
                              i in self.border_edges, outline))
        return out


    def gable_ends(self) -> list[tuple[int, NDArray[np.float64]]]:
        """The wall triangles above the eaves at the ends of a pitched roof: ``(edge index, (3, 3) corners)``.

        A roof vertex higher than ``eave_z`` that lies on footprint edge ``i`` (in plan, within 1 cm) closes the
        gap between wall ``i``'s top (``eave_z``) and the roof: the triangle start-eave, end-eave, that vertex.
        Such a triangle can be textured with :func:`skyrig.dense.facades.texture_plane` over its bounding
        rectangle (wall ``i``'s corners at ``eave_z`` and at the vertex's height)."""
        fp = np.asarray(self.footprint, float)
        out = []
        for i in range(len(fp)):
            a, b = fp[i], fp[(i + 1) % len(fp)]
            e = b - a
            ln2 = float(e @ e)
            for poly in self.roof:
                for v in np.asarray(poly, float):
                    if v[2] <= self.eave_z + 1e-3:
                        continue
                    t = float((v[:2] - a) @ e) / max(ln2, 1e-12)
                    if 0.0 < t < 1.0 and np.linalg.norm(a + t * e - v[:2]) < 0.01:
                        tri = np.array([[a[0], a[1], self.eave_z], [b[0], b[1], self.eave_z], v])
                        if not any(j == i and np.allclose(tr[2], v, rtol=0.0, atol=1e-6) for j, tr in out):
                            out.append((i, tri))
        return out


@dataclass(frozen=True)
class FacadeTexture:
    """A rectified texture of one façade.

    Attributes
    ----------
    facade
        The wall.
    rgb
        ``(H, W, 3)`` uint8; row 0 at the top (``eave_z``, or the apex of a wall with an
        :attr:`~Facade.outline`: ``facade.corners[3, 2]``), column 0 at the start edge (``corners[0]``), texel
        centres at ``(j + 0.5) * texel_m`` along the wall and ``top - (i + 0.5) * texel_m`` in height.
    valid
        ``(H, W)`` bool: texels that got a colour from an image that sees them (inside the wall's outline).
    texel_m
        Texel size in metres.
    images
        Names of the source images, best first.
    source
        ``(H, W)`` index into ``images`` of the image each texel's colour mostly came from (-1: none), or None.
    stats
        Counts of the texturing (see :func:`skyrig.dense.facades.texture_plane`).
    """

    facade: Facade
    rgb: NDArray[np.uint8]
    valid: NDArray[np.bool_]
    texel_m: float
    images: tuple[str, ...] = ()
    source: NDArray[np.int16] | None = None
    stats: dict = field(default_factory=dict)


@dataclass(frozen=True)
class BuildingModel:
    """Buildings with their façade textures and the frame they are in."""

    frame: WorldFrame
    buildings: tuple[BuildingBlock, ...]
    textures: tuple[FacadeTexture, ...] = ()
    vertical_reference: str = ""
    metadata: dict = field(default_factory=dict)


# ----------------------------------------------------------------------------------------------- extraction
@dataclass(frozen=True)
class ExtractionConfig:
    """Options of :func:`extract_buildings` (lengths in metres of the DSM frame).

    Attributes
    ----------
    min_height_m
        Least height above the ground estimate of a building cell.
    min_area_m2
        Smallest footprint kept.
    max_building_m
        Side of the square structuring element of the ground estimate (a grey opening): larger than the widest
        building, smaller than the terrain's wavelengths.
    rect_fit
        A footprint becomes its minimum-area rectangle when the building cells fill at least this fraction of it.
    simplify_m
        Tolerance of :func:`cv2.approxPolyDP` for footprints that are not rectangles (None: one cell).
    ring_m
        Width of the ring outside the footprint whose DSM heights give the ground height (10th percentile).
    edge_cells
        Cells eroded from the footprint before the roof heights are read (mixed cells at the eaves).
    gable_gain
        A two-plane (gabled) roof is chosen when it lowers the robust height spread of the roof cells to this
        fraction of the flat roof's, with planes sloping by at least ``min_slope_deg``.
    min_slope_deg
        Least slope of a roof plane that is not flat.
    max_outside
        A building is left out as cut by the edge of the surveyed area when more than this fraction of the
        2-cell ring around it is void connected to the DSM's border (unless ``clip_border``).
    clip_border
        Keep the buildings cut by the DSM's border (its grid edge, or more than ``max_outside`` of void connected
        to the border around them) with their footprint clipped there: ``clipped=True`` and the footprint edges
        that run along the border (more than half of the points ``border_probe_m`` outside the edge lie beyond the
        grid or beyond the surveyed area, see ``survey_gap_m``) listed in ``border_edges``.  Off: such buildings are left out.
    border_probe_m
        See ``clip_border`` (None: 1.5 cells).
    ridge_gable
        A roof that is neither one level nor a rectangle's gable (a polygon footprint), and any roof next to the
        edge of the surveyed area (measured in part only: the rectangle is that of the measured part, whose middle
        need not be the ridge), gets two planes with a ridge in any direction and position where
        :func:`fit_ridge_gable` accepts them (its model-selection rule; the DSM's noise is the median of its
        ``sigma`` on the roof cells, at least ``noise_m``).  The roof polygons: the footprint cut along the ridge.
    noise_m
        See ``ridge_gable``.
    survey_gap_m
        For ``border_edges``, the surveyed area is the measured cells closed by a disc of this diameter: the void
        strips a matched DSM leaves along walls (occluded ground, eroded depth edges) are not its border.
    """

    min_height_m: float = 2.5
    min_area_m2: float = 20.0
    max_building_m: float = 40.0
    rect_fit: float = 0.85
    simplify_m: float | None = None
    ring_m: float = 2.0
    edge_cells: int = 2
    gable_gain: float = 0.5
    min_slope_deg: float = 5.0
    max_outside: float = 0.25
    clip_border: bool = False
    border_probe_m: float | None = None
    survey_gap_m: float = 4.0
    ridge_gable: bool = True
    noise_m: float = 0.05


def _fill_nearest(h: NDArray) -> NDArray[np.float32]:
    """NaN cells take the value of the nearest measured cell."""
    from scipy import ndimage

    bad = ~np.isfinite(h)
    if not bad.any():
        return np.asarray(h, np.float32)
    if bad.all():
        raise SkyrigError("the DSM has no measured cell")
    idx = ndimage.distance_transform_edt(bad, return_distances=False, return_indices=True)
    return np.asarray(h, np.float32)[tuple(idx)]


def ground_estimate(dsm: DsmGrid, max_building_m: float = 40.0) -> NDArray[np.float32]:
    """The bare ground under a DSM: a grey opening with a square of side ``max_building_m`` (removes anything
    narrower, i.e. buildings; exact on planar slopes) smoothed by a box filter of the same size.

    Holes (NaN) are filled from the nearest measured cell first."""
    import cv2

    h = _fill_nearest(dsm.height)
    k = max(3, int(round(max_building_m / dsm.grid.cell_m)) | 1)
    se = cv2.getStructuringElement(cv2.MORPH_RECT, (k, k))
    opened = cv2.morphologyEx(h, cv2.MORPH_OPEN, se, borderType=cv2.BORDER_REPLICATE)
    # the opening is a lower envelope made of flat plateaus; a box filter no wider than the element keeps it
    # under the surface on average and removes the steps
    smooth = cv2.blur(opened, (k // 2 | 1, k // 2 | 1), borderType=cv2.BORDER_REPLICATE)
    return np.minimum(smooth, h).astype(np.float32)


def _robust_plane(a: NDArray, b: NDArray, z: NDArray, iters: int = 5) -> tuple[NDArray, float]:
    """``z = p0 + p1 a + p2 b`` by iteratively reweighted least squares (Tukey weights); returns the
    coefficients and the robust spread (1.4826 MAD) of the residuals."""
    A = np.column_stack([np.ones_like(a), a, b])
    w = np.ones_like(z)
    p = np.zeros(3)
    for _ in range(iters):
        p, *_ = np.linalg.lstsq(A * w[:, None], z * w, rcond=None)
        r = z - A @ p
        s = 1.4826 * np.median(np.abs(r - np.median(r))) + 1e-6
        u = r / (4.685 * s)
        w = np.where(np.abs(u) < 1, (1 - u * u) ** 2, 0.0)
        if w.sum() < 3:
            break
    r = z - A @ p
    return p, float(1.4826 * np.median(np.abs(r - np.median(r))))


def _ccw(poly: NDArray) -> NDArray[np.float64]:
    p = np.asarray(poly, float)
    x, y = p[:, 0], p[:, 1]
    area2 = np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
    return p if area2 > 0 else p[::-1].copy()


def _cells_to_xy(grid: GridSpec, col: NDArray, row: NDArray) -> NDArray[np.float64]:
    """Fractional cell indices (cell centres at integers) to frame x, y."""
    return np.column_stack([grid.x0 + (np.asarray(col) + 0.5) * grid.cell_m,
                            grid.y0 - (np.asarray(row) + 0.5) * grid.cell_m])


def _footprint_from_mask(mask: NDArray[np.bool_], grid: GridSpec, r0: int, c0: int, cfg: ExtractionConfig,
                         measured: NDArray[np.bool_] | None = None) -> tuple[NDArray[np.float64], bool, tuple | None]:
    """Footprint polygon (frame x, y; CCW) of one component given as a mask window at (r0, c0).

    The mask is upsampled 4 x so that boundary pixel centres lie 1/8 cell inside the cells' outer edges.  The
    minimum-area rectangle is taken when the component fills ``rect_fit`` of it, counting only ``measured``
    cells of the rectangle (a DSM hole does not contradict a rectangle); its sides are then placed on the
    median of their boundary points.  Returns the polygon, whether it is a rectangle, and the rectangle
    ``(centre (2,), axis_long (2,), half_long, half_short)`` in frame units (None for polygons)."""
    import cv2

    up = 4
    big = cv2.resize(mask.astype(np.uint8), (mask.shape[1] * up, mask.shape[0] * up), interpolation=cv2.INTER_NEAREST)
    contours, _ = cv2.findContours(big, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    cont = max(contours, key=cv2.contourArea)[:, 0, :].astype(np.float64)
    cc = (cont + 0.5) / up - 0.5  # (col, row) in cell units of the window, cell centres at integers
    (ux, uy), (w, h), ang = cv2.minAreaRect(cc.astype(np.float32))
    grow = 2.0 / up / 2.0  # 1/8 cell on each side -> 1/4 cell per dimension
    w, h = w + grow, h + grow
    area_cells = float(mask.sum())
    fit = area_cells / max(w * h, 1e-9)
    if measured is not None and fit < cfg.rect_fit:
        box = cv2.boxPoints(((ux, uy), (w, h), ang))
        inside = np.zeros(mask.shape, np.uint8)
        cv2.fillPoly(inside, [np.round(box * 16).astype(np.int32)], 1, shift=4)
        inside = inside.astype(bool)
        known = inside & (measured | mask)
        fit = float((mask & inside).sum()) / max(float(known.sum()), 1.0)
    cell = grid.cell_m
    if fit >= cfg.rect_fit:
        t = np.radians(ang)
        ax_w = np.array([np.cos(t), np.sin(t)])  # along the 'w' side in (col, row)
        ax_h = np.array([-np.sin(t), np.cos(t)])
        ctr = np.array([ux, uy])
        # the enclosing rectangle touches the outermost steps of a turned wall's staircase: place each side at
        # the median of its own boundary points instead (a staircase is centred on the line it rasterises)
        a = (cc - ctr) @ ax_w
        b = (cc - ctr) @ ax_h
        sides = []
        for coord, other, half, ohalf in ((a, b, w / 2, h / 2), (-a, b, w / 2, h / 2), (b, a, h / 2, w / 2),
                                          (-b, a, h / 2, w / 2)):
            sel = (coord > half - 1.5) & (np.abs(other) < ohalf - 1.5)
            sides.append(float(np.median(coord[sel])) + 1.0 / (2 * up) if sel.sum() >= 3 else half)
        w, h = sides[0] + sides[1], sides[2] + sides[3]
        ctr = ctr + 0.5 * (sides[0] - sides[1]) * ax_w + 0.5 * (sides[2] - sides[3]) * ax_h
        pts = np.array([ctr + sx * w / 2 * ax_w + sy * h / 2 * ax_h for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
        xy = _cells_to_xy(grid, pts[:, 0] + c0, pts[:, 1] + r0)
        cxy = _cells_to_xy(grid, np.array([ctr[0] + c0]), np.array([ctr[1] + r0]))[0]
        # axes in the frame (x east, y north): row grows southwards
        long_ax = ax_w if w >= h else ax_h
        la = np.array([long_ax[0], -long_ax[1]])
        rect = (cxy, la / np.linalg.norm(la), 0.5 * max(w, h) * cell, 0.5 * min(w, h) * cell)
        return _ccw(xy), True, rect
    eps = (cfg.simplify_m / cell if cfg.simplify_m else 1.0) * up
    approx = cv2.approxPolyDP(cont.astype(np.int32).reshape(-1, 1, 2), eps, True)[:, 0, :].astype(np.float64)
    ac = (approx + 0.5) / up - 0.5
    return _ccw(_cells_to_xy(grid, ac[:, 0] + c0, ac[:, 1] + r0)), False, None


def extract_buildings(dsm: DsmGrid, *, min_height_m: float = 2.5, min_area_m2: float = 20.0,
                      max_building_m: float = 40.0, config: ExtractionConfig | None = None) -> list[BuildingBlock]:
    """Building blocks from a DSM: footprints, ground and eave heights, roof planes.

    Steps: a ground estimate (:func:`ground_estimate`, a grey opening larger than the widest building), the
    normalised DSM, cells higher than ``min_height_m`` above the ground, connected components (4-neighbours)
    of at least ``min_area_m2``; per component a footprint (the minimum-area rectangle when the cells fill at
    least ``rect_fit`` of it, else a polygon simplified by :func:`cv2.approxPolyDP`; counter-clockwise), the
    ground height (10th percentile of the DSM in a ring of ``ring_m`` around it, other buildings left out)
    and the roof: robust plane fits on the roof cells (the footprint eroded by ``edge_cells``) choose
    between a flat roof (eaves at the median roof height) and, for rectangles, a gabled roof with its ridge
    along either axis (two planes; eave and ridge heights from the planes at the walls and at the ridge);
    where that finds no gable (a polygon footprint) or the building lies at the edge of the surveyed area (its
    roof measured in part only), two planes with a ridge anywhere (:func:`fit_ridge_gable`, accepted by its
    model-selection rule; ``ExtractionConfig.ridge_gable``).

    Parameters
    ----------
    dsm
        The DSM (any frame whose x, y, z are metres: a projected map CRS or a local ENU frame).  NaN holes are
        tolerated (filled from the nearest cell for the ground estimate, left out of the height statistics).
    min_height_m, min_area_m2, max_building_m
        As :class:`ExtractionConfig` (these arguments win over ``config``'s).
    config
        The other options.

    Returns
    -------
    Buildings numbered from 0, in the DSM's frame, ``source="dsm"``.

    Raises
    ------
    SkyrigError
        On a DSM without measured cells or nonsensical options.
    """
    import cv2
    from dataclasses import replace
    from scipy import ndimage

    cfg = replace(config or ExtractionConfig(), min_height_m=min_height_m, min_area_m2=min_area_m2,
                  max_building_m=max_building_m)
    if not (cfg.min_height_m > 0 and cfg.min_area_m2 > 0 and cfg.max_building_m > 0):
        raise SkyrigError(f"building extraction: min_height_m, min_area_m2 and max_building_m must be positive, got "
                          f"{cfg.min_height_m}, {cfg.min_area_m2}, {cfg.max_building_m}")
    grid = dsm.grid
    cell = grid.cell_m
    h = np.asarray(dsm.height, np.float64)
    meas = np.isfinite(h)
    if not meas.any():
        raise SkyrigError("the DSM has no measured cell: no buildings can be extracted")
    ground = ground_estimate(dsm, cfg.max_building_m).astype(np.float64)
    hf = _fill_nearest(h).astype(np.float64)
    ndsm = hf - ground
    # measured cells only (a hole next to a wall is as likely ground as roof); small gaps closed, holes filled
    mask = ((ndsm > cfg.min_height_m) & meas).astype(np.uint8)
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    mask = ndimage.binary_fill_holes(mask).astype(np.uint8)
    # voids connected to the DSM's border are outside the surveyed area: a building touching one is cut
    vlab, _ = ndimage.label(~meas)
    edge_ids = np.unique(np.r_[vlab[0], vlab[-1], vlab[:, 0], vlab[:, -1]])
    outside = np.isin(vlab, edge_ids[edge_ids > 0])
    lab, _ = ndimage.label(mask, structure=[[0, 1, 0], [1, 1, 1], [0, 1, 0]])
    any_bld = ndimage.binary_dilation(mask.astype(bool), iterations=1)
    ring_px = max(1, int(np.ceil(cfg.ring_m / cell)))
    out: list[BuildingBlock] = []
    beyond = None
    for k, sl in enumerate(ndimage.find_objects(lab), start=1):
        if sl is None:
            continue
        comp_full = lab[sl] == k
        if comp_full.sum() * cell * cell < cfg.min_area_m2:
            continue
        pad = ring_px + 2
        r0, r1 = max(sl[0].start - pad, 0), min(sl[0].stop + pad, lab.shape[0])
        c0, c1 = max(sl[1].start - pad, 0), min(sl[1].stop + pad, lab.shape[1])
        comp = lab[r0:r1, c0:c1] == k
        cut = False
        if comp[0].any() or comp[-1].any() or comp[:, 0].any() or comp[:, -1].any():
            if r0 == 0 or c0 == 0 or r1 == lab.shape[0] or c1 == lab.shape[1]:
                if not cfg.clip_border:
                    continue  # cut by the DSM's edge: its footprint is not known
                cut = True
        edge_ring = ndimage.binary_dilation(comp, iterations=2) & ~comp
        # next to the edge of the surveyed area (or the grid's): its roof may be measured in part only
        at_border = cut or bool((edge_ring & outside[r0:r1, c0:c1]).any())
        if (edge_ring & outside[r0:r1, c0:c1]).sum() > cfg.max_outside * edge_ring.sum():
            if not cfg.clip_border:
                continue  # cut by the edge of the surveyed area
            cut = True
        hw = h[r0:r1, c0:c1]
        mw = meas[r0:r1, c0:c1]
        ring = ndimage.binary_dilation(comp, iterations=ring_px) & ~any_bld[r0:r1, c0:c1] & mw
        if ring.sum() >= 5:
            gz = float(np.percentile(hw[ring], 10))
        else:
            gz = float(np.median(ground[r0:r1, c0:c1][comp]))
        # the walls at half the eave height: a matched DSM ramps from ground to roof over a few cells, and the
        # half-height crossing of a symmetric ramp is the wall (on an exact DSM the threshold changes nothing)
        # the eaves from the cells away from the ramp (the ramp's own cells would pull the level down and the
        # walls outwards)
        core = ndimage.binary_erosion(comp, iterations=3) & mw
        core = core if core.sum() >= 10 else comp & mw
        low = float(np.percentile(hw[core], 10)) if core.sum() >= 10 else None
        if low is not None and low - gz > 2 * cfg.min_height_m:
            half = (ndimage.binary_dilation(comp, iterations=2) & mw & (hw > gz + 0.5 * (low - gz))).astype(np.uint8)
            half = cv2.morphologyEx(half, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
            half = cv2.morphologyEx(half, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
            hl_, nh = ndimage.label(ndimage.binary_fill_holes(half), structure=[[0, 1, 0], [1, 1, 1], [0, 1, 0]])
            if nh:
                sizes = np.bincount(hl_.ravel())[1:]
                big = hl_ == (1 + int(np.argmax(sizes)))
                if big.sum() >= 0.5 * comp.sum():
                    comp = big
        foot, is_rect, rect = _footprint_from_mask(comp, grid, r0, c0, cfg, mw)
        if cfg.clip_border:
            if beyond is None:
                beyond = _beyond_survey(meas, cell, cfg.survey_gap_m)
            bw = np.pad(beyond, 3, constant_values=True)[r0:r1 + 6, c0:c1 + 6]
            if (ndimage.binary_dilation(np.pad(comp, 3), iterations=3) & bw).any():
                # cut by the border: a polygon, or a rectangle reaching beyond it, is replaced by the rectangle of
                # its real walls (oriented by them alone: the cut is no wall), clipped there; failing that a
                # rectangle reaching beyond is clipped as it is (a wall merely next to the border stays as it is)
                cut_rect = is_rect and _beyond_fraction(foot, grid, beyond) > 0.03
                got_c = _clipped_rectangle(comp, grid, r0, c0, beyond, cfg, mw) if cut_rect or not is_rect else None
                if got_c is not None:
                    foot, rect = got_c
                    is_rect = False
                elif _beyond_fraction(foot, grid, beyond) > 0.03:
                    clipped_fp = _clip_to_survey(foot, comp, grid, r0, c0, beyond)
                    if clipped_fp is not None:
                        foot, is_rect = clipped_fp, False
        inner = ndimage.binary_erosion(comp, iterations=cfg.edge_cells) & mw
        if inner.sum() < 6:
            inner = comp & mw
        if inner.sum() < 3:
            continue
        rr, cc = np.nonzero(inner)
        xy = _cells_to_xy(grid, cc + c0, rr + r0)
        z = hw[inner]
        zf = float(np.median(z))
        flat_spread = float(1.4826 * np.median(np.abs(z - zf)))
        eave, roof = zf, (np.column_stack([foot, np.full(len(foot), zf)]),)
        got = None
        if rect is not None and len(z) >= 12:
            got = _gable(xy, z, rect, flat_spread, cfg)
            if got is not None:
                eave, roof = got
                if not is_rect:  # a clipped rectangle: the roof planes clipped with the footprint
                    roof = _clip_roofs(roof, foot)
        if cfg.ridge_gable and (got is None or at_border):
            # not a rectangle's gable (a polygon), or a roof measured in part only (at the survey's border the
            # rectangle is that of the measured part, and its middle need not be the ridge): a ridge anywhere, if
            # the DSM's heights choose it (fit_ridge_gable's rule; the noise: the DSM's predicted precision on
            # these cells)
            sg = np.asarray(dsm.sigma, np.float64)[r0:r1, c0:c1][inner] if dsm.sigma is not None else None
            noise = float(np.nanmedian(sg)) if sg is not None and np.isfinite(sg).any() else cfg.noise_m
            noise = max(noise, cfg.noise_m)
            # heights within the noise of one level are a flat roof (a gable's slopes spread them more): not tried
            fit = (fit_ridge_gable(xy, z, cell_m=cell, noise_m=noise, gain=cfg.gable_gain,
                                   min_slope_deg=cfg.min_slope_deg) if flat_spread > noise else None)
            # at the border, a rectangle's gable is replaced only by a ridge that fits better: the two models have
            # as many parameters (two planes each; the rectangle's fixes the ridge at its middle, the ridge fit
            # ties the planes to a shared ridge), so the smaller robust spread (about the roof drawn) chooses
            if fit is not None and fit.accepted and (got is None or fit.spread < _roof_spread(roof, xy, z)):
                ridged = _ridge_roof(fit, foot)
                if ridged is not None:
                    eave, roof = ridged
        if eave - gz < 0.5 * cfg.min_height_m:
            continue
        border: tuple[int, ...] = ()
        if cfg.clip_border:
            if beyond is None:
                beyond = _beyond_survey(meas, cell, cfg.survey_gap_m)
            border = _border_edges(foot, grid, beyond, cfg.border_probe_m or 1.5 * cell)
            cut = cut or bool(border)
        out.append(BuildingBlock(len(out), foot, gz, float(eave), roof, "dsm", cut, border))
    return out


def _clipped_rectangle(comp: NDArray[np.bool_], grid: GridSpec, r0: int, c0: int, beyond: NDArray[np.bool_],
                       cfg: ExtractionConfig, measured: NDArray[np.bool_]) -> tuple[NDArray[np.float64], tuple] | None:
    """Footprint of a component cut by the DSM's border: the rectangle of its real walls, clipped at the border.

    The contour points away from the border (``beyond`` and the grid's outside, dilated by 2 cells) are the real
    walls: their dominant direction (length-weighted mean of 4 x the direction of the contour's straight runs)
    orients the rectangle, each side lies on the median of its real points (a side without any lies beyond the
    border); the rectangle is then intersected with the surveyed area (the window's cells not ``beyond``, inside
    the grid).  Returns the polygon (frame x, y; CCW) and the unclipped rectangle as :func:`_footprint_from_mask`,
    or None when the component does not fill ``rect_fit`` of the clipped rectangle or has too few real points."""
    import cv2
    from scipy import ndimage

    up, p = 4, 3
    H, W = comp.shape
    bp = np.pad(beyond, p, constant_values=True)[r0:r0 + H + 2 * p, c0:c0 + W + 2 * p]
    near = ndimage.binary_dilation(bp, iterations=2)
    big = cv2.resize(comp.astype(np.uint8), (W * up, H * up), interpolation=cv2.INTER_NEAREST)
    contours, _ = cv2.findContours(big, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return None
    cont = max(contours, key=cv2.contourArea)[:, 0, :].astype(np.float64)
    cc = (cont + 0.5) / up - 0.5
    ic = np.clip(np.round(cc).astype(int) + p, 0, [W + 2 * p - 1, H + 2 * p - 1])
    real = ~near[ic[:, 1], ic[:, 0]]
    if real.sum() < 12:
        return None
    # dominant direction from the straight runs of the real contour
    apx = cv2.approxPolyDP(cont.astype(np.int32).reshape(-1, 1, 2), float(up), True)[:, 0, :].astype(np.float64)
    ac = (apx + 0.5) / up - 0.5
    seg = np.roll(ac, -1, axis=0) - ac
    mids = ac + 0.5 * seg
    im = np.clip(np.round(mids).astype(int) + p, 0, [W + 2 * p - 1, H + 2 * p - 1])
    keep = ~near[im[:, 1], im[:, 0]]
    ln = np.linalg.norm(seg, axis=1)
    if not keep.any() or ln[keep].sum() < 6:
        return None
    th = np.arctan2(seg[keep, 1], seg[keep, 0])
    t = 0.25 * np.arctan2(np.sum(ln[keep] * np.sin(4 * th)), np.sum(ln[keep] * np.cos(4 * th)))
    # refined on the real contour points themselves: the turn that stacks them most tightly on lines along both
    # axes (the straight runs' directions follow the staircase of a turned wall and its cut ends by degrees)
    t = _sharpest_axes(cc[real], t)
    ax_w = np.array([np.cos(t), np.sin(t)])
    ax_h = np.array([-np.sin(t), np.cos(t)])
    a, b = cc @ ax_w, cc @ ax_h
    lim = []
    for coord, other, sign in ((a, b, 1), (a, b, -1), (b, a, 1), (b, a, -1)):
        x = sign * coord
        sel = real & (x > x.max() - 1.5) & (other > other.min() + 1.5) & (other < other.max() - 1.5)
        lim.append(sign * (float(np.median(x[sel])) + 1.0 / (2 * up)) if sel.sum() >= 3 else sign * (x.max() + 3.0))
    a1, a0, b1, b0 = lim
    if not (a1 - a0 > 1 and b1 - b0 > 1):
        return None
    pts = np.array([sa * ax_w + sb * ax_h for sa, sb in ((a0, b0), (a1, b0), (a1, b1), (a0, b1))])
    xy = _clip_cells(pts, comp, bp, p)
    if xy is None:
        return None
    # fill: the component's cells against the clipped rectangle's measured cells
    inside = np.zeros(comp.shape, np.uint8)
    cv2.fillPoly(inside, [np.round(xy * 16).astype(np.int32)], 1, shift=4)
    inside = inside.astype(bool)
    fit = float((comp & inside).sum()) / max(float((inside & (measured | comp)).sum()), 1.0)
    if fit < cfg.rect_fit:
        return None
    foot = _ccw(_cells_to_xy(grid, xy[:, 0] + c0, xy[:, 1] + r0))
    w, h = a1 - a0, b1 - b0
    cw = 0.5 * (a0 + a1) * ax_w + 0.5 * (b0 + b1) * ax_h
    cxy = _cells_to_xy(grid, np.array([cw[0] + c0]), np.array([cw[1] + r0]))[0]
    long_ax = ax_w if w >= h else ax_h
    la = np.array([long_ax[0], -long_ax[1]])
    cell = grid.cell_m
    return foot, (cxy, la / np.linalg.norm(la), 0.5 * max(w, h) * cell, 0.5 * min(w, h) * cell)


def _sharpest_axes(pts: NDArray, t0: float, span_deg: float = 15.0, step_deg: float = 0.25, bin_cells: float = 1.0
                   ) -> float:
    """The direction (radians, within ``span_deg`` of ``t0``) of the axes along which the boundary points ``pts``
    ``(N, 2)`` (cell units) of a rectangle's walls are most concentrated: the sum of squared counts of their
    coordinates along both axes in bins of ``bin_cells`` (two bin phases), largest when every wall's points fall
    on one line (a rectangle's sides, each a tight peak; a bin of one cell holds the whole staircase of a turned
    wall, a narrower one would favour the axis-parallel runs of its steps); ties keep the angle nearest ``t0``."""
    best, best_t = -1.0, t0
    for dt in np.radians(np.arange(-span_deg, span_deg + 1e-9, step_deg)):
        t = t0 + dt
        sc = 0.0
        for ax in (np.array([np.cos(t), np.sin(t)]), np.array([-np.sin(t), np.cos(t)])):
            x = pts @ ax
            x = (x - x.min()) / bin_cells
            for off in (0.0, 0.5):
                h = np.bincount(np.floor(x + off).astype(np.int64)).astype(np.float64)
                sc += float(h @ h)
        if sc > best + 1e-9 or (abs(sc - best) <= 1e-9 and abs(dt) < abs(best_t - t0)):
            best, best_t = sc, t
    return float(best_t)


def _clip_cells(pts: NDArray, comp: NDArray[np.bool_], bp: NDArray[np.bool_], p: int) -> NDArray[np.float64] | None:
    """Polygon ``pts`` (window cell units, centres at integers) intersected with the surveyed area of the window
    (``bp``: beyond-the-survey mask padded by ``p``; the piece holding the component's centre)."""
    import cv2
    import shapely

    up = 4
    Hp, Wp = bp.shape
    surv = cv2.resize((~bp).astype(np.uint8), (Wp * up, Hp * up), interpolation=cv2.INTER_NEAREST)
    sc, _ = cv2.findContours(surv, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    rr, cc_ = np.nonzero(comp)
    ctr = shapely.Point(float(cc_.mean()), float(rr.mean()))
    best = None
    for s_ in sc:
        if len(s_) < 4:
            continue
        q = cv2.approxPolyDP(s_, float(up), True)[:, 0, :].astype(np.float64)  # the staircase of an oblique border
        if len(q) < 3:
            continue
        # pixel centres of the upsampled boundary lie 1/8 cell inside the cells' outer edges
        poly = shapely.Polygon((q + 0.5) / up - 0.5 - p).buffer(1.0 / (2 * up), join_style="mitre")
        if poly.contains(ctr) or poly.distance(ctr) < 1.0:
            best = poly
            break
    if best is None:
        return None
    clip = shapely.Polygon(np.asarray(pts, float)).buffer(0).intersection(best)
    if clip.geom_type == "MultiPolygon":
        clip = max(clip.geoms, key=lambda g: g.area)
    if clip.geom_type != "Polygon" or clip.is_empty or clip.area < 4:
        return None
    return np.asarray(shapely.simplify(clip, 0.05).exterior.coords, float)[:-1]


def _beyond_fraction(foot: NDArray, grid: GridSpec, beyond: NDArray[np.bool_]) -> float:
    """Fraction of a footprint's area (sampled every 1/2 cell) beyond the grid or the surveyed area."""
    fp = np.asarray(foot, float)
    lo, hi = fp.min(axis=0), fp.max(axis=0)
    step = 0.5 * grid.cell_m
    X, Y = np.meshgrid(np.arange(lo[0], hi[0], step) + 0.25 * step, np.arange(lo[1], hi[1], step) + 0.25 * step)
    import shapely

    pts = np.column_stack([X.ravel(), Y.ravel()])
    pts = pts[shapely.contains_xy(shapely.Polygon(fp), pts[:, 0], pts[:, 1])]
    if not len(pts):
        return 0.0
    col = np.floor((pts[:, 0] - grid.x0) / grid.cell_m).astype(int)
    row = np.floor((grid.y0 - pts[:, 1]) / grid.cell_m).astype(int)
    off = (col < 0) | (row < 0) | (col >= grid.width) | (row >= grid.height)
    b = off.copy()
    b[~off] = beyond[row[~off], col[~off]]
    return float(b.mean())


def _clip_to_survey(foot: NDArray, comp: NDArray[np.bool_], grid: GridSpec, r0: int, c0: int,
                    beyond: NDArray[np.bool_]) -> NDArray[np.float64] | None:
    """A footprint (frame x, y) clipped at the border of the surveyed area around its component."""
    p = 3
    H, W = comp.shape
    bp = np.pad(beyond, p, constant_values=True)[r0:r0 + H + 2 * p, c0:c0 + W + 2 * p]
    fp = np.asarray(foot, float)
    pts = np.column_stack([(fp[:, 0] - grid.x0) / grid.cell_m - 0.5 - c0, (grid.y0 - fp[:, 1]) / grid.cell_m - 0.5 - r0])
    xy = _clip_cells(pts, comp, bp, p)
    return None if xy is None else _ccw(_cells_to_xy(grid, xy[:, 0] + c0, xy[:, 1] + r0))


def _clip_roofs(roof: tuple[NDArray, ...], foot: NDArray) -> tuple[NDArray[np.float64], ...]:
    """Roof polygons (planes) cut to a footprint in plan; heights from each polygon's plane."""
    import shapely

    fp = shapely.Polygon(np.asarray(foot, float))
    out = []
    for poly in roof:
        P = np.asarray(poly, float)
        coef, *_ = np.linalg.lstsq(np.c_[P[:, :2], np.ones(len(P))], P[:, 2], rcond=None)
        g = shapely.Polygon(P[:, :2]).intersection(fp)
        parts = list(g.geoms) if hasattr(g, "geoms") else [g]
        for part in parts:
            if part.geom_type != "Polygon" or part.area < 0.5:
                continue
            xy = np.asarray(part.exterior.coords, float)[:-1]
            out.append(_ccw3(np.c_[xy, xy @ coef[:2] + coef[2]]))
    return tuple(out) if out else (np.column_stack([foot, np.full(len(foot), float(np.max(roof[0][:, 2])))]),)


def _beyond_survey(meas: NDArray[np.bool_], cell_m: float, gap_m: float) -> NDArray[np.bool_]:
    """Cells beyond the surveyed area: void connected to the grid's edge once the measured area is closed by a
    disc of diameter ``gap_m`` (the strips of void a matched DSM leaves along walls - occluded ground, eroded depth
    edges - are not the survey's border)."""
    import cv2
    from scipy import ndimage

    k = max(3, int(round(gap_m / cell_m)) | 1)
    se = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
    pad = k
    m = np.pad(meas.astype(np.uint8), pad, constant_values=0)
    closed = cv2.morphologyEx(m, cv2.MORPH_CLOSE, se)[pad:-pad, pad:-pad].astype(bool) | meas
    vlab, _ = ndimage.label(~closed)
    ids = np.unique(np.r_[vlab[0], vlab[-1], vlab[:, 0], vlab[:, -1]])
    return np.isin(vlab, ids[ids > 0])


def _border_edges(foot: NDArray, grid: GridSpec, outside: NDArray[np.bool_], probe_m: float) -> tuple[int, ...]:
    """Footprint edges that run along the DSM's border: more than half of the points ``probe_m`` outside the edge
    (every 1/2 cell along its middle 80 %) lie beyond the grid or in void connected to the grid's edge."""
    fp = np.asarray(foot, float)
    out = []
    for i in range(len(fp)):
        a, b = fp[i], fp[(i + 1) % len(fp)]
        d = b - a
        L = float(np.linalg.norm(d))
        if L <= 0:
            continue
        n = np.array([d[1], -d[0]]) / L
        s = np.linspace(0.1, 0.9, max(int(2 * L / grid.cell_m), 3))
        q = a + s[:, None] * d + probe_m * n
        col = np.floor((q[:, 0] - grid.x0) / grid.cell_m).astype(int)
        row = np.floor((grid.y0 - q[:, 1]) / grid.cell_m).astype(int)
        off = (col < 0) | (row < 0) | (col >= grid.width) | (row >= grid.height)
        beyond = off.copy()
        beyond[~off] = outside[row[~off], col[~off]]
        if beyond.mean() > 0.5:
            out.append(i)
    return tuple(out)


def _gable(xy: NDArray, z: NDArray, rect: tuple, flat_spread: float, cfg: ExtractionConfig
           ) -> tuple[float, tuple[NDArray[np.float64], ...]] | None:
    """A gabled roof over a rectangle, if two planes explain the roof cells much better than one level."""
    ctr, la, hl, hs = rect
    lb = np.array([-la[1], la[0]])
    best = None
    for axis, half_ridge, half_across in ((la, hl, hs), (lb, hs, hl)):
        across = np.array([-axis[1], axis[0]])
        a = (xy - ctr) @ axis
        b = (xy - ctr) @ across
        planes, spreads, ok = [], [], True
        for side in (b >= 0, b < 0):
            if side.sum() < 6:
                ok = False
                break
            p, s = _robust_plane(a[side], b[side], z[side])
            planes.append(p)
            spreads.append(s)
        if not ok:
            continue
        # both planes slope down away from the ridge, by a similar amount
        s_pos, s_neg = planes[0][2], planes[1][2]
        slope = np.degrees(np.arctan(0.5 * (abs(s_pos) + abs(s_neg))))
        if not (s_pos < 0 < s_neg and slope >= cfg.min_slope_deg):
            continue
        spread = float(np.sqrt(0.5 * (spreads[0] ** 2 + spreads[1] ** 2)))
        if best is None or spread < best[0]:
            best = (spread, axis, across, half_ridge, half_across, planes)
    if best is None or best[0] > cfg.gable_gain * flat_spread:
        return None
    _, axis, across, hr, ha, (pp, pn) = best
    eave = 0.5 * ((pp[0] + pp[2] * ha) + (pn[0] - pn[2] * ha))
    ridge = 0.5 * (pp[0] + pn[0])
    if ridge <= eave:
        return None
    c3 = lambda s_a, s_b, zz: np.r_[ctr + s_a * hr * axis + s_b * ha * across, zz]  # noqa: E731
    pos = _ccw3(np.array([c3(-1, 0, ridge), c3(1, 0, ridge), c3(1, 1, eave), c3(-1, 1, eave)]))
    neg = _ccw3(np.array([c3(-1, -1, eave), c3(1, -1, eave), c3(1, 0, ridge), c3(-1, 0, ridge)]))
    return float(eave), (pos, neg)


@dataclass(frozen=True)
class RidgeGable:
    """Two roof planes sharing a ridge line (:func:`fit_ridge_gable`), in the plan frame of the fitted points.

    With ``t = direction`` along the ridge and ``n = (-t_y, t_x)`` across it, a point ``p`` has ``u = (p - origin) . n``
    and ``v = (p - origin) . t``; the roof is ``ridge_z + ridge_slope v + slopes[0] u`` where ``u < 0`` and
    ``ridge_z + ridge_slope v + slopes[1] u`` where ``u > 0`` (a gable: ``slopes[0] > 0 > slopes[1]``, the lower
    envelope of the two planes).

    Attributes
    ----------
    origin, direction
        A point of the ridge (plan) and the unit vector along it.
    ridge_z, ridge_slope
        The ridge's height at ``origin`` and its rise per metre along ``direction``.
    slopes
        Rise per metre along ``n`` of the plane on the ``u < 0`` side and on the ``u > 0`` side.
    spread, spread_flat, spread_plane
        Robust spread (1.4826 x median absolute residual) of the roof heights about the two planes, about their
        median (one level) and about one robustly fitted plane.
    noise_m
        The DSM noise the fit was judged against.
    cells
        Measured cells on either side (``u < 0``, ``u > 0``) within 3 spreads of their plane.
    widths
        Extent across the ridge (metres) of those cells on either side.
    accepted
        Whether the model-selection rule of :func:`fit_ridge_gable` chose the two planes.
    """

    origin: NDArray[np.float64]
    direction: NDArray[np.float64]
    ridge_z: float
    ridge_slope: float
    slopes: tuple[float, float]
    spread: float
    spread_flat: float
    spread_plane: float
    noise_m: float
    cells: tuple[int, int]
    widths: tuple[float, float]
    accepted: bool

    @property
    def normal(self) -> NDArray[np.float64]:
        return np.array([-self.direction[1], self.direction[0]])

    def planes(self) -> NDArray[np.float64]:
        """``(2, 3)`` coefficients ``(a, b, c)`` of ``z = a x + b y + c`` of the ``u < 0`` and ``u > 0`` planes."""
        t, n, o = np.asarray(self.direction, float), self.normal, np.asarray(self.origin, float)
        out = []
        for s in self.slopes:
            g = self.ridge_slope * t + s * n
            out.append([g[0], g[1], self.ridge_z - float(g @ o)])
        return np.array(out)

    def height(self, xy: NDArray) -> NDArray[np.float64]:
        """The roof height at plan points ``(N, 2)``."""
        u = (np.asarray(xy, float) - self.origin) @ self.normal
        v = (np.asarray(xy, float) - self.origin) @ self.direction
        return self.ridge_z + self.ridge_slope * v + np.where(u < 0, self.slopes[0], self.slopes[1]) * u


def fit_ridge_gable(xy: NDArray, z: NDArray, *, cell_m: float, noise_m: float, gain: float = 0.5,
                    min_slope_deg: float = 5.0, min_side_cells: int = 20, min_side_width_m: float = 1.0,
                    max_noise_ratio: float = 3.0, step_deg: float = 2.0) -> RidgeGable | None:
    """Two roof planes with a shared ridge fitted to measured roof heights, wherever the ridge runs and whatever
    part of the roof was measured (a house cut by the survey's border, a strip across its ridge).

    The fit: for ridge directions every ``step_deg`` and ridge positions every cell across the measured points
    (leaving ``min_side_cells`` on either side), the linear least-squares fit of ``z = c + g v + a_lo min(u, 0) +
    a_hi max(u, 0)`` (``u`` across the ridge from that position, ``v`` along it; up to 800 points) scored by the
    median absolute residual; from the best, a robust fit of all six parameters (direction, position, ``c, g,
    a_lo, a_hi``; :func:`scipy.optimize.least_squares`, soft-L1 loss at the scale ``noise_m``).

    Model selection - the two planes are ``accepted`` only when all of these hold:

    * both planes slope down away from the ridge by at least ``min_slope_deg`` (a gable, not a step or a valley);
    * each side has at least ``min_side_cells`` measured cells within 3 spreads of its plane, spread over at least
      ``min_side_width_m`` across the ridge (each plane's slope is measured, not extrapolated from a sliver);
    * the two planes' robust spread is at most ``gain`` times that of the better of one level and one fitted plane
      (two more parameters must explain much more than noise: the existing flat-versus-gable rule of
      :func:`extract_buildings`);
    * and at most ``max_noise_ratio`` times the DSM's noise ``noise_m`` (the surface *is* the two planes, to the
      DSM's precision: a tree crown or a complex roof is better fitted by two planes than by one without being a
      gable).

    Returns the fit (``accepted`` says whether it passed), or None with too few points to try."""
    from scipy.optimize import least_squares

    P = np.asarray(xy, float)
    z = np.asarray(z, float)
    ok = np.isfinite(z) & np.all(np.isfinite(P), axis=1)
    P, z = P[ok], z[ok]
    if len(z) < 2 * min_side_cells + 4:
        return None
    noise = max(float(noise_m), 0.01)
    m = np.median(P, axis=0)
    Q = P - m
    zf = float(np.median(z))
    s_flat = float(1.4826 * np.median(np.abs(z - zf)))
    _, s_plane = _robust_plane(Q[:, 0], Q[:, 1], z)
    sub = np.arange(0, len(z), max(1, len(z) // 800))
    Qs, zs = Q[sub], z[sub]
    k_side = max(1, int(round(min_side_cells * len(sub) / len(z))))
    best = (np.inf, None)
    for th in np.radians(np.arange(0.0, 180.0, step_deg)):
        t = np.array([np.cos(th), np.sin(th)])
        n = np.array([-t[1], t[0]])
        u, v = Qs @ n, Qs @ t
        us = np.sort(u)
        if len(us) <= 2 * k_side:
            continue
        u0s = np.arange(us[k_side], us[-k_side - 1], cell_m)
        if not len(u0s):
            continue
        d = u[None, :] - u0s[:, None]
        A = np.stack([np.ones_like(d), np.broadcast_to(v, d.shape), np.minimum(d, 0), np.maximum(d, 0)], axis=2)
        At = A.transpose(0, 2, 1)
        coef = np.linalg.solve(At @ A + 1e-9 * np.eye(4), (At @ zs)[..., None])[..., 0]
        r = zs[None, :] - (A @ coef[..., None])[..., 0]
        score = np.median(np.abs(r), axis=1)
        j = int(np.argmin(score))
        if score[j] < best[0]:
            best = (float(score[j]), (th, float(u0s[j]), *coef[j]))
    if best[1] is None:
        return None

    def resid(p):
        th, u0, c, g, alo, ahi = p
        t = np.array([np.cos(th), np.sin(th)])
        n = np.array([-t[1], t[0]])
        d = Q @ n - u0
        return z - (c + g * (Q @ t) + alo * np.minimum(d, 0) + ahi * np.maximum(d, 0))

    sol = least_squares(resid, np.array(best[1], float), loss="soft_l1", f_scale=noise, x_scale="jac")
    # then with a loss that all but ignores cells far off the planes (a matched DSM rounds the ridge off and
    # lowers the cells next to it: they would pull the ridge down and flatten both planes)
    r = resid(sol.x)
    s1 = max(float(1.4826 * np.median(np.abs(r))), 0.25 * noise)
    sol = least_squares(resid, sol.x, loss="cauchy", f_scale=s1, x_scale="jac")
    th, u0, c, g, alo, ahi = sol.x
    r = resid(sol.x)
    spread = float(1.4826 * np.median(np.abs(r)))
    t = np.array([np.cos(th), np.sin(th)])
    n = np.array([-t[1], t[0]])
    d = Q @ n - u0
    good = np.abs(r) <= 3 * max(spread, 1e-6)
    cells, widths = [], []
    for side in (d < 0, d > 0):
        s = side & good
        cells.append(int(s.sum()))
        widths.append(float(np.ptp(d[s])) if s.any() else 0.0)
    tmin = np.tan(np.radians(min_slope_deg))
    accepted = bool(alo >= tmin and ahi <= -tmin and min(cells) >= min_side_cells
                    and min(widths) >= min_side_width_m and spread <= gain * min(s_flat, s_plane)
                    and spread <= max_noise_ratio * noise)
    return RidgeGable(m + u0 * n, t, float(c), float(g), (float(alo), float(ahi)), spread, s_flat, float(s_plane),
                      noise, (cells[0], cells[1]), (widths[0], widths[1]), accepted)


def _roof_spread(roof: tuple[NDArray, ...], xy: NDArray, z: NDArray) -> float:
    """Robust spread (1.4826 x median absolute residual) of heights ``z`` at ``xy`` about a roof's planes (their
    lower envelope)."""
    env = np.full(len(z), np.inf)
    for poly in roof:
        P = np.asarray(poly, float)
        coef, *_ = np.linalg.lstsq(np.c_[P[:, :2], np.ones(len(P))], P[:, 2], rcond=None)
        env = np.minimum(env, xy @ coef[:2] + coef[2])
    return float(1.4826 * np.median(np.abs(z - env)))


def _ridge_roof(fit: RidgeGable, foot: NDArray) -> tuple[float, tuple[NDArray[np.float64], ...]] | None:
    """Eave height and roof polygons of a ridge-gable fit over a footprint: the footprint cut along the ridge, each
    part at its plane's heights; the eaves are the planes' heights at the footprint's farthest points across the
    ridge on either side (at the footprint's middle along it), averaged.  None when the ridge misses the footprint
    or is not above the eaves."""
    import shapely

    fp = np.asarray(foot, float)
    poly = shapely.Polygon(fp)
    if not poly.is_valid:
        poly = poly.buffer(0)
    t, n, o = np.asarray(fit.direction, float), fit.normal, np.asarray(fit.origin, float)
    u, v = (fp - o) @ n, (fp - o) @ t
    if not (u.min() < 0 < u.max()):
        return None
    big = 2.0 * float(np.ptp(u) + np.ptp(v)) + 10.0
    vm = 0.5 * (v.min() + v.max())
    planes = fit.planes()
    out = []
    for k, sgn in enumerate((-1.0, 1.0)):
        half = shapely.Polygon([o + (vm - big) * t, o + (vm + big) * t, o + (vm + big) * t + sgn * big * n,
                                o + (vm - big) * t + sgn * big * n])
        g = poly.intersection(half)
        for part in (list(g.geoms) if hasattr(g, "geoms") else [g]):
            if part.geom_type != "Polygon" or part.area < 0.5:
                continue
            xy = np.asarray(part.exterior.coords, float)[:-1]
            out.append(_ccw3(np.c_[xy, xy @ planes[k, :2] + planes[k, 2]]))
    if not out:
        return None
    mid = o + vm * t
    eave = 0.5 * (float(fit.height((mid + u.min() * n)[None])[0]) + float(fit.height((mid + u.max() * n)[None])[0]))
    if float(fit.height(mid[None])[0]) <= eave:
        return None
    return eave, tuple(out)


def _ccw3(p: NDArray) -> NDArray[np.float64]:
    x, y = p[:, 0], p[:, 1]
    return p if np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) > 0 else p[::-1].copy()


def _offset_plane(dsm: DsmGrid, other: DsmGrid, min_cells: int = 500) -> NDArray[np.float64] | None:
    """``other - dsm`` as a plane ``c0 + c1 (x - xm) + c2 (y - ym)`` (``(c0, c1, c2, xm, ym)``), fitted robustly
    (Tukey weights) over the cells both measured (``dsm``'s measured, not filled, cell centres; ``other``'s nearest
    cell), or None with fewer than ``min_cells`` such cells."""
    meas = np.isfinite(np.asarray(dsm.height)) & ~np.asarray(dsm.filled, bool)
    r, c = np.nonzero(meas)
    if len(r) > 200_000:  # a regular subsample is plenty for three parameters
        k = np.arange(0, len(r), len(r) // 200_000 + 1)
        r, c = r[k], c[k]
    g = dsm.grid
    x = g.x0 + (c + 0.5) * g.cell_m
    y = g.y0 - (r + 0.5) * g.cell_m
    orow, ocol = other.grid.cell_of(x, y)
    ok = (orow >= 0) & (ocol >= 0) & (orow < other.grid.height) & (ocol < other.grid.width)
    z = np.full(len(x), np.nan)
    z[ok] = np.asarray(other.height, float)[orow[ok], ocol[ok]] - np.asarray(dsm.height, float)[r[ok], c[ok]]
    m = np.isfinite(z)
    if m.sum() < min_cells:
        return None
    x, y, z = x[m], y[m], z[m]
    xm, ym = float(x.mean()), float(y.mean())
    A = np.column_stack([np.ones_like(x), x - xm, y - ym])
    med = float(np.median(z))
    sc = max(1.4826 * float(np.median(np.abs(z - med))), 0.02)
    u = (z - med) / (4.685 * sc)
    w = np.where(np.abs(u) < 1, (1 - u * u) ** 2, 0.0)
    coef = tukey_irls(A, z, w, min_weight=min_cells // 2, sigma_floor=0.02, count_nonzero=True)
    return None if coef is None else np.r_[coef, xm, ym]


def tukey_irls(A: np.ndarray, z: np.ndarray, w: np.ndarray, *, min_weight: float, sigma_floor: float,
               count_nonzero: bool = False, iterations: int = 8) -> np.ndarray | None:
    """Robust linear fit ``A coef ~ z`` by iteratively reweighted least squares with Tukey's biweight (c = 4.685
    robust sigmas, the sigma from the median absolute residual of the weighted observations, at least
    ``sigma_floor``), from the start weights ``w``; None when the weights' sum (or, with ``count_nonzero``, the
    number of non-zero weights) falls below ``min_weight``."""
    coef = None
    for _ in range(iterations):
        if ((w > 0).sum() if count_nonzero else w.sum()) < min_weight:
            return None
        sw = np.sqrt(w)
        coef, *_ = np.linalg.lstsq(A * sw[:, None], z * sw, rcond=None)
        res = z - A @ coef
        sc = max(1.4826 * float(np.median(np.abs(res[w > 0]))), sigma_floor)
        u = res / (4.685 * sc)
        w = np.where(np.abs(u) < 1, (1 - u * u) ** 2, 0.0)
    return coef


def extend_dsm(dsm: DsmGrid, others: Sequence[DsmGrid], *, gap_m: float = 4.0, align: bool = True) -> DsmGrid:
    """A DSM extended beyond its surveyed area by other DSMs of the same frame, for building extraction.

    A DSM matched from the nadir images covers their stereo overlap; the obliques of a penta rig see a wide ring
    around it, and a DSM matched from pairs of obliques of one viewing direction (``skyrig dsm --heads left`` ...)
    reaches there.  The result has ``dsm``'s cell size and grid alignment and covers every DSM's extent; a cell
    keeps ``dsm``'s values where ``dsm`` surveyed it (its holes - occluded ground, eroded depth edges - stay holes:
    the other DSMs, seen from one side, smear walls over them) and takes, beyond ``dsm``'s surveyed area (void
    connected to its border once the measured cells are closed by a disc of ``gap_m``), the median of the other
    DSMs' heights at the cell centre (nearest cell; their ``support`` summed, ``sigma`` and ``spread`` the
    largest).  ``metadata["extended_by"]`` counts the cells taken from the others.

    With ``align`` each other DSM is first brought onto ``dsm``'s heights: DSMs matched from different heads carry
    their own height bias (a head's boresight or interior orientation error; on the demo town the left / right
    obliques' DSMs sit 0.13 m below / above the nadir DSM), and a building's walls, ground and foot beyond the
    nadir area would inherit it.  The offset is a plane (a constant and a tilt) fitted robustly to ``other - dsm``
    over the cells both measured (:func:`_offset_plane`; at least 500 cells, else the DSM is taken as it is);
    ``metadata["extended_by"]["offsets_m"]`` gives each DSM's offset at the overlap's centre (None: not aligned).

    Raises
    ------
    SkyrigError
        A DSM in another frame.
    """
    others = list(others)
    if not others:
        return dsm
    for k, o in enumerate(others):
        if o.frame != dsm.frame:
            raise SkyrigError(f"DSM {k + 1} to extend with is in {o.frame.to_text()}, the DSM in {dsm.frame.to_text()}")
    g = dsm.grid
    b = [g.bounds] + [o.grid.bounds for o in others]
    xmin, ymin = min(v[0] for v in b), min(v[1] for v in b)
    xmax, ymax = max(v[2] for v in b), max(v[3] for v in b)
    c0 = int(np.floor((xmin - g.x0) / g.cell_m + 1e-9))
    r0 = int(np.floor((g.y0 - ymax) / g.cell_m + 1e-9))
    c1 = int(np.ceil((xmax - g.x0) / g.cell_m - 1e-9))
    r1 = int(np.ceil((g.y0 - ymin) / g.cell_m - 1e-9))
    ng = GridSpec(g.x0 + c0 * g.cell_m, g.y0 - r0 * g.cell_m, g.cell_m, c1 - c0, r1 - r0)
    H, W = ng.shape

    def place(a: NDArray, fill) -> NDArray:
        out = np.full((H, W), fill, dtype=a.dtype)
        out[-r0:-r0 + g.height, -c0:-c0 + g.width] = a
        return out

    height = place(np.asarray(dsm.height, np.float32), np.float32(np.nan))
    support = place(np.asarray(dsm.support, np.int16), np.int16(0))
    spread = place(np.asarray(dsm.spread, np.float32), np.float32(np.nan))
    sigma = place(np.asarray(dsm.sigma, np.float32), np.float32(np.nan))
    filled = place(np.asarray(dsm.filled, bool), False)
    inside = place(np.ones(g.shape, bool), False)
    meas = np.isfinite(height)
    beyond = _beyond_survey(meas, g.cell_m, gap_m) | ~inside
    # the surveyed area's own voids (holes inside it) stay holes; the other DSMs fill what lies beyond it
    rr, cc = np.nonzero(beyond)
    x = ng.x0 + (cc + 0.5) * ng.cell_m
    y = ng.y0 - (rr + 0.5) * ng.cell_m
    stack_h, stack_s, stack_sd, stack_sp = [], [], [], []
    offsets: list[float | None] = []
    for o in others:
        orow, ocol = o.grid.cell_of(x, y)
        ok = (orow >= 0) & (ocol >= 0) & (orow < o.grid.height) & (ocol < o.grid.width)
        hh = np.full(len(x), np.nan, np.float32)
        hh[ok] = np.asarray(o.height)[orow[ok], ocol[ok]]
        pl = _offset_plane(dsm, o) if align else None
        offsets.append(None if pl is None else round(float(pl[0]), 4))
        if pl is not None:
            hh = (hh - (pl[0] + (x - pl[3]) * pl[1] + (y - pl[4]) * pl[2])).astype(np.float32)
        ss = np.zeros(len(x), np.int16)
        ss[ok] = np.asarray(o.support)[orow[ok], ocol[ok]]
        sd = np.full(len(x), np.nan, np.float32)
        sd[ok] = np.asarray(o.sigma)[orow[ok], ocol[ok]]
        sp = np.full(len(x), np.nan, np.float32)
        sp[ok] = np.asarray(o.spread)[orow[ok], ocol[ok]]
        stack_h.append(hh)
        stack_s.append(np.where(np.isfinite(hh), ss, 0))
        stack_sd.append(sd)
        stack_sp.append(sp)
    # median over the DSMs that measured the cell: sorted, NaN last (a few DSMs: no per-cell Python loop)
    hs = np.sort(np.stack(stack_h), axis=0)
    nv = np.isfinite(hs).sum(axis=0)
    got = nv > 0
    cols = np.arange(hs.shape[1])
    lo_i, hi_i = np.maximum((nv - 1) // 2, 0), np.maximum(nv // 2, 0)
    med = 0.5 * (hs[lo_i, cols] + hs[hi_i, cols])
    sd_max = np.fmax.reduce(np.stack(stack_sd), axis=0)
    sp_max = np.fmax.reduce(np.stack(stack_sp), axis=0)
    height[rr[got], cc[got]] = med[got]
    support[rr[got], cc[got]] = np.sum(np.stack(stack_s), axis=0)[got]
    sigma[rr[got], cc[got]] = sd_max[got]
    spread[rr[got], cc[got]] = sp_max[got]
    meta = dict(dsm.metadata)
    meta["extended_by"] = {"dsms": len(others), "cells": int(got.sum()), "offsets_m": offsets}
    return DsmGrid(ng, dsm.frame, height, support, spread, sigma, filled, dsm.vertical_reference, meta)


@dataclass(frozen=True)
class FootprintHeights:
    """Heights given with footprints (e.g. a cadastre's attributes), used for the footprints inside which the DSM
    has no heights (beyond its surveyed area): :func:`buildings_from_footprints`.

    Attributes
    ----------
    eave_m
        ``(N,)`` eave height per footprint in metres (where the walls meet the roof; a flat roof's height); NaN:
        none given for that footprint.
    ridge_m
        ``(N,)`` ridge heights (same reference) or None.  A rectangular footprint whose ridge is at least
        ``min_pitch_m`` above its eaves gets a gabled roof with the ridge along its longer sides (the common
        house; its gable ends' walls are textured up to the roof line); otherwise a flat roof at the eaves.
    reference
        ``"ground"``: heights above the ground at the footprint (the 10th percentile of the DSM's measured heights
        in a ring of ``ring_m`` around it, as for a footprint with DSM heights; without 3 measured cells there, the
        DSM's ground estimate (:func:`ground_estimate`) at its measured cell nearest to the footprint, at most
        ``max_ground_m`` away); ``"absolute"``: heights in the DSM's own vertical reference
        (:attr:`DsmGrid.vertical_reference`).
    source
        What the heights are, in words (e.g. ``"footprints.gpkg field eave_m"``), for messages and
        :attr:`BuildingBlock.source`.
    labels
        A name per footprint for messages (e.g. ``"buildings:12"``, layer and feature id); default its number.
    max_ground_m
        See ``reference``.
    min_pitch_m
        See ``ridge_m``.
    """

    eave_m: NDArray[np.float64]
    ridge_m: NDArray[np.float64] | None = None
    reference: str = "ground"
    source: str = "footprint heights"
    labels: tuple[str, ...] | None = None
    max_ground_m: float = 150.0
    min_pitch_m: float = 0.5

    def label(self, k: int) -> str:
        return self.labels[k] if self.labels is not None and k < len(self.labels) else f"footprint {k}"


#: Plausible eave heights above the ground (metres) of a building given with its footprint.
EAVE_RANGE_M = (1.0, 500.0)


def _rectangle_of(foot: NDArray, tol_deg: float = 3.0) -> tuple | None:
    """``(centre, long axis unit vector, half length, half width)`` of a footprint that is a rectangle (4 vertices,
    corner angles within ``tol_deg`` of 90), else None."""
    foot = np.asarray(foot, float)
    if len(foot) != 4:
        return None
    e = np.roll(foot, -1, axis=0) - foot
    ln = np.linalg.norm(e, axis=1)
    if ln.min() <= 0:
        return None
    u = e / ln[:, None]
    if np.max(np.abs(np.sum(u * np.roll(u, -1, axis=0), axis=1))) > np.sin(np.radians(tol_deg)):
        return None
    k = 0 if ln[0] + ln[2] >= ln[1] + ln[3] else 1
    return foot.mean(axis=0), u[k], 0.25 * (ln[k] + ln[k + 2]), 0.25 * (ln[1 - k] + ln[3 - k])


def _gabled_rectangle(foot: NDArray, eave: float, ridge: float) -> tuple[NDArray[np.float64], ...] | None:
    """Two roof planes over a (near) rectangular counter-clockwise footprint, ridge along its longer sides at
    mid-width; None when the footprint is not a rectangle (corner angles within 3 deg of 90)."""
    if len(foot) != 4:
        return None
    e = np.roll(foot, -1, axis=0) - foot
    ln = np.linalg.norm(e, axis=1)
    if ln.min() <= 0:
        return None
    u = e / ln[:, None]
    if np.max(np.abs(np.sum(u * np.roll(u, -1, axis=0), axis=1))) > np.sin(np.radians(3.0)):
        return None
    k = 0 if ln[0] + ln[2] >= ln[1] + ln[3] else 1  # edges k and k + 2 are the long (eave) sides
    a, b, c, d = (foot[(k + j) % 4] for j in range(4))  # a -> b a long side, c -> d the other
    m1, m2 = 0.5 * (a + d), 0.5 * (b + c)  # the ridge ends: middles of the gable ends
    p = lambda xy, z: np.r_[xy, z]  # noqa: E731
    side1 = _ccw3(np.array([p(a, eave), p(b, eave), p(m2, ridge), p(m1, ridge)]))
    side2 = _ccw3(np.array([p(m1, ridge), p(m2, ridge), p(c, eave), p(d, eave)]))
    return side1, side2


def buildings_from_footprints(footprints: list[NDArray], dsm: DsmGrid, *, source: str = "footprints",
                              config: ExtractionConfig | None = None, heights: FootprintHeights | None = None,
                              min_measured: float = 0.5, labels: Sequence[str] | None = None) -> list[BuildingBlock]:
    """Building blocks from given footprints (in the DSM's frame), heights from the DSM where it has them, else
    from ``heights``.

    DSM heights (at least ``min_measured`` of the cells inside the footprint eroded by ``edge_cells`` measured):
    ground = 10th percentile of the DSM in a ring of ``ring_m`` around the footprint, eaves = the median of those
    inner cells (a flat roof), or for a rectangle whose cells two roof planes explain much better than one level
    the gabled roof :func:`extract_buildings` would fit.  Otherwise the footprint's heights come from ``heights``
    (a cadastre's attributes, :class:`FootprintHeights`); its footprint may then lie partly or wholly beyond the
    DSM's grid.  ``source`` of the blocks: ``source``, with ``"; heights: <heights.source>"`` for those with given
    heights.  ``labels``: a name per footprint for messages (default: ``heights.labels``, else its number).

    Raises
    ------
    SkyrigError
        On a footprint with fewer than 3 vertices; one with less than ``min_measured`` of its cells measured and
        no given height for it (named; "outside the DSM" when it lies beyond the grid); a given height that is
        not finite, or an eave height above the ground outside :data:`EAVE_RANGE_M`, or a ridge below the eaves;
        a footprint whose ground would be read further than ``heights.max_ground_m`` from the DSM's measured cells.
    """
    import cv2
    from scipy import ndimage

    cfg = config or ExtractionConfig()
    g = dsm.grid
    h = np.asarray(dsm.height, np.float64)
    meas_all = np.isfinite(h)
    if heights is not None:
        if heights.reference not in ("ground", "absolute"):
            raise SkyrigError(f"footprint heights: reference must be 'ground' or 'absolute', not {heights.reference!r}")
        if len(np.asarray(heights.eave_m).reshape(-1)) != len(footprints):
            raise SkyrigError(f"footprint heights: {len(np.asarray(heights.eave_m).reshape(-1))} eave heights for "
                              f"{len(footprints)} footprints")
    ground_cache: dict = {}

    def far_ground(xy: NDArray, label: str) -> float:
        """The DSM's ground estimate at the measured cell nearest to ``xy`` (frame x, y)."""
        if not ground_cache:
            if not meas_all.any():
                raise SkyrigError("the DSM has no measured cell: no ground height for footprints beyond it")
            ground_cache["g"] = ground_estimate(dsm)
            ground_cache["idx"] = ndimage.distance_transform_edt(~meas_all, return_distances=False,
                                                                  return_indices=True)
        cc = int(np.clip(np.floor((xy[0] - g.x0) / g.cell_m), 0, g.width - 1))
        rr = int(np.clip(np.floor((g.y0 - xy[1]) / g.cell_m), 0, g.height - 1))
        ir, ic = ground_cache["idx"][0][rr, cc], ground_cache["idx"][1][rr, cc]
        x = g.x0 + (ic + 0.5) * g.cell_m
        y = g.y0 - (ir + 0.5) * g.cell_m
        dist = float(np.hypot(x - xy[0], y - xy[1]))
        if dist > heights.max_ground_m:
            raise SkyrigError(f"{label} ({source}): no ground height for its walls: the nearest DSM cell with a ground "
                              f"height is {dist:.0f} m away (more than {heights.max_ground_m:.0f} m); the DSM must "
                              "reach within that distance of the footprints")
        return float(ground_cache["g"][ir, ic])

    out = []
    for k, fp in enumerate(footprints):
        label = (labels[k] if labels is not None and k < len(labels) else
                 heights.label(k) if heights is not None else f"footprint {k}")
        fp = np.asarray(fp, float)[:, :2]
        if len(fp) > 3 and np.allclose(fp[0], fp[-1], rtol=0.0, atol=1e-6):
            fp = fp[:-1]
        if len(fp) < 3:
            raise SkyrigError(f"{label} ({source}): fewer than 3 vertices")
        col = (fp[:, 0] - g.x0) / g.cell_m - 0.5
        row = (g.y0 - fp[:, 1]) / g.cell_m - 0.5
        ring_px = max(1, int(np.ceil(cfg.ring_m / g.cell_m)))
        pad = ring_px + 2
        # the footprint's window, possibly reaching beyond the grid (cells there are unmeasured)
        r0, c0 = int(np.floor(row.min())) - pad, int(np.floor(col.min())) - pad
        r1, c1 = int(np.ceil(row.max())) + pad + 2, int(np.ceil(col.max())) + pad + 2
        m = np.zeros((r1 - r0, c1 - c0), np.uint8)
        pts = np.round(np.column_stack([col - c0, row - r0]) * 16).astype(np.int32)
        cv2.fillPoly(m, [pts], 1, shift=4)
        comp = m.astype(bool)
        hw = np.full(comp.shape, np.nan)
        rs, re_ = max(r0, 0), min(r1, g.height)
        cs, ce = max(c0, 0), min(c1, g.width)
        if rs < re_ and cs < ce:
            hw[rs - r0:re_ - r0, cs - c0:ce - c0] = h[rs:re_, cs:ce]
        mw = np.isfinite(hw)
        inner_all = ndimage.binary_erosion(comp, iterations=cfg.edge_cells)
        if inner_all.sum() < 3:
            inner_all = comp
        measured = float((inner_all & mw).sum()) / max(int(inner_all.sum()), 1)
        ring = ndimage.binary_dilation(comp, iterations=ring_px) & ~ndimage.binary_dilation(comp) & mw
        foot = _ccw(fp)
        given = None
        if heights is not None:
            given = float(np.asarray(heights.eave_m, float).reshape(-1)[k])
            if np.isnan(given):
                given = None
        outside = not (0 <= col.min() and 0 <= row.min() and col.max() <= g.width - 1 and row.max() <= g.height - 1)
        none_given = (f"({heights.source}: empty)" if heights is not None else
                      "(a height attribute of the footprints)")
        if given is None and outside:
            raise SkyrigError(f"{label} ({source}) lies (partly) outside the DSM {g.bounds} and no height was "
                              f"given for it {none_given}")
        if measured >= min_measured:
            # the DSM measured the roof
            inner = inner_all & mw
            if inner.sum() < 3:
                inner = comp & mw
            z = hw[inner]
            eave = float(np.median(z))
            gz = float(np.percentile(hw[ring], 10)) if ring.sum() >= 3 else float(np.nanmin(hw))
            roof = (np.column_stack([foot, np.full(len(foot), eave)]),)
            rect = _rectangle_of(foot)
            if rect is not None and len(z) >= 12:
                # a gabled roof where two planes explain the roof cells much better than one level (as extracted)
                rr, cc = np.nonzero(inner)
                xy = _cells_to_xy(g, cc + c0, rr + r0)
                got = _gable(xy, z, rect, float(1.4826 * np.median(np.abs(z - eave))), cfg)
                if got is not None:
                    eave, roof = got
            out.append(BuildingBlock(k, foot, gz, float(eave), roof, source))
            continue
        if given is None:
            what = ("has no measured cell inside it" if measured == 0 else
                    f"measured {100 * measured:.0f} % of the cells inside it (less than {100 * min_measured:.0f} %)")
            raise SkyrigError(f"{label} ({source}): the DSM {what}, and no height was given for it {none_given}")
        ridge_given = None
        if heights.ridge_m is not None:
            rv = float(np.asarray(heights.ridge_m, float).reshape(-1)[k])
            ridge_given = None if np.isnan(rv) else rv
        if not np.isfinite(given) or (ridge_given is not None and not np.isfinite(ridge_given)):
            raise SkyrigError(f"{label} ({heights.source}): height {given} is not a number")
        # the ground as for DSM heights (the ring's measured cells), else the DSM's ground at its nearest measured cell
        gz = float(np.percentile(hw[ring], 10)) if ring.sum() >= 3 else far_ground(foot.mean(axis=0), label)
        if heights.reference == "ground":
            eave, ridge = gz + given, (None if ridge_given is None else gz + ridge_given)
        else:
            eave, ridge = given, ridge_given
        lo, hi = EAVE_RANGE_M
        if not lo <= eave - gz <= hi:
            raise SkyrigError(f"{label} ({heights.source}): eave height {eave - gz:.2f} m above the ground (at "
                              f"{gz:.2f} m, {dsm.vertical_reference}) is implausible (expected {lo:g} to {hi:g} m; "
                              "heights in metres, reference " + ("above the ground)" if heights.reference == "ground"
                                                                else "the DSM's vertical reference)"))
        if ridge is not None and ridge < eave - 0.01:
            raise SkyrigError(f"{label} ({heights.source}): ridge height {ridge - gz:.2f} m is below the eaves "
                              f"({eave - gz:.2f} m above the ground)")
        roof = None
        if ridge is not None and ridge - eave >= heights.min_pitch_m:
            roof = _gabled_rectangle(foot, eave, ridge)
        if roof is None:
            roof = (np.column_stack([foot, np.full(len(foot), eave)]),)
        out.append(BuildingBlock(k, foot, gz, eave, roof, f"{source}; heights: {heights.source}"))
    return out


def surface_with_buildings(dsm: DsmGrid, buildings: Sequence[BuildingBlock], *, margin_m: float = 10.0) -> DsmGrid:
    """The DSM as an occlusion surface that also holds buildings it did not measure (e.g. given as footprints with
    heights beyond its surveyed area).

    The grid grows (same cell size and alignment) to cover every building plus ``margin_m``.  The cells the DSM
    has not measured (its holes and the new cells) take its ground estimate (:func:`ground_estimate`, flagged
    ``filled``), then in every such cell inside a building's footprint the building's roof height is burnt in (its
    roof polygons; the eaves without).  Measured cells are left as they are.  ``metadata["buildings_burnt"]``
    counts the burnt cells.  Unchanged (the same object) when nothing is to be burnt.
    """
    import cv2

    if not buildings:
        return dsm
    g = dsm.grid
    allp = np.concatenate([np.asarray(b.footprint, float) for b in buildings])
    xmin, ymin = min(g.bounds[0], allp[:, 0].min() - margin_m), min(g.bounds[1], allp[:, 1].min() - margin_m)
    xmax, ymax = max(g.bounds[2], allp[:, 0].max() + margin_m), max(g.bounds[3], allp[:, 1].max() + margin_m)
    c0 = int(np.floor((xmin - g.x0) / g.cell_m + 1e-9))
    r0 = int(np.floor((g.y0 - ymax) / g.cell_m + 1e-9))
    c1 = max(int(np.ceil((xmax - g.x0) / g.cell_m - 1e-9)), g.width)
    r1 = max(int(np.ceil((g.y0 - ymin) / g.cell_m - 1e-9)), g.height)
    c0, r0 = min(c0, 0), min(r0, 0)
    ng = GridSpec(g.x0 + c0 * g.cell_m, g.y0 - r0 * g.cell_m, g.cell_m, c1 - c0, r1 - r0)
    H, W = ng.shape

    def place(a: NDArray, fill) -> NDArray:
        o = np.full((H, W), fill, dtype=a.dtype)
        o[-r0:-r0 + g.height, -c0:-c0 + g.width] = a
        return o

    height = place(np.asarray(dsm.height, np.float32), np.float32(np.nan))
    free = ~np.isfinite(height)
    filled = place(np.asarray(dsm.filled, bool), False)
    if free.any():
        # the unmeasured cells get the ground first (from the measured cells: texturing would fill holes from the
        # nearest measured cell, and a burnt roof would then spread over the void around it)
        ground = ground_estimate(DsmGrid(ng, dsm.frame, height, np.zeros((H, W), np.int16), height, height, filled,
                                         dsm.vertical_reference, {}))
        height = np.where(free, ground, height).astype(np.float32)
        filled = filled | free
    burnt = 0
    for b in buildings:
        fp = np.asarray(b.footprint, float)
        col = (fp[:, 0] - ng.x0) / ng.cell_m - 0.5
        row = (ng.y0 - fp[:, 1]) / ng.cell_m - 0.5
        ra, ca = max(int(np.floor(row.min())) - 1, 0), max(int(np.floor(col.min())) - 1, 0)
        rb, cb = min(int(np.ceil(row.max())) + 2, H), min(int(np.ceil(col.max())) + 2, W)
        if ra >= rb or ca >= cb:
            continue
        m = np.zeros((rb - ra, cb - ca), np.uint8)
        cv2.fillPoly(m, [np.round(np.column_stack([col - ca, row - ra]) * 16).astype(np.int32)], 1, shift=4)
        sel = m.astype(bool) & free[ra:rb, ca:cb]
        if not sel.any():
            continue
        rr, cc = np.nonzero(sel)
        xy = np.column_stack([ng.x0 + (cc + ca + 0.5) * ng.cell_m, ng.y0 - (rr + ra + 0.5) * ng.cell_m])
        height[rr + ra, cc + ca] = _roof_height(b, xy).astype(np.float32)
        burnt += len(rr)
    if burnt == 0 and (H, W) == g.shape:
        return dsm
    meta = dict(dsm.metadata)
    meta["buildings_burnt"] = {"cells": burnt}
    return DsmGrid(ng, dsm.frame, height, place(np.asarray(dsm.support, np.int16), np.int16(0)),
                   place(np.asarray(dsm.spread, np.float32), np.float32(np.nan)),
                   place(np.asarray(dsm.sigma, np.float32), np.float32(np.nan)),
                   filled, dsm.vertical_reference, meta)


def _roof_height(block: BuildingBlock, xy: NDArray) -> NDArray[np.float64]:
    """Height of the roof polygons over plan points ``(N, 2)`` (the highest plane whose polygon contains the point,
    the nearest polygon's plane otherwise; ``eave_z`` without roof polygons)."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    if not block.roof:
        return np.full(len(xy), float(block.eave_z))
    best = np.full(len(xy), -np.inf)
    dist = np.full(len(xy), np.inf)
    near = np.full(len(xy), float(block.eave_z))
    for poly in block.roof:
        p = np.asarray(poly, float)
        A = np.column_stack([p[:, 0], p[:, 1], np.ones(len(p))])
        coef, *_ = np.linalg.lstsq(A, p[:, 2], rcond=None)
        z = xy @ coef[:2] + coef[2]
        inside = np.ones(len(xy), bool)
        dmin = np.full(len(xy), np.inf)
        for i in range(len(p)):
            a, b = p[i, :2], p[(i + 1) % len(p), :2]
            e = b - a
            cross = e[0] * (xy[:, 1] - a[1]) - e[1] * (xy[:, 0] - a[0])
            inside &= cross >= -1e-9  # counter-clockwise: inside is on the left of every edge
            t = np.clip(((xy - a) @ e) / max(e @ e, 1e-12), 0, 1)
            dmin = np.minimum(dmin, np.linalg.norm(xy - (a + t[:, None] * e), axis=1))
        best = np.where(inside & (z > best), z, best)
        closer = dmin < dist
        near = np.where(closer, z, near)
        dist = np.minimum(dist, dmin)
    return np.where(np.isfinite(best), best, near)
