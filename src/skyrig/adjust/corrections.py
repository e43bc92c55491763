"""Image-coordinate refinement applied to observations before an adjustment: atmospheric refraction.

Refraction bends a ray towards the vertical, so an image point appears displaced radially *outwards*
from the principal point by (classical photogrammetric model, e.g. Kraus, *Photogrammetry* vol. 1)::

    dr = K (r + r^3 / f^2)                 r, f in pixels, K in radians

For a standard atmosphere Bertram's formula gives ``K`` from the flying height ``H`` and the ground
height ``h`` (kilometres above sea level)::

    K = 2410e-6 * (H / (H^2 - 6 H + 250) - h^2 / ((h^2 - 6 h + 250) H))

(about 18 microradians at H = 1.8 km).  :func:`remove_refraction` takes the displacement out of
measured pixels so that the central projection of :class:`~skyrig.camera.frame.FrameCamera` applies.

A camera whose image is stitched from several sensor tiles (e.g. the Vexcel UltraCam panchromatic image)
can carry a piecewise deformation that no polynomial distortion model represents.
:func:`fit_image_grid` estimates it as the mean residual per cell of a regular grid over the image (from a
projection with known orientations and points), :class:`ImageGridCorrection` interpolates it bilinearly
between cell centres and :func:`remove_image_grid` takes it out of measured pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.camera.frame import FrameCamera
from skyrig.errors import ConfigError, GeometryError

__all__ = [
    "refraction_coefficient_bertram", "remove_refraction", "fit_radial_scale",
    "ImageGridCorrection", "fit_image_grid", "remove_image_grid",
]


def refraction_coefficient_bertram(flying_height_m: float, ground_height_m: float) -> float:
    """Refraction constant ``K`` (radians) of a standard atmosphere (Bertram), heights above sea level in m."""
    H = float(flying_height_m) / 1000.0
    h = float(ground_height_m) / 1000.0
    if not H > h:
        raise GeometryError(f"flying height {flying_height_m} m must be above the ground height {ground_height_m} m")
    return 2410e-6 * (H / (H * H - 6.0 * H + 250.0) - h * h / ((h * h - 6.0 * h + 250.0) * H))


def remove_refraction(pixels: ArrayLike, camera: FrameCamera, k_rad: float) -> NDArray[np.float64]:
    """Measured pixels ``(N, 2)`` (column, row) corrected for refraction ``dr = K (r + r^3/f^2)``."""
    px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    cx, cy = camera.principal_point_px
    f = camera.focal_px
    xy = px - [cx, cy]
    r2 = (xy * xy).sum(axis=1) / (f * f)
    return np.asarray([cx, cy]) + xy * (1.0 - k_rad * (1.0 + r2))[:, None]


def fit_radial_scale(residual_px: ArrayLike, pixels: ArrayLike, camera: FrameCamera) -> tuple[float, float]:
    """Least-squares ``K`` (and its sigma) of the refraction model from residuals ``computed - observed``.

    ``residual = -K (r + r^3/f^2) * (xy / r) + shift``: use it on residuals of a projection with known
    orientations to find the refraction (or image scale) a data set's measurements carry.
    """
    res = np.asarray(residual_px, dtype=np.float64).reshape(-1, 2)
    px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    cx, cy = camera.principal_point_px
    f = camera.focal_px
    xy = px - [cx, cy]
    r2 = (xy * xy).sum(axis=1) / (f * f)
    n = len(px)
    A = np.zeros((2 * n, 3))
    A[0::2, 0] = -xy[:, 0] * (1 + r2)
    A[1::2, 0] = -xy[:, 1] * (1 + r2)
    A[0::2, 1] = 1.0
    A[1::2, 2] = 1.0
    b = res.reshape(-1)
    c, *_ = np.linalg.lstsq(A, b, rcond=None)
    dof = max(2 * n - 3, 1)
    s2 = float(((b - A @ c) ** 2).sum() / dof)
    cov = np.linalg.inv(A.T @ A) * s2
    return float(c[0]), float(np.sqrt(cov[0, 0]))


@dataclass(frozen=True)
class ImageGridCorrection:
    """A correction field over the image: values at the centres of a regular ``(rows, cols)`` cell grid.

    Attributes
    ----------
    width, height : int
        Image size in pixels.
    shift_px : ndarray, shape (R, C, 2)
        Correction (column, row) in pixels at each cell centre, to be *added* to measured pixels
        (the mean ``computed - observed`` residual of the cell).
    count : ndarray, shape (R, C)
        Number of residuals behind each cell value (0: cell empty, value 0).
    """

    width: int
    height: int
    shift_px: NDArray[np.float64]
    count: NDArray[np.int64]

    def __call__(self, pixels: ArrayLike) -> NDArray[np.float64]:
        """The correction ``(N, 2)`` px at ``pixels`` ``(N, 2)`` (column, row): bilinear between cell centres,
        constant beyond the outer centres."""
        px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        nr, nc = self.shift_px.shape[:2]
        u = np.clip(px[:, 0] / self.width * nc - 0.5, 0.0, nc - 1.0)
        v = np.clip(px[:, 1] / self.height * nr - 0.5, 0.0, nr - 1.0)
        i0 = np.minimum(np.floor(u).astype(int), max(nc - 2, 0))
        j0 = np.minimum(np.floor(v).astype(int), max(nr - 2, 0))
        i1 = np.minimum(i0 + 1, nc - 1)
        j1 = np.minimum(j0 + 1, nr - 1)
        a = (u - i0)[:, None]
        b = (v - j0)[:, None]
        g = self.shift_px
        return ((1 - a) * (1 - b) * g[j0, i0] + a * (1 - b) * g[j0, i1]
                + (1 - a) * b * g[j1, i0] + a * b * g[j1, i1])


def fit_image_grid(residual_px: ArrayLike, pixels: ArrayLike, width: int, height: int,
                   shape: tuple[int, int] = (9, 6), min_count: int = 30) -> ImageGridCorrection:
    """Mean residual (``computed - observed``, px) per cell of a ``shape = (rows, cols)`` grid over the image.

    Parameters
    ----------
    residual_px, pixels : array_like, shape (N, 2)
        Residuals of a projection with known orientations and points, and the measured pixels (column, row).
    width, height : int
        Image size in pixels.
    shape : (int, int)
        Cells along the rows (image height) and the columns (image width).
    min_count : int
        Cells with fewer residuals get no correction (0); raises ValueError when no cell has enough.
    """
    res = np.asarray(residual_px, dtype=np.float64).reshape(-1, 2)
    px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    if len(res) != len(px):
        raise ValueError(f"{len(res)} residuals for {len(px)} pixels")
    nr, nc = int(shape[0]), int(shape[1])
    if nr < 1 or nc < 1:
        raise ConfigError(f"grid shape {shape} must be positive")
    ok = np.all(np.isfinite(res), axis=1) & (px[:, 0] >= 0) & (px[:, 0] < width) & (px[:, 1] >= 0) & (px[:, 1] < height)
    cell = (px[ok, 1] / height * nr).astype(int) * nc + (px[ok, 0] / width * nc).astype(int)
    count = np.bincount(cell, minlength=nr * nc)
    shift = np.stack([np.bincount(cell, res[ok, c], minlength=nr * nc) for c in (0, 1)], axis=1)
    good = count >= min_count
    if not good.any():
        raise ValueError(f"no grid cell has {min_count} residuals ({ok.sum()} usable residuals, grid {nr}x{nc})")
    shift[good] /= count[good, None]  # type: ignore[misc]
    shift[~good] = 0.0
    return ImageGridCorrection(int(width), int(height), shift.reshape(nr, nc, 2), count.reshape(nr, nc))  # type: ignore[arg-type]


def remove_image_grid(pixels: ArrayLike, grid: ImageGridCorrection) -> NDArray[np.float64]:
    """Measured pixels ``(N, 2)`` with the grid correction added (``pixels + grid(pixels)``)."""
    px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    return px + grid(px)
