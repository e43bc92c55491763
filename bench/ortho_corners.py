"""Roof corners of the true orthomosaic of the simulated MIDAS town (``make demo``'s flight), judged by the roof
outline's edges (:func:`skyrig.simulate.judge.roof_outline_offsets`).

Reads a finished demo output (``skyrig demo DIR``: ``DIR/simulated``): the adjusted orientations, the images and the
matched DSM.  Prints, for the nadir orthomosaic on

* the scene's true surface sampled on the matched DSM's grid (the reference: the measure's own floor plus the
  cell quantisation of the edges),
* the same mosaic moved by (+1.5, -1.0) cells (the measure must report that shift),
* the matched DSM as it is (``square_buildings=False``),
* the matched DSM with the buildings squared from the DSM's footprints (``square_refine=False``),
* the matched DSM with the buildings squared after their walls were moved onto the outline in the images (default),

the judged corners (of 4 per scene building; the others lack a seen outside or inside), RMS / max offset and the
share within 1 GSD (the issue's acceptance: roof corners within 1 GSD of their true positions).

Run: ``.venv/bin/python bench/ortho_corners.py demo-output``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np


def main() -> None:
    import cv2

    from skyrig.cli._common import load_cameras
    from skyrig.dense.ortho import OrthoConfig, orthomosaic
    from skyrig.io.dsm_cog import read_dsm_cog
    from skyrig.io.eo_csv import read_eo_csv
    from skyrig.pipeline.dense import ImageFiles, find_images
    from skyrig.simulate.judge import roof_outline_offsets, true_dsm
    from skyrig.simulate.scenarios import build_survey, scenario_spec

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("demo", help="output folder of `skyrig demo`")
    a = ap.parse_args()
    sim = Path(a.demo) / "simulated"
    scene = build_survey(scenario_spec("midas-dsm", "ci", 1)).scene
    eo = read_eo_csv(sim / "output" / "adjust" / "eo.csv")
    eo = eo.subset(np.flatnonzero(["nadir" in str(n) for n in eo.image]))
    cams = load_cameras([str(sim / "rig.yaml")])
    loader = ImageFiles(find_images(eo, [str(sim / "images")]), [(cams[str(c)].width, cams[str(c)].height)
                                                                 for c in eo.camera])
    dsm = read_dsm_cog(sim / "output" / "dsm" / "dsm.tif")

    def report(name, m, shift=None):
        rgb, valid = m.rgb, m.valid
        if shift is not None:
            M = np.float32([[1, 0, shift[0]], [0, 1, shift[1]]])
            rgb = cv2.warpAffine(rgb, M, rgb.shape[1::-1], flags=cv2.INTER_LINEAR)
            valid = cv2.warpAffine(valid.astype(np.uint8), M, rgb.shape[1::-1], flags=cv2.INTER_NEAREST) > 0
        rec = roof_outline_offsets(rgb, valid, m.grid, m.frame, scene)
        ok = [r for r in rec if r["status"] == "ok"]
        off = np.array([r["offset_m"] for r in ok]) / m.grid.cell_m
        d = np.hypot(off[:, 0], off[:, 1])
        print(f"{name:44s} corners {len(ok):3d}/{len(rec)}  mean shift ({off[:, 0].mean():+.2f}, {off[:, 1].mean():+.2f})"
              f" GSD  RMS {np.sqrt(np.mean(d ** 2)):.2f}  max {d.max():.2f}  within 1 GSD {np.mean(d <= 1) * 100:5.1f} %")

    for name, surface, cfg in (("true surface", true_dsm(scene, dsm.grid, dsm.frame), OrthoConfig(square_buildings=False)),
                               ("matched DSM", dsm, OrthoConfig(square_buildings=False)),
                               ("matched DSM, buildings squared", dsm, OrthoConfig(square_refine=False)),
                               ("matched DSM, squared + walls refined", dsm, OrthoConfig())):
        t0 = time.perf_counter()
        m = orthomosaic(eo, cams, surface, loader, config=cfg)
        t1 = time.perf_counter()
        report(name, m)
        if name == "true surface":
            report("true surface moved by (+1.5 E, +1.0 N) cells", m, (1.5, -1.0))
        print(f"{'':44s} (ortho {t1 - t0:.0f} s, squared buildings {m.stats.get('buildings_squared', 0)})")


if __name__ == "__main__":
    main()
