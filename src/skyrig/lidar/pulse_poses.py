"""Trajectory poses and beam directions of laser pulses in a local frame (the fixed data of laser observations).

Layer 2b: arrays in, arrays out.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from skyrig.georef.eo import WorldFrame
from skyrig.lidar.georef import PulseGeoreferencer, ScannerMount
from skyrig.lidar.scanner import RawScan
from skyrig.trajectory.trajectory import Trajectory

__all__ = ["local_poses", "beams"]


def local_poses(trajectory: Trajectory, frame: WorldFrame, time_s: NDArray[np.float64]
                ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """IMU positions ``(N, 3)`` and ``local_from_body`` ``(N, 3, 3)`` of a trajectory in a local ``frame``
    (a time outside the trajectory raises :class:`~skyrig.errors.OutOfRangeError` naming it)."""
    geo = PulseGeoreferencer(trajectory, ScannerMount(np.eye(3)))
    p, r = geo.poses(time_s)
    return frame.from_ecef(p), frame.tangent.ecef_from_local.T @ r


def beams(scan: RawScan, rows: NDArray[np.int64] | slice = slice(None)) -> tuple[NDArray, NDArray]:
    """Unit beams ``(n, 3)`` in the scanner frame and their derivatives by the deflection angle alpha."""
    a = scan.alpha_rad[rows]
    ca, sa = np.cos(a), np.sin(a)
    if scan.beta_rad is None:
        b = np.column_stack([ca, sa, np.zeros_like(ca)])
    else:
        cb, sb = np.cos(scan.beta_rad[rows]), np.sin(scan.beta_rad[rows])
        b = np.column_stack([cb * ca, cb * sa, sb])
    return b, np.column_stack([-b[:, 1], b[:, 0], np.zeros_like(ca)])
