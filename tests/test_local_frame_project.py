"""Issue 29, open line: ``init`` refused the frame-free forms the EO headers accept (``local <lat> <lon> <h>``).

A project whose ``crs:`` is a local ENU frame now runs: inputs in the frame convert exactly (through ECEF), products
are written in the CRS files carry for it (orthographic at its origin on WGS 84, WGS 84 ellipsoidal heights,
:mod:`skyrig.geodesy.local_crs`), and the side-cars say how far that is from ENU.  Checked against PROJ: its
topocentric conversion (ENU) and its own transformation into the carried CRS.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyproj
import pytest
from click.testing import CliRunner

from skyrig.cli import main
from skyrig.geodesy.frame import WorldFrame
from skyrig.geodesy.local_crs import carried_crs, carried_frame, enu_departure, local_of_carried
from test_bad_input_cli import EO, EVENTS, RIG, TRAJ

ORIGIN = (43.64, 4.57, 1807.36)  # a block in the Alps' foothills: a high origin shows the horizontal departure
R_EARTH = 6_371_000.0


def _run(*args):
    r = CliRunner().invoke(main, [str(a) for a in args])
    assert "Traceback" not in r.output, r.output
    assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
    return r


def _proj_enu(origin, lat, lon, h):
    """ENU from PROJ's topocentric conversion (independent of skyrig's tangent-frame code)."""
    t = pyproj.Transformer.from_pipeline(
        "+proj=pipeline +step +proj=axisswap +order=2,1 +step +proj=unitconvert +xy_in=deg +xy_out=rad "
        f"+step +proj=cart +ellps=WGS84 +step +proj=topocentric +ellps=WGS84 +lat_0={origin[0]} +lon_0={origin[1]} "
        f"+h_0={origin[2]}")
    return np.stack(t.transform(lat, lon, h), axis=1)


def _ring(origin, d, h):
    a = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    lat = origin[0] + d * np.sin(a) / 111_132.0
    lon = origin[1] + d * np.cos(a) / (111_320.0 * np.cos(np.radians(origin[0])))
    return lat, lon, np.full(a.shape, float(h))


def test_skyrig_local_frame_is_proj_topocentric():
    rng = np.random.default_rng(3)
    lat = ORIGIN[0] + rng.uniform(-0.05, 0.05, 50)
    lon = ORIGIN[1] + rng.uniform(-0.05, 0.05, 50)
    h = rng.uniform(0, 3000, 50)
    g = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    xyz = np.stack(g.transform(lon, lat, h), axis=1)
    ours = WorldFrame.local(*ORIGIN).from_ecef(xyz)
    assert np.abs(ours - _proj_enu(ORIGIN, lat, lon, h)).max() < 1e-6


def test_carried_crs_is_scaled_enu_on_the_ellipsoid_and_departs_as_stated():
    """On the ellipsoid (h = 0) the carried x, y are k0 times PROJ's ENU east, north exactly (the origin's height
    does not move the horizontal axes); at the origin's height they are ENU to a millimetre at 1 km, and at other
    heights they depart by (h - h0) d / R; the heights by d^2 / 2R (curvature)."""
    local = WorldFrame.local(*ORIGIN)
    crs = carried_crs(local)
    k = next(p.value for p in crs.coordinate_operation.params if "scale" in p.name.lower())
    assert k == pytest.approx(1 + ORIGIN[2] / R_EARTH, rel=1e-5)
    to_carried = pyproj.Transformer.from_crs("EPSG:4979", crs.to_3d(), always_xy=True)
    lat, lon, h = _ring(ORIGIN, 1000.0, 0.0)
    xy = np.stack(to_carried.transform(lon, lat, h), axis=1)[:, :2]
    assert np.abs(xy / k - _proj_enu(ORIGIN, lat, lon, h)[:, :2]).max() < 1e-6
    # one scale factor for both axes: east wants (N + h0) / N, north (M + h0) / M; k0 uses sqrt(M N), so at the
    # origin's height x, y keep d h0 (N - M) / (2 M N) (2.5 mm at 5 km here)
    e2 = (1 / 298.257223563) * (2 - 1 / 298.257223563)
    s2 = np.sin(np.radians(ORIGIN[0])) ** 2
    n_, m_ = 6378137.0 / np.sqrt(1 - e2 * s2), 6378137.0 * (1 - e2) / (1 - e2 * s2) ** 1.5
    for d in (1000.0, 5000.0):
        for dh, tol in ((0.0, 1.05 * d * ORIGIN[2] * (n_ - m_) / (2 * m_ * n_)), (200.0, None), (-500.0, None)):
            lat, lon, h = _ring(ORIGIN, d, ORIGIN[2] + dh)
            x, y, z = to_carried.transform(lon, lat, h)
            horizontal, vertical = enu_departure(local, np.stack([x, y, z], axis=1))
            if tol is not None:
                assert horizontal < tol, (d, horizontal)
            else:
                assert horizontal == pytest.approx(abs(dh) * d / R_EARTH, rel=0.03), (d, dh, horizontal)
            assert vertical == pytest.approx(d * d / (2 * R_EARTH), rel=0.02), (d, vertical)


def test_carried_crs_survives_geotiff_and_las(tmp_path):
    import laspy
    import rasterio
    from rasterio.transform import from_origin

    local = WorldFrame.local(*ORIGIN)
    crs = carried_crs(local)
    with rasterio.open(tmp_path / "t.tif", "w", driver="GTiff", width=4, height=4, count=1, dtype="float32",
                       crs=crs.to_wkt(), transform=from_origin(-10, 10, 5, 5)) as ds:
        ds.write(np.zeros((1, 4, 4), "float32"))
    with rasterio.open(tmp_path / "t.tif") as ds:
        back = pyproj.CRS.from_wkt(ds.crs.to_wkt())
    assert back.equals(crs, ignore_axis_order=True) and local_of_carried(back) == local  # the frame, from the CRS
    hdr = laspy.LasHeader(point_format=6, version="1.4")
    hdr.add_crs(crs.to_3d())
    las = laspy.LasData(hdr)
    las.x, las.y, las.z = np.array([1.0]), np.array([2.0]), np.array([ORIGIN[2]])
    las.write(tmp_path / "t.las")
    assert local_of_carried(laspy.read(tmp_path / "t.las").header.parse_crs()) == local
    import pyogrio
    import shapely

    from skyrig.io.gpkg import write_gpkg

    write_gpkg(tmp_path / "t.gpkg", {"p": ([shapely.Point(1.0, 2.0, ORIGIN[2])], {"name": ["a"]})}, "local %r %r %r" % ORIGIN)
    gp = pyproj.CRS.from_user_input(pyogrio.read_info(tmp_path / "t.gpkg", layer="p")["crs"])
    assert local_of_carried(gp) == local


@pytest.mark.parametrize("origin", [(52.3759, 9.732, 0.0), (-33.9, 151.2, -20.0), (78.2, 15.6, 3.5)],
                         ids=["h0=0", "south-negative-h", "arctic"])
def test_the_frame_comes_back_from_its_crs(origin, tmp_path):
    """An origin on the ellipsoid (k0 = 1: PROJ writes plain Orthographic, found by the full run on a simulated
    flight), a southern one below it, an Arctic one: the local frame comes back from the CRS through a GeoTIFF."""
    import rasterio
    from rasterio.transform import from_origin

    local = WorldFrame.local(*origin)
    with rasterio.open(tmp_path / "t.tif", "w", driver="GTiff", width=2, height=2, count=1, dtype="uint8",
                       crs=carried_crs(local).to_wkt(), transform=from_origin(-10, 10, 5, 5)) as ds:
        ds.write(np.zeros((1, 2, 2), "uint8"))
    with rasterio.open(tmp_path / "t.tif") as ds:
        assert local_of_carried(pyproj.CRS.from_wkt(ds.crs.to_wkt())) == local


def test_a_geoid_with_a_local_frame_is_refused():
    from skyrig.errors import CRSError

    with pytest.raises(CRSError, match="no geoid"):
        carried_frame("local 43.64 4.57 1807.36", "egm96_15.gtx")


def _local_eo_folder(d: Path) -> WorldFrame:
    """Images, a rig file and an EO table in a local ENU frame (its frame in the side-car)."""
    from skyrig.io.eo_csv import read_eo_csv, write_eo_csv
    from test_trust_inputs import _uav_folder

    _uav_folder(d, n=3)
    (d / "rig.yaml").write_text(RIG)
    (d / "h.csv").write_text(EO)
    eo = read_eo_csv(d / "h.csv")
    (d / "h.csv").unlink()
    g = WorldFrame.map("EPSG:25832").projection.to_geodetic([[500300.0, 5350000.0, 300.0]])[0]
    local = WorldFrame.local(*g)
    write_eo_csv(eo.to_frame(local), d / "eo.csv")
    return local


def test_init_and_dry_run_on_a_local_frame_project(tmp_path):
    d = tmp_path / "f"
    local = _local_eo_folder(d)
    r = _run("init", d)
    assert r.exit_code == 0, r.output
    assert "carried as Local Orthographic" in r.output, r.output
    text = (d / "project.yaml").read_text()
    assert f'crs: "{local.to_text()}"' in text and "# crs is a local ENU frame" in text, text
    r = _run("run", d / "project.yaml", "--dry-run")
    assert r.exit_code == 0 and "adjust" in r.output and "ortho" in r.output, r.output
    r = _run("check", d / "project.yaml")
    assert r.exit_code == 0 and "no problem found" in r.output, r.output
    (d / "project.yaml").write_text(text.replace("geoid: null", "geoid: egm96_15.gtx"))
    r = _run("run", d / "project.yaml", "--dry-run")
    assert r.exit_code == 2 and "no geoid" in r.output and "field 'geoid'" in r.output, r.output


def test_init_with_a_local_crs_option(tmp_path):
    d = tmp_path / "f"
    _local_eo_folder(d)
    r = _run("init", d, "--crs", "local 48.3 9.0 300", "--force")
    assert r.exit_code == 0 and 'crs: "local 48.3 9.0 300"' in (d / "project.yaml").read_text(), r.output


def test_georef_in_a_local_frame_equals_proj(tmp_path):
    """A cheap stage end to end: georef with ``--crs local ...`` writes its EO in the carried CRS; the centres equal
    those of a georef in EPSG:25832 taken into the carried CRS by PROJ, and the side-car states the frame and the
    departure from ENU in words."""
    for name, text in {"rig.yaml": RIG, "traj.csv": TRAJ, "events.csv": EVENTS}.items():
        (tmp_path / name).write_text(text)
    geo = ["georef", "--trajectory", tmp_path / "traj.csv", "--events", tmp_path / "events.csv", "--rig",
           tmp_path / "rig.yaml"]
    local_text = "local 48.3 9.0016 300"
    assert _run(*geo, "--crs", "EPSG:25832", "-o", tmp_path / "utm.csv").exit_code == 0
    r = _run(*geo, "--crs", local_text, "-o", tmp_path / "loc.csv")
    assert r.exit_code == 0, r.output
    from skyrig.io.eo_csv import read_eo_csv

    utm, loc = read_eo_csv(tmp_path / "utm.csv"), read_eo_csv(tmp_path / "loc.csv")
    crs = carried_crs(WorldFrame.from_fields(local_text))
    assert pyproj.CRS.from_user_input(loc.frame.crs).equals(crs)
    t = pyproj.Transformer.from_crs(pyproj.CRS("EPSG:25832").to_3d(), crs.to_3d(), always_xy=True)
    ref = np.stack(t.transform(*utm.centre.T), axis=1)
    assert np.abs(loc.centre - ref).max() < 1e-4  # both files written to 0.1 mm (4 decimals)
    side = json.loads((tmp_path / "loc.csv.json").read_text())
    words = json.dumps(side)
    assert "Local Orthographic projection centred at the origin of the local ENU frame" in words, words
    assert "Departure from ENU" in words and "ellipsoidal height, not ENU up" in words, words


def test_a_dsm_in_a_local_frame_project_is_a_cog_that_says_so(tmp_path):
    """The DSM writer (as the dsm stage calls it) in the carried frame: a GeoTIFF whose CRS is the carried one and
    whose tags state the local frame and the departure from ENU; read back into the same frame."""
    import rasterio

    from skyrig.dense.grid import DsmGrid, GridSpec
    from skyrig.io.dsm_cog import read_dsm_cog, write_dsm_cog

    frame = carried_frame("local 48.3 9.0 300")
    n = 16
    dsm = DsmGrid(GridSpec(-40.0, 40.0, 5.0, n, n), frame, np.full((n, n), 305.0, np.float32), np.ones((n, n), np.int16),
                  np.full((n, n), np.nan, np.float32), np.full((n, n), 0.1, np.float32), np.zeros((n, n), bool))
    write_dsm_cog(tmp_path / "dsm.tif", dsm, overviews=False)
    with rasterio.open(tmp_path / "dsm.tif") as ds:
        tags = json.dumps(ds.tags())
        assert local_of_carried(pyproj.CRS.from_wkt(ds.crs.to_wkt())) == WorldFrame.from_fields("local 48.3 9.0 300")
    assert "not ENU up" in tags and "Departure from ENU" in tags, tags
    back = read_dsm_cog(tmp_path / "dsm.tif")
    assert back.frame.kind == "map" and pyproj.CRS.from_user_input(back.frame.crs).equals(
        pyproj.CRS.from_user_input(frame.crs), ignore_axis_order=True)


def test_run_georef_stage_of_a_local_frame_project(tmp_path):
    """``skyrig run`` on a project whose ``crs:`` is a local frame: the georef stage publishes its EO in the carried
    CRS, equal to PROJ's transformation of a georef in EPSG:25832 (to the 0.1 mm the table is written to)."""
    for name, text in {"rig.yaml": RIG, "traj.csv": TRAJ, "events.csv": EVENTS}.items():
        (tmp_path / name).write_text(text)
    local_text = "local 48.3 9.0016 300"
    (tmp_path / "project.yaml").write_text(
        f'format: skyrig-project\nversion: 1\ncrs: "{local_text}"\ninputs:\n  trajectory: traj.csv\n'
        "  events: events.csv\n  rig: rig.yaml\nstages:\n  georef: {}\n")
    r = _run("run", tmp_path / "project.yaml")
    assert r.exit_code == 0, r.output
    from skyrig.io.eo_csv import read_eo_csv

    eo = read_eo_csv(tmp_path / "output" / "georef" / "eo.csv")
    crs = carried_crs(WorldFrame.from_fields(local_text))
    assert local_of_carried(eo.frame.crs) == WorldFrame.from_fields(local_text)
    assert _run("georef", "--trajectory", tmp_path / "traj.csv", "--events", tmp_path / "events.csv", "--rig",
                tmp_path / "rig.yaml", "--crs", "EPSG:25832", "-o", tmp_path / "utm.csv").exit_code == 0
    utm = read_eo_csv(tmp_path / "utm.csv")
    t = pyproj.Transformer.from_crs(pyproj.CRS("EPSG:25832").to_3d(), crs.to_3d(), always_xy=True)
    assert np.abs(eo.centre - np.stack(t.transform(*utm.centre.T), axis=1)).max() < 1e-4


