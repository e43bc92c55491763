"""Façade textures and building extraction on the simulated MIDAS town (issue 11, deliverable 3).

Usage::

    .venv/bin/python bench/facades.py [--project /tmp/skyrig-acc/midas-dsm] [--json FILE] [--no-clip]
                                      [--extend DSM [--extend DSM ...]]

The project is a ``skyrig simulate midas-dsm --size ci`` folder with ``images/``, ``truth/eo.csv``, the adjusted
``output/adjust/eo.csv`` and the DSM matched from them ``output/dsm_adjusted/dsm.tif`` (as
``bench/dense_acceptance.py midas`` leaves it), or the ``simulated`` folder of ``skyrig demo -o DIR`` (the same
scenario; its DSM in ``output/dsm/dsm.tif``).  The truth is the scene of the same scenario rebuilt in memory
(``build_survey(scenario_spec("midas-dsm", "ci", 1))``): its buildings and its façade rule.

Cases (each: extraction figures, then texturing judged by :func:`skyrig.simulate.judge_facades.judge_facades`
over the façades textured from at least one oblique image):

``true``      true orientations (local ENU frame) + the analytic DSM rasterised in EPSG:25832 at the matched
              DSM's cell size, with the true buildings, the buildings extracted from that DSM, those after
              :func:`skyrig.dense.facades.refine_walls`, and those after
              :func:`skyrig.dense.facades.refine_wall_feet` too (``feet_buildings``: what ``skyrig facades`` does);
``adjusted``  adjusted orientations (EPSG:25832) + the matched DSM, with the true buildings, the buildings
              extracted from the matched DSM, those after ``refine_walls`` and after ``refine_wall_feet``.

``--extend DSM`` (repeatable; e.g. the DSMs ``skyrig dsm --heads left`` / ``--heads right`` match from the
obliques of one viewing direction): the matched DSM is extended beyond its surveyed area with them
(:func:`skyrig.dense.buildings.extend_dsm`, as ``skyrig facades --extend-dsm``) in both cases.

Buildings cut by the DSM's border are extracted too (``ExtractionConfig(clip_border=True)``, as ``skyrig facades``
does; their edges on the border get no texture).  Every case also reports the figure over all the scene's walls an
oblique sees (:func:`skyrig.simulate.judge_facades.walls_seen`, <= 60 deg incidence, from the truth):
``walls_seen``, ``walls_textured``, ``walls_within_1px`` and the same over the seen walls whose roof edge the DSM
measured (``*_in_dsm``; the others lie beyond the surveyed area).  ``--no-clip`` extracts as before (cut buildings
left out), for comparison.

``--footprints FILE`` (a GeoPackage with ``eave_m`` / ``ridge_m`` above the ground, as
:func:`skyrig.pipeline.simulate.write_scene_footprints` writes; ``--write-footprints FILE`` writes one from the
scene first: every building, heights perturbed by a seeded normal error of ``--height-sigma`` metres (default
0.3), plan by ``--plan-sigma`` (default 0)): two more sets per case, ``complete`` (the ``feet_buildings``
completed by the footprints no extracted building overlaps, as ``skyrig facades --footprint-mode complete``;
occlusions against the DSM with the footprint buildings burnt in where it has no heights) and ``footprints``
(every footprint a building, heights from the DSM where it measured the roof, else from the attributes; as
``--footprint-mode replace``); ``complete_feet`` / ``footprints_feet``: the same with the footprints' walls moved
onto their feet as the obliques show them (``refine_wall_feet``, as ``--refine-footprints``).  ``--cases`` /
``--sets`` restrict what runs (comma lists).

Speed: texels per second of :func:`skyrig.dense.facades.texture_facades` (occlusion march, per-texel best image,
feathering) next to a plain ``cv2.warpPerspective`` of each façade's first image onto the same texel grid (a
homography from the four corners: no distortion, no occlusion, one image), in the same run.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np


def _fmt(d: dict) -> str:
    return ", ".join(f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in d.items())


def extraction_figures(scene, blocks, frame) -> dict:
    from skyrig.simulate.judge_facades import judge_extraction

    ex = judge_extraction(scene, blocks, frame)
    ce = ex["corner_err_m"]
    return {"extracted": ex["extracted"], "matched": ex["matched"], "true": ex["true"],
            "rectangles": int(sum(len(b.footprint) == 4 for b in blocks)),
            "clipped": int(sum(bool(getattr(b, "clipped", False)) for b in blocks)),
            "corner_median_m": float(np.median(ce)) if len(ce) else float("nan"),
            "corner_p90_m": float(np.percentile(ce, 90)) if len(ce) else float("nan"),
            "corner_max_m": float(ce.max()) if len(ce) else float("nan"),
            "ground_median_m": float(np.median(ex["ground_err_m"])) if len(ce) else float("nan"),
            "eave_median_m": float(np.median(ex["eave_err_m"])) if len(ce) else float("nan"),
            "eave_max_abs_m": float(np.abs(ex["eave_err_m"]).max()) if len(ce) else float("nan"),
            "roof_type_right": int(ex["gabled_right"].sum())}


def warp_baseline(textures, eo, cameras, loader, frame) -> tuple[float, int]:
    """Seconds and texels of a plain homography warp of each textured façade's first image."""
    import cv2

    from skyrig.georef.eo import local_frame_for

    t_all, n = 0.0, 0
    pts = np.concatenate([t.facade.corners for t in textures])
    local = local_frame_for(frame.to_ecef(pts.mean(axis=0)[None]))
    eo_l = eo.to_frame(local)
    idx = {str(x): i for i, x in enumerate(eo.image)}
    for t in textures:
        if not t.images:
            continue
        k = idx[t.images[0]]
        img = loader(k)
        t0 = time.perf_counter()
        H, W = t.valid.shape
        c = t.facade.corners
        cl = local.from_ecef(frame.to_ecef(c))
        cam = cameras[str(eo_l.camera[k])]
        px = cam.project_pixels((cl - eo_l.centre[k]) @ eo_l.rotation[k]).astype(np.float32)
        w_m, h_m = W * t.texel_m, H * t.texel_m
        tx = np.float32([[0, H], [W, H], [W, 0], [0, 0]]) * np.float32([t.facade.width_m / w_m, t.facade.height_m / h_m])
        hm = cv2.getPerspectiveTransform(px, tx)
        cv2.warpPerspective(img, hm, (W, H), flags=cv2.INTER_LINEAR)
        t_all += time.perf_counter() - t0
        n += H * W
    return t_all, n


