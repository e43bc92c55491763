"""Variance component estimation on a seeded synthetic block: the estimated sigmas recover the
simulation's true noise (independent answer: the sigma the simulator drew with), within a band
derived from each component's redundancy."""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from skyrig.adjust.synthetic import synthetic_block
from skyrig.adjust.vce import estimate_variance_components


def test_vce_recovers_true_sigmas_from_wrong_a_priori():
    block, _ = synthetic_block(seed=5, n_strips=2, n_per_strip=8, n_points=300, sigma_px=0.5,
                               gnss_sigma_m=0.03, imu_sigma_rad=2e-4)
    block.obs_sigma_px = block.obs_sigma_px * 2.0   # a priori 1 px, truth 0.5 px
    block.gnss_sigma = block.gnss_sigma * 4.0       # a priori 12 cm, truth 3 cm
    block.imu_sigma_rad = block.imu_sigma_rad / 3.0  # a priori too tight
    vc = estimate_variance_components(block, max_iterations=30)
    assert vc.converged
    res = vc.result
    truth = {"image[0, 1]": 0.5, "gnss[0, 1]": 0.03, "gnss[2]": 0.03, "imu[0, 1, 2]": 2e-4}
    for comp, true_sigma in truth.items():
        g = comp.split("[")[0]
        axes = [int(a) for a in comp[comp.index("[") + 1: -1].split(",")]
        red = float(res.residuals[g].redundancy[:, axes].sum())
        band = 4.0 / np.sqrt(2.0 * red)  # relative sd of a sigma estimate with r degrees of freedom, x4
        assert abs(vc.sigma[comp] / true_sigma - 1.0) < band, (comp, vc.sigma[comp], true_sigma, red)
    assert abs(res.sigma0 - 1.0) < 0.05


# --------------------------------------------------------------------------- full covariances
ALPHA = 0.001  # two-sided level of every interval below


def _variance_interval(truth: float, red: float) -> tuple[float, float]:
    """Interval of a variance factor estimated with ``red`` degrees of freedom: truth * chi2(r) / r."""
    lo, hi = chi2.ppf([ALPHA / 2, 1 - ALPHA / 2], red)
    return truth * lo / red, truth * hi / red


def test_vce_scales_image_covariances_correlated_noise():
    """Image noise drawn from known 2x2 covariances (correlation 0.8, varying size); the block is given
    those covariances 2x too small in sigma (4x in variance).  VCE must find the variance factor 4
    within its chi-square interval, keep the given correlations, and end with sigma0 = 1."""
    b, _ = synthetic_block(seed=7, n_strips=3, n_per_strip=7, n_points=400, sigma_px=1e-9, gnss_sigma_m=0.03,
                           imu_sigma_rad=None, n_control=0)
    rng = np.random.default_rng(21)
    n = b.n_observations
    cov = np.broadcast_to(0.25 * np.array([[1.0, 0.8], [0.8, 1.0]]), (n, 2, 2)).copy()
    cov *= rng.uniform(0.5, 2.0, n)[:, None, None]
    b.obs_pixel = b.obs_pixel + np.einsum("nij,nj->ni", np.linalg.cholesky(cov), rng.normal(size=(n, 2)))
    b.obs_cov_px2 = cov / 4.0
    b.__post_init__()
    # only the image component: the GNSS (given its true sigma) has too little redundancy in so small a
    # block for an iterated estimate to be judged by its chi-square interval
    vc = estimate_variance_components(b, split={"image": ((0, 1),)}, max_iterations=30)
    assert vc.converged and not vc.notes
    red = float(vc.result.residuals["image"].redundancy.sum())
    lo, hi = _variance_interval(4.0, red)
    f = vc.variance_factor["image[0, 1]"]
    assert lo <= f <= hi, (f, lo, hi)
    # the covariance rows were scaled (not only the sigmas): same correlation, factor f
    np.testing.assert_allclose(vc.block.obs_cov_px2, cov / 4.0 * f, rtol=1e-9)
    np.testing.assert_allclose(vc.block.obs_sigma_px, np.sqrt(np.diagonal(cov / 4.0 * f, axis1=1, axis2=2)))
    assert abs(vc.result.sigma0 - 1.0) < 0.02


