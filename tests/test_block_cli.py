"""``skyrig block`` + ``skyrig adjust`` on the built-in demo flight (files as a user has them).

Independent answer: the flight's own direct georeferencing.  Image measurements are exact projections of the
demo's ground points, the trajectory is error-free, so the adjusted rig block must give back the directly
georeferenced orientations (to well below a millimetre) with sigma0 ~ 0 residuals; and bad input must name the file.
"""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from skyrig.cli import main
from skyrig.georef.direct import direct_georeference
from skyrig.georef.ground import world_to_image
from skyrig.georef.observations import ImageMeasurements
from skyrig.io.eo_csv import read_eo_csv
from skyrig.io.events_csv import read_events_csv
from skyrig.io.points_csv import read_points_csv, write_measurements_csv
from skyrig.io.rig_file import read_rig
from skyrig.io.trajectory_csv import read_trajectory_csv
from skyrig.pipeline.demo import build_demo_project


def _project(tmp_path):  # type: ignore[no-untyped-def]
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
    meas = tmp_path / "measurements.csv"
    write_measurements_csv(meas, ImageMeasurements(np.array(pt), np.array(im), np.vstack(px)))
    return p, eo, meas


def test_block_and_adjust_give_back_direct_georeferencing(tmp_path) -> None:  # type: ignore[no-untyped-def]
    p, eo, meas = _project(tmp_path)
    run = CliRunner()
    r = run.invoke(main, ["block", "--trajectory", str(p.trajectory), "--events", str(p.events), "--rig", str(p.rig),
                          "--measurements", str(meas), "--control", str(p.check_points), "--image-sigma-px", "0.5",
                          "-o", str(tmp_path / "blk" / "block.json")])
    assert r.exit_code == 0, r.output
    ev = read_events_csv(p.events)
    assert f"{len(np.unique(ev.exposure_id))} stations" in r.output  # one station per rig exposure
    r = run.invoke(main, ["adjust", str(tmp_path / "blk" / "block.json"), "-o", str(tmp_path / "adj")])
    assert r.exit_code == 0, r.output
    adj = read_eo_csv(tmp_path / "adj" / "eo.csv")
    ref = eo.to_frame(adj.frame)
    rows = np.array([ref.index()[n] for n in adj.image])
    from skyrig.io.points_csv import read_measurements_csv

    assert len(adj) == len(np.unique(read_measurements_csv(meas).image))  # every measured image adjusted
    assert np.abs(adj.centre - ref.centre[rows]).max() < 1e-3
    assert np.abs(adj.rotation - ref.rotation[rows]).max() < 1e-7


def test_block_names_the_file_of_an_unknown_image(tmp_path) -> None:  # type: ignore[no-untyped-def]
    p, _, meas = _project(tmp_path)
    bad = tmp_path / "bad.csv"
    bad.write_text(meas.read_text() + "CP00,no_such_image.tif,10.0,20.0\n")
    r = CliRunner().invoke(main, ["block", "--trajectory", str(p.trajectory), "--events", str(p.events), "--rig",
                                  str(p.rig), "--measurements", str(bad), "-o", str(tmp_path / "b.json")])
    assert r.exit_code == 2 and "bad.csv" in r.output and "no_such_image.tif" in r.output
    assert not (tmp_path / "b.json").exists()


# ------------------------------------------------------------------ issue 13, deliverable 5: one vocabulary for block
def _rig_args(p, meas, *extra):  # type: ignore[no-untyped-def]
    return ["block", "--trajectory", str(p.trajectory), "--events", str(p.events), "--rig", str(p.rig),
            "--measurements", str(meas), "--control", str(p.check_points), *extra]


