"""Issue 13 acceptance: adjusted coordinates read from skyrig's outputs with GDAL (pyogrio) and pyproj alone equal
the simulation truth within their predicted precision, in the project CRS with its stated heights.

* MIDAS: the ``make demo`` chain on the simulated MIDAS flight (scenario ``midas-demo``) without rendering: the
  simulator's natural tie points (``tie/image_measurements.csv``, no false matches) stand in for ``skyrig match``;
  ``skyrig block`` (recorded GNSS/IMU, ties, GCPs in EPSG:25832 ellipsoidal heights) and ``skyrig adjust``.
* UAV: the seeded simulated UAV block of ``tests/test_uav_adjust.py`` (local frame at 50.85 N 0.15 W), written by
  adjust-uav's writer in its UTM zone (EPSG:32630).

The truth is in the simulator's local ENU frame; it is carried to the map CRS by a PROJ pipeline written here
(inverse topocentric, inverse cartesian, the CRS's projection): nothing of skyrig reads or converts the outputs.
"""

from __future__ import annotations

import csv
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyproj
import pytest
from click.testing import CliRunner
from pyogrio.raw import read as ogr_read

pytest.importorskip("pyogrio")
shapely = pytest.importorskip("shapely")


def _local_to(crs: str, origin: tuple[float, float, float], xyz: np.ndarray) -> np.ndarray:
    """Local ENU (WGS84 tangent plane at ``origin``) -> ``crs`` (3D, ellipsoidal heights) with PROJ alone."""
    lat0, lon0, h0 = origin
    to_geo = pyproj.Transformer.from_pipeline(
        f"+proj=pipeline +step +inv +proj=topocentric +ellps=WGS84 +lat_0={lat0!r} +lon_0={lon0!r} +h_0={h0!r} "
        "+step +inv +proj=cart +ellps=WGS84 +step +proj=unitconvert +xy_in=rad +xy_out=deg")
    lon, lat, h = to_geo.transform(xyz[:, 0], xyz[:, 1], xyz[:, 2])
    t = pyproj.Transformer.from_crs("EPSG:4979", pyproj.CRS(crs).to_3d(), always_xy=True)
    x, y, z = t.transform(lon, lat, h)
    return np.column_stack([x, y, z])


def _read_truth_csv(path: Path) -> tuple[dict[str, np.ndarray], tuple[float, float, float]]:
    """A skyrig points table (plain CSV + NAME.csv.json side-car) with the csv and json modules."""
    side = json.loads(Path(str(path) + ".json").read_text())
    kind, *o = side["frame"].split()
    assert kind == "local", side["frame"]
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    return {r["name"]: np.array([float(r["x"]), float(r["y"]), float(r["z"])]) for r in rows}, tuple(map(float, o))


def _gdal_points(path: Path, layer: str | None = None) -> tuple[pyproj.CRS, dict[str, dict], np.ndarray]:
    """Features of a GeoPackage layer or a CSV (via its .csvt / .prj) read by GDAL: (CRS, fields by name, xyz)."""
    meta, _, geom, fields = ogr_read(str(path), layer=layer)
    names = list(meta["fields"])
    g = shapely.from_wkb(geom)
    assert bool(np.all(shapely.has_z(g))), "3D points expected"
    xyz = shapely.get_coordinates(g, include_z=True)
    col = {n: np.asarray(v) for n, v in zip(names, fields)}
    return pyproj.CRS(meta["crs"]), col, xyz


def _axis_report(label: str, d: np.ndarray, s: np.ndarray) -> str:
    r = np.abs(d) / s
    return (f"{label}: n={len(d)}, |adjusted - truth| max E/N/h " + "/".join(f"{v * 100:.2f}" for v in np.abs(d).max(0))
            + " cm, sigma median " + "/".join(f"{v * 100:.2f}" for v in np.median(s, 0)) + " cm, max |d|/sigma "
            + "/".join(f"{v:.2f}" for v in r.max(0)) + ", RMS d/sigma " + "/".join(f"{v:.2f}" for v in
                                                                                   np.sqrt(np.mean(r ** 2, 0))))


