"""Height investigation on the real IGN 68-image block: the hypothesis table of tests/test_adjust_ign.py.

Run:  .venv/bin/python bench/ign_block.py        (needs ../shared/data/ign-aerial-block; about two minutes)
      .venv/bin/python bench/ign_block.py h6     (H6 only, about 30 s)

Prints, each against IGN's own tie-point coordinates (``all_liaisons2_world.mes``), in GSD (5.7 cm):

* H5  IGN's orientations held fixed (skyrig's forward intersection): RMS by strip combination and
      by number of rays, image residuals of IGN's solution binned over the image plane;
* H2  adjustment frame vs map-frame intersection with the poses fixed (must be identical);
* H3  independent centre / attitude prior (VCE weights of that model) vs the correlated "pivot" prior
      (the ground point on the optical axis observed; VCE weights of the test): tie RMS, predicted RMS,
      adjusted-minus-given EO statistics and the centre / attitude correlation;
* H4  height errors by strip combination and rays, their mean, and the normalised errors;
* H1  self-calibration (Brown K1-K3, P1 P2, B1 B2 free) on top of the pivot model;
* H6  sensor-tile (band) correction grid: the mean residual of IGN's solution per cell of an image grid
      (``skyrig.adjust.corrections.fit_image_grid``), removed from the measurements like the refraction:
      IGN-EO intersections with a fraction alpha of it, the adjustment with the test's and re-estimated
      (VCE) weights, and a cross-validation (grid fitted on strips 27 + 55, heights of points seen only in
      strips 26 / 28 / 54, and the reverse).
"""

from __future__ import annotations

import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from test_adjust_ign import (  # noqa: E402
    GSD, _load, _tie_differences, ign_block, ign_refraction,
)

from skyrig.adjust import AdjustConfig, adjust  # noqa: E402
from skyrig.adjust.config import Unknowns
from skyrig.adjust.corrections import fit_image_grid, remove_image_grid, remove_refraction  # noqa: E402
from skyrig.adjust.vce import estimate_variance_components  # noqa: E402
from skyrig.camera.brown import BrownDistortion  # noqa: E402
from skyrig.georef.ground import forward_intersection, world_to_image  # noqa: E402
from skyrig.georef.observations import ImageMeasurements  # noqa: E402
from skyrig.geometry.rotations import rotvec_from_matrix  # noqa: E402

DATA = ROOT / ".." / "shared" / "data" / "ign-aerial-block"


def fmt(v):
    return "/".join(f"{x:.2f}" for x in np.atleast_1d(v))


def strip_key(names_img, obs_point, obs_img, points):
    strip = np.array([s.split("_")[0][-2:] for s in names_img])
    sets = defaultdict(set)
    for p, i in zip(obs_point, obs_img):
        sets[p].add(strip[i])
    return np.array(["+".join(sorted(sets[p])) for p in points])


def breakdown(dd, key, mult, ps=None):
    for c in np.unique(key):
        s = key == c
        extra = "" if ps is None else f"  predicted Z {np.sqrt(np.mean(ps[s, 2] ** 2)) / GSD:.2f}"
        print(f"    strips {c:9s} n={s.sum():4d}  RMS {fmt(np.sqrt(np.mean(dd[s] ** 2, 0)) / GSD)}"
              f"  mean Z {dd[s, 2].mean() / GSD:+.2f}{extra}")
    for a, b in ((2, 2), (3, 3), (4, 5), (6, 99)):
        s = (mult >= a) & (mult <= b)
        extra = "" if ps is None else f"  predicted Z {np.sqrt(np.mean(ps[s, 2] ** 2)) / GSD:.2f}"
        print(f"    rays {a}-{b:<3d}        n={s.sum():4d}  RMS {fmt(np.sqrt(np.mean(dd[s] ** 2, 0)) / GSD)}{extra}")


