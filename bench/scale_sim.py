"""A lean seeded penta-rig (MIDAS) block for ``bench/scale.py``: the simulation model of
:func:`skyrig.adjust.synthetic.synthetic_block` (same flight plan, noise and perturbations), generated in
time and memory linear in the block.

``synthetic_block`` projects every object point into every image (images x points: 2 x 10^10 projections
at 10,000 exposures, hours); here the points are binned in rows of ``cell`` metres across the block and
sorted along it, and each image projects only the points inside the ground bounding box of its footprint
(its corner rays cut with the lowest and highest terrain plane).  The truth kept is what the bench
compares against (the station centres); the block holds nothing else than ``synthetic_block``'s does.

The random stream differs from ``synthetic_block``'s, so the blocks are statistically alike, not equal
(at 506 exposures: same number of points after the two-ray filter within 0.5 %, same observations per
point; see ``bench/scale_profile.py``).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.block import Block
from skyrig.geometry.rotations import matrix_from_rotvec
from skyrig.rig.rig import Rig

__all__ = ["penta_block"]


def _footprint_bbox(cam, Rc: NDArray[np.float64], Cc: NDArray[np.float64], zlo: float, zhi: float,
                    margin: float) -> tuple[float, float, float, float] | None:
    """Ground bounding box ``(xmin, xmax, ymin, ymax)`` of an image between the planes ``zlo`` and ``zhi``."""
    d = cam.rays_from_pixels(cam.corner_pixels()) @ Rc.T  # world directions of the corner rays
    if not np.all(d[:, 2] < -1e-6):
        return None  # a corner above the horizon: no bounded footprint (not the case for MIDAS at 45 deg)
    pts = []
    for z in (zlo, zhi):
        t = (z - Cc[2]) / d[:, 2]
        pts.append(Cc[None, :2] + t[:, None] * d[:, :2])
    p = np.vstack(pts)
    return p[:, 0].min() - margin, p[:, 0].max() + margin, p[:, 1].min() - margin, p[:, 1].max() + margin


def penta_block(seed: int, n_strips: int, n_per_strip: int, n_points: int, rig: Rig, height_m: float = 500.0,
                relief_m: float = 30.0, forward_overlap: float = 0.7, side_overlap: float = 0.4,
                sigma_px: float = 0.5, n_control: int = 9, sigma_control_m: float = 0.02,
                gnss_sigma_m: float = 0.05, imu_sigma_rad: float = 2e-4, perturb_pose_m: float = 2.0,
                perturb_pose_rad: float = 3e-3, perturb_point_m: float = 1.0, cell: float = 100.0
                ) -> tuple[Block, NDArray[np.float64]]:
    """A seeded rig block with GNSS and IMU; ``(block, true station centres (S, 3))``.

    Parameters as :func:`skyrig.adjust.synthetic.synthetic_block` (zero lever arm, boresights and datum
    shift, no actuated heads); ``cell``: the width (m) of the point rows of the spatial index.
    """
    rng = np.random.default_rng(seed)
    heads = list(rig.heads.values())
    if any(h.is_actuated for h in heads):
        raise ValueError("penta_block: actuated heads are not simulated here (use synthetic_block)")
    nh = len(heads)
    ref = heads[0].camera
    gsd = ref.pixel_size_mm / ref.focal_mm * height_m
    fx, fy = ref.width * gsd, ref.height * gsd
    base, spacing = fx * (1 - forward_overlap), fy * (1 - side_overlap)
    # stations, as synthetic_block
    fwd = np.array([[1.0, 0, 0], [0, -1, 0], [0, 0, -1]])
    back = np.array([[-1.0, 0, 0], [0, 1, 0], [0, 0, -1]])
    S = n_strips * n_per_strip
    strip = np.repeat(np.arange(n_strips), n_per_strip)
    j = np.tile(np.arange(n_per_strip), n_strips)
    xs = (j - (n_per_strip - 1) / 2) * base
    xs = np.where(strip % 2 == 1, -xs, xs)  # odd strips fly back
    C = np.column_stack([xs, (strip - (n_strips - 1) / 2) * spacing, np.full(S, height_m)])
    R = np.where((strip % 2 == 0)[:, None, None], fwd, back) @ matrix_from_rotvec(rng.normal(0, 0.01, (S, 3)))
    t = 100.0 * strip + 2.0 * j
    # points, binned in rows across the block (y) and sorted along it (x)
    ext_x = (n_per_strip - 1) * base / 2 + fx / 2
    ext_y = (n_strips - 1) * spacing / 2 + fy / 2
    X = np.column_stack([rng.uniform(-ext_x, ext_x, n_points), rng.uniform(-ext_y, ext_y, n_points),
                         rng.uniform(-relief_m / 2, relief_m / 2, n_points)])
    n_rows = max(1, int(np.ceil(2 * ext_y / cell)))
    prow = np.clip(((X[:, 1] + ext_y) / cell).astype(np.int64), 0, n_rows - 1)
    order = np.lexsort((X[:, 0], prow))
    X = X[order]
    prow = prow[order]
    row_ptr = np.searchsorted(prow, np.arange(n_rows + 1))
    # images
    img_station = np.repeat(np.arange(S), nh)
    img_head = np.tile(np.arange(nh), S)
    mount = [h.body_from_camera_rotation() for h in heads]
    img_rot = np.stack([mount[h] for h in img_head])
    img_off = np.stack([np.asarray(heads[h].lever_arm_m, float) for h in img_head])
    oi, op, px = [], [], []
    margin = 5.0 * gsd * 4  # slack for the 5-pixel margin of the oblique far field
    for i in range(S * nh):
        h = img_head[i]
        s_ = img_station[i]
        cam = heads[h].camera
        Rc = R[s_] @ mount[h]
        Cc = C[s_] + R[s_] @ img_off[i]
        bb = _footprint_bbox(cam, Rc, Cc, -relief_m / 2, relief_m / 2, margin)
        if bb is None:
            raise ValueError(f"penta_block: head {heads[h].name!r} sees the horizon; no bounded footprint")
        r0 = int(np.clip(np.floor((bb[2] + ext_y) / cell), 0, n_rows - 1))
        r1 = int(np.clip(np.floor((bb[3] + ext_y) / cell), 0, n_rows - 1))
        cand = []
        for r in range(r0, r1 + 1):
            a, b = row_ptr[r], row_ptr[r + 1]
            lo = a + np.searchsorted(X[a:b, 0], bb[0])
            hi = a + np.searchsorted(X[a:b, 0], bb[1], side="right")
            if hi > lo:
                cand.append(np.arange(lo, hi))
        if not cand:
            continue
        k = np.concatenate(cand)
        pc = (X[k] - Cc) @ Rc
        ok = pc[:, 2] < 0
        k, pc = k[ok], pc[ok]
        pix = cam.project_pixels(pc)
        vis = cam.in_image(pix, margin_px=5.0)
        oi.append(np.full(int(vis.sum()), i, np.int64))
        op.append(k[vis])
        px.append(pix[vis])
    oi_a, op_a, px_a = np.concatenate(oi), np.concatenate(op), np.concatenate(px)
    del oi, op, px
    px_a += rng.normal(0, sigma_px, px_a.shape)
    # points with >= 2 rays, observations in image order (as synthetic_block)
    keep = np.bincount(op_a, minlength=n_points) >= 2
    new_idx = np.cumsum(keep) - 1
    sel = keep[op_a]
    oi_a, op_a, px_a = oi_a[sel], new_idx[op_a[sel]], px_a[sel]
    X = X[keep]
    P = len(X)
    # control: the points closest to the corners and the centre, then random ones
    anchors = np.array([[-ext_x, -ext_y], [ext_x, ext_y], [-ext_x, ext_y], [ext_x, -ext_y], [0, 0]]) * 0.7
    extra = rng.uniform([-ext_x, -ext_y], [ext_x, ext_y], (max(0, n_control - 5), 2)) * 0.8
    anchors = np.vstack([anchors, extra])[:n_control]
    ctrl = np.unique([int(np.argmin(((X[:, :2] - a) ** 2).sum(axis=1))) for a in anchors]).astype(np.int64)
    ctrl_xyz = X[ctrl] + rng.normal(0, sigma_control_m, (len(ctrl), 3))
    R0 = R @ matrix_from_rotvec(rng.normal(0, perturb_pose_rad, (S, 3)))
    C0 = C + rng.normal(0, perturb_pose_m, (S, 3))
    X0 = X + rng.normal(0, perturb_point_m, X.shape)
    block = Block(
        cameras=[h.camera for h in heads], station_name=np.array([f"s{s:05d}" for s in range(S)]),
        station_rotation=R0, station_centre=C0, station_time=t, station_strip=strip,
        image_name=np.array([f"s{s:05d}_{heads[h].name}" for s, h in zip(img_station, img_head)]),
        image_station=img_station, image_camera=img_head, image_head=img_head, image_rotation=img_rot,
        image_offset=img_off, head_name=np.array([h.name for h in heads]),
        point_name=np.array([f"p{k}" for k in range(P)]), point_xyz=X0, obs_image=oi_a, obs_point=op_a,
        obs_pixel=px_a, obs_sigma_px=sigma_px, control_point=ctrl, control_xyz=ctrl_xyz,
        control_sigma=sigma_control_m, frame="synthetic local ENU",
        gnss_station=np.arange(S), gnss_xyz=C + rng.normal(0, gnss_sigma_m, (S, 3)), gnss_sigma=gnss_sigma_m,
        imu_station=np.arange(S), imu_sigma_rad=imu_sigma_rad,
        imu_rotation=R @ matrix_from_rotvec(rng.normal(0, imu_sigma_rad, (S, 3))),
    )
    return block, C
