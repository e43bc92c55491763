"""Judges of building extraction and façade textures against a simulated scene's analytic truth.

The truth is :class:`skyrig.simulate.world.Scene`: its buildings (convex prisms, :class:`~skyrig.simulate.world.Buildings`)
and its façade rule :meth:`~skyrig.simulate.world.Scene.facade_rgb` (a window grid of ``window_spacing_m``, a
function of the building, the along-wall coordinate ``u = -n_y x + n_x y`` of the wall's outward normal ``n``
and the height).  Textures and buildings may be in any frame (a map CRS or the scene's local ENU frame): their
points are converted rigorously (through ECEF) to the scene's local frame before they meet the rule.

* :func:`scene_dsm` rasterises the analytic surface on a grid of any frame (a DSM free of matching errors);
* :func:`true_buildings` gives the scene's buildings as :class:`~skyrig.dense.buildings.BuildingBlock`;
* :func:`judge_extraction` matches extracted buildings to the true ones (corners, heights);
* :func:`judge_facade` renders the rule on a texture's own texel grid and measures the texture's geometric
  offset: by least-squares alignment over the façade (:func:`_align`), and per window by locating its four edges (sub-texel
  gradient peaks of row / column profiles) in the texture and in the rule's rendering.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from skyrig.dense.buildings import BuildingBlock, FacadeTexture
from skyrig.dense.grid import DsmGrid, GridSpec
from skyrig.georef.eo import WorldFrame
from skyrig.simulate.world import Scene


def _local(scene: Scene) -> WorldFrame:
    return WorldFrame.local(*scene.origin)


def _convert(frame: WorldFrame, other: WorldFrame, xyz: NDArray) -> NDArray[np.float64]:
    xyz = np.asarray(xyz, float)
    if frame == other:
        return xyz.copy()
    return other.from_ecef(frame.to_ecef(xyz.reshape(-1, 3))).reshape(xyz.shape)


def scene_dsm(scene: Scene, grid: GridSpec, frame: WorldFrame | None = None) -> DsmGrid:
    """The scene's analytic surface (roofs, terrain) sampled at the cell centres of ``grid`` in ``frame``.

    For a map frame the height of each cell is found by fixed-point iteration: the map point ``(x, y, H)``
    is converted to the local frame and ``H`` moved by the local height difference to the surface there
    (converges to well below a millimetre in 4 steps: the frames' verticals differ by ~ distance / R)."""
    loc = _local(scene)
    frame = frame or loc
    xx, yy = grid.cell_centres()
    x, y = xx.ravel(), yy.ravel()
    if frame == loc:
        z = scene.surface_height(x, y)
    else:
        from skyrig.dense.surface import FrameMap

        b = grid.bounds
        zr = (scene.terrain_range[0] - 5.0, scene.top + 5.0)
        lo = _convert(loc, frame, np.array([[0.0, 0.0, zr[0]], [0.0, 0.0, zr[1]]]))[:, 2]
        to_local = FrameMap(frame, loc, (b[0], b[1], float(lo.min()) - 50, b[2], b[3], float(lo.max()) + 50))
        z = np.full(x.shape, float(lo.mean()))
        for _ in range(5):
            p = to_local(np.column_stack([x, y, z]))
            z = z + (scene.surface_height(p[:, 0], p[:, 1]) - p[:, 2])
    shape = grid.shape
    hgt = z.reshape(shape).astype(np.float32)
    from skyrig.dense.surface import vertical_reference

    vref = vertical_reference(frame) if frame.kind == "map" else frame.describe()
    return DsmGrid(grid, frame, hgt, np.ones(shape, np.int16), np.full(shape, np.nan, np.float32),
                   np.zeros(shape, np.float32), np.zeros(shape, bool), vref, {"source": "analytic scene surface"})


def true_buildings(scene: Scene, frame: WorldFrame | None = None) -> list[BuildingBlock]:
    """The scene's buildings in ``frame`` (default: the scene's local frame), ids = scene building indices.

    Footprints are the true rectangles (CCW); ``ground_z`` the lowest terrain height at the four corners (the
    walls' visible bottom), ``eave_z`` the eaves; roofs one flat polygon or the two gable planes."""
    loc = _local(scene)
    frame = frame or loc
    bl = scene.buildings
    out = []
    for i in range(len(bl)):
        v = bl.vertices(i)
        fp = v[:4, :2][::-1]  # vertices() lists them clockwise
        tz = scene.terrain_height(fp[:, 0], fp[:, 1])
        gz, ez, rz = float(tz.min()), float(bl.eave_z[i]), float(bl.ridge_z[i])
        a = bl.azimuth_rad[i]
        ux = np.array([np.cos(a), np.sin(a)])
        uy = np.array([-np.sin(a), np.cos(a)])
        c = np.array([bl.cx[i], bl.cy[i]])
        if bl.gabled[i]:
            hl, hw = bl.hl[i], bl.hw[i]
            pt = lambda sa, sb, z: np.r_[c + sa * hl * ux + sb * hw * uy, z]  # noqa: E731
            roofs = [np.array([pt(-1, 0, rz), pt(1, 0, rz), pt(1, 1, ez), pt(-1, 1, ez)]),
                     np.array([pt(-1, -1, ez), pt(1, -1, ez), pt(1, 0, rz), pt(-1, 0, rz)])]
        else:
            roofs = [np.column_stack([fp, np.full(4, ez)])]
        # to the frame: the footprint at the eaves and the ground heights at the footprint's centre
        fpm = _convert(loc, frame, np.column_stack([fp, np.full(4, ez)]))
        zz = _convert(loc, frame, np.array([[c[0], c[1], gz], [c[0], c[1], ez]]))[:, 2]
        roofs = [_convert(loc, frame, r) for r in roofs]
        out.append(BuildingBlock(i, fpm[:, :2], float(zz[0]), float(zz[1]), tuple(roofs), "scene"))
    return out


def judge_extraction(scene: Scene, buildings: list[BuildingBlock], frame: WorldFrame,
                     max_match_m: float = 5.0) -> dict:
    """Extracted buildings against the scene's: each true building whose centre lies within ``max_match_m`` of an
    extracted footprint's centroid is matched; for matched rectangles every true corner's distance to the
    nearest extracted corner, and the ground / eave height differences (extracted - true, frame metres).

    Returns a dict: ``matched``, ``true``, ``extracted``, ``corner_err_m`` (all corners), ``ground_err_m``,
    ``eave_err_m``, ``gabled_right`` (roof type agrees), ``pairs`` (extracted id, true id)."""
    truth = true_buildings(scene, frame)
    tc = np.array([t.footprint.mean(axis=0) for t in truth]) if truth else np.zeros((0, 2))
    corner, ground, eave, pairs, kind_ok = [], [], [], [], []
    used: set[int] = set()
    for b in buildings:
        if not len(tc):
            break
        c = np.asarray(b.footprint).mean(axis=0)
        j = int(np.argmin(np.linalg.norm(tc - c, axis=1)))
        if np.linalg.norm(tc[j] - c) > max_match_m or j in used:
            continue
        used.add(j)
        t = truth[j]
        pairs.append((b.id, t.id))
        corner.extend(float(np.min(np.linalg.norm(np.asarray(b.footprint) - p, axis=1))) for p in t.footprint)
        ground.append(b.ground_z - t.ground_z)
        eave.append(b.eave_z - t.eave_z)
        kind_ok.append(len(b.roof) == len(t.roof))
    return {"matched": len(pairs), "true": len(truth), "extracted": len(buildings), "corner_err_m": np.array(corner),
            "ground_err_m": np.array(ground), "eave_err_m": np.array(eave), "gabled_right": np.array(kind_ok),
            "pairs": pairs}


@dataclass
class FacadeJudgement:
    """A façade texture against the rule.

    Attributes
    ----------
    building, index
        The façade (:class:`~skyrig.dense.buildings.Facade`).
    true_building, true_face
        The scene's wall it was matched to (-1 if none).
    coverage
        Fraction of the texels on the true wall (above the terrain) that have a colour.
    offset_px
        ``(dx, dy)`` shift of the texture against the rule's rendering on the same texel grid (:func:`_align`,
        texels; NaN when fewer than 16 texels are valid).
    windows
        Windows of the rule fully inside the valid texture and at least ``min_window_px`` texels in size.
    windows_found
        Windows whose four edges were found in the texture (a gradient peak of the right sign within
        ``search_px`` of the rule's edge).
    windows_within_1px
        Found windows whose four corners are all within 1 texel of the rule's corners.
    corner_err_px
        Per found window the largest corner error (texels).
    """

    building: int
    index: int
    true_building: int
    true_face: int
    coverage: float
    offset_px: tuple[float, float]
    windows: int
    windows_found: int
    windows_within_1px: int
    corner_err_px: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))

    @property
    def offset_norm_px(self) -> float:
        return float(np.hypot(*self.offset_px))


