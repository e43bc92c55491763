"""pycolmap on skyrig's own tie points (:func:`skyrig.orient.reference.compare_on_same_tracks`, what ``skyrig
adjust-uav --compare-pycolmap --pycolmap-input tracks`` runs) for a GNSS-supported block: the input is a
:class:`skyrig.orient.gnss_block.UavBlockInput` (GNSS instead of approximate positions).

Independent answers: the seeded simulation of tests/test_uav_adjust.py (GNSS noise 0.5, 0.5, 1.0 m, 21 images), so a
similarity of either program's centres onto the GNSS leaves the GNSS noise: a 3D RMS of
sqrt((0.25 + 0.25 + 1) * (63 - 7) / 63) = 1.15 m (63 coordinates, 7 similarity parameters), within the chi-square band
of 56 degrees of freedom (+-30 %, about 3 sigma); and the two programs, solving the same measurements, agree far below
skyrig's predicted sigma.  (The façade without GNSS, through the command: tests/test_project_orientation.py.)
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest


def test_compare_on_same_tracks_with_gnss(tmp_path: Path) -> None:
    pytest.importorskip("pycolmap")
    from test_uav_adjust import _sim_block

    from skyrig.orient.reference import compare_on_same_tracks
    from skyrig.pipeline.orientation import failure_reasons
    from skyrig.pipeline.uav import UavConfig, adjust_uav_block

    inp, truth = _sim_block(n_points=500)
    res = adjust_uav_block(inp, UavConfig(gnss_sigma_m=(0.5, 0.5, 1.0), pixel_sigma_px=0.3, attitude_sigma_deg=5.0,
                                          pnp_threshold_px=4.0))
    assert failure_reasons(res.adjustment) == [] and res.oriented.all()
    rep = compare_on_same_tracks(res, inp, tmp_path)
    assert rep["input"] == "tracks" and rep["registered"] == len(inp.names), rep
    c = rep["centre_differences"]
    assert c["common"] == len(inp.names)
    expected = math.sqrt((0.25 + 0.25 + 1.0) * (63 - 7) / 63)
    for key in ("ours_gnss_similarity_rms_3d_m", "other_gnss_fit_rms_3d_m"):  # GNSS found (UavBlockInput.gnss)
        assert 0.7 * expected < c[key] < 1.3 * expected, (key, c[key], expected)
    # the same measurements: the difference is far below the predicted sigma (here dominated by the GNSS datum)
    sig = np.linalg.norm(res.adjustment.pose_sigma[:, :3], axis=1)
    assert c["normalised_max"] < 1.0 and c["rms_m"] < np.sqrt(np.mean(sig ** 2)), c
    assert c["max_m"] > 0
