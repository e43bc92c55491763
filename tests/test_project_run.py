"""Project runs (skyrig.pipeline.project / run, ``skyrig init`` / ``skyrig run``).

Fast part: the runner's resume rules on a registry of two toy stages (what ran is counted, not assumed), failing
and interrupted stages, bad project files (file, line and key path checked against the line found in the text),
and ``skyrig init`` + ``skyrig run`` of the georef stage on the built-in demo flight against the demo's
independent composition of the same flight.

Slow part (one simulated MIDAS project, computed once): ``skyrig init`` on a ``skyrig simulate midas-demo`` folder,
``skyrig run`` to the DSM, the DSM against the scene's analytic surface, the stages' outputs against the
individual commands, resume / option change / failure / kill.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from skyrig.errors import InputFormatError
from skyrig.io.stage import read_manifest, verify_folder
from skyrig.pipeline.project import Option, load_project, parse_project
from skyrig.pipeline.run import Stage, StageContext, plan_run, register_stage, run_project

SKYRIG = [str(Path(sys.executable).parent / "skyrig")]  # the installed command, as a user runs it


# ------------------------------------------------------------------------------------------ toy registry
class Calls:
    def __init__(self) -> None:
        self.ran: list[str] = []
        self.fail: set[str] = set()
        self.interrupt: set[str] = set()


def _toy_registry(calls: Calls) -> dict[str, Stage]:
    reg: dict[str, Stage] = {}

    def a(ctx: StageContext) -> dict:
        calls.ran.append("a")
        src = ctx.project.control
        assert src is not None
        text = src.read_text() + f"|scale={ctx.options['scale']}"
        (ctx.out / "a.txt").write_text(text)
        return {"chars": len(text)}

    def b(ctx: StageContext) -> dict:
        calls.ran.append("b")
        if calls.fail or calls.interrupt:
            (ctx.out / "partial.txt").write_text("half")  # what a stage dying half-way leaves in its staging
        if "b" in calls.fail:
            raise RuntimeError("boom")
        if "b" in calls.interrupt:
            raise KeyboardInterrupt
        (ctx.out / "b.txt").write_text(ctx.need("a").read_text() + f"|word={ctx.options['word']}")
        return {}

    register_stage(Stage("a", "toy a", a, {"scale": Option(1.0, "float", "a number")}, provides={"a": "a.txt"},
                         inputs=lambda p, o: [p.control]), reg)
    register_stage(Stage("b", "toy b", b, {"word": Option("x", "str", "a word")}, requires=("a",),
                         provides={"b": "b.txt"}), reg)
    return reg


def _toy_project(tmp: Path, a_opts: str = "{}", b_opts: str = "{}") -> Path:
    (tmp / "in.txt").write_text("input-1") if not (tmp / "in.txt").exists() else None
    p = tmp / "project.yaml"
    p.write_text("format: skyrig-project\nversion: 1\ncrs: EPSG:25832\ninputs:\n  control: in.txt\n"
                 f"stages:\n  a: {a_opts}\n  b: {b_opts}\n")
    return p


def _run(tmp: Path, calls: Calls, reg: dict, **kw):  # type: ignore[no-untyped-def]
    calls.ran.clear()
    proj = load_project(tmp / "project.yaml", reg)
    return run_project(proj, registry=reg, **kw)


def test_resume_reruns_only_what_changed(tmp_path: Path) -> None:
    calls = Calls()
    reg = _toy_registry(calls)
    _toy_project(tmp_path)
    r = _run(tmp_path, calls, reg)
    assert r.ok and calls.ran == ["a", "b"]
    assert (tmp_path / "output" / "b" / "b.txt").read_text() == "input-1|scale=1.0|word=x"
    assert verify_folder(tmp_path / "output" / "a") == [] and verify_folder(tmp_path / "output" / "b") == []
    # nothing changed: nothing runs
    r = _run(tmp_path, calls, reg)
    assert r.ok and calls.ran == [] and [s["status"] for s in r.stages] == ["skipped", "skipped"]
    # an option of the second stage: only it
    _toy_project(tmp_path, b_opts="{word: y}")
    assert [a for _, a, _ in plan_run(load_project(tmp_path / "project.yaml", reg), registry=reg)] == ["skip", "run"]
    r = _run(tmp_path, calls, reg)
    assert calls.ran == ["b"] and (tmp_path / "output" / "b" / "b.txt").read_text().endswith("word=y")
    # an option of the first stage: it and the one using its output
    _toy_project(tmp_path, a_opts="{scale: 2}", b_opts="{word: y}")
    r = _run(tmp_path, calls, reg)
    assert calls.ran == ["a", "b"] and "scale=2.0" in (tmp_path / "output" / "b" / "b.txt").read_text()
    # an input file's content
    (tmp_path / "in.txt").write_text("input-2")
    r = _run(tmp_path, calls, reg)
    assert calls.ran == ["a", "b"] and (tmp_path / "output" / "b" / "b.txt").read_text().startswith("input-2")
    # a published output edited by hand: that stage reruns (its folder no longer matches its manifest)
    (tmp_path / "output" / "b" / "b.txt").write_text("edited")
    r = _run(tmp_path, calls, reg)
    assert calls.ran == ["b"]
    # --from / --only / --force
    r = _run(tmp_path, calls, reg, from_stage="b")
    assert calls.ran == ["b"] and r.stages[0]["status"] == "not-selected"
    r = _run(tmp_path, calls, reg, only="a")
    assert calls.ran == ["a"]
    r = _run(tmp_path, calls, reg, force=True)
    assert calls.ran == ["a", "b"]
    run_json = json.loads((tmp_path / "output" / "run.json").read_text())
    assert [s["status"] for s in run_json["stages"]] == ["done", "done"] and run_json["exit_code"] == 0


def test_failed_or_interrupted_stage_leaves_earlier_outputs(tmp_path: Path) -> None:
    calls = Calls()
    reg = _toy_registry(calls)
    _toy_project(tmp_path)
    assert _run(tmp_path, calls, reg).ok
    before = {s: read_manifest(tmp_path / "output" / s) for s in ("a", "b")}
    _toy_project(tmp_path, b_opts="{word: z}")
    calls.fail = {"b"}
    r = _run(tmp_path, calls, reg)
    assert r.exit_code == 1 and "boom" in (r.error or "") and r.stages[-1]["status"] == "failed"
    calls.fail = set()
    calls.interrupt = {"b"}
    with pytest.raises(KeyboardInterrupt):
        _run(tmp_path, calls, reg)
    for s in ("a", "b"):
        assert read_manifest(tmp_path / "output" / s) == before[s]
        assert verify_folder(tmp_path / "output" / s) == []
    assert not (tmp_path / "output" / "b" / "partial.txt").exists()
    assert not [p.name for p in (tmp_path / "output").iterdir() if ".partial-" in p.name]
    calls.interrupt = set()
    r = _run(tmp_path, calls, reg)
    assert r.ok and calls.ran == ["b"] and (tmp_path / "output" / "b" / "b.txt").read_text().endswith("word=z")


def test_failed_stage_that_keeps_its_outputs(tmp_path: Path) -> None:
    """A stage that returns {"failed": ...} (keep_failed) is published, the run stops with status 1."""
    calls = Calls()
    reg = _toy_registry(calls)
    a = reg.pop("a")
    register_stage(Stage("a", a.help, lambda ctx: {**(a.run(ctx) or {}), "failed": "did not converge"}, a.options,
                         provides=a.provides, inputs=a.inputs), reg)
    _toy_project(tmp_path)
    r = _run(tmp_path, calls, reg)
    assert r.exit_code == 1 and "did not converge" in (r.error or "") and calls.ran == ["a"]
    assert verify_folder(tmp_path / "output" / "a") == [] and not (tmp_path / "output" / "b").exists()
    assert (tmp_path / "output" / "a" / "FAILED.txt").is_file()
    r = _run(tmp_path, calls, reg)  # a failed stage is never up to date
    assert r.exit_code == 1 and calls.ran == ["a"]


def test_only_needs_published_inputs(tmp_path: Path) -> None:
    calls = Calls()
    reg = _toy_registry(calls)
    _toy_project(tmp_path)
    r = _run(tmp_path, calls, reg, only="b")
    assert r.exit_code == 2 and "stage a" in (r.error or "") and calls.ran == []


# ------------------------------------------------------------------------------------------ bad project files
GOOD = """format: skyrig-project
version: 1
crs: EPSG:25832
inputs:
  control: in.txt
