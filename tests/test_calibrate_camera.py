"""Issue 12, 1d and 2: the ``camera`` recipe (test-field calibration, paper 004 section 2.5), the calibrated rig file,
and ``skyrig calibrate camera``.

Independent answer: seeded simulation truth.  A cage of 80 retro targets on the floor and walls of a
3.05 m x 3.84 m x 1.88 m box (paper 004: 120" x 151" x 74"), 12 convergent stations around it at 4.8-5.6 m, every
fourth image rolled by 90 deg more, a MIDAS 28 mm camera (5616 x 3744 px of 6.4 um) with a Brown distortion of
about 150 px at the corner, measurements with 0.1 px Gaussian noise; targets and stations fixed, rotations and the
10 intrinsics estimated.  Checks: estimates within 3 predicted sigma of the truth, the redundancy counted by hand
(2 n - 3 I - 10), sigma0 inside its chi-square interval, and over 20 seeds normalised errors consistent with N(0, 1).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.stats import chi2

from skyrig.calibrate import CovarianceBlock, HeadCalibration, Provenance, RigCalibration
from skyrig.calibrate.camera import CalibrationError, calibrate_camera, dlt_pose
from skyrig.camera import BrownDistortion, ForwardDistortion, FrameCamera
from skyrig.cli import main
from skyrig.io.rig_file import read_calibrated_rig, read_rig, write_rig
from skyrig.rig.rig import Head, Rig

TRUE = FrameCamera("midas-28", 5616, 3744, 0.0064, 28.05, 0.021, -0.013,
                   BrownDistortion(k1=1.2e-4, k2=-1.6e-7, k3=8e-11, p1=2.0e-6, p2=-3.0e-6, b1=5e-5, b2=-3e-5))
START = FrameCamera(TRUE.name, TRUE.width, TRUE.height, TRUE.pixel_size_mm, 28.0)
def cage(seed, n_stations=12, n_targets=80, sigma_px=0.1, cam=TRUE):
    rng = np.random.default_rng(seed)
    # 120" x 151" x 74" cage: targets on the floor, the four walls and a few posts inside
    L, Wd, Hh = 3.05, 3.84, 1.88
    X = np.column_stack([rng.uniform(-L/2, L/2, n_targets), rng.uniform(-Wd/2, Wd/2, n_targets), rng.uniform(0, Hh, n_targets)])
    face = rng.integers(0, 5, n_targets)
    X[face == 0, 2] = 0.0
    X[face == 1, 0] = -L/2; X[face == 2, 0] = L/2; X[face == 3, 1] = -Wd/2; X[face == 4, 1] = Wd/2
    Rs, Cs = [], []
    for i in range(n_stations):
        az = 2*np.pi*(i + rng.uniform(-0.2, 0.2))/n_stations
        el = np.radians(rng.uniform(35, 60))
        d = rng.uniform(4.8, 5.6)
        C = np.array([np.cos(az)*np.cos(el), np.sin(az)*np.cos(el), np.sin(el)])*d + [0, 0, 0.9]
        z = C - np.array([0, 0, 0.9]) + rng.normal(0, 0.1, 3); z /= np.linalg.norm(z)
        x = np.cross([0, 0, 1.0], z); x /= np.linalg.norm(x); y = np.cross(z, x)
        roll = np.pi/2*(i % 4) + rng.normal(0, 0.05)
        x, y = np.cos(roll)*x + np.sin(roll)*y, -np.sin(roll)*x + np.cos(roll)*y
        Rs.append(np.column_stack([x, y, z])); Cs.append(C)
    R, C = np.array(Rs), np.array(Cs)
    oi, op, px = [], [], []
    for i in range(n_stations):
        pc = (X - C[i]) @ R[i]
        ok = pc[:, 2] < 0
        uv = np.full((n_targets, 2), np.nan)
        uv[ok] = cam.project_pixels(pc[ok])
        vis = np.flatnonzero(ok & cam.in_image(uv, margin_px=-10.0))
        oi += [f"img{i:02d}"]*vis.size; op += [f"t{k:03d}" for k in vis]; px.append(uv[vis])
    px = np.vstack(px) + rng.normal(0, sigma_px, (len(oi), 2))
    return dict(names=np.array([f"t{k:03d}" for k in range(n_targets)]), xyz=X, oi=np.array(oi), op=np.array(op), px=px,
                centres={f"img{i:02d}": C[i] for i in range(n_stations)}, R=R, C=C)


def run(seed: int, stations: str = "fixed", **kw):  # type: ignore[no-untyped-def]
    d = cage(seed)
    cal = calibrate_camera(START, d["names"], d["xyz"], d["oi"], d["op"], d["px"], stations=stations,
                           station_centres=d["centres"] if stations == "fixed" else None, **kw)
    return cal, d


def chi2_interval(r: int, alpha: float = 0.001) -> tuple[float, float]:
    """Two-sided interval of sigma0 for redundancy r."""
    return float(np.sqrt(chi2.ppf(alpha / 2, r) / r)), float(np.sqrt(chi2.ppf(1 - alpha / 2, r) / r))


@pytest.mark.parametrize("stations", ["fixed", "free"])
def test_cage_calibration_within_3_sigma_and_sigma0_in_its_interval(stations: str) -> None:
    cal, d = run(0, stations)
    n, i = len(d["oi"]), len(d["centres"])
    assert cal.parameters == TRUE.intrinsic_names
    assert cal.n_observations == 2 * n
    assert cal.redundancy == 2 * n - (3 if stations == "fixed" else 6) * i - 10
    z = (cal.values - TRUE.intrinsics) / cal.sigma
    assert np.all(np.abs(z) < 3), dict(zip(cal.parameters, np.round(z, 2)))
    lo, hi = chi2_interval(cal.redundancy)
    assert lo < cal.sigma0 < hi
    assert np.all(np.abs(cal.residual_rms_px - 0.1) < 0.01)
    # the covariance is sigma0² Q, symmetric, and its correlations are a correlation matrix
    np.testing.assert_allclose(cal.covariance, cal.sigma0**2 * cal.cofactor, rtol=1e-12)
    c = cal.correlation
    assert np.allclose(c, c.T) and np.allclose(np.diag(c), 1) and np.linalg.eigvalsh(c)[0] > 0
    if stations == "fixed":  # the stations stay where they were given
        np.testing.assert_array_equal(cal.camera_centre, np.array([d["centres"][k] for k in cal.image_names]))
    # rotations close to the truth (the DLT only started them)
    ang = [np.degrees(np.arccos(np.clip((np.trace(a.T @ b) - 1) / 2, -1, 1)))
           for a, b in zip(cal.world_from_camera_rotation, d["R"])]
    assert max(ang) < 0.01


def test_a_chosen_model_and_subset() -> None:
    """Self-calibration of the forward model (R0 = 15 mm, distortion centre held) on forward-distorted images."""
    global_true = TRUE.with_(distortion=ForwardDistortion(k1=-1.1e-4, k2=1.5e-7, k3=-6e-11, p1=-2e-6, p2=3e-6,
                                                          b1=-5e-5, b2=3e-5, r0_mm=15.0))
    d = cage(4, cam=global_true)
    names = ("focal_mm", "ppx_mm", "ppy_mm", "k1", "k2", "k3", "p1", "p2", "b1", "b2")
    cal = calibrate_camera(START, d["names"], d["xyz"], d["oi"], d["op"], d["px"], model=ForwardDistortion(r0_mm=15.0),
                           parameters=names, station_centres=d["centres"])
    assert cal.camera.distortion.r0_mm == 15.0 and cal.camera.distortion.k4 == 0.0
    truth = global_true.intrinsics[[global_true.intrinsic_names.index(n) for n in names]]
    z = (cal.values - truth) / cal.sigma
    assert np.all(np.abs(z) < 3), dict(zip(names, np.round(z, 2)))
    assert cal.redundancy == cal.n_observations - 3 * len(d["centres"]) - len(names)


def test_errors_are_named() -> None:
    d = cage(0)
    with pytest.raises(CalibrationError, match="no station centre"):
        calibrate_camera(START, d["names"], d["xyz"], d["oi"], d["op"], d["px"], station_centres={})
    with pytest.raises(CalibrationError, match="not targets"):
        calibrate_camera(START, d["names"][1:], d["xyz"][1:], d["oi"], d["op"], d["px"], stations="free")
    with pytest.raises(CalibrationError, match="not intrinsics"):
        calibrate_camera(START, d["names"], d["xyz"], d["oi"], d["op"], d["px"], stations="free", parameters=["k9"])
    with pytest.raises(CalibrationError, match="at least 6"):
        dlt_pose(START, d["xyz"][:5], np.zeros((5, 2)))


@pytest.mark.slow
def test_normalised_errors_over_20_seeds_are_standard_normal() -> None:
    """Per parameter over 20 seeds: mean within 3.3 / sqrt(20) of 0 and the sample variance inside the 99.9 %
    chi-square(19) interval; pooled whitened errors (Cholesky of each seed's covariance, so independent) over all
    200 values: mean within 3.3 / sqrt(200) and variance inside chi-square(199); the sum of the squared
    Mahalanobis distances inside chi-square(200); sigma0² r over all seeds inside chi-square(sum r)."""
    z, w, maha, s2r, rsum = [], [], [], 0.0, 0
    for seed in range(100, 120):
        cal, _ = run(seed)
        e = cal.values - TRUE.intrinsics
        z.append(e / cal.sigma)
        L = np.linalg.cholesky(cal.covariance)
        w.append(np.linalg.solve(L, e))
        maha.append(float(e @ np.linalg.solve(cal.covariance, e)))
        s2r += cal.sigma0**2 * cal.redundancy
        rsum += cal.redundancy
    z_a, w_a = np.array(z), np.array(w).ravel()
    k, p = z_a.shape
    lo19, hi19 = chi2.ppf(0.0005, k - 1) / (k - 1), chi2.ppf(0.9995, k - 1) / (k - 1)
    for j, name in enumerate(TRUE.intrinsic_names):
        assert abs(z_a[:, j].mean()) < 3.3 / np.sqrt(k), (name, z_a[:, j].mean())
        assert lo19 < z_a[:, j].var(ddof=1) < hi19, (name, z_a[:, j].std(ddof=1))
    m = w_a.size
    assert abs(w_a.mean()) < 3.3 / np.sqrt(m)
    assert chi2.ppf(0.0005, m - 1) / (m - 1) < w_a.var(ddof=1) < chi2.ppf(0.9995, m - 1) / (m - 1)
    assert chi2.ppf(0.0005, k * p) < sum(maha) < chi2.ppf(0.9995, k * p)
    assert chi2.ppf(0.0005, rsum) < s2r < chi2.ppf(0.9995, rsum)
    print(f"\n20 seeds x {p} parameters: per-parameter mean {np.round(z_a.mean(axis=0), 2).tolist()}, "
          f"std {np.round(z_a.std(axis=0, ddof=1), 2).tolist()}; whitened mean {w_a.mean():.3f} std "
          f"{w_a.std(ddof=1):.3f}; sum Mahalanobis {sum(maha):.1f} (chi2 {k * p}); "
          f"pooled sigma0 {np.sqrt(s2r / rsum):.4f}")


# ---------------------------------------------------------------------- calibrated rig file
def _calibrated(tmp_path):  # type: ignore[no-untyped-def]
    from skyrig.pipeline.demo import build_demo_project

    p = build_demo_project(tmp_path / "demo")
    rig = read_rig(p.rig)
    heads = {}
    rng = np.random.default_rng(5)
    for h in rig:
        a = rng.normal(size=(3, 3))
        cov3 = a @ a.T * 1e-6
        names = h.camera.intrinsic_names[:3]
        heads[h.name] = HeadCalibration(
            lever_arm_m=CovarianceBlock.from_covariance(("x", "y", "z"), cov3),
            boresight_opk_deg=CovarianceBlock.from_covariance(("omega", "phi", "kappa"), cov3 * 1e-2),
            interior=CovarianceBlock.from_covariance(names, cov3 * 1e-3),
            provenance=Provenance("calqc", "boresight flight 600 m", "2011-05-12", "skyrig test", {"sigma0": 1.02}))
    cal = RigCalibration(heads, CovarianceBlock.from_covariance(("x", "y", "z"), np.diag([1e-4, 1e-4, 4e-4])),
                         Provenance("uncalibrated-gnss-imu", "flight 1", "2011-05-12", "skyrig test",
                                    {"sigma0": 0.98, "redundancy": 12345}, "all heads"))
    return p, rig, cal


def test_calibrated_rig_file_round_trip_and_old_files(tmp_path) -> None:  # type: ignore[no-untyped-def]
    p, rig, cal = _calibrated(tmp_path)
    out = tmp_path / "calibrated.yaml"
    write_rig(rig, out, cal)
    text = out.read_text()
    assert "calibration:" in text and "version: 1" in text
    back, cal2 = read_calibrated_rig(out)
    assert back.isclose(rig) and read_rig(out).isclose(rig)
    assert cal2 is not None and cal2.provenance == cal.provenance
    assert cal2.antenna_lever_arm_m.isclose(cal.antenna_lever_arm_m)  # type: ignore[union-attr]
    for name, hc in cal.heads.items():
        for key, b in hc.groups.items():
            b2 = cal2.heads[name].groups[key]
            assert b2.parameters == b.parameters
            np.testing.assert_allclose(b2.covariance, b.covariance, rtol=1e-9, atol=1e-300)
        assert cal2.heads[name].provenance == hc.provenance
    # an old (uncalibrated) rig file reads as before and has no calibration
    r0, c0 = read_calibrated_rig(p.rig)
    assert c0 is None and r0.isclose(rig)
    # bad blocks are named with their key path
    bad = text.replace("parameters: [focal_mm, ppx_mm, ppy_mm]", "parameters: [focal_mm, ppx_mm, k9]", 1)
    (tmp_path / "bad.yaml").write_text(bad)
    from skyrig.errors import InputFormatError

    with pytest.raises(InputFormatError, match="not parameters of this camera") as e:
        read_rig(tmp_path / "bad.yaml")
    assert e.value.field.endswith("calibration.interior.parameters")


def test_documented_calibrated_example_reads(tmp_path) -> None:  # type: ignore[no-untyped-def]
    import re
    from pathlib import Path

    doc = Path(__file__).resolve().parents[1] / "docs" / "formats" / "rig_file.md"
    blocks = re.findall(r"```yml\n(.*?)```", doc.read_text(encoding="utf-8"), flags=re.S)
    assert len(blocks) == 1
    (tmp_path / "c.yaml").write_text(blocks[0], encoding="utf-8")
    rig, cal = read_calibrated_rig(tmp_path / "c.yaml")
    assert cal is not None and cal.provenance.recipe == "calqc"  # type: ignore[union-attr]
    interior = cal.heads["nadir"].interior  # type: ignore[union-attr]
    assert interior.parameters == ("focal_mm", "ppx_mm", "ppy_mm", "k1", "k2", "k3")
    assert cal.heads["nadir"].provenance.statistics["redundancy"] == 1710  # type: ignore[union-attr]
    assert rig.head("nadir").camera.focal_mm == 28.0512


def test_georef_and_block_take_the_calibrated_rig_file(tmp_path) -> None:  # type: ignore[no-untyped-def]
    p, rig, cal = _calibrated(tmp_path)
    out = tmp_path / "calibrated.yaml"
    write_rig(rig, out, cal)
    run = CliRunner()
    res = {}
    for tag, path in (("plain", p.rig), ("calibrated", out)):
        r = run.invoke(main, ["georef", "--trajectory", str(p.trajectory), "--events", str(p.events), "--rig", str(path),
                              "--crs", "EPSG:25832", "-o", str(tmp_path / f"eo_{tag}.csv")])
        assert r.exit_code == 0, r.output
        res[tag] = (tmp_path / f"eo_{tag}.csv").read_text()
    assert res["plain"] == res["calibrated"]
    # skyrig block with measurements of the check points projected through the georeferenced images
    from skyrig.georef.ground import world_to_image
    from skyrig.georef.observations import ImageMeasurements
    from skyrig.io.eo_csv import read_eo_csv
    from skyrig.io.points_csv import read_points_csv, write_measurements_csv

    eo = read_eo_csv(tmp_path / "eo_calibrated.csv")
    gp = read_points_csv(p.check_points)
    cams = {h.camera.name: h.camera for h in rig}
    pt, im, px = [], [], []
    for img in eo.image:
        uv = world_to_image(eo, cams, np.full(len(gp), img), gp.xyz, gp.frame)
        cam = cams[str(eo.camera[eo.index()[img]])]
        ok = np.isfinite(uv).all(axis=1) & (uv > 0).all(axis=1) & (uv[:, 0] < cam.width - 1) & (uv[:, 1] < cam.height - 1)
        pt += list(gp.name[ok])
        im += [img] * int(ok.sum())
        px.append(uv[ok])
    write_measurements_csv(tmp_path / "m.csv", ImageMeasurements(np.array(pt), np.array(im), np.vstack(px)))
    r = run.invoke(main, ["block", "--trajectory", str(p.trajectory), "--events", str(p.events), "--rig", str(out),
                          "--measurements", str(tmp_path / "m.csv"), "--control", str(p.check_points),
                          "-o", str(tmp_path / "blk" / "block.json")])
    assert r.exit_code == 0, r.output


# ---------------------------------------------------------------------- CLI
def test_cli_calibrate_camera_writes_a_calibrated_rig_and_report(tmp_path) -> None:  # type: ignore[no-untyped-def]
    d = cage(7)
    (tmp_path / "targets.csv").write_text("name,x,y,z\n" + "".join(
        f"{n},{x:.6f},{y:.6f},{z:.6f}\n" for n, (x, y, z) in zip(d["names"], d["xyz"])))
    (tmp_path / "stations.csv").write_text("name,x,y,z\n" + "".join(
        f"{n},{c[0]:.6f},{c[1]:.6f},{c[2]:.6f}\n" for n, c in d["centres"].items()))
    (tmp_path / "meas.csv").write_text("point,image,column,row\n" + "".join(
        f"{p},{i},{u:.4f},{v:.4f}\n" for p, i, (u, v) in zip(d["op"], d["oi"], d["px"])))
    write_rig(Rig("midas", [Head("nadir", START)]), tmp_path / "rig.yaml")
    r = CliRunner().invoke(main, ["calibrate", "camera", "--points", str(tmp_path / "targets.csv"), "--measurements",
                                  str(tmp_path / "meas.csv"), "--stations", str(tmp_path / "stations.csv"), "--rig",
                                  str(tmp_path / "rig.yaml"), "--flight", "cage 2011", "--date", "2011-04-01",
                                  "-o", str(tmp_path / "out" / "calibrated.yaml")])
    assert r.exit_code == 0, r.output
    rig, cal = read_calibrated_rig(tmp_path / "out" / "calibrated.yaml")
    rep = json.loads((tmp_path / "out" / "calibrated.json").read_text())
    cam = rig.head("nadir").camera
    blk = cal.heads["nadir"].interior  # type: ignore[union-attr]
    assert blk.parameters == TRUE.intrinsic_names
    z = (cam.intrinsics - TRUE.intrinsics) / blk.sigma
    assert np.all(np.abs(z) < 3.5), np.round(z, 2)  # coordinates rounded to 1e-6 m / 1e-4 px in the files
    prov = cal.heads["nadir"].provenance  # type: ignore[union-attr]
    assert prov.recipe == "camera" and prov.flight == "cage 2011" and prov.statistics["redundancy"] == rep["redundancy"]
    assert rep["sigma0"] == pytest.approx(prov.statistics["sigma0"])
    assert [e["name"] for e in rep["estimated"]] == list(TRUE.intrinsic_names)
    # without stations: free stations; without a rig: the camera from the options; bad model named
    r = CliRunner().invoke(main, ["calibrate", "camera", "--points", str(tmp_path / "targets.csv"), "--measurements",
                                  str(tmp_path / "meas.csv"), "--width-px", "5616", "--height-px", "3744",
                                  "--pixel-size-um", "6.4", "--focal-mm", "28", "-o", str(tmp_path / "free.yaml")])
    assert r.exit_code == 0, r.output
    assert json.loads((tmp_path / "free.json").read_text())["stations"] == "free"
    r = CliRunner().invoke(main, ["calibrate", "camera", "--points", str(tmp_path / "targets.csv"), "--measurements",
                                  str(tmp_path / "meas.csv"), "--rig", str(tmp_path / "rig.yaml"), "--model", "nope",
                                  "-o", str(tmp_path / "x.yaml")])
    assert r.exit_code != 0 and "nope" in r.output and not (tmp_path / "x.yaml").exists()
