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
    ecef_from_ned_rotation,
    grid_from_enu_rotation,
)
from skyrig.geodesy.attitude import (
    grid_from_camera_from_rpy,
    grid_from_ned_rotation,
    ned_from_body_from_grid_from_camera,
    opk_from_rpy,
    rpy_from_opk,
)
from skyrig.geodesy.mapheights import map_height_from_true_height, true_height_from_map_height

__all__ = [
    "WGS84_ECEF", "WGS84_GEOGRAPHIC_3D", "Geoid", "MapProjection", "ecef_to_geodetic", "geodetic_factors",
    "geodetic_to_ecef", "resolve_crs", "transformer", "LocalTangentFrame", "TangentialFrame",
    "ecef_from_enu_rotation", "ecef_from_ned_rotation", "grid_from_enu_rotation", "map_height_from_true_height", "true_height_from_map_height",
    "grid_from_camera_from_rpy", "grid_from_ned_rotation", "ned_from_body_from_grid_from_camera", "opk_from_rpy",
    "rpy_from_opk",
]
