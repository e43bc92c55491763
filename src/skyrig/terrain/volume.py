"""Cut and fill volumes between two surfaces inside a polygon, with their predicted uncertainty.

The surfaces are sampled on one grid (the top surface's); a cell counts when its centre lies inside the polygon
(``shapely.contains_xy``); cells where a surface has no height (a DSM's hole at a wall) get the difference
interpolated from the cells around, with the local spread of the differences as their variance.  With
``dz = top - base`` per cell of area ``A``: fill ``= A sum(max(dz, 0))``, cut ``= A sum(max(-dz, 0))``, net
``= fill - cut`` (positive: material above the base).

Uncertainty
-----------
The heights' errors are spatially correlated over a length ``L`` (the DSM's matching window, a few cells; for a
DTM's interpolated cells, the size of the gap).  Following Rolstad, Haug and Denby (2009, "Spatially integrated
geodetic glacier mass balance and its uncertainty based on geostatistical analysis", J. Glaciology 55(192)), a sum
over an area of cells with errors correlated over ``L`` (a spherical variogram) has the variance of the sum of
independent cells times the number of cells one correlated patch holds, ``max(1, pi L^2 / (5 A))``::

    var(net) = A^2 * max(1, pi L^2 / (5 A)) * sum(sigma_top^2 + sigma_base^2) + (sigma_sys * area)^2

``sigma_sys`` is an error shared by the whole surface (a datum or height bias: e.g. the adjustment's height
precision); it adds fully correlated.  Cut and fill get the same formula over their own cells.  A base through
boundary points (:func:`base_from_points`) with the points' height precision adds
``sum_k (A sum_cells w_k sigma_k)^2``, ``w_k`` the weight of point ``k``'s height in the base at a cell
(:func:`base_point_weights`): each point's error shifts the base over the cells its triangles cover.  A DTM base's
cells interpolated under a building or across a gap (``base_regions``) share one error per gap: their
``sigma_base`` adds as ``(A sum sigma_base)^2`` per gap.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from skyrig.dense.grid import GridSpec
from skyrig.errors import GeometryError, InputFormatError

__all__ = ["VolumeResult", "cut_fill", "plane_base", "base_from_points", "base_point_weights", "polygon_mask"]


@dataclass(frozen=True)
class VolumeResult:
    """Cut / fill between a top and a base surface inside a polygon (cubic metres, square metres, metres)."""

    fill_m3: float
    cut_m3: float
    net_m3: float
    sigma_fill_m3: float
    sigma_cut_m3: float
    sigma_net_m3: float
    area_m2: float  # area of the cells counted (inside the polygon, both surfaces valid)
    polygon_area_m2: float
    cells: int
    cells_without_data: int  # inside the polygon, no height on a surface and not interpolated (left out)
    cells_interpolated: int  # inside the polygon, no height on a surface: the difference interpolated
    correlation_length_m: float
    sigma_sys_m: float

    def as_dict(self) -> dict[str, float]:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def polygon_mask(polygon, grid: GridSpec) -> NDArray[np.bool_]:
    """Cells of ``grid`` whose centre lies inside a shapely (multi)polygon.

    Raises
    ------
    GeometryError
        On an empty or invalid polygon, or one that covers no cell centre.
    """
    import shapely

    if polygon is None or polygon.is_empty:
        raise GeometryError("the polygon is empty")
    if polygon.geom_type not in ("Polygon", "MultiPolygon"):
        raise GeometryError(f"a polygon is needed, got a {polygon.geom_type}")
    if not polygon.is_valid:
        raise GeometryError(f"the polygon is not valid ({shapely.is_valid_reason(polygon)})")
    xx, yy = grid.cell_centres()
    m = shapely.contains_xy(polygon, xx, yy)
    if not m.any():
        raise GeometryError(f"the polygon (bounds {tuple(round(v, 3) for v in polygon.bounds)}) covers no cell of "
                            f"the surface (bounds {tuple(round(v, 3) for v in grid.bounds)})")
    return m


def plane_base(grid: GridSpec, z0: float, slope_x: float = 0.0, slope_y: float = 0.0,
               x_ref: float = 0.0, y_ref: float = 0.0) -> NDArray[np.float64]:
    """A design plane ``z = z0 + slope_x (x - x_ref) + slope_y (y - y_ref)`` at the grid's cell centres."""
    xx, yy = grid.cell_centres()
    return z0 + slope_x * (xx - x_ref) + slope_y * (yy - y_ref)


