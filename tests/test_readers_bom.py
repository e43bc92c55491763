"""Every text reader accepts a UTF-8 byte-order mark (Excel's "CSV UTF-8" writes one): a BOM-prefixed file
reads back equal to the same file without it. (SBET is binary: not concerned.)"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from skyrig.geometry import matrix_from_opk
from skyrig.georef.eo import ExteriorOrientations, WorldFrame
from skyrig.georef.observations import GroundPoints, ImageMeasurements

BOM = b"\xef\xbb\xbf"
UTM = WorldFrame.map("EPSG:25832")


def _eo(frame=UTM, n=4):
    rng = np.random.default_rng(3)
    c = np.column_stack([rng.uniform(5e5, 5.1e5, n), rng.uniform(5.7e6, 5.71e6, n), rng.uniform(800, 1200, n)])
    if frame.projection.crs.is_geographic:
        c[:, 0], c[:, 1] = 13.4 + (c[:, 0] - 5e5) * 1e-5, 52.5 + (c[:, 1] - 5.7e6) * 1e-5
    r = matrix_from_opk(rng.uniform(-5, 5, n), rng.uniform(-5, 5, n), rng.uniform(-180, 180, n), unit="deg")
    return ExteriorOrientations([f"i{k}.tif" for k in range(n)], ["nadir"] * n, c, r, frame,
                                time_s=np.arange(n) * 1.5, head=["nadir"] * n, exposure=np.arange(n))


def _points(frame=UTM):
    return GroundPoints(np.array(["p1", "p2"]), np.array([[500100.0, 5700200.0, 310.5], [500300.25, 5700400.0, 298.0]]),
                        frame)


def _measurements():
    return ImageMeasurements(np.array(["p1", "p2", "p1"]), np.array(["i0.tif", "i0.tif", "i1.tif"]),
                             np.array([[100.5, 200.25], [1500.0, 20.0], [7.0, 9.0]]))


# ------------------------------------------------------------------------------------------------ one writer each
def _w_points_csv(p):
    from skyrig.io.points_csv import read_points_csv, write_points_csv

    write_points_csv(p / "gcp.csv", _points())
    return "gcp.csv", read_points_csv


def _w_measurements_csv(p):
    from skyrig.io.points_csv import read_measurements_csv, write_measurements_csv

    write_measurements_csv(p / "mes.csv", _measurements())
    return "mes.csv", read_measurements_csv


def _w_eo_csv(p):
    from skyrig.io.eo_csv import read_eo_csv, write_eo_csv

    write_eo_csv(_eo(), p / "eo.csv")
    return "eo.csv", read_eo_csv


def _w_trajectory_csv(p):
    from skyrig.io.trajectory_csv import read_trajectory_csv, write_trajectory_csv
    from skyrig.trajectory import Trajectory

    n = 20
    t = 345600.0 + 0.005 * np.arange(n)
    tr = Trajectory.from_rpy(t, 48.3 + 1e-5 * np.arange(n), 13.0 + 2e-5 * np.arange(n), np.full(n, 900.0),
                             np.zeros(n), np.ones(n), np.linspace(10, 20, n), "deg", reference="antenna")
    write_trajectory_csv(p / "traj.csv", tr, angles="deg")
    return "traj.csv", read_trajectory_csv


def _w_events_csv(p):
    from skyrig.io.events_csv import read_events_csv

    (p / "events.csv").write_text("# skyrig-events 1\n# angles: deg\nimage,time,head,beta,exposure\n"
                                  "a.jpg,345600.0,nadir,,1\nb.jpg,345600.0,oblique,-35.5,1\nc.jpg,345601.5,nadir,,2\n",
                                  encoding="utf-8")
    return "events.csv", read_events_csv


def _w_rig(p):
    from skyrig.io.rig_file import read_rig, write_rig
    from skyrig.rig import preset

    write_rig(preset("midas"), p / "rig.yaml")
    return "rig.yaml", read_rig


def _w_ign_opk(p):
    from skyrig.io.ign import read_ign_opk, write_ign_opk

    write_ign_opk(p / "a.OPK", _eo(WorldFrame.map("EPSG:2154")))
    return "a.OPK", lambda path: read_ign_opk(path, WorldFrame.map("EPSG:2154"))


def _w_ign_mes(p):
    from skyrig.io.ign import read_ign_measurements

    (p / "t.mes").write_text('"p1" i0.tif 100.5 200.25\np2 i0.tif 1500 20\n', encoding="utf-8")
    return "t.mes", read_ign_measurements


def _w_ign_app(p):
    from skyrig.io.ign import read_ign_ground_points

    (p / "g.app").write_text('"p1" 3 650100.0 6860200.0 53.5\n"p2" 3 650300.0 6860400.0 60.0\n', encoding="utf-8")
    return "g.app", lambda path: read_ign_ground_points(path, WorldFrame.map("EPSG:2154"))


def _w_ign_camera(p):
    from skyrig.io.ign import read_ign_camera

    (p / "Camera1.txt").write_text("Name = UCE1\nPPAx = 8657.5\nPPAy = 5600.0\nfocal = 30000.0\nwidth = 17310\n"
                                   "height = 11310\n", encoding="utf-8")
    return "Camera1.txt", read_ign_camera


def _w_odm_gcp_list(p):
    from skyrig.io.odm import read_gcp_list, write_gcp_list

    write_gcp_list(p / "gcp_list.txt", _points(), _measurements())
    return "gcp_list.txt", read_gcp_list


def _w_odm_geo_txt(p):
    from skyrig.io.odm import read_geo_txt, write_geo_txt

    write_geo_txt(p / "geo.txt", _eo(WorldFrame.map("EPSG:4326")))
    return "geo.txt", read_geo_txt


def _w_raw_scan_csv(p):
    from skyrig.io.raw_scan_csv import read_raw_scan_csv, write_raw_scan_csv
    from skyrig.lidar import RawScan

    write_raw_scan_csv(p / "scan.csv", RawScan(np.array([1.0, 1.5, 2.0]), np.array([3.0, 4.0, 5.0]),
                                               np.radians([-10.0, 0.0, 10.0]), intensity=np.array([1.0, 2.0, 3.0])))
    return "scan.csv", read_raw_scan_csv


def _w_bal(p):
    from skyrig.io.bal import read_bal

    cam = " ".join(["0.01", "-0.02", "0.03", "0.1", "0.2", "-5.0", "500.0", "0.0", "0.0"])
    (p / "problem.txt").write_text("1 2 2\n0 0 1.5 -2.5\n0 1 3.0 4.0\n" + cam.replace(" ", "\n") + "\n"
                                   "1.0 2.0 3.0\n-1.0 0.5 2.0\n", encoding="utf-8")
    return "problem.txt", read_bal


READERS = {
    "points-csv": _w_points_csv, "measurements-csv": _w_measurements_csv, "eo-csv": _w_eo_csv,
    "trajectory-csv": _w_trajectory_csv, "events-csv": _w_events_csv, "rig-yaml": _w_rig, "ign-opk": _w_ign_opk,
    "ign-mes": _w_ign_mes, "ign-app": _w_ign_app, "ign-camera": _w_ign_camera, "odm-gcp-list": _w_odm_gcp_list,
    "odm-geo-txt": _w_odm_geo_txt, "raw-scan-csv": _w_raw_scan_csv, "bal": _w_bal,
}


def _same(a, b, where="value"):
    """Deep equality of reader results: dataclasses / objects field by field, arrays exactly (NaN == NaN)."""
    if isinstance(a, Path | str) and isinstance(b, Path | str):
        assert str(a).replace("/plain/", "/bom/") == str(b), where
    elif isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        assert a.shape == b.shape and a.dtype == b.dtype, where
        if a.dtype.kind in "fc":
            np.testing.assert_array_equal(a, b, err_msg=where)
        else:
            assert [str(x).replace("/plain/", "/bom/") for x in a.ravel()] == [str(x) for x in b.ravel()], where
    elif isinstance(a, dict) and isinstance(b, dict):
        assert a.keys() == b.keys(), where
        for k in a:
            _same(a[k], b[k], f"{where}[{k!r}]")
    elif isinstance(a, list | tuple) and isinstance(b, list | tuple):
        assert len(a) == len(b), where
        for k, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{where}[{k}]")
    elif dataclasses.is_dataclass(a) and not isinstance(a, type):
        assert type(a) is type(b), where
        for f in dataclasses.fields(a):
            _same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    elif isinstance(a, float) and isinstance(b, float) and np.isnan(a):
        assert np.isnan(b), where
    else:
        try:
            eq = a == b
        except Exception:  # objects without a usable equality: compare their public state
            eq = NotImplemented
        if eq is NotImplemented or not isinstance(eq, bool | np.bool_):
            _same({k: v for k, v in vars(a).items() if not k.startswith("_")},
                  {k: v for k, v in vars(b).items() if not k.startswith("_")}, where)
        else:
            assert eq, where


@pytest.mark.parametrize("fmt", sorted(READERS))
def test_reader_accepts_utf8_bom(tmp_path, fmt):
    plain, bom = tmp_path / "plain", tmp_path / "bom"
    plain.mkdir()
    bom.mkdir()
    name, read = READERS[fmt](plain)
    data = (plain / name).read_bytes()
    assert not data.startswith(BOM)
    (bom / name).write_bytes(BOM + data)
    for side in plain.iterdir():  # side-cars (NAME.csv.json, .csvt, .prj) travel with their table unchanged
        if side.name != name and side.is_file():
            (bom / side.name).write_bytes(side.read_bytes())
    _same(read(plain / name), read(bom / name), fmt)
