"""How a frame's coordinates are stated in a file: horizontal CRS + vertical reference (compound CRS when PROJ
identifies the geoid's vertical CRS, a custom vertical CRS naming the geoid otherwise), the inverse, and the project
CRS of a user's ``--crs`` (a compound CRS brings its geoid) or of a UAV block (its UTM zone).

Shared by every writer that states a CRS: GeoTIFF (:mod:`skyrig.io.dsm_cog`), LAZ (:mod:`skyrig.io.dense_laz`),
GeoPackage and the CSV side-cars (:mod:`skyrig.io.table_meta`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyproj

from skyrig.errors import CRSError
from skyrig.geodesy.crs import crs_spec, horizontal_crs, resolve_crs
from skyrig.geodesy.frame import WorldFrame
from skyrig.geodesy.geoid_db import _proj_db, _vertical_code_of_grid, vertical_crs_of_geoid  # noqa: F401 - re-exported

__all__ = ["FileCRS", "crs_statement", "file_crs", "frame_from_file_crs", "vertical_crs_of_geoid", "project_frame", "utm_frame"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FileCRS:
    """How a frame's coordinates are stated in a file.

    Attributes
    ----------
    horizontal
        The 2D horizontal CRS.
    full
        The complete 3D statement: a compound CRS (orthometric heights) or a 3D projected / geographic
        CRS (ellipsoidal heights).
    vertical_identified
        True when the vertical CRS is one PROJ's database knows (an EPSG code), so ``full`` is a plain
        ``horizontal + EPSG vertical`` compound that GeoTIFF GeoKeys can hold.
    kind
        ``"ellipsoidal"`` or ``"orthometric"``.
    geoid
        The frame's geoid grid as given, or None.
    vertical_words
        Human-readable vertical reference, e.g. ``"EGM96 height (EPSG:5773)"``.
    """

    horizontal: pyproj.CRS
    full: pyproj.CRS
    vertical_identified: bool
    kind: str
    geoid: str | None
    vertical_words: str


def file_crs(frame: WorldFrame) -> FileCRS:
    """The CRS statement of a ``map`` frame for a file.

    Raises
    ------
    CRSError
        If the frame is not a ``map`` frame.
    """
    if frame.kind != "map" or frame.crs is None:
        raise CRSError(f"outputs are written in a map frame (a CRS), not a {frame.kind} frame")
    h = horizontal_crs(resolve_crs(frame.crs))
    if frame.geoid is None:
        full = h.to_3d()
        ell = h.geodetic_crs.to_3d() if h.geodetic_crs is not None else None
        code = ell.to_epsg() if ell is not None else None
        words = "ellipsoidal heights" + (f" ({ell.name} ellipsoid, EPSG:{code})" if code else
                                         f" ({ell.name})" if ell is not None else "")
        from skyrig.geodesy.local_crs import carried_words

        local = carried_words(h)  # the CRS that carries a local ENU frame: say which, and how far from ENU
        return FileCRS(h, full, False, "ellipsoidal", None, words + (f"; {local}" if local else ""))
    v = vertical_crs_of_geoid(frame.geoid)
    gname = Path(str(frame.geoid)).name
    if v is not None:
        full = pyproj.crs.CompoundCRS(f"{h.name} + {v.name}", [h, v])
        code = v.to_epsg()
        words = f"orthometric heights, {v.name}" + (f" (EPSG:{code})" if code else "") + f", geoid grid {gname}"
        return FileCRS(h, full, True, "orthometric", str(frame.geoid), words)
    datum = pyproj.crs.Datum.from_json_dict({"type": "VerticalReferenceFrame", "name": f"geoid {gname}"})
    v = pyproj.crs.VerticalCRS(name=f"height above geoid {gname}", datum=datum, geoid_model=gname)
    full = pyproj.crs.CompoundCRS(f"{h.name} + {v.name}", [h, v])
    return FileCRS(h, full, False, "orthometric", str(frame.geoid), f"orthometric heights, geoid grid {gname}")


def frame_from_file_crs(crs: pyproj.CRS, geoid: str | None = None, kind: str | None = None) -> WorldFrame:
    """A ``map`` frame from a CRS read from a file (the inverse of :func:`file_crs`).

    Parameters
    ----------
    crs
        The file's CRS: compound (orthometric), 3D (ellipsoidal) or 2D (then ``kind`` decides).
    geoid
        The geoid grid recorded in the file; without it, a compound CRS with an EPSG vertical CRS gets
        the grid PROJ's database names for it, a custom vertical CRS its ``GEOIDMODEL``.
    kind
        ``"ellipsoidal"`` / ``"orthometric"`` as recorded in the file, if any.
    """
    h = horizontal_crs(crs)
    if crs.is_compound or kind == "orthometric":
        if not geoid and crs.is_compound:
            v = crs.sub_crs_list[1]
            geoid = (v.to_json_dict().get("geoid_model") or {}).get("name")
            if geoid is None and v.to_epsg() is not None:
                return WorldFrame.map(crs)  # the grid PROJ uses for this compound CRS, checked against PROJ
        if not geoid:
            raise CRSError(f"the file states orthometric heights ({crs.name}) but no geoid grid for them")
        return WorldFrame.map(crs_spec(h), geoid)
    if kind is None and len(crs.axis_info) < 3:
        log.warning("%s: the file states no vertical reference; heights taken as ellipsoidal", crs.name)
    return WorldFrame.map(crs_spec(h))


def project_frame(crs: Any, geoid: str | None = None) -> WorldFrame:
    """The map frame of a user's CRS: a compound CRS whose vertical CRS PROJ ties to a geoid grid gives
    orthometric heights through that grid (e.g. ``EPSG:25832+5773`` -> EGM96 ``egm96_15.gtx``); a 2D/3D CRS
    gives ellipsoidal heights, or orthometric ones through ``geoid`` when given.

    Raises
    ------
    CRSError
        An unknown CRS, a geocentric one, or a compound CRS whose geoid PROJ does not know (give ``geoid``).

    A local ENU frame ``local <lat> <lon> <h>`` gives the map frame products carry for it (Local Orthographic at
    its origin scaled to its height, WGS 84 ellipsoidal heights: :mod:`skyrig.geodesy.local_crs`).
    """
    c = resolve_crs(crs)
    if c.is_geocentric:
        raise CRSError(f"{c.name}: outputs need a map CRS (projected or geographic), not a geocentric one")
    if c.is_compound:
        return frame_from_file_crs(c, geoid, "orthometric")
    spec = str(crs) if not isinstance(crs, pyproj.CRS) else crs_spec(c)
    if len(c.axis_info) == 3:
        spec = crs_spec(c.to_2d())
    return WorldFrame.map(spec, geoid)


def utm_frame(lat_deg: Any, lon_deg: Any, geoid: str | None = None) -> WorldFrame:
    """The WGS84 UTM zone (EPSG:326xx / 327xx) of the mean of geographic positions (PROJ's database query),
    ellipsoidal heights unless ``geoid`` is given.

    >>> utm_frame([50.85], [-0.15]).crs
    'EPSG:32630'
    """
    lat = float(np.mean(np.asarray(lat_deg, float)))
    lon = float(np.mean(np.asarray(lon_deg, float)))
    from pyproj.aoi import AreaOfInterest
    from pyproj.database import query_utm_crs_info

    info = query_utm_crs_info(datum_name="WGS 84", area_of_interest=AreaOfInterest(lon, lat, lon, lat))
    codes = sorted(f"{i.auth_name}:{i.code}" for i in info if i.auth_name == "EPSG")
    if not codes:
        raise CRSError(f"no UTM zone for lat {lat:.6f} lon {lon:.6f}")
    return WorldFrame.map(codes[0], geoid)


def crs_statement(frame: WorldFrame) -> tuple[str | None, str]:
    """``(wkt or None, words)``: the CRS of a frame for files (WKT2 of the compound / 3D CRS) and its vertical
    reference in words; None for a local frame."""
    if frame.kind == "local":
        return None, "local ENU frame: z up from the tangent plane at the origin"
    if frame.kind == "ecef":
        return resolve_crs("EPSG:4978").to_wkt(), "geocentric (ECEF) coordinates"
    fc = file_crs(frame)
    return fc.full.to_wkt(), fc.vertical_words
