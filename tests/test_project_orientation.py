"""The orientation stages of a project run (``block``, ``adjust``, ``adjust-uav``) are the library functions the
commands call (:mod:`skyrig.pipeline.orientation`): same files as ``skyrig block`` / ``adjust`` / ``adjust-uav`` on
the same inputs, resumable, and a terrestrial set without GNSS oriented end to end through ``skyrig run``.

Independent answers: the truth of the seeded close-range simulation (:func:`skyrig.simulate.closerange.facade_set`,
tolerances = 4 x the adjustment's own predicted sigma), and the demo flight's direct georeferencing (exact
projections of its ground points: the adjusted orientations must give it back to well below a millimetre); the
commands' outputs on the same inputs for the "same numbers" check (byte for byte).
"""

from __future__ import annotations

import csv
import json
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from skyrig.cli import main
from skyrig.io.stage import read_manifest, verify_folder
from skyrig.pipeline.project import load_project
from skyrig.pipeline.run import STAGES, plan_run

SIGMA_PX = 0.5
BAR_SIGMA_M = 0.0005


# ------------------------------------------------------------------------------------------ no GNSS: a façade
def _facade(tmp_path: Path, n_points: int = 300, n_per_row: int = 6):  # type: ignore[no-untyped-def]
    """A façade project without GNSS: tie points measured elsewhere (inputs.ties), a start camera 4 % off in
    focal length without principal point / distortion (inputs.cameras), two scale bars (inputs.scale_bars)."""
    from skyrig.camera.opencv import OpenCVDistortion
    from skyrig.georef.observations import ImageMeasurements
    from skyrig.io.points_csv import write_measurements_csv
    from skyrig.io.rig_file import write_rig
    from skyrig.rig.rig import Head, Rig
    from skyrig.simulate.closerange import facade_set

    s = facade_set(seed=2, n_points=n_points, n_per_row=n_per_row, width_px=1000, sigma_px=SIGMA_PX)
    proj = tmp_path / "facade"
    proj.mkdir()
    write_measurements_csv(proj / "tie_points.csv",
                           ImageMeasurements(s.point_name[s.obs_point], s.names[s.obs_image], s.obs_pixel))
    start = s.camera.with_(focal_mm=s.camera.focal_mm * 1.04, ppx_mm=0.0, ppy_mm=0.0, distortion=OpenCVDistortion())
    write_rig(Rig("start", {"camera": Head("camera", start)}), proj / "camera.yaml")
    rng = np.random.default_rng(7)
    (proj / "bars.csv").write_text("from,to,length_m,sigma_m\n" + "".join(
        f"{a},{b},{v + rng.normal(0, BAR_SIGMA_M):.5f},{BAR_SIGMA_M}\n" for (a, b), v in zip(s.bars, s.bar_length)))
    (proj / "project.yaml").write_text(
        "format: skyrig-project\nversion: 1\nname: facade\ncrs: EPSG:25832\n"
        "inputs:\n  ties: tie_points.csv\n  cameras: [camera.yaml]\n  scale_bars: bars.csv\n"
        "stages:\n  adjust-uav: {no_gps: true, datum: scale-bar}\n")
    return s, proj


def _table(path: Path) -> list[dict[str, str]]:
    with open(path) as fh:
        return list(csv.DictReader(line for line in fh if not line.startswith("#")))


