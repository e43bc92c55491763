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
position (see :mod:`skyrig.camera.distortion`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.camera.distortion import Distortion, NoDistortion
from skyrig.errors import GeometryError
from skyrig.geometry.pose import Pose


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
