"""The reduced camera system's solvers (skyrig.adjust.linalg): CHOLMOD, SuperLU, dense, PCG.

Independent references: LAPACK's dense Cholesky of the same matrix, the previous path (SuperLU) for the
adjustment and its statistics, the truth of a seeded simulation, and an explicit count of the Cholesky
factor's nonzeros.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
import scipy.sparse as sp

import skyrig.adjust.solver as solver
from skyrig.adjust import AdjustConfig, adjust
from skyrig.adjust.config import StatisticsOptions, Unknowns
from skyrig.adjust import linalg
from skyrig.adjust.synthetic import synthetic_block

needs_cholmod = pytest.mark.skipif(not linalg.HAVE_CVXOPT_CHOLMOD, reason="cvxopt (CHOLMOD) not installed")


def _block_spd(n_blocks: int = 60, k: int = 6, seed: int = 0) -> sp.csr_matrix:
    """A Jacobi-scaled SPD matrix with the reduced system's structure: k x k blocks on a 2-D grid of
    'cameras', each coupled to its grid neighbours."""
    rng = np.random.default_rng(seed)
    side = int(np.ceil(np.sqrt(n_blocks)))
    xy = np.stack(np.divmod(np.arange(n_blocks), side), 1)
    d = np.abs(xy[:, None, :] - xy[None, :, :]).max(axis=2)
    pairs = np.argwhere(d <= 1)
    rows, cols, vals = [], [], []
    for a, b in pairs:
        B = rng.normal(size=(k, k)) * 0.1
        if a == b:
            B = B + B.T
        if a <= b:
            for i in range(k):
                for j in range(k):
                    rows += [a * k + i, b * k + j] if a < b else [a * k + i]
                    cols += [b * k + j, a * k + i] if a < b else [a * k + j]
                    vals += [B[i, j], B[i, j]] if a < b else [B[i, j]]
    n = n_blocks * k
    A = sp.csr_matrix((vals, (rows, cols)), shape=(n, n))
    A = A + sp.diags(np.abs(A).sum(axis=1).A1 + 1.0)  # diagonally dominant: SPD
    s = 1.0 / np.sqrt(A.diagonal())
    A = sp.csr_matrix(A.multiply(s[:, None]).multiply(s[None, :]))
    A.sort_indices()
    return A


@needs_cholmod
def test_cholmod_and_splu_solve_as_lapack_does():
    A = _block_spd()
    b = np.random.default_rng(1).normal(size=(A.shape[0], 3))
    ref = scipy.linalg.cho_solve(scipy.linalg.cho_factor(A.toarray()), b)
    for method in ("cholmod", "splu", "dense"):
        rs = linalg.ReducedSolver(A.indptr, A.indices, method)
        for _ in range(2):  # the symbolic analysis is reused on the second call
            np.testing.assert_allclose(rs.solve(A.data, b), ref, rtol=1e-10, atol=1e-12)
            np.testing.assert_allclose(rs.solve(A.data, b[:, 0]), ref[:, 0], rtol=1e-10, atol=1e-12)


@needs_cholmod
def test_cholmod_reports_a_singular_matrix():
    A = _block_spd().tolil()
    n = A.shape[0]
    # make two columns equal (rank deficient) keeping the pattern
    A[:, 1] = A[:, 0]
    A[1, :] = A[0, :]
    A = sp.csr_matrix(A)
    A.sort_indices()
    for method in ("cholmod", "splu"):
        with pytest.raises(linalg.NotPositiveDefinite):
            linalg.ReducedSolver(A.indptr, A.indices, method).solve(A.data, np.ones(n))


def test_symbolic_fill_counts_the_factor():
    # the block-level symbolic factorisation against the nonzeros of the dense Cholesky factor of the
    # permuted matrix (exact zeros are structural here: random values never cancel)
    A = _block_spd(n_blocks=40, k=3, seed=4)
    rs = linalg.ReducedSolver(A.indptr, A.indices, "splu")
    sym = rs.analyse()
    assert sym.nodes == 40
    p = sym.order
    L = np.linalg.cholesky(A.toarray()[np.ix_(p, p)])
    nnz = np.count_nonzero(np.abs(L) > 1e-300)
    assert sym.factor_nnz >= nnz
    assert sym.factor_nnz <= 1.25 * nnz  # dense diagonal blocks may hold a few structural zeros
    col = np.count_nonzero(np.abs(L) > 1e-300, axis=0)
    assert sym.flops == pytest.approx(float((col.astype(float) ** 2).sum()), rel=0.5)


def test_pcg_reaches_its_tolerance_and_auto_chooses_it_above_the_memory_limit():
    A = _block_spd(n_blocks=300, k=6, seed=2)
    b = np.random.default_rng(3).normal(size=A.shape[0])
    rs = linalg.ReducedSolver(A.indptr, A.indices, "auto", dense_limit=100, memory_limit=1e3)
    assert rs.method == "pcg" and "PCG" in rs.reason and "predicted factor" in rs.reason
    for eta in (1e-1, 1e-6):
        x = rs.solve(A.data, b, eta=eta)
        assert np.linalg.norm(A @ x - b) <= eta * np.linalg.norm(b)
    rs2 = linalg.ReducedSolver(A.indptr, A.indices, "auto", dense_limit=100)
    assert rs2.method == ("cholmod" if linalg.HAVE_CVXOPT_CHOLMOD else "splu"), rs2.reason


def _adjust_with(monkeypatch, block, cfg, method):  # type: ignore[no-untyped-def]
    monkeypatch.setattr(solver, "LINEAR_SOLVER", method)
    monkeypatch.setattr(solver, "ENGINE_DENSE_LIMIT", 0)
    monkeypatch.setattr(solver, "REDUCED_SOLVER", method)
    return adjust(block, cfg)


@needs_cholmod
def test_statistics_agree_with_the_previous_path(monkeypatch):
    """The adjustment and its statistics (covariance, redundancy numbers, normalised residuals, selected
    covariance by sparse solves) with CHOLMOD and with SuperLU (the previous path) agree to 1e-9."""
    block, _ = synthetic_block(seed=5, n_strips=3, n_per_strip=8, n_points=500)
    cfg = AdjustConfig(unknowns=Unknowns(boresight="free"),
                       statistics=StatisticsOptions(images=[str(block.image_name[3])],
                                                    points=[str(block.point_name[7])]))
    res = {m: _adjust_with(monkeypatch, block, cfg, m) for m in ("splu", "cholmod")}
    a, b = res["splu"], res["cholmod"]
    assert a.info.linear_solver.startswith("splu") and b.info.linear_solver.startswith("cholmod")
    assert a.info.iterations == b.info.iterations
    assert b.sigma0 == pytest.approx(a.sigma0, rel=1e-9)
    np.testing.assert_allclose(b.block.station_centre, a.block.station_centre, rtol=0, atol=1e-9)
    np.testing.assert_allclose(b.block.point_xyz, a.block.point_xyz, rtol=0, atol=1e-9)
    Qa, Qb = a.covariance.Qcc, b.covariance.Qcc
    assert np.abs(Qb - Qa).max() <= 1e-9 * np.abs(Qa).max()
    np.testing.assert_allclose(b.covariance.Qpp, a.covariance.Qpp, rtol=1e-9, atol=1e-9 * np.abs(a.covariance.Qpp).max())
    for g in a.residuals:
        ra, rb = a.residuals[g].redundancy, b.residuals[g].redundancy
        if ra is not None:
            np.testing.assert_allclose(rb, ra, rtol=1e-9, atol=1e-12)
    # the covariance of chosen unknowns by sparse solves (no dense inverse) with each solver
    cfg2 = AdjustConfig(unknowns=Unknowns(boresight="free"),
                        statistics=StatisticsOptions(max_parameters=0, images=cfg.statistics.images,
                                                     points=cfg.statistics.points))
    sel = {m: _adjust_with(monkeypatch, block, cfg2, m).selected for m in ("splu", "cholmod")}
    for m, s in sel.items():
        assert s is not None and s.method == "sparse solves", m
        assert np.abs(s.Qcc - sel["splu"].Qcc).max() <= 1e-9 * np.abs(sel["splu"].Qcc).max()
        np.testing.assert_allclose(s.Qpp, sel["splu"].Qpp, rtol=1e-9)
        # and both agree with the dense inverse of the full-statistics run
        np.testing.assert_allclose(s.Qcc, a.covariance.Qcc[np.ix_(s.columns, s.columns)], rtol=1e-7,
                                   atol=1e-9 * np.abs(a.covariance.Qcc).max())


@needs_cholmod
def test_pcg_adjustment_reaches_the_direct_cost(monkeypatch):
    block, _ = synthetic_block(seed=6, n_strips=3, n_per_strip=8, n_points=500)
    cfg = AdjustConfig(statistics=StatisticsOptions(compute=False))
    direct = _adjust_with(monkeypatch, block, cfg, "cholmod")
    inexact = _adjust_with(monkeypatch, block, cfg, "pcg")
    assert inexact.info.linear_solver.startswith("pcg")
    assert inexact.info.converged
    assert inexact.info.final_cost == pytest.approx(direct.info.final_cost, rel=1e-3)