def base_from_points(grid: GridSpec, xyz: NDArray[np.float64], fit: str = "tin") -> NDArray[np.float64]:
    """A base surface through boundary points (e.g. the toe of a stockpile measured around it): ``fit="tin"``
    linear on their Delaunay triangulation inside their hull, the least-squares plane through them outside (and for
    3 points or collinear ones); ``fit="plane"`` the least-squares plane everywhere (every point weighs the same: a
    ring of points around a pile, whose triangulation is a fan of slivers, gets a base as precise as their mean).

    Raises
    ------
    GeometryError
        With fewer than 3 points, or another ``fit``.
    """
    p = _base_points(xyz)
    xx, yy = grid.cell_centres()
    return _base_at(p[:, :2], p[:, 2], xx, yy, fit)


def _base_points(xyz: NDArray[np.float64]) -> NDArray[np.float64]:
    p = np.asarray(xyz, np.float64)
    if p.ndim != 2 or p.shape[1] not in (2, 3) or len(p) < 3:
        raise GeometryError(f"a base surface needs at least 3 points (x, y, z), got {p.shape}")
    return p


def _base_at(xy: NDArray[np.float64], z: NDArray[np.float64], x: NDArray[np.float64], y: NDArray[np.float64],
             fit: str = "tin") -> NDArray[np.float64]:
    """:func:`base_from_points`' surface at ``x, y``; ``z`` ``(K,)`` or ``(K, M)`` (M surfaces on the same points:
    the result then has a trailing axis of M).  Linear in ``z``."""
    from scipy.interpolate import LinearNDInterpolator

    A = np.column_stack([np.ones(len(xy)), xy[:, 0] - xy[:, 0].mean(), xy[:, 1] - xy[:, 1].mean()])
    coef, *_ = np.linalg.lstsq(A, z, rcond=None)
    dx, dy = x - xy[:, 0].mean(), y - xy[:, 1].mean()
    if z.ndim == 2:
        dx, dy = dx[..., None], dy[..., None]
    plane = coef[0] + coef[1] * dx + coef[2] * dy
    if fit not in ("tin", "plane"):
        raise GeometryError(f"a base fit is 'tin' or 'plane', got {fit!r}")
    if fit == "plane":
        return plane
    try:
        tin = LinearNDInterpolator(xy, z)(x, y)
    except Exception:  # collinear points
        return plane
    return np.where(np.isfinite(tin), tin, plane)


def base_point_weights(grid: GridSpec, xy: NDArray[np.float64], cells: NDArray[np.bool_], fit: str = "tin"
                       ) -> NDArray[np.float64]:
    """``(M, K)`` weights of the ``K`` base points' heights in :func:`base_from_points`' surface at the ``M`` cells
    of the mask ``cells``: the surface there is ``weights @ z`` (the surface is linear in the heights), so the
    heights' errors reach a volume through these weights."""
    p = _base_points(xy)
    xx, yy = grid.cell_centres()
    return _base_at(p[:, :2], np.eye(len(p)), xx[cells], yy[cells], fit)


