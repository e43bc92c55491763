"""The joint laser factor's memory: bounded by its planes and unknowns, not by its laser points (issue 34).

Each laser plane's square-root rows share one column set (:mod:`skyrig.adjust.factors.lidar`); the normal
equations of such factors are accumulated per column set, rows a chunk at a time
(:func:`skyrig.adjust.schur_engine.set_normals`), and the factor is evaluated a chunk of whole planes at a time
(:func:`skyrig.adjust.factors.lidar.plane_chunks`).  Checked here: the per-set normals equal the dense
``A^T A`` / ``A^T r`` of the rows (an independent dense product), the engine's and :func:`assemble`'s reduced
normals equal it, the chunked evaluation equals the one-chunk evaluation (the former code path) to round-off, and
the peak memory of evaluating and linearising the factor does not grow with the laser points at fixed planes.
"""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

import skyrig.adjust.factors.lidar as lidar_mod
import skyrig.adjust.schur_engine as eng_mod
from skyrig.adjust import AdjustConfig
from skyrig.adjust.config import Unknowns
from skyrig.adjust.factors.lidar import NAME, lidar_unknowns
from skyrig.adjust.model import Model
from skyrig.adjust.solver import SchurEngine, assemble
from test_adjust_lidar_factor import STRIP_SIGMA, _joint_block


def _model(per: int, n_patch: int = 12, n_tie: int = 6):
    b, _, _ = _joint_block(seed=4, n_patch=n_patch, n_tie=n_tie, per=per)
    cfg = AdjustConfig(unknowns=lidar_unknowns(Unknowns(), strip_sigma=tuple(STRIP_SIGMA)))
    m = Model(b, cfg)
    return m, m.initial.copy()


def _dense(f, n_c):
    """``A^T A`` and ``A^T r`` of a factor's rows as one dense matrix (the reference)."""
    n, d, kf = f.jc.shape
    A = np.zeros((n * d, n_c + 1))
    rows = np.repeat(np.arange(n * d), kf)
    cols = np.where(f.cols >= 0, f.cols, n_c)[:, None, :].repeat(d, axis=1).reshape(-1)
    np.add.at(A, (rows, cols), f.jc.reshape(-1))
    A = A[:, :n_c]
    r = f.r.reshape(-1)
    return A.T @ A, A.T @ r


@pytest.fixture(scope="module")
def small():
    return _model(per=12)


def test_set_normals_equal_the_dense_products(small, monkeypatch):
    m, s = small
    f = next(x for x in m.evaluate(s, jacobians=True) if x.name == NAME)
    n_c = m.layout.n_c
    AtA, Atr = _dense(f, n_c)
    sets, srow = eng_mod.column_sets(f.cols)
    assert len(sets) <= m.block.observations[NAME].n_planes < len(f)  # one block per plane at most, not per row
    monkeypatch.setattr(eng_mod, "SET_CHUNK_ENTRIES", 5000)  # many chunks
    scale = np.abs(AtA).max()
    # one product per set (many rows per set), then the chunked per-row path (told of as many sets as rows)
    for n_sets in (len(sets), len(f)):
        jtj, g = eng_mod.set_normals(f.jc, f.r, np.ones(len(f)), srow, n_sets)
        assert np.abs(jtj[len(sets):]).max(initial=0.0) == 0.0
        U = np.zeros((n_c + 1, n_c + 1))
        gc = np.zeros(n_c + 1)
        c = np.where(sets >= 0, sets, n_c)
        np.add.at(U, (c[:, :, None], c[:, None, :]), jtj[:len(sets)])
        np.add.at(gc, c, g[:len(sets)])
        assert np.abs(U[:n_c, :n_c] - AtA).max() < 1e-12 * scale
        assert np.abs(gc[:n_c] - Atr).max() < 1e-12 * np.abs(Atr).max()
    # assemble and the compiled engine on the laser factor alone
    N = assemble([f], m.layout, None)
    assert np.abs(N.U.toarray() - AtA).max() < 1e-12 * scale
    assert np.abs(N.gc - Atr).max() < 1e-12 * np.abs(Atr).max()
    if eng_mod.HAVE_NUMBA:
        e = SchurEngine([f], m.layout, m.block.obs_image)
        e.linearize([f])
        Ue = np.zeros((n_c, n_c))
        Ue[e.rows, e.indices] = e.U0
        assert np.abs(Ue - AtA).max() < 1e-12 * scale
        assert np.abs(e.gc - Atr).max() < 1e-12 * np.abs(Atr).max()


