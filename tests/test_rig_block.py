"""Rig blocks from the recorded flight (:func:`skyrig.adjust.rig_block.block_from_trajectory`).

Independent answer: the simulator's truth (:func:`skyrig.simulate.build_survey`, MIDAS penta rig with
boresight errors of 0.01-0.03 deg per head, GNSS 3 cm / IMU 0.003-0.006 deg noise).  Tie points are
random terrain points projected with the *true* orientations (0.3 px noise); the block is built from the
*recorded* trajectory and the nominal rig, and the adjustment must recover each head's true mounting
within its predicted precision (chi-square over all heads), on paper 004's MIDAS calibration flight
(two heights, opposite directions).  Measured: sigma0 1.000, chi-square 2.9 for 15 degrees of freedom
(the marginal sigmas are conservative here), against 21,000 for the nominal rig.
"""

from __future__ import annotations

import numpy as np
import pytest

from skyrig.adjust import AdjustConfig, adjust
from skyrig.adjust.config import Unknowns
from skyrig.adjust.block import BlockError
from skyrig.adjust.rig_block import block_from_trajectory
from skyrig.georef.direct import direct_georeference
from skyrig.georef.ground import world_to_image
from skyrig.georef.observations import GroundPoints, ImageMeasurements
from skyrig.geometry.rotations import matrix_from_rotvec, rotvec_from_matrix
from skyrig.simulate.scenarios import build_survey, scenario_spec

SIGMA_PX = 0.3


@pytest.fixture(scope="module")
def survey():  # type: ignore[no-untyped-def]
    return build_survey(scenario_spec("midas-demo", "ci", 1))


@pytest.fixture(scope="module")
def block_survey():  # type: ignore[no-untyped-def]
    """Paper 004's MIDAS calibration flight (90 exposures, 450 images, two heights, opposite directions)."""
    return build_survey(scenario_spec("midas", "full", 1))


def _measurements(sv, n: int = 4000, seed: int = 3) -> ImageMeasurements:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(seed)
    eo = sv.eo_true
    cams = {h.camera.name: h.camera for h in sv.rig_true}
    lo, hi = eo.centre[:, :2].min(axis=0) - 600, eo.centre[:, :2].max(axis=0) + 600
    xy = rng.uniform(lo, hi, (n, 2))
    z = sv.scene.terrain_height(xy[:, 0], xy[:, 1])
    X = np.column_stack([xy, z])
    names = np.array([f"p{k}" for k in range(n)])
    pt, im, px = [], [], []
    for i, img in enumerate(eo.image):
        uv = world_to_image(eo, cams, np.full(n, img), X, eo.frame)
        cam = cams[str(eo.camera[i])]
        ok = np.isfinite(uv).all(axis=1) & (uv[:, 0] > 0) & (uv[:, 1] > 0) & (uv[:, 0] < cam.width - 1) & (
            uv[:, 1] < cam.height - 1)
        pt.append(names[ok]), im.append(np.full(ok.sum(), img)), px.append(uv[ok])
    pix = np.vstack(px)
    m = sv.measurements
    return ImageMeasurements(np.concatenate(pt + [m["point"]]), np.concatenate(im + [m["image"]]),
                             np.vstack([pix + rng.normal(0, SIGMA_PX, pix.shape), m["pixel"]]))


def test_true_flight_reproduces_true_orientations(survey) -> None:  # type: ignore[no-untyped-def]
    sv = survey
    m = _measurements(sv, 600)
    b, frame = block_from_trajectory(sv.trajectory_true, sv.rig_true, sv.events_true, m, frame=sv.frame)
    assert b.n_stations == len(np.unique(sv.events_true.exposure_id)) and b.n_images == len(sv.eo_true)
    R_s = b.station_rotation[b.image_station]
    C = b.station_centre[b.image_station] + np.einsum("nij,nj->ni", R_s, b.image_offset)
    idx = sv.eo_true.index()
    rows = [idx[n] for n in b.image_name]
    assert np.abs(C - sv.eo_true.centre[rows]).max() < 1e-4
    assert np.abs(R_s @ b.image_rotation - sv.eo_true.rotation[rows]).max() < 1e-8


def test_boresights_recovered_within_predicted_sigma(block_survey) -> None:  # type: ignore[no-untyped-def]
    sv = block_survey
    err = sv.spec.errors
    m = _measurements(sv, 6000)
    ctrl = GroundPoints(sv.gcp_names, sv.gcp_surveyed, sv.frame)
    checks = tuple(str(n) for n, c in zip(sv.gcp_names, sv.gcp_is_check) if c)
    b, frame = block_from_trajectory(sv.trajectory_recorded, sv.rig_recorded, sv.events_recorded, m, ctrl,
                                     check_points=checks, frame=sv.frame, sigma_px=SIGMA_PX,
                                     gnss_sigma_m=err.gnss_noise_m, imu_sigma_rad=err.imu_noise_rad,
                                     control_sigma_m=0.01)
    res = adjust(b, AdjustConfig(unknowns=Unknowns(boresight="free")))
    assert 0.8 < res.sigma0 < 1.2
    sig = res.sigma_reduced()
    chi2, chi2_nominal, dof = 0.0, 0.0, 0
    for h, name in enumerate(res.block.head_name):
        R_nom = sv.rig_recorded.head(str(name)).body_from_camera().rotation
        R_true = sv.rig_true.head(str(name)).body_from_camera().rotation
        truth = rotvec_from_matrix(R_nom.T @ R_true)
        est = res.block.head_boresight[h]
        s = np.array([sig[k] for k in sig if k[0] == "boresight" and k[1] == str(name)])
        assert s.shape == (3,), sig.keys()
        # the boresight is a rotation vector in the camera frame, applied as R_nom @ expmap(b)
        assert np.abs(rotvec_from_matrix(matrix_from_rotvec(est).T @ matrix_from_rotvec(truth))).max() < 5 * s.max()
        chi2 += float(np.sum(((est - truth) / s) ** 2))
        chi2_nominal += float(np.sum((truth / s) ** 2))
        dof += 3
    print(f"sigma0 {res.sigma0:.3f} chi2 {chi2:.1f} nominal {chi2_nominal:.1f} ({dof} dof)")
    assert chi2_nominal > 100.0, chi2_nominal  # the test has power: the nominal rig is far off
    assert chi2 < 37.7, chi2  # chi-square 99.9 % for 15 degrees of freedom (correlations ignored: conservative)


def test_one_exposure_images_at_different_times_rejected(survey) -> None:  # type: ignore[no-untyped-def]
    sv = survey
    from dataclasses import replace

    ev = sv.events_true
    t = np.array(ev.time_s, dtype=float).copy()
    t[1] += 0.05
    bad = replace(ev, time_s=t)
    with pytest.raises(BlockError, match="apart"):
        block_from_trajectory(sv.trajectory_true, sv.rig_true, bad, _measurements(sv, 300), frame=sv.frame)
