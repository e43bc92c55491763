"""Stereo pair selection from exterior orientations.

A pair is worth matching when both images see a common part of the scene (overlap measured on the scene
box, not on image corners), look in similar directions (nadir with nadir, a north-looking oblique with
another north-looking one, whatever head took them), and intersect at an angle that gives depth without
destroying the similarity of the two views.  Each image takes part in at most ``pairs_per_image`` pairs,
chosen greedily by a score that prefers large overlap and an intersection angle near the middle of the
accepted window.

Everything is computed in a local Cartesian frame (``eo.frame`` must be ``local``: east, north, up).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np
from numpy.typing import NDArray

from skyrig.camera.frame import FrameCamera
from skyrig.errors import SkyrigError
from skyrig.georef.eo import ExteriorOrientations


@dataclass(frozen=True)
class PairConfig:
    """Which image pairs are matched.

    Attributes
    ----------
    min_overlap
        Least share of the smaller of the two images' views of the scene box that the other image sees too.
    intersection_deg
        Window ``(min, max)`` of the intersection angle of the two rays at the centre of the common area
        (degrees).  Too small: poor depth; too large: the views differ too much for area matching.
    base_height
        Window ``(min, max)`` of base length over mean viewing distance.
    max_axis_angle_deg
        Largest angle between the two optical axes (keeps nadir with nadir and obliques of one viewing
        direction together; a rig's heads pair with each other when they look the same way).
    pairs_per_image
        Budget: an image takes part in at most this many pairs.
    samples
        Pixels per image side used to measure overlap (``samples x samples`` rays).
    """

    min_overlap: float = 0.3
    intersection_deg: tuple[float, float] = (4.0, 45.0)
    base_height: tuple[float, float] = (0.05, 1.2)
    max_axis_angle_deg: float = 25.0
    pairs_per_image: int = 6
    samples: int = 12


@dataclass(frozen=True)
class StereoPair:
    """Two images to match (row indices into the orientations), ``left`` before ``right`` in the input.

    Attributes
    ----------
    left, right
        Rows of the exterior orientations.
    overlap
        Share of the smaller view both images see (0..1).
    base_m
        Distance of the projection centres (metres).
    base_height
        ``base_m`` over the mean distance to the common area.
    intersection_deg
        Intersection angle at the centre of the common area (degrees).
    centre
        ``(3,)`` centre of the common area in the local frame (metres).
    score
        Selection score (larger is better).
    """

    left: int
    right: int
    overlap: float
    base_m: float
    base_height: float
    intersection_deg: float
    centre: tuple[float, float, float]
    score: float


def ray_box_interval(origin: NDArray[np.float64], direction: NDArray[np.float64],
                     box: tuple[float, float, float, float, float, float]) -> tuple[NDArray, NDArray]:
    """Slab intersection of rays with an axis-aligned box.

    Parameters
    ----------
    origin
        ``(3,)`` or ``(N, 3)`` ray origins.
    direction
        ``(N, 3)`` ray directions (need not be unit; the returned parameters are in units of ``direction``).
    box
        ``(xmin, ymin, zmin, xmax, ymax, zmax)``.

    Returns
    -------
    t_near, t_far
        ``(N,)`` entry and exit parameters, clipped to ``t >= 0``; ``t_near > t_far`` where the ray misses.
    """
    lo = np.asarray(box[:3], dtype=np.float64)
    hi = np.asarray(box[3:], dtype=np.float64)
    d = np.asarray(direction, dtype=np.float64)
    o = np.broadcast_to(np.asarray(origin, dtype=np.float64), d.shape)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t1 = (lo - o) * inv
        t2 = (hi - o) * inv
    # a ray parallel to a slab: inside it -> (-inf, inf), outside -> empty
    par = d == 0
    inside = (o >= lo) & (o <= hi)
    t1 = np.where(par, np.where(inside, -np.inf, np.inf), t1)
    t2 = np.where(par, np.where(inside, np.inf, -np.inf), t2)
    tn = np.max(np.minimum(t1, t2), axis=-1)
    tf = np.min(np.maximum(t1, t2), axis=-1)
    return np.maximum(tn, 0.0), tf


def _view_samples(eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera], box: tuple, n: int
                  ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Per image, ``n*n`` scene points seen through a pixel grid: the middle of each ray's path in the box.

    Returns ``(N, n*n, 3)`` points and ``(N, n*n)`` validity (the ray meets the box)."""
    out = np.full((len(eo), n * n, 3), np.nan)
    ok = np.zeros((len(eo), n * n), bool)
    for i in range(len(eo)):
        cam = cameras[str(eo.camera[i])]
        c = (np.arange(n) + 0.5) / n
        cc, rr = np.meshgrid(c * cam.width - 0.5, c * cam.height - 0.5)
        rays = cam.rays_from_pixels(np.stack([cc.ravel(), rr.ravel()], axis=1)) @ eo.rotation[i].T
        tn, tf = ray_box_interval(eo.centre[i], rays, box)
        hit = tn < tf
        t = np.where(hit, 0.5 * (tn + tf), np.nan)  # the middle of the ray's path through the box
        out[i] = eo.centre[i] + rays * t[:, None]
        ok[i] = hit
    return out, ok


def select_pairs(eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera],
                 box: tuple[float, float, float, float, float, float], config: PairConfig = PairConfig()
                 ) -> list[StereoPair]:
    """Stereo pairs of a block.

    Parameters
    ----------
    eo
        Orientations in a local Cartesian frame (``eo.frame.kind == "local"``).
    cameras
        Camera name -> :class:`FrameCamera`.
    box
        Scene box ``(xmin, ymin, zmin, xmax, ymax, zmax)`` in the same frame: the region whose surface is
        wanted (for an aerial block: the area and the expected height range).
    config
        Selection windows and the per-image budget.

    Returns
    -------
    list of StereoPair
        Best first.

    Raises
    ------
    SkyrigError
        When the frame is not local.
    """
    if eo.frame.kind != "local":
        raise SkyrigError("stereo pair selection needs orientations in a local frame (call eo.to_frame first)")
    n = len(eo)
    if n < 2:
        return []
    for name in set(eo.camera.tolist()):
        if name not in cameras:
            raise SkyrigError(f"no camera {name!r} for the orientations (cameras given: {', '.join(sorted(cameras))})")
    from scipy.spatial import cKDTree

    pts, ok = _view_samples(eo, cameras, box, config.samples)
    axis = -eo.rotation[:, :, 2]  # viewing direction (camera looks along -z)
    # candidates: images whose viewed areas (centroid + radius) can touch - a KD-tree, not all n^2 pairs -
    # and that look in similar directions
    sees = ok.any(axis=1)
    cnt = np.maximum(ok.sum(axis=1), 1)[:, None]
    cen = np.where(ok[..., None], np.nan_to_num(pts), 0.0).sum(axis=1) / cnt
    rad = np.sqrt(np.max(np.where(ok, np.sum((np.nan_to_num(pts) - cen[:, None]) ** 2, axis=2), 0.0), axis=1))
    idx = np.flatnonzero(sees)
    if len(idx) < 2:
        return []
    near = cKDTree(cen[idx]).query_pairs(2.0 * float(rad[idx].max()), output_type="ndarray")
    cand = idx[near] if len(near) else np.zeros((0, 2), np.int64)
    if len(cand):
        i0, j0 = cand[:, 0], cand[:, 1]
        keep = (np.linalg.norm(cen[i0] - cen[j0], axis=1) <= rad[i0] + rad[j0]) & \
            (np.sum(axis[i0] * axis[j0], axis=1) >= np.cos(np.radians(config.max_axis_angle_deg)))
        cand = np.sort(cand[keep], axis=1)
        cand = cand[np.lexsort((cand[:, 1], cand[:, 0]))]
    out: list[StereoPair] = []
    lo_i, hi_i = np.radians(config.intersection_deg)
    seen = {int(a): pts[a][ok[a]] for a in np.unique(cand)}  # each image's view samples
    inside: dict[tuple[int, int], NDArray[np.bool_]] = {}  # (a, b): a's samples that b sees
    ends = np.concatenate([cand, cand[:, ::-1]]) if len(cand) else np.zeros((0, 2), np.int64)
    for b in np.unique(ends[:, 1]):  # one projection into each image of all its candidates' samples
        srcs = [int(a) for a in ends[ends[:, 1] == b, 0]]
        cam = cameras[str(eo.camera[b])]
        pc = (np.concatenate([seen[a] for a in srcs]) - eo.centre[b]) @ eo.rotation[b]
        ins = cam.in_image(cam.project_pixels(pc)) & (pc[:, 2] < 0)
        cut = np.cumsum([len(seen[a]) for a in srcs])[:-1]
        inside.update(((a, int(b)), part) for a, part in zip(srcs, np.split(ins, cut)))
    for i, j in cand:
        i, j = int(i), int(j)
        overlap = float(min(inside[(i, j)].mean(), inside[(j, i)].mean()))
        if overlap < config.min_overlap:
            continue
        centre = np.concatenate([seen[i][inside[(i, j)]], seen[j][inside[(j, i)]]]).mean(axis=0)
        ri, rj = centre - eo.centre[i], centre - eo.centre[j]
        cosang = ri @ rj / (np.linalg.norm(ri) * np.linalg.norm(rj))
        ang = float(np.arccos(np.clip(cosang, -1, 1)))
        base = float(np.linalg.norm(eo.centre[j] - eo.centre[i]))
        bh = base / (0.5 * (np.linalg.norm(ri) + np.linalg.norm(rj)))
        if not (lo_i <= ang <= hi_i and config.base_height[0] <= bh <= config.base_height[1]):
            continue
        mid = 0.5 * (lo_i + hi_i)
        score = overlap * (1.0 - abs(ang - mid) / (hi_i - lo_i))
        out.append(StereoPair(int(i), int(j), overlap, base, float(bh), float(np.degrees(ang)),
                              tuple(float(v) for v in centre), float(score)))
    out.sort(key=lambda p: (-p.score, p.left, p.right))
    used = np.zeros(n, int)
    chosen = []
    for p in out:
        if used[p.left] < config.pairs_per_image and used[p.right] < config.pairs_per_image:
            chosen.append(p)
            used[p.left] += 1
            used[p.right] += 1
    return chosen
