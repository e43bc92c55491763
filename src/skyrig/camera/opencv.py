"""OpenCV's radial-tangential distortion (``k1 k2 p1 p2 k3`` and the rational ``k4 k5 k6``).

Defined exactly as ``cv2.projectPoints`` on normalised coordinates of OpenCV's camera frame
(x right, **y down**, z forward)::

    x = X/Z, y = Y/Z,  r² = x² + y²
    a  = (1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶)
    x' = x a + 2 p1 x y + p2 (r² + 2 x²)
    y' = y a + p1 (r² + 2 y²) + 2 p2 x y
    col = fx x' + cx,  row = fy y' + cy

Mapping to skyrig's conventions
-------------------------------
skyrig's camera frame is x right, y up, z backwards and image millimetres are y up
(:mod:`skyrig.camera.frame`).  For ideal image coordinates relative to the principal point
``(x_mm, y_mm)`` and principal distance ``f``, the normalised coordinates are ``u = x_mm / f``,
``v = y_mm / f`` and OpenCV's are ``x = u``, ``y = -v`` (same point: ``X_cv = X``, ``Y_cv = -Y``,
``Z_cv = -Z``).  The distorted OpenCV coordinates map back the same way: observed
``x_mm = f x'``, ``y_mm = -f y'``.  With a :class:`~skyrig.camera.frame.FrameCamera` of square pixels
this is identical to ``cv2.projectPoints`` with ``fx = fy = focal_px`` and ``(cx, cy)`` the principal
point in pixels (both use the centre of the top-left pixel as origin).  In skyrig's y-up frame the
formulas read ``u' = u a - 2 p1 u v + p2 (r² + 2u²)``, ``v' = v a - p1 (r² + 2v²) + 2 p2 u v``: p1
changes sign, the other coefficients do not.

All parameters are dimensionless (normalised coordinates), so the model depends on ``focal_mm``.
``distort`` is closed form; ``undistort`` is Newton iteration to 1e-12 mm.  Thin-prism (s1..s4) and
tilted-sensor (tauX, tauY) terms are not supported.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.camera.distortion import Distortion, _as_points, register_distortion

__all__ = ["OpenCVDistortion", "OpenCVRationalDistortion"]

_ALL = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")


def _opencv_core(
    x: NDArray[np.float64], y: NDArray[np.float64], c: dict[str, float]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """OpenCV normalised distortion in OpenCV's frame: ``(xy' (N,2), d/dxy (N,2,2), d/dparams (N,2,8))``."""
    k1, k2, p1, p2, k3, k4, k5, k6 = (c[n] for n in _ALL)
    r2 = x * x + y * y
    r4 = r2 * r2
    r6 = r4 * r2
    A = 1.0 + k1 * r2 + k2 * r4 + k3 * r6
    B = 1.0 + k4 * r2 + k5 * r4 + k6 * r6
    a = A / B
    dA = k1 + 2.0 * k2 * r2 + 3.0 * k3 * r4
    dB = k4 + 2.0 * k5 * r2 + 3.0 * k6 * r4
    da = (dA * B - A * dB) / (B * B)  # d a / d r²
    xy = x * y
    n = x.shape[0]
    out = np.empty((n, 2))
    out[:, 0] = x * a + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x * x)
    out[:, 1] = y * a + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * xy
    J = np.empty((n, 2, 2))
    J[:, 0, 0] = a + 2.0 * x * x * da + 2.0 * p1 * y + 6.0 * p2 * x
    J[:, 0, 1] = 2.0 * xy * da + 2.0 * p1 * x + 2.0 * p2 * y
    J[:, 1, 0] = 2.0 * xy * da + 2.0 * p1 * x + 2.0 * p2 * y
    J[:, 1, 1] = a + 2.0 * y * y * da + 6.0 * p1 * y + 2.0 * p2 * x
    Jp = np.empty((n, 2, 8))
    inv_b = 1.0 / B
    for col, rk in ((0, r2), (1, r4), (4, r6)):  # k1, k2, k3: loop over 3 parameters, not points
        Jp[:, 0, col] = x * rk * inv_b
        Jp[:, 1, col] = y * rk * inv_b
    for col, rk in ((5, r2), (6, r4), (7, r6)):  # k4, k5, k6
        Jp[:, 0, col] = -x * a * rk * inv_b
        Jp[:, 1, col] = -y * a * rk * inv_b
    Jp[:, 0, 2], Jp[:, 1, 2] = 2.0 * xy, r2 + 2.0 * y * y  # p1
    Jp[:, 0, 3], Jp[:, 1, 3] = r2 + 2.0 * x * x, 2.0 * xy  # p2
    return out, J, Jp


_FLIP = np.array([1.0, -1.0])


class _OpenCVBase(Distortion):
    def distort_with_jacobians(
        self, xy_ideal: ArrayLike, focal_mm: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        q, _ = _as_points(xy_ideal)
        f = float(focal_mm)
        coeffs = {n: float(getattr(self, n, 0.0)) for n in _ALL}
        # to OpenCV normalised coordinates: x = u, y = -v
        xc = q[:, 0] / f
        yc = -q[:, 1] / f
        d, J, Jp = _opencv_core(xc, yc, coeffs)
        # back to skyrig: u' = x', v' = -y'; M = diag(1, -1) on both sides
        uv_d = d * _FLIP
        J = J * _FLIP[None, :, None] * _FLIP[None, None, :]
        cols = [_ALL.index(n) for n in self.param_names]
        d_params = f * Jp[:, :, cols] * _FLIP[None, :, None]
        observed = f * uv_d
        # observed = f D(q/f)  =>  d/df = D(u) - J u
        uv = np.stack([xc, -yc], axis=1)
        d_focal = uv_d - np.einsum("nij,nj->ni", J, uv)
        return observed, J, d_params, d_focal


@register_distortion
@dataclass(frozen=True)
class OpenCVDistortion(_OpenCVBase):
    """OpenCV radial-tangential distortion ``(k1, k2, p1, p2, k3)``, all dimensionless."""

    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0

    name: ClassVar[str] = "opencv"
    param_names: ClassVar[tuple[str, ...]] = ("k1", "k2", "p1", "p2", "k3")
    param_units: ClassVar[tuple[str, ...]] = ("1",) * 5

    def opencv_coefficients(self) -> NDArray[np.float64]:
        """``distCoeffs`` for OpenCV functions, in OpenCV's order ``(k1, k2, p1, p2, k3[, k4, k5, k6])``."""
        return self.params


@register_distortion
@dataclass(frozen=True)
class OpenCVRationalDistortion(OpenCVDistortion):
    """OpenCV rational model ``(k1, k2, p1, p2, k3, k4, k5, k6)`` (``CALIB_RATIONAL_MODEL``)."""

    k4: float = 0.0
    k5: float = 0.0
    k6: float = 0.0

    name: ClassVar[str] = "opencv_rational"
    param_names: ClassVar[tuple[str, ...]] = _ALL
    param_units: ClassVar[tuple[str, ...]] = ("1",) * 8
