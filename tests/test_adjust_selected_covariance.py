"""Covariance of chosen unknowns by sparse solves (any block size) against the dense inverse.

Independent answer: the inverse of the full normal matrix ``J^T J`` built densely from the whitened
Jacobians of every factor (no Schur complement, no sparse factorisation) on a small block.
"""

from __future__ import annotations

import numpy as np
import pytest

from _dense_reference import dense_system

from skyrig.adjust import AdjustConfig, adjust
from skyrig.adjust.config import StatisticsOptions, Unknowns
from skyrig.adjust.model import Model, State
from skyrig.adjust.synthetic import synthetic_block


def _dense_normal_inverse(model: Model, state: State) -> np.ndarray:
    J, _ = dense_system(model.evaluate(state), model.layout)
    return np.linalg.inv(J.T @ J)


@pytest.fixture(scope="module")
def block():
    b, _ = synthetic_block(seed=8, n_strips=2, n_per_strip=5, n_points=120, lever_arm=np.array([0.1, -0.2, 0.5]))
    return b


CFG = AdjustConfig(unknowns=Unknowns(lever_arm="free", boresight="weighted", boresight_sigma_rad=1e-3),
                   statistics=StatisticsOptions(images=("s0003_nadir", "s0007"), points=("p3", "p40", "p77")))


def test_sparse_solves_match_the_dense_inverse(block):
    dense = adjust(block, CFG)
    sparse = adjust(block, CFG.with_statistics(max_parameters=0))
    assert dense.covariance is not None and sparse.covariance is None
    assert dense.selected.method == "dense inverse" and sparse.selected.method == "sparse solves"
    assert any("sparse solves" in w for w in sparse.warnings)
    assert any("redundancy numbers" in w and "skipped" in w for w in sparse.warnings)
    sel = sparse.selected
    # chosen: lever arm, boresight, 2 stations x 6, 3 points
    groups = [g for g, _, _ in sel.labels]
    assert groups.count("lever_arm") == 3 and groups.count("boresight") == 3 and groups.count("pose") == 12
    assert len(sel.points) == 3
    # the reference: inverse of the full (not reduced) normal matrix at the adjusted state
    model = Model(sparse.block, CFG)
    Q = _dense_normal_inverse(model, State.from_block(sparse.block))
    lay = model.layout
    np.testing.assert_allclose(sel.Qcc, Q[np.ix_(sel.columns, sel.columns)], rtol=1e-6, atol=1e-14)
    for k, p in enumerate(sel.points):
        pc = lay.n_c + 3 * lay.point[p] + np.arange(3)
        np.testing.assert_allclose(sel.Qpp[k], Q[np.ix_(pc, pc)], rtol=1e-6, atol=1e-14)
        np.testing.assert_allclose(sel.Qcp[:, k, :], Q[np.ix_(sel.columns, pc)], rtol=1e-6, atol=1e-12)
    # the dense path slices the same numbers
    np.testing.assert_allclose(dense.selected.Qcc, sel.Qcc, rtol=1e-6, atol=1e-14)
    np.testing.assert_allclose(dense.selected.Qpp, sel.Qpp, rtol=1e-6, atol=1e-14)
    # sigmas of the non-pose unknowns are reported either way
    s_d, s_s = dense.sigma_reduced(), sparse.sigma_reduced()
    for key in (("lever_arm", "antenna", "z"), ("boresight", "nadir", "rx")):
        assert s_s[key] == pytest.approx(s_d[key], rel=1e-6)


def test_unknown_names_are_reported(block):
    with pytest.raises(ValueError, match="nosuchimage"):
        adjust(block, CFG.with_statistics(max_parameters=0, images=("nosuchimage",)))
