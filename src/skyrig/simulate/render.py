"""Vectorised ray casting of a :class:`~skyrig.simulate.world.Scene` into frame-camera images.

For every pixel centre the camera's observed-to-ideal model (:meth:`FrameCamera.rays_from_pixels`,
i.e. the lens distortion is inverted exactly) gives the ray in the camera frame; the pose
``world_from_camera`` (local scene frame) turns it into the world.  Each ray is intersected with

* the terrain: bracketed between the planes of its highest and lowest point and refined by the
  Illinois variant of regula falsi to ``1e-6`` m (vectorised over all rays);
* every building (a convex prism of half-spaces; slab method) whose bounding sphere the ray passes;

and the nearest hit is textured (ground / roof / façade rule of the scene) and shaded (Lambertian,
fixed sun: identical in every view).  Rays that hit nothing see the sky.

Speed (``bench/simulate.py``): rays are kept as three contiguous columns; the analytic terrain's phases are
linear in the ray parameter, so a regula-falsi step costs one sine per terrain term and ray; a camera's
rays are cached by value (copies sent to worker processes hit the cache) together with 32 x 32 pixel
tiles bounding them by cones, against which each building's bounding sphere is tested before any of its
rays; the ground texture's lattice hashes share their products.  The output is bit-identical to the
straightforward per-ray formulation.  A :class:`~skyrig.simulate.world.RasterScene` (a given DSM) is
ray-marched in half-cell steps to its first crossing before the refinement.
"""

from __future__ import annotations

import pickle
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from skyrig.camera.frame import FrameCamera
from skyrig.errors import GeometryError
from skyrig.geometry.pose import Pose
from skyrig.simulate.world import Scene

#: hit kinds
SKY, TERRAIN, ROOF, WALL = 0, 1, 2, 3
_SKY_RGB = np.array([0.62, 0.75, 0.92])


@dataclass(frozen=True)
class Hits:
    """Ray casting results for ``N`` rays.

    Attributes
    ----------
    t
        ``(N,)`` distance along the unit ray (metres; inf for the sky).
    xyz
        ``(N, 3)`` hit points (NaN for the sky).
    kind
        ``(N,)`` SKY (0), TERRAIN (1), ROOF (2) or WALL (3).
    building, face
        ``(N,)`` building index and half-space index of the hit face (-1 for terrain and sky).
    normal
        ``(N, 3)`` unit surface normal at the hit (zeros for the sky).
    """

    t: NDArray[np.float64]
    xyz: NDArray[np.float64]
    kind: NDArray[np.int64]
    building: NDArray[np.int64]
    face: NDArray[np.int64]
    normal: NDArray[np.float64]


def _terrain_is_analytic(scene: Scene) -> bool:
    return type(scene).terrain_height is Scene.terrain_height


def intersect_terrain(scene: Scene, origin: NDArray[np.float64], d: NDArray[np.float64],
                      tol_m: float = 1e-6, max_iter: int = 80) -> NDArray[np.float64]:
    """Distances ``(N,)`` along unit rays ``d (N, 3)`` from ``origin (3,)`` to the terrain (inf where none)."""
    dd = np.asarray(d, dtype=np.float64)
    return _terrain_t(scene, np.asarray(origin, dtype=np.float64).reshape(3),
                      tuple(np.ascontiguousarray(dd[:, j]) for j in range(3)), tol_m, max_iter)