def h5_fixed(conv, eo, cams, m, world):
    print("H5  IGN's orientations fixed: forward intersection of the (refraction-corrected) measurements")
    (cam,) = cams.values()
    k, ks = ign_refraction(eo, cams, m, world)
    mc = ImageMeasurements(m.point, m.image, remove_refraction(m.pixel, cam, k))
    inter = forward_intersection(eo, cams, mc.point, mc.image, mc.pixel, world.frame)
    ii = {p: j for j, p in enumerate(inter.point)}
    s = np.array([p in ii for p in world.name])
    dd = inter.xyz[[ii[p] for p in world.name[s]]] - world.xyz[s]
    print(f"    refraction K = {k * 1e6:.2f} +- {ks * 1e6:.2f} urad;  all points RMS {fmt(np.sqrt(np.mean(dd**2, 0)) / GSD)}"
          f" GSD, mean Z {dd[:, 2].mean() / GSD:+.2f}")
    names, cnt = np.unique(mc.point, return_counts=True)
    mult = dict(zip(names, cnt))
    imgs = np.unique(mc.image)
    iidx = {n: j for j, n in enumerate(imgs)}
    key = strip_key(imgs, mc.point, [iidx[i] for i in mc.image], world.name[s])
    breakdown(dd, key, np.array([mult[p] for p in world.name[s]]))
    from scipy.spatial import cKDTree

    xy = world.xyz[s, :2]
    for lab, c in (("single-strip", np.char.find(key, "+") < 0), ("cross-strip", np.char.find(key, "+") >= 0)):
        d, j = cKDTree(xy[c]).query(xy[c], k=2)
        z = dd[c, 2]
        print(f"    {lab} height differences: nearest-neighbour correlation {np.corrcoef(z, z[j[:, 1]])[0, 1]:.2f} "
              f"(median spacing {np.median(d[:, 1]):.0f} m)  -> smooth = model difference, ~0 = point by point")
    idx = world.index()
    sel = np.array([p in idx for p in mc.point])
    r = world_to_image(eo, cams, mc.image[sel], world.xyz[[idx[p] for p in mc.point[sel]]], world.frame) - mc.pixel[sel]
    print(f"    IGN solution image residuals RMS {fmt(np.sqrt(np.mean(r**2, 0)))} px; mean (col,row) px in 6x6 bins:")
    binned(mc.pixel[sel], r, cam)


def binned(px, r, cam, nb=6):
    bi = np.clip((px[:, 0] / cam.width * nb).astype(int), 0, nb - 1)
    bj = np.clip((px[:, 1] / cam.height * nb).astype(int), 0, nb - 1)
    for j in range(nb):
        print("     " + " ".join(f"({r[(bi == i) & (bj == j), 0].mean():+.2f},{r[(bi == i) & (bj == j), 1].mean():+.2f})"
                                for i in range(nb)))


def eo_stats(res, block):
    b = res.block
    C, R = b.station_centre, b.station_rotation
    dth = rotvec_from_matrix(np.swapaxes(block.imu_rotation, 1, 2) @ R)
    dthw = np.einsum("nij,nj->ni", block.imu_rotation, dth)
    given_c = block.gnss_xyz - block.imu_rotation @ block.lever_arm
    dC = C - given_c
    H = 1760.0
    foot = dC[:, :2] + H * np.c_[-dthw[:, 1], dthw[:, 0]]
    print(f"    adjusted - given: centre RMS E/N/U {fmt(np.sqrt(np.mean(dC**2, 0)) * 100)} cm, footprint E/N "
          f"{fmt(np.sqrt(np.mean(foot**2, 0)) * 100)} cm, attitude (world E/N/U axes) "
          f"{'/'.join(f'{x:.4f}' for x in np.degrees(np.sqrt(np.mean(dthw**2, 0))))} deg")
    if np.ptp(dC) == 0:
        return
    print(f"    correlation dE ~ H*rotN {np.corrcoef(dC[:, 0], H * dthw[:, 1])[0, 1]:.2f}, "
          f"dN ~ -H*rotE {np.corrcoef(dC[:, 1], -H * dthw[:, 0])[0, 1]:.2f}")


