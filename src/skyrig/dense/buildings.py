"""Building blocks and façades: the data model shared by building extraction, façade texturing and 3D models.

Coordinates are in the frame of the DSM they came from (``frame``: a map CRS with its height reference, or a
local ENU frame), metres.  Polygons are counter-clockwise seen from above, without a repeated closing vertex.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from skyrig.geodesy.frame import WorldFrame


@dataclass(frozen=True)
class Facade:
    """One vertical wall: the footprint edge ``index`` (vertex ``index`` -> ``index + 1``) of a building.

    Attributes
    ----------
    building
        Id of the building (:attr:`BuildingBlock.id`).
    index
        Edge number in the footprint.
    corners
        ``(4, 3)``: bottom-start, bottom-end, top-end, top-start.  Seen from outside, start is on the left, so the
        outward normal is ``(end - start) x up`` normalised.
    """

    building: int
    index: int
    corners: NDArray[np.float64]

    @property
    def normal(self) -> NDArray[np.float64]:
        """Outward horizontal unit normal."""
        d = self.corners[1] - self.corners[0]
        n = np.array([d[1], -d[0], 0.0])
        return n / np.linalg.norm(n)

    @property
    def width_m(self) -> float:
        return float(np.linalg.norm((self.corners[1] - self.corners[0])[:2]))

    @property
    def height_m(self) -> float:
        return float(self.corners[3, 2] - self.corners[0, 2])


@dataclass(frozen=True)
class BuildingBlock:
    """A building as a prism with a roof.

    Attributes
    ----------
    id
        Building number.
    footprint
        ``(N, 2)`` counter-clockwise polygon (x, y).
    ground_z
        Height of the wall bottoms (terrain at the footprint).
    eave_z
        Height of the wall tops.
    roof
        Roof polygons, each ``(K, 3)``, counter-clockwise seen from above (one for a flat roof, two for a gable ...).
    source
        ``"dsm"`` (extracted) or the file the footprint came from.
    """

    id: int
    footprint: NDArray[np.float64]
    ground_z: float
    eave_z: float
    roof: tuple[NDArray[np.float64], ...] = ()
    source: str = "dsm"

    def facades(self) -> list[Facade]:
        """The walls, one per footprint edge."""
        out = []
        fp = np.asarray(self.footprint, float)
        for i in range(len(fp)):
            a, b = fp[i], fp[(i + 1) % len(fp)]
            out.append(Facade(self.id, i, np.array([[a[0], a[1], self.ground_z], [b[0], b[1], self.ground_z],
                                                    [b[0], b[1], self.eave_z], [a[0], a[1], self.eave_z]])))
        return out


@dataclass(frozen=True)
class FacadeTexture:
    """A rectified texture of one façade.

    Attributes
    ----------
    facade
        The wall.
    rgb
        ``(H, W, 3)`` uint8; row 0 at the top (``eave_z``), column 0 at the start edge (``corners[0]``), texel centres at
        ``(j + 0.5) * texel_m`` along the wall and ``eave_z - (i + 0.5) * texel_m`` in height.
    valid
        ``(H, W)`` bool: texels that got a colour from an image that sees them.
    texel_m
        Texel size in metres.
    images
        Names of the source images, best first.
    """

    facade: Facade
    rgb: NDArray[np.uint8]
    valid: NDArray[np.bool_]
    texel_m: float
    images: tuple[str, ...] = ()


@dataclass(frozen=True)
class BuildingModel:
    """Buildings with their façade textures and the frame they are in."""

    frame: WorldFrame
    buildings: tuple[BuildingBlock, ...]
    textures: tuple[FacadeTexture, ...] = ()
    vertical_reference: str = ""
    metadata: dict = field(default_factory=dict)
