"""Local features: SIFT through OpenCV or pycolmap, on a downscaled copy or an image pyramid level.

Keypoint positions are always returned in **full-resolution skyrig pixels** (column right, row down, origin at
the centre of the top-left pixel), whatever scale the detector ran on.  OpenCV's keypoints already use the
pixel-centre origin; COLMAP's use the top-left *corner* of the top-left pixel, so 0.5 is subtracted.
A level downscaled by ``s`` maps back as ``x_full = (x_level + 0.5) * s - 0.5``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import numpy as np
from numpy.typing import NDArray

from skyrig.errors import ConfigError

if TYPE_CHECKING:
    from skyrig.camera.frame import FrameCamera
    from skyrig.geometry.pose import Pose

logger = logging.getLogger(__name__)

Method = Literal["opencv", "pycolmap"]
Rectify = Literal["off", "oblique", "always"]


@dataclass(frozen=True)
class FeatureConfig:
    """Feature extraction settings."""

    #: ``"opencv"`` (cv2.SIFT) or ``"pycolmap"`` (COLMAP's SIFT through pycolmap).
    method: Method = "opencv"
    #: Longer image side (pixels) the detector runs on; larger images are downscaled (area averaging).
    #: None = full resolution.
    max_size: int | None = 1600
    #: Keep at most this many features per image (strongest responses first).
    max_features: int = 8000
    #: Contrast threshold of OpenCV's SIFT (lower = more, weaker features); COLMAP's peak threshold is
    #: this divided by OpenCV's octave-layer count (3).
    contrast_threshold: float = 0.02
    #: Convert descriptors to RootSIFT (L1-normalise, square root) before quantising to uint8.
    root_sift: bool = True
    #: Detect on the ground-plane rectification of the image when an approximate orientation and a terrain height
    #: are given to :func:`extract_features`: ``"oblique"`` (images tilted by ``rectify_min_tilt_deg`` or more),
    #: ``"always"`` or ``"off"``.  Nadir images and images without orientation are never affected by "oblique".
    rectify: Rectify = "oblique"
    #: Tilt from the vertical (degrees) from which "oblique" rectifies.
    rectify_min_tilt_deg: float = 20.0
    #: Largest rectified image as a multiple of the image's own pixel count (the far field is coarsened beyond).
    rectify_max_area: float = 3.0
    #: COLMAP's SIFT (``method="pycolmap"``) starts at octave -1 (the image upsampled 2 x: four times the pixels).
    #: Its budget keeps the largest scales, so on a large image that fills ``max_features`` from octave 0 on the
    #: upsampled octave's keypoints are dropped after costing most of the time.  ``None`` (auto): octave 0 when the
    #: detected image has at least :data:`OCTAVE0_PIXELS_PER_FEATURE` pixels per feature of the budget, and octave
    #: -1 again if octave 0 then falls short of the budget; otherwise -1 (COLMAP's default).  ``-1`` / ``0``: always
    #: that octave.  brighton-uav at full resolution (4000 x 2250, 8,000 features): 19.4 -> 3.2 CPU s per image,
    #: 97.5 % of the keypoints within 0.5 px of octave -1's (91.7 % within 0.05 px).
    colmap_first_octave: int | None = None

    def __post_init__(self) -> None:
        if self.method not in ("opencv", "pycolmap"):
            raise ConfigError(f"unknown feature method {self.method!r} (opencv or pycolmap)")
        if self.max_size is not None and self.max_size < 32:
            raise ConfigError("max_size must be at least 32 pixels")
        if self.max_features < 1:
            raise ConfigError("max_features must be positive")
        if self.rectify not in ("off", "oblique", "always"):
            raise ConfigError(f"unknown rectify mode {self.rectify!r} (off, oblique or always)")
        if self.colmap_first_octave not in (None, -1, 0):
            raise ConfigError(f"colmap_first_octave must be None (auto), -1 or 0, not {self.colmap_first_octave!r}")


@dataclass(frozen=True)
class Features:
    """Features of one image.

    Attributes
    ----------
    xy
        ``(N, 2)`` keypoint (column, row) in full-resolution pixels (skyrig origin, see module doc).
    scale
        ``(N,)`` keypoint size (diameter) in full-resolution pixels.
    angle_deg
        ``(N,)`` keypoint orientation, degrees.
    descriptors
        ``(N, 128)`` uint8 SIFT (or RootSIFT) descriptors.
    image_size
        (width, height) of the full-resolution image.
    """

    xy: NDArray[np.float64]
    scale: NDArray[np.float64]
    angle_deg: NDArray[np.float64]
    descriptors: NDArray[np.uint8]
    image_size: tuple[int, int]

    def __len__(self) -> int:
        return len(self.xy)


def to_uint8(image: NDArray) -> NDArray[np.uint8]:
    """Grey uint8 view of an 8 / 16 bit, grey or RGB image (16 bit: robust 0.1-99.9 % stretch)."""
    import cv2

    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    if img.dtype == np.uint8:
        return np.ascontiguousarray(img)
    f = img.astype(np.float32)
    lo, hi = np.percentile(f, [0.1, 99.9])
    if hi <= lo:
        hi = lo + 1.0
    return np.clip((f - lo) * (255.0 / (hi - lo)), 0, 255).astype(np.uint8)


def downscale(image: NDArray, max_size: int | None) -> tuple[NDArray, NDArray[np.float64]]:
    """Downscale so that the longer side is at most ``max_size``; returns (image, factors full/level >= 1 per
    axis ``[columns, rows]``: the two sides are rounded to whole pixels separately, so a 3000 x 2000 image becomes
    1600 x 1067 with factors 1.875 and 1.8744)."""
    import cv2

    h, w = image.shape[:2]
    if max_size is None or max(h, w) <= max_size:
        return image, np.ones(2)
    s = max(h, w) / max_size
    size = (max(1, round(w / s)), max(1, round(h / s)))
    out = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    return out, np.array([w / size[0], h / size[1]])


def pyramid(image: NDArray, levels: int) -> list[NDArray]:
    """Gaussian image pyramid ``[full, 1/2, 1/4, ...]`` (``levels`` images, cv2.pyrDown)."""
    import cv2

    out = [np.asarray(image)]
    for _ in range(levels - 1):
        if min(out[-1].shape[:2]) < 16:
            break
        out.append(cv2.pyrDown(out[-1]))
    return out


def _root_sift(desc: NDArray[np.float32]) -> NDArray[np.uint8]:
    d = desc / np.maximum(np.abs(desc).sum(axis=1, keepdims=True), 1e-12)
    d = np.sqrt(np.maximum(d, 0))
    return np.clip(np.round(d * 512.0), 0, 255).astype(np.uint8)


def _quantise(desc: NDArray[np.float32]) -> NDArray[np.uint8]:
    d = desc / np.maximum(np.linalg.norm(desc, axis=1, keepdims=True), 1e-12)
    return np.clip(np.round(d * 512.0), 0, 255).astype(np.uint8)


#: auto first octave of COLMAP's SIFT (:attr:`FeatureConfig.colmap_first_octave`): octave 0 is tried on images with
#: at least this many pixels per feature of the budget (brighton's 9.0 MP frames gave 10,693 keypoints from octave 0,
#: 1.2 per 1,000 pixels; a default 1,600 px level of them, 1.4 MP, stays at octave -1)
OCTAVE0_PIXELS_PER_FEATURE = 800


def first_octave(config: FeatureConfig, shape: tuple[int, ...]) -> int:
    """The first octave COLMAP's SIFT is run at first on an image of ``shape`` (see
    :attr:`FeatureConfig.colmap_first_octave`)."""
    if config.colmap_first_octave is not None:
        return int(config.colmap_first_octave)
    return 0 if shape[0] * shape[1] >= OCTAVE0_PIXELS_PER_FEATURE * config.max_features else -1


def _colmap_sift(opts: object) -> object:
    import warnings

    import pycolmap

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        return pycolmap.Sift(opts, device=pycolmap.Device.cpu)


def _opencv_sift(config: FeatureConfig) -> object:
    """cv2.SIFT with OpenCV's *precise* first-octave upscaling.

    OpenCV's default doubles the image with a pixel-centre bilinear resize (index ``x`` -> ``2 x + 0.5``) but
    halves keypoint coordinates as if it mapped ``x`` -> ``2 x``: every keypoint lands 0.25 px right of and
    below the feature (measured: a 180-degree rotated copy gives keypoints 0.5 px apart).  The offset cancels
    between images of the same orientation but not between images turned against each other (e.g. a nadir
    and a side-looking oblique head, 90 degrees apart: 0.57 px tie bias).  ``enable_precise_upscale`` (OpenCV
    >= 4.8) maps ``x`` -> ``2 x`` and removes it; older OpenCV gets the 0.25 px subtracted instead.
    """
    import cv2

    try:
        return cv2.SIFT_create(nfeatures=config.max_features, contrastThreshold=config.contrast_threshold,
                               enable_precise_upscale=True)
    except TypeError:  # pragma: no cover - OpenCV < 4.8
        return _ShiftedSift(cv2.SIFT_create(nfeatures=config.max_features,
                                            contrastThreshold=config.contrast_threshold), -0.25)


class _ShiftedSift:  # pragma: no cover - OpenCV < 4.8
    def __init__(self, sift: object, shift: float) -> None:
        self.sift, self.shift = sift, shift

    def detectAndCompute(self, image: NDArray, mask: object) -> tuple:  # noqa: N802 - OpenCV's name
        import cv2

        kps, desc = self.sift.detectAndCompute(image, mask)  # type: ignore[attr-defined]
        kps = [cv2.KeyPoint(k.pt[0] + self.shift, k.pt[1] + self.shift, k.size, k.angle, k.response, k.octave,
                            k.class_id) for k in kps]
        return kps, desc


def _detect(level: NDArray[np.uint8], config: FeatureConfig) -> tuple[NDArray, ...]:
    """SIFT on one grey uint8 image: level pixels (skyrig origin), diameters, angles, responses, descriptors
    and whether the descriptors are already RootSIFT-normalised."""
    if config.method == "opencv":
        kps, desc = _opencv_sift(config).detectAndCompute(level, None)  # type: ignore[attr-defined]
        if not kps:
            return np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros(0), np.zeros((0, 128), np.float32), False
        xy = np.array([k.pt for k in kps], dtype=np.float64)
        size = np.array([k.size for k in kps], dtype=np.float64)
        ang = np.array([k.angle for k in kps], dtype=np.float64)
        resp = np.array([k.response for k in kps], dtype=np.float64)
        return xy, size, ang, resp, desc.astype(np.float32), False
    import pycolmap

    opts = pycolmap.FeatureExtractionOptions()
    opts.max_image_size = max(level.shape[:2]) + 1
    opts.sift.max_num_features = config.max_features
    opts.sift.peak_threshold = config.contrast_threshold / 3.0
    opts.use_gpu = False
    opts.sift.first_octave = first_octave(config, level.shape)
    kp, desc = _colmap_sift(opts).extract(np.ascontiguousarray(level))  # type: ignore[attr-defined]
    if opts.sift.first_octave == 0 and config.colmap_first_octave is None and len(kp) < config.max_features:
        opts.sift.first_octave = -1  # the budget is not filled without the upsampled octave: COLMAP's default
        kp, desc = _colmap_sift(opts).extract(np.ascontiguousarray(level))  # type: ignore[attr-defined]
    kp = np.asarray(kp, dtype=np.float64).reshape(-1, 4)
    xy = kp[:, :2] - 0.5  # COLMAP: origin at the top-left corner of the top-left pixel
    size = kp[:, 2] * 2.0
    ang = np.degrees(kp[:, 3])
    # COLMAP keeps the strongest already; prefer larger scales when trimming.  Unit-norm RootSIFT floats: same
    # uint8 scale as _root_sift
    return xy, size, ang, size.copy(), np.asarray(desc, dtype=np.float32).reshape(-1, 128) * 512.0, True


def wants_rectification(config: FeatureConfig, world_from_camera: Pose | None) -> bool:
    """Whether :func:`extract_features` rectifies an image of this orientation under ``config``."""
    if world_from_camera is None or config.rectify == "off":
        return False
    if not np.all(np.isfinite(world_from_camera.rotation)):
        return False
    from skyrig.match.rectify import tilt_deg

    return config.rectify == "always" or tilt_deg(world_from_camera) >= config.rectify_min_tilt_deg


def extract_features(
    image: NDArray, config: FeatureConfig = FeatureConfig(), camera: FrameCamera | None = None,
    world_from_camera: Pose | None = None, ground_height: float | None = None,
) -> Features:
    """Detect and describe SIFT features.

    Parameters
    ----------
    image
        ``(H, W)`` or ``(H, W, 3)`` uint8 / uint16 full-resolution image.
    config
        Detector settings.
    camera, world_from_camera, ground_height
        Optional approximate orientation of the image (world frame with z up) and the mean terrain height in
        that frame (metres).  With all three, an image tilted by ``config.rectify_min_tilt_deg`` or more (an
        oblique head) is detected on its ground-plane rectification (:mod:`skyrig.match.rectify`) and the
        keypoints are mapped back exactly; without them, or for nadir images, nothing changes.

    Returns
    -------
    Features with positions in full-resolution pixels.
    """
    img = to_uint8(image)
    h, w = img.shape[:2]
    level, s = downscale(img, config.max_size)
    rect = None
    if camera is not None and ground_height is not None and wants_rectification(config, world_from_camera):
        from skyrig.errors import GeometryError
        from skyrig.match.rectify import ground_rectification, keypoints_to_image, rectify_image

        assert world_from_camera is not None
        try:
            full = ground_rectification(camera, world_from_camera, float(ground_height),
                                        max_pixels=config.rectify_max_area * w * h)
        except GeometryError as exc:
            logger.info("no rectification (%s): features on the original image", exc)
        else:
            from dataclasses import replace as _replace

            sm = float(np.sqrt(s[0] * s[1]))  # the rectified grid's own scale: one factor
            rect = _replace(full, gsd_m=full.gsd_m * sm,
                            size=(int(np.ceil(full.size[0] / sm)), int(np.ceil(full.size[1] / sm))))
    if rect is not None:
        import cv2

        rimg, mask = rectify_image(level, camera, world_from_camera, rect, level_scale=s)  # type: ignore[arg-type]
        xy_r, size_r, ang_r, resp, desc, pre_normalised = _detect(rimg, config)
        inner = cv2.erode(mask, np.ones((9, 9), np.uint8))
        ij = np.round(xy_r).astype(np.int64)
        ok = (ij[:, 0] >= 0) & (ij[:, 1] >= 0) & (ij[:, 0] < inner.shape[1]) & (ij[:, 1] < inner.shape[0])
        ok[ok] = inner[ij[ok, 1], ij[ok, 0]] > 0
        xy_r, size_r, ang_r, resp, desc = xy_r[ok], size_r[ok], ang_r[ok], resp[ok], desc[ok]
        xy_full, size_full, ang = keypoints_to_image(xy_r, size_r, ang_r, camera, world_from_camera, rect)  # type: ignore[arg-type]
        fin = np.all(np.isfinite(xy_full), axis=1)
        xy_full, size_full, ang, resp, desc = xy_full[fin], size_full[fin], ang[fin], resp[fin], desc[fin]
    else:
        xy, size, ang, resp, desc, pre_normalised = _detect(level, config)
        xy_full = (xy + 0.5) * s - 0.5  # per axis
        size_full = size * float(np.sqrt(s[0] * s[1]))
    order = np.argsort(-resp, kind="stable")[: config.max_features]
    xy_full, size_full, ang, desc = xy_full[order], size_full[order], ang[order], desc[order]
    if pre_normalised:
        d8 = np.clip(np.round(desc), 0, 255).astype(np.uint8)
    else:
        d8 = _root_sift(desc) if config.root_sift else _quantise(desc)
    return Features(xy_full, size_full, ang, d8, (w, h))
