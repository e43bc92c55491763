"""``skyrig calibrate tumbling-head`` (paper 000's laboratory recipe) on the simulated laboratory of
``bench/tumbling_lab.py``: 8 positions x 3 circles at 320 px, judged against the simulator's true curve.

Tolerances come from the predicted precision: one circle's measurement at a position scatters with
``sqrt(repeat^2 + fit^2)`` (the injected repeat error, paper 000 Tab. 2 / 2, and the per-image fit sigma the recipe
reports), the mean of C circles with that / sqrt(C).
"""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.stats import chi2

from skyrig.cli import main
from skyrig.errors import SkyrigError
from skyrig.io.rig_file import read_calibrated_rig
from skyrig.rig.boresight_curve import AXES

ROOT = Path(__file__).resolve().parents[1]


def _bench():
    spec = importlib.util.spec_from_file_location("tumbling_lab", ROOT / "bench" / "tumbling_lab.py")
    mod = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    sys.modules.setdefault("tumbling_lab", mod)
    spec.loader.exec_module(mod)  # type: ignore[union-attr]
    return mod


@pytest.fixture(scope="module")
def lab_run(tmp_path_factory):
    tl = _bench()
    lab = tl.build_lab(positions=8, circles=3, width=320, distance_m=3.0, seed=1)
    images, ref = tl.render_lab(lab)
    d = tmp_path_factory.mktemp("tumbling_lab")
    paths = tl.write_lab(lab, images, ref, d)
    out = d / "calibrated_rig.yaml"
    r = CliRunner().invoke(main, ["calibrate", "tumbling-head", "--images", str(paths["images"]), "--rig",
                                  str(paths["rig"]), "--positions", str(paths["positions"]), "--plane-distance-m", "3.0",
                                  "--flight", "simulated lab", "-o", str(out)])
    assert r.exit_code == 0, r.output
    return tl, lab, paths, out, r.output


def test_curve_within_predicted_precision(lab_run):
    tl, lab, _, out, _ = lab_run
    rig, cal = read_calibrated_rig(out)
    curve = rig.head("oblique").curve
    assert curve is not None and curve.beta_rad.size == 8 and np.all(curve.count == 3)
    rep = json.loads(out.with_suffix(".json").read_text())
    fit = np.radians(np.array([[m[f"{a}_sigma_mdeg"] for a in AXES] for m in rep["measurements"]]) / 1000)
    fit_rms = np.sqrt(np.mean(fit ** 2, axis=0))
    one = np.sqrt(lab.repeat_sigma_rad ** 2 + fit_rms ** 2)  # predicted scatter of one circle's value
    # the circles see the same texture at a position: the comparison's error repeats, only the repeat error averages
    se = np.sqrt(lab.repeat_sigma_rad ** 2 / 3 + fit_rms ** 2)
    err = curve.corrections_rad - lab.true_curve(curve.beta_rad)
    z = err / se
    print("curve error (mdeg) rms", 1000 * np.degrees(np.sqrt(np.mean(err ** 2, axis=0))), "predicted SE",
          1000 * np.degrees(se), "max |z|", np.abs(z).max(axis=0), "within 2 sigma", np.mean(np.abs(z) <= 2))
    assert np.all(np.abs(z) < 4.0)
    # the recovered curve explains most of the true curve (amplitude 50-100 mdeg)
    amp = np.abs(lab.true_curve(curve.beta_rad)).max(axis=0)
    assert np.all(np.sqrt(np.mean(err ** 2, axis=0)) < 0.35 * amp)
    # repeatability: the pooled per-position variance against the predicted one (chi-square, (C-1) K dof)
    dof = 2 * 8
    pooled = np.mean(curve.std_rad ** 2, axis=0)
    stat = pooled * dof / one ** 2
    print("repeatability pooled (mdeg)", 1000 * np.degrees(np.sqrt(pooled)), "predicted", 1000 * np.degrees(one))
    assert np.all(stat > chi2.ppf(0.0005, dof)) and np.all(stat < chi2.ppf(0.9995, dof))
    # the mechanism's repeat error (measurement variance removed) against the injected one: the pooled variance
    # has a standard error of one^2 sqrt(2 / dof)
    mech = np.radians(np.array([rep["table2_2sigma"][a]["mechanism_std_mdeg"] for a in AXES]) / 2000)
    print("mechanism repeatability (mdeg)", 1000 * np.degrees(mech), "injected", 1000 * np.degrees(lab.repeat_sigma_rad))
    assert np.all(np.abs(mech ** 2 - lab.repeat_sigma_rad ** 2) < 4 * one ** 2 * np.sqrt(2 / dof))
    # the actuator block: values = mean curve in degrees, sigma = standard errors
    blk = cal.heads["oblique"].actuator
    assert blk is not None and len(blk.parameters) == 24
    np.testing.assert_allclose(blk.values.reshape(8, 3), np.degrees(curve.corrections_rad), atol=1e-9)
    fit_pos = np.mean(fit.reshape(3, 8, 3) ** 2, axis=0)
    np.testing.assert_allclose(blk.sigma.reshape(8, 3), np.degrees(np.sqrt(curve.std_rad ** 2 / 3 + fit_pos)),
                               rtol=1e-4)
    assert cal.heads["oblique"].provenance.recipe == "tumbling-head"


