"""Centres of signalised ground targets in an image window, to a fraction of a pixel.

:func:`target_centre` finds the target nearest a start position (a click, or a position predicted from the
orientations) and fits its centre:

* a **disc target** (a bright disc on a dark square, or a dark disc on a bright one): the blob of the
  window's Otsu threshold nearest the start position, then the centroid of its grey values above the
  background (the median of a ring around it), each pixel weighted by ``(g - background) / (foreground -
  background)`` clipped to [0, 1].  For a disc seen at any angle the centroid of a symmetric edge profile is
  the projected centre up to the perspective shift of a finite disc (below 0.01 px for a target of 20 px seen
  from 200 m);
* a **checkerboard / chevron corner** (:func:`corner_centre`): the saddle point of OpenCV's ``cornerSubPix``;
  found automatically, with a test that it is a 2 x 2 chequer, by :func:`chequer_centre`;
* an **ArUco / AprilTag marker** (:func:`aruco_centre`, OpenCV's ``cv2.aruco``): the intersection of its diagonals;
* a **circular coded target** (:func:`coded_centre`; ring-coded, of the Schneider / AICON kind: a bright centre dot
  of radius ``r``, a dark gap to ``2 r``, a ring from ``2 r`` to ``3 r`` of ``N`` bright or dark sectors, dark
  around to ``4 r`` at least): an ellipse fitted to sub-pixel edge points of the dot, corrected to the projected
  centre with the ring's edge (projective-centre correction), and the code read on the ring.

:func:`detect_target` tries the kinds in turn.

The standard deviation of the centre follows from the background noise (MAD of the ring) propagated through the
weighted centroid.  Positions are (column, row) in the window's pixels, pixel centres at integers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["TargetFit", "MarkerFit", "CodedFit", "target_centre", "corner_centre", "chequer_centre", "aruco_centre",
           "coded_centre", "rotation_code", "detect_target", "CODED_MIN_RADIUS_PX", "CODE_BITS"]

#: The smallest dot radius (pixels, from the dot's area) :func:`coded_centre` reads a coded target at: a smaller
#: dot's Otsu blob merges with the ring (measured on the simulator's rendered targets: read from about 2.4 px, not
#: below 2.2 px; tests/test_targets_rendered.py).
CODED_MIN_RADIUS_PX = 2.5
#: Sectors of a coded target's ring (the bits of its code).
CODE_BITS = 12


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


def _ring(g: NDArray[np.float32], xy: NDArray, r: float, n: int = 72) -> NDArray[np.float64]:
    """Grey values (bilinear) on a circle of radius ``r`` around ``xy``, ``n`` samples from angle 0."""
    import cv2

    t = np.arange(n) * (2.0 * np.pi / n)
    mx = (xy[0] + r * np.cos(t)).astype(np.float32).reshape(1, -1)
    my = (xy[1] + r * np.sin(t)).astype(np.float32).reshape(1, -1)
    return cv2.remap(g, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).reshape(-1).astype(np.float64)


def _chequer_ring(p: NDArray[np.float64], noise: float, r: float) -> tuple[NDArray | None, str]:
    """Transition angles (radians, 4) of a ring profile (radius ``r``) that is two bright and two dark sectors,
    else a reason."""
    n = p.size
    cut = int(np.ceil(2.0 / r / (2.0 * np.pi / n)))  # samples within 2 px (a blurred edge) of a transition
    lo, hi = np.percentile(p, 10), np.percentile(p, 90)
    if hi - lo <= 6.0 * noise:
        return None, f"ring contrast {hi - lo:.3g} below 6 x the noise {noise:.3g}"
    b = p > (lo + hi) / 2.0
    ch = np.nonzero(b != np.roll(b, 1))[0]
    if ch.size != 4:
        return None, f"{ch.size} bright/dark transitions on the ring, not 4"
    runs = np.diff(np.r_[ch, ch[0] + n])
    if runs.min() < n // 12:
        return None, "a sector narrower than 30 deg"
    # inside each sector (2 px off its ends) the grey values stay on their side: a chequer, not texture
    means = []
    for a, L in zip(ch, runs):
        idx = (a + np.arange(cut, max(L - cut, cut + 1))) % n
        vals = p[idx]
        side = b[a % n]
        spread = float(np.max(vals) - np.min(vals)) if vals.size else 0.0
        if spread > 0.25 * (hi - lo) + 3.0 * noise or (np.any(vals <= (lo + hi) / 2) if side else np.any(vals > (lo + hi) / 2)):
            return None, "a sector is not uniform"
        means.append(float(np.mean(vals)) if vals.size else float(p[(a + L // 2) % n]))
    if abs(means[0] - means[2]) > 0.2 * (hi - lo) or abs(means[1] - means[3]) > 0.2 * (hi - lo):
        return None, "opposite sectors differ"
    a = ch * (2.0 * np.pi / n)
    # two straight edges through the centre: the transitions come in antipodal pairs (a, a + pi)
    if np.max(np.abs(np.angle(np.exp(1j * (a[2:] - a[:2] - np.pi))))) > np.radians(15.0):
        return None, "the transitions are not two lines through the centre"
    return a, ""


def chequer_centre(window: ArrayLike, xy0: ArrayLike, search_px: float = 12.0, radii: tuple[float, ...] = (4.0, 7.0),
                   half_px: int = 5, candidates: int = 6) -> TargetFit:
    """Centre of a 2 x 2 chequer (checkerboard / chevron target) found automatically near ``xy0``.

    The saddle points of the grey surface (negative Hessian determinant, on a 1-px Gaussian blur) within
    ``search_px`` of ``xy0`` are the candidates, strongest first; each is refined with OpenCV's ``cornerSubPix``
    (``2 half_px + 1`` square) and accepted only when circles of every radius in ``radii`` around it cross
    exactly four uniform sectors, alternately bright and dark, their transitions in antipodal pairs (within 15 deg)
    and at the same angles on every circle (within 10 deg: a band's edges are not): two straight edges crossing at the centre, and a contrast above 6 x the noise (MAD of the grey
    values' differences), the centre's grey value halfway between bright and dark.  ``sigma_px`` is the edge-fit precision ``noise sqrt(2 sqrt(pi) s / L) / contrast``
    with the edge width ``s`` measured from the gradient and ``L = 4 half_px`` edge pixels.
    """
    import cv2

    g = np.asarray(window, dtype=np.float32)
    xy0 = np.asarray(xy0, dtype=np.float64).reshape(2)
    h, w = g.shape
    rmax = max(max(radii), half_px) + 2
    if min(h, w) < 2 * rmax + 3:
        return _fail(xy0, "window too small")
    noise = float(1.4826 * np.median(np.abs(np.diff(g, axis=1))) / np.sqrt(2.0))
    gb = cv2.GaussianBlur(g, (0, 0), 1.0)
    gxx = cv2.Sobel(gb, cv2.CV_32F, 2, 0, ksize=3)
    gyy = cv2.Sobel(gb, cv2.CV_32F, 0, 2, ksize=3)
    gxy = cv2.Sobel(gb, cv2.CV_32F, 1, 1, ksize=3)
    s = -(gxx * gyy - gxy * gxy)
    yy, xx = np.mgrid[0:h, 0:w]
    ok = (np.hypot(xx - xy0[0], yy - xy0[1]) <= search_px) & (xx >= rmax) & (yy >= rmax) & (xx < w - rmax) & (yy < h - rmax)
    s = np.where(ok, s, 0.0).astype(np.float32)
    peak = (s == cv2.dilate(s, np.ones((5, 5), np.uint8))) & (s > 0)
    rows, cols = np.nonzero(peak)
    if rows.size == 0:
        return _fail(xy0, f"no saddle point within {search_px:.0f} px")
    order = np.argsort(-s[rows, cols])[:candidates]
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
    note = ""
    for k in order:
        st = np.array([[[cols[k], rows[k]]]], dtype=np.float32)
        xy = cv2.cornerSubPix(g, st, (half_px, half_px), (-1, -1), crit).reshape(2).astype(np.float64)
        if not np.all(np.isfinite(xy)) or np.hypot(*(xy - [cols[k], rows[k]])) > half_px or \
                not (rmax <= xy[0] < w - rmax and rmax <= xy[1] < h - rmax):
            note = "corner search left its window"
            continue
        angles, contrast = [], 0.0
        for r in radii:
            p = _ring(g, xy, r)
            a, note = _chequer_ring(p, noise, r)
            if a is None:
                break
            angles.append(a)
            lo, hi = float(np.percentile(p, 10)), float(np.percentile(p, 90))
            contrast = max(contrast, hi - lo)
        else:
            d = np.angle(np.exp(1j * (angles[0][None, :] - np.concatenate(angles[1:])[:, None])))
            mid = float(_ring(g, xy, 0.0, 1)[0])
            if abs(mid - (lo + hi) / 2.0) > 0.25 * (hi - lo):
                note = "the centre is not halfway between bright and dark (a line or a blob, not a corner)"
                continue
            if np.all(np.min(np.abs(d).reshape(-1, 4, 4), axis=2) <= np.radians(10.0)):
                gy_, gx_ = np.gradient(gb.astype(np.float64))
                gmax = float(np.max(np.hypot(gx_, gy_)[int(xy[1]) - half_px:int(xy[1]) + half_px + 1,
                                                       int(xy[0]) - half_px:int(xy[0]) + half_px + 1]))
                width = contrast / max(gmax, 1e-9) / np.sqrt(2.0 * np.pi)  # Gaussian edge: peak gradient C/(sqrt(2 pi) s)
                sig = noise * np.sqrt(2.0 * np.sqrt(np.pi) * max(width, 0.5) / (4.0 * half_px)) / contrast
                return TargetFit(xy, True, float(np.hypot(sig, 0.01)), float("nan"), contrast)
            note = "the sectors' edges are not straight lines through the centre"
    return _fail(xy0, note or "no chequer corner")


#: dictionaries tried by default (the 250-marker sets: a 1000-marker set costs 4 x the time per window)
_ARUCO_DICTS = ("DICT_4X4_250", "DICT_5X5_250", "DICT_6X6_250", "DICT_APRILTAG_36h11")


@dataclass(frozen=True)
class MarkerFit:
    """An ArUco / AprilTag marker: ``fit`` (its centre, :class:`TargetFit`), ``marker_id``, ``dictionary`` and the
    ``(4, 2)`` ``corners`` (column, row) in OpenCV's order."""

    fit: TargetFit
    marker_id: int
    dictionary: str
    corners: NDArray[np.float64]


def _marker_edges(g: NDArray[np.float64], q: NDArray[np.float64], reach: float = 3.0, n: int = 16
                  ) -> NDArray[np.float64]:
    """The marker's corners ``q`` (4, 2) re-measured as intersections of its four outer edges: on each side the
    mid-grey crossing of ``n`` profiles across the edge (``reach`` px each way, at most an eighth of the shortest
    side: the profiles stay within the black border cell and the quiet zone) and a straight line fitted to
    them.  A blurred straight edge's mid-grey crossing is unbiased; the corner of a blurred square, which the
    detector's ``cornerSubPix`` refines, is pulled inwards (measured: up to 0.17 px at a 0.8-px blur; 0.7 px on
    an oblique marker of 18 px).  ``q`` unchanged when a side is under 12 px or an edge not found."""
    import cv2

    gf = g.astype(np.float32)
    ctr = q.mean(axis=0)
    reach = min(reach, float(np.min(np.hypot(*(q - np.roll(q, -1, axis=0)).T))) / 8.0)
    if reach < 1.5:
        return q  # cells too small for profiles across the edge
    lines = []
    for i in range(4):
        a, b = q[i], q[(i + 1) % 4]
        side = float(np.hypot(*(b - a)))
        d = (b - a) / side
        nrm = np.array([d[1], -d[0]])
        if np.dot(nrm, (a + b) / 2.0 - ctr) < 0:
            nrm = -nrm  # outwards
        t = np.linspace(0.2, 0.8, n)
        off = np.linspace(-reach, reach, int(8 * reach) + 1)
        pts = a[None, None, :] + (t[:, None, None] * (b - a)[None, None, :]) + off[None, :, None] * nrm[None, None, :]
        prof = cv2.remap(gf, pts[..., 0].astype(np.float32), pts[..., 1].astype(np.float32), cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
        k = max(2, off.size // 6)
        inner, outer = prof[:, :k].mean(axis=1), prof[:, -k:].mean(axis=1)
        mid = (inner + outer) / 2.0
        edge = []
        for j in range(n):
            above = np.nonzero(prof[j] > mid[j])[0] if outer[j] > inner[j] else np.nonzero(prof[j] < mid[j])[0]
            if outer[j] - inner[j] == 0 or above.size == 0 or above[0] == 0:
                continue
            m = above[0]  # first sample past mid-grey, going outwards
            f = (mid[j] - prof[j, m - 1]) / (prof[j, m] - prof[j, m - 1])
            s_ = off[m - 1] + f * (off[m] - off[m - 1])
            edge.append(a + t[j] * (b - a) + s_ * nrm)
        if len(edge) < n // 2:
            return q
        e = np.array(edge)
        c0 = e.mean(axis=0)
        _, _, vt = np.linalg.svd(e - c0)
        lines.append(np.cross([*c0, 1.0], [*(c0 + vt[0]), 1.0]))
    out = []
    for i in range(4):
        x = np.cross(lines[(i - 1) % 4], lines[i])  # corner i lies on sides i-1 and i
        if abs(x[2]) < 1e-12:
            return q
        out.append(x[:2] / x[2])
    out = np.array(out)
    return out if np.max(np.hypot(*(out - q).T)) < reach else q


def aruco_centre(window: ArrayLike, xy0: ArrayLike, search_px: float = 12.0,
                 dictionaries: tuple[str, ...] = _ARUCO_DICTS) -> MarkerFit | None:
    """The ArUco / AprilTag marker (OpenCV ``cv2.aruco``, corners refined to sub-pixel) whose centre lies nearest
    ``xy0`` and within ``search_px`` plus the marker's half diagonal; None when none.  Its corners are re-measured
    as the intersections of straight lines fitted to its outer edges (:func:`_marker_edges`).  The centre is the
    intersection of the marker's diagonals, the image of the square's centre under any perspective (a centroid of
    the corners would not be)."""
    import cv2

    g = np.asarray(window, dtype=np.float64)
    xy0 = np.asarray(xy0, dtype=np.float64).reshape(2)
    lo, hi = float(np.min(g)), float(np.max(g))
    if hi - lo < 1e-6:
        return None
    u8 = np.round((g - lo) / (hi - lo) * 255.0).astype(np.uint8)
    par = cv2.aruco.DetectorParameters()
    par.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    par.cornerRefinementWinSize = 4
    par.cornerRefinementMinAccuracy = 0.01
    best, best_d = None, np.inf
    for name in dictionaries:
        det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name)), par)
        corners, ids, _ = det.detectMarkers(u8)
        for c, i in zip(corners, [] if ids is None else ids.reshape(-1)):
            q = _marker_edges(g, c.reshape(4, 2).astype(np.float64))
            # diagonals q0-q2 and q1-q3 as homogeneous lines; their intersection
            l1 = np.cross([*q[0], 1.0], [*q[2], 1.0])
            l2 = np.cross([*q[1], 1.0], [*q[3], 1.0])
            x = np.cross(l1, l2)
            if abs(x[2]) < 1e-12:
                continue
            ctr = x[:2] / x[2]
            d = float(np.hypot(*(ctr - xy0)))
            half_diag = 0.5 * max(np.hypot(*(q[0] - q[2])), np.hypot(*(q[1] - q[3])))
            if d <= search_px + half_diag and d < best_d:
                side = float(np.mean(np.hypot(*(q - np.roll(q, 1, axis=0)).T)))
                best_d = d
                # sigma 0.05 px: tests/test_targets_auto.py measures <= 0.04 px
                best = MarkerFit(TargetFit(ctr, True, 0.05, side / 2.0, hi - lo), int(i), name, q)
    return best


