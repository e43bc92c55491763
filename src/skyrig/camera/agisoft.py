"""The frame camera model of Agisoft Metashape / PhotoScan / Lens (``k1..k4``, ``p1 p2``, ``b1 b2``).

Defined as in the Metashape Professional manual, Appendix C "Camera models", frame cameras, on
normalised coordinates of the camera frame x right, **y down**, z forward (Metashape's, as OpenCV's)::

    x = X/Z, y = Y/Z,  r² = x² + y²
    x' = x (1 + K1 r² + K2 r⁴ + K3 r⁶ + K4 r⁸) + P1 (r² + 2 x²) + 2 P2 x y
    y' = y (1 + K1 r² + K2 r⁴ + K3 r⁶ + K4 r⁸) + P2 (r² + 2 y²) + 2 P1 x y
    u  = w/2 + cx + x' f + x' B1 + y' B2
    v  = h/2 + cy + y' f

with ``f`` (the principal distance), ``cx``, ``cy``, ``B1``, ``B2`` in pixels and ``u, v`` from the image's
top-left *corner*.

Against OpenCV: Metashape's ``P1`` multiplies ``r² + 2x²`` in x', which is OpenCV's ``p2``: **P1 and P2
are swapped** (``p1_opencv = P2``, ``p2_opencv = P1``).  ``B1`` is ``fx - fy`` and ``B2`` the skew
(Agisoft support: "F = Fy, B1 = Fx - Fy, B2 = skew").  A Metashape camera with ``K4 = B1 = B2 = 0`` is
exactly an OpenCV one (:class:`~skyrig.camera.opencv.OpenCVDistortion` with ``k3 = K3`` and the swap).

Mapping to skyrig
-----------------
skyrig's distortion works on image millimetres relative to the principal point, y up
(:mod:`skyrig.camera.distortion`); with principal distance ``c`` (mm) the normalised coordinates are
``x = x_mm / c``, ``y = -y_mm / c``, and the observed point is ``x_mm = c (x'(1 + b1) + y' b2)``,
``y_mm = -c y'``.  The parameters are dimensionless:

=======  ======================================================
k1..k4   radial, as Metashape's K1..K4
p1, p2   decentring, **Metashape's** P1, P2 (not OpenCV's order)
b1       affinity ``B1 / f`` (Metashape's B1 in pixels over f in pixels)
b2       skew ``B2 / f``
=======  ======================================================

so a Metashape calibration maps exactly: ``focal_px = f``, principal point ``((w-1)/2 + cx, (h-1)/2 + cy)``
in skyrig pixels (origin the centre of the top-left pixel), ``b1 = B1/f``, ``b2 = B2/f``.
``distort`` is closed form; ``undistort`` is Newton iteration (1e-12 mm).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.camera.distortion import Distortion, _as_points, register_distortion

__all__ = ["AgisoftDistortion"]


@register_distortion
@dataclass(frozen=True)
class AgisoftDistortion(Distortion):
    """Agisoft Metashape frame-camera distortion (module docstring); all parameters dimensionless."""

    k1: float = 0.0
    k2: float = 0.0
    k3: float = 0.0
    k4: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    b1: float = 0.0
    b2: float = 0.0

    name: ClassVar[str] = "agisoft"
    param_names: ClassVar[tuple[str, ...]] = ("k1", "k2", "k3", "k4", "p1", "p2", "b1", "b2")
    param_units: ClassVar[tuple[str, ...]] = ("1",) * 8

    def distort_with_jacobians(
        self, xy_ideal: ArrayLike, focal_mm: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        q, _ = _as_points(xy_ideal)
        f = float(focal_mm)
        k1, k2, k3, k4, p1, p2, b1, b2 = (float(v) for v in self.params)
        x = q[:, 0] / f
        y = -q[:, 1] / f
        r2 = x * x + y * y
        r4 = r2 * r2
        r6 = r4 * r2
        r8 = r4 * r4
        rad = 1.0 + k1 * r2 + k2 * r4 + k3 * r6 + k4 * r8
        drad = k1 + 2.0 * k2 * r2 + 3.0 * k3 * r4 + 4.0 * k4 * r6  # d rad / d r²
        xy = x * y
        xd = x * rad + p1 * (r2 + 2.0 * x * x) + 2.0 * p2 * xy
        yd = y * rad + p2 * (r2 + 2.0 * y * y) + 2.0 * p1 * xy
        a = 1.0 + b1
        n = q.shape[0]
        # normalised observed point (skyrig orientation, y up): g = (U, -V), U = a x' + b2 y', V = y'
        g = np.column_stack([a * xd + b2 * yd, -yd])
        # d(x', y') / d(x, y)
        dxx = rad + 2.0 * x * x * drad + 6.0 * p1 * x + 2.0 * p2 * y
        dxy = 2.0 * xy * drad + 2.0 * p1 * y + 2.0 * p2 * x
        dyx = 2.0 * xy * drad + 2.0 * p2 * x + 2.0 * p1 * y
        dyy = rad + 2.0 * y * y * drad + 6.0 * p2 * y + 2.0 * p1 * x
        # d(obs_mm) / d(q_mm) = d g / d(x, -y) : the y input and output both change sign
        J = np.empty((n, 2, 2))
        J[:, 0, 0] = a * dxx + b2 * dyx
        J[:, 0, 1] = -(a * dxy + b2 * dyy)
        J[:, 1, 0] = -dyx
        J[:, 1, 1] = dyy
        # parameters: d(x', y') / d p, then through U, V
        dp_x = np.column_stack([x * r2, x * r4, x * r6, x * r8, r2 + 2.0 * x * x, 2.0 * xy])
        dp_y = np.column_stack([y * r2, y * r4, y * r6, y * r8, 2.0 * xy, r2 + 2.0 * y * y])
        Jp = np.zeros((n, 2, 8))
        Jp[:, 0, :6] = f * (a * dp_x + b2 * dp_y)
        Jp[:, 1, :6] = -f * dp_y
        Jp[:, 0, 6] = f * xd
        Jp[:, 0, 7] = f * yd
        # observed = f g(q / f)  =>  d/df = g - J (q / f)
        d_focal = g - np.einsum("nij,nj->ni", J, q / f)
        return f * g, J, Jp, d_focal
