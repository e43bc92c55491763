"""Centres of signalised ground targets in an image window, to a fraction of a pixel.

:func:`target_centre` finds the target nearest a start position (a click, or a position predicted from the
orientations) and fits its centre:

* a **disc target** (a bright disc on a dark square, or a dark disc on a bright one): the blob of the
  window's Otsu threshold nearest the start position, then the centroid of its grey values above the
  background (the median of a ring around it), each pixel weighted by ``(g - background) / (foreground -
  background)`` clipped to [0, 1].  For a disc seen at any angle the centroid of a symmetric edge profile is
  the projected centre up to the perspective shift of a finite disc (below 0.01 px for a target of 20 px seen
  from 200 m);
* a **checkerboard / chevron corner** (:func:`corner_centre`): the saddle point of OpenCV's ``cornerSubPix``.

The standard deviation of the centre follows from the background noise (MAD of the ring) propagated through the
weighted centroid.  Positions are (column, row) in the window's pixels, pixel centres at integers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["TargetFit", "target_centre", "corner_centre"]


@dataclass(frozen=True)
class TargetFit:
    """One target's centre in a window.

    Attributes
    ----------
    xy
        ``(2,)`` centre (column, row), window pixels; the start position when ``ok`` is false.
    ok
        A target was found and fitted.
    sigma_px
        Standard deviation of the centre (mean of the two axes), pixels; NaN when not ``ok``.
    radius_px
        Radius of the disc (from its area), pixels; NaN for a corner.
    contrast
        Foreground minus background grey value.
    note
        Why not ``ok`` (empty when ``ok``).
    """

    xy: NDArray[np.float64]
    ok: bool
    sigma_px: float
    radius_px: float
    contrast: float
    note: str = ""


def _fail(xy0: NDArray, note: str) -> TargetFit:
    return TargetFit(np.asarray(xy0, dtype=np.float64), False, float("nan"), float("nan"), 0.0, note)


def _blob(g: NDArray[np.float64], xy0: NDArray, search_px: float, min_area: int
          ) -> tuple[NDArray[np.bool_] | None, str]:
    """The compact bright component of the Otsu threshold nearest ``xy0`` (within ``search_px``), or None."""
    import cv2

    lo, hi = float(np.min(g)), float(np.max(g))
    if hi - lo < 1e-6:
        return None, "flat window"
    u8 = np.round((g - lo) / (hi - lo) * 255.0).astype(np.uint8)
    _, bw = cv2.threshold(u8, 0, 1, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    n, lab, stats, cents = cv2.connectedComponentsWithStats(bw, connectivity=8)
    h, w = g.shape
    best, best_d = None, np.inf
    for k in range(1, n):
        x, y, bw_, bh, area = (int(v) for v in stats[k])
        if area < min_area or x == 0 or y == 0 or x + bw_ >= w or y + bh >= h:
            continue  # too small, or cut by the window's border
        side = max(bw_, bh)
        if area < 0.5 * np.pi / 4.0 * bw_ * bh or side > 4.0 * max(min(bw_, bh), 1):
            continue  # not an ellipse-like blob (a road, a roof edge)
        d = float(np.hypot(*(cents[k] - xy0)))
        if d <= search_px + side / 2.0 and d < best_d:
            best, best_d = k, d
    if best is None:
        return None, f"no compact blob within {search_px:.0f} px"
    return lab == best, ""


def target_centre(window: ArrayLike, xy0: ArrayLike, search_px: float = 12.0, polarity: str = "auto",
                  min_area: int = 5) -> TargetFit:
    """Centre of the disc target nearest ``xy0`` in a grey ``window`` (module docstring).

    Parameters
    ----------
    window
        ``(H, W)`` grey values (any numeric type).
    xy0
        ``(2,)`` start position (column, row) in the window.
    search_px
        How far from ``xy0`` the blob's centroid may lie (plus its half size).
    polarity
        ``"bright"`` (bright disc), ``"dark"`` or ``"auto"`` (bright first, then dark).
    min_area
        Smallest blob, pixels.
    """
    import cv2

    g0 = np.asarray(window, dtype=np.float64)
    xy0 = np.asarray(xy0, dtype=np.float64).reshape(2)
    if g0.ndim != 2 or min(g0.shape) < 7:
        return _fail(xy0, "window too small")
    tries = {"bright": [1.0], "dark": [-1.0], "auto": [1.0, -1.0]}[polarity]
    note = ""
    for sign in tries:
        g = sign * g0
        mask, note = _blob(g, xy0, search_px, min_area)
        if mask is None:
            continue
        m2 = cv2.dilate(mask.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
        ring = cv2.dilate(m2.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool) & ~m2
        if ring.sum() < 8:
            note = "no background around the blob"
            continue
        bg = float(np.median(g[ring]))
        fg = float(np.percentile(g[mask], 90))
        contrast = fg - bg
        noise = 1.4826 * float(np.median(np.abs(g[ring] - bg)))
        if contrast <= max(6.0 * noise, 1e-6):
            note = f"contrast {contrast:.3g} below 6 x the background noise {noise:.3g}"
            continue
        wgt = np.clip((g - bg) / contrast, 0.0, 1.0) * m2
        rows, cols = np.nonzero(m2)
        wv = wgt[rows, cols]
        s = float(wv.sum())
        xc, yc = float(np.sum(wv * cols) / s), float(np.sum(wv * rows) / s)
        var = (np.sum((cols - xc) ** 2) + np.sum((rows - yc) ** 2)) / 2.0 * (noise / contrast) ** 2 / s**2
        return TargetFit(np.array([xc, yc]), True, float(np.sqrt(var + 0.02**2)), float(np.sqrt(mask.sum() / np.pi)),
                         abs(contrast))
    return _fail(xy0, note or "no target")


def corner_centre(window: ArrayLike, xy0: ArrayLike, half_px: int = 5, max_shift_px: float | None = None
                  ) -> TargetFit:
    """Saddle point of a checkerboard / chevron corner near ``xy0`` (OpenCV ``cornerSubPix`` on a ``2 half + 1``
    square); not ``ok`` when it moves further than ``max_shift_px`` (default ``half_px``)."""
    import cv2

    g = np.asarray(window, dtype=np.float32)
    xy0 = np.asarray(xy0, dtype=np.float64).reshape(2)
    h, w = g.shape
    if not (half_px <= xy0[0] < w - half_px - 1 and half_px <= xy0[1] < h - half_px - 1):
        return _fail(xy0, "start position too close to the window's border")
    pts = xy0.astype(np.float32).reshape(1, 1, 2).copy()
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
    out = cv2.cornerSubPix(g, pts, (half_px, half_px), (-1, -1), crit).reshape(2).astype(np.float64)
    shift = float(np.hypot(*(out - xy0)))
    lim = half_px if max_shift_px is None else max_shift_px
    if not np.all(np.isfinite(out)) or shift > lim:
        return _fail(xy0, f"corner search moved {shift:.1f} px (limit {lim:g})")
    patch = g[int(out[1]) - half_px:int(out[1]) + half_px + 1, int(out[0]) - half_px:int(out[0]) + half_px + 1]
    return TargetFit(out, True, float("nan"), float("nan"), float(np.ptp(patch)) if patch.size else 0.0)
