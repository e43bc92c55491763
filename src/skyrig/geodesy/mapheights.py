"""Heights of results adjusted *directly in map coordinates*.

A block adjusted in a projected CRS as if it were Cartesian sees horizontal distances scaled by the
point scale factor ``k`` but vertical distances unscaled.  Programs that do this (e.g. IGN's, or
BLUH without the tangential frame) compensate by scaling heights above the ground by ``k`` as well,
the "linear alteration": ``Z_map = Z + (k - 1) (Z - z_ground)``.  Projection centres from such an
adjustment carry this alteration and must be reduced before they are used with a rigorous (ECEF or
tangential-frame) model; ground points near ``z_ground`` are almost unaffected.

skyrig itself never adjusts in map coordinates: blocks are transformed to the tangential frame, adjusted
there, and transformed back (see ``docs/frames.md``).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray


def true_height_from_map_height(z_map: ArrayLike, scale_factor: ArrayLike, z_ground: float) -> NDArray[np.float64]:
    """Undo the linear alteration: ``Z = z_ground + (Z_map - z_ground) / k``."""
    return z_ground + (np.asarray(z_map, dtype=np.float64) - z_ground) / np.asarray(scale_factor, dtype=np.float64)


def map_height_from_true_height(z: ArrayLike, scale_factor: ArrayLike, z_ground: float) -> NDArray[np.float64]:
    """Apply the linear alteration: ``Z_map = Z + (k - 1) (Z - z_ground)``."""
    z = np.asarray(z, dtype=np.float64)
    return z + (np.asarray(scale_factor, dtype=np.float64) - 1.0) * (z - z_ground)
