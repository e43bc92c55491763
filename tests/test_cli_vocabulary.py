"""Issue 13, deliverable 5: one CLI vocabulary.

- ``-o/--output`` names every command's output (a file for single-file commands, a folder for the others):
  ``convert``, ``simulate`` and ``demo`` took a positional destination; the positional form still works with a
  deprecation warning on standard error, both at once is a usage error.
- ``adjust --outdir`` is the older spelling of ``-o/--output``: accepted with the same warning as
  ``adjust-uav --out``; the adjustment's own warnings go to standard error.
- ``skyrig block`` reads every EO and point format the other commands read (IGN .OPK/.app/.mes here, checked
  against IGN's own orientations of the real block).
"""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from skyrig.cli import main
from skyrig.georef.eo import ExteriorOrientations, WorldFrame
from skyrig.io.eo_csv import read_eo_csv, write_eo_csv


def _eo_file(tmp_path):  # type: ignore[no-untyped-def]
    from skyrig.geometry.rotations import matrix_from_rotvec

    rng = np.random.default_rng(0)
    n = 4
    eo = ExteriorOrientations(np.array([f"im{k}.tif" for k in range(n)]), np.array(["cam"] * n),
                              np.column_stack([549700 + 100 * np.arange(n), np.full(n, 5799900.0), np.full(n, 800.0)]),
                              matrix_from_rotvec(rng.normal(0, 0.02, (n, 3))),  # nadir (looking up is refused)
                              WorldFrame.map("EPSG:25832"))
    write_eo_csv(eo, tmp_path / "eo.csv")
    return tmp_path / "eo.csv", eo


def test_convert_output_option_and_the_deprecated_positional(tmp_path):
    src, eo = _eo_file(tmp_path)
    run = CliRunner()
    r = run.invoke(main, ["convert", str(src), "-o", str(tmp_path / "a.csv"), "--to-crs", "EPSG:4326"])
    assert r.exit_code == 0, r.output
    assert "deprecated" not in r.output
    back = read_eo_csv(tmp_path / "a.csv").to_frame(eo.frame)  # PROJ there and back: the same orientations
    assert np.abs(back.centre - eo.centre).max() < 1e-4 and np.abs(back.rotation - eo.rotation).max() < 1e-8
    r = run.invoke(main, ["convert", str(src), str(tmp_path / "b.csv"), "--to-crs", "EPSG:4326"])
    assert r.exit_code == 0, r.output
    assert "warning: the positional DST is deprecated; use -o/--output" in r.stderr
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()
    r = run.invoke(main, ["convert", str(src), str(tmp_path / "c.csv"), "-o", str(tmp_path / "d.csv")])
    assert r.exit_code == 2 and "given twice" in r.output and not (tmp_path / "c.csv").exists()
    r = run.invoke(main, ["convert", str(src)])
    assert r.exit_code == 2 and "'-o' / '--output'" in r.output


def test_simulate_output_option_and_the_deprecated_positional(tmp_path, monkeypatch):
    seen: list[str] = []

    def fake(scenario, outdir, **kw):  # type: ignore[no-untyped-def]
        from types import SimpleNamespace

        seen.append(str(outdir))
        return SimpleNamespace(n_images=0, summary="stub", total_s=0.0, outdir=outdir)

    monkeypatch.setattr("skyrig.pipeline.simulate.simulate_scenario", fake)
    run = CliRunner()
    r = run.invoke(main, ["simulate", "midas", "-o", str(tmp_path / "a")])
    assert r.exit_code == 0 and "deprecated" not in r.output, r.output
    r = run.invoke(main, ["simulate", "midas", str(tmp_path / "b")])
    assert r.exit_code == 0 and "warning: the positional OUTDIR is deprecated" in r.stderr, r.output
    assert seen == [str(tmp_path / "a"), str(tmp_path / "b")]
    r = run.invoke(main, ["simulate", "midas", str(tmp_path / "c"), "--output", str(tmp_path / "d")])
    assert r.exit_code == 2 and "given twice" in r.output
    r = run.invoke(main, ["simulate", "midas"])
    assert r.exit_code == 2 and "'-o' / '--output'" in r.output
    assert len(seen) == 2


def test_demo_output_option_default_and_the_deprecated_positional(tmp_path, monkeypatch):
    import click

    seen: list[str] = []

    def fake(outdir):  # type: ignore[no-untyped-def]
        seen.append(str(outdir))
        raise click.ClickException("stub stops here")

    monkeypatch.setattr("skyrig.pipeline.demo.build_demo_project", fake)
    run = CliRunner()
    for args, warned in ((["-o", str(tmp_path / "a")], False), ([str(tmp_path / "b")], True), ([], False)):
        r = run.invoke(main, ["demo", *args])
        assert r.exit_code == 1 and "stub stops here" in r.output, r.output
        assert ("warning: the positional OUTDIR is deprecated" in r.stderr) == warned
    assert seen == [str(tmp_path / "a"), str(tmp_path / "b"), "demo-output"]


def test_help_shows_one_output_spelling():
    run = CliRunner()
    for cmd in ("convert", "simulate", "demo", "adjust", "block", "match"):
        r = run.invoke(main, [cmd, "--help"])
        assert r.exit_code == 0 and "-o, --output" in r.output, (cmd, r.output)
        assert "--outdir" not in r.output.replace("(--outdir: deprecated", ""), (cmd, r.output)


def test_adjust_outdir_warned_as_deprecated(tmp_path):
    (tmp_path / "block.json").write_text("{}\n")
    r = CliRunner().invoke(main, ["adjust", str(tmp_path / "block.json"), "--outdir", str(tmp_path / "adj")])
    assert "warning: --outdir is deprecated; use --output" in r.stderr, r.output
    assert r.exit_code == 2 and "block.json" in r.output and "Traceback" not in r.output  # the empty block refused