def _terrain_t(scene: Scene, origin: NDArray[np.float64], cols: tuple[NDArray, NDArray, NDArray],
               tol_m: float = 1e-6, max_iter: int = 80) -> NDArray[np.float64]:
    """:func:`intersect_terrain` on ray direction columns ``(dx, dy, dz)`` ``(N,)`` each.

    The ray is bracketed between the planes of the terrain's highest and lowest point and the root of
    ``f(t) = z(t) - terrain(x(t), y(t))`` refined by the Illinois variant of regula falsi.  For the analytic
    terrain ``sum a_k sin(kx_k x + ky_k y + phase_k)`` the phase of every term is linear in ``t`` along a
    ray (``c_k + t s_k``), so an evaluation of ``f`` costs one sine per term and ray.
    """
    dx, dy, dz = cols
    zmin, zmax = scene.terrain_range
    zmin -= 1e-3
    zmax += 1e-3
    n = dz.shape[0]
    t = np.full(n, np.inf)
    if origin[2] <= zmax:
        h0 = float(scene.terrain_height(origin[0], origin[1]))
        if origin[2] <= h0:
            raise GeometryError("the camera is below the terrain")
    down = dz < -1e-12
    all_down = bool(down.all())
    idx = None if all_down else np.flatnonzero(down)
    if idx is not None and idx.size == 0:
        return t
    rx, ry, rz = (dx, dy, dz) if all_down else (dx[idx], dy[idx], dz[idx])
    ox, oy, oz = (float(v) for v in origin)
    inv_dz = 1.0 / rz
    a = np.maximum((zmax - oz) * inv_dz, 0.0)
    b = (zmin - oz) * inv_dz
    if _terrain_is_analytic(scene):
        amp = [float(v) for v in scene.terrain_amp_m]
        c0 = [float(kx * ox + ky * oy + ph) for kx, ky, ph in zip(scene.terrain_kx, scene.terrain_ky, scene.terrain_phase)]
        slope = [float(kx) * rx + float(ky) * ry for kx, ky in zip(scene.terrain_kx, scene.terrain_ky)]
        base = float(scene.base_height_m)

        piles = scene.stockpiles if scene.stockpiles is not None and len(scene.stockpiles) else None

        def f(sel: NDArray[np.intp] | None, tt: NDArray[np.float64]) -> NDArray[np.float64]:
            z = (oz - base) + tt * (rz if sel is None else rz[sel])
            for ak, ck, sk in zip(amp, c0, slope):
                z -= ak * np.sin(ck + tt * (sk if sel is None else sk[sel]))
            if piles is not None:  # the stockpiles' heights at the ray's point (they stand on the analytic terrain)
                z -= piles.height(ox + tt * (rx if sel is None else rx[sel]), oy + tt * (ry if sel is None else ry[sel]))
            return z
    else:
        def f(sel: NDArray[np.intp] | None, tt: NDArray[np.float64]) -> NDArray[np.float64]:
            x = ox + tt * (rx if sel is None else rx[sel])
            y = oy + tt * (ry if sel is None else ry[sel])
            return oz + tt * (rz if sel is None else rz[sel]) - scene.terrain_height(x, y)

    step = getattr(scene, "march_step_m", None)
    if step is not None:  # a 2.5D raster surface: march to the first crossing, then refine within the step
        a, b = _march(f, a, b, np.hypot(rx, ry), float(step))
    fa, fb = f(None, a), f(None, b)
    m = a.size
    res = np.full(m, np.inf)
    side = np.zeros(m, dtype=np.int8)
    active: NDArray[np.intp] | None = None  # None: all rays still active (no gathers)
    for _ in range(max_iter):
        if active is not None and active.size == 0:
            break
        if active is None:
            aa, bb, fa_, fb_, s = a, b, fa, fb, side
        else:
            aa, bb, fa_, fb_, s = a[active], b[active], fa[active], fb[active], side[active]
        c = (aa * fb_ - bb * fa_) / (fb_ - fa_)
        fc = f(active, c)
        pos = fc > 0
        # Illinois: halve the retained end's function value when the same end is kept twice
        new_fa = np.where(pos, fc, np.where(s == -1, fa_ * 0.5, fa_))
        new_fb = np.where(pos, np.where(s == 1, fb_ * 0.5, fb_), fc)
        new_a = np.where(pos, c, aa)
        new_b = np.where(pos, bb, c)
        new_s = np.where(pos, 1, -1).astype(np.int8)
        done = np.abs(fc) < tol_m
        if active is None:
            a, b, fa, fb, side = new_a, new_b, new_fa, new_fb, new_s
            res[done] = c[done]
            active = np.flatnonzero(~done)
        else:
            a[active], b[active], fa[active], fb[active], side[active] = new_a, new_b, new_fa, new_fb, new_s
            res[active[done]] = c[done]
            active = active[~done]
    if active is None:
        res = 0.5 * (a + b)
    elif active.size:
        res[active] = 0.5 * (a[active] + b[active])
    if idx is None:
        return res
    t[idx] = res
    return t


