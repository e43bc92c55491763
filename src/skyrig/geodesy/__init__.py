"""Layer 0 geodesy on pyproj: CRS, ECEF, local tangent and tangential frames, factors, geoid heights, world frames
(:class:`WorldFrame` and its text form) and the CRS statement of a frame in files."""

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
from skyrig.geodesy.frame import WorldFrame, local_frame_for
from skyrig.geodesy.statement import (
    FileCRS,
    file_crs,
    frame_from_file_crs,
    project_frame,
    utm_frame,
    vertical_crs_of_geoid,
)

__all__ = [
    "WGS84_ECEF", "WGS84_GEOGRAPHIC_3D", "Geoid", "MapProjection", "ecef_to_geodetic", "geodetic_factors",
    "geodetic_to_ecef", "resolve_crs", "transformer", "LocalTangentFrame", "TangentialFrame",
    "ecef_from_enu_rotation", "ecef_from_ned_rotation", "grid_from_enu_rotation", "map_height_from_true_height", "true_height_from_map_height",
    "grid_from_camera_from_rpy", "grid_from_ned_rotation", "ned_from_body_from_grid_from_camera", "opk_from_rpy",
    "rpy_from_opk", "WorldFrame", "local_frame_for", "FileCRS", "file_crs", "frame_from_file_crs", "project_frame",
    "utm_frame", "vertical_crs_of_geoid", "clear_caches",
]


def clear_caches() -> None:
    """Forget cached PROJ objects (after PROJ's data folders change, e.g. ``pyproj.datadir.append_data_dir``)."""
    from skyrig.geodesy import crs, frame, statement

    for f in (crs._transformer, crs._vgrid, crs._proj, crs._compound_geoid, frame._projection_cached,
              statement._vertical_code_of_grid):
        f.cache_clear()
