"""Statistics of the online boresight (issue 35): the sigma of "online - batch" and the realism of a window's sigma."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.stats import chi2


@pytest.mark.parametrize("n_a, n_b, n_shared", [(50, 52, 50), (50, 52, 45), (40, 60, 0), (10, 30, 5)])
def test_difference_sigma_against_monte_carlo(n_a, n_b, n_shared):
    """Two least-squares estimates of one mean from overlapping samples (the online window's observations, the
    batch's): the spread of their difference over 20,000 draws against :func:`difference_sigma` with the shared
    share of the first one's observations (exact for this model: ``Cov = C_a I_s C_b``)."""
    from skyrig.pipeline.live_check import difference_sigma

    rng = np.random.default_rng(7)
    sigma = 0.3
    n_all = n_a + n_b - n_shared
    y = rng.normal(0.0, sigma, (20000, n_all))
    a = y[:, :n_a].mean(axis=1)  # the first n_a; the batch: the last n_b (overlap n_shared)
    b = y[:, n_all - n_b:].mean(axis=1)
    sd = float(difference_sigma(np.array([sigma / np.sqrt(n_a)]), np.array([sigma / np.sqrt(n_b)]),
                                n_shared / n_a)[0])
    # the sample standard deviation of 20,000 normal values is within 2 % of the true one (4 sigma)
    assert np.std(a - b) == pytest.approx(sd, rel=0.02)


def test_shared_observations():
    from skyrig.georef.observations import ImageMeasurements
    from skyrig.pipeline.live_check import shared_observations

    def m(rows):
        return ImageMeasurements(np.array([f"p{k}" for k in range(len(rows))]), np.array([r[0] for r in rows]),
                                 np.array([r[1:] for r in rows], float))

    w1 = m([("a", 1.0, 2.0), ("b", 3.0, 4.0)])
    w2 = m([("c", 5.0, 6.0), ("c", 7.0, 8.0)])
    batch = m([("a", 1.0, 2.0), ("c", 7.0, 8.0), ("d", 0.0, 0.0)])
    assert shared_observations([w1, w2], batch) == pytest.approx(0.5)
    assert shared_observations([], batch) == 0.0


@pytest.mark.slow
def test_window_sigma_realistic_over_seeds():
    """One rig adjustment of the 3K rig (two strips of 13 exposures, simulated tie points with 0.1 px noise: what
    SIFT gives on the rendered images, so sigma0 ~0.3 of the a-priori 0.5 px; GNSS/IMU noise as the simulator
    draws it; reference heights with 2 m noise) over 5 seeds: the boresight errors against the injected truth in
    units of the window's sigma (sigma0-scaled covariance) have an RMS within the chi-square 99 % bounds of the
    15 heads' angles (each head's three angles counted as one degree of freedom: they share the seed's GNSS/IMU
    noise)."""
    from skyrig.calibrate import online_boresight as ob
    from skyrig.geometry.rotations import rotvec_from_matrix
    from skyrig.georef.observations import GroundPoints, ImageMeasurements
    from skyrig.pipeline.live_check import INJECTED_BORESIGHT_DEG
    from skyrig.simulate.scenarios import build_survey, scenario_spec

    z = []
    for seed in range(1, 6):
        s = scenario_spec("3k", "ci", seed)
        err = replace(s.errors, tie_points=600, measurement_sigma_px=0.1,
                      boresight_rpy_rad={h: tuple(np.radians(v)) for h, v in INJECTED_BORESIGHT_DEG.items()})
        s = replace(s, errors=err, flights=(replace(s.flights[0], area=(-200.0, -1200.0, 200.0, 1200.0)),),
                    scene_extent=(-1800.0, -2700.0, 1800.0, 2700.0))
        sv = build_survey(s)
        tp = sv.tie_points
        rng = np.random.default_rng(100 + seed)
        xyz = np.asarray(tp["xyz"], float).copy()
        xyz[:, 2] += rng.normal(0.0, 2.0, len(xyz))
        m = ImageMeasurements(np.asarray(tp["point"]).astype(str), np.asarray(tp["image"]).astype(str),
                              np.asarray(tp["pixel"], float))
        gp = GroundPoints(np.asarray(tp["name"]).astype(str), xyz, sv.frame)
        w = ob.adjust_window(sv.trajectory_recorded, sv.rig_recorded, sv.events_recorded, m, gp, height_sigma_m=2.0)
        assert 0.2 < w.sigma0 < 0.5
        for h in sv.rig_recorded:
            truth = rotvec_from_matrix(h.boresight.T @ sv.rig_true.heads[h.name].boresight)
            z.extend((w.correction[h.name] - truth) / np.sqrt(np.diag(w.covariance[h.name])))
    z = np.asarray(z)
    dof = 15
    lo, hi = np.sqrt(chi2.ppf(0.005, dof) / dof), np.sqrt(chi2.ppf(0.995, dof) / dof)
    rms = float(np.sqrt(np.mean(z**2)))
    assert lo < rms < hi, (rms, lo, hi)
    assert abs(float(z.mean())) < 3.0 / np.sqrt(dof)  # no bias beyond 3 standard errors
