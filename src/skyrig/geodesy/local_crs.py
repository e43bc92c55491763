"""A local ENU frame as a project's output frame: the CRS products carry for it, and how far it is from ENU.

A local tangent frame ``local <lat> <lon> <h>`` (east, north, up at a WGS84 origin; :class:`WorldFrame.local`) is a
3D Cartesian frame.  No GeoTIFF, LAS or GeoPackage CRS holds it: PROJ's ``+proj=topocentric`` is a geocentric ->
topocentric *conversion*, not a CRS a raster can be georeferenced in, and an engineering CRS (``LOCAL_CS``) loses
its tie to the Earth in every GIS.  So products of a project whose ``crs:`` is a local frame are written in the
nearest CRS files carry: the **orthographic projection centred at the frame's origin on WGS 84** (EPSG method
9840, ellipsoidal, through PROJ), with **ellipsoidal heights (WGS 84)**.  Its x, y are the ENU east, north of a
point's foot on the ellipsoid; its z is the ellipsoidal height ``h``, not ENU ``up``.  They depart from ENU, for a
point at horizontal distance ``d`` from the origin and ellipsoidal height ``h`` (``R`` ~ 6,380 km):

* horizontally by about ``h * d / R`` (the point's normal leans by ``d / R``): 0.28 m at d = 1 km for h = 1,800 m,
  0.016 m for h = 100 m;
* vertically, ``(h - h0) - up``, by about ``d**2 / (2 R)`` (Earth curvature): 0.08 m at 1 km, 2 m at 5 km.

:func:`enu_departure` measures both against PROJ's own topocentric conversion; the CRS's name states the local
frame it stands for, and :func:`carried_words` says all this in the side-cars.  Orientations and points read in a
local frame are converted exactly (through ECEF); only the products' coordinates are in the carried CRS.

>>> carried_frame(WorldFrame.local(43.64, 4.57, 1807.36)).kind
'map'
"""

from __future__ import annotations

import re
from functools import lru_cache

import numpy as np
import pyproj
from numpy.typing import ArrayLike

from skyrig.errors import CRSError
from skyrig.geodesy.crs import crs_spec, geodetic_to_ecef
from skyrig.geodesy.frame import WorldFrame

__all__ = ["is_local_text", "carried_crs", "carried_frame", "local_of_carried", "enu_departure", "carried_words",
           "CARRIED_PREFIX"]

#: The start of the name of every CRS :func:`carried_crs` makes (how a file's CRS is recognised as one).
CARRIED_PREFIX = "skyrig local ENU"
_NAME = re.compile(CARRIED_PREFIX + r" (\S+) (\S+) (\S+) carried as Orthographic")


def is_local_text(text: object) -> bool:
    """True for a frame text ``local <lat> <lon> <h>`` (checked by :meth:`WorldFrame.from_fields`)."""
    return isinstance(text, str) and text.strip().lower().startswith("local")


@lru_cache(maxsize=32)
def _carried(lat: float, lon: float, h: float) -> pyproj.CRS:
    from pyproj.crs import ProjectedCRS
    from pyproj.crs.coordinate_operation import OrthographicConversion

    name = f"{CARRIED_PREFIX} {lat:.9f} {lon:.9f} {h:.4f} carried as Orthographic (WGS 84, ellipsoidal heights)"
    return ProjectedCRS(conversion=OrthographicConversion(latitude_natural_origin=lat, longitude_natural_origin=lon),
                        geodetic_crs=pyproj.CRS.from_epsg(4326), name=name)


def carried_crs(local: WorldFrame) -> pyproj.CRS:
    """The projected CRS that products of the local frame ``local`` are written in: orthographic at its origin on
    WGS 84, named after the local frame (module docstring)."""
    if local.kind != "local" or local.origin is None:
        raise CRSError(f"a {local.kind} frame is not a local ENU frame")
    lat, lon, h = local.origin
    return _carried(float(lat), float(lon), float(h))


