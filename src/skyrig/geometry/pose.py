"""Rigid transforms that carry the names of their frames.

A :class:`Pose` named ``dst_from_src`` maps points of frame *src* to frame *dst*::

    x_dst = rotation @ x_src + translation

so ``translation`` is the origin of *src* expressed in *dst*.  For a camera, ``world_from_camera``
has the projection centre as translation and the photogrammetric rotation matrix (see
:mod:`skyrig.geometry.rotations`).  Poses may be batched: ``rotation`` ``(N, 3, 3)`` and
``translation`` ``(N, 3)``; composition broadcasts.  Composing poses whose inner frames differ
raises :class:`~skyrig.errors.FrameError`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.errors import FrameError


@dataclass(frozen=True)
class Pose:
    """Rigid transform ``dst_from_src`` with named frames (optionally a batch of them).

    Attributes
    ----------
    rotation
        ``(3, 3)`` or ``(N, 3, 3)`` rotation matrices ``dst_from_src``.
    translation
        ``(3,)`` or ``(N, 3)``: origin of *src* in *dst* coordinates (metres).
    dst, src
        Frame names, e.g. ``"world"``, ``"body"``, ``"camera:nadir"``.
    """

    rotation: NDArray[np.float64]
    translation: NDArray[np.float64]
    dst: str
    src: str

    def __post_init__(self) -> None:
        r = np.asarray(self.rotation, dtype=np.float64)
        t = np.asarray(self.translation, dtype=np.float64)
        if r.shape[-2:] != (3, 3) or t.shape[-1:] != (3,):
            raise ValueError(f"Pose needs rotation (...,3,3) and translation (...,3), got {r.shape}, {t.shape}")
        object.__setattr__(self, "rotation", r)
        object.__setattr__(self, "translation", t)

    @classmethod
    def identity(cls, dst: str, src: str) -> "Pose":
        """The identity transform between two frames that coincide."""
        return cls(np.eye(3), np.zeros(3), dst, src)

    @property
    def name(self) -> str:
        """``"dst_from_src"``."""
        return f"{self.dst}_from_{self.src}"

    def __len__(self) -> int:
        if self.rotation.ndim == 2:
            raise TypeError("a single Pose has no length")
        return self.rotation.shape[0]

    def __getitem__(self, index: object) -> "Pose":
        return Pose(self.rotation[index], self.translation[index], self.dst, self.src)

    def inverse(self) -> "Pose":
        """``src_from_dst``."""
        rt = np.swapaxes(self.rotation, -1, -2)
        return Pose(rt, -np.einsum("...ij,...j->...i", rt, self.translation), self.src, self.dst)

    def __matmul__(self, other: "Pose") -> "Pose":
        """``(a_from_b) @ (b_from_c) -> a_from_c``; raises FrameError if the b's differ."""
        if not isinstance(other, Pose):
            return NotImplemented
        if self.src != other.dst:
            raise FrameError(f"cannot compose {self.name} with {other.name}: '{self.src}' != '{other.dst}'")
        return Pose(
            self.rotation @ other.rotation,
            np.einsum("...ij,...j->...i", self.rotation, other.translation) + self.translation,
            self.dst,
            other.src,
        )

    def apply(self, points: ArrayLike) -> NDArray[np.float64]:
        """Map points ``(..., 3)`` from *src* to *dst*: ``R @ x + t`` (broadcasts over a batch)."""
        p = np.asarray(points, dtype=np.float64)
        return np.einsum("...ij,...j->...i", self.rotation, p) + self.translation

    def apply_inverse(self, points: ArrayLike) -> NDArray[np.float64]:
        """Map points ``(..., 3)`` from *dst* to *src*: ``R^T (x - t)``."""
        p = np.asarray(points, dtype=np.float64) - self.translation
        return np.einsum("...ji,...j->...i", self.rotation, p)

    def rotate(self, vectors: ArrayLike) -> NDArray[np.float64]:
        """Rotate direction vectors ``(..., 3)`` from *src* to *dst* (no translation)."""
        return np.einsum("...ij,...j->...i", self.rotation, np.asarray(vectors, dtype=np.float64))