@pytest.mark.slow  # three orientations of the set: ~35 s on the shared machine
def test_facade_without_gnss_through_skyrig_run(tmp_path: Path) -> None:
    """``skyrig run`` of a project with ``adjust-uav: {no_gps: true}``: camera-to-camera distances as the truth's
    within 4 predicted sigma (the scale from the scale bars); the same files as ``skyrig adjust-uav --no-gps``
    with the same inputs; a rerun skips it, a changed option of the stage reruns it."""
    s, proj = _facade(tmp_path)
    (proj / "project.yaml").write_text((proj / "project.yaml").read_text().replace(
        "{no_gps: true,", "{no_gps: true, compare_pycolmap: true,"))
    r = CliRunner().invoke(main, ["run", str(proj / "project.yaml")])
    assert r.exit_code == 0, r.output
    out = proj / "output" / "adjust-uav"
    assert verify_folder(out) == []
    rep = json.loads((out / "report.json").read_text())
    assert rep["uav"]["datum"]["kind"] == "scale-bar" and rep["uav"]["oriented"] == len(s.names)
    # the stage's pycolmap comparison: no image files, so on the same tie points (pycolmap_input null -> tracks)
    assert rep["pycolmap"]["input"] == "tracks" and rep["pycolmap"]["registered"] == len(s.names), rep["pycolmap"]
    assert rep["pycolmap"]["centre_differences"]["normalised_max"] < 1.0, rep["pycolmap"]["centre_differences"]
    rows = _table(out / "eo.csv")
    k = [list(s.names).index(row["image"]) for row in rows]
    C = np.array([[float(row[c]) for c in "xyz"] for row in rows])
    sd = np.linalg.norm(np.array([[float(row[c]) for c in ("sx", "sy", "sz")] for row in rows]), axis=1)
    D = np.linalg.norm(C[:, None] - C[None], axis=2)
    Dt = np.linalg.norm(s.C[k][:, None] - s.C[k][None], axis=2)
    assert np.all(np.abs(D - Dt) <= 4 * (sd[:, None] + sd[None]) + 1e-9), np.max(np.abs(D - Dt))
    assert np.max(np.abs(D - Dt)) > 0  # a real estimate, not the truth copied
    # the command on the same inputs: the same numbers
    (proj / "cmd").mkdir()
    (proj / "cmd" / "match").mkdir()
    (proj / "cmd" / "match" / "tie_points.csv").write_bytes((proj / "tie_points.csv").read_bytes())
    r = CliRunner().invoke(main, ["adjust-uav", str(proj / "cmd"), "--no-gps", "--datum", "scale-bar", "--crs",
                                  "EPSG:25832", "--camera", str(proj / "camera.yaml"), "--scale-bar",
                                  str(proj / "bars.csv"), "-o", str(tmp_path / "cmd-out")])
    assert r.exit_code == 0, r.output
    for f in ("eo.csv", "points.csv", "camera.yaml"):
        assert (tmp_path / "cmd-out" / f).read_bytes() == (out / f).read_bytes(), f
    # resume: up to date; an option of the stage changed: it reruns
    created = read_manifest(out)["created"]
    r = CliRunner().invoke(main, ["run", str(proj / "project.yaml")])
    assert r.exit_code == 0 and read_manifest(out)["created"] == created, r.output
    time.sleep(1.1)  # manifests carry the second
    text = (proj / "project.yaml").read_text()
    (proj / "project.yaml").write_text(text.replace("datum: scale-bar}", "datum: scale-bar, focal_prior: 0.2}"))
    assert [a for _, a, _ in plan_run(load_project(proj / "project.yaml"))] == ["run"]
    r = CliRunner().invoke(main, ["run", str(proj / "project.yaml")])
    assert r.exit_code == 0 and read_manifest(out)["created"] != created, r.output


def test_facade_control_datum_in_the_control_frame(tmp_path: Path) -> None:
    """``no_gps`` with inputs.control / check (datum: auto -> control): outputs in the control points' frame,
    centres against the truth within 4 predicted sigma."""
    from skyrig.io.eo_csv import read_eo_csv

    s, proj = _facade(tmp_path)
    idx = {n: q for q, n in enumerate(s.point_name)}
    rows = [f"{n},{s.X[idx[n]][0]:.4f},{s.X[idx[n]][1]:.4f},{s.X[idx[n]][2]:.4f}\n" for n in s.target_names]
    head = "# crs: local 48.85 2.35 35.0\nname,x,y,z\n"
    (proj / "gcp.csv").write_text(head + "".join(rows[:6]))
    (proj / "check.csv").write_text(head + "".join(rows[6:]))
    (proj / "project.yaml").write_text(
        "format: skyrig-project\nversion: 1\ncrs: EPSG:25832\n"
        "inputs: {ties: tie_points.csv, cameras: [camera.yaml], control: gcp.csv, check: check.csv}\n"
        "stages:\n  adjust-uav: {no_gps: true, control_sigma: [0.002, 0.002, 0.002]}\n")
    r = CliRunner().invoke(main, ["run", str(proj / "project.yaml")])
    assert r.exit_code == 0, r.output
    out = proj / "output" / "adjust-uav"
    rep = json.loads((out / "report.json").read_text())
    assert rep["uav"]["datum"]["kind"] == "control"
    eo = read_eo_csv(out / "eo.csv")
    k = [list(s.names).index(n) for n in eo.image]
    sig = np.array([rep["uav"]["centre_sigma_m"][str(n)] for n in eo.image])
    d = np.linalg.norm(eo.centre - s.C[k], axis=1)
    assert np.all(d < 4 * np.linalg.norm(sig, axis=1)), (d / np.linalg.norm(sig, axis=1)).max()