def _march(f, a: NDArray[np.float64], b: NDArray[np.float64], horiz: NDArray[np.float64], step_m: float
           ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Brackets ``[a', b']`` of the first sign change of ``f`` (positive above the surface) on ``[a, b]``,
    stepping ``step_m`` horizontally along each ray (``horiz``: the rays' horizontal direction components)."""
    dt = step_m / np.maximum(horiz, 1e-12)
    lo = a.copy()
    hi = b.copy()
    active = np.arange(a.size)
    t = a.copy()
    while active.size:
        t_next = np.minimum(t[active] + dt[active], b[active])
        below = f(active, t_next) <= 0
        done = below | (t_next >= b[active])
        idx = active[done]
        lo[idx] = t[active][done]
        hi[idx] = t_next[done]
        t[active] = t_next
        active = active[~done]
    return lo, hi


@dataclass(frozen=True, eq=False)
class _RayGrid:
    """Camera-frame rays of all pixels of a camera as columns, and 32 x 32 pixel tiles bounding them."""

    cols: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]
    tile_of_ray: NDArray[np.int32]  # (N,)
    tile_axis: NDArray[np.float64]  # (T, 3) unit, camera frame
    tile_cos: NDArray[np.float64]  # (T,) cosine of the tile cone's half angle
    tile_sin: NDArray[np.float64]


_TILE = 32


def _ray_grid(camera: FrameCamera, rays: NDArray[np.float64]) -> _RayGrid:
    h, w = camera.height, camera.width
    cols = tuple(np.ascontiguousarray(rays[:, j]) for j in range(3))
    ty = np.arange(h) // _TILE
    tx = np.arange(w) // _TILE
    ntx = int(tx[-1]) + 1
    tile = (ty[:, None] * ntx + tx[None, :]).astype(np.int32).ravel()
    nt = int(tile.max()) + 1
    axis = np.zeros((nt, 3))
    for j in range(3):
        axis[:, j] = np.bincount(tile, cols[j], minlength=nt)
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    cosang = np.einsum("ij,ij->i", rays, axis[tile])
    cmin = np.full(nt, 1.0)
    np.minimum.at(cmin, tile, cosang)
    # a margin for rounding: widen each cone by 1e-6 rad
    ang = np.arccos(np.clip(cmin, -1.0, 1.0)) + 1e-6
    return _RayGrid(cols, tile, axis, np.cos(ang), np.sin(ang))


def _cast(scene: Scene, o: NDArray[np.float64], cols: tuple[NDArray, NDArray, NDArray],
          grid: tuple[NDArray[np.int32], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]] | None = None
          ) -> Hits:
    """Ray casting on unit direction columns; ``grid``: (tile of each ray, world tile axes (T, 3), cos and sin
    of the tiles' half angles) to cull buildings by tile cones instead of testing every ray."""
    dx, dy, dz = cols
    n = dx.shape[0]
    t = _terrain_t(scene, o, cols)
    kind = np.where(np.isfinite(t), TERRAIN, SKY).astype(np.int64)
    bidx = np.full(n, -1, dtype=np.int64)
    face = np.full(n, -1, dtype=np.int64)
    normal = np.zeros((n, 3))
    bl = scene.buildings
    for i in range(len(bl)):
        v = bl.vertices(i)
        centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
        rad = 0.5 * float(np.linalg.norm(v.max(axis=0) - v.min(axis=0))) + 1e-6
        w = centre - o
        wn = float(np.linalg.norm(w))
        if grid is not None and wn > rad:
            tile_of, axes, tcos, tsin = grid
            # tiles whose cone meets the building's bounding cone: angle(axis, w) <= tile angle + asin(rad / |w|)
            sa = rad / wn
            ca = np.sqrt(1.0 - sa * sa)
            cos_lim = tcos * ca - tsin * sa  # cos(tile angle + building angle)
            cos_lim = np.where(np.arccos(np.clip(tcos, -1, 1)) + np.arcsin(sa) >= np.pi, -2.0, cos_lim)
            tiles = (axes @ w) / wn >= cos_lim
            if not tiles.any():
                continue
            cand = np.flatnonzero(tiles[tile_of])
        else:
            cand = None
        if cand is None:
            proj = dx * w[0] + dy * w[1] + dz * w[2]
            thr = np.sqrt(max(wn * wn - rad * rad, 0.0)) if wn > rad else -rad
            cand = np.flatnonzero(proj >= thr)
        else:
            proj = dx[cand] * w[0] + dy[cand] * w[1] + dz[cand] * w[2]
            cand = cand[proj >= np.sqrt(wn * wn - rad * rad)]
        if cand.size == 0:
            continue
        nrm, off, knd = bl.planes(i)
        dc = np.column_stack([dx[cand], dy[cand], dz[cand]])
        denom = dc @ nrm.T  # (M, P)
        num = off - nrm @ o  # (P,)
        with np.errstate(divide="ignore", invalid="ignore"):
            tp = num[None, :] / denom
        entering = denom < 0
        t_in = np.where(entering, tp, -np.inf)
        t_out = np.where(denom > 0, tp, np.inf)
        parallel_out = (denom == 0) & (num[None, :] < 0)
        tin = t_in.max(axis=1)
        tout = t_out.min(axis=1)
        hit = (tin <= tout) & (tin > 0) & ~parallel_out.any(axis=1) & (tin < t[cand])
        if not np.any(hit):
            continue
        sel = cand[hit]
        fidx = np.argmax(t_in[hit], axis=1)
        t[sel] = tin[hit]
        bidx[sel] = i
        face[sel] = fidx
        kind[sel] = np.where(knd[fidx] == 1, ROOF, WALL)
        normal[sel] = nrm[fidx]
    fin = np.isfinite(t)
    xyz = np.empty((n, 3))
    t0 = np.where(fin, t, 0.0)
    for j, dj in enumerate(cols):
        xyz[:, j] = o[j] + t0 * dj
    if not fin.all():
        xyz[~fin] = np.nan
    ter = kind == TERRAIN
    if np.any(ter):
        gx, gy = scene.terrain_gradient(xyz[ter, 0], xyz[ter, 1])
        inv = 1.0 / np.sqrt(gx * gx + gy * gy + 1.0)
        normal[ter] = np.column_stack([-gx * inv, -gy * inv, inv])
    return Hits(t, xyz, kind, bidx, face, normal)


