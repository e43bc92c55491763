"""Full per-observation covariance (image 2x2, GNSS / control / IMU 3x3) in the bundle adjustment.

Independent answers: the truth of seeded simulations whose noise is drawn from the stated
covariances, and the distributions theory assigns to the results (chi-square for sigma0 and for the
Mahalanobis norm of the true errors, N(0, I) for whitened point errors).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from skyrig.adjust import AdjustConfig, BlockError, adjust
from skyrig.adjust.config import Unknowns
from skyrig.adjust.model import whitening_matrices
from skyrig.adjust.synthetic import synthetic_block
from skyrig.geometry.rotations import matrix_from_rotvec, rotvec_from_matrix

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
        res = adjust(blk, AdjustConfig(unknowns=Unknowns(poses="fixed")))
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


def test_imu_covariance_gives_normalised_attitude_errors():
    """IMU attitude errors drawn from correlated 3x3 covariances about the station axes (common
    correlation, varying size), precise enough to dominate the attitudes of a weakly tied block.  With
    ``imu_cov_rad2`` the attitude errors whitened by their predicted 3x3 covariance are N(0, I)
    (sum of squares chi-square, cross-correlations within the 1/sqrt(n) band), sigma0 and the joint
    Mahalanobis norm of all pose errors follow chi-square; with the per-axis sigmas alone the whitened
    errors keep the correlation of the simulation."""
    b, tr = synthetic_block(seed=4, n_strips=5, n_per_strip=20, n_points=300, sigma_px=0.5, gnss_sigma_m=0.05,
                            imu_sigma_rad=1e-12, n_control=0)
    rng = np.random.default_rng(17)
    m = len(b.imu_station)
    corr = np.array([[1.0, 0.9, 0.5], [0.9, 1.0, 0.6], [0.5, 0.6, 1.0]])
    sd = np.array([2e-5, 2e-5, 4e-5])
    cov = corr * np.outer(sd, sd) * rng.uniform(0.5, 2.0, m)[:, None, None]
    # R_imu = R_true expmap(noise): the noise is a rotation vector about the station axes
    b.imu_rotation = b.imu_rotation @ matrix_from_rotvec(
        np.einsum("nij,nj->ni", np.linalg.cholesky(cov), rng.normal(size=(m, 3))))
    out = {}
    for name in ("used", "ignored"):
        blk = b.copy()
        if name == "used":
            blk.imu_cov_rad2 = cov
        else:
            blk.imu_sigma_rad = np.sqrt(np.diagonal(cov, axis1=1, axis2=2))
        blk.__post_init__()
        res = adjust(blk, AdjustConfig())
        dth = rotvec_from_matrix(np.swapaxes(tr.station_rotation, 1, 2) @ res.block.station_rotation)
        rc = res.layout.pose[:, 3:]
        Q = res.covariance.Qcc[rc[:, :, None], rc[:, None, :]]  # a-priori variance factor 1 (the simulation's)
        z = np.linalg.solve(np.linalg.cholesky(Q), dth[:, :, None])[:, :, 0]
        out[name] = (res, z, dth)
    res, z, dth = out["used"]
    np.testing.assert_allclose(res.block.imu_sigma_rad, np.sqrt(np.diagonal(cov, axis1=1, axis2=2)))
    lo, hi = _chi2_interval(res.redundancy)
    assert lo <= res.sigma0**2 * res.redundancy <= hi
    lo, hi = _chi2_interval(z.size)
    assert lo <= float((z**2).sum()) <= hi
    C = z.T @ z / len(z)
    assert np.abs(C[np.triu_indices(3, 1)]).max() < 3.3 / np.sqrt(m), C
    e = np.concatenate([res.block.station_centre - tr.station_centre, dth], axis=1).reshape(-1)
    cols = res.layout.pose.reshape(-1)
    lo, hi = _chi2_interval(len(e))
    assert lo <= float(e @ np.linalg.solve(res.covariance.Qcc[np.ix_(cols, cols)], e)) <= hi
    # the IMU residuals come back as rotation vectors: v^T cov^-1 v over all groups is sigma0^2 r
    q = 0.0
    for grp, c in (("imu", cov), ("gnss", None), ("image", None)):
        v = res.residuals[grp].residual
        sig = {"gnss": res.block.gnss_sigma, "image": res.block.obs_sigma_px}.get(grp)
        q += float(np.einsum("ni,nij,nj->", v, np.linalg.inv(c), v)) if c is not None else float(((v / sig) ** 2).sum())
    assert q == pytest.approx(res.sigma0**2 * res.redundancy, rel=1e-6)
    # ignoring the correlation: the whitened errors stay correlated far outside the band
    z_ign = out["ignored"][1]
    C_ign = z_ign.T @ z_ign / len(z_ign)
    assert np.abs(C_ign[np.triu_indices(3, 1)]).max() > 6.0 / np.sqrt(m), C_ign  # (0.9 simulated)


# --------------------------------------------------------------------------- IMU covariance in block files
def _imu_cov_block():  # type: ignore[no-untyped-def]
    b, _ = synthetic_block(seed=4, n_strips=2, n_per_strip=4, n_points=60, gnss_sigma_m=0.05, imu_sigma_rad=2e-4)
    A = np.random.default_rng(0).normal(size=(len(b.imu_station), 3, 3)) * 2e-4
    b.imu_cov_rad2 = A @ np.swapaxes(A, 1, 2) + 1e-9 * np.eye(3)
    b.__post_init__()
    return b


def _edit_csv(path, line, column, value=None, drop=False):  # type: ignore[no-untyped-def]
    rows = [r.split(",") for r in path.read_text().splitlines()]
    k = rows[0].index(column)
    if drop:
        rows = [[c for j, c in enumerate(r) if j != k] for r in rows]
    else:
        rows[line - 1][k] = value
    path.write_text("\n".join(",".join(r) for r in rows) + "\n")


def test_block_file_imu_covariance_round_trip_and_units(tmp_path):
    import json

    from skyrig.io.block_file import read_block, write_block

    b = _imu_cov_block()
    write_block(tmp_path / "b.json", b)
    man = json.loads((tmp_path / "b.json").read_text())
    assert man["version"] == 1.1
    imu = tmp_path / "b_imu.csv"
    header = imu.read_text().splitlines()[0].split(",")
    assert header[-6:] == ["cov_rx_rx_deg2", "cov_rx_ry_deg2", "cov_rx_rz_deg2", "cov_ry_ry_deg2",
                           "cov_ry_rz_deg2", "cov_rz_rz_deg2"]
    got = read_block(tmp_path / "b.json").block
    np.testing.assert_allclose(got.imu_cov_rad2, b.imu_cov_rad2, rtol=1e-12)
    np.testing.assert_allclose(got.imu_sigma_rad, np.sqrt(np.diagonal(b.imu_cov_rad2, axis1=1, axis2=2)), rtol=1e-12)
    # known answer for the unit: 1e-4 deg² (0.01 deg sigma) is (0.01 * pi / 180)² rad²; sigma columns may go
    for c in ("sigma_omega_deg", "sigma_phi_deg", "sigma_kappa_deg"):
        _edit_csv(imu, 0, c, drop=True)
    for line in range(2, len(b.imu_station) + 2):
        for c, v in (("cov_rx_rx_deg2", "1e-4"), ("cov_rx_ry_deg2", "0"), ("cov_rx_rz_deg2", "0"),
                     ("cov_ry_ry_deg2", "4e-4"), ("cov_ry_rz_deg2", "0"), ("cov_rz_rz_deg2", "9e-4")):
            _edit_csv(imu, line, c, v)
    got = read_block(tmp_path / "b.json").block
    want = np.broadcast_to(np.radians([0.01, 0.02, 0.03]), got.imu_sigma_rad.shape)
    np.testing.assert_allclose(got.imu_sigma_rad, want, rtol=1e-12)


def test_block_file_imu_covariance_errors_name_file_line_and_field(tmp_path):
    from skyrig.errors import InputFormatError
    from skyrig.io.block_file import read_block, write_block

    write_block(tmp_path / "b.json", _imu_cov_block())
    imu = tmp_path / "b_imu.csv"
    good = imu.read_text()
    _edit_csv(imu, 3, "cov_rx_ry_deg2", "1")  # |rho| > 1
    with pytest.raises(InputFormatError, match="not positive definite") as e:
        read_block(tmp_path / "b.json")
    assert e.value.line == 3 and str(e.value.path).endswith("b_imu.csv")
    imu.write_text(good)
    _edit_csv(imu, 2, "cov_rz_rz_deg2", "9000")  # a variance of (95 deg)²: radians or gon, not deg²
    with pytest.raises(InputFormatError, match="implausibly large") as e:
        read_block(tmp_path / "b.json")
    assert e.value.line == 2
    imu.write_text(good)
    _edit_csv(imu, 0, "cov_ry_rz_deg2", drop=True)
    with pytest.raises(InputFormatError, match="come as a set") as e:
        read_block(tmp_path / "b.json")
    assert e.value.field == "cov_ry_rz_deg2"
