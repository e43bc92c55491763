"""Products of a simulated survey judged against the scene's truth (the analytic surface, not a raster).

Used by tests and ``make demo``; everything here compares a product with :class:`skyrig.simulate.world.Scene`
quantities that the product's code never sees.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from skyrig.dense.grid import DenseCloud, DsmGrid
from skyrig.georef.eo import WorldFrame
from skyrig.simulate.world import Scene


def _nmad(e: NDArray[np.float64]) -> float:
    return float(1.4826 * np.median(np.abs(e - np.median(e)))) if len(e) else float("nan")


def judge_dsm(dsm: DsmGrid, scene: Scene, gsd_m: float, area_local: tuple[float, float, float, float],
              edge_gsd: float = 2.0) -> dict[str, Any]:
    """Compare a DSM with the scene's true surface inside an area of the scene's local frame.

    Parameters
    ----------
    dsm
        The DSM (any map frame; cell centres are converted rigorously to the scene's local frame).
    scene
        The simulated world (true surface heights and building footprints).
    gsd_m
        Ground sample distance the figures are expressed in.
    area_local
        ``(xmin, ymin, xmax, ymax)`` of the evaluated area in the scene's local frame (e.g. the planned block).
    edge_gsd
        Cells within this many GSD of a building outline are "edge" cells; the others are "flat".

    Returns
    -------
    dict
        For ``all``, ``flat`` and ``edge`` cells: ``n`` (cells in the area), ``completeness``, ``bias_m``
        (median error), ``nmad_m``, ``rmse_m``, ``outliers`` (share of valid cells off by more than 5 GSD),
        the same in GSD units (``*_gsd``).
    """
    from scipy import ndimage

    local = WorldFrame.local(*scene.origin)
    xx, yy = dsm.grid.cell_centres()
    h = dsm.height.astype(np.float64)
    z_guess = np.where(np.isfinite(h), h, np.nanmedian(h) if np.isfinite(h).any() else 0.0)
    L = local.from_ecef(dsm.frame.to_ecef(np.stack([xx.ravel(), yy.ravel(), z_guess.ravel()], 1)))
    lx, ly = L[:, 0].reshape(xx.shape), L[:, 1].reshape(xx.shape)
    inside = (lx >= area_local[0]) & (lx <= area_local[2]) & (ly >= area_local[1]) & (ly <= area_local[3])
    _, bidx = scene.buildings.top_height(lx.ravel(), ly.ravel())
    on_bld = (bidx >= 0).reshape(xx.shape)
    cell = dsm.grid.cell_m
    d_out = ndimage.distance_transform_edt(~on_bld) * cell
    d_in = ndimage.distance_transform_edt(on_bld) * cell
    edge = np.where(on_bld, d_in, d_out) <= edge_gsd * gsd_m
    err = np.full(xx.shape, np.nan)
    ok = np.isfinite(h)
    err[ok] = L[ok.ravel(), 2] - scene.surface_height(L[ok.ravel(), 0], L[ok.ravel(), 1])
    out: dict[str, Any] = {"gsd_m": gsd_m, "cell_m": cell}
    for name, m in (("all", inside), ("flat", inside & ~edge), ("edge", inside & edge)):
        e = err[m & ok]
        n = int(m.sum())
        r = {"n": n, "valid": int(len(e)), "completeness": float(len(e) / n) if n else float("nan"),
             "bias_m": float(np.median(e)) if len(e) else float("nan"), "nmad_m": _nmad(e),
             "rmse_m": float(np.sqrt(np.mean(e ** 2))) if len(e) else float("nan"),
             "outliers": float(np.mean(np.abs(e) > 5 * gsd_m)) if len(e) else float("nan")}
        for k in ("bias_m", "nmad_m", "rmse_m"):
            r[k.replace("_m", "_gsd")] = r[k] / gsd_m
        out[name] = r
    return out


def cloud_to_surface(cloud: DenseCloud, scene: Scene) -> NDArray[np.float64]:
    """Vertical distance (m) of every cloud point from the true 2.5D surface (positive above)."""
    local = WorldFrame.local(*scene.origin)
    L = local.from_ecef(cloud.frame.to_ecef(cloud.xyz))
    return L[:, 2] - scene.surface_height(L[:, 0], L[:, 1])
