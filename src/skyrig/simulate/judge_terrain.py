"""Terrain products of a simulated survey judged against the scene's truth: the DTM against the analytic bare
earth (:meth:`skyrig.simulate.world.Scene.terrain_height`), the ground / building classes against the building
footprints, a building's volume above the ground against the scene's (integrated from the analytic surfaces), and a
stockpile's volume above its toe against the scene's (the pile's closed form and the base its toe defines).

Used by tests and ``make demo``; nothing here is seen by the code that makes the products.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from skyrig.georef.eo import WorldFrame
from skyrig.simulate.world import Scene

__all__ = ["judge_dtm", "judge_classes", "building_volume_truth", "footprint_polygon_map", "stockpile_toe_ring",
           "stockpile_volume_truth"]


def _nmad(e: NDArray[np.float64]) -> float:
    return float(1.4826 * np.median(np.abs(e - np.median(e)))) if len(e) else float("nan")


def _figures(e: NDArray[np.float64], n: int, gsd_m: float) -> dict[str, float]:
    r = {"n": n, "valid": int(len(e)), "completeness": float(len(e) / n) if n else float("nan"),
         "bias_m": float(np.median(e)) if len(e) else float("nan"), "nmad_m": _nmad(e),
         "rmse_m": float(np.sqrt(np.mean(e ** 2))) if len(e) else float("nan")}
    for k in ("bias_m", "nmad_m", "rmse_m"):
        r[k.replace("_m", "_gsd")] = r[k] / gsd_m
    return r


def _to_local(frame: WorldFrame, xyz: NDArray[np.float64], scene: Scene) -> NDArray[np.float64]:
    return WorldFrame.local(*scene.origin).from_ecef(frame.to_ecef(xyz))


def _edge_distance(lx: NDArray[np.float64], ly: NDArray[np.float64], scene: Scene) -> tuple[NDArray, NDArray]:
    """Building index at points and their distance to the nearest footprint outline (metres)."""
    b = scene.buildings
    _, idx = b.top_height(lx, ly)
    d = np.full(np.shape(lx), np.inf)
    for i in range(len(b)):
        a = b.azimuth_rad[i]
        dx, dy = lx - b.cx[i], ly - b.cy[i]
        u = np.abs(dx * np.cos(a) + dy * np.sin(a)) - b.hl[i]
        v = np.abs(-dx * np.sin(a) + dy * np.cos(a)) - b.hw[i]
        outside = np.hypot(np.maximum(u, 0), np.maximum(v, 0))
        inside = np.minimum(np.maximum(u, v), 0.0)
        d = np.minimum(d, np.abs(outside + inside))
    return idx, d


def _on_piles(lx: NDArray[np.float64], ly: NDArray[np.float64], scene: Scene, margin_m: float) -> NDArray[np.bool_]:
    """Points within ``margin_m`` of a stockpile's toe: not judged for a class or a bare-earth height (a heap of
    material on the ground is ground to one user and an object to another: its truth is its volume)."""
    p = scene.stockpiles
    out = np.zeros(np.shape(lx), bool)
    for i in range(0 if p is None else len(p)):
        out |= np.hypot(lx - p.cx[i], ly - p.cy[i]) <= p.radius_m[i] + margin_m
    return out


def judge_dtm(dtm: Any, scene: Scene, gsd_m: float, area_local: tuple[float, float, float, float],
              edge_gsd: float = 2.0) -> dict[str, Any]:
    """A DTM (:class:`skyrig.terrain.dtm.DtmGrid`, any map frame) against the scene's true bare earth.

    Returns the figures (``n``, ``valid``, ``completeness``, ``bias``, ``nmad``, ``rmse`` in metres and GSD) of
    ``open`` cells (in the area, farther than ``edge_gsd`` GSD from every building outline and stockpile toe) and of
    cells ``under_buildings`` (inside a footprint), plus the share of footprint cells the DTM's mask flags as under a
    building (``footprint_flagged``).
    """
    xx, yy = dtm.grid.cell_centres()
    h = dtm.height.astype(np.float64)
    zg = np.where(np.isfinite(h), h, np.nanmedian(h))
    L = _to_local(dtm.frame, np.stack([xx.ravel(), yy.ravel(), zg.ravel()], 1), scene)
    lx, ly = L[:, 0].reshape(xx.shape), L[:, 1].reshape(xx.shape)
    inside = (lx >= area_local[0]) & (lx <= area_local[2]) & (ly >= area_local[1]) & (ly <= area_local[3])
    idx, dist = _edge_distance(lx, ly, scene)
    err = L[:, 2].reshape(xx.shape) - scene.terrain_height(lx, ly)
    ok = np.isfinite(h)
    open_ = inside & (idx < 0) & (dist > edge_gsd * gsd_m) & ~_on_piles(lx, ly, scene, edge_gsd * gsd_m)
    under = inside & (idx >= 0)
    out = {"gsd_m": gsd_m, "cell_m": dtm.grid.cell_m,
           "open": _figures(err[open_ & ok], int(open_.sum()), gsd_m),
           "under_buildings": _figures(err[under & ok], int(under.sum()), gsd_m),
           "footprint_flagged": float(np.mean(dtm.source[under] == 3)) if under.any() else float("nan")}
    return out


def judge_classes(xyz: NDArray[np.float64], code: NDArray[np.integer], frame: WorldFrame, scene: Scene, gsd_m: float,
                  area_local: tuple[float, float, float, float], edge_gsd: float = 2.0,
                  blunder_gsd: float = 5.0) -> dict[str, Any]:
    """ASPRS classes of a cloud against the scene: a point is truly *ground* outside every footprint and truly
    *building* inside one; points on a stockpile (:func:`_on_piles`), within ``edge_gsd`` GSD of an outline (walls,
    mixed cells) and points farther
    than ``blunder_gsd`` GSD from the true surface (matching blunders: their truth is no class) are not judged.

    Returns ``ground_type1`` (ground labelled otherwise / ground points), ``ground_type2`` (non-ground labelled
    ground / non-ground points), ``ground_class_error`` (both counts / ground points, the issue's figure),
    ``building_recall``, ``building_precision`` and the counts.
    """
    L = _to_local(frame, np.asarray(xyz, np.float64), scene)
    inside = (L[:, 0] >= area_local[0]) & (L[:, 0] <= area_local[2]) & (L[:, 1] >= area_local[1]) & \
        (L[:, 1] <= area_local[3])
    idx, dist = _edge_distance(L[:, 0], L[:, 1], scene)
    off = np.abs(L[:, 2] - scene.surface_height(L[:, 0], L[:, 1])) > blunder_gsd * gsd_m
    judged = inside & (dist > edge_gsd * gsd_m) & ~off & ~_on_piles(L[:, 0], L[:, 1], scene, edge_gsd * gsd_m)
    tg = judged & (idx < 0)
    tb = judged & (idx >= 0)
    c = np.asarray(code)
    g = c == 2
    b = c == 6
    n_g, n_b = int(tg.sum()), int(tb.sum())
    return {"points_judged": int(judged.sum()), "ground_points": n_g, "building_points": n_b,
            "blunders_not_judged": int((inside & off).sum()),
            "ground_type1": float(np.sum(tg & ~g) / max(n_g, 1)), "ground_type2": float(np.sum(tb & g) / max(n_b, 1)),
            "ground_class_error": float((np.sum(tg & ~g) + np.sum(tb & g)) / max(n_g, 1)),
            "building_recall": float(np.sum(tb & b) / max(n_b, 1)),
            "building_precision": float(np.sum(tb & b) / max(np.sum(judged & b), 1))}


def footprint_polygon_map(scene: Scene, i: int, frame: WorldFrame, margin_m: float = 0.0) -> NDArray[np.float64]:
    """``(4, 2)`` corners of building ``i``'s footprint grown by ``margin_m``, in a map frame (at its ground)."""
    b = scene.buildings
    a = b.azimuth_rad[i]
    ux, uy = np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)])
    c = np.array([b.cx[i], b.cy[i]])
    hl, hw = b.hl[i] + margin_m, b.hw[i] + margin_m
    xy = np.array([c + sx * hl * ux + sy * hw * uy for sx, sy in ((1, 1), (1, -1), (-1, -1), (-1, 1))])
    z = scene.terrain_height(xy[:, 0], xy[:, 1])
    local = WorldFrame.local(*scene.origin)
    return frame.from_ecef(local.to_ecef(np.column_stack([xy, z])))[:, :2]