def test_chunked_evaluation_equals_one_chunk(small, monkeypatch):
    m, s = small
    s.groups["lidar_scanner"][0] += np.array([1e-3, -2e-3, 1e-3, 0.01, 0.02, -0.01, 0.01, 2e-4])  # off the start
    out = {}
    for chunk in (10**9, 40):  # the whole factor at once (the former path), then a few planes at a time
        monkeypatch.setattr(lidar_mod, "CHUNK_POINTS", chunk)
        fj = next(x for x in m.evaluate(s, jacobians=True) if x.name == NAME)
        f0 = next(x for x in m.evaluate(s, jacobians=False) if x.name == NAME)
        z, rms = lidar_mod.LIDAR.normalised_residuals(m.block)
        out[chunk] = (fj, f0, z, rms)
    (a, a0, za, ra), (b, b0, zb, rb) = out.values()
    assert a.cols.shape == b.cols.shape and np.array_equal(a.cols, b.cols) and a.n_extra == b.n_extra
    np.testing.assert_allclose(b.r, a.r, rtol=0, atol=1e-10 * np.abs(a.r).max())
    np.testing.assert_allclose(b.jc, a.jc, rtol=0, atol=1e-10 * np.abs(a.jc).max())
    np.testing.assert_allclose(b0.r, a0.r, rtol=1e-10, atol=0)
    np.testing.assert_allclose(zb, za, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(rb, ra, rtol=1e-10, atol=0)


def _peak_bytes(n_patch: int, n_tie: int, monkeypatch) -> tuple[int, int, int, int]:
    """Peak traced memory of one evaluation of the laser factor with its Jacobians and of its normals by
    :func:`assemble` and by the compiled engine (block built and kernels compiled before tracing); the laser
    points, the planes and the factor's row width."""
    m, s = _model(per=48, n_patch=n_patch, n_tie=n_tie)
    monkeypatch.setattr(lidar_mod, "CHUNK_POINTS", 1000)
    lp = m.block.observations[NAME]

    def run() -> int:
        f = lidar_mod.LIDAR.evaluate(m, s, True)[0]
        assemble([f], m.layout, None)
        if eng_mod.HAVE_NUMBA:
            SchurEngine([f], m.layout, m.block.obs_image).linearize([f])
        return f.jc.shape[2]

    run()
    tracemalloc.start()
    try:
        w = run()
        return tracemalloc.get_traced_memory()[1], len(lp), lp.n_planes, w
    finally:
        tracemalloc.stop()


def test_peak_memory_grows_by_the_planes_not_by_the_laser_points(monkeypatch):
    # 48 points per strip and plane (the cap of the joint recipe's patches): each plane has its k + 1 rows.  Four
    # times the planes and points: the peak may grow by the planes' blocks (k x k each, a few times over), not by
    # the points' Jacobians and a k x k product per row (before: +270 MB here, of which +12 MB per-point arrays)
    p1, n1, q1, w = _peak_bytes(12, 6, monkeypatch)
    p4, n4, q4, _ = _peak_bytes(48, 24, monkeypatch)
    assert n4 == 4 * n1 and q4 == 4 * q1
    per_plane = w * w * 8
    assert p4 - p1 < 8 * (q4 - q1) * per_plane, ((p4 - p1) / 1e6, (q4 - q1) * per_plane / 1e6)
