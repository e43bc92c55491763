"""The text of a local ENU frame and the projected CRS its products are carried in (a leaf: pyproj and numpy only).

:mod:`skyrig.geodesy.crs` and :mod:`skyrig.geodesy.frame` read ``local <lat> <lon> <h>`` through this module, so
that every ``--crs`` means the same CRS; :mod:`skyrig.geodesy.local_crs` (above both) says why this CRS, and how far
it departs from ENU.
"""

from __future__ import annotations

import re
from functools import lru_cache

import numpy as np
import pyproj

from skyrig.errors import CRSError

__all__ = ["CARRIED_PREFIX", "is_local_text", "parse_local_text", "gauss_radius", "carried_crs_at", "carried_origin"]

#: The start of the name of every CRS :func:`carried_crs_at` makes (GDAL's GeoTIFF writes it with underscores).
CARRIED_PREFIX = "skyrig local ENU"
_PREFIX = re.compile(r"^skyrig[ _]local[ _]ENU")
_A, _F = 6378137.0, 1 / 298.257223563  # WGS 84


def is_local_text(text: object) -> bool:
    """True for a frame text ``local <lat> <lon> <h>`` (:func:`parse_local_text` checks it)."""
    return isinstance(text, str) and text.strip().lower().startswith("local")


def parse_local_text(text: str) -> tuple[float, float, float]:
    """``(lat_deg, lon_deg, h_m)`` of ``local <lat_deg> <lon_deg> <h_m>``; :class:`CRSError` when malformed."""
    parts = str(text).strip().split()
    if len(parts) != 4 or parts[0].lower() != "local":
        raise CRSError("expected 'local <lat_deg> <lon_deg> <h_m>'")
    try:
        lat, lon, h = (float(p) for p in parts[1:])
    except ValueError:
        raise CRSError(f"expected 'local <lat_deg> <lon_deg> <h_m>', not {text!r}") from None
    if not all(np.isfinite([lat, lon, h])) or abs(lat) > 90:
        raise CRSError(f"local frame origin out of range: {text!r}")
    return lat, lon, h


def gauss_radius(lat_deg: float) -> float:
    """sqrt(M N) of WGS 84 at ``lat_deg`` (the Gaussian mean radius of curvature, metres)."""
    e2 = _F * (2 - _F)
    s2 = np.sin(np.radians(lat_deg)) ** 2
    return float(_A * np.sqrt(1 - e2) / (1 - e2 * s2))


@lru_cache(maxsize=32)
def carried_crs_at(lat: float, lon: float, h: float) -> pyproj.CRS:
    """Local Orthographic at ``(lat, lon)`` on WGS 84 with scale factor ``1 + h / sqrt(M N)``, named after the local
    frame (:mod:`skyrig.geodesy.local_crs`)."""
    k = 1.0 + h / gauss_radius(lat)
    c = pyproj.CRS.from_proj4(f"+proj=ortho +lat_0={lat!r} +lon_0={lon!r} +k_0={k!r} +datum=WGS84 +units=m "
                              "+no_defs +type=crs")
    d = c.to_json_dict()
    d["name"] = f"{CARRIED_PREFIX} {lat:.9f} {lon:.9f} {h:.4f} carried as Local Orthographic (WGS 84 ellipsoidal heights)"
    d["base_crs"] = pyproj.CRS.from_epsg(4326).to_json_dict()
    return pyproj.CRS.from_json_dict(d)


def carried_origin(crs: object) -> tuple[float, float, float] | None:
    """The local frame's origin ``(lat, lon, h)`` a CRS made by :func:`carried_crs_at` stands for (its projection
    centre, and h0 from its scale factor), else None."""
    try:
        c = crs if isinstance(crs, pyproj.CRS) else pyproj.CRS.from_user_input(crs)
    except (pyproj.exceptions.CRSError, TypeError, ValueError):
        return None
    op = c.coordinate_operation
    if not _PREFIX.match(c.name or "") or op is None:
        return None
    values = {}
    for p in op.params:
        low = p.name.lower()
        key = "lat" if "latitude" in low else "lon" if "longitude" in low else "k" if "scale" in low else None
        if key:
            values[key] = float(p.value)
    values.setdefault("k", 1.0)  # an origin on the ellipsoid (h0 = 0): PROJ writes it as plain Orthographic
    if set(values) != {"lat", "lon", "k"}:
        return None
    return values["lat"], values["lon"], round((values["k"] - 1.0) * gauss_radius(values["lat"]), 4)