def _ign_block(d, out):  # type: ignore[no-untyped-def]
    return CliRunner().invoke(main, [
        "block", "--eo", str(d / "23FD1305_alt_test.OPK"), "--eo-crs", "EPSG:2154", "--eo-geoid",
        str(d / "fr_ign_RAF20.tif"), "--eo-map-z-ground", "53", "--camera", str(d / "Camera1.txt"),
        "--camera", str(d / "Camera2.txt"), "--measurements", str(d / "liaisons_test.mes"),
        "--measurements", str(d / "terrain_test.mes"), "--control", str(d / "GCP_test.app"),
        "--gnss-sigma", "0.1", "--imu-sigma-deg", "0.01", "-o", str(out)])


def test_block_reads_ign_formats(ign_dir, tmp_path):
    """IGN .OPK with --eo-crs/--eo-geoid/--eo-map-z-ground, IGN .mes measurements, IGN .app control read in the
    EO's CRS (what world-to-image reads): the block's control points are the .app coordinates."""
    from skyrig.io.ign import read_ign_ground_points

    d = ign_dir / "dataset"
    r = _ign_block(d, tmp_path / "b" / "block.json")
    assert r.exit_code == 0, r.output
    assert "7 images" in r.output and "3 ground points" in r.output and "Lambert-93" in r.output
    assert "left out 0 of 24 measurements" in r.output
    from skyrig.io.block_file import read_block

    bf = read_block(tmp_path / "b" / "block.json")
    gp = read_ign_ground_points(d / "GCP_test.app", WorldFrame.map("EPSG:2154"))
    local = bf.frame.from_ecef(gp.frame.to_ecef(gp.xyz))
    names = list(bf.block.point_name[bf.block.control_point])
    assert sorted(names) == sorted(gp.name.tolist())
    got = bf.block.control_xyz[[names.index(n) for n in gp.name]]
    assert np.abs(got - local).max() < 1e-3


@pytest.mark.slow  # block + adjustment of the real IGN block (~6 s CPU, more on a loaded machine)
def test_block_from_ign_formats_adjusts_and_adjust_warns_on_stderr(ign_dir, tmp_path):
    """The real IGN block (7 images) adjusted with the EO as GNSS/IMU observations (0.1 m, 0.01 deg): the
    orientations stay within 3 sigma of IGN's own, the control residuals within 3 sigma of the control sigma.
    `adjust --outdir` warned; the adjustment's warnings on standard error only."""
    d = ign_dir / "dataset"
    r = _ign_block(d, tmp_path / "b" / "block.json")
    assert r.exit_code == 0, r.output
    run = CliRunner()
    r = run.invoke(main, ["adjust", str(tmp_path / "b" / "block.json"), "--outdir", str(tmp_path / "adj")])
    assert r.exit_code == 0, r.output
    assert "warning: --outdir is deprecated; use --output" in r.stderr
    assert "warning:" not in r.stdout, r.stdout  # warnings belong on standard error
    from skyrig.cli._common import load_eo
    from skyrig.geometry.rotations import rotvec_from_matrix
    from skyrig.io.points_csv import read_points_csv

    ign = load_eo(str(d / "23FD1305_alt_test.OPK"), None, "EPSG:2154", str(d / "fr_ign_RAF20.tif"), 53.0)
    adj = read_eo_csv(tmp_path / "adj" / "eo.csv")
    ref = ign.to_frame(adj.frame)
    rows = np.array([ref.index()[n] for n in adj.image])
    assert len(adj) == 7
    assert np.abs(adj.centre - ref.centre[rows]).max() < 0.3
    ang = np.degrees(np.linalg.norm(rotvec_from_matrix(np.swapaxes(ref.rotation[rows], -1, -2) @ adj.rotation), axis=1))
    assert ang.max() < 0.03
    gc = read_points_csv(tmp_path / "adj" / "ground_control.csv")
    assert len(gc) == 3
    import csv

    rows_gc = list(csv.DictReader(line for line in open(tmp_path / "adj" / "ground_control.csv") if line[0] != "#"))
    assert max(abs(float(x[k])) for x in rows_gc for k in ("vx", "vy", "vz")) < 3 * 0.02


@pytest.mark.parametrize("cmd", ["convert", "simulate", "demo"])
def test_docs_cli_states_the_output_option(cmd):
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "cli.md").read_text()
    row = next(line for line in text.splitlines() if line.startswith(f"| `{cmd}` |"))
    assert row.split("|")[3].strip().startswith("`-o/--output`"), row


@pytest.mark.parametrize("cmd,old,new", [("block", "--sigma-px", "--image-sigma-px"),
                                         ("adjust-uav", "--gcp", "--control"),
                                         ("adjust-uav", "--gcp-sigma", "--control-sigma")])
def test_one_spelling_per_option_old_ones_warn(cmd, old, new, tmp_path):
    """One spelling per option across commands (block and adjust-uav: --control/--control-sigma, calibrate and block:
    --image-sigma-px): the old spellings still parse, with a deprecation warning naming the new one."""
    from click.testing import CliRunner

    from skyrig.cli import main

    r = CliRunner().invoke(main, [cmd, old, "0.5", "-o", str(tmp_path / "x")])
    assert f"warning: {old} is deprecated; use {new}" in r.output, r.output
    assert f"no such option: {old}" not in r.output.lower()
    r = CliRunner().invoke(main, [cmd, "--help"])
    assert new in r.output and f"{old} " not in r.output
