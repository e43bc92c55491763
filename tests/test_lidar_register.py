"""Registration: 3-point coarse alignment and ICP (Open3D and skyrig's scipy backend) on a seeded scene."""

from __future__ import annotations

import numpy as np
import pytest

from skyrig.errors import GeometryError
from skyrig.geometry.rotations import matrix_from_rotvec
from skyrig.lidar.register import apply_transform, fit_transform, icp


def _surface(n=6000, seed=0):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-10, 10, (n, 2))
    z = 0.5 * np.sin(0.5 * xy[:, 0]) + 0.3 * np.cos(0.4 * xy[:, 1]) + 0.02 * xy[:, 0] * xy[:, 1]
    return np.c_[xy, z]


def _truth():
    m = np.eye(4)
    m[:3, :3] = matrix_from_rotvec(np.radians([1.0, -2.0, 5.0]))
    m[:3, 3] = [0.4, -0.3, 0.2]
    return m


def test_three_point_rigid_and_similarity_fit():
    rng = np.random.default_rng(1)
    src = rng.uniform(-50, 50, (3, 3))
    m = _truth()
    np.testing.assert_allclose(fit_transform(src, apply_transform(m, src)).matrix, m, atol=1e-10)
    ms = m.copy()
    ms[:3, :3] *= 1.0003
    f = fit_transform(src, apply_transform(ms, src), similarity=True)
    assert f.scale == pytest.approx(1.0003, abs=1e-12) and f.rms_m < 1e-9
    # with noise: the residuals are target minus transformed source, and sigma0 is near the noise
    src = rng.uniform(-50, 50, (40, 3))
    dst = apply_transform(m, src) + rng.normal(0, 0.01, (40, 3))
    f = fit_transform(src, dst)
    np.testing.assert_allclose(f.residuals, dst - apply_transform(f.matrix, src))
    assert 0.007 < f.sigma0_m < 0.013


def test_degenerate_points_are_rejected():
    with pytest.raises(GeometryError, match="collinear"):
        fit_transform(np.array([[0, 0, 0], [1, 1, 1], [2, 2, 2.0]]), np.zeros((3, 3)))
    with pytest.raises(GeometryError):
        fit_transform(np.zeros((2, 3)), np.zeros((2, 3)))


@pytest.mark.parametrize("backend", ["open3d", "scipy"])
@pytest.mark.parametrize("method", ["point_to_point", "point_to_plane"])
def test_icp_recovers_the_transform(backend, method):
    if backend == "open3d":
        pytest.importorskip("open3d", exc_type=ImportError)
    target = _surface()
    m = _truth()
    if method == "point_to_plane":
        source = apply_transform(np.linalg.inv(m), _surface(seed=1))  # different samples of the same surface
    else:  # point-to-point is biased by the sampling: give it the target's own points, with 5 mm noise
        noise = np.random.default_rng(4).normal(0, 0.005, (3000, 3))
        source = apply_transform(np.linalg.inv(m), target[::2] + noise)
    r = icp(source, target, method=method, max_correspondence_distance=1.0, backend=backend, max_iterations=100)
    assert r.backend == backend
    # residual error of the recovered pose at the points: a fraction of the 0.2 m sample spacing
    err = np.linalg.norm(apply_transform(r.matrix, source) - apply_transform(m, source), axis=1)
    assert err.max() < 0.03, err.max()
    assert r.fitness > 0.9 and r.rmse_m < 0.2


def test_icp_backends_agree():
    pytest.importorskip("open3d", exc_type=ImportError)
    target = _surface()
    source = apply_transform(np.linalg.inv(_truth()), _surface(seed=2))
    a = icp(source, target, backend="open3d", max_iterations=100)
    b = icp(source, target, backend="scipy", max_iterations=100)
    np.testing.assert_allclose(apply_transform(a.matrix, source), apply_transform(b.matrix, source), atol=0.02)
