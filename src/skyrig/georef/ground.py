"""Ground <-> image: world-to-image projection, image-to-world by intersection with a height surface or a
DEM, and forward intersection of rays from two or more images.

Everything is computed rigorously in a local Cartesian frame (ENU at the block, through ECEF): map
coordinates are only used for input and output, so projection scale and earth curvature never enter
the collinearity equations (see ``docs/frames.md``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.camera.frame import FrameCamera
from skyrig.camera.jacobians import project_with_jacobians
from skyrig.errors import GeometryError, InputFormatError
from skyrig.georef.eo import ExteriorOrientations, WorldFrame, local_frame_for
from skyrig.geometry.pose import Pose

_CHUNK = 2_000_000


def _lookup(eo: ExteriorOrientations, images: NDArray[np.str_]) -> NDArray[np.int64]:
    idx = eo.index()
    uniq, inv = np.unique(images, return_inverse=True)
    rows = np.empty(len(uniq), dtype=np.int64)
    for i, name in enumerate(uniq):
        if name not in idx:
            raise InputFormatError(f"image {name!r} has no exterior orientation", field="image")
        rows[i] = idx[name]
    return rows[inv]


def _camera_for(cameras: Mapping[str, FrameCamera], name: str) -> FrameCamera:
    try:
        return cameras[name]
    except KeyError:
        raise InputFormatError(f"camera {name!r} is not defined (known: {', '.join(sorted(cameras))})", field="camera") from None


def project_points(camera: FrameCamera, world_from_camera: Pose, points: ArrayLike) -> NDArray[np.float64]:
    """Fast path: project ``(N, 3)`` points of a Cartesian world frame into one image; pixels ``(N, 2)``.

    Processes large arrays in chunks to bound memory.
    """
    p = np.asarray(points, dtype=np.float64)
    out = np.empty(p.shape[:-1] + (2,))
    r, c = world_from_camera.rotation, world_from_camera.translation
    for s in range(0, len(p), _CHUNK):
        cam = (p[s : s + _CHUNK] - c) @ r  # R^T (X - C), row-vector form
        out[s : s + _CHUNK] = camera.project_pixels(cam)
    return out


def world_to_image(
    eo: ExteriorOrientations,
    cameras: Mapping[str, FrameCamera],
    images: ArrayLike,
    points: ArrayLike,
    points_frame: WorldFrame,
) -> NDArray[np.float64]:
    """Project ground points into named images.

    Parameters
    ----------
    eo
        Exterior orientations (any world frame).
    cameras
        Camera name -> :class:`FrameCamera`.
    images
        ``(N,)`` image name per point.
    points
        ``(N, 3)`` ground coordinates in ``points_frame``.

    Returns
    -------
    ``(N, 2)`` pixels (column, row); NaN for points behind the camera.
    """
    images = np.asarray(images, dtype=str).reshape(-1)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(images) != len(pts):
        raise ValueError("images and points must have the same length")
    rows = _lookup(eo, images)
    used = np.unique(rows)
    sub = eo.subset(used)
    if points_frame == sub.frame and sub.frame.kind != "map":
        sub_l, pts_l = sub, pts  # already Cartesian: no conversion
    else:
        local = local_frame_for(sub.frame.to_ecef(sub.centre))
        sub_l = sub.to_frame(local)
        pts_l = local.from_ecef(points_frame.to_ecef(pts))
    out = np.full((len(pts), 2), np.nan)
    order = np.argsort(rows, kind="stable")
    bounds = np.searchsorted(rows[order], used)
    bounds = np.append(bounds, len(rows))
    for k in range(len(used)):
        sel = order[bounds[k] : bounds[k + 1]]
        cam = _camera_for(cameras, str(sub_l.camera[k]))
        pose = Pose(sub_l.rotation[k], sub_l.centre[k], "world", "camera")
        out[sel] = project_points(cam, pose, pts_l[sel])
    return out


def _rays_local(
    eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera], images: NDArray[np.str_], pixels: NDArray[np.float64],
    local: WorldFrame,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    rows = _lookup(eo, images)
    eo_l = eo.to_frame(local)
    origin = eo_l.centre[rows]
    direction = np.empty((len(rows), 3))
    order = np.argsort(rows, kind="stable")  # the rows of each image by slicing, not a mask per image
    cuts = np.flatnonzero(np.r_[True, rows[order][1:] != rows[order][:-1], True]) if len(rows) else np.zeros(1, int)
    for lo, hi in zip(cuts[:-1], cuts[1:]):
        sel = order[lo:hi]
        r = rows[sel[0]]
        cam = _camera_for(cameras, str(eo_l.camera[r]))
        direction[sel] = cam.rays_from_pixels(pixels[sel]) @ eo_l.rotation[r].T
    return origin, direction


@dataclass(frozen=True)
class Dem:
    """A digital elevation model on a regular grid (pure data; read one with :func:`skyrig.io.dem.read_dem`).

    Attributes
    ----------
    heights
        ``(rows, cols)`` heights in metres, NaN where unknown.
    transform
        Affine coefficients ``(a, b, c, d, e, f)`` mapping (col + 0.5, row + 0.5)... i.e. the GDAL/rasterio
        affine: ``x = a*col + b*row + c``, ``y = d*col + e*row + f`` for the *corner* of a pixel.
    frame
        The map frame of x, y and of the heights (ellipsoidal, or orthometric through its geoid).
    """

    heights: NDArray[np.float64]
    transform: tuple[float, float, float, float, float, float]
    frame: WorldFrame

    def sample(self, x: ArrayLike, y: ArrayLike) -> NDArray[np.float64]:
        """Bilinear heights at map positions (NaN outside the grid or next to unknown cells)."""
        a, b, c, d, e, f = self.transform
        det = a * e - b * d
        x = np.asarray(x, dtype=np.float64) - c
        y = np.asarray(y, dtype=np.float64) - f
        col = (e * x - b * y) / det - 0.5
        row = (-d * x + a * y) / det - 0.5
        h = self.heights
        c0 = np.floor(col)
        r0 = np.floor(row)
        fc, fr = col - c0, row - r0
        ok = (c0 >= 0) & (r0 >= 0) & (c0 + 1 < h.shape[1]) & (r0 + 1 < h.shape[0])
        ci = np.where(ok, c0, 0).astype(np.int64)
        ri = np.where(ok, r0, 0).astype(np.int64)
        v = (
            h[ri, ci] * (1 - fc) * (1 - fr) + h[ri, ci + 1] * fc * (1 - fr)
            + h[ri + 1, ci] * (1 - fc) * fr + h[ri + 1, ci + 1] * fc * fr
        )
        return np.where(ok, v, np.nan)

    @property
    def cell_size(self) -> float:
        a, b, _, d, e, _ = self.transform
        return float(min(np.hypot(a, d), np.hypot(b, e)))


def _height_on_ray(
    frame: WorldFrame, local: WorldFrame, origin: NDArray, direction: NDArray, t: NDArray
) -> NDArray[np.float64]:
    out = np.full((len(t), 3), np.nan)
    ok = np.isfinite(t) & np.all(np.isfinite(direction), axis=1)
    if np.any(ok):
        out[ok] = frame.from_ecef(local.to_ecef(origin[ok] + t[ok, None] * direction[ok]))
    return out


def _intersect_height(
    frame: WorldFrame, local: WorldFrame, origin: NDArray, direction: NDArray, target: NDArray, iterations: int = 20
) -> NDArray[np.float64]:
    """Parameters t along the rays where the frame height equals ``target`` (Newton on t, vectorised)."""
    # start from the local-frame plane solution; the frame's vertical is almost the local one
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (target - _height_on_ray(frame, local, origin, direction, np.zeros(len(origin)))[:, 2]) / direction[:, 2]
    t = np.where(np.isfinite(t), t, np.nan)
    for _ in range(iterations):
        z = _height_on_ray(frame, local, origin, direction, t)[:, 2]
        dz = _height_on_ray(frame, local, origin, direction, t + 1.0)[:, 2] - z
        with np.errstate(divide="ignore", invalid="ignore"):
            step = (target - z) / dz
        t = t + np.where(np.isfinite(step), step, 0.0)
        if np.all(~np.isfinite(step) | (np.abs(step) < 1e-7)):
            break
    return t


def image_to_world_height(
    eo: ExteriorOrientations,
    cameras: Mapping[str, FrameCamera],
    images: ArrayLike,
    pixels: ArrayLike,
    height: float | ArrayLike,
    frame: WorldFrame,
) -> NDArray[np.float64]:
    """Intersect image rays with the surface of constant ``height`` in ``frame``.

    In a local or ECEF frame this is the plane z = height; in a map frame it is the surface of constant
    (ellipsoidal or orthometric) height, i.e. "a horizontal plane" as map users mean it.  Returns
    ``(N, 3)`` points in ``frame``; rays that point away from the surface raise :class:`GeometryError`.
    """
    images = np.asarray(images, dtype=str).reshape(-1)
    px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    local = local_frame_for(eo.frame.to_ecef(eo.centre))
    origin, direction = _rays_local(eo, cameras, images, px, local)
    target = np.broadcast_to(np.asarray(height, dtype=np.float64), (len(px),)).astype(np.float64)
    t = _intersect_height(frame, local, origin, direction, target)
    bad = ~np.isfinite(t) | (t <= 0)
    if np.any(bad):
        i = int(np.argmax(bad))
        raise GeometryError(
            f"ray of pixel {px[i].tolist()} in image {images[i]!r} does not reach height {target[i]:g} in front of the camera"
        )
    return _height_on_ray(frame, local, origin, direction, t)


def image_to_world_dem(
    eo: ExteriorOrientations,
    cameras: Mapping[str, FrameCamera],
    images: ArrayLike,
    pixels: ArrayLike,
    dem: Dem,
    anchors: int = 17,
) -> NDArray[np.float64]:
    """Intersect image rays with a DEM: the first crossing of the ray with the surface, seen from the camera.

    The ray is transformed rigorously into the DEM's map frame at ``anchors`` points between the DEM's
    highest and lowest heights, marched in steps of half a DEM cell along that (almost straight) polyline
    to find the first crossing, then refined by bisection.  Returns ``(N, 3)`` points in ``dem.frame``;
    NaN where the ray misses the DEM.
    """
    images = np.asarray(images, dtype=str).reshape(-1)
    px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    n = len(px)
    local = local_frame_for(eo.frame.to_ecef(eo.centre))
    origin, direction = _rays_local(eo, cameras, images, px, local)
    zmax = float(np.nanmax(dem.heights)) + 1.0
    zmin = float(np.nanmin(dem.heights)) - 1.0
    t0 = _intersect_height(dem.frame, local, origin, direction, np.full(n, zmax))
    t1 = _intersect_height(dem.frame, local, origin, direction, np.full(n, zmin))
    if np.any(~np.isfinite(t1) | (t1 <= 0)):
        i = int(np.argmax(~np.isfinite(t1) | (t1 <= 0)))
        raise GeometryError(f"ray of pixel {px[i].tolist()} in image {images[i]!r} never goes below the DEM")
    t0 = np.maximum(np.where(np.isfinite(t0), t0, 0.0), 0.0)
    # anchor points along each ray, in map coordinates
    s = np.linspace(0.0, 1.0, anchors)
    ta = t0[:, None] + (t1 - t0)[:, None] * s[None, :]
    amap = _height_on_ray(dem.frame, local, np.repeat(origin, anchors, 0), np.repeat(direction, anchors, 0), ta.ravel())
    amap = amap.reshape(n, anchors, 3)

    length = np.linalg.norm(amap[:, -1, :2] - amap[:, 0, :2], axis=1) + (zmax - zmin)
    steps = int(min(max(np.ceil(np.max(length) / (0.5 * dem.cell_size)), 2), 20000))
    out = np.full((n, 3), np.nan)
    chunk = max(1, 4_000_000 // steps)
    for c0 in range(0, n, chunk):
        sl = slice(c0, min(n, c0 + chunk))
        u = np.broadcast_to(np.linspace(0.0, 1.0, steps + 1), (sl.stop - sl.start, steps + 1))
        p = _along(amap[sl], u)
        f = p[..., 2] - dem.sample(p[..., 0], p[..., 1])
        below = f <= 0
        hit = below.any(axis=1)
        k = np.argmax(below, axis=1)
        ok = hit & (k > 0)
        lo = np.where(ok, (k - 1) / steps, 0.0)
        hi = np.where(ok, k / steps, 0.0)
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            pm = _along(amap[sl], mid[:, None])[:, 0]
            fm = pm[:, 2] - dem.sample(pm[:, 0], pm[:, 1])
            go_down = fm > 0
            lo = np.where(go_down, mid, lo)
            hi = np.where(go_down, hi, mid)
        tt = t0[sl] + (t1[sl] - t0[sl]) * (0.5 * (lo + hi))
        exact = _height_on_ray(dem.frame, local, origin[sl], direction[sl], tt)
        out[sl] = np.where(ok[:, None], exact, np.nan)
    return out


def _along(a: NDArray, u: NDArray) -> NDArray:
    """Points ``(n, k, 3)`` at fractions ``u`` ``(n, k)`` along per-ray anchor polylines ``a`` ``(n, anchors, 3)``."""
    anchors = a.shape[1]
    pos = np.clip(u, 0.0, 1.0) * (anchors - 1)
    i0 = np.minimum(np.floor(pos).astype(np.int64), anchors - 2)
    w = (pos - i0)[..., None]
    idx = np.arange(len(a))[:, None]
    return a[idx, i0] * (1 - w) + a[idx, i0 + 1] * w


def far_outside_image(
    eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera], images: ArrayLike, pixels: ArrayLike,
    margin_images: float = 1.0,
) -> NDArray[np.bool_]:
    """Which measurements are not finite or lie more than ``margin_images`` image sizes outside their image.

    Such a pixel cannot be a measurement (a typing slip, a unit or axis mix-up); its ray is meaningless.

    Parameters
    ----------
    images
        ``(N,)`` image names (each must have an exterior orientation).
    pixels
        ``(N, 2)`` (column, row) in pixels.
    margin_images
        Allowed distance outside the image, in image widths (columns) and heights (rows).

    Returns
    -------
    ``(N,)`` bool, True where the pixel is not finite or beyond the margin.
    """
    images = np.asarray(images, dtype=str).reshape(-1)
    px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    rows = _lookup(eo, images)
    size = np.empty((len(px), 2))
    for c in np.unique(eo.camera[rows]):
        cam = _camera_for(cameras, str(c))
        size[eo.camera[rows] == c] = (cam.width, cam.height)
    with np.errstate(invalid="ignore"):
        inside = np.all((px >= -0.5 - margin_images * size) & (px <= size - 0.5 + margin_images * size), axis=1)
    return ~inside


@dataclass(frozen=True)
class Intersection:
    """Result of :func:`forward_intersection`.

    Attributes
    ----------
    point
        ``(P,)`` point names.
    xyz
        ``(P, 3)`` coordinates in the requested frame (NaN for points with fewer than two usable rays).
    n_rays
        ``(P,)`` number of rays used.
    residual_px
        ``(N, 2)`` per observation: measured minus re-projected pixel, also for observations that were not
        used; NaN where the point has no position or lies behind that camera. Never set to zero.
    ray_distance_m
        ``(N,)`` per observation: perpendicular distance of the point from the ray.
    rms_px
        ``(P,)`` per point: RMS of the image residuals (both axes) of its used observations; NaN when the
        point has no position or a used observation does not re-project (point behind the camera).
    used
        ``(N,)`` whether the observation entered the solution (False: pixel not finite or more than one image
        size outside its image, see :func:`far_outside_image`).
    valid
        ``(P,)`` whether the point is trustworthy: at least two used rays, a finite position in front of every
        camera of its used rays.
    note
        ``(P,)`` why a point is not valid or which of its observations were left out (empty when all is well).
    """

    point: NDArray[np.str_]
    xyz: NDArray[np.float64]
    n_rays: NDArray[np.int64]
    residual_px: NDArray[np.float64]
    ray_distance_m: NDArray[np.float64]
    rms_px: NDArray[np.float64]
    used: NDArray[np.bool_]
    valid: NDArray[np.bool_]
    note: NDArray[np.str_]


def forward_intersection(
    eo: ExteriorOrientations,
    cameras: Mapping[str, FrameCamera],
    points: ArrayLike,
    images: ArrayLike,
    pixels: ArrayLike,
    frame: WorldFrame,
    iterations: int = 5,
) -> Intersection:
    """Least-squares intersection of the rays of every point measured in two or more images.

    The linear solution (minimum sum of squared ray distances) is refined by Gauss-Newton on the image
    residuals (analytic Jacobians of the full camera model, 3 unknowns per point).  Observations whose pixel
    is not finite or lies more than one image size outside its image are left out (``used`` False) and named
    in the point's ``note``; points with fewer than two used rays come back as NaN; a point behind one of its
    cameras is kept but marked not ``valid`` with an RMS of NaN (see :class:`Intersection`).
    """
    names = np.asarray(points, dtype=str).reshape(-1)
    images = np.asarray(images, dtype=str).reshape(-1)
    px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    if not (len(names) == len(images) == len(px)):
        raise ValueError(f"{len(names)} point names, {len(images)} image names and {len(px)} pixels: "
                         "one of each per observation")
    used = ~far_outside_image(eo, cameras, images, px)
    px_ray = np.where(used[:, None], px, 0.0)  # left-out observations: any finite ray, weight 0 below
    local = local_frame_for(eo.frame.to_ecef(eo.centre))
    origin, d = _rays_local(eo, cameras, images, px_ray, local)
    uniq, pid = np.unique(names, return_inverse=True)
    P = len(uniq)
    M = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    M[~used] = 0.0
    A = np.zeros((P, 3, 3))
    b = np.zeros((P, 3))
    np.add.at(A, pid, M)
    np.add.at(b, pid, np.einsum("nij,nj->ni", M, origin))
    n_rays = np.bincount(pid[used], minlength=P)
    good = n_rays >= 2
    X = np.full((P, 3), np.nan)
    if np.any(good):
        X[good] = np.linalg.solve(A[good] + 1e-12 * np.eye(3), b[good][..., None])[..., 0]
    eo_l = eo.to_frame(local)
    rows = _lookup(eo_l, images)
    cam_names = eo_l.camera[rows]
    groups = [(_camera_for(cameras, str(c)), np.flatnonzero(cam_names == c)) for c in np.unique(cam_names)]

    def reproject(Xp: NDArray, jac: bool = False) -> tuple[NDArray, NDArray | None]:
        out = np.full((len(px), 2), np.nan)
        J = np.full((len(px), 2, 3), np.nan) if jac else None
        for cam, sel in groups:
            pose = Pose(eo_l.rotation[rows[sel]], eo_l.centre[rows[sel]], "world", "camera")
            pix, jd = project_with_jacobians(cam, pose, Xp[pid[sel]], want=("point",) if jac else ())
            out[sel] = pix
            if jac:
                J[sel] = jd["point"]
        return out, J

    with np.errstate(invalid="ignore", over="ignore"):
        for _ in range(iterations):
            proj, J = reproject(X, jac=True)
            r = px - proj
            N = np.zeros((P, 3, 3))
            g = np.zeros((P, 3))
            ok = np.all(np.isfinite(r), axis=1) & good[pid] & used
            np.add.at(N, pid[ok], np.einsum("nki,nkj->nij", J[ok], J[ok]))
            np.add.at(g, pid[ok], np.einsum("nki,nk->ni", J[ok], r[ok]))
            solvable = good & (np.linalg.matrix_rank(N) == 3)
            step = np.zeros((P, 3))
            step[solvable] = np.linalg.solve(N[solvable], g[solvable][..., None])[..., 0]
            X = X + step
            if np.nanmax(np.abs(step), initial=0.0) < 1e-6:
                break
        res = px - reproject(X)[0]
        v = X[pid] - origin
        dist = np.linalg.norm(v - np.sum(v * d, axis=1)[:, None] * d, axis=1)
    dist[~used] = np.nan
    res_finite = np.all(np.isfinite(res), axis=1)
    sq = np.zeros(P)
    np.add.at(sq, pid[used & res_finite], np.sum(res[used & res_finite] ** 2, axis=1))
    behind = np.bincount(pid[used & ~res_finite], minlength=P) > 0  # a used ray that does not see the point
    rms = np.sqrt(sq / np.maximum(2 * n_rays, 1))
    valid = good & ~behind & np.all(np.isfinite(X), axis=1)
    rms[~valid] = np.nan
    note = np.full(P, "", dtype=object)
    for k in np.flatnonzero(~used):
        note[pid[k]] += f"; measurement in {images[k]} left out (not finite or more than one image size outside)"
    for p in np.flatnonzero(~good):
        note[p] += f"; {n_rays[p]} usable ray{'s' if n_rays[p] != 1 else ''} (needs 2)"
    for p in np.flatnonzero(good & behind):
        note[p] += "; behind the camera of a measurement: no valid intersection"
    note = np.array([s.lstrip("; ") for s in note], dtype=str)
    xyz = np.full((P, 3), np.nan)
    if np.any(good):
        xyz[good] = frame.from_ecef(local.to_ecef(X[good]))
    return Intersection(uniq, xyz, n_rays, res, dist, rms, used, valid, note)
