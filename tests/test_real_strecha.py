"""strecha-entry-p10 (10 real images of a building entrance, no EXIF, ground-truth K, R, C; issue 28): skyrig's
orientation without GNSS from the images alone, self-calibrating the camera from the weak default prior (1.2 x the
image width, 50 %), judged absolutely against the ground truth, and against pycolmap's own pipeline on the same
images in the same run.  The test runs ``bench/real.py``'s strecha part itself (``skyrig match`` with the CLI's
defaults at 1,600 px, then the library), so that the bench and the test measure the same thing."""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))


@pytest.mark.slow  # matching 10 x 6 MP images, two orientations and pycolmap's reconstruction: about 3 minutes
def test_strecha_self_calibration_and_orientation_against_ground_truth(tmp_path):
    from conftest import shared_path

    pytest.importorskip("pycolmap")
    import real

    folder = shared_path("strecha-entry-p10")
    out = real.strecha(folder.parent, tmp_path, 1600)
    logging.getLogger(__name__).info("strecha %s", out)
    assert out["oriented"] == out["images"] == 10
    assert abs(out["focal_px"] / 2759.5 - 1) < 0.005, out["focal_px"]
    assert out["pp_error_px"] < 10.0, (out["pp_px"], out["pp_gt_px"])
    # the self-calibrated principal point within 3 of its own predicted sigmas of the ground truth's
    d = np.subtract(out["pp_px"], out["pp_gt_px"])
    assert np.all(np.abs(d) < 3.0 * np.asarray(out["pp_sigma_px"])), (d, out["pp_sigma_px"])
    sky, col, kk = out["skyrig"], out["pycolmap"], out["skyrig_known_k"]
    assert sky["centre_rms_m"] <= 1.5 * col["centre_rms_m"], (sky, col)
    assert sky["rotation_rms_deg"] < col["rotation_rms_deg"], (sky, col)
    ps, pc_ = sky["pose_similarity"], col["pose_similarity"]
    assert ps["centre_rms_m"] <= 1.5 * pc_["centre_rms_m"], (ps, pc_)
    assert ps["rotation_rms_deg"] < pc_["rotation_rms_deg"], (ps, pc_)
    assert sky["rotation_rms_own_alignment_deg"] < col["rotation_rms_own_alignment_deg"], (sky, col)

    # What limits the rotations (issue 28's 0.05 deg line stays open, see below).  The same tie points oriented with
    # the camera held at the ground truth's own K: one-similarity rotation RMS 0.042-0.045 deg on seven tie-point
    # sets (COLMAP SIFT at 1,600 px with FLANN and brute force and at full resolution, OpenCV SIFT at full
    # resolution, two disjoint halves of the tracks), with the same per-image pattern, ten times its random part
    # predicted from the adjustment's covariance (0.003-0.004 deg): a systematic difference between these images
    # and the ground truth that no self-calibration and no matching choice causes.  The ground-truth poses miss
    # the tie points' best fit (plain pinhole, the ground truth's K) by delta chi2 2,839-4,782 where 53 (6 x 10 - 7
    # pose unknowns) would be expected of exact poses: 7-9.5 formal sigmas per unknown, along the block's weakest
    # pose mode (the rotation differences follow the centre differences, 8 mm RMS, with correlation 0.98 / -0.91
    # and lever arms of 12-21 m: each camera turned about a point in front of it).
    floor, pk = kk["pose_similarity"]["rotation_rms_deg"], kk["predicted"]
    assert floor > 5.0 * pk["rotation_rms_deg"], kk
    tc = kk["truth_consistency"]
    assert tc["delta_chi2"] > 10 * tc["expected_delta_chi2"], tc
    assert tc["sigma_px"] < tc["sigma_with_truth_px"], tc
    # The self-calibration then costs no more than its own predicted random part (3 sigma, in quadrature) on top of
    # that floor, for both rotation figures.  Measured (one similarity of the poses): 0.040 deg with the CLI's FLANN
    # matches, 0.051 with brute-force ones, 0.041 at full resolution (predicted random part 0.0145 deg, 90 %:
    # 0.024; the principal point's sigma 1.0-1.3 px is 0.02-0.03 deg of rotation): on one side of 0.05 deg or the
    # other depending on the matches, so the line is reported by bench/real.py, not asserted here.
    pr = sky["predicted"]
    assert ps["rotation_rms_deg"] ** 2 <= floor ** 2 + (3.0 * pr["rotation_rms_deg"]) ** 2, (ps, kk, pr)
    own_floor = kk["rotation_rms_own_alignment_deg"]
    assert sky["rotation_rms_own_alignment_deg"] ** 2 <= (own_floor ** 2
                                                         + (3.0 * pr["rotation_rms_own_alignment_deg"]) ** 2), (sky, kk)
