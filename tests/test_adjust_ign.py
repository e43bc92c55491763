"""The real IGN 68-image block (../shared/data/ign-aerial-block/block805) adjusted by skyrig.

Independent answer: IGN's own adjusted tie-point ground coordinates (``all_liaisons2_world.mes``) and
exposure orientations (``23FD1305_alt_2.OPK``).  IGN's orientations enter as GNSS/IMU observations;
the adjustment starts from them perturbed by 3 m and 0.2 deg (1 sigma) and must converge back.
GSD 5.7 cm.  The 68 images form two separate sub-blocks (strips 26-28 and 54-55, 18 km apart), north-south
strips with 250 m base at 1760 m (base/height 0.14 in a strip, 0.37 across strips).

How IGN's orientations enter (the height investigation, ``bench/ign_block.py``)
-------------------------------------------------------------------------------
IGN's orientations are *adjusted* orientations: an aerial triangulation fixes where each image looks
on the ground far better than how that is split between centre and attitude (a centre shift dX with a
tilt -dX/H leaves the footprint in place).  Entered as independent centre and attitude observations
(the previous version of this test), the variance components came out at 4.3 cm horizontal / 0.83 cm
vertical and 0.0013 deg, and the adjusted-minus-given centre shifts correlate with H x the attitude
shifts at 0.97 (X with phi) and 0.90 (Y with omega): the adjustment moved along that flat direction,
which the diagonal prior could not express.  Here each orientation's GNSS observation is the point on
its optical axis at the flying height (``block_from_georef(eo_pivot_m=...)``, a fixed lever arm), so the
prior has the centre/attitude correlation of an adjusted orientation.  Förstner's variance component
estimation (``estimate_variance_components``) converges in about 11 adjustments to::

    image 0.182 px    ground point 5.6 mm horizontal, 1.0 cm vertical    attitude 0.0018 deg
    GCP 2.7 cm horizontal (vertical: too little redundancy to estimate, 3.2 cm kept)

(rerun: ``.venv/bin/python tests/test_adjust_ign.py``).  The test uses these weights and checks that the
data still support them (every group's variance factor within 15 % of 1).

Refraction
----------
Projecting IGN's ground points with IGN's orientations leaves a radial pattern in the residuals:
IGN's measurements carry an outward radial displacement ``K (r + r^3/f^2)`` with K = 8.5 +- 0.2
microradians (about half of the standard-atmosphere value, 18 microradians at 1.8 km), i.e. IGN's
imaging model includes atmospheric refraction.  K is fitted here from IGN's own orientations and points
(like the frame conventions of ``test_ign_block.py``) and removed from the measurements.

Results and what is not met
---------------------------
Tie points agree with IGN's to 0.18 / 0.13 GSD (X / Y) and 0.65 GSD in height (independent diagonal
prior: 0.33 / 0.22 / 0.77), image RMS 0.14 / 0.16 px, sigma0 1.00.  The 0.5 GSD height target is *not*
reached, and the investigation says it cannot be with this data and weights the data support:

* holding IGN's orientations fixed, heights agree to 0.29 GSD only (points seen in two strips: 0.36 -
  0.45 GSD); the adjustment reproduces a map-frame forward intersection exactly, so this floor is a
  difference between IGN's points and these measurements, not frame handling, and it varies point by
  point (nearest-neighbour correlation 0.2 at 38 m for cross-strip points): no smooth model term can
  remove it (IGN's points were evidently not intersected from exactly these rays and weights);
* with IGN's orientations fixed the image residuals are 0.148 / 0.172 px (sigma0 1.05): the 68 images'
  measurements reject IGN's orientations: freeing the 408 pose unknowns lowers the chi-square by 2,600
  (22,459 on redundancy 20,247 -> 19,841 on 19,839), not by about 408, so the orientations must move (IGN fixed them with the other 737 images), by 0.0018 deg in attitude;
* single-strip points (63 % of the points; base/height 0.14) then have a predicted height sigma of
  0.9 - 1.3 GSD from this sub-block; their actual errors (0.4 - 0.8 GSD) are below it;
* tightening the attitude prior beyond its VCE value buys height agreement only against the data: at
  0.0005 deg heights reach 0.51 GSD but the IMU group's a-posteriori sigma factor is 1.64 on a redundancy of 96
  (chi-square / r = 2.7, rejected far beyond any significance level), at 0.0002 deg 0.43 GSD with 1.83;
* a systematic image pattern exists (row residuals -0.15 / +0.12 px in horizontal bands), but
  self-calibration (Brown K1-K3, P1 P2, B1 B2 free) lowers sigma0 to 0.975 and moves heights *away*
  from IGN's (0.89 GSD, mean -0.43 GSD): IGN's heights were computed without that correction.
* the sensor-tile hypothesis (the UltraCam Eagle M3 panchromatic image is stitched from several CCDs;
  maybe IGN's adjustment modelled the row bands and the missing correction is what moves our EO by
  0.0018 deg) is refuted (``bench/ign_block.py h6``).  A 9 x 6 correction grid, the mean residual of
  IGN's solution per cell (``fit_image_grid``; row bands -0.19 / +0.08 px around rows 10,000 - 17,000),
  estimated from IGN's orientations and points like K, lowers the image residuals, sigma0 (0.89) and the
  attitude VCE sigma (0.0018 -> 0.0011 deg), but heights change only from 0.65 to 0.62 GSD (0.20 / 0.13 /
  0.62 with re-estimated weights).  The decisive check needs no adjustment: with IGN's orientations held
  fixed, intersections of the corrected measurements move *away* from IGN's points (0.29 -> 0.48 GSD in
  height), symmetrically for +1 and -1 times the grid, minimum at 0: IGN's heights contain none of it.
  Cross-validated (grid fitted on strips 27 + 55, heights of points seen only in 26 / 28 / 54, and the
  reverse) held-out heights go 0.75 -> 0.69 and 0.60 -> 0.76 GSD: no consistent gain.

The test checks the achieved figures and that they match the adjustment's own predicted precision.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from conftest import shared_path
from skyrig.adjust import AdjustConfig, adjust
from skyrig.adjust.config import StatisticsOptions, Unknowns
from skyrig.adjust.corrections import fit_image_grid, fit_radial_scale, remove_image_grid, remove_refraction
from skyrig.adjust.frames import block_from_georef, eo_from_block, points_to_frame
from skyrig.geodesy.crs import ecef_to_geodetic
from skyrig.georef.ground import forward_intersection, world_to_image
from skyrig.georef.ign_block import IgnConventions
from skyrig.georef.observations import ImageMeasurements
from skyrig.geometry.rotations import matrix_from_rotvec, rotvec_from_matrix
from skyrig.io.ign import read_ign_camera, read_ign_ground_points, read_ign_measurements, read_ign_opk

GSD = 0.057
#: weights from variance component estimation (module docstring); GNSS = the ground point on the axis
SIGMA_PX = 0.1823
GNSS_SIGMA_M = (0.0056, 0.0056, 0.0101)
IMU_SIGMA_DEG = 0.00177
GCP_SIGMA_M = (0.0269, 0.0269, 0.032)


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


def flying_height(eo, gcp):
    """Mean height (m) of the measured exposures above the mean control height (ellipsoidal, via ECEF)."""
    hc = ecef_to_geodetic(eo.frame.to_ecef(eo.centre))[2]
    hg = ecef_to_geodetic(gcp.frame.to_ecef(gcp.xyz))[2]
    return float(np.mean(hc) - np.mean(hg))


def ign_block(d, sigma_px=SIGMA_PX, gnss=GNSS_SIGMA_M, imu_deg=IMU_SIGMA_DEG, gcp_sigma=GCP_SIGMA_M, seed=0,
              pivot=True):
    """The IGN block with refraction removed and perturbed starting orientations.

    ``pivot``: IGN's orientations enter as observations of the ground point on the optical axis (the
    correlated centre/attitude prior of an adjusted orientation, ``block_from_georef(eo_pivot_m=...)``
    at the flying height); False: as independent centre and attitude observations.
    """
    conv, eo, cams, m, gcp, world = _load(d)
    used = {eo.camera[eo.index()[i]] for i in np.unique(m.image)}
    cams = {c: cams[c] for c in used}
    k, k_sigma = ign_refraction(eo, cams, m, world)
    (cam,) = cams.values()
    m = ImageMeasurements(m.point, m.image, remove_refraction(m.pixel, cam, k))
    rng = np.random.default_rng(seed)
    n = len(eo)
    measured = eo.subset(np.array([eo.index()[i] for i in np.unique(m.image)]))
    pivot_m = flying_height(measured, gcp) if pivot else None
    start = replace(eo, centre=eo.centre + rng.normal(0, 3.0, (n, 3)),
                    rotation=eo.rotation @ matrix_from_rotvec(rng.normal(0, np.radians(0.2), (n, 3))))
    block, frame = block_from_georef(eo, cams, m, gcp, start_eo=start, gnss_sigma_m=gnss,
                                     imu_sigma_rad=np.radians(imu_deg), control_sigma_m=gcp_sigma, sigma_px=sigma_px,
                                     eo_pivot_m=pivot_m)
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
    """Planimetry within 0.3 GSD RMS per axis (target 0.5); heights to 0.75 GSD (the 0.5 GSD target is not
    reachable from this sub-block, module docstring); all three match the adjustment's predicted precision."""
    conv, eo, world, block, frame, res, _ = ign
    d, k = _tie_differences(conv, world, frame, res)
    assert len(d) > 2900
    rms = np.sqrt(np.mean(d**2, axis=0))
    assert np.all(rms[:2] <= 0.3 * GSD), rms / GSD
    assert rms[2] <= 0.75 * GSD, rms / GSD
    pred = np.sqrt(np.mean(res.point_sigma[k] ** 2, axis=0))
    ratio = rms / pred
    assert np.all((ratio > 0.6) & (ratio < 1.4)), (rms / GSD, pred / GSD)


