"""Image pyramid levels of the dense chain: the image scale it matches at, and the hierarchical search.

Scale
    The dense chain can match images reduced by a power of two (``DenseConfig.image_scale``), as ODM's
    point-cloud quality levels do: ultra 1, high 1/2, medium 1/4, low 1/8, lowest 1/16 (:data:`QUALITY`).
    A level is OpenCV's ``pyrDown`` applied ``level`` times (Gaussian 5 x 5, every second row and column), under
    which the centre of full-resolution pixel ``(c, r)`` lands at ``(c, r) / 2**level`` exactly; the camera of a
    level (:func:`scaled_camera`) keeps the lens (distortion in millimetres, focal length in millimetres) with
    pixels ``2**level`` times larger, so every ray of the level's pixels is the ray of the full image's.
    By default the scale follows the requested DSM cell (:func:`auto_image_scale`): a DSM of 4 GSD cells needs
    no more than a quarter of the pixels.

Hierarchy
    At full resolution the disparity range of a low flight over relief is wider than OpenCV's search can take
    (``SgmConfig.max_disparities``; a camera 40 m above ground sees the ground at ~600 px and a 20 m roof at
    ~1200 px).  As paper 001's hierarchical matching refines the search spaces pyramid level by level, a block
    whose geometric window (its rays through the scene box) is too wide is matched first at a coarse level
    whose window fits; the coarse disparities give the block's window (their 0.1 - 99.9 percentiles, plus one
    coarse pixel and 2 px; disparities stuck at either end of the coarse search are no surface and left out), and
    where the surface inside the block is still deeper than the search allows the block is split in four, each
    part with the window of its own coarse disparities (:func:`refine_windows`), until the window fits or the
    part is :data:`MIN_SPLIT_PX` (48 px) small.  Only then is a window narrowed: to the one that holds the most
    coarse matches; it is counted as *trimmed* when it leaves out at most :data:`TRIM_SHARE` of them (isolated
    mismatches of the coarse level, e.g. at occlusions), as *cut* otherwise.  A part in which the coarse level
    matched (almost) nothing over the whole geometric window (fewer than :data:`MIN_COARSE_SHARE` of its pixels:
    no overlap at the surface's disparity, or no texture at any level) is not matched, and counted.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from skyrig.camera.frame import FrameCamera
from skyrig.errors import SkyrigError

#: ODM's point-cloud quality names and the image scale each matches at
QUALITY = {"ultra": 1.0, "high": 0.5, "medium": 0.25, "low": 0.125, "lowest": 0.0625}
#: the image scales the dense chain matches at (pyramid levels 0 .. 4)
SCALES = tuple(QUALITY.values())
#: smallest side (full-level pixels) of a block part the hierarchy splits further
MIN_SPLIT_PX = 48
#: a block part whose coarse level matched fewer pixels than this share is not matched
MIN_COARSE_SHARE = 0.02
#: a narrowed window that leaves out at most this share of its part's coarse matches is "trimmed", not "cut"
TRIM_SHARE = 0.01


def level_of_scale(scale: float, option: str = "image_scale") -> int:
    """Pyramid level (0 .. 4) of an image scale (1, 0.5, 0.25, 0.125, 0.0625)."""
    for k, s in enumerate(SCALES):
        if abs(float(scale) - s) < 1e-9:
            return k
    raise SkyrigError(f"image scale must be one of {', '.join(f'{s:g}' for s in SCALES)} (ODM's quality levels "
                      f"{', '.join(QUALITY)}), not {scale!r} (option: {option})")


#: without a DSM cell, the automatic scale keeps the images' longer side within this many pixels
AUTO_MAX_SIDE_PX = 2048


def auto_image_scale(gsd_m: float, cell_m: float | None, side_px: int | None = None) -> float:
    """The smallest image scale whose ground sample distance (``gsd_m / scale``) is still no larger than the DSM
    cell (one matched pixel per cell and pair).  Without a cell: the largest scale at which the images' longer
    side ``side_px`` is at most :data:`AUTO_MAX_SIDE_PX` (a 4000 x 2250 px UAV image is matched at 0.5, a 640 px
    one at 1; as ODM matches at a reduced "quality" by default), 1 without ``side_px``."""
    if cell_m is None:
        if side_px is None:
            return 1.0
        fits = [s for s in SCALES if side_px * s <= AUTO_MAX_SIDE_PX]
        return max(fits) if fits else SCALES[-1]
    if not gsd_m > 0:
        return 1.0
    need = gsd_m / float(cell_m) * (1.0 - 1e-9)
    fits = [s for s in SCALES if s >= need]
    return min(fits) if fits else 1.0


def scaled_camera(cam: FrameCamera, level: int) -> FrameCamera:
    """The camera of pyramid level ``level`` (``pyrDown`` applied ``level`` times): pixel ``(c, r)`` of the full
    image is ``(c, r) / 2**level`` of the level, the size is what ``pyrDown`` gives, the lens is unchanged."""
    if level == 0:
        return cam
    s = 0.5 ** level
    w, h = cam.width, cam.height
    for _ in range(level):
        w, h = (w + 1) // 2, (h + 1) // 2
    pc, pr = cam.principal_point_px
    return FrameCamera.from_pixels(cam.name, w, h, cam.focal_px * s, pc * s, pr * s, cam.pixel_size_mm / s,
                                   cam.distortion)


def pyramid(image: NDArray, level: int) -> NDArray:
    """``image`` reduced to pyramid level ``level`` (OpenCV ``pyrDown``, ``level`` times)."""
    import cv2

    for _ in range(level):
        image = cv2.pyrDown(image)
    return image


def coarse_level(width_px: float, max_disparities: int) -> int:
    """Levels up (1 ..) at which a disparity range of ``width_px`` full-level pixels fits ``max_disparities``
    (with the 3 px its integer ends may take); at most 6."""
    k = 1
    while width_px / 2 ** k > max_disparities - 3 and k < 6:
        k += 1
    return k


def refine_windows(coarse: NDArray[np.float32], factor: int, cu0: int, cv0: int, u0: int, u1: int, v0: int, v1: int,
                   d_min: float, d_max: float, max_width: float
                   ) -> tuple[list[tuple[int, int, int, int, float, float]], int, int, int]:
    """Search windows of a block's parts from the coarse level's disparities.

    ``coarse``: coarse disparities (NaN: none) whose element ``[r, c]`` is the coarse rectified pixel
    ``(cu0 + c, cv0 + r)``, i.e. full-level ``(factor (cu0 + c), factor (cv0 + r))``, in coarse pixels.  The block is
    full-level columns ``u0..u1``, rows ``v0..v1``; its geometric window ``[d_min, d_max]`` bounds every window.
    Returns the parts ``(u0, u1, v0, v1, d_min, d_max)`` to match, how many of them had their window narrowed to
    ``max_width`` leaving out more than :data:`TRIM_SHARE` of their coarse matches (cut) and at most that share
    (trimmed), and how many parts were left out (too few coarse matches).
    """
    out: list[tuple[int, int, int, int, float, float]] = []
    n_cut = n_trim = n_blind = 0
    hc, wc = coarse.shape
    pad = factor + 2.0

    def values(a: int, b: int, c: int, d: int) -> NDArray | None:
        ca = max(0, a // factor - cu0)  # the coarse pixels over the part's full-level pixels
        cb = min(wc, -(-b // factor) - cu0)
        cc = max(0, c // factor - cv0)
        cd = min(hc, -(-d // factor) - cv0)
        sub = coarse[cc:cd, ca:cb]
        x = sub[np.isfinite(sub)]
        if sub.size == 0 or x.size < max(4, MIN_COARSE_SHARE * sub.size):
            return None
        return np.sort(x) * factor

    def visit(a: int, b: int, c: int, d: int) -> None:
        nonlocal n_cut, n_trim, n_blind
        x = values(a, b, c, d)
        if x is None:
            n_blind += 1
            return
        lo, hi = np.percentile(x, [0.1, 99.9])
        w = (max(d_min, float(lo) - pad), min(d_max, float(hi) + pad))
        if w[1] < w[0]:  # the coarse surface lies outside the geometric window: keep the geometric one
            w = (d_min, d_max)
        if w[1] - w[0] <= max_width:
            out.append((a, b, c, d, w[0], w[1]))
            return
        if min(b - a, d - c) < 2 * MIN_SPLIT_PX:  # the window holding the most coarse matches
            inner = max_width - 2 * pad
            held = np.searchsorted(x, x + inner, side="right") - np.arange(x.size)
            k = int(np.argmax(held))
            if held[k] >= (1.0 - TRIM_SHARE) * x.size:
                n_trim += 1
            else:
                n_cut += 1
            lo_w = max(d_min, min(float(x[k]) - pad, d_max - max_width))  # inside the geometric window
            out.append((a, b, c, d, lo_w, min(d_max, lo_w + max_width)))
            return
        um, vm = (a + b) // 2, (c + d) // 2
        for q in ((a, um, c, vm), (um, b, c, vm), (a, um, vm, d), (um, b, vm, d)):
            visit(*q)

    visit(u0, u1, v0, v1)
    return out, n_cut, n_trim, n_blind


def coarse_rectification(rect, level: int):  # type: ignore[no-untyped-def]
    """The rectification ``rect`` on pyramid level ``level`` above it: the same plane with a focal length
    ``2**level`` times shorter (rectified coordinates divide by ``2**level``), the cameras of that level."""
    f = 2 ** level
    b = np.asarray(rect.bounds, np.int64).copy()
    b[:, 0] //= f
    b[:, 2] //= f
    b[:, 1] = -(-b[:, 1] // f)
    b[:, 3] = -(-b[:, 3] // f)
    return replace(rect, cameras=(scaled_camera(rect.cameras[0], level), scaled_camera(rect.cameras[1], level)),
                   focal_px=rect.focal_px / f, bounds=b)
