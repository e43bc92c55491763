"""Lens distortion models (placeholder registry; full models in brown.py / opencv.py)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray


class Distortion:
    """Base class: maps ideal image coordinates relative to the principal point (mm) to observed ones."""

    name = "base"

    def distort(self, xy: ArrayLike, focal_mm: float) -> NDArray[np.float64]:
        raise NotImplementedError

    def undistort(self, xy: ArrayLike, focal_mm: float) -> NDArray[np.float64]:
        raise NotImplementedError


@dataclass(frozen=True)
class NoDistortion(Distortion):
    """The identity: an ideal pinhole."""

    name = "none"

    def distort(self, xy: ArrayLike, focal_mm: float) -> NDArray[np.float64]:
        return np.asarray(xy, dtype=np.float64)

    def undistort(self, xy: ArrayLike, focal_mm: float) -> NDArray[np.float64]:
        return np.asarray(xy, dtype=np.float64)
