"""Tracks (multi-image tie points) from pairwise matches, and thinning to a good distribution per image.

Tracks are the connected components of the graph whose nodes are (image, feature) and whose edges are
verified matches (union-find through ``scipy.sparse.csgraph.connected_components``).  A component that holds
two different features of the same image is inconsistent and dropped.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from skyrig.georef.observations import ImageMeasurements


@dataclass(frozen=True)
class Tracks:
    """Tie-point tracks as one row per observation.

    Attributes
    ----------
    track
        ``(K,)`` track id (0..T-1) of each observation.
    image
        ``(K,)`` image index.
    feature
        ``(K,)`` feature index within the image.
    n_tracks
        T.
    n_inconsistent
        Components dropped because they hold two features of one image.
    """

    track: NDArray[np.int64]
    image: NDArray[np.int64]
    feature: NDArray[np.int64]
    n_tracks: int
    n_inconsistent: int = 0

    def multiplicity(self) -> NDArray[np.int64]:
        """``(T,)`` number of images per track."""
        return np.bincount(self.track, minlength=self.n_tracks)

    def subset(self, keep_track: NDArray[np.bool_]) -> "Tracks":
        """Tracks where ``keep_track`` ``(T,)`` is true, renumbered 0..T'-1."""
        keep_track = np.asarray(keep_track, dtype=bool)
        new_id = np.cumsum(keep_track) - 1
        rows = keep_track[self.track]
        return Tracks(new_id[self.track[rows]], self.image[rows], self.feature[rows], int(keep_track.sum()),
                      self.n_inconsistent)


def build_tracks(
    n_features: Sequence[int], pair_matches: Mapping[tuple[int, int], NDArray], min_length: int = 2
) -> Tracks:
    """Union-find tracks from verified pair matches.

    Parameters
    ----------
    n_features
        Number of features of each image.
    pair_matches
        ``(i, j) -> (M, 2)`` feature index pairs (into image i, into image j).
    min_length
        Minimum number of images of a kept track.
    """
    offs = np.concatenate([[0], np.cumsum(np.asarray(n_features, dtype=np.int64))])
    total = int(offs[-1])
    a_list, b_list = [], []
    for (i, j), m in pair_matches.items():
        m = np.asarray(m, dtype=np.int64).reshape(-1, 2)
        if len(m):
            a_list.append(offs[i] + m[:, 0])
            b_list.append(offs[j] + m[:, 1])
    if not a_list or total == 0:
        return Tracks(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64), 0)
    a, b = np.concatenate(a_list), np.concatenate(b_list)
    g = coo_matrix((np.ones(len(a), np.int8), (a, b)), shape=(total, total))
    _, label = connected_components(g, directed=False)
    used = np.unique(np.concatenate([a, b]))
    lab = label[used]
    img = np.searchsorted(offs, used, side="right") - 1
    feat = used - offs[img]
    # consistency: number of distinct images == number of nodes per component
    n_nodes = np.bincount(lab)
    key = np.unique(lab * (len(offs)) + img)
    n_imgs = np.bincount(key // len(offs), minlength=len(n_nodes))
    good_comp = (n_nodes == n_imgs) & (n_nodes >= min_length)
    bad = int(np.sum((n_nodes != n_imgs) & (n_nodes > 0)))
    rows = good_comp[lab]
    _, tid = np.unique(lab[rows], return_inverse=True)
    return Tracks(tid.astype(np.int64), img[rows].astype(np.int64), feat[rows].astype(np.int64),
                  int(tid.max() + 1) if len(tid) else 0, bad)


def thin_tracks(
    tracks: Tracks, xy: Sequence[NDArray], image_sizes: Sequence[tuple[int, int]],
    cells: tuple[int, int] = (8, 8), per_cell: int = 4,
) -> Tracks:
    """Keep a good distribution: in every image, a grid of ``cells`` (columns, rows), the ``per_cell`` tracks of
    highest multiplicity per cell; a track survives if any of its images selects it.

    Parameters
    ----------
    xy
        Per image ``(N_i, 2)`` feature pixels.
    image_sizes
        Per image (width, height).
    """
    if tracks.n_tracks == 0:
        return tracks
    mult = tracks.multiplicity()
    px = np.array([xy[i][f] for i, f in zip(tracks.image, tracks.feature)]).reshape(-1, 2)
    w = np.array([image_sizes[i][0] for i in tracks.image], dtype=float)
    h = np.array([image_sizes[i][1] for i in tracks.image], dtype=float)
    cx = np.clip((px[:, 0] + 0.5) / w * cells[0], 0, cells[0] - 1).astype(np.int64)
    cy = np.clip((px[:, 1] + 0.5) / h * cells[1], 0, cells[1] - 1).astype(np.int64)
    cell = (tracks.image * cells[1] + cy) * cells[0] + cx
    # rank observations within each cell by multiplicity (desc), then track id for determinism
    order = np.lexsort((tracks.track, -mult[tracks.track], cell))
    c_sorted = cell[order]
    start = np.r_[0, np.nonzero(np.diff(c_sorted))[0] + 1]
    rank = np.arange(len(order)) - np.repeat(start, np.diff(np.r_[start, len(order)]))
    chosen = order[rank < per_cell]
    keep = np.zeros(tracks.n_tracks, bool)
    keep[tracks.track[chosen]] = True
    return tracks.subset(keep)


def tracks_to_measurements(
    tracks: Tracks, xy: Sequence[NDArray], image_names: Sequence[str], prefix: str = "t"
) -> ImageMeasurements:
    """Tracks as :class:`ImageMeasurements` (point names ``prefix + track id``, pixels in skyrig convention)."""
    px = np.array([xy[i][f] for i, f in zip(tracks.image, tracks.feature)]).reshape(-1, 2)
    names = np.array([f"{prefix}{t}" for t in tracks.track], dtype=str)
    imgs = np.array([image_names[i] for i in tracks.image], dtype=str)
    order = np.lexsort((imgs, tracks.track))
    return ImageMeasurements(names[order], imgs[order], px[order])