def building_volume_truth(scene: Scene, i: int, margin_m: float = 0.0, step_m: float = 0.05) -> float:
    """Volume (m^3) between the true top surface and the true bare earth over building ``i``'s footprint grown by
    ``margin_m`` (midpoint rule on a ``step_m`` lattice aligned with the footprint, in the scene's local frame;
    the ground around adds nothing)."""
    b = scene.buildings
    a = b.azimuth_rad[i]
    hl, hw = b.hl[i] + margin_m, b.hw[i] + margin_m
    u = np.arange(-hl + step_m / 2, hl, step_m)
    v = np.arange(-hw + step_m / 2, hw, step_m)
    U, V = np.meshgrid(u, v)
    x = b.cx[i] + U * np.cos(a) - V * np.sin(a)
    y = b.cy[i] + U * np.sin(a) + V * np.cos(a)
    dz = scene.surface_height(x, y) - scene.terrain_height(x, y)
    return float(dz.sum() * (len(u) and (2 * hl / len(u))) * (2 * hw / len(v)))


def stockpile_toe_ring(scene: Scene, i: int, margin_m: float = 2.0, n: int = 48) -> NDArray[np.float64]:
    """``(n, 2)`` local ``x, y`` of a ring of ``n`` points ``margin_m`` outside stockpile ``i``'s toe (the polygon
    a surveyor draws around the pile, its vertices the points the base goes through)."""
    p = scene.stockpiles
    a = np.arange(n) * (2 * np.pi / n)
    rad = float(p.radius_m[i]) + margin_m
    return np.column_stack([p.cx[i] + rad * np.cos(a), p.cy[i] + rad * np.sin(a)])