def test_a_local_text_means_the_carried_crs_wherever_a_map_crs_is_asked():
    """Every command that builds a map frame or resolves a CRS from a user's text (``--crs`` of dsm, ortho, lidar,
    convert...) takes ``local lat lon h`` as the carried CRS; a table header keeps the exact local frame."""
    from skyrig.errors import CRSError
    from skyrig.geodesy.crs import check_metric_projected, resolve_crs

    text = "local 48.3 9.0 300"
    assert WorldFrame.map(text) == carried_frame(text)
    assert resolve_crs(text).equals(carried_crs(WorldFrame.from_fields(text)))
    check_metric_projected(text, "a DSM")
    assert WorldFrame.from_text(text).kind == "local"
    assert WorldFrame.from_text(WorldFrame.map(text).to_text()) == WorldFrame.map(text)  # the text form round trips
    with pytest.raises(CRSError, match="no geoid"):
        WorldFrame.map(text, "egm96_15.gtx")


@pytest.mark.slow
def test_simulated_flight_run_to_ortho_in_the_scene_local_frame(tmp_path):
    """End to end (about 90 s): ``skyrig simulate midas-demo --size ci``, ``skyrig init --crs "local <the scene's
    origin>"``, ``skyrig run`` to the orthomosaic.  Every stage folder verifies; the DSM and ortho carry the frame;
    the DSM judged against the scene's analytic surface meets the dense stage's acceptance (flat cells: NMAD < 1 GSD,
    |bias| < 0.3 GSD) as the same flight in EPSG:25832 does (measured: NMAD 0.363 vs 0.360 GSD, bias -0.056 vs
    -0.050 GSD, sigma0 0.411 vs 0.412)."""
    import subprocess
    import sys

    import rasterio

    from skyrig.io.dsm_cog import read_dsm_cog
    from skyrig.io.stage import verify_folder
    from skyrig.simulate.judge import judge_dsm
    from skyrig.simulate.scenarios import build_survey, scenario_spec

    folder = tmp_path / "flight"
    assert _run("simulate", "midas-demo", "-o", folder, "--size", "ci", "--workers", "1").exit_code == 0
    spec = scenario_spec("midas-demo", "ci", 1)
    local = WorldFrame.local(*spec.origin)
    r = _run("init", folder, "--crs", local.to_text())
    assert r.exit_code == 0, r.output
    p = folder / "project.yaml"
    p.write_text(p.read_text().replace("  kind: auto ", "  kind: serial ")
                 .replace("    # max_features: 8000 ", "    max_features: 3000 "))
    res = subprocess.run([str(Path(sys.executable).parent / "skyrig"), "run", str(p)], capture_output=True, text=True,
                         timeout=900)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    out = folder / "output"
    for s in ("georef", "match", "block", "adjust", "dsm", "ortho"):
        assert verify_folder(out / s) == [], s
    for f in (out / "dsm" / "dsm.tif", out / "ortho" / "ortho.tif"):
        with rasterio.open(f) as ds:
            assert local_of_carried(pyproj.CRS.from_wkt(ds.crs.to_wkt())) == local, f
            assert "Departure from ENU" in ds.tags().get("VERTICAL_CRS", ""), f
    survey = build_survey(spec)
    dense = json.loads((out / "dsm" / "dense.json").read_text())
    j = judge_dsm(read_dsm_cog(out / "dsm" / "dsm.tif"), survey.scene, dense["stats"]["gsd_m"],
                  survey.spec.flights[0].area)
    assert j["flat"]["nmad_gsd"] < 1.0 and abs(j["flat"]["bias_gsd"]) < 0.3, j["flat"]
    rep = json.loads((out / "adjust" / "report.json").read_text())
    assert 0.3 < rep["summary"]["sigma0"] < 1.5
