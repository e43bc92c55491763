"""The real IGN 68-image block (../shared/data/ign-aerial-block/block805) adjusted by skyrig.

Independent answer: IGN's own adjusted tie-point ground coordinates (``all_liaisons2_world.mes``) and
exposure orientations (``23FD1305_alt_2.OPK``).  IGN's orientations enter as GNSS/IMU observations;
the adjustment starts from them perturbed by 3 m and 0.2 deg (1 sigma) and must converge back.
GSD 5.7 cm.

How the weights were chosen (variance component estimation, :mod:`skyrig.adjust.vce`)
------------------------------------------------------------------------------------
The "GNSS/IMU" observations are IGN's *adjusted* orientations, so their realistic sigma is that of an
adjusted EO, not of a raw GNSS/IMU system.  Starting from 15 cm px / 5 cm / 0.0025 deg / 5 cm, Förstner's
iteration (``estimate_variance_components``; horizontal and vertical components for GNSS and control)
converges in about 11 adjustments to::

    image 0.183 px    GNSS 4.3 cm horizontal, 0.83 cm vertical    IMU 0.0013 deg    GCP 3.2 cm

(rerun: ``.venv/bin/python tests/test_adjust_ign.py``).  The test uses these weights and checks that
the data still support them (every group's variance factor within 15 % of 1).  The 2 cm GCP sigma
used before was too tight: GCP 1005 disagrees with IGN's orientations by about 5 cm E / 7 cm up, and
the VCE puts the GCP sigma at 3.2 cm.

Refraction
----------
Projecting IGN's ground points with IGN's orientations leaves a radial pattern in the residuals:
IGN's measurements carry an outward radial displacement ``K (r + r^3/f^2)`` with K = 8.9 +- 0.4
microradians (about half of the standard-atmosphere value, 18 microradians at 1.8 km), i.e. IGN's
imaging model includes atmospheric refraction.  Without it, heights intersected with IGN's fixed
orientations are biased by +0.32 GSD; with it by +0.01 GSD.  K is fitted here from IGN's own
orientations and points (like the frame conventions of ``test_ign_block.py``) and removed from the
measurements before the adjustment.

Heights: what is and is not met
-------------------------------
With these weights the tie points agree with IGN's to 0.33 / 0.22 GSD (X / Y) and 0.77 GSD in
height, matching the adjustment's *own predicted* sigma (0.88 GSD RMS): a 68-image sub-block whose
orientations are known to 4 cm / 0.0013 deg cannot fix single tie-point heights (base/height 0.2, many
2- and 3-ray points) better than that, while IGN's heights come from an 805-image triangulation.
Holding IGN's orientations fixed gives 0.29 GSD.  Much tighter weights (GNSS 5 mm, IMU 0.0002 deg,
plausible for an adjusted attitude from ~200 tie points per image) give 0.45 GSD and per-group
variance factors of 1.14 (GNSS) and 1.03 (IMU), which with ~50 redundancy per component is not a
significant rejection; but the VCE iteration started there drifts back to the 4 cm / 0.0013 deg fixed
point (the variance function is flat along the GNSS-position / attitude correlation, which this
sub-block cannot resolve).  The principled choice is the VCE fixed point, so the 0.5 GSD height target
is not claimed; the test checks the honest figure against the predicted precision.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from conftest import shared_path
from skyrig.adjust import AdjustConfig, adjust
from skyrig.adjust.corrections import fit_radial_scale, remove_refraction
from skyrig.adjust.frames import block_from_georef, eo_from_block, points_to_frame
from skyrig.georef.ground import world_to_image
from skyrig.georef.ign_block import IgnConventions
from skyrig.georef.observations import ImageMeasurements
from skyrig.geometry.rotations import matrix_from_rotvec, rotvec_from_matrix
from skyrig.io.ign import read_ign_camera, read_ign_ground_points, read_ign_measurements, read_ign_opk

GSD = 0.057
#: weights from variance component estimation (module docstring)
SIGMA_PX = 0.183
GNSS_SIGMA_M = (0.043, 0.043, 0.0083)
IMU_SIGMA_DEG = 0.0013
GCP_SIGMA_M = 0.032


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


def ign_refraction(eo, cams, m, world):
    """K (rad) and its sigma of the radial displacement in IGN's tie measurements (single camera)."""
    idx = world.index()
    sel = np.array([p in idx for p in m.point])
    px = world_to_image(eo, cams, m.image[sel], world.xyz[[idx[p] for p in m.point[sel]]], world.frame)
    (cam,) = cams.values() if len(cams) == 1 else [cams[eo.camera[eo.index()[m.image[0]]]]]
    return fit_radial_scale(px - m.pixel[sel], m.pixel[sel], cam)


