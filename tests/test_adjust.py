"""Bundle adjustment on seeded synthetic blocks: estimates against the simulation's truth.

Independent answer: the truth of the simulation (skyrig.adjust.synthetic draws Gaussian noise of known
sigma).  Tolerances come from the adjustment's own predicted precision: normalised errors
(estimate - truth) / sigma must be consistent with N(0, 1) (sample standard deviation within the band
of a chi-square with the number of errors, and no error beyond 5 sigma).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from skyrig.adjust import AdjustConfig, BlockError, DatumDefectError, adjust
from skyrig.adjust.config import ReliabilityOptions, SolverOptions, StatisticsOptions, Unknowns
from skyrig.adjust.synthetic import synthetic_block


def _std_band(n: int) -> tuple[float, float]:
    # sample std of n N(0,1) values: 1 +- 4/sqrt(2n) covers it with overwhelming probability
    h = 4.0 / np.sqrt(2.0 * n)
    return 1.0 - h, 1.0 + h


def _assert_normal(e: np.ndarray, what: str, n_eff: int | None = None) -> None:
    """``n_eff``: effective number of independent values when the errors are correlated (points of one
    block share the errors of the orientations that carry them)."""
    e = e[np.isfinite(e)]
    lo, hi = _std_band(n_eff or e.size)
    s = float(np.sqrt(np.mean(e**2)))
    assert lo < s < hi, f"{what}: RMS of normalised errors {s:.3f} outside [{lo:.3f}, {hi:.3f}] (n={e.size})"
    assert np.abs(e).max() < 5.0, f"{what}: a normalised error of {np.abs(e).max():.2f}"


@pytest.fixture(scope="module")
def block_truth():
    return synthetic_block(seed=3, n_strips=3, n_per_strip=7, n_points=400)


@pytest.fixture(scope="module")
def result(block_truth):
    return adjust(block_truth[0])


def test_converges_and_recovers_truth_within_predicted_sigma(block_truth, result):
    b, truth = block_truth
    assert result.info.converged
    assert result.info.final_cost < 1e-2 * result.info.initial_cost
    # sigma0 of a correct model: chi-square with r degrees of freedom
    r = result.redundancy
    assert abs(result.sigma0 - 1.0) < 4.0 / np.sqrt(2 * r)
    _assert_normal((result.block.point_xyz - truth.point_xyz) / result.point_sigma, "points", 6 * b.n_stations)
    ps = result.pose_sigma
    _assert_normal((result.block.station_centre - truth.station_centre) / ps[:, :3], "centres")
    # rotations: error rotation vector in the station frame (right perturbation, as the unknowns)
    from skyrig.geometry.rotations import rotvec_from_matrix

    dth = rotvec_from_matrix(np.swapaxes(truth.station_rotation, 1, 2) @ result.block.station_rotation)
    _assert_normal(dth / ps[:, 3:], "rotations")


def test_redundancy_numbers_sum_to_the_redundancy(result):
    total = sum(float(np.sum(g.redundancy)) for g in result.residuals.values())
    assert total == pytest.approx(result.redundancy, rel=1e-6)
    red = result.residuals["image"].redundancy
    assert np.all((red > -1e-9) & (red < 1 + 1e-9))
    # normalised residuals of a blunder-free block are N(0, 1)
    _assert_normal(result.residuals["image"].normalised.ravel(), "normalised image residuals")


def test_variance_components_near_one(result):
    for name in ("image", "gnss", "imu"):
        g = result.groups[name]
        assert abs(g.sigma0 - 1.0) < 5.0 / np.sqrt(2 * g.redundancy), (name, g.sigma0, g.redundancy)


def test_data_snooping_finds_injected_blunders_without_false_rejections(block_truth):
    b = block_truth[0].copy()
    rng = np.random.default_rng(11)
    # a blunder can only be localised where the point has enough rays (with 2 rays both residuals are equal)
    rays = np.bincount(b.obs_point, minlength=b.n_points)[b.obs_point]
    cand = np.flatnonzero(rays >= 4)
    cand = cand[np.unique(b.obs_point[cand], return_index=True)[1]]  # one blunder per point
    bad = rng.choice(cand, 5, replace=False)
    b.obs_pixel[bad] += rng.choice([-1, 1], (5, 2)) * rng.uniform(6, 10, (5, 2))  # 12-20 sigma
    res = adjust(b, AdjustConfig(reliability=ReliabilityOptions(snooping=True)))
    found = sorted(r.index for r in res.rejected)
    assert found == sorted(bad.tolist())
    assert all(r.group == "image" for r in res.rejected)
    assert abs(res.sigma0 - 1.0) < 0.1


def test_robust_huber_downweights_blunders(block_truth):
    b, truth = block_truth[0].copy(), block_truth[1]
    rng = np.random.default_rng(12)
    bad = rng.choice(b.n_observations, 10, replace=False)
    b.obs_pixel[bad] += 40.0
    plain = adjust(b, AdjustConfig(statistics=StatisticsOptions(compute=False)))
    robust = adjust(b, AdjustConfig(solver=SolverOptions(robust="huber"),
                                    statistics=StatisticsOptions(compute=False)))
    err = lambda r: np.sqrt(np.mean((r.block.point_xyz - truth.point_xyz) ** 2))  # noqa: E731
    assert err(robust) < 0.5 * err(plain)
    assert np.all(robust.residuals["image"].weight[bad] < 0.2)


def test_free_network_without_datum_is_reported_in_words(block_truth):
    b = block_truth[0]
    free = dataclasses.replace(b, gnss_station=None, gnss_xyz=None, gnss_sigma=1.0, imu_station=None,
                               imu_rotation=None, imu_sigma_rad=1.0, control_point=None, control_xyz=None,
                               control_sigma=1.0, control_check=None)
    with pytest.raises(DatumDefectError) as e:
        adjust(free)
    msg = str(e.value)
    assert "rank deficient by 7" in msg
    for word in ("translation along X", "rotation about Z", "scale"):
        assert word in msg
    # inner constraints: converges, same residuals as any datum (sigma0 ~ 1), redundancy + 7
    res = adjust(free, AdjustConfig(unknowns=Unknowns(datum="free")))
    assert res.redundancy == res.n_observations - res.n_unknowns + 7
    assert abs(res.sigma0 - 1.0) < 4.0 / np.sqrt(2 * res.redundancy)


def test_lever_arm_boresight_and_datum_shift_recovered():
    lever = np.array([0.3, -0.2, -1.5])
    bore = np.array([[2e-3, -1.5e-3, 3e-3]])
    shift = np.array([0.4, -0.3, 0.0])
    b, truth = synthetic_block(seed=5, n_strips=3, n_per_strip=7, n_points=400, lever_arm=lever,
                               head_boresight=bore, datum_shift=shift, n_control=6, imu_sigma_rad=5e-5,
                               gnss_sigma_m=0.03)
    cfg = AdjustConfig(unknowns=Unknowns(lever_arm="free", boresight="free", datum_shift="free"))
    # lever arm z (body down) and the shift's Z act almost identically for near-level flight: the
    # adjustment must say so in words instead of returning them as if they were determined
    res = adjust(b, cfg)
    assert any("lever_arm antenna z" in w and "datum_shift gnss Z" in w for w in res.warnings), res.warnings
    b2, _ = synthetic_block(seed=5, n_strips=3, n_per_strip=7, n_points=400, lever_arm=lever,
                            head_boresight=bore, n_control=6, imu_sigma_rad=5e-5, gnss_sigma_m=0.03)
    res2 = adjust(b2, AdjustConfig(unknowns=Unknowns(lever_arm="free", boresight="free")))
    sig2 = res2.sigma_reduced()
    sl = np.array([sig2[("lever_arm", "antenna", c)] for c in "xyz"])
    sb = np.array([sig2[("boresight", "nadir", c)] for c in ("rx", "ry", "rz")])
    assert np.all(np.abs(res2.block.lever_arm - lever) < 4.5 * sl), (res2.block.lever_arm, sl)
    assert np.all(np.abs(res2.block.head_boresight[0] - bore[0]) < 4.5 * sb), (res2.block.head_boresight, sb)
    assert np.all(sl < 0.1) and np.all(sb < 5e-4)


def test_self_calibration_of_focal_and_principal_point():
    from skyrig.adjust.synthetic import _default_camera

    given = _default_camera()
    true = given.with_(focal_mm=given.focal_mm * 1.004, ppx_mm=given.ppx_mm + 0.02, ppy_mm=given.ppy_mm - 0.015)
    b, truth = synthetic_block(seed=6, n_strips=3, n_per_strip=7, n_points=500, camera=given, true_camera=true,
                               relief_m=80.0, n_control=6)
    cfg = AdjustConfig(unknowns=Unknowns(intrinsics="free", intrinsic_names=("focal_mm", "ppx_mm", "ppy_mm")))
    res = adjust(b, cfg)
    sig = res.sigma_reduced()
    est = res.block.cameras[0]
    for name, t in (("focal_mm", true.focal_mm), ("ppx_mm", true.ppx_mm), ("ppy_mm", true.ppy_mm)):
        s = sig[("intrinsics", "cam", name)]
        assert abs(getattr(est, name) - t) < 4.5 * s, (name, getattr(est, name), t, s)
    # without self-calibration the wrong focal length leaves a model error: sigma0 grows
    assert adjust(b).sigma0 > 1.3 * res.sigma0


def test_rig_block_with_lever_arms_and_mountings():
    from skyrig.rig.presets import midas

    rig = midas()
    b, truth = synthetic_block(seed=7, n_strips=2, n_per_strip=5, n_points=600, rig=rig, height_m=500.0,
                               n_control=5)
    assert len(b.head_name) == 5 and b.n_images == 5 * b.n_stations
    res = adjust(b)
    assert res.info.converged
    # 600 points hang on 10 stations: their errors are correlated through the 60 pose unknowns
    _assert_normal((res.block.point_xyz - truth.point_xyz) / res.point_sigma, "rig points", n_eff=6 * b.n_stations)


@pytest.mark.parametrize(
    "change, needle",
    [
        (lambda b: b.obs_image.__setitem__(3, 10_000), "names an unknown image"),
        (lambda b: b.obs_pixel.__setitem__((5, 1), np.nan), "obs_pixel[5] is not finite"),
        (lambda b: b.obs_sigma_px.__setitem__((2, 0), -1.0), "obs_sigma_px[2] must be > 0"),
    ],
)
def test_bad_blocks_give_clear_errors(block_truth, change, needle):
    b = block_truth[0].copy()
    change(b)
    with pytest.raises(BlockError, match=needle.replace("[", r"\[").replace("]", r"\]")):
        adjust(b)


def test_point_seen_once_is_an_error(block_truth):
    b = block_truth[0].copy()
    p = b.obs_point[0]
    rows = np.flatnonzero(b.obs_point == p)
    keep = np.ones(b.n_observations, bool)
    keep[rows[1:]] = False
    b2 = dataclasses.replace(b, obs_image=b.obs_image[keep], obs_point=b.obs_point[keep],
                             obs_pixel=b.obs_pixel[keep], obs_sigma_px=b.obs_sigma_px[keep])
    if p in set(b.control_point.tolist()):
        pytest.skip("control point")
    with pytest.raises(BlockError, match="seen in 1 image"):
        adjust(b2)
