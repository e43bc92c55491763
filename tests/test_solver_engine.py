"""The compiled Schur engine (skyrig.adjust.solver.SchurEngine) against the dense normal equations.

The independent answer: the full Jacobian of all factors written out as a dense matrix (every row, every
reduced column and every point coordinate), ``A = J^T J``, ``g = J^T r``, and the damped system
``(A + lam diag(A)) d = -g`` solved with numpy - no Schur complement, no units, no sparse patterns.
The blocks exercise what the engine's bookkeeping must get right: a penta rig (5 heads share a station
pose), free boresights (head-level columns shared by all stations), free intrinsics (shared by all images),
GNSS with lever arm, IMU, control points, and Huber reweighting.
"""

from __future__ import annotations

import numpy as np
import pytest

from _dense_reference import dense_system

from skyrig.adjust import AdjustConfig
from skyrig.adjust.config import Unknowns
from skyrig.adjust.model import Model, State
from skyrig.adjust.solver import HAVE_NUMBA, SchurEngine, _robust, _ScipyEngine, levenberg_marquardt
from skyrig.adjust.synthetic import synthetic_block
from skyrig.rig.presets import midas

pytestmark = pytest.mark.skipif(not HAVE_NUMBA, reason="numba not installed")


def _dense_step(factors, layout, lam, huber_k=None, diag_min=1e-6):
    n_c = layout.n_c
    J, r = dense_system(factors, layout, lambda f: _robust(f, huber_k)[0])
    A = J.T @ J
    g = J.T @ r
    D = np.clip(np.diag(A), diag_min, None)
    d = np.linalg.solve(A + lam * np.diag(D), -g)
    return d[:n_c], d[n_c:].reshape(-1, 3)


def _rig_block(seed=11):
    bore = np.array([[1e-3, -2e-3, 5e-4]] * 5)
    return synthetic_block(seed=seed, n_strips=2, n_per_strip=4, n_points=150, rig=midas(), height_m=500.0,
                           n_control=5, lever_arm=np.array([0.2, -0.1, -1.2]), head_boresight=bore)


@pytest.mark.parametrize("lam", [1e-4, 0.3])
@pytest.mark.parametrize(
    "cfg, huber",
    [
        (AdjustConfig(), None),
        (AdjustConfig(unknowns=Unknowns(boresight="free", lever_arm="free", intrinsics="free",
                                        intrinsic_names=("focal_mm", "ppx_mm"))), None),
        (AdjustConfig(unknowns=Unknowns(boresight="weighted", intrinsics="weighted", intrinsic_names=("focal_mm",),
                                        intrinsic_sigma=(("focal_mm", 0.01),))), 1.5),
    ],
)
def test_engine_step_equals_dense_normal_equations(cfg, huber, lam):
    b, _ = _rig_block()
    model = Model(b, cfg)
    state = State.from_block(b)
    factors = model.evaluate(state)
    eng = SchurEngine(factors, model.layout, b.obs_image)
    eng.linearize(factors, huber)
    dc, dp, _ = eng.solve(lam)
    dc_ref, dp_ref = _dense_step(factors, model.layout, lam, huber)
    scale_c = np.abs(dc_ref).max()
    np.testing.assert_allclose(dc, dc_ref, rtol=0, atol=1e-7 * scale_c)
    np.testing.assert_allclose(dp, dp_ref, rtol=0, atol=1e-7 * np.abs(dp_ref).max())
    # the scipy reference path (assemble / schur_matrix / solve_reduced, blocks per unit) as well
    ref = _ScipyEngine(model.layout, b.obs_image)
    ref.linearize(factors, huber)
    dc2, dp2, _ = ref.solve(lam)
    np.testing.assert_allclose(dc2, dc_ref, rtol=0, atol=1e-7 * scale_c)
    np.testing.assert_allclose(dp2, dp_ref, rtol=0, atol=1e-7 * np.abs(dp_ref).max())


def test_units_are_stations_when_only_poses_are_free():
    # all five heads of an exposure share the station's 6 pose columns: one unit (block) per station
    b, _ = _rig_block()
    model = Model(b, AdjustConfig())
    factors = model.evaluate(State.from_block(b))
    eng = SchurEngine(factors, model.layout, b.obs_image)
    assert b.n_images == 5 * b.n_stations
    n_units = int((eng.ucols >= 0).any(axis=1).sum())  # (images without observations: one unit of no columns)
    assert n_units == len(np.unique(b.image_station[b.obs_image])) and eng.k == 6
    # with per-head boresight columns each image has its own column set
    model = Model(b, AdjustConfig(unknowns=Unknowns(boresight="free")))
    eng = SchurEngine(model.evaluate(State.from_block(b)), model.layout, b.obs_image)
    assert int((eng.ucols >= 0).any(axis=1).sum()) == len(np.unique(b.obs_image)) and eng.k == 9


def test_numba_and_scipy_engines_reach_the_same_minimum():
    b, _ = _rig_block(seed=12)
    model = Model(b, AdjustConfig(unknowns=Unknowns(boresight="free", lever_arm="free")))
    s1, i1 = levenberg_marquardt(model, State.from_block(b), engine="numba", huber_k=2.0)
    s2, i2 = levenberg_marquardt(model, State.from_block(b), engine="scipy", huber_k=2.0)
    assert i1.converged and i2.converged
    assert i1.final_cost == pytest.approx(i2.final_cost, rel=1e-8)
    np.testing.assert_allclose(s1.X, s2.X, rtol=0, atol=1e-5)
    np.testing.assert_allclose(s1.bore, s2.bore, rtol=0, atol=1e-9)


