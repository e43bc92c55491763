"""Point-cloud comparison: cloud-to-cloud distances, M3C2, and distance statistics.

Cloud-to-cloud (C2C)
--------------------
:func:`cloud_to_cloud` gives, for every point of the *compared* cloud, the distance to the *reference*
cloud, either to the nearest reference point (``model="nearest"``, CloudCompare's default C2C) or to a
least-squares plane through its ``k`` nearest reference points (``model="plane"``, CloudCompare's
"local model: least square plane").  The plane model removes the sampling effect of the reference: on a
smooth surface it measures the displacement along the surface normal.

M3C2 (Lague et al. 2013)
------------------------
:func:`m3c2` follows CloudCompare's qM3C2 plugin and PDAL's ``filters.m3c2`` (verified against
CloudCompare's output on PDAL's Autzen test clouds, ``tests/test_lidar_compare.py``):

1. Normal at each core point: the eigenvector of the smallest eigenvalue of the covariance matrix (divisor
   ``n``) of the points of cloud 1 within ``normal_radius`` of the core point (a sphere, boundary
   included); at least 3 points are needed, otherwise the normal and every result of that core point are
   undefined (CloudCompare writes a zero normal and a distance of 0 there; skyrig reports NaN and
   ``normal_valid = False``).  The normal is oriented towards ``+Z`` (``orientation="up"``), towards a
   given direction, or left as the eigen solver returns it (``"none"``).
2. A cylinder of radius ``cylinder_radius`` along the normal through the core point, extending
   ``cylinder_half_length`` to both sides (boundaries included): the signed positions ``s`` along the
   normal of the points of each cloud inside it give ``n_i``, mean ``i_i`` and standard deviation
   ``sigma_i`` (population, divisor ``n_i``).
3. ``distance = i_2 - i_1`` where both cylinders hold at least one point.
4. Level of detection at 95 %: ``LoD = 1.96 (sqrt(sigma_1^2 / n_1 + sigma_2^2 / n_2) + reg_error)``, defined
   where both counts reach ``min_points_for_stats`` (CloudCompare's "minimum points for statistics",
   default 5 here; PDAL's ``min_points`` defaults to 1); ``significant = |distance| > LoD``.

CloudCompare stores normals compressed: each normal is snapped to one of ``8 * 4**9`` directions (a
recursive subdivision of the octahedron's faces, 9 levels, about 0.1 deg apart) before the cylinders are
built.  On sparse clouds that moves points across a cylinder's boundary (by up to 0.35 m of M3C2 distance
on the Autzen test clouds).  ``normal_quantization=9`` (:meth:`M3C2Params.cloudcompare`) reproduces it
(:func:`quantize_normals`); ``None`` keeps the exact normals (PDAL, :meth:`M3C2Params.pdal`).

Parameters are radii and a half-length, as in PDAL.  CloudCompare's dialog takes *diameters* ("normal
scale", "projection scale") and the half-length ("max depth"): divide its two scales by 2.

Statistics
----------
:func:`distance_statistics` gives mean, standard deviation, RMS, extremes and percentiles of distances;
``p68_abs_m`` is paper 002's "2/3 of all points have deviations less than" figure (68th percentile of the
absolute distances).  :func:`histogram` bins them for a plot.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from skyrig.errors import GeometryError, InputFormatError

logger = logging.getLogger(__name__)

__all__ = [
    "C2CResult",
    "DistanceStatistics",
    "M3C2Params",
    "M3C2Result",
    "cloud_to_cloud",
    "distance_statistics",
    "histogram",
    "local_normals",
    "m3c2",
    "quantize_normals",
]

Orientation = Literal["up", "none"]


def _points(name: str, a: ArrayLike) -> NDArray[np.float64]:
    p = np.asarray(a, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputFormatError(f"expected an (N, 3) array of points, got shape {p.shape}", field=name)
    if not np.all(np.isfinite(p)):
        raise InputFormatError(f"non-finite coordinate at point {int(np.argmax(~np.isfinite(p).all(1)))}", field=name)
    return p


def _flatten_neighbours(lists: NDArray[np.object_] | list, m: int) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """(owner, index) pairs from cKDTree.query_ball_point's list of lists."""
    counts = np.fromiter((len(x) for x in lists), dtype=np.intp, count=m)
    if counts.sum() == 0:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    idx = np.fromiter((i for x in lists for i in x), dtype=np.intp, count=int(counts.sum()))
    owner = np.repeat(np.arange(m, dtype=np.intp), counts)
    return owner, idx


