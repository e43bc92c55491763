"""Layer 1 rigs: the platform (IMU body) frame, camera heads with lever arms, mountings and boresight
misalignments, the GNSS antenna lever arm, actuated (tumbling) heads and presets of published systems."""

from skyrig.rig.boresight_curve import AXES, BoresightCurve, Repeatability, wrap_2pi
from skyrig.rig.presets import PRESETS, UnknownPresetError, dlr_3k, macs_tumblecam, midas, preset, uav_single
from skyrig.rig.rig import (
    NADIR_BODY_FROM_CAMERA,
    VIEW_DIRECTION_CAMERA,
    ActuatedHead,
    Head,
    HeadNotFoundError,
    Rig,
    boresight_from_opk,
    mounting_from_rpy,
    oblique_mounting,
    rpy_from_mounting,
    tumble_angles,
)

__all__ = [
    "AXES", "BoresightCurve", "Repeatability", "wrap_2pi",
    "PRESETS", "UnknownPresetError", "dlr_3k", "macs_tumblecam", "midas", "preset", "uav_single",
    "NADIR_BODY_FROM_CAMERA", "VIEW_DIRECTION_CAMERA", "ActuatedHead", "Head", "HeadNotFoundError", "Rig",
    "boresight_from_opk", "mounting_from_rpy", "oblique_mounting", "rpy_from_mounting", "tumble_angles",
]
