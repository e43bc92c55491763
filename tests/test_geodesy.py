"""Known-answer tests for skyrig.geodesy (crs, local) against pyproj/PROJ, closed-form formulas and
published values."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pyproj
import pytest

from skyrig.errors import CRSError
from skyrig.geodesy.crs import (
    Geoid,
    MapProjection,
    ecef_to_geodetic,
    geodetic_factors,
    geodetic_to_ecef,
    resolve_crs,
)
from skyrig.geodesy.local import LocalTangentFrame, ecef_from_enu_rotation, grid_from_enu_rotation
from skyrig.geometry.rotations import ENU_FROM_NED

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
EGM96 = DATA / "geoid" / "egm96_15.gtx"
RAF20 = DATA / "ign-aerial-block" / "dataset" / "fr_ign_RAF20.tif"
needs_egm96 = pytest.mark.skipif(not EGM96.is_file(), reason=f"test data {EGM96} not present (../shared absent)")
needs_raf20 = pytest.mark.skipif(not RAF20.is_file(), reason=f"test data {RAF20} not present (../shared absent)")

# WGS84 / GRS80 defining constants
WGS84_A, WGS84_F = 6378137.0, 1.0 / 298.257223563
GRS80_A, GRS80_F = 6378137.0, 1.0 / 298.257222101
AIRY_A, AIRY_F = 6377563.396, 1.0 / 299.3249646


def closed_form_ecef(lat_deg, lon_deg, h, a=WGS84_A, f=WGS84_F):
    """X = (N+h) cos(lat) cos(lon), Y = (N+h) cos(lat) sin(lon), Z = (N(1-e^2)+h) sin(lat)."""
    e2 = f * (2 - f)
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    n = a / np.sqrt(1 - e2 * np.sin(lat) ** 2)
    return np.stack(
        [(n + h) * np.cos(lat) * np.cos(lon), (n + h) * np.cos(lat) * np.sin(lon), (n * (1 - e2) + h) * np.sin(lat)],
        axis=-1,
    )


def radii(lat_deg, a=WGS84_A, f=WGS84_F):
    """Meridian (M) and prime-vertical (N) radii of curvature."""
    e2 = f * (2 - f)
    w2 = 1 - e2 * math.sin(math.radians(lat_deg)) ** 2
    return a * (1 - e2) / w2**1.5, a / math.sqrt(w2)


def tm_series(lat_deg, dlon_deg, k0, a, f):
    """Closed-form transverse Mercator convergence (rad) and point scale factor (Redfearn / Snyder 8-11).

    gamma = dl sin(p) [1 + dl^2 cos^2 p (1 + 3 eta^2 + 2 eta^4) / 3 + dl^4 cos^4 p (2 - t^2) / 15]
    k = k0 [1 + (1 + C) A^2 / 2 + (5 - 4T + 42C + 13C^2 - 28 e'^2) A^4 / 24 + (61 - 148T + 16T^2) A^6 / 720]
    Truncation: about 1e-9 rad and 1e-10 in k for |dl| <= 3 deg.
    """
    p, dl = np.radians(lat_deg), np.radians(dlon_deg)
    e2 = f * (2 - f)
    ep2 = e2 / (1 - e2)
    c = ep2 * np.cos(p) ** 2  # eta^2
    t2 = np.tan(p) ** 2
    cp = np.cos(p)
    gamma = dl * np.sin(p) * (1 + dl**2 * cp**2 * (1 + 3 * c + 2 * c**2) / 3 + dl**4 * cp**4 * (2 - t2) / 15)
    A = dl * cp
    k = k0 * (
        1
        + (1 + c) * A**2 / 2
        + (5 - 4 * t2 + 42 * c + 13 * c**2 - 28 * ep2) * A**4 / 24
        + (61 - 148 * t2 + 16 * t2**2) * A**6 / 720
    )
    return gamma, k


# --------------------------------------------------------------------------- geodetic <-> ECEF
def _random_llh(n, seed):
    rng = np.random.default_rng(seed)
    return rng.uniform(-89.9, 89.9, n), rng.uniform(-180, 180, n), rng.uniform(-500, 12000, n)


def test_geodetic_to_ecef_vs_pyproj_and_closed_form():
    lat, lon, h = _random_llh(500, 1)
    xyz = geodetic_to_ecef(lat, lon, h)
    assert xyz.shape == (500, 3)
    t = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978")  # authority axis order: lat, lon, h
    ref = np.stack(t.transform(lat, lon, h), axis=-1)
    np.testing.assert_allclose(xyz, ref, rtol=0, atol=1e-6)
    np.testing.assert_allclose(xyz, closed_form_ecef(lat, lon, h), rtol=0, atol=1e-6)
    # a textbook point: on the equator at the prime meridian, X = a
    np.testing.assert_allclose(geodetic_to_ecef(0.0, 0.0, 0.0), [WGS84_A, 0.0, 0.0], atol=1e-6)
    # north pole: Z = b = a (1 - f)
    np.testing.assert_allclose(geodetic_to_ecef(90.0, 0.0, 0.0)[2], WGS84_A * (1 - WGS84_F), atol=1e-6)


def test_ecef_to_geodetic_vs_pyproj_and_round_trip():
    lat, lon, h = _random_llh(500, 2)
    xyz = closed_form_ecef(lat, lon, h)
    lat2, lon2, h2 = ecef_to_geodetic(xyz)
    np.testing.assert_allclose(lat2, lat, atol=1e-10)  # 1e-10 deg ~ 0.01 mm
    np.testing.assert_allclose(lon2, lon, atol=1e-10)
    np.testing.assert_allclose(h2, h, atol=1e-6)
    t = pyproj.Transformer.from_crs("EPSG:4978", "EPSG:4979")
    rlat, rlon, rh = t.transform(xyz[:, 0], xyz[:, 1], xyz[:, 2])
    np.testing.assert_allclose(np.stack([lat2, lon2, h2]), np.stack([rlat, rlon, rh]), atol=1e-9)


# --------------------------------------------------------------------------- local tangent planes
def test_enu_rotation_columns():
    lat, lon = 43.6, 4.43
    r = ecef_from_enu_rotation(lat, lon)
    np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-15)
    assert np.linalg.det(r) == pytest.approx(1.0)
    # up is the ellipsoid normal: the direction of d(ECEF)/dh from the closed form
    up = closed_form_ecef(lat, lon, 1.0) - closed_form_ecef(lat, lon, 0.0)
    np.testing.assert_allclose(r[:, 2], up, atol=1e-9)
    # north is along d(ECEF)/dlat, east along d(ECEF)/dlon
    d = 1e-6
    dn = closed_form_ecef(lat + d, lon, 0.0) - closed_form_ecef(lat - d, lon, 0.0)
    de = closed_form_ecef(lat, lon + d, 0.0) - closed_form_ecef(lat, lon - d, 0.0)
    np.testing.assert_allclose(r[:, 1], dn / np.linalg.norm(dn), atol=1e-9)
    np.testing.assert_allclose(r[:, 0], de / np.linalg.norm(de), atol=1e-9)
    assert ecef_from_enu_rotation(np.zeros(4), np.zeros(4)).shape == (4, 3, 3)


@pytest.mark.parametrize("lat0", [0.0, 38.7, 60.0, -33.9])
def test_enu_ned_known_offsets(lat0):
    lon0, h0 = -9.1, 0.0
    enu = LocalTangentFrame(lat0, lon0, h0, "enu")
    ned = LocalTangentFrame(lat0, lon0, h0, "ned")
    geod = pyproj.Geod(ellps="WGS84")
    M, N = radii(lat0)
    s = 100.0
    # 100 m north along the meridian on the ellipsoid: the meridian is locally a circle of radius M, so
    # ENU = (0, M sin(s/M), -M (1 - cos(s/M))) ~ (0, 100, -0.00079)
    lon_n, lat_n, _ = geod.fwd(lon0, lat0, 0.0, s)
    got = enu.from_geodetic(lat_n, lon_n, 0.0).reshape(3)
    expected = [0.0, M * math.sin(s / M), -M * (1 - math.cos(s / M))]
    np.testing.assert_allclose(got, expected, atol=1e-6)
    assert -0.0008 < got[2] < -0.00078
    # 100 m east along the geodesic: the normal section has radius N
    lon_e, lat_e, _ = geod.fwd(lon0, lat0, 90.0, s)
    got = enu.from_geodetic(lat_e, lon_e, 0.0).reshape(3)
    np.testing.assert_allclose(got, [N * math.sin(s / N), 0.0, -N * (1 - math.cos(s / N))], atol=1e-6)
    # straight up
    np.testing.assert_allclose(enu.from_geodetic(lat0, lon0, 100.0).reshape(3), [0, 0, 100.0], atol=1e-8)
    # NED is the permutation (N, E, -U)
    pts = np.array([[lat_n, lon_n, 5.0], [lat_e, lon_e, -3.0], [lat0, lon0, 100.0]])
    e = enu.from_geodetic(pts[:, 0], pts[:, 1], pts[:, 2])
    n = ned.from_geodetic(pts[:, 0], pts[:, 1], pts[:, 2])
    np.testing.assert_allclose(n, np.stack([e[:, 1], e[:, 0], -e[:, 2]], axis=1), atol=1e-9)
    np.testing.assert_allclose(n, e @ ENU_FROM_NED.T, atol=1e-9)


def test_local_frame_round_trips_and_validation():
    f = LocalTangentFrame(48.85, 2.35, 35.0, "ned")
    rng = np.random.default_rng(3)
    local = rng.uniform(-5000, 5000, (100, 3))
    lat, lon, h = f.to_geodetic(local)
    np.testing.assert_allclose(f.from_geodetic(lat, lon, h), local, atol=1e-6)
    np.testing.assert_allclose(f.from_ecef(f.to_ecef(local)), local, atol=1e-8)
    np.testing.assert_allclose(f.origin_ecef, closed_form_ecef(48.85, 2.35, 35.0), atol=1e-6)
    # the ENU frame at the origin expressed in this NED frame is ENU_FROM_NED's inverse (= itself)
    np.testing.assert_allclose(f.local_from_local_enu_at(48.85, 2.35), ENU_FROM_NED, atol=1e-15)
    with pytest.raises(CRSError):
        LocalTangentFrame(0.0, 0.0, 0.0, "nwu")  # type: ignore[arg-type]
    with pytest.raises(CRSError):
        LocalTangentFrame(91.0, 0.0)
    with pytest.raises(CRSError):
        LocalTangentFrame(0.0, float("nan"))


# --------------------------------------------------------------------------- projected CRSs
# (spec, a WGS84 sample centre) ; published origins are checked separately below
PROJECTED = [
    ("EPSG:25832", (50.0, 9.5)),  # ETRS89 / UTM 32N
    (32632, (45.0, 7.0)),  # WGS84 / UTM 32N
    (2154, (43.64, 4.43)),  # Lambert-93
    ("27700", (52.0, -1.5)),  # British National Grid (OSGB36 datum, false origin)
    ("EPSG:3763", (39.5, -8.3)),  # ETRS89 / Portugal TM06 (paper 003)
]


def _samples(centre, n=50, seed=4):
    rng = np.random.default_rng(seed)
    lat = centre[0] + rng.uniform(-0.5, 0.5, n)
    lon = centre[1] + rng.uniform(-0.5, 0.5, n)
    h = rng.uniform(-50, 3000, n)
    return np.stack([lat, lon, h], axis=1)


@pytest.mark.parametrize(("spec", "centre"), PROJECTED)
def test_projected_round_trip_and_vs_pyproj(spec, centre):
    mp = MapProjection(spec)
    assert mp.crs.is_projected and mp.height_kind == "ellipsoidal"
    llh = _samples(centre)
    xyz = mp.from_geodetic(llh)
    t = pyproj.Transformer.from_crs("EPSG:4326", resolve_crs(spec), always_xy=True)
    x, y = t.transform(llh[:, 1], llh[:, 0])
    np.testing.assert_allclose(xyz[:, :2], np.stack([x, y], axis=1), atol=1e-6)
    np.testing.assert_array_equal(xyz[:, 2], llh[:, 2])  # ellipsoidal heights pass through
    np.testing.assert_allclose(mp.to_geodetic(xyz), llh, atol=1e-9)  # 1e-9 deg ~ 0.1 mm
    # through ECEF, against the closed form
    ecef = mp.to_ecef(xyz)
    np.testing.assert_allclose(ecef, closed_form_ecef(llh[:, 0], llh[:, 1], llh[:, 2]), atol=1e-4)
    np.testing.assert_allclose(mp.from_ecef(ecef), xyz, atol=1e-6)
    # a single point keeps working
    assert mp.from_geodetic(llh[0]).shape == (1, 3)


def test_published_false_origins():
    # Lambert-93: (46.5 N, 3 E) -> (700 000, 6 600 000) (IGN)
    np.testing.assert_allclose(MapProjection(2154).from_geodetic([46.5, 3.0, 0.0])[0, :2], [700000, 6600000], atol=1e-3)
    # UTM 32N: (0, 9 E) -> (500 000, 0)
    np.testing.assert_allclose(MapProjection(25832).from_geodetic([0.0, 9.0, 0.0])[0, :2], [500000, 0], atol=1e-3)
    # PT-TM06 natural origin 39 40' 05.73" N, 8 07' 59.19" W -> (0, 0) (EPSG:3763 definition)
    lat0, lon0 = 39 + 40 / 60 + 5.73 / 3600, -(8 + 7 / 60 + 59.19 / 3600)
    np.testing.assert_allclose(MapProjection(3763).from_geodetic([lat0, lon0, 0.0])[0, :2], [0, 0], atol=1e-3)


def test_wkt_and_proj_string_defined_crs():
    # a national transverse Mercator with a false origin given only as WKT2 (no EPSG code anywhere)
    wkt = """PROJCRS["Custom TM",
      BASEGEOGCRS["ETRS89-like",DATUM["d",ELLIPSOID["GRS 1980",6378137,298.257222101,LENGTHUNIT["metre",1]]],
        PRIMEM["Greenwich",0,ANGLEUNIT["degree",0.0174532925199433]]],
      CONVERSION["tm",METHOD["Transverse Mercator"],
        PARAMETER["Latitude of natural origin",39.6682583333333,ANGLEUNIT["degree",0.0174532925199433]],
        PARAMETER["Longitude of natural origin",-8.13310833333333,ANGLEUNIT["degree",0.0174532925199433]],
        PARAMETER["Scale factor at natural origin",1,SCALEUNIT["unity",1]],
        PARAMETER["False easting",200000,LENGTHUNIT["metre",1]],
        PARAMETER["False northing",300000,LENGTHUNIT["metre",1]]],
      CS[Cartesian,2],AXIS["easting",east,ORDER[1],LENGTHUNIT["metre",1]],
        AXIS["northing",north,ORDER[2],LENGTHUNIT["metre",1]]]"""
    mp = MapProjection(wkt)
    ref = MapProjection(3763)
    llh = _samples((39.5, -8.3), seed=5)
    # same projection as PT-TM06 shifted by the false origin
    np.testing.assert_allclose(mp.from_geodetic(llh)[:, :2], ref.from_geodetic(llh)[:, :2] + [200000, 300000], atol=1e-6)
    np.testing.assert_allclose(mp.to_geodetic(mp.from_geodetic(llh)), llh, atol=1e-9)
    # convergence and scale identical to PT-TM06's at the same places
    ca, ka = mp.factors(mp.from_geodetic(llh))
    cb, kb = ref.factors(ref.from_geodetic(llh))
    np.testing.assert_allclose(ca, cb, atol=1e-12)
    np.testing.assert_allclose(ka, kb, atol=1e-12)
    ps = MapProjection("+proj=tmerc +lat_0=39.6682583333333 +lon_0=-8.13310833333333 +k=1 +x_0=0 +y_0=0 +ellps=GRS80")
    np.testing.assert_allclose(ps.from_geodetic(llh)[:, :2], ref.from_geodetic(llh)[:, :2], atol=1e-6)


def test_crs_errors_and_compound():
    for bad in ("EPSG:999999", "not a crs at all", 999999, "+proj=nonsense"):
        with pytest.raises(CRSError):
            resolve_crs(bad)
        with pytest.raises(CRSError):
            MapProjection(bad)
    with pytest.raises(CRSError):
        MapProjection(4978)  # geocentric is not a mapping frame
    assert resolve_crs("2154").to_epsg() == 2154
    assert resolve_crs(np.int64(2154)).to_epsg() == 2154
    c = pyproj.CRS(2154)
    assert resolve_crs(c) is c
    # compound Lambert-93 + NGF-IGN69 height: the horizontal part is used
    assert MapProjection("EPSG:2154+5720").crs.to_epsg() == 2154
    # a geographic mapping frame has no convergence and unit scale
    g = MapProjection(4326)
    conv, k = g.factors([[4.0, 44.0, 0.0]])
    np.testing.assert_array_equal(conv, [0.0])
    np.testing.assert_array_equal(k, [1.0])


def test_impossible_coordinates_are_refused():
    mp = MapProjection(25832)
    with pytest.raises(CRSError):
        mp.to_geodetic([[500000.0, 5e6, 0.0], [1e8, 0.0, 0.0]])  # 100 000 km east of the central meridian
    with pytest.raises(CRSError):
        mp.from_geodetic([[95.0, 9.0, 0.0]])  # latitude beyond the pole


# --------------------------------------------------------------------------- meridian convergence, scale factor
UTM_POINTS = [(50.0, 9.0), (50.0, 11.5), (45.0, 6.2), (60.0, 7.1), (35.0, 11.9), (10.0, 10.0), (70.0, 6.0)]


def test_utm_factors_vs_closed_form_series():
    lat = np.array([p[0] for p in UTM_POINTS])
    lon = np.array([p[1] for p in UTM_POINTS])
    g_ref, k_ref = tm_series(lat, lon - 9.0, 0.9996, GRS80_A, GRS80_F)
    conv, k = geodetic_factors(25832, lat, lon)
    np.testing.assert_allclose(conv, g_ref, atol=1e-9)  # 1e-9 rad = 0.0002", the series' truncation
    np.testing.assert_allclose(k, k_ref, atol=2e-10)
    # same through map coordinates
    mp = MapProjection(25832)
    conv2, k2 = mp.factors(mp.from_geodetic(np.stack([lat, lon, np.zeros_like(lat)], axis=1)))
    np.testing.assert_allclose(conv2, g_ref, atol=1e-9)
    np.testing.assert_allclose(k2, k_ref, atol=2e-10)
    # sign: east of the central meridian in the northern hemisphere grid north is east of true north
    assert conv[1] > 0 and conv[2] < 0
    # on the central meridian: gamma = 0, k = k0 (PROJ differentiates numerically: ~1e-11)
    c0, k0 = geodetic_factors(25832, 47.0, 9.0)
    assert abs(c0[0]) < 1e-12 and k0[0] == pytest.approx(0.9996, abs=1e-10)


def test_bng_factors_vs_closed_form_on_osgb36():
    # OS published example (Caister water tower): OSGB36 52 39' 27.2531" N, 1 43' 4.5177" E
    # -> E 651409.903, N 313177.270.  Factors must be computed on the OSGB36 (Airy) geographic
    # coordinates, not on WGS84 ones ~100 m away.
    lat = 52 + 39 / 60 + 27.2531 / 3600
    lon = 1 + 43 / 60 + 4.5177 / 3600
    g_ref, k_ref = tm_series(lat, lon + 2.0, 0.9996012717, AIRY_A, AIRY_F)
    conv, k = MapProjection(27700).factors([[651409.903, 313177.270]])
    np.testing.assert_allclose(conv, g_ref, atol=1e-8)
    np.testing.assert_allclose(k, k_ref, atol=1e-9)
    # at the true origin (49 N, 2 W) -> (400 000, -100 000): gamma = 0, k = k0
    conv, k = MapProjection(27700).factors([[400000.0, -100000.0]])
    assert abs(conv[0]) < 1e-9 and k[0] == pytest.approx(0.9996012717, abs=1e-10)


def test_lambert93_convergence_known_value():
    # Lambert conformal conic: gamma = n (lon - lon0) exactly, n from the two standard parallels (Snyder 15-8)
    e = math.sqrt(GRS80_F * (2 - GRS80_F))

    def m(p):
        return math.cos(p) / math.sqrt(1 - e * e * math.sin(p) ** 2)

    def t(p):
        return math.tan(math.pi / 4 - p / 2) / ((1 - e * math.sin(p)) / (1 + e * math.sin(p))) ** (e / 2)

    p1, p2 = math.radians(49.0), math.radians(44.0)
    n = (math.log(m(p1)) - math.log(m(p2))) / (math.log(t(p1)) - math.log(t(p2)))
    lat = np.array([44.0, 47.0, 43.64, 50.9])
    lon = np.array([6.0, -4.5, 4.43, 2.0])
    conv, _ = geodetic_factors(2154, lat, lon)
    np.testing.assert_allclose(conv, n * np.radians(lon - 3.0), atol=1e-10)
    assert math.degrees(conv[0]) == pytest.approx(2.18, abs=0.005)


def _grid_north_azimuth_and_scale(crs_spec, lat, lon):
    """Finite differences of PROJ forward transforms in the CRS's own geographic CRS.

    Returns the grid azimuth of true north (= -convergence) and the ratio of a short grid distance to the
    ellipsoidal geodesic distance (pyproj.Geod) between the same two points (= point scale factor).
    """
    crs = resolve_crs(crs_spec)
    fwd = pyproj.Transformer.from_crs(crs.geodetic_crs, crs, always_xy=True)
    d = 1e-5  # deg, ~1.1 m
    x, y = fwd.transform([lon, lon], [lat - d, lat + d])
    az_true_north = math.atan2(x[1] - x[0], y[1] - y[0])
    geod = crs.get_geod()
    ratios = []
    for az in (0.0, 57.0, 123.0):  # conformal: same scale in every direction
        lo1, la1, _ = geod.fwd(lon, lat, az + 180.0, 100.0)
        lo2, la2, _ = geod.fwd(lon, lat, az, 100.0)
        _, _, dist = geod.inv(lo1, la1, lo2, la2)
        gx, gy = fwd.transform([lo1, lo2], [la1, la2])
        ratios.append(math.hypot(gx[1] - gx[0], gy[1] - gy[0]) / dist)
    return az_true_north, np.array(ratios)


@pytest.mark.parametrize(
    ("spec", "lat", "lon"),
    [
        (25832, 50.0, 11.5),
        (2154, 44.0, 6.0),
        (2154, 48.8, -4.0),
        (27700, 57.0, -5.0),
        (3763, 41.5, -6.5),
        (3763, 37.1, -8.9),
    ],
)
def test_factors_vs_pyproj_finite_differences(spec, lat, lon):
    az, ratios = _grid_north_azimuth_and_scale(spec, lat, lon)
    mp = MapProjection(spec)
    crs = resolve_crs(spec)
    x, y = pyproj.Transformer.from_crs(crs.geodetic_crs, crs, always_xy=True).transform(lon, lat)
    conv, k = mp.factors([[x, y]])
    # convention: true north has grid azimuth -convergence
    assert az == pytest.approx(-conv[0], abs=1e-9)
    np.testing.assert_allclose(ratios, k[0], atol=5e-10)
    # grid_from_enu = rot_z(convergence) takes the ENU north vector to grid azimuth -convergence
    v = grid_from_enu_rotation(conv[0]) @ [0.0, 1.0, 0.0]
    assert math.atan2(v[0], v[1]) == pytest.approx(az, abs=1e-8)


# --------------------------------------------------------------------------- geoid
@needs_egm96
def test_egm96_published_value():
    g = Geoid(str(EGM96))
    n = g.undulation(39.0, -9.0)
    assert float(n) == pytest.approx(54.11, abs=0.01)  # ../shared/data/README.md
    np.testing.assert_allclose(g.to_ellipsoidal(39.0, -9.0, 100.0), 100.0 + n)
    np.testing.assert_allclose(g.to_orthometric(39.0, -9.0, 100.0), 100.0 - n)
    assert g.undulation(np.full(4, 39.0), np.full(4, -9.0)).shape == (4,)


@needs_egm96
def test_map_projection_with_geoid_round_trip():
    g = Geoid(str(EGM96))
    mp = MapProjection(3763, geoid=g)
    assert mp.height_kind == "orthometric"
    llh = _samples((39.0, -9.0), seed=6)
    xyH = mp.from_geodetic(llh)
    np.testing.assert_allclose(xyH[:, 2], llh[:, 2] - g.undulation(llh[:, 0], llh[:, 1]), atol=1e-9)
    np.testing.assert_allclose(mp.to_geodetic(xyH), llh, atol=1e-9)
    # at 39 N 9 W, H = 0 means h = N = 54.11 m
    x0 = MapProjection(3763).from_geodetic([39.0, -9.0, 0.0])
    assert mp.to_geodetic(x0)[0, 2] == pytest.approx(54.11, abs=0.01)


@needs_raf20
def test_raf20_at_ign_gcp_1003_vs_pyproj_pipeline():
    x, y, H = 815601.510, 6283629.280, 54.960
    mp = MapProjection(2154, geoid=Geoid(str(RAF20)))
    h = mp.to_geodetic([x, y, H])[0, 2]
    # independent PROJ pipeline: inverse Lambert-93 (IGN parameters), then the RAF20 grid with a +1 multiplier
    pipe = pyproj.Transformer.from_pipeline(
        "+proj=pipeline +step +inv +proj=lcc +lat_0=46.5 +lon_0=3 +lat_1=49 +lat_2=44 +x_0=700000 +y_0=6600000 "
        f"+ellps=GRS80 +step +proj=vgridshift +grids={RAF20} +multiplier=1 +step +proj=unitconvert +xy_in=rad +xy_out=deg"
    )
    lon, lat, h_ref = pipe.transform(x, y, H)
    assert h == pytest.approx(h_ref, abs=1e-6)
    assert 40.0 < h - H < 60.0  # RAF20 undulation in southern France is about 50 m
    np.testing.assert_allclose(mp.to_geodetic([x, y, H])[0, :2], [lat, lon], atol=1e-9)


@needs_raf20
def test_geoid_path_with_spaces(tmp_path):
    d = tmp_path / "dir with space"
    d.mkdir()
    shutil.copy(RAF20, d / "raf20 copy.tif")
    a = Geoid(str(d / "raf20 copy.tif")).undulation(43.64, 4.43)
    b = Geoid(str(RAF20)).undulation(43.64, 4.43)
    assert float(a) == float(b)


@needs_raf20
def test_geoid_outside_grid():
    with pytest.raises(CRSError):
        Geoid(str(RAF20)).undulation(0.0, 0.0)  # RAF20 covers France only


def test_missing_geoid_is_crs_error(tmp_path):
    with pytest.raises(CRSError, match="does not exist"):
        Geoid(str(tmp_path / "no_such_grid.gtx"))
    with pytest.raises(CRSError):
        Geoid("skyrig_no_such_grid_anywhere.gtx")  # a name PROJ cannot find
    bad = tmp_path / "not_a_grid.gtx"
    bad.write_text("garbage")
    with pytest.raises(CRSError):
        Geoid(str(bad))