def cast_rays(scene: Scene, origin: np.ndarray, directions: np.ndarray) -> Hits:
    """Nearest intersection of rays from one ``origin (3,)`` along ``directions (N, 3)`` with the scene."""
    o = np.asarray(origin, dtype=np.float64).reshape(3)
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    return _cast(scene, o, tuple(np.ascontiguousarray(d[:, j]) for j in range(3)))


def shade(scene: Scene, hits: Hits) -> NDArray[np.float64]:
    """Colours ``(N, 3)`` in [0, 1] of ray hits (texture x Lambertian shading; sky colour for misses)."""
    n = hits.t.shape[0]
    ter = hits.kind == TERRAIN
    all_ter = bool(ter.all())
    if all_ter:  # the common case of a view of open country: no gathers and scatters
        rgb = scene.ground_rgb(np.ascontiguousarray(hits.xyz[:, 0]), np.ascontiguousarray(hits.xyz[:, 1]))
    else:
        rgb = np.tile(_SKY_RGB, (n, 1))
    if np.any(ter) and not all_ter:
        rgb[ter] = scene.ground_rgb(hits.xyz[ter, 0], hits.xyz[ter, 1])
    roof = hits.kind == ROOF
    if np.any(roof):
        rgb[roof] = scene.roof_rgb(hits.building[roof], hits.xyz[roof, 0], hits.xyz[roof, 1])
    wall = hits.kind == WALL
    if np.any(wall):
        b = hits.building[wall]
        nrm = hits.normal[wall]
        p = hits.xyz[wall]
        u = -nrm[:, 1] * p[:, 0] + nrm[:, 0] * p[:, 1]  # along-wall coordinate (tangent = z x n)
        rgb[wall] = scene.facade_rgb(b, u, p[:, 2], hits.face[wall])
    hit = hits.kind != SKY
    if hit.all():
        lam = np.clip(hits.normal @ scene.sun, 0.0, 1.0)
        rgb *= (0.45 + 0.6 * lam)[:, None]
    else:
        lam = np.clip(hits.normal[hit] @ scene.sun, 0.0, 1.0)
        rgb[hit] = rgb[hit] * (0.45 + 0.6 * lam)[:, None]
    return np.clip(rgb, 0.0, 1.0, out=rgb)