def test_image_grid_recovers_a_seeded_tile_pattern():
    """fit_image_grid returns each cell's true shift of a seeded piecewise (sensor-tile) field within
    4 sigma of the mean of its noisy residuals; the bilinear field equals the values at the cell centres."""
    rng = np.random.default_rng(7)
    w, h, shape = 2646, 1700, (9, 6)
    truth = rng.normal(0, 0.2, shape + (2,))
    px = rng.uniform(0, [w, h], (20000, 2))
    cell = (px[:, 1] / h * shape[0]).astype(int), (px[:, 0] / w * shape[1]).astype(int)
    noise = 0.15
    grid = fit_image_grid(truth[cell] + rng.normal(0, noise, px.shape), px, w, h, shape, min_count=1)
    assert grid.count.sum() == len(px)
    assert np.all(np.abs(grid.shift_px - truth) < 4 * noise / np.sqrt(grid.count)[..., None])
    jc, ic = np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij")
    centres = np.c_[(ic.ravel() + 0.5) * w / shape[1], (jc.ravel() + 0.5) * h / shape[0]]
    np.testing.assert_allclose(grid(centres), grid.shift_px.reshape(-1, 2), atol=1e-12)
    np.testing.assert_allclose(remove_image_grid(centres, grid) - centres, grid.shift_px.reshape(-1, 2), atol=1e-9)
    with pytest.raises(ValueError):
        fit_image_grid(np.zeros((5, 2)), np.ones((5, 2)), w, h, shape)  # 5 residuals: no cell reaches 30


