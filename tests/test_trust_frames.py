"""Issue 29, frames: a compound CRS means what PROJ means by it, wherever it is given.

``georef --crs EPSG:25832+5773`` wrote ellipsoidal heights (48 m off here) while the file said EGM96 heights.  The
reference is PROJ itself: the same projection centres in ECEF (``--crs ecef``) carried to the compound CRS by a pyproj
Transformer from the ellipsoidal WGS84 CRS (EPSG:4979), with the EGM96 grid made visible to PROJ.  A compound CRS
whose geoid grid is not installed is refused before anything runs, naming the grid.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pyproj
import pytest
from click.testing import CliRunner

from skyrig.cli import main
from test_bad_input_readers import RIG

N = 24  # images (>= 20 points)
TRAJ = ("# skyrig-trajectory 1\n# crs: EPSG:4979\n# angles: deg\n# time: gps-sow\ntime,lat,lon,h,roll,pitch,yaw\n"
        + "".join(f"{345600.0 + k:.3f},{48.0 + 0.02 * k:.5f},{8.7 + 0.03 * k:.5f},{1200.0 + 3 * k:.1f},0.5,-1.2,90.0\n"
                  for k in range(N + 2)))
EVENTS = ("# skyrig-events 1\n# time: gps-sow\nimage,time,head,exposure\n"
          + "".join(f"e{k}.jpg,{345600.5 + k:.6f},camera,{k}\n" for k in range(N)))


@pytest.fixture
def proj_with_egm96(egm96_grid):
    """PROJ sees the EGM96 grid (under its old name, which PROJ's grid_alternatives accepts)."""
    from skyrig import geodesy

    old = pyproj.datadir.get_data_dir()
    pyproj.datadir.append_data_dir(str(egm96_grid.parent))
    clear = getattr(geodesy, "clear_caches", lambda: None)  # the grids PROJ finds are cached
    clear()
    yield egm96_grid
    pyproj.datadir.set_data_dir(old)
    clear()


def _files(d: Path) -> list[str]:
    for name, text in {"traj.csv": TRAJ, "events.csv": EVENTS, "rig.yaml": RIG}.items():
        (d / name).write_text(text)
    return ["georef", "--trajectory", str(d / "traj.csv"), "--events", str(d / "events.csv"), "--rig", str(d / "rig.yaml")]


def _centres(path: Path) -> dict[str, np.ndarray]:
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(ln for ln in fh if not ln.startswith("#")))
    return {r["image"]: np.array([float(r["x"]), float(r["y"]), float(r["z"])]) for r in rows}


def _proj_answer(ecef: dict[str, np.ndarray], crs: str) -> dict[str, np.ndarray]:
    to_geo = pyproj.Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
    from pyproj.transformer import TransformerGroup

    best = TransformerGroup("EPSG:4979", crs, always_xy=True).transformers[0]
    assert "vgridshift" in best.to_proj4(), best.description  # PROJ's answer uses the grid (not a ballpark height)
    t = pyproj.Transformer.from_crs("EPSG:4979", crs, always_xy=True)
    out = {}
    for k, p in ecef.items():
        lon, lat, h = to_geo.transform(*p)
        out[k] = np.array(t.transform(lon, lat, h))
    return out


def test_georef_compound_crs_heights_equal_proj(tmp_path, proj_with_egm96):
    args = _files(tmp_path)
    r = CliRunner().invoke(main, args + ["--crs", "ecef", "-o", str(tmp_path / "ecef.csv")])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, args + ["--crs", "EPSG:25832+5773", "-o", str(tmp_path / "eo.csv")])
    assert r.exit_code == 0, r.output
    got, ref = _centres(tmp_path / "eo.csv"), _proj_answer(_centres(tmp_path / "ecef.csv"), "EPSG:25832+5773")
    assert len(got) == N
    d = np.array([got[k] - ref[k] for k in ref])
    assert np.abs(d).max() < 1e-3, np.abs(d).max(0)
    # and the file states the heights it holds
    side = json.loads((tmp_path / "eo.csv.json").read_text())
    assert "EGM96 height (EPSG:5773)" in side["vertical"], side["vertical"]


def test_project_frame_compound_crs_equals_proj(proj_with_egm96):
    """The frame of a project ``crs:`` (and of any side-car) with a vertical part: PROJ's answer at 20 points."""
    from skyrig.geodesy import WorldFrame, project_frame

    rng = np.random.default_rng(29)
    lat, lon, h = rng.uniform(47, 55, 20), rng.uniform(6, 12, 20), rng.uniform(-50, 3000, 20)
    t = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:25832+5773", always_xy=True)
    ref = np.column_stack(t.transform(lon, lat, h))
    ecef = np.column_stack(pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True).transform(lon, lat, h))
    for frame in (project_frame("EPSG:25832+5773"), WorldFrame.map("EPSG:25832+5773"),
                  WorldFrame.from_text("EPSG:25832+5773")):
        assert frame.heights == "orthometric", frame
        np.testing.assert_allclose(frame.from_ecef(ecef), ref, atol=1e-3, rtol=0)


def test_compound_crs_with_missing_grid_is_refused_naming_it(tmp_path):
    """EPSG:32632+3855 (EGM2008 heights) without PROJ's EGM2008 grid: refused before anything is read."""
    from pyproj.transformer import TransformerGroup

    tg = TransformerGroup("EPSG:4979", "EPSG:32632+3855", always_xy=True)
    if tg.best_available:
        pytest.skip("the EGM2008 grid is installed here: the refusal cannot be shown")
    r = CliRunner().invoke(main, _files(tmp_path) + ["--crs", "EPSG:32632+3855", "-o", str(tmp_path / "eo.csv")])
    assert r.exit_code == 2, r.output
    assert "us_nga_egm08_25.tif" in r.output and "Traceback" not in r.output, r.output
    assert not (tmp_path / "eo.csv").exists()


