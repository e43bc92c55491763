"""Full per-observation covariance (image 2x2, GNSS / control 3x3) in the bundle adjustment.

Independent answers: the truth of seeded simulations whose noise is drawn from the stated
covariances, and the distributions theory assigns to the results (chi-square for sigma0 and for the
Mahalanobis norm of the true errors, N(0, I) for whitened point errors).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from skyrig.adjust import AdjustConfig, BlockError, adjust
from skyrig.adjust.model import whitening_matrices
from skyrig.adjust.synthetic import synthetic_block
from skyrig.geometry.rotations import rotvec_from_matrix

ALPHA = 0.001  # two-sided level of every distribution check


def _chi2_interval(dof: int) -> tuple[float, float]:
    lo, hi = chi2.ppf([ALPHA / 2, 1 - ALPHA / 2], dof)
    return float(lo), float(hi)


def _correlated_image_noise(block, rng, rho=0.8, sigma=0.5):  # type: ignore[no-untyped-def]
    """Draw image noise from per-observation covariances (common correlation, varying size)."""
    n = block.n_observations
    cov = np.broadcast_to(sigma**2 * np.array([[1.0, rho], [rho, 1.0]]), (n, 2, 2)).copy()
    cov *= rng.uniform(0.5, 2.0, n)[:, None, None]
    block.obs_pixel = block.obs_pixel + np.einsum("nij,nj->ni", np.linalg.cholesky(cov), rng.normal(size=(n, 2)))
    return cov


def test_whitening_matrices_invert_the_covariance():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(50, 3, 3))
    cov = A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(3)
    W = whitening_matrices(cov)
    # W^T W = cov^-1 and W is upper triangular (Cholesky factor of the inverse covariance)
    np.testing.assert_allclose(np.swapaxes(W, 1, 2) @ W, np.linalg.inv(cov), rtol=1e-9, atol=1e-9)
    assert np.allclose(np.tril(W, -1), 0.0)


def test_image_covariance_gives_independent_normalised_point_errors():
    """Intersection with known orientations: every point error is independent of the others, so the
    point errors whitened by their predicted 3x3 covariance must be N(0, I) only when the 2x2 image
    covariances are used; with per-axis sigmas alone (correlation ignored) X and Y errors correlate."""
    b, tr = synthetic_block(seed=3, n_strips=3, n_per_strip=7, n_points=600, sigma_px=1e-9, gnss_sigma_m=None,
                            imu_sigma_rad=None, n_control=0)
    b.station_centre, b.station_rotation = tr.station_centre.copy(), tr.station_rotation.copy()
    cov = _correlated_image_noise(b, np.random.default_rng(11))
    used = b.copy()
    used.obs_cov_px2 = cov
    used.__post_init__()
    np.testing.assert_allclose(used.obs_sigma_px, np.sqrt(np.diagonal(cov, axis1=1, axis2=2)))
    ignored = b.copy()
    ignored.obs_sigma_px = np.sqrt(np.diagonal(cov, axis1=1, axis2=2))
    out = {}
    for name, blk in (("used", used), ("ignored", ignored)):
        res = adjust(blk, AdjustConfig(poses="fixed"))
        e = res.block.point_xyz - tr.point_xyz
        z = np.linalg.solve(np.linalg.cholesky(res.point_covariance()), e[:, :, None])[:, :, 0]
        out[name] = (res, z.T @ z / len(z), len(z))
    res, C, n_pts = out["used"]
    lo, hi = _chi2_interval(res.redundancy)
    assert lo <= res.sigma0**2 * res.redundancy <= hi
    lo, hi = _chi2_interval(n_pts)
    for k in range(3):  # each whitened component: mean square ~ chi2(n)/n
        assert lo / n_pts <= C[k, k] <= hi / n_pts, C
    off = np.abs(C[np.triu_indices(3, 1)])
    assert off.max() < 3.3 / np.sqrt(n_pts), C  # |r| of independent N(0,1): sd 1/sqrt(n)
    # ignoring the correlation: X-Y correlation of the whitened errors is far outside that band
    C_ign = out["ignored"][1]
    assert np.abs(C_ign[np.triu_indices(3, 1)]).max() > 8.0 / np.sqrt(n_pts), C_ign


def test_image_and_gnss_covariance_in_a_full_adjustment():
    """Integrated adjustment with correlated image noise and correlated 3x3 GNSS noise: sigma0 and
    the Mahalanobis norm of the true pose errors (joint covariance of all poses) follow chi-square."""
    b, tr = synthetic_block(seed=3, n_strips=3, n_per_strip=7, n_points=400, sigma_px=1e-9, gnss_sigma_m=1e-9,
                            imu_sigma_rad=None, n_control=0)
    rng = np.random.default_rng(11)
    cov = _correlated_image_noise(b, rng)
    g = len(b.gnss_station)
    A = rng.normal(size=(g, 3, 3)) * 0.03
    gcov = A @ np.swapaxes(A, 1, 2) + 1e-4 * np.eye(3)
    b.gnss_xyz = b.gnss_xyz + np.einsum("nij,nj->ni", np.linalg.cholesky(gcov), rng.normal(size=(g, 3)))
    b.obs_cov_px2, b.gnss_cov_m2 = cov, gcov
    b.__post_init__()
    res = adjust(b, AdjustConfig())
    lo, hi = _chi2_interval(res.redundancy)
    assert lo <= res.sigma0**2 * res.redundancy <= hi
    dC = res.block.station_centre - tr.station_centre
    dth = rotvec_from_matrix(np.swapaxes(tr.station_rotation, 1, 2) @ res.block.station_rotation)
    e = np.concatenate([dC, dth], axis=1).reshape(-1)
    cols = res.layout.pose.reshape(-1)
    Q = res.covariance.Qcc[np.ix_(cols, cols)] * res.sigma0**2
    lo, hi = _chi2_interval(len(e))
    assert lo <= float(e @ np.linalg.solve(Q, e)) <= hi
    # residuals come back in observation units: v^T cov^-1 v summed over both groups is sigma0^2 r
    q = 0.0
    for grp, c in (("gnss", gcov), ("image", cov)):
        v = res.residuals[grp].residual
        q += float(np.einsum("ni,nij,nj->", v, np.linalg.inv(c), v))
    assert q == pytest.approx(res.sigma0**2 * res.redundancy, rel=1e-6)


def test_invalid_covariance_is_named():
    b, _ = synthetic_block(seed=1, n_strips=2, n_per_strip=4, n_points=80)
    cov = np.broadcast_to(np.eye(2), (b.n_observations, 2, 2)).copy()
    cov[5] = [[1.0, 2.0], [2.0, 1.0]]  # indefinite
    b.obs_cov_px2 = cov
    with pytest.raises(BlockError, match=r"obs_cov_px2\[5\]"):
        b.validate()
    with pytest.raises(BlockError, match="shape"):
        b.obs_cov_px2 = cov[:3]
        b.__post_init__()
