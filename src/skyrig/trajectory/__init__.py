"""Layer 1: GNSS/IMU trajectories (time series of positions and attitudes) and camera events."""

from skyrig.trajectory.events import CameraEvents, EventOutOfSpanError, check_events_in_span, interpolate_events
from skyrig.trajectory.trajectory import Trajectory, TrajectorySample, ecef_from_ned_rotation

__all__ = [
    "CameraEvents", "EventOutOfSpanError", "check_events_in_span", "interpolate_events",
    "Trajectory", "TrajectorySample", "ecef_from_ned_rotation",
]
