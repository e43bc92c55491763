"""Seeded synthetic blocks with known truth (for tests and benchmarks).

A block is flown in the local ENU frame: ``n_strips`` strips along +x (alternate strips fly back along
-x), one station (platform body: x forward, y right, z down) per exposure, a rig of heads
(``body_from_camera`` rotations and lever arms), object points scattered over the area with a random
relief, image measurements of every point that falls in an image, GNSS antenna positions, IMU attitudes
and control points, each with Gaussian noise of the stated sigma.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.block import Block
from skyrig.camera.frame import FrameCamera
from skyrig.errors import ConfigError
from skyrig.geometry.rotations import matrix_from_rotvec
from skyrig.rig.camera_pose import antenna_from_body_origin, world_from_camera
from skyrig.rig.rig import Rig

__all__ = ["SyntheticTruth", "synthetic_block"]


@dataclass
class SyntheticTruth:
    """The true values of a synthetic block (same layout as the :class:`Block`)."""

    station_rotation: NDArray[np.float64]
    station_centre: NDArray[np.float64]
    point_xyz: NDArray[np.float64]
    cameras: list
    lever_arm: NDArray[np.float64]
    head_boresight: NDArray[np.float64]
    datum_shift: NDArray[np.float64]


def _default_camera() -> FrameCamera:
    return FrameCamera.from_pixels("cam", 3000, 2000, 2500.0, 1499.5, 999.5, pixel_size_mm=0.004)


def _flown_heads(rig: Rig | None, cam: FrameCamera, true_camera: FrameCamera | None, true_rig: Rig | None):
    """The heads flown ``(name, camera, body_from_camera or None when actuated, lever arm)``, the head objects of
    the block's rig and of the true rig, which are actuated, and the true and given camera of each head."""
    if rig is None:
        from skyrig.rig.rig import NADIR_BODY_FROM_CAMERA

        heads = [("nadir", cam, NADIR_BODY_FROM_CAMERA, np.zeros(3))]
    else:
        heads = [(h.name, h.camera, None if h.is_actuated else h.body_from_camera_rotation(), h.lever_arm_m)  # type: ignore[misc]
                 for h in rig.heads.values()]
    head_objs = list(rig.heads.values()) if rig is not None else [None]
    true_objs = list((true_rig or rig).heads.values()) if rig is not None else [None]
    actuated = [h is not None and h.is_actuated for h in head_objs]
    true_cams = [true_camera or h[1] for h in heads] if rig is None else [h[1] for h in heads]
    given_cams = [cam] if rig is None else [h[1] for h in heads]
    return heads, head_objs, true_objs, actuated, true_cams, given_cams


def _points(rng: np.random.Generator, n_points: int, n_strips: int, n_per_strip: int, base: float, spacing: float,
            fx: float, fy: float, relief_m: float) -> tuple[NDArray[np.float64], float, float]:
    """Uniform random points over the flown area (and its half extents x, y)."""
    ext_x = (n_per_strip - 1) * base / 2 + fx / 2
    ext_y = (n_strips - 1) * spacing / 2 + fy / 2
    X = np.column_stack([rng.uniform(-ext_x, ext_x, n_points), rng.uniform(-ext_y, ext_y, n_points),
                         rng.uniform(-relief_m / 2, relief_m / 2, n_points)])
    return X, ext_x, ext_y


def _platform_observations(rng: np.random.Generator, R, C, lever, shift, gnss_sigma_m: float | None,
                           imu_sigma_rad: float | None) -> dict:
    """Noisy GNSS antenna positions and IMU attitudes of every station (None sigma: left out)."""
    S = len(C)
    block_kw: dict = {}
    if gnss_sigma_m is not None:
        ant = antenna_from_body_origin(R, C, lever) + shift
        block_kw.update(gnss_station=np.arange(S), gnss_xyz=ant + rng.normal(0, gnss_sigma_m, (S, 3)),
                        gnss_sigma=gnss_sigma_m)
    if imu_sigma_rad is not None:
        block_kw.update(imu_station=np.arange(S), imu_sigma_rad=imu_sigma_rad,
                        imu_rotation=R @ matrix_from_rotvec(rng.normal(0, imu_sigma_rad, (S, 3))))
    return block_kw


