"""The BAL model mapped onto COLMAP/Ceres (bench/bal.py) against skyrig's BAL model.

pycolmap is the independent reference: its own projection and Ceres's cost of the reconstruction that
bench/bal.py builds must equal skyrig's BAL residuals and cost; and Ceres and skyrig, started from the
same block with the same tolerances, must reach the same minimum.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from conftest import shared_path
from skyrig.adjust import AdjustConfig, adjust
from skyrig.adjust.config import SolverOptions, StatisticsOptions, Unknowns
from skyrig.adjust.model import bal_project
from skyrig.io.bal import read_bal

pycolmap = pytest.importorskip("pycolmap")

_spec = importlib.util.spec_from_file_location("bench_bal", Path(__file__).resolve().parents[1] / "bench" / "bal.py")
bench = importlib.util.module_from_spec(_spec)  # type: ignore[arg-type]
_spec.loader.exec_module(bench)  # type: ignore[union-attr]


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    p = tmp_path_factory.mktemp("bal") / "tiny.txt"
    bench.generate(p, 9, 300, obs_per_point=4, seed=3)
    return read_bal(p)


def _ceres(rec, iterations):
    opt = pycolmap.BundleAdjustmentOptions()
    opt.print_summary = False
    so = opt.ceres.solver_options
    so.max_num_iterations = iterations
    so.function_tolerance, so.parameter_tolerance, so.gradient_tolerance = 1e-6, 1e-8, 1e-10
    so.num_threads = 1
    cfg = pycolmap.BundleAdjustmentConfig()
    for i in rec.reg_image_ids():
        cfg.add_image(i)
    cfg.fix_gauge(pycolmap.BundleAdjustmentGauge.UNSPECIFIED)
    return pycolmap.create_default_bundle_adjuster(opt, cfg, rec).solve().ceres_summary


def test_colmap_projection_equals_bal_projection(tiny):
    rec, ids = bench.to_colmap(tiny)
    # skyrig's BAL projection
    o, p = tiny.obs_image, tiny.obs_point
    R = np.swapaxes(tiny.station_rotation, 1, 2)[o]
    P = np.einsum("nij,nj->ni", R, tiny.point_xyz[p] - tiny.station_centre[o])
    intr = np.array([c.intrinsics for c in tiny.cameras])[o]
    uv, _, _ = bal_project(P, intr)
    # pycolmap's own projection of the same point in the same image
    got = np.array([rec.camera(int(i) + 1).img_from_cam(rec.image(int(i) + 1).cam_from_world() * tiny.point_xyz[k])
                    for i, k in zip(o, p)])
    np.testing.assert_allclose(got, uv * [1.0, -1.0], rtol=0, atol=1e-9 * np.abs(uv).max())
    # and the tracks carry the measurements: the reconstruction's point2D of each observation
    for i in range(tiny.n_images):
        img = rec.image(i + 1)
        xy = np.array([q.xy for q in img.points2D])
        np.testing.assert_array_equal(xy, tiny.obs_pixel[tiny.obs_image == i] * [1.0, -1.0])


def test_ceres_initial_cost_equals_skyrig(tiny):
    rec, _ = bench.to_colmap(tiny)
    s = _ceres(rec, 1)
    assert s.num_residuals == 2 * tiny.n_observations
    assert s.initial_cost == pytest.approx(bench.bal_cost(tiny), rel=1e-10)


def test_ceres_and_skyrig_reach_the_same_minimum(tiny):
    rec, ids = bench.to_colmap(tiny)
    s = _ceres(rec, 100)
    assert str(s.termination_type).endswith("CONVERGENCE")
    ceres_final = bench.bal_cost(bench.from_colmap(tiny, rec, ids))
    assert ceres_final == pytest.approx(s.final_cost, rel=1e-9)  # the round trip back to BAL is exact
    r = adjust(tiny, AdjustConfig(unknowns=Unknowns(intrinsics="free", datum="none"),
                                  statistics=StatisticsOptions(compute=False),
                                  solver=SolverOptions(max_iterations=100)))
    # both stop on a relative decrease below 1e-6 at the same minimum (far below the start: noise only)
    assert r.info.final_cost < 0.05 * s.initial_cost
    assert r.info.final_cost == pytest.approx(ceres_final, rel=1e-4)


def test_problem_49_initial_cost_equals_ceres():
    b = read_bal(shared_path("bal", "problem-49-7776-pre.txt"))
    b, n_obs, _ = bench.drop_behind(b)  # COLMAP zeroes the residual of a point behind the camera
    assert 0 < n_obs < 100
    rec, _ = bench.to_colmap(b)
    s = _ceres(rec, 1)
    assert s.initial_cost == pytest.approx(bench.bal_cost(b), rel=1e-10)