def ign_block(d, sigma_px=SIGMA_PX, gnss=GNSS_SIGMA_M, imu_deg=IMU_SIGMA_DEG, gcp_sigma=GCP_SIGMA_M, seed=0):
    """The IGN block with refraction removed and perturbed starting orientations."""
    conv, eo, cams, m, gcp, world = _load(d)
    used = {eo.camera[eo.index()[i]] for i in np.unique(m.image)}
    cams = {c: cams[c] for c in used}
    k, k_sigma = ign_refraction(eo, cams, m, world)
    (cam,) = cams.values()
    m = ImageMeasurements(m.point, m.image, remove_refraction(m.pixel, cam, k))
    rng = np.random.default_rng(seed)
    n = len(eo)
    start = replace(eo, centre=eo.centre + rng.normal(0, 3.0, (n, 3)),
                    rotation=eo.rotation @ matrix_from_rotvec(rng.normal(0, np.radians(0.2), (n, 3))))
    block, frame = block_from_georef(eo, cams, m, gcp, start_eo=start, gnss_sigma_m=gnss,
                                     imu_sigma_rad=np.radians(imu_deg), control_sigma_m=gcp_sigma, sigma_px=sigma_px)
    return conv, eo, world, block, frame, (k, k_sigma)


@pytest.fixture(scope="module")
def ign():
    conv, eo, world, block, frame, k = ign_block(shared_path("ign-aerial-block"))
    res = adjust(block, AdjustConfig())
    return conv, eo, world, block, frame, res, k


def _tie_differences(conv, world, frame, res):
    idx = {p: k for k, p in enumerate(res.block.point_name)}
    sel = np.array([p in idx for p in world.name])
    k = np.array([idx[p] for p in world.name[sel]])
    xyz = points_to_frame(res.block.point_xyz[k], frame, conv.ground_frame)
    return xyz - world.xyz[sel], k


def test_ign_measurements_carry_refraction(ign):
    """The radial displacement is significant (> 10 sigma) and of the size of atmospheric refraction
    (positive, below the 18 microradian standard-atmosphere value at 1.8 km flying height)."""
    k, k_sigma = ign[-1]
    assert k > 10 * k_sigma
    assert 3e-6 < k < 18e-6


def test_ign_block_converges_with_small_image_residuals(ign):
    conv, eo, world, block, frame, res, _ = ign
    assert block.n_images == 68 and block.n_observations > 14000
    assert res.info.converged and res.info.iterations < 20
    rms = np.sqrt(np.mean(res.residuals["image"].residual ** 2, axis=0))
    assert np.all(rms <= 0.3), rms
    assert abs(res.sigma0 - 1.0) < 0.1


def test_ign_weights_are_supported_by_variance_components(ign):
    """The VCE weights of the module docstring still fit: each group's variance factor is 1 +- 15 %."""
    res = ign[5]
    for g in ("image", "gnss", "imu", "control"):
        assert 0.85 < res.groups[g].sigma0 < 1.15, (g, res.groups[g].sigma0)


def test_ign_tie_points_agree_with_ign(ign):
    """Planimetry within 0.5 GSD RMS per axis; heights agree with IGN to the adjustment's own predicted
    precision (module docstring: 0.5 GSD in height is not reachable from this sub-block)."""
    conv, eo, world, block, frame, res, _ = ign
    d, k = _tie_differences(conv, world, frame, res)
    assert len(d) > 2900
    rms = np.sqrt(np.mean(d**2, axis=0))
    assert np.all(rms[:2] <= 0.5 * GSD), rms / GSD
    assert rms[2] <= 1.0 * GSD, rms / GSD
    pred = np.sqrt(np.mean(res.point_sigma[k] ** 2, axis=0))
    ratio = rms / pred
    assert np.all((ratio > 0.6) & (ratio < 1.4)), (rms / GSD, pred / GSD)


def test_ign_adjusted_eo_close_to_ign(ign):
    conv, eo, world, block, frame, res, _ = ign
    adj = eo_from_block(res.block, frame, conv.eo_frame)
    idx = eo.index()
    rows = [idx[i] for i in adj.image]
    dc = frame.from_ecef(adj.frame.to_ecef(adj.centre)) - frame.from_ecef(eo.frame.to_ecef(eo.centre[rows]))
    # started 3 m off; back to IGN's values within about the GNSS sigma per axis (they are its residuals)
    rms = np.sqrt(np.mean(dc**2, axis=0))
    assert np.all(rms < 1.5 * np.array(GNSS_SIGMA_M)), rms
    ang = np.linalg.norm(rotvec_from_matrix(np.swapaxes(eo.rotation[rows], 1, 2) @ adj.rotation), axis=1)
    assert np.degrees(np.sqrt(np.mean(ang**2))) < 1.5 * IMU_SIGMA_DEG * np.sqrt(3)


if __name__ == "__main__":  # rerun the variance component estimation of the module docstring
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from skyrig.adjust.vce import estimate_variance_components

    d = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "ign-aerial-block"
    conv, eo, world, block, frame, k = ign_block(d, 0.15, 0.05, 0.0025, 0.05)
    print(f"refraction K = {k[0] * 1e6:.2f} +- {k[1] * 1e6:.2f} microradians")
    vc = estimate_variance_components(block, callback=lambda i, f: print(i, {a: round(b, 3) for a, b in f.items()}))
    print("converged", vc.converged, {a: (round(b, 5) if "imu" not in a else f"{np.degrees(b):.5f} deg")
                                      for a, b in vc.sigma.items()})
    dd, kk = _tie_differences(conv, world, frame, vc.result)
    print("tie RMS / GSD", np.sqrt(np.mean(dd**2, axis=0)) / GSD,
          "predicted", np.sqrt(np.mean(vc.result.point_sigma[kk] ** 2, axis=0)) / GSD)
