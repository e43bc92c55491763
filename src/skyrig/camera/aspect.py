"""Cameras given with two focal lengths ``fx != fy`` (non-square pixels, a pixel aspect ratio other than 1).

skyrig's :class:`~skyrig.camera.frame.FrameCamera` has one principal distance; the difference between the two
image axes is the **affinity** term ``B1`` of the Brown / Australis model (:mod:`skyrig.camera.brown`):
``x_ideal = (1 + B1) x_observed`` (with only B1).  A pinhole ``col = cx + fx X/Z``, ``row = cy + fy Y/Z``
(OpenCV's camera frame, focal lengths in pixels) is therefore exactly::

    focal_px = fy,   B1 = fy / fx - 1            (so fx = focal_px / (1 + B1))

the principal distance taken from the *y* (row) axis, the columns scaled by ``1 / (1 + B1)``.  The map is exact
(no approximation: B1 is linear, the projection's Newton step solves it in one iteration) for a camera with no
other distortion, and keeps its meaning when it is combined with the other Brown terms (``k1 ... p2``, B2 = 0),
which then act as usual on the observed (measured) image coordinates.  Other distortion models (OpenCV's
apply ``fx``, ``fy`` *after* their distortion of normalised coordinates) cannot carry ``fx != fy`` and are
refused.

:func:`camera_from_fx_fy` builds such a camera, :func:`fx_fy_px` gives ``(fx, fy)`` back for a camera whose only
distortion is the affinity (what writers use to write the camera the way it was entered).
"""

from __future__ import annotations

from skyrig.camera.brown import BrownDistortion
from skyrig.camera.distortion import Distortion, NoDistortion
from skyrig.camera.frame import FrameCamera

__all__ = ["camera_from_fx_fy", "fx_fy_px", "with_fx_fy"]

#: relative difference of fx and fy below which they are one focal length (no affinity term is made)
SQUARE_RTOL = 1e-12


def with_fx_fy(fx: float, fy: float, distortion: Distortion | None = None) -> tuple[float, Distortion]:
    """``(focal_px, distortion)`` of skyrig's model for the focal lengths ``fx``, ``fy`` (pixels) and a
    distortion (None: none).  Raises ValueError for non-positive focal lengths, for ``fx != fy`` with a
    distortion model other than Brown, and for ``fx != fy`` with a Brown model that has its own B1."""
    fx, fy = float(fx), float(fy)
    if not (fx > 0 and fy > 0):
        raise ValueError(f"focal lengths must be positive, got fx = {fx}, fy = {fy}")
    d = NoDistortion() if distortion is None else distortion
    if abs(fx - fy) <= SQUARE_RTOL * fy:
        return fy, d
    b1 = fy / fx - 1.0
    if isinstance(d, NoDistortion):
        return fy, BrownDistortion(b1=b1)
    if isinstance(d, BrownDistortion):
        if d.b1 != 0.0:
            raise ValueError(f"fx = {fx} != fy = {fy} and the Brown distortion's own b1 = {d.b1}: give one of them "
                             "(fx != fy is the Brown b1 term)")
        return fy, BrownDistortion(d.k1, d.k2, d.k3, d.p1, d.p2, b1, d.b2)
    raise ValueError(f"fx = {fx} != fy = {fy} cannot be combined with the {d.name!r} distortion model (skyrig "
                     "carries fx != fy as the Brown affinity b1; use the 'brown' model, or fx = fy)")


def camera_from_fx_fy(name: str, width: int, height: int, fx: float, fy: float, pp_col: float, pp_row: float,
                      pixel_size_mm: float = 0.001, distortion: Distortion | None = None) -> FrameCamera:
    """A :class:`FrameCamera` projecting as the pinhole ``col = pp_col + fx X/Z``, ``row = pp_row + fy Y/Z``
    (OpenCV's frame and pixel convention, :mod:`skyrig.camera.frame`), see the module docstring."""
    f, d = with_fx_fy(fx, fy, distortion)
    return FrameCamera.from_pixels(name, width, height, f, pp_col, pp_row, pixel_size_mm=pixel_size_mm, distortion=d)


def fx_fy_px(camera: FrameCamera) -> tuple[float, float] | None:
    """``(fx, fy)`` in pixels when ``camera``'s only distortion is a non-zero Brown affinity B1 (a camera entered
    with ``fx != fy``), else None (square pixels, or other distortion terms: write the camera as it is)."""
    d = camera.distortion
    if not isinstance(d, BrownDistortion) or d.b1 == 0.0:
        return None
    if any(getattr(d, k) != 0.0 for k in ("k1", "k2", "k3", "p1", "p2", "b2")):
        return None
    fy = camera.focal_px
    return fy / (1.0 + d.b1), fy
