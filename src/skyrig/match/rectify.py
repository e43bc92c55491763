"""Feature detection on oblique images rectified to the ground plane (a nadir-like view).

SIFT is invariant to scale and rotation but not to the strong anisotropic foreshortening of a 45-degree oblique
view: its blobs are found (and described) on a squashed image of the ground, so the same ground feature lands on
slightly different physical points in a nadir and an oblique view, the more the coarser the keypoint scale.  The
standard remedy (professional oblique-block software, ASIFT's idea with the *predicted* affine): warp each oblique
image by the ground-plane mapping of its approximate exterior orientation to a nadir-like geometry at its own
ground sampling distance, detect and describe there, and map every keypoint back.

The mapping is exact in skyrig's camera model (distortion included): a rectified pixel ``(u, v)`` is the ground
point ``O + gsd (u e_col + v e_row)`` on the plane ``z = ground_height``; its image pixel is
:meth:`FrameCamera.world_to_pixel`.  Keypoints therefore come back to the original image with no approximation;
only the *detection* happens in the rectified geometry.  The approximate orientation need not be accurate
(degrees of attitude error and tens of metres of height error only change how nadir-like the rectified view is).

The world frame must have z up (local ENU, or a map grid with heights).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from skyrig.camera.frame import FrameCamera
from skyrig.errors import GeometryError
from skyrig.geometry.pose import Pose

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class GroundRectification:
    """A rectified (ground-plane, north-free nadir-like) grid of one image.

    Attributes
    ----------
    origin
        ``(3,)`` world position of rectified pixel (0, 0) (its centre), metres.
    e_col, e_row
        ``(3,)`` horizontal unit vectors of the rectified columns and rows (``e_row`` is ``e_col`` turned 90 deg
        clockwise seen from above, so the rectified image is never mirrored).
    gsd_m
        Rectified pixel size, metres.
    size
        (width, height) of the rectified image, pixels.
    """

    origin: NDArray[np.float64]
    e_col: NDArray[np.float64]
    e_row: NDArray[np.float64]
    gsd_m: float
    size: tuple[int, int]

    def ground(self, uv: NDArray) -> NDArray[np.float64]:
        """World points ``(N, 3)`` of rectified pixels ``(N, 2)``."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        return self.origin + self.gsd_m * (uv[:, :1] * self.e_col + uv[:, 1:] * self.e_row)


def tilt_deg(world_from_camera: Pose) -> float:
    """Angle between the camera's viewing direction (``-z``) and the vertical (down), degrees."""
    view = -np.asarray(world_from_camera.rotation, dtype=np.float64)[:, 2]
    return float(np.degrees(np.arccos(np.clip(-view[2] / np.linalg.norm(view), -1.0, 1.0))))


def ground_rectification(
    camera: FrameCamera, world_from_camera: Pose, ground_height: float, max_pixels: float = 4.0e6,
    max_range_factor: float = 4.0,
) -> GroundRectification:
    """The rectified grid covering an image's footprint on the plane ``z = ground_height``.

    The pixel size is the geometric mean ground footprint of the image's central pixel (``sqrt`` of the
    Jacobian determinant pixel -> ground), so the image centre keeps its resolution; the far field of an oblique
    is up-sampled, the near field down-sampled.  Far-field ground beyond ``max_range_factor`` times the central
    ray's range is cut, and the pixel size grows if the grid would exceed ``max_pixels``.

    Raises
    ------
    GeometryError
        The central ray does not reach the ground plane (camera at or below it, or looking at the horizon).
    """
    R = np.asarray(world_from_camera.rotation, dtype=np.float64)
    C = np.asarray(world_from_camera.translation, dtype=np.float64).reshape(3)
    w, h = camera.width, camera.height
    ctr = np.array([[(w - 1) / 2.0, (h - 1) / 2.0]])

    def hit(px: NDArray) -> tuple[NDArray, NDArray]:
        d = camera.rays_from_pixels(px) @ R.T
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (ground_height - C[2]) / d[:, 2]
        ok = np.isfinite(t) & (t > 0)
        return C + np.where(ok, t, np.nan)[:, None] * d, t

    g0, t0 = hit(ctr)
    if not (np.isfinite(t0[0]) and t0[0] > 0):
        raise GeometryError("the image centre's ray does not reach the ground plane: no rectification")
    eps = 0.5
    gx, _ = hit(ctr + [[eps, 0.0]])
    gy, _ = hit(ctr + [[0.0, eps]])
    J = np.column_stack([(gx - g0)[0, :2], (gy - g0)[0, :2]]) / eps
    gsd = float(np.sqrt(abs(np.linalg.det(J))))
    if not np.isfinite(gsd) or gsd <= 0:
        raise GeometryError("degenerate ground footprint of the image centre: no rectification")
    cam_x = R[:, 0].copy()
    cam_x[2] = 0.0
    if np.linalg.norm(cam_x) < 1e-6:  # camera x axis vertical (90 deg roll): use the viewing direction
        cam_x = np.cross(-R[:, 2], [0.0, 0.0, 1.0])
    e_col = cam_x / np.linalg.norm(cam_x)
    e_row = np.array([e_col[1], -e_col[0], 0.0])  # turned 90 deg clockwise seen from above (x east, y north)
    # footprint: the image border and an inner grid, clipped to max_range_factor x the central range
    s = np.linspace(0.0, 1.0, 33)
    border = np.concatenate([np.column_stack([s * (w - 1), np.zeros_like(s)]),
                             np.column_stack([s * (w - 1), np.full_like(s, h - 1.0)]),
                             np.column_stack([np.zeros_like(s), s * (h - 1)]),
                             np.column_stack([np.full_like(s, w - 1.0), s * (h - 1)])])
    gb, tb = hit(border)
    rmax = max_range_factor * float(t0[0])
    d = np.asarray(camera.rays_from_pixels(border) @ R.T)
    far = ~np.isfinite(tb) | (tb > rmax)
    horiz = d[:, :2] / np.maximum(np.linalg.norm(d[:, :2], axis=1, keepdims=True), 1e-12)
    reach = np.sqrt(max(rmax**2 - (C[2] - ground_height) ** 2, 0.0))
    gb[far] = np.column_stack([C[0] + reach * horiz[far, 0], C[1] + reach * horiz[far, 1],
                               np.full(int(far.sum()), ground_height)])
    gb = gb[np.all(np.isfinite(gb), axis=1)]
    a = (gb - g0) @ np.column_stack([e_col, e_row])  # (M, 2) metres along col / row
    lo, hi = a.min(axis=0), a.max(axis=0)
    npx = float(np.prod((hi - lo) / gsd + 1.0))
    if npx > max_pixels:
        gsd *= float(np.sqrt(npx / max_pixels))
    size = (int(np.ceil((hi[0] - lo[0]) / gsd)) + 1, int(np.ceil((hi[1] - lo[1]) / gsd)) + 1)
    origin = g0[0] + lo[0] * e_col + lo[1] * e_row
    origin[2] = ground_height
    return GroundRectification(origin, e_col, e_row, gsd, size)


