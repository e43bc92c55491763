"""A simulated project folder in the documented formats: files read back, georeferenced, GeoPackage opens."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from skyrig.georef.direct import direct_georeference
from skyrig.io.eo_csv import read_eo_csv
from skyrig.io.events_csv import read_events_csv
from skyrig.io.points_csv import read_measurements_csv, read_points_csv
from skyrig.io.rig_file import read_rig
from skyrig.io.trajectory_csv import read_trajectory_csv
from skyrig.io.truth import read_truth


def test_project_files_georeference_to_truth(tmp_path):
    pyogrio = pytest.importorskip("pyogrio")
    from skyrig.pipeline.simulate import simulate_scenario

    out = tmp_path / "se"
    simulate_scenario("southeast", out, "ci", seed=4, images=False)
    truth = read_truth(out / "truth" / "truth.json")
    assert truth["scenario"] == "southeast"
    eo_true = read_eo_csv(out / "truth" / "eo.csv")
    eo = direct_georeference(read_trajectory_csv(out / "truth" / "trajectory.csv"), read_rig(out / "truth" / "rig.yaml"),
                             read_events_csv(out / "truth" / "events.csv"), eo_true.frame)
    # the CSV files round positions to 0.1 mm / angles to 1e-9 deg or so: agreement at that level
    assert np.max(np.linalg.norm(eo.centre - eo_true.centre, axis=1)) < 2e-3
    # recorded data carry the Tab. 4 datum shift: about 7.5 m off
    eo_rec = direct_georeference(read_trajectory_csv(out / "trajectory.csv"), read_rig(out / "rig.yaml"),
                                 read_events_csv(out / "events.csv"), eo_true.frame)
    d = np.linalg.norm(eo_rec.centre - eo_true.centre, axis=1)
    assert 6.0 < np.median(d) < 9.5
    gcp = read_points_csv(out / "gcp" / "ground_points.csv")
    assert gcp.frame.crs == "EPSG:3763"
    m = read_measurements_csv(out / "gcp" / "image_measurements.csv")
    assert len(m) > 0 and set(m.point) <= set(gcp.name) | set(read_points_csv(out / "gcp" / "check_points.csv").name)
    layers = [str(x[0]) for x in pyogrio.list_layers(out / "plan.gpkg")]
    assert {"stations", "footprints", "strips"} <= set(layers)
    assert pyogrio.read_info(out / "plan.gpkg", layer="stations")["features"] == 12
    assert (out / "scene" / "dsm.tif").exists() and (out / "scene" / "orthophoto.tif").exists()


def test_cli_plan_writes_gpkg_and_png(tmp_path):
    pytest.importorskip("pyogrio")
    pytest.importorskip("matplotlib")
    from skyrig.cli.plan import command

    area = tmp_path / "area.txt"
    area.write_text("0 0\n2000 0\n2000 1500\n0 1500\n")
    out = tmp_path / "plan.gpkg"
    r = CliRunner().invoke(command, ["--rig", "dlr-3k", "--area", str(area), "--crs", "EPSG:25832", "--height", "1000",
                                     "-o", str(out)])
    assert r.exit_code == 0, r.output
    assert out.exists() and out.with_suffix(".png").exists()
    assert "GSD nadir: centre 0.144" in r.output


def test_cli_simulate_rejects_unknown_scenario(tmp_path):
    from skyrig.cli.simulate import command

    r = CliRunner().invoke(command, ["nosuch", str(tmp_path / "x")])
    assert r.exit_code != 0