def _match_wall(scene: Scene, p_loc: NDArray, n_loc: NDArray) -> tuple[int, int, float]:
    """The scene wall (building, face) nearest to a façade's centre with a normal within 30 deg."""
    bl = scene.buildings
    best = (-1, -1, np.inf)
    for i in range(len(bl)):
        nrm, off, knd = bl.planes(i)
        for f in range(4):
            if nrm[f] @ n_loc < np.cos(np.radians(30)):
                continue
            dist = abs(nrm[f] @ p_loc - off[f])
            a = bl.azimuth_rad[i]
            ux = np.array([np.cos(a), np.sin(a), 0.0])
            uy = np.array([-np.sin(a), np.cos(a), 0.0])
            q = p_loc - np.array([bl.cx[i], bl.cy[i], 0.0])
            lim = max(bl.hl[i], bl.hw[i]) + 1.0
            if abs(q @ ux) > lim or abs(q @ uy) > lim:
                continue
            if dist < best[2]:
                best = (i, f, dist)
    return best


def rule_texture(scene: Scene, texture: FacadeTexture, frame: WorldFrame, supersample: int = 3
                 ) -> tuple[NDArray, NDArray, NDArray, int, int]:
    """The rule's colours on the texture's texel grid (each texel the mean of ``supersample`` x ``supersample``
    point samples, so that window edges fall between samples as they should, without aliasing).

    Every sample point (frame) is converted to the local frame and projected orthogonally onto the matched true
    wall, where the rule gives its colour (times the renderer's Lambertian shading of that wall).

    Returns ``rgb (H, W, 3)`` float in [0, 1], ``on_wall (H, W)`` (texel centre inside the true wall, above the
    terrain; a gabled house's end wall reaches up to its roof line), the ``(H, W, 2)`` rule coordinates ``(u, z)`` of the texel centres, the building and the face
    (-1, -1 if none)."""
    f = texture.facade
    H, W = texture.valid.shape
    t = texture.texel_m
    c = np.asarray(f.corners, float)
    u = (c[1] - c[0]) / np.linalg.norm(c[1] - c[0])
    v = (c[3] - c[0]) / np.linalg.norm(c[3] - c[0])
    loc = _local(scene)
    cl = _convert(frame, loc, np.array([c.mean(axis=0), c.mean(axis=0) + f.normal]))
    n_loc = cl[1] - cl[0]
    n_loc /= np.linalg.norm(n_loc)
    b, face, _ = _match_wall(scene, cl[0], n_loc)
    uz = np.zeros((H, W, 2))
    if b < 0:
        return np.zeros((H, W, 3)), np.zeros((H, W), bool), uz, -1, -1
    bl = scene.buildings
    nrm, off, _ = bl.planes(b)
    n = nrm[face]
    along = np.array([-n[1], n[0], 0.0])
    half = bl.hw[b] if face < 2 else bl.hl[b]
    shade = 0.45 + 0.6 * float(np.clip(n @ scene.sun, 0.0, 1.0))

    def at(dj: float, di: float) -> tuple[NDArray, NDArray, NDArray]:
        jj, ii = np.meshgrid(np.arange(W) + 0.5 + dj, np.arange(H) + 0.5 + di)
        P = c[3] + (jj.reshape(-1, 1) * t) * u - (ii.reshape(-1, 1) * t) * v
        Pl = _convert(frame, loc, P)
        Pp = Pl - ((Pl @ n) - off[face])[:, None] * n[None]
        ur = -n[1] * Pp[:, 0] + n[0] * Pp[:, 1]
        col = scene.facade_rgb(np.full(len(Pp), b), ur, Pp[:, 2], np.full(len(Pp), face)) * shade
        return col, Pp, ur

    _, Pp, ur = at(0.0, 0.0)
    s_ = (Pp - np.array([bl.cx[b], bl.cy[b], 0.0])) @ along
    top = np.full(len(Pp), bl.eave_z[b])
    if bl.gabled[b] and face < 2:  # a gable end (ridge along the building's axis): the wall reaches the roof line
        top = top + (bl.ridge_z[b] - bl.eave_z[b]) * np.clip(1.0 - np.abs(s_) / half, 0.0, 1.0)
    on = (np.abs(s_) <= half) & (Pp[:, 2] >= scene.terrain_height(Pp[:, 0], Pp[:, 1])) & (Pp[:, 2] <= top)
    uz = np.stack([ur, Pp[:, 2]], -1).reshape(H, W, 2)
    k = max(int(supersample), 1)
    offs = (np.arange(k) + 0.5) / k - 0.5
    rgb = np.zeros((H * W, 3))
    for dj in offs:
        for di in offs:
            rgb += at(float(dj), float(di))[0]
    rgb /= k * k
    return np.clip(rgb, 0, 1).reshape(H, W, 3), on.reshape(H, W), uz, b, face