def _plane_normals(offsets: NDArray[np.float64], owner: NDArray[np.intp], m: int,
                   min_points: int) -> tuple[NDArray[np.float64], NDArray[np.intp], NDArray[np.float64]]:
    """Least-squares plane normals of grouped offsets: ``(m, 3)`` normals (NaN where fewer than
    ``min_points``), counts ``(m,)`` and group centroids ``(m, 3)`` (in the offsets' frame)."""
    n = np.bincount(owner, minlength=m)
    s = np.stack([np.bincount(owner, offsets[:, j], minlength=m) for j in range(3)], axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = s / n[:, None]
    cov = np.empty((m, 3, 3))
    for a in range(3):
        for b in range(a, 3):
            sab = np.bincount(owner, offsets[:, a] * offsets[:, b], minlength=m)
            with np.errstate(invalid="ignore", divide="ignore"):
                cov[:, a, b] = cov[:, b, a] = sab / n - mean[:, a] * mean[:, b]
    normals = np.full((m, 3), np.nan)
    ok = n >= min_points
    if np.any(ok):
        _, vec = np.linalg.eigh(cov[ok])
        normals[ok] = vec[:, :, 0]
    return normals, n, mean


def _orient(normals: NDArray[np.float64], orientation: Orientation | ArrayLike) -> NDArray[np.float64]:
    if isinstance(orientation, str):
        if orientation == "none":
            return normals
        if orientation != "up":
            raise InputFormatError(f"orientation must be 'up', 'none' or a direction vector, not {orientation!r}",
                                   field="orientation")
        ref = np.array([0.0, 0.0, 1.0])
    else:
        ref = np.asarray(orientation, dtype=np.float64)
    flip = (normals @ ref if ref.ndim == 1 else np.einsum("ij,ij->i", normals, ref)) < 0
    out = normals.copy()
    out[flip] *= -1.0
    return out


def local_normals(
    points: ArrayLike,
    cloud: ArrayLike,
    radius: float,
    orientation: Orientation | ArrayLike = "up",
    min_points: int = 3,
    tree: cKDTree | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """Surface normals at ``points`` from the points of ``cloud`` within ``radius`` (PCA plane fit).

    Parameters
    ----------
    points
        ``(M, 3)`` query positions (metres).
    cloud
        ``(N, 3)`` points the planes are fitted to.
    radius
        Neighbourhood radius (metres, sphere, boundary included).
    orientation
        ``"up"`` (normal z >= 0), ``"none"``, or a direction ``(3,)`` / per-point ``(M, 3)`` the normals
        are turned towards.
    min_points
        Fewest neighbours for a normal (at least 3).
    tree
        A prebuilt ``cKDTree(cloud)`` to reuse.

    Returns
    -------
    normals
        ``(M, 3)`` unit normals, NaN where fewer than ``min_points`` neighbours.
    counts
        ``(M,)`` neighbour counts.
    """
    q = _points("points", points)
    c = _points("cloud", cloud)
    if radius <= 0:
        raise InputFormatError(f"normal radius must be positive, got {radius}", field="normal_radius")
    tree = cKDTree(c) if tree is None else tree
    owner, idx = _flatten_neighbours(tree.query_ball_point(q, radius), len(q))
    normals, counts, _ = _plane_normals(c[idx] - q[owner], owner, len(q), max(3, min_points))
    return _orient(normals, orientation), counts


# --------------------------------------------------------------------------- cloud to cloud
@dataclass(frozen=True, eq=False)
class C2CResult:
    """Cloud-to-cloud distances of the compared cloud's ``N`` points.

    Attributes
    ----------
    distance_m
        ``(N,)`` distances (metres): unsigned for ``model="nearest"``; for ``model="plane"`` signed along
        the plane normal when the result was asked ``signed=True``, otherwise absolute.  NaN where no
        reference point lies within ``max_distance``.  The plane model fits the ``k`` nearest reference points
        within ``max_distance`` (all of them where fewer lie there, at least 3); where fewer than 3 lie there or
        they are collinear, the point gets its nearest distance, counted in ``n_fallback``.
    nearest_index
        ``(N,)`` index of the nearest reference point (``len(reference)`` where none).
    model
        ``"nearest"`` or ``"plane"``.
    n_fallback
        Points of the plane model that got the nearest distance: fewer than 3 reference points within
        ``max_distance`` or collinear ones (a sparse reference makes these common: the distance to the nearest
        point then includes the reference's sampling spacing).
    """

    distance_m: NDArray[np.float64]
    nearest_index: NDArray[np.intp]
    model: str
    n_fallback: int = 0


def cloud_to_cloud(
    compared: ArrayLike,
    reference: ArrayLike,
    model: Literal["nearest", "plane"] = "nearest",
    k: int = 8,
    max_distance: float | None = None,
    signed: bool = False,
    orientation: Orientation | ArrayLike = "up",
    tree: cKDTree | None = None,
    workers: int = 1,
    chunk: int = 500_000,
) -> C2CResult:
    """Distances from each compared point to the reference cloud.

    Parameters
    ----------
    compared
        ``(N, 3)`` points whose distances are computed (metres).
    reference
        ``(R, 3)`` reference points (e.g. a TLS cloud).
    model
        ``"nearest"``: distance to the nearest reference point.  ``"plane"``: distance to the
        least-squares plane through the ``k`` nearest reference points.
    k
        Neighbours for the plane model (>= 3).
    max_distance
        Ignore reference points farther than this (metres): a point with none within it gets NaN; the plane
        model's neighbours are the ``k`` nearest within it (fewer where fewer lie there).
    signed
        Plane model only: keep the sign along the plane normal oriented by ``orientation``.
    orientation
        Normal orientation for signed distances (see :func:`local_normals`).
    tree
        A prebuilt ``cKDTree(reference)``.
    workers
        Threads for the k-d tree queries (``-1``: all cores).
    chunk
        Points per batch (bounds memory).
    """
    p = _points("compared", compared)
    r = _points("reference", reference)
    if model not in ("nearest", "plane"):
        raise InputFormatError(f"model must be 'nearest' or 'plane', not {model!r}", field="model")
    if len(r) == 0:
        raise GeometryError("the reference cloud is empty")
    tree = cKDTree(r) if tree is None else tree
    ub = np.inf if max_distance is None else float(max_distance)
    dist = np.empty(len(p))
    nearest = np.empty(len(p), dtype=np.intp)
    fallback = 0
    kk = 1 if model == "nearest" else max(3, int(k))
    if model == "plane" and len(r) < kk:
        raise GeometryError(f"the plane model needs at least {kk} reference points, got {len(r)}")
    for a in range(0, len(p), chunk):
        q = p[a:a + chunk]
        d, i = tree.query(q, k=kk, distance_upper_bound=ub, workers=workers)
        if kk == 1:
            dist[a:a + len(q)] = np.where(np.isfinite(d), d, np.nan)
            nearest[a:a + len(q)] = i
            continue
        nearest[a:a + len(q)] = i[:, 0]
        valid = np.isfinite(d)  # neighbours within max_distance
        nv = valid.sum(axis=1)
        out = np.where(np.isfinite(d[:, 0]), d[:, 0], np.nan)
        enough = nv >= 3
        fallback += int(np.count_nonzero((nv > 0) & ~enough))
        if np.any(enough):
            wv = valid[enough].astype(np.float64)[:, :, None]  # (F, k, 1): 0 for the missing neighbours
            nb = r[np.where(valid[enough], i[enough], 0)] - q[enough][:, None, :]  # (F, k, 3) offsets from the query
            cnt = nv[enough].astype(np.float64)[:, None]
            c = (wv * nb).sum(axis=1) / cnt
            dev = (nb - c[:, None, :]) * wv
            cov = np.einsum("fki,fkj->fij", dev, dev) / cnt[:, :, None]
            w, vec = np.linalg.eigh(cov)
            nrm = vec[:, :, 0]
            # collinear / coincident neighbours: the plane is undefined -> nearest distance
            degenerate = w[:, 1] <= 1e-12 * np.maximum(w[:, 2], 1e-300)
            nrm = _orient(nrm, orientation if not isinstance(orientation, str) or orientation != "none" else "none")
            sd = -np.einsum("fi,fi->f", c, nrm)  # signed distance of the query point to the plane
            vals = sd if signed else np.abs(sd)
            vals = np.where(degenerate, d[enough, 0], vals)
            fallback += int(degenerate.sum())
            out[enough] = vals
        dist[a:a + len(q)] = out
    return C2CResult(dist, nearest, model, fallback)


# --------------------------------------------------------------------------- M3C2
def quantize_normals(normals: ArrayLike, level: int = 9) -> NDArray[np.float64]:
    """Snap unit vectors ``(M, 3)`` to CloudCompare's compressed normal directions.

    CloudCompare (``ccNormalCompressor``) encodes a normal by its octant (signs) and ``level`` steps of a
    recursive 4-way subdivision of the octant's triangle ``x + y + z = 1`` (corner triangles and the
    flipped centre triangle); the decoded direction is the centre of the final small triangle.  Ties
    (a component exactly on a dividing line) go as in CloudCompare: strictly greater (or, in a flipped
    triangle, strictly smaller) selects a corner.

    Returns
    -------
    ``(M, 3)`` unit vectors; a zero vector stays zero.
    """
    n = np.asarray(normals, dtype=np.float64)
    sign = np.where(n < 0, -1.0, 1.0)
    a = np.abs(n)
    tot = a.sum(axis=1, keepdims=True)
    zero = tot[:, 0] == 0
    a = a / np.where(tot == 0, 1.0, tot)
    m = len(a)
    lo = np.zeros((m, 3))
    hi = np.ones((m, 3))
    flip = np.zeros(m, dtype=bool)
    rows = np.arange(m)
    for _ in range(int(level)):
        half = (lo + hi) / 2
        corner = np.where(flip[:, None], a < half, a > half)
        sector = np.where(corner[:, 2], 2, np.where(corner[:, 1], 1, np.where(corner[:, 0], 0, 3)))
        centre = sector == 3
        new_lo, new_hi = lo.copy(), hi.copy()
        up = ~flip  # upright triangle: shrink towards the corner of ``sector`` (or to the flipped centre)
        new_hi[up] = half[up]
        i = rows[up & ~centre]
        new_lo[i, sector[i]] = half[i, sector[i]]
        new_hi[i, sector[i]] = hi[i, sector[i]]
        new_lo[flip] = half[flip]
        j = rows[flip & ~centre]
        new_hi[j, sector[j]] = half[j, sector[j]]
        new_lo[j, sector[j]] = lo[j, sector[j]]
        flip = np.where(centre, ~flip, flip)
        lo, hi = new_lo, new_hi
    q = sign * (lo + hi)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[zero] = 0.0
    return q


@dataclass(frozen=True)
class M3C2Params:
    """M3C2 parameters (all lengths in metres).

    Attributes
    ----------
    normal_radius
        Radius of the sphere of cloud-1 points that gives the normal (CloudCompare: half its "normal scale").
    cylinder_radius
        Radius of the projection cylinder (CloudCompare: half its "projection scale").
    cylinder_half_length
        Half-length of the cylinder (CloudCompare: "max depth"; PDAL: ``cyl_halflen``).
    registration_error
        Registration error added to the level of detection (``reg``).
    orientation
        ``"up"``, ``"none"`` or a direction ``(3,)`` the normals are turned towards.
    min_points_for_stats
        Fewest points in each cylinder for an uncertainty (and significance) to be given.
    normal_min_points
        Fewest cloud-1 points in the normal sphere (3 is the mathematical minimum).
    normal_quantization
        ``None``: exact normals; an integer ``L``: snap normals to CloudCompare's compressed directions
        of ``L`` levels (CloudCompare uses 9), see :func:`quantize_normals`.
    """

    normal_radius: float
    cylinder_radius: float
    cylinder_half_length: float
    registration_error: float = 0.0
    orientation: Orientation | tuple[float, float, float] = "up"
    min_points_for_stats: int = 5
    normal_min_points: int = 3
    normal_quantization: int | None = None

    @classmethod
    def cloudcompare(cls, normal_radius: float, cylinder_radius: float, cylinder_half_length: float,
                     registration_error: float = 0.0, min_points_for_stats: int = 5) -> "M3C2Params":
        """CloudCompare's qM3C2 behaviour: compressed normals (9 levels), 5 points for statistics."""
        return cls(normal_radius, cylinder_radius, cylinder_half_length, registration_error, "up",
                   min_points_for_stats, 3, 9)

    @classmethod
    def pdal(cls, normal_radius: float, cylinder_radius: float, cylinder_half_length: float,
             registration_error: float = 0.0, min_points: int = 1) -> "M3C2Params":
        """PDAL ``filters.m3c2`` behaviour: exact normals, ``min_points`` (default 1) for statistics."""
        return cls(normal_radius, cylinder_radius, cylinder_half_length, registration_error, "up",
                   min_points, 3, None)

    def __post_init__(self) -> None:
        for name in ("normal_radius", "cylinder_radius", "cylinder_half_length"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise InputFormatError(f"must be a positive length, got {v!r}", field=name)
        if not (np.isfinite(self.registration_error) and self.registration_error >= 0):
            raise InputFormatError(f"must be >= 0, got {self.registration_error!r}", field="registration_error")


@dataclass(frozen=True, eq=False)
class M3C2Result:
    """M3C2 results at ``M`` core points (NaN / 0 where undefined).

    Attributes
    ----------
    core
        ``(M, 3)`` core points.
    normal
        ``(M, 3)`` unit normals (NaN where ``normal_valid`` is False).
    normal_valid
        ``(M,)`` whether the normal sphere held enough cloud-1 points.
    distance_m
        ``(M,)`` M3C2 distance ``i2 - i1`` along the normal (cloud 2 minus cloud 1).
    uncertainty_m
        ``(M,)`` level of detection at 95 % (``LoD95``).
    significant
        ``(M,)`` ``|distance| > LoD95``.
    std1_m, std2_m
        ``(M,)`` standard deviation of the positions along the normal in each cylinder.
    count1, count2
        ``(M,)`` points of each cloud in the cylinder.
    """

    core: NDArray[np.float64]
    normal: NDArray[np.float64]
    normal_valid: NDArray[np.bool_]
    distance_m: NDArray[np.float64]
    uncertainty_m: NDArray[np.float64]
    significant: NDArray[np.bool_]
    std1_m: NDArray[np.float64]
    std2_m: NDArray[np.float64]
    count1: NDArray[np.intp]
    count2: NDArray[np.intp]

    def __len__(self) -> int:
        return int(self.core.shape[0])


def _cylinder_stats(core: NDArray[np.float64], normal: NDArray[np.float64], cloud: NDArray[np.float64],
                    tree: cKDTree, radius: float, half: float) -> tuple[NDArray, NDArray, NDArray]:
    m = len(core)
    ball = float(np.hypot(radius, half))
    owner, idx = _flatten_neighbours(tree.query_ball_point(core, ball), m)
    d = cloud[idx] - core[owner]
    s = np.einsum("ij,ij->i", d, normal[owner])
    r2 = np.einsum("ij,ij->i", d, d) - s * s
    inside = (r2 <= radius * radius) & (np.abs(s) <= half)
    owner, s = owner[inside], s[inside]
    n = np.bincount(owner, minlength=m)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.bincount(owner, s, minlength=m) / n
        var = np.bincount(owner, (s - mean[owner]) ** 2, minlength=m) / n
    return n, mean, np.sqrt(var)


def m3c2(
    cloud1: ArrayLike,
    cloud2: ArrayLike,
    core: ArrayLike,
    params: M3C2Params,
    chunk: int = 20_000,
) -> M3C2Result:
    """M3C2 distances from cloud 1 (reference epoch) to cloud 2 (compared epoch) at core points.

    Parameters
    ----------
    cloud1, cloud2
        ``(N1, 3)``, ``(N2, 3)`` point clouds (metres, one Cartesian frame).
    core
        ``(M, 3)`` core points (often a subsample of cloud 1).
    params
        See :class:`M3C2Params`.
    chunk
        Core points per batch (bounds memory).

    Returns
    -------
    M3C2Result
        Distances are positive where cloud 2 lies on the side the normal points to.
    """
    c1 = _points("cloud1", cloud1)
    c2 = _points("cloud2", cloud2)
    cp = _points("core", core)
    if len(c1) < 3 or len(c2) == 0:
        raise GeometryError(f"M3C2 needs at least 3 points in cloud 1 and 1 in cloud 2, got {len(c1)} and {len(c2)}")
    t1, t2 = cKDTree(c1), cKDTree(c2)
    m = len(cp)
    out = {k: np.full(m, np.nan) for k in ("dist", "lod", "sd1", "sd2")}
    normal = np.full((m, 3), np.nan)
    n1 = np.zeros(m, np.intp)
    n2 = np.zeros(m, np.intp)
    orient = params.orientation if isinstance(params.orientation, str) else np.asarray(params.orientation, float)
    for a in range(0, m, chunk):
        q = cp[a:a + chunk]
        sl = slice(a, a + len(q))
        nrm, _ = local_normals(q, c1, params.normal_radius, orient, params.normal_min_points, tree=t1)
        if params.normal_quantization is not None:
            fin = np.isfinite(nrm[:, 0])
            nrm[fin] = quantize_normals(nrm[fin], params.normal_quantization)
        normal[sl] = nrm
        ok = np.isfinite(nrm[:, 0])
        if not np.any(ok):
            continue
        qa, na = q[ok], nrm[ok]
        k1, m1, s1 = _cylinder_stats(qa, na, c1, t1, params.cylinder_radius, params.cylinder_half_length)
        k2, m2, s2 = _cylinder_stats(qa, na, c2, t2, params.cylinder_radius, params.cylinder_half_length)
        dist = np.where((k1 > 0) & (k2 > 0), m2 - m1, np.nan)
        enough = (k1 >= params.min_points_for_stats) & (k2 >= params.min_points_for_stats)
        with np.errstate(invalid="ignore", divide="ignore"):
            lod = 1.96 * (np.sqrt(s1**2 / k1 + s2**2 / k2) + params.registration_error)
        lod = np.where(enough, lod, np.nan)
        rows = np.flatnonzero(ok) + a
        out["dist"][rows], out["lod"][rows] = dist, lod
        out["sd1"][rows], out["sd2"][rows] = s1, s2
        n1[rows], n2[rows] = k1, k2
    valid = np.isfinite(normal[:, 0])
    with np.errstate(invalid="ignore"):
        significant = np.abs(out["dist"]) > out["lod"]
    if np.any(~valid):
        logger.info("M3C2: %d of %d core points have fewer than %d cloud-1 points within the normal radius %.3f m",
                    int((~valid).sum()), m, params.normal_min_points, params.normal_radius)
    return M3C2Result(cp, normal, valid, out["dist"], out["lod"], significant, out["sd1"], out["sd2"], n1, n2)


# --------------------------------------------------------------------------- statistics
@dataclass(frozen=True)
class DistanceStatistics:
    """Summary of distances (metres); NaNs are excluded and counted.

    Attributes
    ----------
    count, n_undefined
        Finite distances used, NaN distances left out.
    mean_m, std_m, rms_m, min_m, max_m, median_m
        Of the signed values (``std`` with divisor ``n - 1``).
    mean_abs_m
        Mean of absolute values.
    p68_abs_m
        68th percentile of absolute values: paper 002's "2/3 of all points have deviations less than".
    p95_abs_m
        95th percentile of absolute values.
    percentiles_abs_m
        Further percentiles of the absolute values, ``{percent: value}``.
    """

    count: int
    n_undefined: int
    mean_m: float
    std_m: float
    rms_m: float
    min_m: float
    max_m: float
    median_m: float
    mean_abs_m: float
    p68_abs_m: float
    p95_abs_m: float
    percentiles_abs_m: dict[float, float] = field(default_factory=dict)

    def as_dict(self) -> dict[str, object]:
        d = {k: getattr(self, k) for k in ("count", "n_undefined", "mean_m", "std_m", "rms_m", "min_m", "max_m",
                                           "median_m", "mean_abs_m", "p68_abs_m", "p95_abs_m")}
        d["percentiles_abs_m"] = {str(k): v for k, v in self.percentiles_abs_m.items()}
        return d


def distance_statistics(distances: ArrayLike, percentiles: Sequence[float] = (50, 68, 90, 95, 99)) -> DistanceStatistics:
    """Statistics of distances ``(N,)`` (metres); raises GeometryError when none is finite."""
    d = np.asarray(distances, dtype=np.float64).ravel()
    fin = np.isfinite(d)
    v = d[fin]
    if v.size == 0:
        raise GeometryError("no finite distance to summarise")
    a = np.abs(v)
    pct = {float(p): float(np.percentile(a, p)) for p in percentiles}
    return DistanceStatistics(
        count=int(v.size), n_undefined=int((~fin).sum()), mean_m=float(v.mean()),
        std_m=float(v.std(ddof=1)) if v.size > 1 else 0.0, rms_m=float(np.sqrt(np.mean(v * v))),
        min_m=float(v.min()), max_m=float(v.max()), median_m=float(np.median(v)), mean_abs_m=float(a.mean()),
        p68_abs_m=float(np.percentile(a, 68.0)), p95_abs_m=float(np.percentile(a, 95.0)), percentiles_abs_m=pct,
    )


def histogram(distances: ArrayLike, bins: int = 50, absolute: bool = True,
              range_m: tuple[float, float] | None = None) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """Histogram ``(counts (bins,), edges (bins + 1,))`` of the finite (absolute) distances."""
    d = np.asarray(distances, dtype=np.float64).ravel()
    d = d[np.isfinite(d)]
    if absolute:
        d = np.abs(d)
    counts, edges = np.histogram(d, bins=bins, range=range_m)
    return counts, edges
