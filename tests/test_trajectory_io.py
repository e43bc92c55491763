"""Trajectory CSV, camera events CSV and Applanix SBET readers/writers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyproj
import pytest

from skyrig.errors import InputFormatError, UnitError
from skyrig.io.events_csv import read_events_csv, write_events_csv
from skyrig.io.sbet import SBET_FIELDS, read_sbet, read_sbet_records, write_sbet
from skyrig.io.trajectory_csv import ImplausibleAngleError, read_trajectory_csv, write_trajectory_csv
from skyrig.trajectory import EventOutOfSpanError, Trajectory, check_events_in_span

GEOID = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "geoid" / "egm96_15.gtx"
T0 = 345600.0


def _sample_trajectory(n=50, sigmas=True, velocity=True, lat0=48.3, lon0=13.0):
    rng = np.random.default_rng(7)
    t = T0 + 0.005 * np.arange(n)
    lat = lat0 + 1e-5 * np.arange(n)
    lon = lon0 + 2e-5 * np.arange(n)
    h = 900.0 + rng.normal(0, 1, n)
    roll, pitch = rng.uniform(-15, 15, n), rng.uniform(-8, 8, n)
    yaw = rng.uniform(-179, 179, n)
    kw = {}
    if velocity:
        kw["velocity_ned"] = rng.normal(0, 30, (n, 3))
    if sigmas:
        kw["sigma_ned_m"] = rng.uniform(0.01, 0.1, (n, 3))
        kw["sigma_rpy"] = rng.uniform(0.001, 0.01, (n, 3))
    return Trajectory.from_rpy(t, lat, lon, h, roll, pitch, yaw, "deg", reference="antenna", **kw)


def _ang_diff_deg(a, b):
    return np.abs((np.asarray(a) - np.asarray(b) + 180.0) % 360.0 - 180.0)


def _assert_same(a: Trajectory, b: Trajectory, pos_m=1e-4, ang_deg=1e-8):
    np.testing.assert_allclose(a.time_s, b.time_s, atol=1e-6)
    assert np.max(np.linalg.norm(a.ecef - b.ecef, axis=1)) < pos_m
    for x, y in zip(a.rpy("deg"), b.rpy("deg")):
        assert np.max(_ang_diff_deg(x, y)) < ang_deg
    assert a.reference == b.reference and a.time_system == b.time_system


def _write(tmp_path, text, name="traj.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


# ---------------------------------------------------------------------------- trajectory CSV
def test_csv_round_trip_geographic_with_velocities_and_sigmas(tmp_path):
    tr = _sample_trajectory()
    p = tmp_path / "t.csv"
    write_trajectory_csv(p, tr, angles="gon")
    back = read_trajectory_csv(p)
    _assert_same(tr, back)
    np.testing.assert_allclose(back.velocity_ned, tr.velocity_ned, atol=1e-5)
    np.testing.assert_allclose(back.sigma_ned_m, tr.sigma_ned_m, atol=1e-5)
    np.testing.assert_allclose(back.sigma_rpy_rad, tr.sigma_rpy_rad, rtol=1e-8)
    assert not list(tmp_path.glob(".*.tmp"))  # the temporary file was renamed away


def test_csv_round_trip_geocentric_against_pyproj(tmp_path):
    tr = _sample_trajectory(sigmas=True, velocity=False)
    p = tmp_path / "ecef.csv"
    write_trajectory_csv(p, tr, crs="EPSG:4978", angles="rad")
    text = p.read_text().splitlines()
    table = np.loadtxt(text[text.index("time,x,y,z,roll,pitch,yaw,sx,sy,sz,sroll,spitch,syaw") + 1:], delimiter=",")
    xyz = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True).transform(tr.lon_deg, tr.lat_deg,
                                                                                             tr.h_m)
    np.testing.assert_allclose(table[:, 1:4], np.stack(xyz, axis=1), atol=2e-5)
    back = read_trajectory_csv(p)
    _assert_same(tr, back)
    np.testing.assert_allclose(back.sigma_ned_m, tr.sigma_ned_m, atol=1e-5)


def _egm96_bilinear(lat, lon):
    """Geoid undulation from the .gtx grid read with numpy (independent of PROJ's grid code)."""
    raw = GEOID.read_bytes()
    lat0, lon0, dlat, dlon = np.frombuffer(raw[:32], ">f8")
    rows, cols = np.frombuffer(raw[32:40], ">i4")
    grid = np.frombuffer(raw[40:], ">f4").reshape(rows, cols).astype(float)
    fi, fj = (lat - lat0) / dlat, (lon - lon0) / dlon
    i, j = np.floor(fi).astype(int), np.floor(fj).astype(int)
    u, v = fi - i, fj - j
    return ((1 - u) * (1 - v) * grid[i, j] + (1 - u) * v * grid[i, j + 1]
            + u * (1 - v) * grid[i + 1, j] + u * v * grid[i + 1, j + 1])


@pytest.mark.skipif(not GEOID.is_file(), reason=f"geoid grid {GEOID} not available (../shared absent)")
def test_csv_round_trip_projected_orthometric_grid_heading(tmp_path):
    tr = _sample_trajectory(sigmas=False, velocity=False)
    p = tmp_path / "utm.csv"
    write_trajectory_csv(p, tr, crs="EPSG:32632", geoid=str(GEOID), angles="rad", heading="grid")
    text = p.read_text().splitlines()
    assert "# height: orthometric" in text and "# heading: grid" in text and "# crs: EPSG:32632" in text
    header = text.index("time,x,y,z,roll,pitch,yaw")
    table = np.loadtxt(text[header + 1:], delimiter=",")
    # the file's coordinates against pyproj directly and an independent bilinear read of the grid
    e, n = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32632", always_xy=True).transform(tr.lon_deg, tr.lat_deg)
    np.testing.assert_allclose(table[:, 1], e, atol=2e-5)
    np.testing.assert_allclose(table[:, 2], n, atol=2e-5)
    big_n = _egm96_bilinear(tr.lat_deg, tr.lon_deg)
    assert 40.0 < big_n.mean() < 55.0  # EGM96 in Bavaria is about 47 m
    np.testing.assert_allclose(table[:, 3], tr.h_m - big_n, atol=1e-3)
    # grid heading = true heading - convergence (convergence from PROJ factors at the point)
    f = pyproj.Proj("EPSG:32632").get_factors(tr.lon_deg, tr.lat_deg)
    yaw_true = tr.rpy("rad")[2]
    np.testing.assert_allclose(np.degrees(np.angle(np.exp(1j * (table[:, 6] - yaw_true)))),
                               -np.asarray(f.meridian_convergence), atol=1e-8)
    back = read_trajectory_csv(p)
    _assert_same(tr, back)
    # a relative geoid path is taken relative to the file
    rel = tmp_path / "rel.csv"
    import os

    rel.write_text(p.read_text().replace(f"# geoid: {GEOID}", f"# geoid: {os.path.relpath(GEOID, tmp_path)}"))
    _assert_same(tr, read_trajectory_csv(rel))


def test_csv_gps_week_sow_and_column_order(tmp_path):
    p = _write(tmp_path, "# skyrig-trajectory 1\n# angles: deg\n# time: gps-week-sow\n"
                         "yaw,pitch,roll,h,lon,lat,time,week\n"
                         "90,1,2,100,7,46,604799.5,2200\n"
                         "91,1,2,100,7,46,0.5,2201\n")
    tr = read_trajectory_csv(p)
    assert tr.time_system == "gps"
    np.testing.assert_allclose(tr.time_s, [2200 * 604800 + 604799.5, 2201 * 604800 + 0.5])
    r, pi, y = tr.rpy("deg")
    np.testing.assert_allclose([r[0], pi[0], y[0]], [2, 1, 90], atol=1e-12)
    np.testing.assert_allclose(tr.lat_deg, 46.0, atol=1e-12)


GOOD = ("# skyrig-trajectory 1\n"  # line 1
        "# crs: EPSG:4979\n"  # 2
        "# angles: deg\n"  # 3
        "# exported by a test\n"  # 4 (free comment)
        "time,lat,lon,h,roll,pitch,yaw\n"  # 5
        "100.0,46.0,7.0,1000.0,1.0,2.0,30.0\n"  # 6
        "100.5,46.0001,7.0001,1000.5,1.1,2.1,31.0\n"  # 7
        "101.0,46.0002,7.0002,1001.0,1.2,2.2,32.0\n")  # 8


def test_good_file_reads(tmp_path):
    tr = read_trajectory_csv(_write(tmp_path, GOOD))
    assert len(tr) == 3 and tr.reference == "imu" and tr.time_system == "gps-sow"
    np.testing.assert_allclose(tr.rpy("deg")[2], [30, 31, 32], atol=1e-12)


BAD_TRAJECTORY_CASES = {
    # name: (replace old, by new, expected line, expected field, extra exception class)
    "missing column": ("time,lat,lon,h,roll,pitch,yaw", "time,lat,lon,h,roll,pitch", 5, "yaw", None),
    "unknown column": ("time,lat,lon,h,roll,pitch,yaw", "time,lat,lon,h,roll,pitch,yaw,temp", 5, "temp", None),
    "x instead of lat in geographic": ("time,lat,lon,h", "time,x,lon,h", 5, "x", None),
    "nan": ("1.1,2.1,31.0", "1.1,nan,31.0", 7, "pitch", None),
    "non number": ("100.5,46.0001", "100.5,46.0001x", 7, "lat", None),
    "empty cell": ("101.0,46.0002,7.0002,1001.0,", "101.0,46.0002,7.0002,,", 8, "h", None),
    "short row": ("1.2,2.2,32.0\n", "1.2,2.2\n", 8, None, None),
    "unknown crs": ("EPSG:4979", "EPSG:999999", 2, "crs", None),
    "unknown angle unit": ("# angles: deg", "# angles: mil", 3, "angles", None),
    "misspelled key": ("# angles: deg", "# angle: deg", 3, "angle", None),
    # pitch 2.0 "rad" (115 deg) is the first impossible value, on line 6
    "radians claimed, degrees given": ("# angles: deg", "# angles: rad", 6, "pitch", ImplausibleAngleError),
    "pitch beyond a quarter turn": ("1.1,2.1,31.0", "1.1,95.0,31.0", 7, "pitch", ImplausibleAngleError),
    "time not increasing": ("100.5,46.0001", "99.0,46.0001", 7, "time", None),
    "latitude beyond 90": ("100.5,46.0001", "100.5,96.0001", 7, "lat", None),
    "no version line": ("# skyrig-trajectory 1\n", "", 1, "skyrig-trajectory", None),
    "wrong version": ("# skyrig-trajectory 1", "# skyrig-trajectory 2", 1, "skyrig-trajectory", None),
    "orthometric without geoid": ("# angles: deg", "# angles: deg\n# height: orthometric", 4, "geoid", None),
    "unknown time system": ("# angles: deg", "# angles: deg\n# time: tai", 4, "time", None),
    "repeated key": ("# angles: deg", "# angles: deg\n# angles: rad", 4, "angles", None),
    "partial velocity group": ("pitch,yaw\n100.0,46.0,7.0,1000.0,1.0,2.0,30.0\n"
                               "100.5,46.0001,7.0001,1000.5,1.1,2.1,31.0\n"
                               "101.0,46.0002,7.0002,1001.0,1.2,2.2,32.0",
                               "pitch,yaw,vn,ve\n100.0,46.0,7.0,1000.0,1.0,2.0,30.0,1,1\n"
                               "100.5,46.0001,7.0001,1000.5,1.1,2.1,31.0,1,1\n"
                               "101.0,46.0002,7.0002,1001.0,1.2,2.2,32.0,1,1", 5, "vd", None),
}


@pytest.mark.parametrize("case", list(BAD_TRAJECTORY_CASES))
def test_bad_trajectory_csv_names_line_and_field(tmp_path, case):
    old, new, line, field, cls = BAD_TRAJECTORY_CASES[case]
    assert old in GOOD
    p = _write(tmp_path, GOOD.replace(old, new, 1))
    with pytest.raises(InputFormatError) as ei:
        read_trajectory_csv(p)
    e = ei.value
    assert (e.path, e.line, e.field) == (str(p), line, field), str(e)
    assert str(p) in str(e)
    if cls is not None:
        assert isinstance(e, cls) and isinstance(e, UnitError)


def test_heading_in_degrees_declared_radians(tmp_path):
    text = ("# skyrig-trajectory 1\n# angles: rad\ntime,lat,lon,h,roll,pitch,yaw\n"
            "1.0,46,7,100,0.01,0.02,3.1\n2.0,46,7,100,0.01,0.02,250.0\n")
    with pytest.raises(ImplausibleAngleError) as ei:
        read_trajectory_csv(_write(tmp_path, text))
    assert (ei.value.line, ei.value.field) == (5, "yaw")
    assert "wrong unit" in str(ei.value)


def test_unknown_geoid_names_geoid_line(tmp_path):
    text = GOOD.replace("# angles: deg", "# angles: deg\n# height: orthometric\n# geoid: /no/such/grid.gtx")
    with pytest.raises(InputFormatError) as ei:
        read_trajectory_csv(_write(tmp_path, text))
    assert (ei.value.line, ei.value.field) == (5, "geoid")


# ---------------------------------------------------------------------------- events CSV
EVENTS = ("# skyrig-events 1\n"  # 1
          "# angles: deg\n"  # 2
          "image,time,head,beta,exposure\n"  # 3
          "img_0001_n.jpg,100.2,nadir,,1\n"  # 4
          "img_0001_o.jpg,100.2,oblique,-35.5,1\n"  # 5
          "\"img, 0002_n.jpg\",100.7,nadir,,2\n")  # 6


def test_events_read_and_round_trip(tmp_path):
    p = _write(tmp_path, EVENTS, "ev.csv")
    ev = read_events_csv(p)
    assert ev.image_name.tolist() == ["img_0001_n.jpg", "img_0001_o.jpg", "img, 0002_n.jpg"]
    assert ev.head.tolist() == ["nadir", "oblique", "nadir"]
    assert np.isnan(ev.beta_rad[0]) and np.isclose(ev.beta_rad[1], np.radians(-35.5))
    assert ev.exposure_id.tolist() == [1, 1, 2]
    assert ev.source_line.tolist() == [4, 5, 6]
    q = tmp_path / "ev2.csv"
    write_events_csv(q, ev, angles="gon")
    back = read_events_csv(q)
    for name in ("image_name", "head", "exposure_id"):
        assert getattr(back, name).tolist() == getattr(ev, name).tolist()
    np.testing.assert_allclose(back.time_s, ev.time_s, atol=1e-6)
    # the writer wraps actuator angles into one turn [0, 2 pi): same angle on the circle
    np.testing.assert_allclose(back.beta_rad, np.mod(ev.beta_rad, 2 * np.pi), atol=1e-10, equal_nan=True)


def test_events_without_beta_or_exposure(tmp_path):
    p = _write(tmp_path, "# skyrig-events 1\nimage,time,head\na,1.0,n\nb,1.0,o\nc,2.0,n\n", "ev.csv")
    ev = read_events_csv(p)
    assert np.all(np.isnan(ev.beta_rad))
    assert ev.exposure_id.tolist() == [0, 0, 1]


BAD_EVENT_CASES = {
    "missing head column": ("image,time,head,beta,exposure", "image,time,beta,exposure", 3, "head", None),
    "unknown column": ("image,time,head,beta,exposure", "image,time,head,beta,exposure,iso", 3, "iso", None),
    "angles missing with beta": ("# angles: deg\n", "", 2, "angles", None),
    "nan time": ("img_0001_o.jpg,100.2", "img_0001_o.jpg,nan", 5, "time", None),
    "nan beta": ("oblique,-35.5", "oblique,nan", 5, "beta", None),
    "text beta": ("oblique,-35.5", "oblique,abc", 5, "beta", None),
    "radians claimed, degrees given": ("# angles: deg", "# angles: rad", 5, "beta", ImplausibleAngleError),
    "exposure not integer": ("-35.5,1", "-35.5,1.5", 5, "exposure", None),
    "duplicate image": ("img, 0002_n.jpg", "img_0001_n.jpg", 6, "image", None),
    "empty head": ("100.7,nadir", "100.7,", 6, "head", None),
    "short row": (",100.7,nadir,,2", ",100.7,nadir", 6, None, None),
}


@pytest.mark.parametrize("case", list(BAD_EVENT_CASES))
def test_bad_events_csv_names_line_and_field(tmp_path, case):
    old, new, line, field, cls = BAD_EVENT_CASES[case]
    assert old in EVENTS
    p = _write(tmp_path, EVENTS.replace(old, new, 1), "ev.csv")
    with pytest.raises(InputFormatError) as ei:
        read_events_csv(p)
    assert (ei.value.path, ei.value.line, ei.value.field) == (str(p), line, field), str(ei.value)
    if cls is not None:
        assert isinstance(ei.value, cls)


def test_event_outside_trajectory_span_names_events_file_line(tmp_path):
    tr = read_trajectory_csv(_write(tmp_path, GOOD))  # spans 100.0 .. 101.0
    p = _write(tmp_path, EVENTS.replace("100.7,nadir", "101.7,nadir"), "ev.csv")
    ev = read_events_csv(p)
    with pytest.raises(EventOutOfSpanError) as ei:
        check_events_in_span(ev, tr)
    assert (ei.value.path, ei.value.line, ei.value.field) == (str(p), 6, "time")


# ---------------------------------------------------------------------------- SBET
def _synthetic_sbet(n=40):
    rng = np.random.default_rng(11)
    rec = np.zeros((n, 17))
    rec[:, 0] = 400000.0 + 0.005 * np.arange(n)
    rec[:, 1] = np.radians(-33.9 + 1e-6 * np.arange(n))
    rec[:, 2] = np.radians(151.2 - 1e-6 * np.arange(n))
    rec[:, 3] = 600.0 + 0.01 * np.arange(n)
    # velocities of that motion (north, east, down: wander angle 0) with noise; their speed matches the positions'
    rec[:, 4] = np.radians(1e-6) * 6_356_752.0 / 0.005 + rng.normal(0, 0.05, n)
    rec[:, 5] = -np.radians(1e-6) * 6_378_137.0 * np.cos(np.radians(-33.9)) / 0.005 + rng.normal(0, 0.05, n)
    rec[:, 6] = -0.01 / 0.005 + rng.normal(0, 0.05, n)
    rec[:, 7] = np.radians(rng.uniform(-10, 10, n))
    rec[:, 8] = np.radians(rng.uniform(-5, 5, n))
    rec[:, 9] = np.radians(rng.uniform(-179, 179, n))
    rec[:, 10:] = rng.normal(0, 1, (n, 7))
    return rec


def test_sbet_read_numpy_written_file(tmp_path):
    rec = _synthetic_sbet()
    p = tmp_path / "sbet_test.out"
    p.write_bytes(rec.astype("<f8").tobytes())  # written independently of skyrig
    assert p.stat().st_size == rec.shape[0] * 136
    tr = read_sbet(p)
    assert tr.time_system == "gps-sow" and tr.velocity_ned is None
    np.testing.assert_array_equal(tr.time_s, rec[:, 0])
    np.testing.assert_allclose(tr.lat_deg, np.degrees(rec[:, 1]), atol=1e-12)
    np.testing.assert_allclose(tr.lon_deg, np.degrees(rec[:, 2]), atol=1e-12)
    np.testing.assert_allclose(tr.h_m, rec[:, 3], atol=1e-12)
    r, pi, y = tr.rpy("rad")
    np.testing.assert_allclose(np.stack([r, pi, y], 1), rec[:, 7:10], atol=1e-12)
    raw = read_sbet_records(p)
    for k, name in enumerate(SBET_FIELDS):
        np.testing.assert_array_equal(raw[name], rec[:, k])


def test_sbet_write_round_trip(tmp_path):
    rec = _synthetic_sbet()
    src = tmp_path / "a.out"
    src.write_bytes(rec.astype("<f8").tobytes())
    tr = read_sbet(src)
    extra = {name: rec[:, k] for k, name in enumerate(SBET_FIELDS) if k in (4, 5, 6) or k >= 10}
    dst = tmp_path / "b.out"
    write_sbet(dst, tr, extra=extra)
    back = np.frombuffer(dst.read_bytes(), "<f8").reshape(-1, 17)
    np.testing.assert_array_equal(back[:, [0, 3] + list(range(4, 7)) + list(range(10, 17))],
                                  rec[:, [0, 3] + list(range(4, 7)) + list(range(10, 17))])
    np.testing.assert_allclose(back[:, 1:3], rec[:, 1:3], atol=1e-15)
    np.testing.assert_allclose(back[:, 7:10], rec[:, 7:10], atol=1e-12)


def test_sbet_bad_files(tmp_path):
    rec = _synthetic_sbet(5)
    p = tmp_path / "trunc.out"
    p.write_bytes(rec.astype("<f8").tobytes()[:-8])
    with pytest.raises(InputFormatError) as ei:
        read_sbet(p)
    assert ei.value.line == 5 and "136" in str(ei.value)
    bad = rec.copy()
    bad[3, 8] = np.nan
    p.write_bytes(bad.astype("<f8").tobytes())
    with pytest.raises(InputFormatError) as ei:
        read_sbet(p)
    assert (ei.value.line, ei.value.field) == (4, "pitch")
    bad = rec.copy()
    bad[2, 0] = bad[1, 0]
    p.write_bytes(bad.astype("<f8").tobytes())
    with pytest.raises(InputFormatError) as ei:
        read_sbet(p)
    assert (ei.value.line, ei.value.field) == (3, "time")
    bad = rec.copy()
    bad[:, 1] = np.degrees(bad[:, 1])  # degrees where radians belong
    p.write_bytes(bad.astype("<f8").tobytes())
    with pytest.raises(InputFormatError) as ei:
        read_sbet(p)
    assert (ei.value.line, ei.value.field) == (1, "latitude")