def _edge(profile: NDArray, x0: float, sign: float, search: float) -> tuple[float, float]:
    """Sub-sample position of the strongest gradient of ``sign`` within ``search`` of ``x0`` in a 1-D profile
    (samples at integer positions); returns (position, gradient strength), (NaN, 0) if none."""
    g = np.diff(profile) * sign  # g[k] is the gradient between samples k and k + 1, at k + 0.5
    lo = max(int(np.floor(x0 - 0.5 - search)), 1)
    hi = min(int(np.ceil(x0 - 0.5 + search)), len(g) - 2)
    if hi < lo:
        return np.nan, 0.0
    k = lo + int(np.argmax(g[lo:hi + 1]))
    if g[k] <= 0:
        return np.nan, 0.0
    a, b, c = g[k - 1], g[k], g[k + 1]
    den = a - 2 * b + c
    d = 0.5 * (a - c) / den if den < 0 else 0.0
    return k + 0.5 + float(np.clip(d, -0.5, 0.5)), float(b)


def _window_edges(grey: NDArray, box: tuple[float, float, float, float], search: float, min_grad: float
                  ) -> NDArray[np.float64] | None:
    """Left, right, top, bottom edges (texel coordinates, pixel centres at integers) of a dark window expected
    at ``box = (left, right, top, bottom)``: gradient peaks of the mean profiles across its middle."""
    l, r, t, b = box
    H, W = grey.shape
    rows = slice(int(np.ceil(t + 0.25 * (b - t))), int(np.floor(b - 0.25 * (b - t))) + 1)
    cols = slice(int(np.ceil(l + 0.25 * (r - l))), int(np.floor(r - 0.25 * (r - l))) + 1)
    if rows.stop - rows.start < 1 or cols.stop - cols.start < 1:
        return None
    prow = grey[rows].mean(axis=0)
    pcol = grey[:, cols].mean(axis=1)
    el, gl = _edge(prow, l, -1.0, search)   # wall -> glass: darker
    er, gr = _edge(prow, r, +1.0, search)
    et, gt = _edge(pcol, t, -1.0, search)
    eb, gb = _edge(pcol, b, +1.0, search)
    if min(gl, gr, gt, gb) < min_grad:
        return None
    return np.array([el, er, et, eb])


