"""Issue 29, inputs: empty tables, frames a command cannot use, a rig head missing, ``init``'s silent choices.

Each case was a traceback or a silent wrong answer (exit 0) on main; now a refusal in words naming the file, line
and field (or option), or the choice written down.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from skyrig.cli import main
from skyrig.errors import SkyrigError
from test_bad_input_cli import EO, EVENTS, PTS, RIG, TRAJ


def _run(*args):
    r = CliRunner().invoke(main, [str(a) for a in args])
    assert "Traceback" not in r.output, r.output
    assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
    return r


@pytest.fixture
def proj(tmp_path) -> Path:
    for name, text in {"eo.csv": EO, "gcp.csv": PTS, "rig.yaml": RIG, "traj.csv": TRAJ, "events.csv": EVENTS}.items():
        (tmp_path / name).write_text(text)
    return tmp_path


def test_header_only_events_file_is_refused_naming_it(proj):
    (proj / "ev.csv").write_text("# skyrig-events 1\n# time: gps-sow\nimage,time,head,exposure\n")
    r = _run("georef", "--trajectory", proj / "traj.csv", "--events", proj / "ev.csv", "--rig", proj / "rig.yaml",
             "--crs", "EPSG:25832", "-o", proj / "eo2.csv")
    assert r.exit_code == 2 and "ev.csv" in r.output and "line 3" in r.output and "no rows" in r.output, r.output


def test_header_only_points_file_is_refused_naming_it(proj):
    (proj / "g.csv").write_text("# crs: EPSG:25832\n# heights: ellipsoidal\nname,x,y,z\n")
    r = _run("world-to-image", "--eo", proj / "eo.csv", "--camera", proj / "rig.yaml", "--points", proj / "g.csv",
             "-o", proj / "px.csv")
    assert r.exit_code == 2 and "g.csv" in r.output and "line 3" in r.output and "no rows" in r.output, r.output


def _dsm(crs, x0, y0, cell):
    from skyrig.dense.grid import DsmGrid, GridSpec
    from skyrig.geodesy.frame import WorldFrame

    n = 50
    shp = (n, n)
    return DsmGrid(GridSpec(x0, y0, cell, n, n), WorldFrame.map(crs), np.full(shp, 300, np.float32),
                   np.ones(shp, np.int16), np.full(shp, np.nan, np.float32), np.full(shp, 0.1, np.float32),
                   np.zeros(shp, bool))


def _eo(d: Path):
    from skyrig.io.eo_csv import read_eo_csv

    (d / "eo.csv").write_text(EO)
    return read_eo_csv(d / "eo.csv")


def test_ortho_on_a_geographic_dsm_is_refused(tmp_path):
    """OpenCV was asked for 97 TB (cells of 1e-5 'metres' over a block in degrees)."""
    from skyrig.dense.ortho import orthomosaic

    dsm, eo = _dsm("EPSG:4326", 8.99, 48.31, 1e-4), _eo(tmp_path)
    with pytest.raises(SkyrigError, match=r"geographic CRS \(degrees\): an orthomosaic"):
        orthomosaic(eo, {}, dsm, lambda i: np.zeros((10, 10), np.uint8))


@pytest.mark.parametrize("stage", ["ortho", "dsm"])
def test_a_camera_missing_for_the_eo_is_named(tmp_path, stage):
    """``run_ortho`` and ``run_dsm`` looked the cameras up before any check: a KeyError traceback."""
    from skyrig.geodesy.frame import WorldFrame
    from skyrig.pipeline.dense import run_dsm
    from skyrig.pipeline.ortho import run_ortho

    dsm, eo = _dsm("EPSG:25832", 499900.0, 5350100.0, 10.0), _eo(tmp_path)
    with pytest.raises(SkyrigError, match="image 'img1.tif': no camera 'camera' among those given"):
        if stage == "ortho":
            run_ortho(eo, {}, [], dsm, tmp_path / "o")
        else:
            run_dsm(eo, {}, [], WorldFrame.map("EPSG:25832"), (250.0, 350.0), tmp_path / "o")
    assert not (tmp_path / "o").exists()


def test_rig_head_missing_for_an_eo_camera_is_a_clear_error(proj):
    """An EO camera that no rig head carries (the EO names head 'oblique', the rig has 'camera')."""
    eo = EO.replace(".tif,camera,", ".tif,oblique,")
    (proj / "eo2.csv").write_text(eo)
    r = _run("world-to-image", "--eo", proj / "eo2.csv", "--camera", proj / "rig.yaml", "--points", proj / "gcp.csv",
             "-o", proj / "px.csv")
    assert r.exit_code == 2 and "oblique" in r.output, r.output


# ------------------------------------------------------------------------------------------------ init
def _jpeg(path: Path, gps: bool = True, k: int = 0) -> Path:
    from PIL import Image

    ex = Image.Exif()
    ex[0x010F], ex[0x0110] = "DJI", "FC300S"
    if gps:
        ex.get_ifd(0x8825).update({1: "N", 2: (50.0, 51.0, 0.0 + k), 3: "W", 4: (0.0, 9.0, 0.0), 5: 0, 6: 40.0})
    ex.get_ifd(0x8769).update({0x920A: 3.61, 0xA405: 20})
    rgb = (np.random.default_rng(k).random((48, 64, 3)) * 255).astype(np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(rgb).save(path, exif=ex)
    return path


def _uav_folder(d: Path, n: int = 6, without_gps: tuple[int, ...] = ()) -> Path:
    for k in range(n):
        _jpeg(d / "images" / f"DJI_{k:04d}.JPG", gps=k not in without_gps, k=k)
    return d


def _init(folder: Path, *extra: str):
    return _run("init", folder, *extra)


def test_init_refuses_a_damaged_rig_file(tmp_path):
    """Was: rig: null and the UAV stages, silently."""
    from skyrig.pipeline.demo import build_demo_project

    paths = build_demo_project(tmp_path / "f")
    _uav_folder(tmp_path / "f")
    text = Path(paths.rig).read_text()
    Path(paths.rig).write_text(text.replace("heads:", "heads: [", 1))  # a YAML syntax error
    r = _init(tmp_path / "f")
    assert r.exit_code == 2 and Path(paths.rig).name in r.output, r.output
    assert not (tmp_path / "f" / "project.yaml").exists()


def test_init_refuses_two_trajectories_listing_them(tmp_path):
    from skyrig.pipeline.demo import build_demo_project

    paths = build_demo_project(tmp_path / "f")
    second = tmp_path / "f" / "gnss" / "trajectory_2.csv"
    second.parent.mkdir()
    second.write_text(Path(paths.trajectory).read_text())
    r = _init(tmp_path / "f")
    assert r.exit_code == 2 and "trajectory_2.csv" in r.output and Path(paths.trajectory).name in r.output, r.output
    assert not (tmp_path / "f" / "project.yaml").exists()


def test_init_one_image_without_gps_keeps_the_gnss_block_and_says_so(tmp_path):
    """The first shot before a GPS fix: init kept GPS mode only if that image was not the first one read; now the
    project stays GNSS-supported and its file names the image left out."""
    _uav_folder(tmp_path / "f", without_gps=(0,))
    r = _init(tmp_path / "f")
    assert r.exit_code == 0, r.output
    text = (tmp_path / "f" / "project.yaml").read_text()
    assert "no_gps: true" not in text and "adjust-uav:" in text, text
    assert "DJI_0000.JPG" in text and "left out" in text, text
    assert "DJI_0000.JPG" in r.output


def test_uav_run_leaves_an_image_without_gps_out_with_a_warning():
    from types import SimpleNamespace

    from skyrig.georef.observations import ImageMeasurements
    from skyrig.pipeline.uav import without_gps_left_out

    metas = [SimpleNamespace(name=f"i{k}", path=f"/x/i{k}.jpg", has_gps=k != 1, alt_m=40.0) for k in range(4)]
    meas = ImageMeasurements(np.array(["p", "p", "q"]), np.array(["i0", "i1", "i2"]), np.zeros((3, 2)))
    with pytest.warns(UserWarning, match="i1.jpg.*no EXIF GPS.*left out"):
        kept, m2 = without_gps_left_out(metas, meas)
    assert [m.name for m in kept] == ["i0", "i2", "i3"] and list(m2.image) == ["i0", "i2"]


def test_init_refuses_a_us_feet_crs(tmp_path):
    """EPSG:6503: x/y came out in US survey feet while the side-car and init's comment said metres."""
    _uav_folder(tmp_path / "f")
    r = _init(tmp_path / "f", "--crs", "EPSG:6503")
    assert r.exit_code == 2 and "EPSG:6503" in r.output and "foot" in r.output, r.output
    assert not (tmp_path / "f" / "project.yaml").exists()


