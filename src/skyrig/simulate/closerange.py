"""A simulated terrestrial / close-range image set: a façade with relief photographed from the ground by convergent
images, with coded targets (control points) and scale bars, measured by exact projection plus noise.

For the geometry of orientation without GNSS (:mod:`skyrig.orient.incremental`): no pixels are rendered, the tie
points are the projections of the scene points (Gaussian noise, a share of gross mismatches).  World frame:
x along the façade, y away from it (towards the cameras is -y), z up, metres; the façade face is y = 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from skyrig.camera.frame import FrameCamera
from skyrig.camera.opencv import OpenCVDistortion

__all__ = ["CloseRangeSet", "facade_set"]


@dataclass
class CloseRangeSet:
    """A simulated set: truth and measurements.

    Attributes
    ----------
    names, camera
        ``(I,)`` image names and the true camera (the start camera of a run should differ from it).
    R, C
        ``(I, 3, 3)`` true ``world_from_camera`` and ``(I, 3)`` projection centres.
    point_name, X
        ``(P,)`` names and ``(P, 3)`` true points (tie points, then targets).
    obs_point, obs_image, obs_pixel
        Measurements ``(N,)``, ``(N,)``, ``(N, 2)`` px (noise and mismatches included).
    target_names
        Names of the coded targets (control points) among ``point_name``.
    bars
        ``(D, 2)`` names of scale-bar ends and ``bar_length`` ``(D,)`` true lengths (m).
    """

    names: NDArray[np.str_]
    camera: FrameCamera
    R: NDArray[np.float64]
    C: NDArray[np.float64]
    point_name: NDArray[np.str_]
    X: NDArray[np.float64]
    obs_point: NDArray[np.int64]
    obs_image: NDArray[np.int64]
    obs_pixel: NDArray[np.float64]
    target_names: NDArray[np.str_]
    bars: NDArray[np.str_]
    bar_length: NDArray[np.float64]


def _look_at(C: NDArray, target: NDArray, roll_deg: float) -> NDArray[np.float64]:
    """``world_from_camera`` of a camera at ``C`` looking at ``target`` (skyrig camera: x right, y up, z back),
    rolled by ``roll_deg`` about its viewing axis."""
    back = C - target
    back = back / np.linalg.norm(back)
    right = np.cross([0.0, 0.0, 1.0], back)
    right /= np.linalg.norm(right)
    up = np.cross(back, right)
    r = np.radians(roll_deg)
    x = np.cos(r) * right + np.sin(r) * up
    y = -np.sin(r) * right + np.cos(r) * up
    return np.column_stack([x, y, back])


def facade_set(seed: int = 1, n_points: int = 1500, sigma_px: float = 0.5, outlier_share: float = 0.01,
               width_px: int = 1500, n_per_row: int = 9) -> CloseRangeSet:
    """A 24 m x 12 m façade (windows recessed 0.3 m, pillars and balconies standing 0.5-1.2 m out, ground in
    front) seen by two rows of convergent images (``n_per_row`` each, 1.6 m and 7 m high, on an arc 14-18 m away,
    every third image rolled 90 deg), 10 coded targets on the façade and two 2 m scale bars on the ground."""
    rng = np.random.default_rng(seed)
    h = int(round(width_px * 2 / 3))
    pix = 0.0039 * 6000 / width_px
    cam = FrameCamera("closerange", width_px, h, pix, 0.8 * width_px * pix, ppx_mm=6 * pix, ppy_mm=-4 * pix,
                      distortion=OpenCVDistortion(k1=-0.08, k2=0.04, p1=2e-4, p2=-1e-4))
    # scene points: façade face with relief, and the ground in front
    nf = int(0.85 * n_points)
    x = rng.uniform(-12, 12, nf)
    z = rng.uniform(0.2, 12, nf)
    y = np.zeros(nf)
    window = (np.mod(x, 4.0) > 1.0) & (np.mod(x, 4.0) < 3.0) & (np.mod(z, 3.5) > 1.0) & (np.mod(z, 3.5) < 2.8)
    y[window] = 0.3
    pillar = np.mod(x + 0.4, 8.0) < 0.8
    y[pillar] = -0.5
    balcony = (np.abs(np.mod(z, 3.5) - 0.9) < 0.25) & (np.abs(x) < 6)
    y[balcony] = -1.2
    ng = n_points - nf
    ground = np.column_stack([rng.uniform(-12, 12, ng), rng.uniform(-8, -0.2, ng), rng.normal(0, 0.05, ng)])
    tie = np.vstack([np.column_stack([x, y, z]), ground])
    targets = np.array([[-10, 0, 1.5], [-10, 0, 10.5], [10, 0, 1.5], [10, 0, 10.5], [0, 0, 6.0], [-5, 0, 4.0],
                        [5, 0, 8.0], [-4.4, -0.5, 3.0], [3.6, -0.5, 9.0], [0, -1.2, 4.4]], float)
    bar_ends = np.array([[-4, -4, 0.0], [-2, -4, 0.0], [3, -5, 0.0], [3, -3, 0.0]], float)
    X = np.vstack([tie, targets, bar_ends])
    names_pt = np.array([f"t{k}" for k in range(len(tie))] + [f"GCP{k + 1}" for k in range(len(targets))]
                        + ["bar1a", "bar1b", "bar2a", "bar2b"])
    # cameras: two rows on an arc, convergent towards the façade centre
    C, R = [], []
    for row, zc in enumerate((1.6, 7.0)):
        for k, az in enumerate(np.linspace(-50, 50, n_per_row)):
            d = rng.uniform(14, 18)
            a = np.radians(az + rng.normal(0, 2))
            Ck = np.array([d * np.sin(a), -d * np.cos(a), zc + rng.normal(0, 0.2)])
            target = np.array([rng.normal(0, 2), 0.0, 5.0 + rng.normal(0, 1)])
            roll = 90.0 if (k + row) % 3 == 0 else rng.normal(0, 3)
            C.append(Ck)
            R.append(_look_at(Ck, target, roll))
    C, R = np.array(C), np.array(R)
    ot, oi, op = [], [], []
    for i in range(len(C)):
        pc = (X - C[i]) @ R[i]
        front = pc[:, 2] < -0.5
        px = np.full((len(X), 2), np.nan)
        px[front] = cam.project_pixels(pc[front])
        ok = front & cam.in_image(np.nan_to_num(px, nan=-1e9), margin_px=-2)
        k = np.flatnonzero(ok)
        ot.append(k)
        oi.append(np.full(len(k), i))
        op.append(px[k] + rng.normal(0, sigma_px, (len(k), 2)))
    ot, oi, op = np.concatenate(ot), np.concatenate(oi), np.concatenate(op)
    bad = np.flatnonzero(rng.random(len(ot)) < outlier_share)
    bad = bad[ot[bad] < len(tie)]  # targets are measured without blunders
    op[bad] += rng.uniform(10, 40, (len(bad), 2)) * rng.choice([-1, 1], (len(bad), 2))
    keep = np.bincount(ot, minlength=len(X))[ot] >= 2
    names = np.array([f"IMG_{k:03d}.JPG" for k in range(len(C))])
    bars = np.array([["bar1a", "bar1b"], ["bar2a", "bar2b"]])
    bl = np.linalg.norm(bar_ends[[0, 2]] - bar_ends[[1, 3]], axis=1)
    return CloseRangeSet(names, cam, R, C, names_pt, X, ot[keep], oi[keep], op[keep],
                         names_pt[len(tie):len(tie) + len(targets)], bars, bl)