def _align(rule: NDArray, tex: NDArray, ok: NDArray, search_px: float = 2.5) -> tuple[float, float]:
    """The shift ``(dx, dy)`` (texels) of ``tex`` against ``rule`` (``tex(x) ~ a + b rule(x - d)``): the largest
    correlation over the texels of ``ok`` at least 3 texels from its border, on a grid of 0.25 texel within
    ``search_px``, then of 0.05 texel around the best (the rule shifted by bilinear interpolation).

    A direct least-squares alignment, not phase correlation: OpenCV's phase correlation (Hanning window, sub-pixel
    centroid of the peak) reported 0.77 / 0.81 texel on the 15 x 43 texel texture of a low wall textured from the
    true orientations on the true wall, whose windows lie within 0.2-0.4 texel of the rule and whose best
    correlation is at the zero shift (tests/test_facades.py, wall (19, 2) of the demo town)."""
    import cv2

    H, W = ok.shape
    inner = cv2.erode(ok.astype(np.uint8), np.ones((7, 7), np.uint8), borderType=cv2.BORDER_CONSTANT,
                      borderValue=0).astype(bool)
    if inner.sum() < 16:
        inner = ok
    t = tex[inner] - tex[inner].mean()
    tn = float(np.sqrt(t @ t))
    if tn == 0:
        return 0.0, 0.0

    def corr(dx: float, dy: float) -> float:
        m = np.float32([[1, 0, dx], [0, 1, dy]])
        rs = cv2.warpAffine(rule.astype(np.float32), m, (W, H), flags=cv2.INTER_LINEAR,
                            borderMode=cv2.BORDER_REPLICATE)[inner].astype(np.float64)
        rs -= rs.mean()
        n = float(np.sqrt(rs @ rs))
        return float(t @ rs) / (tn * n) if n > 0 else -1.0

    best = (0.0, 0.0)
    for step, half in ((0.25, search_px), (0.05, 0.25)):
        cx, cy = best
        grid = np.arange(-half, half + 1e-9, step)
        scores = [(corr(cx + gx, cy + gy), cx + gx, cy + gy) for gy in grid for gx in grid]
        _, bx, by = max(scores)
        best = (bx, by)
    return float(best[0]), float(best[1])