def report(label, conv, world, frame, res, block, detail=False):
    dd, kk = _tie_differences(conv, world, frame, res)
    img = np.sqrt(np.mean(res.residuals["image"].residual ** 2, axis=0))
    print(f"{label}\n    converged {res.info.converged} in {res.info.iterations}, sigma0 {res.sigma0:.3f}, "
          f"image RMS {fmt(img)} px, groups " + ", ".join(f"{g} {st.sigma0:.2f}" for g, st in res.groups.items()))
    ps = res.point_sigma[kk] if res.point_sigma is not None else None
    pred = "" if ps is None else f", predicted {fmt(np.sqrt(np.mean(ps**2, 0)) / GSD)}, normalised RMS {fmt(np.sqrt(np.mean((dd / ps) ** 2, 0)))}"
    print(f"    tie points RMS X/Y/Z {fmt(np.sqrt(np.mean(dd**2, 0)) / GSD)} GSD, mean {fmt(dd.mean(0) / GSD)}{pred}")
    eo_stats(res, block)
    if detail:
        b = res.block
        key = strip_key(b.image_name, b.obs_point, b.obs_image, kk)
        breakdown(dd, key, np.bincount(b.obs_point, minlength=b.n_points)[kk], ps)
        print("    adjusted image residuals, mean (col,row) px in 6x6 bins:")
        binned(b.obs_pixel, res.residuals["image"].residual, b.cameras[0])
    return dd


def h6_grid(grid_shape=(9, 6)):
    """The sensor-tile hypothesis: a camera correction grid estimated from IGN's orientations and points."""
    conv, eo, cams, m, gcp, world = _load(DATA)
    used = {eo.camera[eo.index()[i]] for i in np.unique(m.image)}
    cams = {c: cams[c] for c in used}
    (cam,) = cams.values()
    k, _ = ign_refraction(eo, cams, m, world)
    px0 = remove_refraction(m.pixel, cam, k)
    idx = world.index()
    sel = np.array([p in idx for p in m.point])
    r = np.full_like(px0, np.nan)
    r[sel] = world_to_image(eo, cams, m.image[sel], world.xyz[[idx[p] for p in m.point[sel]]], world.frame) - px0[sel]
    strip = np.array([s.split("_")[0][-2:] for s in m.image])
    seen = defaultdict(set)
    for p, st in zip(m.point, strip):
        seen[p].add(st)
    print(f"H6  sensor-tile correction grid {grid_shape[0]} rows x {grid_shape[1]} columns, fitted from IGN's "
          f"EO + points (refraction removed); IGN residual RMS {fmt(np.sqrt(np.mean(r[sel] ** 2, 0)))} px")
    rows = px0[sel, 1]
    band = (rows / cam.height * 17).astype(int)
    print("    IGN residual row component, mean per 1000-row band: "
          + " ".join(f"{r[sel, 1][band == j].mean():+.2f}" for j in range(17)))
    g_all = fit_image_grid(r[sel], px0[sel], cam.width, cam.height, grid_shape)
    print(f"    residual RMS after the grid {fmt(np.sqrt(np.mean((r[sel] - g_all(px0[sel])) ** 2, 0)))} px")
    for a in (-1.0, -0.5, 0.0, 0.5, 1.0):
        inter = forward_intersection(eo, cams, m.point, m.image, px0 + a * g_all(px0), world.frame)
        ii = {p: j for j, p in enumerate(inter.point)}
        s = np.array([p in ii for p in world.name])
        dd = inter.xyz[[ii[p] for p in world.name[s]]] - world.xyz[s]
        print(f"    IGN's EO fixed, measurements + {a:+.1f} x grid: intersection RMS "
              f"{fmt(np.sqrt(np.mean(dd**2, 0)) / GSD)} GSD")

    def adjusted(grid, label, vce):
        conv, eo_, world_, block, frame, _ = ign_block(DATA)
        if grid is not None:
            block.obs_pixel = remove_image_grid(block.obs_pixel, grid)
        if vce:
            vc = estimate_variance_components(block)
            res = vc.result
            label += " VCE: " + ", ".join(f"{a} {np.degrees(b):.5f} deg" if "imu" in a else f"{a} {b:.4f}"
                                          for a, b in vc.sigma.items())
        else:
            res = adjust(block, AdjustConfig())
        dd = report(label, conv, world_, frame, res, block)
        _, kk = _tie_differences(conv, world_, frame, res)
        return dd, res.block.point_name[kk]

    base = {}
    for vce in (False, True):
        w = "re-estimated weights" if vce else "test weights"
        base[vce] = adjusted(None, f"  H6 no grid, {w}", vce)
        adjusted(g_all, f"  H6 grid fitted on all images, {w}", vce)
    for fit in ({"27", "55"}, {"26", "28", "54"}):
        fs = sel & np.isin(strip, sorted(fit))
        held = set(np.unique(strip)) - fit
        g = fit_image_grid(r[fs], px0[fs], cam.width, cam.height, grid_shape)
        dd, pn = adjusted(g, f"  H6 cross-validation: grid fitted on strips {'+'.join(sorted(fit))}, "
                          "re-estimated weights", True)
        s = np.array([seen[p] <= held for p in pn])
        b = np.array([seen[p] <= held for p in base[True][1]])
        print(f"    held-out points (seen only in strips {'+'.join(sorted(held))}, n={s.sum()}): RMS "
              f"{fmt(np.sqrt(np.mean(dd[s] ** 2, 0)) / GSD)} GSD; without grid "
              f"{fmt(np.sqrt(np.mean(base[True][0][b] ** 2, 0)) / GSD)} GSD")


