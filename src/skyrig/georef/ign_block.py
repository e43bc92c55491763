"""Conventions of IGN aerial-triangulation results, as one place to get them right.

IGN projection centres (``.OPK``) are in Lambert-93 (EPSG:2154) with altitudes (NGF-IGN69, geoid RAF20)
that carry the linear alteration of an adjustment made in map coordinates; ground points (``.app``,
``*_world.mes``) behave as ellipsoidal heights.  :func:`ign_frames` returns the frames and the ground
height that undo this, so that a rigorous (ECEF) projection reproduces IGN's image measurements.
"""

from __future__ import annotations

from dataclasses import dataclass

from skyrig.georef.eo import ExteriorOrientations, WorldFrame


@dataclass(frozen=True)
class IgnConventions:
    """How to read an IGN block.

    Attributes
    ----------
    crs
        Mapping CRS of all coordinates (default Lambert-93).
    geoid
        Geoid grid for the projection-centre altitudes (RAF20 for France), path or PROJ name.
    z_ground
        Mean ground height (m) used by the linear alteration of projection-centre heights.
    ground_heights
        ``"ellipsoidal"`` (IGN block 805) or ``"orthometric"`` for the ground points.
    """

    crs: str = "EPSG:2154"
    geoid: str | None = None
    z_ground: float = 53.0
    ground_heights: str = "ellipsoidal"

    @property
    def eo_frame(self) -> WorldFrame:
        return WorldFrame.map(self.crs, self.geoid)

    @property
    def ground_frame(self) -> WorldFrame:
        return WorldFrame.map(self.crs, self.geoid if self.ground_heights == "orthometric" else None)

    def reduce(self, eo: ExteriorOrientations) -> ExteriorOrientations:
        """Undo the linear alteration of the projection-centre heights."""
        return eo.with_map_heights_reduced(self.z_ground)