@dataclass(frozen=True)
class CodedFit:
    """A circular coded target: ``fit`` (its centre, :class:`TargetFit`; ``radius_px`` the dot's mean radius),
    ``code`` (the smallest of the ``bits``-bit ring code's rotations, bit ``b`` the ``b``-th sector counter-clockwise
    as seen from the target's front), ``bits`` and ``ellipse_xy`` (the dot ellipse's centre: ``fit.xy`` minus the
    projective-centre correction)."""

    fit: TargetFit
    code: int
    bits: int
    ellipse_xy: NDArray[np.float64]

    @property
    def corrected_px(self) -> float:
        """Length of the projective-centre correction, pixels."""
        return float(np.hypot(*(self.fit.xy - self.ellipse_xy)))

    @property
    def words(self) -> str:
        """What was found, in words (the code and the dot's radius)."""
        return f"coded target {self.code}, dot radius {self.fit.radius_px:.1f} px"


def _crossings(prof: NDArray[np.float64], rho: NDArray[np.float64], lo: float, hi: float, rising: bool
               ) -> NDArray[np.float64]:
    """Per profile (rows of ``prof`` sampled at ``rho``), the first radius where it crosses ``(lo + hi) / 2``
    going outwards, upwards when ``rising``; NaN where none."""
    mid = (lo + hi) / 2.0
    above = prof > mid
    edge = (above[:, 1:] & ~above[:, :-1]) if rising else (~above[:, 1:] & above[:, :-1])
    out = np.full(prof.shape[0], np.nan)
    rows = np.nonzero(edge.any(axis=1))[0]
    j = np.argmax(edge[rows], axis=1)
    a, b = prof[rows, j], prof[rows, j + 1]
    out[rows] = rho[j] + (mid - a) / (b - a) * (rho[j + 1] - rho[j])
    return out


