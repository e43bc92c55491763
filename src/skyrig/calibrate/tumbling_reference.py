"""Did the laboratory's static reference camera move during the session?  (Paper 000, 3.4.)

Paper 000: "Executing block matching on each of the static camera images showed that this camera did not change
orientation.  Thus, just one EOS 5D image could be used as a reference."  The ``tumbling-head`` recipe relies on
the same: every tumbling image is compared with one reference image.  :func:`reference_stability` checks it.

Block matching: the first image of the session is the template; every image is cut into non-overlapping square
blocks (``block_px``), each block searched in the template within +-``search_px`` by normalised cross-correlation
(``cv2.matchTemplate``, ``TM_CCOEFF_NORMED``; the peak refined by a parabola in x and in y), and the image's motion
fitted to the block shifts by least squares as a translation plus a turn about the image centre (a camera knocked
on a rigid frame tilts - the whole image shifts - or turns about its axis).  The image is then moved back by the
fitted motion (``cv2.warpAffine``, cubic) and matched again (``refinements`` times).  Blocks whose shift residual
exceeds 4 robust sigmas are dropped.  (Phase correlation, ``cv2.phaseCorrelate``, was tried first: on the simulated
lab's 1024 px reference its sub-pixel answer is scaled by about 0.3 near zero shift, and it writes into a block of a
larger array passed to it.)  Measured on the simulated lab (8 x 3 exposures, 1024 px, 1 DN noise): a still camera
0.0005 px of largest corner displacement with a matching precision of 0.0005-0.0006 px; a turn of 0.1 deg about the
axis found as 1.760e-3 rad (1.745e-3 injected); at 512 px as 0.78 / 0.91 / 0.94 / 0.95 of it with 0 / 1 / 2 / 4
refinements; 0.02 deg at 1024 px as 2.85e-4 rad (3.49e-4): the interpolation's and the parabola's sub-pixel bias,
0.05 px at the corners, is larger than the noise at such small motions.  So the threshold is a detection limit (a
still camera stays below it), and the movement is stated to about 5-20 %.

Threshold from the matching precision: per image the covariance of the motion is ``s^2 (A^T A)^-1`` from the block
residuals; the displacement it causes at the image corners has a standard deviation; the session's matching
precision ``sigma_px`` is the median over the images of the largest corner sigma, and the camera counts as moved
where an image's largest corner displacement exceeds ``k_sigma * sigma_px`` (default 5: a still camera's images
exceed it with probability ~1e-6 each).  :meth:`ReferenceStability.require_static` raises
:class:`~skyrig.errors.ReferenceCameraMoved` naming the images and the movement.  With the reference camera's
angular pixel size (IFOV, radians) the threshold and the movement are also stated as angles.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from skyrig.errors import CalibrationError, ReferenceCameraMoved

__all__ = ["ReferenceStability", "reference_stability"]


@dataclass(frozen=True)
class ReferenceStability:
    """The block matching of the reference camera's images (:func:`reference_stability`).

    Attributes
    ----------
    names
        ``(N,)`` image names, the first is the template.
    motion
        ``(N, 3)`` fitted motion per image against the template: shift x, y (pixels) and turn (radians, about the
        image centre, x right, y down).
    corner_px
        ``(N,)`` the largest displacement at the image corners (pixels).
    corner_sigma_px
        ``(N,)`` its standard deviation from the block residuals (pixels).
    blocks
        ``(N,)`` blocks used per image.
    sigma_px
        The session's matching precision: median of ``corner_sigma_px`` over the images but the template.
    k_sigma
        Threshold factor.
    ifov_rad
        The camera's angular pixel size (radians) or None.
    """

    names: tuple[str, ...]
    motion: NDArray[np.float64]
    corner_px: NDArray[np.float64]
    corner_sigma_px: NDArray[np.float64]
    blocks: NDArray[np.int64]
    sigma_px: float
    k_sigma: float
    ifov_rad: float | None = None

    @property
    def threshold_px(self) -> float:
        """Largest corner displacement a still camera's image may show: ``k_sigma * sigma_px`` (pixels)."""
        return float(self.k_sigma * self.sigma_px)

    @property
    def moved(self) -> NDArray[np.bool_]:
        """``(N,)`` whether each image moved by more than the threshold."""
        return self.corner_px > self.threshold_px

    @property
    def static(self) -> bool:
        """No image moved."""
        return not bool(self.moved.any())

    def _angle_mdeg(self, px: float) -> float | None:
        return None if self.ifov_rad is None else float(1000.0 * np.degrees(px * self.ifov_rad))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary: threshold, precision, largest movement (pixels and, with the IFOV, 1/1000 deg), the
        images that moved."""
        k = int(np.argmax(self.corner_px))
        return {"images": len(self.names), "template": self.names[0], "static": self.static,
                "sigma_px": self.sigma_px, "k_sigma": self.k_sigma, "threshold_px": self.threshold_px,
                "threshold_mdeg": self._angle_mdeg(self.threshold_px),
                "max_movement_px": float(self.corner_px[k]), "max_movement_mdeg": self._angle_mdeg(self.corner_px[k]),
                "image_at_max": self.names[k], "blocks_min": int(self.blocks[1:].min()) if len(self.names) > 1 else 0,
                "moved": [n for n, m in zip(self.names, self.moved) if m]}

    def require_static(self) -> "ReferenceStability":
        """``self`` if the camera did not move; else :class:`ReferenceCameraMoved` naming the images."""
        if self.static:
            return self
        bad = [f"{n} ({c:.3f} px)" for n, c, m in zip(self.names, self.corner_px, self.moved) if m]
        ang = self._angle_mdeg(float(self.corner_px.max()))
        raise ReferenceCameraMoved(
            f"the reference camera moved during the session: {len(bad)} of {len(self.names)} images are displaced "
            f"against {self.names[0]!r} by more than {self.threshold_px:.3f} px ({self.k_sigma:g} x the matching "
            f"precision {self.sigma_px:.4f} px)"
            + (f"; largest {float(self.corner_px.max()):.3f} px = {ang:.1f} mdeg" if ang is not None else "")
            + f": {', '.join(bad[:8])}{', ...' if len(bad) > 8 else ''}; one reference image cannot serve the whole "
            "session (fix the camera and repeat, or calibrate the parts before and after the movement separately)")


def _gray(img: NDArray[Any]) -> NDArray[np.float32]:
    a = np.asarray(img)
    if a.ndim == 3:
        a = a[..., :3].astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)
    return np.ascontiguousarray(a, dtype=np.float32)


def _design(centres: NDArray[np.float64], c0: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(2 B, 3)`` block shift per (dx, dy, turn): a shift plus a small turn about ``c0``."""
    d = centres - c0
    a = np.zeros((2 * len(centres), 3))
    a[0::2, 0] = 1.0
    a[1::2, 1] = 1.0
    a[0::2, 2] = -d[:, 1]
    a[1::2, 2] = d[:, 0]
    return a


