"""strecha-entry-p10 (10 real images of a building entrance, no EXIF, ground-truth K, R, C; issue 28): skyrig's
orientation without GNSS from the images alone, self-calibrating the camera from the weak default prior (1.2 x the
image width, 50 %), judged absolutely against the ground truth, and against pycolmap's own pipeline on the same
images in the same run.  ``bench/real.py --datasets strecha`` prints the same figures at 1,600 px."""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))


@pytest.mark.slow  # matching 10 x 6 MP images and pycolmap's reconstruction: about 2 minutes
def test_strecha_self_calibration_and_orientation_against_ground_truth(tmp_path):
    from conftest import shared_path

    pytest.importorskip("pycolmap")
    import real

    from skyrig.cli.match import match_images
    from skyrig.match.features import FeatureConfig
    from skyrig.match.matching import MatchConfig
    from skyrig.pipeline.uav import orient_without_gnss

    folder = shared_path("strecha-entry-p10")
    images = folder / "images"
    gt = real.read_strecha_cameras(folder)
    size = 1600
    match_images([images], tmp_path / "match", FeatureConfig(method="pycolmap", max_size=size, max_features=8000),
                 MatchConfig(matcher="bruteforce", threshold_scale=3072 / size), pair_mode="exhaustive")
    res, _ = orient_without_gnss(images, tmp_path / "match", None)
    assert res.oriented.all()
    cam = res.camera
    f = cam.focal_mm / cam.pixel_size_mm
    assert abs(f / 2759.5 - 1) < 0.005, f
    K = np.mean([g["K"] for g in gt.values()], axis=0)
    pp = cam.principal_point_px
    assert np.hypot(pp[0] - K[0, 2], pp[1] - K[1, 2]) < 10.0, (pp, K[:2, 2])
    names = [str(n).split(".")[0] for n in res.names]
    cv = np.diag([1.0, -1.0, -1.0])
    sky = real.compare_with_truth(names, res.centre, res.rotation @ cv, gt)
    from skyrig.match.colmap_check import reconstruct_with_pycolmap

    rec, _ = reconstruct_with_pycolmap(images, [f"{n}.jpg" for n in names], tmp_path / "colmap", max_image_size=size,
                                       max_features=8000)
    assert rec is not None
    pn, pc, pr = [], [], []
    for img in rec.images.values():
        if img.has_pose:
            pn.append(img.name.split(".")[0])
            pc.append(np.asarray(img.projection_center()))
            pr.append(np.asarray(img.cam_from_world().rotation.matrix()).T)
    col = real.compare_with_truth(pn, np.array(pc), np.array(pr), gt)
    logging.getLogger(__name__).info("skyrig %s pycolmap %s", sky, col)
    assert sky["centre_rms_m"] <= 1.5 * col["centre_rms_m"], (sky, col)
    # the issue's goal is 0.05 deg.  After the centres' similarity: 0.092 (pycolmap 0.44), of which 0.082 is the
    # similarity's own rotation error (10 nearly coplanar centres, mm of centre error, common to every image);
    # after the rotations' own best common rotation: 0.042 (pycolmap 0.18)
    assert sky["rotation_rms_deg"] < 0.12 and sky["rotation_rms_deg"] < col["rotation_rms_deg"], (sky, col)
    assert sky["rotation_rms_own_alignment_deg"] <= 0.05, sky
    assert sky["rotation_rms_own_alignment_deg"] < col["rotation_rms_own_alignment_deg"], (sky, col)
    # one similarity fitted to the whole poses (centres and rotations, nominal weights 1 cm / 0.05 deg for both
    # programs): centres and rotations judged after the same transform.  Measured: bench/real.py 0.0109 m /
    # 0.043 deg (pycolmap 0.042 m / 0.23 deg); this test's own run 0.0113 m / 0.0507 deg: at the 0.05 deg,
    # on one side or the other depending on the run's matches (issue 28 stays open on this line).  Guarded here
    # against regressions at 0.06 deg, and against pycolmap's
    ps, pc_ = sky["pose_similarity"], col["pose_similarity"]
    assert ps["centre_rms_m"] <= 1.5 * pc_["centre_rms_m"], (ps, pc_)
    assert ps["rotation_rms_deg"] <= 0.06 and ps["rotation_rms_deg"] < pc_["rotation_rms_deg"], (ps, pc_)