def _dsm_path(project: Path) -> Path:
    """The matched DSM: ``output/dsm_adjusted`` (bench/dense_acceptance.py) or ``output/dsm`` (``skyrig demo``)."""
    p = project / "output" / "dsm_adjusted" / "dsm.tif"
    return p if p.exists() else project / "output" / "dsm" / "dsm.tif"


SETS = ("true_buildings", "extracted_buildings", "refined_buildings", "feet_buildings", "complete", "footprints",
        "complete_feet", "footprints_feet")
FOOTPRINT_SETS = {"complete", "footprints", "complete_feet", "footprints_feet"}


def footprint_sets(feet, footprints: Path, dsm, refine=None):
    """``complete`` and ``footprints`` building sets (see the module docstring) and the occlusion surface of each;
    with ``refine`` (``(eo, cameras, loader)``) also ``complete_feet`` and ``footprints_feet``: the footprints'
    walls moved onto their feet as the obliques show them (:func:`skyrig.dense.facades.refine_wall_feet`, on the
    DSM with the footprint buildings burnt in)."""
    from skyrig.dense.buildings import FootprintHeights, buildings_from_footprints, surface_with_buildings
    from skyrig.dense.facades import refine_wall_feet
    from skyrig.pipeline.facades import _complete, read_footprint_layer

    fl = read_footprint_layer(footprints, dsm.frame, None, ["eave_m", "ridge_m"], max_height_m=500.0)
    hts = FootprintHeights(fl.heights["eave_m"], fl.heights["ridge_m"], "ground", f"{footprints.name} eave_m / ridge_m",
                           tuple(fl.labels))
    given = buildings_from_footprints(fl.rings, dsm, source=footprints.name, heights=hts)
    todo = [("complete", _complete(feet, given)), ("footprints", given)]
    if refine is not None:
        burnt = surface_with_buildings(dsm, [b for b in given if "; heights: " in str(b.source)])
        moved = refine_wall_feet(given, *refine, burnt)
        todo += [("complete_feet", _complete(feet, moved)), ("footprints_feet", moved)]
    out = {}
    for label, blocks in todo:
        surf = surface_with_buildings(dsm, [b for b in blocks if "; heights: " in str(b.source)])
        out[label] = (blocks, surf, sum("; heights: " in str(b.source) for b in blocks))
    return out