def test_project_options_of_the_orientation_without_gnss_are_checked(tmp_path: Path) -> None:
    """Unknown keys stay errors; a datum or scale bars without no_gps, and no tie points, are errors naming the
    key path."""
    from skyrig.errors import InputFormatError

    _, proj = _facade(tmp_path)
    p = proj / "project.yaml"
    base = p.read_text()
    cases = [("{no_gps: true, scale_bar: x.csv}", "stages.adjust-uav.scale_bar"),
             ("{datum: scale-bar}", "stages.adjust-uav.datum"),
             ("{}", "inputs.scale_bars"),
             ("{no_gps: true, datum: sideways}", "stages.adjust-uav.datum"),
             ("{no_gps: true, compare_pycolmap: true, pycolmap_input: pixels}", "stages.adjust-uav.pycolmap_input")]
    for opts, key in cases:
        p.write_text(base.replace("{no_gps: true, datum: scale-bar}", opts))
        with pytest.raises(InputFormatError) as e:
            load_project(p)
        assert e.value.field == key, (opts, str(e.value))
    p.write_text(base.replace("  ties: tie_points.csv\n", ""))
    with pytest.raises(InputFormatError, match="tie points"):
        load_project(p)


def test_adjust_uav_compares_with_pycolmap_on_the_same_tie_points(tmp_path: Path) -> None:
    """``skyrig adjust-uav --no-gps --compare-pycolmap`` on the façade without image files: pycolmap's mapper on the
    same tie points (``--pycolmap-input`` defaults to tracks without images), every image registered; skyrig - pycolmap
    centres after a similarity within the predicted precision: each image's difference below 1 predicted sigma
    (|d| / |sigma|, sigma from eo.csv's sx, sy, sz; the two programs solve the same measurements, so their difference
    is well below the noise both share), and not zero (two programs, not one result copied).  The report's sigma
    figures agree with eo.csv's.  ``images`` asked for without images is an error naming the option."""
    pytest.importorskip("pycolmap")
    s, proj = _facade(tmp_path, n_points=150, n_per_row=5)
    (proj / "match").mkdir()
    (proj / "match" / "tie_points.csv").write_bytes((proj / "tie_points.csv").read_bytes())
    args = ["adjust-uav", str(proj), "--no-gps", "--datum", "scale-bar", "--camera", str(proj / "camera.yaml"),
            "--scale-bar", str(proj / "bars.csv"), "--compare-pycolmap", "-o", str(tmp_path / "out")]
    r = CliRunner().invoke(main, [*args, "--pycolmap-input", "images"])
    assert r.exit_code == 2 and "--pycolmap-input" in r.output and "tracks" in r.output, r.output
    assert not (tmp_path / "out").exists()
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    out = tmp_path / "out"
    p = json.loads((out / "report.json").read_text())["pycolmap"]
    assert p["input"] == "tracks" and p["registered"] == len(s.names), p
    c = p["centre_differences"]
    assert c["common"] == len(s.names)
    sig = {row["image"]: float(np.linalg.norm([float(row[k]) for k in ("sx", "sy", "sz")]))
           for row in _table(out / "eo.csv")}
    z = np.array([c["per_image_m"][n] / sig[n] for n in sig])
    assert 0 < z.max() < 1.0, z
    assert np.isclose(c["normalised_max"], z.max(), rtol=1e-3) and np.isclose(
        c["normalised_rms"], np.sqrt(np.mean(z ** 2)), rtol=1e-3), c
    assert "predicted sigma" in r.output
    assert read_manifest(out)["options"]["pycolmap_input"] == "tracks"


def test_orientation_stages_call_no_command() -> None:
    """The runner's stages are library calls: the pipeline package never imports the CLI."""
    import ast

    import skyrig.pipeline as pkg

    for f in Path(pkg.__file__).parent.glob("*.py"):
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module:
                assert not node.module.startswith("skyrig.cli"), f"{f.name} imports {node.module}"
    assert {"block", "adjust", "adjust-uav"} <= set(STAGES)