def ring_to_map(scene: Scene, ring_local: NDArray[np.float64], frame: WorldFrame) -> NDArray[np.float64]:
    """Local ``(n, 2)`` points on the natural ground to ``(n, 2)`` map coordinates of ``frame``."""
    z = scene.natural_ground_height(ring_local[:, 0], ring_local[:, 1])
    local = WorldFrame.local(*scene.origin)
    return frame.from_ecef(local.to_ecef(np.column_stack([ring_local, z])))[:, :2]


def stockpile_volume_truth(scene: Scene, i: int, ring_local: NDArray[np.float64], step_m: float = 0.05,
                           fit: str = "tin") -> dict[str, float]:
    """Truths of stockpile ``i``'s volume (m^3): ``pile``, its closed form ``pi h (R^2 + R r + r^2) / 3`` (the
    material above the natural ground); ``above_toe_base``, the material between the scene's surface and the base
    through the ring's true ground heights (:func:`skyrig.terrain.volume.base_from_points`' surface of ``fit``:
    linear on their triangles, or their least-squares plane) inside the ring's polygon, on a ``step_m`` midpoint lattice in the scene's local frame: what
    a measurement with that base estimates (it differs from ``pile`` by the natural ground's curvature under the
    triangles, ``base_error``).  Local metres: a map projection's scale (UTM: ~1e-3 of the area) is not in it."""
    import shapely
    from scipy.interpolate import LinearNDInterpolator

    ring = np.asarray(ring_local, np.float64)
    zr = scene.natural_ground_height(ring[:, 0], ring[:, 1])
    lo, hi = ring.min(axis=0), ring.max(axis=0)
    gx, gy = np.meshgrid(np.arange(lo[0] + step_m / 2, hi[0], step_m), np.arange(lo[1] + step_m / 2, hi[1], step_m))
    ins = shapely.contains_xy(shapely.Polygon(ring), gx, gy)
    x, y = gx[ins], gy[ins]
    if fit == "plane":  # the least-squares plane through the ring's true heights
        A = np.column_stack([np.ones(len(ring)), ring])
        coef = np.linalg.lstsq(A, zr, rcond=None)[0]
        base = coef[0] + coef[1] * x + coef[2] * y
    else:
        base = LinearNDInterpolator(ring, zr)(x, y)
    a = step_m * step_m
    above = float(np.sum(scene.terrain_height(x, y) - base) * a)
    pile = float(scene.stockpiles.volume()[i])
    return {"pile": pile, "above_toe_base": above, "base_error": above - pile}