def _footprint(ref: FrameCamera, height_m: float, forward_overlap: float,
               side_overlap: float) -> tuple[float, float, float, float]:
    """The ground footprint of ``ref`` (x along track, y across), the base and the strip spacing."""
    gsd = ref.pixel_size_mm / ref.focal_mm * height_m
    fx, fy = ref.width * gsd, ref.height * gsd  # footprint: image x along track
    base = fx * (1 - forward_overlap)
    spacing = fy * (1 - side_overlap)
    return fx, fy, base, spacing


def _start_values(rng: np.random.Generator, R, C, X, perturb_pose_rad: float, perturb_pose_m: float,
                  perturb_point_m: float):
    """The true station rotations, centres and points, perturbed (Gaussian) as the block's starting values."""
    S = len(C)
    R0 = R @ matrix_from_rotvec(rng.normal(0, perturb_pose_rad, (S, 3)))
    C0 = C + rng.normal(0, perturb_pose_m, (S, 3))
    X0 = X + rng.normal(0, perturb_point_m, X.shape)
    return R0, C0, X0


def synthetic_block(
    seed: int = 0,
    n_strips: int = 2,
    n_per_strip: int = 6,
    height_m: float = 400.0,
    n_points: int = 300,
    relief_m: float = 30.0,
    rig: Rig | None = None,
    camera: FrameCamera | None = None,
    forward_overlap: float = 0.7,
    side_overlap: float = 0.4,
    sigma_px: float = 0.5,
    n_control: int = 4,
    sigma_control_m: float = 0.02,
    gnss_sigma_m: float | None = 0.05,
    imu_sigma_rad: float | None = 2e-4,
    lever_arm: NDArray[np.float64] | None = None,
    head_boresight: NDArray[np.float64] | None = None,
    datum_shift: NDArray[np.float64] | None = None,
    perturb_pose_m: float = 2.0,
    perturb_pose_rad: float = 3e-3,
    perturb_point_m: float = 1.0,
    true_camera: FrameCamera | None = None,
    beta_rad: NDArray[np.float64] | None = None,
    true_rig: Rig | None = None,
    beta_offset_rad: float = 0.0,
    beta_scale: float = 0.0,
) -> tuple[Block, SyntheticTruth]:
    """A seeded block and its truth.

    Parameters
    ----------
    rig
        Heads to fly (default: one nadir ``camera`` with the standard nadir mount).
    camera
        Camera of the single-head default, and the *assumed* camera given to the block.
    true_camera
        If given, the camera the measurements are simulated with (self-calibration tests).
    lever_arm, head_boresight, datum_shift
        True antenna lever arm (body frame), head boresight rotation vectors ``(H, 3)`` and GNSS datum
        shift; the block starts from zeros for all three.
    perturb_pose_m, perturb_pose_rad, perturb_point_m
        Sigma of the Gaussian perturbation of the starting values.
    beta_rad
        ``(S,)`` actuator angle of every station (needed when ``rig`` has actuated heads); the block
        gets it as ``image_beta_rad`` and the rig's heads as ``head_actuated``.
    true_rig
        The rig the measurements are simulated with (e.g. actuated heads with a boresight curve the
        block's rig lacks); default ``rig``.
    beta_offset_rad, beta_scale
        True actuator error: images are taken at ``(1 + beta_scale) beta + beta_offset_rad``.

    Returns
    -------
    block, truth
    """
    rng = np.random.default_rng(seed)
    cam = camera or _default_camera()
    heads, head_objs, true_objs, actuated, true_cams, given_cams = _flown_heads(rig, cam, true_camera, true_rig)
    nh = len(heads)
    fx, fy, base, spacing = _footprint(heads[0][1], height_m, forward_overlap, side_overlap)
    lever = np.zeros(3) if lever_arm is None else np.asarray(lever_arm, float)
    bore = np.zeros((nh, 3)) if head_boresight is None else np.asarray(head_boresight, float).reshape(nh, 3)
    shift = np.zeros(3) if datum_shift is None else np.asarray(datum_shift, float)

    R, C, strip, t = _stations(rng, n_strips, n_per_strip, base, spacing, height_m)
    S = len(C)
    X, ext_x, ext_y = _points(rng, n_points, n_strips, n_per_strip, base, spacing, fx, fy, relief_m)
    # images
    img_station = np.repeat(np.arange(S), nh)
    img_head = np.tile(np.arange(nh), S)
    if any(actuated) and beta_rad is None:
        raise ConfigError("synthetic_block: the rig has actuated heads; give beta_rad (one angle per station)")
    img_beta, img_rot, true_rot = _mountings(heads, head_objs, true_objs, actuated, img_station, img_head, beta_rad,
                                             beta_scale, beta_offset_rad)
    img_off = np.array([heads[h][3] for h in img_head])
    names = np.array([f"s{s:04d}_{heads[h][0]}" for s, h in zip(img_station, img_head)])
    Rc, Cc = world_from_camera(R[img_station], C[img_station], true_rot, img_off)
    Rc = Rc @ matrix_from_rotvec(bore[img_head])
    oi_a, op_a, px_a, X = _observe(rng, X, Rc, Cc, [true_cams[h] for h in img_head], sigma_px)
    P = len(X)
    ctrl = _control_points(rng, X, n_control, ext_x, ext_y)
    ctrl_xyz = X[ctrl] + rng.normal(0, sigma_control_m, (len(ctrl), 3))
    block_kw: dict = {}
    if any(actuated):
        block_kw.update(image_beta_rad=img_beta, head_actuated=[h if a else None for h, a in zip(head_objs, actuated)])
    block_kw.update(_platform_observations(rng, R, C, lever, shift, gnss_sigma_m, imu_sigma_rad))
    R0, C0, X0 = _start_values(rng, R, C, X, perturb_pose_rad, perturb_pose_m, perturb_point_m)
    block = Block(
        cameras=list(given_cams), station_name=np.array([f"s{s:04d}" for s in range(S)]), station_rotation=R0,
        station_centre=C0, station_time=np.array(t, float), station_strip=np.array(strip),
        image_name=names, image_station=img_station, image_camera=img_head, image_head=img_head,
        image_rotation=img_rot, image_offset=img_off, head_name=np.array([h[0] for h in heads]),
        point_name=np.array([f"p{k}" for k in range(P)]), point_xyz=X0, obs_image=oi_a, obs_point=op_a,
        obs_pixel=px_a, obs_sigma_px=np.asarray(sigma_px, dtype=np.float64), control_point=ctrl,
        control_xyz=ctrl_xyz,
        control_sigma=np.asarray(sigma_control_m, dtype=np.float64), frame="synthetic local ENU", **block_kw,
    )
    truth = SyntheticTruth(R, C, X, list(true_cams), lever, bore, shift)
    return block, truth