def test_egm2008_compound_crs_equals_proj_when_the_grid_is_installed(tmp_path):
    from pyproj.transformer import TransformerGroup

    if not TransformerGroup("EPSG:4979", "EPSG:32632+3855", always_xy=True).best_available:
        pytest.skip("PROJ's EGM2008 grid us_nga_egm08_25.tif is not installed (PROJ_DATA); see the refusal test")
    args = _files(tmp_path)
    assert CliRunner().invoke(main, args + ["--crs", "ecef", "-o", str(tmp_path / "ecef.csv")]).exit_code == 0
    r = CliRunner().invoke(main, args + ["--crs", "EPSG:32632+3855", "-o", str(tmp_path / "eo.csv")])
    assert r.exit_code == 0, r.output
    got, ref = _centres(tmp_path / "eo.csv"), _proj_answer(_centres(tmp_path / "ecef.csv"), "EPSG:32632+3855")
    assert max(np.abs(got[k] - ref[k]).max() for k in ref) < 1e-3


def test_side_car_crs_far_from_the_coordinates_is_refused_naming_both(tmp_path):
    """An EO side-car naming Lambert-93 for UTM 32N coordinates put the block 1,400 km from France's centre (6 deg
    south of its area of use) and ``dsm`` went on with a warning; now refused with the CRS, its area and where the
    positions would be."""
    from test_bad_input_cli import EO, RIG

    from skyrig.io.eo_csv import read_eo_csv, write_eo_csv

    (tmp_path / "eo.csv").write_text(EO)
    write_eo_csv(read_eo_csv(tmp_path / "eo.csv"), tmp_path / "side.csv")
    side = json.loads((tmp_path / "side.csv.json").read_text())
    side["frame"] = "EPSG:2154; heights: ellipsoidal"
    side["crs_wkt"] = pyproj.CRS("EPSG:2154").to_3d().to_wkt()
    (tmp_path / "side.csv.json").write_text(json.dumps(side))
    (tmp_path / "rig.yaml").write_text(RIG)
    r = CliRunner().invoke(main, ["dsm", "--eo", str(tmp_path / "side.csv"), "--camera", str(tmp_path / "rig.yaml"),
                                  "--images", str(tmp_path), "--height-range", "200", "400", "-o", str(tmp_path / "d")])
    assert r.exit_code == 2, r.output
    err = [ln for ln in r.output.splitlines() if ln.startswith("error:")]
    assert len(err) == 1, r.output
    for words in ("side.csv", "Lambert-93 (EPSG:2154)", "latitude 41.15 to 51.56", "latitude 35.2778"):
        assert words in err[0], (words, r.output)
    assert not (tmp_path / "d").exists()


@pytest.mark.slow  # two adjustments: 9 s
def test_adjust_outputs_in_a_compound_crs_equal_proj(tmp_path, proj_with_egm96):
    """``skyrig adjust --crs EPSG:25832+5773``: the adjusted centres and points are those of ``--crs EPSG:25832``
    (ellipsoidal heights) carried by PROJ's own transformation to the compound CRS, to 1 mm; the side-cars state
    EGM96 heights."""
    import sys

    sys.path.insert(0, str(Path(__file__).parent))
    from test_fuzz_readers import _good_block

    blk = _good_block(tmp_path)
    outs = {}
    for crs in ("EPSG:25832", "EPSG:25832+5773"):
        out = tmp_path / crs.replace(":", "_").replace("+", "_")
        r = CliRunner().invoke(main, ["adjust", str(blk), "--crs", crs, "-o", str(out)])
        assert r.exit_code == 0, r.output
        outs[crs] = out
    t = pyproj.Transformer.from_crs(pyproj.CRS("EPSG:25832").to_3d(), "EPSG:25832+5773", always_xy=True)
    n = 0
    for table, key in (("eo.csv", "image"), ("points.csv", "name")):
        with open(outs["EPSG:25832"] / table, newline="") as fh:
            ell = {r[key]: np.array([float(r["x"]), float(r["y"]), float(r["z"])]) for r in csv.DictReader(fh)}
        with open(outs["EPSG:25832+5773"] / table, newline="") as fh:
            got = {r[key]: np.array([float(r["x"]), float(r["y"]), float(r["z"])]) for r in csv.DictReader(fh)}
        assert got.keys() == ell.keys()
        for k, p in ell.items():
            ref = np.array(t.transform(*p))
            assert np.abs(got[k] - ref).max() < 1e-3, (table, k, got[k] - ref)
            n += 1
        side = json.loads((outs["EPSG:25832+5773"] / (table + ".json")).read_text())
        assert "EGM96 height (EPSG:5773)" in side["vertical"], side["vertical"]
    assert n >= 6


def test_navd88_compound_crs_is_refused_with_the_geoid_candidates():
    """EPSG:6318+5703 (NAD83(2011) + NAVD88): the old lookup took the first grid of proj.db (an older geoid) without
    saying so; PROJ's preferred transformation needs several grids, so skyrig refuses and lists the geoid grids PROJ
    knows for it, the current GEOID18 among them."""
    from skyrig.errors import CRSError
    from skyrig.geodesy import WorldFrame, project_frame

    for make in (WorldFrame.map, project_frame):
        with pytest.raises(CRSError) as ei:
            make("EPSG:6318+5703")
        msg = str(ei.value)
        assert "NAVD88" in msg and "us_noaa_g2018u0.tif" in msg and "--geoid" in msg, msg