def test_init_picks_up_ground_points_as_the_format_page_shows(tmp_path, egm96_grid):
    import pyproj

    from skyrig import geodesy

    doc = (Path(__file__).parents[1] / "docs" / "formats" / "points_csv.md").read_text()
    example = doc.split("## Ground points", 1)[1].split("```text\n", 1)[1].split("```", 1)[0]
    from skyrig.pipeline.demo import build_demo_project

    build_demo_project(tmp_path / "f")
    (tmp_path / "f" / "gcp").mkdir()
    (tmp_path / "f" / "gcp" / "ground_points.csv").write_text(example)
    old = pyproj.datadir.get_data_dir()
    pyproj.datadir.append_data_dir(str(egm96_grid.parent))
    getattr(geodesy, "clear_caches", lambda: None)()
    try:
        r = _init(tmp_path / "f")
    finally:
        pyproj.datadir.set_data_dir(old)
        getattr(geodesy, "clear_caches", lambda: None)()
    assert r.exit_code == 0, r.output
    text = (tmp_path / "f" / "project.yaml").read_text()
    assert "control: gcp/ground_points.csv" in text, text


def test_init_force_with_a_bad_crs_keeps_the_good_project_file(tmp_path):
    from skyrig.pipeline.demo import build_demo_project

    build_demo_project(tmp_path / "f")
    assert _init(tmp_path / "f").exit_code == 0
    good = (tmp_path / "f" / "project.yaml").read_text()
    for bad in ("EPSG:4326", "EPSG:5773", "EPSG:99999"):
        r = _init(tmp_path / "f", "--force", "--crs", bad)
        assert r.exit_code == 2, r.output
        assert (tmp_path / "f" / "project.yaml").read_text() == good, bad
    assert sorted(p.name for p in (tmp_path / "f").iterdir() if "project" in p.name) == ["project.yaml"]


