"""Real IGN survey 23FD1305 (../shared/data/ign-aerial-block): exact ground <-> image with the given orientations.

Independent reference: IGN's own image measurements and adjusted ground coordinates.  The data README
reports that an independent implementation reproduces the tie measurements with 0.20 px RMS per axis;
the acceptance limits are 0.3 px RMS per axis and 2 px maximum.  Any convention error (geoid, meridian
convergence, axis directions, linear alteration) shows up as tens to hundreds of pixels.
"""

from __future__ import annotations

import numpy as np
import pytest

from skyrig.georef.eo import WorldFrame
from skyrig.georef.ground import forward_intersection, image_to_world_height, world_to_image
from skyrig.georef.ign_block import IgnConventions
from skyrig.io.ign import read_ign_camera, read_ign_ground_points, read_ign_measurements, read_ign_opk


def _setup(ign_dir, opk):
    conv = IgnConventions(geoid=str(ign_dir / "dataset" / "fr_ign_RAF20.tif"))
    eo = conv.reduce(read_ign_opk(ign_dir / opk, conv.eo_frame))
    cams = {c.name: c for c in (read_ign_camera(ign_dir / "dataset" / f"Camera{i}.txt") for i in (1, 2))}
    return conv, eo, cams


SETS = [
    ("block805/23FD1305_alt_2.OPK", "block805/all_liaisons2.mes", "block805/all_liaisons2_world.mes"),
    ("block805/23FD1305_alt_2.OPK", "block805/all_terrains2.mes", "block805/23FD1305_Biais2.app"),
    ("dataset/23FD1305_alt_test.OPK", "dataset/terrain_test.mes", "dataset/GCP_test.app"),
]


def _residuals(ign_dir, opk, mes, ground):
    conv, eo, cams = _setup(ign_dir, opk)
    gp = read_ign_ground_points(ign_dir / ground, conv.ground_frame)
    m = read_ign_measurements(ign_dir / mes)
    idx = gp.index()
    sel = np.array([p in idx for p in m.point])
    px = world_to_image(eo, cams, m.image[sel], gp.xyz[[idx[p] for p in m.point[sel]]], gp.frame)
    return px - m.pixel[sel]


def test_world_to_image_reproduces_ign_measurements(ign_dir):
    """All measurements of the three sets: RMS <= 0.3 px per axis, none above 2 px.

    Tie points alone must also be within 0.3 px RMS.  The two GCP files measure GCPs 1003 and 1005, whose
    surveyed coordinates disagree with IGN's own orientations by about one GSD (forward intersection of
    IGN's measurements puts 1005 about 5 cm east of its .app position; residuals flip sign between the
    two opposite-direction strips), so per-file their RMS is larger; they still stay below 2 px."""
    res = [_residuals(ign_dir, *s) for s in SETS]
    assert len(res[0]) > 14000 and len(res[1]) >= 19 and len(res[2]) >= 7
    tie_rms = np.sqrt(np.mean(res[0] ** 2, axis=0))
    assert np.all(tie_rms <= 0.3), tie_rms
    pooled = np.concatenate(res)
    rms = np.sqrt(np.mean(pooled**2, axis=0))
    assert np.all(rms <= 0.3), rms
    for r in res:
        assert np.abs(r).max() <= 2.0


def test_published_gcp_example(ign_dir):
    # data README: GCP 1003 (815601.510, 6283629.280, 54.960) at column 24042.25, row 14781.17 in 23FD1305x00026_01306
    conv, eo, cams = _setup(ign_dir, "dataset/23FD1305_alt_test.OPK")
    px = world_to_image(eo, cams, ["23FD1305x00026_01306"], [[815601.510, 6283629.280, 54.960]], conv.ground_frame)
    assert np.abs(px[0] - [24042.25, 14781.17]).max() < 1.0


def test_forward_intersection_matches_ign_adjusted_points(ign_dir):
    """Intersecting IGN's tie measurements with IGN's orientations gives IGN's adjusted ground points.

    GSD is about 5.7 cm; IGN's points come from the same adjustment, so agreement must be well inside
    0.5 GSD per axis (RMS), much better in planimetry than in height (base/height ratio)."""
    conv, eo, cams = _setup(ign_dir, "block805/23FD1305_alt_2.OPK")
    m = read_ign_measurements(ign_dir / "block805" / "all_liaisons2.mes")
    gp = read_ign_ground_points(ign_dir / "block805" / "all_liaisons2_world.mes", conv.ground_frame)
    res = forward_intersection(eo, cams, m.point, m.image, m.pixel, conv.ground_frame)
    idx = gp.index()
    sel = np.array([p in idx for p in res.point]) & (res.n_rays >= 2)
    d = res.xyz[sel] - gp.xyz[[idx[p] for p in res.point[sel]]]
    rms = np.sqrt(np.mean(d**2, axis=0))
    gsd = 0.057
    assert sel.sum() > 2900
    assert np.all(rms < 0.5 * gsd), rms
    assert np.sqrt(np.nanmean(res.residual_px**2)) < 0.3


def test_image_to_world_height_inverts_world_to_image(ign_dir):
    conv, eo, cams = _setup(ign_dir, "block805/23FD1305_alt_2.OPK")
    gp = read_ign_ground_points(ign_dir / "block805" / "all_liaisons2_world.mes", conv.ground_frame)
    m = read_ign_measurements(ign_dir / "block805" / "all_liaisons2.mes")
    idx = gp.index()
    sel = np.flatnonzero([p in idx for p in m.point])[:500]
    truth = gp.xyz[[idx[p] for p in m.point[sel]]]
    px = world_to_image(eo, cams, m.image[sel], truth, gp.frame)
    back = image_to_world_height(eo, cams, m.image[sel], px, truth[:, 2], gp.frame)
    assert np.abs(back - truth).max() < 1e-5
