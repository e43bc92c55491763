"""One image resampled onto a north-up grid of any CRS over a smooth reference surface (the live mode's quick ortho).

:func:`rectify_onto_grid` is the per-exposure ortho of ``skyrig live`` (:mod:`skyrig.pipeline.live`): the output
grid (e.g. the Web Mercator pixels of the XYZ tiles an image touches, so that no second resampling follows) is
mapped to the ground with PROJ (grid CRS -> the orientations' map CRS, plus the reference surface's height there),
to a local ENU frame at the camera (rigorous, through ECEF: :meth:`WorldFrame.points_to`) and into the image with the
full camera model (:meth:`FrameCamera.project_pixels`, distortion included).  That chain runs on a lattice every
``step`` grid pixels only; the pixel positions in between are interpolated bilinearly from the lattice (OpenCV
``cv2.remap`` of the lattice) and the image is resampled bilinearly (``cv2.remap``).

What it leaves out, next to the true ortho of :func:`skyrig.dense.ortho.orthomosaic`: occlusions (a reference
DEM of tens of metres hides nothing from an aerial camera) and radiometric balancing.  The lattice interpolation
error is the second derivative of the mapping over ``step`` pixels: lens distortion and a DEM sampled bilinearly
are smooth at ``step = 8`` (about 10 m on the ground at a 1.2 m pixel), the error stays well under a pixel
(``tests/test_live.py`` compares with the exact mapping).
"""

from __future__ import annotations

from typing import Callable

import cv2
import numpy as np
from numpy.typing import NDArray

from skyrig.camera.frame import FrameCamera
from skyrig.geodesy.crs import horizontal_crs, resolve_crs, transformer
from skyrig.geodesy.frame import local_frame_for
from skyrig.georef.eo import ExteriorOrientations

__all__ = ["rectify_onto_grid", "rectify_maps", "grid_to_image"]

HeightAt = Callable[[NDArray[np.float64], NDArray[np.float64]], NDArray[np.float64]]


def grid_to_image(eo: ExteriorOrientations, i: int, camera: FrameCamera, grid_crs: str, gx: NDArray[np.float64],
                  gy: NDArray[np.float64], height_at: HeightAt) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Pixel positions (col, row; NaN behind the camera) in image ``i`` of ``eo`` of the ground under grid points
    ``(gx, gy)`` of ``grid_crs``, at the reference surface's height ``height_at(x, y)`` (``x, y`` in the horizontal
    CRS of ``eo.frame``, heights of ``eo.frame``)."""
    frame = eo.frame
    shape = np.shape(gx)
    tr = transformer(grid_crs, horizontal_crs(resolve_crs(frame.crs)))
    x, y = tr.transform(np.ravel(gx), np.ravel(gy))
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    h = np.asarray(height_at(x, y), np.float64)
    one = eo.subset([i])
    local = local_frame_for(frame.to_ecef(one.centre))
    el = one.to_frame(local)
    p = frame.points_to(np.column_stack([x, y, h]), local)
    pc = (p - el.centre[0]) @ el.rotation[0]  # world -> camera: R^T (P - C), row-wise (P - C) @ R
    with np.errstate(invalid="ignore", divide="ignore"):
        uv = camera.project_pixels(pc)
    bad = ~(-pc[:, 2] > 0) | ~np.isfinite(h)
    uv[bad] = np.nan
    return uv[:, 0].reshape(shape), uv[:, 1].reshape(shape)


def rectify_onto_grid(image: NDArray[np.uint8], eo: ExteriorOrientations, i: int, camera: FrameCamera,
                      grid_crs: str, xmin: float, ymax: float, pixel: float, width: int, height: int,
                      height_at: HeightAt, step: int = 8, level: int = 0) -> NDArray[np.uint8]:
    """``(height, width, 4)`` RGBA of image ``i`` of ``eo`` on the north-up grid of ``grid_crs`` with upper-left
    corner ``(xmin, ymax)`` and square ``pixel`` size; alpha 255 where the image sees the ground, 0 elsewhere.

    ``level``: ``image`` is the camera's image reduced ``level`` times by ``cv2.pyrDown`` (for a grid ``2**level``
    times coarser than the image's GSD: no aliasing)."""
    f = 2 ** int(level)
    ew, eh = camera.width, camera.height
    for _ in range(int(level)):  # cv2.pyrDown's size: (w + 1) // 2
        ew, eh = (ew + 1) // 2, (eh + 1) // 2
    if image.shape[:2] != (eh, ew):
        from skyrig.errors import SkyrigError

        raise SkyrigError(f"image {eo.image[i]!r} is {image.shape[1]} x {image.shape[0]} px but its camera "
                          f"{camera.name!r} reduced {level} times is {ew} x {eh}")
    mu, mv = rectify_maps(eo, i, camera, grid_crs, xmin, ymax, pixel, width, height, height_at, step, level)
    img = image if image.ndim == 3 else np.dstack([image] * 3)
    src = cv2.cvtColor(np.ascontiguousarray(img[..., :3]), cv2.COLOR_RGB2RGBA)  # alpha 255 inside the image
    out = np.asarray(cv2.remap(src, mu, mv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0),
                     np.uint8)
    # a pixel whose bilinear footprint reaches outside the image (alpha < 255) has no whole colour: none
    out[..., 3] = cv2.threshold(np.ascontiguousarray(out[..., 3]), 254, 255, cv2.THRESH_BINARY)[1]
    return out