def test_ign_band_pattern_is_not_in_ign_heights():
    """The row-band pattern of IGN's solution is significant, but removing it moves IGN-EO intersections away
    from IGN's points (module docstring: the sensor-tile hypothesis is refuted)."""
    d = shared_path("ign-aerial-block")
    conv, eo, cams, m, gcp, world = _load(d)
    cams = {c: cams[c] for c in {eo.camera[eo.index()[i]] for i in np.unique(m.image)}}
    (cam,) = cams.values()
    px = remove_refraction(m.pixel, cam, ign_refraction(eo, cams, m, world)[0])
    idx = world.index()
    sel = np.array([p in idx for p in m.point])
    r = world_to_image(eo, cams, m.image[sel], world.xyz[[idx[p] for p in m.point[sel]]], world.frame) - px[sel]
    grid = fit_image_grid(r, px[sel], cam.width, cam.height, (9, 6))
    band = grid.shift_px[5:7, :, 1]  # rows 9,400 - 13,200: the negative band
    assert band.mean() < -5 * r[:, 1].std() / np.sqrt(grid.count[5:7].sum())
    rms_z = []
    for a in (-1.0, 0.0, 1.0):
        inter = forward_intersection(eo, cams, m.point, m.image, px + a * grid(px), world.frame)
        ii = {p: j for j, p in enumerate(inter.point)}
        s = np.array([p in ii for p in world.name])
        dz = inter.xyz[[ii[p] for p in world.name[s]], 2] - world.xyz[s, 2]
        rms_z.append(np.sqrt(np.mean(dz**2)))
    assert rms_z[1] < 0.35 * GSD
    assert rms_z[0] > 1.3 * rms_z[1] and rms_z[2] > 1.3 * rms_z[1], np.array(rms_z) / GSD


def _ground_point(C, R, h):
    return C + R @ np.array([0.0, 0.0, -h])


def test_ign_adjusted_eo_close_to_ign(ign):
    """From 3 m / 0.2 deg off, back to IGN's orientations within the observation sigmas: the ground point on
    the axis per axis, the attitude in angle; the centres themselves within the implied prior sigma."""
    conv, eo, world, block, frame, res, _ = ign
    h = -block.lever_arm[2]
    adj = eo_from_block(res.block, frame)
    idx = eo.index()
    given = eo.subset(np.array([idx[i] for i in adj.image])).to_frame(frame)
    du = _ground_point(adj.centre, adj.rotation, h) - _ground_point(given.centre, given.rotation, h)
    assert np.all(np.sqrt(np.mean(du**2, axis=0)) < 1.5 * np.array(GNSS_SIGMA_M)), du
    ang = np.linalg.norm(rotvec_from_matrix(np.swapaxes(given.rotation, 1, 2) @ adj.rotation), axis=1)
    assert np.degrees(np.sqrt(np.mean(ang**2))) < 1.5 * IMU_SIGMA_DEG * np.sqrt(3)
    prior_h = np.hypot(GNSS_SIGMA_M[0], h * np.radians(IMU_SIGMA_DEG))
    dc = adj.centre - given.centre
    assert np.all(np.sqrt(np.mean(dc[:, :2] ** 2, axis=0)) < 1.5 * prior_h), dc


