"""Orientation of image blocks (layer 2b): triangulation, space resection, strip detection, similarity fits and
the incremental GNSS-supported orientation of a UAV block.  Arrays in, arrays out; no file is opened here
(:mod:`skyrig.pipeline.uav` is the file-level wrapper behind ``skyrig adjust-uav``).

Modules
-------
triangulation
    :func:`triangulate_tracks` (multi-view midpoint with depth / angle checks), :func:`resect` (EPnP RANSAC + LM).
strips
    :func:`detect_strips` from a sequence of GNSS positions.
similarity
    :func:`robust_similarity` (trimmed Umeyama), :func:`compare_with_reconstruction`.
gnss_block
    :class:`UavConfig`, :class:`UavBlockInput`, :class:`UavResult`, :func:`attitude_agreement`,
    :func:`adjust_uav_block` (seed from trusted attitudes or a two-view relative orientation, growth,
    self-calibrating final adjustment).
incremental
    :class:`OrientConfig`, :class:`OrientInput`, :func:`orient_incremental`: orientation without GNSS (two-view
    start chosen by inliers and parallax, resection, periodic bundle adjustment; datum from control points, scale
    bars, a similarity onto approximate positions, or inner constraints) for terrestrial, close-range, UAV and
    aerial sets.
reference
    :func:`pycolmap_from_tracks`, :func:`compare_on_same_tracks`: a peer orientation (COLMAP's incremental mapper,
    pycolmap) of the very tie points skyrig oriented (no image needed).
"""

from skyrig.orient.gnss_block import (
    UavAdjustError, UavBlockInput, UavConfig, UavResult, adjust_uav_block, attitude_agreement,
)
from skyrig.orient.incremental import OrientConfig, OrientError, OrientInput, choose_seed_pair, orient_incremental
from skyrig.orient.reference import PeerOrientation, compare_on_same_tracks, pycolmap_from_tracks
from skyrig.orient.similarity import compare_with_reconstruction, robust_similarity
from skyrig.orient.strips import detect_strips
from skyrig.orient.triangulation import resect, triangulate_tracks

__all__ = ["UavAdjustError", "UavBlockInput", "UavConfig", "UavResult", "adjust_uav_block", "attitude_agreement",
           "compare_with_reconstruction", "robust_similarity", "detect_strips", "resect", "triangulate_tracks",
           "OrientConfig", "OrientError", "OrientInput", "choose_seed_pair", "orient_incremental",
           "PeerOrientation", "compare_on_same_tracks", "pycolmap_from_tracks"]
