"""Issue 13, deliverable 6: the README's own-flight walkthrough - a rig file from a preset (`skyrig rig`) and the
events CSV from a camera trigger log and the heads' image folders (`skyrig events`).

Independent answers: the preset itself (the rig file read back equals it), and the demo flight's own events file
(the events rebuilt from a log of its trigger times and empty image files named as its images equal it, and
georeference to the same orientations).
"""

from __future__ import annotations

import numpy as np
from click.testing import CliRunner

from skyrig.cli import main
from skyrig.io.eo_csv import read_eo_csv
from skyrig.io.events_csv import read_events_csv
from skyrig.io.rig_file import read_rig
from skyrig.pipeline.demo import CRS, build_demo_project
from skyrig.rig.presets import PRESETS, preset


def test_rig_file_from_every_preset(tmp_path):
    run = CliRunner()
    r = run.invoke(main, ["rig", "--list"])
    assert r.exit_code == 0 and all(name in r.output for name in PRESETS)
    for name in PRESETS:
        r = run.invoke(main, ["rig", "--preset", name, "-o", str(tmp_path / f"{name}.yaml")])
        assert r.exit_code == 0, r.output
        assert read_rig(tmp_path / f"{name}.yaml").isclose(preset(name), atol=1e-9), name
    r = run.invoke(main, ["rig", "--preset", "midsa", "-o", str(tmp_path / "x.yaml")])
    assert r.exit_code == 2 and "--preset" in r.output and "midas" in r.output and not (tmp_path / "x.yaml").exists()


def _log_and_folders(tmp_path, ev):  # type: ignore[no-untyped-def]
    """The demo's trigger log (one row per exposure: time, exposure id) and one folder of empty images per head,
    named as the demo's images but listed in shuffled creation order (the command sorts by name)."""
    expo, first = np.unique(ev.exposure_id, return_index=True)
    log = tmp_path / "camera_log.csv"
    log.write_text("# trigger log\nexposure,time,gps_week,note\n"
                   + "".join(f"{int(e)},{ev.time_s[k]:.6f},2300,ok\n" for e, k in zip(expo, first)))
    specs = []
    rng = np.random.default_rng(0)
    for head in np.unique(ev.head):
        folder = tmp_path / "images" / str(head)
        folder.mkdir(parents=True)
        names = [str(n) for n in ev.image_name[ev.head == head]]
        for n in rng.permutation(names):
            (folder / n).write_bytes(b"")
        specs += ["--images", f"{head}={folder}"]
    return log, specs


def test_events_from_a_camera_log_give_back_the_flight(tmp_path):
    p = build_demo_project(tmp_path / "demo")
    ev = read_events_csv(p.events)
    # the demo's image names sort in exposure order within each head (s1_e001_nadir.tif, ...)
    for head in np.unique(ev.head):
        sel = ev.head == head
        assert list(ev.image_name[sel]) == sorted(ev.image_name[sel])
    log, specs = _log_and_folders(tmp_path, ev)
    run = CliRunner()
    r = run.invoke(main, ["events", "--log", str(log), *specs, "--rig", str(p.rig), "-o", str(tmp_path / "ev.csv")])
    assert r.exit_code == 0, r.output
    got = read_events_csv(tmp_path / "ev.csv")
    order = {n: k for k, n in enumerate(got.image_name)}
    rows = np.array([order[str(n)] for n in ev.image_name])
    assert np.array_equal(got.head[rows], ev.head) and np.array_equal(got.exposure_id[rows], ev.exposure_id)
    assert np.abs(got.time_s[rows] - ev.time_s).max() < 1e-6
    # heads sharing one folder: a glob pattern per head gives the same file
    shared = tmp_path / "all_images"
    shared.mkdir()
    for n in ev.image_name:
        (shared / str(n)).write_bytes(b"")
    globs = [a for h in np.unique(ev.head) for a in ("--images", f"{h}={shared}/*_{h}.tif")]
    r = run.invoke(main, ["events", "--log", str(log), *globs, "--rig", str(p.rig), "-o", str(tmp_path / "ev2.csv")])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "ev2.csv").read_text() == (tmp_path / "ev.csv").read_text()
    # the walkthrough's next step: georeference with them, the same orientations as from the flight's own events
    for events, out in ((p.events, "eo_a.csv"), (tmp_path / "ev.csv", "eo_b.csv")):
        r = run.invoke(main, ["georef", "--trajectory", str(p.trajectory), "--events", str(events), "--rig",
                              str(p.rig), "--crs", CRS, "-o", str(tmp_path / out)])
        assert r.exit_code == 0, r.output
    a, b = read_eo_csv(tmp_path / "eo_a.csv"), read_eo_csv(tmp_path / "eo_b.csv")
    rb = np.array([b.index()[n] for n in a.image])
    assert np.abs(a.centre - b.centre[rb]).max() < 1e-4 and np.abs(a.rotation - b.rotation[rb]).max() < 1e-9


def test_events_refuse_a_log_that_does_not_fit_the_folders(tmp_path):
    p = build_demo_project(tmp_path / "demo")
    ev = read_events_csv(p.events)
    log, specs = _log_and_folders(tmp_path, ev)
    text = log.read_text().splitlines()
    short = tmp_path / "short_log.csv"
    short.write_text("\n".join(text[:-1]) + "\n")  # one trigger missing
    run = CliRunner()
    r = run.invoke(main, ["events", "--log", str(short), *specs, "-o", str(tmp_path / "ev.csv")])
    assert r.exit_code == 2 and "short_log.csv" in r.output and "triggers in the log" in r.output, r.output
    back = tmp_path / "back_log.csv"
    back.write_text("\n".join(text[:3] + [text[4], text[3]] + text[5:]) + "\n")  # two rows swapped
    r = run.invoke(main, ["events", "--log", str(back), *specs, "-o", str(tmp_path / "ev.csv")])
    assert r.exit_code == 2 and "back_log.csv" in r.output and "line 5" in r.output and "time order" in r.output
    r = run.invoke(main, ["events", "--log", str(log), "--images", "nadir", "-o", str(tmp_path / "ev.csv")])
    assert r.exit_code == 2 and "HEAD=FOLDER" in r.output
    r = run.invoke(main, ["events", "--log", str(log), *specs, "--rig", str(p.rig), "--actuated", "nadir",
                          "-o", str(tmp_path / "ev.csv")])
    assert r.exit_code == 2 and "--actuated" in r.output
    assert not (tmp_path / "ev.csv").exists() and "Traceback" not in r.output