def cut_fill(top: NDArray[np.float64], base: NDArray[np.float64], grid: GridSpec, polygon, *,
             sigma_top: NDArray[np.float64] | float = 0.0, sigma_base: NDArray[np.float64] | float = 0.0,
             correlation_length_m: float | None = None, sigma_sys_m: float = 0.0,
             fill_missing: bool = True, base_points: tuple | None = None,
             base_regions: NDArray[np.integer] | None = None) -> VolumeResult:
    """Cut and fill between ``top`` and ``base`` inside ``polygon`` (module docstring).

    Parameters
    ----------
    top, base
        ``(rows, cols)`` heights on ``grid`` (metres, NaN = no data).
    polygon
        shapely (multi)polygon in the grid's map coordinates.
    sigma_top, sigma_base
        Predicted precision of the heights (metres, per cell or one value; NaN counts as 0).
    correlation_length_m
        Length over which the height errors are correlated (default: 3 cells).
    sigma_sys_m
        Error common to the whole difference (metres).
    fill_missing
        Interpolate the difference into cells inside the polygon where a surface has no height (linear from the
        valid cells around; variance: the spread of the valid differences within 7 cells); False leaves them out
        (the volume is then of the cells with data only, ``cells_without_data`` says how many).
    base_points
        ``(xy (K, 2), sigma_z (K,)[, fit])`` when ``base`` is :func:`base_from_points` of these points: their heights'
        standard deviations (metres, independent) are propagated to the volumes through the surface's weights
        (:func:`base_point_weights`): an error of a point moves the base over every cell its triangles cover, the
        same way for all of them (``sigma_base`` is then the base's own per-cell error, usually 0).
    base_regions
        ``(rows, cols)`` labels (0: none) of regions whose base errors are one error: a DTM's ground interpolated
        under a building or across a gap is off by about the same amount over the whole gap, so ``sigma_base``
        there adds as ``(A sum sigma_base)^2`` per region (fully correlated) instead of cell by cell.

    Raises
    ------
    GeometryError
        On an empty / invalid polygon or one outside the grid.
    InputFormatError
        On arrays not of the grid's shape.
    """
    t = np.asarray(top, np.float64)
    b = np.asarray(base, np.float64)
    for name, a in (("top", t), ("base", b)):
        if a.shape != grid.shape:
            raise InputFormatError(f"{name} surface {a.shape} does not match the grid {grid.shape}", field=name)
    inside = polygon_mask(polygon, grid)
    both = np.isfinite(t) & np.isfinite(b)
    ok = inside & both
    if not ok.any():
        raise GeometryError("no cell inside the polygon has a height on both surfaces")
    A = grid.cell_m ** 2
    L = 3 * grid.cell_m if correlation_length_m is None else float(correlation_length_m)
    patch = max(1.0, np.pi * L * L / (5.0 * A))
    st = np.broadcast_to(np.asarray(sigma_top, np.float64), grid.shape)
    sb = np.broadcast_to(np.asarray(sigma_base, np.float64), grid.shape)
    var = np.nan_to_num(st) ** 2 + np.nan_to_num(sb) ** 2
    diff = np.where(both, t - b, np.nan)
    missing = inside & ~both
    if fill_missing and missing.any():
        diff, var = _fill_differences(diff, var, missing, grid)
        ok = inside & np.isfinite(diff)
    dz = diff[ok]
    v = var[ok]
    up, down = dz > 0, dz < 0

    if base_points is not None:
        bxy, bs = np.asarray(base_points[0], np.float64), np.asarray(base_points[1], np.float64)
        if bs.shape != (len(bxy),) or not np.all(np.isfinite(bs) & (bs >= 0)):
            raise InputFormatError(f"base point sigmas must be ({len(bxy)},) non-negative numbers", field="sz")
        W = base_point_weights(grid, bxy, ok, *base_points[2:])  # (cells of ok, row-major, K): the order of dz

    if base_regions is not None:
        reg = np.asarray(base_regions)[ok]
        sb_ok = np.nan_to_num(sb[ok]) * (reg > 0)
        v = v - sb_ok ** 2  # those cells' base variance is counted per region below

    def sig(sel: NDArray[np.bool_]) -> float:
        area = A * float(sel.sum())
        var_pts = float(np.sum((A * W[sel].sum(axis=0) * bs) ** 2)) if base_points is not None else 0.0
        var_reg = float(np.sum((A * np.bincount(reg[sel], weights=sb_ok[sel])) ** 2)) if base_regions is not None \
            else 0.0
        return float(np.sqrt(A * A * patch * v[sel].sum() + (sigma_sys_m * area) ** 2 + var_pts + var_reg))

    fill = A * float(dz[up].sum())
    cut = -A * float(dz[down].sum())
    return VolumeResult(fill, cut, fill - cut, sig(up), sig(down), sig(np.ones(len(dz), bool)),
                        A * float(ok.sum()), float(polygon.area), int(ok.sum()), int((inside & ~ok).sum()),
                        int((missing & ok).sum()), L, float(sigma_sys_m))


def _fill_differences(diff: NDArray[np.float64], var: NDArray[np.float64], missing: NDArray[np.bool_],
                      grid: GridSpec, window: int = 7) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Differences of the ``missing`` cells interpolated linearly (Delaunay of the valid cells near them, nearest
    outside their hull), with the variance of the valid differences in a ``window`` x ``window`` cells around
    (a gap at a wall gets the spread of roof and ground)."""
    from scipy import ndimage
    from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator

    valid = np.isfinite(diff)
    near = valid & ndimage.binary_dilation(missing, iterations=window)
    if not near.any():
        return diff, var
    xx, yy = grid.cell_centres()
    P = np.column_stack([xx[near], yy[near]])
    Q = np.column_stack([xx[missing], yy[missing]])
    try:
        z = LinearNDInterpolator(P, diff[near])(Q)
    except Exception:  # too few or collinear cells
        z = np.full(len(Q), np.nan)
    bad = ~np.isfinite(z)
    if bad.any():
        z[bad] = NearestNDInterpolator(P, diff[near])(Q[bad])
    d0 = np.where(valid, diff, 0.0)
    w = ndimage.uniform_filter(valid.astype(np.float64), window, mode="constant")
    m1 = ndimage.uniform_filter(d0, window, mode="constant")
    m2 = ndimage.uniform_filter(d0 * d0, window, mode="constant")
    with np.errstate(invalid="ignore", divide="ignore"):
        local_var = np.where(w > 0, np.maximum(m2 / w - (m1 / w) ** 2, 0.0), np.nan)
    spread = np.nanmax(local_var[missing]) if np.isfinite(local_var[missing]).any() else 0.0
    out, v = diff.copy(), var.copy()
    out[missing] = z
    v[missing] = np.where(np.isfinite(local_var[missing]), local_var[missing], spread) + np.nan_to_num(var[missing])
    return out, v