# ------------------------------------------------------------------------------------------ block + adjust
def _demo(tmp_path: Path):  # type: ignore[no-untyped-def]
    """The demo flight (trajectory, events, rig, ground points) with exact image measurements of its points."""
    from skyrig.georef.direct import direct_georeference
    from skyrig.georef.ground import world_to_image
    from skyrig.georef.observations import ImageMeasurements
    from skyrig.io.events_csv import read_events_csv
    from skyrig.io.points_csv import read_points_csv, write_measurements_csv
    from skyrig.io.rig_file import read_rig
    from skyrig.io.trajectory_csv import read_trajectory_csv
    from skyrig.pipeline.demo import build_demo_project

    p = build_demo_project(tmp_path)
    traj, ev, rig = read_trajectory_csv(p.trajectory), read_events_csv(p.events), read_rig(p.rig)
    gp = read_points_csv(p.check_points)
    eo = direct_georeference(traj, rig, ev, gp.frame)
    cams = {h.camera.name: h.camera for h in rig}
    pt, im, px = [], [], []
    for img in eo.image:
        uv = world_to_image(eo, cams, np.full(len(gp), img), gp.xyz, gp.frame)
        cam = cams[str(eo.camera[eo.index()[img]])]
        ok = np.isfinite(uv).all(axis=1) & (uv[:, 0] > 0) & (uv[:, 1] > 0) & (uv[:, 0] < cam.width - 1) & (
            uv[:, 1] < cam.height - 1)
        pt += list(gp.name[ok])
        im += [img] * int(ok.sum())
        px.append(uv[ok])
    write_measurements_csv(p.trajectory.parent / "measurements.csv",
                           ImageMeasurements(np.array(pt), np.array(im), np.vstack(px)))
    (p.trajectory.parent / "project.yaml").write_text(
        "format: skyrig-project\nversion: 1\ncrs: EPSG:25832\n"
        "inputs: {trajectory: trajectory.csv, events: events.csv, rig: rig.yaml, control: check_points.csv,\n"
        "         measurements: [measurements.csv]}\n"
        "stages:\n  georef: {}\n  block: {sigma_px: 0.5}\n  adjust: {}\n")
    return p, eo


@pytest.mark.slow  # the demo block: run, both commands, two reruns (~25-55 s on the shared machine)
def test_block_and_adjust_stages_equal_the_commands_and_resume(tmp_path: Path) -> None:
    from skyrig.io.block_file import read_block
    from skyrig.io.eo_csv import read_eo_csv

    p, eo = _demo(tmp_path)
    folder = p.trajectory.parent
    proj = folder / "project.yaml"
    r = CliRunner().invoke(main, ["run", str(proj)])
    assert r.exit_code == 0, r.output
    out = folder / "output"
    adj = read_eo_csv(out / "adjust" / "eo.csv")
    ref = eo.to_frame(adj.frame)
    rows = np.array([ref.index()[n] for n in adj.image])
    assert np.abs(adj.centre - ref.centre[rows]).max() < 1e-3  # the independent answer: direct georeferencing
    # the commands on the same inputs
    r = CliRunner().invoke(main, ["block", "--trajectory", str(p.trajectory), "--events", str(p.events), "--rig",
                                  str(p.rig), "--measurements", str(folder / "measurements.csv"), "--control",
                                  str(p.check_points), "--crs", "EPSG:25832", "-o", str(tmp_path / "blk" / "block.json")])
    assert r.exit_code == 0, r.output
    a, b = read_block(tmp_path / "blk" / "block.json"), read_block(out / "block" / "block.json")
    assert a.config == b.config and a.crs == b.crs
    for name in ("station_centre", "station_rotation", "obs_pixel", "obs_image", "obs_point", "point_xyz",
                 "control_xyz", "gnss_xyz"):
        if hasattr(a.block, name):
            np.testing.assert_array_equal(getattr(a.block, name), getattr(b.block, name), err_msg=name)
    r = CliRunner().invoke(main, ["adjust", str(out / "block" / "block.json"), "-o", str(tmp_path / "adj")])
    assert r.exit_code == 0, r.output
    for f in ("eo.csv", "points.csv", "ground_control.csv"):
        assert (tmp_path / "adj" / f).read_bytes() == (out / "adjust" / f).read_bytes(), f
    # resume: an option of adjust reruns adjust only; one of block reruns block and adjust, never georef
    stages = ("georef", "block", "adjust")
    created = {s: read_manifest(out / s)["created"] for s in stages}
    time.sleep(1.1)
    text = proj.read_text()
    proj.write_text(text.replace("  adjust: {}", "  adjust: {gsd: 0.1}"))
    r = CliRunner().invoke(main, ["run", str(proj)])
    assert r.exit_code == 0, r.output
    now = {s: read_manifest(out / s)["created"] for s in stages}
    assert [s for s in stages if now[s] != created[s]] == ["adjust"]
    time.sleep(1.1)
    proj.write_text(text.replace("  adjust: {}", "  adjust: {gsd: 0.1}").replace("sigma_px: 0.5", "sigma_px: 0.7"))
    r = CliRunner().invoke(main, ["run", str(proj)])
    assert r.exit_code == 0, r.output
    later = {s: read_manifest(out / s)["created"] for s in stages}
    assert [s for s in stages if later[s] != now[s]] == ["block", "adjust"]


