"""Layer 0 geodesy on pyproj: CRS, ECEF, local tangent and tangential frames, factors, geoid heights."""

from skyrig.geodesy.crs import (
    WGS84_ECEF,
    WGS84_GEOGRAPHIC_3D,
    Geoid,
    MapProjection,
    ecef_to_geodetic,
    geodetic_factors,
    geodetic_to_ecef,
    resolve_crs,
    transformer,
)
from skyrig.geodesy.local import (
    LocalTangentFrame,
    TangentialFrame,
    ecef_from_enu_rotation,
    grid_from_enu_rotation,
)
from skyrig.geodesy.mapheights import map_height_from_true_height, true_height_from_map_height

__all__ = [
    "WGS84_ECEF", "WGS84_GEOGRAPHIC_3D", "Geoid", "MapProjection", "ecef_to_geodetic", "geodetic_factors",
    "geodetic_to_ecef", "resolve_crs", "transformer", "LocalTangentFrame", "TangentialFrame",
    "ecef_from_enu_rotation", "grid_from_enu_rotation", "map_height_from_true_height", "true_height_from_map_height",
]
