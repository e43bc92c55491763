"""The statistics pass keeps ``M = Q_cc W`` on the observations' block pattern above a small size (issue 35: the
dense ``n_c x 3 n_p`` product grew with the square of the block and was most of each snooping round).  What the
callers read from :class:`~skyrig.adjust.stats.Covariance` must not change:

- ``Q_cc`` and the point blocks ``Q_pp`` against an independent answer: the inverse of the *full* dense normal
  matrix ``[[U, W], [W^T, V]]`` built here (no Schur complement, numpy's general inverse);
- the chosen unknowns' cofactors (``statistics_points`` / ``statistics_images``, the cross terms ``Q_cp`` off the
  pattern) and the ground-height correlations of :mod:`skyrig.adjust.determinability`, which needed the dense ``M``
  before (with the pattern they fell back to sparse solves or NaN): equal to the dense ``M``'s to 1e-9.

Seeded penta-rig block (midas rig, boresights and interior orientation free, ground control).
"""

from __future__ import annotations

import functools
import importlib

import numpy as np
import pytest
import scipy.sparse as sp

from skyrig.adjust import AdjustConfig, adjust
from skyrig.adjust.config import StatisticsOptions, Unknowns
from skyrig.adjust.determinability import ground_height_correlation
from skyrig.adjust.model import Model, State
from skyrig.adjust.solver import assemble
from skyrig.adjust.stats import PointPatternM, covariance
from skyrig.adjust.synthetic import synthetic_block
from skyrig.rig.presets import midas

adjust_module = importlib.import_module("skyrig.adjust.adjust")


@pytest.fixture(scope="module")
def block():  # type: ignore[no-untyped-def]
    b, _ = synthetic_block(seed=3, n_strips=3, n_per_strip=4, n_points=300, rig=midas(), n_control=6,
                           side_overlap=0.6)
    return b


def _cfg(b) -> AdjustConfig:  # type: ignore[no-untyped-def]
    counts = np.bincount(b.obs_point, minlength=b.n_points)
    pts = tuple(str(b.point_name[k]) for k in np.flatnonzero(counts >= 4)[[0, 7, 30]])
    return AdjustConfig(unknowns=Unknowns(boresight="free", intrinsics="free"),
                        statistics=StatisticsOptions(points=pts, images=(str(b.image_name[3]),)))


def test_cofactors_equal_the_inverse_of_the_full_normal_matrix(block):  # type: ignore[no-untyped-def]
    res = adjust(block, _cfg(block))
    cov = res.covariance
    assert cov is not None
    model = Model(res.block, _cfg(block))
    lay = model.layout
    assert lay.n_c == cov.Qcc.shape[0] and lay.n_p == len(cov.Qpp)
    st = State.from_block(res.block)
    N = assemble(model.evaluate(st), lay, res.block.obs_image)
    n_c, n_p = lay.n_c, lay.n_p
    W = sp.csr_matrix(N.p.T @ N.wb.tocsr()).toarray()
    full = np.zeros((n_c + 3 * n_p, n_c + 3 * n_p))
    full[:n_c, :n_c] = N.U.toarray()
    full[:n_c, n_c:] = W
    full[n_c:, :n_c] = W.T
    for p in range(n_p):
        full[n_c + 3 * p:n_c + 3 * p + 3, n_c + 3 * p:n_c + 3 * p + 3] = N.V[p]
    d = 1.0 / np.sqrt(np.diag(full))
    Qfull = np.linalg.inv(full * d[:, None] * d[None, :]) * d[:, None] * d[None, :]
    cv = covariance(N, lay, st, max_dense_products=1)
    assert isinstance(cv.M, PointPatternM)
    np.testing.assert_allclose(cv.Qcc, Qfull[:n_c, :n_c], rtol=1e-7, atol=1e-9 * np.abs(Qfull[:n_c, :n_c]).max())
    Qpp = np.stack([Qfull[n_c + 3 * p:n_c + 3 * p + 3, n_c + 3 * p:n_c + 3 * p + 3] for p in range(n_p)])
    np.testing.assert_allclose(cv.Qpp, Qpp, rtol=1e-7, atol=1e-9 * np.abs(Qpp).max())
    # the cross cofactors a caller asks for, off the pattern: -Q_cp V = (Q_cc W)
    pts = np.array([0, 5, n_p - 1])
    cols3 = (3 * pts[:, None] + np.arange(3)).reshape(-1)
    Qcp = Qfull[:n_c, n_c + cols3].reshape(n_c, len(pts), 3)
    got = -np.einsum("cka,kab->ckb", cv.cross(pts), cv.Vinv[pts])
    np.testing.assert_allclose(got, Qcp, rtol=1e-7, atol=1e-9 * np.abs(Qcp).max())


def test_chosen_unknowns_and_ground_height_correlation_as_with_the_dense_product(block, monkeypatch):  # type: ignore[no-untyped-def]
    cfg = _cfg(block)
    with monkeypatch.context() as m:
        m.setattr(adjust_module, "covariance", functools.partial(covariance, max_dense_products=10**12))
        dense = adjust(block, cfg)
    with monkeypatch.context() as m:
        m.setattr(adjust_module, "covariance", functools.partial(covariance, max_dense_products=1))
        small = adjust(block, cfg)
    assert isinstance(dense.covariance.M, np.ndarray) and isinstance(small.covariance.M, PointPatternM)
    ds, ss = dense.selected, small.selected
    assert ds is not None and ss is not None
    # sliced from the full covariance either way (before: the pattern fell back to sparse solves)
    assert ds.method == ss.method == "dense inverse"
    assert len(ss.points) == 3
    np.testing.assert_array_equal(ss.columns, ds.columns)
    np.testing.assert_allclose(ss.Qcc, ds.Qcc, rtol=1e-9, atol=1e-12 * np.abs(ds.Qcc).max())
    np.testing.assert_allclose(ss.Qpp, ds.Qpp, rtol=1e-9, atol=1e-12 * np.abs(ds.Qpp).max())
    np.testing.assert_allclose(ss.Qcp, ds.Qcp, rtol=1e-9, atol=1e-9 * np.abs(ds.Qcp).max())
    assert np.abs(ds.Qcp).max() > 0
    labels = [lab for lab in dense.layout.labels if lab[0] != "pose"]
    gd = ground_height_correlation(dense, labels)
    gs = ground_height_correlation(small, labels)
    assert np.all(np.isfinite(gd)) and np.all(np.isfinite(gs))  # before: NaN with the pattern
    np.testing.assert_allclose(gs, gd, rtol=1e-9, atol=1e-12)
    assert small.sigma0 == pytest.approx(dense.sigma0, rel=1e-12)
    np.testing.assert_allclose(small.pose_sigma, dense.pose_sigma, rtol=1e-9)
    np.testing.assert_allclose(small.point_sigma, dense.point_sigma, rtol=1e-9)
