"""Layer 1 camera models: the photogrammetric frame camera and its distortion models.

* :mod:`skyrig.camera.frame`: :class:`FrameCamera` (conventions of image, pixel and camera frames),
  ground sampling and footprints on planes and surfaces.
* :mod:`skyrig.camera.distortion`: the :class:`Distortion` interface and the model registry.
* :mod:`skyrig.camera.brown`: Brown / Australis (K1 K2 K3 P1 P2 B1 B2, mm-based).
* :mod:`skyrig.camera.opencv`: OpenCV radial-tangential and rational models.
* :mod:`skyrig.camera.forward`: distortion at the ideal point (balanced radial K1..K4 with R0, distortion
  centre, decentring, affinity, shear), as calibration reports and other bundle programs give it.
* :mod:`skyrig.camera.agisoft`: Agisoft Metashape's frame model (K1..K4, P1 P2 in Metashape's order, B1 B2).
* :mod:`skyrig.camera.convert`: :func:`convert_camera`, a least-squares fit of one model to another over
  the whole frame, with its residual.
* :mod:`skyrig.camera.jacobians`: projection with analytic Jacobians for bundle adjustment.
"""

from skyrig.camera.distortion import (
    CorrectionModel,
    Distortion,
    NoDistortion,
    distortion_class,
    distortion_from_dict,
    distortion_models,
    register_distortion,
)
# The shipped models register themselves (register_distortion) when imported, here, so that the registry is
# full whenever skyrig.camera (or any module of it) is imported; distortion.py itself imports none of them.
from skyrig.camera.brown import BrownDistortion
from skyrig.camera.opencv import OpenCVDistortion, OpenCVRationalDistortion
from skyrig.camera.forward import ForwardDistortion
from skyrig.camera.agisoft import AgisoftDistortion
from skyrig.camera.frame import (
    FrameCamera,
    GroundSampling,
    HeightFunction,
    footprint_on_plane,
    footprint_on_surface,
    intersect_rays_with_surface,
)
from skyrig.camera.jacobians import JACOBIAN_KINDS, project_camera_with_jacobians, project_with_jacobians
from skyrig.camera.convert import ConversionReport, RegionResidual, compare_cameras, convert_camera

__all__ = [
    "CorrectionModel", "Distortion", "NoDistortion", "distortion_class", "distortion_from_dict", "distortion_models",
    "register_distortion", "BrownDistortion", "OpenCVDistortion", "OpenCVRationalDistortion", "ForwardDistortion", "AgisoftDistortion", "FrameCamera",
    "GroundSampling", "HeightFunction", "footprint_on_plane", "footprint_on_surface", "intersect_rays_with_surface",
    "JACOBIAN_KINDS", "project_camera_with_jacobians", "project_with_jacobians", "ConversionReport", "RegionResidual",
    "compare_cameras", "convert_camera",
]
