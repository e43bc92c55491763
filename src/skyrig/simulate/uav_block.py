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
from scipy.spatial.transform import Rotation

from skyrig.camera.frame import FrameCamera
from skyrig.camera.opencv import OpenCVDistortion
from skyrig.georef.attitude_frames import rotation_from_gimbal_ypr
from skyrig.georef.eo import WorldFrame
from skyrig.orient.gnss_block import UavBlockInput

__all__ = ["UavBlockTruth", "flat_site_block", "render_rolling_shutter", "FLAT", "CROSS"]

FLAT: tuple[tuple[str, float, float], ...] = (("x", -20.0, 50.0), ("x", 0.0, 50.0), ("x", 20.0, 50.0))
CROSS = FLAT + (("y", -20.0, 80.0), ("y", 0.0, 80.0), ("y", 20.0, 80.0))


@dataclass(frozen=True)
class UavBlockTruth:
    """The simulation's truth: camera, projection centres ``(I, 3)``, ``world_from_camera`` ``(I, 3, 3)``, points."""

    camera: FrameCamera
    C: NDArray[np.float64]
    R: NDArray[np.float64]
    X: NDArray[np.float64]
    #: rolling shutter (``readout_s`` > 0): linear ``v (I, 3)`` m/s and angular ``w (I, 3)`` rad/s velocity per image
    #: (world frame) and the readout time (s); see :func:`render_rolling_shutter`
    v: NDArray[np.float64] | None = None
    w: NDArray[np.float64] | None = None
    readout_s: float = 0.0


def render_rolling_shutter(camera: FrameCamera, R: NDArray[np.float64], C: NDArray[np.float64], X: NDArray[np.float64],
                           v: NDArray[np.float64], w: NDArray[np.float64], readout_s: float,
                           iterations: int = 3) -> NDArray[np.float64]:
    """Pixels ``(N, 2)`` of points ``X (N, 3)`` seen by a rolling-shutter camera (``world_from_camera`` ``R``, centre
    ``C`` at mid-exposure, velocities ``v``, ``w`` in the world frame): row ``r`` is exposed at
    ``t = (r - (rows - 1) / 2) / rows * readout_s``, when the camera is at ``C + v t`` turned to ``expmap(w t) R``.
    Each point is projected with the pose at its own row's time: row -> time -> pose -> projection, ``iterations``
    times from the mid-exposure pose (the fixed point converges by a factor ``|d row / d t| * readout / rows`` per
    step, about 0.01 for a drone).  NaN for points behind the camera."""
    t = np.zeros(len(X))
    px = np.full((len(X), 2), np.nan)
    for _ in range(iterations + 1):
        Rt = Rotation.from_rotvec(np.outer(t, w)).as_matrix() @ R
        pc = np.einsum("nji,nj->ni", Rt, X - C - np.outer(t, v))
        front = pc[:, 2] < 0
        px[:] = np.nan
        px[front] = camera.project_pixels(pc[front])
        t = np.where(front, (px[:, 1] - (camera.height - 1) / 2.0) / camera.height * readout_s, 0.0)
    return px


def flat_site_block(strips: Sequence[tuple[str, float, float]], seed: int, camera: FrameCamera, *,
                    n_points: int = 1500, relief_m: float = 0.2, tilt_deg: float = 0.2,
                    gnss_noise_m: Sequence[float] = (0.3, 0.3, 0.5), focal_error: float = 1.2,
                    prior_rel: float = 0.1, sigma_px: float = 0.3, readout_s: float = 0.0, speed_m_s: float = 10.0,
                    speed_sigma_m_s: float = 0.5, angular_sigma_rad_s: float = 0.05
                    ) -> tuple[UavBlockInput, UavBlockTruth]:
    """The block and its truth (module docstring); ``camera`` is the nominal camera (the truth adds a principal
    point offset of (3, -2) px and OpenCV k1 = -0.05, k2 = 0.02).

    With ``readout_s`` > 0 the images are rendered with a rolling shutter (:func:`render_rolling_shutter`): the
    strips are flown back and forth at ``speed_m_s`` (per image a velocity error of ``speed_sigma_m_s`` per axis,
    and an angular velocity of ``angular_sigma_rad_s`` per axis); the truth holds ``v``, ``w`` and the readout."""
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
    v = w = None
    if readout_s > 0:  # serpentine: every other strip flown backwards (the strip's images in the same order)
        k_strip = np.repeat(np.arange(len(strips)), len(C) // len(strips))
        along = np.array([[1.0, 0.0, 0.0] if s[0] == "x" else [0.0, 1.0, 0.0] for s in strips])[k_strip]
        v = along * np.where(k_strip % 2 == 0, 1.0, -1.0)[:, None] * speed_m_s
        v = v + rng.normal(0, speed_sigma_m_s, v.shape)
        w = rng.normal(0, angular_sigma_rad_s, v.shape)
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
        if v is None:
            px[front] = true_cam.project_pixels(pc[front])
        else:
            px[front] = render_rolling_shutter(true_cam, R_true[i], Ca[i], X[front], v[i], w[i], readout_s)
            front &= np.isfinite(px).all(axis=1)
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
    times = None
    if v is not None:  # capture times: 12 m apart along a strip at speed_m_s, a 20 s turn between strips
        per = len(C) // len(strips)
        k_strip = np.repeat(np.arange(len(strips)), per)
        j = np.tile(np.arange(per), len(strips))
        j = np.where(k_strip % 2 == 0, j, per - 1 - j)  # odd strips flown backwards (v points that way too)
        times = (k_strip * per + j) * 12.0 / speed_m_s + 20.0 * k_strip
    inp = UavBlockInput(names, start, gnss, R_meta, 0.0, ot_a[keep], oi_a[keep], op_a[keep],
                        np.array([f"p{k}" for k in range(n_points)]), frame,
                        intrinsic_sigma={"focal_mm": prior_rel * start.focal_mm}, times_s=times)
    return inp, UavBlockTruth(true_cam, Ca, R_true, X, v, w, float(readout_s))