stages:
  a: {scale: 2}
  b:
    word: y
"""


def _line_of(text: str, needle: str) -> int:
    return next(i for i, ln in enumerate(text.splitlines(), 1) if needle in ln)


@pytest.mark.parametrize("bad, needle, field, words", [
    (GOOD.replace("version: 1\n", "version: 1\ncolour: red\n"), "colour:", "colour", "unknown key"),
    (GOOD.replace("  b:\n    word: y\n", "  c: {}\n"), "  c:", "stages.c", "unknown stage"),
    (GOOD.replace("word: y", "wrod: y"), "wrod:", "stages.b.wrod", "unknown key"),
    (GOOD.replace("{scale: 2}", "{scale: two}"), "  a:", "stages.a.scale", "expected a number"),
    (GOOD.replace("control: in.txt", "control: missing.txt"), "control:", "inputs.control", "no such file"),
    (GOOD.replace("crs: EPSG:25832", "crs: EPSG:99999999"), "crs:", "crs", "CRS"),
    (GOOD.replace("  a: {scale: 2}\n  b:\n    word: y\n", "  b:\n    word: y\n  a: {}\n"), "  b:", "stages.b",
     "needs a"),
    (GOOD.replace("format: skyrig-project", "format: skyrig-rig"), "format:", "format", "expected format"),
    (GOOD.replace("version: 1\n", "version: 1\nexecutor: {workers: 0}\n"), "executor:", "executor.workers",
     "positive"),
    (GOOD.replace("version: 1\n", "version: 1\nversion: 2\n"), "version: 2", None, "duplicate key"),
    (GOOD.replace("  b:\n    word: y\n", "  b:\n    word: [y\n"), None, None, "not valid YAML"),
])
def test_bad_project_file_names_file_line_field(tmp_path: Path, bad: str, needle: str | None, field: str | None,
                                               words: str) -> None:
    calls = Calls()
    reg = _toy_registry(calls)
    (tmp_path / "in.txt").write_text("x")
    p = tmp_path / "project.yaml"
    p.write_text(bad)
    with pytest.raises(InputFormatError) as ei:
        load_project(p, reg)
    e = ei.value
    assert e.path == str(p.absolute()) and words in str(e)
    if needle is not None:
        assert e.line == _line_of(bad, needle), str(e)
    else:
        assert e.line is not None
    if field is not None:
        assert e.field == field
    # the good file reads
    p.write_text(GOOD)
    assert [s.name for s in load_project(p, reg).stages] == ["a", "b"]


def test_bad_project_file_cli_exit_2(tmp_path: Path) -> None:
    from skyrig.cli import main

    (tmp_path / "in.txt").write_text("x")
    p = tmp_path / "project.yaml"
    p.write_text(GOOD.replace("  a: {scale: 2}\n", "  georef: {convention: xyz}\n").replace("  b:\n    word: y\n", ""))
    r = CliRunner().invoke(main, ["run", str(p)])
    assert r.exit_code == 2
    assert f"line {_line_of(p.read_text(), 'georef:')}" in r.output and "stages.georef.convention" in r.output


# ------------------------------------------------------------------------------------------ init + georef
def test_init_and_run_georef_on_the_demo_flight(tmp_path: Path) -> None:
    """skyrig init on the demo inputs (no images: georef only), skyrig run; the EO equals the demo's independent
    composition of the same flight (explicit ECEF/NED matrices, PROJ only for UTM) within 5 mm / 1 arcsec."""
    from skyrig.cli import main
    from skyrig.io.eo_csv import read_eo_csv
    from skyrig.io.events_csv import read_events_csv
    from skyrig.io.rig_file import read_rig
    from skyrig.io.trajectory_csv import read_trajectory_csv
    from skyrig.pipeline.demo import build_demo_project, independent_eo, rotation_angle_deg

    paths = build_demo_project(tmp_path / "flight")
    runner = CliRunner()
    r = runner.invoke(main, ["init", str(tmp_path / "flight")])
    assert r.exit_code == 0, r.output
    text = (tmp_path / "flight" / "project.yaml").read_text()
    assert "crs: EPSG:25832" in text and "georef:" in text and "match:" not in text
    r = runner.invoke(main, ["run", str(tmp_path / "flight" / "project.yaml")])
    assert r.exit_code == 0, r.output
    eo = read_eo_csv(tmp_path / "flight" / "output" / "georef" / "eo.csv")
    events = read_events_csv(paths.events)
    centres, rots = independent_eo(read_trajectory_csv(paths.trajectory), events, read_rig(paths.rig))
    rows = np.array([eo.index()[n] for n in events.image_name])
    assert np.abs(eo.centre[rows] - centres).max() < 0.005
    assert rotation_angle_deg(eo.rotation[rows], rots).max() < 1.0 / 3600
    r = runner.invoke(main, ["run", str(tmp_path / "flight")])
    assert r.exit_code == 0 and "skipped (up to date)" in r.output
    r = runner.invoke(main, ["run", str(tmp_path / "flight"), "--dry-run"])
    assert r.exit_code == 0 and r.output.split()[:3] == ["georef", "skip", "up"], r.output
    r = runner.invoke(main, ["run", "--list-stages"])
    assert r.exit_code == 0 and all(f"{s}:" in r.output for s in ("georef", "match", "block", "adjust", "dsm"))
    r = runner.invoke(main, ["run", str(tmp_path / "flight"), "--only", "dsm"])
    assert r.exit_code == 2 and "no such stage" in r.output
    r = runner.invoke(main, ["init", str(tmp_path / "flight")])
    assert r.exit_code == 2 and "--force" in r.output


def test_builtin_stages_plug_in() -> None:
    from skyrig.pipeline.run import STAGES

    assert list(STAGES)[:4] == ["georef", "match", "block", "adjust"] and "dsm" in STAGES
    assert STAGES["dsm"].requires == ("eo",) and STAGES["adjust"].provides["eo"] == "eo.csv"
    with pytest.raises(Exception, match="twice"):
        register_stage(STAGES["dsm"])


# ------------------------------------------------------------------------------------------ slow: a simulated flight
@pytest.fixture(scope="module")
def sim_project(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from skyrig.cli import main

    root = tmp_path_factory.mktemp("project-run")
    folder = root / "flight"
    r = CliRunner().invoke(main, ["simulate", "midas-demo", "-o", str(folder), "--size", "ci", "--workers", "1"])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, ["init", str(folder)])
    assert r.exit_code == 0, r.output
    p = folder / "project.yaml"
    text = p.read_text()
    assert "terrain_height:" in text and "heads: [nadir]" in text and "free: [boresight]" in text
    # this machine is shared: serial, fewer features
    text = text.replace("  kind: auto ", "  kind: serial ").replace("    # max_features: 8000 ", "    max_features: 3000 ")
    p.write_text(text)
    res = subprocess.run([*SKYRIG, "run", str(p)], capture_output=True, text=True, timeout=900)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    return p


@pytest.mark.slow
def test_run_to_dsm_against_the_scene(sim_project: Path) -> None:
    import rasterio

    from skyrig.io.dsm_cog import read_dsm_cog
    from skyrig.simulate.judge import judge_dsm
    from skyrig.simulate.scenarios import build_survey, scenario_spec

    out = sim_project.parent / "output"
    for s in ("georef", "match", "block", "adjust", "dsm", "ortho"):
        assert verify_folder(out / s) == [], s
    with rasterio.open(out / "dsm" / "dsm.tif") as ds:
        assert ds.crs.to_epsg() == 25832
    survey = build_survey(scenario_spec("midas-demo", "ci", 1))
    dense = json.loads((out / "dsm" / "dense.json").read_text())
    dsm = read_dsm_cog(out / "dsm" / "dsm.tif")
    j = judge_dsm(dsm, survey.scene, dense["stats"]["gsd_m"], survey.spec.flights[0].area)
    # flat cells: robust spread within 1 GSD and no bias beyond 0.3 GSD (the dense stage's own acceptance figures)
    assert j["flat"]["nmad_gsd"] < 1.0 and abs(j["flat"]["bias_gsd"]) < 0.3, j["flat"]
    rep = json.loads((out / "adjust" / "report.json").read_text())
    assert 0.3 < rep["summary"]["sigma0"] < 1.5
    import html

    page = html.unescape((out / "adjust" / "report.html").read_text())  # written in the staging folder
    assert f"skyrig measure {sim_project} --adjustment {out / 'adjust'}" in page


@pytest.mark.slow
def test_stage_outputs_equal_the_individual_commands(sim_project: Path, tmp_path: Path) -> None:
    from skyrig.cli import main

    folder, out = sim_project.parent, sim_project.parent / "output"
    r = CliRunner().invoke(main, ["georef", "--trajectory", str(folder / "trajectory.csv"), "--events",
                                  str(folder / "events.csv"), "--rig", str(folder / "rig.yaml"), "--crs", "EPSG:25832",
                                  "-o", str(tmp_path / "eo.csv")])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "eo.csv").read_bytes() == (out / "georef" / "eo.csv").read_bytes()
    # block: the command with the project's inputs and the stage's options -> the same block
    from skyrig.io.block_file import read_block

    proj = load_project(sim_project)
    o = proj.stage("block").options
    args = ["block", "--trajectory", str(proj.trajectory), "--events", str(proj.events), "--rig", str(proj.rig),
            "--measurements", str(out / "match" / "tie_points.csv"),
            *[x for m in proj.measurements for x in ("--measurements", str(m))],
            *(["--control", str(proj.control)] if proj.control else []),
            *(["--check", str(proj.check)] if proj.check else []),
            "--image-sigma-px", str(o["sigma_px"]), "--gnss-sigma", ",".join(map(str, o["gnss_sigma"])),
            "--imu-sigma-deg", ",".join(map(str, o["imu_sigma_deg"])),
            "--control-sigma", ",".join(map(str, o["control_sigma"])), "--crs", proj.crs,
            *(["--free", ",".join(o["free"])] if o["free"] else []), "-o", str(tmp_path / "block" / "block.json")]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    a, b = read_block(tmp_path / "block" / "block.json"), read_block(out / "block" / "block.json")
    assert a.config == b.config and a.crs == b.crs
    for name in ("station_centre", "station_rotation", "obs_pixel", "obs_image", "obs_point", "point_xyz"):
        np.testing.assert_array_equal(getattr(a.block, name), getattr(b.block, name), err_msg=name)
    r = CliRunner().invoke(main, ["adjust", str(out / "block" / "block.json"), "-o", str(tmp_path / "adjust")])
    assert r.exit_code == 0, r.output
    for f in ("eo.csv", "points.csv", "ground_control.csv"):
        assert (tmp_path / "adjust" / f).read_bytes() == (out / "adjust" / f).read_bytes(), f
    # the product stages call the commands' library functions: same surface and mosaic as the commands
    from skyrig.io.dsm_cog import read_dsm_cog
    from skyrig.io.ortho_cog import read_ortho_cog

    proj = load_project(sim_project)
    o = next(s.options for s in proj.stages if s.name == "dsm")
    common = ["--eo", str(out / "adjust" / "eo.csv"), "--camera", str(proj.rig),
              *[x for d in proj.images for x in ("--images", str(d))], "--executor", "serial"]
    heads = ["--heads", ",".join(o["heads"])] if o["heads"] else []
    r = CliRunner().invoke(main, ["dsm", *common, *heads, "--crs", proj.crs, "--points",
                                  str(out / "adjust" / "points.csv"), "-o", str(tmp_path / "dsm")])
    assert r.exit_code == 0, r.output
    np.testing.assert_array_equal(read_dsm_cog(tmp_path / "dsm" / "dsm.tif").height,
                                  read_dsm_cog(out / "dsm" / "dsm.tif").height)
    o = next(s.options for s in proj.stages if s.name == "ortho")
    heads = ["--heads", ",".join(o["heads"])] if o["heads"] else []
    r = CliRunner().invoke(main, ["ortho", *common, *heads, "--dsm", str(out / "dsm" / "dsm.tif"),
                                  "-o", str(tmp_path / "ortho")])
    assert r.exit_code == 0, r.output
    a, b = read_ortho_cog(tmp_path / "ortho" / "ortho.tif"), read_ortho_cog(out / "ortho" / "ortho.tif")
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])


@pytest.mark.slow
def test_option_change_reruns_from_that_stage_and_failure_keeps_outputs(sim_project: Path) -> None:
    out = sim_project.parent / "output"
    created = {s: read_manifest(out / s)["created"] for s in ("georef", "match", "block", "adjust", "dsm")}
    res = subprocess.run([*SKYRIG, "run", str(sim_project)], capture_output=True, text=True, timeout=600)
    # georef, match, block, adjust, dsm, ortho
    assert res.returncode == 0 and res.stderr.count("skipped (up to date)") == 6, res.stderr
    text = sim_project.read_text()
    time.sleep(1.1)  # manifests carry the second
    sim_project.write_text(text.replace("    # pairs_per_image: 6 ", "    pairs_per_image: 4 "))
    res = subprocess.run([*SKYRIG, "run", str(sim_project)], capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr
    now = {s: read_manifest(out / s)["created"] for s in created}
    assert [s for s in created if now[s] != created[s]] == ["dsm"]
    # a failing DSM (no surface in an absurd height window): exit non-zero, every output as it was
    dsm_manifest = read_manifest(out / "dsm")
    sim_project.write_text(text.replace("    # height_range: null ", "    height_range: [5000, 5001] "))
    res = subprocess.run([*SKYRIG, "run", str(sim_project)], capture_output=True, text=True, timeout=600)
    assert res.returncode in (1, 2) and "dsm" in res.stderr, res.stderr
    assert read_manifest(out / "dsm") == dsm_manifest and verify_folder(out / "dsm") == []
    assert {s: read_manifest(out / s)["created"] for s in created if s != "dsm"} == \
        {s: now[s] for s in created if s != "dsm"}
    assert not [p for p in out.iterdir() if ".partial-" in p.name]
    sim_project.write_text(text.replace("    # pairs_per_image: 6 ", "    pairs_per_image: 4 "))


@pytest.mark.slow
def test_killed_stage_and_local_cluster(sim_project: Path) -> None:
    """SIGKILL during matching leaves every published folder as it was; then the same stages on a LocalCluster
    of 2 worker processes (resuming the killed run's feature store) give the serial run's outputs bit for bit."""
    import shutil

    from skyrig.io.dsm_cog import read_dsm_cog

    out = sim_project.parent / "output"
    stages = ("georef", "match", "block", "adjust", "dsm")
    before = {s: read_manifest(out / s) for s in stages}
    ties_serial = (out / "match" / "tie_points.csv").read_bytes()
    dsm_serial = read_dsm_cog(out / "dsm" / "dsm.tif").height
    shutil.rmtree(out / ".cache" / "match")  # the feature store: matching starts from nothing
    proc = subprocess.Popen([*SKYRIG, "run", str(sim_project), "--only", "match", "--force"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.time() + 120
        while time.time() < deadline and not any(".match.partial-" in p.name for p in out.iterdir()):
            time.sleep(0.2)
        time.sleep(3.0)  # features under way
        assert proc.poll() is None, "the match stage ended before it could be killed"
        os.killpg(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(timeout=60)
    for s, m in before.items():
        assert read_manifest(out / s) == m and verify_folder(out / s) == [], s
    plan = {n: a for n, a, _ in plan_run(load_project(sim_project))}
    # every stage of the project (the ortho after the DSM too) is still up to date: nothing to redo
    assert set(stages) <= set(plan) and set(plan.values()) == {"skip"}, plan
    text = sim_project.read_text()
    try:
        sim_project.write_text(text.replace("  kind: serial ", "  kind: local ").replace("  workers: null ",
                                                                                           "  workers: 2 "))
        for st in ("match", "dsm"):
            res = subprocess.run([*SKYRIG, "run", str(sim_project), "--only", st, "--force"], capture_output=True,
                                 text=True, timeout=900)
            assert res.returncode == 0, res.stderr[-3000:]
        assert not [p for p in out.iterdir() if ".partial-" in p.name]  # the killed run's staging went
        assert (out / "match" / "tie_points.csv").read_bytes() == ties_serial
        np.testing.assert_array_equal(read_dsm_cog(out / "dsm" / "dsm.tif").height, dsm_serial)
        # the executor is not part of a stage's fingerprint
        assert read_manifest(out / "dsm")["options"]["fingerprint"] == before["dsm"]["options"]["fingerprint"]
    finally:
        sim_project.write_text(text)
