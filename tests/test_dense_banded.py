"""The banded left-right check (``SgmConfig.lr_check="banded"``, the DSM's default): the right-based matching only on
the row bands where OpenCV's own check leaves a depth edge.

Checked against the full check (the second matching on every row) on a seeded pair with a known step
(:func:`test_dense._occlusion_pair`: a textured rectangle 16 px in front of a textured plane, its occluded strip
known): where the bands run the two agree, where they do not the full check adds nothing to OpenCV's, and next to
the step the banded check keeps no more wrong or occluded pixels than the full one.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skyrig.dense._kernels import lr_band_rows
from skyrig.dense.sgm import SgmConfig, match_crop
from skyrig.errors import SkyrigError

from test_dense import _occlusion_pair


def test_band_rows_flags_depth_edges_across_holes():
    """A band is flagged by a jump between consecutive finite disparities of one of its rows (holes between them
    skipped), larger than the threshold, right of the first columns; nothing else flags it."""
    nan = np.nan
    d = np.full((12, 8), 5.0, np.float32)
    d[1, 3:5] = nan  # a hole without a jump: no edge
    d[5, 4:] = 9.0  # a jump of 4 px along row 5 (band 4..7)
    d[9, 2], d[9, 3] = nan, nan
    d[9, 4:] = 7.5  # a jump of 2.5 px across a hole in row 9 (band 8..11)
    d[2, 0] = 50.0  # a jump in column 0 only: left of c0
    rows = lr_band_rows(d, np.float32(2.0), 1, 4)
    assert rows.tolist() == [False] * 4 + [True] * 8
    assert lr_band_rows(d, np.float32(3.0), 1, 4).tolist() == [False] * 4 + [True] * 4 + [False] * 4
    assert lr_band_rows(d, np.float32(2.0), 0, 4)[:4].all()  # column 0 counted from c0 = 0
    assert lr_band_rows(d, np.float32(2.0), 1, 5).tolist() == [False] * 5 + [True] * 5 + [False] * 2  # 5..9


def test_banded_check_matches_the_full_check_next_to_a_step():
    """On the seeded step: (1) on the rows whose bands run the banded check keeps the same pixels as the full check
    (up to the few that the right-based matching's top-down path, started ``lr_band_context_px`` rows above a run
    instead of at the crop's top, settles otherwise: at most 0.1 % of them); (2) on the other rows the full check
    agrees with OpenCV's (no depth edge there for it to act on), so leaving them to OpenCV's costs nothing;
    (3) of the pixels within 3 px of the step's outline and of its occluded strip, the banded check keeps no more
    pixels off by more than 1 px and no more occluded ones than the full check, within 1 % of their count (a margin
    that OpenCV's check alone exceeds on both counts)."""
    left, right, truth, occluded = _occlusion_pair(db=8, df=24)
    H, W = left.shape
    n = 32  # the search 0..31; the crop is the whole pair (its last n columns serve the right-based pass only)
    base = SgmConfig(lr_check="full")
    full = match_crop(left, right, 0, n, base)
    band = match_crop(left, right, 0, n, replace(base, lr_check="banded"))
    # OpenCV's check on the same left matching (the columns the left pass of the other two sees)
    cv = np.full((H, W), np.nan, np.float32)
    cv[:, :W - n] = match_crop(np.ascontiguousarray(left[:, :W - n]), np.ascontiguousarray(right[:, :W - n]), 0, n,
                               replace(base, lr_check="opencv"))
    # the rows the banded check ran on: its own rule on OpenCV's result
    rows = lr_band_rows(cv, np.float32(base.lr_band_jump_px), n, base.lr_band_px)
    assert rows[40:120].all() and not rows.all(), f"the step's rows (40..119) must be banded, not every row: {rows}"
    fk, bk, ck = np.isfinite(full), np.isfinite(band), np.isfinite(cv)
    same = (fk == bk) & (~fk | (np.abs(np.nan_to_num(full) - np.nan_to_num(band)) < 1e-6))
    assert same[rows].mean() >= 0.999, f"banded vs full on the banded rows: {100 * same[rows].mean():.2f} % the same"
    assert (bk == ck)[~rows].all() and np.array_equal(band[~rows], cv[~rows], equal_nan=True)
    assert (fk == ck)[~rows].mean() >= 0.99, "outside the bands the full check must agree with OpenCV's"
    # next to the step: outline pixels (3 px either side of the truth's depth edges) and the occluded strip
    from scipy import ndimage

    step = np.zeros(truth.shape, bool)
    step[:, 1:] |= truth[:, 1:] != truth[:, :-1]
    step[1:, :] |= truth[1:, :] != truth[:-1, :]
    edge = ndimage.binary_dilation(step, np.ones((7, 7), bool))
    edge[:, :40] = False  # the first columns have no right pixel within the search window
    edge[:, W - n:] = False  # nor any result
    with np.errstate(invalid="ignore"):
        bad_f = int((fk & edge & (np.abs(full - truth) > 1.0)).sum())
        bad_b = int((bk & edge & (np.abs(band - truth) > 1.0)).sum())
    tol_edge = 0.01 * int(edge.sum())
    assert bad_b <= bad_f + tol_edge, f"edge pixels off by > 1 px: banded {bad_b}, full {bad_f}"
    occ_f, occ_b = int((fk & occluded).sum()), int((bk & occluded).sum())
    tol_occ = 0.01 * int(occluded.sum())
    assert occ_b <= occ_f + tol_occ, f"occluded pixels kept: banded {occ_b}, full {occ_f}"
    # the tolerances tell the checks apart: OpenCV's alone keeps more of both (measured 193 vs 121 and 116 vs 75)
    with np.errstate(invalid="ignore"):
        bad_c = int((ck & edge & (np.abs(cv - truth) > 1.0)).sum())
    assert bad_c > bad_f + tol_edge and int((ck & occluded).sum()) > occ_f + tol_occ


def test_banded_check_options_are_checked():
    for kw in ({"lr_band_px": 0}, {"lr_band_context_px": -1}, {"lr_band_jump_px": -1.0}):
        with pytest.raises(SkyrigError, match="lr_band"):
            SgmConfig(**kw)
    with pytest.raises(SkyrigError, match="banded"):
        SgmConfig(lr_check="half")
