"""Point-cloud registration: coarse alignment from homologous points, fine alignment by ICP.

* :func:`fit_transform` -- rigid (6 parameters) or similarity (7) transformation from ``>= 3``
  homologous points by the closed-form least-squares solution (Umeyama 1991), with residuals; collinear
  or coincident points are rejected (:class:`~skyrig.errors.GeometryError`).
* :func:`icp` -- iterative closest point, point-to-point or point-to-plane, by Open3D
  (``open3d.pipelines.registration.registration_icp``) or, where Open3D is not installed, by skyrig's
  own scipy implementation of the same two objectives (``backend="scipy"``).  Returns the final
  transform, the inlier RMSE and the overlap (fraction of source points with a correspondence within
  ``max_correspondence_distance``, Open3D's "fitness").

Transforms are ``target_from_source`` 4x4 matrices: ``x_t = s R x_s + t``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from skyrig.errors import GeometryError, InputFormatError
from skyrig.geometry.rotations import matrix_from_rotvec

logger = logging.getLogger(__name__)

__all__ = ["IcpResult", "TransformFit", "apply_transform", "fit_transform", "icp"]


def _pts(name: str, a: ArrayLike) -> NDArray[np.float64]:
    p = np.asarray(a, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or not np.all(np.isfinite(p)):
        raise InputFormatError(f"expected a finite (N, 3) array, got shape {p.shape}", field=name)
    return p


def apply_transform(matrix: ArrayLike, points: ArrayLike) -> NDArray[np.float64]:
    """``(N, 3)`` points mapped by a 4x4 ``target_from_source`` matrix."""
    m = np.asarray(matrix, dtype=np.float64)
    return _pts("points", points) @ m[:3, :3].T + m[:3, 3]


@dataclass(frozen=True, eq=False)
class TransformFit:
    """A fitted ``target_from_source`` transformation.

    Attributes
    ----------
    matrix
        ``(4, 4)``: ``[[s R, t], [0, 1]]``.
    scale
        ``s`` (1 for a rigid fit).
    residuals
        ``(N, 3)`` ``target - transformed source`` (metres).
    rms_m
        RMS of the residual vector lengths.
    sigma0_m
        Standard deviation of unit weight per coordinate, ``sqrt(sum r^2 / (3N - u))`` (NaN when no redundancy).
    """

    matrix: NDArray[np.float64]
    scale: float
    residuals: NDArray[np.float64]
    rms_m: float
    sigma0_m: float

    @property
    def rotation(self) -> NDArray[np.float64]:
        return self.matrix[:3, :3] / self.scale

    @property
    def translation(self) -> NDArray[np.float64]:
        return self.matrix[:3, 3].copy()


def fit_transform(source: ArrayLike, target: ArrayLike, similarity: bool = False) -> TransformFit:
    """Least-squares rigid or similarity transform from homologous points (Umeyama).

    Parameters
    ----------
    source, target
        ``(N, 3)`` homologous points, ``N >= 3``, not collinear.
    similarity
        Also estimate a scale.

    Raises
    ------
    GeometryError
        Fewer than 3 points, or points (nearly) collinear / coincident.
    """
    a, b = _pts("source", source), _pts("target", target)
    if a.shape != b.shape:
        raise InputFormatError(f"source and target differ in shape: {a.shape} vs {b.shape}", field="target")
    n = len(a)
    if n < 3:
        raise GeometryError(f"a transformation needs at least 3 homologous points, got {n}")
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    da, db = a - ca, b - cb
    sv = np.linalg.svd(da, compute_uv=False)
    if sv[1] <= 1e-9 * max(sv[0], 1e-300) or sv[0] == 0:
        raise GeometryError("the homologous points are collinear or coincident: the rotation about their line is undetermined")
    cov = db.T @ da / n
    u, d, vt = np.linalg.svd(cov)
    sgn = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sgn[2] = -1.0
    r = u @ np.diag(sgn) @ vt
    s = float((d * sgn).sum() / (np.sum(da**2) / n)) if similarity else 1.0
    t = cb - s * r @ ca
    m = np.eye(4)
    m[:3, :3] = s * r
    m[:3, 3] = t
    res = b - apply_transform(m, a)
    u_par = 7 if similarity else 6
    red = 3 * n - u_par
    s0 = float(np.sqrt(np.sum(res**2) / red)) if red > 0 else float("nan")
    return TransformFit(m, s, res, float(np.sqrt(np.mean(np.sum(res**2, axis=1)))), s0)


@dataclass(frozen=True, eq=False)
class IcpResult:
    """Result of :func:`icp`.

    Attributes
    ----------
    matrix
        ``(4, 4)`` ``target_from_source``.
    rmse_m
        RMS of the inlier correspondence distances (point-to-point) after the last iteration.
    fitness
        Overlap: fraction of source points with a target point within ``max_correspondence_distance``.
    iterations
        Iterations run (scipy backend; Open3D does not report them: -1).
    backend
        ``"open3d"`` or ``"scipy"``.
    """

    matrix: NDArray[np.float64]
    rmse_m: float
    fitness: float
    iterations: int
    backend: str


def _normals(points: NDArray[np.float64], k: int, tree: cKDTree) -> NDArray[np.float64]:
    _, idx = tree.query(points, k=k)
    nb = points[idx]
    dev = nb - nb.mean(axis=1, keepdims=True)
    _, v = np.linalg.eigh(np.einsum("nki,nkj->nij", dev, dev))
    return v[:, :, 0]


def _icp_scipy(src, tgt, init, method, max_dist, max_iter, k, tol):
    tree = cKDTree(tgt)
    normals = _normals(tgt, k, tree) if method == "point_to_plane" else None
    m = init.copy()
    it = 0
    for it in range(1, max_iter + 1):
        x = src @ m[:3, :3].T + m[:3, 3]
        d, j = tree.query(x, distance_upper_bound=max_dist)
        ok = np.isfinite(d)
        if ok.sum() < 6:
            raise GeometryError(f"ICP: only {int(ok.sum())} correspondences within {max_dist} m")
        xs, y = x[ok], tgt[j[ok]]
        if method == "point_to_point":
            step = fit_transform(xs, y).matrix
        else:
            nn = normals[j[ok]]
            a = np.concatenate([np.cross(xs, nn), nn], axis=1)
            r = np.einsum("ij,ij->i", xs - y, nn)
            sol = np.linalg.lstsq(a, -r, rcond=None)[0]
            step = np.eye(4)
            step[:3, :3] = matrix_from_rotvec(sol[:3])
            step[:3, 3] = sol[3:]
        m = step @ m
        if np.abs(step - np.eye(4)).max() < tol:
            break
    x = src @ m[:3, :3].T + m[:3, 3]
    d, _ = tree.query(x, distance_upper_bound=max_dist)
    ok = np.isfinite(d)
    rmse = float(np.sqrt(np.mean(d[ok] ** 2))) if ok.any() else float("nan")
    return IcpResult(m, rmse, float(ok.mean()), it, "scipy")


def icp(
    source: ArrayLike,
    target: ArrayLike,
    init: ArrayLike | None = None,
    method: Literal["point_to_point", "point_to_plane"] = "point_to_plane",
    max_correspondence_distance: float = 1.0,
    max_iterations: int = 50,
    normal_k: int = 16,
    backend: Literal["auto", "open3d", "scipy"] = "auto",
    tolerance: float = 1e-8,
) -> IcpResult:
    """Fine registration of ``source`` onto ``target`` by ICP.

    Parameters
    ----------
    source, target
        ``(N, 3)`` and ``(M, 3)`` clouds (metres).  Work relative to a local origin (e.g. subtract the
        target's centroid) when coordinates are large: Open3D computes in double precision but its
        normals and thresholds are absolute.
    init
        ``(4, 4)`` starting ``target_from_source`` (e.g. :func:`fit_transform` from 3 homologous points).
    method
        ``"point_to_point"`` or ``"point_to_plane"`` (target normals from ``normal_k`` neighbours).
    max_correspondence_distance
        Pairs farther apart are ignored (metres).
    max_iterations, tolerance
        Stopping rules.
    backend
        ``"open3d"``, ``"scipy"``, or ``"auto"`` (Open3D when importable).
    """
    src, tgt = _pts("source", source), _pts("target", target)
    m0 = np.eye(4) if init is None else np.asarray(init, dtype=np.float64)
    if method not in ("point_to_point", "point_to_plane"):
        raise InputFormatError(f"method must be 'point_to_point' or 'point_to_plane', not {method!r}", field="method")
    if backend in ("auto", "open3d"):
        try:
            import open3d as o3d  # noqa: PLC0415
        except ImportError:
            if backend == "open3d":
                raise
            backend = "scipy"
        else:
            reg = o3d.pipelines.registration
            ps, pt = o3d.geometry.PointCloud(), o3d.geometry.PointCloud()
            ps.points = o3d.utility.Vector3dVector(src)
            pt.points = o3d.utility.Vector3dVector(tgt)
            if method == "point_to_plane":
                pt.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(normal_k))
                est = reg.TransformationEstimationPointToPlane()
            else:
                est = reg.TransformationEstimationPointToPoint()
            crit = reg.ICPConvergenceCriteria(relative_fitness=tolerance, relative_rmse=tolerance,
                                              max_iteration=max_iterations)
            r = reg.registration_icp(ps, pt, max_correspondence_distance, m0, est, crit)
            if r.fitness == 0:
                raise GeometryError(f"ICP: no correspondence within {max_correspondence_distance} m")
            return IcpResult(np.asarray(r.transformation), float(r.inlier_rmse), float(r.fitness), -1, "open3d")
    return _icp_scipy(src, tgt, m0, method, max_correspondence_distance, max_iterations, normal_k, tolerance)
