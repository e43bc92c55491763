"""Roof corners of the true orthomosaic of the simulated MIDAS town (``make demo``'s flight), judged by the roof
outline's edges (:func:`skyrig.simulate.judge.roof_outline_offsets`).

Reads a finished demo output (``skyrig demo DIR``: ``DIR/simulated``): the adjusted orientations, the images and the
matched DSM.  Prints, for the nadir orthomosaic on

* the scene's true surface sampled on the matched DSM's grid (``square_buildings=False``): the earlier reference.
  Its corners are off by up to ~1.5 GSD, not because the measure is noisy (on the scene's own colours rendered
  straight onto the grid, shifted by a known sub-cell amount, it is within 0.2 GSD, ``tests/test_ortho_judge.py``)
  but because a raster surface puts every wall between two cell centres: interpolated heights put part-way-down
  heights inside the roof edge and the depth buffer a slanted wall outside it, so the roof edge moves to and fro
  by up to a DSM cell along the wall;
* the same true surface at a third of the cell (the raster's part in the above);
* the true surface with the scene's own buildings drawn with sharp edges (``buildings=`` true blocks,
  ``square_refine=False``; :func:`skyrig.dense.ortho.sharp_heights`, :func:`skyrig.dense.ortho.snap_lattice`): the
  floor of the ortho's geometry with perfect buildings,
* that mosaic moved by (+1.5, -1.0) cells (the measure must report that shift),
* the matched DSM as it is (``square_buildings=False``),
* the matched DSM with the buildings squared from the DSM's footprints (``square_refine=False``), edges on the
  DSM's cells (``square_sharp=False``, the session-9 default) and sharp,
* the matched DSM with the buildings squared after their walls were moved onto the outline in the images, edges
  on the DSM's cells (session 9) and sharp (default, ``skyrig ortho`` / ``make demo``),

the judged corners (of 4 per scene building; the others lack a seen outside or inside), RMS / max offset, the
share within 1 GSD (the issue's acceptance: roof corners within 1 GSD of their true positions) and the corners
beyond 1 GSD.

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
        far = ", ".join(f"{r['building']}/{r['corner']} {x:.2f}" for x, r in sorted(zip(d, ok), key=lambda t: -t[0])
                        if x > 1.0 and shift is None)
        print(f"{name:44s} corners {len(ok):3d}/{len(rec)}  mean shift ({off[:, 0].mean():+.2f}, {off[:, 1].mean():+.2f})"
              f" GSD  RMS {np.sqrt(np.mean(d ** 2)):.2f}  max {d.max():.2f}  within 1 GSD {np.mean(d <= 1) * 100:5.1f} %"
              + (f"  beyond 1 GSD (building/corner): {far}" if far else ""))

    from skyrig.dense.grid import GridSpec
    from skyrig.simulate.judge_facades import true_buildings

    g = dsm.grid
    fine = GridSpec(g.x0, g.y0, g.cell_m / 3, g.width * 3, g.height * 3)
    tdsm = true_dsm(scene, dsm.grid, dsm.frame)
    rows = (("true surface (DSM cells)", tdsm, OrthoConfig(square_buildings=False), {}),
            ("true surface (1/3 DSM cell)", true_dsm(scene, fine, dsm.frame), OrthoConfig(square_buildings=False), {}),
            ("true surface, true buildings sharp", tdsm, OrthoConfig(square_refine=False),
             {"buildings": true_buildings(scene, dsm.frame)}),
            ("matched DSM", dsm, OrthoConfig(square_buildings=False), {}),
            ("matched DSM, squared, on cells", dsm, OrthoConfig(square_refine=False, square_sharp=False), {}),
            ("matched DSM, squared, sharp", dsm, OrthoConfig(square_refine=False), {}),
            ("matched DSM, squared + refined, on cells", dsm, OrthoConfig(square_sharp=False), {}),
            ("matched DSM, squared + refined, sharp", dsm, OrthoConfig(), {}))
    for name, surface, cfg, kw in rows:
        t0 = time.perf_counter()
        m = orthomosaic(eo, cams, surface, loader, config=cfg, **kw)
        t1 = time.perf_counter()
        report(name, m)
        if name.startswith("true surface, true buildings"):
            report("  the same moved by (+1.5 E, +1.0 N) cells", m, (1.5, -1.0))
        print(f"{'':44s} (ortho {t1 - t0:.0f} s, squared buildings {m.stats.get('buildings_squared', 0)})")


if __name__ == "__main__":
    main()