def judge_facade(scene: Scene, texture: FacadeTexture, frame: WorldFrame, search_px: float = 2.0,
                 min_grad: float = 0.04, min_window_px: float = 3.0) -> FacadeJudgement:
    """Judge one façade texture against the rule (see :func:`rule_texture`).

    The offset is measured twice: by least-squares alignment (:func:`_align`) of the whole texture (valid texels
    on the true wall) with the rule's rendering, and per window: the window rectangles of the rule (``window_spacing_m``
    grid) at least ``min_window_px`` texels wide and high that lie fully in the valid texture are located in
    the texture by their edges (:func:`_window_edges` on the grey texture, searched ``search_px`` around the
    rule's edges); corner errors are the distances to the rule's corners (texels), which are exact: the window
    rectangle mapped to texel coordinates through the affine map of the texel grid onto the true wall.  A window
    is judged when it and one texel of wall around it are coloured and on the true wall; the edge search sees the
    wall only (texels off the true wall or without colour take the wall's median grey), so a window near the
    ground, the eaves or a wall's end is judged too (a search 2 texels beyond its edges used to exclude those
    within 2 texels of the wall's border: a low wall's whole window rows)."""

    f = texture.facade
    truth, on, uz, b, face = rule_texture(scene, texture, frame)
    H, W = texture.valid.shape
    ok = texture.valid & on
    cov = float(ok.sum() / max(on.sum(), 1))
    if b < 0 or ok.sum() < 16 or min(H, W) < 8:  # a sliver (e.g. a clipped wall): no offset can be measured
        return FacadeJudgement(f.building, f.index, b, face, cov, (np.nan, np.nan), 0, 0, 0)
    grey_t = texture.rgb.astype(np.float64).mean(axis=2) / 255.0
    grey_r = truth.mean(axis=2)
    # the window edges are searched on the true wall only: texels off it (roof, ground, beyond the wall's ends)
    # or without colour take the wall's median grey, which makes no edge
    grey_w = np.where(ok, grey_t, float(np.median(grey_t[ok])))
    m_t = float(grey_t[ok].mean())
    m_r = float(grey_r[ok].mean())
    a = np.where(ok, grey_t, m_t)
    r = np.where(ok, grey_r, m_r)
    dx, dy = _align(r, a, ok)
    # windows of the rule: u in [k sp + 0.3 sp, k sp + 0.7 sp], z - zb - 0.8 in [m sp + 0.35 sp, m sp + 0.8 sp]
    sp = scene.window_spacing_m
    zb = scene.buildings.base_z[b]
    # texel coordinates as an affine function of (u, z): fit on the grid (exact for a plane)
    jj, ii = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    A = np.column_stack([uz[..., 0].ravel(), uz[..., 1].ravel(), np.ones(H * W)])
    cj, *_ = np.linalg.lstsq(A, jj.ravel(), rcond=None)
    ci, *_ = np.linalg.lstsq(A, ii.ravel(), rcond=None)
    u_lo, u_hi = uz[..., 0].min(), uz[..., 0].max()
    z_lo, z_hi = uz[..., 1].min(), uz[..., 1].max()
    n_win = found = within = 0
    errs = []
    for k in range(int(np.floor(u_lo / sp)) - 1, int(np.ceil(u_hi / sp)) + 1):
        for m in range(int(np.floor((z_lo - zb - 0.8) / sp)) - 1, int(np.ceil((z_hi - zb - 0.8) / sp)) + 1):
            u0, u1 = (k + 0.3) * sp, (k + 0.7) * sp
            z0, z1 = zb + 0.8 + (m + 0.35) * sp, zb + 0.8 + (m + 0.8) * sp
            if z0 - zb <= 1.5:
                z0 = max(z0, zb + 1.5)
                if z1 <= z0:
                    continue
            cu = np.array([[u0, z0], [u1, z0], [u1, z1], [u0, z1]])
            cj_ = cu @ cj[:2] + cj[2]
            ci_ = cu @ ci[:2] + ci[2]
            # texel-coordinate box (left, right, top, bottom) of the window (columns may run either way)
            l, rr = float(cj_.min()), float(cj_.max())
            t, bb = float(ci_.min()), float(ci_.max())
            if l < 1 or t < 1 or rr > W - 2 or bb > H - 2:
                continue
            # the window and a texel of wall around it on the valid true wall (its edges need wall beyond them)
            i0, i1 = int(np.floor(t)) - 1, int(np.ceil(bb)) + 2
            j0, j1 = int(np.floor(l)) - 1, int(np.ceil(rr)) + 2
            if not ok[max(i0, 0):i1, max(j0, 0):j1].all():
                continue
            if rr - l < min_window_px or bb - t < min_window_px:
                continue  # the texture is too coarse to show this window
            n_win += 1
            et = _window_edges(grey_w, (l, rr, t, bb), search_px, min_grad)
            if et is None:
                continue
            found += 1
            d = et - np.array([l, rr, t, bb])
            corner = np.hypot(d[[0, 1, 1, 0]], d[[2, 2, 3, 3]])
            errs.append(float(corner.max()))
            within += int(corner.max() <= 1.0)
    return FacadeJudgement(f.building, f.index, b, face, cov, (float(dx), float(dy)), n_win, found, within,
                           np.array(errs))


