"""The lean pattern of the reduced matrix (skyrig.adjust.linalg.schur_pattern / scatter_unit_pairs)
against the Schur engine's keyed pattern and per-entry maps (skyrig.adjust.solver.SchurEngine)."""

import numpy as np
import pytest

from skyrig.adjust import AdjustConfig
from skyrig.adjust import linalg as L
from skyrig.adjust import solver as S
from skyrig.adjust.model import Model, State
from skyrig.adjust.synthetic import synthetic_block
from skyrig.rig.presets import midas


@pytest.mark.parametrize("boresight", ["free", "fixed"])
def test_schur_pattern_matches_engine(boresight: str) -> None:
    block, _ = synthetic_block(seed=3, n_strips=3, n_per_strip=5, n_points=400, rig=midas(), height_m=500.0,
                               n_control=9)
    model = Model(block, AdjustConfig(statistics=False, boresight=boresight))
    factors = model.evaluate(State.from_block(block))
    eng = S.SchurEngine(factors, model.layout, block.obs_image)
    others = [f.cols for i, f in enumerate(factors)
              if i != eng._img_index and f.jc is not None and f.cols is not None and f.cols.shape[1] > 0]
    indptr, indices = L.schur_pattern(eng.n_c, eng.ucols, eng.row_ptr, eng.col_idx, others)
    np.testing.assert_array_equal(indptr, eng.indptr)
    np.testing.assert_array_equal(indices, eng.indices)
    rng = np.random.default_rng(0)
    blocks = rng.standard_normal((len(eng.col_idx), eng.k, eng.k))
    want = np.zeros(eng.nnz)
    S._K["scatter"](blocks.reshape(-1), eng.map_a, eng.map_b, want)
    got = np.zeros(eng.nnz)
    L.scatter_unit_pairs(blocks, eng.row_ptr, eng.col_idx, eng.ucols, indptr, indices, got)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
