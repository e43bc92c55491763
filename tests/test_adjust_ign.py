"""The real IGN 68-image block (../shared/data/ign-aerial-block/block805) adjusted by skyrig.

Independent answer: IGN's own adjusted tie-point ground coordinates (``all_liaisons2_world.mes``) and
exposure orientations (``23FD1305_alt_2.OPK``).  IGN's orientations enter as GNSS/IMU observations;
the adjustment starts from them perturbed by 3 m and 0.2 deg (1 sigma) and must converge back.
GSD 5.7 cm.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skyrig.adjust import AdjustConfig, adjust
from conftest import shared_path
from skyrig.adjust.frames import block_from_georef, eo_from_block, points_to_frame
from skyrig.georef.ign_block import IgnConventions
from skyrig.georef.observations import ImageMeasurements
from skyrig.geometry.rotations import matrix_from_rotvec
from skyrig.io.ign import read_ign_camera, read_ign_ground_points, read_ign_measurements, read_ign_opk

GSD = 0.057


def _load(d):
    conv = IgnConventions(geoid=str(d / "dataset" / "fr_ign_RAF20.tif"))
    eo = conv.reduce(read_ign_opk(d / "block805" / "23FD1305_alt_2.OPK", conv.eo_frame))
    cams = {c.name: c for c in (read_ign_camera(d / "dataset" / f"Camera{i}.txt") for i in (1, 2))}
    tie = read_ign_measurements(d / "block805" / "all_liaisons2.mes")
    gcpm = read_ign_measurements(d / "block805" / "all_terrains2.mes")
    m = ImageMeasurements(np.concatenate([tie.point, gcpm.point]), np.concatenate([tie.image, gcpm.image]),
                          np.concatenate([tie.pixel, gcpm.pixel]))
    gcp = read_ign_ground_points(d / "block805" / "23FD1305_Biais2.app", conv.ground_frame)
    world = read_ign_ground_points(d / "block805" / "all_liaisons2_world.mes", conv.ground_frame)
    return conv, eo, cams, m, gcp, world


@pytest.fixture(scope="module")
def ign():
    conv, eo, cams, m, gcp, world = _load(shared_path("ign-aerial-block"))
    rng = np.random.default_rng(0)
    n = len(eo)
    start = replace(eo, centre=eo.centre + rng.normal(0, 3.0, (n, 3)),
                    rotation=eo.rotation @ matrix_from_rotvec(rng.normal(0, np.radians(0.2), (n, 3))))
    # realistic GNSS/IMU sigma (post-processed GNSS 5 cm, POS AV class IMU 0.0025 deg)
    block, frame = block_from_georef(eo, cams, m, gcp, start_eo=start, gnss_sigma_m=0.05,
                                     imu_sigma_rad=np.radians(0.0025), control_sigma_m=0.02, sigma_px=0.15)
    res = adjust(block, AdjustConfig())
    return conv, eo, world, block, frame, res


def _tie_differences(conv, world, frame, res):
    idx = {p: k for k, p in enumerate(res.block.point_name)}
    sel = np.array([p in idx for p in world.name])
    k = np.array([idx[p] for p in world.name[sel]])
    xyz = points_to_frame(res.block.point_xyz[k], frame, conv.ground_frame)
    return xyz - world.xyz[sel], k


def test_ign_block_converges_with_small_image_residuals(ign):
    conv, eo, world, block, frame, res = ign
    assert block.n_images == 68 and block.n_observations > 14000
    assert res.info.converged and res.info.iterations < 20
    rms = np.sqrt(np.mean(res.residuals["image"].residual ** 2, axis=0))
    assert np.all(rms <= 0.3), rms
    assert 0.7 < res.sigma0 < 1.5  # image sigma 0.15 px a priori


def test_ign_tie_points_agree_with_ign_within_predicted_precision(ign):
    """Planimetry within 0.5 GSD RMS per axis.  Heights: this 68-image sub-block with realistic GNSS/IMU
    sigma determines tie-point heights to about 0.9 GSD (the adjustment's own prediction), so the
    height differences to IGN must match that prediction rather than 0.5 GSD."""
    conv, eo, world, block, frame, res = ign
    d, k = _tie_differences(conv, world, frame, res)
    assert len(d) > 2900
    rms = np.sqrt(np.mean(d**2, axis=0))
    assert np.all(rms[:2] <= 0.5 * GSD), rms / GSD
    pred = np.sqrt(np.mean(res.point_sigma[k] ** 2, axis=0))
    ratio = rms / pred
    assert np.all((ratio > 0.6) & (ratio < 1.5)), (rms / GSD, pred / GSD)


def test_ign_adjusted_eo_close_to_ign(ign):
    conv, eo, world, block, frame, res = ign
    adj = eo_from_block(res.block, frame, conv.eo_frame)
    idx = eo.index()
    rows = [idx[i] for i in adj.image]
    dc = adj.centre - eo.centre[rows]
    # started 3 m off; back to IGN's values: the differences are the GNSS residuals, whose RMS must stay
    # within twice the a-priori sigma (5 cm) times sigma0
    assert np.all(np.sqrt(np.mean(dc**2, axis=0)) < 2 * 0.05 * res.sigma0)
    dR = np.swapaxes(eo.rotation[rows], 1, 2) @ adj.rotation
    ang = np.arccos(np.clip((np.trace(dR, axis1=1, axis2=2) - 1) / 2, -1, 1))
    assert np.degrees(np.sqrt(np.mean(ang**2))) < 2 * 0.0025 * np.sqrt(3) * res.sigma0
