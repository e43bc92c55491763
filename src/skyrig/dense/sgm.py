"""Semi-global matching of rectified images with OpenCV's StereoSGBM, in tiles of bounded memory.

:func:`match_rectified` is the one matching path of skyrig: the Middlebury benchmarks and the aerial
blocks both go through it.  The disparity search window ``[d_min, d_max]`` comes from the caller (for
oriented images: from the geometry and the scene box, see :mod:`skyrig.dense.stereo`); the right image is
shifted by ``d_min`` so that OpenCV searches ``0 .. n`` only.  Large images are cut into tiles with an
overlap (``SgmConfig.tile_px``, ``margin_px``); a tile's result is kept only in its interior, so memory
is bounded by the tile, not the image.

Filters (all OpenCV's, applied inside StereoSGBM): sub-pixel parabola fit (1/16 px), uniqueness ratio,
left-right consistency (``disp12MaxDiff``), speckle filtering of small disconnected disparity blobs.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
import logging
from typing import Any

import numpy as np
from numpy.typing import NDArray

from skyrig.errors import SkyrigError

logger = logging.getLogger(__name__)

MODES = ("sgbm", "hh", "3way", "hh4")
#: left-right checks (:attr:`SgmConfig.lr_check`)
LR_CHECKS = ("full", "banded", "opencv")


@dataclass(frozen=True)
class SgmConfig:
    """Semi-global matching options.

    Attributes
    ----------
    mode
        ``"sgbm"`` (5 paths, OpenCV default), ``"hh"`` (8 paths, full Hirschmueller), ``"3way"`` or ``"hh4"``.
    block_size
        Matched block size (odd, 1..11; SGBM's pixel-wise cost over this window).
    p1, p2
        Smoothness penalties per channel and block pixel; OpenCV's ``P1 = p1 * cn * block_size**2``.
    uniqueness
        Uniqueness ratio in percent (best cost must beat the second by this margin).
    lr_max_diff
        Left-right consistency tolerance in pixels (``disp12MaxDiff``).  OpenCV takes 0 and negative values as 1
        (measured with OpenCV 5.0 on a seeded pair, ``tests/test_dense.py``); a tolerance wider than the search
        disables the check.
    speckle_window
        Largest disconnected blob (pixels) removed as speckle (0 disables).
    speckle_range
        Disparity variation (pixels) within one connected blob.
    pre_filter_cap
        Truncation of the x-derivative pre-filter.
    max_disparities
        Upper limit of the search width; wider windows are cut (with a warning) to bound time and memory.
    tile_px
        Tile side (interior) for large images.
    margin_px
        Tile overlap on each side (aggregation paths see this much context).
    disparity_sigma_px
        Assumed precision of a matched disparity (1 sigma, pixels), used for predicted point precision.
    edge_jump_px, edge_erode_px
        Against "foreground fattening" (area matching spreads the nearer surface over the farther one next to
        a depth edge): at disparity jumps above ``edge_jump_px`` the nearer side loses ``edge_erode_px``
        pixels (0 disables).
    edge_erode_across_px
        Erosion at disparity jumps across the epipolar lines (between rows), None: ``edge_erode_px`` (then the
        nearer side loses a diamond of ``edge_erode_px``).  Occlusions and the derivative pre-filter spread the
        foreground along the rows only, so jumps between rows fatten less: given, every jump between columns
        erodes ``edge_erode_px`` pixels along its row and every jump between rows ``edge_erode_across_px`` along
        its column.
    edge_erode_left_px
        Pixels eroded from the left end of a nearer surface along the rows (its first pixels right of a jump up
        in disparity), None: ``edge_erode_px``; only with ``edge_erode_across_px`` given.  For the ``"opencv"``
        check: OpenCV's check settles a right pixel that two left pixels claim by their costs, and where the
        nearer surface's left end is fattened over the background it is often the fattened pixel that costs less,
        so the true background pixel is dropped and the fattened one kept.  Middlebury Cones (block size 3, erosion
        2 along the rows, 0 across), left pixels whose disparity is > 1 px nearer than the truth with the true
        nearer surface within 6 px on their right / left: full check 1013 / 703, ``"opencv"`` 1776 / 833, opencv
        with 3 / 4 px at left ends 1490 / 830, 1339 / 828.  ``make demo``'s town (DenseConfig, adjusted
        orientations; full / opencv / opencv with 4 px at left ends): roof corners of the orthomosaic within 1 GSD
        100 / 96.5 / 96.3 %, RMS 0.28 / 0.70 / 0.34 GSD (the demo's gate: >= 95 % and <= 0.5 GSD); DSM cells within
        2 GSD of building edges valid 83.9 / 83.5 / 82.2 %, RMSE 14.7 / 16.0 / 15.4 GSD, cells off by > 5 GSD
        0.46 / 0.63 / 0.51 %; flat cells NMAD 0.166 / 0.165 / 0.167 GSD, completeness 99.7 % in all three.
    lr_check
        ``"full"``: a second matching from the right image (the mirrored pair) must confirm every disparity within
        ``lr_max_diff`` (occlusions and fattening next to depth edges fail); ``"banded"``: that second matching only on
        the bands of ``lr_band_px`` rows (counted from the crop's first row) in which OpenCV's own check leaves a depth
        edge: two finite disparities next to each other along a row (holes skipped) that differ by more than
        ``lr_band_jump_px``; each run of such bands is matched with ``lr_band_context_px`` rows above it (the top-down
        path of the 3-way mode starts there), its rows get the full check and the other rows OpenCV's (where no depth
        edge is left, neither occlusion nor fattening is either: on the 16-image ``bench/dense.py`` block the full
        check rejects 0.95 % of the disparities OpenCV's keeps, and 89 % of those lie in the banded rows).  The DSM's
        default (:class:`skyrig.dense.surface.DenseConfig`): on that block the bands hold 64 % of the rows and the
        right-based pass takes 0.64-0.67 instead of 0.91-0.96 CPU s, the DSM's edge cells as with the full check (valid
        38.87 / 38.81 %, off by > 5 GSD 22.70 / 22.69 %, RMSE 19.11 / 19.07 GSD, flat NMAD 0.139 GSD both).  Bands of
        16 rows, 8 rows of context, jumps over 2 / 4 / 8 px: 22.89 / 22.81 / 23.24 % and 19.23 / 19.18 / 19.28 GSD,
        0.66 / 0.61 / 0.50 CPU s; bands of 32, 8 rows, 2 px: 22.57 %, 18.99 GSD, 0.72 CPU s (the spread of these
        figures is about what the choice of band moves them: +-0.2 % and +-0.15 GSD).  ``"opencv"``: only OpenCV's
        internal check (``disp12MaxDiff``): the right image's disparities taken from the same aggregated cost volume
        (per right pixel the best of the costs along its diagonal, Hirschmueller 2008), no second matching, half the
        time.  Middlebury (block size 3, the tests' settings) full / opencv: Cones bad > 1 px non-occluded 7.18 / 6.38
        %, all known 17.76 / 17.00 %, all known with ``fill_occlusions`` 11.00 / 12.17 %; Motorcycle bad > 2 px 15.85 /
        14.52 %, filled 7.50 / 10.60 %.  The DSM's figures are in :class:`skyrig.dense.surface.DenseConfig`.  Cheaper
        right-based passes cost edge cells (midas-dsm, adjusted orientations, DenseConfig defaults otherwise; cells
        within 2 GSD of building edges valid / outliers > 5 GSD of all valid cells): full 80.0 / 0.42 %; ``"opencv"``
        77.4 / 0.55 %; the mirrored pair reduced 2 x 2 (a fifth of the time; tolerance 1 / 1.5 / 2 px) 73.9 / 0.45,
        76.8 / 0.52, 77.5 / 0.55 %; rows averaged in pairs (half the time, disparities kept at full resolution) 77.9 /
        0.46 %.  Searching the right-based pass over the left pass's disparities only (their least to largest, +-
        ``lr_max_diff + 1``) changes 348 of 1.05 M cells of the 16-image ``bench/dense.py`` block but saves no time:
        OpenCV's cost per pixel does grow with the width (3-way, 1 thread: 94 / 133 / 172 ns at 16 / 32 / 64
        disparities), but a block's left disparities span nearly its whole geometric window (ground to roofs, and
        hundreds to thousands of pixels stuck at either end of the search, which the full check then rejects: 28 of 7.0
        M disparities outside the window survive it), so the narrower windows model at 11 % of the pass's time and
        measured within noise (sgm right 2.09 vs 2.07 CPU s).
    max_incidence_deg
        Points whose surface (from the depth grid of the pair) is seen at a more grazing angle than this
        (angle between the surface normal and the ray to the camera) are dropped: next to a depth edge the
        matcher smooths the jump into a steep ramp whose points float off the surface; a real surface seen
        that obliquely cannot be matched reliably either.  90 disables.
    lr_mode
        Matcher mode of the right-based pass of the full (or banded) left-right check (None: ``mode``).
    lr_band_px, lr_band_context_px, lr_band_jump_px
        The banded check's bands (rows), the rows matched above each run of bands, and the disparity jump (pixels)
        that marks a depth edge (see ``lr_check``).
    lr_band_cols_px
        0: the banded check's right-based matching runs on the bands' whole rows.  > 0: only on the columns near a
        depth edge of the band (:func:`skyrig.dense._kernels.lr_band_cols`: within this many pixels of it, widened by
        the search width and by as many pixels again of path on either side), and only the left pixels within this
        many pixels of an edge get its check; the others keep OpenCV's, as the rows outside the bands do.  On the
        16-image ``bench/dense.py`` block the columns within 32 px of an edge are about a fifth of the banded pixels;
        the DSM's default (32): right-based pass 0.65 -> 0.44 CPU s, cells within 2 GSD of building outlines valid
        38.87 -> 39.01 %, off by more than 5 GSD 22.70 -> 22.80 %, RMSE 19.11 -> 19.14 GSD, flat NMAD 0.139 GSD both
        (16 px: 0.38 s, 39.03 %, 22.79 %, 19.15 GSD; 64 px: 0.54 s, 39.01 %, 22.80 %, 19.14 GSD; within the spread
        that the choice of band moves these figures).  The DSM's default since issue 35 is 8 px (the crops keep the
        search width and 8 px of path on either side; ``bench/dense.py --lr-band-cols``, products deterministic, CPU s
        medians of 2 runs): 16 images 32 / 16 / 8 / 4 px: right-based pass 0.43 / 0.375 / 0.33 / 0.305 s, edge cells
        valid 39.01 / 39.03 / 39.04 / 39.05 %, off by more than 5 GSD 22.80 / 22.79 / 22.78 / 22.66 %, RMSE 19.14 /
        19.15 / 19.15 / 19.07 GSD, flat NMAD 0.139 GSD in all; 32 images (one run each) 32 / 8 / 4 px: 1.03 / 0.85 /
        0.78 s, edge cells valid 70.83 / 70.89 / 70.92 %, off by more than 5 GSD 18.18 / 18.24 / 18.28 %, RMSE 15.81 /
        15.83 / 15.84 GSD, flat NMAD 0.142 GSD in all.
    wall_max_nz, wall_window_px
        A triangulated point gets a DSM height only where the matched pixels of its ``wall_window_px`` square
        window are at least half of the window and their points fit a plane no steeper than
        ``acos(wall_max_nz)``; otherwise it keeps its place in the point cloud but gets no DSM height
        (``PairPoints.sigma_h`` NaN; 0 disables).  Steep: the wall pixels a view sees, matched correctly, all
        project onto the building outline with every height from the ground to the eaves and pull the heights
        of the cells on both sides of it (midas-dsm, true orientations: 69 % of the points > 5 GSD above the
        truth in ground cells next to buildings).  Sparse: isolated matches next to depth edges (wall and
        fattened pixels among them) split the pairs of a cell.  midas-dsm, true orientations,
        bench/dense_edges.py, cells within 2 GSD of building outlines, valid / within 5 GSD / off by more:
        77.4 / 64.7 / 12.7 % without the test, 77.5 / 66.3 / 11.2 % with the steep test alone, 79.9 / 68.8 /
        11.1 % with both; flat cells valid 99.5 -> 99.7 %, NMAD 0.166 GSD either way.  A fully matched window
        whose disparities differ by less than half of what the steepest slope tested makes across it (seen
        straight down) is taken as not steep without a fit (triangulation 0.5 -> 0.9 s instead of 2.1 s on
        midas-dsm's 31 pairs; edge cells 80.1 / 68.9 / 11.2 %).  Half of a 7 x 7 window:
        78.8 / 68.4 / 10.4 %; a third of 5 x 5: 79.0 / 67.6 / 11.4 %; two thirds: 74.6 / 66.3 / 8.4 %.
    fill_occlusions
        Give every pixel left without a match the disparity of the farther of its nearest matched neighbours
        on the same row (left and right): the background, which is what a pixel seen by one camera only
        (occlusion) shows, and what the foreground erosion (``edge_erode_px``) took off.  A dense disparity map
        for benchmarks over all pixels (Middlebury "all"); the DSM leaves it off (its holes are filled, and
        flagged, in object space).  Rows are filled within a matched crop (tile plus margin).
    """

    mode: str = "sgbm"
    block_size: int = 3
    p1: int = 8
    p2: int = 32
    uniqueness: int = 10
    lr_max_diff: int = 1
    speckle_window: int = 100
    speckle_range: int = 2
    pre_filter_cap: int = 63
    max_disparities: int = 512
    tile_px: int = 1024
    margin_px: int = 48
    disparity_sigma_px: float = 0.3
    edge_jump_px: float = 2.0
    edge_erode_px: int = 0
    edge_erode_across_px: int | None = None
    edge_erode_left_px: int | None = None
    max_incidence_deg: float = 75.0
    lr_check: str = "full"
    fill_occlusions: bool = False
    lr_mode: str | None = None
    lr_band_px: int = 16
    lr_band_context_px: int = 4
    lr_band_jump_px: float = 2.0
    lr_band_cols_px: int = 0
    wall_max_nz: float = 0.3
    wall_window_px: int = 5

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise SkyrigError(f"SGM mode must be one of {', '.join(MODES)}, not {self.mode!r} (option: mode)")
        if self.block_size % 2 != 1 or not 1 <= self.block_size <= 11:
            raise SkyrigError(f"SGM block size must be odd and 1..11, not {self.block_size} (option: block_size)")
        if self.lr_mode is not None and self.lr_mode not in MODES:
            raise SkyrigError(f"lr_mode must be one of {', '.join(MODES)} or None, not {self.lr_mode!r} (option: lr_mode)")
        if self.lr_check not in LR_CHECKS:
            raise SkyrigError(f"lr_check must be one of {', '.join(LR_CHECKS)}, not {self.lr_check!r} "
                              "(option: lr_check)")
        if self.lr_band_px < 1 or self.lr_band_context_px < 0 or not self.lr_band_jump_px >= 0 or self.lr_band_cols_px < 0:
            raise SkyrigError(f"lr_band_px must be >= 1, lr_band_context_px, lr_band_cols_px >= 0 and lr_band_jump_px >= "
                              f"0, got {self.lr_band_px}, {self.lr_band_context_px}, {self.lr_band_cols_px}, "
                              f"{self.lr_band_jump_px} (options: lr_band_px, lr_band_context_px, lr_band_cols_px, "
                              "lr_band_jump_px)")
        if self.edge_erode_left_px is not None and (self.edge_erode_left_px < 0 or self.edge_erode_across_px is None):
            raise SkyrigError("edge_erode_left_px must be >= 0 and needs edge_erode_across_px (the erosion along rows "
                              f"and columns), got {self.edge_erode_left_px} with edge_erode_across_px "
                              f"{self.edge_erode_across_px} (option: edge_erode_left_px)")
        if self.tile_px < 64 or self.margin_px < 0:
            raise SkyrigError("SGM tile_px must be >= 64 and margin_px >= 0")


def _matcher(cfg: SgmConfig, num_disp: int, channels: int):  # type: ignore[no-untyped-def]
    import cv2

    mode = {"sgbm": cv2.STEREO_SGBM_MODE_SGBM, "hh": cv2.STEREO_SGBM_MODE_HH,
            "3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY, "hh4": cv2.STEREO_SGBM_MODE_HH4}[cfg.mode]
    bs2 = cfg.block_size * cfg.block_size
    return cv2.StereoSGBM_create(minDisparity=0, numDisparities=num_disp, blockSize=cfg.block_size,
                                 P1=cfg.p1 * channels * bs2, P2=cfg.p2 * channels * bs2,
                                 disp12MaxDiff=cfg.lr_max_diff, preFilterCap=cfg.pre_filter_cap,
                                 uniquenessRatio=cfg.uniqueness, speckleWindowSize=cfg.speckle_window,
                                 speckleRange=cfg.speckle_range, mode=mode)


def disparity_window(d_min: float, d_max: float, cfg: SgmConfig) -> tuple[int, int]:
    """Integer shift and OpenCV search width (a multiple of 16) covering ``[d_min, d_max]``; a window wider than
    ``cfg.max_disparities`` is cut to it (:func:`window_cut` tells; the callers count and report cuts once, the
    dense chain avoids them by its hierarchical search, :mod:`skyrig.dense.levels`)."""
    if not (np.isfinite(d_min) and np.isfinite(d_max)) or d_max < d_min:
        raise SkyrigError(f"invalid disparity window [{d_min}, {d_max}]")
    shift = int(np.floor(d_min))
    width = int(np.ceil(d_max)) - shift + 1
    n = max(16, int(np.ceil(width / 16.0)) * 16)
    return shift, min(n, cfg.max_disparities)


def window_cut(d_min: float, d_max: float, cfg: SgmConfig) -> bool:
    """True when :func:`disparity_window` cuts ``[d_min, d_max]`` (wider than ``cfg.max_disparities``)."""
    return int(np.ceil(d_max)) - int(np.floor(d_min)) + 1 > cfg.max_disparities


def match_rectified(left: NDArray, right: NDArray, d_min: float, d_max: float, cfg: SgmConfig = SgmConfig(),
                    valid_left: NDArray[np.bool_] | None = None) -> NDArray[np.float32]:
    """Disparities of a rectified pair (``x_right = x_left - d``), NaN where no reliable match.

    Parameters
    ----------
    left, right
        Rectified images of equal shape ``(H, W)`` or ``(H, W, C)``, uint8.  Column ``c`` of ``right``
        covers the same rectified column as column ``c`` of ``left``.
    d_min, d_max
        Disparity search window (pixels, may be negative).
    cfg
        Matcher options.
    valid_left
        Optional ``(H, W)`` mask of left pixels that carry image content (results elsewhere are NaN).

    Returns
    -------
    ``(H, W)`` float32 disparities in pixels (1/16 px steps), NaN = invalid.
    """
    if left.shape != right.shape:
        raise SkyrigError(f"rectified images differ in shape: {left.shape} vs {right.shape}")
    shift, n = disparity_window(d_min, d_max, cfg)
    if window_cut(d_min, d_max, cfg):
        logger.warning("disparity window %.0f px wider than max_disparities %d: cut (near surfaces may be missed)",
                       d_max - d_min, cfg.max_disparities)
    H, W = left.shape[:2]
    out = np.full((H, W), np.nan, np.float32)
    t = cfg.tile_px
    for r0 in range(0, H, t):
        r1 = min(H, r0 + t)
        for c0 in range(0, W, t):
            c1 = min(W, c0 + t)
            out[r0:r1, c0:c1] = _match_tile(left, right, cfg, shift, n, r0, r1, c0, c1)
    if valid_left is not None:
        out[~valid_left] = np.nan
    return out


def crop_extra_right(n: int, cfg: SgmConfig) -> int:
    """Columns a crop needs right of its interior: the right-based pass of the full left-right check leaves
    its last ``n`` columns without result (the banded one too, on its bands)."""
    return n if cfg.lr_check in ("full", "banded") else 0


def match_crop(left: NDArray, right: NDArray, shift: int, n: int, cfg: SgmConfig,
               valid_left: NDArray[np.bool_] | None = None, valid_right: NDArray[np.bool_] | None = None
               ) -> NDArray[np.float32]:
    """The matching core every path goes through (benchmarks and oriented images alike).

    ``left`` and ``right`` are equal crops, the right one shifted so that a disparity ``d`` appears as
    ``d - shift`` (searched over ``0..n``).  Runs StereoSGBM, the left-right check (``cfg.lr_check``),
    refuses matches on pixels without image content (``valid_*``), adds the shift back and erodes the
    foreground at depth edges.  Returns ``(H, W)`` float32 disparities, NaN = invalid; the first ``n`` columns
    (and with the full check the last ``n``) are always invalid.
    """
    from skyrig.dense._kernels import check_disparities
    from skyrig.dense._phases import phase

    channels = 1 if left.ndim == 2 else left.shape[2]
    matcher = _matcher(cfg, n, channels)
    H, W = left.shape[:2]
    extra = crop_extra_right(n, cfg) if W - crop_extra_right(n, cfg) > n else 0
    with phase("sgm left"):  # the last n columns (full check) only serve the right-based pass: skipped here
        d16 = np.ascontiguousarray(matcher.compute(np.ascontiguousarray(left[:, :W - extra]),
                                                   np.ascontiguousarray(right[:, :W - extra])), np.int16)
    vl = np.ones((H, W), bool) if valid_left is None else np.ascontiguousarray(valid_left, bool)
    vr = np.ones((H, W), bool) if valid_right is None else np.ascontiguousarray(valid_right, bool)
    tol = np.float32(max(cfg.lr_max_diff, 0.5))
    if cfg.lr_check == "opencv":
        with phase("lr check"):
            d = check_disparities(d16, np.zeros((1, 1), np.int16), vl, vr, tol, int(shift), False)
    else:  # the same matcher (or lr_mode's) on the mirrored pair
        rm = matcher if cfg.lr_mode in (None, cfg.mode) else _matcher(replace(cfg, mode=cfg.lr_mode), n, channels)
        if cfg.lr_check == "banded":
            d = _banded_check(left, right, d16, vl, vr, tol, shift, n, cfg, rm)
        else:
            with phase("sgm right"):
                e16 = np.ascontiguousarray(rm.compute(np.ascontiguousarray(right[:, ::-1]),
                                                      np.ascontiguousarray(left[:, ::-1]))[:, ::-1])
            with phase("lr check"):
                d = check_disparities(d16, e16, vl, vr, tol, int(shift), True)
    with phase("filters"):
        d = erode_foreground(d, cfg.edge_jump_px, cfg.edge_erode_px, cfg.edge_erode_across_px, cfg.edge_erode_left_px)
        if cfg.fill_occlusions:
            d = fill_background(d, valid_left)
    return d


def _banded_check(left: NDArray, right: NDArray, d16: NDArray[np.int16], vl: NDArray[np.bool_],
                  vr: NDArray[np.bool_], tol: np.float32, shift: int, n: int, cfg: SgmConfig, rm: Any
                  ) -> NDArray[np.float32]:
    """The banded left-right check of :func:`match_crop` (``cfg.lr_check == "banded"``): the right-based matching
    only on the bands of ``cfg.lr_band_px`` rows where OpenCV's own check leaves a depth edge (:func:`lr_band_rows`),
    each run of such bands matched with ``cfg.lr_band_context_px`` rows above it; those rows get the full check, the
    others OpenCV's."""
    from skyrig.dense._kernels import check_disparities, lr_band_crops, lr_band_rows
    from skyrig.dense._phases import phase

    H, W = left.shape[:2]
    with phase("lr check"):
        dc = check_disparities(d16, np.zeros((1, 1), np.int16), vl, vr, tol, int(shift), False)
        rows = lr_band_rows(dc, np.float32(cfg.lr_band_jump_px), n, int(cfg.lr_band_px))
    if not rows.any():
        return dc
    e16 = np.full((H, W), -1, np.int16)
    zone = int(cfg.lr_band_cols_px)
    with phase("lr check"):
        if zone:  # the crops of the columns near the edges, the pixels they check
            crops, full = lr_band_crops(dc, rows, np.float32(cfg.lr_band_jump_px), n, zone, n,
                                        int(cfg.lr_band_context_px))
        else:
            crops = [(max(0, r0 - cfg.lr_band_context_px), r0, r1, 0, W) for r0, r1 in _runs(rows)]
            full = rows[:, None]
    with phase("sgm right"):
        for y0, r0, r1, ca, cb in crops:
            e = rm.compute(np.ascontiguousarray(right[y0:r1, ca:cb][:, ::-1]),
                           np.ascontiguousarray(left[y0:r1, ca:cb][:, ::-1]))
            e16[r0:r1, ca:cb] = e[r0 - y0:, ::-1]
    with phase("lr check"):
        d = check_disparities(d16, e16, vl, vr, tol, int(shift), True)
        np.copyto(d, dc, where=~full)  # in place (a new array is new memory, page by page)
    return d


def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """``[start, end)`` of every run of True in a 1-D mask."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    edges = np.flatnonzero(m[1:] != m[:-1])
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2])]


def _match_tile(left: NDArray, right: NDArray, cfg: SgmConfig, shift: int, n: int, r0: int, r1: int, c0: int,
                c1: int) -> NDArray[np.float32]:
    """Disparities of the tile ``[r0:r1, c0:c1]`` from a zero-padded crop with context and the search width."""
    H, W = left.shape[:2]
    m = cfg.margin_px
    a0, a1 = max(0, r0 - m), min(H, r1 + m)
    b0 = c0 - m - n  # OpenCV leaves the first n columns without result
    b1 = c1 + m + crop_extra_right(n, cfg)
    lc = _crop_cols(left[a0:a1], b0, b1)
    rc = _crop_cols(right[a0:a1], b0 - shift, b1 - shift)
    vl = _crop_cols(np.ones(left.shape[:2], bool)[a0:a1], b0, b1)
    vr = _crop_cols(np.ones(right.shape[:2], bool)[a0:a1], b0 - shift, b1 - shift)
    d = match_crop(lc, rc, shift, n, cfg, vl, vr)
    return d[r0 - a0:r1 - a0, c0 - b0:c1 - b0]


def _crop_cols(img: NDArray, b0: int, b1: int) -> NDArray:
    """Columns ``b0:b1`` of an image, zero outside it."""
    W = img.shape[1]
    out = np.zeros((img.shape[0], b1 - b0) + img.shape[2:], img.dtype)
    s0, s1 = max(0, b0), min(W, b1)
    if s1 > s0:
        out[:, s0 - b0:s1 - b0] = img[:, s0:s1]
    return np.ascontiguousarray(out)


def erode_foreground(d: NDArray[np.float32], jump_px: float, erode_px: int, across_px: int | None = None,
                     left_px: int | None = None) -> NDArray[np.float32]:
    """Remove ``erode_px`` pixels of the nearer surface at every disparity jump larger than ``jump_px``
    between two matched neighbours (along rows and columns).

    Area matching (the cost window, OpenCV's derivative pre-filter and the smoothness term) spreads the
    nearer surface over the farther one by about a pixel or two next to a depth edge ("foreground
    fattening"); this puts the edge back where the images have it, at the price of a thin band at edges that
    other pairs may fill."""
    if across_px is not None:
        return _erode_foreground_rows_cols(d, jump_px, erode_px, across_px, left_px)
    if left_px is not None:
        raise SkyrigError("left_px (pixels eroded at the left ends of nearer surfaces) needs across_px")
    if erode_px <= 0:
        return d
    fg = np.zeros(d.shape, bool)
    dd = np.where(np.isfinite(d), d, -np.inf)  # no match: as far as it gets (occlusion holes border the edges)
    with np.errstate(invalid="ignore"):
        dx = dd[:, 1:] - dd[:, :-1]
        dy = dd[1:, :] - dd[:-1, :]
    fg[:, 1:] |= dx > jump_px
    fg[:, :-1] |= dx < -jump_px
    fg[1:, :] |= dy > jump_px
    fg[:-1, :] |= dy < -jump_px
    if erode_px > 1:
        from scipy import ndimage

        fg = ndimage.binary_dilation(fg, iterations=erode_px - 1)
    out = d.copy()
    out[fg & np.isfinite(d)] = np.nan
    return out


def _erode_foreground_rows_cols(d: NDArray[np.float32], jump_px: float, along_px: int, across_px: int,
                                left_px: int | None = None) -> NDArray[np.float32]:
    """:func:`erode_foreground` with ``along_px`` pixels along the rows at jumps between columns and ``across_px``
    along the columns at jumps between rows (into the nearer side only); ``left_px`` (None: ``along_px``) pixels
    instead at the left end of a nearer surface along the rows."""
    dd = np.where(np.isfinite(d), d, -np.inf)
    fg = np.zeros(d.shape, bool)
    with np.errstate(invalid="ignore"):
        for axis, n, n_lo in ((1, along_px, along_px if left_px is None else left_px), (0, across_px, across_px)):
            if max(n, n_lo) <= 0:
                continue
            step = np.diff(dd, axis=axis)
            lo = np.zeros(d.shape, bool)  # nearer side starts here (its first pixel along the axis)
            hi = np.zeros(d.shape, bool)  # nearer side ends here (its last pixel)
            if axis == 1:
                lo[:, 1:] = step > jump_px
                hi[:, :-1] = step < -jump_px
            else:
                lo[1:, :] = step > jump_px
                hi[:-1, :] = step < -jump_px
            if n_lo > 0:
                fg |= lo
            if n > 0:
                fg |= hi
            for k in range(1, max(n, n_lo)):  # grow into the nearer side only
                if axis == 1:
                    if k < n_lo:
                        fg[:, k:] |= lo[:, :-k]
                    if k < n:
                        fg[:, :-k] |= hi[:, k:]
                else:
                    fg[k:, :] |= lo[:-k, :]
                    fg[:-k, :] |= hi[k:, :]
    out = d.copy()
    out[fg & np.isfinite(d)] = np.nan
    return out


def fill_background(d: NDArray[np.float32], valid: NDArray[np.bool_] | None = None) -> NDArray[np.float32]:
    """Fill NaN pixels along each row with the smaller (farther) of the nearest finite disparities to their left
    and right (one side only where the other has none); pixels outside ``valid`` stay NaN.

    An occluded pixel sees the background next to a foreground edge, so the farther neighbour is the
    estimate (the standard scanline occlusion fill)."""
    H, W = d.shape
    ok = np.isfinite(d)
    if ok.all() or not ok.any():
        return d
    col = np.broadcast_to(np.arange(W), (H, W))
    li = np.maximum.accumulate(np.where(ok, col, -1), axis=1)
    ri = np.minimum.accumulate(np.where(ok, col, W)[:, ::-1], axis=1)[:, ::-1]
    lv = np.take_along_axis(d, np.clip(li, 0, W - 1), axis=1)
    rv = np.take_along_axis(d, np.clip(ri, 0, W - 1), axis=1)
    lv[li < 0] = np.inf
    rv[ri >= W] = np.inf
    f = np.minimum(lv, rv)
    hole = ~ok & np.isfinite(f)
    if valid is not None:
        hole &= valid
    out = d.copy()
    out[hole] = f[hole]
    return out


def left_right_check(d: NDArray[np.float32], matcher, lg: NDArray, rg: NDArray, tol: float
                      ) -> NDArray[np.float32]:  # type: ignore[no-untyped-def]
    """Keep the left disparities that the right-based matching (same matcher on the mirrored pair) confirms
    within ``tol`` pixels; occluded and fattened pixels fail."""
    e16 = matcher.compute(np.ascontiguousarray(rg[:, ::-1]), np.ascontiguousarray(lg[:, ::-1]))[:, ::-1]
    e = e16.astype(np.float32) / 16.0
    e[e16 < 0] = np.nan
    w = d.shape[1]
    jr = np.arange(w)[None, :] - d
    ok = np.isfinite(jr) & (jr >= 0) & (jr <= w - 1)
    ji = np.clip(np.round(np.nan_to_num(jr, nan=0.0)).astype(np.int64), 0, w - 1)
    er = np.take_along_axis(e, ji, axis=1)
    with np.errstate(invalid="ignore"):
        ok &= np.abs(er - d) <= max(tol, 0.5)
    out = d.copy()
    out[~ok] = np.nan
    return out
