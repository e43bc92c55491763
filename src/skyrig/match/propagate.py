"""Propagation of a point measured in one image to another by its appearance: the template around the measurement,
warped by the local linear map between the two views, is searched by normalised cross-correlation around the
geometric prediction, then refined by least-squares matching with an affine model (:func:`skyrig.match.lsm.lsm_refine`).

What a user does with a natural point (a corner of a building, a mark on a kerb): measure it once, and have it found
in the other images on the same feature, even where the orientations are a few pixels off (a prediction from the
orientations, however good, reproduces their errors; a match by appearance does not).

The local linear map image A -> image B (scale, rotation, shear between the views) comes from candidates, the one
whose match correlates best wins:

* planes through the point (:func:`plane_maps`): with the point's Jacobians ``d(col, row) / d(X)`` in both images,
  the map induced by a plane of basis ``U`` is ``(J_B U) (J_A U)^-1``; the planes tried are the ground (level), the
  plane facing both cameras (normal along the bisector of the two rays) and the vertical plane facing them (a
  facade);
* the identity.

The match is refused (``ok`` false, with the reason) where the final correlation is below ``min_correlation``, where
the cross-correlation peak is not unique (a second peak outside the template's own footprint within
``ambiguity`` of the best: a repeated pattern), or where the least-squares matching moves more than its limit from
the cross-correlation peak.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from skyrig.match.lsm import _sample, lsm_refine

__all__ = ["Propagation", "plane_maps", "propagate_point", "search_lsm"]


@dataclass(frozen=True)
class Propagation:
    """The homologue in image B of a point of image A.

    Attributes
    ----------
    xy
        ``(2,)`` pixel in image B (the start where ``ok`` is false).
    ok
        Found: correlation above the threshold, unique, converged.
    sigma_px
        Formal standard deviation of the position (least-squares matching), pixels.
    correlation
        Correlation of the template with the final warped patch (-1 when nothing converged).
    source
        Which candidate map won (``"ground"``, ``"facing"``, ``"facade"``, ``"identity"``, or the caller's names).
    note
        What was found or why it was refused, in words.
    tried
        Every candidate's cross-correlation peak and its runner-up, final correlation, position and outcome.
    """

    xy: NDArray[np.float64]
    ok: bool
    sigma_px: float
    correlation: float
    source: str
    note: str
    tried: dict = field(default_factory=dict)


def _basis(n: NDArray) -> NDArray[np.float64]:
    """``(3, 2)`` orthonormal basis of the plane of normal ``n``."""
    n = np.asarray(n, dtype=np.float64)
    n = n / np.linalg.norm(n)
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(n, a)
    u /= np.linalg.norm(u)
    return np.stack([u, np.cross(n, u)], axis=1)


def plane_maps(jac_a: NDArray, jac_b: NDArray, ray_a: NDArray, ray_b: NDArray,
               up: NDArray = np.array([0.0, 0.0, 1.0])) -> dict[str, NDArray[np.float64]]:
    """Linear maps image A -> image B ``{name: (2, 2)}`` induced by planes through the point.

    ``jac_a``, ``jac_b``: ``(2, 3)`` Jacobians of the pixel with respect to the point (any Cartesian frame);
    ``ray_a``, ``ray_b``: ``(3,)`` directions from the projection centres to the point in that frame; ``up`` the
    frame's vertical.  Planes: ``ground`` (level), ``facing`` (normal along the bisector of the two rays),
    ``facade`` (vertical, facing the cameras); a plane seen edge-on by either camera is left out."""
    ra = np.asarray(ray_a, dtype=np.float64) / np.linalg.norm(ray_a)
    rb = np.asarray(ray_b, dtype=np.float64) / np.linalg.norm(ray_b)
    up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    bis = ra + rb
    hor = bis - (bis @ up) * up
    normals = {"ground": up, "facing": bis}
    if np.linalg.norm(hor) > 1e-6 * np.linalg.norm(bis):
        normals["facade"] = hor
    out = {}
    for name, n in normals.items():
        if np.linalg.norm(n) < 1e-12:
            continue
        nn = n / np.linalg.norm(n)
        if min(abs(nn @ ra), abs(nn @ rb)) < 0.1:  # grazing (within ~6 degrees of edge-on) in one of the views
            continue
        U = _basis(nn)
        pa, pb = np.asarray(jac_a) @ U, np.asarray(jac_b) @ U
        if abs(np.linalg.det(pa)) < 1e-12:
            continue
        M = pb @ np.linalg.inv(pa)
        if np.all(np.isfinite(M)) and abs(np.linalg.det(M)) > 1e-6:
            out[name] = M
    return out


def _peaks(ncc: NDArray, exclude: int) -> tuple[tuple[int, int], float, float]:
    """Best peak ``(x, y)``, its value and the best value outside ``exclude`` px of it."""
    import cv2

    _, best, _, (mx, my) = cv2.minMaxLoc(ncc)
    masked = ncc.copy()
    masked[max(my - exclude, 0):my + exclude + 1, max(mx - exclude, 0):mx + exclude + 1] = -1.0
    second = float(masked.max()) if masked.size else -1.0
    return (mx, my), float(best), second


def _subpixel(ncc: NDArray, mx: int, my: int) -> tuple[float, float]:
    """Parabola through the peak and its neighbours, each axis."""
    def one(a, b, c):
        d = a - 2 * b + c
        return 0.0 if d >= 0 else float(np.clip(0.5 * (a - c) / d, -0.5, 0.5))

    h, w = ncc.shape
    dx = one(ncc[my, mx - 1], ncc[my, mx], ncc[my, mx + 1]) if 0 < mx < w - 1 else 0.0
    dy = one(ncc[my - 1, mx], ncc[my, mx], ncc[my + 1, mx]) if 0 < my < h - 1 else 0.0
    return mx + dx, my + dy


def propagate_point(
    image_a: NDArray, xy_a: NDArray, image_b: NDArray, xy_b: NDArray, search_px: float,
    maps: dict[str, NDArray], half_size: int = 12, min_correlation: float = 0.8, ambiguity: float | None = 0.03,
    lsm_shift_px: float = 3.0, identity: bool = True,
) -> Propagation:
    """The homologue in ``image_b`` of ``xy_a`` of ``image_a`` within ``search_px`` of ``xy_b`` (module docstring).

    ``maps``: candidate ``(2, 2)`` linear maps A -> B by name (the identity added when ``identity``).
    ``half_size``: the template's half width in image B's pixels.  Every candidate is searched (normalised
    cross-correlation of the warped template, OpenCV ``matchTemplate``, over the disc of ``search_px`` around
    ``xy_b``; the peak to a parabola's sub-pixel) and refined (least-squares matching, at most ``lsm_shift_px``
    from the peak); the refined match of the highest correlation wins.  ``search_px`` 0: no search, least-squares
    matching from ``xy_b`` (at most ``lsm_shift_px`` from it).  ``ambiguity``: refuse a match whose correlation
    peak has a runner-up (beyond the template's half width from it) within this of its value; None: no check."""
    import cv2

    g1 = np.asarray(image_a, dtype=np.float32)
    g2 = np.asarray(image_b, dtype=np.float32)
    p1 = np.asarray(xy_a, dtype=np.float64).reshape(2)
    p2 = np.asarray(xy_b, dtype=np.float64).reshape(2)
    s = int(math.ceil(max(search_px, 0.0)))
    h = int(half_size)
    r = np.arange(-h, h + 1, dtype=np.float64)
    ex, ey = np.meshgrid(r, r)
    c2, r2 = int(round(p2[0])), int(round(p2[1]))
    H2, W2 = g2.shape
    a0, b0 = max(c2 - s - h, 0), max(r2 - s - h, 0)
    region = g2[b0:min(r2 + s + h + 1, H2), a0:min(c2 + s + h + 1, W2)]
    cands = {str(k): np.asarray(v, dtype=np.float64) for k, v in maps.items()}
    if identity:
        cands.setdefault("identity", np.eye(2))
    tried: dict[str, dict] = {}
    best: Propagation | None = None
    for name, M in cands.items():
        try:
            Mi = np.linalg.inv(M)
        except np.linalg.LinAlgError:
            tried[name] = {"note": "singular map"}
            continue
        v1, v2, start = float("nan"), float("nan"), p2
        if s > 0:
            tpl = _sample(g1, p1[0] + Mi[0, 0] * ex + Mi[0, 1] * ey, p1[1] + Mi[1, 0] * ex + Mi[1, 1] * ey)
            if not np.all(np.isfinite(tpl)) or region.shape[0] <= tpl.shape[0] or region.shape[1] <= tpl.shape[1]:
                tried[name] = {"note": "template or search region outside the images"}
                continue
            ncc = cv2.matchTemplate(region, tpl.astype(np.float32), cv2.TM_CCOEFF_NORMED)
            yy, xx = np.mgrid[0:ncc.shape[0], 0:ncc.shape[1]]
            ncc = np.where(np.hypot(xx + a0 + h - p2[0], yy + b0 + h - p2[1]) <= s + 0.5, ncc, -1.0)
            (mx, my), v1, v2 = _peaks(ncc, h)
            sx, sy = _subpixel(ncc, mx, my)
            start = np.array([a0 + sx + h, b0 + sy + h])
        res = lsm_refine(g1, g2, p1[None], start[None], M[None], half_size=h, max_shift_px=lsm_shift_px,
                         min_correlation=min_correlation)
        xy, corr = res.xy2[0], float(res.correlation[0])
        tried[name] = {"ncc": round(v1, 3), "second": round(v2, 3), "correlation": round(corr, 3),
                       "ok": bool(res.ok[0]), "xy": [round(float(v), 3) for v in xy]}
        if not res.ok[0]:
            why = (f"correlation {corr:.2f} below {min_correlation:.2f}" if corr < min_correlation else
                   f"least-squares matching did not converge within {lsm_shift_px:g} px of its start")
            cand = Propagation(p2.copy(), False, float("nan"), corr, name, f"{name} map: {why}")
        elif ambiguity is not None and s > 0 and v2 > v1 - ambiguity:
            cand = Propagation(p2.copy(), False, float("nan"), corr, name,
                               f"{name} map: ambiguous, a second correlation peak {v2:.2f} beside {v1:.2f} (a "
                               f"repeated pattern?)")
        else:
            cand = Propagation(xy.copy(), True, float(res.sigma_px[0]), corr, name,
                               f"{name} map, correlation {corr:.2f}" + (f" (next peak {v2:.2f})" if s > 0 else ""))
        if best is None or (cand.ok, cand.correlation) > (best.ok, best.correlation):
            best = cand
    if best is None:
        return Propagation(p2.copy(), False, float("nan"), -1.0, "", "no template could be made", tried)
    return Propagation(best.xy, best.ok, best.sigma_px, best.correlation, best.source, best.note, tried)


def search_lsm(
    image1: NDArray, image2: NDArray, xy1: NDArray, xy2: NDArray, affines: NDArray, search_px: float,
    half_size: int = 10, min_correlation: float = 0.7, max_shift_px: float = 8.0,
) -> tuple[NDArray[np.float64], bool, float, float, int]:
    """Find the homologue of one point ``xy1`` of image 1 in image 2 when the start ``xy2`` may be ``search_px``
    off: for each candidate ``(2, 2)`` linear map of ``affines`` ``(K, 2, 2)`` (image 1 -> image 2), the template
    resampled into image 2's geometry is located by normalised cross-correlation within ``search_px`` of
    ``xy2`` (OpenCV ``matchTemplate``), then refined by :func:`lsm_refine` (shift limit 3 px); the candidate with
    the highest final correlation wins (:func:`propagate_point` without its ambiguity check).

    Returns ``(xy2, ok, sigma_px, correlation, k)`` (``k`` the winning candidate, -1 when none converged)."""
    maps = {str(k): A for k, A in enumerate(np.asarray(affines, dtype=np.float64).reshape(-1, 2, 2))}
    got = propagate_point(image1, xy1, image2, xy2, search_px, maps, half_size=half_size,
                          min_correlation=min_correlation, ambiguity=None,
                          lsm_shift_px=3.0 if math.ceil(max(search_px, 0.0)) > 0 else max_shift_px, identity=False)
    if not got.ok:
        return np.asarray(xy2, dtype=np.float64).reshape(2).copy(), False, float("nan"), -1.0, -1
    return got.xy, True, got.sigma_px, got.correlation, int(got.source)