def main() -> None:
    conv, eo, cams, m, gcp, world = _load(DATA)
    used = {eo.camera[eo.index()[i]] for i in np.unique(m.image)}
    cams = {c: cams[c] for c in used}
    h5_fixed(conv, eo, cams, m, world)

    conv, eo, world, block, frame, _ = ign_block(DATA, pivot=False)
    block.station_centre = block.gnss_xyz.copy()
    block.station_rotation = block.imu_rotation.copy()
    report("H2  poses fixed at IGN's in the adjustment frame (compare with H5's intersection)", conv, world, frame,
           adjust(block, AdjustConfig(unknowns=Unknowns(poses="fixed"))), block)

    conv, eo, world, block, frame, _ = ign_block(DATA, 0.183, (0.043, 0.043, 0.0083), 0.0013, 0.032, pivot=False)
    report("H3a independent centre / attitude prior (its VCE weights: 4.3 cm h, 0.83 cm v, 0.0013 deg)", conv, world,
           frame, adjust(block, AdjustConfig()), block)
    conv, eo, world, block, frame, _ = ign_block(DATA)
    report("H3b correlated prior: ground point on the axis observed (VCE: 5.6 mm h, 1.0 cm v, 0.0018 deg) [the test]",
           conv, world, frame, adjust(block, AdjustConfig()), block, detail=True)

    print("H3c attitude prior tightened beyond its VCE value (pivot model): variance factor of the IMU group "
          "(1 = supported) vs heights")
    for imu in (0.00177, 0.001, 0.0005, 0.0002):
        conv, eo, world, block, frame, _ = ign_block(DATA, imu_deg=imu)
        res = adjust(block, AdjustConfig())
        dd, kk = _tie_differences(conv, world, frame, res)
        g = res.groups
        print(f"    IMU {imu:.5f} deg: IMU factor {g['imu'].sigma0:.2f} (redundancy {g['imu'].redundancy:.0f}), "
              f"GNSS {g['gnss'].sigma0:.2f}, image {g['image'].sigma0:.3f}, sigma0 {res.sigma0:.3f}; "
              f"tie RMS {fmt(np.sqrt(np.mean(dd**2, 0)) / GSD)} GSD")

    conv, eo, world, block, frame, _ = ign_block(DATA)
    block.cameras = [c.with_(distortion=BrownDistortion()) for c in block.cameras]
    res = adjust(block, AdjustConfig(unknowns=Unknowns(intrinsics="free",
                                                       intrinsic_names=("k1", "k2", "k3", "p1", "p2", "b1", "b2"))))
    sr = res.sigma_reduced()
    cam = res.block.cameras[0]
    vals = dict(zip(cam.intrinsic_names, cam.intrinsics))
    print("H1  self-calibration on top of H3b: " + ", ".join(
        f"{n} {vals[n]:.3g} ({vals[n] / sr[('intrinsics', cam.name, n)]:+.0f} sigma)"
        for n in ("k1", "k2", "k3", "p1", "p2", "b1", "b2")))
    report("    (self-calibrated)", conv, world, frame, res, block)

    h6_grid()


if __name__ == "__main__":
    if sys.argv[1:] == ["h6"]:
        h6_grid()
    else:
        main()