def walls_seen(scene: Scene, eo, cameras, images: set[str] | None = None, *, max_incidence_deg: float = 60.0,
               min_fraction: float = 0.5, step_m: float = 1.0, march_m: float = 0.25) -> set[tuple[int, int]]:
    """The scene's walls ``(building, face)`` (faces numbered as :meth:`~skyrig.simulate.world.Buildings.planes`)
    that at least one image of ``images`` (default: all of ``eo``) sees, from the scene's analytic truth alone.

    A wall is seen by an image when at least ``min_fraction`` of the points of a ``step_m`` grid over it (above
    the terrain, below the eaves) lie in front of the camera, inside its frame, at an incidence of at most
    ``max_incidence_deg`` (angle between the wall's normal and the direction to the projection centre), and are
    not hidden: no point of the ray towards the camera, marched every ``march_m`` up to the scene's top, lies
    under the scene's surface (roofs, terrain; 5 cm tolerance).  ``eo`` in any frame (converted to the scene's
    local frame), ``cameras`` camera name -> camera."""
    loc = _local(scene)
    eo_l = eo.to_frame(loc)
    names = [str(n) for n in eo_l.image]
    use = [k for k, n in enumerate(names) if images is None or n in images]
    bl = scene.buildings
    cos_max = np.cos(np.radians(max_incidence_deg))
    top = scene.top + 1.0
    out: set[tuple[int, int]] = set()
    for i in range(len(bl)):
        for f in range(4):
            w = _wall_line(scene, i, f)
            if w is None:
                continue
            mid, along, n2, half = w
            s = np.arange(-half + 0.5 * step_m, half, step_m)
            zt = scene.terrain_height(mid[0] + s * along[0], mid[1] + s * along[1])
            zs = np.arange(float(zt.min()) + 0.25 * step_m, float(bl.eave_z[i]), step_m)
            S, Z = np.meshgrid(s, zs)
            P = np.column_stack([mid[0] + S.ravel() * along[0], mid[1] + S.ravel() * along[1], Z.ravel()])
            P = P[P[:, 2] > scene.terrain_height(P[:, 0], P[:, 1])]
            if len(P) < 3:
                continue
            P = P + np.r_[0.05 * n2, 0.0]  # just outside the wall
            for k in use:
                C = eo_l.centre[k]
                d = C - P
                dist = np.linalg.norm(d, axis=1)
                if np.median((d[:, :2] @ n2) / dist) < cos_max:
                    continue
                cam = cameras[str(eo_l.camera[k])]
                pc = (P - C) @ eo_l.rotation[k]
                front = pc[:, 2] < 0
                px = np.full((len(P), 2), np.nan)
                px[front] = cam.project_pixels(pc[front])
                ok = front & ((d[:, :2] @ n2) / dist >= cos_max) & (px[:, 0] >= 0) & (px[:, 1] >= 0) \
                    & (px[:, 0] < cam.width) & (px[:, 1] < cam.height)
                if ok.sum() < min_fraction * len(P):
                    continue
                u = d[ok] / dist[ok, None]
                t_top = np.where(u[:, 2] > 1e-6, (top - P[ok, 2]) / np.maximum(u[:, 2], 1e-6), dist[ok])
                t_end = np.minimum(t_top, dist[ok])
                steps = np.arange(march_m, float(t_end.max()) + march_m, march_m)
                Q = P[ok, None, :] + steps[None, :, None] * u[:, None, :]
                live = steps[None, :] <= t_end[:, None]
                zq = scene.surface_height(Q[..., 0].ravel(), Q[..., 1].ravel()).reshape(live.shape)
                hidden = np.any(live & (zq > Q[..., 2] + 0.05), axis=1)
                if (~hidden).sum() >= min_fraction * len(P):
                    out.add((i, f))
                    break
    return out


