"""skyrig lidar georef | register | compare through click, and the LAS/LAZ and raw-scan CSV formats."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from conftest import shared_path
from skyrig.cli.lidar import command as lidar
from skyrig.errors import InputFormatError
from skyrig.io.laz import read_las, write_las
from skyrig.io.raw_scan_csv import read_raw_scan_csv, write_raw_scan_csv
from skyrig.lidar.scanner import RawScan

pytest.importorskip("laspy")


def test_las_round_trip_with_crs_and_extra_dimension(tmp_path):
    rng = np.random.default_rng(0)
    x = rng.uniform(0, 100, (500, 3)) + [500000.0, 5650000.0, 100.0]
    write_las(tmp_path / "a.laz", x, "EPSG:32633", gps_time=np.arange(500) + 0.25, intensity=np.arange(500),
              scan_angle_deg=np.linspace(-135, 135, 500), extra={"distance": np.linspace(-1, 1, 500)})
    r = read_las(tmp_path / "a.laz", require_crs=True)
    assert np.abs(r.xyz - x).max() <= 0.0005 + 1e-9
    assert "UTM zone 33N" in r.crs_wkt
    np.testing.assert_allclose(r.gps_time, np.arange(500) + 0.25)
    np.testing.assert_allclose(r.scan_angle_deg, np.linspace(-135, 135, 500), atol=0.003)
    np.testing.assert_allclose(r.extra["distance"], np.linspace(-1, 1, 500))
    import laspy

    h = laspy.read(tmp_path / "a.laz").header
    assert str(h.version) == "1.4" and h.point_format.id == 6 and h.global_encoding.wkt


def test_las_without_crs_is_an_error_when_required(tmp_path):
    import laspy

    las = laspy.LasData(laspy.LasHeader(point_format=3, version="1.2"))
    las.x, las.y, las.z = np.arange(3.0), np.arange(3.0), np.arange(3.0)
    las.write(tmp_path / "nocrs.las")
    assert read_las(tmp_path / "nocrs.las").crs_wkt is None
    with pytest.raises(InputFormatError, match="no CRS") as e:
        read_las(tmp_path / "nocrs.las", require_crs=True)
    assert e.value.field == "crs" and "nocrs.las" in str(e.value)
    r = CliRunner().invoke(lidar, ["compare", "--compared", str(tmp_path / "nocrs.las"), "--reference",
                                   str(tmp_path / "nocrs.las"), "-o", str(tmp_path / "out.las")])
    assert r.exit_code != 0 and "CRS" in str(r.exception)


def test_raw_scan_csv_round_trip_and_errors(tmp_path):
    s = RawScan(np.array([1.0, 1.5, 1.5, 2.0]), np.array([3.0, 4.0, 5.0, 6.0]), np.radians([-10.0, 0.0, 10.0, 20.0]),
                intensity=np.array([1.0, 2.0, 3.0, 4.0]))
    write_raw_scan_csv(tmp_path / "s.csv", s)
    r, hdr = read_raw_scan_csv(tmp_path / "s.csv")
    np.testing.assert_allclose(r.alpha_rad, s.alpha_rad, atol=1e-8)
    np.testing.assert_allclose(r.range_m, s.range_m)
    assert hdr["angles"] == "deg"
    lines = (tmp_path / "s.csv").read_text().splitlines()
    bad = lines[:5] + ["0.5,3.0,1.0,1"] + lines[5:]
    (tmp_path / "bad.csv").write_text("\n".join(bad) + "\n")
    with pytest.raises(InputFormatError, match="must not decrease") as e:
        read_raw_scan_csv(tmp_path / "bad.csv")
    assert e.value.line == 6 and e.value.field == "time"
    bad2 = lines[:5] + ["2.5,abc,1.0,1"]
    (tmp_path / "bad2.csv").write_text("\n".join(bad2) + "\n")
    with pytest.raises(InputFormatError) as e:
        read_raw_scan_csv(tmp_path / "bad2.csv")
    assert e.value.line == 6 and e.value.field == "range"


def test_cli_compare_m3c2_on_autzen(tmp_path):
    d = shared_path("autzen-lidar")
    out, js, png = tmp_path / "m3c2.laz", tmp_path / "s.json", tmp_path / "h.png"
    r = CliRunner().invoke(lidar, ["compare", "--method", "m3c2", "--reference", str(d / "autzen-bmx-2010.las"),
                                   "--compared", str(d / "autzen-bmx-2023.las"), "--core",
                                   str(d / "autzen-bmx-largersample.txt"), "--normal-radius", "1.390432",
                                   "--cylinder-radius", "2.890432", "--half-length", "5.5", "-o", str(out),
                                   "--stats", str(js), "--histogram", str(png)])
    assert r.exit_code == 0, r.output + repr(r.exception)
    cc = np.genfromtxt(d / "autzen-bmx-cc.txt", delimiter=",", names=True)
    las = read_las(out, require_crs=True)
    dist = las.extra["m3c2_distance"]
    ok = (dist != -9999.0) & np.isfinite(cc["M3C2_distance"])
    assert ok.sum() >= 90
    assert np.abs(dist[ok] - cc["M3C2_distance"][ok]).max() < 0.01
    assert np.array_equal(las.extra["m3c2_significant"] == 1, cc["significant_change"] == 1)
    st = json.loads(js.read_text())
    assert st["count"] == ok.sum()
    assert png.read_bytes()[:4] == b"\x89PNG"


def test_cli_register_recovers_a_shift(tmp_path):
    rng = np.random.default_rng(2)
    xy = rng.uniform(0, 40, (8000, 2))
    z = 2 * np.sin(xy[:, 0] / 5) + np.cos(xy[:, 1] / 4)
    tgt = np.c_[xy, z] + [500000.0, 5650000.0, 100.0]
    shift = np.array([0.3, -0.2, 0.15])
    write_las(tmp_path / "t.las", tgt, "EPSG:32633")
    write_las(tmp_path / "s.las", tgt[::2] - shift, "EPSG:32633")
    # three homologous points for the coarse step
    hp = np.c_[tgt[:3] - shift, tgt[:3]]
    np.savetxt(tmp_path / "hp.csv", hp, delimiter=",", header="sx,sy,sz,tx,ty,tz", comments="", fmt="%.4f")
    r = CliRunner().invoke(lidar, ["register", "--source", str(tmp_path / "s.las"), "--target", str(tmp_path / "t.las"),
                                   "--points", str(tmp_path / "hp.csv"), "--method", "point_to_point",
                                   "--max-distance", "0.5", "-o", str(tmp_path / "reg.laz"),
                                   "--matrix", str(tmp_path / "m.txt")])
    assert r.exit_code == 0, r.output + repr(r.exception)
    m = np.loadtxt(tmp_path / "m.txt")
    np.testing.assert_allclose(m[:3, 3], shift, atol=0.005)
    moved = read_las(tmp_path / "reg.laz").xyz
    assert np.abs(moved - tgt[::2]).max() < 0.01


def test_cli_georef_matches_truth(tmp_path):
    from test_lidar_georef import BODY_FROM_SCANNER, LEVER, ORIGIN, make_trajectory, simulate

    from skyrig.georef.eo import WorldFrame
    from skyrig.io.trajectory_csv import write_trajectory_csv
    from skyrig.lidar.georef import ScannerMount

    traj = make_trajectory(duration=1.0)
    scan, truth, _, _ = simulate(traj, ScannerMount(BODY_FROM_SCANNER, LEVER), duration=0.5)
    write_trajectory_csv(tmp_path / "t.csv", traj)
    write_raw_scan_csv(tmp_path / "s.csv", scan)
    mounting = ",".join(str(v) for v in BODY_FROM_SCANNER.ravel())
    r = CliRunner().invoke(lidar, ["georef", "--scan", str(tmp_path / "s.csv"), "--trajectory", str(tmp_path / "t.csv"),
                                   "--lever-arm", ",".join(map(str, LEVER)), "--mounting", mounting,
                                   "--crs", "EPSG:32633", "-o", str(tmp_path / "g.laz")])
    assert r.exit_code == 0, r.output + repr(r.exception)
    las = read_las(tmp_path / "g.laz", require_crs=True)
    utm = WorldFrame.map("EPSG:32633")
    expect = utm.from_ecef(WorldFrame.local(*ORIGIN).to_ecef(truth))
    # CSV rounding: 0.1 mm range, 1e-6 deg angles at 30 m, trajectory CSV digits; LAS 1 mm steps
    assert np.abs(las.xyz - expect).max() < 0.003
    np.testing.assert_allclose(las.gps_time, scan.time_s, atol=1e-6)
