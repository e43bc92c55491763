"""Ground classification of a point cloud and ASPRS classes (arrays in, arrays out).

The ground filter
-----------------
Ground points are found by the **Cloth Simulation Filter** (CSF; W. Zhang, J. Qi, P. Wan, H. Wang, D. Xie,
X. Wang, G. Yan, "An Easy-to-Use Airborne LiDAR Data Filtering Method Based on Cloth Simulation", Remote
Sensing 8(6):501, 2016), through its authors' own implementation, the PyPI package ``cloth-simulation-filter``
(module ``CSF``, Apache-2.0, C++ with a SWIG binding and manylinux wheels).  Why this one:

* it installs with ``pip`` alone (a binary wheel, no system library);
* PDAL's SMRF / PMF filters would be the other published choice, but the ``pdal`` package on PyPI is source
  only and needs the PDAL C++ library (``pdal-config``) to build: ``pip install pdal`` fails without it, so it
  cannot be a dependency of a pip-installed skyrig;
* the filter is the published algorithm as its authors maintain it (also the one in CloudCompare), not a
  re-implementation.

CSF turns the cloud upside down and drops a cloth of ``cloth_resolution_m`` particles on it; points within
``class_threshold_m`` of the settled cloth are ground.  The C++ library prints its progress to the process's
standard output; :func:`csf_ground` silences file descriptor 1 for the call (layers 0-2 print nothing).  Its
parameters are in the cloud's units, so every function here takes coordinates in **metres** (a caller with a cloud
in feet scales it first).

The other classes
-----------------
A rule on height above the ground (HAG, from a ground surface gridded from CSF's ground points), local shape and,
where the cloud has colours, colour (ASPRS LAS 1.4 R15 class codes):

* **2 ground**: CSF's ground points; with point precisions (an image cloud's ``sigma``) also the points the filter
  left off whose height above the ground surface is within ``ground_sigmas`` of their own precision and within
  ``ground_max_off_m`` (CSF's ``class_threshold_m`` is one distance for all points; an image cloud's noise varies
  from point to point);
* **7 low point (noise)**: isolated points (the distance to their ``noise_neighbours``-th nearest neighbour more
  than ``noise_spacing_factor`` times its median over the cloud: a test that follows the cloud's density) and
  points more than ``noise_below_m`` below the ground surface;
* **6 building**: the points of a *raised object* (connected cells of ``ground_cell_m`` holding points at least
  ``building_min_height_m`` above the ground) of at least ``building_min_area_m2`` whose points are mostly
  (``building_planar_share``) on locally planar surfaces, and, with colours, which is not mostly green and rough
  (a tree); inside it every point above ``wall_min_height_m`` (walls, eaves) except rough green ones (a tree over
  the roof).  Planar: the scatter off the local plane (32 nearest points within ``neighbourhood_m``) within
  ``planarity_sigmas`` of the points' predicted precision when the cloud has one (an image cloud), else a
  surface variation (smallest eigenvalue of the covariance / the sum) below ``planarity_max``;
* **3 / 4 / 5 low / medium / high vegetation** (HAG below 2 m / 2-5 m / above 5 m: skyrig's split, ASPRS leaves
  the heights to the data producer): the rest above ``vegetation_min_height_m`` when colour says green (excess green
  ``(2G - R - B) / (R + G + B)`` above ``green_min``) or, without colours, when the neighbourhood is not planar;
* **1 unclassified**: what no rule supports (cars, walls outside building patches, grey non-planar objects).
"""

from __future__ import annotations

import logging
import os
import sys
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Iterator

import numpy as np
from numpy.typing import NDArray

from skyrig.errors import InputFormatError

__all__ = ["GroundFilter", "ClassRules", "Classification", "csf_ground", "classify_points",
           "ASPRS_UNCLASSIFIED", "ASPRS_GROUND", "ASPRS_LOW_VEGETATION", "ASPRS_MEDIUM_VEGETATION",
           "ASPRS_HIGH_VEGETATION", "ASPRS_BUILDING", "ASPRS_NOISE", "ASPRS_NAMES"]

log = logging.getLogger(__name__)

ASPRS_UNCLASSIFIED = 1
ASPRS_GROUND = 2
ASPRS_LOW_VEGETATION = 3
ASPRS_MEDIUM_VEGETATION = 4
ASPRS_HIGH_VEGETATION = 5
ASPRS_BUILDING = 6
ASPRS_NOISE = 7
#: Names of the class codes skyrig writes (ASPRS LAS 1.4 R15, table 17).
ASPRS_NAMES = {1: "unclassified", 2: "ground", 3: "low vegetation", 4: "medium vegetation", 5: "high vegetation",
               6: "building", 7: "low point (noise)"}


