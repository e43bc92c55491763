"""Occlusion-aware façade textures: rectified textures of building walls (and any plane) from oriented images.

For every texel of a plane (a façade of :class:`~skyrig.dense.buildings.BuildingBlock`, or a roof plane) the
texel centre is projected backwards into the candidate images with the full camera model (distortion
included: :meth:`FrameCamera.project_pixels`) and sampled bilinearly (``cv2.remap``).  A texel takes its
colour from the image that sees it best:

* candidates face the plane (angle between its outward normal and the direction to the camera below
  ``max_angle_deg``) and see part of it inside the image;
* per texel, visibility along the ray to each camera is checked against the DSM (a march in half-cell steps,
  a numba kernel, each step against the highest of the 4 cells around it, so that obstacles are never
  thinner than in the DSM): a texel hidden behind another building in one image takes its colour from another.  A
  wall is vertical, so the DSM cells of its own roof edge lie right above it: the march starts
  ``self_margin_m`` away from the plane (measured along its normal), beyond the eave's mixed cells;
* the best visible image per texel has the smallest texel footprint (``distance / (focal_px cos(incidence))``,
  i.e. the highest resolution and most frontal view); image boundaries are feathered over ``feather_texels``;
* the texel size defaults to the best image's footprint on the plane (median over the plane); or a texel of the
  area of its pixels' footprint there (``TextureConfig.texel_rule="pixel_area"``: :func:`_native_texel`).

Roofs: :func:`texture_roofs` textures every roof polygon the same way (normal up), over its bounding rectangle
(:func:`roof_rectangle`).

Walls of buildings extracted from a matched DSM can first be moved onto the roof outlines the images show
(:func:`refine_walls`): a matched DSM's roof edges are blurred and shifted by a fraction of a metre, a
texture on a wall in the wrong place is shifted by about as much.

Frames: the planes are in the DSM's frame (a projected map CRS with its height reference, or a local ENU
frame); the orientations may be in any frame.  Projection runs in a local tangent frame at the buildings:
orientations are converted rigorously (:meth:`ExteriorOrientations.to_frame`), texel centres through
:class:`skyrig.dense.surface.FrameMap` (a polynomial checked against PROJ, so map scale factor and geoid are
honoured).  Occlusion rays are marched in the DSM's frame (a straight line there is straight in the local
frame to well below a millimetre over a block).  Texels are in the DSM frame's metres (grid metres for a map
CRS).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Callable, Mapping, NamedTuple, Sequence

import numpy as np
from numba import njit
from numpy.typing import NDArray

from skyrig.camera.frame import FrameCamera
from skyrig.dense.buildings import BuildingBlock, Facade, FacadeTexture, _roof_height, tukey_irls
from skyrig.dense.grid import DsmGrid
from skyrig.errors import SkyrigError
from skyrig.georef.eo import ExteriorOrientations, local_frame_for

ImageLoader = Callable[[int], NDArray[np.uint8]]


@dataclass(frozen=True)
class TextureConfig:
    """Options of :func:`texture_plane` / :func:`texture_facades`.

    Attributes
    ----------
    texel_m
        Texel size (frame metres); None: from the best image by ``texel_rule``.
    texel_rule
        ``"footprint"``: the best image's texel footprint on the plane (``distance / (focal_px cos(incidence))``,
        the pixel's longer side there; median over the plane); ``"pixel_area"``: a square of the area of that
        pixel footprint (:func:`_native_texel`; finer by ``sqrt(cos(incidence))``: as many texels as the image
        has pixels on the plane).
    max_images
        Images that contribute at most (more are tried, up to ``max_candidates``, only while texels remain that
        no chosen image sees).
    max_candidates
        Images whose visibility is computed at most per plane.
    max_angle_deg
        Largest angle between the plane's normal and the direction to a camera.
    feather_texels
        Width of the blend across a change of source image (Gaussian sigma, texels); 0: no blending.
    occlusion_tol_m
        A ray is blocked where the DSM is higher than the ray by more than this.
    self_margin_m
        Distance from the plane (along its normal) where the occlusion march starts; None: 5 DSM cells (a
        matched DSM bleeds roofs over the eaves by a few cells: on the midas-dsm block 3 cells leave 220
        texels falsely hidden in their best image, 5 cells 40).
    edge_margin_px
        Image pixels this close to the image border do not count as seen.
    to_roof
        :func:`texture_facades`: the wall under a gable end is textured up to the roof line (one texture over
        the wall and its gable triangle, :meth:`BuildingBlock.facades` with ``to_roof``); off: every wall up to
        the eaves only.
    """

    texel_m: float | None = None
    texel_rule: str = "footprint"
    max_images: int = 3
    max_candidates: int = 8
    max_angle_deg: float = 75.0
    feather_texels: float = 2.0
    occlusion_tol_m: float = 0.3
    self_margin_m: float | None = None
    edge_margin_px: float = 1.0
    to_roof: bool = True


@njit(cache=True, nogil=True)
def _visible(dsm, x0, y0, cell, pts, cam, t0, step, zmax, tol):  # pragma: no cover - compiled
    """For points ``(N, 3)`` of the DSM frame: is the segment to ``cam`` free of the DSM from ``t0[i]`` on?"""
    rows, cols = dsm.shape
    n = pts.shape[0]
    out = np.zeros(n, np.bool_)
    for i in range(n):
        px, py, pz = pts[i, 0], pts[i, 1], pts[i, 2]
        dx, dy, dz = cam[0] - px, cam[1] - py, cam[2] - pz
        ln = np.sqrt(dx * dx + dy * dy + dz * dz)
        dx, dy, dz = dx / ln, dy / ln, dz / ln
        hz = np.sqrt(dx * dx + dy * dy)
        dt = step / max(hz, 1e-6)
        t = t0[i]
        ok = True
        while t < ln:
            z = pz + t * dz
            if z > zmax:
                break
            u = (px + t * dx - x0) / cell - 0.5
            v = (y0 - (py + t * dy)) / cell - 0.5
            if u < 0.0 or v < 0.0 or u > cols - 1.0 or v > rows - 1.0:
                break  # left the DSM: nothing known blocks it
            j = min(int(u), cols - 2)
            k = min(int(v), rows - 2)
            # the highest of the 4 cells around: a bilinear surface would shave up to a cell off every roof edge
            h = max(max(dsm[k, j], dsm[k, j + 1]), max(dsm[k + 1, j], dsm[k + 1, j + 1]))
            if h > z + tol:
                ok = False
                break
            t += dt
        out[i] = ok
    return out


class _Images:
    """Loads images on demand and keeps the last ones read, at most ``keep`` images and ``max_bytes`` bytes (the
    newest always: large-format frames are 0.3-1.4 GB each in RGB, sixteen of them would not fit)."""

    def __init__(self, loader: ImageLoader, keep: int = 16, max_bytes: int = 2 << 30) -> None:
        self.loader, self.keep, self.max_bytes, self.cache = loader, keep, max_bytes, {}

    def __call__(self, i: int) -> NDArray[np.uint8]:
        if i not in self.cache:
            img = np.asarray(self.loader(i))
            if img.ndim == 2:
                img = np.repeat(img[..., None], 3, axis=2)
            while self.cache and (len(self.cache) >= self.keep
                                  or sum(a.nbytes for a in self.cache.values()) + img.nbytes > self.max_bytes):
                self.cache.pop(next(iter(self.cache)))
            self.cache[i] = img
        return self.cache[i]


@dataclass
class _Context:
    """What is shared by all planes of one texturing run."""

    eo_l: ExteriorOrientations
    centres_dsm: NDArray[np.float64]
    cameras: Mapping[str, FrameCamera]
    to_local: Callable[[NDArray], NDArray]
    dsm: DsmGrid
    dsm_filled: NDArray[np.float32]
    zmax: float
    images: _Images


def _context(eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera], loader: ImageLoader, dsm: DsmGrid,
             box: tuple[float, ...]) -> _Context:
    from skyrig.dense.buildings import ground_estimate
    from skyrig.dense.surface import FrameMap

    missing = sorted(set(eo.camera.tolist()) - set(cameras))
    if missing:
        raise SkyrigError(f"no camera for {', '.join(missing)} (cameras given: {', '.join(sorted(cameras))})")
    if dsm.frame.kind == "map":
        from skyrig.geodesy.crs import resolve_crs

        if not resolve_crs(dsm.frame.crs).is_projected:
            raise SkyrigError(f"façade texturing needs a DSM in a projected CRS or a local frame, not {dsm.frame.crs}")
    elif dsm.frame.kind != "local":
        raise SkyrigError(f"façade texturing needs a DSM in a map or local frame, not a {dsm.frame.kind} frame")
    ctr = 0.5 * (np.array(box[:3]) + np.array(box[3:]))
    local = local_frame_for(dsm.frame.to_ecef(ctr[None]))
    eo_l = eo.to_frame(local)
    centres = eo.to_frame(dsm.frame).centre if eo.frame != dsm.frame else eo.centre
    to_local = FrameMap(dsm.frame, local, box)
    # holes of a matched DSM are mostly the ground hidden next to tall objects: filled with the ground estimate
    # (a hole filled from its nearest cells would take the roof's height and hide the walls beside it)
    h = np.asarray(dsm.height, np.float32)
    hole = ~np.isfinite(h)
    filled = np.where(hole, ground_estimate(dsm), h).astype(np.float32) if hole.any() else h
    return _Context(eo_l, centres, cameras, to_local, dsm, filled, float(np.nanmax(dsm.height)), _Images(loader))


def _plane_axes(corners: NDArray) -> tuple[NDArray, NDArray, NDArray, float, float]:
    c = np.asarray(corners, float)
    du, dv = c[1] - c[0], c[3] - c[0]
    w, h = float(np.linalg.norm(du)), float(np.linalg.norm(dv))
    if w <= 0 or h <= 0:
        raise SkyrigError(f"degenerate plane (width {w:g} m, height {h:g} m)")
    u, v = du / w, dv / h
    n = np.cross(u, v)
    return u, v, n / np.linalg.norm(n), w, h


def _footprint_per_image(ctx: _Context, P_l: NDArray, n_l: NDArray, k: int) -> tuple[NDArray, NDArray, NDArray]:
    """Pixels ``(N, 2)``, texel footprint in metres per image pixel ``(N,)`` and cos of incidence for image k."""
    cam = ctx.cameras[str(ctx.eo_l.camera[k])]
    C, R = ctx.eo_l.centre[k], ctx.eo_l.rotation[k]
    d = C - P_l
    dist = np.linalg.norm(d, axis=1)
    cosi = (d @ n_l) / dist
    px = cam.project_pixels((P_l - C) @ R)
    with np.errstate(divide="ignore", invalid="ignore"):
        fp = dist / (cam.focal_px * cosi)
    return px, np.where(cosi > 0, fp, np.inf), cosi


def _candidates(ctx: _Context, corners: NDArray, n_dsm: NDArray, cfg: TextureConfig) -> list[tuple[int, float]]:
    """Images facing the plane that see part of it, with their median texel footprint, best first."""
    u, v, _, w, h = _plane_axes(corners)
    s = np.linspace(0.02, 0.98, 7)
    ss, tt = np.meshgrid(s * w, s * h)
    P = corners[0] + ss.reshape(-1, 1) * u + tt.reshape(-1, 1) * v
    P_l = ctx.to_local(P)
    n_l = ctx.to_local(corners[:1] + n_dsm) - ctx.to_local(corners[:1])
    n_l = n_l[0] / np.linalg.norm(n_l[0])
    cmax = np.cos(np.radians(cfg.max_angle_deg))
    # all images at once: directions, incidence and distance (N images x 49 points)
    d = ctx.eo_l.centre[:, None, :] - P_l[None]
    dist = np.linalg.norm(d, axis=2)
    cosi = (d @ n_l) / dist
    facing = np.flatnonzero((np.median(cosi, axis=1) >= cmax) & (cosi >= cmax).any(axis=1))
    out = []
    names = ctx.eo_l.camera[facing]
    for name in np.unique(names):
        idx = facing[names == name]
        cam = ctx.cameras[str(name)]
        pc = np.einsum("kpj,kji->kpi", -d[idx], ctx.eo_l.rotation[idx])  # camera-frame points
        px = cam.project_pixels(pc.reshape(-1, 3)).reshape(len(idx), -1, 2)
        inside = cam.in_image(px, -cfg.edge_margin_px) & (cosi[idx] >= cmax)
        with np.errstate(divide="ignore", invalid="ignore"):
            fp = dist[idx] / (cam.focal_px * cosi[idx])
        for m, k in enumerate(idx):
            if inside[m].any():
                out.append((int(k), float(np.median(fp[m][inside[m]])), float(inside[m].mean())))
    out.sort(key=lambda t: t[1])
    return [(k, f) for k, f, _ in out]


def _native_texel(ctx: _Context, corners: NDArray, k: int, fallback: float, cfg: TextureConfig) -> float:
    """The texel of image ``k``'s own resolution on a plane: the square of the same area as a pixel's footprint
    there, ``distance / (focal_px sqrt(cos i))`` (median over the points :func:`_candidates` uses that lie in
    the image), so that the texture has as many texels as the image has pixels on the plane.

    A pixel's footprint on a plane seen at incidence ``i`` is ``distance / focal_px`` across the incidence and
    ``1 / cos(i)`` times that along it (the footprint :func:`_candidates` ranks images by).  Square texels of the
    longer side (the default before) drop what the image resolves along the shorter one: a 45 deg oblique's view
    of a wall carries its horizontal detail at 0.7 of such a texel, and windows 1.2 m wide, 3.4 image pixels
    across, come out under 3 texels of 0.41 m.  ``fallback`` where no point is inside.

    Measured (``bench/facades.py --texel-rule``; tests/test_tumblecam_chain.py's façade case): on the TumbleCam
    town (true buildings, orientations transferred from the nadir images) 28 façades become judgeable instead of
    9, of which only 64 % have every window within 1 of these finer texels (137 of 196 windows; offsets up to 1.4
    texel) - so it is not the default."""
    u, v, _, w, h = _plane_axes(corners)
    s = np.linspace(0.02, 0.98, 7)
    ss, tt = np.meshgrid(s * w, s * h)
    P_l = ctx.to_local(corners[0] + ss.reshape(-1, 1) * u + tt.reshape(-1, 1) * v)
    cam = ctx.cameras[str(ctx.eo_l.camera[k])]
    d = P_l - ctx.eo_l.centre[k]
    pc = d @ ctx.eo_l.rotation[k]
    inside = (pc[:, 2] < 0) & cam.in_image(cam.project_pixels(pc), -cfg.edge_margin_px)
    if not inside.any():
        return float(fallback)
    n_l = ctx.to_local(corners[:1] + np.cross(u, v)) - ctx.to_local(corners[:1])
    n_l = n_l[0] / np.linalg.norm(n_l[0])
    dist = np.linalg.norm(d[inside], axis=1)
    cosi = np.clip(-(d[inside] @ n_l) / dist, 0.05, 1.0)
    return float(np.median(dist / (cam.focal_px * np.sqrt(cosi))))


class PlaneTexture(NamedTuple):
    """The texture of one plane (see :func:`texture_plane`)."""

    rgb: NDArray[np.uint8]
    valid: NDArray[np.bool_]
    texel_m: float
    images: tuple[str, ...]
    source: NDArray[np.int16]
    stats: dict


def texture_plane(corners: NDArray, eo: ExteriorOrientations | None = None,
                  cameras: Mapping[str, FrameCamera] | None = None, loader: ImageLoader | None = None,
                  dsm: DsmGrid | None = None, *, texel_m: float | None = None, max_images: int = 3,
                  normal: NDArray | None = None, config: TextureConfig | None = None,
                  context: "_Context | None" = None, outline: NDArray | None = None) -> PlaneTexture:
    """Occlusion-aware texture of one planar rectangle of the DSM's frame (a wall, a roof plane ...).

    Parameters
    ----------
    corners
        ``(4, 3)`` bottom-start, bottom-end, top-end, top-start (DSM frame).  Texel ``(i, j)`` has its centre at
        ``corners[3] + (j + 0.5) t u - (i + 0.5) t v`` with ``u`` along bottom-start -> bottom-end and ``v``
        along bottom-start -> top-start, ``t`` the texel size: row 0 at the top edge.
    eo, cameras, loader, dsm
        As :func:`texture_facades`; not needed when ``context`` is given.
    texel_m, max_images
        As :class:`TextureConfig` (these arguments win over ``config``'s).
    normal
        Outward unit normal (DSM frame); default ``u x v`` (outward for a façade's corners, up for a roof whose
        corners run counter-clockwise seen from above).
    config
        The other options.
    context
        From :func:`texturing_context`, to share orientations, DSM and image cache between planes.
    outline
        ``(K, 2)`` polygon inside the rectangle as ``(s, z)``: ``s`` the distance from ``corners[0]`` along ``u``,
        ``z = corners[0, 2] + `` the distance along ``v`` (the height, for a wall); texels whose centre lies outside
        get no colour (:attr:`~skyrig.dense.buildings.Facade.outline`), nor do those within one texel of a sloped
        edge of it (a gable's roof line: such a texel's footprint in the images straddles the roof).  None: the
        whole rectangle.

    Returns
    -------
    rgb ``(H, W, 3)`` uint8, valid ``(H, W)``, texel size, names of the images used (most texels first), the
    source image per texel ``(H, W)`` (index into the names, -1 none) and counts: ``texels``, ``valid``,
    ``occluded_in_best`` (texels inside the best image but hidden there by the DSM),
    ``occluded_filled`` (of those, texels coloured from another image), ``candidates``.
    """
    from dataclasses import replace

    cfg = replace(config or TextureConfig(), texel_m=texel_m, max_images=int(max_images))
    if context is None:
        if eo is None or cameras is None or loader is None or dsm is None:
            raise SkyrigError("texture_plane needs eo, cameras, loader and dsm, or a context")
        context = texturing_context(eo, cameras, loader, dsm, np.asarray(corners, float).reshape(4, 3))
    return PlaneTexture(*_texture_plane(np.asarray(corners, float), context, cfg, normal, outline))


def _texture_plane(corners: NDArray, ctx: _Context, cfg: TextureConfig, normal: NDArray | None,
                   outline: NDArray | None = None
                   ) -> tuple[NDArray[np.uint8], NDArray[np.bool_], float, tuple[str, ...], NDArray[np.int16], dict]:
    import cv2

    corners = np.asarray(corners, float).reshape(4, 3)
    u, v, n, w, h = _plane_axes(corners)
    if normal is not None:
        n = np.asarray(normal, float) / np.linalg.norm(normal)
    if cfg.texel_rule not in ("footprint", "pixel_area"):
        raise SkyrigError(f"texel rule must be 'footprint' or 'pixel_area', not {cfg.texel_rule!r} (option: texel_rule)")
    cand = _candidates(ctx, corners, n, cfg)
    if cfg.texel_m is not None:
        texel = float(cfg.texel_m)
        if not (texel > 0 and np.isfinite(texel)):
            raise SkyrigError(f"texel size must be positive, got {cfg.texel_m} (option: texel_m)")
    elif cand:
        texel = _native_texel(ctx, corners, cand[0][0], cand[0][1], cfg) if cfg.texel_rule == "pixel_area" \
            else cand[0][1]
    else:
        texel = max(w, h) / 64.0
    W = max(1, int(np.ceil(w / texel - 1e-6)))
    H = max(1, int(np.ceil(h / texel - 1e-6)))
    if W * H > 25_000_000:
        raise SkyrigError(f"a {texel:g} m texel over a {w:.1f} x {h:.1f} m plane is {W * H:.3g} texels (option: texel_m)")
    jj, ii = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    P = corners[3] + (jj.reshape(-1, 1) * texel) * u - (ii.reshape(-1, 1) * texel) * v
    inside_plane = ((jj * texel <= w + 1e-9) & (ii * texel <= h + 1e-9)).reshape(-1)
    if outline is not None:
        import shapely

        ol = np.asarray(outline, float).reshape(-1, 2)
        if len(ol) < 3:
            raise SkyrigError(f"a plane's outline needs at least 3 points, got {len(ol)}")
        poly = shapely.Polygon(ol).buffer(1e-6)
        # sloped edges (a gable's roof lines): a texel within one texel of one straddles the roof in the images
        d = np.roll(ol, -1, axis=0) - ol
        sloped = [shapely.LineString([ol[k], ol[k] + d[k]]) for k in range(len(ol))
                  if abs(d[k, 0]) > 1e-6 and abs(d[k, 1]) > 1e-6]
        if sloped:
            poly = poly.difference(shapely.MultiLineString(sloped).buffer(texel))
        inside_plane &= shapely.contains_xy(poly, (jj * texel).reshape(-1),
                                            (corners[0, 2] + h - ii * texel).reshape(-1))
    rgb = np.zeros((H, W, 3), np.uint8)
    stats = {"texels": int(inside_plane.sum()), "valid": 0, "occluded_in_best": 0, "occluded_filled": 0,
             "candidates": len(cand)}
    if not cand:
        return rgb, np.zeros((H, W), bool), texel, (), np.full((H, W), -1, np.int16), stats
    P_l = ctx.to_local(P)
    n_l = ctx.to_local(corners[:1] + n) - ctx.to_local(corners[:1])
    n_l = n_l[0] / np.linalg.norm(n_l[0])
    g = ctx.dsm.grid
    margin = cfg.self_margin_m if cfg.self_margin_m is not None else 5.0 * g.cell_m
    cmax = np.cos(np.radians(cfg.max_angle_deg))
    N = len(P)
    used: list[int] = []
    fps, vis_l, maps = [], [], []
    covered = np.zeros(N, bool)
    for k, _ in cand[: cfg.max_candidates]:
        if len(used) >= cfg.max_images and covered[inside_plane].all():
            break
        px, fp, cosi = _footprint_per_image(ctx, P_l, n_l, k)
        cam = ctx.cameras[str(ctx.eo_l.camera[k])]
        seen = cam.in_image(px, -cfg.edge_margin_px) & (cosi >= cmax) & inside_plane
        vis = np.zeros(N, bool)
        if seen.any():
            idx = np.flatnonzero(seen)
            C = ctx.centres_dsm[k]
            d = C[None] - P[idx]
            dn = np.linalg.norm(d, axis=1)
            t0 = margin / np.maximum((d @ n) / dn, 0.05)
            vis[idx] = _visible(ctx.dsm_filled, g.x0, g.y0, g.cell_m, np.ascontiguousarray(P[idx]),
                                np.ascontiguousarray(C), t0, 0.5 * g.cell_m, ctx.zmax, cfg.occlusion_tol_m)
        new = vis & ~covered
        if len(used) >= cfg.max_images and not new.any():
            continue
        if not vis.any():
            if not used:  # the best image is blind here: count its occluded texels
                stats["occluded_in_best"] += int(seen.sum())
                used.append(k)
                fps.append(np.full(N, np.inf))
                vis_l.append(vis)
                maps.append((px, seen))
            continue
        if not used:
            stats["occluded_in_best"] = int((seen & ~vis).sum())
        used.append(k)
        fps.append(np.where(vis, fp, np.inf))
        vis_l.append(vis)
        maps.append((px, seen))
        covered |= vis
    F = np.stack(fps)  # (M, N)
    best = np.argmin(F, axis=0)
    valid = np.isfinite(F.min(axis=0)) & inside_plane
    # blend: per image, its share of the labels smoothed over the feather width, where the image sees the texel
    acc = np.zeros((H, W, 3), np.float64)
    wsum = np.zeros((H, W), np.float64)
    counts = np.bincount(best[valid], minlength=len(used))
    for m, k in enumerate(used):
        if counts[m] == 0:
            continue
        px, _ = maps[m]
        img = ctx.images(k)
        mx = px[:, 0].reshape(H, W).astype(np.float32)
        my = px[:, 1].reshape(H, W).astype(np.float32)
        col = cv2.remap(img, np.nan_to_num(mx, nan=-10), np.nan_to_num(my, nan=-10), cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
        lab = ((best == m) & valid).reshape(H, W).astype(np.float32)
        if cfg.feather_texels > 0:
            lab = cv2.GaussianBlur(lab, (0, 0), cfg.feather_texels, borderType=cv2.BORDER_REPLICATE)
        wk = lab * vis_l[m].reshape(H, W)
        acc += col * wk[..., None]
        wsum += wk
    ok = valid.reshape(H, W) & (wsum > 1e-6)
    first_seen = maps[0][1] & ~vis_l[0]  # inside the best image, hidden there
    stats["occluded_filled"] = int((first_seen & ok.reshape(-1)).sum())
    stats["valid"] = int(ok.sum())
    rgb[ok] = np.clip(acc[ok] / wsum[ok, None] + 0.5, 0, 255).astype(np.uint8)
    order = np.argsort(-counts, kind="stable")
    keep = [m for m in order if counts[m] > 0]
    names = tuple(str(ctx.eo_l.image[used[m]]) for m in keep)
    remap = np.full(len(used), -1, np.int16)
    remap[keep] = np.arange(len(keep), dtype=np.int16)
    src = np.where(ok.reshape(-1), remap[best], -1).astype(np.int16).reshape(H, W)
    return rgb, ok, texel, names, src, stats


def texturing_context(eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera], loader: ImageLoader,
                      dsm: DsmGrid, points: NDArray | None = None) -> _Context:
    """The shared state of a texturing run (orientations in a local frame at ``points``, the DSM prepared for the
    occlusion march, an image cache).  ``points`` ``(N, 3)`` in the DSM's frame bound the planes to texture
    (default: the DSM's extent)."""
    if points is None or len(points) == 0:
        b = dsm.grid.bounds
        zl, zh = float(np.nanmin(dsm.height)), float(np.nanmax(dsm.height))
        points = np.array([[b[0], b[1], zl], [b[2], b[3], zh]])
    p = np.asarray(points, float).reshape(-1, 3)
    lo, hi = p.min(axis=0) - 5.0, p.max(axis=0) + 5.0
    return _context(eo, cameras, loader, dsm, (*lo, *hi))


def texture_facades(buildings: Sequence[BuildingBlock], eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera],
                    loader: ImageLoader, dsm: DsmGrid, *, texel_m: float | None = None, max_images: int = 3,
                    config: TextureConfig | None = None,
                    progress: Callable[[int, int], None] | None = None) -> list[FacadeTexture]:
    """Occlusion-aware rectified textures of every façade of ``buildings``.

    Parameters
    ----------
    buildings
        Building blocks in the DSM's frame (:func:`skyrig.dense.buildings.extract_buildings`, or given footprints).
    eo
        Orientations of the images (any frame; converted rigorously).
    cameras
        Camera name -> camera (with its distortion) for every ``eo.camera``.
    loader
        ``loader(i)`` -> image of ``eo`` row ``i`` (RGB uint8, e.g. :class:`skyrig.pipeline.dense.ImageFiles`).
    dsm
        The surface the occlusions are checked against (a projected map CRS or a local frame).
    texel_m, max_images
        As :class:`TextureConfig` (these arguments win over ``config``'s).
    config
        The other options.
    progress
        Called with (façades done, façades) after each façade.

    Returns
    -------
    One :class:`FacadeTexture` per façade (``valid`` all False where no image sees it), in the order of
    ``buildings`` and their footprint edges, leaving out the edges on the DSM's border of clipped buildings
    (:attr:`~skyrig.dense.buildings.Facade.on_border`); ``stats`` holds the counts of :func:`texture_plane`.  With
    ``to_roof`` (default) the façade of a wall under a gable end reaches up to the roof line
    (:attr:`~skyrig.dense.buildings.Facade.outline`; texels above the roof line are not ``valid``).

    Raises
    ------
    SkyrigError
        On a camera missing for an image, a DSM in a geographic CRS or ECEF, or a bad texel size.
    """
    from dataclasses import replace

    cfg = replace(config or TextureConfig(), texel_m=texel_m, max_images=int(max_images))
    if cfg.max_images < 1:
        raise SkyrigError(f"max_images must be at least 1, got {max_images} (option: max_images)")
    # the edges of a building cut by the DSM's border that run along that border are not walls: no texture;
    # a gable end's wall up to the roof line (one texture over the wall and its gable triangle)
    facades: list[Facade] = [f for b in buildings for f in b.facades(to_roof=cfg.to_roof) if not f.on_border]
    if not facades:
        return []
    pts = np.concatenate([f.corners for f in facades])
    xmin, ymin, xmax, ymax = dsm.grid.bounds
    pad = 0.5 * max(xmax - xmin, ymax - ymin)
    far = (pts[:, 0] < xmin - pad) | (pts[:, 0] > xmax + pad) | (pts[:, 1] < ymin - pad) | (pts[:, 1] > ymax + pad)
    if far.any():
        f = facades[int(np.flatnonzero(far)[0]) // 4]
        raise SkyrigError(f"building {f.building} lies far outside the DSM ({f.corners[0, :2]} vs DSM bounds "
                          f"{dsm.grid.bounds}): buildings must be in the DSM's frame ({dsm.frame.to_text()})")
    ctx = texturing_context(eo, cameras, loader, dsm, pts)
    out = []
    for i, f in enumerate(facades):
        cf = cfg
        if f.outline is not None:
            f, cf = _to_roof_on_eave_grid(f, ctx, cfg)
        rgb, valid, texel, names, src, stats = _texture_plane(f.corners, ctx, cf, f.normal, f.outline)
        out.append(FacadeTexture(f, rgb, valid, texel, names, src, stats))
        if progress is not None:
            progress(i + 1, len(facades))
    return out


def _to_roof_on_eave_grid(f: Facade, ctx: _Context, cfg: TextureConfig) -> tuple[Facade, TextureConfig]:
    """A wall up to the roof line textured on the texel grid of the wall up to the eaves: the texel size that wall
    gets and its rectangle's top raised above the apex to the eaves plus a whole number of texels, so that the
    texels below the eaves are those of the plain wall (the gable adds rows, it does not move the wall's)."""
    from dataclasses import replace

    ol = np.asarray(f.outline, float)
    L = f.width_m
    ends = (np.abs(ol[:, 0]) < 1e-6) | (np.abs(ol[:, 0] - L) < 1e-6)
    eave = float(ol[ends, 1].max())
    c = np.array(f.corners, float)
    if not eave < c[3, 2] - 1e-6:
        return f, cfg
    c_eave = c.copy()
    c_eave[2:, 2] = eave
    texel = cfg.texel_m
    if texel is None:
        cand = _candidates(ctx, c_eave, f.normal, cfg)
        if not cand:
            return f, cfg
        texel = _native_texel(ctx, c_eave, cand[0][0], cand[0][1], cfg) if cfg.texel_rule == "pixel_area" \
            else cand[0][1]
    c[2:, 2] = eave + np.ceil((c[3, 2] - eave) / texel - 1e-6) * texel
    return replace(f, corners=c), replace(cfg, texel_m=float(texel))


# ------------------------------------------------------------------------------------------ wall refinement
def _sample(img: NDArray, px: NDArray) -> NDArray[np.float64]:
    """Bilinear colours ``(N, C)`` at pixels ``(N, 2)`` (NaN outside)."""
    import cv2

    n = len(px)
    w = min(max(n, 1), 4096)  # cv2.remap takes maps of fewer than 32767 columns: a block of rows
    m = np.zeros(((n + w - 1) // w * w, 2), np.float32)
    m[:n] = px
    m = m.reshape(-1, w, 2)
    out = cv2.remap(img, m[..., 0], m[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                    borderValue=(-1, -1, -1)).reshape(m.shape[0] * w, -1)[:n].astype(np.float64)
    h, w = img.shape[:2]
    ok = (px[:, 0] >= 0) & (px[:, 1] >= 0) & (px[:, 0] <= w - 1) & (px[:, 1] <= h - 1)
    out[~ok] = np.nan
    return out


def refine_walls(buildings: Sequence[BuildingBlock], eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera],
                 loader: ImageLoader, dsm: DsmGrid, *, search_m: float = 1.0, step_m: float = 0.05,
                 band_m: float | None = None, n_images: int = 3, min_gain: float = 1.1,
                 max_view_deg: float = 30.0) -> list[BuildingBlock]:
    """Move every wall of DSM-extracted buildings to the roof outline seen in the images.

    A matched DSM blurs and shifts roof edges by a fraction of a metre (on the midas-dsm block the outlines sit
    0.17 m south of the truth); the images show the outline sharply.  For each footprint edge the roof's edge
    line (at the roof's height there) is moved along the wall's normal by offsets within ``+-search_m``; at
    each offset the mean colours of a band ``band_m`` wide just inside and of one just outside are compared with
    the roof's own colour (a band ``search_m`` further inside), in the ``n_images`` images with the finest view
    of the roof among those that see it within ``max_view_deg`` of the vertical (nadir images; any view up to 60 deg
    when none does - the obliques of a penta rig have the finer ground resolution, but their outline moves one for
    one with an error of the eave height): the score is how much more the outside band differs from the roof than the
    inside band does (so a wall-to-ground step beyond the eaves does not count).  The best offset (parabolic
    sub-step) becomes the wall's; corners are the intersections of consecutive moved
    edge lines; roof polygons follow (corners to corners, points on an edge with the edge).  An edge stays
    where it is when its best score lies at the end of the search range, is not positive, or is not
    ``min_gain`` times the score at the edge's own place (an edge already on the outline stays), or when most
    images' own best offsets are not within 2 steps of it (what lies beyond the eaves, wall or ground, differs
    between views; the outline does not).

    Returns new :class:`BuildingBlock` objects (``source`` unchanged; ``metadata``-free), in the same order.
    """
    if not (search_m > 0 and step_m > 0):
        raise SkyrigError(f"search_m and step_m must be positive, got {search_m}, {step_m}")
    if not buildings:
        return []
    pts = np.concatenate([np.column_stack([b.footprint, np.full(len(b.footprint), b.eave_z)]) for b in buildings])
    ctx = texturing_context(eo, cameras, loader, dsm, pts)
    band = band_m if band_m is not None else max(dsm.grid.cell_m, 0.15)
    offs = np.arange(-search_m, search_m + 0.5 * step_m, step_m)
    out = []
    for b in buildings:
        fp = np.asarray(b.footprint, float)
        nv = len(fp)
        # images with the finest view of the roof's top
        c = np.r_[fp.mean(axis=0), float(_roof_height(b, fp.mean(axis=0)[None])[0])]
        # steep views first: an error of the eave height moves the outline by that error times the tangent of the
        # view's angle (a 45 deg oblique: one for one), and beyond the eaves a steep view sees ground, not the wall
        sq = np.array([c + [-0.5, -0.5, 0], c + [0.5, -0.5, 0], c + [0.5, 0.5, 0], c + [-0.5, 0.5, 0]])
        cand = []
        for max_angle in (max_view_deg, 60.0):
            cand = _candidates(ctx, sq, np.array([0.0, 0.0, 1.0]), TextureConfig(max_angle_deg=max_angle))[:n_images]
            if cand:
                break
        delta = np.zeros(nv)
        if cand:
            for i in range(nv):
                if i in b.border_edges:
                    continue  # the DSM's border, not a roof outline
                a, e = fp[i], fp[(i + 1) % nv]
                L = float(np.linalg.norm(e - a))
                if L < 4 * band:
                    continue
                t = (e - a) / L
                n = np.array([t[1], -t[0]])
                s = np.linspace(0.1, 0.9, max(int(L / band), 4)) * L
                edge = a + s[:, None] * t
                z = _roof_height(b, edge - 0.5 * band * n)
                score = np.zeros(len(offs))
                peaks: list[int] = []
                for k, _ in cand:
                    img = ctx.images(k)
                    cam = ctx.cameras[str(ctx.eo_l.camera[k])]
                    rows = []
                    for off in offs:
                        q_in = edge + (off - 0.5 * band) * n
                        q_out = edge + (off + 0.5 * band) * n
                        P = np.vstack([np.column_stack([q_in, z]), np.column_stack([q_out, z])])
                        Pl = ctx.to_local(P)
                        px = cam.project_pixels((Pl - ctx.eo_l.centre[k]) @ ctx.eo_l.rotation[k])
                        rows.append(px)
                    # the roof's own colour: a band inside the edge, beyond the search range
                    q_ref = edge - (search_m + band) * n
                    rows.append(cam.project_pixels((ctx.to_local(np.column_stack([q_ref, z])) - ctx.eo_l.centre[k])
                                                   @ ctx.eo_l.rotation[k]))
                    px_all = np.concatenate(rows)
                    smp = _sample(img, px_all)
                    col = smp[:-len(edge)].reshape(len(offs), 2, len(edge), -1)
                    with np.errstate(invalid="ignore"), warnings.catch_warnings():
                        warnings.simplefilter("ignore", RuntimeWarning)  # offsets outside the image: NaN, no step
                        ref = np.nanmean(smp[-len(edge):], axis=0)
                        m_in = np.nanmean(col[:, 0], axis=1)  # (offsets, channels)
                        m_out = np.nanmean(col[:, 1], axis=1)
                    # the roof's edge: roof-coloured inside, not outside (a wall-to-ground step further out is not it)
                    sk = np.nan_to_num(np.linalg.norm(m_out - ref, axis=1) - np.linalg.norm(m_in - ref, axis=1))
                    score += sk
                    peaks.append(int(np.argmax(sk)))
                j = int(np.argmax(score))
                j0 = int(np.argmin(np.abs(offs)))
                # the images must agree: what lies beyond the eaves differs between views, the outline does not
                agree = sum(abs(p - j) <= 2 for p in peaks) > 0.5 * len(peaks)
                if 0 < j < len(offs) - 1 and score[j] > 0 and score[j] >= min_gain * max(score[j0], 0.0) and agree:
                    y0, y1, y2 = score[j - 1], score[j], score[j + 1]
                    den = y0 - 2 * y1 + y2
                    sub = 0.5 * (y0 - y2) / den if den < 0 else 0.0
                    delta[i] = offs[j] + float(np.clip(sub, -0.5, 0.5)) * step_m
        out.append(_moved(b, delta))
    return out


def _moved(b: BuildingBlock, delta: NDArray) -> BuildingBlock:
    """The building with footprint edge ``i`` moved by ``delta[i]`` along its outward normal."""
    fp = np.asarray(b.footprint, float)
    nv = len(fp)
    if not np.any(delta):
        return b
    normals = []
    for i in range(nv):
        d = fp[(i + 1) % nv] - fp[i]
        normals.append(np.array([d[1], -d[0]]) / np.linalg.norm(d))
    new = fp.copy()
    for i in range(nv):
        j = (i - 1) % nv  # edges j (ending at vertex i) and i (starting at it)
        pj, nj = fp[i] + delta[j] * normals[j], normals[j]
        pi, ni = fp[i] + delta[i] * normals[i], normals[i]
        A = np.array([nj, ni])
        if abs(np.linalg.det(A)) < 1e-6:  # collinear edges: move along the common normal
            new[i] = fp[i] + delta[i] * ni
        else:
            new[i] = np.linalg.solve(A, [nj @ pj, ni @ pi])
    return _with_footprint(b, fp, new)


def _with_footprint(b: BuildingBlock, fp: NDArray, new: NDArray) -> BuildingBlock:
    """``b`` with its footprint vertices ``fp`` moved to ``new`` and its roof polygons carried along: a roof vertex
    on a footprint vertex moves with it, one on a footprint edge keeps its fraction along the moved edge."""
    from dataclasses import replace

    nv = len(fp)
    roofs = []
    for poly in b.roof:
        pr = np.asarray(poly, float).copy()
        for m in range(len(pr)):
            xy = pr[m, :2]
            hit = np.flatnonzero(np.linalg.norm(fp - xy, axis=1) < 1e-3)
            if len(hit):
                pr[m, :2] = new[hit[0]]
                continue
            for i in range(nv):
                a, e = fp[i], fp[(i + 1) % nv]
                tt = ((xy - a) @ (e - a)) / max((e - a) @ (e - a), 1e-12)
                if 0 <= tt <= 1 and np.linalg.norm(a + tt * (e - a) - xy) < 1e-3:
                    pr[m, :2] = new[i] + tt * (new[(i + 1) % nv] - new[i])
                    break
        roofs.append(pr)
    return replace(b, footprint=new, roof=tuple(roofs))


def _ground_plane(dsm: DsmGrid, footprint: NDArray, fallback: float, ring_m: tuple[float, float] = (2.0, 10.0)
                  ) -> Callable[[NDArray], NDArray]:
    """The ground around a building: a plane fitted robustly (Tukey weights, started on the cells within 0.5 m of
    the lower third) to the DSM's measured (not ``filled``) cells between ``ring_m[0]`` and ``ring_m[1]`` from the footprint (a matched DSM
    smears walls over the cells right next to them; other buildings and anything else standing there are
    outliers).  Terrain is smooth over a building's size; the plane interpolates across the building.  Returns
    ``f(xy (N, 2)) -> heights``; a constant ``fallback`` where too few cells are measured."""
    import shapely

    g = dsm.grid
    fp = np.asarray(footprint, float)
    poly = shapely.Polygon(fp)
    lo, hi = fp.min(axis=0) - ring_m[1], fp.max(axis=0) + ring_m[1]
    c0 = max(int(np.floor((lo[0] - g.x0) / g.cell_m)), 0)
    c1 = min(int(np.ceil((hi[0] - g.x0) / g.cell_m)) + 1, g.width)
    r0 = max(int(np.floor((g.y0 - hi[1]) / g.cell_m)), 0)
    r1 = min(int(np.ceil((g.y0 - lo[1]) / g.cell_m)) + 1, g.height)
    const = lambda xy: np.full(len(np.asarray(xy).reshape(-1, 2)), float(fallback))  # noqa: E731
    if c1 <= c0 or r1 <= r0:
        return const
    cc, rr = np.meshgrid(np.arange(c0, c1), np.arange(r0, r1))
    x = g.x0 + (cc.ravel() + 0.5) * g.cell_m
    y = g.y0 - (rr.ravel() + 0.5) * g.cell_m
    z = np.asarray(dsm.height, float)[r0:r1, c0:c1].ravel()
    dist = shapely.distance(poly, shapely.points(x, y))
    m = np.isfinite(z) & (dist >= ring_m[0]) & (dist <= ring_m[1]) & (np.abs(z - fallback) < 3.0)
    # measured cells only: an occlusion surface's filled cells (the DSM's ground estimate around a building
    # given beyond the surveyed area, :func:`skyrig.dense.buildings.surface_with_buildings`) are an
    # extrapolation, tenths of a metre off; they serve only where too few cells were measured
    meas = m & ~np.asarray(dsm.filled, bool)[r0:r1, c0:c1].ravel()
    if meas.sum() >= 30:
        m = meas
    if m.sum() < 30:
        return const
    ctr = fp.mean(axis=0)
    x, y, z = x[m] - ctr[0], y[m] - ctr[1], z[m]
    start = float(np.percentile(z, 33))
    w = (np.abs(z - start) < 0.5).astype(float)
    A = np.column_stack([np.ones_like(x), x, y])
    coef = tukey_irls(A, z, w, min_weight=15, sigma_floor=0.03)
    if coef is None:
        return const
    cf = coef.copy()
    return lambda xy: cf[0] + (np.asarray(xy, float).reshape(-1, 2) - ctr) @ cf[1:]


def _foot_profile_peaks(col: NDArray, vis: NDArray, z: NDArray, zg: NDArray, search: NDArray, band: int,
                        min_step: float) -> tuple[NDArray, NDArray]:
    """Heights of the ground-to-wall step per chunk of a rectified strip.

    ``col`` ``(R, J, 3)``: colours of the strip, rows at heights ``z`` (ascending), chunk ``j`` below its ground
    height ``zg[j]`` showing the ground in front of the wall; ``vis`` ``(J,)``: chunks whose foot the image sees.
    The ground's colour is taken at the bottom of the strip (below the search range ``zg +- search``); the step is
    where a band of ``band`` rows above differs most from it and a band below least (parabolic sub-row).  Returns
    the heights (NaN where no step of at least ``min_step`` (colour units) is found) and the step strengths."""
    R, J, _ = col.shape
    dz = float(z[1] - z[0])
    zs = np.full(J, np.nan)
    st = np.zeros(J)
    for j in range(J):
        if not vis[j]:
            continue
        lo = int(np.searchsorted(z, zg[j] - search[j]))
        hi = int(np.searchsorted(z, zg[j] + search[j]))
        if lo < 2 * band + 1 or hi > R - band - 1 or hi - lo < 3:
            continue
        c = col[:, j]
        if not np.isfinite(c[: lo + band]).all():
            continue
        ref = np.nanmean(c[max(lo - 2 * band, 0): lo - band], axis=0)
        d = np.linalg.norm(c - ref, axis=1)
        cs = np.r_[0.0, np.cumsum(np.nan_to_num(d))]
        k = np.arange(lo, hi)
        above = (cs[k + band] - cs[k]) / band
        below = (cs[k] - cs[k - band]) / band
        sc = above - below
        if not np.isfinite(sc).all():
            continue
        m = int(np.argmax(sc))
        if sc[m] < min_step or m == 0 or m == len(sc) - 1:
            continue
        y0, y1, y2 = sc[m - 1], sc[m], sc[m + 1]
        den = y0 - 2 * y1 + y2
        sub = float(np.clip(0.5 * (y0 - y2) / den, -0.5, 0.5)) if den < 0 else 0.0
        zs[j] = z[k[m]] + (sub - 0.5) * dz  # the step lies between rows k - 1 and k
        st[j] = float(sc[m])
    return zs, st


def refine_wall_feet(buildings: Sequence[BuildingBlock], eo: ExteriorOrientations,
                     cameras: Mapping[str, FrameCamera], loader: ImageLoader, dsm: DsmGrid, *,
                     search_m: float = 1.5, chunk_m: float = 1.0, step_m: float | None = None,
                     band_m: float | None = None, n_images: int = 4, max_angle_deg: float = 75.0,
                     min_step: float = 12.0, agree_m: float = 0.25, min_chunks: int = 3,
                     max_turn_deg: float = 12.0, max_scatter_m: float = 0.2) -> list[BuildingBlock]:
    """Move every wall onto its foot as the images that see the wall show it.

    A wall placed ``d`` in front of its true place (along its outward normal) shows, in an image whose ray leaves
    the wall with components ``r_n`` (outward) and ``r_z`` (up), the true wall's foot at height
    ``z_ground + d r_z / r_n`` of the misplaced wall: in a 45 deg oblique one for one.  The texture of such a wall
    is shifted by as much, so the foot - the line where the wall's colour meets the ground's, sharp in the obliques
    that texture it - is where the wall belongs (the eave height, often off by tenths of a metre in a matched DSM,
    does not enter; the ground height in front of the wall is robust: flat, many cells).

    For each wall (footprint edge not on the DSM's border, at least ``2 chunk_m`` long) the ``n_images`` images
    with the finest view of it (incidence within ``max_angle_deg``, as the texturing's) are rectified on the wall's plane extended
    below the ground (where the plane shows the ground in front of the wall) in chunks ``chunk_m`` wide, rows
    ``step_m`` apart (default: a fifth of the image's footprint); per chunk whose foot the image sees (a ray
    march over the DSM) the step from the ground's colour to anything else (wall, window) is located within
    ``+-search_m r_z / r_n`` of the ground height (:func:`_ground_plane`: a plane through the DSM's ground cells
    around the building) and turned into an offset ``d``.  A line ``d(s)`` along the wall (offsets at both ends:
    a wall turned by the DSM's staircase is turned back) is fitted robustly to all images' chunks; the wall
    moves by ``-d(s)`` when at least ``min_chunks`` chunks in total from at least two images, most images agree
    within ``agree_m`` (what the images see beyond the foot differs, the foot does not), the chunks scatter about
    the line by at most ``max_scatter_m`` (robust spread: steep views of a wall's foot are noisy), the move stays
    within ``search_m`` and turns the wall by at most ``max_turn_deg`` (a footprint of a clipped building or of an
    oblique DSM can be turned by several degrees); the corners are the intersections of consecutive moved edge lines, roof
    polygons follow (:func:`_moved_lines`).  ``min_step``: least colour step (0-255 units) between the ground and
    the wall; ``band_m``: height of the bands compared above and below a candidate step (default 1.6 times the
    image's footprint: 0.6 m on the demo town; 2.5 times lets windows at the foot pull the step by ~0.2 m).

    The ground in front of the wall must differ in colour from the wall (a wall on a pavement of its own colour
    keeps its place); in real images, a cast shadow at the foot is part of the ground side.

    Returns new :class:`BuildingBlock` objects in the same order (unchanged where no wall moved)."""
    if not (search_m > 0 and chunk_m > 0):
        raise SkyrigError(f"search_m and chunk_m must be positive, got {search_m}, {chunk_m}")
    if not buildings:
        return []
    pts = np.concatenate([np.column_stack([b.footprint, np.full(len(b.footprint), b.ground_z)]) for b in buildings]
                         + [np.column_stack([b.footprint, np.full(len(b.footprint), b.eave_z)]) for b in buildings])
    ctx = texturing_context(eo, cameras, loader, dsm, pts)
    out = []
    for b in buildings:
        fp = np.asarray(b.footprint, float)
        nv = len(fp)
        d0 = np.zeros(nv)
        d1 = np.zeros(nv)
        ground = _ground_plane(dsm, fp, b.ground_z)
        for i, f in enumerate(b.facades()):
            if f.on_border:
                continue
            L = f.width_m
            if L < 2 * chunk_m:
                continue
            a = fp[i]
            t = (fp[(i + 1) % nv] - a) / L
            n2 = np.array([t[1], -t[0]])
            nch = max(int(L / chunk_m), 2)
            edges = np.linspace(0.05 * L, 0.95 * L, nch + 1)
            samples: list[tuple[float, float, float, int]] = []  # (s, d, weight, image)
            for k, fpm in _candidates(ctx, f.corners, f.normal, TextureConfig(max_angle_deg=max_angle_deg))[:n_images]:
                samples += _foot_samples(ctx, k, fpm, a, t, n2, edges, ground, chunk_m, search_m, step_m, band_m,
                                         min_step)
            got = _foot_line(samples, L, search_m, agree_m, min_chunks, max_turn_deg, max_scatter_m)
            if got is None:
                continue
            e0, e1 = got
            d0[i], d1[i] = -e0, -e1
        out.append(_moved_valid(b, d0, d1, 2 * search_m))
    return out


def _moved_valid(b: BuildingBlock, d0: NDArray, d1: NDArray, max_corner_m: float) -> BuildingBlock:
    """:func:`_moved_lines`, keeping the footprint a simple polygon whose corners move by at most ``max_corner_m``
    (the moved lines of short, nearly parallel edges of a polygon can meet far away): when the whole move breaks
    that, the edges' moves are added one at a time (largest first) and those that break it are left out."""
    import shapely

    def ok(m: BuildingBlock) -> bool:
        fp0, fp1 = np.asarray(b.footprint, float), np.asarray(m.footprint, float)
        poly = shapely.Polygon(fp1)
        return bool(poly.is_valid and poly.area > 0 and np.all(np.linalg.norm(fp1 - fp0, axis=1) <= max_corner_m))

    moved = _moved_lines(b, d0, d1)
    if ok(moved):
        return moved
    e0, e1 = np.zeros_like(d0), np.zeros_like(d1)
    for i in np.argsort(-np.maximum(np.abs(d0), np.abs(d1))):
        if d0[i] == 0 and d1[i] == 0:
            continue
        t0, t1 = e0.copy(), e1.copy()
        t0[i], t1[i] = d0[i], d1[i]
        if ok(_moved_lines(b, t0, t1)):
            e0, e1 = t0, t1
    return _moved_lines(b, e0, e1)


def _foot_samples(ctx: _Context, k: int, fpm: float, a: NDArray, t: NDArray, n2: NDArray, edges: NDArray,
                  ground: Callable[[NDArray], NDArray], chunk_m: float, search_m: float, step_m: float | None,
                  band_m: float | None, min_step: float) -> list[tuple[float, float, float, int]]:
    """Image ``k``'s view of a wall's foot (start ``a``, direction ``t``, outward ``n2``; chunks between ``edges``
    along it): per chunk whose foot the image sees and shows, ``(s, d, step strength, k)`` with ``d`` the wall's
    offset in front of its foot (see :func:`refine_wall_feet`)."""
    g = ctx.dsm.grid
    cam = ctx.cameras[str(ctx.eo_l.camera[k])]
    C = ctx.centres_dsm[k]
    centres = 0.5 * (edges[1:] + edges[:-1])
    nch = len(centres)
    zg = ground(a + centres[:, None] * t)
    # ray geometry at the chunks' feet: height change per metre of wall offset
    foot = np.column_stack([a + centres[:, None] * t, zg])
    r = C[None] - foot
    r /= np.linalg.norm(r, axis=1, keepdims=True)
    rn = r[:, :2] @ n2
    if np.any(rn <= 0.05):
        return []
    ratio = r[:, 2] / rn
    dz = step_m if step_m is not None else 0.2 * fpm
    band = max(int(round((band_m if band_m is not None else 1.6 * fpm) / dz)), 2)
    search = search_m * ratio
    zlo = float(np.min(zg - search)) - 3 * band * dz
    zhi = float(np.max(zg + search)) + 2 * band * dz
    z = np.arange(zlo, zhi, dz)
    cols = np.linspace(0, 1, max(int(chunk_m / dz), 3), endpoint=False)
    ss = (edges[:-1, None] + cols[None] * (edges[1:] - edges[:-1])[:, None]).ravel()  # (J * Q)
    Z, S = np.meshgrid(z, ss, indexing="ij")
    P = np.column_stack([a[0] + S.ravel() * t[0], a[1] + S.ravel() * t[1], Z.ravel()])
    px = cam.project_pixels((ctx.to_local(P) - ctx.eo_l.centre[k]) @ ctx.eo_l.rotation[k])
    smp = _sample(ctx.images(k), px).reshape(len(z), nch, -1, 3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        col = np.nanmean(smp, axis=2)
    # the foot must be seen: the rays through the chunks' feet, marched over the DSM from beyond the search range
    # (a wall placed inside its building has its own roof over its foot)
    q = foot + ((search_m + 0.3) / rn)[:, None] * r
    vis = _visible(ctx.dsm_filled, g.x0, g.y0, g.cell_m, np.ascontiguousarray(q), np.ascontiguousarray(C),
                   np.full(len(q), 0.5 * g.cell_m), 0.5 * g.cell_m, ctx.zmax, 0.3)
    zs, st = _foot_profile_peaks(col, vis, z, zg, search, band, min_step)
    return [(float(centres[j]), float((zs[j] - zg[j]) / ratio[j]), float(st[j]), k)
            for j in np.flatnonzero(np.isfinite(zs))]


def _foot_line(samples: list[tuple[float, float, float, int]], L: float, search_m: float, agree_m: float,
               min_chunks: int, max_turn_deg: float, max_scatter_m: float) -> tuple[float, float] | None:
    """The wall's offsets ``(start, end)`` in front of its foot from all images' chunks (a robust line), or None
    when the images do not settle it (see :func:`refine_wall_feet`)."""
    if len(samples) < min_chunks:
        return None
    sm = np.array(samples)
    line = _robust_line(sm[:, 0] / L, sm[:, 1], sm[:, 2])
    if line is None:
        return None
    res = sm[:, 1] - (line[0] + line[1] * sm[:, 0] / L)
    imgs = np.unique(sm[:, 3])
    agree = [np.median(np.abs(res[sm[:, 3] == k])) <= agree_m for k in imgs]
    if len(imgs) < 2 or sum(agree) <= 0.5 * len(imgs) or np.sum(np.abs(res) <= agree_m) < min_chunks:
        return None
    if 1.4826 * float(np.median(np.abs(res))) > max_scatter_m:
        return None
    e0, e1 = line[0], line[0] + line[1]
    if max(abs(e0), abs(e1)) > search_m or abs(e1 - e0) > L * np.tan(np.radians(max_turn_deg)):
        return None
    return float(e0), float(e1)


def _robust_line(x: NDArray, y: NDArray, w: NDArray, iters: int = 6) -> tuple[float, float] | None:
    """``y = c0 + c1 x`` by iteratively reweighted least squares (Tukey weights times ``w``); a constant when ``x``
    spans less than half the range.  The first weights are Tukey's about the weighted median of ``y`` (scale: the
    median absolute deviation), not a least-squares start: a third of the samples off to one side (a window's sill
    taken for the foot in the chunks under a window column) pulls a least-squares start so far that the
    reweighting settles between the two groups."""
    x, y, w = (np.asarray(v, float) for v in (x, y, w))
    if len(x) < 2:
        return None
    line = float(np.ptp(x)) >= 0.5 and len(x) >= 4
    A = np.column_stack([np.ones_like(x), x]) if line else np.ones((len(x), 1))
    o = np.argsort(y)
    cw = np.cumsum(w[o])
    med = float(y[o][min(int(np.searchsorted(cw, 0.5 * cw[-1])), len(y) - 1)]) if cw[-1] > 0 else float(np.median(y))
    r = y - med
    s = max(1.4826 * float(np.median(np.abs(r))), 0.02)
    u = r / (4.685 * s)
    wt = w * np.where(np.abs(u) < 1, (1 - u * u) ** 2, 0.0)
    if (wt > 0).sum() < A.shape[1] + 1:
        return None
    c = np.zeros(A.shape[1])
    for _ in range(iters):
        sw = np.sqrt(wt)
        c, *_ = np.linalg.lstsq(A * sw[:, None], y * sw, rcond=None)
        r = y - A @ c
        s = max(1.4826 * float(np.median(np.abs(r))), 0.02)
        u = r / (4.685 * s)
        wt = w * np.where(np.abs(u) < 1, (1 - u * u) ** 2, 0.0)
        if (wt > 0).sum() < A.shape[1] + 1:
            return None
    return (float(c[0]), float(c[1]) if line else 0.0)


def _moved_lines(b: BuildingBlock, d0: NDArray, d1: NDArray) -> BuildingBlock:
    """The building with footprint edge ``i`` moved along its outward normal by ``d0[i]`` at its start and
    ``d1[i]`` at its end (a shift and a turn); corners are the intersections of consecutive moved edge lines and
    roof vertices follow (corners to corners, points on an edge to the same place along the moved edge)."""
    fp = np.asarray(b.footprint, float)
    nv = len(fp)
    if not (np.any(d0) or np.any(d1)):
        return b
    starts, ends = [], []
    for i in range(nv):
        a, e = fp[i], fp[(i + 1) % nv]
        d = e - a
        nrm = np.array([d[1], -d[0]]) / np.linalg.norm(d)
        starts.append(a + d0[i] * nrm)
        ends.append(e + d1[i] * nrm)
    new = fp.copy()
    for i in range(nv):
        j = (i - 1) % nv  # edge j ends at vertex i, edge i starts there
        p, r = starts[j], ends[j] - starts[j]
        q, s = starts[i], ends[i] - starts[i]
        den = r[0] * s[1] - r[1] * s[0]
        if abs(den) < 1e-9 * np.linalg.norm(r) * np.linalg.norm(s):  # collinear: the mean of both moved ends
            new[i] = 0.5 * (ends[j] + starts[i])
        else:
            tt = ((q[0] - p[0]) * s[1] - (q[1] - p[1]) * s[0]) / den
            new[i] = p + tt * r
    return _with_footprint(b, fp, new)


class RoofTexture(NamedTuple):
    """The texture of one roof polygon: ``corners`` ``(4, 3)`` of the textured rectangle (bottom-start,
    bottom-end, top-end, top-start as :func:`texture_plane`), the polygon's texels in ``texture.valid``."""

    building: int
    index: int
    corners: NDArray[np.float64]
    texture: PlaneTexture


def roof_rectangle(polygon: NDArray) -> NDArray[np.float64]:
    """``(4, 3)`` corners of the rectangle (in the polygon's plane) that bounds a planar roof polygon ``(K, 3)``:
    the polygon itself when it is a counter-clockwise quadrilateral, else its minimum-area rectangle in plan with
    heights from the polygon's plane; counter-clockwise from above, so the texture's normal points up."""
    import cv2

    p = np.asarray(polygon, float)
    A = np.column_stack([p[:, 0], p[:, 1], np.ones(len(p))])
    coef, *_ = np.linalg.lstsq(A, p[:, 2], rcond=None)
    if len(p) == 4:
        q = p
    else:
        c0 = p[:, :2].mean(axis=0)
        box = cv2.boxPoints(cv2.minAreaRect((p[:, :2] - c0).astype(np.float32))).astype(np.float64) + c0
        q = np.column_stack([box, box @ coef[:2] + coef[2]])
    x, y = q[:, 0], q[:, 1]
    if np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) < 0:
        q = q[::-1].copy()
    return q


def texture_roofs(buildings: Sequence[BuildingBlock], eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera],
                  loader: ImageLoader, dsm: DsmGrid, *, texel_m: float | None = None, max_images: int = 3,
                  config: TextureConfig | None = None) -> list[RoofTexture]:
    """Occlusion-aware textures of every roof polygon of ``buildings`` (as :func:`texture_facades` for walls).

    Each polygon is textured over :func:`roof_rectangle` with :func:`texture_plane` (normal up, out of the roof);
    texels outside the polygon (in plan) are marked invalid."""
    import cv2
    from dataclasses import replace

    cfg = replace(config or TextureConfig(), texel_m=texel_m, max_images=int(max_images))
    polys = [(b.id, i, np.asarray(r, float)) for b in buildings for i, r in enumerate(b.roof)]
    if not polys:
        return []
    ctx = texturing_context(eo, cameras, loader, dsm, np.concatenate([p for _, _, p in polys]))
    out = []
    for bid, i, poly in polys:
        q = roof_rectangle(poly)
        rgb, valid, texel, names, src, stats = _texture_plane(q, ctx, cfg, None)
        H, W = valid.shape
        u, v, _, _, _ = _plane_axes(q)
        # the polygon in texel coordinates (texel centres at integers), rasterised
        col = ((poly - q[3]) @ u) / texel - 0.5
        row = ((q[3] - poly) @ v) / texel - 0.5
        inside = np.zeros((H, W), np.uint8)
        cv2.fillPoly(inside, [np.round(np.column_stack([col, row]) * 16).astype(np.int32)], 1, shift=4)
        valid = valid & inside.astype(bool)
        src = np.where(valid, src, -1).astype(np.int16)
        out.append(RoofTexture(bid, i, q, PlaneTexture(rgb, valid, texel, names, src, stats)))
    return out
