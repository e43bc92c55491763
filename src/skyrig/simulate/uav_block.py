"""A seeded UAV image block over a flat site with known truth, for the self-calibration's determinability (issue 28).

Nadir images along straight strips (``(axis, offset_m, height_m)``: ``axis`` "x" or "y"), a stabilised gimbal
(``tilt_deg`` of wobble about nadir), ground points on a plane with ``relief_m`` of roughness, GNSS noise per axis,
0.3 px image noise; the metadata camera's focal length is ``focal_error`` x the truth's, with a prior sigma of
``prior_rel``.  Returns the block as :class:`skyrig.orient.gnss_block.UavBlockInput` and the truth.

:data:`FLAT` (one height) cannot separate the focal length from the ground's height; :data:`CROSS` (cross strips at a
second altitude) can.  Layer 2c, arrays only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numpy.typing import NDArray

from skyrig.camera.frame import FrameCamera
from skyrig.camera.opencv import OpenCVDistortion
from skyrig.georef.attitude_frames import rotation_from_gimbal_ypr
from skyrig.georef.eo import WorldFrame
from skyrig.orient.gnss_block import UavBlockInput

__all__ = ["UavBlockTruth", "flat_site_block", "FLAT", "CROSS"]

FLAT: tuple[tuple[str, float, float], ...] = (("x", -20.0, 50.0), ("x", 0.0, 50.0), ("x", 20.0, 50.0))
CROSS = FLAT + (("y", -20.0, 80.0), ("y", 0.0, 80.0), ("y", 20.0, 80.0))


@dataclass(frozen=True)
class UavBlockTruth:
    """The simulation's truth: camera, projection centres ``(I, 3)``, ``world_from_camera`` ``(I, 3, 3)``, points."""

    camera: FrameCamera
    C: NDArray[np.float64]
    R: NDArray[np.float64]
    X: NDArray[np.float64]


def flat_site_block(strips: Sequence[tuple[str, float, float]], seed: int, camera: FrameCamera, *,
                    n_points: int = 1500, relief_m: float = 0.2, tilt_deg: float = 0.2,
                    gnss_noise_m: Sequence[float] = (0.3, 0.3, 0.5), focal_error: float = 1.2,
                    prior_rel: float = 0.1, sigma_px: float = 0.3) -> tuple[UavBlockInput, UavBlockTruth]:
    """The block and its truth (module docstring); ``camera`` is the nominal camera (the truth adds a principal
    point offset of (3, -2) px and OpenCV k1 = -0.05, k2 = 0.02)."""
    rng = np.random.default_rng(seed)
    pix = camera.pixel_size_mm
    true_cam = camera.with_(ppx_mm=3 * pix, ppy_mm=-2 * pix, distortion=OpenCVDistortion(k1=-0.05, k2=0.02))
    frame = WorldFrame.local(50.85, -0.15, 120.0)
    C, ypr = [], []
    for axis, off, h in strips:
        for t in np.arange(-36.0, 36.1, 12.0):
            C.append([t, off, h] if axis == "x" else [off, t, h])
            ypr.append([90.0 if axis == "x" else 0.0, -90.0, 0.0])
    Ca = np.array(C) + rng.normal(0, 0.2, (len(C), 3))
    ypr_a = np.array(ypr)
    ypr_true = ypr_a + rng.normal(0, tilt_deg, ypr_a.shape)
    R_true = rotation_from_gimbal_ypr(frame, Ca, ypr_true)
    R_meta = rotation_from_gimbal_ypr(frame, Ca, ypr_true + rng.normal(0, 1.0, ypr_a.shape))
    xy = rng.uniform([-70, -60], [70, 60], (n_points, 2))
    X = np.column_stack([xy, rng.normal(0, relief_m, n_points)])
    ot, oi, op = [], [], []
    for i in range(len(Ca)):
        pc = (X - Ca[i]) @ R_true[i]
        front = pc[:, 2] < 0
        px = np.full((len(X), 2), -1e9)
        px[front] = true_cam.project_pixels(pc[front])
        inside = front & (px[:, 0] > 2) & (px[:, 0] < true_cam.width - 3) & (px[:, 1] > 2) & \
            (px[:, 1] < true_cam.height - 3)
        k = np.flatnonzero(inside)
        ot.append(k)
        oi.append(np.full(len(k), i))
        op.append(px[k] + rng.normal(0, sigma_px, (len(k), 2)))
    ot_a, oi_a, op_a = np.concatenate(ot), np.concatenate(oi), np.concatenate(op)
    keep = np.bincount(ot_a, minlength=n_points)[ot_a] >= 2
    gnss = Ca + rng.normal(0, 1, Ca.shape) * np.asarray(gnss_noise_m, float)
    start = camera.with_(focal_mm=camera.focal_mm * focal_error)
    names = np.array([f"IMG_{k:03d}.JPG" for k in range(len(Ca))])
    inp = UavBlockInput(names, start, gnss, R_meta, 0.0, ot_a[keep], oi_a[keep], op_a[keep],
                        np.array([f"p{k}" for k in range(n_points)]), frame,
                        intrinsic_sigma={"focal_mm": prior_rel * start.focal_mm})
    return inp, UavBlockTruth(true_cam, Ca, R_true, X)