@dataclass(frozen=True)
class GroundFilter:
    """Parameters of the cloth simulation filter (Zhang et al. 2016), in metres."""

    cloth_resolution_m: float = 1.0  # particle spacing of the cloth; about 2-3 x the point spacing
    class_threshold_m: float = 0.5  # points within this distance of the settled cloth are ground
    rigidness: int = 2  # 1 steep slopes, 2 relief, 3 flat terrain (the paper's scene types)
    iterations: int = 500  # simulation steps (the library's default)
    time_step: float = 0.65  # the library's default
    slope_smooth: bool = True  # post-processing of steep slopes (the library's bSloopSmooth)

    def check(self) -> None:
        for name in ("cloth_resolution_m", "class_threshold_m", "time_step"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise InputFormatError(f"must be a positive number, got {v!r}", field=name)
        if self.rigidness not in (1, 2, 3):
            raise InputFormatError(f"must be 1, 2 or 3, got {self.rigidness!r}", field="rigidness")
        if self.iterations < 1:
            raise InputFormatError(f"must be at least 1, got {self.iterations!r}", field="iterations")


@dataclass(frozen=True)
class ClassRules:
    """Thresholds of the building / vegetation / noise rule (metres unless named otherwise)."""

    noise_neighbours: int = 2  # isolated-point test: the distance to the k-th nearest other point ...
    noise_spacing_factor: float = 5.0  # ... above this many times its median over the cloud: noise
    noise_below_m: float = 1.0  # points this far below the ground surface: noise
    neighbourhood_m: float = 1.5  # radius of the local shape (covariance of the 32 nearest points) neighbourhood
    planarity_max: float = 0.02  # without point sigmas: smallest covariance eigenvalue / trace below this: planar
    planarity_sigmas: float = 3.0  # with point sigmas: scatter off the local plane within this many sigmas: planar
    building_min_height_m: float = 2.0  # roofs are at least this high above the ground
    building_min_area_m2: float = 12.0  # smaller raised objects are not buildings
    building_planar_share: float = 0.5  # a raised object is a building when this share of its points is planar
    wall_min_height_m: float = 0.5  # points inside a building object above this are building (walls)
    vegetation_min_height_m: float = 0.3  # lower non-ground points stay unclassified
    green_min: float = 0.05  # excess-green index above this: green
    ground_cell_m: float = 1.0  # cell of the ground surface the heights above ground are taken from
    ground_sigmas: float = 3.0  # with point sigmas: non-ground points within this many sigmas of the ground ...
    ground_max_off_m: float = 0.5  # ... and no farther than this from it: ground


@dataclass(frozen=True)
class Classification:
    """Per-point result of :func:`classify_points`.

    Attributes
    ----------
    code
        ``(N,)`` uint8 ASPRS class codes (see :data:`ASPRS_NAMES`).
    hag
        ``(N,)`` height above the ground surface, metres (NaN where no ground surface).
    counts
        Points per class code.
    """

    code: NDArray[np.uint8]
    hag: NDArray[np.float64]
    counts: dict[int, int]


@contextmanager
def _quiet_stdout() -> Iterator[None]:
    """Silence the C++ library's progress lines (it writes to the process's standard output, file descriptor 1)."""
    try:
        fd = sys.stdout.fileno() if sys.stdout is not None else 1
    except (AttributeError, OSError, ValueError):
        fd = 1
    if sys.stdout is not None:
        sys.stdout.flush()
    saved = os.dup(fd)
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, fd)
        yield
    finally:
        os.dup2(saved, fd)
        os.close(saved)
        os.close(null)


