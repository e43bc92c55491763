"""Image files (PNG, TIFF, JPEG) through OpenCV; RGB arrays in memory, BGR on disk as OpenCV wants."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from skyrig.errors import InputFormatError
from skyrig.io._text import PathLike, output_temp, publish


def write_image(path: PathLike, rgb: NDArray[np.uint8]) -> None:
    """Write an ``(H, W, 3)`` RGB or ``(H, W)`` grey uint8 image; the format follows the suffix (atomic)."""
    import cv2

    p = Path(path)
    arr = np.asarray(rgb)
    if arr.ndim == 3:
        arr = arr[:, :, ::-1]
    fd, tmp = output_temp(p, p.suffix)
    os.close(fd)
    try:
        if not cv2.imwrite(tmp, np.ascontiguousarray(arr)):
            raise OSError(f"OpenCV could not write {p}")
        publish(tmp, p)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def read_image(path: PathLike) -> NDArray[np.uint8]:
    """Read an image as ``(H, W, 3)`` RGB uint8 (grey images are returned ``(H, W)``)."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InputFormatError("not a readable image", path)
    return img[:, :, ::-1].copy() if img.ndim == 3 else img