# ------------------------------------------------------------------------------------------ real data
@pytest.mark.slow  # exhaustive matching of 29 images at 1024 px: ~30 min on the shared 2-core machine
def test_lund_without_gps_through_skyrig_run(tmp_path: Path) -> None:
    """The 29 lund phone images through ``skyrig run``: a match stage (exhaustive pairs, nothing of the GPS used)
    and ``adjust-uav: {no_gps: true, datum: gps-similarity}``; the EXIF GPS only places the block.  The checks of
    the command's own test (tests/test_orient_incremental.py, which also compares with pycolmap in the same run):
    images oriented, the similarity's residuals at a phone GPS's level (metres; a wrongly oriented image or a bent
    block would be tens of metres off), and our centres' predicted precision far below that."""
    from conftest import shared_path

    src = shared_path("opensfm", "lund", "images")
    p = tmp_path / "project.yaml"
    p.write_text("format: skyrig-project\nversion: 1\nname: lund\ncrs: EPSG:32633\n"
                 f"inputs: {{images: [{src}]}}\nexecutor: {{kind: serial}}\n"
                 "stages:\n  match: {pairs: exhaustive, max_size: 1024, max_features: 4000}\n"
                 "  adjust-uav: {no_gps: true, datum: gps-similarity}\n")
    r = CliRunner().invoke(main, ["run", str(p)])
    assert r.exit_code == 0, r.output
    out = tmp_path / "output" / "adjust-uav"
    assert verify_folder(out) == []
    rep = json.loads((out / "report.json").read_text())
    s = rep["uav"]
    assert s["oriented"] >= 20, s["not_oriented"]
    d = s["datum"]
    assert d["kind"] == "positions" and d["positions_similarity_rms_3d_m"] < 8.0, d
    sig = np.array(list(s["centre_sigma_m"].values()))
    assert float(np.sqrt(np.mean(np.sum(sig ** 2, axis=1)))) < 0.25 * d["positions_similarity_rms_3d_m"], d


def test_init_chooses_the_orientation_without_gnss_for_images_without_gps(tmp_path: Path) -> None:
    """``skyrig init`` on a folder of images without EXIF GPS (and no trajectory / EO): match + adjust-uav with
    no_gps, no DSM (no georeference to put it in)."""
    import cv2

    (tmp_path / "images").mkdir()
    rng = np.random.default_rng(0)
    for k in range(3):
        cv2.imwrite(str(tmp_path / "images" / f"img{k}.png"), rng.integers(0, 255, (48, 64), dtype=np.uint8))
    r = CliRunner().invoke(main, ["init", str(tmp_path), "--crs", "EPSG:25832"])
    assert r.exit_code == 0, r.output
    proj = load_project(tmp_path / "project.yaml")
    assert [s.name for s in proj.stages] == ["match", "adjust-uav"]
    assert proj.stage("adjust-uav").options["no_gps"] is True


@pytest.mark.slow
def test_brighton_gnss_stage_equals_the_command(tmp_path: Path) -> None:
    """The 18 brighton DJI images with their EXIF GPS through ``skyrig run`` (match + adjust-uav, CI image size):
    the adjust-uav stage writes the files ``skyrig adjust-uav`` writes on the same tie points, byte for byte, and
    orients every image (the command's own accuracy checks: tests/test_uav_adjust.py)."""
    from conftest import shared_path

    src = shared_path("brighton-uav")
    p = tmp_path / "project.yaml"
    p.write_text("format: skyrig-project\nversion: 1\nname: brighton\ncrs: EPSG:32615\n"
                 f"inputs: {{images: [{src}]}}\nexecutor: {{kind: serial}}\n"
                 "stages:\n  match: {max_size: 640, max_features: 1500}\n  adjust-uav: {}\n")
    r = CliRunner().invoke(main, ["run", str(p)])
    assert r.exit_code == 0, r.output
    out = tmp_path / "output"
    rep = json.loads((out / "adjust-uav" / "report.json").read_text())
    assert rep["uav"]["oriented"] == rep["uav"]["images"] == 18, rep["uav"]["not_oriented"]
    r = CliRunner().invoke(main, ["adjust-uav", str(tmp_path), "--images", str(src), "--match", str(out / "match"),
                                  "--crs", "EPSG:32615", "-o", str(tmp_path / "cmd")])
    assert r.exit_code == 0, r.output
    for f in ("eo.csv", "points.csv", "camera.yaml"):
        assert (tmp_path / "cmd" / f).read_bytes() == (out / "adjust-uav" / f).read_bytes(), f