# ------------------------------------------------------------------------------------------------ MIDAS
@pytest.fixture(scope="module")
def midas(tmp_path_factory):
    from skyrig.cli import main
    from skyrig.pipeline.simulate import write_project
    from skyrig.simulate.scenarios import build_survey, scenario_spec

    out = tmp_path_factory.mktemp("midas")
    spec = scenario_spec("midas-demo", "ci", 1)
    spec = replace(spec, errors=replace(spec.errors, tie_points=400, wrong_tie_points=0))
    write_project(build_survey(spec), out / "sim", images=False)
    sim = out / "sim"
    blk = out / "block" / "block.json"
    r = CliRunner().invoke(main, [
        "block", "--trajectory", str(sim / "trajectory.csv"), "--events", str(sim / "events.csv"),
        "--rig", str(sim / "rig.yaml"), "--measurements", str(sim / "tie" / "image_measurements.csv"),
        "--measurements", str(sim / "gcp" / "image_measurements.csv"),
        "--control", str(sim / "gcp" / "ground_points.csv"), "--check", str(sim / "gcp" / "check_points.csv"),
        "--image-sigma-px", "0.3", "--gnss-sigma", "0.03,0.03,0.05", "--imu-sigma-deg", "0.003,0.003,0.006",
        "--control-sigma", "0.01", "-o", str(blk)])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, ["adjust", str(blk), "-o", str(out / "adjust")])
    assert r.exit_code == 0, r.output
    return sim, out / "adjust", blk


@pytest.mark.slow  # the MIDAS simulation and adjustment: ~30 s
def test_midas_block_records_the_project_crs(midas):
    _, _, blk = midas
    man = json.loads(blk.read_text())
    assert man["crs"] == "EPSG:25832; heights: ellipsoidal"
    assert man["frame"].startswith("local ")


@pytest.mark.slow  # the MIDAS simulation and adjustment: ~30 s
@pytest.mark.parametrize("source", ["gpkg", "csv"])
def test_midas_check_points_in_epsg25832_equal_truth_within_sigma(midas, source):
    sim, adj, _ = midas
    if source == "gpkg":
        crs, col, xyz = _gdal_points(adj / "adjusted.gpkg", "points")
        sig = np.column_stack([col["sx_m"], col["sy_m"], col["sz_m"]]).astype(float)
    else:
        crs, col, xyz = _gdal_points(adj / "points.csv")
        sig = np.column_stack([col["sx"], col["sy"], col["sz"]]).astype(float)
    # the CRS GDAL reads: ETRS89 / UTM 32N with ellipsoidal heights (a 3D projected CRS)
    assert crs.to_2d().equals(pyproj.CRS("EPSG:25832").to_2d()) or crs.to_2d().to_epsg() == 25832, crs.to_wkt()
    if source == "csv":
        assert len(crs.axis_info) == 3 and "ellipsoidal" in crs.axis_info[2].name.lower(), crs.axis_info
    words = json.loads((adj / "points.csv.json").read_text())
    assert words["frame"] == "EPSG:25832; heights: ellipsoidal" and "ellipsoidal" in words["vertical"]
    truth, origin = _read_truth_csv(sim / "truth" / "points.csv")
    role = col["role"].astype(str)
    name = col["name"].astype(str)
    for which in ("check", "control"):
        sel = np.flatnonzero(role == which)
        assert len(sel) >= 3
        t = _local_to("EPSG:25832", origin, np.array([truth[n] for n in name[sel]]))
        d = xyz[sel] - t
        print(_axis_report(f"MIDAS {which} points ({source}, EPSG:25832 ellipsoidal)", d, sig[sel]))
        assert np.all(np.isfinite(sig[sel])) and np.all(sig[sel] > 0)
        assert np.all(np.abs(d) < 3 * sig[sel]), (np.abs(d) / sig[sel]).max(0)


