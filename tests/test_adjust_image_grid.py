"""Correction-grid node values as unknowns of the adjustment (skyrig.adjust.factors.image_grid, issue 12).

Independent answers: central finite differences of the residuals for the Jacobian; the dense normal equations
(every row, every column written out, no Schur complement, no units) for the compiled engine's step; and a seeded
simulation whose image deformation is drawn from the grid's own prior (so it is exactly a grid of those nodes), with
an interior-orientation error on top, for the joint estimate: the IO within 2 sigma of the truth and the grid's
error consistent with its posterior covariance (chi-square of the whole grid).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.stats import chi2

from _dense_reference import dense_system

from skyrig.adjust import AdjustConfig
from skyrig.adjust.config import Unknowns
from skyrig.adjust.adjust import adjust
from skyrig.adjust.block import BlockError
from skyrig.adjust.factors.image_grid import GridSpec, ImageGrids, bilinear_weights
from skyrig.adjust.model import Model, State
from skyrig.adjust.synthetic import synthetic_block
from skyrig.camera.frame import FrameCamera

IO = ("focal_mm", "ppx_mm", "ppy_mm")


def _prior(xs, ys, c0=0.25, length=700.0, nugget=0.01):
    gx, gy = np.meshgrid(xs, ys)
    nodes = np.column_stack([gx.ravel(), gy.ravel()])
    d = np.linalg.norm(nodes[:, None] - nodes[None], axis=2)
    return c0 * np.exp(-np.square(d / length)) + nugget * c0 * np.eye(len(nodes))


def _scenario(seed=3, grid_seed=5):
    cam = FrameCamera.from_pixels("cam", 1500, 1000, 1250.0, 749.5, 499.5, pixel_size_mm=0.008)
    true = FrameCamera.from_pixels("cam", 1500, 1000, 1256.0, 752.5, 497.5, pixel_size_mm=0.008)
    b, _ = synthetic_block(seed=seed, n_strips=3, n_per_strip=6, n_points=800, camera=cam, true_camera=true,
                           sigma_px=0.3, n_control=6)
    xs, ys = np.linspace(0, 1499, 6), np.linspace(0, 999, 4)
    C = _prior(xs, ys)
    Lc = np.linalg.cholesky(C)
    rng = np.random.default_rng(grid_seed)
    g_true = np.stack([Lc @ rng.standard_normal(len(C)), Lc @ rng.standard_normal(len(C))], axis=-1)  # (m, 2)
    idx, w = bilinear_weights(xs, ys, b.obs_pixel)
    d = np.stack([(w * g_true[idx, 0]).sum(1), (w * g_true[idx, 1]).sum(1)], axis=1)
    grids = ImageGrids([GridSpec("cam", xs, ys, np.zeros((len(ys), len(xs), 2)), C)])
    return replace(b, obs_pixel=b.obs_pixel + d, observations={**b.observations, "image_grid": grids}), true, g_true


def _dense(factors, layout):
    return dense_system(factors, layout)


CFG = AdjustConfig(unknowns=Unknowns(intrinsics="free", intrinsic_names=IO, boresight="free", image_grid="weighted"))


def test_grid_jacobian_equals_finite_differences():
    b, _, g_true = _scenario()
    model = Model(b, CFG)
    lay = model.layout
    s = State.from_block(b)
    s.grid = 0.3 * g_true.reshape(-1)  # away from zero: the prior's rows are not at their minimum
    J, _ = _dense(model.evaluate(s), lay)
    grid_cols = [j for j, lab in enumerate(lay.labels) if lab[0] == "image_grid"]
    io_cols = [j for j, lab in enumerate(lay.labels) if lab[0] == "intrinsics"]
    assert len(grid_cols) == 2 * 24 and len(io_cols) == 3
    for j in grid_cols[::5] + grid_cols[-3:] + io_cols:
        h = 1e-3 if lay.labels[j][0] == "image_grid" else 1e-6
        dc = np.zeros(lay.n_c)
        dc[j] = h
        dp = np.zeros((lay.n_p, 3))
        fp = np.concatenate([(f.r * (np.sqrt(f.weight) if f.weight is not None else 1.0)[:, None]).reshape(-1)
                             for f in model.evaluate(lay.apply(s, dc, dp), jacobians=False)])
        fm = np.concatenate([(f.r * (np.sqrt(f.weight) if f.weight is not None else 1.0)[:, None]).reshape(-1)
                             for f in model.evaluate(lay.apply(s, -dc, dp), jacobians=False)])
        fd = (fp - fm) / (2 * h)
        scale = max(np.abs(J[:, j]).max(), 1e-12)
        np.testing.assert_allclose(J[:, j], fd, rtol=0, atol=1e-5 * scale, err_msg=str(lay.labels[j]))


def test_engine_step_with_grid_equals_dense_normal_equations():
    from skyrig.adjust.solver import HAVE_NUMBA, SchurEngine

    if not HAVE_NUMBA:
        pytest.skip("numba not installed")
    b, _, _ = _scenario()
    model = Model(b, CFG)
    s = State.from_block(b)
    factors = model.evaluate(s)
    eng = SchurEngine(factors, model.layout, b.obs_image)
    eng.linearize(factors)
    lam = 1e-3
    dc, dp, _ = eng.solve(lam)
    J, r = _dense(factors, model.layout)
    A, g = J.T @ J, J.T @ r
    D = np.clip(np.diag(A), 1e-6, None)
    ref = np.linalg.solve(A + lam * np.diag(D), -g)
    n_c = model.layout.n_c
    np.testing.assert_allclose(dc, ref[:n_c], rtol=0, atol=1e-7 * np.abs(ref[:n_c]).max())
    np.testing.assert_allclose(dp.reshape(-1), ref[n_c:], rtol=0, atol=1e-7 * np.abs(ref[n_c:]).max())


def test_joint_estimate_separates_grid_and_interior_orientation():
    b, true, g_true = _scenario()
    r = adjust(b, CFG)
    assert r.ok, r.failures
    lab = r.layout.labels
    Q = r.covariance.Qcc  # a-priori cofactors: the simulated sigmas are the block's
    est = dict(zip(r.block.cameras[0].intrinsic_names, r.block.cameras[0].intrinsics))
    tru = dict(zip(true.intrinsic_names, true.intrinsics))
    for name in IO:
        j = lab.index(("intrinsics", "cam", name))
        z = (est[name] - tru[name]) / np.sqrt(Q[j, j])
        assert abs(z) < 2.0, (name, z)
    gi = [j for j, q in enumerate(lab) if q[0] == "image_grid"]
    e = r.block.observations["image_grid"].grids[0].value_px.reshape(-1) - g_true.reshape(-1)
    m2 = float(e @ np.linalg.solve(Q[np.ix_(gi, gi)], e))
    p = chi2.sf(m2, len(gi))
    assert 0.001 < p < 0.999, (m2, len(gi))
    # the same data without the grid unknowns: the deformation goes into the IO (the test has power)
    r0 = adjust(b, CFG.with_unknowns(image_grid="fixed"))
    est0 = dict(zip(r0.block.cameras[0].intrinsic_names, r0.block.cameras[0].intrinsics))
    z0 = max(abs(est0[n] - tru[n]) / r0.sigma_reduced()[("intrinsics", "cam", n)] for n in IO)
    assert z0 > 4.0


def test_fixed_grid_is_applied_as_a_known_correction():
    b, true, g_true = _scenario()
    known = b.observations["image_grid"].with_values(g_true.reshape(-1))
    r = adjust(replace(b, observations={**b.observations, "image_grid": known}), CFG.with_unknowns(image_grid="fixed"))
    assert r.ok and 0.8 < r.sigma0 < 1.2
    assert not any(q[0] == "image_grid" for q in r.layout.labels)


def test_grid_of_an_unknown_camera_is_refused():
    b, _, _ = _scenario()
    g = b.observations["image_grid"].grids[0]
    with pytest.raises(BlockError, match="no camera of that name"):
        replace(b, observations={**b.observations, "image_grid": ImageGrids([replace(g, camera="other")])}).validate()