def _ring_centre_shift(pts: NDArray[np.float64], c1: NDArray[np.float64], A1: NDArray[np.float64]
                       ) -> NDArray[np.float64] | None:
    """The projected centre from the dot's ellipse (centre ``c1``, frame ``A1``: the unit circle onto it) and edge
    points ``pts`` of a concentric circle ``s`` times larger.  Under perspective the centre of a projected circle
    of radius ``r`` misses the projected centre by ``k r^2`` to first order (the same ``k`` for concentric
    circles), so ``c = c1 - (e2 - c1) / (s^2 - 1)`` with ``e2`` the larger ellipse's centre.  ``e2`` and ``s`` are
    fitted with the larger ellipse's shape fixed to the dot's (three unknowns, linear: partial arcs suffice);
    None when the arcs do not pin the shift down."""
    q = np.linalg.solve(A1, (pts - c1).T).T  # in dot radii
    rho = np.hypot(*q.T)
    n = q / rho[:, None]
    J = np.column_stack([np.ones(len(q)), n])
    if np.linalg.cond(J) > 10.0:
        return None
    s_, dx, dy = np.linalg.lstsq(J, rho, rcond=None)[0]
    if not 1.5 < s_ < 4.0:
        return None
    return c1 - (A1 @ np.array([dx, dy])) / (s_**2 - 1.0)