def _wall_line(scene: Scene, i: int, f: int) -> tuple[NDArray, NDArray, NDArray, float] | None:
    """Wall ``f`` of building ``i`` in plan (local frame): its middle, along and outward unit vectors, half length
    (None for a face that is not a wall)."""
    bl = scene.buildings
    nrm, off, _ = bl.planes(i)
    n = np.asarray(nrm[f], float)
    if abs(n[2]) > 0.1:
        return None
    c = np.array([bl.cx[i], bl.cy[i]])
    n2 = n[:2] / np.linalg.norm(n[:2])
    mid = c + n2 * (off[f] - n[:2] @ c) / max(float(n[:2] @ n2), 1e-9)
    return mid, np.array([-n2[1], n2[0]]), n2, float(bl.hw[i] if f < 2 else bl.hl[i])


def walls_in_dsm(scene: Scene, walls: set[tuple[int, int]], dsm: DsmGrid, *, inset_m: float = 1.0,
                 min_fraction: float = 0.5) -> set[tuple[int, int]]:
    """The walls of ``walls`` whose roof edge the DSM measured: at least ``min_fraction`` of the points ``inset_m``
    inside the wall (every 0.5 m along it, at the eaves) fall on measured (finite) DSM cells.  The others lie
    outside the DSM (beyond the surveyed area), where no building can be extracted from it."""
    loc = _local(scene)
    g = dsm.grid
    meas = np.isfinite(np.asarray(dsm.height))
    out = set()
    for i, f in walls:
        w = _wall_line(scene, i, f)
        if w is None:
            continue
        mid, along, n2, half = w
        s = np.arange(-half + 0.25, half, 0.5)
        xy = mid + s[:, None] * along - inset_m * n2
        P = _convert(loc, dsm.frame, np.column_stack([xy, np.full(len(xy), scene.buildings.eave_z[i])]))
        col = np.floor((P[:, 0] - g.x0) / g.cell_m).astype(int)
        row = np.floor((g.y0 - P[:, 1]) / g.cell_m).astype(int)
        ing = (col >= 0) & (row >= 0) & (col < g.width) & (row < g.height)
        ok = np.zeros(len(P), bool)
        ok[ing] = meas[row[ing], col[ing]]
        if ok.mean() >= min_fraction:
            out.add((i, f))
    return out


