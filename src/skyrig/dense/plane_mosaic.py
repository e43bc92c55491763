"""Images projected onto a common plane from their orientations alone, and the offsets across the seams
(paper 000, Fig. 9).

Paper 000 shows the quality of MACS-TumbleCam's actuator-dependent mounting by stitching one full circle of
oblique images "without any image analysis or interpretation": every image is projected onto one plane with its
orientation (nadir orientation x tumbling angles + boresight corrections at beta), and features must run on
across the seams.  This module does the same and measures it:

* :func:`plane_mosaic`: a backward-projection mosaic.  For every cell of a grid on the plane, the world point is
  projected into every image with the full camera model (:meth:`~skyrig.camera.frame.FrameCamera.project_pixels`,
  distortion included) and resampled with ``cv2.remap`` (bilinear); the cell takes its colour from the image whose
  optical axis is closest to the cell's ray (the image that looks at it most directly).  No image matching.
* :func:`seam_offsets`: along every seam between two neighbouring images, square windows centred on the seam in
  which both images' projections are complete are compared by phase correlation (``cv2.phaseCorrelate``, Hann
  window): the shift of image *b*'s projection against image *a*'s in mosaic pixels.  Correct orientations give
  zero (to the sub-pixel precision of the correlation); an orientation error shows as the difference of the two
  images' displacements on the plane.

Images taken from one projection centre (the tumbling camera of a hovering or laboratory sensor head) agree on
any plane whatever the relief; images from different centres (a circle flown along a strip) also show the relief
displacement of everything off the plane.  A seam shows the *difference* of its two images' orientation errors: an
error common to all images (the nadir orientation they were transferred from) moves the whole mosaic and no seam,
and a smooth boresight curve differs little between close actuator positions (on the simulated TumbleCam: without
the curve, seams 22.5 deg apart reach 2.9 px, seams 5 deg apart 0.4 px).

Frames: the plane and the grid live in the orientations' world frame, which must be Cartesian (a local ENU frame
or ECEF; use :meth:`~skyrig.georef.eo.ExteriorOrientations.to_frame` with
:func:`~skyrig.georef.eo.local_frame_for` first for map-CRS orientations).  Grid rows run along ``-v``, columns
along ``+u`` (a north-up picture for a horizontal plane with ``u`` east and ``v`` north).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.camera.frame import FrameCamera
from skyrig.errors import GeometryError, SkyrigError
from skyrig.georef.eo import ExteriorOrientations

log = logging.getLogger(__name__)

ImageSource = Sequence[NDArray[np.uint8]] | Callable[[str], NDArray[np.uint8]]


@dataclass(frozen=True)
class Plane:
    """A plane in a Cartesian world frame with two in-plane axes.

    Attributes
    ----------
    origin
        ``(3,)`` a point of the plane (world frame, metres): plane coordinates (0, 0).
    u_axis, v_axis
        ``(3,)`` orthonormal in-plane directions; the normal is ``u x v``.
    """

    origin: NDArray[np.float64]
    u_axis: NDArray[np.float64]
    v_axis: NDArray[np.float64]

    def __post_init__(self) -> None:
        o, u, v = (np.asarray(a, dtype=np.float64).reshape(-1) for a in (self.origin, self.u_axis, self.v_axis))
        if o.shape != (3,) or u.shape != (3,) or v.shape != (3,) or not np.all(np.isfinite(np.r_[o, u, v])):
            raise GeometryError("a plane needs a finite origin and two finite 3-vectors as axes")
        if abs(np.linalg.norm(u) - 1) > 1e-9 or abs(np.linalg.norm(v) - 1) > 1e-9 or abs(u @ v) > 1e-9:
            raise GeometryError("plane axes must be orthonormal")
        for name, a in (("origin", o), ("u_axis", u), ("v_axis", v)):
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    @classmethod
    def horizontal(cls, height_m: float, origin_xy: ArrayLike = (0.0, 0.0)) -> "Plane":
        """The plane ``z = height_m`` of a local ENU frame, ``u`` east, ``v`` north."""
        x, y = np.asarray(origin_xy, dtype=np.float64).reshape(2)
        return cls(np.array([x, y, float(height_m)]), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))

    @property
    def normal(self) -> NDArray[np.float64]:
        """``(3,)`` unit normal ``u x v``."""
        return np.cross(self.u_axis, self.v_axis)

    def to_world(self, uv: ArrayLike) -> NDArray[np.float64]:
        """Plane coordinates ``(..., 2)`` (m) to world points ``(..., 3)``."""
        p = np.asarray(uv, dtype=np.float64)
        return self.origin + p[..., :1] * self.u_axis + p[..., 1:2] * self.v_axis

    def intersect(self, centre: ArrayLike, direction: ArrayLike) -> NDArray[np.float64]:
        """Plane coordinates ``(..., 2)`` where rays ``centre + s direction`` (``s > 0``) meet the plane (NaN if never)."""
        c = np.asarray(centre, dtype=np.float64)
        d = np.asarray(direction, dtype=np.float64)
        n = self.normal
        with np.errstate(divide="ignore", invalid="ignore"):
            s = ((self.origin - c) @ n) / (d @ n)
        s = np.where(s > 0, s, np.nan)
        x = c + s[..., None] * d - self.origin
        return np.stack([x @ self.u_axis, x @ self.v_axis], axis=-1)


@dataclass(frozen=True)
class PlaneGrid:
    """A raster on a plane: cell ``(row, col)`` has its centre at ``u = u0 + col * cell``, ``v = v0 - row * cell``."""

    plane: Plane
    u0: float
    v0: float
    cell_m: float
    shape: tuple[int, int]

    def uv(self, rows: ArrayLike, cols: ArrayLike) -> NDArray[np.float64]:
        """Plane coordinates ``(..., 2)`` of (fractional) cells."""
        r, c = np.broadcast_arrays(np.asarray(rows, dtype=np.float64), np.asarray(cols, dtype=np.float64))
        return np.stack([self.u0 + c * self.cell_m, self.v0 - r * self.cell_m], axis=-1)

    def cell_of(self, uv: ArrayLike) -> NDArray[np.float64]:
        """Fractional ``(row, col)`` ``(..., 2)`` of plane coordinates."""
        p = np.asarray(uv, dtype=np.float64)
        return np.stack([(self.v0 - p[..., 1]) / self.cell_m, (p[..., 0] - self.u0) / self.cell_m], axis=-1)


@dataclass(frozen=True)
class PlaneMosaic:
    """A mosaic of images on a plane.

    Attributes
    ----------
    rgb
        ``(H, W, 3)`` uint8 mosaic (black where no image sees the cell).
    source
        ``(H, W)`` int16 index of the image each cell comes from (-1: none).
    grid
        The plane grid.
    images
        ``(N,)`` image names (the order of ``source`` indices).
    gray
        ``(N, H, W)`` uint8 every image's own projection (grey), for the seam check.
    valid
        ``(N, H, W)`` bool where each image's projection is defined (inside the image, in front of the camera).
    gsd_m
        ``(N,)`` ground sample distance of each image on the plane at its principal point (m; the square root of a
        pixel's footprint area).
    """

    rgb: NDArray[np.uint8]
    source: NDArray[np.int16]
    grid: PlaneGrid
    images: NDArray[np.str_]
    gray: NDArray[np.uint8]
    valid: NDArray[np.bool_]
    gsd_m: NDArray[np.float64]


@dataclass(frozen=True)
class SeamOffset:
    """Feature offset across the seam between two images of a mosaic.

    Attributes
    ----------
    a, b
        Indices (into ``PlaneMosaic.images``) of the two images, ``a < b``.
    seam_cells
        Number of mosaic cells on the seam (cells of ``a`` next to cells of ``b``).
    centres
        ``(K, 2)`` (row, col) of the correlation windows on the seam.
    shift_px
        ``(K, 2)`` shift ``(d_col, d_row)`` of image *b*'s projection against image *a*'s in each window (mosaic
        pixels): the feature at cell ``x`` in *a*'s projection lies at ``x + shift`` in *b*'s.
    response
        ``(K,)`` phase-correlation peak response (0..1) of each window.
    """

    a: int
    b: int
    seam_cells: int
    centres: NDArray[np.float64]
    shift_px: NDArray[np.float64]
    response: NDArray[np.float64]

    @property
    def median_shift_px(self) -> NDArray[np.float64]:
        """``(2,)`` component-wise median shift over the windows (NaN without windows)."""
        return np.median(self.shift_px, axis=0) if len(self.shift_px) else np.full(2, np.nan)

    @property
    def offset_px(self) -> float:
        """Length of :attr:`median_shift_px` (mosaic pixels)."""
        return float(np.linalg.norm(self.median_shift_px))


def _load(images: ImageSource, name: str, k: int) -> NDArray[np.uint8]:
    img = images(name) if callable(images) else images[k]
    a = np.asarray(img)
    if a.ndim == 2:
        a = np.repeat(a[:, :, None], 3, axis=2)
    if a.ndim != 3 or a.shape[2] < 3 or a.dtype != np.uint8:
        raise SkyrigError(f"image {name!r}: expected an (H, W, 3) uint8 RGB array, got {a.shape} {a.dtype}")
    return np.ascontiguousarray(a[:, :, :3])


def _camera_of(cameras: Mapping[str, FrameCamera] | FrameCamera, name: str, image: str) -> FrameCamera:
    if isinstance(cameras, FrameCamera):
        return cameras
    try:
        return cameras[name]
    except KeyError:
        raise SkyrigError(f"image {image!r}: no camera {name!r} among {', '.join(cameras)}") from None


def default_grid(eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera] | FrameCamera, plane: Plane,
                 cell_m: float | None = None, max_cells: int = 4_000_000, max_tilt_deg: float = 80.0
                 ) -> tuple[PlaneGrid, NDArray[np.float64], NDArray[np.float64]]:
    """The grid covering every image's footprint on the plane, each image's GSD on it and its footprint box.

    Parameters
    ----------
    eo
        Orientations in a Cartesian frame.
    cameras
        Camera per camera name (``eo.camera``), or one camera for all.
    plane
        The plane.
    cell_m
        Cell size (m); default: the median of the images' GSD on the plane at their principal points, so that
        mosaic pixels are about image pixels.
    max_cells
        Refuse grids larger than this (the footprint of an image looking near the horizon is unbounded).
    max_tilt_deg
        Image corner rays more than this from the plane's normal are clipped to it (far-field footprints).

    Returns
    -------
    (PlaneGrid, (N,) GSD in metres, (N, 4) footprint boxes umin, vmin, umax, vmax in plane metres)
    """
    n = plane.normal
    corners_uv, gsd = [], np.empty(len(eo))
    for k in range(len(eo)):
        cam = _camera_of(cameras, str(eo.camera[k]), str(eo.image[k]))
        r, c = eo.rotation[k], eo.centre[k]
        axis = r @ np.array([0.0, 0.0, -1.0])
        cos_i = abs(axis @ n)
        uv0 = plane.intersect(c, axis)
        if not np.all(np.isfinite(uv0)):
            raise GeometryError(f"image {str(eo.image[k])!r}: its optical axis does not meet the plane")
        dist = float(np.linalg.norm(plane.to_world(uv0) - c))
        gsd[k] = dist * cam.pixel_size_mm / cam.focal_mm / np.sqrt(max(cos_i, 1e-6))
        ed = np.linspace(0, 1, 9)
        w, h = cam.width - 1.0, cam.height - 1.0
        border = np.concatenate([np.c_[ed * w, 0 * ed], np.c_[w + 0 * ed, ed * h], np.c_[ed * w, h + 0 * ed],
                                 np.c_[0 * ed, ed * h]])
        d = cam.rays_from_pixels(border) @ r.T
        # clip rays to max_tilt from the normal direction pointing at the plane
        toward = -n if (plane.origin - c) @ n < 0 else n
        cos_t = d @ toward
        lim = np.cos(np.radians(max_tilt_deg))
        low = cos_t < lim
        if np.any(low):
            perp = d[low] - cos_t[low, None] * toward
            perp /= np.linalg.norm(perp, axis=1, keepdims=True)
            d[low] = lim * toward + np.sqrt(1 - lim ** 2) * perp
        corners_uv.append(plane.intersect(c, d))
    boxes = np.full((len(eo), 4), np.nan)
    for k, cu in enumerate(corners_uv):
        f = cu[np.all(np.isfinite(cu), axis=1)]
        if len(f):
            boxes[k] = [*f.min(axis=0), *f.max(axis=0)]
    uv = np.concatenate(corners_uv)
    uv = uv[np.all(np.isfinite(uv), axis=1)]
    if not len(uv):
        raise GeometryError("no image sees the plane")
    cell = float(np.median(gsd)) if cell_m is None else float(cell_m)
    if not (np.isfinite(cell) and cell > 0):
        raise SkyrigError(f"cell size must be a positive number of metres, got {cell_m!r}")
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    shape = (int(np.ceil((hi[1] - lo[1]) / cell)) + 1, int(np.ceil((hi[0] - lo[0]) / cell)) + 1)
    if shape[0] * shape[1] > max_cells:
        raise SkyrigError(f"the mosaic grid would have {shape[0]} x {shape[1]} cells of {cell:.4g} m (> {max_cells}); "
                          "give a larger cell size or a smaller set of images")
    return PlaneGrid(plane, float(lo[0]), float(hi[1]), cell, shape), gsd, boxes


def plane_mosaic(
    images: ImageSource,
    eo: ExteriorOrientations,
    cameras: Mapping[str, FrameCamera] | FrameCamera,
    plane: Plane,
    *,
    cell_m: float | None = None,
    grid: PlaneGrid | None = None,
    max_cells: int = 4_000_000,
) -> PlaneMosaic:
    """Backward-projection mosaic of oriented images on a plane, from their orientations alone.

    Parameters
    ----------
    images
        The images in ``eo`` order (``(H, W, 3)`` uint8 RGB arrays), or a function image name -> array.
    eo
        Orientations in a Cartesian world frame (local ENU or ECEF).
    cameras
        Camera per camera name, or one camera for all images; distortion is applied as the camera model says.
    plane
        The common plane (e.g. :meth:`Plane.horizontal` at the mean terrain height).
    cell_m, max_cells
        See :func:`default_grid` (used when ``grid`` is None).
    grid
        A given grid (e.g. to compare two mosaics cell by cell).

    Returns
    -------
    PlaneMosaic
    """
    if eo.frame.kind == "map":
        raise SkyrigError("plane_mosaic needs orientations in a Cartesian frame (local ENU or ECEF), not a map CRS: "
                          "convert them with eo.to_frame(local_frame_for(...)) first")
    if len(eo) == 0:
        raise SkyrigError("plane_mosaic: no images")
    if grid is None:
        g, gsd, boxes = default_grid(eo, cameras, plane, cell_m, max_cells)
    else:
        g = grid
        _, gsd, boxes = default_grid(eo, cameras, plane, grid.cell_m, max_cells=1 << 62)
    h, w = g.shape
    n = len(eo)
    best = np.full((h, w), -np.inf)
    source = np.full((h, w), -1, np.int16)
    gray = np.zeros((n, h, w), np.uint8)
    valid = np.zeros((n, h, w), bool)
    rgb = np.zeros((h, w, 3), np.uint8)
    for k in range(n):
        name = str(eo.image[k])
        cam = _camera_of(cameras, str(eo.camera[k]), name)
        img = _load(images, name, k)
        if img.shape[:2] != (cam.height, cam.width):
            raise SkyrigError(f"image {name!r} is {img.shape[1]} x {img.shape[0]} px but its camera "
                              f"{cam.name!r} says {cam.width} x {cam.height}")
        if not np.all(np.isfinite(boxes[k])):
            continue
        # the cells of the image's footprint box (one cell of margin), clipped to the grid
        rc_a = g.cell_of(np.array([boxes[k, 0], boxes[k, 3]]))
        rc_b = g.cell_of(np.array([boxes[k, 2], boxes[k, 1]]))
        r0, c0 = max(int(np.floor(rc_a[0])) - 1, 0), max(int(np.floor(rc_a[1])) - 1, 0)
        r1, c1 = min(int(np.ceil(rc_b[0])) + 2, h), min(int(np.ceil(rc_b[1])) + 2, w)
        if r1 <= r0 or c1 <= c0:
            continue
        hh, ww = r1 - r0, c1 - c0
        rr, cc = np.mgrid[r0:r1, c0:c1]
        d = plane.to_world(g.uv(rr, cc)).reshape(-1, 3) - eo.centre[k]
        r = eo.rotation[k]
        px = cam.project_pixels(d @ r)  # world -> camera frame: R^T d, row-wise d @ R
        ok = np.all(np.isfinite(px), axis=1) & cam.in_image(px, margin_px=-0.5)
        axis = r @ np.array([0.0, 0.0, -1.0])
        cosang = ((d @ axis) / np.linalg.norm(d, axis=1)).reshape(hh, ww)
        mx = np.where(ok, px[:, 0], -10.0).astype(np.float32).reshape(hh, ww)
        my = np.where(ok, px[:, 1], -10.0).astype(np.float32).reshape(hh, ww)
        ok = ok.reshape(hh, ww)
        warped = cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        gray[k, r0:r1, c0:c1] = cv2.cvtColor(warped, cv2.COLOR_RGB2GRAY)
        valid[k, r0:r1, c0:c1] = ok
        sub_best = best[r0:r1, c0:c1]
        take = ok & (cosang > sub_best)
        sub_best[take] = cosang[take]
        source[r0:r1, c0:c1][take] = k
        rgb[r0:r1, c0:c1][take] = warped[take]
    gsd_out = gsd
    log.info("plane mosaic of %d images: %d x %d cells of %.4g m, %.1f %% covered", n, h, w, g.cell_m,
             100.0 * np.mean(source >= 0))
    return PlaneMosaic(rgb, source, g, eo.image.copy(), gray, valid, gsd_out)


def seam_cells(source: NDArray[np.int16]) -> dict[tuple[int, int], NDArray[np.intp]]:
    """Cells on the seams of a source-index raster: ``{(a, b): (K, 2) (row, col)}`` with ``a < b``.

    A cell of image *a* with a 4-neighbour of image *b* is on the (a, b) seam (both sides are listed).
    """
    out: dict[tuple[int, int], list[NDArray[np.intp]]] = {}
    s = source.astype(np.int32)
    for axis in (0, 1):
        x0 = s[:-1, :] if axis == 0 else s[:, :-1]
        x1 = s[1:, :] if axis == 0 else s[:, 1:]
        m = (x0 >= 0) & (x1 >= 0) & (x0 != x1)
        r, c = np.nonzero(m)
        a, b = np.minimum(x0[m], x1[m]), np.maximum(x0[m], x1[m])
        key = a * 65536 + b
        for kk in np.unique(key):
            sel = key == kk
            pa, pb = int(kk // 65536), int(kk % 65536)
            r2, c2 = (r[sel] + 1, c[sel]) if axis == 0 else (r[sel], c[sel] + 1)
            out.setdefault((pa, pb), []).append(np.c_[np.r_[r[sel], r2], np.r_[c[sel], c2]])
    return {k: np.unique(np.concatenate(v), axis=0) for k, v in out.items()}


def seam_offsets(mosaic: PlaneMosaic, window_px: int = 64, min_valid: float = 0.99, min_response: float = 0.05,
                 min_texture: float = 2.0, refine: int = 3, pad: int = 8) -> list[SeamOffset]:
    """Feature offsets across every seam of a mosaic by phase correlation of the two images' projections.

    Parameters
    ----------
    mosaic
        From :func:`plane_mosaic`.
    window_px
        Side of the square correlation windows (mosaic pixels, even), centred on seam cells at least
        ``window_px / 2`` apart.
    min_valid
        Share of a window both projections must cover.
    min_response
        Phase-correlation peaks below this are dropped (no common features).
    min_texture
        Windows whose grey values vary less than this (standard deviation, DN) in either image are dropped.
    refine
        Iterations that shift image *b*'s window back by the shift found so far (bilinear resampling) and correlate
        again: ``cv2.phaseCorrelate``'s sub-pixel peak (a centroid) is biased towards whole pixels; the iteration
        removes that bias (0: one plain correlation).
    pad
        Margin (pixels) around each window that both projections must also cover (room for the refinement shifts;
        larger shifts than ``pad - 1`` stop the refinement).

    Returns
    -------
    list of SeamOffset, one per pair of neighbouring images with at least one usable window (also pairs with
    none, with empty arrays).
    """
    w = int(window_px) // 2 * 2
    if w < 8:
        raise SkyrigError(f"window_px must be at least 8, got {window_px!r}")
    half = w // 2
    hann = cv2.createHanningWindow((w, w), cv2.CV_64F)
    h, wd = mosaic.source.shape
    out = []
    for (a, b), cells in sorted(seam_cells(mosaic.source).items()):
        inner = cells[(cells[:, 0] >= half) & (cells[:, 0] < h - half) & (cells[:, 1] >= half) & (cells[:, 1] < wd - half)]
        both = mosaic.valid[a] & mosaic.valid[b]
        centres, shifts, resp = [], [], []
        taken: list[NDArray[np.intp]] = []
        order = np.lexsort((inner[:, 1], inner[:, 0])) if len(inner) else np.zeros(0, np.intp)
        for rc in inner[order]:
            if taken and np.min(np.max(np.abs(np.asarray(taken) - rc), axis=1)) < half:
                continue
            r0, c0 = int(rc[0]) - half, int(rc[1]) - half
            if r0 < pad or c0 < pad or r0 + w + pad > h or c0 + w + pad > wd:
                continue
            if np.mean(both[r0 - pad:r0 + w + pad, c0 - pad:c0 + w + pad]) < min_valid:
                continue
            ga = mosaic.gray[a, r0:r0 + w, c0:c0 + w].astype(np.float64)
            gb_pad = mosaic.gray[b, r0 - pad:r0 + w + pad, c0 - pad:c0 + w + pad].astype(np.float64)
            gb = gb_pad[pad:pad + w, pad:pad + w]
            if ga.std() < min_texture or gb.std() < min_texture:
                continue
            taken.append(rc)
            total = np.zeros(2)
            response = 0.0
            for _ in range(refine + 1):
                # b shifted back by the shift found so far: b'(x) = b(x + total), resampled bilinearly
                m = np.array([[1.0, 0.0, total[0]], [0.0, 1.0, total[1]]])
                gbs = cv2.warpAffine(gb_pad, m, gb_pad.shape[::-1], flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                     borderMode=cv2.BORDER_REFLECT)[pad:pad + w, pad:pad + w] if np.any(total) else gb
                (dx, dy), response = cv2.phaseCorrelate(ga, gbs, hann)
                total += (dx, dy)
                if np.hypot(dx, dy) < 0.005 or np.max(np.abs(total)) > pad - 1:
                    break
            dx, dy = total
            if response < min_response:
                continue
            centres.append(rc.astype(np.float64))
            shifts.append((dx, dy))
            resp.append(response)
        out.append(SeamOffset(a, b, len(cells), np.asarray(centres, np.float64).reshape(-1, 2),
                              np.asarray(shifts, np.float64).reshape(-1, 2), np.asarray(resp, np.float64)))
    return out
