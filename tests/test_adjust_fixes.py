"""Regression tests for the adjustment defects of issues 12 and 13.

Independent answers: seeded simulation truth (the injected boresight, the injected pixel noise), the
chi-square distribution of sigma0^2 r for a correct redundancy r = 2n - 6 of a space resection, and
what a user wrote into the block file (groups freed with ``skyrig block --free``).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.stats import chi2

from skyrig.adjust import AdjustConfig, Block, BlockError, adjust
from skyrig.adjust.config import ReliabilityOptions, SolverOptions, Unknowns
from skyrig.adjust.presets import apply_preset, merge_preset
from skyrig.adjust.synthetic import synthetic_block
from skyrig.camera.frame import FrameCamera
from skyrig.cli import main
from skyrig.geometry.rotations import matrix_from_rotvec
from skyrig.io.block_file import read_block, write_block


# ------------------------------------------------------------------ 1 + 2: skyrig block --free, presets merge
def _demo(tmp_path):  # type: ignore[no-untyped-def]
    from test_block_cli import _project  # the demo flight with exact measurements of its ground points

    return _project(tmp_path)


def test_block_free_datum_shift_and_preset_keeps_the_freed_groups(tmp_path):
    p, _, meas = _demo(tmp_path)
    run = CliRunner()
    blk = tmp_path / "blk" / "block.json"
    r = run.invoke(main, ["block", "--trajectory", str(p.trajectory), "--events", str(p.events), "--rig", str(p.rig),
                          "--measurements", str(meas), "--control", str(p.check_points), "--free",
                          "datum-shift,lever-arm", "-o", str(blk)])
    assert r.exit_code == 0, r.output  # was: TypeError, AdjustConfig() got multiple values for 'datum_shift'
    bf = read_block(blk)
    assert bf.config.unknowns.datum_shift == "free" and bf.config.unknowns.lever_arm == "free"
    assert {"unknowns.datum_shift", "unknowns.lever_arm"} <= bf.adjustment_keys
    # a preset merges with the section: the lever arm stays free (it used to be wiped to "fixed")
    r = run.invoke(main, ["adjust", str(blk), "--preset", "dg-control", "-o", str(tmp_path / "dg")])
    assert r.exit_code == 0, r.output
    used = read_block(tmp_path / "dg" / "adjusted.json").config
    assert used.unknowns.lever_arm == "free" and used.unknowns.poses == "fixed" and used.unknowns.datum_shift == "free"
    # an explicit conflict is stated in words (stderr and the report), naming the field and both values
    r = run.invoke(main, ["adjust", str(blk), "--preset", "refine-eo-check", "-o", str(tmp_path / "ref")])
    assert r.exit_code == 0, r.output
    text = r.output  # stdout and stderr as a terminal shows them
    assert "preset 'refine-eo-check' sets unknowns.datum_shift = 'fixed'" in text and "says 'free'" in text
    used = read_block(tmp_path / "ref" / "adjusted.json").config
    assert used.unknowns.lever_arm == "free" and used.unknowns.datum_shift == "fixed"
    rep = json.loads((tmp_path / "ref" / "report.json").read_text())
    assert any("datum_shift" in w for w in rep["warnings"])


def test_merge_preset_rules():
    base = AdjustConfig(unknowns=Unknowns(boresight="free", lever_arm="weighted", datum_shift="free"),
                        reliability=ReliabilityOptions(snooping=False))
    cfg, conflicts = merge_preset("ba-eo-control", base, {"unknowns.boresight", "unknowns.lever_arm",
                                                          "reliability.snooping", "unknowns.datum_shift"})
    # the block's groups and its explicit snooping survive; the variant's fields are the preset's
    u = cfg.unknowns
    assert (u.boresight, u.lever_arm, cfg.reliability.snooping, u.poses, u.datum_shift) == (
        "free", "weighted", False, "free", "free")
    assert conflicts == []
    cfg, conflicts = merge_preset("ba-eo-control", AdjustConfig())  # nothing explicit: the preset's defaults
    assert cfg.reliability.snooping and cfg.unknowns.datum_shift == "free"
    cfg, _ = merge_preset("ba-eo-control", AdjustConfig(), has_gnss=False)
    assert cfg.unknowns.datum_shift == "fixed"
    cfg, conflicts = merge_preset("dg-control", AdjustConfig(unknowns=Unknowns(poses="weighted")), {"unknowns.poses"})
    assert cfg.unknowns.poses == "fixed" and len(conflicts) == 1
    assert "unknowns.poses" in conflicts[0] and "'weighted'" in conflicts[0]
    b, _ = synthetic_block(seed=1, n_points=60)
    _, cfg = apply_preset(b, "refine-eo-check", AdjustConfig(unknowns=Unknowns(intrinsics="free")),
                          {"unknowns.intrinsics"})
    assert cfg.unknowns.intrinsics == "free" and cfg.unknowns.datum_shift == "fixed"


# ------------------------------------------------------------------ 3: snooping that hides a model error
@pytest.fixture(scope="module")
def boresight_block():  # type: ignore[no-untyped-def]
    # 0.5 deg unmodelled boresight; IMU sigma 2e-4 rad: the IMU attitudes are 40-50 sigma off
    return synthetic_block(seed=3, n_strips=2, n_per_strip=8, n_points=300, n_control=6,
                           head_boresight=np.array([[0.01, -0.008, 0.005]]))


def test_snooping_reports_an_unmodelled_boresight_as_a_model_error(boresight_block):
    b, tr = boresight_block
    res = adjust(b, AdjustConfig(reliability=ReliabilityOptions(snooping=True),
                                 unknowns=Unknowns(datum_shift="free")))
    assert not res.ok
    msg = " ".join(res.failures)
    n_imu = sum(r.group == "imu" for r in res.rejected)
    assert f"rejected {n_imu} of {len(b.imu_station)} IMU observations" in msg
    assert "model is probably wrong" in msg and "boresight" in msg and "--free boresight" in msg
    assert len(res.rejected) < 10  # stopped early instead of running to the cap
    # the same block with the boresight free: no rejection, the truth within 3 sigma, a clean result
    res = adjust(b, AdjustConfig(reliability=ReliabilityOptions(snooping=True),
                                 unknowns=Unknowns(datum_shift="free", boresight="free")))
    assert res.ok and not res.rejected, res.failures
    sig = res.sigma_reduced()
    est = res.block.head_boresight[0]
    s = np.array([sig[("boresight", "nadir", c)] for c in ("rx", "ry", "rz")])
    assert np.all(np.abs(est - tr.head_boresight[0]) < 3 * s)


def test_snooping_at_its_cap_is_a_failure(boresight_block):
    b, _ = boresight_block
    res = adjust(b, AdjustConfig(reliability=ReliabilityOptions(snooping=True, max_rejections=6, max_share=0.0,
                                                                max_group_share=1.0),
                                 unknowns=Unknowns(datum_shift="free")))
    assert len(res.rejected) == 6 and not res.ok
    msg = " ".join(res.failures)
    assert "cap of 6 rejections" in msg and "IMU" in msg and "still above the critical value" in msg


# ------------------------------------------------------------------ 5: fixed points are not observations
def _resection(seed: int, n: int, sigma_px: float = 0.5) -> tuple[Block, np.ndarray]:
    rng = np.random.default_rng(seed)
    cam = FrameCamera.from_pixels("cam", 3000, 2000, 2500.0, 1499.5, 999.5, pixel_size_mm=0.004)
    R = matrix_from_rotvec(rng.normal(0, 0.02, 3))  # world_from_camera: looking down (camera -z)
    C = np.array([10.0, -5.0, 300.0])
    X = np.column_stack([rng.uniform(-150, 150, n), rng.uniform(-100, 100, n), rng.uniform(-20, 20, n)])
    px = cam.project_pixels((X - C) @ R) + rng.normal(0, sigma_px, (n, 2))
    b = Block(cameras=[cam], station_name=["s0"], station_rotation=(R @ matrix_from_rotvec(rng.normal(0, 0.01, 3)))[None],
              station_centre=(C + rng.normal(0, 2.0, 3))[None], image_name=["img0"], image_station=[0],
              image_camera=[0], point_name=[f"p{k}" for k in range(n)], point_xyz=X, obs_image=np.zeros(n, int),
              obs_point=np.arange(n), obs_pixel=px, obs_sigma_px=sigma_px, control_point=np.arange(n),
              control_xyz=X, control_sigma=0.01)
    return b, C


def test_space_resection_with_fixed_points_has_redundancy_2n_minus_6():
    n, seeds = 12, range(20)
    chi = 0.0
    for seed in seeds:
        b, C = _resection(seed, n)
        res = adjust(b, AdjustConfig(unknowns=Unknowns(points="fixed")))
        assert res.n_unknowns == 6 and res.n_observations == 2 * n  # the control rows are constants here
        assert res.redundancy == 2 * n - 6  # was 5n - 6
        assert res.ok
        chi += res.sigma0**2 * res.redundancy
        assert np.linalg.norm(res.block.station_centre[0] - C) < 1.0
        assert res.groups["control"].n_rows == 0
    # sum over seeds of sigma0^2 r (sigma_px is the true noise): chi-square with 20 (2n - 6) dof
    dof = len(seeds) * (2 * n - 6)
    lo, hi = chi2.ppf([0.0005, 0.9995], dof)
    assert lo < chi < hi, (chi, lo, hi)


def test_exactly_determined_resection_fails_for_lack_of_redundancy():
    b, _ = _resection(0, 3)
    res = adjust(b, AdjustConfig(unknowns=Unknowns(points="fixed")))
    assert res.redundancy == 0 and not res.ok
    assert any("no redundancy" in f for f in res.failures)


# ------------------------------------------------------------------ 6: a point behind a camera
def test_point_starting_behind_a_camera_is_left_out_and_named():
    b, _ = synthetic_block(seed=1, n_points=80)
    p = int(b.obs_point[0])
    b.point_xyz[p, 2] = b.station_centre[:, 2].max() + 100.0  # above the cameras: behind every one of them
    res = adjust(b, AdjustConfig())  # was: numpy LinAlgError: Singular matrix
    assert res.ok
    name = str(b.point_name[p])
    assert any(f"point {name} in image" in w and "behind a camera" in w for w in res.warnings)
    rows = np.flatnonzero(b.obs_point == p)
    assert sorted(r.index for r in res.rejected) == rows.tolist()
    assert np.all(res.residuals["image"].weight[rows] == 0)


def test_undetermined_point_is_named_without_numpy_reprs():
    b, _ = synthetic_block(seed=1, n_points=80)
    p = int(b.obs_point[0])
    rows = np.flatnonzero(b.obs_point == p)
    keep = np.ones(b.n_observations, bool)
    keep[rows[1:]] = False  # one ray left
    b2 = b.copy()
    b2.obs_image, b2.obs_point, b2.obs_pixel = b.obs_image[keep], b.obs_point[keep], b.obs_pixel[keep]
    b2.obs_sigma_px = b.obs_sigma_px[keep]
    b2.__post_init__()
    with pytest.raises(BlockError, match=f"^point '{b.point_name[p]}' is seen in 1 image"):
        adjust(b2, AdjustConfig())


# ------------------------------------------------------------------ 7: a failed run exits non-zero
def test_adjust_cli_exits_non_zero_on_failure_and_keep_failed_writes(tmp_path):
    b, _ = synthetic_block(seed=2, n_points=120)
    write_block(tmp_path / "nc" / "block.json", b, AdjustConfig(solver=SolverOptions(max_iterations=1)))
    run = CliRunner()
    r = run.invoke(main, ["adjust", str(tmp_path / "nc" / "block.json"), "-o", str(tmp_path / "out")])
    assert r.exit_code != 0
    assert "did not converge" in r.output and "maximum number of iterations" in r.output
    assert not (tmp_path / "out" / "report.json").exists()
    r = run.invoke(main, ["adjust", str(tmp_path / "nc" / "block.json"), "--keep-failed", "-o", str(tmp_path / "kf")])
    assert r.exit_code != 0 and "did not converge" in r.output
    rep = json.loads((tmp_path / "kf" / "report.json").read_text())
    assert any("FAILED" in w and "did not converge" in w for w in rep["warnings"])
    # no redundancy: an exactly determined resection
    rb, _ = _resection(0, 3)
    write_block(tmp_path / "r3" / "block.json", rb, AdjustConfig(unknowns=Unknowns(points="fixed")))
    r = run.invoke(main, ["adjust", str(tmp_path / "r3" / "block.json"), "-o", str(tmp_path / "o3")])
    assert r.exit_code != 0 and "no redundancy" in r.output
    # a good run still exits 0
    write_block(tmp_path / "ok" / "block.json", b)
    r = run.invoke(main, ["adjust", str(tmp_path / "ok" / "block.json"), "-o", str(tmp_path / "ok_out")])
    assert r.exit_code == 0, r.output


def test_single_image_with_points_it_cannot_intersect_is_refused():
    b, _ = _resection(1, 10)
    res = adjust(b, AdjustConfig())  # free points, weighted control: a resection with weighted control is fine
    assert res.ok and res.redundancy == 2 * 10 + 3 * 10 - 6 - 3 * 10
    b.control_check[:2] = True  # two points left with one ray each and no control
    with pytest.raises(BlockError, match="^point 'p0' is seen in 1 image"):
        adjust(b, AdjustConfig())
