"""Dense stage (layer 2c): stereo pair selection, epipolar rectification, semi-global matching, triangulation,
multi-view fusion into DSM grids and dense point clouds.  Arrays and orientations in, arrays out; no files."""

from skyrig.dense.grid import DenseCloud, DsmGrid, GridSpec

__all__ = ["DenseCloud", "DsmGrid", "GridSpec"]