def test_init_refuses_a_truncated_jpeg_naming_it(tmp_path):
    _uav_folder(tmp_path / "f")
    p = tmp_path / "f" / "images" / "DJI_0003.JPG"
    data = p.read_bytes()
    p.write_bytes(data[: len(data) * 2 // 3])
    r = _init(tmp_path / "f")
    assert r.exit_code == 2 and "DJI_0003.JPG" in r.output and "truncated" in r.output, r.output


def test_read_image_refuses_a_truncated_jpeg_naming_it(tmp_path):
    from skyrig.io.image_read import read_image

    p = _jpeg(tmp_path / "a.jpg")
    data = p.read_bytes()
    p.write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(SkyrigError, match=r"a\.jpg.*truncated"):
        read_image(p)


def test_lidar_lever_arm_in_millimetres_is_refused(tmp_path):
    """``skyrig lidar georef --lever-arm 100,-20,150`` (millimetres) was taken as metres: points 180 m off."""
    raw = ("# skyrig-raw-scan 1\n# angles: deg\n# time: gps-sow\ntime,range,alpha,intensity\n"
           "345601.508350,12.418,-134.875,1893\n345601.508368,12.402,-134.625,1901\n")
    (tmp_path / "scan.csv").write_text(raw)
    (tmp_path / "traj.csv").write_text(TRAJ)
    r = _run("lidar", "georef", "--scan", tmp_path / "scan.csv", "--trajectory", tmp_path / "traj.csv",
             "--lever-arm", "100,-20,150", "--crs", "EPSG:25832", "-o", tmp_path / "p.las")
    assert r.exit_code == 2 and "--lever-arm" in r.output and "millimetres (0.181 m)" in r.output, r.output
    assert not (tmp_path / "p.las").exists()


@pytest.mark.parametrize("crs_line, words", [
    ("crs: EPSG:4326", "geographic CRS (degrees)"),
    ("crs: EPSG:5773", "not a projected CRS"),
    ("crs: EPSG:6503", "us survey foot"),
    ("crs: EPSG:25832\ngeoid: no_such_grid.gtx", "no_such_grid.gtx"),
], ids=["geographic", "vertical-only", "us-feet", "missing-geoid"])
def test_run_dry_run_refuses_an_unusable_output_frame(tmp_path, crs_line, words):
    """``skyrig run --dry-run`` accepted a geographic or vertical-only output CRS and a geoid grid that does not
    exist (found only after the match stage had run)."""
    from skyrig.pipeline.demo import build_demo_project

    build_demo_project(tmp_path / "f")
    assert _init(tmp_path / "f").exit_code == 0
    p = tmp_path / "f" / "project.yaml"
    text = p.read_text()
    start = text.index("crs: EPSG:25832")
    end = text.index("\n", text.index("\ngeoid:") + 1)
    p.write_text(text[:start] + crs_line + text[end:])
    r = _run("run", p, "--dry-run")
    assert r.exit_code == 2 and "project.yaml" in r.output and words in r.output, r.output


# ------------------------------------------------------------------------------------------------ skyrig check
def test_check_on_the_demo_project_reports_nothing(tmp_path):
    from skyrig.pipeline.demo import build_demo_project

    build_demo_project(tmp_path / "f")
    assert _init(tmp_path / "f").exit_code == 0
    r = _run("check", tmp_path / "f")
    assert r.exit_code == 0 and r.output.startswith("ok: 4 input file(s) read, no problem found"), r.output


def test_check_names_every_mistake_in_one_run(tmp_path):
    """Three mistakes in three files: all three named (file, line, field) in a single run, exit 2."""
    from skyrig.pipeline.demo import build_demo_project

    build_demo_project(tmp_path / "f")
    assert _init(tmp_path / "f").exit_code == 0
    inp = tmp_path / "f" / "input"
    (inp / "events.csv").write_text("# skyrig-events 1\n# time: gps-sow\nimage,time,head,exposure\n")
    rig = (inp / "rig.yaml").read_text()
    (inp / "rig.yaml").write_text(rig.replace("lever_arm_m: [0.12, 0.0, 0.12]", "lever_arm_m: [120, 0, 120]", 1))
    pts = (inp / "check_points.csv").read_text().splitlines()
    (inp / "check_points.csv").write_text("\n".join(pts[:2] + ["CP01,5799900.0000,549975.0000,58.7763"] + pts[3:])
                                          + "\n")
    r = _run("check", tmp_path / "f")
    assert r.exit_code == 2, r.output
    errors = [ln for ln in r.output.splitlines() if ln.startswith("error:")]
    assert len(errors) == 3, r.output
    text = "\n".join(errors)
    assert "events.csv, line 3" in text and "no rows" in text, text
    assert "rig.yaml" in text and "millimetres" in text, text
    assert "check_points.csv" in text and "line 3" in text, text


def test_init_without_gnss_writes_a_free_network_project_without_a_crs(tmp_path):
    """Images without GNSS and no control: init demanded --crs for a free network that ignores it; now it writes
    crs: null with the reason, adjust-uav with no_gps, and the project loads (check and run --dry-run)."""
    _uav_folder(tmp_path / "f", without_gps=tuple(range(6)))
    r = _init(tmp_path / "f")
    assert r.exit_code == 0, r.output
    text = (tmp_path / "f" / "project.yaml").read_text()
    assert "crs: null    # none: no GNSS and no control points" in text and "no_gps: true" in text, text
    assert "dsm:" not in text
    assert _run("run", tmp_path / "f", "--dry-run").exit_code == 0
    # and a stage that needs a CRS is refused with the key named
    p = tmp_path / "f" / "project.yaml"
    p.write_text(text + "  dsm: {}\n")
    r = _run("run", p, "--dry-run")
    assert r.exit_code == 2 and "field 'crs'" in r.output and "'dsm' needs an output CRS" in r.output, r.output


def test_init_refuses_control_points_that_do_not_read(tmp_path):
    """Was: 'control points ... not readable; left out' and a project without control."""
    from skyrig.pipeline.demo import build_demo_project

    build_demo_project(tmp_path / "f")
    (tmp_path / "f" / "gcp").mkdir()
    (tmp_path / "f" / "gcp" / "ground_points.csv").write_text("# crs: EPSG:25832\nname,x,y,z\nG1,549700.0,abc,47.6\n")
    r = _init(tmp_path / "f")
    assert r.exit_code == 2 and "ground_points.csv, line 3" in r.output and "'abc'" in r.output, r.output
    assert not (tmp_path / "f" / "project.yaml").exists()


def test_block_refuses_a_control_measurement_with_column_and_row_swapped(tmp_path):
    """A control point measured at (row, column) instead of (column, row): still inside the image, so it passed,
    hundreds of pixels from where the orientation puts the point; now refused naming file, line and field."""
    import csv

    from test_fuzz_readers import _good_block

    _good_block(tmp_path)  # eo.csv, rig.yaml, gcp.csv and px.csv (world-to-image of the points: the truth)
    with open(tmp_path / "px.csv", newline="") as fh:
        rows = list(csv.reader(fh))
    top = next(k for k, r in enumerate(rows) if r and r[0] == "point")
    ic, ir = rows[top].index("column"), rows[top].index("row")
    far = max(range(top + 1, len(rows)), key=lambda k: abs(float(rows[k][ic]) - float(rows[k][ir])))
    rows[far][ic], rows[far][ir] = rows[far][ir], rows[far][ic]
    with open(tmp_path / "px2.csv", "w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    r = _run("block", "--eo", tmp_path / "eo.csv", "--camera", tmp_path / "rig.yaml", "--measurements",
             tmp_path / "px2.csv", "--control", tmp_path / "gcp.csv", "-o", tmp_path / "b2.json")
    assert r.exit_code == 2, r.output
    assert f"px2.csv, line {far + 1}" in r.output and "field 'column'" in r.output and "swapped" in r.output, r.output


def _eo_side_car_folder(d: Path) -> Path:
    """Images, a rig file and an EO table with its side-car (a plain CSV: the CRS only in eo.csv.json)."""
    from skyrig.io.eo_csv import read_eo_csv, write_eo_csv

    _uav_folder(d, n=3)
    (d / "rig.yaml").write_text(RIG)
    (d / "h.csv").write_text(EO)
    (d / "eo").mkdir()
    write_eo_csv(read_eo_csv(d / "h.csv"), d / "eo" / "eo.csv")
    (d / "h.csv").unlink()
    assert not (d / "eo" / "eo.csv").read_text().startswith("#")
    return d


def test_init_takes_the_crs_from_an_eo_side_car_and_says_so(tmp_path):
    """Was: a plain EO table whose CRS is in its side-car was not taken for an EO file (init went the UAV way
    with the EXIF GPS's UTM zone 30, the side-car's EPSG:25832 unread)."""
    d = _eo_side_car_folder(tmp_path / "f")
    r = _init(d)
    assert r.exit_code == 0, r.output
    text = (d / "project.yaml").read_text()
    assert "eo: eo/eo.csv" in text, text
    assert "crs: EPSG:25832    # from the EO file's side-car (eo.csv.json)" in text, text


def test_init_refuses_side_car_and_control_crs_that_disagree_listing_them(tmp_path):
    from skyrig.georef.eo import WorldFrame
    from skyrig.georef.observations import GroundPoints
    from skyrig.io.points_csv import write_points_csv

    d = _eo_side_car_folder(tmp_path / "f")
    write_points_csv(d / "ground_control.csv", GroundPoints(["g1", "g2", "g3"], np.array(
        [[300_100.0, 5_350_050.0, 310.0], [300_300.0, 5_349_950.0, 305.0], [300_450.0, 5_350_020.0, 298.0]]),
        WorldFrame.map("EPSG:32633")))
    r = _init(d)
    assert r.exit_code == 2, r.output
    assert ("EPSG:25832 from the EO file's side-car (eo.csv.json)" in r.output
            and "EPSG:32633 from the control points' CRS (ground_control.csv)" in r.output
            and "--crs" in r.output), r.output
    assert not (d / "project.yaml").exists()
    r = _init(d, "--crs", "EPSG:25832")  # the user's choice settles it
    assert r.exit_code == 0, r.output
    assert "crs: EPSG:25832" in (d / "project.yaml").read_text()


def test_run_dry_run_refuses_stages_out_of_order(tmp_path):
    """Issue 29 (``run --dry-run`` accepted stages out of order): block listed before the match stage that makes
    its measurements is refused naming the project file and the stage; in order the same stages pass."""
    from skyrig.pipeline.demo import build_demo_project

    build_demo_project(tmp_path / "f")
    _uav_folder(tmp_path / "f", n=3)
    assert _init(tmp_path / "f").exit_code == 0
    p = tmp_path / "f" / "project.yaml"
    text = p.read_text()
    head = text[:text.index("stages:")]
    p.write_text(head + "stages:\n  georef: {}\n  block: {}\n  match: {}\n")
    r = _run("run", p, "--dry-run")
    assert r.exit_code == 2 and "project.yaml" in r.output and "field 'stages.block'" in r.output \
        and "a match stage before it" in r.output, r.output
    p.write_text(head + "stages:\n  georef: {}\n  match: {}\n  block: {}\n")
    r = _run("run", p, "--dry-run")
    assert r.exit_code == 0, r.output