def test_georeferencing_with_calibrated_rig_beats_nominal(lab_run):
    tl, lab, _, out, _ = lab_run
    rig, _ = read_calibrated_rig(out)
    nominal = tl.image_point_errors(lab, lab.setup.rig)
    calibrated = tl.image_point_errors(lab, rig)
    print("image points: nominal", nominal, "calibrated", calibrated)
    assert calibrated["rms_px"] < 0.3 * nominal["rms_px"]
    assert calibrated["max_px"] < 1.0


def test_table2_report(lab_run):
    _, lab, _, out, output = lab_run
    rep = json.loads(out.with_suffix(".json").read_text())
    t2 = rep["table2_2sigma"]
    std = np.array([[c[f"{a}_std_mdeg"] for a in AXES] for c in rep["curve"]])
    for i, a in enumerate(AXES):
        assert t2[a]["mean_std_mdeg"] == pytest.approx(2 * std[:, i].mean(), rel=1e-9)
        assert t2[a]["max_std_mdeg"] == pytest.approx(2 * std[:, i].max(), rel=1e-9)
        assert rep["curve"][int(np.argmax(std[:, i]))]["beta_deg"] == pytest.approx(t2[a]["beta_at_max_deg"])
    assert out.with_suffix(".html").is_file() and "Tab. 2" in out.with_suffix(".html").read_text()
    assert "repeat accuracies" in output


def test_bad_positions_named(lab_run, tmp_path):
    _, _, paths, _, _ = lab_run
    bad = tmp_path / "positions.csv"
    lines = paths["positions"].read_text().splitlines()
    lines[3] = lines[3].rsplit(",", 1)[0] + ",abc"
    bad.write_text("\n".join(lines) + "\n")
    r = CliRunner().invoke(main, ["calibrate", "tumbling-head", "--images", str(paths["images"]), "--rig",
                                  str(paths["rig"]), "--positions", str(bad), "--plane-distance-m", "3.0",
                                  "-o", str(tmp_path / "x.yaml")])
    assert r.exit_code == 2
    assert "beta_deg" in r.output and "line 4" in r.output
    assert not (tmp_path / "x.yaml").exists()


def test_circles_must_hold_the_same_positions(lab_run):
    from skyrig.calibrate.tumbling import calibrate_tumbling_head

    _, lab, _, _, _ = lab_run
    names, circles, betas = lab.names[:-1], lab.circles[:-1], lab.betas[:-1]
    with pytest.raises(SkyrigError, match="same actuator positions"):
        calibrate_tumbling_head(lab.setup, lambda n: None, names, circles, betas, None)
