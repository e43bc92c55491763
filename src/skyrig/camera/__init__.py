"""Layer 1 camera models: the photogrammetric frame camera and its distortion models."""

from skyrig.camera.distortion import Distortion, NoDistortion
from skyrig.camera.frame import FrameCamera, footprint_on_plane

__all__ = ["Distortion", "NoDistortion", "FrameCamera", "footprint_on_plane"]
