"""Variance component estimation on a seeded synthetic block: the estimated sigmas recover the
simulation's true noise (independent answer: the sigma the simulator drew with), within a band
derived from each component's redundancy."""

from __future__ import annotations

import numpy as np

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
