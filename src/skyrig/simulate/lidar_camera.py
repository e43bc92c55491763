"""The camera of paper 002's scanning UAV on the laser strip flight (issue 34): one platform, two sensors.

The laser strip flight of :func:`skyrig.simulate.lidar.build_lidar_survey` (``passes="strips"``) carries the
GT3300C camera of :mod:`skyrig.simulate.bridge_camera` as well, looking across the flight at the bridge.  An image
is exposed every ``image_interval_s`` on the strips; its true pose is the *true* trajectory at the exposure with the
camera's lever arm and its true mounting (the nominal mounting with the injected camera boresight
``errors.camera_boresight_rad``, a rotation vector in the camera frame: ``body_from_camera = nominal @
expmap(b)``); its recorded pose is the *recorded* trajectory (with the same per-strip errors as the laser).

Tie points are points of the bridge's surfaces (drawn as a terrestrial scan would see them) measured in every image
that sees them unoccluded (a ray cast from the projection centre), with Gaussian pixel noise.  No image is rendered:
the measurements are what matching would give with the stated noise.

Layer 2c: arrays and dataclasses in memory.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from skyrig.camera.frame import FrameCamera
from skyrig.geometry.rotations import matrix_from_rotvec
from skyrig.lidar.pulse_poses import local_poses
from skyrig.simulate.bridge_camera import _body_from_camera, gt3300c_camera
from skyrig.simulate.lidar import LidarErrors, LidarSurvey, build_lidar_survey, lidar_scenario_spec

__all__ = ["JointFlight", "build_joint_flight"]


@dataclass(frozen=True, eq=False)
class JointFlight:
    """The laser strip flight and the images of the same platform (local ENU frame of ``survey.frame``).

    Attributes
    ----------
    survey
        The laser survey (raw scans, trajectories, reference scan, injected errors).
    camera, body_from_camera, camera_lever_arm_m
        The camera, its nominal mounting and its lever arm (body frame, m).
    camera_boresight_rad
        ``(3,)`` the injected camera boresight (truth).
    image_time_s, image_strip
        ``(I,)`` exposure times and strip of each image.
    body_true_position, body_true_rotation, body_rec_position, body_rec_rotation
        ``(I, 3)`` / ``(I, 3, 3)`` true and recorded IMU poses (``local_from_body``) at the exposures.
    point_xyz
        ``(P, 3)`` true tie points.
    obs_image, obs_point, obs_pixel
        ``(N,)``, ``(N,)``, ``(N, 2)`` image measurements (column, row px) with noise ``sigma_px``.
    """

    survey: LidarSurvey
    camera: FrameCamera
    body_from_camera: NDArray[np.float64]
    camera_lever_arm_m: NDArray[np.float64]
    camera_boresight_rad: NDArray[np.float64]
    image_time_s: NDArray[np.float64]
    image_strip: NDArray[np.int64]
    body_true_position: NDArray[np.float64]
    body_true_rotation: NDArray[np.float64]
    body_rec_position: NDArray[np.float64]
    body_rec_rotation: NDArray[np.float64]
    point_xyz: NDArray[np.float64]
    obs_image: NDArray[np.int64]
    obs_point: NDArray[np.int64]
    obs_pixel: NDArray[np.float64]
    sigma_px: float

    @property
    def n_images(self) -> int:
        return len(self.image_time_s)


def build_joint_flight(size: str = "strips-ci", seed: int = 1, errors: LidarErrors | None = None,
                       image_interval_s: float = 1.0, point_density_per_m2: float = 1.5, sigma_px: float = 0.5,
                       binning: int = 4, tilt_deg: float = 15.0, min_rays: int = 3) -> JointFlight:
    """Simulate the laser strip flight (``size``: ``"strips-ci"`` or ``"strips"``) and its images.

    Deterministic for a given seed.  ``binning`` bins the GT3300C (4: 824 x 618 px); ``tilt_deg`` tilts the camera
    down from the horizontal; tie points are kept when seen in at least ``min_rays`` images.
    """
    survey = build_lidar_survey(lidar_scenario_spec(size, seed, errors))
    frame, scene = survey.frame, survey.scene
    rng = np.random.default_rng([seed, 34])
    cam = gt3300c_camera(binning)
    mount = _body_from_camera(np.radians(tilt_deg))
    lever = np.array([0.05, 0.0, 0.12])
    bore = np.asarray(survey.injected["camera_boresight_rad"], float)
    mount_true = mount @ matrix_from_rotvec(bore)
    spans = np.asarray(survey.strip_time_s)
    times, strips = [], []
    for k, (a, b) in enumerate(spans):
        t = np.arange(a + 0.25, b - 0.25, image_interval_s)
        times.append(t)
        strips.append(np.full(len(t), k, np.int64))
    t_img = np.concatenate(times)
    s_img = np.concatenate(strips)
    pt, rt = local_poses(survey.trajectory_true, frame, t_img)
    pr, rr = local_poses(survey.trajectory_recorded, frame, t_img)
    # tie points on the structure within the flown stretch (and some ground)
    lb = scene.local_from_bridge
    uv = pt[:, :2] @ lb[:2, :2]
    xyz, _ = scene.sample_surfaces(rng, point_density_per_m2, point_density_per_m2 / 3, 0.0,
                                   (float(uv[:, 0].min()) - 4.0, float(uv[:, 0].max()) + 4.0), (-25.0, 25.0))
    Rc = rt @ mount_true
    Cc = pt + np.einsum("nij,j->ni", rt, lever)
    oi, op, ox = [], [], []
    for i in range(len(t_img)):
        pc = (xyz - Cc[i]) @ Rc[i]
        px = cam.project_pixels(pc)
        ok = np.isfinite(px).all(axis=1) & cam.in_image(px, -5.0) & (np.linalg.norm(pc, axis=1) < 60.0)
        j = np.flatnonzero(ok)
        if not j.size:
            continue
        d = xyz[j] - Cc[i]
        dist = np.linalg.norm(d, axis=1)
        hit, _, _ = scene.cast(np.broadcast_to(Cc[i], (len(j), 3)), d / dist[:, None], 200.0)
        vis = np.abs(hit - dist) < 0.01
        oi.append(np.full(int(vis.sum()), i))
        op.append(j[vis])
        ox.append(px[j[vis]])
    obs_i, obs_p, obs_x = np.concatenate(oi), np.concatenate(op), np.concatenate(ox)
    rays = np.bincount(obs_p, minlength=len(xyz))
    keep_pt = rays >= min_rays
    new = np.cumsum(keep_pt) - 1
    sel = keep_pt[obs_p]
    obs_i, obs_p, obs_x = obs_i[sel], new[obs_p[sel]], obs_x[sel]
    obs_x = obs_x + rng.normal(0.0, sigma_px, obs_x.shape)
    return JointFlight(survey, cam, mount, lever, bore, t_img, s_img, pt, rt, pr, rr, xyz[keep_pt],
                       obs_i.astype(np.int64), obs_p.astype(np.int64), obs_x, float(sigma_px))