def run(project: Path, clip: bool = True, extend: list[Path] | None = None, cases: tuple[str, ...] = ("true", "adjusted"),
        sets: tuple[str, ...] = SETS, footprints: Path | None = None, texel_rule: str = "footprint") -> dict:
    from skyrig.dense.buildings import ExtractionConfig, extend_dsm, extract_buildings
    from skyrig.dense.facades import TextureConfig, refine_wall_feet, refine_walls, texture_facades
    from skyrig.io.dsm_cog import read_dsm_cog
    from skyrig.io.eo_csv import read_eo_csv
    from skyrig.io.rig_file import read_rig
    from skyrig.pipeline.dense import ImageFiles
    from skyrig.simulate.judge_facades import judge_facades, scene_dsm, true_buildings, walls_seen
    from skyrig.simulate.scenarios import build_survey, scenario_spec

    survey = build_survey(scenario_spec("midas-dsm", "ci", 1))
    scene = survey.scene
    rig = read_rig(project / "rig.yaml")
    cams = {h.camera.name: h.camera for h in rig.heads.values()}
    dsm_m = read_dsm_cog(_dsm_path(project))
    walls_dsm = dsm_m  # "in the DSM" figures: the nadir DSM's surveyed area
    if extend:
        t0 = time.perf_counter()
        dsm_m = extend_dsm(dsm_m, [read_dsm_cog(p) for p in extend])
        print(f"DSM extended by {dsm_m.metadata['extended_by']['cells']} cells of {len(extend)} DSM(s) "
              f"({time.perf_counter() - t0:.1f} s)", flush=True)
    eo_adj = read_eo_csv(project / "output" / "adjust" / "eo.csv")
    eo_true = read_eo_csv(project / "truth" / "eo.csv")
    frame = dsm_m.frame
    t0 = time.perf_counter()
    dsm_a = scene_dsm(scene, dsm_m.grid, frame)
    print(f"analytic DSM on the matched DSM's grid {dsm_m.grid.shape} ({time.perf_counter() - t0:.1f} s)", flush=True)
    out: dict = {}
    for case, eo, dsm in (("true", eo_true, dsm_a), ("adjusted", eo_adj, dsm_m)):
        if case not in cases:
            continue
        loader = ImageFiles([str(project / "images" / n) for n in eo.image],
                            [(cams[c].width, cams[c].height) for c in eo.camera])
        oblique = {str(n) for n in eo.image if "nadir" not in str(n)}
        walls = walls_seen(scene, eo, cams, oblique)
        t0 = time.perf_counter()
        extracted = extract_buildings(dsm, config=ExtractionConfig(clip_border=clip))
        te = time.perf_counter() - t0
        ex = extraction_figures(scene, extracted, frame)
        ex["seconds"] = te
        print(f"[{case}] extraction: {_fmt(ex)}", flush=True)
        out[case] = {"extraction": ex}
        t0 = time.perf_counter()
        refined = refine_walls(extracted, eo, cams, loader, dsm)
        rx = extraction_figures(scene, refined, frame)
        rx["seconds"] = time.perf_counter() - t0
        print(f"[{case}] extraction + refine_walls: {_fmt(rx)}", flush=True)
        out[case]["refined"] = rx
        t0 = time.perf_counter()
        feet = refine_wall_feet(refined, eo, cams, loader, dsm)
        fx = extraction_figures(scene, feet, frame)
        fx["seconds"] = time.perf_counter() - t0
        print(f"[{case}] extraction + refine_walls + refine_wall_feet: {_fmt(fx)}", flush=True)
        out[case]["feet"] = fx
        todo = [(label, blocks, dsm) for label, blocks in (
            ("true_buildings", true_buildings(scene, frame)), ("extracted_buildings", extracted),
            ("refined_buildings", refined), ("feet_buildings", feet)) if label in sets]
        if footprints is not None and FOOTPRINT_SETS & set(sets):
            rf = (eo, cams, loader) if {"complete_feet", "footprints_feet"} & set(sets) else None
            for label, (blocks, surf, n_att) in footprint_sets(feet, footprints, dsm, rf).items():
                if label in sets:
                    print(f"[{case}] {label}: {len(blocks)} buildings, {n_att} with heights from the attributes, "
                          f"{surf.metadata.get('buildings_burnt', {}).get('cells', 0)} occlusion cells burnt in",
                          flush=True)
                    todo.append((label, blocks, surf))
        for label, blocks, surf in todo:
            t0 = time.perf_counter()
            tex = texture_facades(blocks, eo, cams, loader, surf, config=TextureConfig(texel_rule=texel_rule))
            tt = time.perf_counter() - t0
            _, summ = judge_facades(scene, tex, frame, oblique, walls=walls, dsm=walls_dsm)
            texels = int(sum(t.valid.size for t in tex if t.images))
            summ["seconds"] = tt
            summ["texels"] = texels
            summ["occluded_filled_fraction"] = summ["occluded_filled"] / max(summ["occluded_in_best"], 1)
            if case == "true" and label == "true_buildings":
                tw, nw = warp_baseline(tex, eo, cams, loader, frame)
                summ["warp_seconds"] = tw
                summ["texels_per_s"] = texels / tt
                summ["warp_texels_per_s"] = nw / max(tw, 1e-9)
            print(f"[{case}] {label}: {_fmt(summ)}", flush=True)
            out[case][label] = summ
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--project", default="/tmp/skyrig-acc/midas-dsm", type=Path)
    ap.add_argument("--json", type=Path)
    ap.add_argument("--no-clip", action="store_true", help="leave out the buildings cut by the DSM's border")
    ap.add_argument("--extend", type=Path, action="append", default=[],
                    help="a DSM beyond the matched DSM's surveyed area (e.g. from one direction's obliques); repeat")
    ap.add_argument("--cases", default="true,adjusted", help="comma list of cases: true, adjusted")
    ap.add_argument("--sets", default=",".join(SETS), help="comma list of building sets: " + ", ".join(SETS))
    ap.add_argument("--footprints", type=Path, help="footprints GeoPackage (eave_m, ridge_m above the ground)")
    ap.add_argument("--write-footprints", type=Path,
                    help="write the scene's footprints (every building, perturbed heights) here first and use them")
    ap.add_argument("--height-sigma", type=float, default=0.3, help="--write-footprints: height error (m, seeded)")
    ap.add_argument("--plan-sigma", type=float, default=0.0, help="--write-footprints: plan error per building (m)")
    ap.add_argument("--seed", type=int, default=0, help="--write-footprints: seed of the errors")
    ap.add_argument("--texel-rule", default="footprint", choices=("footprint", "pixel_area"),
                    help="default texel size from the best image (skyrig.dense.facades.TextureConfig.texel_rule)")
    a = ap.parse_args(argv)
    for need in ("images", "truth/eo.csv", "output/adjust/eo.csv", str(_dsm_path(a.project).relative_to(a.project)),
                 "rig.yaml"):
        if not (a.project / need).exists():
            print(f"{a.project / need} is missing: run bench/dense_acceptance.py midas first", file=sys.stderr)
            return 2
    for p in a.extend:
        if not p.is_file():
            print(f"{p} is missing", file=sys.stderr)
            return 2
    fp = a.footprints
    if a.write_footprints is not None:
        from skyrig.io.dsm_cog import read_dsm_cog
        from skyrig.pipeline.simulate import write_scene_footprints
        from skyrig.simulate.scenarios import build_survey, scenario_spec

        crs = read_dsm_cog(_dsm_path(a.project)).frame.crs
        w = write_scene_footprints(a.write_footprints, build_survey(scenario_spec("midas-dsm", "ci", 1)).scene, crs,
                                   height_sigma_m=a.height_sigma, plan_sigma_m=a.plan_sigma, seed=a.seed)
        print(f"wrote {len(w['ids'])} footprints to {a.write_footprints} ({crs}; height errors RMS "
              f"{np.sqrt(np.mean(w['height_error_m'] ** 2)):.3f} m, plan errors RMS "
              f"{np.sqrt(np.mean(np.sum(w['plan_error_m'] ** 2, axis=1))):.3f} m)", flush=True)
        fp = a.write_footprints
    res = run(a.project, clip=not a.no_clip, extend=a.extend, cases=tuple(a.cases.split(",")),
              sets=tuple(a.sets.split(",")), footprints=fp, texel_rule=a.texel_rule)
    if a.json:
        a.json.write_text(json.dumps(res, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
