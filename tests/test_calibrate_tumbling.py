"""``skyrig calibrate tumbling-head`` (paper 000's laboratory recipe) on the simulated laboratory of
``bench/tumbling_lab.py``: 8 positions x 3 circles at 320 px, judged against the simulator's true curve and true
per-circle offsets.

Tolerances come from the precision the recipe states (each image's fit sigma, the curve's standard errors in the rig
file, the mechanism repeatability's standard error), checked against the truth with chi-square / family-wise bounds.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.stats import chi2

from skyrig.cli import main
from skyrig.errors import SkyrigError
from skyrig.io.rig_file import read_calibrated_rig
from skyrig.rig.boresight_curve import AXES

from _tumbling_lab import tumbling_lab





@pytest.fixture(scope="module")
def lab_run(tmp_path_factory):
    tl = tumbling_lab()
    lab = tl.build_lab(positions=8, circles=3, width=320, distance_m=3.0, seed=1)
    images, ref = tl.render_lab(lab)
    d = tmp_path_factory.mktemp("tumbling_lab")
    paths = tl.write_lab(lab, images, ref, d)
    out = d / "calibrated_rig.yaml"
    r = CliRunner().invoke(main, ["calibrate", "tumbling-head", "--images", str(paths["images"]), "--rig",
                                  str(paths["rig"]), "--positions", str(paths["positions"]), "--plane-distance-m", "3.0",
                                  "--flight", "simulated lab", "-o", str(out)])
    assert r.exit_code == 0, r.output
    return tl, lab, paths, out, r.output


@pytest.fixture(scope="module")
def lab_files(tmp_path_factory):
    """The lab's rig and positions files without rendering (for the input checks)."""
    tl = tumbling_lab()
    lab = tl.build_lab(positions=8, circles=3, width=320, distance_m=3.0, seed=1)
    d = tmp_path_factory.mktemp("tumbling_files")
    return lab, tl.write_lab(lab, {}, np.zeros((4, 4, 3), np.uint8), d)


