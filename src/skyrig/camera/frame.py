"""The frame camera in the photogrammetric convention.

Coordinate systems
------------------
* **camera frame** (3D, metres): x to the right of the image, y up in the image, z towards the viewer;
  the camera looks along -z.  ``world_from_camera`` poses map this frame to the world.
* **image coordinates** (2D, millimetres): x right, y up, origin at the image centre (the centre of the
  pixel array).  The principal point ``(ppx_mm, ppy_mm)`` is given in this system.
* **pixel coordinates** (2D, pixels): column to the right, row down, origin at the *centre* of the
  top-left pixel, so the image spans ``[-0.5, width - 0.5] x [-0.5, height - 0.5]`` (the OpenCV
  convention; COLMAP's differs by 0.5).

Collinearity: a camera-frame point ``P`` maps to the ideal (undistorted) image point
``x = ppx - f P_x / P_z``, ``y = ppy - f P_y / P_z``; lens distortion then moves it to the observed
position (see :mod:`skyrig.camera.distortion`): ``observed = pp + distort(ideal - pp)``.

Intrinsic parameter vector (for calibration and bundle adjustment, see :attr:`FrameCamera.intrinsics`):
``(focal_mm, ppx_mm, ppy_mm, *distortion.params)`` with names :attr:`FrameCamera.intrinsic_names`.
Analytic Jacobians of the projection live in :mod:`skyrig.camera.jacobians`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Callable, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.camera.distortion import Distortion, NoDistortion
from skyrig.errors import GeometryError
from skyrig.geometry.pose import Pose

#: a surface ``z = height(x, y)``: vectorised, takes two arrays of the same shape (world x, y) and
#: returns heights of that shape (NaN where undefined, e.g. outside a DEM)
HeightFunction = Callable[[NDArray[np.float64], NDArray[np.float64]], ArrayLike]


class GroundSampling(NamedTuple):
    """Ground sample distance of one pixel on a horizontal plane (all in metres, shapes ``(N,)``).

    Attributes
    ----------
    col_m
        Ground distance between the centres of two horizontally adjacent pixels (one column step).
    row_m
        Ground distance of one row step (for a camera tilted forward: the along-tilt, larger value).
    mean_m
        ``(col_m + row_m) / 2``.
    area_m2
        Ground area covered by the pixel (``|d/dcol x d/drow|``).
    slant_m
        Distance from the projection centre to the ground point.
    """

    col_m: NDArray[np.float64]
    row_m: NDArray[np.float64]
    mean_m: NDArray[np.float64]
    area_m2: NDArray[np.float64]
    slant_m: NDArray[np.float64]


@dataclass(frozen=True)
class FrameCamera:
    """A central-perspective frame camera.

    Attributes
    ----------
    name
        Identifier (used to link images to cameras).
    width, height
        Image size in pixels.
    pixel_size_mm
        Pixel pitch in millimetres (square pixels).
    focal_mm
        Principal distance (calibrated focal length) in millimetres.
    ppx_mm, ppy_mm
        Principal point in image coordinates (mm, x right, y up, from the image centre).
    distortion
        Lens distortion model (default: none).
    """

    name: str
    width: int
    height: int
    pixel_size_mm: float
    focal_mm: float
    ppx_mm: float = 0.0
    ppy_mm: float = 0.0
    distortion: Distortion = field(default_factory=NoDistortion)

    def __post_init__(self) -> None:
        for k in ("width", "height"):
            if int(getattr(self, k)) <= 0:
                raise ValueError(f"camera {self.name!r}: {k} must be positive")
        for k in ("pixel_size_mm", "focal_mm"):
            v = float(getattr(self, k))
            if not np.isfinite(v) or v <= 0:
                raise ValueError(f"camera {self.name!r}: {k} must be a positive number, got {v}")

    # ------------------------------------------------------------------ construction helpers
    @classmethod
    def from_pixels(
        cls,
        name: str,
        width: int,
        height: int,
        focal_px: float,
        pp_col: float,
        pp_row: float,
        pixel_size_mm: float = 0.001,
        distortion: Distortion | None = None,
    ) -> "FrameCamera":
        """Build from a focal length and principal point in pixels (column right, row down).

        ``pixel_size_mm`` only fixes the metric scale of image coordinates; projections in pixels do
        not depend on it.
        """
        cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
        return cls(
            name,
            int(width),
            int(height),
            float(pixel_size_mm),
            float(focal_px) * pixel_size_mm,
            (pp_col - cx) * pixel_size_mm,
            -(pp_row - cy) * pixel_size_mm,
            distortion if distortion is not None else NoDistortion(),
        )

    def with_(self, **changes: Any) -> "FrameCamera":
        """A copy with some fields changed."""
        return replace(self, **changes)

    # ------------------------------------------------------------------ intrinsic parameter vector
    @property
    def intrinsic_names(self) -> tuple[str, ...]:
        """Names of :attr:`intrinsics`: ``("focal_mm", "ppx_mm", "ppy_mm", *distortion.param_names)``."""
        return ("focal_mm", "ppx_mm", "ppy_mm") + tuple(self.distortion.param_names)

    @property
    def intrinsics(self) -> NDArray[np.float64]:
        """Intrinsic parameter vector ``(3 + P,)``: focal (mm), principal point (mm), distortion parameters."""
        return np.concatenate([[self.focal_mm, self.ppx_mm, self.ppy_mm], self.distortion.params])

    def with_intrinsics(self, intrinsics: ArrayLike) -> "FrameCamera":
        """A copy with the intrinsic vector ``(3 + P,)`` (ordered as :attr:`intrinsic_names`) replaced."""
        v = np.asarray(intrinsics, dtype=np.float64).reshape(-1)
        if v.size != 3 + self.distortion.n_params:
            raise ValueError(f"camera {self.name!r}: expected {3 + self.distortion.n_params} intrinsics, got {v.size}")
        return replace(
            self,
            focal_mm=float(v[0]),
            ppx_mm=float(v[1]),
            ppy_mm=float(v[2]),
            distortion=self.distortion.with_params(v[3:]),  # keeps model constants (e.g. R0)
        )

    # ------------------------------------------------------------------ derived quantities
    @property
    def focal_px(self) -> float:
        """Principal distance in pixels."""
        return self.focal_mm / self.pixel_size_mm

    @property
    def principal_point_px(self) -> tuple[float, float]:
        """Principal point as (column, row) in pixels."""
        c = self.image_to_pixel(np.array([[self.ppx_mm, self.ppy_mm]]))[0]
        return float(c[0]), float(c[1])

    @property
    def sensor_size_mm(self) -> tuple[float, float]:
        """Sensor width and height in millimetres."""
        return self.width * self.pixel_size_mm, self.height * self.pixel_size_mm

    # ------------------------------------------------------------------ 2D conversions
    def image_to_pixel(self, xy_mm: ArrayLike) -> NDArray[np.float64]:
        """Image coordinates ``(N, 2)`` mm (x right, y up, from centre) to pixels ``(N, 2)`` (col, row)."""
        xy = np.asarray(xy_mm, dtype=np.float64)
        out = np.empty_like(xy)
        out[..., 0] = xy[..., 0] / self.pixel_size_mm + (self.width - 1) / 2.0
        out[..., 1] = -xy[..., 1] / self.pixel_size_mm + (self.height - 1) / 2.0
        return out

    def pixel_to_image(self, colrow: ArrayLike) -> NDArray[np.float64]:
        """Pixels ``(N, 2)`` (col, row) to image coordinates ``(N, 2)`` mm."""
        cr = np.asarray(colrow, dtype=np.float64)
        out = np.empty_like(cr)
        out[..., 0] = (cr[..., 0] - (self.width - 1) / 2.0) * self.pixel_size_mm
        out[..., 1] = -(cr[..., 1] - (self.height - 1) / 2.0) * self.pixel_size_mm
        return out

    # ------------------------------------------------------------------ projection
    def project(self, points_camera: ArrayLike) -> NDArray[np.float64]:
        """Camera-frame points ``(N, 3)`` to observed (distorted) image coordinates ``(N, 2)`` mm.

        Points on or behind the image plane (``P_z >= 0``) give NaN.
        """
        p = np.asarray(points_camera, dtype=np.float64)
        z = p[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(z < 0, -self.focal_mm / z, np.nan)
        ideal = np.stack([p[..., 0] * s, p[..., 1] * s], axis=-1)
        return self.distortion.distort(ideal, self.focal_mm) + np.array([self.ppx_mm, self.ppy_mm])

    def project_pixels(self, points_camera: ArrayLike) -> NDArray[np.float64]:
        """Camera-frame points ``(N, 3)`` to pixels ``(N, 2)``."""
        return self.image_to_pixel(self.project(points_camera))

    def rays(self, xy_mm: ArrayLike) -> NDArray[np.float64]:
        """Unit viewing directions ``(N, 3)`` in the camera frame of observed image points ``(N, 2)`` mm."""
        xy = np.asarray(xy_mm, dtype=np.float64) - np.array([self.ppx_mm, self.ppy_mm])
        ideal = self.distortion.undistort(xy, self.focal_mm)
        d = np.concatenate([ideal, np.full(ideal.shape[:-1] + (1,), -self.focal_mm)], axis=-1)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def rays_from_pixels(self, colrow: ArrayLike) -> NDArray[np.float64]:
        """Unit viewing directions ``(N, 3)`` in the camera frame of pixels ``(N, 2)``."""
        return self.rays(self.pixel_to_image(colrow))

    def world_to_pixel(self, world_from_camera: Pose, points_world: ArrayLike) -> NDArray[np.float64]:
        """World points ``(N, 3)`` to pixels ``(N, 2)`` for a pose (single, or a batch of N)."""
        return self.project_pixels(world_from_camera.apply_inverse(points_world))

    def in_image(self, colrow: ArrayLike, margin_px: float = 0.0) -> NDArray[np.bool_]:
        """Whether pixels ``(N, 2)`` lie inside the image (NaN counts as outside)."""
        cr = np.asarray(colrow, dtype=np.float64)
        with np.errstate(invalid="ignore"):
            return (
                (cr[..., 0] >= -0.5 - margin_px)
                & (cr[..., 0] <= self.width - 0.5 + margin_px)
                & (cr[..., 1] >= -0.5 - margin_px)
                & (cr[..., 1] <= self.height - 0.5 + margin_px)
            )

    # ------------------------------------------------------------------ ground sampling
    def gsd(self, distance_m: ArrayLike) -> NDArray[np.float64]:
        """Ground sample distance (m) at the image centre for a distance along the optical axis
        (for a nadir view: height above ground): ``pixel / f * distance``."""
        return np.asarray(distance_m, dtype=np.float64) * self.pixel_size_mm / self.focal_mm

    def gsd_at(
        self, world_from_camera: Pose, ground_height: float = 0.0, pixels: ArrayLike | None = None
    ) -> GroundSampling:
        """Ground sample distance on the horizontal plane ``z = ground_height`` for tilted views.

        Exact (to first order in one pixel) for any orientation and for the lens distortion: the
        ground point of a pixel is differentiated with respect to its column and row.  For a level
        nadir view it equals :meth:`gsd` of the flying height; for a view tilted by ``t`` from nadir it
        grows to ``H p / (f cos t)`` across and ``H p / (f cos² t)`` along the tilt (at the principal
        point).

        Parameters
        ----------
        world_from_camera
            Pose (single, or a batch of N).  The world z axis must be the vertical (map or ENU frame).
        ground_height
            Height of the plane, metres, same vertical datum as the pose.
        pixels
            Where to evaluate, ``(N, 2)`` or ``(2,)`` (col, row); default the image centre
            ``((width - 1) / 2, (height - 1) / 2)``.

        Returns
        -------
        GroundSampling
            Per-pixel column and row steps on the ground, their mean, the pixel's ground area and the
            slant range; arrays of shape ``(N,)`` (``()`` for a single pose and pixel).

        Raises
        ------
        GeometryError
            If the ray does not reach the plane (above the horizon).
        """
        if pixels is None:
            px = np.array([(self.width - 1) / 2.0, (self.height - 1) / 2.0])
        else:
            px = np.asarray(pixels, dtype=np.float64)
        obs = self.pixel_to_image(px) - np.array([self.ppx_mm, self.ppy_mm])
        flat_obs = obs.reshape(-1, 2)
        ideal = self.distortion.undistort(flat_obs, self.focal_mm)
        jd = self.distortion.jacobian_ideal(ideal, self.focal_mm)  # d obs / d ideal
        d_ideal_d_px = np.linalg.inv(jd) * np.array([self.pixel_size_mm, -self.pixel_size_mm])[None, None, :]
        ideal = ideal.reshape(obs.shape)
        d_ideal_d_px = d_ideal_d_px.reshape(obs.shape[:-1] + (2, 2))
        # unnormalised camera-frame ray (ideal_x, ideal_y, -f) and its derivative w.r.t. (col, row)
        ray_c = np.concatenate([ideal, np.full(ideal.shape[:-1] + (1,), -self.focal_mm)], axis=-1)
        d_ray_c = np.concatenate([d_ideal_d_px, np.zeros(d_ideal_d_px.shape[:-2] + (1, 2))], axis=-2)
        R = world_from_camera.rotation
        c = world_from_camera.translation
        d = np.einsum("...ij,...j->...i", R, ray_c)
        dd = np.einsum("...ij,...jk->...ik", R, d_ray_c)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (ground_height - c[..., 2]) / d[..., 2]
        if np.any(~np.isfinite(t)) or np.any(t <= 0):
            raise GeometryError("gsd_at: the ray does not reach the ground plane (above the horizon or parallel)")
        # G = c + t d with t = (h - c_z) / d_z  =>  dG = t (dd - d dd_z / d_z)
        dG = t[..., None, None] * (dd - d[..., :, None] * (dd[..., 2:3, :] / d[..., 2, None, None]))
        col = np.linalg.norm(dG[..., 0], axis=-1)
        row = np.linalg.norm(dG[..., 1], axis=-1)
        area = np.linalg.norm(np.cross(dG[..., 0], dG[..., 1]), axis=-1)
        slant = t * np.linalg.norm(d, axis=-1)
        return GroundSampling(col, row, 0.5 * (col + row), area, slant)

    def corner_pixels(self) -> NDArray[np.float64]:
        """The four outer image corners ``(4, 2)`` in pixels: top-left, top-right, bottom-right, bottom-left."""
        w, h = self.width - 0.5, self.height - 0.5
        return np.array([[-0.5, -0.5], [w, -0.5], [w, h], [-0.5, h]])

    def fov_deg(self) -> tuple[float, float]:
        """Full horizontal and vertical field of view in degrees (pinhole, from the image centre)."""
        sw, sh = self.sensor_size_mm
        return (
            float(np.degrees(2 * np.arctan(sw / 2 / self.focal_mm))),
            float(np.degrees(2 * np.arctan(sh / 2 / self.focal_mm))),
        )


def footprint_on_plane(
    camera: FrameCamera, world_from_camera: Pose, plane_height: float = 0.0, pixels: ArrayLike | None = None
) -> NDArray[np.float64]:
    """Intersect the rays of image corners (or given pixels ``(M, 2)``) with the plane ``z = plane_height``.

    Returns ``(M, 3)`` world points.  Raises :class:`GeometryError` if a ray points away from the plane
    (e.g. an oblique camera's upper corners above the horizon).
    """
    px = camera.corner_pixels() if pixels is None else np.asarray(pixels, dtype=np.float64)
    d = world_from_camera.rotate(camera.rays_from_pixels(px))
    c = world_from_camera.translation
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (plane_height - c[..., 2]) / d[..., 2]
    if np.any(~np.isfinite(t)) or np.any(t <= 0):
        raise GeometryError("a footprint ray does not reach the ground plane (above the horizon or parallel)")
    return c + t[..., None] * d


def intersect_rays_with_surface(
    origins: ArrayLike,
    directions: ArrayLike,
    height: HeightFunction,
    tol_m: float = 1e-4,
    max_iter: int = 100,
    max_distance_m: float = 1e6,
) -> NDArray[np.float64]:
    """First-found intersection of rays with a surface ``z = height(x, y)`` (e.g. a DEM).

    Vectorised over rays: every iteration evaluates ``height`` once on all unfinished rays.  The ray
    parameter is bracketed between the origin (which must be above the surface) and a point below it
    (starting from the intersection with the horizontal plane through the surface height under the
    origin, doubling outwards as needed), then refined by the Illinois variant of regula falsi, which
    converges superlinearly and never leaves the bracket (so steep terrain and oblique rays are safe).
    Where a ray crosses the surface several times inside the bracket, the root found need not be the
    nearest one (occlusion is not resolved here).

    Parameters
    ----------
    origins
        ``(N, 3)`` or ``(3,)`` ray origins, metres (broadcast against ``directions``).
    directions
        ``(N, 3)`` ray directions (need not be unit).
    height
        Vectorised surface: ``height(x, y)`` on arrays ``(M,)`` returns ``(M,)`` heights.
    tol_m
        Convergence: vertical distance of the point from the surface, metres.
    max_iter
        Iteration cap of the refinement.
    max_distance_m
        Give up bracketing beyond this range along the ray.

    Returns
    -------
    ``(N, 3)`` world points on the surface.

    Raises
    ------
    GeometryError
        An origin is not above the surface, the surface height is undefined (NaN) on the way, no
        intersection lies within ``max_distance_m``, or the refinement does not converge.
    """
    d = np.asarray(directions, dtype=np.float64)
    o = np.asarray(origins, dtype=np.float64)
    o, d = np.broadcast_arrays(o, d)
    shape = o.shape
    o = o.reshape(-1, 3)
    d = d.reshape(-1, 3)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)

    def f(idx: NDArray[np.intp], t: NDArray[np.float64]) -> NDArray[np.float64]:
        p = o[idx] + t[:, None] * d[idx]
        h = np.asarray(height(p[:, 0], p[:, 1]), dtype=np.float64).reshape(-1)
        return p[:, 2] - h

    everyone = np.arange(o.shape[0])
    t_lo = np.zeros(o.shape[0])
    f_lo = f(everyone, t_lo)
    if not np.all(np.isfinite(f_lo)):
        raise GeometryError("surface height undefined under a ray origin")
    if np.any(f_lo <= 0):
        raise GeometryError("a ray origin is not above the surface")
    # first guess: the plane through the surface height under the origin
    with np.errstate(divide="ignore", invalid="ignore"):
        t_hi = np.where(d[:, 2] < -1e-12, f_lo / -d[:, 2], f_lo)
    f_hi = f(everyone, t_hi)
    todo = f_hi > 0
    while np.any(todo):
        idx = np.flatnonzero(todo)
        t_lo[idx], f_lo[idx] = t_hi[idx], f_hi[idx]
        t_hi[idx] *= 2.0
        if np.any(t_hi[idx] > max_distance_m):
            raise GeometryError(f"a ray does not meet the surface within {max_distance_m} m")
        f_hi[idx] = f(idx, t_hi[idx])
        todo[idx] = f_hi[idx] > 0
    if not np.all(np.isfinite(f_hi)):
        raise GeometryError("surface height undefined along a ray")

    t = t_hi.copy()
    ft = f_hi.copy()
    active = np.abs(ft) > tol_m
    side = np.zeros(o.shape[0], dtype=np.int8)  # Illinois: which end was kept last time
    for _ in range(max_iter):
        if not np.any(active):
            break
        i = np.flatnonzero(active)
        tn = (t_lo[i] * f_hi[i] - t_hi[i] * f_lo[i]) / (f_hi[i] - f_lo[i])
        fn = f(i, tn)
        if not np.all(np.isfinite(fn)):
            raise GeometryError("surface height undefined along a ray")
        t[i], ft[i] = tn, fn
        above = fn > 0
        # replace the end on the same side; halve the other end's value if it was kept twice
        ia, ib = i[above], i[~above]
        t_lo[ia], f_lo[ia] = tn[above], fn[above]
        f_hi[ia] = np.where(side[ia] == 1, 0.5 * f_hi[ia], f_hi[ia])
        side[ia] = 1
        t_hi[ib], f_hi[ib] = tn[~above], fn[~above]
        f_lo[ib] = np.where(side[ib] == -1, 0.5 * f_lo[ib], f_lo[ib])
        side[ib] = -1
        active[i] = np.abs(fn) > tol_m
    if np.any(active):
        raise GeometryError("ray/surface intersection did not converge")
    return (o + t[:, None] * d).reshape(shape)


def footprint_on_surface(
    camera: FrameCamera,
    world_from_camera: Pose,
    height: HeightFunction,
    pixels: ArrayLike | None = None,
    tol_m: float = 1e-4,
    max_iter: int = 100,
    max_distance_m: float = 1e6,
) -> NDArray[np.float64]:
    """Intersect the rays of image corners (or given pixels ``(M, 2)``) with a surface ``z = height(x, y)``.

    The world frame must have z vertical (map grid with heights, or ENU).  See
    :func:`intersect_rays_with_surface` for the method, tolerances and errors.

    Returns
    -------
    ``(M, 3)`` world points (M = 4 corners by default, in :meth:`FrameCamera.corner_pixels` order).
    """
    px = camera.corner_pixels() if pixels is None else np.asarray(pixels, dtype=np.float64)
    d = world_from_camera.rotate(camera.rays_from_pixels(px))
    c = np.broadcast_to(world_from_camera.translation, d.shape)
    return intersect_rays_with_surface(c, d, height, tol_m=tol_m, max_iter=max_iter, max_distance_m=max_distance_m)
