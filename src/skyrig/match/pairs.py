"""Which image pairs to match.

* :func:`footprint_pairs` — guided by direct georeferencing: a grid of pixels of each image is intersected with
  the terrain (a DEM-like height function or a mean height), and a pair is kept when enough of one image's
  ground samples fall inside the other image (in front of it).  Works for any mix of nadir and oblique heads
  (nadir-oblique and oblique-oblique pairs across heads and strips).  Candidates come from a KD-tree over
  footprint centres, so the cost grows linearly with the block, not quadratically.
* :func:`gps_pairs` — fallback when only EXIF exists: k nearest projection centres (plus an optional radius),
  dropping pairs whose viewing headings differ too much.
* :func:`exhaustive_pairs` — every pair, the reference.
* :func:`budget_pairs` — a per-image pair budget for wide blocks (the strongest-overlap pairs of each image,
  the graph kept connected and every kind of link - other head, other strip - kept where one exists), so that
  the number of pairs grows linearly with the block, not with the footprint reach of its obliques.
* :func:`image_strips` — flight strips of the images (event times), for ``budget_pairs``' cross-strip links.

Pairs are ``(P, 2)`` int arrays with ``i < j``, sorted.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, minimum_spanning_tree
from scipy.spatial import cKDTree

from skyrig.camera.frame import FrameCamera, intersect_rays_with_surface
from skyrig.errors import ConfigError, GeometryError
from skyrig.georef.eo import ExteriorOrientations

HeightFunction = Callable[[NDArray[np.float64], NDArray[np.float64]], NDArray[np.float64]]


def _unique_pairs(pairs: NDArray) -> NDArray[np.int64]:
    p = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    p = np.sort(p, axis=1)
    p = p[p[:, 0] != p[:, 1]]
    if len(p) == 0:
        return np.zeros((0, 2), np.int64)
    return np.unique(p, axis=0)


def exhaustive_pairs(n: int) -> NDArray[np.int64]:
    """All ``n (n - 1) / 2`` pairs ``(P, 2)``."""
    i, j = np.triu_indices(int(n), k=1)
    return np.column_stack([i, j]).astype(np.int64)


def gps_pairs(
    centres: NDArray, k: int = 8, radius_m: float | None = None,
    heading_deg: NDArray | None = None, max_heading_diff_deg: float | None = None,
) -> NDArray[np.int64]:
    """Pairs of each image with its ``k`` nearest neighbours by projection centre (and all within ``radius_m``).

    Parameters
    ----------
    centres
        ``(N, 3)`` (or ``(N, 2)``) positions in metres (a local ENU or map frame, not degrees).
    k
        Neighbours per image.
    radius_m
        Also pair all images closer than this.
    heading_deg, max_heading_diff_deg
        ``(N,)`` viewing headings (NaN = unknown) and a limit: pairs with both known and differing by more than
        the limit are dropped.  Off by default: phone compasses (lund: 21 deg accuracy) and even DJI gimbal yaws
        (brighton strip 2: 180 deg off) are not reliable enough to drop pairs on.
    """
    c = np.asarray(centres, dtype=np.float64)
    n = len(c)
    if n < 2:
        return np.zeros((0, 2), np.int64)
    tree = cKDTree(c)
    kk = min(k + 1, n)
    _, idx = tree.query(c, k=kk)
    pairs = [np.column_stack([np.repeat(np.arange(n), kk - 1), idx[:, 1:].reshape(-1)])]
    if radius_m is not None:
        pairs.append(tree.query_pairs(radius_m, output_type="ndarray"))
    p = _unique_pairs(np.concatenate(pairs))
    if heading_deg is not None and max_heading_diff_deg is not None and len(p):
        h = np.asarray(heading_deg, dtype=np.float64)
        d = np.abs((h[p[:, 0]] - h[p[:, 1]] + 180.0) % 360.0 - 180.0)
        p = p[~(d > max_heading_diff_deg)]  # NaN compares False: unknown headings keep the pair
    return p


def ground_samples(
    camera: FrameCamera, world_from_camera: "object", height: float | HeightFunction, grid: int = 9,
    max_distance_m: float | None = None,
) -> NDArray[np.float64]:
    """Ground points ``(M, 3)`` of a ``grid x grid`` lattice of pixels (rays that miss the terrain are dropped).

    ``height`` is a constant terrain height or a function ``z = h(x, y)`` (e.g. ``Dem.sample``).
    ``max_distance_m`` drops ground points farther than this from the projection centre (near-horizon rays
    of oblique heads).
    """
    g = (np.arange(grid) + 0.5) / grid
    px = np.stack(np.meshgrid(g * camera.width - 0.5, g * camera.height - 0.5), -1).reshape(-1, 2)
    d = world_from_camera.rotate(camera.rays_from_pixels(px))  # type: ignore[attr-defined]
    c = np.broadcast_to(world_from_camera.translation, d.shape)  # type: ignore[attr-defined]
    if callable(height):
        out = np.full(d.shape, np.nan)
        down = d[:, 2] < 0
        if down.any():
            try:
                out[down] = intersect_rays_with_surface(c[down], d[down], height,
                                                        max_distance_m=max_distance_m or 1e6)
            except GeometryError:
                for r in np.nonzero(down)[0]:  # some rays miss: intersect one by one, keep the good ones
                    try:
                        out[r] = intersect_rays_with_surface(c[r:r + 1], d[r:r + 1], height,
                                                             max_distance_m=max_distance_m or 1e6)[0]
                    except GeometryError:
                        pass
    else:
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (float(height) - c[:, 2]) / d[:, 2]
        t = np.where(t > 0, t, np.nan)
        out = c + t[:, None] * d
    ok = np.all(np.isfinite(out), axis=1)
    if max_distance_m is not None:
        ok &= np.linalg.norm(out - c, axis=1) <= max_distance_m
    return out[ok]


def footprint_pairs(
    eo: ExteriorOrientations,
    cameras: Mapping[str, FrameCamera],
    height: float | HeightFunction,
    min_overlap: float = 0.05,
    max_view_angle_deg: float = 75.0,
    grid: int = 9,
    max_distance_m: float | None = None,
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Image pairs whose terrain footprints overlap, predicted from exterior orientations.

    Parameters
    ----------
    eo
        Approximate exterior orientations in a frame with z vertical (map grid with heights, or local ENU).
    cameras
        Camera name -> :class:`FrameCamera` (``eo.camera`` names).
    height
        Mean terrain height (same frame) or a height function ``z = h(x, y)`` (a DEM's ``sample``).
    min_overlap
        Keep a pair when the larger of the two fractions "ground samples of image a seen by image b" reaches this.
    max_view_angle_deg
        Drop pairs whose optical axes differ by more than this (e.g. forward- vs backward-looking obliques,
        whose views of the ground are too different for SIFT).
    grid
        Pixels per image side sampled.
    max_distance_m
        Ignore ground points farther than this from the camera (default: 20 x the median flying height).

    Returns
    -------
    pairs
        ``(P, 2)`` image-row pairs ``i < j``.
    overlap
        ``(P,)`` the overlap fraction of each pair.

    Raises
    ------
    GeometryError
        An image's footprint does not reach the terrain at all.
    """
    n = len(eo)
    if n < 2:
        return np.zeros((0, 2), np.int64), np.zeros(0)
    pose = eo.pose()
    if not np.all(np.isfinite(eo.rotation)):
        raise GeometryError("footprint pairs need finite rotations for every image (use gps_pairs instead)")
    if max_distance_m is None:
        z = float(height) if not callable(height) else float(np.median(height(eo.centre[:, 0], eo.centre[:, 1])))
        max_distance_m = 20.0 * max(float(np.median(np.abs(eo.centre[:, 2] - z))), 1.0)
    samples = []
    for i in range(n):
        cam = cameras[str(eo.camera[i])]
        s = ground_samples(cam, pose[i], height, grid, max_distance_m)
        if len(s) == 0:
            raise GeometryError(f"image {eo.image[i]!r}: no footprint ray reaches the terrain")
        samples.append(s)
    centre = np.array([s[:, :2].mean(axis=0) for s in samples])
    radius = np.array([np.max(np.linalg.norm(s[:, :2] - c, axis=1)) for s, c in zip(samples, centre)])
    tree = cKDTree(centre)
    rmax = float(radius.max())
    cand = []
    for i in range(n):  # linear: each image only meets footprints within reach
        for j in tree.query_ball_point(centre[i], radius[i] + rmax):
            if j > i and np.linalg.norm(centre[i] - centre[j]) <= radius[i] + radius[j]:
                cand.append((i, j))
    if not cand:
        return np.zeros((0, 2), np.int64), np.zeros(0)
    cand_a = np.array(cand, dtype=np.int64)
    axis = -eo.rotation[:, :, 2]  # viewing direction (camera looks along -z)
    cosang = np.einsum("ij,ij->i", axis[cand_a[:, 0]], axis[cand_a[:, 1]])
    cand_a = cand_a[cosang >= np.cos(np.radians(max_view_angle_deg))]

    # overlap = max(share of a's ground samples that b sees, share of b's that a sees); projected per image b,
    # all of its candidates' samples at once
    m = len(cand_a)
    src = np.concatenate([cand_a[:, 0], cand_a[:, 1]])
    dst = np.concatenate([cand_a[:, 1], cand_a[:, 0]])
    frac = np.zeros(2 * m)
    order = np.argsort(dst, kind="stable")
    cuts = np.flatnonzero(np.r_[True, dst[order][1:] != dst[order][:-1], True])
    for lo, hi in zip(cuts[:-1], cuts[1:]):
        rows = order[lo:hi]
        b = int(dst[rows[0]])
        cam = cameras[str(eo.camera[b])]
        counts = np.array([len(samples[a]) for a in src[rows]])
        pts = np.concatenate([samples[a] for a in src[rows]])
        inside = cam.in_image(cam.world_to_pixel(pose[b], pts)).astype(np.float64)
        frac[rows] = np.add.reduceat(inside, np.r_[0, np.cumsum(counts)[:-1]]) / counts
    ov = np.maximum(frac[:m], frac[m:])
    keep = ov >= min_overlap
    return cand_a[keep], ov[keep]