@pytest.mark.slow
def test_curve_within_predicted_precision(lab_run):
    tl, lab, _, out, _ = lab_run
    rig, cal = read_calibrated_rig(out)
    curve = rig.head("oblique").curve
    assert curve is not None and curve.beta_rad.size == 8 and np.all(curve.count == 3)
    rep = json.loads(out.with_suffix(".json").read_text())
    meas = np.radians(np.array([[m[f"{a}_mdeg"] for a in AXES] for m in rep["measurements"]]) / 1000).reshape(3, 8, 3)
    fit = np.radians(np.array([[m[f"{a}_sigma_mdeg"] for a in AXES] for m in rep["measurements"]]) / 1000)
    fit = fit.reshape(3, 8, 3)
    # every image's measured offset against the simulator's true one (curve + that circle's repeat error), in units
    # of the sigma the recipe states for it: chi-square with 24 degrees of freedom per axis (99.9 % bounds)
    z_img = (meas - lab.true_rad) / fit
    rms_z = np.sqrt(np.mean(z_img ** 2, axis=(0, 1)))
    print("per-image error / stated sigma, RMS per axis", rms_z)
    assert np.all(rms_z > np.sqrt(chi2.ppf(0.0005, 24) / 24)) and np.all(rms_z < np.sqrt(chi2.ppf(0.9995, 24) / 24))
    # the same with the stated correlations between the axes (the tilt across the view and the yaw, |r| ~ 0.95 in
    # one image): Mahalanobis square sum over the 24 images, chi-square with 72 degrees of freedom; with those
    # correlations wrong (e.g. absent in truth) it would be several times larger
    pairs = ((0, 1), (0, 2), (1, 2))
    r_img = np.array([[m[f"r_{AXES[i]}_{AXES[j]}"] for i, j in pairs] for m in rep["measurements"]]).reshape(3, 8, 3)
    corr = np.broadcast_to(np.eye(3), (3, 8, 3, 3)).copy()
    for p_, (i, j) in enumerate(pairs):
        corr[..., i, j] = corr[..., j, i] = r_img[..., p_]
    d2 = float(np.einsum("cki,ckij,ckj->", z_img, np.linalg.inv(corr), z_img))
    print("per-image Mahalanobis square sum", d2, "of 72 dof; largest |r|", np.abs(r_img).max())
    assert chi2.ppf(0.0005, 72) < d2 < chi2.ppf(0.9995, 72)
    # the mean curve against the true curve in units of the standard errors written into the rig file
    blk = cal.heads["oblique"].actuator
    assert blk is not None and len(blk.parameters) == 24
    se = np.radians(blk.sigma.reshape(8, 3))
    err = curve.corrections_rad - lab.true_curve(curve.beta_rad)
    z = err / se
    print("curve error (mdeg) rms", 1000 * np.degrees(np.sqrt(np.mean(err ** 2, axis=0))), "stated SE median",
          1000 * np.degrees(np.median(se, axis=0)), "max |z|", np.abs(z).max(axis=0))
    assert np.all(np.abs(z) < np.sqrt(chi2.ppf(1 - 0.01 / 24, 1)))  # 24 draws, 1 % family-wise
    # with the rig file's correlations (block diagonal, 3 x 3 per position): at 8 positions the Fourier series the
    # repeating error's share is estimated with (order 1, 5 residuals per axis) does not hold the curve's harmonics
    # 2 and 3, so the share leans to its bound 1 and the covariance is an upper bound: only the upper chi-square
    # bound (tests/test_calibrate_tumbling_normalised.py checks both on labs with enough positions)
    share = np.array([rep["curve_statement"]["lookup"]["repeat_share"][a] for a in AXES])
    print("repeating share of the fit variance", share)
    cov = np.radians(1.0) ** 2 * blk.sigma[:, None] * blk.correlation * blk.sigma[None]
    assert np.all(cov[np.abs(np.subtract.outer(np.arange(24) // 3, np.arange(24) // 3)) > 0] == 0)
    e = err.reshape(-1)
    d2 = float(e @ np.linalg.solve(cov, e))
    print("mean curve Mahalanobis square", d2, "of 24 dof")
    assert d2 < chi2.ppf(0.999, 24)
    # the stated SE is not so loose that it hides the curve: the curve (amplitude 50-130 mdeg) is > 8 SE
    amp = np.abs(lab.true_curve(curve.beta_rad)).max(axis=0)
    assert np.all(amp > 8 * np.median(se, axis=0))
    # the mechanism's repeatability (measurement noise removed) against the injected one: its variance within
    # 3.5 of its stated standard errors (the stated SE from the chi-square spread, K (C - 1) = 16 dof)
    mech = np.radians(np.array([rep["table2_2sigma"][a]["mechanism_std_mdeg"] for a in AXES]) / 2000)
    mech_se = np.radians(np.array([rep["table2_2sigma"][a]["mechanism_std_se_mdeg"] for a in AXES]) / 2000)
    print("mechanism repeatability (mdeg)", 1000 * np.degrees(mech), "+-", 1000 * np.degrees(mech_se), "injected",
          1000 * np.degrees(lab.repeat_sigma_rad))
    assert np.all(np.abs(mech - lab.repeat_sigma_rad) < 3.5 * mech_se)
    # the actuator block: values = mean curve in degrees, sigma = sqrt(pooled^2 / C + share x the position's fit
    # variance), the share as the report states it, within [0, 1]
    np.testing.assert_allclose(blk.values.reshape(8, 3), np.degrees(curve.corrections_rad), atol=1e-9)
    assert np.all((share >= 0) & (share <= 1))
    pooled2 = np.mean(curve.std_rad ** 2, axis=0)
    np.testing.assert_allclose(blk.sigma.reshape(8, 3),
                               np.degrees(np.sqrt(pooled2 / 3 + share * np.mean(fit ** 2, axis=0))), rtol=1e-4)
    bound = np.array([rep["curve_statement"]["lookup"]["sigma_bound_mdeg"][a] for a in AXES]).T
    np.testing.assert_allclose(bound, 1000 * np.degrees(np.sqrt(pooled2 / 3 + np.mean(fit ** 2, axis=0))), rtol=1e-4)
    assert cal.heads["oblique"].provenance.recipe == "tumbling-head"


def test_position_offset_single_image():
    """One tumbling image against the reference: the measured offset equals the true one within its stated sigma
    (4 sigma), and a textureless image is refused naming it."""
    from skyrig.calibrate.tumbling import measure_position_offset

    tl = tumbling_lab()
    lab = tl.build_lab(positions=4, circles=2, width=256, distance_m=2.0, seed=3)
    rr, rc = lab.setup.reference_orientation()
    ref = tl.render_plane(lab, lab.setup.rig.head("reference").camera, rr, rc, 1.0, seed=99)
    cam = lab.setup.rig.head("oblique").camera
    for k in (1, 3):
        r, c = lab.setup.tumbling_orientation(lab.beta_rad[k], lab.true_rad[0, k])
        img = tl.render_plane(lab, cam, r, c, 1.0, seed=k)
        off = measure_position_offset(lab.setup, img, float(lab.beta_rad[k]), ref, name=f"img{k}")
        z = (off.correction_rad - lab.true_rad[0, k]) / off.sigma_rad
        print("offset (mdeg)", 1000 * np.degrees(off.correction_rad), "true", 1000 * np.degrees(lab.true_rad[0, k]),
              "sigma", 1000 * np.degrees(off.sigma_rad), "gain", off.gain, "windows", off.windows)
        assert np.all(np.abs(z) < 4.0)
        assert off.windows >= 25
        assert np.all(off.sigma_rad < np.radians(0.03))  # a few 1/1000 deg (a pixel is 113/1000 deg at 256 px)
    flat = np.full_like(img, 128)
    with pytest.raises(SkyrigError, match="'blank.png'.*textured windows"):
        measure_position_offset(lab.setup, flat, float(lab.beta_rad[1]), ref, name="blank.png")


@pytest.mark.slow
def test_georeferencing_with_calibrated_rig_beats_nominal(lab_run):
    tl, lab, _, out, _ = lab_run
    rig, _ = read_calibrated_rig(out)
    nominal = tl.image_point_errors(lab, lab.setup.rig)
    calibrated = tl.image_point_errors(lab, rig)
    print("image points: nominal", nominal, "calibrated", calibrated)
    assert calibrated["rms_px"] < 0.3 * nominal["rms_px"]
    assert calibrated["max_px"] < 1.0


@pytest.mark.slow
def test_table2_report(lab_run):
    _, lab, _, out, output = lab_run
    rep = json.loads(out.with_suffix(".json").read_text())
    t2 = rep["table2_2sigma"]
    std = np.array([[c[f"{a}_std_mdeg"] for a in AXES] for c in rep["curve"]])
    for i, a in enumerate(AXES):
        assert t2[a]["mean_std_mdeg"] == pytest.approx(2 * std[:, i].mean(), rel=1e-9)
        assert t2[a]["max_std_mdeg"] == pytest.approx(2 * std[:, i].max(), rel=1e-9)
        assert rep["curve"][int(np.argmax(std[:, i]))]["beta_deg"] == pytest.approx(t2[a]["beta_at_max_deg"])
    assert out.with_suffix(".html").is_file() and "Tab. 2" in out.with_suffix(".html").read_text()
    assert "repeat accuracies" in output
    # the console states the curve's simultaneous band as the report has it
    band = rep["curve_statement"]["lookup"]["simultaneous_z"]
    assert f"within {band:.2f} sigma" in output and "simultaneous bands" in out.with_suffix(".html").read_text()


def test_bad_positions_named(lab_files, tmp_path):
    _, paths = lab_files
    bad = tmp_path / "positions.csv"
    lines = paths["positions"].read_text().splitlines()
    lines[3] = lines[3].rsplit(",", 1)[0] + ",abc"
    bad.write_text("\n".join(lines) + "\n")
    r = CliRunner().invoke(main, ["calibrate", "tumbling-head", "--images", str(paths["images"]), "--rig",
                                  str(paths["rig"]), "--positions", str(bad), "--plane-distance-m", "3.0",
                                  "-o", str(tmp_path / "x.yaml")])
    assert r.exit_code == 2
    assert "beta_deg" in r.output and "line 4" in r.output
    assert not (tmp_path / "x.yaml").exists()


def test_circles_must_hold_the_same_positions(lab_files):
    from skyrig.calibrate.tumbling import calibrate_tumbling_head

    lab, _ = lab_files
    names, circles, betas = lab.names[:-1], lab.circles[:-1], lab.betas[:-1]
    with pytest.raises(SkyrigError, match="same actuator positions"):
        calibrate_tumbling_head(lab.setup, lambda n: None, names, circles, betas, None)


def test_curve_statements_cover_as_stated():
    """The two statements of a curve (``TumblingCalibration.curve_statement``), checked by simulation without images:
    a 72-position curve like the lab's (three harmonics) plus Gaussian errors with the per-position sigmas stated
    (uneven, of the recipe's size), 300 draws.  The Fourier series' terms against the true terms are chi-square
    with 21 x 300 degrees of freedom; its simultaneous 95 % band and its "every value within 2 sigma" probability
    (both from its covariance), and Sidak's band for the independent per-position values, hold as often as stated
    (binomial 99.9 % bounds); the order chosen is the true one but for the selection test's false alarms."""
    from scipy.stats import binom

    from skyrig.adjust.stats import sidak_z
    from skyrig.calibrate.tumbling import fit_fourier_curve, fourier_design
    from skyrig.simulate.errors import tumble_curve_samples

    rng = np.random.default_rng(12)
    beta, truth = tumble_curve_samples(np.radians([0.05, 0.05, 0.1]), rng)
    k = beta.size
    sig = np.radians(np.array([3.0, 3.0, 10.0]) / 1000) * (1.0 + 0.5 * np.sin(beta))[:, None] ** np.array([1, -1, 1])
    t_coef = np.linalg.lstsq(fourier_design(beta, 3), truth, rcond=None)[0]
    n = 300
    ref = fit_fourier_curve(beta, truth, sig, order=3)  # the covariance depends on the sigmas only
    draws = ref.max_abs_z_draws(beta)
    c_f, p2 = float(np.quantile(draws, 0.95)), float(np.mean(draws <= 2.0))
    c_l = sidak_z(3 * k, 0.95)
    orders, d2, in_band, in_2, in_sidak = [], 0.0, 0, 0, 0
    for _ in range(n):
        y = truth + rng.normal(0.0, 1.0, truth.shape) * sig
        f = fit_fourier_curve(beta, y, sig)
        orders.append(f.order)
        f = fit_fourier_curve(beta, y, sig, order=3)
        d = f.coefficients_rad - t_coef
        d2 += sum(float(d[:, i] @ np.linalg.solve(f.covariance_rad2[i], d[:, i])) for i in range(3))
        z = np.abs(f(beta) - truth) / f.sigma_rad(beta)
        in_band += bool(np.all(z <= c_f))
        in_2 += bool(np.all(z <= 2.0))
        in_sidak += bool(np.all(np.abs(y - truth) / sig <= c_l))
    print("order != 3:", sum(o != 3 for o in orders), "chi2/dof", d2 / (21 * n), "band", in_band, "c", c_f,
          "all within 2 sigma", in_2, "model p", p2, "sidak", in_sidak, c_l)
    assert sum(o != 3 for o in orders) <= binom.ppf(0.9999, n, 9e-3)  # 9 harmonics above 3, each a 1e-3 test
    assert chi2.ppf(0.0005, 21 * n) < d2 < chi2.ppf(0.9995, 21 * n)
    for hits, p in ((in_band, 0.95), (in_2, p2), (in_sidak, 0.95)):
        assert binom.ppf(0.0005, n, p - 0.005) <= hits <= binom.ppf(0.9995, n, min(p + 0.005, 1.0))
    assert c_f < c_l  # the series' values are correlated: its simultaneous band is narrower than Sidak's


def test_repeat_share_estimate_and_sigma_as_stated():
    """The repeating error's share (``estimate_repeat_share``, REML on the residuals about a Fourier series) on
    simulated mean curves without images: a 72-position curve like the lab's plus Gaussian errors with variance
    ``s + lambda f_k`` (``s`` known, ``f_k`` uneven, ``lambda`` 0.5 on every axis, far enough from the bounds 0
    and 1 for its spread to be the stated one), 300 draws.  The share's mean is lambda and its spread the stated
    standard error (normal and chi-square 99 % bounds for 300 draws); the values' error over the sigma from the
    estimated share has RMS 1 (chi-square 99 % bounds for 300 x 72 values: conservative, the share is estimated
    from the same residuals), and over the upper bound (``lambda = 1``) it is below that band."""
    from scipy.stats import norm

    from skyrig.calibrate.tumbling import estimate_repeat_share
    from skyrig.simulate.errors import tumble_curve_samples

    rng = np.random.default_rng(21)
    beta, truth = tumble_curve_samples(np.radians([0.05, 0.05, 0.1]), rng)
    k, n = beta.size, 300
    s = np.radians(np.array([1.0, 1.5, 2.0]) / 1000) ** 2
    f = (np.radians(np.array([3.0, 3.0, 4.0]) / 1000) * (1.0 + 0.5 * np.sin(beta))[:, None]) ** 2
    lam = 0.5
    est, se, z, zb = [], [], [], []
    for _ in range(n):
        y = truth + rng.normal(size=truth.shape) * np.sqrt(s + lam * f)
        r = estimate_repeat_share(beta, y, s, f, 3)
        assert r.order == 3 and r.dof == k - 7
        est.append(r.share)
        se.append(r.share_se)
        z.append((y - truth) / np.sqrt(s + r.share * f))
        zb.append((y - truth) / np.sqrt(s + f))
    est, se, z, zb = np.array(est), np.array(se), np.array(z), np.array(zb)
    sd = np.sqrt(np.mean(se ** 2, axis=0))  # the stated spread
    print("share mean", est.mean(0), "sd", est.std(0), "stated", sd, "values z rms",
          np.sqrt(np.mean(z ** 2, axis=(0, 1))), "bound", np.sqrt(np.mean(zb ** 2, axis=(0, 1))))
    assert np.all(np.abs(est.mean(0) - lam) < norm.ppf(0.995) * sd / np.sqrt(n))
    lo, hi = np.sqrt(chi2.ppf([0.005, 0.995], n - 1) / (n - 1))
    assert np.all((est.std(0, ddof=1) / sd > lo) & (est.std(0, ddof=1) / sd < hi))
    lo, hi = np.sqrt(chi2.ppf([0.005, 0.995], n * k) / (n * k))
    rms = np.sqrt(np.mean(z ** 2, axis=(0, 1)))
    assert np.all((rms > lo) & (rms < hi))
    assert np.all(np.sqrt(np.mean(zb ** 2, axis=(0, 1))) < lo)


def test_reference_sampling_kernel():
    """The reference is sampled by Keys' cubic convolution: with a = -0.75 it equals OpenCV's INTER_CUBIC (up to
    cv2's 1/32 px tables), and with a = -0.5 (the recipe's) a grey-value ramp is reproduced exactly at any sub-pixel
    position, which a = -0.75 misplaces by up to 0.047 px."""
    import cv2

    from skyrig.calibrate.tumbling import _cubic_sample, _cubic_sample_kernel

    rng = np.random.default_rng(5)
    img = cv2.GaussianBlur(rng.normal(128, 40, (64, 80)).astype(np.float32), (0, 0), 1.5)
    x = rng.uniform(2, 76, (30, 40)).astype(np.float32)
    y = rng.uniform(2, 60, (30, 40)).astype(np.float32)
    ref = cv2.remap(img, x, y, cv2.INTER_CUBIC)
    ours = _cubic_sample_kernel(img, x, y, -0.75).reshape(x.shape)
    grad = np.abs(np.gradient(img)).max()
    assert np.abs(ours - ref).max() < grad / 32  # within one table step of cv2's quantised position
    ramp = (np.arange(80, dtype=np.float32)[None] * 1.5 + 0.25 * np.arange(64, dtype=np.float32)[:, None])
    want = 1.5 * x + 0.25 * y
    assert np.abs(_cubic_sample(ramp, x, y) - want).max() < 1e-3
    off = np.abs(_cubic_sample_kernel(ramp, x, y, -0.75).reshape(x.shape) - want).max() / 1.5
    assert 0.03 < off < 0.06  # a = -0.75 misplaces the ramp (px)
