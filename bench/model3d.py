"""Textured 3D model figures (issue 11): GLB size / write time, round trip, viewer in headless Chromium, and
``skyrig facades`` on a simulated project judged against its scene.

Part 1 (always): the simulator's true town (``make_scene``, N houses) as blocks in EPSG:25832 with façade textures
painted from the façade rule at ``--texel``: time of build_model / write_glb / write_obj / write_viewer, GLB size,
round trip of every vertex to the map CRS through the recorded origin (skyrig.io.gltf.model_points_to_frame)
against the blocks' corners.

Part 2 (``--project DIR``, a simulated project with ``images/``, ``rig.yaml``, ``scene/scene.json``, an adjusted
``output/adjust/eo.csv`` and a DSM ``output/dsm_adjusted/dsm.tif``): ``skyrig facades`` into ``--out`` (optionally
with ``--ortho``), its wall time and summary, the buildings against the scene (``judge_model``), the viewer in
headless Chromium with a screenshot (``--screenshot``).

    .venv/bin/python bench/model3d.py
    .venv/bin/python bench/model3d.py --project /tmp/skyrig-acc/midas-dsm --out /tmp/h/B/midas-facades \\
        --ortho /tmp/h/B/midas-ortho/ortho.tif --screenshot /tmp/h/viewer.png
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def town_figures(n_buildings: int, texel: float, chromium: bool) -> dict:
    from skyrig.dense.model import build_model
    from skyrig.geodesy.frame import WorldFrame
    from skyrig.io.gltf import glb_problems, read_glb, accessor_array, model_points_to_frame, write_glb, write_obj
    from skyrig.report.viewer import chromium_check, find_chromium, write_viewer
    from skyrig.simulate.judge_model import true_buildings, true_facade_textures
    from skyrig.simulate.world import make_scene

    scene = make_scene(1, (-250.0, -250.0, 250.0, 250.0), n_buildings=n_buildings)
    frame = WorldFrame.map("EPSG:25832")
    blocks = true_buildings(scene, frame)
    t = time.perf_counter()
    tex = true_facade_textures(scene, blocks, frame, texel)
    t_tex = time.perf_counter() - t
    out: dict = {"buildings": len(blocks), "facades": len(tex), "texel_m": texel,
                 "texels_M": round(sum(x.rgb.shape[0] * x.rgb.shape[1] for x in tex) / 1e6, 3),
                 "paint_textures_s": round(t_tex, 2)}
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        t = time.perf_counter()
        model = build_model(blocks, tex, frame)
        out["build_model_s"] = round(time.perf_counter() - t, 3)
        for fmt in ("png", "jpeg"):
            t = time.perf_counter()
            write_glb(d / f"m_{fmt}.glb", model, image_format=fmt)
            out[f"write_glb_{fmt}_s"] = round(time.perf_counter() - t, 3)
            out[f"glb_{fmt}_MB"] = round((d / f"m_{fmt}.glb").stat().st_size / 1e6, 3)
        t = time.perf_counter()
        write_obj(d / "obj" / "m.obj", model)
        out["write_obj_s"] = round(time.perf_counter() - t, 3)
        t = time.perf_counter()
        write_viewer(d / "viewer.html", d / "m_png.glb")
        out["write_viewer_s"] = round(time.perf_counter() - t, 3)
        out["viewer_MB"] = round((d / "viewer.html").stat().st_size / 1e6, 3)
        out["glb_problems"] = glb_problems(d / "m_png.glb")
        out["triangles"] = model.n_triangles
        gltf, binary = read_glb(d / "m_png.glb")
        worst = 0.0
        for node in gltf["nodes"]:
            b = blocks[node["extras"]["building"]]
            fp = np.asarray(b.footprint)
            corners = np.vstack([np.column_stack([fp, np.full(len(fp), b.ground_z)]),
                                 np.column_stack([fp, np.full(len(fp), b.eave_z)])] + [np.asarray(r) for r in b.roof])
            for pr in gltf["meshes"][node["mesh"]]["primitives"]:
                p = model_points_to_frame(accessor_array(gltf, binary, pr["attributes"]["POSITION"]), gltf, frame)
                worst = max(worst, float(np.linalg.norm(p[:, None] - corners[None], axis=2).min(axis=1).max()))
        out["round_trip_worst_mm"] = round(worst * 1000, 4)
        if chromium and find_chromium():
            st = chromium_check(d / "viewer.html", timeout_s=180)
            out["chromium"] = st
    return out


def project_figures(project: Path, outdir: Path, ortho: Path | None, screenshot: Path | None) -> dict:
    from skyrig.io.gltf import glb_problems
    from skyrig.report.viewer import chromium_check, find_chromium
    from skyrig.simulate.judge_model import judge_model, scene_from_dict

    cmd = [str(Path(sys.executable).parent / "skyrig"), "facades", "--dsm", str(project / "output/dsm_adjusted/dsm.tif"),
           "--eo", str(project / "output/adjust/eo.csv"), "--camera", str(project / "rig.yaml"),
           "--images", str(project / "images"), "-o", str(outdir)]
    if ortho is not None:
        cmd += ["--ortho", str(ortho)]
    t = time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t
    if res.returncode != 0:
        raise SystemExit(f"skyrig facades failed ({res.returncode}): {res.stderr}")
    summary = json.loads((outdir / "facades.json").read_text())
    out = {"cli_wall_s": round(wall, 2), "cli_output": res.stdout.strip(),
           **{k: summary[k] for k in ("buildings", "facades", "facades_seen", "coverage_median", "texel_median_m",
                                      "roofs", "triangles", "glb_bytes", "seconds")}}
    out["glb_problems"] = glb_problems(outdir / "model.glb")
    # the model's buildings (buildings.gpkg) against the scene
    import shapely
    from pyogrio.raw import read

    from skyrig.dense.buildings import BuildingBlock
    from skyrig.geodesy.frame import WorldFrame

    scene = scene_from_dict(json.loads((project / "scene/scene.json").read_text()))
    meta, _, geoms, fields = read(str(outdir / "buildings.gpkg"), layer="buildings")
    cols = dict(zip(meta["fields"], fields))
    rmeta, _, rgeoms, rfields = read(str(outdir / "buildings.gpkg"), layer="roofs")
    rb = dict(zip(rmeta["fields"], rfields))["building"]
    blocks = []
    for k, g in enumerate(geoms):
        poly = np.asarray(shapely.from_wkb(g).exterior.coords)[:-1, :2]
        roofs = tuple(np.asarray(shapely.from_wkb(r).exterior.coords)[:-1] for r, b in zip(rgeoms, rb) if b == cols["id"][k])
        blocks.append(BuildingBlock(int(cols["id"][k]), poly, float(cols["ground_z"][k]), float(cols["eave_z"][k]), roofs))
    frame = WorldFrame.from_text(summary["frame"])
    j = judge_model(blocks, frame, scene, match_radius_m=5.0)
    out["judge"] = {k: (round(v, 4) if isinstance(v, float) else v) for k, v in j.items() if k != "per_building"}
    # how many true buildings lie inside the DSM at all
    from skyrig.io.dsm_cog import read_dsm_cog

    dsm = read_dsm_cog(project / "output/dsm_adjusted/dsm.tif")
    b = dsm.grid.bounds
    loc = WorldFrame.local(*scene.origin)
    c = loc.points_to(np.column_stack([scene.buildings.cx, scene.buildings.cy, scene.buildings.eave_z]), frame)
    out["judge"]["true_buildings_inside_dsm"] = int(np.sum((c[:, 0] > b[0]) & (c[:, 0] < b[2]) & (c[:, 1] > b[1]) & (c[:, 1] < b[3])))
    if find_chromium():
        out["chromium"] = chromium_check(outdir / "viewer.html", screenshot=screenshot, timeout_s=180)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--buildings", type=int, default=20)
    ap.add_argument("--texel", type=float, default=0.1)
    ap.add_argument("--project", type=Path, default=None)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--ortho", type=Path, default=None)
    ap.add_argument("--screenshot", type=Path, default=None)
    ap.add_argument("--no-chromium", action="store_true")
    ap.add_argument("--json", type=Path, default=None, help="Write the figures here too.")
    a = ap.parse_args()
    figs = {"town": town_figures(a.buildings, a.texel, not a.no_chromium)}
    print(json.dumps(figs, indent=1))
    if a.project is not None:
        if a.out is None:
            raise SystemExit("--out is needed with --project")
        figs["project"] = project_figures(a.project, a.out, a.ortho, a.screenshot)
        print(json.dumps(figs["project"], indent=1))
    if a.json:
        a.json.write_text(json.dumps(figs, indent=1) + "\n")


if __name__ == "__main__":
    main()
