"""Layer 2: direct georeferencing, exterior orientations in world frames, ground <-> image."""

from skyrig.georef.direct import PlatformStates, direct_georeference, inverse_georeference
from skyrig.georef.eo import ExteriorOrientations, WorldFrame
from skyrig.georef.ground import (
    Dem,
    Intersection,
    forward_intersection,
    image_to_world_dem,
    image_to_world_height,
    world_to_image,
)
from skyrig.georef.observations import GroundPoints, ImageMeasurements

__all__ = [
    "PlatformStates", "direct_georeference", "inverse_georeference", "ExteriorOrientations", "WorldFrame", "Dem",
    "Intersection", "forward_intersection", "image_to_world_dem", "image_to_world_height", "world_to_image",
    "GroundPoints", "ImageMeasurements",
]
