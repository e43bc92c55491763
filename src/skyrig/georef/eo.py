"""Exterior orientations of images and the frames they are expressed in.

An :class:`ExteriorOrientations` holds, for N images, the projection centre and the rotation
``frame_from_camera`` (photogrammetric camera frame, see :mod:`skyrig.camera.frame`) in one
:class:`WorldFrame`:

* ``WorldFrame.ecef()``: geocentric WGS84 (EPSG:4978); rotations are ``ecef_from_camera``.
* ``WorldFrame.map(crs, geoid=None)``: a mapping CRS (projected or geographic) with ellipsoidal heights,
  or orthometric heights through a geoid grid.  Rotations are ``grid_from_camera`` where *grid* is
  the local frame at the projection centre with axes (grid east, grid north, ellipsoid normal up).
  This is how photogrammetric software exchanges omega/phi/kappa in map coordinates: kappa counts
  from grid north, and the meridian convergence separates it from an IMU heading.
* ``WorldFrame.local(lat, lon, h)``: a local tangent plane ENU frame (the tangential frame of
  paper 003) with origin at a geodetic position; rotations are ``local_from_camera``.

Conversions between frames are rigorous (through ECEF).  :class:`WorldFrame` lives in layer 0
(:mod:`skyrig.geodesy.frame`, with its text form) and is re-exported here.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.geodesy.frame import FrameKind, WorldFrame, local_frame_for
from skyrig.geodesy.mapheights import map_height_from_true_height, true_height_from_map_height
from skyrig.geometry.pose import Pose

__all__ = ["ExteriorOrientations", "FrameKind", "WorldFrame", "local_frame_for"]

@dataclass(frozen=True)
class ExteriorOrientations:
    """Exterior orientation of N images in one :class:`WorldFrame`.

    Attributes
    ----------
    image
        ``(N,)`` image names.
    camera
        ``(N,)`` camera (interior orientation) names.
    centre
        ``(N, 3)`` projection centres in the frame (metres, or degrees + metres for a geographic CRS).
    rotation
        ``(N, 3, 3)`` ``frame_from_camera`` rotations (grid axes for map frames).
    frame
        The world frame.
    time_s, head, exposure
        Optional per-image event time, rig head name and platform exposure id.
    """

    image: NDArray[np.str_]
    camera: NDArray[np.str_]
    centre: NDArray[np.float64]
    rotation: NDArray[np.float64]
    frame: WorldFrame
    time_s: NDArray[np.float64] | None = None
    head: NDArray[np.str_] | None = None
    exposure: NDArray[np.int64] | None = None
    extra: dict[str, NDArray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        image = np.asarray(self.image, dtype=str).reshape(-1)
        n = len(image)
        object.__setattr__(self, "image", image)
        object.__setattr__(self, "camera", np.broadcast_to(np.asarray(self.camera, dtype=str), (n,)).copy())
        c = np.asarray(self.centre, dtype=np.float64).reshape(n, 3)
        r = np.asarray(self.rotation, dtype=np.float64).reshape(n, 3, 3)
        object.__setattr__(self, "centre", c)
        object.__setattr__(self, "rotation", r)
        if self.time_s is not None:
            object.__setattr__(self, "time_s", np.asarray(self.time_s, dtype=np.float64).reshape(n))
        if self.head is not None:
            object.__setattr__(self, "head", np.asarray(self.head, dtype=str).reshape(n))
        if self.exposure is not None:
            object.__setattr__(self, "exposure", np.asarray(self.exposure, dtype=np.int64).reshape(n))

    def __len__(self) -> int:
        return len(self.image)

    def pose(self) -> Pose:
        """Batched ``frame_from_camera`` pose ``(N)``."""
        return Pose(self.rotation, self.centre, "world", "camera")

    def index(self) -> dict[str, int]:
        """Image name -> row; raises on duplicate names."""
        idx: dict[str, int] = {}
        for i, name in enumerate(self.image):
            if name in idx:
                raise ValueError(f"duplicate image name {name!r} in exterior orientations")
            idx[str(name)] = i
        return idx

    def subset(self, rows: ArrayLike) -> "ExteriorOrientations":
        """The orientations at the given rows (indices or boolean mask)."""
        r = np.asarray(rows)
        return replace(
            self,
            image=self.image[r], camera=self.camera[r], centre=self.centre[r], rotation=self.rotation[r],
            time_s=None if self.time_s is None else self.time_s[r],
            head=None if self.head is None else self.head[r],
            exposure=None if self.exposure is None else self.exposure[r],
            extra={k: v[r] for k, v in self.extra.items()},
        )

    def to_frame(self, frame: WorldFrame) -> "ExteriorOrientations":
        """The same orientations expressed in another world frame (rigorous, through ECEF)."""
        if frame == self.frame:
            return self
        ecef_c = self.frame.to_ecef(self.centre)
        ecef_r = self.frame.ecef_from_frame_rotation(self.centre) @ self.rotation
        new_c = frame.from_ecef(ecef_c)
        new_r = np.swapaxes(frame.ecef_from_frame_rotation(new_c), -1, -2) @ ecef_r
        return replace(self, centre=new_c, rotation=new_r, frame=frame)

    def with_map_heights_reduced(self, z_ground: float) -> "ExteriorOrientations":
        """Undo the 'linear alteration' of projection-centre heights from an adjustment made directly in map
        coordinates (see :mod:`skyrig.geodesy.mapheights`); only for map frames."""
        _, k = self.frame.projection.factors(self.centre)
        c = self.centre.copy()
        c[:, 2] = true_height_from_map_height(c[:, 2], k, z_ground)
        return replace(self, centre=c)

    def with_map_heights_altered(self, z_ground: float) -> "ExteriorOrientations":
        """Inverse of :meth:`with_map_heights_reduced`."""
        _, k = self.frame.projection.factors(self.centre)
        c = self.centre.copy()
        c[:, 2] = map_height_from_true_height(c[:, 2], k, z_ground)
        return replace(self, centre=c)