def _block_shifts(template: NDArray[np.float32], image: NDArray[np.float32], corners: list[tuple[int, int]],
                  block: int, search: int, min_score: float) -> NDArray[np.float64]:
    """``(B, 2)`` shift of each block of ``image`` against ``template`` (NaN: no reliable peak): normalised
    cross-correlation (``cv2.matchTemplate``, ``TM_CCOEFF_NORMED``) of the image's block over the template within
    +-``search`` px, the peak refined by a parabola through it and its neighbours in x and in y.  The content of the
    template at p is at p + shift in the image."""
    h, w = template.shape
    out = np.full((len(corners), 2), np.nan)
    for i, (r0, c0) in enumerate(corners):
        if r0 - search < 0 or c0 - search < 0 or r0 + block + search > h or c0 + block + search > w:
            continue
        score = cv2.matchTemplate(template[r0 - search:r0 + block + search, c0 - search:c0 + block + search],
                                  image[r0:r0 + block, c0:c0 + block], cv2.TM_CCOEFF_NORMED)
        iy, ix = np.unravel_index(int(np.argmax(score)), score.shape)
        if score[iy, ix] < min_score or not (0 < ix < score.shape[1] - 1 and 0 < iy < score.shape[0] - 1):
            continue
        fx = score[iy, ix - 1:ix + 2].astype(np.float64)
        fy = score[iy - 1:iy + 2, ix].astype(np.float64)
        sx = 0.5 * (fx[0] - fx[2]) / (fx[0] - 2 * fx[1] + fx[2])
        sy = 0.5 * (fy[0] - fy[2]) / (fy[0] - 2 * fy[1] + fy[2])
        # the block of the image matches the template at offset (ix, iy) - search: image(p) = template(p + offset)
        out[i] = (search - (ix + sx), search - (iy + sy))
    return out


