"""Digital terrain model from classified points, the normalised DSM, and sampling of a surface at points.

The DTM is gridded from the ground points alone: a cell's height is the mean of the ground points in it, its
precision the larger of the points' predicted precision and their scatter, divided by the square root of their
number.  Cells without ground are interpolated linearly on a triangulation (Delaunay, ``scipy``) of the measured
cells around the gaps, and flagged by what covered the ground there (:data:`DTM_SOURCE`): a building, vegetation, or
nothing (a gap in the cloud).  Such a cell's predicted precision grows with its distance ``d`` to the nearest
measured cell as ``hypot(sigma_edge, kappa * d**2 / 2)``: the error of a straight line across a gap in a terrain of
curvature ``kappa``, with ``kappa`` the robust spread of the measured DTM's second differences over 5 cells.
Gaps farther than ``max_gap_m`` from any ground and not covered by a building or vegetation stay without data, and
so do open gaps outside the triangulation (no extrapolation beyond the measured ground; under a building or a tree
at the cloud's edge the nearest measured cell's height is taken).

Heights are in the cloud's frame and vertical reference (the DTM carries the frame it was given).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from skyrig.dense.grid import DsmGrid, GridSpec
from skyrig.errors import InputFormatError
from skyrig.georef.eo import WorldFrame

__all__ = ["DtmGrid", "DTM_SOURCE", "make_dtm", "normalised_dsm", "ground_surface", "sample_surface", "sample_grid",
           "same_frame",
           "SOURCE_NONE", "SOURCE_MEASURED", "SOURCE_OPEN", "SOURCE_BUILDING", "SOURCE_VEGETATION"]

SOURCE_NONE, SOURCE_MEASURED, SOURCE_OPEN, SOURCE_BUILDING, SOURCE_VEGETATION = 0, 1, 2, 3, 4
#: Meaning of the DTM's ``source`` (mask) layer.
DTM_SOURCE = {SOURCE_NONE: "no data", SOURCE_MEASURED: "measured ground", SOURCE_OPEN: "interpolated across a gap",
              SOURCE_BUILDING: "interpolated under a building", SOURCE_VEGETATION: "interpolated under vegetation"}


@dataclass(frozen=True)
class DtmGrid:
    """A digital terrain model (bare earth).

    Attributes
    ----------
    grid
        Where the cells are (north-up, metres).
    frame
        The map frame (CRS and height reference) of the heights.
    height
        ``(rows, cols)`` float32 ground heights, metres; NaN = no data.
    sigma
        ``(rows, cols)`` float32 predicted precision of the height (metres, 1 sigma); NaN = no data.
    ground_points
        ``(rows, cols)`` int32 ground points in the cell (0 where interpolated).
    source
        ``(rows, cols)`` uint8 :data:`DTM_SOURCE` code: measured, or interpolated under what.
    vertical_reference
        Words for the height reference (as :attr:`skyrig.dense.grid.DsmGrid.vertical_reference`).
    metadata
        Free key/values written into the file.
    """

    grid: GridSpec
    frame: WorldFrame
    height: NDArray[np.float32]
    sigma: NDArray[np.float32]
    ground_points: NDArray[np.int32]
    source: NDArray[np.uint8]
    vertical_reference: str = ""
    metadata: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in ("height", "sigma", "ground_points", "source"):
            if getattr(self, name).shape != self.grid.shape:
                raise ValueError(f"DtmGrid.{name} has shape {getattr(self, name).shape}, grid is {self.grid.shape}")


@dataclass(frozen=True)
class _Surface:
    grid: GridSpec
    height: NDArray[np.float64]


def _cell_stats(xyz: NDArray[np.float64], grid: GridSpec, sigma: NDArray[np.float64] | None
                ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
    """Per-cell mean height, its precision and the count of the points (NaN / 0 where none)."""
    r, c = grid.cell_of(xyz[:, 0], xyz[:, 1])
    ok = (r >= 0) & (r < grid.height) & (c >= 0) & (c < grid.width)
    k = (r * grid.width + c)[ok]
    z = xyz[ok, 2]
    size = grid.height * grid.width
    n = np.bincount(k, minlength=size)
    s1 = np.bincount(k, weights=z, minlength=size)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = s1 / n
        var = np.bincount(k, weights=(z - mean[k]) ** 2, minlength=size) / np.maximum(n - 1, 1)
        var = np.where(n >= 2, var, np.nan)
        if sigma is not None:
            ps = np.asarray(sigma, np.float64)[ok]
            ps = np.where(np.isfinite(ps), ps, np.nan)
            pvar = np.bincount(k, weights=np.nan_to_num(ps ** 2), minlength=size) / n
            var = np.fmax(var, np.where(n > 0, pvar, np.nan))
        typical = np.nanmedian(var[n >= 2]) if np.any(n >= 2) else np.nan
        var = np.where(np.isfinite(var), var, typical)
        sig = np.sqrt(var / n)
    shp = grid.shape
    return mean.reshape(shp), sig.reshape(shp), n.reshape(shp)


def _fill(height: NDArray[np.float64], measured: NDArray[np.bool_], want: NDArray[np.bool_], grid: GridSpec,
          extrapolate: NDArray[np.bool_] | None = None) -> NDArray[np.float64]:
    """Heights of the ``want`` cells linearly interpolated on a Delaunay triangulation of the measured cells next to
    the gaps; outside their hull the nearest measured cell's where ``extrapolate`` allows it (default everywhere),
    else NaN."""
    from scipy import ndimage
    from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator

    out = height.copy()
    if not want.any() or not measured.any():
        return out
    support = measured & ndimage.binary_dilation(want, iterations=2)
    if support.sum() < 3:
        support = measured
    xx, yy = grid.cell_centres()
    P = np.column_stack([xx[support], yy[support]])
    Q = np.column_stack([xx[want], yy[want]])
    v = height[support]
    try:
        z = LinearNDInterpolator(P, v)(Q)
    except Exception:  # degenerate support (collinear cells): nearest only
        z = np.full(len(Q), np.nan)
    bad = ~np.isfinite(z)
    if extrapolate is not None:
        bad &= extrapolate[want]
    if bad.any():
        z[bad] = NearestNDInterpolator(P, v)(Q[bad])
    out[want] = z
    return out


def ground_surface(ground_xyz: NDArray[np.float64], cell_m: float, grid: GridSpec | None = None) -> _Surface:
    """A gap-free ground surface from ground points: cell means, gaps interpolated (for heights above ground)."""
    pts = np.asarray(ground_xyz, np.float64)
    if grid is None:
        grid = GridSpec.covering(pts[:, 0].min(), pts[:, 1].min(), pts[:, 0].max() + 1e-9, pts[:, 1].max() + 1e-9,
                                 cell_m)
    mean, _, n = _cell_stats(pts, grid, None)
    return _Surface(grid, _fill(mean, n > 0, n == 0, grid))


def sample_surface(surf: _Surface | DtmGrid | DsmGrid, x: NDArray[np.float64], y: NDArray[np.float64]
                   ) -> NDArray[np.float64]:
    """Bilinear interpolation of a gridded surface's heights at map points (:func:`sample_grid`)."""
    return sample_grid(surf.grid, surf.height, x, y)


