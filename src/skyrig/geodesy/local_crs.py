"""A local ENU frame as a project's output frame: the CRS products carry for it, and how far it is from ENU.

A local tangent frame ``local <lat> <lon> <h>`` (east, north, up at a WGS84 origin; :class:`WorldFrame.local`) is a
3D Cartesian frame.  No GeoTIFF, LAS or GeoPackage CRS holds it: PROJ's ``+proj=topocentric`` is a geocentric ->
topocentric *conversion*, not a CRS a raster can be georeferenced in, and an engineering CRS (``LOCAL_CS``) loses
its tie to the Earth in every GIS.  So products of a project whose ``crs:`` is a local frame are written in the
nearest CRS files carry: the **Local Orthographic projection** (EPSG method 1130, ellipsoidal, through PROJ)
**centred at the frame's origin on WGS 84, with its scale factor k0 = 1 + h0 / sqrt(M0 N0)** (the ground scale at
the origin's height h0, as a low-distortion projection is scaled to its project height), and **WGS 84 ellipsoidal
heights**.  Its x, y are k0 times the ENU east, north of a point's foot on the ellipsoid; its z is the ellipsoidal
height ``h``, not ENU ``up``.  They depart from ENU, for a point at horizontal distance ``d`` from the origin
(``R`` ~ 6,380 km):

* horizontally by about ``(h - h0) * d / R`` (the point's normal leans by ``d / R``; the scale factor takes out the
  origin's height): 0.5 mm at d = 1 km at the origin's height, 0.016 m at 1 km for a point 100 m above or below it;
* vertically, ``(h - h0) - up``, by about ``d**2 / (2 R)`` (Earth curvature): 0.08 m at 1 km, 2 m at 5 km.

:func:`enu_departure` measures both against PROJ's own topocentric conversion, and :func:`carried_words` says this in
the side-cars.  The CRS alone defines the frame (origin: the projection centre; h0: from k0), so any file in it tells
which local frame it stands for (:func:`local_of_carried`).  GeoTIFF stores it as GDAL's ESRI PE string (no GeoKey
for a Local Orthographic): GDAL, rasterio and QGIS read it back exactly; LAS 1.4 and GeoPackage hold its WKT.
Orientations and points read in a local frame are converted exactly (through ECEF); only the products' coordinates
are in the carried CRS.

>>> carried_frame(WorldFrame.local(43.64, 4.57, 1807.36)).kind
'map'
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pyproj
from numpy.typing import ArrayLike

from skyrig.errors import CRSError
from skyrig.geodesy.carried import CARRIED_PREFIX, carried_crs_at, carried_origin, is_local_text
from skyrig.geodesy.crs import crs_spec, geodetic_to_ecef
from skyrig.geodesy.frame import WorldFrame

__all__ = ["is_local_text", "carried_crs", "carried_frame", "local_of_carried", "enu_departure", "carried_words",
           "CARRIED_PREFIX"]


def carried_crs(local: WorldFrame) -> pyproj.CRS:
    """The projected CRS that products of the local frame ``local`` are written in: Local Orthographic at its origin
    on WGS 84, scaled to its height, named after the local frame (module docstring)."""
    if local.kind != "local" or local.origin is None:
        raise CRSError(f"a {local.kind} frame is not a local ENU frame")
    lat, lon, h = local.origin
    return carried_crs_at(float(lat), float(lon), float(h))


def carried_frame(local: WorldFrame | str, geoid: str | None = None) -> WorldFrame:
    """The map frame (ellipsoidal heights) of :func:`carried_crs`; ``local`` may be its text ``local lat lon h``.

    Raises
    ------
    CRSError
        A malformed local frame, or a geoid: a local frame's heights are ellipsoidal (WGS 84), there is no geoid
        to give.
    """
    if isinstance(local, str):
        return WorldFrame.map(local, geoid)  # parses the text, refuses a geoid
    if geoid:
        return WorldFrame.map(local.fields()["crs"], geoid)  # the same refusal
    return WorldFrame.map(crs_spec(carried_crs(local)))


def local_of_carried(crs: object) -> WorldFrame | None:
    """The local frame a CRS made by :func:`carried_crs` stands for (its projection centre, and h0 from its scale
    factor), else None."""
    origin = carried_origin(crs)
    return None if origin is None else WorldFrame.local(*origin)


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
    it stands for, and its departure from ENU at 1 km and 5 km from the origin, at the origin's height and 100 m
    above it."""
    local = local_of_carried(crs)
    if local is None:
        return None
    lat, lon, h0 = local.origin  # type: ignore[misc]
    frame = carried_frame(local)
    dep = {}
    for d in (1000.0, 5000.0):
        for up in (0.0, 100.0):
            ring = [[d * np.cos(a), d * np.sin(a), up] for a in np.linspace(0, 2 * np.pi, 8, endpoint=False)]
            dep[d, up] = enu_departure(local, frame.from_ecef(local.to_ecef(ring)))
    return (f"x, y: Local Orthographic projection centred at the origin of the local ENU frame '{local.to_text()}' on "
            "WGS 84, scaled to the origin's height, the nearest CRS that GeoTIFF / LAS / GeoPackage carry (a local "
            "ENU frame is no such CRS); z: WGS 84 ellipsoidal height, not ENU up. Departure from ENU (PROJ "
            f"topocentric): at 1 km from the origin {dep[1000.0, 0.0][0]:.4f} m horizontal at the origin's height, "
            f"{dep[1000.0, 100.0][0]:.3f} m 100 m above it, {dep[1000.0, 0.0][1]:.3f} m vertical; at 5 km "
            f"{dep[5000.0, 0.0][0]:.4f} m, {dep[5000.0, 100.0][0]:.3f} m, {dep[5000.0, 0.0][1]:.3f} m")
