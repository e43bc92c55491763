"""Failed runs and unwritable outputs (issue 13): ``skyrig adjust-uav`` exits 2 with the reason when its adjustment
cannot be trusted (``--keep-failed`` still writes the outputs); an output path under a regular file, or a folder
where a file is expected, is one clean error naming the option and the path (never a traceback about a temp file)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from click.testing import CliRunner

from skyrig.cli import main, option_for_path
from skyrig.errors import SkyrigError
from skyrig.io._text import OutputPathError, atomic_write, check_output_dir, output_temp


# ------------------------------------------------------------------------------------------- adjust-uav failures
def _fake_adjust_uav(adj):
    def fake(images, match, out, cfg, pycolmap_dir=None, **kw):
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "eo.csv").write_text("new run\n")
        (out / "report.json").write_text(json.dumps({"converged": adj.info.converged}))
        rep = {"uav": dict(oriented=3, images=3, tie_points=40, reprojection_rms_px=0.4, sigma0=adj.sigma0,
                           gnss_fit_rms_enu_m=[1.0, 1.0, 2.0], not_oriented=[], attitude_check={}, total_wall_s=0.1)}
        return SimpleNamespace(adjustment=adj), rep
    return fake


def _adj(converged=True, sigma0=1.0, redundancy=10, **extra):
    return SimpleNamespace(info=SimpleNamespace(converged=converged, message="maximum iterations reached",
                                                iterations=50), sigma0=sigma0, redundancy=redundancy, **extra)


def _uav_project(tmp_path):
    proj = tmp_path / "proj"
    (proj / "match").mkdir(parents=True)
    (proj / "match" / "tie_points.csv").write_text("point,image,column,row\n")
    old = proj / "adjust-uav"
    old.mkdir()
    (old / "eo.csv").write_text("previous run\n")
    return proj


CASES = [
    ("not-converged", _adj(converged=False), "did not converge (maximum iterations reached; 50 iterations)"),
    ("sigma0-inf", _adj(sigma0=math.inf), "sigma0 is inf (not finite)"),
    ("sigma0-nan", _adj(sigma0=math.nan), "sigma0 is nan (not finite)"),
    ("no-redundancy", _adj(redundancy=0), "no redundancy"),
    ("stated-failure", _adj(failures=["a single image with points to intersect"]), "a single image with points"),
]


@pytest.mark.parametrize("keep", [False, True], ids=["default", "keep-failed"])
@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_adjust_uav_failure_exits_1_with_reason(tmp_path, monkeypatch, case, keep):
    _, adj, words = case
    monkeypatch.setattr("skyrig.pipeline.uav.adjust_uav", _fake_adjust_uav(adj))
    proj = _uav_project(tmp_path)
    res = CliRunner().invoke(main, ["adjust-uav", str(proj)] + (["--keep-failed"] if keep else []))
    assert res.exit_code == 1, res.output  # a failed run: 1 (docs/cli.md), as skyrig adjust
    assert "error: the UAV adjustment failed: " in res.output and words in res.output
    assert "Traceback" not in res.output and "written to" not in res.output
    eo = (proj / "adjust-uav" / "eo.csv").read_text()
    if keep:
        assert eo == "new run\n" and "outputs kept" in res.output
        assert (proj / "adjust-uav" / "report.json").exists()
    else:  # the previous run's outputs are left as they were, nothing half-written
        assert eo == "previous run\n" and "no outputs written" in res.output
        assert not (proj / "adjust-uav" / "report.json").exists()
    assert [p.name for p in proj.iterdir()] == sorted(["match", "adjust-uav"]) or \
        sorted(p.name for p in proj.iterdir()) == ["adjust-uav", "match"]  # no staging folder left behind


def test_adjust_uav_success_publishes(tmp_path, monkeypatch):
    monkeypatch.setattr("skyrig.pipeline.uav.adjust_uav", _fake_adjust_uav(_adj(failures=[])))
    proj = _uav_project(tmp_path)
    res = CliRunner().invoke(main, ["adjust-uav", str(proj), "-o", str(tmp_path / "new" / "out")])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "new" / "out" / "eo.csv").read_text() == "new run\n" and "written to" in res.output
    assert sorted(p.name for p in (tmp_path / "new").iterdir()) == ["out"]


def test_adjust_uav_out_under_a_file(tmp_path, monkeypatch):
    monkeypatch.setattr("skyrig.pipeline.uav.adjust_uav", _fake_adjust_uav(_adj()))
    proj = _uav_project(tmp_path)
    (tmp_path / "somefile.txt").write_text("x")
    for out in ("somefile.txt", "somefile.txt/out"):
        res = CliRunner().invoke(main, ["adjust-uav", str(proj), "--out", str(tmp_path / out)])
        assert res.exit_code == 2, res.output
        assert "'--out'" in res.output or f"-o/--out {tmp_path / out}:" in res.output  # click checks the first
        assert str(tmp_path / "somefile.txt") in res.output and "is a file" in res.output
        assert "Traceback" not in res.output and "staging" not in res.output
    assert (tmp_path / "somefile.txt").read_text() == "x"


# ------------------------------------------------------------------------------------------------ output paths
def test_atomic_write_under_a_regular_file(tmp_path):
    (tmp_path / "somefile.txt").write_text("keep")
    for rel in ("somefile.txt/out.csv", "somefile.txt/deeper/out.csv"):
        with pytest.raises(OutputPathError) as ei:
            with atomic_write(tmp_path / rel) as fh:
                fh.write("x")
        e = ei.value
        assert isinstance(e, SkyrigError) and isinstance(e, OSError)
        assert e.path == str(tmp_path / rel) and f"'{tmp_path / 'somefile.txt'}' is a file, not a folder" in str(e)
        assert ".tmp" not in str(e)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["somefile.txt"]


def test_atomic_write_onto_a_folder(tmp_path):
    (tmp_path / "d").mkdir()
    with pytest.raises(OutputPathError, match="is a folder; give a file name"):
        with atomic_write(tmp_path / "d") as fh:
            fh.write("x")
    with pytest.raises(OutputPathError, match="is a folder"):
        output_temp(tmp_path / "d")
    assert list((tmp_path / "d").iterdir()) == [] and sorted(p.name for p in tmp_path.iterdir()) == ["d"]


def test_check_output_dir(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(OutputPathError, match="is a file, not a folder"):
        check_output_dir(tmp_path / "f")
    with pytest.raises(OutputPathError, match="'.*f' is a file, not a folder"):
        check_output_dir(tmp_path / "f" / "sub")
    assert check_output_dir(tmp_path / "a" / "b").is_dir()
    assert not check_output_dir(tmp_path / "c", create=False).exists()


def _writers():
    from skyrig.georef.eo import ExteriorOrientations, WorldFrame
    from skyrig.georef.ground import Dem
    from skyrig.georef.observations import GroundPoints

    utm = WorldFrame.map("EPSG:25832")
    eo = ExteriorOrientations(["a"], ["cam"], [[5e5, 5.7e6, 900.0]], np.eye(3)[None], utm)
    pts = GroundPoints(np.array(["p"]), np.array([[5e5, 5.7e6, 100.0]]), utm)

    def eo_csv(p):
        from skyrig.io.eo_csv import write_eo_csv
        write_eo_csv(eo, p)

    def points_csv(p):
        from skyrig.io.points_csv import write_points_csv
        write_points_csv(p, pts)

    def ign_opk(p):
        from skyrig.io.ign import write_ign_opk
        write_ign_opk(p, eo)

    def rig(p):
        from skyrig.io.rig_file import write_rig
        from skyrig.rig import preset
        write_rig(preset("midas"), p)

    def image(p):
        from skyrig.io.images import write_image
        write_image(p.with_suffix(".png"), np.zeros((4, 4, 3), np.uint8))

    def dem(p):
        from skyrig.io.dem import write_dem
        write_dem(p.with_suffix(".tif"), Dem(np.zeros((4, 4)), (1.0, 0.0, 5e5, 0.0, -1.0, 5.7e6), utm))

    def laz(p):
        from skyrig.io.laz import write_las
        write_las(p.with_suffix(".laz"), np.array([[5e5, 5.7e6, 100.0]]), "EPSG:25832")

    return {f.__name__: f for f in (eo_csv, points_csv, ign_opk, rig, image, dem, laz)}


@pytest.mark.parametrize("writer", sorted(_writers()))
def test_every_writer_under_a_regular_file(tmp_path, writer):
    (tmp_path / "somefile.txt").write_text("keep")
    with pytest.raises(OutputPathError) as ei:
        _writers()[writer](tmp_path / "somefile.txt" / "out.csv")
    assert "is a file, not a folder" in str(ei.value) and str(tmp_path / "somefile.txt") in str(ei.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["somefile.txt"]


def test_cli_output_under_a_regular_file_names_option_and_path(tmp_path):
    from test_bad_input_intersection import _project, _scene

    _, truth, names, images, px = _scene()
    _project(tmp_path, px, names, images)
    (tmp_path / "somefile.txt").write_text("keep")
    out = tmp_path / "somefile.txt" / "out.csv"
    res = CliRunner().invoke(main, ["image-to-world", "--eo", str(tmp_path / "eo.csv"), "--camera",
                                    str(tmp_path / "cam.txt"), "--measurements", str(tmp_path / "mes.csv"),
                                    "--height", "100", "-o", str(out)])
    assert res.exit_code == 2, res.output
    assert res.output.strip() == (f"error: -o {out}: '{tmp_path / 'somefile.txt'}' is a file, not a folder")


def test_option_for_path():
    assert option_for_path(["x", "-o", "a/b.csv"], "a/b.csv") == ("-o", "a/b.csv")
    assert option_for_path(["x", "--outdir=a"], "a/b.csv") == ("--outdir", "a")
    assert option_for_path(["convert", "in.OPK", "out/x.csv"], "out/x.csv") == ("argument", "out/x.csv")
    assert option_for_path(["x", "-o", "a"], "b/c.csv") is None


def test_outputs_get_ordinary_permissions(tmp_path):
    import os
    import stat

    from skyrig.io._text import _umask

    with atomic_write(tmp_path / "a.csv") as fh:
        fh.write("x")
    assert stat.S_IMODE(os.stat(tmp_path / "a.csv").st_mode) == 0o666 & ~_umask()
