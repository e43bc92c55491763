"""Result containers of the dense stage: a DSM grid and a dense point cloud (arrays only, no files).

Both carry the :class:`skyrig.georef.eo.WorldFrame` their coordinates are in.  For a DSM the frame is a
``map`` frame (a projected CRS; heights ellipsoidal, or orthometric through the frame's geoid): cell
centres are ``x = x0 + (col + 0.5) * cell_m``, ``y = y0 - (row + 0.5) * cell_m`` (north-up, row 0 at the
north edge, GDAL's convention for a transform ``(cell, 0, x0, 0, -cell, y0)``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from skyrig.georef.eo import WorldFrame


@dataclass(frozen=True)
class GridSpec:
    """A north-up grid in a map frame.

    Attributes
    ----------
    x0, y0
        Map coordinates (metres) of the north-west corner of the top-left cell (not its centre).
    cell_m
        Cell size in metres (square cells).
    width, height
        Number of columns and rows.
    """

    x0: float
    y0: float
    cell_m: float
    width: int
    height: int

    @property
    def transform(self) -> tuple[float, float, float, float, float, float]:
        """GDAL/affine order ``(a, b, c, d, e, f)``: ``x = a*col + b*row + c``, ``y = d*col + e*row + f``."""
        return (self.cell_m, 0.0, self.x0, 0.0, -self.cell_m, self.y0)

    @property
    def shape(self) -> tuple[int, int]:
        return (self.height, self.width)

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the grid's outer edges."""
        return (self.x0, self.y0 - self.height * self.cell_m, self.x0 + self.width * self.cell_m, self.y0)

    def cell_centres(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(height, width)`` arrays of cell-centre x and y."""
        x = self.x0 + (np.arange(self.width) + 0.5) * self.cell_m
        y = self.y0 - (np.arange(self.height) + 0.5) * self.cell_m
        return np.meshgrid(x, y)

    def cell_of(self, x: NDArray[np.float64], y: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """(row, col) of the cells containing map points; outside the grid gives indices out of range."""
        col = np.floor((np.asarray(x) - self.x0) / self.cell_m).astype(np.int64)
        row = np.floor((self.y0 - np.asarray(y)) / self.cell_m).astype(np.int64)
        return row, col

    @classmethod
    def covering(cls, xmin: float, ymin: float, xmax: float, ymax: float, cell_m: float) -> "GridSpec":
        """The grid of ``cell_m`` cells aligned on multiples of the cell size that covers an area."""
        x0 = float(np.floor(xmin / cell_m) * cell_m)
        y0 = float(np.ceil(ymax / cell_m) * cell_m)
        return cls(x0, y0, float(cell_m), int(np.ceil((xmax - x0) / cell_m)), int(np.ceil((y0 - ymin) / cell_m)))

    def tiles(self, size: int) -> tuple[tuple[int, int, int, int], ...]:
        """``(row0, col0, height, width)`` windows of at most ``size`` cells a side covering the grid."""
        return tuple((r0, c0, min(size, self.height - r0), min(size, self.width - c0))
                     for r0 in range(0, self.height, size) for c0 in range(0, self.width, size))

    def window(self, row0: int, col0: int, height: int, width: int) -> "GridSpec":
        """The sub-grid starting at (row0, col0)."""
        return GridSpec(self.x0 + col0 * self.cell_m, self.y0 - row0 * self.cell_m, self.cell_m, int(width), int(height))


@dataclass(frozen=True)
class DsmGrid:
    """A fused digital surface model.

    Attributes
    ----------
    grid
        Where the cells are.
    frame
        ``WorldFrame.map(crs, geoid)``: the horizontal CRS and the height reference (ellipsoidal when
        ``frame.geoid`` is None, orthometric through that geoid otherwise).
    height
        ``(rows, cols)`` float32 heights in metres; NaN = no data.
    support
        ``(rows, cols)`` int16 number of stereo pairs that agree on the cell's height (0 = no data).
    spread
        ``(rows, cols)`` float32 robust spread (1.4826 x median absolute deviation) of the supporting pairs'
        heights in metres; NaN where fewer than two pairs support the cell.
    sigma
        ``(rows, cols)`` float32 predicted height precision of the fused value (metres, 1 sigma); NaN = no data.
    filled
        ``(rows, cols)`` bool: True where the height was interpolated into a hole (not measured).
    vertical_reference
        Words for the height reference, e.g. ``"ellipsoidal heights (GRS80)"`` or ``"orthometric heights,
        geoid egm96_15.gtx"``; writers put it into the file.
    """

    grid: GridSpec
    frame: WorldFrame
    height: NDArray[np.float32]
    support: NDArray[np.int16]
    spread: NDArray[np.float32]
    sigma: NDArray[np.float32]
    filled: NDArray[np.bool_]
    vertical_reference: str = ""
    metadata: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in ("height", "support", "spread", "sigma", "filled"):
            a = getattr(self, name)
            if a.shape != self.grid.shape:
                raise ValueError(f"DsmGrid.{name} has shape {a.shape}, grid is {self.grid.shape}")


@dataclass(frozen=True)
class DenseCloud:
    """A fused dense point cloud.

    Attributes
    ----------
    xyz
        ``(N, 3)`` coordinates in ``frame`` (metres).
    rgb
        ``(N, 3)`` uint8 colour sampled from the images.
    normal
        ``(N, 3)`` unit normals in the same frame's axes (east, north, up for map/local frames), pointing
        towards the cameras that saw the point.
    support
        ``(N,)`` int16 number of stereo pairs that confirm the point.
    sigma
        ``(N,)`` float32 predicted precision (metres, 1 sigma, along the viewing ray of the best pair).
    frame
        Where the coordinates are.
    vertical_reference
        As :attr:`DsmGrid.vertical_reference`.
    """

    xyz: NDArray[np.float64]
    rgb: NDArray[np.uint8]
    normal: NDArray[np.float32]
    support: NDArray[np.int16]
    sigma: NDArray[np.float32]
    frame: WorldFrame
    vertical_reference: str = ""

    def __len__(self) -> int:
        return len(self.xyz)
