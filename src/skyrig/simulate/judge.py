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


# ------------------------------------------------------------------------------------------ orthophotos
def true_surface_rgb(scene: Scene, x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
    """Colour ``(N, 3)`` in [0, 1] of the visible top surface seen from straight above at local ``x, y``: the
    ground or roof texture times the renderer's Lambertian shading (so a perfect orthophoto equals it up to image
    noise)."""
    b = scene.buildings
    _, bidx = b.top_height(x, y)
    rgb = scene.ground_rgb(x, y)
    gx, gy = scene.terrain_gradient(x, y)
    n = np.stack([-np.asarray(gx, float), -np.asarray(gy, float), np.ones_like(x)], 1)
    on = bidx >= 0
    if np.any(on):
        i = bidx[on]
        rgb[on] = scene.roof_rgb(i, x[on], y[on])
        a = b.azimuth_rad[i]
        uyx, uyy = -np.sin(a), np.cos(a)
        v = -(x[on] - b.cx[i]) * np.sin(a) + (y[on] - b.cy[i]) * np.cos(a)
        rise = b.ridge_z[i] - b.eave_z[i]
        s = np.sign(v)
        n[on] = np.stack([s * uyx * rise, s * uyy * rise, b.hw[i]], 1)
        flat = rise <= 1e-9
        n[np.flatnonzero(on)[flat]] = [0.0, 0.0, 1.0]
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    lam = np.clip(n @ scene.sun, 0.0, 1.0)
    return np.clip(rgb * (0.45 + 0.6 * lam)[:, None], 0.0, 1.0)


def roof_outline_offsets(img: NDArray, valid: NDArray[np.bool_], grid: Any, frame: WorldFrame, scene: Scene, *,
                         search_cells: float = 8.0, reach_cells: float = 8.0, min_contrast_dn: float = 8.0,
                         sub: int = 5, blur_cells: float = 0.6, buildings: Any = None) -> list[dict[str, Any]]:
    """Where each true roof corner lies in an orthophoto, located by the roof outline's edges.

    For every eave corner of every scene building, the two roof sides that meet there are located in the mosaic:
    along the half of each side next to the corner (from 2 cells off the corner), profiles across the side
    (``reach_cells`` either way) are compared with the scene's true top-surface colours along the same lines (the
    truth seen through a cell: a one-cell box and a Gaussian of ``blur_cells``), shifted across the side by up to
    ``search_cells`` in 1/``sub`` cell steps; the shift with the least squared residual (a gain and an offset per
    colour channel fitted; sub-step by a parabola) is the side's outward offset.  Every line must see at least 2
    cells on both sides of the true edge; samples the mosaic has no colour for are left out.  The corner's offset
    is the sum of the two sides' offsets along their outward normals (the sides are perpendicular).

    Colour is used, not grey: roofs of the same brightness as the ground around them still differ in hue.  A
    side whose truth shows less than ``min_contrast_dn`` colour difference across it is not judged.

    ``buildings``: indices of the scene buildings to judge (default all).

    Returns one dict per corner: ``building``, ``corner``, ``status`` (``ok``, ``no data`` - a side's outside or
    inside not seen, ``low contrast``, ``at search limit``), and when located ``d_sides_m`` (outward offsets of the
    two sides, frame metres), ``offset_m`` (the corner's shift in the scene's local x, y) and ``contrast_dn``.
    """
    from scipy import ndimage

    local = WorldFrame.local(*scene.origin)
    b = scene.buildings
    cell = grid.cell_m
    ds = cell / sub
    im = np.asarray(img, np.float64)
    if im.ndim == 2:
        im = im[..., None]
    nch = im.shape[2]
    vf = np.asarray(valid, np.float32)
    res: list[dict[str, Any]] = []

    def to_cells(P: NDArray) -> tuple[NDArray, NDArray]:
        M = frame.from_ecef(local.to_ecef(P))
        return (grid.y0 - M[:, 1]) / cell - 0.5, (M[:, 0] - grid.x0) / cell - 0.5

    def side_offset(side: tuple, from_start: bool) -> tuple:
        p, q, L, t, n, other = side
        reach = min(reach_cells * cell, 0.45 * other)
        nS, nR = int(round(search_cells * cell / ds)), int(round(reach / ds))
        al = np.arange(max(2.0 * cell, 0.05 * L), 0.5 * L, cell)
        if len(al) < 4 or nR < 2 * sub + 1:
            return ("no data",)
        base = p[None] + al[:, None] * t if from_start else q[None] - al[:, None] * t
        s_t = np.arange(-nR - nS, nR + nS + 1) * ds
        P = (base[:, None, :] + s_t[None, :, None] * n[None, None, :]).reshape(-1, 2)
        no = 2 * nR + 1
        # the mosaic along the unshifted lines
        Pc = (base[:, None, :] + s_t[None, nS:nS + no, None] * n[None, None, :]).reshape(-1, 2)
        rr, cc = to_cells(np.c_[Pc, scene.surface_height(Pc[:, 0], Pc[:, 1])])
        m = (ndimage.map_coordinates(vf, [rr, cc], order=1, cval=0.0) > 0.999).reshape(len(al), no)
        both = m[:, nR - 2 * sub:nR].all(1) & m[:, nR + 1:nR + 1 + 2 * sub].all(1)
        if both.sum() < 3:
            return ("no data",)
        m &= both[:, None]
        tru = (true_surface_rgb(scene, P[:, 0], P[:, 1]) * 255.0).reshape(len(al), len(s_t), 3)
        tru = ndimage.uniform_filter1d(tru, sub, axis=1, mode="nearest")
        tru = ndimage.gaussian_filter1d(tru, blur_cells * sub, axis=1, mode="nearest")
        if nch == 1:
            tru = tru.mean(axis=2, keepdims=True)
        ctr = tru[:, nS:nS + no]
        contrast = float(np.linalg.norm(ctr[both, nR - 2 * sub:nR].mean((0, 1))
                                        - ctr[both, nR + 1:nR + 1 + 2 * sub].mean((0, 1))))
        if contrast < min_contrast_dn:
            return ("low contrast", contrast)
        Y = np.stack([ndimage.map_coordinates(im[..., c], [rr, cc], order=1) for c in range(nch)], -1)
        Y = Y.reshape(len(al), no, nch)
        w = m.astype(np.float64)[..., None]
        sw = w.sum((0, 1))
        sy = (w * Y).sum((0, 1))
        cost = np.full(2 * nS + 1, np.inf)
        for j, sh in enumerate(range(-nS, nS + 1)):
            X = tru[:, nS - sh:nS - sh + no]  # the truth moved outward by sh samples
            sx, sxx, sxy = (w * X).sum((0, 1)), (w * X * X).sum((0, 1)), (w * X * Y).sum((0, 1))
            vx = sxx - sx * sx / sw
            a = np.where(vx > 1e-9, (sxy - sx * sy / sw) / np.maximum(vx, 1e-9), 0.0)
            if np.any(a <= 0.2):
                continue  # not the truth's pattern (or inverted)
            cost[j] = float((w * (Y - a * X - (sy - a * sx) / sw) ** 2).sum())
        if not np.isfinite(cost).any():
            return ("no data",)
        j = int(np.argmin(cost))
        f = 0.0
        if 0 < j < len(cost) - 1 and np.isfinite(cost[j - 1]) and np.isfinite(cost[j + 1]):
            den = cost[j - 1] - 2 * cost[j] + cost[j + 1]
            if den > 0:
                f = 0.5 * (cost[j - 1] - cost[j + 1]) / den
        return ("ok" if 0 < j < len(cost) - 1 else "at search limit", (j - nS + f) * ds, contrast)

    for i in (range(len(b)) if buildings is None else [int(k) for k in buildings]):
        V = b.vertices(i)[4:8, :2]
        ctr_b = np.array([b.cx[i], b.cy[i]])
        sides = []
        for k in range(4):
            p, q = V[k], V[(k + 1) % 4]
            L = float(np.linalg.norm(q - p))
            t = (q - p) / L
            n = np.array([t[1], -t[0]])
            if n @ (0.5 * (p + q) - ctr_b) < 0:
                n = -n
            sides.append((p, q, L, t, n, float(np.linalg.norm(V[(k + 2) % 4] - q))))
        got = [(side_offset(s, True), side_offset(s, False)) for s in sides]
        for k in range(4):
            ka, kb = k, (k - 1) % 4  # corner k starts side k and ends side k - 1
            ra, rb = got[ka][0], got[kb][1]
            rec: dict[str, Any] = {"building": i, "corner": k, "xy": V[k].tolist()}
            st = [ra[0], rb[0]]
            rec["status"] = next((s for s in ("no data", "low contrast", "at search limit") if s in st), "ok")
            if ra[0] in ("ok", "at search limit") and rb[0] in ("ok", "at search limit"):
                dvec = ra[1] * sides[ka][4] + rb[1] * sides[kb][4]
                rec.update(d_sides_m=[float(ra[1]), float(rb[1])], offset_m=[float(dvec[0]), float(dvec[1])],
                           contrast_dn=[float(ra[2]), float(rb[2])])
            res.append(rec)
    return res


def _shift(a: NDArray[np.float64], b: NDArray[np.float64]) -> tuple[float, float, float]:
    """Translation (dx, dy) in cells that moves ``b`` onto ``a`` (phase correlation, Hanning window), response."""
    import cv2

    win = cv2.createHanningWindow((a.shape[1], a.shape[0]), cv2.CV_64F)
    (dx, dy), resp = cv2.phaseCorrelate(np.ascontiguousarray(b, np.float64), np.ascontiguousarray(a, np.float64), win)
    return float(dx), float(dy), float(resp)


def _masked_match(search: NDArray[np.float64], templ: NDArray[np.float64], mask: NDArray[np.bool_]
                  ) -> tuple[float, float]:
    """Sub-cell shift (dx, dy) of ``templ`` (where ``mask``) inside ``search`` relative to its centred position."""
    import cv2

    res = cv2.matchTemplate(search.astype(np.float32), templ.astype(np.float32), cv2.TM_SQDIFF,
                            mask=mask.astype(np.float32))
    y, x = np.unravel_index(np.argmin(res), res.shape)

    def vertex(a: float, b: float, c: float) -> float:
        den = a - 2 * b + c
        return 0.0 if den <= 0 else 0.5 * (a - c) / den

    fx = vertex(res[y, x - 1], res[y, x], res[y, x + 1]) if 0 < x < res.shape[1] - 1 else 0.0
    fy = vertex(res[y - 1, x], res[y, x], res[y + 1, x]) if 0 < y < res.shape[0] - 1 else 0.0
    cy, cx = (res.shape[0] - 1) / 2.0, (res.shape[1] - 1) / 2.0
    return float(x + fx - cx), float(y + fy - cy)


def judge_ortho(rgb: NDArray[np.uint8], valid: NDArray[np.bool_], source: NDArray, grid: Any, frame: WorldFrame,
                scene: Scene, gsd_m: float, *, eo_local: Any = None, cameras: Any = None, surface: Any = None,
                noise_dn: float = 1.0,
                tile: int = 128, corner_win: int = 24, corner_search: int = 12, seam_band: int = 3,
                seam_gap: int = 4) -> dict[str, Any]:
    """Compare an orthomosaic with the scene's true top-surface colours.

    Parameters
    ----------
    rgb, valid, source, grid, frame
        The mosaic (``source``: image index per cell, -1 no surface, -2 a surface no image sees) on a :class:`~skyrig.dense.grid.GridSpec` in a map
        frame; cells are converted rigorously to the scene's local frame.
    scene
        The simulated world.
    gsd_m
        Ground sample distance the offsets are expressed in.
    eo_local, cameras
        TRUE orientations in the scene's local frame and the cameras: with them, cells hidden from their best image
        (least off-nadir image that has the cell in its frame) are found by casting rays in the scene, and the
        share of them that got their right colour from another image is reported.
    surface
        ``(rows, cols)`` bool, optional: cells where the mosaic has a surface height (the DSM's extent); hidden cells
        outside it are not counted.  Default: ``source != -1``.
    noise_dn
        The images' noise (digital numbers): the yardstick of the seam colour step.
    seam_band, seam_gap
        The colour step across a seamline compares the residuals (mosaic - truth) of two bands ``seam_band`` cells
        wide, ``seam_gap`` cells away on either side (beyond the blend), averaged per pair of images.

    Returns
    -------
    dict
        ``tiles`` (phase-correlation offset per tile of ``tile`` cells: ``n``, ``rms_gsd``, ``max_gsd``),
        ``roof_corners`` (where each true roof corner lies in the mosaic, by the roof outline's edges,
        :func:`roof_outline_offsets`: ``n`` judged corners of ``corners``, ``not_judged`` by reason, ``rms_gsd``,
        ``max_gsd``, ``within_1gsd``, ``side_outward_median_gsd`` (roofs grown > 0 / shrunk < 0), ``worst``
        (offset, building, corner)), ``roof_corners_template`` (the earlier measure: the roof's texture near each
        corner found by masked template matching; unreliable on roofs of low texture contrast, kept for comparison),
        ``occluded`` (``n``, ``filled``, ``correct``), ``seams`` (``pairs``, ``step_max_dn``, ``step_rms_dn``,
        ``noise_dn``, ``step_lower_max_dn``: the largest per-pair step less twice its standard error over the seam's
        samples - a step the samples show to be at least that large), ``colour`` (median absolute difference in DN over valid cells).
    """
    from scipy import ndimage

    local = WorldFrame.local(*scene.origin)
    H, W = valid.shape
    if surface is None:
        surface = np.asarray(source) != -1
    xx, yy = grid.cell_centres()
    z0 = float(np.mean(scene.terrain_range))
    # map -> local at the true surface height: two passes (the map vertical leans slightly from the local one)
    P = np.stack([xx.ravel(), yy.ravel(), np.full(xx.size, z0)], 1)
    L = local.from_ecef(frame.to_ecef(P))
    for _ in range(2):
        zt = scene.surface_height(L[:, 0], L[:, 1])
        h_map = frame.from_ecef(local.to_ecef(np.stack([L[:, 0], L[:, 1], zt], 1)))[:, 2]
        L = local.from_ecef(frame.to_ecef(np.stack([xx.ravel(), yy.ravel(), h_map], 1)))
    truth = (true_surface_rgb(scene, L[:, 0], L[:, 1]) * 255.0).reshape(H, W, 3)
    img = rgb.astype(np.float64)
    out: dict[str, Any] = {"gsd_m": gsd_m, "cell_m": grid.cell_m}
    diff = np.abs(img - truth).mean(axis=2)
    out["colour"] = {"median_abs_dn": float(np.median(diff[valid])) if valid.any() else float("nan")}
    g_img, g_tru = img.mean(axis=2), truth.mean(axis=2)
    scale = grid.cell_m / gsd_m
    # 1. per-tile offsets
    offs = []
    for r in range(0, H - tile + 1, tile):
        for c in range(0, W - tile + 1, tile):
            if valid[r:r + tile, c:c + tile].mean() < 0.98:
                continue
            dx, dy, resp = _shift(g_img[r:r + tile, c:c + tile], g_tru[r:r + tile, c:c + tile])
            if resp > 0.05:
                offs.append(np.hypot(dx, dy) * scale)
    o = np.array(offs)
    out["tiles"] = {"n": len(o), "rms_gsd": float(np.sqrt(np.mean(o ** 2))) if len(o) else float("nan"),
                    "max_gsd": float(o.max()) if len(o) else float("nan")}
    # 2. roof corners: the roof's own texture near each corner (the rest masked out) found in the mosaic by masked
    #    template matching over +-search cells; a leaning roof (a classic ortho) moves by its height x tan(view angle)
    b = scene.buildings
    _, bidx_all = b.top_height(L[:, 0], L[:, 1])
    bidx_all = bidx_all.reshape(H, W)
    coffs: list[float] = []
    worst: list[tuple[float, int]] = []
    h2, R = corner_win // 2, corner_search
    for i in range(len(b)):
        own = ndimage.binary_erosion(bidx_all == i, iterations=1)
        cm = frame.from_ecef(local.to_ecef(b.vertices(i)[4:8]))
        rr, cc = grid.cell_of(cm[:, 0], cm[:, 1])
        for r, c in zip(rr, cc):
            if r - h2 - R < 0 or c - h2 - R < 0 or r + h2 + R > H or c + h2 + R > W:
                continue
            win = (slice(r - h2, r + h2), slice(c - h2, c + h2))
            big = (slice(r - h2 - R, r + h2 + R), slice(c - h2 - R, c + h2 + R))
            m = own[win]
            if m.sum() < 30 or valid[big].mean() < 0.97 or not valid[win][m].all() or g_tru[win][m].std() < 3.0:
                continue
            srch = np.where(valid[big], g_img[big], g_tru[win][m].mean())
            dx, dy = _masked_match(srch, g_tru[win], m)
            d = float(np.hypot(dx, dy) * scale)
            coffs.append(d)
            worst.append((round(d, 2), i))
    co = np.array(coffs)
    out["roof_corners_template"] = {
        "n": len(co), "rms_gsd": float(np.sqrt(np.mean(co ** 2))) if len(co) else float("nan"),
        "max_gsd": float(co.max()) if len(co) else float("nan"),
        "within_1gsd": float(np.mean(co <= 1.0)) if len(co) else float("nan"), "worst": sorted(worst, reverse=True)[:5]}
    # 2b. roof corners located by the roof outline's edges (the judged figure: the template above is unreliable on
    #     roofs of low texture contrast)
    rec = roof_outline_offsets(img, valid, grid, frame, scene)
    okc = [r for r in rec if r["status"] == "ok"]
    d = np.array([np.hypot(*r["offset_m"]) for r in okc]) / gsd_m
    sides = np.array([r["d_sides_m"] for r in okc]).ravel() / gsd_m
    out["roof_corners"] = {
        "method": "roof outline edges", "n": len(d), "corners": len(rec),
        "not_judged": {s_: sum(r["status"] == s_ for r in rec)
                       for s_ in ("no data", "low contrast", "at search limit")},
        "rms_gsd": float(np.sqrt(np.mean(d ** 2))) if len(d) else float("nan"),
        "max_gsd": float(d.max()) if len(d) else float("nan"),
        "within_1gsd": float(np.mean(d <= 1.0)) if len(d) else float("nan"),
        "side_outward_median_gsd": float(np.median(sides)) if len(sides) else float("nan"),
        "worst": sorted(((round(float(x), 2), r["building"], r["corner"]) for x, r in zip(d, okc)), reverse=True)[:5]}
    # 3. cells hidden from their best image
    if eo_local is not None and cameras is not None:
        from skyrig.simulate.render import cast_rays

        sub = (slice(None, None, 2), slice(None, None, 2))
        Lg = L.reshape(H, W, 3)[sub].reshape(-1, 3)
        Lg = np.stack([Lg[:, 0], Lg[:, 1], scene.surface_height(Lg[:, 0], Lg[:, 1])], 1)
        best_tan = np.full(len(Lg), np.inf)
        best = np.full(len(Lg), -1)
        for k in range(len(eo_local)):
            cam = cameras[str(eo_local.camera[k])]
            rel = Lg - eo_local.centre[k]
            pc = rel @ eo_local.rotation[k]
            with np.errstate(invalid="ignore", divide="ignore"):
                uv = cam.project_pixels(pc)
                tan = np.hypot(rel[:, 0], rel[:, 1]) / np.maximum(-rel[:, 2], 1e-9)
            inside = (pc[:, 2] < 0) & cam.in_image(uv) & (rel[:, 2] < 0)
            better = inside & (tan < best_tan)
            best_tan[better] = tan[better]
            best[better] = k
        def sees(k: int, sel: NDArray[np.intp]) -> NDArray[np.bool_]:
            o_ = eo_local.centre[k]
            d = Lg[sel] - o_
            dist = np.linalg.norm(d, axis=1)
            return cast_rays(scene, o_, d / dist[:, None]).t >= dist - 0.05

        hidden = np.zeros(len(Lg), bool)
        for k in np.unique(best[best >= 0]):
            sel = np.flatnonzero(best == k)
            hidden[sel] = ~sees(int(k), sel)
        # ... and seen by another image (only those can be filled)
        other = np.zeros(len(Lg), bool)
        hid = np.flatnonzero(hidden)
        for k in range(len(eo_local)):
            cam = cameras[str(eo_local.camera[k])]
            cand = hid[(best[hid] != k) & ~other[hid]]
            if len(cand) == 0:
                continue
            pc = (Lg[cand] - eo_local.centre[k]) @ eo_local.rotation[k]
            with np.errstate(invalid="ignore", divide="ignore"):
                inside = (pc[:, 2] < 0) & cam.in_image(cam.project_pixels(pc))
            if inside.any():
                c2 = cand[inside]
                other[c2] = sees(k, c2)
        hidden &= other
        if surface is not None:
            hidden &= np.asarray(surface, bool)[sub].ravel()
        vsub = valid[sub].ravel()
        dsub = diff[sub].ravel()
        n_h = int(hidden.sum())
        out["occluded"] = {"n": n_h, "filled": float(np.mean(vsub[hidden])) if n_h else float("nan"),
                           "correct": float(np.mean(vsub[hidden] & (dsub[hidden] < 12.0 + 3 * noise_dn)))
                           if n_h else float("nan")}
    # 4. colour step across seamlines (ground cells, residual against the truth on both sides)
    res = img - truth
    ground = ~ndimage.binary_dilation(bidx_all >= 0, iterations=seam_band + seam_gap + 2)
    src = np.where(valid, source, -1)
    steps = []
    pairs: dict[tuple[int, int], list[NDArray]] = {}
    for axis in (0, 1):
        a = src[:-1, :] if axis == 0 else src[:, :-1]
        bb = src[1:, :] if axis == 0 else src[:, 1:]
        m = (a >= 0) & (bb >= 0) & (a != bb)
        m &= (ground[:-1, :] & ground[1:, :]) if axis == 0 else (ground[:, :-1] & ground[:, 1:])
        rr, cc = np.nonzero(m)
        for r, c in zip(rr, cc):
            g0, g1 = seam_gap, seam_gap + seam_band  # bands beyond the blend on either side
            if axis == 0:
                if r - g1 + 1 < 0 or r + 1 + g1 > H:
                    continue
                lo, hi = (slice(r - g1 + 1, r - g0 + 1), c), (slice(r + 1 + g0, r + 1 + g1), c)
            else:
                if c - g1 + 1 < 0 or c + 1 + g1 > W:
                    continue
                lo, hi = (r, slice(c - g1 + 1, c - g0 + 1)), (r, slice(c + 1 + g0, c + 1 + g1))
            if not (valid[lo].all() and valid[hi].all()):
                continue
            key = (int(a[r, c]), int(bb[r, c]))
            if key[0] > key[1]:
                key, lo, hi = (key[1], key[0]), hi, lo
            pairs.setdefault(key, []).append(res[hi].mean(axis=0) - res[lo].mean(axis=0))
    lows = []  # per pair: the step less twice its standard error (what the samples rule out as too small)
    for key, v in pairs.items():
        if len(v) >= 30:
            va = np.asarray(v)
            m, se = np.abs(va.mean(axis=0)), va.std(axis=0, ddof=1) / np.sqrt(len(va))
            steps.append(m.max())
            lows.append(float(np.max(m - 2.0 * se)))
    s = np.array(steps)
    out["seams"] = {"pairs": len(s), "step_max_dn": float(s.max()) if len(s) else float("nan"),
                    "step_rms_dn": float(np.sqrt(np.mean(s ** 2))) if len(s) else float("nan"), "noise_dn": noise_dn,
                    "step_lower_max_dn": float(max(lows)) if lows else float("nan")}
    return out


def true_dsm(scene: Scene, grid: Any, frame: WorldFrame) -> DsmGrid:
    """The scene's true surface sampled at the cell centres of a map grid (heights in ``frame``'s reference)."""
    from skyrig.dense.surface import vertical_reference

    local = WorldFrame.local(*scene.origin)
    xx, yy = grid.cell_centres()
    z0 = float(np.mean(scene.terrain_range))
    L = local.from_ecef(frame.to_ecef(np.stack([xx.ravel(), yy.ravel(), np.full(xx.size, z0)], 1)))
    for _ in range(3):
        zt = scene.surface_height(L[:, 0], L[:, 1])
        h_map = frame.from_ecef(local.to_ecef(np.stack([L[:, 0], L[:, 1], zt], 1)))[:, 2]
        L = local.from_ecef(frame.to_ecef(np.stack([xx.ravel(), yy.ravel(), h_map], 1)))
    h = h_map.reshape(xx.shape).astype(np.float32)
    shp = xx.shape
    return DsmGrid(grid, frame, h, np.full(shp, 9, np.int16), np.zeros(shp, np.float32), np.zeros(shp, np.float32),
                   np.zeros(shp, bool), vertical_reference(frame), {"truth": True})
