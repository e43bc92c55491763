"""Reproduce IGN's image measurements of block 23FD1305 with skyrig's world-to-image.

Run:  .venv/bin/python examples/ign_world_to_image.py [path/to/shared/data/ign-aerial-block]

For each measurement file it projects the ground points (ellipsoidal heights, Lambert-93) with IGN's
exterior orientations (Lambert-93, altitudes through RAF20 with the linear alteration undone) and
prints RMS per axis, percentiles and maximum of measured minus projected pixels; then the forward
intersection of the tie measurements against IGN's adjusted ground points.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from skyrig.georef.ground import forward_intersection, world_to_image
from skyrig.georef.ign_block import IgnConventions
from skyrig.io.ign import read_ign_camera, read_ign_ground_points, read_ign_measurements, read_ign_opk

SETS = [
    ("tie points", "block805/23FD1305_alt_2.OPK", "block805/all_liaisons2.mes", "block805/all_liaisons2_world.mes"),
    ("GCPs (block)", "block805/23FD1305_alt_2.OPK", "block805/all_terrains2.mes", "block805/23FD1305_Biais2.app"),
    ("GCPs (extract)", "dataset/23FD1305_alt_test.OPK", "dataset/terrain_test.mes", "dataset/GCP_test.app"),
]


def stats(name: str, d: np.ndarray) -> None:
    rms = np.sqrt(np.mean(d**2, axis=0))
    r = np.hypot(d[:, 0], d[:, 1])
    p = np.percentile(np.abs(d), [50, 90, 99], axis=0)
    print(f"{name:16s} n={len(d):6d}  RMS col {rms[0]:.3f} row {rms[1]:.3f} px | |d| 50/90/99%: "
          f"col {p[0, 0]:.2f}/{p[1, 0]:.2f}/{p[2, 0]:.2f} row {p[0, 1]:.2f}/{p[1, 1]:.2f}/{p[2, 1]:.2f} | "
          f"max col {np.abs(d[:, 0]).max():.3f} row {np.abs(d[:, 1]).max():.3f} radial {r.max():.3f} px")


def main() -> None:
    root = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "ign-aerial-block"
    conv = IgnConventions(geoid=str(root / "dataset" / "fr_ign_RAF20.tif"))
    cams = {c.name: c for c in (read_ign_camera(root / "dataset" / f"Camera{i}.txt") for i in (1, 2))}
    pooled = []
    for name, opk, mes, ground in SETS:
        eo = conv.reduce(read_ign_opk(root / opk, conv.eo_frame))
        gp = read_ign_ground_points(root / ground, conv.ground_frame)
        m = read_ign_measurements(root / mes)
        idx = gp.index()
        sel = np.array([p in idx for p in m.point])
        px = world_to_image(eo, cams, m.image[sel], gp.xyz[[idx[p] for p in m.point[sel]]], gp.frame)
        d = m.pixel[sel] - px
        pooled.append(d)
        stats(name, d)
    stats("all pooled", np.concatenate(pooled))
    eo = conv.reduce(read_ign_opk(root / SETS[0][1], conv.eo_frame))
    m = read_ign_measurements(root / SETS[0][2])
    gp = read_ign_ground_points(root / SETS[0][3], conv.ground_frame)
    res = forward_intersection(eo, cams, m.point, m.image, m.pixel, conv.ground_frame)
    idx = gp.index()
    sel = np.array([p in idx for p in res.point]) & (res.n_rays >= 2)
    dd = res.xyz[sel] - gp.xyz[[idx[p] for p in res.point[sel]]]
    rms = np.sqrt(np.mean(dd**2, axis=0))
    print(f"forward intersection of {sel.sum()} tie points vs IGN's adjusted coordinates: RMS X {rms[0] * 100:.2f} cm, "
          f"Y {rms[1] * 100:.2f} cm, Z {rms[2] * 100:.2f} cm (GSD ~5.7 cm); image residual RMS "
          f"{np.sqrt(np.nanmean(res.residual_px ** 2)):.3f} px")


if __name__ == "__main__":
    main()
