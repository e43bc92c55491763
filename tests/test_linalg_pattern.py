"""The lean pattern of the reduced matrix (skyrig.adjust.linalg.schur_pattern / scatter_unit_pairs)
against a plain listing of every block entry (numpy keys, np.add.at) on a penta-rig block, and against
the pattern the Schur engine uses."""

import numpy as np
import pytest

from skyrig.adjust import AdjustConfig
from skyrig.adjust.config import StatisticsOptions, Unknowns
from skyrig.adjust import linalg as L
from skyrig.adjust import solver as S
from skyrig.adjust.model import Model, State
from skyrig.adjust.synthetic import synthetic_block
from skyrig.rig.presets import midas


@pytest.mark.parametrize("boresight", ["free", "fixed"])
def test_schur_pattern_matches_a_listing_of_all_block_entries(boresight: str) -> None:
    block, _ = synthetic_block(seed=3, n_strips=3, n_per_strip=5, n_points=400, rig=midas(), height_m=500.0,
                               n_control=9)
    model = Model(block, AdjustConfig(statistics=StatisticsOptions(compute=False),
                                      unknowns=Unknowns(boresight=boresight)))
    factors = model.evaluate(State.from_block(block))
    eng = S.SchurEngine(factors, model.layout, block.obs_image)
    n_c, k, uc = eng.n_c, eng.k, eng.ucols
    others = [f.cols for i, f in enumerate(factors)
              if i != eng._img_index and f.jc is not None and f.cols is not None and f.cols.shape[1] > 0]
    indptr, indices = L.schur_pattern(n_c, uc, eng.row_ptr, eng.col_idx, others)
    # reference: every (row, col) of every block listed, sorted, unique
    ua = np.repeat(np.arange(eng.n_u), np.diff(eng.row_ptr))
    ub = eng.col_idx
    r = [np.repeat(uc[ua], k, axis=1).reshape(-1), np.tile(uc[ub], (1, k)).reshape(-1)]
    c = [r[1], r[0]]  # mirrors
    for f in others:
        kf = f.shape[1]
        r.append(np.repeat(f, kf, axis=1).reshape(-1))
        c.append(np.tile(f, (1, kf)).reshape(-1))
    r.append(np.arange(n_c))
    c.append(np.arange(n_c))
    rr, cc = np.concatenate(r), np.concatenate(c)
    ok = (rr >= 0) & (cc >= 0)
    keys = np.unique(rr[ok] * n_c + cc[ok])
    want_ptr = np.concatenate([[0], np.cumsum(np.bincount(keys // n_c, minlength=n_c))])
    np.testing.assert_array_equal(indptr, want_ptr)
    np.testing.assert_array_equal(indices, keys % n_c)
    np.testing.assert_array_equal(indices, eng.indices)  # the engine's pattern (keyed or lean) is the same
    # scatter: blocks at (ucols[u] x ucols[v]) and the mirrors, summed with np.add.at into a dense matrix
    rng = np.random.default_rng(0)
    blocks = rng.standard_normal((len(ub), k, k))
    got = np.zeros(len(indices))
    L.scatter_unit_pairs(blocks, eng.row_ptr, eng.col_idx, uc, indptr, indices, got)
    dense = np.zeros((n_c + 1, n_c + 1))  # row/col n_c: the -1 padding
    ra = np.where(uc[ua] >= 0, uc[ua], n_c)[:, :, None]
    cb = np.where(uc[ub] >= 0, uc[ub], n_c)[:, None, :]
    np.add.at(dense, (np.broadcast_to(ra, blocks.shape), np.broadcast_to(cb, blocks.shape)), blocks)
    off = ua != ub
    np.add.at(dense, (np.broadcast_to(cb[off].transpose(0, 2, 1), blocks[off].shape),
                      np.broadcast_to(ra[off].transpose(0, 2, 1), blocks[off].shape)),
              blocks[off].transpose(0, 2, 1))
    rows = np.repeat(np.arange(n_c), np.diff(indptr))
    np.testing.assert_allclose(got, dense[rows, indices], rtol=1e-12, atol=1e-12)
    assert np.count_nonzero(dense[:n_c, :n_c]) <= len(indices)  # nothing scattered outside the pattern
