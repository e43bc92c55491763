"""Terrain products (layer 2c, arrays in and out): ground classification (the cloth simulation filter) and ASPRS
classes, the DTM and normalised DSM, contour lines, cut/fill volumes.  Files are read and written by
:mod:`skyrig.io.terrain_files`; ``skyrig terrain`` is the command line."""

from skyrig.terrain.classify import (ASPRS_NAMES, Classification, ClassRules, GroundFilter, classify_points,
                                     csf_ground)
from skyrig.terrain.contours import Contours, make_contours
from skyrig.terrain.dtm import DTM_SOURCE, DtmGrid, make_dtm, normalised_dsm, sample_surface
from skyrig.terrain.volume import VolumeResult, base_from_points, cut_fill, plane_base

__all__ = ["ASPRS_NAMES", "Classification", "ClassRules", "GroundFilter", "classify_points", "csf_ground",
           "Contours", "make_contours", "DTM_SOURCE", "DtmGrid", "make_dtm", "normalised_dsm", "sample_surface",
           "VolumeResult", "base_from_points", "cut_fill", "plane_base"]