def coded_centre(window: ArrayLike, xy0: ArrayLike, search_px: float = 12.0, bits: int = CODE_BITS,
                 min_radius_px: float = CODED_MIN_RADIUS_PX,
                 candidates: int = 4) -> CodedFit | None:
    """The circular coded target (module docstring) nearest ``xy0`` (its centre within ``search_px``), or None.

    Candidates are the compact bright blobs of the window's Otsu threshold, nearest first.  For each, with the
    blob's ellipse as a first affine frame (``rho`` in dot radii), grey profiles along 64 rays give: the dot's
    edge (the mid-grey crossing between the dot and the gap), the ring's inner (``2 r``) and outer (``3 r``)
    edges where a sector is bright.  A candidate is a coded target when the gap (``1.5 r``) and the surround
    (``3.5 r``: the target's black ground reaches ``4 r``) are dark all round, the dot bright, and every sector of
    the ring (read at ``2.5 r``, phase chosen by the most uniform sectors) clearly bright or dark (beyond a quarter
    of the contrast from mid-grey), with both present.  An ellipse (OpenCV ``fitEllipseDirect``) is fitted to the dot's edge points;
    its centre is corrected to the projected centre with the ring's outer (else inner) edge points
    (:func:`_ring_centre_shift`), unless they are too few (under 3 bright sectors) or the correction exceeds a
    quarter of the dot's radius.  ``sigma_px``: the RMS of the dot edge points' distances to their ellipse over
    ``sqrt(n / 2)``.  ``code``: bit ``b`` is sector ``b`` counter-clockwise on the target's face seen from the
    front; an image of the face (column right, row down) mirrors it, so the ring is read clockwise there."""
    import cv2

    g = np.asarray(window, dtype=np.float64)
    gf = g.astype(np.float32)
    xy0 = np.asarray(xy0, dtype=np.float64).reshape(2)
    if g.ndim != 2 or min(g.shape) < 15:
        return None
    lo_, hi_ = float(np.min(g)), float(np.max(g))
    if hi_ - lo_ < 1e-6:
        return None
    u8 = np.round((g - lo_) / (hi_ - lo_) * 255.0).astype(np.uint8)
    _, bw = cv2.threshold(u8, 0, 1, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    n_lab, lab, stats, cents = cv2.connectedComponentsWithStats(bw, connectivity=8)
    h, w = g.shape
    cand = []
    for k in range(1, n_lab):
        x, y, bw_, bh, area = (int(v) for v in stats[k])
        if area < np.pi * min_radius_px**2 or x == 0 or y == 0 or x + bw_ >= w or y + bh >= h:
            continue
        if area < 0.5 * np.pi / 4.0 * bw_ * bh or max(bw_, bh) > 3.0 * max(min(bw_, bh), 1):
            continue  # not an ellipse-like blob
        d = float(np.hypot(*(cents[k] - xy0)))
        if d <= search_px + max(bw_, bh) / 2.0:
            cand.append((d, k))
    noise = float(1.4826 * np.median(np.abs(np.diff(g, axis=1))) / np.sqrt(2.0))
    nray = 64
    t = (np.arange(nray) + 0.5) * (2.0 * np.pi / nray)
    u = np.stack([np.cos(t), np.sin(t)], axis=1)

    def sample(c: NDArray, A: NDArray, rho: NDArray) -> NDArray[np.float64]:
        pts = c[None, None, :] + rho[None, :, None] * (u @ A.T)[:, None, :]
        return cv2.remap(gf, pts[..., 0].astype(np.float32), pts[..., 1].astype(np.float32), cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REPLICATE).astype(np.float64)

    def frame(e: tuple) -> tuple[NDArray, NDArray]:
        (cx, cy), (ew, eh), ang = e
        a_ = np.radians(ang)
        R = np.array([[np.cos(a_), -np.sin(a_)], [np.sin(a_), np.cos(a_)]])
        return np.array([cx, cy]), R @ np.diag([ew / 2.0, eh / 2.0])

    for _, k in sorted(cand)[:candidates]:
        cnt, _ = cv2.findContours((lab == k).astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        pts = max(cnt, key=len).reshape(-1, 2).astype(np.float32)
        if len(pts) < 6:
            continue
        c, A = frame(cv2.fitEllipseDirect(pts))
        if not np.all(np.isfinite(A)) or np.linalg.det(A) <= 0:
            continue
        # the outermost sample must stay in the window
        if not (4.0 * np.linalg.norm(A, 2) < min(c[0], c[1], w - 1 - c[0], h - 1 - c[1])):
            continue
        ok = True
        for _it in range(2):  # the dot's ellipse from sub-pixel edge points, twice (the second in its own frame)
            rho = np.arange(0.0, 1.81, 0.05)
            prof = sample(c, A, rho)
            fg = float(np.median(prof[:, rho <= 0.5]))
            gap = float(np.median(prof[:, (rho >= 1.3) & (rho <= 1.7)]))
            if fg - gap <= 6.0 * noise:
                ok = False
                break
            rd = _crossings(prof, rho, gap, fg, rising=False)
            good = np.isfinite(rd) & (rd > 0.6) & (rd < 1.4)
            if good.sum() < 0.8 * nray:
                ok = False
                break
            ep = c + (rd[good, None] * u[good]) @ A.T
            e1 = cv2.fitEllipseDirect(ep.astype(np.float32))
            c, A = frame(e1)
            if not np.all(np.isfinite(A)) or np.linalg.det(A) <= 0:
                ok = False
                break
        if not ok:
            continue
        contrast = fg - gap
        prof = sample(c, A, np.array([1.5, 3.5]))
        mid = (fg + gap) / 2.0
        if np.any(prof > mid - 0.25 * contrast):
            continue  # the gap or the surround is not dark all round
        # the code: 16 samples per sector at 2.5 r, phase by the most uniform sectors
        ns = 16
        tt = np.arange(bits * ns) * (2.0 * np.pi / (bits * ns))
        uu = np.stack([np.cos(tt), np.sin(tt)], axis=1)
        q = c[None, :] + 2.5 * (uu @ A.T)
        ring = cv2.remap(gf, q[:, 0].astype(np.float32).reshape(1, -1), q[:, 1].astype(np.float32).reshape(1, -1),
                         cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).reshape(-1).astype(np.float64)
        best = None
        for ph in range(ns):
            sec = np.roll(ring, -ph).reshape(bits, ns)[:, 3:ns - 3]  # away from the sector's ends
            spread = float(np.sum(np.ptp(sec, axis=1)))
            if best is None or spread < best[0]:
                best = (spread, ph, sec)
        _, ph, sec = best
        val = np.median(sec, axis=1)
        if np.any(np.abs(sec - mid) < 0.25 * contrast) or np.any((sec > mid) != (val > mid)[:, None]):
            continue  # a sector neither clearly bright nor dark
        on = val > mid
        if on.all() or not on.any():
            continue
        # ring edges where the sector is bright (samples of the 64 rays whose angle falls in a bright sector)
        rho = np.arange(1.5, 3.31, 0.05)
        prof = sample(c, A, rho)
        sector = np.floor((t / (2.0 * np.pi) * bits * ns - ph) / ns).astype(int) % bits
        pos = (t / (2.0 * np.pi) * bits * ns - ph) % ns
        bright = on[sector] & (pos > 4) & (pos < ns - 4)
        ring_pts = None
        if on.sum() >= 3 and bright.sum() >= 8:
            for rising, r0, band in ((False, 3.0, rho >= 2.5), (True, 2.0, rho <= 2.5)):
                rr = _crossings(prof[:, band], rho[band], gap, fg, rising=rising)
                sel = bright & np.isfinite(rr) & (np.abs(rr - r0) < 0.4 * r0)
                if sel.sum() >= 8:
                    ring_pts = c + (rr[sel, None] * u[sel]) @ A.T
                    break
        # the dot's edge points again in the final frame: the centre's precision
        rho = np.arange(0.0, 1.81, 0.05)
        rd = _crossings(sample(c, A, rho), rho, gap, fg, rising=False)
        good = np.isfinite(rd) & (rd > 0.6) & (rd < 1.4)
        e1 = cv2.fitEllipseDirect((c + (rd[good, None] * u[good]) @ A.T).astype(np.float32))
        c1, A1 = frame(e1)
        resid = (rd[good] - 1.0) * np.linalg.norm(A1, 2)  # radial, pixels (the frame is the fitted ellipse)
        radius = float(np.sqrt(abs(np.linalg.det(A1))))
        centre = c1
        if ring_pts is not None:
            cc = _ring_centre_shift(ring_pts, c1, A1)
            if cc is not None and np.hypot(*(cc - c1)) < 0.25 * radius:
                centre = cc
        if np.hypot(*(centre - xy0)) > search_px:
            continue
        sig = float(np.sqrt(np.mean(resid**2)) / np.sqrt(max(good.sum(), 2) / 2.0))
        # bits in sampling order run clockwise on the target's front (an image from above mirrors it): reverse
        code = rotation_code(sum(1 << j for j, x in enumerate(on[::-1]) if x), bits)
        return CodedFit(TargetFit(centre, True, float(np.hypot(sig, 0.01)), radius, contrast), code, bits, c1)
    return None


def rotation_code(code: int, bits: int = 12) -> int:
    """The smallest of the ``bits``-bit rotations of ``code``: the identity a ring code is read as."""
    m = (1 << bits) - 1
    return min(((code << i) | (code >> (bits - i))) & m for i in range(bits))


def detect_target(window: ArrayLike, xy0: ArrayLike, search_px: float = 12.0,
                  kinds: tuple[str, ...] = ("aruco", "coded", "chequer", "disc")) -> tuple[TargetFit, str, str]:
    """The first target of ``kinds`` (``"disc"``: :func:`target_centre`, ``"aruco"``: :func:`aruco_centre`,
    ``"chequer"``: :func:`chequer_centre`) found near ``xy0``: its fit, a few words on what it is and its kind
    (or, when none is, a failed fit whose note says what each kind found, and two empty strings).  Markers first and chequers next: a disc's Otsu blob would
    take one bright square of a chequer, and a chequer test the cell corners inside a marker."""
    notes = []
    for kind in kinds:
        if kind == "disc":
            f = target_centre(window, xy0, search_px=search_px)
            if f.ok:
                return f, f"disc target, radius {f.radius_px:.1f} px", kind
        elif kind == "aruco":
            m = aruco_centre(window, xy0, search_px=search_px)
            if m is not None:
                return m.fit, f"{m.dictionary[5:]} marker {m.marker_id}, side {2 * m.fit.radius_px:.1f} px", kind
            f = _fail(np.asarray(xy0, dtype=np.float64), "no marker")
        elif kind == "coded":
            c = coded_centre(window, xy0, search_px=search_px)
            if c is not None:
                return c.fit, c.words, kind
            f = _fail(np.asarray(xy0, dtype=np.float64), "no coded target")
        elif kind == "chequer":
            f = chequer_centre(window, xy0, search_px=search_px)
            if f.ok:
                return f, "chequer corner", kind
        else:
            raise ValueError(f"unknown target kind {kind!r} (disc, aruco, coded, chequer)")
        notes.append(f"{kind}: {f.note}")
    return _fail(np.asarray(xy0, dtype=np.float64), "; ".join(notes)), "", ""
