"""The "forward" distortion model of aerial calibration reports and bundle programs: distortion applied at
the **ideal** point, balanced radial distortion (a radius R0 of zero distortion), a distortion centre
apart from the principal point, radial terms to r^8, decentring, affinity and shear.

Where it comes from
-------------------
Camera calibration reports of aerial cameras and several bundle programs (BINGO, Inpho MATCH-AT, the
"Fraser" model with a distortion centre of MicMac) give the distortion as a *displacement of the ideal
image point*, with the radial part "balanced" so that it is zero at a chosen radius R0 (the focal length
is then the one that makes the distortion curve cross zero there).  skyrig's Brown model
(:mod:`skyrig.camera.brown`, Australis) is the other convention: a *correction of the observed point*.

Convention
----------
Coordinates are image coordinates in millimetres relative to the principal point (x right, y up).  With
the ideal (collinear) point ``q`` and the distortion centre ``c = (xc_mm, yc_mm)`` (relative to the
principal point)::

    u   = q - c,   r² = u_x² + u_y²
    ρ   = K1 (r² - R0²) + K2 (r⁴ - R0⁴) + K3 (r⁶ - R0⁶) + K4 (r⁸ - R0⁸)
    Δx  = u_x ρ + P1 (r² + 2 u_x²) + 2 P2 u_x u_y + B1 u_x + B2 u_y
    Δy  = u_y ρ + P2 (r² + 2 u_y²) + 2 P1 u_x u_y
    observed = q + Δ

so :meth:`ForwardDistortion.distort` (ideal -> observed, used by projection) is closed form and
:meth:`~skyrig.camera.distortion.Distortion.undistort` is Newton iteration to 1e-12 mm.

Signs, against Brown: here a **positive K1 moves points outwards** (pincushion): the radial displacement
of an ideal point at radius r is ``+K1 r (r² - R0²) + ...``.  Brown's correction is added to the
*observed* point, so to first order the forward coefficients are Brown's with the opposite sign
(``K1_forward ≈ -K1_brown``); R0 ≠ 0 adds the linear term ``-K1 R0² r``, a change of the principal
distance.  Convert between the two with :func:`skyrig.camera.convert.convert_camera`, which fits one to
the other over the whole frame and reports the residual.

Parameters (estimable, in this order) and the constant:

=======  =========  ===========================================================
xc_mm    mm         distortion centre, x, relative to the principal point
yc_mm    mm         distortion centre, y
k1..k4   mm^-2..-8  radial terms r^2, r^4, r^6, r^8 (balanced at R0)
p1, p2   mm^-1      decentring
b1       1          affinity (differential scale of x against y)
b2       1          shear (non-orthogonality)
r0_mm    mm         **constant** (never estimated): radius of zero radial distortion; 0 = unbalanced
=======  =========  ===========================================================

``r0_mm`` is a model constant (:attr:`~skyrig.camera.distortion.Distortion.constant_names`): it is
written to and read from rig files with the parameters, but not part of :attr:`params` (with the K terms
and the principal distance free it cannot be estimated).  The distortion centre is strongly correlated
with the principal point and the decentring terms; a self-calibration normally holds it fixed.

>>> import numpy as np
>>> m = ForwardDistortion(k1=1e-4, r0_mm=10.0)
>>> float(np.linalg.norm(m.distort(np.array([[10.0, 0.0]]), 50.0)[0] - [10.0, 0.0]))  # zero at R0
0.0
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.camera.distortion import Distortion, _as_points, register_distortion

__all__ = ["ForwardDistortion"]


@register_distortion
@dataclass(frozen=True)
class ForwardDistortion(Distortion):
    """Distortion at the ideal point with balanced radial terms (K1..K4, zero at ``r0_mm``), a distortion
    centre ``(xc_mm, yc_mm)``, decentring P1 P2, affinity B1 and shear B2 (module docstring)."""

    xc_mm: float = 0.0
    yc_mm: float = 0.0
    k1: float = 0.0
    k2: float = 0.0
    k3: float = 0.0
    k4: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    b1: float = 0.0
    b2: float = 0.0
    r0_mm: float = 0.0

    name: ClassVar[str] = "forward"
    param_names: ClassVar[tuple[str, ...]] = ("xc_mm", "yc_mm", "k1", "k2", "k3", "k4", "p1", "p2", "b1", "b2")
    param_units: ClassVar[tuple[str, ...]] = ("mm", "mm", "mm^-2", "mm^-4", "mm^-6", "mm^-8", "mm^-1", "mm^-1",
                                              "1", "1")
    constant_names: ClassVar[tuple[str, ...]] = ("r0_mm",)

    def __post_init__(self) -> None:
        if not np.isfinite(self.r0_mm) or self.r0_mm < 0:
            raise ValueError(f"forward distortion: r0_mm must be a finite number >= 0, got {self.r0_mm}")

    def distort_with_jacobians(
        self, xy_ideal: ArrayLike, focal_mm: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        q, _ = _as_points(xy_ideal)
        n = q.shape[0]
        ux = q[:, 0] - self.xc_mm
        uy = q[:, 1] - self.yc_mm
        k1, k2, k3, k4, p1, p2, b1, b2 = self.k1, self.k2, self.k3, self.k4, self.p1, self.p2, self.b1, self.b2
        R2 = self.r0_mm**2
        r2 = ux * ux + uy * uy
        r4 = r2 * r2
        r6 = r4 * r2
        r8 = r4 * r4
        t1, t2, t3, t4 = r2 - R2, r4 - R2**2, r6 - R2**3, r8 - R2**4
        rho = k1 * t1 + k2 * t2 + k3 * t3 + k4 * t4
        drho = k1 + 2.0 * k2 * r2 + 3.0 * k3 * r4 + 4.0 * k4 * r6  # d rho / d r²
        uxy2 = 2.0 * ux * uy

        obs = np.empty((n, 2))
        obs[:, 0] = q[:, 0] + ux * rho + p1 * (r2 + 2.0 * ux * ux) + p2 * uxy2 + b1 * ux + b2 * uy
        obs[:, 1] = q[:, 1] + uy * rho + p2 * (r2 + 2.0 * uy * uy) + p1 * uxy2

        D = np.empty((n, 2, 2))  # d(Delta)/du
        D[:, 0, 0] = rho + 2.0 * ux * ux * drho + 6.0 * p1 * ux + 2.0 * p2 * uy + b1
        D[:, 0, 1] = uxy2 * drho + 2.0 * p1 * uy + 2.0 * p2 * ux + b2
        D[:, 1, 0] = uxy2 * drho + 2.0 * p2 * ux + 2.0 * p1 * uy
        D[:, 1, 1] = rho + 2.0 * uy * uy * drho + 6.0 * p2 * uy + 2.0 * p1 * ux
        J = D.copy()
        J[:, 0, 0] += 1.0
        J[:, 1, 1] += 1.0

        Jp = np.zeros((n, 2, 10))
        Jp[:, :, 0] = -D[:, :, 0]  # d obs / d xc = -dDelta/du_x
        Jp[:, :, 1] = -D[:, :, 1]
        for col, t in ((2, t1), (3, t2), (4, t3), (5, t4)):
            Jp[:, 0, col] = ux * t
            Jp[:, 1, col] = uy * t
        Jp[:, 0, 6], Jp[:, 1, 6] = r2 + 2.0 * ux * ux, uxy2
        Jp[:, 0, 7], Jp[:, 1, 7] = uxy2, r2 + 2.0 * uy * uy
        Jp[:, 0, 8] = ux
        Jp[:, 0, 9] = uy
        return obs, J, Jp, np.zeros((n, 2))