def judge_facades(scene: Scene, textures: list[FacadeTexture], frame: WorldFrame, oblique: set[str] | None = None,
                  walls: set[tuple[int, int]] | None = None, dsm: DsmGrid | None = None
                  ) -> tuple[list[FacadeJudgement], dict]:
    """Judge every texture; the summary counts façades "seen" (at least 16 valid texels on a true wall and at
    least one resolvable window of the rule in the valid part; with ``oblique`` given, only textures whose
    images include one of those image names).

    Summary keys: ``facades``, ``seen``, ``offset_median_px``, ``offset_max_px`` (:func:`_align`, seen façades),
    ``within_1px`` (fraction of seen façades with every window found, the median window-corner error and the
    whole-façade offset within 1 texel),
    ``windows``, ``windows_found``, ``windows_within_1px``, ``corner_err_median_px``, ``corner_err_max_px``,
    ``occluded_in_best``, ``occluded_filled`` (texel counts from the textures' stats).

    With ``walls`` (the scene's walls seen by an oblique, :func:`walls_seen`), the figure over every such wall,
    textured or not: ``walls_seen``, ``walls_textured`` (with a seen texture matched to it), ``walls_within_1px``
    (with a matched texture that passes as ``within_1px`` counts it) and ``walls_within_1px_fraction`` (of
    ``walls_seen``); ``walls_missed`` lists the seen walls without a passing texture.  With ``dsm`` too, the
    same over the seen walls whose roof edge the DSM measured (:func:`walls_in_dsm`): ``walls_seen_in_dsm``,
    ``walls_textured_in_dsm``, ``walls_within_1px_in_dsm``."""
    out = [judge_facade(scene, t, frame) for t in textures]
    seen = []
    for t, j in zip(textures, out):
        if j.true_building < 0 or not np.isfinite(j.offset_px[0]) or j.windows == 0:
            continue
        if oblique is not None and not (set(t.images) & oblique):
            continue
        seen.append(j)
    off = np.array([j.offset_norm_px for j in seen]) if seen else np.zeros(0)
    errs = np.concatenate([j.corner_err_px for j in seen]) if seen else np.zeros(0)
    good = [j for j in seen if j.windows_found == j.windows and j.offset_norm_px <= 1.0
            and float(np.median(j.corner_err_px)) <= 1.0]
    summ = {"facades": len(textures), "seen": len(seen),
            "offset_median_px": float(np.median(off)) if len(off) else float("nan"),
            "offset_max_px": float(off.max()) if len(off) else float("nan"),
            "within_1px": len(good) / len(seen) if seen else float("nan"),
            "windows": int(sum(j.windows for j in seen)), "windows_found": int(sum(j.windows_found for j in seen)),
            "windows_within_1px": int(sum(j.windows_within_1px for j in seen)),
            "corner_err_median_px": float(np.median(errs)) if len(errs) else float("nan"),
            "corner_err_max_px": float(errs.max()) if len(errs) else float("nan"),
            "occluded_in_best": int(sum(t.stats.get("occluded_in_best", 0) for t in textures)),
            "occluded_filled": int(sum(t.stats.get("occluded_filled", 0) for t in textures))}
    if walls is not None:
        tex_w = {(j.true_building, j.true_face) for j in seen}
        good_w = {(j.true_building, j.true_face) for j in good}
        summ.update({"walls_seen": len(walls), "walls_textured": len(walls & tex_w),
                     "walls_within_1px": len(walls & good_w),
                     "walls_within_1px_fraction": len(walls & good_w) / len(walls) if walls else float("nan"),
                     "walls_missed": sorted(walls - good_w)})
        if dsm is not None:
            wd = walls_in_dsm(scene, walls, dsm)
            summ.update({"walls_seen_in_dsm": len(wd), "walls_textured_in_dsm": len(wd & tex_w),
                         "walls_within_1px_in_dsm": len(wd & good_w)})
    return out, summ
