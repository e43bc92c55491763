"""Image-coordinate refinement applied to observations before an adjustment: atmospheric refraction.

Refraction bends a ray towards the vertical, so an image point appears displaced radially *outwards*
from the principal point by (classical photogrammetric model, e.g. Kraus, *Photogrammetry* vol. 1)::

    dr = K (r + r^3 / f^2)                 r, f in pixels, K in radians

For a standard atmosphere Bertram's formula gives ``K`` from the flying height ``H`` and the ground
height ``h`` (kilometres above sea level)::

    K = 2410e-6 * (H / (H^2 - 6 H + 250) - h^2 / ((h^2 - 6 h + 250) H))

(about 18 microradians at H = 1.8 km).  :func:`remove_refraction` takes the displacement out of
measured pixels so that the central projection of :class:`~skyrig.camera.frame.FrameCamera` applies.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.camera.frame import FrameCamera

__all__ = ["refraction_coefficient_bertram", "remove_refraction", "fit_radial_scale"]


def refraction_coefficient_bertram(flying_height_m: float, ground_height_m: float) -> float:
    """Refraction constant ``K`` (radians) of a standard atmosphere (Bertram), heights above sea level in m."""
    H = float(flying_height_m) / 1000.0
    h = float(ground_height_m) / 1000.0
    if not H > h:
        raise ValueError(f"flying height {flying_height_m} m must be above the ground height {ground_height_m} m")
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