def test_ign_adjustment_frame_matches_map_frame_intersection():
    """Hypothesis "frame inconsistency" ruled out: with IGN's orientations held fixed, the adjustment in its
    local frame gives the same points as skyrig's forward intersection in Lambert-93 (through PROJ), which
    reproduces IGN's measurements at 0.20 px (test_ign_block.py)."""
    conv, eo, world, block, frame, _ = ign_block(shared_path("ign-aerial-block"), pivot=False)
    block.station_centre = block.gnss_xyz.copy()
    block.station_rotation = block.imu_rotation.copy()
    res = adjust(block, AdjustConfig(unknowns=Unknowns(poses="fixed"), statistics=StatisticsOptions(compute=False)))
    _, cams, m, _, _ = _load(shared_path("ign-aerial-block"))[1:]
    (cam,) = block.cameras
    k = ign_refraction(eo, {cam.name: cam}, m, world)[0]
    inter = forward_intersection(eo, {cam.name: cam}, m.point, m.image, remove_refraction(m.pixel, cam, k),
                                 conv.ground_frame)
    ii = {p: j for j, p in enumerate(inter.point)}
    sel = np.array([p in ii for p in res.block.point_name])
    sel[block.control_point] = False  # control points are also weighted by their coordinates
    mine = points_to_frame(res.block.point_xyz[sel], frame, conv.ground_frame)
    ref = inter.xyz[[ii[p] for p in res.block.point_name[sel]]]
    assert sel.sum() > 3000
    assert np.abs(mine - ref).max() < 1e-3  # mm: the same geometry


def test_ign_independent_eo_prior_moves_along_the_flat_direction():
    """With independent centre / attitude observations the adjusted-minus-given centre shifts follow H x the
    attitude shifts (the footprint stays): the reason for the correlated (pivot) prior."""
    conv, eo, world, block, frame, _ = ign_block(shared_path("ign-aerial-block"), SIGMA_PX, (0.043, 0.043, 0.0083),
                                                 0.0013, 0.032, pivot=False)
    res = adjust(block, AdjustConfig(statistics=StatisticsOptions(compute=False)))
    dC = res.block.station_centre - block.gnss_xyz
    dth = rotvec_from_matrix(np.swapaxes(block.imu_rotation, 1, 2) @ res.block.station_rotation)
    dthw = np.einsum("nij,nj->ni", block.imu_rotation, dth)  # world-frame small rotations
    H = 1760.0
    assert np.corrcoef(dC[:, 0], H * dthw[:, 1])[0, 1] > 0.85
    assert np.corrcoef(dC[:, 1], -H * dthw[:, 0])[0, 1] > 0.8
    # while the footprint centre moved far less than the centre
    foot = dC[:, :2] + H * np.c_[-dthw[:, 1], dthw[:, 0]]  # C + R (0, 0, -H)
    assert np.sqrt(np.mean(foot**2)) < 0.5 * np.sqrt(np.mean(dC[:, :2] ** 2))


if __name__ == "__main__":  # rerun the variance component estimation of the module docstring
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from skyrig.adjust.vce import estimate_variance_components

    d = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "ign-aerial-block"
    conv, eo, world, block, frame, k = ign_block(d, 0.15, (0.02, 0.02, 0.01), 0.0025, 0.05)
    print("flying height (pivot) m", block.lever_arm)
    print(f"refraction K = {k[0] * 1e6:.2f} +- {k[1] * 1e6:.2f} microradians")
    vc = estimate_variance_components(block, callback=lambda i, f: print(i, {a: round(b, 3) for a, b in f.items()}))
    print("converged", vc.converged, {a: (round(b, 5) if "imu" not in a else f"{np.degrees(b):.5f} deg")
                                      for a, b in vc.sigma.items()})
    dd, kk = _tie_differences(conv, world, frame, vc.result)
    print("tie RMS / GSD", np.sqrt(np.mean(dd**2, axis=0)) / GSD,
          "predicted", np.sqrt(np.mean(vc.result.point_sigma[kk] ** 2, axis=0)) / GSD)