@pytest.mark.parametrize("cfg", [AdjustConfig(unknowns=Unknowns(intrinsics="free", datum="none")), AdjustConfig(unknowns=Unknowns(datum="none")),
                                 AdjustConfig(unknowns=Unknowns(intrinsics="free", poses="fixed", datum="none"))])
def test_compiled_bal_rows_equal_the_numpy_path(monkeypatch, tmp_path, cfg):
    # the numpy path of Model._image (bal_project + chain rule, itself checked against pycolmap's projection
    # in test_bal_ceres.py) is the reference; a head offset exercises the lever term of the pose Jacobian
    import importlib.util
    from pathlib import Path

    import skyrig.adjust.model as model_mod
    from skyrig.io.bal import read_bal

    if model_mod._BAL_KERNEL is None:
        pytest.skip("numba not installed")
    spec = importlib.util.spec_from_file_location("bench_bal", Path(__file__).resolve().parents[1] / "bench" / "bal.py")
    bench = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    spec.loader.exec_module(bench)  # type: ignore[union-attr]
    bench.generate(tmp_path / "g.txt", 12, 400, obs_per_point=4, seed=4)
    b = read_bal(tmp_path / "g.txt")
    b.image_offset = np.random.default_rng(1).normal(0, 0.5, b.image_offset.shape)
    m = Model(b, cfg)
    s = State.from_block(b)
    s.X[b.obs_point[0]] = m.camera_poses(s)[1][b.obs_image[0]]  # a point at the projection centre: a bad row
    got = m._image(s, True)
    monkeypatch.setattr(model_mod, "_BAL_KERNEL", None)
    monkeypatch.setattr(model_mod, "_CHAIN_KERNEL", None)  # the reference: numpy throughout (the kernels share code)
    with np.errstate(divide="ignore", invalid="ignore"):
        ref = m._image(s, True)
    assert got.bad.any() and np.array_equal(got.bad, ref.bad)
    np.testing.assert_array_equal(got.r, ref.r)
    np.testing.assert_array_equal(got.cols, ref.cols)
    np.testing.assert_array_equal(got.point, ref.point)
    for a, c in ((got.jc, ref.jc), (got.jp, ref.jp)):
        scale = np.abs(c).max(axis=(0, 1))
        assert np.all(np.abs(a - c).max(axis=(0, 1)) <= 1e-12 * np.where(scale > 0, scale, 1.0))


@pytest.mark.parametrize("method", ["splu", "dense", "cholmod"])
def test_datum_defect_is_reported_by_the_sparse_solver(method):
    # no control, no GNSS, no IMU: the block floats (7 similarity motions); S is singular
    from skyrig.adjust.solver import SingularError, assemble, schur_matrix, solve_reduced

    b, _ = synthetic_block(seed=2, n_strips=2, n_per_strip=5, n_points=200, n_control=0, gnss_sigma_m=None,
                           imu_sigma_rad=None)
    model = Model(b, AdjustConfig(unknowns=Unknowns(datum="none")))
    N = assemble(model.evaluate(State.from_block(b)), model.layout, b.obs_image)
    S, rhs, _ = schur_matrix(N, 0.0)
    with pytest.raises(SingularError):
        solve_reduced(S, rhs, method=method)
    # the same system damped (Levenberg-Marquardt) is regular, and both solvers agree
    S2, rhs2, _ = schur_matrix(N, 1e-3)
    np.testing.assert_allclose(solve_reduced(S2, rhs2, method=method), solve_reduced(S2, rhs2, method="dense"),
                               rtol=1e-8, atol=1e-12)


@pytest.mark.parametrize("cfg", [AdjustConfig(), AdjustConfig(unknowns=Unknowns(boresight="free", intrinsics="free")),
                                 AdjustConfig(unknowns=Unknowns(poses="fixed", boresight="free"))])
def test_compiled_chain_rule_equals_the_numpy_path(monkeypatch, cfg):
    # frame cameras on a penta rig with lever arms (head offsets) and boresights: the numpy chain rule of
    # Model._image is the reference (itself checked against finite differences in test_adjust.py)
    import skyrig.adjust.model as model_mod

    if model_mod._CHAIN_KERNEL is None:
        pytest.skip("numba not installed")
    b, _ = _rig_block(seed=13)
    b.image_offset = np.random.default_rng(3).normal(0, 0.3, b.image_offset.shape)  # heads off the station
    model = Model(b, cfg)
    s = State.from_block(b)
    s.bore = np.random.default_rng(2).normal(0, 1e-3, s.bore.shape)
    got = model._image(s, True)
    monkeypatch.setattr(model_mod, "_CHAIN_KERNEL", None)
    ref = model._image(s, True)
    np.testing.assert_array_equal(got.cols, ref.cols)
    for a, c in ((got.jc, ref.jc), (got.jp, ref.jp)):
        scale = np.abs(c).max(axis=(0, 1))
        assert np.all(np.abs(a - c).max(axis=(0, 1)) <= 1e-12 * np.where(scale > 0, scale, 1.0))
