"""Vectorised ray casting of a :class:`~skyrig.simulate.world.Scene` into frame-camera images.

For every pixel centre the camera's observed-to-ideal model (:meth:`FrameCamera.rays_from_pixels`,
i.e. the lens distortion is inverted exactly) gives the ray in the camera frame; the pose
``world_from_camera`` (local scene frame) turns it into the world.  Each ray is intersected with

* the terrain: bracketed between the planes of its highest and lowest point and refined by the
  Illinois variant of regula falsi to ``1e-6`` m (vectorised over all rays);
* every building (a convex prism of half-spaces; slab method) whose bounding sphere the ray passes;

and the nearest hit is textured (ground / roof / façade rule of the scene) and shaded (Lambertian,
fixed sun: identical in every view).  Rays that hit nothing see the sky.
"""

from __future__ import annotations

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


def intersect_terrain(scene: Scene, origin: NDArray[np.float64], d: NDArray[np.float64],
                      tol_m: float = 1e-6, max_iter: int = 80) -> NDArray[np.float64]:
    """Distances ``(N,)`` along unit rays ``d (N, 3)`` from ``origin (3,)`` to the terrain (inf where none)."""
    zmin, zmax = scene.terrain_range
    zmin -= 1e-3
    zmax += 1e-3
    n = d.shape[0]
    t = np.full(n, np.inf)
    down = d[:, 2] < -1e-12
    if origin[2] <= zmax:
        h0 = float(scene.terrain_height(origin[0], origin[1]))
        if origin[2] <= h0:
            raise GeometryError("the camera is below the terrain")
    idx = np.nonzero(down)[0]
    if idx.size == 0:
        return t
    dz = d[idx, 2]
    a = np.maximum((zmax - origin[2]) / dz, 0.0)
    b = (zmin - origin[2]) / dz

    def f(ii: NDArray[np.intp], tt: NDArray[np.float64]) -> NDArray[np.float64]:
        p = origin + tt[:, None] * d[ii]
        return p[:, 2] - scene.terrain_height(p[:, 0], p[:, 1])

    fa, fb = f(idx, a), f(idx, b)
    side = np.zeros(idx.size, dtype=np.int8)
    active = np.arange(idx.size)
    for _ in range(max_iter):
        if active.size == 0:
            break
        aa, bb, fa_, fb_ = a[active], b[active], fa[active], fb[active]
        c = (aa * fb_ - bb * fa_) / (fb_ - fa_)
        fc = f(idx[active], c)
        pos = fc > 0
        s = side[active]
        # Illinois: halve the retained end's function value when the same end is kept twice
        new_fa = np.where(pos, fc, np.where(s == -1, fa_ * 0.5, fa_))
        new_fb = np.where(pos, np.where(s == 1, fb_ * 0.5, fb_), fc)
        a[active] = np.where(pos, c, aa)
        b[active] = np.where(pos, bb, c)
        fa[active] = new_fa
        fb[active] = new_fb
        side[active] = np.where(pos, 1, -1)
        done = np.abs(fc) < tol_m
        res = np.where(done, c, np.nan)
        tt = t[idx[active]]
        t[idx[active]] = np.where(done, res, tt)
        active = active[~done]
    if active.size:
        t[idx[active]] = 0.5 * (a[active] + b[active])
    return t


def cast_rays(scene: Scene, origin: np.ndarray, directions: np.ndarray) -> Hits:
    """Nearest intersection of rays from one ``origin (3,)`` along ``directions (N, 3)`` with the scene."""
    o = np.asarray(origin, dtype=np.float64).reshape(3)
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    n = d.shape[0]
    t = intersect_terrain(scene, o, d)
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
        proj = d @ w
        dist2 = float(w @ w) - proj * proj
        cand = np.nonzero((dist2 <= rad * rad) & (proj > -rad))[0]
        if cand.size == 0:
            continue
        nrm, off, knd = bl.planes(i)
        dc = d[cand]
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
    xyz = np.where(np.isfinite(t)[:, None], o + np.where(np.isfinite(t), t, 0.0)[:, None] * d, np.nan)
    ter = kind == TERRAIN
    if np.any(ter):
        gx, gy = scene.terrain_gradient(xyz[ter, 0], xyz[ter, 1])
        nn = np.column_stack([-gx, -gy, np.ones_like(gx)])
        normal[ter] = nn / np.linalg.norm(nn, axis=1, keepdims=True)
    return Hits(t, xyz, kind, bidx, face, normal)


def shade(scene: Scene, hits: Hits) -> NDArray[np.float64]:
    """Colours ``(N, 3)`` in [0, 1] of ray hits (texture x Lambertian shading; sky colour for misses)."""
    n = hits.t.shape[0]
    rgb = np.tile(_SKY_RGB, (n, 1))
    ter = hits.kind == TERRAIN
    if np.any(ter):
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
    lam = np.clip(hits.normal[hit] @ scene.sun, 0.0, 1.0)
    rgb[hit] = rgb[hit] * (0.45 + 0.6 * lam)[:, None]
    return np.clip(rgb, 0.0, 1.0)


_RAY_CACHE: dict[int, tuple[FrameCamera, NDArray[np.float64]]] = {}


def camera_rays(camera: FrameCamera) -> NDArray[np.float64]:
    """Unit camera-frame rays ``(H * W, 3)`` of all pixel centres (row-major), cached per camera object."""
    hit = _RAY_CACHE.get(id(camera))
    if hit is not None and hit[0] is camera:
        return hit[1]
    cols, rows = np.meshgrid(np.arange(camera.width, dtype=np.float64), np.arange(camera.height, dtype=np.float64))
    rays = camera.rays_from_pixels(np.column_stack([cols.ravel(), rows.ravel()]))
    if len(_RAY_CACHE) > 16:
        _RAY_CACHE.clear()
    _RAY_CACHE[id(camera)] = (camera, rays)
    return rays


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
    rays_c = camera_rays(camera)
    d = rays_c @ np.asarray(world_from_camera.rotation, dtype=np.float64).reshape(3, 3).T
    o = np.asarray(world_from_camera.translation, dtype=np.float64).reshape(3)
    hits = cast_rays(scene, o, d)
    rgb = shade(scene, hits) * 255.0
    if noise_dn > 0:
        rgb = rgb + np.random.default_rng(seed).normal(0.0, noise_dn, rgb.shape)
    img = np.clip(rgb + 0.5, 0, 255).astype(np.uint8).reshape(camera.height, camera.width, 3)
    if return_hits:
        return img, hits
    return img


def ray_hits_at_pixels(scene: Scene, camera: FrameCamera, world_from_camera: Pose, pixels: np.ndarray) -> Hits:
    """Scene points seen at given pixels ``(M, 2)`` (col, row; any sub-pixel position, e.g. image corners)."""
    rays_c = camera.rays_from_pixels(np.asarray(pixels, dtype=np.float64).reshape(-1, 2))
    d = rays_c @ np.asarray(world_from_camera.rotation, dtype=np.float64).reshape(3, 3).T
    return cast_rays(scene, np.asarray(world_from_camera.translation).reshape(3), d)