_RAY_CACHE: dict[bytes, tuple[NDArray[np.float64], _RayGrid | None]] = {}
_KEY_BY_ID: dict[int, tuple[FrameCamera, bytes]] = {}


def _camera_key(camera: FrameCamera) -> bytes:
    """A value key of a camera (equal cameras share cached rays, e.g. copies sent to worker processes)."""
    hit = _KEY_BY_ID.get(id(camera))
    if hit is not None and hit[0] is camera:
        return hit[1]
    key = pickle.dumps(camera, protocol=4)
    if len(_KEY_BY_ID) > 256:
        _KEY_BY_ID.clear()
    _KEY_BY_ID[id(camera)] = (camera, key)
    return key


def camera_rays(camera: FrameCamera) -> NDArray[np.float64]:
    """Unit camera-frame rays ``(H * W, 3)`` of all pixel centres (row-major), cached per camera (by value)."""
    key = _camera_key(camera)
    hit = _RAY_CACHE.get(key)
    if hit is not None:
        return hit[0]
    cols, rows = np.meshgrid(np.arange(camera.width, dtype=np.float64), np.arange(camera.height, dtype=np.float64))
    rays = camera.rays_from_pixels(np.column_stack([cols.ravel(), rows.ravel()]))
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    if len(_RAY_CACHE) > 16:
        _RAY_CACHE.clear()
    _RAY_CACHE[key] = (rays, None)
    return rays


def _camera_grid(camera: FrameCamera) -> _RayGrid:
    rays = camera_rays(camera)
    key = _camera_key(camera)
    _, grid = _RAY_CACHE[key]
    if grid is None:
        grid = _ray_grid(camera, rays)
        _RAY_CACHE[key] = (rays, grid)
    return grid


def render_image(
    scene: Scene,
    camera: FrameCamera,
    world_from_camera: Pose,
    noise_dn: float = 0.0,
    seed: int = 0,
    return_hits: bool = False,
) -> NDArray[np.uint8] | tuple[NDArray[np.uint8], Hits]:
    """Render one image.

    Parameters
    ----------
    scene
        The scene (local frame).
    camera
        Camera model including distortion (the image is the *observed*, distorted image).
    world_from_camera
        True exterior orientation in the scene's local frame (single pose).
    noise_dn
        Standard deviation of additive Gaussian sensor noise in digital numbers (0-255 scale).
    seed
        Seed of the noise.
    return_hits
        Also return the per-pixel :class:`Hits` (row-major, ``H * W`` rays).

    Returns
    -------
    ``(H, W, 3)`` uint8 RGB image (and the hits).
    """
    g = _camera_grid(camera)
    r = np.asarray(world_from_camera.rotation, dtype=np.float64).reshape(3, 3)
    cx, cy, cz = g.cols
    cols = tuple(r[j, 0] * cx + r[j, 1] * cy + r[j, 2] * cz for j in range(3))  # world directions, unit
    o = np.asarray(world_from_camera.translation, dtype=np.float64).reshape(3)
    hits = _cast(scene, o, cols, (g.tile_of_ray, g.tile_axis @ r.T, g.tile_cos, g.tile_sin))
    rgb = shade(scene, hits)
    rgb *= 255.0
    rgb += 0.5
    if noise_dn > 0:
        rgb += np.random.default_rng(seed).normal(0.0, noise_dn, rgb.shape)
    np.clip(rgb, 0, 255, out=rgb)
    img = rgb.astype(np.uint8).reshape(camera.height, camera.width, 3)
    if return_hits:
        return img, hits
    return img


def ray_hits_at_pixels(scene: Scene, camera: FrameCamera, world_from_camera: Pose, pixels: np.ndarray) -> Hits:
    """Scene points seen at given pixels ``(M, 2)`` (col, row; any sub-pixel position, e.g. image corners)."""
    rays_c = camera.rays_from_pixels(np.asarray(pixels, dtype=np.float64).reshape(-1, 2))
    d = rays_c @ np.asarray(world_from_camera.rotation, dtype=np.float64).reshape(3, 3).T
    return cast_rays(scene, np.asarray(world_from_camera.translation).reshape(3), d)