def rectify_image(
    image: NDArray, camera: FrameCamera, world_from_camera: Pose, rect: GroundRectification,
    level_scale: float | NDArray[np.float64] = 1.0,
) -> tuple[NDArray, NDArray[np.uint8]]:
    """Warp an image (or a pyramid level of it) onto the rectified grid (bilinear).

    Parameters
    ----------
    image
        ``(h, w)`` grey image: the full-resolution image downscaled by ``level_scale`` (full / level >= 1; one
        factor or ``[columns, rows]``).
    rect
        The grid (:func:`ground_rectification` of the full-resolution camera).

    Returns
    -------
    rectified
        ``(H_r, W_r)`` image of the same dtype.
    mask
        ``(H_r, W_r)`` uint8, 255 where the rectified pixel lies inside the image (2 level pixels margin).
    """
    import cv2

    W, H = rect.size
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    px = camera.world_to_pixel(world_from_camera, rect.ground(np.column_stack([u.ravel(), v.ravel()])))
    lv = (px + 0.5) / np.asarray(level_scale, dtype=np.float64) - 0.5
    h, w = image.shape[:2]
    with np.errstate(invalid="ignore"):
        inside = (np.all(np.isfinite(lv), axis=1) & (lv[:, 0] >= 2) & (lv[:, 1] >= 2) & (lv[:, 0] <= w - 3)
                  & (lv[:, 1] <= h - 3))
    lv[~inside] = -10.0
    mx = lv[:, 0].reshape(H, W).astype(np.float32)
    my = lv[:, 1].reshape(H, W).astype(np.float32)
    out = cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    mask = np.where(inside.reshape(H, W), 255, 0).astype(np.uint8)
    return out, mask


def keypoints_to_image(
    uv: NDArray, size_px: NDArray, angle_deg: NDArray, camera: FrameCamera, world_from_camera: Pose,
    rect: GroundRectification,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Rectified keypoints back to full-resolution image pixels (exact), with sizes and angles mapped through the
    local Jacobian of the mapping.

    Parameters
    ----------
    uv
        ``(N, 2)`` rectified keypoint positions (pixel-centre origin).
    size_px, angle_deg
        ``(N,)`` rectified keypoint diameters (pixels) and orientations (degrees, OpenCV: clockwise in the
        image, i.e. measured from +u towards +v).

    Returns
    -------
    xy, size, angle
        ``(N, 2)`` image pixels, ``(N,)`` diameters (image pixels, geometric mean scale) and angles (degrees).
    """
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)

    def to_img(q: NDArray) -> NDArray:
        return camera.world_to_pixel(world_from_camera, rect.ground(q))

    xy = to_img(uv)
    e = 0.5
    jx = (to_img(uv + [e, 0.0]) - to_img(uv - [e, 0.0])) / (2 * e)  # d xy / d u
    jy = (to_img(uv + [0.0, e]) - to_img(uv - [0.0, e])) / (2 * e)
    det = np.abs(jx[:, 0] * jy[:, 1] - jx[:, 1] * jy[:, 0])
    size = np.asarray(size_px, dtype=np.float64) * np.sqrt(det)
    a = np.radians(np.asarray(angle_deg, dtype=np.float64))
    dvec = jx * np.cos(a)[:, None] + jy * np.sin(a)[:, None]
    angle = np.degrees(np.arctan2(dvec[:, 1], dvec[:, 0])) % 360.0
    return xy, size, angle
