"""Distance observations (scale bars) in the bundle adjustment.

Independent answers: the truth of a seeded simulation whose scale is defined only by the distances
(datum: one GNSS position and one IMU attitude = 6 constraints, no scale), the predicted precision of
the adjustment, the identity sum(redundancy numbers) = n - u, and finite differences for the Jacobian.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from skyrig.adjust import AdjustConfig, DatumDefectError, adjust
from skyrig.adjust.config import ReliabilityOptions, Unknowns
from skyrig.adjust.model import Model, State
from skyrig.adjust.report import adjustment_report
from skyrig.adjust.synthetic import synthetic_block
from skyrig.io.report_html import write_report_html
from skyrig.geometry.rotations import matrix_from_rotvec

SIGMA_BAR_M = 0.2  # surveyed distances of 600-900 m: comparable to what the images give (GSD 16 cm)
START_SCALE = 1.03


@pytest.fixture(scope="module")
def scene():
    b, tr = synthetic_block(seed=5, n_strips=3, n_per_strip=6, n_points=300, sigma_px=0.5, gnss_sigma_m=None,
                            imu_sigma_rad=None, n_control=0)
    rng = np.random.default_rng(2)
    c0 = tr.station_centre.mean(axis=0)
    # starting values 3 % too large: only the distances can tell
    b.station_centre = c0 + START_SCALE * (b.station_centre - c0)
    b.point_xyz = c0 + START_SCALE * (b.point_xyz - c0)
    # weak datum: position and attitude of one station (fixes translation and rotation, not scale)
    b.gnss_station, b.gnss_xyz, b.gnss_sigma = np.array([0]), tr.station_centre[:1] + rng.normal(0, 0.02, (1, 3)), 0.02
    b.imu_station, b.imu_sigma_rad = np.array([0]), 1e-4
    b.imu_rotation = tr.station_rotation[:1] @ matrix_from_rotvec(rng.normal(0, 1e-4, (1, 3)))
    b.__post_init__()
    X = tr.point_xyz
    pairs = []
    for _ in range(6):
        a = int(rng.integers(len(X)))
        d = np.linalg.norm(X - X[a], axis=1)
        pairs.append((a, int(rng.choice(np.flatnonzero(d > 600)))))
    pairs = np.array(pairs)
    true_len = np.linalg.norm(X[pairs[:, 0]] - X[pairs[:, 1]], axis=1)
    with_bars = b.copy()
    with_bars.distance_point = pairs
    with_bars.distance_m = true_len + rng.normal(0, SIGMA_BAR_M, len(pairs))
    with_bars.distance_sigma_m = SIGMA_BAR_M
    with_bars.__post_init__()
    return b, with_bars, tr


def _scale_and_sigma(res, tr, i=0, j=-1):  # type: ignore[no-untyped-def]
    """Ratio of the adjusted to the true distance between two far stations, and its predicted sigma."""
    Ce, Ct = res.block.station_centre, tr.station_centre
    j = j % len(Ct)
    d_est, d_true = np.linalg.norm(Ce[i] - Ce[j]), np.linalg.norm(Ct[i] - Ct[j])
    cols = np.r_[res.layout.pose[i, :3], res.layout.pose[j, :3]]
    Q = res.covariance.Qcc[np.ix_(cols, cols)] * res.sigma0**2
    u = (Ce[i] - Ce[j]) / d_est
    g = np.r_[u, -u]
    return d_est / d_true, float(np.sqrt(g @ Q @ g)) / d_true


def test_without_distances_the_scale_is_a_datum_defect(scene):
    b, _, _ = scene
    with pytest.raises(DatumDefectError, match="scale"):
        adjust(b)


def test_distances_recover_the_true_scale_within_predicted_sigma(scene, tmp_path):
    _, b, tr = scene
    res = adjust(b)
    assert res.info.converged
    scale, sd = _scale_and_sigma(res, tr)
    assert abs(START_SCALE - 1.0) > 20 * sd  # the start was far off in units of the final precision
    assert abs(scale - 1.0) < 3.3 * sd, (scale, sd)
    lo, hi = chi2.ppf([0.0005, 0.9995], res.redundancy)
    assert lo <= res.sigma0**2 * res.redundancy <= hi
    # statistics: redundancy numbers of all rows add up to n - u (Baarda); distances take a real share
    total = sum(float(np.sum(g.redundancy)) for g in res.residuals.values())
    assert total == pytest.approx(res.redundancy, abs=1e-6 * res.redundancy)
    rd = res.residuals["distance"].redundancy[:, 0]
    assert np.all((rd > 0.05) & (rd < 1.0))
    # report table: adjusted minus observed is the residual; the adjusted length is the point distance
    rep = adjustment_report(res)
    rows = rep["distances"]["rows"]
    assert len(rows) == b.n_distances
    for r, v in zip(rows, res.residuals["distance"].residual[:, 0]):
        assert r["adjusted_m"] - r["observed_m"] == pytest.approx(v, abs=1e-9)
    write_report_html(tmp_path / "r.html", rep)
    html = (tmp_path / "r.html").read_text()
    assert "Distances" in html and rows[0]["point_a"] in html
    # the end points are estimated in the reduced part and have a covariance like the others
    ps = res.point_sigma
    ends = np.unique(b.distance_point)
    assert np.all(np.isfinite(ps[ends])) and np.all(ps[ends] < 1.0)


def test_free_network_scale_from_distances(scene):
    _, b, tr = scene
    free = b.copy()
    free.gnss_station = free.imu_station = None
    free.__post_init__()
    res = adjust(free, AdjustConfig(unknowns=Unknowns(datum="free")))
    scale, sd = _scale_and_sigma(res, tr)
    assert abs(scale - 1.0) < 3.3 * sd, (scale, sd)
    n_unk = res.layout.n_c + 3 * res.layout.n_p
    assert res.redundancy == res.n_observations - n_unk + 6  # 6 similarity motions: the scale is observed


def test_blunder_in_one_distance_is_found_by_data_snooping(scene):
    _, b, _ = scene
    bad = b.copy()
    bad.distance_m[2] += 10 * SIGMA_BAR_M
    res = adjust(bad, AdjustConfig(reliability=ReliabilityOptions(snooping=True)))
    assert res.rejected, "the blunder was not found"
    first = res.rejected[0]
    assert (first.group, first.index) == ("distance", 2)
    assert not any(r.group == "distance" and r.index != 2 for r in res.rejected)


def test_distance_jacobian_matches_finite_differences(scene):
    _, b, _ = scene
    m = Model(b, AdjustConfig())
    s = State.from_block(b)
    f = next(f for f in m.evaluate(s) if f.name == "distance")
    n_c = m.layout.n_c
    h = 1e-4
    for row in range(b.n_distances):
        for k, col in enumerate(f.cols[row]):
            dc = np.zeros(n_c)
            dc[col] = h
            fp = next(g for g in m.evaluate(m.layout.apply(s, dc, np.zeros((m.layout.n_p, 3))), False)
                      if g.name == "distance")
            dc[col] = -h
            fm = next(g for g in m.evaluate(m.layout.apply(s, dc, np.zeros((m.layout.n_p, 3))), False)
                      if g.name == "distance")
            num = (fp.r[row, 0] - fm.r[row, 0]) / (2 * h)
            assert f.jc[row, 0, k] == pytest.approx(num, rel=1e-6, abs=1e-9)