def rectify_maps(eo: ExteriorOrientations, i: int, camera: FrameCamera, grid_crs: str, xmin: float, ymax: float,
                 pixel: float, width: int, height: int, height_at: HeightAt, step: int = 8, level: int = 0
                 ) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """The ``cv2.remap`` maps of :func:`rectify_onto_grid`: for every grid pixel its column and row in the image
    (reduced ``level`` times; -10 where the ground is behind the camera or has no height), exact on a lattice every
    ``step`` pixels and bilinear in between."""
    f = 2 ** int(level)
    step = max(int(step), 1)
    # a lattice every ``step`` grid pixels, at grid pixels (k + 0.5) step - 0.5 for k = -1 .. n: cv2.resize to
    # (n + 2) step pixels then interpolates it bilinearly at every grid pixel exactly (its pixel-centre
    # convention), the outer ring keeping the border pixels interpolated rather than extrapolated
    n, m = -(-width // step), -(-height // step)
    kk = (np.arange(-1, n + 1) + 0.5) * step - 0.5
    ll = (np.arange(-1, m + 1) + 0.5) * step - 0.5
    gx, gy = np.meshgrid(xmin + (kk + 0.5) * pixel, ymax - (ll + 0.5) * pixel)
    u, v = grid_to_image(eo, i, camera, grid_crs, gx, gy, height_at)
    if f > 1:  # pixel centres of the reduced image (cv2.pyrDown halves about the pixel centres' grid)
        u, v = (u + 0.5) / f - 0.5, (v + 0.5) / f - 0.5
    mu: NDArray[np.float32]
    mv: NDArray[np.float32]
    if step == 1:
        mu, mv = u[1:-1, 1:-1].astype(np.float32), v[1:-1, 1:-1].astype(np.float32)
    else:
        size = ((n + 2) * step, (m + 2) * step)
        mu = np.asarray(cv2.resize(u.astype(np.float32), size, interpolation=cv2.INTER_LINEAR),
                        np.float32)[step:step + height, step:step + width]
        mv = np.asarray(cv2.resize(v.astype(np.float32), size, interpolation=cv2.INTER_LINEAR),
                        np.float32)[step:step + height, step:step + width]
    mu, mv = np.ascontiguousarray(mu), np.ascontiguousarray(mv)
    cv2.patchNaNs(mu, -10.0)  # behind the camera or no height: outside the image
    cv2.patchNaNs(mv, -10.0)
    return mu, mv
