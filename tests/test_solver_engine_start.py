"""The datum check's Schur engine: its reduced matrix against the scipy reference path, and the solver
started from it (``levenberg_marquardt(engine_at_start=)``) against a solver that builds its own.

The reference for the matrix is the sparse-matrix path (``assemble`` + ``schur_matrix``: BSR products,
no units, no compiled kernels); the reference for the solve is the same solve from scratch.
"""

from __future__ import annotations

import importlib

import numpy as np
import pytest

from skyrig.adjust import AdjustConfig
from skyrig.adjust.config import Unknowns
from skyrig.adjust.model import Model, State
from skyrig.adjust.solver import HAVE_NUMBA, assemble, levenberg_marquardt, schur_matrix
from skyrig.adjust.synthetic import synthetic_block
from skyrig.rig.presets import midas

A = importlib.import_module("skyrig.adjust.adjust")  # the module (the package re-exports the function)

pytestmark = pytest.mark.skipif(not HAVE_NUMBA, reason="numba not installed")


def _rig_model(cfg: AdjustConfig, seed: int = 21):
    bore = np.array([[1e-3, -2e-3, 5e-4]] * 5)
    b, _ = synthetic_block(seed=seed, n_strips=3, n_per_strip=5, n_points=400, rig=midas(), height_m=500.0,
                           n_control=5, head_boresight=bore)
    return b, Model(b, cfg)


def test_engine_reduced_matrix_equals_the_scipy_path():
    b, model = _rig_model(AdjustConfig(unknowns=Unknowns(boresight="free")))
    state = State.from_block(b)
    S, rhs, eng = A._reduced_at(model, state)
    assert eng is not None
    S0, rhs0, _ = schur_matrix(assemble(model.evaluate(state), model.layout, b.obs_image), 0.0)
    D, D0 = S.toarray(), S0.toarray()
    scale = np.sqrt(np.outer(np.diag(D0), np.diag(D0)))
    assert np.all(np.diag(D0) > 0)
    np.testing.assert_allclose(D / scale, D0 / scale, rtol=0, atol=1e-10)
    np.testing.assert_allclose(rhs, rhs0, rtol=0, atol=1e-9 * np.abs(rhs0).max())


@pytest.mark.parametrize("cfg", [AdjustConfig(unknowns=Unknowns(boresight="free")),
                                 AdjustConfig(unknowns=Unknowns(boresight="free", intrinsics="free",
                                                                intrinsic_names=("focal_mm",)))])
def test_solver_started_from_the_datum_check_engine_is_identical(cfg):
    b, model = _rig_model(cfg)
    state = State.from_block(b)
    free = cfg.unknowns.datum == "free"
    eng = A.check_datum(model, state, free)
    assert eng is not None and eng.cost > 0
    s1, i1 = levenberg_marquardt(model, state, free_datum=free, engine_at_start=eng)
    s2, i2 = levenberg_marquardt(model, State.from_block(b), free_datum=free)
    assert i1.iterations == i2.iterations and i1.unsuccessful == i2.unsuccessful
    assert i1.initial_cost == i2.initial_cost and i1.final_cost == i2.final_cost
    for name in ("C", "X", "bore"):
        np.testing.assert_array_equal(getattr(s1, name), getattr(s2, name))


def test_engine_at_start_is_not_used_with_robust_weights():
    """Huber reweighting changes the first linearisation: the solver must build its own."""
    b, model = _rig_model(AdjustConfig(unknowns=Unknowns(boresight="free")))
    state = State.from_block(b)
    eng = A.check_datum(model, state, False)
    s1, i1 = levenberg_marquardt(model, state, huber_k=1.5, engine_at_start=eng)
    s2, i2 = levenberg_marquardt(model, State.from_block(b), huber_k=1.5)
    assert i1.initial_cost == i2.initial_cost and i1.final_cost == i2.final_cost
    np.testing.assert_array_equal(s1.X, s2.X)


@pytest.fixture
def sparse_engine(monkeypatch):
    """The engine's sparse direct path on a small block (its dense limit lowered below the block's size)."""
    import skyrig.adjust.solver as S

    monkeypatch.setattr(S, "ENGINE_DENSE_LIMIT", 40)
    return S


def test_datum_check_on_the_engine_solver_then_the_same_solve(sparse_engine):
    b, model = _rig_model(AdjustConfig(unknowns=Unknowns(boresight="free")))
    state = State.from_block(b)
    eng = A.check_datum(model, state, False)
    assert eng._rs is not None and eng._rs.method in ("cholmod", "splu")  # the round trip ran on it
    s1, i1 = levenberg_marquardt(model, state, engine_at_start=eng)
    s2, i2 = levenberg_marquardt(model, State.from_block(b))
    assert i1.linear_solver == i2.linear_solver
    assert i1.iterations == i2.iterations and i1.final_cost == pytest.approx(i2.final_cost, rel=1e-12)
    np.testing.assert_allclose(s1.X, s2.X, rtol=0, atol=1e-9)


def test_datum_defect_found_by_the_engine_solver(sparse_engine):
    # no control, no GNSS, no IMU: the block floats (7 similarity motions)
    b, _ = synthetic_block(seed=2, n_strips=2, n_per_strip=5, n_points=200, n_control=0, gnss_sigma_m=None,
                           imu_sigma_rad=None)
    model = Model(b, AdjustConfig(unknowns=Unknowns(datum="none")))
    with pytest.raises(A.DatumDefectError):
        A.check_datum(model, State.from_block(b), False)
