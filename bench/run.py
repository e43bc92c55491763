"""Time and peak memory of every stage of a simulated project run (``skyrig init`` + ``skyrig run``).

    .venv/bin/python bench/run.py                                  # midas-demo (CI size, 20 images)
    .venv/bin/python bench/run.py --scenario midas-demo --scenario midas --executor local --workers 2
    .venv/bin/python bench/run.py --scenario tumblecam --max-features 3000 --json figures.json
    .venv/bin/python bench/run.py --grow 1 2          # the midas-dsm 80/60 surface block, area x1, x2
    .venv/bin/python bench/run.py --grow 1 2 --only dsm --dsm-tile-cells 512   # one stage again (after --keep)
    .venv/bin/python bench/run.py --grow 1 2 3 --only dsm --dsm-tile-memory-mb 0   # dsm tiles of tile_cells (no budget)

For each scenario: ``skyrig simulate SCENARIO --size ci`` (timed) into ``--workdir``, ``skyrig init`` on it, the
executor and the matcher's feature count set in the project file, then each stage in its own child process
(``run_project(only=STAGE, force=True)``, in the project's order, so that one stage's peak memory does not hide
the next): wall time and the child's peak resident memory (``VmHWM``, which exec resets - unlike ``ru_maxrss``,
which a child inherits from the process that forked it - and ``ru_maxrss`` of its own children for Dask worker
processes).  Then a whole ``skyrig run`` that must skip every stage (the resume cost: fingerprints,
manifest checks).  ``--grow K ...`` flies the ``midas-dsm`` surface block (CI: 3 strips over 100 m x 100 m,
60 images) over a K times wider and longer area with 3 K strips (about K^2 x 60 images), one project per K.
Scenarios beyond CI size (the issue's 500 exposures / 2,500 images) need ``--size full``
projects that take hours to render on a small machine; ``--size`` is passed to ``skyrig simulate``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

CHILD = r"""
import json, resource, sys, time
from skyrig.pipeline.project import load_project
from skyrig.pipeline.run import run_project
t0 = time.perf_counter()
proj = load_project(sys.argv[1])
t1 = time.perf_counter()
res = run_project(proj, only=sys.argv[2], force=True)
t2 = time.perf_counter()
me = next(int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("VmHWM")) / 1024  # reset at exec
kids = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
cpu = sum(getattr(resource.getrusage(w), f) for w in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)
          for f in ("ru_utime", "ru_stime"))  # the stage process and its reaped worker processes
row = next(r for r in res.stages if r["stage"] == sys.argv[2])
print("BENCH " + json.dumps({"exit": res.exit_code, "error": res.error, "load_s": t1 - t0, "stage_s": row.get("seconds"),
                             "wall_s": t2 - t0, "cpu_s": cpu, "peak_mib": me, "children_peak_mib": kids,
                             "summary": row.get("summary")}))