def image_strips(eo: ExteriorOrientations) -> NDArray[np.int64]:
    """Flight strip of every image (``-1``: unknown), for :func:`budget_pairs`.

    Strips come from :func:`skyrig.trajectory.strips.detect_strips` on the exposures in time order (one position
    per exposure, the mean of its images' centres; the exposures are ``eo.exposure``, else the images that share
    an event time).  Without event times every image gets ``-1``.
    """
    n = len(eo)
    strip = np.full(n, -1, np.int64)
    if eo.time_s is None:
        return strip
    t = np.asarray(eo.time_s, float)
    ok = np.isfinite(t)
    if ok.sum() < 3:
        return strip
    from skyrig.trajectory.strips import detect_strips

    key = np.asarray(eo.exposure)[ok] if eo.exposure is not None else t[ok]
    _, ex = np.unique(key, return_inverse=True)
    m = int(ex.max()) + 1
    cnt = np.bincount(ex, minlength=m)
    tex = np.bincount(ex, weights=t[ok], minlength=m) / cnt
    cen = np.stack([np.bincount(ex, weights=eo.centre[ok, d], minlength=m) for d in range(3)], 1) / cnt[:, None]
    order = np.argsort(tex, kind="stable")
    lab = np.empty(m, np.int64)
    lab[order] = detect_strips(cen[order])
    strip[ok] = lab[ex]
    return strip


