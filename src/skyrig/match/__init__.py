"""Tie points: features, pair selection guided by direct georeferencing, verified matching, least-squares
refinement, tracks and reports.

Modules
-------
features
    SIFT (OpenCV or pycolmap) on downscaled images / pyramids; keypoints in full-resolution skyrig pixels.
rectify
    Oblique images detected on their ground-plane rectification from the approximate orientation (exact back
    mapping of keypoints).
pairs
    Footprint-overlap pairs from exterior orientations (any nadir/oblique head mix), GPS-neighbour pairs,
    exhaustive pairs.
matching
    Ratio + mutual nearest-neighbour matching, epipolar-band guided search from predicted geometry,
    MAGSAC++ fundamental / essential verification, local affine consistency of the inliers.
lsm
    Least-squares matching (affine + radiometric) sub-pixel refinement.
tracks
    Union-find tracks, thinning per image grid cell, conversion to :class:`skyrig.georef.ImageMeasurements`.
report
    Tie-point statistics and a coverage map image.
colmap_check
    Peer cross-check: pycolmap reconstructions from skyrig's matches and from COLMAP's own pipeline.

The block-level runner (images on disk, resumable store, Dask) is :func:`skyrig.cli.match.match_images`.
"""

from skyrig.match.features import FeatureConfig, Features, extract_features
from skyrig.match.matching import MatchConfig, PairMatches, match_pair
from skyrig.match.pairs import exhaustive_pairs, footprint_pairs, gps_pairs
from skyrig.match.tracks import Tracks, build_tracks, thin_tracks, tracks_to_measurements

__all__ = [
    "FeatureConfig", "Features", "extract_features", "MatchConfig", "PairMatches", "match_pair",
    "exhaustive_pairs", "footprint_pairs", "gps_pairs", "Tracks", "build_tracks", "thin_tracks",
    "tracks_to_measurements",
]