@pytest.mark.slow  # the MIDAS simulation and adjustment: ~30 s
def test_midas_ground_residual_lines_and_centres(midas):
    sim, adj, _ = midas
    meta, _, geom, fields = ogr_read(str(adj / "adjusted.gpkg"), layer="ground_residuals")
    lines = shapely.from_wkb(geom)
    col = dict(zip(meta["fields"], fields))
    ends = np.array([shapely.get_coordinates(g, include_z=True) for g in lines])
    v = ends[:, 1] - ends[:, 0]
    np.testing.assert_allclose(v[:, 0], col["vx_m"], atol=1e-6)
    np.testing.assert_allclose(v[:, 2], col["vz_m"], atol=1e-6)
    # projection centres vs the truth EO in the map CRS (skyrig's own truth/eo_map.csv read as plain CSV)
    crs, c, xyz = _gdal_points(adj / "adjusted.gpkg", "projection_centres")
    with open(sim / "truth" / "eo_map.csv", newline="") as fh:
        tr = {r["image"]: np.array([float(r["x"]), float(r["y"]), float(r["z"])]) for r in csv.DictReader(fh)}
    d = xyz - np.array([tr[n] for n in c["image"].astype(str)])
    assert np.sqrt(np.mean(d ** 2)) < 0.1, np.abs(d).max(0)
    # the report's check table is in the same CRS: V = adjusted - given of ground_control.csv
    rep = json.loads((adj / "report.json").read_text())
    assert rep["summary"]["frame"] == "EPSG:25832; heights: ellipsoidal"
    assert rep["summary"]["adjusted_in"].startswith("local ")


@pytest.mark.slow  # the MIDAS simulation and adjustment: ~30 s
def test_midas_outputs_still_read_by_skyrig(midas):
    from skyrig.io.eo_csv import read_eo_csv
    from skyrig.io.points_csv import read_points_csv

    _, adj, _ = midas
    eo = read_eo_csv(adj / "eo.csv")
    assert eo.frame.kind == "map" and eo.frame.crs == "EPSG:25832" and eo.frame.geoid is None
    assert not (adj / "eo.csv").read_text().startswith("#")
    pts = read_points_csv(adj / "points.csv")
    assert pts.frame == eo.frame


# ------------------------------------------------------------------------------------------------ UAV
@pytest.fixture(scope="module")
def uav(tmp_path_factory):
    from test_uav_adjust import _sim_block

    from skyrig.adjust.report import adjustment_report
    from skyrig.pipeline.uav import UavConfig, _write_outputs, adjust_uav_block, uav_project_frame

    inp, truth = _sim_block()
    cfg = UavConfig(gnss_sigma_m=(0.5, 0.5, 1.0), pixel_sigma_px=0.3, attitude_sigma_deg=5.0, pnp_threshold_px=4.0)
    res = adjust_uav_block(inp, cfg)
    project = uav_project_frame(inp)
    out = tmp_path_factory.mktemp("uav")
    _write_outputs(out, res, adjustment_report(res.adjustment, frames=(inp.frame, project)), inp, project)
    return inp, truth, res, out


def test_uav_points_in_utm_zone_equal_truth_within_sigma(uav):
    inp, truth, res, out = uav
    crs, col, xyz = _gdal_points(out / "adjusted.gpkg", "points")
    assert crs.to_2d().to_epsg() == 32630, crs.name  # UTM 30N: 0.15 W
    sig = np.column_stack([col["sx_m"], col["sy_m"], col["sz_m"]]).astype(float)
    k = np.array([int(n[1:]) for n in col["name"].astype(str)])
    t = _local_to("EPSG:32630", inp.frame.origin, truth["X"][k])
    d = xyz - t
    ok = np.isfinite(sig).all(1)
    assert ok.mean() > 0.95
    print(_axis_report("UAV tie points (gpkg, EPSG:32630 ellipsoidal)", d[ok], sig[ok]))
    # 4 sigma as in test_uav_adjust; the few points a mismatch pulled are data snooping's leftovers
    assert np.mean(np.all(np.abs(d[ok]) < 4 * sig[ok], axis=1)) > 0.99
    r = np.abs(d[ok]) / sig[ok]
    assert np.all(np.sqrt(np.mean(r ** 2, 0)) < 1.5)


def test_uav_csv_and_centres_in_utm(uav):
    inp, truth, res, out = uav
    crs, col, xyz = _gdal_points(out / "eo.csv")
    assert crs.to_2d().to_epsg() == 32630 and len(crs.axis_info) == 3
    k = np.array([int(n[4:7]) for n in col["image"].astype(str)])
    t = _local_to("EPSG:32630", inp.frame.origin, truth["C"][k])
    ps = res.adjustment.pose_sigma
    d = xyz - t
    print(_axis_report("UAV projection centres (eo.csv, EPSG:32630 ellipsoidal)", d, ps[:, :3]))
    assert np.all(np.abs(d) < 4 * ps[:, :3] + 1e-3)