def budget_pairs(
    pairs: NDArray, overlap: NDArray, n_images: int, max_per_image: int | None,
    camera: NDArray | None = None, strip: NDArray | None = None,
) -> NDArray[np.bool_]:
    """Which of the candidate pairs to match under a per-image budget (``True`` = keep).

    Wide blocks of oblique rigs give every image tens of overlapping images (a 45 deg oblique sees the ground
    of several strips), so matching every overlapping pair grows faster than the block.  Like the neighbour
    limits of production tools, each image keeps a bounded number of pairs, chosen so that the block stays
    one rigid, connected network:

    1. a maximum spanning tree (forest, where the candidates already fall apart) over the overlaps: every
       image stays connected to the block by its strongest links;
    2. for each image a pair to every *kind* of partner (its strongest, or the strongest whose partner still
       has budget, so that no image becomes everybody's link): the partner's camera (rig head) and whether it
       lies on the same strip, on a strip numbered lower or on one numbered higher (``strip``,
       :func:`image_strips`).  So nadir <-> oblique links, same-direction obliques of the next exposures and
       of the neighbouring strips, and links across the strips on both sides are kept wherever one exists;
    3. the remaining pairs by decreasing overlap, as long as both images have fewer than ``max_per_image``
       pairs.

    Steps 1 and 2 do not look at the budget, so an image can take part in more pairs than ``max_per_image``
    (a few: its link kinds, at most 3 x the cameras, and the images that chose it as their strongest link of
    a kind; neither grows with the block).

    Parameters
    ----------
    pairs, overlap
        ``(P, 2)`` candidate pairs and ``(P,)`` their overlap (e.g. from :func:`footprint_pairs`).
    n_images
        Number of images (the pairs' indices are rows ``0 .. n_images - 1``).
    max_per_image
        The budget; ``None`` or ``0`` keeps every pair.
    camera, strip
        ``(n_images,)`` camera (head) label and flight strip (``-1`` unknown) of every image (default: one
        camera, strips unknown).

    Returns
    -------
    ``(P,)`` boolean mask of the kept pairs.
    """
    p = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    ov = np.asarray(overlap, dtype=np.float64).reshape(-1)
    if len(ov) != len(p):
        raise ValueError(f"budget_pairs: {len(p)} pairs but {len(ov)} overlaps")
    if not max_per_image or len(p) == 0:
        return np.ones(len(p), bool)
    if max_per_image < 1:
        raise ConfigError(f"max_per_image must be >= 1 (or 0 / None for all pairs), not {max_per_image}")
    n = int(n_images)
    keep = np.zeros(len(p), bool)
    # 1. maximum spanning forest: minimum spanning tree of weights 2 - overlap (> 0, so that no edge vanishes)
    w = coo_matrix((2.0 - ov, (p[:, 0], p[:, 1])), shape=(n, n)).tocsr()
    t = minimum_spanning_tree(w).tocoo()
    if t.nnz:
        a, b = np.minimum(t.row, t.col), np.maximum(t.row, t.col)
        index = {(int(i), int(j)): k for k, (i, j) in enumerate(p)}
        keep[[index[(int(i), int(j))] for i, j in zip(a, b)]] = True
    # 2. each image's best pair per partner class; directed rows (image, partner class, overlap, pair)
    cam = np.zeros(n, np.int64) if camera is None else np.unique(np.asarray(camera).astype(str).reshape(n),
                                                                  return_inverse=True)[1].astype(np.int64)
    st = np.full(n, -1, np.int64) if strip is None else np.asarray(strip, np.int64).reshape(n)
    img = np.concatenate([p[:, 0], p[:, 1]])
    par = np.concatenate([p[:, 1], p[:, 0]])
    side = np.where((st[img] < 0) | (st[par] < 0), 0, np.sign(st[par] - st[img]))
    other = 3 * cam[par] + side + 1
    pid = np.tile(np.arange(len(p)), 2)
    o2 = np.tile(ov, 2)
    order = np.lexsort((pid, -o2, other, img))  # per (image, class): strongest first, ties by pair order
    img, par, other, pid, o2 = img[order], par[order], other[order], pid[order], o2[order]
    start = np.flatnonzero(np.r_[True, (img[1:] != img[:-1]) | (other[1:] != other[:-1])])
    stop = np.r_[start[1:], len(order)]
    deg = np.bincount(p[keep].ravel(), minlength=n)
    for g in np.lexsort((start, -o2[start])):  # the groups with the strongest links first
        a, b = start[g], stop[g]
        if keep[pid[a:b]].any():
            continue
        # the strongest link of the kind whose partner still has budget (no hubs), else the strongest
        free = np.flatnonzero(deg[par[a:b]] < max_per_image)
        k = pid[a + (free[0] if len(free) else 0)]
        keep[k] = True
        deg[p[k]] += 1
    # 3. fill the budget by decreasing overlap
    for k in np.lexsort((np.arange(len(p)), -ov)):
        if keep[k]:
            continue
        i, j = p[k]
        if deg[i] < max_per_image and deg[j] < max_per_image:
            keep[k] = True
            deg[i] += 1
            deg[j] += 1
    return keep


def pair_graph_components(pairs: NDArray, n_images: int) -> int:
    """Number of connected components of the pair graph over ``n_images`` images (1 = one block)."""
    p = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    g = coo_matrix((np.ones(len(p)), (p[:, 0], p[:, 1])), shape=(n_images, n_images))
    return int(connected_components(g, directed=False)[0])
