"""Local Cartesian frames: local tangent planes (ENU / NED at an origin) and the tangential frame.

The *tangential* frame of Redweik & Jacobsen (paper 003; Heipke et al. 2001) is a local tangent plane
ENU frame: origin at a tangent point on the ellipsoid, Y towards geographic north, Z along the
ellipsoid normal, the same (unit) scale on all three axes, no map projection distortion.  skyrig
adjusts blocks in this frame; see ``docs/frames.md`` for why.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.errors import CRSError
from skyrig.geodesy.crs import MapProjection, ecef_to_geodetic, geodetic_to_ecef
from skyrig.geometry.rotations import ENU_FROM_NED, rot_z

LocalKind = Literal["enu", "ned"]


def ecef_from_enu_rotation(lat_deg: ArrayLike, lon_deg: ArrayLike) -> NDArray[np.float64]:
    """``ecef_from_enu`` rotation matrices ``(..., 3, 3)`` at geodetic positions (degrees).

    Columns are the east, north and up unit vectors (up = ellipsoid normal) in ECEF.
    """
    lat = np.radians(np.asarray(lat_deg, dtype=np.float64))
    lon = np.radians(np.asarray(lon_deg, dtype=np.float64))
    sl, cl = np.sin(lat), np.cos(lat)
    so, co = np.sin(lon), np.cos(lon)
    r = np.empty(lat.shape + (3, 3))
    r[..., :, 0] = np.stack([-so, co, np.zeros_like(so)], axis=-1)
    r[..., :, 1] = np.stack([-sl * co, -sl * so, cl], axis=-1)
    r[..., :, 2] = np.stack([cl * co, cl * so, sl], axis=-1)
    return r


def ecef_from_ned_rotation(lat_deg: ArrayLike, lon_deg: ArrayLike) -> NDArray[np.float64]:
    """``ecef_from_ned`` rotation matrices ``(..., 3, 3)`` at geodetic positions (degrees).

    Columns are the north, east and down unit vectors (down = minus the ellipsoid normal) in ECEF.
    """
    enu = ecef_from_enu_rotation(lat_deg, lon_deg)
    out = enu[..., :, [1, 0, 2]]  # = ecef_from_enu @ ENU_FROM_NED, without a batched product
    out[..., :, 2] *= -1.0
    return out


def grid_from_enu_rotation(convergence_rad: ArrayLike) -> NDArray[np.float64]:
    """``grid_from_enu``: rotation from the local ENU frame to the map grid axes (E_grid, N_grid, Up).

    ``convergence_rad`` is the meridian convergence as returned by
    :meth:`skyrig.geodesy.MapProjection.factors` (azimuth of grid north, clockwise from true north).
    """
    return rot_z(convergence_rad)


@dataclass(frozen=True)
class LocalTangentFrame:
    """A local tangent plane at a geodetic origin, ENU (x east, y north, z up) or NED.

    Parameters
    ----------
    lat_deg, lon_deg, h
        Origin: WGS84 latitude and longitude in degrees, ellipsoidal height in metres.
    kind
        ``"enu"`` or ``"ned"``.
    """

    lat_deg: float
    lon_deg: float
    h: float = 0.0
    kind: LocalKind = "enu"

    def __post_init__(self) -> None:
        if self.kind not in ("enu", "ned"):
            raise CRSError(f"local frame kind must be 'enu' or 'ned', not {self.kind!r}")
        if not (-90.0 <= self.lat_deg <= 90.0) or not np.isfinite(self.lon_deg) or not np.isfinite(self.h):
            raise CRSError(f"invalid local frame origin ({self.lat_deg}, {self.lon_deg}, {self.h})")

    @property
    def origin_ecef(self) -> NDArray[np.float64]:
        """Origin in ECEF, ``(3,)`` metres."""
        return geodetic_to_ecef(self.lat_deg, self.lon_deg, self.h).reshape(3)

    @property
    def ecef_from_local(self) -> NDArray[np.float64]:
        """Rotation ``ecef_from_local`` ``(3, 3)``."""
        r = ecef_from_enu_rotation(self.lat_deg, self.lon_deg)
        return r if self.kind == "enu" else r @ ENU_FROM_NED

    def from_ecef(self, xyz: ArrayLike) -> NDArray[np.float64]:
        """ECEF ``(N, 3)`` to local ``(N, 3)`` (metres)."""
        return (np.asarray(xyz, dtype=np.float64) - self.origin_ecef) @ self.ecef_from_local

    def to_ecef(self, local: ArrayLike) -> NDArray[np.float64]:
        """Local ``(N, 3)`` to ECEF ``(N, 3)``."""
        return np.asarray(local, dtype=np.float64) @ self.ecef_from_local.T + self.origin_ecef

    def from_geodetic(self, lat_deg: ArrayLike, lon_deg: ArrayLike, h: ArrayLike) -> NDArray[np.float64]:
        """WGS84 geodetic to local ``(N, 3)``."""
        return self.from_ecef(geodetic_to_ecef(lat_deg, lon_deg, h))

    def to_geodetic(self, local: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Local ``(N, 3)`` to WGS84 ``(lat_deg, lon_deg, h)``."""
        return ecef_to_geodetic(self.to_ecef(local))

    def local_from_local_enu_at(self, lat_deg: ArrayLike, lon_deg: ArrayLike) -> NDArray[np.float64]:
        """Rotation from the ENU frame at other positions into this frame, ``(..., 3, 3)``.

        Needed to carry attitudes given relative to the local vertical at each exposure into one frame.
        """
        return self.ecef_from_local.T @ ecef_from_enu_rotation(lat_deg, lon_deg)


@dataclass(frozen=True)
class TangentialFrame:
    """The tangential frame of paper 003 tied to a mapping CRS.

    A :class:`LocalTangentFrame` (ENU) whose origin is given in map coordinates, with transforms of
    points and attitudes to and from that mapping frame.

    Parameters
    ----------
    projection
        The mapping frame (CRS and height reference).
    origin_map
        Tangent point in map coordinates ``(x, y, height)``, usually the block centre at ground level.
    """

    projection: MapProjection
    origin_map: tuple[float, float, float]

    @property
    def local(self) -> LocalTangentFrame:
        lat, lon, h = self.projection.to_geodetic(np.asarray(self.origin_map, dtype=np.float64))[0]
        return LocalTangentFrame(float(lat), float(lon), float(h), "enu")

    def from_map(self, points: ArrayLike) -> NDArray[np.float64]:
        """Map coordinates ``(N, 3)`` to tangential ``(N, 3)`` metres."""
        return self.local.from_ecef(self.projection.to_ecef(points))

    def to_map(self, points: ArrayLike) -> NDArray[np.float64]:
        """Tangential ``(N, 3)`` to map coordinates ``(N, 3)``."""
        return self.projection.from_ecef(self.local.to_ecef(points))

    def tangential_from_grid_rotation(self, points_map: ArrayLike) -> NDArray[np.float64]:
        """Rotation ``(N, 3, 3)`` taking attitudes expressed in the map grid axes at each map position
        (E_grid, N_grid, local up) into the tangential frame.

        ``tangential_from_camera = tangential_from_grid @ grid_from_camera``.  It contains the meridian
        convergence and the tilt of the local vertical between each point and the tangent point.
        """
        p = np.atleast_2d(np.asarray(points_map, dtype=np.float64))
        g = self.projection.to_geodetic(p)
        conv, _ = self.projection.factors(p)
        local = self.local
        return local.local_from_local_enu_at(g[:, 0], g[:, 1]) @ np.swapaxes(grid_from_enu_rotation(conv), -1, -2)