def carried_frame(local: WorldFrame | str, geoid: str | None = None) -> WorldFrame:
    """The map frame (ellipsoidal heights) of :func:`carried_crs`; ``local`` may be its text ``local lat lon h``.

    Raises
    ------
    CRSError
        A malformed local frame, or a geoid: a local frame's heights are ellipsoidal (WGS 84), there is no geoid
        to give.
    """
    if isinstance(local, str):
        local = WorldFrame.from_fields(local)
    if geoid:
        raise CRSError("a local ENU frame has no geoid: its products carry WGS 84 ellipsoidal heights (give a map CRS "
                       "with the geoid for orthometric heights)")
    return WorldFrame.map(crs_spec(carried_crs(local)))


def local_of_carried(crs: object) -> WorldFrame | None:
    """The local frame a CRS made by :func:`carried_crs` stands for (from its name), else None."""
    try:
        name = pyproj.CRS.from_user_input(crs).name if not isinstance(crs, pyproj.CRS) else crs.name
    except (pyproj.exceptions.CRSError, TypeError, ValueError):
        return None
    m = _NAME.match(name or "")
    return WorldFrame.local(*(float(g) for g in m.groups())) if m else None


@lru_cache(maxsize=32)
def _topocentric(lat: float, lon: float, h: float) -> pyproj.Transformer:
    return pyproj.Transformer.from_pipeline(
        f"+proj=pipeline +step +proj=topocentric +ellps=WGS84 +lat_0={lat!r} +lon_0={lon!r} +h_0={h!r}")


def enu_departure(local: WorldFrame, points: ArrayLike) -> tuple[float, float]:
    """How far the carried CRS departs from the ENU frame at ``points`` ``(N, 3)`` given in the carried frame:
    ``(horizontal, vertical)`` maxima in metres, against PROJ's topocentric conversion (horizontal: the carried
    x, y against ENU east, north; vertical: ``h - h0`` against ENU up)."""
    frame = carried_frame(local)
    p = np.atleast_2d(np.asarray(points, dtype=np.float64))
    g = frame.projection.to_geodetic(p)
    xyz = geodetic_to_ecef(g[:, 0], g[:, 1], g[:, 2])
    lat, lon, h0 = local.origin  # type: ignore[misc]
    e, n, u = _topocentric(float(lat), float(lon), float(h0)).transform(xyz[:, 0], xyz[:, 1], xyz[:, 2])
    horizontal = np.hypot(p[:, 0] - np.asarray(e), p[:, 1] - np.asarray(n))
    vertical = np.abs(p[:, 2] - h0 - np.asarray(u))
    return float(horizontal.max()), float(vertical.max())


def carried_words(crs: object) -> str | None:
    """A sentence for side-cars on a CRS made by :func:`carried_crs` (None for any other CRS): which local frame
    it stands for, and its departure from ENU at 1 km and 5 km from the origin at the origin's height."""
    local = local_of_carried(crs)
    if local is None:
        return None
    lat, lon, h0 = local.origin  # type: ignore[misc]
    frame = carried_frame(local)
    dep = {}
    for d in (1000.0, 5000.0):
        ring = [[d * np.cos(a), d * np.sin(a), h0] for a in np.linspace(0, 2 * np.pi, 8, endpoint=False)]
        dep[d] = enu_departure(local, frame.from_ecef(WorldFrame.local(lat, lon, h0).to_ecef(
            [[q[0], q[1], 0.0] for q in ring])))
    return (f"x, y: orthographic projection centred at the origin of the local ENU frame '{local.to_text()}' on WGS 84, "
            "the nearest CRS that GeoTIFF / LAS / GeoPackage carry (a local ENU frame is no such CRS); z: WGS 84 "
            "ellipsoidal height, not ENU up. Departure from ENU (PROJ topocentric) at the origin's height: "
            f"{dep[1000.0][0]:.3f} m horizontal, {dep[1000.0][1]:.3f} m vertical at 1 km from the origin; "
            f"{dep[5000.0][0]:.3f} m, {dep[5000.0][1]:.3f} m at 5 km")
