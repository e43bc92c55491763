"""Least-squares matching (LSM): sub-pixel refinement of tie points with an affine geometric and a linear
radiometric model (Gruen 1985), vectorised over all points of an image pair.

For every tie (x1 in image 1, x2 in image 2) a square template around x1 (image 1, bilinear) is matched to
image 2 under ``x2' = x2 + t + A d`` (``d`` the template offsets) and ``g2 = r0 + r1 g1``; Gauss-Newton on the
8 unknowns per point.  x1 stays fixed, so the refined x2 is the sub-pixel homologue of x1.
The initial affine ``A`` matters for nadir-oblique pairs: :func:`local_affine` estimates it from neighbouring
matches.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree


@dataclass(frozen=True)
class LsmResult:
    """Refined image-2 positions.

    Attributes
    ----------
    xy2
        ``(N, 2)`` refined pixels (unrefined where ``ok`` is false).
    ok
        ``(N,)`` converged, inside the image, shift below the limit, correlation above the limit.
    sigma_px
        ``(N,)`` formal standard deviation of the position (mean of the two axes), pixels.
    correlation
        ``(N,)`` correlation of the template with the final warped patch.
    """

    xy2: NDArray[np.float64]
    ok: NDArray[np.bool_]
    sigma_px: NDArray[np.float64]
    correlation: NDArray[np.float64]


def local_affine(xy1: NDArray, xy2: NDArray, k: int = 12) -> NDArray[np.float64]:
    """Per-match ``(N, 2, 2)`` linear part of the affine map image 1 -> image 2 from the k nearest matches."""
    xy1 = np.asarray(xy1, dtype=np.float64)
    xy2 = np.asarray(xy2, dtype=np.float64)
    n = len(xy1)
    if n < 4:
        return np.broadcast_to(np.eye(2), (n, 2, 2)).copy()
    kk = min(k, n)
    _, idx = cKDTree(xy1).query(xy1, k=kk)
    a = xy1[idx] - xy1[idx].mean(axis=1, keepdims=True)  # (N, k, 2)
    b = xy2[idx] - xy2[idx].mean(axis=1, keepdims=True)
    ata = np.einsum("nki,nkj->nij", a, a) + 1e-9 * np.eye(2)
    atb = np.einsum("nki,nkj->nij", a, b)
    M = np.linalg.solve(ata, atb)  # b ~ a @ M  => A = M^T
    A = np.swapaxes(M, 1, 2)
    bad = ~np.all(np.isfinite(A), axis=(1, 2)) | (np.abs(np.linalg.det(A)) < 1e-3)
    A[bad] = np.eye(2)
    return A


def _sample(img: NDArray[np.float32], x: NDArray, y: NDArray) -> NDArray[np.float32]:
    import cv2

    shp = x.shape
    n = x.size
    w = 1024  # remap maps must stay below 32767 rows / columns
    pad = (-n) % w
    mx = np.concatenate([x.reshape(-1), np.full(pad, -1e4)]).astype(np.float32).reshape(-1, w)
    my = np.concatenate([y.reshape(-1), np.full(pad, -1e4)]).astype(np.float32).reshape(-1, w)
    out = cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    return out.reshape(-1)[:n].reshape(shp)


def lsm_refine(
    image1: NDArray, image2: NDArray, xy1: NDArray, xy2: NDArray, affine: NDArray | None = None,
    half_size: int = 7, iterations: int = 30, max_shift_px: float = 3.0, min_correlation: float = 0.7,
) -> LsmResult:
    """Refine ``xy2`` ``(N, 2)`` to the sub-pixel homologue of ``xy1`` ``(N, 2)``.

    Parameters
    ----------
    image1, image2
        Grey images (any dtype), full resolution of the pixel coordinates.
    affine
        ``(N, 2, 2)`` initial linear map image 1 -> image 2 (default identity; see :func:`local_affine`).
    half_size
        Template half width in pixels (template ``2 h + 1`` square).
    max_shift_px
        Refinements that move ``xy2`` further than this are rejected.
    """
    g1 = np.asarray(image1, dtype=np.float32)
    g2 = np.asarray(image2, dtype=np.float32)
    if g1.ndim != 2 or g2.ndim != 2:
        raise ValueError("lsm_refine needs grey (2-D) images")
    import cv2

    gx = cv2.Sobel(g2, cv2.CV_32F, 1, 0, ksize=1) * 0.5  # central difference
    gy = cv2.Sobel(g2, cv2.CV_32F, 0, 1, ksize=1) * 0.5
    xy1 = np.asarray(xy1, dtype=np.float64).reshape(-1, 2)
    x0 = np.asarray(xy2, dtype=np.float64).reshape(-1, 2)
    n = len(xy1)
    r = np.arange(-half_size, half_size + 1, dtype=np.float64)
    dx, dy = [a.reshape(-1) for a in np.meshgrid(r, r)]
    T = _sample(g1, xy1[:, :1] + dx, xy1[:, 1:] + dy).astype(np.float64)  # (N, P)
    A = np.broadcast_to(np.eye(2), (n, 2, 2)).copy() if affine is None else np.array(affine, dtype=np.float64)
    t = np.zeros((n, 2))
    r0 = np.zeros(n)
    r1 = np.ones(n)
    active = np.all(np.isfinite(T), axis=1)
    conv = np.zeros(n, bool)
    cov_diag = np.full((n, 2), np.nan)
    for _ in range(iterations):
        ux = x0[:, :1] + t[:, :1] + A[:, 0, :1] * dx + A[:, 0, 1:] * dy
        uy = x0[:, 1:] + t[:, 1:] + A[:, 1, :1] * dx + A[:, 1, 1:] * dy
        G = _sample(g2, ux, uy).astype(np.float64)
        Gx = _sample(gx, ux, uy).astype(np.float64)
        Gy = _sample(gy, ux, uy).astype(np.float64)
        fin = np.all(np.isfinite(G), axis=1) & np.all(np.isfinite(Gx), axis=1)
        active &= fin
        J = np.stack([Gx, Gy, Gx * dx, Gx * dy, Gy * dx, Gy * dy, -np.ones_like(G), -T], axis=-1)  # (N,P,8)
        res = -(G - r0[:, None] - r1[:, None] * T)
        J = np.where(active[:, None, None], J, 0.0)
        res = np.where(active[:, None], res, 0.0)
        N_ = np.einsum("npi,npj->nij", J, J) + 1e-9 * np.eye(8)
        b = np.einsum("npi,np->ni", J, res)
        try:
            dp = np.linalg.solve(N_, b[..., None])[..., 0]
        except np.linalg.LinAlgError:
            dp = np.zeros((n, 8))
        dp[~active] = 0
        t += dp[:, :2]
        A[:, 0, 0] += dp[:, 2]
        A[:, 0, 1] += dp[:, 3]
        A[:, 1, 0] += dp[:, 4]
        A[:, 1, 1] += dp[:, 5]
        r0 += dp[:, 6]
        r1 += dp[:, 7]
        if np.all(np.abs(dp[active, :2]).max(axis=1, initial=0) < 1e-4):
            conv = active.copy()
            s0 = np.sum(res**2, axis=1) / max(len(dx) - 8, 1)
            with np.errstate(invalid="ignore"):
                cov_diag = np.stack([np.linalg.inv(N_)[:, 0, 0], np.linalg.inv(N_)[:, 1, 1]], -1) * s0[:, None]
            break
        conv = active & (np.abs(dp[:, :2]).max(axis=1) < 1e-3)
        s0 = np.sum(res**2, axis=1) / max(len(dx) - 8, 1)
        with np.errstate(invalid="ignore"):
            Ni = np.linalg.inv(N_)
            cov_diag = np.stack([Ni[:, 0, 0], Ni[:, 1, 1]], -1) * s0[:, None]
    ux = x0[:, :1] + t[:, :1] + A[:, 0, :1] * dx + A[:, 0, 1:] * dy
    uy = x0[:, 1:] + t[:, 1:] + A[:, 1, :1] * dx + A[:, 1, 1:] * dy
    G = _sample(g2, ux, uy).astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        Tc = T - T.mean(axis=1, keepdims=True)
        Gc = G - G.mean(axis=1, keepdims=True)
        corr = np.sum(Tc * Gc, axis=1) / np.sqrt(np.sum(Tc**2, axis=1) * np.sum(Gc**2, axis=1))
    shift = np.linalg.norm(t, axis=1)
    ok = conv & (shift <= max_shift_px) & (corr >= min_correlation) & np.isfinite(corr)
    out = np.where(ok[:, None], x0 + t, x0)
    sigma = np.sqrt(np.mean(np.abs(cov_diag), axis=1))
    return LsmResult(out, ok, sigma, np.nan_to_num(corr, nan=-1.0))


def refine_tracks(
    track: NDArray, image: NDArray, xy_obs: NDArray, load_image: "object", half_size: int = 7,
    min_correlation: float = 0.7,
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """LSM-refine every observation of multi-image tracks against the track's reference observation.

    The reference of a track is its first observation (kept fixed); each other observation is refined as the
    homologue of the reference, with the initial affine from neighbouring ties of the same image pair.

    Parameters
    ----------
    track, image
        ``(K,)`` track id and image index of every observation.
    xy_obs
        ``(K, 2)`` observation pixels.
    load_image
        Callable ``index -> grey image``; called once per image involved.

    Returns
    -------
    xy
        ``(K, 2)`` refined pixels (unchanged where refinement failed and for references).
    refined
        ``(K,)`` whether the observation was refined (references count as refined).
    """
    track = np.asarray(track)
    image = np.asarray(image)
    xy = np.asarray(xy_obs, dtype=np.float64).copy()
    order = np.lexsort((np.arange(len(track)), track))
    first = np.ones(len(track), bool)
    first[order[1:]] = track[order[1:]] != track[order[:-1]]
    ref_row = np.empty(int(track.max()) + 1 if len(track) else 0, np.int64)
    ref_row[track[first]] = np.nonzero(first)[0]
    refined = first.copy()
    rows = np.nonzero(~first)[0]
    ref = ref_row[track[rows]]
    cache: dict[int, NDArray] = {}

    def get(i: int) -> NDArray:
        if i not in cache:
            if len(cache) > 8:
                cache.pop(next(iter(cache)))
            cache[i] = load_image(i)  # type: ignore[operator]
        return cache[i]

    pair_key = image[ref] * (int(image.max()) + 1) + image[rows]
    for key in np.unique(pair_key):
        sel = pair_key == key
        r_rows, o_rows = ref[sel], rows[sel]
        ia, ib = int(image[r_rows[0]]), int(image[o_rows[0]])
        x1, x2 = xy_obs[r_rows], xy_obs[o_rows]
        res = lsm_refine(get(ia), get(ib), x1, x2, local_affine(x1, x2), half_size=half_size,
                         min_correlation=min_correlation)
        xy[o_rows] = res.xy2
        refined[o_rows] = res.ok
    return xy, refined
