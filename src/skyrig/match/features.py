"""Local features: SIFT through OpenCV or pycolmap, on a downscaled copy or an image pyramid level.

Keypoint positions are always returned in **full-resolution skyrig pixels** (column right, row down, origin at
the centre of the top-left pixel), whatever scale the detector ran on.  OpenCV's keypoints already use the
pixel-centre origin; COLMAP's use the top-left *corner* of the top-left pixel, so 0.5 is subtracted.
A level downscaled by ``s`` maps back as ``x_full = (x_level + 0.5) * s - 0.5``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

Method = Literal["opencv", "pycolmap"]


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

    def __post_init__(self) -> None:
        if self.method not in ("opencv", "pycolmap"):
            raise ValueError(f"unknown feature method {self.method!r} (opencv or pycolmap)")
        if self.max_size is not None and self.max_size < 32:
            raise ValueError("max_size must be at least 32 pixels")
        if self.max_features < 1:
            raise ValueError("max_features must be positive")


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


def downscale(image: NDArray, max_size: int | None) -> tuple[NDArray, float]:
    """Downscale so that the longer side is at most ``max_size``; returns (image, factor full/level >= 1)."""
    import cv2

    h, w = image.shape[:2]
    if max_size is None or max(h, w) <= max_size:
        return image, 1.0
    s = max(h, w) / max_size
    size = (max(1, round(w / s)), max(1, round(h / s)))
    out = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    return out, w / size[0]


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


def _colmap_sift(opts: object) -> object:
    import warnings

    import pycolmap

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        return pycolmap.Sift(opts, device=pycolmap.Device.cpu)


def extract_features(image: NDArray, config: FeatureConfig = FeatureConfig()) -> Features:
    """Detect and describe SIFT features.

    Parameters
    ----------
    image
        ``(H, W)`` or ``(H, W, 3)`` uint8 / uint16 full-resolution image.
    config
        Detector settings.

    Returns
    -------
    Features with positions in full-resolution pixels.
    """
    img = to_uint8(image)
    h, w = img.shape[:2]
    level, s = downscale(img, config.max_size)
    if config.method == "opencv":
        import cv2

        sift = cv2.SIFT_create(nfeatures=config.max_features, contrastThreshold=config.contrast_threshold)
        kps, desc = sift.detectAndCompute(level, None)
        if not kps:
            return Features(np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros((0, 128), np.uint8), (w, h))
        xy = np.array([k.pt for k in kps], dtype=np.float64)
        size = np.array([k.size for k in kps], dtype=np.float64)
        ang = np.array([k.angle for k in kps], dtype=np.float64)
        resp = np.array([k.response for k in kps], dtype=np.float64)
        desc = desc.astype(np.float32)
        pre_normalised = False
    else:
        import pycolmap

        opts = pycolmap.FeatureExtractionOptions()
        opts.max_image_size = max(level.shape[:2]) + 1
        opts.sift.max_num_features = config.max_features
        opts.sift.peak_threshold = config.contrast_threshold / 3.0
        opts.use_gpu = False
        kp, desc = _colmap_sift(opts).extract(np.ascontiguousarray(level))
        kp = np.asarray(kp, dtype=np.float64)
        xy = kp[:, :2] - 0.5  # COLMAP: origin at the top-left corner of the top-left pixel
        size = kp[:, 2] * 2.0
        ang = np.degrees(kp[:, 3])
        resp = size  # COLMAP keeps the strongest already; prefer larger scales when trimming
        desc = np.asarray(desc, dtype=np.float32)
        desc = desc * 512.0  # COLMAP returns unit-norm RootSIFT floats; same uint8 scale as _root_sift
        pre_normalised = True
    order = np.argsort(-resp, kind="stable")[: config.max_features]
    xy, size, ang, desc = xy[order], size[order], ang[order], desc[order]
    xy_full = (xy + 0.5) * s - 0.5
    if pre_normalised:
        d8 = np.clip(np.round(desc), 0, 255).astype(np.uint8)
    else:
        d8 = _root_sift(desc) if config.root_sift else _quantise(desc)
    return Features(xy_full, size * s, ang, d8, (w, h))