def _fit(a: NDArray[np.float64], shifts: NDArray[np.float64], reject_k: float
         ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Least-squares motion from the block shifts, gross blocks dropped once: motion, covariance, blocks used."""
    use = np.all(np.isfinite(shifts), axis=1)
    for _ in range(2):
        aa = a.reshape(-1, 2, 3)[use].reshape(-1, 3)
        o = shifts[use].reshape(-1)
        p, *_ = np.linalg.lstsq(aa, o, rcond=None)
        r = (o - aa @ p).reshape(-1, 2)
        r2 = np.hypot(r[:, 0], r[:, 1])
        bad = r2 > reject_k * (np.median(r2) / 1.1774 + 1e-12)
        if not bad.any():
            break
        use[np.flatnonzero(use)[bad]] = False
    aa = a.reshape(-1, 2, 3)[use].reshape(-1, 3)
    o = shifts[use].reshape(-1)
    p, *_ = np.linalg.lstsq(aa, o, rcond=None)
    res = o - aa @ p
    s2 = float(res @ res / max(res.size - 3, 1))
    return p, s2 * np.linalg.inv(aa.T @ aa), use


def reference_stability(images: Sequence[NDArray[Any]], names: Sequence[str], *, block_px: int = 64,
                        k_sigma: float = 5.0, ifov_rad: float | None = None, min_blocks: int = 8,
                        min_texture: float = 2.0, min_score: float = 0.5, search_px: int = 3, refinements: int = 2,
                        reject_k: float = 4.0) -> ReferenceStability:
    """Block matching of the reference camera's images against the first (module docstring).

    ``images``: ``(H, W, 3)`` RGB or ``(H, W)`` grey, all of one size; ``names`` for the messages; ``ifov_rad``:
    the camera's pixel size over its principal distance (to state the movement as an angle).  Raises
    :class:`~skyrig.errors.CalibrationError` for inconsistent input or too few textured blocks.
    """
    if len(images) != len(names) or len(images) < 2:
        raise CalibrationError(f"reference check: need at least 2 images with one name each, got {len(images)} "
                               f"images and {len(names)} names")
    if not (np.isfinite(k_sigma) and k_sigma > 0):
        raise CalibrationError(f"reference check: k_sigma must be a positive number, got {k_sigma!r}")
    template = _gray(images[0])
    h, w = template.shape
    block = int(block_px)
    n_r, n_c = h // block, w // block
    r_off, c_off = (h - n_r * block) // 2, (w - n_c * block) // 2
    corners = [(r_off + i * block, c_off + j * block) for i in range(n_r) for j in range(n_c)
               if template[r_off + i * block:r_off + (i + 1) * block, c_off + j * block:c_off + (j + 1) * block].std()
               >= min_texture]
    if len(corners) < min_blocks:
        raise CalibrationError(f"reference check: only {len(corners)} textured {block} px blocks in {names[0]!r} "
                               f"(need {min_blocks})")
    centres = np.array([(c0 + (block - 1) / 2.0, r0 + (block - 1) / 2.0) for r0, c0 in corners])
    c_img = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    a = _design(centres, c_img)
    img_corners = np.array([[0.0, 0.0], [w - 1.0, 0.0], [0.0, h - 1.0], [w - 1.0, h - 1.0]])
    jc = _design(img_corners, c_img).reshape(4, 2, 3)
    n = len(images)
    motion = np.zeros((n, 3))
    corner = np.zeros(n)
    corner_sigma = np.zeros(n)
    used = np.zeros(n, np.int64)
    used[0] = len(corners)
    for k in range(1, n):
        img = _gray(images[k])
        if img.shape != template.shape:
            raise CalibrationError(f"reference check: {names[k]!r} is {img.shape[1]} x {img.shape[0]} px, "
                                   f"{names[0]!r} {w} x {h}")
        p = np.zeros(3)
        cov = np.zeros((3, 3))
        use = np.zeros(len(corners), bool)
        for _ in range(int(refinements) + 1):
            # the image moved back by the motion so far (turn about the centre, then the shift), matched again
            ct, st = np.cos(p[2]), np.sin(p[2])
            rot = np.array([[ct, -st], [st, ct]])
            fwd = np.c_[rot, c_img + p[:2] - rot @ c_img]  # template pixel -> image pixel
            back = cv2.warpAffine(img, fwd, (w, h), flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP,
                                  borderMode=cv2.BORDER_REFLECT)
            dp, cov, use = _fit(a, _block_shifts(template, back, corners, block, int(search_px), min_score), reject_k)
            if use.sum() < min_blocks:
                raise CalibrationError(f"reference check: only {int(use.sum())} blocks of {names[k]!r} match "
                                       f"{names[0]!r} (need {min_blocks}); is it the same camera and scene?")
            p = p + dp
        motion[k] = p
        disp = jc @ p
        corner[k] = float(np.max(np.hypot(disp[:, 0], disp[:, 1])))
        corner_sigma[k] = float(max(np.sqrt(np.linalg.eigvalsh(j @ cov @ j.T)[-1]) for j in jc))
        used[k] = int(use.sum())
    sigma = float(np.median(corner_sigma[1:]))
    return ReferenceStability(tuple(str(x) for x in names), motion, corner, corner_sigma, used, sigma,
                              float(k_sigma), ifov_rad)