def test_block_sigmas_read_as_adjust_uav_reads_them(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """`--gnss-sigma 0.1,0.1,0.2` (the one syntax), the old three separate numbers (accepted with the same
    deprecation warning adjust-uav gives) and bad values refused with adjust-uav's words, naming the option."""
    p, _, meas = _project(tmp_path)
    run = CliRunner()
    a = run.invoke(main, _rig_args(p, meas, "--gnss-sigma", "0.1,0.1,0.2", "--imu-sigma-deg", "0.01,0.01,0.02",
                                   "-o", str(tmp_path / "a" / "b.json")))
    assert a.exit_code == 0, a.output
    assert "deprecated" not in a.output
    b = run.invoke(main, _rig_args(p, meas, "--gnss-sigma", "0.1", "0.1", "0.2", "--imu-sigma-deg", "0.01",
                                   "0.01", "0.02", "-o", str(tmp_path / "b" / "b.json")))
    assert b.exit_code == 0, b.output
    assert "warning: --gnss-sigma N N N is deprecated; use --gnss-sigma N,N,N" in b.stderr
    assert "warning: --imu-sigma-deg N N N is deprecated" in b.stderr
    for table in ("gnss", "imu"):  # the same block either way
        assert (tmp_path / "a" / f"b_{table}.csv").read_text() == (tmp_path / "b" / f"b_{table}.csv").read_text()
    assert ",0.2" in (tmp_path / "a" / "b_gnss.csv").read_text()
    for value, words in (("2,2", "got 2"), ("2,-1,3", "finite and > 0"), ("two", "not one number"),
                         ("nan", "finite and > 0"), ("0", "finite and > 0")):
        r = run.invoke(main, _rig_args(p, meas, "--gnss-sigma", value, "-o", str(tmp_path / "x.json")))
        assert r.exit_code == 2 and "--gnss-sigma" in r.output and words in r.output, (value, r.output)
        assert "Traceback" not in r.output and not (tmp_path / "x.json").exists()
    r = run.invoke(main, _rig_args(p, meas, "--control-sigma", "0.01,0.01", "-o", str(tmp_path / "x.json")))
    assert r.exit_code == 2 and "--control-sigma" in r.output and "X,Y,Z" in r.output, r.output


def test_block_counts_the_measurements_it_leaves_out(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """Injected: 2 measurements of tie points seen in one image, 2 of a tie point seen by two heads of one
    exposure (no base); the block says so, by reason, and leaves every other measurement in."""
    from skyrig.io.points_csv import read_measurements_csv

    p, _, meas = _project(tmp_path)
    n = len(read_measurements_csv(meas))
    ev = read_events_csv(p.events)
    first = ev.exposure_id[0]
    same = [str(i) for i, e in zip(ev.image_name, ev.exposure_id) if e == first][:2]
    extra = (f"LONE1,{ev.image_name[0]},1000.0,900.0\nLONE2,{ev.image_name[3]},1100.0,800.0\n"
             f"ONEEXP,{same[0]},1200.0,1000.0\nONEEXP,{same[1]},1300.0,1000.0\n")
    bad = tmp_path / "with_extra.csv"
    bad.write_text(meas.read_text() + extra)
    r = CliRunner().invoke(main, _rig_args(p, bad, "-o", str(tmp_path / "blk" / "block.json")))
    assert r.exit_code == 0, r.output
    assert f"left out 4 of {n + 4} measurements" in r.output, r.output
    assert "2 of tie points measured in one image only" in r.output
    assert "2 of points whose images all come from one exposure (no base)" in r.output
    r = CliRunner().invoke(main, _rig_args(p, meas, "-o", str(tmp_path / "blk2" / "block.json")))
    assert r.exit_code == 0 and f"left out 0 of {n} measurements" in r.output, r.output


@pytest.mark.slow  # two blocks and an adjustment of the demo flight (~25 s CPU)
def test_block_eo_as_start_values_only_and_the_datum(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """Image mode from an EO 0.5 m / 0.05 deg off the truth: as GNSS/IMU observations it pulls the adjustment
    off; with --start-values-only the block has no GNSS/IMU and the adjustment on exact measurements + control
    gives back the truth (< 1 mm); --datum is recorded; no control and no GNSS is refused unless --datum free."""
    import json
    from dataclasses import replace

    from skyrig.geometry.rotations import matrix_from_rotvec
    from skyrig.io.eo_csv import write_eo_csv

    p, eo, meas = _project(tmp_path)
    rng = np.random.default_rng(3)
    off = replace(eo, centre=eo.centre + rng.normal(0, 0.5, eo.centre.shape),
                  rotation=eo.rotation @ matrix_from_rotvec(rng.normal(0, np.radians(0.05), (len(eo), 3))))
    write_eo_csv(off, tmp_path / "eo_off.csv")
    from skyrig.io.points_csv import read_measurements_csv

    m = read_measurements_csv(meas)  # images that see >= 5 ground points: each one determined by resection alone
    imgs, counts = np.unique(m.image, return_counts=True)
    keep = np.isin(m.image, imgs[counts >= 5])
    assert keep.sum() > 50
    meas = tmp_path / "resectable.csv"
    write_measurements_csv(meas, ImageMeasurements(m.point[keep], m.image[keep], m.pixel[keep]))
    rig = str(p.rig)
    base = ["block", "--eo", str(tmp_path / "eo_off.csv"), "--camera", rig, "--measurements", str(meas)]
    run = CliRunner()
    r = run.invoke(main, base + ["--control", str(p.check_points), "--start-values-only", "--control-sigma", "0.001",
                                 "-o", str(tmp_path / "s" / "block.json")])
    assert r.exit_code == 0, r.output
    assert "0 GNSS, 0 IMU" in r.output and "starting values only" in r.output
    obs = run.invoke(main, base + ["--control", str(p.check_points), "-o", str(tmp_path / "o" / "block.json")])
    assert obs.exit_code == 0 and " 0 GNSS" not in obs.output, obs.output  # the default: EO as observations
    r = run.invoke(main, ["adjust", str(tmp_path / "s" / "block.json"), "-o", str(tmp_path / "adj")])
    assert r.exit_code == 0, r.output
    adj = read_eo_csv(tmp_path / "adj" / "eo.csv")
    ref = eo.to_frame(adj.frame)
    rows = np.array([ref.index()[n] for n in adj.image])
    assert np.abs(adj.centre - ref.centre[rows]).max() < 1e-3  # the start was 0.5 m off
    # no datum at all: refused, naming the way out; --datum free accepted and recorded
    r = run.invoke(main, base + ["--start-values-only", "-o", str(tmp_path / "n" / "block.json")])
    assert r.exit_code == 2 and "--datum free" in r.output and not (tmp_path / "n").exists(), r.output
    r = run.invoke(main, base + ["--start-values-only", "--datum", "free", "-o", str(tmp_path / "f" / "block.json")])
    assert r.exit_code == 0, r.output
    assert json.loads((tmp_path / "f" / "block.json").read_text())["adjustment"]["unknowns"]["datum"] == "free"
