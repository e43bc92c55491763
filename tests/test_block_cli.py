"""``skyrig block`` + ``skyrig adjust`` on the built-in demo flight (files as a user has them).

Independent answer: the flight's own direct georeferencing.  Image measurements are exact projections of the
demo's ground points, the trajectory is error-free, so the adjusted rig block must give back the directly
georeferenced orientations (to well below a millimetre) with sigma0 ~ 0 residuals; and bad input must name the file.
"""

from __future__ import annotations

import numpy as np
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
                          "--measurements", str(meas), "--control", str(p.check_points), "--sigma-px", "0.5",
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