def _gnss_block(seed: int):  # type: ignore[no-untyped-def]
    b, _ = synthetic_block(seed=seed, n_strips=4, n_per_strip=12, n_points=300, sigma_px=0.5, gnss_sigma_m=1e-9,
                           imu_sigma_rad=None, n_control=0)
    return b


def test_vce_gnss_split_scales_the_horizontal_and_vertical_blocks():
    """GNSS noise from block-diagonal covariances (correlated horizontal 2x2 block, separate vertical;
    code-GNSS size, so that the image block checks the GNSS with ample redundancy); given horizontal
    variances 4x too small and vertical 2x too large: the horizontal / vertical components must
    recover the factors 4 and 0.5 within their chi-square intervals and scale only their own blocks."""
    b = _gnss_block(11)
    rng = np.random.default_rng(5)
    g = len(b.gnss_station)
    cov = np.zeros((g, 3, 3))
    cov[:, :2, :2] = 0.5**2 * np.array([[1.0, 0.7], [0.7, 1.0]])
    cov[:, 2, 2] = 0.8**2
    cov *= rng.uniform(0.5, 2.0, g)[:, None, None]
    b.gnss_xyz = b.gnss_xyz + np.einsum("nij,nj->ni", np.linalg.cholesky(cov), rng.normal(size=(g, 3)))
    given = cov.copy()
    given[:, :2, :2] /= 4.0
    given[:, 2, 2] *= 2.0
    b.gnss_cov_m2 = given
    b.__post_init__()
    vc = estimate_variance_components(b, max_iterations=30)
    assert vc.converged and not vc.notes
    gr = vc.result.residuals["gnss"]
    for comp, axes, truth in (("gnss[0, 1]", [0, 1], 4.0), ("gnss[2]", [2], 0.5)):
        lo, hi = _variance_interval(truth, float(gr.redundancy[:, axes].sum()))
        assert lo <= vc.variance_factor[comp] <= hi, (comp, vc.variance_factor[comp], lo, hi)
    out = vc.block.gnss_cov_m2
    np.testing.assert_allclose(out[:, :2, :2], given[:, :2, :2] * vc.variance_factor["gnss[0, 1]"], rtol=1e-9)
    np.testing.assert_allclose(out[:, 2, 2], given[:, 2, 2] * vc.variance_factor["gnss[2]"], rtol=1e-9)
    np.testing.assert_array_equal(out[:, :2, 2], 0.0)
    assert abs(vc.result.sigma0 - 1.0) < 0.02


def test_vce_full_gnss_covariance_merges_the_split():
    """General 3x3 GNSS covariances (correlated across horizontal and vertical) given 2x too small in
    variance: the split cannot apply, the note says so, and the one factor of the whole covariance
    recovers 2 within its interval."""
    b = _gnss_block(12)
    rng = np.random.default_rng(6)
    g = len(b.gnss_station)
    A = rng.normal(size=(g, 3, 3)) * 0.5
    cov = A @ np.swapaxes(A, 1, 2) + 0.01 * np.eye(3)
    b.gnss_xyz = b.gnss_xyz + np.einsum("nij,nj->ni", np.linalg.cholesky(cov), rng.normal(size=(g, 3)))
    b.gnss_cov_m2 = cov / 2.0
    b.__post_init__()
    vc = estimate_variance_components(b, max_iterations=30)
    assert vc.converged
    assert len(vc.notes) == 1 and "gnss" in vc.notes[0] and "whole 3x3" in vc.notes[0]
    assert set(vc.variance_factor) >= {"gnss[0, 1, 2]", "image[0, 1]"}
    assert "gnss[0, 1]" not in vc.variance_factor
    lo, hi = _variance_interval(2.0, float(vc.result.residuals["gnss"].redundancy.sum()))
    assert lo <= vc.variance_factor["gnss[0, 1, 2]"] <= hi
    np.testing.assert_allclose(vc.block.gnss_cov_m2, cov / 2.0 * vc.variance_factor["gnss[0, 1, 2]"], rtol=1e-9)
