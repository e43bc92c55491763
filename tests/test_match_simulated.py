"""Tie points on the simulator's MIDAS penta-rig project (``midas-demo``, the flight ``make demo`` renders: 2 strips
x 2 exposures x 5 heads, CI-size 640 px images of a 3-D town with 1 DN sensor noise), judged against the
simulator's truth: the true orientations and the true scene surface (ray casting).

Matching is guided by direct georeferencing of the *recorded* (noisy) trajectory and nominal rig, as in a real
block; the truth is used only to judge.  A tie's error is its transfer error ``x2 - T(x1)``: the true surface
point seen at x1 in image 1, projected with the true orientation into image 2 (both images' localisation errors,
so an upper bound of the per-image error).  Checked (issue 5): cross-head ties exist for every overlapping
nadir/oblique pair; the RMS per image coordinate of ALL verified ties (no trimming) is at most 0.3 px for
nadir-nadir and nadir-oblique pairs, 0.1 px after least-squares matching.
"""

from __future__ import annotations

import itertools

import cv2
import numpy as np
import pytest

from skyrig.match.features import FeatureConfig, extract_features
from skyrig.match.lsm import local_affine, lsm_refine
from skyrig.match.matching import MatchConfig, match_pair
from skyrig.match.pairs import footprint_pairs
from skyrig.simulate.render import cast_rays, ray_hits_at_pixels, render_image
from skyrig.simulate.scenarios import build_survey, georeference_recorded, scenario_spec


def _klass(h1: str, h2: str) -> str:
    if h1 == h2 == "nadir":
        return "nadir-nadir"
    return "nadir-oblique" if "nadir" in (h1, h2) else "oblique-oblique"


@pytest.fixture(scope="module")
def block():
    s = build_survey(scenario_spec("midas-demo", "ci", 1))
    eo = s.eo_true
    n = len(eo)
    P = eo.pose()
    cam = [s.rig_true.head(str(eo.head[k])).camera for k in range(n)]
    imgs = [cv2.cvtColor(render_image(s.scene, cam[k], P[k], noise_dn=s.spec.image_noise_dn, seed=k),
                         cv2.COLOR_RGB2GRAY) for k in range(n)]

    def truth(a, b, xa):
        """True projection in b of the surface point seen at xa in a, and whether b sees it (not occluded)."""
        hit = ray_hits_at_pixels(s.scene, cam[a], P[a], xa)
        xb = cam[b].world_to_pixel(P[b], hit.xyz)
        d = hit.xyz - P[b].translation
        dist = np.linalg.norm(d, axis=1)
        with np.errstate(invalid="ignore"):
            back = cast_rays(s.scene, P[b].translation, d / dist[:, None])
            vis = np.abs(back.t - dist) < 0.01 + 1e-4 * dist
        return xb, vis & cam[b].in_image(xb)

    # approximate orientations: direct georeferencing of the recorded trajectory with the nominal rig
    eo_rec = georeference_recorded(s)
    Pr = eo_rec.pose()
    cams = {str(eo_rec.camera[k]): s.rig_recorded.head(str(eo_rec.head[k])).camera for k in range(n)}
    cam_rec = [cams[str(c)] for c in eo_rec.camera]
    z0 = float(s.spec.base_height_m)  # mean terrain height: all the matcher knows of the scene
    fc = FeatureConfig(method="opencv", max_size=None, max_features=4000)
    feats = [extract_features(imgs[k], fc, cam_rec[k], Pr[k], z0) for k in range(n)]
    pairs, _ = footprint_pairs(eo_rec, cams, z0, min_overlap=0.05)
    mc = MatchConfig(matcher="bruteforce")  # deterministic
    pm = {(int(a), int(b)): match_pair(feats[a], feats[b], mc, cam_rec[a], Pr[a], cam_rec[b], Pr[b]) for a, b in pairs}
    return s, eo, cam, imgs, truth, feats, pm


def test_every_overlapping_nadir_oblique_pair_has_ties(block):
    s, eo, cam, imgs, truth, feats, pm = block
    n = len(eo)
    g = np.linspace(0.03, 0.97, 12)
    missing, checked, checked_heads = [], 0, set()
    for a, b in itertools.combinations(range(n), 2):
        ha, hb = str(eo.head[a]), str(eo.head[b])
        if _klass(ha, hb) != "nadir-oblique":
            continue
        frac = 0.0
        for u, v in ((a, b), (b, a)):  # true overlap: share of image u's surface points that image v sees
            px = np.stack(np.meshgrid(g * (cam[u].width - 1), g * (cam[u].height - 1)), -1).reshape(-1, 2)
            frac = max(frac, float(truth(u, v, px)[1].mean()))
        if frac < 0.15:
            continue
        checked += 1
        checked_heads.add((ha, hb))
        r = pm.get((a, b))
        if r is None or not r.ok or len(r) < 20:
            missing.append((str(eo.image[a]), str(eo.image[b]), round(frac, 2), None if r is None else r.reason))
    assert checked >= 10
    assert not missing, missing
    # the oblique heads that really overlap the nadir images in this block (nadir-left only reaches 6 %)
    assert {h for pair in checked_heads for h in pair} >= {"nadir", "forward", "backward", "right"}


def test_tie_accuracy_against_simulator_truth(block):
    s, eo, cam, imgs, truth, feats, pm = block
    err: dict[str, list] = {}
    err_lsm: dict[str, list] = {}
    refined: dict[str, list] = {}
    for (a, b), r in pm.items():
        if not r.ok:
            continue
        x1, x2 = feats[a].xy[r.matches[:, 0]], feats[b].xy[r.matches[:, 1]]
        t2, vis = truth(a, b, x1)
        k = _klass(str(eo.head[a]), str(eo.head[b]))
        e = x2 - t2
        assert np.all(np.isfinite(e))
        err.setdefault(k, []).append(e)
        if k != "oblique-oblique":  # LSM on the cross-head and nadir pairs (time)
            lr = lsm_refine(imgs[a], imgs[b], x1, x2, local_affine(x1, x2), half_size=7)
            err_lsm.setdefault(k, []).append(lr.xy2[lr.ok] - t2[lr.ok])
            refined.setdefault(k, []).append(lr.ok)
    lines = []
    for k, v in sorted(err.items()):
        e = np.concatenate(v)
        r = np.linalg.norm(e, axis=1)
        rms = float(np.sqrt(np.mean(e**2)))
        line = (f"{k}: {len(v)} pairs, {len(e)} ties, RMS {rms:.3f} px per coordinate (all ties), "
                f"{np.mean(r > 3):.1%} > 3 px, max {r.max():.2f} px")
        if k in err_lsm:
            el = np.concatenate(err_lsm[k])
            rl = float(np.sqrt(np.mean(el**2)))
            line += f"; LSM {rl:.3f} px on {np.mean(np.concatenate(refined[k])):.0%} refined"
            assert rl < 0.1, line
            assert np.mean(np.concatenate(refined[k])) > 0.7, line
        lines.append(line)
        assert np.mean(r > 3) < 0.002, line  # gross mismatches (> 3 px) all but gone after verification
        if k == "oblique-oblique":
            # same-head pairs (A ~ identity): the transfer error holds two equal errors; per image rms / sqrt(2)
            assert rms / np.sqrt(2) < 0.3, line
        else:
            assert rms < 0.3, line
    print("\n" + "\n".join(lines))