def csf_ground(xyz: NDArray[np.float64], params: GroundFilter = GroundFilter()) -> NDArray[np.bool_]:
    """Ground points of a cloud by the cloth simulation filter (the ``cloth-simulation-filter`` package).

    Parameters
    ----------
    xyz
        ``(N, 3)`` coordinates in metres (east, north, up; any offset: the filter works on ``xyz - min``).
    params
        The filter's parameters.

    Returns
    -------
    ``(N,)`` bool, True for ground.

    Raises
    ------
    InputFormatError
        On an empty or non-finite cloud or a bad parameter.
    """
    import CSF

    params.check()
    pts = np.asarray(xyz, np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
        raise InputFormatError(f"points must be a non-empty (N, 3) array, got {pts.shape}", field="xyz")
    if not np.all(np.isfinite(pts)):
        raise InputFormatError("points hold non-finite coordinates", field="xyz")
    c = CSF.CSF()
    c.params.bSloopSmooth = bool(params.slope_smooth)
    c.params.cloth_resolution = float(params.cloth_resolution_m)
    c.params.class_threshold = float(params.class_threshold_m)
    c.params.rigidness = int(params.rigidness)
    c.params.interations = int(params.iterations)  # sic: the library's spelling
    c.params.time_step = float(params.time_step)
    c.setPointCloud(np.ascontiguousarray(pts - pts.min(axis=0)))
    ground, off = CSF.VecInt(), CSF.VecInt()
    with _quiet_stdout():
        c.do_filtering(ground, off, False)
    out = np.zeros(len(pts), bool)
    out[np.asarray(ground, dtype=np.int64)] = True
    return out


def _excess_green(rgb: NDArray) -> NDArray[np.float64]:
    c = np.asarray(rgb, np.float64)
    s = c.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(s > 0, (2 * c[:, 1] - c[:, 0] - c[:, 2]) / s, 0.0)


def _local_shape(xyz: NDArray[np.float64], idx: NDArray[np.int64], radius: float, k: int = 32
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Shape of each point's neighbourhood (its ``k`` nearest neighbours within ``radius``, 3D): the surface
    variation (smallest eigenvalue of the covariance / its trace, Pauly et al. 2002: 0 on a plane, 1/3 for
    isotropic scatter) and the scatter off the best-fitting plane (square root of the smallest eigenvalue,
    metres); NaN with fewer than 5 neighbours."""
    from scipy.spatial import cKDTree

    var_out = np.full(len(idx), np.nan)
    off_out = np.full(len(idx), np.nan)
    if len(idx) == 0:
        return var_out, off_out
    from threadpoolctl import threadpool_limits

    tree = cKDTree(xyz)
    pad = np.vstack([xyz, np.zeros((1, 3))])
    chunk = 20000
    with threadpool_limits(1, user_api="blas"):  # a LAPACK call per 3x3 matrix: threads only spin
        _shape_chunks(tree, xyz, pad, idx, radius, k, chunk, var_out, off_out)
    return var_out, off_out


def _shape_chunks(tree, xyz: NDArray[np.float64], pad: NDArray[np.float64], idx: NDArray[np.int64], radius: float,
                  k: int, chunk: int, var_out: NDArray[np.float64], off_out: NDArray[np.float64]) -> None:
    """:func:`_local_shape`'s work, ``chunk`` points at a time, into ``var_out`` / ``off_out``."""
    for s in range(0, len(idx), chunk):
        d, nb = tree.query(xyz[idx[s:s + chunk]], k=min(k, len(xyz)), distance_upper_bound=radius)
        nb = np.asarray(nb).reshape(len(d), -1)
        w = (nb < len(xyz)).astype(np.float64)
        m = w.sum(axis=1)
        p = pad[np.minimum(nb, len(xyz))]
        mean = np.einsum("ij,ijk->ik", w, p) / np.maximum(m, 1)[:, None]
        q = (p - mean[:, None, :]) * w[:, :, None]
        cov = np.einsum("ijk,ijl->ikl", q, q) / np.maximum(m - 1, 1)[:, None, None]
        ev = np.linalg.eigvalsh(cov)
        tr = ev.sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            v = np.where(tr > 0, ev[:, 0] / tr, 0.0)
        enough = m >= 5
        var_out[s:s + chunk] = np.where(enough, v, np.nan)
        off_out[s:s + chunk] = np.where(enough, np.sqrt(np.maximum(ev[:, 0], 0.0)), np.nan)


def classify_points(xyz: NDArray[np.float64], rgb: NDArray | None = None, *,
                    ground: GroundFilter = GroundFilter(), rules: ClassRules = ClassRules(),
                    sigma: NDArray[np.float64] | None = None,
                    is_ground: NDArray[np.bool_] | None = None) -> Classification:
    """ASPRS classes of a cloud: CSF ground, then the building / vegetation / noise rule (module docstring).

    Parameters
    ----------
    xyz
        ``(N, 3)`` coordinates in metres.
    rgb
        ``(N, 3)`` colours (any scale) or None; enables the colour rule for vegetation.
    ground, rules
        Parameters of the ground filter and of the rule.
    sigma
        ``(N,)`` predicted precision of the points (metres, e.g. a dense cloud's), or None: with it a
        neighbourhood is planar when its scatter off the plane is within ``planarity_sigmas`` of it, without it
        when its surface variation is below ``planarity_max``.
    is_ground
        ``(N,)`` ground flags to use instead of running the filter (e.g. a provider's ground class).

    Returns
    -------
    :class:`Classification`.
    """
    from scipy import ndimage
    from scipy.spatial import cKDTree

    from skyrig.terrain.dtm import ground_surface, sample_surface

    pts = np.asarray(xyz, np.float64)
    n = len(pts)
    g = csf_ground(pts, ground) if is_ground is None else np.asarray(is_ground, bool)
    if g.shape != (n,):
        raise InputFormatError(f"ground flags must be ({n},), got {g.shape}", field="is_ground")
    if rgb is not None and np.shape(rgb) != (n, 3):
        raise InputFormatError(f"colours must be ({n}, 3), got {np.shape(rgb)}", field="rgb")
    if sigma is not None and np.shape(sigma) != (n,):
        raise InputFormatError(f"sigmas must be ({n},), got {np.shape(sigma)}", field="sigma")
    code = np.full(n, ASPRS_UNCLASSIFIED, np.uint8)
    if not g.any():
        log.warning("the ground filter found no ground point; every point stays unclassified")
        return Classification(code, np.full(n, np.nan), {ASPRS_UNCLASSIFIED: n})
    # isolated points first (they must not bend the ground surface)
    k = rules.noise_neighbours
    dk = cKDTree(pts).query(pts, k=k + 1)[0][:, k] if n > k else np.zeros(n)
    noise = dk > rules.noise_spacing_factor * max(float(np.median(dk)), 1e-9)
    surf = ground_surface(pts[g & ~noise], rules.ground_cell_m)
    hag = pts[:, 2] - sample_surface(surf, pts[:, 0], pts[:, 1])
    noise |= hag < -rules.noise_below_m
    if sigma is not None:  # points the filter left off the ground by no more than their own noise
        s = np.asarray(sigma, np.float64)
        lim = np.minimum(rules.ground_sigmas * np.where(np.isfinite(s), s, 0.0), rules.ground_max_off_m)
        g = g | (~noise & (np.abs(hag) <= lim))
    code[g & ~noise] = ASPRS_GROUND
    rest = ~g & ~noise & np.isfinite(hag)
    green = np.zeros(n, bool) if rgb is None else _excess_green(rgb) > rules.green_min
    cand = np.flatnonzero(rest & (hag >= min(rules.vegetation_min_height_m, rules.wall_min_height_m)))
    variation = np.full(n, np.nan)
    scatter = np.full(n, np.nan)
    variation[cand], scatter[cand] = _local_shape(pts, cand, rules.neighbourhood_m)
    if sigma is not None:
        s = np.asarray(sigma, np.float64)
        planar = scatter <= rules.planarity_sigmas * np.where(np.isfinite(s) & (s > 0), s, np.nan)
    else:
        planar = variation < rules.planarity_max
    shaped = np.isfinite(scatter)
    # raised objects: connected cells of points at least building_min_height above the ground
    high = rest & (hag >= rules.building_min_height_m)
    cell = rules.ground_cell_m
    x0, y1 = pts[:, 0].min(), pts[:, 1].max()
    col = np.floor((pts[:, 0] - x0) / cell).astype(np.int64)
    row = np.floor((y1 - pts[:, 1]) / cell).astype(np.int64)
    shape = (int(row.max()) + 1, int(col.max()) + 1)
    occ = np.zeros(shape, bool)
    occ[row[high], col[high]] = True
    lab, nlab = ndimage.label(occ | ndimage.binary_closing(occ), structure=np.ones((3, 3)))
    if nlab:
        obj = lab[row, col]
        idx = np.arange(1, nlab + 1)
        area = ndimage.sum_labels(np.ones(shape), lab, index=idx) * cell * cell
        w = high & shaped
        n_shaped = np.bincount(obj[w], minlength=nlab + 1)[1:]
        n_planar = np.bincount(obj[w & planar], minlength=nlab + 1)[1:]
        n_green = np.bincount(obj[high & green], minlength=nlab + 1)[1:]
        n_high = np.bincount(obj[high], minlength=nlab + 1)[1:]
        with np.errstate(invalid="ignore", divide="ignore"):
            planar_share = np.where(n_shaped > 0, n_planar / n_shaped, 0.0)
            green_share = np.where(n_high > 0, n_green / n_high, 0.0)
        is_b = (area >= rules.building_min_area_m2) & (planar_share >= rules.building_planar_share)
        if rgb is not None:  # a green, rough object is a tree, whatever its size
            is_b &= ~((green_share > 0.5) & (planar_share < 0.75))
        b_cells = np.r_[False, is_b][lab]
        b_cells = ndimage.binary_dilation(b_cells, iterations=1)  # walls at the object's edge
        in_b = b_cells[row, col]
        # inside a building: everything raised, except rough green parts (a tree over the roof)
        building = rest & in_b & (hag >= rules.wall_min_height_m) & ~(green & ~planar & shaped)
        code[building] = ASPRS_BUILDING
        rest &= ~building
    veg_ok = green if rgb is not None else ~planar  # scattered or too sparse for a surface
    veg = rest & veg_ok & (hag >= rules.vegetation_min_height_m)
    code[veg & (hag < 2.0)] = ASPRS_LOW_VEGETATION
    code[veg & (hag >= 2.0) & (hag < 5.0)] = ASPRS_MEDIUM_VEGETATION
    code[veg & (hag >= 5.0)] = ASPRS_HIGH_VEGETATION
    code[noise] = ASPRS_NOISE
    u, c = np.unique(code, return_counts=True)
    return Classification(code, hag, {int(a): int(b) for a, b in zip(u, c)})


def tile_windows(xy: NDArray[np.float64], tile_m: float, buffer_m: float
                 ) -> list[tuple[NDArray[np.int64], NDArray[np.int64]]]:
    """Square tiles of ``tile_m`` over the points, each with a buffer of ``buffer_m``: ``[(core, buffered)]`` index
    arrays per non-empty tile, ``core`` a subset of ``buffered`` (every point in exactly one core)."""
    if not (np.isfinite(tile_m) and tile_m > 0 and np.isfinite(buffer_m) and buffer_m >= 0):
        raise InputFormatError(f"tile {tile_m!r} m must be positive and buffer {buffer_m!r} m not negative",
                               field="tile_m")
    p = np.asarray(xy, np.float64)
    x0, y0 = p[:, 0].min(), p[:, 1].min()
    ti = np.floor((p[:, 0] - x0) / tile_m).astype(np.int64)
    tj = np.floor((p[:, 1] - y0) / tile_m).astype(np.int64)
    out = []
    for i, j in sorted(set(zip(ti.tolist(), tj.tolist()))):
        core = np.flatnonzero((ti == i) & (tj == j))
        bx0, by0 = x0 + i * tile_m - buffer_m, y0 + j * tile_m - buffer_m
        buf = np.flatnonzero((p[:, 0] >= bx0) & (p[:, 0] < bx0 + tile_m + 2 * buffer_m)
                             & (p[:, 1] >= by0) & (p[:, 1] < by0 + tile_m + 2 * buffer_m))
        out.append((core, buf))
    return out


def classify_tiled(xyz: NDArray[np.float64], rgb: NDArray | None = None, *, sigma: NDArray[np.float64] | None = None,
                   ground: GroundFilter = GroundFilter(), rules: ClassRules = ClassRules(), tile_m: float = 500.0,
                   buffer_m: float = 50.0, map_fn=map) -> Classification:
    """:func:`classify_points` tile by tile (:func:`tile_windows`): each tile's points with a buffer around them are
    classified together and the tile keeps the classes of its own points, so the work and memory of one task are
    bounded by the buffered tile.  The buffer must hold the largest building (a roof cut by a tile's edge could
    look like a small object, the cloth could sag into it): 50 m by default.

    ``map_fn(func, items)`` runs the tiles (the built-in ``map``, or an executor's, e.g.
    :meth:`skyrig.pipeline.executor.Executor.map`: the function and the items are picklable).
    """
    pts = np.asarray(xyz, np.float64)
    wins = tile_windows(pts[:, :2], tile_m, buffer_m)
    if len(wins) == 1:
        return classify_points(pts, rgb, ground=ground, rules=rules, sigma=sigma)
    items = [(pts[b], None if rgb is None else np.asarray(rgb)[b], None if sigma is None else np.asarray(sigma)[b],
              ground, rules) for _, b in wins]
    results = list(map_fn(_classify_item, items))
    code = np.full(len(pts), ASPRS_UNCLASSIFIED, np.uint8)
    hag = np.full(len(pts), np.nan)
    for (core, buf), (c, h) in zip(wins, results):
        pos = np.searchsorted(buf, core)  # buf is sorted and holds core
        code[core] = c[pos]
        hag[core] = h[pos]
    u, n = np.unique(code, return_counts=True)
    return Classification(code, hag, {int(a): int(b) for a, b in zip(u, n)})


def _classify_item(item: tuple) -> tuple[NDArray[np.uint8], NDArray[np.float64]]:
    """One tile of :func:`classify_tiled` (module level: picklable for worker processes)."""
    xyz, rgb, sigma, ground, rules = item
    cl = classify_points(xyz, rgb, ground=ground, rules=rules, sigma=sigma)
    return cl.code, cl.hag
