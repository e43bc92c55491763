"""One stereo pair from original images to triangulated points, block by block.

A pair's left rectified image is cut into fixed blocks (:func:`pair_blocks`); each block is matched on its
own crop with context (:func:`match_block`), so the result of a block never depends on which ground tile
asked for it: tiled and untiled runs give the same points, bit for bit.  The disparity window of each block
comes from its rays and the scene box (the nearest and farthest box crossing of every sampled ray), never
from a hand-set number.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from numpy.typing import NDArray

from skyrig.dense.pairs import ray_box_interval
from skyrig.dense.rectify import Rectification, WindowedImage
from skyrig.dense.sgm import SgmConfig, crop_extra_right, disparity_window, match_crop

#: image loader: image row index -> uint8 array (H, W, 3) RGB or (H, W) grey, as the camera sees it
ImageLoader = Callable[[int], NDArray[np.uint8]]


@dataclass(frozen=True)
class Block:
    """A block of a pair's left rectified image: rows ``v0..v1``, columns ``u0..u1`` (rectified coordinates,
    exclusive ends) and its disparity window."""

    u0: int
    u1: int
    v0: int
    v1: int
    d_min: float
    d_max: float


@dataclass(frozen=True)
class PairPoints:
    """Triangulated points of one block.

    Attributes
    ----------
    xyz
        ``(M, 3)`` world points (the orientations' Cartesian frame, metres).
    sigma_h
        ``(M,)`` predicted precision of the point's height (m, 1 sigma, from ``disparity_sigma_px``); NaN for a
        point on a wall or an isolated match (``SgmConfig.wall_max_nz``), which gives no height to a DSM (the
        grid fusion leaves it out, the cloud keeps it).
    sigma_3d
        ``(M,)`` predicted precision along the left ray (m).
    rgb
        ``(M, 3)`` uint8 colour of the left image.
    normal
        ``(M, 3)`` float32 unit normals from the depth grid, facing the left camera (NaN at depth edges).
    centres
        ``(2, 3)`` the pair's projection centres (left, right; world frame), for :attr:`angle_deg`.
    """

    xyz: NDArray[np.float64]
    sigma_h: NDArray[np.float32]
    sigma_3d: NDArray[np.float32]
    rgb: NDArray[np.uint8]
    normal: NDArray[np.float32]
    centres: NDArray[np.float64]

    @property
    def angle_deg(self) -> NDArray[np.float32]:
        """``(M,)`` intersection angle (degrees) of the two rays of each point, computed on demand (neither the DSM
        nor the cloud uses it; an arccos per point was ~30 % of the triangulation's time)."""
        a = self.xyz - self.centres[0]
        b = self.xyz - self.centres[1]
        ca = np.einsum("ij,ij->i", a, b) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
        return np.degrees(np.arccos(np.clip(ca, -1.0, 1.0))).astype(np.float32)

    def subset(self, sel: NDArray) -> "PairPoints":
        """The points ``sel`` (indices or mask)."""
        return PairPoints(self.xyz[sel], self.sigma_h[sel], self.sigma_3d[sel], self.rgb[sel], self.normal[sel],
                          self.centres)

    @staticmethod
    def empty() -> "PairPoints":
        return PairPoints(np.zeros((0, 3)), np.zeros(0, np.float32), np.zeros(0, np.float32),
                          np.zeros((0, 3), np.uint8), np.zeros((0, 3), np.float32), np.zeros((2, 3)))

    def __len__(self) -> int:
        return len(self.xyz)


def block_window(rect: Rectification, u0: int, u1: int, v0: int, v1: int,
                 box: tuple[float, float, float, float, float, float], samples: int = 9,
                 margin_px: float = 3.0, min_depth_m: float = 0.0) -> tuple[float, float] | None:
    """Disparity window of a rectified block from its rays through the scene box (None: the block's rays
    miss the box).  Depths below ``min_depth_m`` are not searched (a camera inside the box, as in a
    terrestrial set, would otherwise ask for an unbounded window)."""
    uu, vv = np.meshgrid(np.linspace(u0, u1 - 1, samples), np.linspace(v0, v1 - 1, samples))
    d = rect.rect_directions(uu.ravel(), vv.ravel()) @ rect.rotation.T  # world, depth 1 along the rectified axis
    tn, tf = ray_box_interval(rect.centres[0], d, box)
    hit = tn < tf
    if not hit.any():
        return None
    fb = rect.focal_px * rect.base_m
    near = np.maximum(tn[hit], max(min_depth_m, 1e-6))
    if not np.any(tf[hit] > near):
        return None
    return float(fb / tf[hit].max() - margin_px), float(fb / near.min() + margin_px)


def pair_blocks(rect: Rectification, box: tuple[float, float, float, float, float, float], block_px: int = 768,
                min_depth_m: float = 0.0) -> list[Block]:
    """Fixed blocks covering the left image on the rectified plane (rows both images share): the fewest blocks
    of at most ``block_px`` a side, of equal size (within a pixel) along each axis (no sliver of a block that
    would cost a whole crop of context and search width)."""
    u0, u1, v0, v1 = (int(x) for x in rect.bounds[0])

    def cuts(lo: int, hi: int) -> list[int]:
        k = max(1, -(-(hi - lo) // block_px))
        return [lo + ((hi - lo) * i) // k for i in range(k + 1)]

    out = []
    vc, uc = cuts(v0, v1), cuts(u0, u1)
    for a, a1 in zip(vc[:-1], vc[1:]):
        for b, b1 in zip(uc[:-1], uc[1:]):
            bb = (b, b1, a, a1)
            w = block_window(rect, *bb, box, min_depth_m=min_depth_m)
            if w is not None:
                out.append(Block(*bb, *w))
    return out


def block_ground_bounds(rect: Rectification, blk: Block, samples: int = 5) -> NDArray[np.float64]:
    """``(xmin, ymin, xmax, ymax)`` of what a block can see between its nearest and farthest depth (world)."""
    uu, vv = np.meshgrid(np.linspace(blk.u0, blk.u1 - 1, samples), np.linspace(blk.v0, blk.v1 - 1, samples))
    dirs = rect.rect_directions(uu.ravel(), vv.ravel()) @ rect.rotation.T
    fb = rect.focal_px * rect.base_m
    depths = [fb / max(blk.d_max, 1e-6), fb / max(blk.d_min, 1e-6) if blk.d_min > 0 else 1e7]
    pts = np.concatenate([rect.centres[0] + dirs * dd for dd in depths])
    return np.array([pts[:, 0].min(), pts[:, 1].min(), pts[:, 0].max(), pts[:, 1].max()])


def block_crop(rect: Rectification, blk: Block, cfg: SgmConfig) -> tuple[int, int, int, int, int, int, int, int] | None:
    """Where a block is matched: ``(shift, n, a, b, cu0, cu1, cv0, cv1)`` (None: nothing of the block can match).

    ``[a, b)`` are the block's columns whose search window reaches the right image (no other left pixel can
    get a match); ``[cu0, cu1) x [cv0, cv1)`` the crop that is matched: ``cfg.margin_px`` of context around the
    block where both images carry content (none beyond the pair's rectified bounds: only zeros lie there), the
    search width left of it (OpenCV leaves the first ``n`` columns without result) and, for the full left-right
    check, right of it (:func:`skyrig.dense.sgm.crop_extra_right`).  A function of the block and the pair only,
    so the result of a block never depends on the tiling."""
    shift, n = disparity_window(blk.d_min, blk.d_max, cfg)
    m = cfg.margin_px
    lu0, lu1, v0, v1 = (int(x) for x in rect.bounds[0])
    ru0, ru1 = int(rect.bounds[1][0]), int(rect.bounds[1][1])
    lo = max(lu0, ru0 + shift)  # left columns whose window reaches a right column with content
    hi = min(lu1, ru1 + shift + n - 1)
    a, b = max(blk.u0, lo), min(blk.u1, hi)
    if b <= a:
        return None
    cu0 = a - min(m, a - lo) - n
    cu1 = b + min(m, max(hi - b, 0)) + crop_extra_right(n, cfg)
    cv0, cv1 = max(blk.v0 - m, v0), min(blk.v1 + m, v1)
    return shift, n, a, b, cu0, cu1, cv0, cv1


def match_block(rect: Rectification, left_img: NDArray | WindowedImage, right_img: NDArray | WindowedImage,
                blk: Block, cfg: SgmConfig) -> tuple[NDArray[np.float32], NDArray, NDArray[np.bool_]]:
    """Disparities ``(v1-v0, u1-u0)`` of a block (NaN invalid), its left colour crop and validity.

    The crop (:func:`block_crop`) carries context where both images have content and the search width; the
    right crop is shifted by the window's start so OpenCV searches ``0..n``.  Columns of the block no right
    pixel can match stay NaN (colour 0, not valid).  ``right_img`` may be grey already (it is only matched, never
    coloured from: a pair's blocks then share one conversion).  Either image may be a
    :class:`~skyrig.dense.rectify.WindowedImage` (only the window the block's crop samples is read); a right one
    that is RGB is then resampled in colour and converted afterwards, which is not bit-identical to the grey path
    (give it grey).
    """
    import cv2

    from skyrig.dense._phases import phase

    bh, bw = blk.v1 - blk.v0, blk.u1 - blk.u0
    if isinstance(left_img, WindowedImage):
        ch: tuple[int, ...] = (left_img.channels,) if left_img.channels > 1 else ()
    else:
        ch = left_img.shape[2:] if left_img.ndim == 3 else ()
    disp = np.full((bh, bw), np.nan, np.float32)
    colour = np.zeros((bh, bw) + ch, np.uint8)
    valid = np.zeros((bh, bw), bool)
    crop = block_crop(rect, blk, cfg)
    if crop is None:
        return disp, colour, valid
    shift, n, a, b, cu0, cu1, cv0, cv1 = crop
    w, h = cu1 - cu0, cv1 - cv0
    with phase("rectify"):
        lc, lvalid = rect.remap(0, left_img, cu0, cv0, w, h)
        lg = cv2.cvtColor(lc, cv2.COLOR_RGB2GRAY) if lc.ndim == 3 else lc
        # the right image is only matched, never coloured from: grey first, one channel resampled
        if isinstance(right_img, WindowedImage):
            rg, rvalid = rect.remap(1, right_img, cu0 - shift, cv0, w, h)
            rg = cv2.cvtColor(rg, cv2.COLOR_RGB2GRAY) if rg.ndim == 3 else rg
        else:
            rg, rvalid = rect.remap(1, cv2.cvtColor(right_img, cv2.COLOR_RGB2GRAY) if right_img.ndim == 3 else right_img,
                                    cu0 - shift, cv0, w, h)
    d = match_crop(lg, rg, shift, n, cfg, lvalid, rvalid)
    src = (slice(blk.v0 - cv0, blk.v1 - cv0), slice(a - cu0, b - cu0))
    dst = (slice(None), slice(a - blk.u0, b - blk.u0))
    disp[dst], colour[dst], valid[dst] = d[src], lc[src], lvalid[src]
    return disp, colour, valid


def block_points(rect: Rectification, blk: Block, disp: NDArray[np.float32], colour: NDArray, cfg: SgmConfig
                 ) -> PairPoints:
    """Triangulate every matched pixel of a block, with precision, intersection angle, colour and normal.

    Everything is computed in the rectified frame of the left camera, where a pixel ``(u, v)`` with depth
    ``D = f B / d`` is the point ``p = (u D / f, -v D / f, -D)``; normals come from the depth's derivatives
    along the grid (central differences), ``n = dp/dv x dp/du``; world = ``C_left + R p``.
    """
    from skyrig.dense._kernels import triangulate_block
    from skyrig.dense._phases import phase

    with phase("triangulate"):
        return _block_points(rect, blk, disp, colour, cfg, triangulate_block)


def triangulation_args(rect: Rectification, blk: Block, disp: NDArray[np.float32], colour: NDArray, cfg: SgmConfig
                       ) -> tuple:
    """The arguments of the triangulation kernels for a block (:func:`skyrig.dense._kernels.triangulate_block`'s,
    then the wall test's ``wall_nz, half, min_count, flat_range`` of :func:`skyrig.dense._kernels.steep_points`;
    ``wall_nz`` 0: no wall test)."""
    cos_lim = float(np.cos(np.radians(cfg.max_incidence_deg)))
    d = np.nan_to_num(np.ascontiguousarray(disp, np.float32), nan=-1.0)
    col = np.ascontiguousarray(colour, np.uint8)
    half = cfg.wall_window_px // 2
    flat = 0.0
    if cfg.wall_max_nz > 0:
        # windows whose disparities differ by less than this are not fitted: across 2 half pixels of a window
        # seen straight down (ground sample D / f) a height change D dd / d is a slope of f dd / (2 half d);
        # half the disparity change of the steepest slope tested, at the block's largest disparity
        slope = np.sqrt(1.0 - cfg.wall_max_nz ** 2) / cfg.wall_max_nz
        flat = 0.5 * slope * 2 * half * max(blk.d_max, 1e-6) / float(rect.focal_px)
    return (d, float(blk.u0), float(blk.v0), float(rect.focal_px), float(rect.base_m),
            np.ascontiguousarray(rect.rotation, np.float64), np.ascontiguousarray(rect.centres[0], np.float64),
            float(cfg.disparity_sigma_px), cos_lim, col if col.ndim == 3 else col[:, :, None],
            float(max(cfg.wall_max_nz, 0.0)), int(half), int(max(3, (2 * half + 1) ** 2 // 2)), float(flat))


def _block_points(rect: Rectification, blk: Block, disp: NDArray[np.float32], colour: NDArray, cfg: SgmConfig,
                  triangulate_block) -> PairPoints:  # type: ignore[no-untyped-def]
    args = triangulation_args(rect, blk, disp, colour, cfg)
    rr, cc, xyz, normal, sigma_h, sigma_3d, rgb = triangulate_block(*args[:10])
    wall_nz, half, min_count, flat = args[10:]
    if wall_nz > 0 and len(rr):
        from skyrig.dense._kernels import steep_points

        nz = steep_points(args[0], rr, cc, *args[1:6], half, min_count, flat)  # type: ignore[call-arg]
        sigma_h[~(nz >= wall_nz)] = np.float32(np.nan)  # NaN: steep or sparse (a fresh array: in place)
    return PairPoints(xyz, sigma_h, sigma_3d, rgb, normal, np.ascontiguousarray(rect.centres, np.float64))
