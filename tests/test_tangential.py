"""Tests for the tangential frame of paper 003 (skyrig.geodesy.local.TangentialFrame) and for
skyrig.geodesy.mapheights, against independent PROJ pipelines and finite differences."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pyproj
import pytest

from skyrig.geodesy.crs import Geoid, MapProjection
from skyrig.geodesy.local import TangentialFrame
from skyrig.geodesy.mapheights import map_height_from_true_height, true_height_from_map_height
from skyrig.geometry.rotations import rot_z

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
EGM96 = DATA / "geoid" / "egm96_15.gtx"
RAF20 = DATA / "ign-aerial-block" / "dataset" / "fr_ign_RAF20.tif"

# Map -> ECEF written as explicit PROJ pipelines, independently of skyrig: inverse projection with the
# published parameters, the geoid grid adding N (multiplier +1) to orthometric heights, then geocentric
# coordinates (WGS84 ellipsoid, skyrig's ECEF; RGF93/ETRS89 are taken equal to WGS84 as PROJ does).
LAMBERT93 = "+proj=lcc +lat_0=46.5 +lon_0=3 +lat_1=49 +lat_2=44 +x_0=700000 +y_0=6600000 +ellps=GRS80"
PTTM06 = "+proj=tmerc +lat_0=39.6682583333333 +lon_0=-8.13310833333333 +k=1 +x_0=0 +y_0=0 +ellps=GRS80"
UTM32 = "+proj=utm +zone=32 +ellps=GRS80"

CASES = [
    pytest.param(
        2154, RAF20, LAMBERT93, (815601.510, 6283629.280, 54.96), id="lambert93-raf20",
        marks=pytest.mark.skipif(not RAF20.is_file(), reason=f"{RAF20} not present (../shared absent)"),
    ),
    pytest.param(
        3763, EGM96, PTTM06, (-95000.0, -120000.0, 100.0), id="pttm06-egm96",
        marks=pytest.mark.skipif(not EGM96.is_file(), reason=f"{EGM96} not present (../shared absent)"),
    ),
    pytest.param(25832, None, UTM32, (690000.0, 5540000.0, 300.0), id="utm32-ellipsoidal"),
]


def _frame(epsg, grid, origin):
    mp = MapProjection(epsg, geoid=None if grid is None else Geoid(str(grid)))
    return TangentialFrame(mp, origin)


def _ecef_pipeline(proj, grid):
    steps = f"+proj=pipeline +step +inv {proj}"
    if grid is not None:
        steps += f" +step +proj=vgridshift +grids={grid} +multiplier=1"
    steps += " +step +proj=cart +ellps=WGS84"
    return pyproj.Transformer.from_pipeline(steps)


def _undulation(grid, lon, lat):
    """Geoid undulation from the grid through a PROJ pipeline written here (0 without a grid)."""
    if grid is None:
        return 0.0
    # input in degrees: pyproj converts to the radians PROJ's vgridshift expects
    t = pyproj.Transformer.from_pipeline(f"+proj=vgridshift +grids={grid} +multiplier=1")
    return float(t.transform(lon, lat, 0.0)[2])


def _block(origin, half=10000.0, n=400, seed=0):
    """Points over a 20 km x 20 km block, heights from the ground up to flying height."""
    rng = np.random.default_rng(seed)
    x = origin[0] + rng.uniform(-half, half, n)
    y = origin[1] + rng.uniform(-half, half, n)
    z = origin[2] + rng.uniform(-50.0, 2000.0, n)
    return np.stack([x, y, z], axis=1)


@pytest.mark.parametrize(("epsg", "grid", "proj", "origin"), CASES)
def test_round_trip_20km_block(epsg, grid, proj, origin):
    tf = _frame(epsg, grid, origin)
    pts = _block(origin)
    t = tf.from_map(pts)
    np.testing.assert_allclose(tf.to_map(t), pts, rtol=0, atol=1e-6)
    # the tangent point is the origin
    np.testing.assert_allclose(tf.from_map(np.array(origin)), np.zeros((1, 3)), atol=1e-6)
    # and tangential -> map -> tangential
    tt = np.random.default_rng(1).uniform(-10000, 10000, (100, 3))
    np.testing.assert_allclose(tf.from_map(tf.to_map(tt)), tt, atol=1e-6)


@pytest.mark.parametrize(("epsg", "grid", "proj", "origin"), CASES)
def test_distances_are_ecef_chords(epsg, grid, proj, origin):
    """Uniform scale: tangential distances equal 3D chord distances between ECEF positions computed by an
    independent PROJ pipeline (and map-grid distances do not)."""
    tf = _frame(epsg, grid, origin)
    pts = _block(origin, n=60, seed=2)
    t = tf.from_map(pts)
    X, Y, Z = _ecef_pipeline(proj, grid).transform(pts[:, 0], pts[:, 1], pts[:, 2])
    ecef = np.stack([X, Y, Z], axis=1)
    np.testing.assert_allclose(tf.local.to_ecef(t), ecef, atol=1e-6)
    d_t = np.linalg.norm(t[:, None] - t[None], axis=-1)
    d_e = np.linalg.norm(ecef[:, None] - ecef[None], axis=-1)
    np.testing.assert_allclose(d_t, d_e, atol=1e-6)
    # for contrast: map coordinates are not Cartesian (scale factor, heights not scaled, geoid)
    d_m = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
    assert np.max(np.abs(d_m - d_e)) > 0.5


@pytest.mark.parametrize(("epsg", "grid", "proj", "origin"), CASES)
def test_axes_at_tangent_point(epsg, grid, proj, origin):
    tf = _frame(epsg, grid, origin)
    crs = pyproj.CRS(epsg)
    to_geo = pyproj.Transformer.from_crs(crs, crs.geodetic_crs, always_xy=True)
    to_map = pyproj.Transformer.from_crs(crs.geodetic_crs, crs, always_xy=True)
    lon0, lat0 = to_geo.transform(origin[0], origin[1])
    # geodesic 1 km towards geographic north and east, at the same ellipsoidal height: Y is north, X east.
    # With a geoid the orthometric height of that point is H0 + N0 - N1 (N from an independent grid lookup).
    geod = crs.get_geod()
    h0 = origin[2] + _undulation(grid, lon0, lat0)
    a, f = crs.ellipsoid.semi_major_metre, 1.0 / crs.ellipsoid.inverse_flattening
    e2 = f * (2 - f)
    w2 = 1 - e2 * math.sin(math.radians(lat0)) ** 2
    radius_m, radius_n = a * (1 - e2) / w2**1.5, a / math.sqrt(w2)  # meridian, prime vertical
    s = 1000.0
    for az, axis, R in ((0.0, 1, radius_m), (90.0, 0, radius_n)):
        lon, lat, _ = geod.fwd(lon0, lat0, az, s)
        x, y = to_map.transform(lon, lat)
        H = origin[2] + _undulation(grid, lon0, lat0) - _undulation(grid, lon, lat)
        v = tf.from_map([x, y, H])[0]
        # normal section of radius R at height h0: chord (R + h0) sin(s/R), drop (R + h0)(1 - cos(s/R)) ~ 0.08 m
        assert v[axis] == pytest.approx((R + h0) * math.sin(s / R), abs=1e-4)
        assert v[2] == pytest.approx(-(R + h0) * (1 - math.cos(s / R)), abs=1e-4)
        assert abs(v[1 - axis]) < (1e-6 if az == 0.0 else 1e-4)  # the meridian plane is exactly the Y-Z plane
    # Z along the ellipsoid normal (a point above the tangent point, same lat/lon)
    v = tf.from_map([origin[0], origin[1], origin[2] + 500.0])[0]
    np.testing.assert_allclose(v, [0.0, 0.0, 500.0], atol=1e-6)


def _grid_north_azimuth(epsg, x, y):
    """Grid azimuth of true north by finite differences of PROJ (= -meridian convergence)."""
    crs = pyproj.CRS(epsg)
    lon, lat = pyproj.Transformer.from_crs(crs, crs.geodetic_crs, always_xy=True).transform(x, y)
    fwd = pyproj.Transformer.from_crs(crs.geodetic_crs, crs, always_xy=True)
    d = 1e-5
    xs, ys = fwd.transform([lon, lon], [lat - d, lat + d])
    return math.atan2(xs[1] - xs[0], ys[1] - ys[0])


@pytest.mark.parametrize(("epsg", "grid", "proj", "origin"), CASES)
def test_tangential_from_grid_rotation(epsg, grid, proj, origin):
    tf = _frame(epsg, grid, origin)
    # at the tangent point it is rot_z(-convergence); the convergence from PROJ finite differences
    az = _grid_north_azimuth(epsg, origin[0], origin[1])  # = -convergence
    r0 = tf.tangential_from_grid_rotation(np.array(origin))
    assert r0.shape == (1, 3, 3)
    np.testing.assert_allclose(r0[0], rot_z(az), atol=1e-9)
    # elsewhere in the block, its columns are the grid east, grid north and up directions at each point,
    # obtained here by central differences of the independent map -> ECEF pipeline, rotated to the frame.
    # The grid axes are horizontal, i.e. at constant *ellipsoidal* height: the differences are taken without
    # the geoid.  Points are near the ellipsoid: at height h the (x, y) grid lines turn by
    # ~ gamma h (N - M) / (M N), 1.7e-8 rad per km for gamma = 2 deg, which the convention neglects.
    pts = _block(origin, n=8, seed=3)
    pts[:, 2] = _block(origin, n=8, seed=4)[:, 2] * 0.02  # within +-50 m of the ellipsoid
    r = tf.tangential_from_grid_rotation(pts)
    pipe = _ecef_pipeline(proj, None)
    local_from_ecef = tf.local.ecef_from_local.T
    d = 1.0
    for col in range(3):
        step = np.zeros(3)
        step[col] = d
        a = np.stack(pipe.transform(*(pts + step).T), axis=1)
        b = np.stack(pipe.transform(*(pts - step).T), axis=1)
        v = (a - b) @ local_from_ecef.T
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        np.testing.assert_allclose(r[:, :, col], v, atol=5e-9)
    # orthonormal
    np.testing.assert_allclose(r @ np.swapaxes(r, 1, 2), np.broadcast_to(np.eye(3), r.shape), atol=1e-14)


# --------------------------------------------------------------------------- mapheights
def test_linear_alteration_numeric_example():
    # IGN block: ground about 53 m, exposures about 1770 m above it, Lambert-93 scale factor 1.000286
    k, zg = 1.000286, 53.0
    z_true = 1823.0
    # hand computation: Z_map = Z + (k - 1)(Z - z_ground) = 1823 + 0.000286 * 1770 = 1823.50622
    assert float(map_height_from_true_height(z_true, k, zg)) == pytest.approx(1823.50622, abs=1e-9)
    assert float(true_height_from_map_height(1823.50622, k, zg)) == pytest.approx(1823.0, abs=1e-9)
    # ground points are unaffected; heights above ground scale by k like horizontal distances do
    assert float(map_height_from_true_height(zg, k, zg)) == zg
    z = np.array([0.0, 53.0, 553.0, 2053.0])
    np.testing.assert_allclose(map_height_from_true_height(z, k, zg) - zg, k * (z - zg), atol=1e-9)


def test_linear_alteration_round_trip():
    rng = np.random.default_rng(5)
    z = rng.uniform(-100, 5000, 1000)
    k = rng.uniform(0.9996, 1.001, 1000)
    zg = 120.0
    np.testing.assert_allclose(true_height_from_map_height(map_height_from_true_height(z, k, zg), k, zg), z, atol=1e-9)
    np.testing.assert_allclose(map_height_from_true_height(true_height_from_map_height(z, k, zg), k, zg), z, atol=1e-9)
    # k = 1: no alteration
    np.testing.assert_array_equal(map_height_from_true_height(z, 1.0, zg), z)
