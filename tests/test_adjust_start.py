"""``adjust(block, config, start=...)``: starting values apart from the prior centres of the weighted groups.

The independent answer is the linear-Gaussian combination of a measurement and a prior on one parameter: with
the focal length estimated from the data alone (``f_d``, a-priori variance ``q_d`` from the free adjustment's
cofactor matrix) and a prior ``f_0 +- s_p`` on it, the posterior is ``(f_d / q_d + f_0 / s_p^2) / (1 / q_d +
1 / s_p^2)`` whatever the other unknowns do (their correlation with the focal length is inside ``q_d``).  The
solution must be that value whether the solve starts at the prior or elsewhere; a prior that moved with the
starting value (the behaviour this option exists to avoid) lands on a different value.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skyrig.adjust import AdjustConfig, adjust
from skyrig.adjust.config import Unknowns
from skyrig.adjust.synthetic import synthetic_block
from skyrig.camera.frame import FrameCamera


def _block():
    nominal = FrameCamera.from_pixels("cam", 3000, 2000, 2500.0, 1499.5, 999.5, pixel_size_mm=0.004)
    truth = nominal.with_(focal_mm=nominal.focal_mm * 1.004)  # 10 px off
    return synthetic_block(seed=5, n_strips=3, n_per_strip=6, n_points=400, relief_m=80.0, camera=nominal,
                           true_camera=truth, gnss_sigma_m=0.05, imu_sigma_rad=None, n_control=6)[0], nominal


def _focal_px(res):
    cam = res.block.cameras[0]
    return cam.focal_mm / cam.pixel_size_mm


def test_start_moves_the_solve_not_the_prior():
    b, nominal = _block()
    pix = nominal.pixel_size_mm
    free = adjust(b, AdjustConfig(unknowns=Unknowns(intrinsics="free", intrinsic_names=("focal_mm",))))
    f_d = _focal_px(free)
    q_d = (free.sigma_reduced()[("intrinsics", "cam", "focal_mm")] / free.sigma0 / pix) ** 2
    s_p = float(np.sqrt(q_d))  # px: the data's own sigma, so the prior pulls halfway
    f_0 = nominal.focal_mm / pix
    expected = (f_d / q_d + f_0 / s_p ** 2) / (1.0 / q_d + 1.0 / s_p ** 2)
    s_post = 1.0 / np.sqrt(1.0 / q_d + 1.0 / s_p ** 2)
    cfg = AdjustConfig(unknowns=Unknowns(intrinsics="weighted", intrinsic_names=("focal_mm",),
                                         intrinsic_sigma=(("focal_mm", s_p * pix),)))
    assert abs(f_d - f_0) > 3 * s_post  # the data and the prior disagree: the check below can fail
    plain = adjust(b, cfg)
    far = nominal.with_(focal_mm=nominal.focal_mm * 1.01)  # 25 px beyond the prior centre
    started = adjust(b, cfg, start=replace(b, cameras=[far]))
    for res in (plain, started):
        assert res.ok, res.failures
        assert abs(_focal_px(res) - expected) < 0.05 * s_post, (_focal_px(res), expected, s_post)
    # the prior centred on the starting value instead would give another answer
    moved = adjust(replace(b, cameras=[far]), cfg)
    assert abs(_focal_px(moved) - expected) > 1.0 * s_post, (_focal_px(moved), expected, s_post)


def test_start_that_does_not_correspond_is_refused():
    b, nominal = _block()
    other, _ = synthetic_block(seed=5, n_strips=2, n_per_strip=6, n_points=400, camera=nominal)
    with pytest.raises(ValueError, match="start: its R unknowns do not correspond"):
        adjust(b, AdjustConfig(), start=other)
    bad = replace(b, point_xyz=np.where(np.arange(len(b.point_xyz))[:, None] == 0, np.nan, b.point_xyz))
    with pytest.raises(ValueError, match="non-finite"):
        adjust(b, AdjustConfig(), start=bad)
