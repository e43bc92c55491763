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
    for kw in ({"lr_band_px": 0}, {"lr_band_context_px": -1}, {"lr_band_jump_px": -1.0}, {"lr_band_cols_px": -1}):
        with pytest.raises(SkyrigError, match="lr_band"):
            SgmConfig(**kw)
    with pytest.raises(SkyrigError, match="banded"):
        SgmConfig(lr_check="half")


def test_banded_check_on_columns_near_the_edges_only():
    """``lr_band_cols_px`` (the DSM's default): in the banded rows the right-based matching runs only on the columns
    near a depth edge (with its search width and path context), and only the left pixels within ``lr_band_cols_px``
    of an edge get its check; the others keep OpenCV's, as the rows outside the bands do.  On the seeded step: the
    checked pixels agree with the whole-row banded check (paths started ``lr_band_cols_px`` columns away settle the
    same: at least 99.5 % of them the same), the other pixels are OpenCV's bit for bit, and next to the step it keeps
    no more pixels off by more than 1 px and no more occluded ones than the whole-row check, within 1 % of their count
    (as the whole-row check against the full one)."""
    from skyrig.dense._kernels import lr_band_cols

    left, right, truth, occluded = _occlusion_pair(db=8, df=24)
    H, W = left.shape
    n = 32
    base = SgmConfig(lr_check="banded")
    rows_cfg = match_crop(left, right, 0, n, base)
    cols_cfg = replace(base, lr_band_cols_px=16)
    cols = match_crop(left, right, 0, n, cols_cfg)
    cv = np.full((H, W), np.nan, np.float32)
    cv[:, :W - n] = match_crop(np.ascontiguousarray(left[:, :W - n]), np.ascontiguousarray(right[:, :W - n]), 0, n,
                               replace(base, lr_check="opencv"))
    rows = lr_band_rows(cv, np.float32(base.lr_band_jump_px), n, base.lr_band_px)
    near = np.zeros((H, W), bool)
    for r0 in np.flatnonzero(rows):
        near[r0] = lr_band_cols(cv, np.float32(base.lr_band_jump_px), n, r0, r0 + 1, 16)
    checked = near & rows[:, None]
    assert 0 < checked.sum() < 0.5 * rows.sum() * W, "the checked columns must be a part of the banded rows"
    rk, ck = np.isfinite(rows_cfg), np.isfinite(cols)
    same = (rk == ck) & (~rk | (np.abs(np.nan_to_num(rows_cfg) - np.nan_to_num(cols)) < 1e-6))
    # a band's columns are the union over its rows: compare on every row's own near columns
    assert same[checked].mean() >= 0.995, f"{100 * same[checked].mean():.2f} % the same where both check"
    band_cols = np.zeros((H, W), bool)
    for r0, r1 in [(int(a), int(b)) for a, b in _band_runs(rows)]:
        band_cols[r0:r1] = lr_band_cols(cv, np.float32(base.lr_band_jump_px), n, r0, r1, 16)[None, :]
    assert np.array_equal(cols[~band_cols], cv[~band_cols], equal_nan=True)
    from scipy import ndimage

    step = np.zeros(truth.shape, bool)
    step[:, 1:] |= truth[:, 1:] != truth[:, :-1]
    step[1:, :] |= truth[1:, :] != truth[:-1, :]
    edge = ndimage.binary_dilation(step, np.ones((7, 7), bool))
    edge[:, :40] = False
    edge[:, W - n:] = False
    with np.errstate(invalid="ignore"):
        bad_r = int((rk & edge & (np.abs(rows_cfg - truth) > 1.0)).sum())
        bad_c = int((ck & edge & (np.abs(cols - truth) > 1.0)).sum())
    assert bad_c <= bad_r + 0.01 * int(edge.sum()), f"edge pixels off by > 1 px: columns {bad_c}, rows {bad_r}"
    occ_r, occ_c = int((rk & occluded).sum()), int((ck & occluded).sum())
    assert occ_c <= occ_r + 0.01 * int(occluded.sum()), f"occluded pixels kept: columns {occ_c}, rows {occ_r}"


def _band_runs(rows):  # type: ignore[no-untyped-def]
    m = np.concatenate([[False], rows, [False]])
    e = np.flatnonzero(m[1:] != m[:-1])
    return zip(e[::2], e[1::2])
