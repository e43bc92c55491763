"""Point-cloud comparison: M3C2 against CloudCompare and PDAL on PDAL's Autzen clouds, C2C on known geometry."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import shared_path
from skyrig.errors import GeometryError, InputFormatError
from skyrig.lidar.compare import (
    M3C2Params,
    cloud_to_cloud,
    distance_statistics,
    histogram,
    m3c2,
    quantize_normals,
)

laspy = pytest.importorskip("laspy")


def _autzen():
    d = shared_path("autzen-lidar")
    a = laspy.read(d / "autzen-bmx-2010.las")
    b = laspy.read(d / "autzen-bmx-2023.las")
    return d, np.c_[a.x, a.y, a.z], np.c_[b.x, b.y, b.z]


def test_m3c2_matches_cloudcompare_on_103_core_points():
    d, c1, c2 = _autzen()
    cc = np.genfromtxt(d / "autzen-bmx-cc.txt", delimiter=",", names=True)
    core = np.c_[cc["X"], cc["Y"], cc["Z"]]
    r = m3c2(c1, c2, core, M3C2Params.cloudcompare(1.390432, 2.890432, 5.5))
    ccd = cc["M3C2_distance"]
    both = np.isfinite(r.distance_m) & np.isfinite(ccd)
    assert both.sum() >= 90
    assert np.max(np.abs(r.distance_m[both] - ccd[both])) < 0.01
    # same significance flags everywhere (CloudCompare: 0 where undefined)
    assert np.array_equal(r.significant, cc["significant_change"] == 1)
    # where skyrig finds the normal undefined (< 3 points), CloudCompare wrote a zero normal and distance 0
    bad = ~r.normal_valid
    assert np.all(np.abs(cc["NormalX"][bad]) + np.abs(cc["NormalY"][bad]) + np.abs(cc["NormalZ"][bad]) == 0)
    assert np.all(ccd[bad] == 0)
    v = r.normal_valid
    normals_cc = np.c_[cc["NormalX"], cc["NormalY"], cc["NormalZ"]]
    assert np.max(np.abs(r.normal[v] - normals_cc[v])) < 0.004  # file rounds to 0.001; float32 in CloudCompare
    assert np.array_equal(r.count1[v], cc["Npoints_cloud1"][v].astype(int))
    assert np.array_equal(r.count2[v], cc["Npoints_cloud2"][v].astype(int))
    u = np.isfinite(r.uncertainty_m)
    assert np.array_equal(u[v], np.isfinite(cc["distance_uncertainty"][v]))
    assert np.max(np.abs(r.uncertainty_m[u] - cc["distance_uncertainty"][u])) < 0.005
    assert np.nanmax(np.abs(r.std1_m[v] - cc["STD_cloud1"][v])) < 0.005  # CloudCompare: float32 sum of squares
    assert np.nanmax(np.abs(r.std2_m[v] - cc["STD_cloud2"][v])) < 0.005  # CloudCompare: float32 sum of squares


def test_exact_normals_differ_from_cloudcompare_only_by_its_normal_compression():
    # PDAL-style exact normals move a few boundary points in or out of the cylinders
    d, c1, c2 = _autzen()
    cc = np.genfromtxt(d / "autzen-bmx-cc.txt", delimiter=",", names=True)
    core = np.c_[cc["X"], cc["Y"], cc["Z"]]
    exact = m3c2(c1, c2, core, M3C2Params(1.390432, 2.890432, 5.5))
    v = exact.normal_valid
    assert np.sum(exact.count1[v] != cc["Npoints_cloud1"][v]) >= 1
    q = quantize_normals(exact.normal[v], 9)
    ang = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", q, exact.normal[v]), -1, 1)))
    assert ang.max() < 0.3


def test_m3c2_matches_pdal_unit_test_values():
    # PDAL test/unit/filters/M3C2FilterTest.cpp: 3 core points, its expected values at +-0.01
    d, c1, c2 = _autzen()
    core = np.loadtxt(d / "autzen-bmx-cores.txt", delimiter=",", skiprows=1)
    r = m3c2(c1, c2, core, M3C2Params.pdal(5.24414, 10.4882815, 2.763006))
    np.testing.assert_allclose(r.distance_m, [1.396, 0.670, 1.246], atol=0.01)
    np.testing.assert_allclose(r.uncertainty_m, [0.275, 0.140, 0.226], atol=0.01)
    assert r.significant.all()
    assert abs(r.std1_m[0] - 0.732) < 0.01 and abs(r.std2_m[0] - 1.582) < 0.01
    assert (r.count1[0], r.count2[0]) == (118, 166)


def test_m3c2_known_offset_between_noisy_planes():
    rng = np.random.default_rng(1)
    n = 4000
    xy = rng.uniform(-10, 10, (n, 2))
    tilt = np.array([0.1, -0.05])
    z = xy @ tilt
    c1 = np.c_[xy, z + rng.normal(0, 0.01, n)]
    normal = np.array([-0.1, 0.05, 1.0]) / np.linalg.norm([-0.1, 0.05, 1.0])
    shift = 0.2
    xy2 = rng.uniform(-10, 10, (n, 2))
    c2 = np.c_[xy2, xy2 @ tilt + rng.normal(0, 0.01, n)] + shift * normal
    core = np.c_[np.zeros(3), np.linspace(-3, 3, 3), np.zeros(3)]
    core[:, 2] = core[:, :2] @ tilt
    r = m3c2(c1, c2, core, M3C2Params(1.5, 1.0, 2.0))
    np.testing.assert_allclose(r.normal, np.tile(normal, (3, 1)), atol=0.02)
    # sigma of a mean of ~30 points with 1 cm noise: ~2 mm each
    np.testing.assert_allclose(r.distance_m, shift, atol=0.01)
    assert r.significant.all()


def test_quantize_normals_properties():
    rng = np.random.default_rng(0)
    v = rng.normal(size=(1000, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    q = quantize_normals(v, 9)
    assert np.allclose(np.linalg.norm(q, axis=1), 1)
    assert np.all(np.sign(q) == np.sign(v))
    ang = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", q, v), -1, 1)))
    assert 0 < ang.max() < 0.3
    # coarser levels are coarser, and quantised vectors are fixed points
    assert np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", quantize_normals(v, 4), v), -1, 1))).max() > ang.max()
    np.testing.assert_allclose(quantize_normals(q, 9), q, atol=1e-12)
    assert np.all(quantize_normals(np.zeros((1, 3)))) == 0


def test_cloud_to_cloud_nearest_and_plane_on_a_known_offset():
    g = np.arange(0, 10, 0.05)
    x, y = np.meshgrid(g, g)
    ref = np.c_[x.ravel(), y.ravel(), np.zeros(x.size)]
    rng = np.random.default_rng(3)
    q = np.c_[rng.uniform(2, 8, (500, 2)), np.full(500, 0.1)]
    plane = cloud_to_cloud(q, ref, model="plane", k=8)
    np.testing.assert_allclose(plane.distance_m, 0.1, atol=1e-9)
    near = cloud_to_cloud(q, ref, model="nearest")
    # nearest point: horizontal offset to the 5 cm grid adds to the 10 cm
    assert np.all(near.distance_m >= 0.1 - 1e-12) and near.distance_m.max() <= np.hypot(0.1, 0.025 * np.sqrt(2)) + 1e-9
    signed = cloud_to_cloud(q - [0, 0, 0.2], ref, model="plane", signed=True)
    np.testing.assert_allclose(signed.distance_m, -0.1, atol=1e-9)
    far = cloud_to_cloud(np.array([[5.0, 5.0, 3.0]]), ref, max_distance=1.0)
    assert np.isnan(far.distance_m[0])


def test_plane_model_fits_the_neighbours_within_max_distance_on_a_sparse_reference():
    # a sparse reference (8 points/m^2 on the plane z = 0, as the strip flight's TLS ground was): 10 neighbours rarely
    # all lie within 0.5 m; the plane through those that do gives the offset, not the nearest point's distance
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(11)
    ref = np.c_[rng.uniform(0, 20, (3200, 2)), np.zeros(3200)]
    q = np.c_[rng.uniform(2, 18, (2000, 2)), np.full(2000, 0.05)]
    res = cloud_to_cloud(q, ref, model="plane", k=10, max_distance=0.5)
    within = np.array([len(v) for v in cKDTree(ref).query_ball_point(q, 0.5)])
    assert np.mean(within < 10) > 0.5  # the case at hand: most points have fewer than k neighbours there
    ok = within >= 3
    np.testing.assert_allclose(res.distance_m[ok], 0.05, atol=1e-9)
    assert res.n_fallback == np.count_nonzero((within > 0) & (within < 3))
    near = cKDTree(ref).query(q[(within > 0) & (within < 3)])[0]
    np.testing.assert_allclose(res.distance_m[(within > 0) & (within < 3)], near)
    assert np.all(np.isnan(res.distance_m[within == 0]))


def test_statistics_two_thirds_figure_of_a_normal_distribution():
    rng = np.random.default_rng(7)
    sigma = 0.3
    d = rng.normal(0, sigma, 400_000)
    d[:10] = np.nan
    s = distance_statistics(d)
    assert s.n_undefined == 10 and s.count == d.size - 10
    # |N(0, s)|: 68th percentile = 0.9945 s; RMS = s
    assert abs(s.p68_abs_m / sigma - 0.99446) < 0.01
    assert abs(s.rms_m / sigma - 1) < 0.01
    counts, edges = histogram(d, bins=20)
    assert counts.sum() == s.count and len(edges) == 21 and edges[0] >= 0


def test_bad_input():
    with pytest.raises(InputFormatError):
        cloud_to_cloud(np.zeros((3, 2)), np.zeros((3, 3)))
    with pytest.raises(InputFormatError):
        M3C2Params(0.0, 1.0, 1.0)
    with pytest.raises(GeometryError):
        distance_statistics([np.nan])
    with pytest.raises(InputFormatError):
        cloud_to_cloud(np.array([[0, 0, np.nan]]), np.zeros((3, 3)))
