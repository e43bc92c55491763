"""Tie-point statistics (points per image and pair, multiplicity) and a coverage map image."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from skyrig.match.matching import PairMatches
from skyrig.match.tracks import Tracks


def tie_point_report(
    tracks: Tracks, image_names: Sequence[str], pair_matches: Mapping[tuple[int, int], PairMatches],
) -> dict:
    """JSON-able statistics.

    Keys: ``n_images``, ``n_tracks``, ``n_observations``, ``multiplicity_histogram`` (images per point ->
    count), ``per_image`` (name -> tie points), ``images_without_ties``, ``pairs_tried``, ``pairs_matched``,
    ``per_pair`` (list of {image1, image2, inliers, putative, guided, reason}).
    """
    per_img = np.bincount(tracks.image, minlength=len(image_names))
    mult = tracks.multiplicity()
    hist = np.bincount(mult)
    pairs = [
        {"image1": image_names[i], "image2": image_names[j], "inliers": int(len(pm)), "putative": int(pm.n_putative),
         "guided": bool(pm.guided), "reason": pm.reason}
        for (i, j), pm in sorted(pair_matches.items())
    ]
    return {
        "n_images": len(image_names),
        "n_tracks": int(tracks.n_tracks),
        "n_observations": int(len(tracks.track)),
        "n_inconsistent_tracks_dropped": int(tracks.n_inconsistent),
        "mean_multiplicity": float(mult.mean()) if len(mult) else 0.0,
        "multiplicity_histogram": {int(k): int(v) for k, v in enumerate(hist) if v and k >= 2},
        "per_image": {n: int(c) for n, c in zip(image_names, per_img)},
        "images_without_ties": [n for n, c in zip(image_names, per_img) if c == 0],
        "pairs_tried": len(pair_matches),
        "pairs_matched": int(sum(1 for pm in pair_matches.values() if pm.ok)),
        "per_pair": pairs,
    }


def coverage_image(
    tracks: Tracks, xy: Sequence[NDArray], image_sizes: Sequence[tuple[int, int]],
    tile: int = 96, columns: int = 6, cells: int = 16,
) -> NDArray[np.uint8]:
    """A mosaic ``(H, W, 3)`` uint8: one tile per image, each a ``cells``-wide heat map of tie points
    (black = none, through red to yellow/white = many; the brightest cell is the block's maximum)."""
    n = len(xy)
    rows = max(1, -(-n // columns))
    grids = []
    for i in range(n):
        w, h = image_sizes[i]
        ch = max(1, round(cells * h / w))
        sel = tracks.image == i
        p = xy[i][tracks.feature[sel]] if sel.any() else np.zeros((0, 2))
        g = np.zeros((ch, cells))
        if len(p):
            cx = np.clip(((p[:, 0] + 0.5) / w * cells).astype(int), 0, cells - 1)
            cy = np.clip(((p[:, 1] + 0.5) / h * ch).astype(int), 0, ch - 1)
            np.add.at(g, (cy, cx), 1)
        grids.append(g)
    vmax = max([g.max() for g in grids] + [1.0])
    th = max(round(tile * g.shape[0] / g.shape[1]) for g in grids) if grids else tile
    out = np.full((rows * (th + 4), columns * (tile + 4), 3), 40, np.uint8)
    for i, g in enumerate(grids):
        v = np.sqrt(g / vmax)
        rgb = np.stack([np.clip(3 * v, 0, 1), np.clip(3 * v - 1, 0, 1), np.clip(3 * v - 2, 0, 1)], -1)
        ry = np.minimum((np.arange(th) * g.shape[0] / th).astype(int), g.shape[0] - 1)
        rx = np.minimum((np.arange(tile) * g.shape[1] / tile).astype(int), g.shape[1] - 1)
        img = (rgb[ry][:, rx] * 255).astype(np.uint8)
        r0, c0 = (i // columns) * (th + 4) + 2, (i % columns) * (tile + 4) + 2
        out[r0:r0 + th, c0:c0 + tile] = img
    return out
