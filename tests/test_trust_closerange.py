"""Issue 29, close-range findings: a given non-OpenCV camera survives ``adjust-uav --no-gps``; data snooping's
cap scales with the block; feature downscaling per axis; LAS scan angle from nadir."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from skyrig.camera.brown import BrownDistortion
from skyrig.simulate.closerange import facade_set


def test_no_gps_keeps_a_brown_camera_when_self_calibration_is_off(tmp_path):
    """A calibrated Brown camera (k1 and b1) given with --camera comes back unchanged (was: OpenCV, all zeros)."""
    import yaml

    from skyrig.cli import main
    from skyrig.georef.observations import ImageMeasurements
    from skyrig.io.points_csv import write_measurements_csv
    from skyrig.io.rig_file import read_rig, write_rig
    from skyrig.rig.rig import Head, Rig

    s = facade_set(seed=2, n_points=300, n_per_row=6, width_px=1000, sigma_px=0.5, outlier_share=0.0)
    cam = s.camera.with_(distortion=BrownDistortion(k1=-2e-4, b1=1e-3))
    rng = np.random.default_rng(3)
    px = np.array([cam.project_pixels((s.X[p] - s.C[i]) @ s.R[i]) for p, i in zip(s.obs_point, s.obs_image)])
    px += rng.normal(0, 0.5, px.shape)
    proj = tmp_path / "p"
    (proj / "match").mkdir(parents=True)
    write_measurements_csv(proj / "match" / "tie_points.csv",
                           ImageMeasurements(s.point_name[s.obs_point], s.names[s.obs_image], px))
    write_rig(Rig("given", {"camera": Head("camera", cam)}), proj / "camera.yaml")
    idx = {n: k for k, n in enumerate(s.point_name)}
    (proj / "gcp.csv").write_text("# crs: local 48.85 2.35 35.0\nname,x,y,z\n" + "".join(
        f"{n},{s.X[idx[n]][0]:.4f},{s.X[idx[n]][1]:.4f},{s.X[idx[n]][2]:.4f}\n" for n in s.target_names))
    r = CliRunner().invoke(main, ["adjust-uav", str(proj), "--no-gps", "--no-self-calibration", "--camera",
                                  str(proj / "camera.yaml"), "--control", str(proj / "gcp.csv"), "--control-sigma",
                                  "0.002"])
    assert r.exit_code == 0, r.output
    out = read_rig(proj / "adjust-uav" / "camera.yaml")
    back = next(iter(out.heads.values())).camera
    assert isinstance(back.distortion, BrownDistortion), yaml.safe_load((proj / "adjust-uav" / "camera.yaml").read_text())
    np.testing.assert_allclose(back.distortion.params, cam.distortion.params, rtol=0, atol=1e-12)
    np.testing.assert_allclose(back.intrinsics, cam.intrinsics, rtol=0, atol=1e-12)