def _stations(rng: np.random.Generator, n_strips: int, n_per_strip: int, base: float, spacing: float,
              height_m: float) -> tuple[NDArray[np.float64], NDArray[np.float64], list[int], list[float]]:
    """Platform poses ``world_from_body`` and centres of strips flown alternately along +x and -x (attitudes
    perturbed by 0.01 rad), their strip indices and times."""
    R_list, C_list, strip, t = [], [], [], []
    fwd = np.array([[1.0, 0, 0], [0, -1, 0], [0, 0, -1]])  # world_from_body flying +x (body y right = -y world)
    back = np.array([[-1.0, 0, 0], [0, 1, 0], [0, 0, -1]])  # flying -x
    for s in range(n_strips):
        xs = (np.arange(n_per_strip) - (n_per_strip - 1) / 2) * base
        if s % 2:
            xs = xs[::-1]
        for j, x in enumerate(xs):
            C_list.append([x, (s - (n_strips - 1) / 2) * spacing, height_m])
            small = rng.normal(0, 0.01, 3)
            R_list.append((fwd if s % 2 == 0 else back) @ matrix_from_rotvec(small))
            strip.append(s)
            t.append(100.0 * s + 2.0 * j)
    return np.array(R_list), np.array(C_list), strip, t


def _mountings(heads: list[Any], head_objs: list[Any], true_objs: list[Any], actuated: list[bool],
               img_station: NDArray[np.int64], img_head: NDArray[np.int64], beta_rad: NDArray[np.float64] | None,
               beta_scale: float, beta_offset_rad: float
               ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Per image: the actuator angle (NaN for a fixed head), the block's (nominal) ``body_from_camera`` and the
    true one the measurements are simulated with (actuator error applied)."""
    img_beta = np.full(len(img_head), np.nan)
    img_rot = np.empty((len(img_head), 3, 3))
    true_rot = np.empty((len(img_head), 3, 3))
    for h in range(len(heads)):
        sel = img_head == h
        if actuated[h]:
            b_nom = np.asarray(beta_rad, float)[img_station[sel]]
            img_beta[sel] = b_nom
            img_rot[sel] = head_objs[h].body_from_camera_rotation(b_nom)
            true_rot[sel] = true_objs[h].body_from_camera_rotation((1 + beta_scale) * b_nom + beta_offset_rad)
        else:
            img_rot[sel] = heads[h][2]
            true_rot[sel] = heads[h][2] if head_objs[h] is None else true_objs[h].body_from_camera_rotation()
    return img_beta, img_rot, true_rot


def _observe(rng: np.random.Generator, X: NDArray[np.float64], Rc: NDArray[np.float64], Cc: NDArray[np.float64],
             cams: list[FrameCamera], sigma_px: float
             ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
    """The points ``X`` seen by every image (in front, 5 px inside the frame) with Gaussian pixel noise, keeping the
    points seen at least twice: observations' image, point (renumbered) and pixel, and the kept points."""
    n_points = len(X)
    oi, op, px = [], [], []
    for i in range(len(cams)):  # loop over images only (tens to thousands), vectorised over points
        camt = cams[i]
        pc = (X - Cc[i]) @ Rc[i]
        ok = pc[:, 2] < 0
        pix = np.full((n_points, 2), np.nan)
        pix[ok] = camt.project_pixels(pc[ok])
        vis = ok & camt.in_image(pix, margin_px=5.0)
        k = np.flatnonzero(vis)
        oi.append(np.full(k.size, i))
        op.append(k)
        px.append(pix[k])
    oi_a, op_a, px_a = np.concatenate(oi), np.concatenate(op), np.concatenate(px)
    px_a = px_a + rng.normal(0, sigma_px, px_a.shape)
    # keep points with >= 2 rays
    cnt = np.bincount(op_a, minlength=n_points)
    keep = cnt >= 2
    new_idx = np.cumsum(keep) - 1
    sel = keep[op_a]
    return oi_a[sel], new_idx[op_a[sel]], px_a[sel], X[keep]


def _control_points(rng: np.random.Generator, X: NDArray[np.float64], n_control: int, ext_x: float,
                    ext_y: float) -> NDArray[np.int64]:
    """Indices of ``n_control`` points spread over the block (closest to the corners and centre, then random)."""
    ctrl = np.zeros(0, np.int64)
    if n_control:
        anchors = np.array([[-ext_x, -ext_y], [ext_x, ext_y], [-ext_x, ext_y], [ext_x, -ext_y], [0, 0]]) * 0.7
        extra = rng.uniform([-ext_x, -ext_y], [ext_x, ext_y], (max(0, n_control - 5), 2)) * 0.8
        anchors = np.vstack([anchors, extra])[:n_control]
        d = np.linalg.norm(X[None, :, :2] - anchors[:, None, :], axis=2)
        ctrl = np.unique(np.argmin(d, axis=1))
    return ctrl
