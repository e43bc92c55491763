"""Paper 000's TumbleCam chain (issue 11, deliverable 4): oblique orientations transferred from nadir orientations
(``skyrig.georef.transfer``, ``skyrig transfer``) and the Fig. 9 circle mosaic (``skyrig.dense.plane_mosaic``).

Truth: the simulator's orientations (``build_survey``: composed explicitly from the true IMU states and the TRUE rig
with its boresight curve, not through ``skyrig.georef``), its rendered images, and analytic predictions.
"""

from __future__ import annotations

import importlib.util
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from skyrig.georef.direct import direct_georeference
from skyrig.georef.eo import ExteriorOrientations, WorldFrame
from skyrig.georef.transfer import TransferError, orientation_differences, transfer_orientations
from skyrig.geometry.rotations import matrix_from_rotvec
from skyrig.simulate.scenarios import build_survey, scenario_spec
from skyrig.trajectory.events import CameraEvents

ROOT = Path(__file__).resolve().parents[1]


def _bench():
    spec = importlib.util.spec_from_file_location("tumblecam_chain", ROOT / "bench" / "tumblecam_chain.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # its dataclasses look their module up
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def survey():
    return build_survey(scenario_spec("tumblecam", "ci", 1))


@pytest.fixture(scope="module")
def bench():
    return _bench()


def _nadir(eo: ExteriorOrientations) -> ExteriorOrientations:
    return eo.subset(eo.head == "nadir")


def _obliques(eo: ExteriorOrientations) -> ExteriorOrientations:
    return eo.subset(eo.head == "oblique")


# ----------------------------------------------------------------------------------------------- transfer
def test_transfer_from_true_nadir_reproduces_the_true_obliques(survey):
    """True nadir orientations + the true rig (curve included) give the simulator's oblique orientations."""
    eo = survey.eo_true
    tr = transfer_orientations(_nadir(eo), survey.rig_true, survey.events_true)
    d = orientation_differences(tr, eo)
    assert len(tr) == int(np.sum(eo.head == "oblique")) > 0
    assert np.max(d["angle_rad"]) < 1e-12
    assert np.max(np.abs(d["centre_m"])) < 1e-6
    assert np.all(tr.extra["transfer_method"] == 0)  # all simultaneous
    # without the curve: the error is the curve's rotation at each beta (head frame) - an independent composition
    nc = transfer_orientations(_nadir(eo), survey.rig_true, survey.events_true, curve=None)
    d_nc = orientation_differences(nc, eo)
    ob = survey.rig_true.head("oblique")
    beta = nc.extra["beta_rad"]
    expect = np.array([np.linalg.norm(_rotvec(ob.head_from_camera_rotation(b).T
                                              @ ob.with_(curve=None).head_from_camera_rotation(b))) for b in beta])
    assert np.allclose(d_nc["angle_rad"], expect, atol=1e-12)
    assert np.min(expect) > np.radians(0.01)  # the scenario's curve is not negligible


def test_transfer_through_lever_arms_and_boresights():
    """A rig with lever arms and boresight misalignments on every head (the MIDAS scenario's true rig): the other
    heads' orientations follow from the true nadir orientations exactly (the transfer also serves fixed heads)."""
    sv = build_survey(scenario_spec("midas", "ci", 1))
    eo = sv.eo_true
    assert np.any(np.abs(sv.rig_true.head("nadir").lever_arm_m) > 0)
    others = [h for h in sv.rig_true.head_names if h != "nadir"]
    tr = transfer_orientations(_nadir(eo), sv.rig_true, sv.events_true, heads=others)
    d = orientation_differences(tr, eo)
    assert len(tr) == int(np.sum(eo.head != "nadir"))
    assert np.max(d["angle_rad"]) < 1e-12 and np.max(np.abs(d["centre_m"])) < 1e-6
    # with the recorded rig (no boresights) the error is the boresight difference: nadir's and the head's
    rec = transfer_orientations(_nadir(eo), sv.rig_recorded, sv.events_true, heads=others)
    assert np.degrees(np.max(orientation_differences(rec, eo)["angle_rad"])) > 0.005


def _rotvec(r):
    from skyrig.geometry.rotations import rotvec_from_matrix

    return rotvec_from_matrix(r)


def test_transfer_carries_nadir_errors_and_calibration_noise(survey, bench):
    """Noisy nadir orientations (adjustment size) and a lab-calibrated curve: the obliques' world-side rotation error
    is the nadir's (the mounting is exact up to the curve's calibration noise), the centres' error the nadir's
    (zero lever arms); the image-space error of scene points stays within its prediction with the curve and is
    several times larger without it."""
    rng = np.random.default_rng(3)
    eo = survey.eo_true
    nad = _nadir(eo)
    s_ang, s_c = 1e-4, 0.05
    rv = rng.normal(0.0, s_ang, (len(nad), 3))
    noisy = replace(nad, rotation=nad.rotation @ matrix_from_rotvec(rv), centre=nad.centre + rng.normal(0, s_c, (len(nad), 3)))
    tr_exact = transfer_orientations(noisy, survey.rig_true, survey.events_true)
    d = orientation_differences(tr_exact, eo)
    dn = orientation_differences(noisy, eo)
    order = [list(noisy.exposure).index(x) for x in tr_exact.exposure]
    assert np.allclose(d["angle_rad"], dn["angle_rad"][order], atol=1e-12)
    assert np.allclose(d["centre_m"], dn["centre_m"][order], atol=1e-6)
    # calibrated rig (recorded rig + curve from 5 noisy lab circles, paper 000 Tab. 2 repeatability)
    cal = bench.lab_calibrated_curve(survey.tumble_curve, np.random.default_rng(11))
    rig = bench.calibrated_rig(survey.rig_recorded, cal)
    with_c = transfer_orientations(noisy, rig, survey.events_true)
    without = transfer_orientations(noisy, rig, survey.events_true, curve=None)
    e_c = bench.image_space_errors(with_c, eo, survey.scene, survey.rig_true, survey.frame)
    e_n = bench.image_space_errors(without, eo, survey.scene, survey.rig_true, survey.frame)
    cam = survey.rig_true.head("oblique").camera
    # prediction (1 sigma per image coordinate): attitude s_ang and curve noise (Tab. 2 / 2 / sqrt(5) per axis)
    # through the focal length, centre s_c over the shortest slant distance (flying height above the terrain)
    sig_curve = np.radians(np.asarray(bench.TAB2_MEAN_2SIGMA_DEG) / 2 / np.sqrt(5))
    dist = survey.spec.flights[0].flying_height_m
    s_px = np.hypot(cam.focal_px * np.hypot(s_ang, np.linalg.norm(sig_curve)), cam.focal_px * s_c / dist)
    assert e_c["rms_px"] < 3.0 * np.sqrt(2) * s_px  # radial: sqrt(2) coordinates
    assert e_n["rms_px"] > 3.0 * e_c["rms_px"]


def _offset_events(survey, dt: float):
    """Events of the true flight with every oblique taken ``dt`` s after its nadir partner (not the last of a strip)."""
    ev = survey.events_true
    t = ev.time_s.copy()
    last = np.zeros(len(ev), bool)
    for s in np.unique([n[:3] for n in ev.image_name]):
        rows = np.flatnonzero(np.char.startswith(ev.image_name.astype(str), s))
        last[rows[ev.time_s[rows] == ev.time_s[rows].max()]] = True
    ob = (ev.head == "oblique") & ~last
    keep = (ev.head == "nadir") | ob
    t[ob] += dt
    return CameraEvents.create(t[keep], ev.head[keep], ev.image_name[keep], ev.beta_rad[keep], ev.exposure_id[keep])


def test_transfer_across_a_time_offset(survey):
    """Obliques 0.4 s after the nadir images: with the trajectory exact; by interpolation between the adjusted
    exposures within the analytic bound of the attitude wobble (A w^2 T^2 / 8 per axis) and the lateral wobble."""
    frame = survey.frame
    ev = _offset_events(survey, 0.4)
    truth = direct_georeference(survey.trajectory_true, survey.rig_true, ev, frame)
    nad = _nadir(truth)
    tr = transfer_orientations(nad, survey.rig_true, ev, trajectory=survey.trajectory_true)
    d = orientation_differences(tr, truth)
    assert np.all(tr.extra["transfer_method"] == 2)
    assert np.max(d["angle_rad"]) < 1e-9 and np.max(np.abs(d["centre_m"])) < 1e-5
    ip = transfer_orientations(nad, survey.rig_true, ev)
    d = orientation_differences(ip, truth)
    assert np.all(ip.extra["transfer_method"] == 1)
    sp = survey.spec
    period = 1.0 / sp.flights[0].frame_rate_hz
    amp = np.radians(np.asarray(sp.attitude_wobble_deg)) * np.array([0.31, 0.23, 0.11]) ** 2 * period ** 2 / 8
    bound = np.linalg.norm(amp) + 1e-6
    assert np.max(d["angle_rad"]) <= bound
    assert np.max(d["angle_rad"]) > 1e-3 * bound  # the interpolation is not exact: the test can see it
    lateral = sp.lateral_wobble_m * 0.05 ** 2 * period ** 2 / 8
    assert np.max(np.linalg.norm(d["centre_m"], axis=1)) < lateral + 0.01  # + cubic-vs-linear along track (mm)
    # no trajectory, an oblique after the last exposure of its strip: refused, naming the image
    ev2 = CameraEvents.create(np.r_[ev.time_s, survey.events_true.time_s.max() + 0.4], np.r_[ev.head, ["oblique"]],
                              np.r_[ev.image_name, ["late_oblique.png"]], np.r_[ev.beta_rad, [0.3]],
                              np.r_[ev.exposure_id, [999]])
    with pytest.raises(TransferError, match="late_oblique.png"):
        transfer_orientations(nad, survey.rig_true, ev2)
    # with the trajectory the last exposure's correction is held over the 0.4 s: exact for the true trajectory
    late = transfer_orientations(nad, survey.rig_true, ev2, trajectory=survey.trajectory_true)
    truth2 = direct_georeference(survey.trajectory_true, survey.rig_true, ev2, frame)
    d = orientation_differences(late, truth2)
    assert np.max(d["angle_rad"]) < 1e-9 and np.max(np.abs(d["centre_m"])) < 1e-5


def test_transfer_refuses_bad_input(survey):
    eo = survey.eo_true
    with pytest.raises(TransferError, match="none of the"):
        transfer_orientations(_obliques(eo), survey.rig_true, survey.events_true)
    ev = survey.events_true
    beta = ev.beta_rad.copy()
    beta[ev.head == "oblique"] = np.nan
    bad = CameraEvents.create(ev.time_s, ev.head, ev.image_name, beta, ev.exposure_id)
    with pytest.raises(TransferError, match="no actuator angle"):
        transfer_orientations(_nadir(eo), survey.rig_true, bad)


def test_cli_transfer(survey, tmp_path, bench):
    """``skyrig transfer`` over files = the library on the same data; --no-curve differs by the curve; bad input -> 2."""
    from skyrig.cli.transfer import command
    from skyrig.io.eo_csv import read_eo_csv, write_eo_csv
    from skyrig.io.events_csv import write_events_csv
    from skyrig.io.rig_file import write_rig

    frame = WorldFrame.map("EPSG:25832")
    nad = _nadir(survey.eo_true).to_frame(frame)
    write_eo_csv(nad, tmp_path / "nadir.csv")
    write_events_csv(tmp_path / "events.csv", survey.events_true)
    rig = bench.calibrated_rig(survey.rig_recorded, survey.tumble_curve)
    write_rig(rig, tmp_path / "rig.yaml")
    run = CliRunner().invoke
    r = run(command, ["--eo", str(tmp_path / "nadir.csv"), "--rig", str(tmp_path / "rig.yaml"), "--events",
                      str(tmp_path / "events.csv"), "-o", str(tmp_path / "obl.csv")])
    assert r.exit_code == 0, r.output
    got = read_eo_csv(tmp_path / "obl.csv")
    d = orientation_differences(got, survey.eo_true)
    assert np.degrees(np.max(d["angle_rad"])) < 2e-8  # 1e-10 deg angles in the file
    assert np.max(np.abs(d["centre_m"])) < 1e-3  # 0.1 mm coordinates in the file
    r = run(command, ["--eo", str(tmp_path / "nadir.csv"), "--rig", str(tmp_path / "rig.yaml"), "--events",
                      str(tmp_path / "events.csv"), "--no-curve", "-o", str(tmp_path / "obl_nc.csv")])
    assert r.exit_code == 0, r.output
    d = orientation_differences(read_eo_csv(tmp_path / "obl_nc.csv"), survey.eo_true)
    assert np.degrees(np.min(d["angle_rad"])) > 0.01
    (tmp_path / "ev_nadir.csv").write_text("\n".join(
        ln for ln in (tmp_path / "events.csv").read_text().splitlines() if ",oblique," not in ln) + "\n")
    from skyrig.cli import main

    r = CliRunner().invoke(main, ["transfer", "--eo", str(tmp_path / "nadir.csv"), "--rig", str(tmp_path / "rig.yaml"),
                                  "--events", str(tmp_path / "ev_nadir.csv"), "-o", str(tmp_path / "x.csv")])
    assert r.exit_code == 2 and "actuated" in r.output
    assert not (tmp_path / "x.csv").exists()


# ----------------------------------------------------------------------------------------------- Fig. 9
def _check_fig9(circ, rig, bench, min_seams: int, tol_px: float, window_px: int = 64):
    res = {lab: bench.fig9(circ, rig, cv, window_px=window_px) for lab, cv in (("curve", "rig"), ("no_curve", None))}
    for lab, f in res.items():
        assert len(f["seams"]) >= min_seams, lab
        for s in f["seams"]:
            diff = np.subtract(s["measured_px"], s["predicted_px"])
            assert np.hypot(*diff) < tol_px, (lab, s)
    return res


@pytest.mark.slow
def test_fig9_small_circle(survey, bench):
    """A 400-pixel rendering of a 30 deg circle: the measured seam offsets agree with the
    offsets predicted from the orientation errors alone, with and without the curve (to 0.45 px: the phase
    correlation of 48-pixel windows of these small images scatters by ~0.15 px RMS, measured with the true
    orientations), and the curve shrinks them."""
    cal = bench.lab_calibrated_curve(survey.tumble_curve, np.random.default_rng(5))
    circ = bench.hover_circle(survey, step_deg=30.0, seed=5, width=400)
    res = _check_fig9(circ, bench.calibrated_rig(survey.rig_recorded, cal), bench, min_seams=12, tol_px=0.45,
                      window_px=48)
    assert res["no_curve"]["median_offset_px"] > 2 * res["curve"]["median_offset_px"]


@pytest.mark.slow
def test_fig9_seams_with_and_without_the_curve(survey, bench):
    """Issue 11 acceptance: one full circle of oblique images (+ the nadir image, which does not overlap them at this
    tilt) on a common plane from the transferred orientations alone: seam offsets <= 1 px with the boresight curve
    and measurably larger without.

    The measured offsets (phase correlation of the images' projections) must also agree with the offsets predicted
    from the orientation errors alone, so that the figure measures the orientations and not the correlator."""
    cal = bench.lab_calibrated_curve(survey.tumble_curve, np.random.default_rng(7))
    circ = bench.hover_circle(survey, step_deg=30.0, seed=7)
    res = _check_fig9(circ, bench.calibrated_rig(survey.rig_recorded, cal), bench, min_seams=12, tol_px=0.3)
    cam = circ.camera
    # with the curve: within the 1 px, and within the prediction from the calibration noise (3 sigma,
    # two images, roll/pitch/yaw noise of the mean of 5 circles through the focal length) + correlation noise
    sig = np.radians(np.asarray(bench.TAB2_MEAN_2SIGMA_DEG) / 2 / np.sqrt(5))
    bound = 3 * np.sqrt(2) * cam.focal_px * np.linalg.norm(sig) + 0.3
    assert res["curve"]["max_offset_px"] <= min(1.0, bound)
    # without: several times larger, and over a pixel somewhere (the scenario's curve reaches ~0.15 deg)
    assert res["no_curve"]["max_offset_px"] > 1.0
    assert res["no_curve"]["median_offset_px"] > 3 * res["curve"]["median_offset_px"]


# ----------------------------------------------------------------------------------------------- the whole chain
@pytest.mark.slow
def test_chain_simulate_adjust_nadir_transfer(tmp_path_factory, bench):
    """skyrig simulate tumblecam -> georef / match / block / adjust of the nadir images only -> skyrig transfer to the
    obliques (calibrated curve / --no-curve) against the simulator's truth.  The obliques inherit the nadir's
    adjusted errors plus the curve's calibration noise: their image-space error stays within the prediction from
    those (focal length x angle, focal length x centre error / flying height); without the curve it is several
    times larger."""
    cache = tmp_path_factory.mktemp("tumblecam-chain")
    r = bench.chain(cache, np.random.default_rng(7), "tumblecam")
    sv = build_survey(scenario_spec("tumblecam", "ci", 1))
    cam = sv.rig_true.head("oblique").camera
    nadir_rot = np.radians(r["adjust"]["rotation_rms_deg"])
    sig_curve = np.linalg.norm(np.radians(np.asarray(bench.TAB2_MEAN_2SIGMA_DEG) / 2 / np.sqrt(5)))
    # orientation: the nadir's rotation error and the calibration noise, nothing else (3 sigma of the latter)
    assert r["curve"]["angle_rms_deg"] <= np.degrees(np.hypot(nadir_rot, 3 * sig_curve))
    assert abs(r["curve"]["centre_rms_m"] - r["adjust"]["centre_rms_m"]) < 1e-3  # zero lever arms
    pred_px = np.hypot(cam.focal_px * np.hypot(nadir_rot, sig_curve),
                       cam.focal_px * r["adjust"]["centre_rms_m"] / sv.spec.flights[0].flying_height_m)
    assert r["curve"]["image_space"]["rms_px"] <= 1.5 * np.sqrt(2) * pred_px
    assert r["no_curve"]["image_space"]["rms_px"] > 2 * r["curve"]["image_space"]["rms_px"]
    assert r["no_curve"]["angle_rms_deg"] > 3 * r["curve"]["angle_rms_deg"]


@pytest.mark.slow
def test_facades_from_transferred_orientations(tmp_path_factory, bench):
    """Issue 11: "the TumbleCam textures from transferred orientations reach the same" (every window corner within
    1 texel of the simulator's façade rule, as from the true orientations).  The real chain on the tumblecam-dsm
    flight (80/60 block of 4 x 6 exposures): skyrig simulate -> georef / match / block / adjust of the nadir images
    only -> skyrig transfer to the obliques through the lab-calibrated rig (bench/tumblecam_chain.py) -> façade
    textures from the simulated oblique images.  On this tree the adjusted nadir orientations are off the truth by
    (1.6, 1.4, 4.6) cm and (66, 61, 43) urad RMS per axis (the height mostly a common 4.6 cm); earlier this test
    drew 5 cm and 100 urad per axis instead, sqrt(3) times what the adjustment reaches, and one window corner
    came out at 1.07 texel.  Without the curve the windows move off."""
    cache = tmp_path_factory.mktemp("tumblecam-dsm-chain")
    r = bench.chain(cache, np.random.default_rng(7), "tumblecam-dsm")
    p = cache / "tumblecam-dsm"
    res = bench.facades(p, {"curve": p / "output" / "eo_obliques_curve.csv",
                            "no_curve": p / "output" / "eo_obliques_no_curve.csv"}, Path(r["rig"]),
                        scenario="tumblecam-dsm")
    c, n = res["curve"], res["no_curve"]
    # the adjustment is what the chain is about: its nadir errors stay at adjustment size (a few cm, ~0.01 deg)
    assert r["adjust"]["centre_rms_m"] < 0.15 and r["adjust"]["rotation_rms_deg"] < 0.02, r["adjust"]
    assert c["seen"] >= 5 and c["windows_found"] >= 0.9 * c["windows"] > 0, c
    assert c["windows_within_1px"] == c["windows_found"], c
    assert c["offset_max_px"] <= 1.0, c
    assert n["windows_within_1px"] < 0.8 * n["windows_found"] or n["offset_max_px"] > 1.0, n


# ----------------------------------------------------------------------------------------------- plane mosaic units
def test_plane_and_seam_cells():
    from skyrig.dense.plane_mosaic import Plane, PlaneGrid, seam_cells
    from skyrig.errors import GeometryError

    p = Plane.horizontal(80.0, (10.0, -5.0))
    uv = p.intersect(np.array([10.0, -5.0, 280.0]), np.array([[0.0, 0.0, -1.0], [1.0, 0.0, -1.0], [0.0, 0.0, 1.0]]))
    assert np.allclose(uv[:2], [[0.0, 0.0], [200.0, 0.0]]) and np.all(np.isnan(uv[2]))  # upward ray: never
    assert np.allclose(p.to_world(np.array([3.0, 4.0])), [13.0, -1.0, 80.0])
    g = PlaneGrid(p, -1.0, 2.0, 0.5, (8, 8))
    assert np.allclose(g.cell_of(g.uv(3.0, 5.0)), [3.0, 5.0])
    with pytest.raises(GeometryError):
        Plane(np.zeros(3), np.array([1.0, 0, 0]), np.array([1.0, 1.0, 0]) / np.sqrt(2))
    src = np.full((4, 5), -1, np.int16)
    src[:, :2], src[:, 2:] = 0, 1
    src[0, 4] = 2
    cells = seam_cells(src)
    assert set(cells) == {(0, 1), (1, 2)}
    assert len(cells[(0, 1)]) == 8  # 4 rows x both sides of the seam
    assert {tuple(c) for c in cells[(1, 2)]} == {(0, 3), (0, 4), (1, 4)}


def test_plane_mosaic_refuses_bad_input(survey):
    from skyrig.dense.plane_mosaic import Plane, plane_mosaic
    from skyrig.errors import SkyrigError

    ob = _obliques(survey.eo_true).subset([0])
    cam = survey.rig_true.head("oblique").camera
    plane = Plane.horizontal(80.0)
    with pytest.raises(SkyrigError, match="Cartesian"):
        plane_mosaic([np.zeros((cam.height, cam.width, 3), np.uint8)], ob.to_frame(WorldFrame.map("EPSG:25832")),
                     cam, plane)
    with pytest.raises(SkyrigError, match="640 x 480"):
        plane_mosaic([np.zeros((10, 10, 3), np.uint8)], ob, cam, plane, cell_m=1.0)
    with pytest.raises(SkyrigError, match="no camera"):
        plane_mosaic([np.zeros((cam.height, cam.width, 3), np.uint8)], ob, {"other": cam}, plane, cell_m=1.0)
    with pytest.raises(SkyrigError, match="cells"):
        plane_mosaic([np.zeros((cam.height, cam.width, 3), np.uint8)], ob, cam, plane, cell_m=0.001)


@pytest.mark.slow
def test_cli_plane_mosaic(survey, bench, tmp_path):
    """``skyrig plane-mosaic`` (Fig. 9 from files): the seam offsets it writes for obliques transferred without the
    boresight curve agree with the offsets predicted from the orientation errors alone (bench.predicted_shifts, no
    image involved), and --max-offset turns them into a failed check (exit 1, outputs kept)."""
    import cv2
    from click.testing import CliRunner

    from skyrig.cli import main
    from skyrig.io.eo_csv import write_eo_csv
    from skyrig.io.rig_file import write_rig

    circ = bench.hover_circle(survey, step_deg=30.0, seed=5, width=400)
    rig = bench.calibrated_rig(survey.rig_recorded, bench.lab_calibrated_curve(survey.tumble_curve,
                                                                             np.random.default_rng(5)))
    eo = bench.circle_orientations(circ, rig, None)
    img_dir = tmp_path / "images"
    img_dir.mkdir()
    for name, img in zip(eo.image, circ.images):
        assert cv2.imwrite(str(img_dir / str(name)), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    write_eo_csv(eo, tmp_path / "eo.csv", unit="deg", convention="opk")
    small = replace(rig, heads={"oblique": rig.head("oblique").with_(camera=circ.camera),
                                "nadir": rig.head("nadir").with_(camera=circ.nadir_camera)})
    write_rig(small, tmp_path / "rig.yaml")
    args = ["plane-mosaic", "--eo", str(tmp_path / "eo.csv"), "--camera", str(tmp_path / "rig.yaml"), "--images",
            str(img_dir), "--height", str(circ.plane_height_m), "--window", "48", "-o", str(tmp_path / "pm")]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    s = json.loads((tmp_path / "pm" / "plane_mosaic.json").read_text())
    assert s["seams_measured"] >= 12 and s["covered"] > 0.5
    ref = bench.fig9(circ, rig, None, window_px=48)  # the library on the same orientations, with predictions
    pred = {(r_["a"], r_["b"]): r_["predicted_offset_px"] * ref["cell_m"] for r_ in ref["seams"]}
    import csv

    with open(tmp_path / "pm" / "seams.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    checked = 0
    for row in rows:
        key = (row["a"], row["b"])
        if key in pred:
            checked += 1
            assert abs(float(row["offset_m"]) - pred[key]) < 0.45 * ref["cell_m"], (row, pred[key])
    assert checked >= 10
    worst = max(float(row["offset_px"]) for row in rows)
    assert worst > 1.0  # without the curve the seams jump (2-3 px at 30 deg steps)
    r = CliRunner().invoke(main, [*args[:-1], str(tmp_path / "pm2"), "--max-offset", "1.0"])
    assert r.exit_code == 1 and "exceeds --max-offset" in r.output
    assert (tmp_path / "pm2" / "manifest.json").exists()


def test_plane_mosaic_plane_options():
    """The plane: exactly one of a height or a point + normal; a façade normal given in a map CRS stays horizontal
    in the local frame (carried through ECEF, so the grid convergence of UTM does not tilt it); bad values name
    the option."""
    from skyrig.errors import OptionError
    from skyrig.pipeline.products import plane_in_local_frame

    frame = WorldFrame.map("EPSG:25832")
    eo = ExteriorOrientations(np.array(["a.png"]), np.array(["cam"]), np.array([[700000.0, 5500000.0, 400.0]]),
                              np.eye(3)[None], frame)
    local, pl = plane_in_local_frame(eo, height=100.0)
    assert np.allclose(pl.normal, [0, 0, 1]) and np.allclose(local.to_ecef(np.zeros((1, 3))),
                                                              frame.to_ecef(np.array([[700000.0, 5500000.0, 100.0]])))
    # a wall facing grid north at 700 km easting (2 deg off the central meridian: convergence ~1.6 deg)
    local, pl = plane_in_local_frame(eo, plane=[700000.0, 5500000.0, 100.0, 0.0, 1.0, 0.0])
    assert abs(pl.normal[2]) < 1e-6 and abs(pl.v_axis @ [0, 0, 1] - 1) < 1e-6
    from pyproj import Transformer

    lon0, lat0 = Transformer.from_crs(25832, 4326, always_xy=True).transform(700000.0, 5500000.0)
    lon1, lat1 = Transformer.from_crs(25832, 4326, always_xy=True).transform(700000.0, 5500010.0)
    az = np.degrees(np.arctan2((lon1 - lon0) * np.cos(np.radians(lat0)), lat1 - lat0))  # grid north's azimuth
    assert abs(np.degrees(np.arctan2(pl.normal[0], pl.normal[1])) - az) < 0.01
    for kw, opt in (({}, "--height"), ({"height": 1.0, "plane": [0] * 6}, "--height"),
                    ({"plane": [1, 2, 3, 0, 0, 0]}, "--plane")):
        with pytest.raises(OptionError, match=opt):
            plane_in_local_frame(eo, **kw)
