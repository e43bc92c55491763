"""Ground control in the GNSS-supported UAV adjustment (issue 28): metre-class targets (handheld GNSS: 1 m in plan, 5 m
in height, declared as such) are used, not refused; check points come back within their predicted precision of the
simulation's truth and are reported in metres and GSD; a target seen in one image only is reported and left out."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from skyrig.adjust.report import adjustment_report
from skyrig.pipeline.uav import UavConfig, adjust_uav_block, block_gsd_m
from test_uav_determinability import FLAT, _block

SIGMA = np.array([1.5, 1.5, 10.0])  # declared target sigma (m): handheld GNSS, a loose height


def _checks_within_predicted(res, track_name, chk, X):
    """Check points against the simulation's truth within their predicted precision (4 sigma per axis, + 2 cm);
    returns their predicted height sigmas (m)."""
    b, ps = res.adjustment.block, res.adjustment.point_sigma
    idx = {str(n): k for k, n in enumerate(b.point_name)}
    ks = [idx[str(track_name[t])] for t in chk]
    for k, t in zip(ks, chk):
        d = b.point_xyz[k] - X[t]
        assert np.all(np.abs(d) < 4 * ps[k] + 0.02), (d, ps[k])
    return ps[ks, 2]


def test_metre_class_control_and_check_points_in_the_gnss_block(caplog):
    truth: dict = {}
    inp, true_cam = _block(FLAT, seed=21, gnss_noise=(2.0, 2.0, 4.0), focal_error=1.0, truth=truth)
    rng = np.random.default_rng(5)
    seen = np.bincount(inp.obs_track, minlength=len(inp.track_name))
    multi = np.flatnonzero(seen >= 3)
    pick = rng.choice(multi, 15, replace=False)
    ctrl, chk = pick[:10], pick[10:]
    # a target measured in one image only: a new track with one observation (the pixel of a ground point of image 0)
    k0 = np.flatnonzero(inp.obs_image == 0)[0]
    inp.track_name = np.append(inp.track_name, "T1")
    inp.obs_track = np.append(inp.obs_track, len(inp.track_name) - 1)
    inp.obs_image = np.append(inp.obs_image, 0)
    inp.obs_pixel = np.vstack([inp.obs_pixel, inp.obs_pixel[k0] + 5.0])
    single = np.array([len(inp.track_name) - 1])
    X = np.vstack([truth["X"], truth["X"][inp.obs_track[k0]]])
    noise = rng.normal(0, 1, (len(ctrl) + len(single), 3)) * np.array([1.0, 1.0, 5.0])
    tracks = np.concatenate([ctrl, single, chk])
    xyz = np.vstack([X[np.concatenate([ctrl, single])] + noise, X[chk]])  # check points exact (a good survey)
    inp.control_track = tracks.astype(np.int64)
    inp.control_xyz = xyz
    inp.control_sigma = np.vstack([np.broadcast_to(SIGMA, (len(ctrl) + len(single), 3)),
                                   np.broadcast_to([0.01, 0.01, 0.02], (len(chk), 3))])
    inp.control_check = np.r_[np.zeros(len(ctrl) + len(single), bool), np.ones(len(chk), bool)]
    cfg = UavConfig(gnss_sigma_m=(2.0, 2.0, 4.0), pixel_sigma_px=0.3, pnp_threshold_px=4.0,
                    self_calibration=("focal_mm", "ppx_mm", "ppy_mm", "k1", "k2"))
    with caplog.at_level(logging.WARNING):
        res = adjust_uav_block(inp, cfg)
    assert res.adjustment.ok, res.adjustment.failures
    s = res.summary
    assert len(s["control_used"]) == 10 and len(s["check_used"]) == 5
    assert list(s["control_left_out"]) == [str(inp.track_name[single[0]])]
    assert any("cannot be intersected" in r.getMessage() for r in caplog.records)
    # check points against the truth within their predicted precision (4 sigma per axis)
    _checks_within_predicted(res, inp.track_name, chk, X)
    rep = adjustment_report(res.adjustment, gsd_m=block_gsd_m(res))
    assert rep["check"]["stats"]["n"] == 5 and len(rep["check"]["stats"]["rms_gsd"]) == 3
    gsd = block_gsd_m(res)
    assert gsd == pytest.approx(50.0 / (true_cam.focal_mm / true_cam.pixel_size_mm), rel=0.05)  # 50 m / f_px


def test_no_gnss_block_with_metre_class_control_only():
    """No GNSS, an uncalibrated camera (focal 5 % off), 10 targets with 1 m plan and 5 m height noise declared as
    1.5 / 1.5 / 10 m: the block is oriented in their frame, check points (exact) land within their predicted precision,
    and the report says the datum is as good as the targets."""
    from skyrig.orient.incremental import OrientConfig, OrientInput, orient_incremental
    from skyrig.report.adjustment import absolute_accuracy_statement
    from test_uav_determinability import CROSS

    truth: dict = {}
    inp, true_cam = _block(CROSS, seed=31, focal_error=1.05, truth=truth)
    rng = np.random.default_rng(9)
    seen = np.bincount(inp.obs_track, minlength=len(inp.track_name))
    X = truth["X"]
    # targets spread over the site: the well-seen point nearest each node of a 5 x 2 grid
    good = np.flatnonzero(seen >= 3)
    nodes = np.array([[x, y] for x in (-50.0, -25.0, 0.0, 25.0, 50.0) for y in (-35.0, 35.0)])
    ctrl = [int(good[np.argmin(np.linalg.norm(X[good, :2] - q, axis=1))]) for q in nodes]
    chk = [int(t) for t in rng.choice(np.setdiff1d(np.flatnonzero(seen >= 4), ctrl), 5, replace=False)]
    noise = rng.normal(0, 1, (10, 3)) * np.array([1.0, 1.0, 5.0])
    oi = OrientInput(inp.names, inp.camera, inp.obs_track, inp.obs_image, inp.obs_pixel, inp.track_name,
                     control_track=np.array(ctrl + chk), control_xyz=np.vstack([X[ctrl] + noise, X[chk]]),
                     control_sigma=np.vstack([np.broadcast_to(SIGMA, (10, 3)), np.full((5, 3), 0.01)]),
                     control_check=np.r_[np.zeros(10, bool), np.ones(5, bool)])
    res = orient_incremental(oi, OrientConfig(pixel_sigma_px=0.3))
    assert res.oriented.all() and res.adjustment.ok
    assert res.summary["datum"]["kind"] == "control"
    sz = _checks_within_predicted(res, inp.track_name, chk, X)
    assert sz.max() > 0.5  # a metre-class datum, honestly stated
    text = absolute_accuracy_statement(res.summary)
    assert "control points" in text and "that of the targets" in text


def _dms(v: float) -> tuple[float, float, float]:
    v = abs(v)
    d = int(v)
    m = int((v - d) * 60)
    return float(d), float(m), (v - d - m / 60) * 3600


def test_cli_routes_gps_images_with_control_to_the_gnss_block(tmp_path):
    """``skyrig adjust-uav`` on image files that carry EXIF GPS (written here with Pillow), with ``--control`` /
    ``--check`` / ``--control-sigma``: the GNSS-supported block with control (not the orientation without GNSS), the
    report's check points within their predicted precision of the simulation's truth."""
    from click.testing import CliRunner
    from PIL import Image

    from skyrig.cli import main
    from skyrig.geodesy.crs import ecef_to_geodetic
    from skyrig.geodesy.frame import WorldFrame
    from skyrig.georef.observations import ImageMeasurements
    from skyrig.io.points_csv import write_measurements_csv
    from test_uav_determinability import CROSS

    truth: dict = {}
    inp, true_cam = _block(CROSS, seed=41, focal_error=1.0, truth=truth)
    pix = true_cam.pixel_size_mm
    lat, lon, h = ecef_to_geodetic(inp.frame.points_to(inp.gnss, WorldFrame.ecef()))
    img = tmp_path / "images"
    img.mkdir()
    for k, name in enumerate(inp.names):
        ex = Image.Exif()
        ex[0x010F], ex[0x0110] = "Test", "Cam"
        ex[0x8769] = {0x920A: float(true_cam.focal_mm), 0xA20E: 1.0 / pix, 0xA210: 4}  # focal, px per mm
        ex[0x8825] = {1: "N" if lat[k] >= 0 else "S", 2: _dms(lat[k]), 3: "E" if lon[k] >= 0 else "W",
                      4: _dms(lon[k]), 5: b"\x00", 6: float(h[k])}
        Image.new("RGB", (true_cam.width, true_cam.height)).save(img / name, exif=ex)
    (tmp_path / "match").mkdir()
    write_measurements_csv(tmp_path / "match" / "tie_points.csv", ImageMeasurements(
        inp.track_name[inp.obs_track], inp.names[inp.obs_image], inp.obs_pixel))
    X = truth["X"]
    seen = np.bincount(inp.obs_track, minlength=len(inp.track_name))
    good = np.flatnonzero(seen >= 4)
    nodes = np.array([[x, y] for x in (-50.0, 0.0, 50.0) for y in (-35.0, 35.0)])
    ctrl = [int(good[np.argmin(np.linalg.norm(X[good, :2] - q, axis=1))]) for q in nodes]
    chk = [int(t) for t in np.random.default_rng(2).choice(np.setdiff1d(good, ctrl), 4, replace=False)]
    head = "# crs: local 50.85 -0.15 120.0\nname,x,y,z\n"
    noise = np.random.default_rng(3).normal(0, 1, (len(ctrl), 3)) * [1.0, 1.0, 5.0]
    (tmp_path / "gcp.csv").write_text(head + "".join(
        f"{inp.track_name[t]},{x:.3f},{y:.3f},{z:.3f}\n" for t, (x, y, z) in zip(ctrl, X[ctrl] + noise)))
    (tmp_path / "chk.csv").write_text(head + "".join(
        f"{inp.track_name[t]},{x:.4f},{y:.4f},{z:.4f}\n" for t, (x, y, z) in zip(chk, X[chk])))
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["adjust-uav", str(tmp_path), "--images", str(img), "--match", str(tmp_path / "match"),
                                  "--altitude", "ellipsoidal", "--gnss-sigma", "0.3,0.3,0.5", "--attitude-sigma", "0",
                                  "--control", str(tmp_path / "gcp.csv"), "--control-sigma", "1.5,1.5,10",
                                  "--check", str(tmp_path / "chk.csv"), "-o", str(out)])
    assert r.exit_code == 0, r.output
    import json

    rep = json.loads((out / "report.json").read_text())
    u = rep["uav"]
    assert "datum" not in u or u["datum"].get("kind") != "control"  # the GNSS block, not the no-GNSS path
    assert sorted(u["control_used"]) == sorted(str(inp.track_name[t]) for t in ctrl)
    st = rep["check"]["stats"]
    assert st["n"] == 4 and len(st["rms_gsd"]) == 3
    # the check points against the truth: report rows (adjusted - given, in the output CRS = UTM) within a bound
    # from the GNSS datum: 0.3 / 0.5 m per image over 42 images, a few decimetres at most
    v = np.array([[row["VX"], row["VY"], row["VZ"]] for row in rep["check"]["rows"]])
    assert np.all(np.abs(v) < [0.5, 0.5, 1.0]), v


def test_accuracy_statement_names_what_defines_the_datum():
    """The report's words for each datum: check points win; GNSS; EXIF GPS by similarity; a free frame."""
    from skyrig.report.adjustment import absolute_accuracy_statement

    chk = {"stats": {"n": 3, "rms_m": [0.01, 0.02, 0.03], "rms_gsd": [0.5, 1.0, 1.5]}}
    assert "3 check points" in absolute_accuracy_statement({}, chk) and "1.50 GSD" in absolute_accuracy_statement({}, chk)
    gnss = absolute_accuracy_statement({"config": {"gnss_sigma_m": [2, 2, 4]}, "gnss_fit_rms_enu_m": [0.2, 0.5, 0.6]})
    assert "GNSS" in gnss and "2, 2, 4 m" in gnss
    pos = absolute_accuracy_statement({"datum": {"kind": "positions", "positions_similarity_rms_3d_m": 4.2}})
    assert "EXIF GPS" in pos and "4.20 m" in pos
    assert "undefined" in absolute_accuracy_statement({"datum": {"kind": "free"}})
