"""Report tables, presets and the ``skyrig adjust`` command on a seeded synthetic block.

Independent answers: control/check table values against the adjusted block and the given coordinates
computed here directly, check-point errors against the simulation's truth scale (predicted sigma),
and the presets' definitions (paper 004: DG holds the orientations; "refine EO" turns all control
into check points)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from skyrig.adjust import adjust
from skyrig.adjust.presets import apply_preset
from skyrig.adjust.report import adjustment_report
from skyrig.adjust.synthetic import synthetic_block
from skyrig.cli.adjust import command
from skyrig.io.block_file import write_block


@pytest.fixture(scope="module")
def blk():
    b, truth = synthetic_block(seed=2, n_strips=2, n_per_strip=6, n_points=200, n_control=6)
    b.control_check[-2:] = True
    return b, truth


def test_control_and_check_tables(blk):
    b, truth = blk
    b2, cfg = apply_preset(b, "ba-eo-control")
    cfg = cfg.with_reliability(snooping=False)
    res = adjust(b2, cfg)
    rep = adjustment_report(res, gsd_m=0.016, limits_m=(0.1, 0.1, 0.1))
    cp, chk = b.control_point, b.control_check
    v = res.block.point_xyz[cp] - b.control_xyz
    assert [r["point"] for r in rep["check"]["rows"]] == list(b.point_name[cp[chk]])
    np.testing.assert_allclose([[r["VX"], r["VY"], r["VZ"]] for r in rep["check"]["rows"]], v[chk])
    np.testing.assert_allclose(rep["control"]["stats"]["rms_m"], np.sqrt(np.mean(v[~chk] ** 2, axis=0)))
    np.testing.assert_allclose(rep["control"]["stats"]["rms_gsd"], np.sqrt(np.mean(v[~chk] ** 2, axis=0)) / 0.016)
    assert rep["check"]["stats"]["within_limits"] == bool(np.all(np.abs(v[chk]) <= 0.1))
    # check-point errors are consistent with the predicted point sigma plus the given sigma (2 cm)
    sig = np.sqrt(res.point_sigma[cp[chk]] ** 2 + b.control_sigma[chk] ** 2)
    assert np.all(np.abs(v[chk]) < 5 * sig)
    gn = res.residuals["gnss"].residual
    np.testing.assert_allclose(rep["orientation"]["gnss_rms_m"], np.sqrt(np.mean(gn**2, axis=0)))
    assert set(rep["images"]) == {c.name for c in b.cameras}


def test_presets(blk):
    b, _ = blk
    b_dg, cfg_dg = apply_preset(b, "dg-control")
    res = adjust(b_dg, cfg_dg)
    np.testing.assert_array_equal(res.block.station_centre, b.station_centre)  # orientations held
    b_ref, cfg_ref = apply_preset(b, "refine-eo-check")
    assert b_ref.control_check.all() and not b.control_check[:-2].any()
    assert cfg_ref.unknowns.datum_shift == "fixed" and cfg_dg.unknowns.poses == "fixed"
    with pytest.raises(ValueError, match="unknown preset"):
        apply_preset(b, "nope")


def test_cli_writes_outputs(blk, tmp_path):
    b, _ = blk
    write_block(tmp_path / "in" / "block.json", b)
    r = CliRunner().invoke(command, [str(tmp_path / "in" / "block.json"), "--preset", "refine-eo-check",
                                     "-o", str(tmp_path / "out")])
    assert r.exit_code == 0, r.output
    rep = json.loads((tmp_path / "out" / "report.json").read_text())
    assert len(rep["check"]["rows"]) == len(b.control_point) and not rep["control"]["rows"]
    assert (tmp_path / "out" / "report.html").read_text().startswith("<!DOCTYPE html>")
    # one self-contained page (skyrig.report): plots embedded, no separate PNG files
    assert "data:image/png;base64," in (tmp_path / "out" / "report.html").read_text()
    assert not list((tmp_path / "out").glob("residuals_*.png"))
    assert (tmp_path / "out" / "adjusted.json").exists()
    # bad block: clear error, not a traceback
    (tmp_path / "in" / "block_observations.csv").write_text("point,image,col_px,row_px\np0,ghost,1,2\n")
    r = CliRunner().invoke(command, [str(tmp_path / "in" / "block.json"), "-o", str(tmp_path / "o2")])
    assert r.exit_code != 0 and "unknown image 'ghost'" in str(r.exception)
