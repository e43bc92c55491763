"""Similarity transforms between camera centres or points of two frames (layer 2b): a robust fit with trimming
(a free-network or relative-orientation block onto GNSS positions) and the comparison of two reconstructions."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Sequence

import numpy as np
from numpy.typing import NDArray

from skyrig.errors import GeometryError

if TYPE_CHECKING:
    from skyrig.orient.gnss_block import UavResult

__all__ = ["robust_similarity", "compare_with_reconstruction"]


_MIN_COMMON = 12


def _robust_similarity(src: NDArray[np.float64], dst: NDArray[np.float64]
                       ) -> tuple[float, NDArray[np.float64], NDArray[np.float64], int] | None:
    """Similarity ``dst ~ s R src + t`` with iterative trimming (points farther than 3 x 1.4826 x the median
    distance leave); None if fewer than ``_MIN_COMMON`` points survive or the fit stays poor (inlier residual median above 5 % of the spread)."""
    from skyrig.match.colmap_check import similarity_transform

    keep = np.ones(len(src), bool)
    for _ in range(10):
        if keep.sum() < _MIN_COMMON:
            return None
        sc, Rs, ts = similarity_transform(src[keep], dst[keep])
        res = np.linalg.norm(sc * src @ Rs.T + ts - dst, axis=1)
        thr = 3.0 * 1.4826 * float(np.median(res[keep])) + 1e-9
        new = res <= thr
        if np.array_equal(new, keep):
            break
        keep = new
    spread = float(np.sqrt(np.mean(np.sum((dst[keep] - dst[keep].mean(axis=0)) ** 2, axis=1))))
    if keep.sum() < _MIN_COMMON or not float(np.median(res[keep])) < 0.05 * spread:
        return None
    return float(sc), Rs, ts, int(keep.sum())


def robust_similarity(src: NDArray[np.float64], dst: NDArray[np.float64]
                      ) -> tuple[float, NDArray[np.float64], NDArray[np.float64], int] | None:
    """Public name of the trimmed similarity fit ``dst ~ s R src + t``: ``(s, R, t, inliers)`` or None."""
    return _robust_similarity(src, dst)


def compare_with_reconstruction(result: UavResult, other_names: Sequence[str], other_centres: NDArray,
                                gnss: NDArray | None = None) -> dict[str, Any]:
    """Camera centres of another reconstruction (e.g. pycolmap's own, arbitrary frame) against the adjusted ones
    after a similarity transform (Umeyama) of the other onto the adjusted; also the other's fit to GNSS.

    Returns a dict with ``common``, ``scale``, ``rms_m``, ``max_m``, ``rms_enu_m`` and, with ``gnss``,
    ``other_gnss_fit_rms_3d_m`` (similarity of the other's centres onto GNSS) and ``ours_gnss_similarity_rms_3d_m``
    (the same for the adjusted centres, for a like-for-like comparison).
    """
    from skyrig.match.colmap_check import similarity_transform

    idx = {str(n): k for k, n in enumerate(result.names)}
    common = [(k, idx[str(n)]) for k, n in enumerate(other_names) if str(n) in idx and result.oriented[idx[str(n)]]]
    if len(common) < 3:
        raise GeometryError("fewer than 3 common oriented images: no similarity transform")
    a = np.asarray(other_centres, float)[[c[0] for c in common]]
    b = result.centre[[c[1] for c in common]]
    s, Rm, t = similarity_transform(a, b)
    d = s * a @ Rm.T + t - b
    out: dict[str, Any] = {
        "common": len(common), "scale": s, "rms_m": float(np.sqrt(np.mean(np.sum(d ** 2, 1)))),
        "max_m": float(np.linalg.norm(d, axis=1).max()), "rms_enu_m": np.sqrt(np.mean(d ** 2, axis=0)).tolist(),
        "per_image_m": {str(result.names[c[1]]): float(np.linalg.norm(d[k])) for k, c in enumerate(common)}}
    if gnss is not None:
        g = np.asarray(gnss, float)[[c[1] for c in common]]
        s2, R2, t2 = similarity_transform(a, g)
        out["other_gnss_fit_rms_3d_m"] = float(np.sqrt(np.mean(np.sum((s2 * a @ R2.T + t2 - g) ** 2, 1))))
        s3, R3, t3 = similarity_transform(b, g)
        out["ours_gnss_similarity_rms_3d_m"] = float(np.sqrt(np.mean(np.sum((s3 * b @ R3.T + t3 - g) ** 2, 1))))
    return out
