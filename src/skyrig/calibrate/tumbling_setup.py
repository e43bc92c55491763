"""The laboratory set-up of the ``tumbling-head`` recipe (paper 000, 3.4): a rig held still above a textured plane.

Frames and units: the lab frame is a local Cartesian frame (ENU axes, metres) with the sensor head at its origin,
body x along north, y east, z down; the plane is ``z = -plane_distance_m`` (the floor seen straight below the head).
Angles are radians.  The recipe: :mod:`skyrig.calibrate.tumbling`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.dense.plane_mosaic import Plane
from skyrig.errors import SkyrigError
from skyrig.geodesy.frame import WorldFrame
from skyrig.georef.eo import ExteriorOrientations
from skyrig.rig.boresight_curve import BoresightCurve
from skyrig.rig.rig import ActuatedHead, Rig

__all__ = ["LabSetup", "ENU_FROM_BODY"]

#: lab frame (east, north, up) from body (x forward = north, y right = east, z down)
ENU_FROM_BODY = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


@dataclass(frozen=True)
class LabSetup:
    """The laboratory set-up: a rig held still above a textured plane.

    Attributes
    ----------
    rig
        The nominal rig: the tumbling head's curve is ignored (the recipe measures it), the reference head is a
        fixed head of the same rig (its mounting and lever arm are the reference camera's pose on the sensor head).
    head
        Name of the tumbling (actuated) head.
    reference_head
        Name of the static reference camera's head.
    plane_distance_m
        Distance of the textured plane below the sensor head origin along body z (m, > 0).
    """

    rig: Rig
    head: str
    reference_head: str
    plane_distance_m: float
    frame: WorldFrame = field(default_factory=lambda: WorldFrame.local(0.0, 0.0, 0.0))

    def __post_init__(self) -> None:
        for opt, name in (("head", self.head), ("reference head", self.reference_head)):
            if name not in self.rig:
                raise SkyrigError(f"{opt} {name!r} is not in rig {self.rig.name!r} (heads: "
                                  f"{', '.join(self.rig.head_names)})")
        if not self.rig.head(self.head).is_actuated:
            raise SkyrigError(f"head {self.head!r} of rig {self.rig.name!r} is not actuated (no tumbling mount)")
        if self.rig.head(self.reference_head).is_actuated:
            raise SkyrigError(f"reference head {self.reference_head!r} must be a fixed head, not an actuated one")
        d = float(self.plane_distance_m)
        if not (np.isfinite(d) and d > 0):
            raise SkyrigError(f"plane distance must be a positive number of metres, got {self.plane_distance_m!r}")
        object.__setattr__(self, "plane_distance_m", d)

    @property
    def plane(self) -> Plane:
        """The textured plane ``z = -plane_distance_m`` of the lab frame (u east, v north)."""
        return Plane.horizontal(-self.plane_distance_m)

    @property
    def nominal_head(self) -> ActuatedHead:
        """The tumbling head without any correction curve (eqs 1-3 of paper 000)."""
        h = cast(ActuatedHead, self.rig.head(self.head))  # checked on construction
        return cast(ActuatedHead, h.with_(curve=None))

    def tumbling_orientation(self, beta_rad: ArrayLike, correction_rad: ArrayLike | None = None
                             ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``lab_from_camera`` rotations ``(..., 3, 3)`` and centre ``(3,)`` of the tumbling camera at ``beta_rad``.

        ``correction_rad``: a constant ``(droll, dpitch, dyaw)`` added to the tumbling angles (radians), applied
        through the rig's own composition (a one-position curve); None: the nominal mounting.
        """
        h = self.nominal_head
        if correction_rad is not None:
            c = np.asarray(correction_rad, dtype=np.float64).reshape(1, 3)
            h = h.with_(curve=BoresightCurve(np.zeros(1), c, interpolation="linear"))  # type: ignore[assignment]
        r = ENU_FROM_BODY @ h.body_from_camera_rotation(np.asarray(beta_rad, dtype=np.float64))
        return r, ENU_FROM_BODY @ h.lever_arm_m

    def reference_orientation(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``lab_from_camera`` rotation ``(3, 3)`` and centre ``(3,)`` of the reference camera."""
        h = self.rig.head(self.reference_head)
        return ENU_FROM_BODY @ h.body_from_camera_rotation(), ENU_FROM_BODY @ h.lever_arm_m

    def eo(self, names: Sequence[str], heads: Sequence[str], rotations: ArrayLike, centres: ArrayLike
           ) -> ExteriorOrientations:
        """Orientations of images in the lab frame."""
        cams = [self.rig.head(h).camera.name for h in heads]
        return ExteriorOrientations(np.asarray(names, dtype=str), np.asarray(cams, dtype=str),
                                    np.asarray(centres, dtype=np.float64).reshape(-1, 3),
                                    np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3), self.frame)
