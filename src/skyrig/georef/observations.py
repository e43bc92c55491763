"""Plain containers for image measurements and ground points."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from skyrig.georef.eo import WorldFrame


@dataclass(frozen=True)
class ImageMeasurements:
    """N image measurements of named points.

    Attributes
    ----------
    point, image
        ``(N,)`` point and image names.
    pixel
        ``(N, 2)`` (column, row) in pixels, column right, row down, origin at the centre of the
        top-left pixel (see :mod:`skyrig.camera.frame`).
    """

    point: NDArray[np.str_]
    image: NDArray[np.str_]
    pixel: NDArray[np.float64]

    def __post_init__(self) -> None:
        p = np.asarray(self.point, dtype=str).reshape(-1)
        object.__setattr__(self, "point", p)
        object.__setattr__(self, "image", np.asarray(self.image, dtype=str).reshape(len(p)))
        object.__setattr__(self, "pixel", np.asarray(self.pixel, dtype=np.float64).reshape(len(p), 2))

    def __len__(self) -> int:
        return len(self.point)


@dataclass(frozen=True)
class GroundPoints:
    """Named ground points in a world frame.

    Attributes
    ----------
    name
        ``(N,)`` point names.
    xyz
        ``(N, 3)`` coordinates in ``frame``.
    frame
        The world frame of ``xyz``.
    kind
        Optional ``(N,)`` integer type code from the source file (e.g. IGN's 3 = planimetric+height...).
    """

    name: NDArray[np.str_]
    xyz: NDArray[np.float64]
    frame: WorldFrame
    kind: NDArray[np.int64] | None = None

    def __post_init__(self) -> None:
        n = np.asarray(self.name, dtype=str).reshape(-1)
        object.__setattr__(self, "name", n)
        object.__setattr__(self, "xyz", np.asarray(self.xyz, dtype=np.float64).reshape(len(n), 3))

    def __len__(self) -> int:
        return len(self.name)

    def index(self) -> dict[str, int]:
        return {str(k): i for i, k in enumerate(self.name)}
