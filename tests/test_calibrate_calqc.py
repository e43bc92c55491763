"""``skyrig calibrate calqc`` (paper 004): the correction grid by least-squares collocation against a known
field, with dense and with sparse residuals; the recipe on a small simulated MIDAS flight (slow)."""

from __future__ import annotations

import numpy as np
import pytest

from skyrig.calibrate.calqc import collocation_grid, fit_covariance, wave_deformation

W, H = 1200, 800


def _field(pix: np.ndarray) -> np.ndarray:
    return wave_deformation(0.5, W, H)(pix)


def _samples(n: int, noise: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    pix = rng.uniform([0, 0], [W - 1, H - 1], (n, 2))
    return pix, _field(pix) + rng.normal(0, noise, (n, 2))


def _nodes(g) -> np.ndarray:  # type: ignore[no-untyped-def]
    gx, gy = np.meshgrid(g.x_px, g.y_px)
    return np.column_stack([gx.ravel(), gy.ravel()])


def test_collocation_grid_recovers_a_smooth_field_within_its_sigma() -> None:
    pix, obs = _samples(1500, 0.1, 1)
    g = collocation_grid("cam", W, H, pix, obs)  # nodes fine enough for the fitted correlation length
    truth = _field(_nodes(g)).reshape(g.value_px.shape)
    # the node spacing: the true field interpolated bilinearly from its values at the chosen nodes loses little of it
    # (the 13-node grid of earlier versions lost a fifth: interpolation shrinks a wave between its nodes)
    exact = type(g)(g.camera, g.x_px, g.y_px, truth, g.sigma_px, g.covariance, g.n_residuals)
    rng = np.random.default_rng(9)
    p = rng.uniform([0, 0], [W - 1, H - 1], (5000, 2))
    assert np.sqrt(np.mean((exact.at(p) - _field(p)) ** 2)) < 0.1 * np.sqrt(np.mean(_field(p) ** 2))
    # the fitted covariance: signal variance near that of the field, nugget near the noise variance
    assert g.covariance.nugget == pytest.approx(0.01, rel=0.3)
    assert np.sqrt(g.covariance.c0) == pytest.approx(float(np.sqrt(np.mean(truth ** 2))), rel=0.5)
    e = (g.value_px - truth) / g.sigma_px[:, :, None]
    assert np.sqrt(np.mean(e ** 2)) < 2.0 and np.abs(e).max() < 5.0
    assert np.sqrt(np.mean((g.value_px - truth) ** 2)) < 0.2 * np.sqrt(np.mean(truth ** 2))
    # applied: corrected coordinates lose the field
    corr = g.correct(pix + _field(pix)) - pix
    assert np.sqrt(np.mean(corr ** 2)) < 0.25 * np.sqrt(np.mean(_field(pix) ** 2))


def test_collocation_grid_works_with_sparse_residuals_where_a_cell_mean_cannot() -> None:
    pix, obs = _samples(70, 0.05, 2)
    cov = fit_covariance(*_samples(1500, 0.05, 3), max_distance=0.5 * np.hypot(W, H))  # the field's covariance
    g = collocation_grid("cam", W, H, pix, obs, cov=cov)
    nodes = _nodes(g)
    # a mean per grid cell: most cells have no residual at all
    cx = np.clip(np.round(pix[:, 0] / (g.x_px[1] - g.x_px[0])).astype(int), 0, len(g.x_px) - 1)
    cy = np.clip(np.round(pix[:, 1] / (g.y_px[1] - g.y_px[0])).astype(int), 0, len(g.y_px) - 1)
    occupied = np.zeros(g.sigma_px.shape, bool)
    occupied[cy, cx] = True
    assert occupied.mean() < 0.6
    # collocation predicts every node, empty cells included, within its sigma
    truth = _field(nodes).reshape(g.value_px.shape)
    assert np.all(np.isfinite(g.value_px)) and np.all(g.sigma_px > 0)
    e = (g.value_px - truth) / g.sigma_px[:, :, None]
    # (a Gaussian covariance cannot follow the wave's negative lobes: with sparse data the sigmas are optimistic)
    assert np.sqrt(np.mean(e ** 2)) < 2.5
    empty = ~occupied
    assert np.sqrt(np.mean((g.value_px[empty] - truth[empty]) ** 2)) < 0.75 * np.sqrt(np.mean(truth ** 2))
    # sparse data: larger predicted sigma than with dense data
    dense = collocation_grid("cam", W, H, *_samples(1000, 0.05, 4), nodes_x=len(g.x_px), cov=cov)
    assert g.sigma_px.mean() > dense.sigma_px.mean()


def test_collocation_grid_without_signal_is_flat() -> None:
    rng = np.random.default_rng(5)
    pix = rng.uniform([0, 0], [W - 1, H - 1], (800, 2))
    g = collocation_grid("cam", W, H, pix, rng.normal(0, 0.1, (800, 2)), nodes_x=9)
    assert np.abs(g.value_px).max() < 0.05


def test_grid_without_calibration_part_keeps_the_wave_and_drops_io_like_fields() -> None:
    """A grid holding the wave plus what a principal-point shift, a principal-distance error, a kappa rotation and
    tilts make: removing the calibration-like part leaves the wave (which has little of it on the uniform nodes)."""
    from skyrig.calibrate.calqc import without_calibration_part

    pix, obs = _samples(1500, 0.1, 1)
    g = collocation_grid("cam", W, H, pix, obs)
    nodes = _nodes(g)
    c = np.array([(W - 1) / 2, (H - 1) / 2])
    d = nodes - c
    x, y = d[:, 0] / 500, d[:, 1] / 500
    extra = (np.array([0.2, -0.15]) + 3e-4 * d + 2e-4 * np.column_stack([-d[:, 1], d[:, 0]])
             + 0.1 * np.column_stack([x * x, x * y]) - 0.07 * np.column_stack([x * y, y * y]))
    g2 = without_calibration_part(type(g)(g.camera, g.x_px, g.y_px, g.value_px + extra.reshape(g.value_px.shape),
                                          g.sigma_px, g.covariance, g.n_residuals))
    np.testing.assert_allclose(g2.value_px, without_calibration_part(g).value_px, atol=1e-9)
    truth = _field(nodes).reshape(g.value_px.shape)
    assert np.sqrt(np.mean((g2.value_px - truth) ** 2)) < 0.25 * np.sqrt(np.mean(truth ** 2))
    # the wave itself has almost none of it on the nodes (none on a continuous format)
    wave_only = type(g)(g.camera, g.x_px, g.y_px, truth, g.sigma_px, g.covariance, g.n_residuals)
    change = without_calibration_part(wave_only).value_px - truth
    assert np.sqrt(np.mean(change ** 2)) < 0.1 * np.sqrt(np.mean(truth ** 2))


def test_calqc_cli_missing_input_exits_nonzero(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from click.testing import CliRunner

    from skyrig.cli.calibrate import command

    r = CliRunner().invoke(command, ["calqc", "--trajectory", str(tmp_path / "none.csv"), "--events", "x", "--rig", "y",
                                     "--measurements", "z", "--control", "c", "-o", str(tmp_path / "rig.yaml")])
    assert r.exit_code == 2 and "none.csv" in r.output


@pytest.mark.slow
def test_calqc_recovers_boresight_io_and_datum_within_2_sigma(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from skyrig.calibrate.calqc import calibrate_calqc, midas_calqc_scenario

    data, truth = midas_calqc_scenario("reduced", 3, tie_points=800, camera_width_px=600)
    cal = calibrate_calqc(data, variants=False, grid=False)
    z = []
    for h, (v, cov) in cal.boresight.items():
        z.append((v - truth.boresight_rotvec_rad[h]) / np.sqrt(np.diag(cov)))
    for h, (names, v, cov) in cal.interior.items():
        z.append((v - np.array([truth.intrinsics[h][n] for n in names])) / np.sqrt(np.diag(cov)))
    z.append((cal.datum_shift_m - truth.datum_shift_m) / np.sqrt(np.diag(cal.datum_shift_cov_m2)))
    z = np.concatenate(z)
    # 33 normalised errors: N(0,1) -> RMS near 1, a few may exceed 2
    assert np.sqrt(np.mean(z ** 2)) < 1.6
    assert (np.abs(z) > 2.0).sum() <= 4 and np.abs(z).max() < 3.5
    assert cal.geometry["opposite_directions"] and len(cal.geometry["heights_m"]) == 2
    # the calibrated rig file carries each head's boresight and IO with their sigma
    from skyrig.io.rig_file import read_calibrated_rig, write_rig

    write_rig(cal.rig, tmp_path / "rig.yaml", cal.rig_calibration("sim", "2011-10-01"))
    rig, rc = read_calibrated_rig(tmp_path / "rig.yaml")
    assert rc is not None
    for h, (names, v, cov) in cal.interior.items():
        assert rig.head(h).camera.focal_mm == pytest.approx(v[0], abs=1e-9)
        assert rc.heads[h].interior.sigma_of("focal_mm") == pytest.approx(np.sqrt(cov[0, 0]), rel=1e-6)
        assert rc.heads[h].boresight_opk_deg is not None


def test_collocation_grid_posterior_draws_have_the_node_sigmas() -> None:
    # the grid's posterior factor (for propagating its uncertainty) against the node sigmas computed separately
    # (cho_solve of the posterior), and draws from it against both
    pix, err = _samples(1500, 0.1, 7)
    g = collocation_grid("c", 600, 400, pix, err)
    F = g.posterior_factor
    assert F is not None
    np.testing.assert_allclose(np.sqrt(np.sum(F * F, axis=1)).reshape(g.sigma_px.shape), g.sigma_px, rtol=1e-8)
    rng = np.random.default_rng(3)
    d = np.stack([g.sample(rng) for _ in range(400)])
    emp = d.std(axis=0).mean(axis=-1)
    assert np.median(np.abs(emp / g.sigma_px - 1.0)) < 0.08


def test_collocation_prior_is_the_fitted_covariance_at_the_nodes() -> None:
    from skyrig.calibrate.calqc import collocation_prior, grid_nodes_for

    pix, obs = _samples(1500, 0.1, 11)
    cov = fit_covariance(pix, obs, 0.5 * np.hypot(W, H))
    spec = collocation_prior("cam", W, H, cov)
    assert len(spec.x_px) == grid_nodes_for(cov, W, H)
    gx, gy = np.meshgrid(spec.x_px, spec.y_px)
    nodes = np.column_stack([gx.ravel(), gy.ravel()])
    i, j = 0, len(nodes) // 2 + 1
    # independent: the Gaussian covariance function written out, plus 1 % of c0 on the diagonal
    assert spec.cov_px2[i, j] == pytest.approx(cov.c0 * np.exp(-(np.linalg.norm(nodes[i] - nodes[j]) / cov.length_px) ** 2))
    assert spec.cov_px2[i, i] == pytest.approx(1.01 * cov.c0)
    assert np.linalg.eigvalsh(spec.cov_px2)[0] > 0 and not spec.value_px.any()


@pytest.mark.slow
def test_calqc_joint_grid_returns_the_oblique_principal_distances_noise_free() -> None:
    """Noise-free flight with a wave on the nadir camera (0.2 px at 400 px: 18 um, as 0.3 px at 600 px): the
    residual-grid cycles leave the obliques' principal distances with the share of the wave they absorbed through
    the tie points (1200 px: -0.59 / -0.62 a-priori sigma, module docstring); the nadir grid's nodes as unknowns of
    the adjustment return them (errors in a-priori sigma: sigma / sigma0).  Only the nadir head may get a grid
    (``grid_heads``): noise-free, every head's residuals carry a "signal" (the absorbed share, nugget ~0), and five
    grids cost minutes (the 600 px / 800 tie-point version of this test ran 566 s)."""
    from skyrig.calibrate.calqc import calibrate_calqc, midas_calqc_scenario

    quiet = dict(gnss_noise_m=(0, 0, 0), imu_noise_rad=(0, 0, 0), gcp_sigma_m=(0, 0, 0))
    data, truth = midas_calqc_scenario("reduced", 1, tie_points=400, camera_width_px=400, deformation_px=0.2,
                                       error_overrides=quiet, image_noise_um=0.0)

    def focal_z(cal):  # type: ignore[no-untyped-def]
        s0 = cal.statistics["sigma0_joint"]
        out = {}
        for h, (names, v, cov) in cal.interior.items():
            k = list(names).index("focal_mm")
            out[h] = (v[k] - truth.intrinsics[h]["focal_mm"]) / (np.sqrt(cov[k, k]) / s0)
        return out

    joint = focal_z(calibrate_calqc(data, variants=False, grid=True, design=False, grid_heads=("nadir",)))
    for h in ("forward", "backward"):
        assert abs(joint[h]) < 0.2, (h, joint)
    # the test has power: without the grid the wave goes into the obliques' principal distances
    plain = focal_z(calibrate_calqc(data, variants=False, grid=False, design=False))
    assert max(abs(plain["forward"]), abs(plain["backward"])) > 1.0, plain


def test_covariance_fit_spread_is_the_spread_of_fits_to_fields_of_that_function() -> None:
    # the truth: the sampling spread of the detrended fit, from fields drawn independently with the true function
    # (Gaussian signal plus white noise) and fitted as joint_grid_adjustment fits them; the function under test
    # draws its own fields from the CovarianceFit it is given (here the true one).  Both sample variances have 23
    # degrees of freedom: their ratio inside the F distribution's 99 % interval.
    from scipy.stats import f as f_dist

    from skyrig.calibrate.calqc import CovarianceFit, covariance_fit_spread, random_field_deformation

    w, h, L, a, nug = 300, 200, 60.0, 0.05, 0.0036
    xy = np.random.default_rng(3).uniform([0, 0], [w - 1, h - 1], (600, 2))
    rng = np.random.default_rng(4)
    direct = []
    for _ in range(24):
        v = random_field_deformation(a, L, w, h, rng)(xy) + np.sqrt(nug) * rng.standard_normal((len(xy), 2))
        cf = fit_covariance(xy, v, 0.5 * float(np.hypot(w, h)), detrend_format=(w, h))
        direct.append([np.log(max(cf.c0, 1e-3 * a * a) / (a * a)), np.log(cf.length_px / L)])
    direct = np.array(direct)
    true = CovarianceFit(a * a, L, nug, np.zeros(1), np.zeros(1), np.zeros(1, np.int64), a * a + nug)
    S = covariance_fit_spread(xy, true, w, h, draws=24, seed=5)
    lo, hi = f_dist.ppf([0.005, 0.995], 23, 23)
    for k in range(2):
        ratio = S[k, k] / np.var(direct[:, k], ddof=1)
        assert lo < ratio < hi, (k, ratio, lo, hi)
    assert S.shape == (2, 2) and np.all(np.linalg.eigvalsh(S) >= -1e-12)