def sample_grid(g: GridSpec, values: NDArray, x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
    """Bilinear interpolation of ``(rows, cols)`` values on a grid at map points (cell centres as nodes; NaN
    outside the grid or next to no-data cells)."""
    h = np.asarray(values, np.float64)
    u = (np.asarray(x, np.float64) - g.x0) / g.cell_m - 0.5
    v = (g.y0 - np.asarray(y, np.float64)) / g.cell_m - 0.5
    u = np.clip(u, 0, g.width - 1)  # edge half-cells: nearest edge value
    v = np.clip(v, 0, g.height - 1)
    inside = ((np.asarray(x) >= g.x0) & (np.asarray(x) <= g.x0 + g.width * g.cell_m)
              & (np.asarray(y) <= g.y0) & (np.asarray(y) >= g.y0 - g.height * g.cell_m))
    c0 = np.minimum(np.floor(u).astype(np.int64), max(g.width - 2, 0))
    r0 = np.minimum(np.floor(v).astype(np.int64), max(g.height - 2, 0))
    c1 = np.minimum(c0 + 1, g.width - 1)
    r1 = np.minimum(r0 + 1, g.height - 1)
    fu, fv = u - c0, v - r0
    z = ((h[r0, c0] * (1 - fu) + h[r0, c1] * fu) * (1 - fv) + (h[r1, c0] * (1 - fu) + h[r1, c1] * fu) * fv)
    return np.where(inside, z, np.nan)


def _curvature(height: NDArray[np.float64], measured: NDArray[np.bool_], cell_m: float, step: int = 5) -> float:
    """Robust spread (NMAD) of the measured surface's second differences over ``step`` cells, 1/m."""
    vals = []
    h = np.where(measured, height, np.nan)
    for axis in (0, 1):
        a = np.moveaxis(h, axis, 0)
        if a.shape[0] <= 2 * step:
            continue
        d2 = (a[2 * step:] - 2 * a[step:-step] + a[:-2 * step]) / (step * cell_m) ** 2
        vals.append(d2[np.isfinite(d2)])
    v = np.concatenate(vals) if vals else np.zeros(0)
    if len(v) < 10:
        return 0.0
    return float(1.4826 * np.median(np.abs(v - np.median(v))))


def make_dtm(xyz: NDArray[np.float64], code: NDArray[np.integer], frame: WorldFrame, *, cell_m: float | None = None,
             grid: GridSpec | None = None, sigma: NDArray[np.float64] | None = None, max_gap_m: float = 20.0,
             vertical_reference: str = "", metadata: dict | None = None) -> DtmGrid:
    """Grid the ground points of a classified cloud into a DTM (module docstring).

    Parameters
    ----------
    xyz
        ``(N, 3)`` map coordinates in ``frame``, metres.
    code
        ``(N,)`` ASPRS classes: 2 is ground; 6 marks buildings, 3-5 vegetation (what the gaps are flagged with);
        7 (noise) is ignored.
    frame
        The map frame of the points (kept by the DTM).
    cell_m, grid
        The cell size (grid covering the points) or the grid itself (e.g. the DSM's).
    sigma
        ``(N,)`` predicted precision of the points (metres) or None.
    max_gap_m
        Gaps in the cloud farther than this from any ground point stay without data (gaps under buildings and
        vegetation are always filled).

    Raises
    ------
    InputFormatError
        When no point is ground, or on bad shapes / cell size.
    """
    from scipy import ndimage

    pts = np.asarray(xyz, np.float64)
    cls = np.asarray(code)
    if pts.ndim != 2 or pts.shape[1] != 3 or cls.shape != (len(pts),):
        raise InputFormatError(f"need (N, 3) points and (N,) classes, got {pts.shape} and {cls.shape}", field="xyz")
    is_g = cls == 2
    if not is_g.any():
        raise InputFormatError("no ground point (class 2) in the cloud: classify it first", field="classification")
    if grid is None:
        if cell_m is None or not (np.isfinite(cell_m) and cell_m > 0):
            raise InputFormatError(f"cell size must be a positive number of metres, got {cell_m!r}", field="cell_m")
        use = pts[cls != 7]
        grid = GridSpec.covering(use[:, 0].min(), use[:, 1].min(), use[:, 0].max() + 1e-9, use[:, 1].max() + 1e-9,
                                 float(cell_m))
    sig = None if sigma is None else np.asarray(sigma, np.float64)[is_g]
    mean, s_meas, n = _cell_stats(pts[is_g], grid, sig)
    measured = n > 0

    def covered(mask: NDArray[np.bool_]) -> NDArray[np.bool_]:
        r, c = grid.cell_of(pts[mask, 0], pts[mask, 1])
        ok = (r >= 0) & (r < grid.height) & (c >= 0) & (c < grid.width)
        out = np.zeros(grid.shape, bool)
        out[r[ok], c[ok]] = True
        return out

    cov_b, cov_v = covered(cls == 6), covered((cls >= 3) & (cls <= 5))
    any_pt = covered(cls != 7)
    if any_pt.any():  # empty cells take what covers the nearest cell with points (a sparse roof's holes)
        near_d, (ir, ic) = ndimage.distance_transform_edt(~any_pt, return_indices=True)
        near = near_d * grid.cell_m <= 2.0 * grid.cell_m
        cov_b = cov_b | (near & cov_b[ir, ic])
        cov_v = cov_v | (near & cov_v[ir, ic])
    under_b = cov_b & ~measured
    under_v = cov_v & ~measured & ~under_b
    dist = ndimage.distance_transform_edt(~measured) * grid.cell_m
    gap = ~measured & ~under_b & ~under_v & (dist <= max_gap_m)
    want = under_b | under_v | gap
    height = _fill(mean, measured, want, grid, extrapolate=under_b | under_v)
    gap &= np.isfinite(height)  # an open gap is interpolated, never extrapolated beyond the measured ground
    want = under_b | under_v | gap
    kappa = _curvature(mean, measured, grid.cell_m)
    s_edge = float(np.nanmedian(s_meas[measured]))
    sigma_out = np.where(measured, s_meas, np.where(want, np.hypot(s_edge, 0.5 * kappa * dist ** 2), np.nan))
    source = np.full(grid.shape, SOURCE_NONE, np.uint8)
    source[measured] = SOURCE_MEASURED
    source[gap] = SOURCE_OPEN
    source[under_b] = SOURCE_BUILDING
    source[under_v] = SOURCE_VEGETATION
    height = np.where(source > 0, height, np.nan)
    meta = {"dtm_source_codes": {str(k): v for k, v in DTM_SOURCE.items()}, "curvature_nmad_per_m": kappa,
            "max_gap_m": max_gap_m, **(metadata or {})}
    return DtmGrid(grid, frame, height.astype(np.float32), sigma_out.astype(np.float32), n.astype(np.int32), source,
                   vertical_reference, meta)


def same_frame(a: WorldFrame, b: WorldFrame) -> bool:
    """Whether two map frames have the same CRS (PROJ's equality) and the same height reference."""
    from skyrig.geodesy.crs import resolve_crs

    return (a.kind == b.kind and (a.geoid or None) == (b.geoid or None)
            and (a.crs == b.crs or resolve_crs(a.crs) == resolve_crs(b.crs)))


def normalised_dsm(dsm: DsmGrid, dtm: DtmGrid) -> NDArray[np.float32]:
    """The normalised DSM (DSM - DTM, heights above ground, metres) on the DSM's grid.

    The DTM is sampled bilinearly at the DSM's cell centres (the same values when the grids coincide).

    Raises
    ------
    InputFormatError
        When the two surfaces are in different frames (CRS or height reference).
    """
    if not same_frame(dsm.frame, dtm.frame):
        raise InputFormatError(f"DSM ({dsm.frame.to_text()}) and DTM ({dtm.frame.to_text()}) are in different frames",
                               field="frame")
    if dsm.grid == dtm.grid:
        base = dtm.height.astype(np.float64)
    else:
        xx, yy = dsm.grid.cell_centres()
        base = sample_surface(dtm, xx, yy)
    return (dsm.height.astype(np.float64) - base).astype(np.float32)
