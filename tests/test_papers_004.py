"""Paper 004 (MIDAS) reproduced: ``skyrig.papers.p004.run`` at size ci - Tab. 11 of the calqc recipe on the
reduced simulated MIDAS flight, the POSEO file, the per-head oblique mosaics - asserted against the simulation's
injected truth and, where the scenario reproduces the paper's conditions (28 mm nadir at 2,000 ft, 3.84 um image
noise), against the paper's statement (about 1 GSD planimetric, 2 GSD vertical).

The injected values are :func:`skyrig.calibrate.calqc.midas_calqc_scenario`'s defaults (inputs, not results):
datum shift (0.25, -0.15, 0.20) m, image noise 3.84 um, GNSS noise 3 / 3 / 5 cm (scenario ``midas``).
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

DATUM_M = np.array([0.25, -0.15, 0.20])
IMAGE_NOISE_UM = 3.84
GNSS_NOISE_M = np.array([0.03, 0.03, 0.05])


@pytest.fixture(scope="module")
def paper(tmp_path_factory):
    from skyrig.papers import runner

    out = tmp_path_factory.mktemp("paper004")
    return out, runner("004")(out, "ci")


def _table(res, key):  # type: ignore[no-untyped-def]
    (t,) = [t for t in res.tables if t.key == key]
    return {r[0]: dict(zip(t.columns, r)) for r in t.rows}


def test_table11_against_the_injected_truth(paper):
    _, res = paper
    t = _table(res, "table11")
    cols = [c for c in next(iter(t.values())) if c.endswith(" skyrig")]
    ba = [c for c in cols if c.startswith("ba-eo-control")]
    dg = [c for c in cols if c.startswith("dg-control")]
    ref = [c for c in cols if c.startswith("refine-eo-check")]
    assert len(ba) == len(dg) == len(ref) == 2  # the low and the high flight
    # sigma of the image measurements: the injected noise (thousands of redundant observations: a few % at most),
    # where the GNSS/IMU are weighted; fixed (direct georeferencing) their noise goes into the images (the paper's
    # pattern too: 8.2 / 6.5 um against 6.0 / 3.3 um)
    for c in ba + ref:
        assert t["sigma"][c] == pytest.approx(IMAGE_NOISE_UM, rel=0.12), (c, t["sigma"][c])
    for b, d in zip(ba, dg):
        assert t["sigma"][d] > 1.05 * t["sigma"][b]
    # the photo positions' residuals: at most the injected GNSS noise (the adjustment absorbs part of it)
    for c in ba + ref:
        for k, a in enumerate("XYZ"):
            assert 0.25 * GNSS_NOISE_M[k] < t[f"RMS photo position {a}"][c] < 1.3 * GNSS_NOISE_M[k]
    # the POSEO carries the datum shift: what the BA variant's block shift finds is small against the injected one
    for c in ba:
        shift = np.array([t[f"GPS block shift {a}"][c] for a in "XYZ"])
        assert np.linalg.norm(shift) < np.linalg.norm(DATUM_M) / 3, (c, shift)
    # the paper's printed Tab. 11 next to it
    paper_cols = [c for c in next(iter(t.values())) if c.endswith(" paper")]
    assert t["sigma"]["ba-eo-control low paper"] == 6.0 and t["GPS block shift Z"]["dg-control high paper"] == -0.458
    assert len(paper_cols) == len(cols)


def test_accuracy_statement_where_the_conditions_match(paper):
    _, res = paper
    comp = {c.quantity: c for c in res.comparisons}
    gsd = _table(res, "table11")["GSD"]
    low = [c for c in gsd if c.startswith("ba-eo-control") and c.endswith("skyrig")][0]
    assert gsd[low] == pytest.approx(100 * 0.0064 * 609.6 / 28.0, abs=0.006)  # the paper's 28 mm camera, 2,000 ft
    plan = comp["RMS check, planimetric (X, Y), low block, in GSD"]
    vert = comp["RMS check, vertical (Z), low block, in GSD"]
    assert plan.paper == 1.0 and vert.paper == 2.0
    assert plan.agrees and vert.agrees and plan.skyrig <= 1.0 and vert.skyrig <= 2.0
    assert comp["sigma of the image measurements, low block, BA + EO + control"].agrees
    for a in "ENU":
        assert comp[f"GNSS datum shift {a} minus the injected"].agrees


def test_poseo_file_closer_to_the_truth_than_the_uncorrected_orientations(paper):
    from skyrig.calibrate.calqc import midas_calqc_scenario
    from skyrig.georef.direct import direct_georeference
    from skyrig.io.eo_csv import read_eo_csv
    from skyrig.papers.p004 import poseo_errors

    out, res = paper
    assert (out / "poseo.csv").is_file() and (out / "poseo.csv.json").is_file()
    poseo = read_eo_csv(out / "poseo.csv")
    data, truth = midas_calqc_scenario("reduced", 1, tie_points=400, camera_width_px=400)
    frame = truth.survey.eo_true.frame
    raw = direct_georeference(data.trajectory, data.rig, data.events, frame)
    assert len(poseo) == len(raw) == len(truth.survey.eo_true)
    st = poseo_errors(poseo.to_frame(frame), raw, truth.survey.eo_true)
    n = len(poseo)
    datum = _table(res, "datum_shift")
    sigma = np.array([datum[a]["sigma (m)"] for a in "ENU"])
    # uncorrected: displaced by the injected datum shift (the GNSS noise averages over n images)
    np.testing.assert_allclose(st["uncorrected"]["mean_position_m"], DATUM_M, atol=0.002 + 3 * GNSS_NOISE_M.max()
                               / np.sqrt(n))
    # POSEO: only the datum shift's estimation error is left (its stated sigma) and the noise's mean
    assert np.all(np.abs(st["POSEO"]["mean_position_m"]) <= 3 * np.sqrt(sigma ** 2 + GNSS_NOISE_M ** 2 / n))
    # the expected amount: the RMS position error from |datum| (+ noise) down to the noise (+ the datum's sigma)
    expect_raw = np.sqrt(np.sum(DATUM_M ** 2 + GNSS_NOISE_M ** 2))
    expect_poseo = np.sqrt(np.sum(sigma ** 2 + GNSS_NOISE_M ** 2))
    assert st["uncorrected"]["rms_position_m"] == pytest.approx(expect_raw, rel=0.15)
    assert st["POSEO"]["rms_position_m"] < 1.3 * expect_poseo
    # attitudes: the uncorrected ones carry the injected boresights (each head's mean error is minus its
    # boresight), the POSEO's are calibrated: smaller by far
    for h, v in st["uncorrected"]["mean_rotation_mdeg"].items():
        np.testing.assert_allclose(v, -1000 * np.degrees(truth.boresight_rotvec_rad[h]), atol=4.0)
    assert st["POSEO"]["rms_attitude_mdeg"] < 0.5 * st["uncorrected"]["rms_attitude_mdeg"]


def test_oblique_mosaics_in_place_against_the_scene(paper):
    out, res = paper
    rows = _table(res, "oblique_mosaics")
    assert set(rows) == {"forward", "left"}
    for head, r in rows.items():
        assert r["texture tiles judged"] >= 4
        assert r["RMS offset (GSD)"] <= 0.5 and r["max offset (GSD)"] <= 1.0, r
        assert r["median colour error (DN)"] <= 4.0 and r["share of cells coloured"] > 0.9
    ok = [c for c in res.checks if c[0].startswith("oblique mosaic")]
    assert len(ok) == 2 and all(c[1] for c in ok)
    (fig,) = [f for f in res.figures if f.key == "oblique_mosaics"]
    img = cv2.imread(str(out / fig.path))
    assert img is not None and img.shape[1] > 400


@pytest.mark.slow
def test_cli_calqc_writes_the_poseo(tmp_path):
    """``skyrig calibrate calqc --poseo`` on the reduced flight written as a project: the EO CSV (+ side-car) holds
    every image, in the control points' CRS, closer to the true orientations than the injected datum shift."""
    from click.testing import CliRunner

    from skyrig.calibrate.calqc import midas_calqc_scenario
    from skyrig.cli import main
    from skyrig.io.eo_csv import read_eo_csv
    from skyrig.pipeline.simulate import write_project

    _, truth = midas_calqc_scenario("reduced", 1, tie_points=400, camera_width_px=400)
    d = tmp_path / "flight"
    write_project(truth.survey, d, images=False)
    r = CliRunner().invoke(main, [
        "calibrate", "calqc", "--trajectory", str(d / "trajectory.csv"), "--events", str(d / "events.csv"),
        "--rig", str(d / "rig.yaml"), "--measurements", str(d / "gcp" / "image_measurements.csv"),
        "--measurements", str(d / "tie" / "image_measurements.csv"), "--control", str(d / "gcp" / "ground_points.csv"),
        "--check", str(d / "gcp" / "check_points.csv"), "--gnss-sigma", "0.03,0.03,0.05", "--no-grid",
        "--no-design-study", "--no-variants", "-o", str(tmp_path / "cal" / "rig.yaml"),
        "--poseo", str(tmp_path / "cal" / "poseo.csv")])
    assert r.exit_code == 0, r.output
    poseo = read_eo_csv(tmp_path / "cal" / "poseo.csv")
    true = read_eo_csv(d / "truth" / "eo_map.csv")
    assert poseo.frame.crs == true.frame.crs and (tmp_path / "cal" / "poseo.csv.json").is_file()
    idx = {str(n): i for i, n in enumerate(true.image)}
    k = np.array([idx[str(n)] for n in poseo.image])
    assert len(k) == len(true)
    dp = poseo.centre - true.centre[k]
    assert np.sqrt(np.mean(np.sum(dp ** 2, 1))) < 0.35 * np.linalg.norm(DATUM_M)


def test_result_is_plain_data(paper):
    """The command writes the tables and values as JSON: plain Python values only."""
    import dataclasses
    import json

    _, res = paper
    json.loads(json.dumps(dataclasses.asdict(res), allow_nan=True))
