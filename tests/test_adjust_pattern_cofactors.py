"""Statistics above the dense size limit: ``Q_cc W`` kept only on the observations' block pattern
(:class:`skyrig.adjust.stats.PointPatternM`) must give the redundancy numbers, normalised residuals, point
cofactors and data snooping of the dense product ``Q_cc W`` (the reference: the dense path, whose cofactors
the point-datum tests check against a bordered dense inverse), not skip the image observations.

Before: above ``max_dense_products`` the image rows got no normalised residuals, so tie points were never
snooped (a 2,940-image chain rejected 4 observations, sigma0 0.68 instead of ~0.5).
"""

from __future__ import annotations

import functools
import importlib

import numpy as np
import pytest

from skyrig.adjust import AdjustConfig, adjust
from skyrig.adjust.config import ReliabilityOptions, Unknowns
from skyrig.adjust.stats import PointPatternM, covariance
from skyrig.adjust.synthetic import synthetic_block

from test_adjust_fixes_covariance import close_range_block

adjust_module = importlib.import_module("skyrig.adjust.adjust")


def _both(block, cfg, monkeypatch):  # type: ignore[no-untyped-def]
    dense = adjust(block, cfg)
    with monkeypatch.context() as m:
        m.setattr(adjust_module, "covariance", functools.partial(covariance, max_dense_products=1))
        small = adjust(block, cfg)
    return dense, small


def _same_statistics(dense, small):  # type: ignore[no-untyped-def]
    assert dense.covariance is not None and small.covariance is not None
    assert isinstance(small.covariance.M, PointPatternM) and isinstance(dense.covariance.M, np.ndarray)
    assert [(r.group, r.index) for r in small.rejected] == [(r.group, r.index) for r in dense.rejected]
    for rs, rd in zip(small.rejected, dense.rejected):
        assert rs.normalised_residual == pytest.approx(rd.normalised_residual, rel=1e-7)
    assert small.sigma0 == pytest.approx(dense.sigma0, rel=1e-9)
    np.testing.assert_allclose(small.covariance.Qpp, dense.covariance.Qpp, rtol=1e-8,
                               atol=1e-10 * np.abs(dense.covariance.Qpp).max())
    for g, gd in dense.residuals.items():
        gs = small.residuals[g]
        assert (gd.normalised is None) == (gs.normalised is None), g
        if gd.normalised is not None:
            # redundancy numbers lie in [0, 1] (absolute 1e-8); a normalised residual is divided by sqrt(q_vv),
            # which cancels digits where the redundancy is small: 1e-5 of a sigma is far below any test's step
            np.testing.assert_allclose(gs.redundancy, gd.redundancy, rtol=0, atol=1e-8, err_msg=g)
            np.testing.assert_allclose(gs.normalised, gd.normalised, rtol=1e-6, atol=1e-5, err_msg=g)
    for g in dense.groups:
        assert small.groups[g].redundancy == pytest.approx(dense.groups[g].redundancy, rel=1e-9), g


def test_pattern_cofactors_equal_the_dense_product_with_self_calibration_and_snooping(monkeypatch):
    """GNSS/IMU block, interior orientation free (columns shared by every image), two blunders snooped."""
    b, _ = synthetic_block(seed=5, n_strips=2, n_per_strip=6, n_points=250)
    b.obs_pixel = b.obs_pixel.copy()
    counts = np.bincount(b.obs_point, minlength=b.n_points)
    rows = np.flatnonzero(counts[b.obs_point] >= 5)[[3, 200]]  # observations of well-observed points
    b.obs_pixel[rows] += [[25.0, 0.0], [0.0, -30.0]]
    dense, small = _both(b, AdjustConfig(unknowns=Unknowns(intrinsics="free"),
                                         reliability=ReliabilityOptions(snooping=True)), monkeypatch)
    assert len(dense.rejected) >= 2
    _same_statistics(dense, small)
    # the image group has normalised residuals (not skipped) and the redundancy adds up
    assert small.residuals["image"].normalised is not None
    assert sum(g.redundancy for g in small.groups.values()) == pytest.approx(small.redundancy, rel=1e-6)


def test_pattern_cofactors_in_a_point_datum(monkeypatch):
    """Free network with inner constraints on the points: the S-transformed cross terms on the pattern."""
    b = close_range_block(24)
    dense, small = _both(b, AdjustConfig(unknowns=Unknowns(datum="free", intrinsics="free",
                                                           inner_constraints="points")), monkeypatch)
    _same_statistics(dense, small)
