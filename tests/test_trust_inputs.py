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


def test_ortho_with_a_camera_missing_names_it(tmp_path):
    """``run_ortho`` looked the cameras up before any check: a KeyError traceback."""
    from skyrig.pipeline.ortho import run_ortho

    dsm, eo = _dsm("EPSG:25832", 499900.0, 5350100.0, 10.0), _eo(tmp_path)
    with pytest.raises(SkyrigError, match="no camera for camera"):
        run_ortho(eo, {}, [], dsm, tmp_path / "o")
    assert not (tmp_path / "o").exists()


def test_rig_head_missing_for_an_eo_camera_is_a_clear_error(proj):
    """An EO camera that no rig head carries (the EO names head 'oblique', the rig has 'camera')."""
    eo = EO.replace(".tif,camera,", ".tif,oblique,")
    (proj / "eo2.csv").write_text(eo)
    r = _run("world-to-image", "--eo", proj / "eo2.csv", "--camera", proj / "rig.yaml", "--points", proj / "gcp.csv",
             "-o", proj / "px.csv")
    assert r.exit_code == 2 and "oblique" in r.output, r.output