"""


def _skyrig() -> str:
    return str(Path(sys.executable).parent / "skyrig")


def _simulate_grown(folder: Path, k: int, image_scale: float = 1.0) -> None:
    """The ``midas-dsm`` surface block over a ``k`` times wider and longer area with ``3 k`` strips.

    ``image_scale`` F scales every head's sensor (width and height in pixels) by F with the same field of view
    (the pixel pitch grows by 1/F, the focal length in mm stays, so the focal length in pixels scales by F): the
    footprints, the flight plan and the block geometry stay the same and the GSD grows by 1/F.  The scene
    (1 km x 1 km at CI size) is widened, at the same building density, where the block and its oblique
    footprints would leave it (K >= 4)."""
    from dataclasses import replace

    from skyrig.pipeline.simulate import write_project
    from skyrig.simulate.scenarios import build_survey, ci_camera, scenario_spec

    spec = scenario_spec("midas-dsm", "ci", 1)
    f = spec.flights[0]
    half = 50.0 * k
    ext = max(500.0, half + 300.0)
    spec = replace(spec, name=f"midas-dsm-x{k}", flights=(replace(f, n_strips=3 * k, area=(-half, -half, half, half)),))
    if ext > 500.0:
        spec = replace(spec, scene_extent=(-ext, -ext, ext, ext),
                       n_buildings=int(round(spec.n_buildings * (ext / 500.0) ** 2)))
    if image_scale != 1.0:
        if not 0.05 <= image_scale <= 1.0:
            raise SystemExit(f"--image-scale must lie in [0.05, 1], not {image_scale}")
        heads = {n: h.with_(camera=ci_camera(h.camera, int(round(h.camera.width * image_scale))))
                 for n, h in spec.rig.heads.items()}
        spec = replace(spec, rig=replace(spec.rig, heads=heads))
    write_project(build_survey(spec), folder)


def bench_scenario(name: str, size: str, workdir: Path, executor: str, workers: int | None, max_features: int,
                   keep: bool, grow: int | None = None, image_scale: float = 1.0,
                   max_pairs_per_image: int | None = None, dsm_tile_cells: int | None = None,
                   only: list[str] | None = None, snooping_share: float | None = None,
                   dsm_tile_memory_mb: float | None = None) -> dict:
    tag = "" if image_scale == 1.0 else f"-s{image_scale:g}"
    folder = workdir / (f"{name}-x{grow}{tag}" if grow is not None else f"{name}-{size}")
    out: dict = {"scenario": name if grow is None else f"{name}-x{grow}{tag}", "size": size, "stages": [],
                 "image_scale": image_scale, "grow": grow}
    if not (folder / "truth" / "truth.json").is_file():
        t0 = time.perf_counter()
        if grow is not None:
            _simulate_grown(folder, grow, image_scale)
        else:
            subprocess.run([_skyrig(), "simulate", name, "-o", str(folder), "--size", size], check=True,
                           stdout=subprocess.DEVNULL)
        out["simulate_s"] = time.perf_counter() - t0
    proj = folder / "project.yaml"
    subprocess.run([_skyrig(), "init", str(folder), "--force"], check=True, stdout=subprocess.DEVNULL)
    text = proj.read_text().replace("  kind: auto ", f"  kind: {executor} ")
    if workers:
        text = text.replace("  workers: null ", f"  workers: {workers} ")
    text = text.replace("    # max_features: 8000 ", f"    max_features: {max_features} ")
    if max_pairs_per_image is not None:
        text = text.replace("    # max_pairs_per_image: 12 ", f"    max_pairs_per_image: {max_pairs_per_image} ")
    out["max_pairs_per_image"] = max_pairs_per_image
    if dsm_tile_cells is not None:
        text = text.replace("    # tile_cells: 2048    # ground tile side in cells", f"    tile_cells: {dsm_tile_cells}")
    out["dsm_tile_cells"] = dsm_tile_cells
    if dsm_tile_memory_mb is not None:
        line = next(ln for ln in text.splitlines() if ln.startswith("    # tile_memory_mb: "))
        text = text.replace(line, f"    tile_memory_mb: {dsm_tile_memory_mb if dsm_tile_memory_mb > 0 else 'null'}")
    out["dsm_tile_memory_mb"] = dsm_tile_memory_mb
    if snooping_share is not None:
        line = next(ln for ln in text.splitlines() if ln.startswith("    # snooping_per_round_share: "))
        text = text.replace(line, f"    snooping_per_round_share: {snooping_share}")
    out["snooping_per_round_share"] = snooping_share
    proj.write_text(text)
    truth = json.loads((folder / "truth" / "truth.json").read_text())
    out["images"] = truth.get("statistics", {}).get("images")
    out["megapixels"] = truth.get("statistics", {}).get("megapixels")
    from skyrig.pipeline.project import load_project

    stages = [s.name for s in load_project(proj).stages]
    if only:
        unknown = sorted(set(only) - set(stages))
        if unknown:
            raise SystemExit(f"--only: no stage {', '.join(unknown)} in {proj} (stages: {', '.join(stages)})")
        stages = [st for st in stages if st in only]
    for st in stages:
        r = subprocess.run([sys.executable, "-c", CHILD, str(proj), st], capture_output=True, text=True)
        line = next((ln for ln in r.stdout.splitlines() if ln.startswith("BENCH ")), None)
        if line is None:
            out["stages"].append({"stage": st, "exit": r.returncode, "error": r.stderr[-500:]})
            break
        row = {"stage": st, **json.loads(line[6:])}
        out["stages"].append(row)
        print(f"  {out['scenario']:12s} {st:10s} {row['stage_s'] or 0:8.1f} s  (CPU {row['cpu_s']:6.1f} s)  "
              f"peak {row['peak_mib']:7.0f} MiB"
              f"  (workers {row['children_peak_mib']:6.0f} MiB)  exit {row['exit']}", flush=True)
        if row["exit"]:
            break
    if only:  # a resume run would run the stages after these again
        return out
    t0 = time.perf_counter()
    r = subprocess.run([_skyrig(), "run", str(proj)], capture_output=True, text=True)
    out["resume_all_skipped_s"] = time.perf_counter() - t0
    out["resume_skipped"] = r.stderr.count("skipped (up to date)")
    print(f"  {out['scenario']:12s} resume run: {out['resume_all_skipped_s']:.1f} s, {out['resume_skipped']} of {len(stages)} "
          "stages skipped", flush=True)
    if not keep:
        import shutil

        shutil.rmtree(folder / "output", ignore_errors=True)
    return out


def _growth(rows: list[dict], ks: list[int], k_to: int) -> dict:
    """Per stage, the exponent b of time ~ images^b and peak memory ~ images^b (log-log least squares over
    the sizes whose stage ran), and the projection to ``k_to`` from the largest size with that exponent
    (images at ``k_to`` from the images per K^2 of the largest size)."""
    import numpy as np

    n = np.array([float(r["images"] or 0) for r in rows])
    n_to = n[-1] * (k_to / ks[-1]) ** 2
    out: dict = {"k_to": k_to, "images_projected": int(round(n_to)), "stages": {}}

    def fit(x: np.ndarray, y: np.ndarray) -> float:
        ok = (x > 0) & (y > 0)
        if ok.sum() < 2:
            return float("nan")
        return float(np.polyfit(np.log(x[ok]), np.log(y[ok]), 1)[0])

    names = [s["stage"] for s in rows[0]["stages"]]
    for st in names:
        t = np.array([next((s.get("stage_s") or 0 for s in r["stages"] if s["stage"] == st), 0.0) for r in rows])
        m = np.array([next((max(s.get("peak_mib") or 0, s.get("children_peak_mib") or 0)
                            for s in r["stages"] if s["stage"] == st), 0.0) for r in rows])
        bt, bm = fit(n, t), fit(n, m)
        out["stages"][st] = {"b_time": bt, "b_mem": bm, "projected_s": float(t[-1] * (n_to / n[-1]) ** bt),
                             "projected_mib": float(m[-1] * (n_to / n[-1]) ** bm)}
    tt = np.array([sum(s.get("stage_s") or 0 for s in r["stages"]) for r in rows])
    bt = fit(n, tt)
    out["total"] = {"b_time": bt, "projected_s": float(tt[-1] * (n_to / n[-1]) ** bt),
                    "projected_sum_of_stages_s": float(sum(g["projected_s"] for g in out["stages"].values()
                                                           if np.isfinite(g["projected_s"])))}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenario", action="append", help="skyrig simulate scenario (repeatable; default midas-demo)")
    ap.add_argument("--size", default="ci", choices=["ci", "full"])
    ap.add_argument("--grow", type=int, nargs="+", default=None,
                    help="midas-dsm surface block over K x the CI area (3 K strips), one run per K")
    ap.add_argument("--image-scale", type=float, default=1.0,
                    help="with --grow: every head's sensor width/height in pixels x F at the same field of view "
                    "(GSD / F, same footprints and block geometry), e.g. 0.25 for fast grown blocks")
    ap.add_argument("--project-to", type=int, default=7,
                    help="with --grow over >= 2 sizes: project each stage's time and peak memory to this K")
    ap.add_argument("--workdir", default="/tmp/skyrig-bench-run", help="where projects are simulated (kept: reruns "
                    "reuse them)")
    ap.add_argument("--executor", default="serial", choices=["serial", "local", "auto"])
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--max-features", type=int, default=3000)
    ap.add_argument("--max-pairs-per-image", type=int, default=None,
                    help="stages.match.max_pairs_per_image (guided pairs' per-image budget; 0 = every overlapping "
                    "pair; default: the stage's default)")
    ap.add_argument("--dsm-tile-cells", type=int, default=None,
                    help="stages.dsm.tile_cells (ground tile side in cells; default: the stage's default)")
    ap.add_argument("--dsm-tile-memory-mb", type=float, default=None,
                    help="stages.dsm.tile_memory_mb (memory budget of a ground tile's work, MiB; 0: null, tiles of "
                    "tile_cells; default: the stage's default)")
    ap.add_argument("--snooping-per-round-share", type=float, default=None,
                    help="stages.block.snooping_per_round_share (e.g. 0.001: snooping's rounds do not grow with the "
                    "block; default: the stage's default, 0)")
    ap.add_argument("--only", nargs="+", default=None, metavar="STAGE",
                    help="run only these stages (the earlier stages' outputs must be there: an earlier run with "
                    "--keep), e.g. --only dsm")
    ap.add_argument("--keep", action="store_true", help="keep the run outputs")
    ap.add_argument("--json", default=None, help="write the figures here")
    ap.add_argument("--report", default=None, metavar="JSON",
                    help="only print the tables (and growth) of figures written by an earlier --json run")
    a = ap.parse_args()
    if a.report:
        rows = [r for r in json.loads(Path(a.report).read_text()) if "stages" in r]
        _print_tables(rows, a.project_to)
        return
    work = Path(a.workdir)
    work.mkdir(parents=True, exist_ok=True)
    rows: list[dict] = []

    def save() -> None:  # after every size, so that a cut-off run keeps its figures
        if a.json:
            tmp = Path(a.json + ".tmp")
            tmp.write_text(json.dumps(rows, indent=1, default=str) + "\n")
            tmp.replace(a.json)

    if a.grow:
        for k in a.grow:
            print(f"midas-dsm x{k}, executor {a.executor}", flush=True)
            rows.append(bench_scenario("midas-dsm", a.size, work, a.executor, a.workers, a.max_features,
                                       a.keep or bool(a.only), k, a.image_scale, a.max_pairs_per_image,
                                       a.dsm_tile_cells, a.only, a.snooping_per_round_share,
                                       a.dsm_tile_memory_mb))
            save()
    for name in a.scenario or ([] if a.grow else ["midas-demo"]):
        print(f"{name} ({a.size}), executor {a.executor}", flush=True)
        rows.append(bench_scenario(name, a.size, work, a.executor, a.workers, a.max_features, a.keep or bool(a.only),
                                   max_pairs_per_image=a.max_pairs_per_image, dsm_tile_cells=a.dsm_tile_cells,
                                   only=a.only, snooping_share=a.snooping_per_round_share,
                                   dsm_tile_memory_mb=a.dsm_tile_memory_mb))
        save()
    growth = _print_tables(rows, a.project_to)
    if growth is not None:
        rows.append({"growth": growth})
    save()


def _print_tables(rows: list[dict], k_to: int) -> dict | None:
    """The time and peak-memory tables; with >= 2 grown sizes, the growth exponents and projection to ``k_to``."""
    names = max((r["stages"] for r in rows), key=len)
    names = [s["stage"] for s in names]

    def cell(r: dict, st: str, key) -> float | None:
        s = next((s for s in r["stages"] if s["stage"] == st), None)
        return None if s is None or s.get("exit") else key(s)

    def fmt(v: float | None, spec: str) -> str:
        return f"{'-':>10s}" if v is None else format(v, spec)

    print("\nseconds        images     MP  " + "  ".join(f"{st:>10s}" for st in names)
          + "   total s  resume s  match pairs (kept/overlapping)")
    for r in rows:
        tot = sum(s.get("stage_s") or 0 for s in r["stages"])
        summ = next(((s.get("summary") or {}) for s in r["stages"] if s["stage"] == "match"), {})
        pairs = summ.get("pairs")
        if pairs is not None and summ.get("pairs_overlapping") is not None:
            pairs = f"{pairs}/{summ['pairs_overlapping']}"
        print(f"{r['scenario']:14s} {r['images'] or 0:7d} {r['megapixels'] or 0:6.1f}  "
              + "  ".join(fmt(cell(r, st, lambda s: s.get("stage_s") or 0.0), "10.1f") for st in names)
              + f"  {tot:8.1f}  {r.get('resume_all_skipped_s', 0.0):8.1f}  {pairs if pairs is not None else '-':>11}")
    print("\npeak MiB       images     MP  " + "  ".join(f"{st:>10s}" for st in names))
    for r in rows:
        print(f"{r['scenario']:14s} {r['images'] or 0:7d} {r['megapixels'] or 0:6.1f}  "
              + "  ".join(fmt(cell(r, st, lambda s: max(s.get("peak_mib") or 0, s.get("children_peak_mib") or 0)),
                              "10.0f") for st in names))
    grown = [r for r in rows if r.get("grow") is not None and all(not s.get("exit") for s in r["stages"])]
    if len(grown) < 2:
        return None
    growth = _growth(grown, [r["grow"] for r in grown], k_to)
    print(f"\ngrowth: t ~ images^b (log-log least squares over {len(grown)} complete sizes); projection to K={k_to} "
          f"(~{growth['images_projected']} images) from the largest size")
    print(f"{'stage':10s} {'b time':>7s} {'b mem':>7s} {'proj s':>9s} {'proj MiB':>9s}")
    for st, g in growth["stages"].items():
        print(f"{st:10s} {g['b_time']:7.2f} {g['b_mem']:7.2f} {g['projected_s']:9.0f} {g['projected_mib']:9.0f}")
    tot = growth["total"]
    print(f"{'total':10s} {tot['b_time']:7.2f} {'':7s} {tot['projected_s']:9.0f}  (sum of the stages' projections "
          f"{tot['projected_sum_of_stages_s']:.0f} s)")
    return growth

if __name__ == "__main__":
    main()
