"""The Brown / Australis distortion model (physical "additional parameters" of close-range photogrammetry).

This is the 10-parameter camera model of Fraser (1997) as used by Australis (the software paper 004
used for the MIDAS cage calibration) and by most photogrammetric bundle programs: principal distance
and principal point (held by :class:`~skyrig.camera.frame.FrameCamera`) plus seven parameters here.

Convention
----------
Coordinates are **image coordinates in millimetres relative to the principal point**, x right, y up.
The model is a *correction* evaluated at the **observed** (distorted, measured) coordinates
``x̄, ȳ``; adding it gives the ideal coordinates that satisfy the collinearity equations::

    r² = x̄² + ȳ²
    Δx = x̄ (K1 r² + K2 r⁴ + K3 r⁶) + P1 (r² + 2 x̄²) + 2 P2 x̄ ȳ + B1 x̄ + B2 ȳ
    Δy = ȳ (K1 r² + K2 r⁴ + K3 r⁶) + P2 (r² + 2 ȳ²) + 2 P1 x̄ ȳ
    x_ideal = x̄ + Δx,  y_ideal = ȳ + Δy          (x_ideal = -c X_cam / Z_cam, see frame.py)

so :meth:`BrownDistortion.undistort` (observed -> ideal) is closed form and
:meth:`BrownDistortion.distort` (ideal -> observed, used by projection) is solved by Newton iteration
to 1e-12 mm, its Jacobians following from the implicit function theorem.

Signs: with this convention a **positive K1 pulls observed points towards the principal point
(barrel distortion)**: the observed radius is smaller than the ideal one.  A negative K1 is
pincushion.  The radial displacement of an observed point is ``-(K1 r³ + K2 r⁵ + K3 r⁷)`` to first order.

Units (mm-based, independent of the focal length):

=====  =========  ================================================
K1     mm^-2      radial, 3rd order
K2     mm^-4      radial, 5th order
K3     mm^-6      radial, 7th order
P1     mm^-1      decentring (tangential), x
P2     mm^-1      decentring (tangential), y
B1     1          affinity: differential scale of x against y
B2     1          shear: non-orthogonality of the x and y axes
=====  =========  ================================================

Parameter names in files and in ``param_names`` are lower case (``k1 ... b2``); dictionaries are read
case-insensitively, so ``K1`` works as well.  Because the parameters are mm-based, a calibration made
with one pixel size/principal point stays valid only together with that image coordinate system.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from skyrig.camera.distortion import CorrectionModel, register_distortion

__all__ = ["BrownDistortion"]


@register_distortion
@dataclass(frozen=True)
class BrownDistortion(CorrectionModel):
    """Brown / Australis distortion (K1 K2 K3 radial, P1 P2 decentring, B1 B2 affinity and shear).

    Attributes
    ----------
    k1, k2, k3
        Radial coefficients, mm^-2, mm^-4, mm^-6.
    p1, p2
        Decentring coefficients, mm^-1.
    b1, b2
        Affinity and shear, dimensionless.
    """

    k1: float = 0.0
    k2: float = 0.0
    k3: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    b1: float = 0.0
    b2: float = 0.0

    name: ClassVar[str] = "brown"
    param_names: ClassVar[tuple[str, ...]] = ("k1", "k2", "k3", "p1", "p2", "b1", "b2")
    param_units: ClassVar[tuple[str, ...]] = ("mm^-2", "mm^-4", "mm^-6", "mm^-1", "mm^-1", "1", "1")

    def correction(self, xy_observed: NDArray[np.float64]) -> NDArray[np.float64]:
        """The correction ``(Δx, Δy)`` ``(N, 2)`` mm at observed coordinates ``(N, 2)`` mm."""
        xy = np.asarray(xy_observed, dtype=np.float64)
        return self.undistort(xy, 1.0) - xy

    def _correct_with_jacobians(
        self, xy_observed: NDArray[np.float64], focal_mm: float, with_params: bool = True
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        x, y = xy_observed[:, 0], xy_observed[:, 1]
        k1, k2, k3, p1, p2, b1, b2 = self.k1, self.k2, self.k3, self.p1, self.p2, self.b1, self.b2
        r2 = x * x + y * y
        r4 = r2 * r2
        r6 = r4 * r2
        radial = k1 * r2 + k2 * r4 + k3 * r6
        dradial = k1 + 2.0 * k2 * r2 + 3.0 * k3 * r4  # d(radial)/d(r²)
        xy2 = 2.0 * x * y
        n = x.shape[0]

        ideal = np.empty((n, 2))
        ideal[:, 0] = x + x * radial + p1 * (r2 + 2.0 * x * x) + p2 * xy2 + b1 * x + b2 * y
        ideal[:, 1] = y + y * radial + p2 * (r2 + 2.0 * y * y) + p1 * xy2

        G = np.empty((n, 2, 2))
        G[:, 0, 0] = 1.0 + radial + 2.0 * x * x * dradial + 6.0 * p1 * x + 2.0 * p2 * y + b1
        G[:, 0, 1] = 2.0 * x * y * dradial + 2.0 * p1 * y + 2.0 * p2 * x + b2
        G[:, 1, 0] = 2.0 * x * y * dradial + 2.0 * p2 * x + 2.0 * p1 * y
        G[:, 1, 1] = 1.0 + radial + 2.0 * y * y * dradial + 6.0 * p2 * y + 2.0 * p1 * x

        if not with_params:
            return ideal, G, np.empty((n, 2, 0)), np.empty((n, 2))
        Gp = np.zeros((n, 2, 7))
        Gp[:, 0, 0], Gp[:, 1, 0] = x * r2, y * r2
        Gp[:, 0, 1], Gp[:, 1, 1] = x * r4, y * r4
        Gp[:, 0, 2], Gp[:, 1, 2] = x * r6, y * r6
        Gp[:, 0, 3], Gp[:, 1, 3] = r2 + 2.0 * x * x, xy2
        Gp[:, 0, 4], Gp[:, 1, 4] = xy2, r2 + 2.0 * y * y
        Gp[:, 0, 5] = x
        Gp[:, 0, 6] = y
        return ideal, G, Gp, np.zeros((n, 2))
