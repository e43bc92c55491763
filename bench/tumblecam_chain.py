"""Paper 000's TumbleCam chain end to end (issue 11, deliverable 4) and its Fig. 9 circle mosaic.

    .venv/bin/python bench/tumblecam_chain.py [--cache DIR] [--scenario tumblecam-dsm] [--step 22.5]
                                              [--png /tmp/h/fig9.png] [--skip-chain]

1. ``skyrig simulate tumblecam-dsm`` (or ``tumblecam``; CI size, seed 1, rendered images) -> ``skyrig georef`` /
   ``match`` / ``block`` /
   ``adjust`` of the **nadir images only** (``bench/dense_acceptance.py``'s ``adjusted_block``, cached in DIR);
2. a *calibrated rig*: the recorded (nominal) rig plus a boresight curve calibrated as in paper 000's laboratory
   (5 full circles at the 72 positions, each measured with the repeatability of paper 000 Tab. 2, mean curve);
3. ``skyrig transfer`` of the adjusted nadir orientations to the oblique images, with the curve and ``--no-curve``;
   the transferred orientations against the simulator's truth (angles / centres RMS) and the image-space error of
   scene points (ray-cast from the true orientation through a pixel grid of every oblique image, projected with the
   transferred orientation, px);
4. Fig. 9: the laboratory circle -- the sensor head held still at a station of the flight, one full circle of the
   tumbling camera (``--step`` deg apart) plus the nadir image rendered with the TRUE rig, projected onto the
   horizontal plane at the scene's mean terrain height with orientations transferred from one (noisy, adjustment-
   size) nadir orientation, with the calibrated curve and without it; the seam offsets by phase correlation next to
   the offsets predicted from the orientation errors alone (geometry);
5. the façade textures of the town from the transferred oblique orientations (engineer A's ``texture_facades`` on
   the scene's DSM and true buildings) judged by ``judge_facades`` (window corners in texels), when those land.

Figures are printed and written to ``DIR/tumblecam_chain.json``.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

# the Fig. 9 circle lives in the simulator; re-exported for the tests that load this bench
from skyrig.simulate.tumble_circle import (  # noqa: F401
    TAB2_MEAN_2SIGMA_DEG, Circle, calibrated_rig, circle_orientations, fig9, hover_circle, lab_calibrated_curve,
    predicted_shifts)

ROOT = Path(__file__).resolve().parents[1]
SKYRIG = str(Path(sys.executable).with_name("skyrig"))


def _dense_acceptance() -> Any:
    spec = importlib.util.spec_from_file_location("dense_acceptance", ROOT / "bench" / "dense_acceptance.py")
    mod = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    spec.loader.exec_module(mod)  # type: ignore[union-attr]
    return mod


# --------------------------------------------------------------------------------------------- chain
def image_space_errors(eo: Any, eo_true: Any, scene: Any, rig_true: Any, frame: Any, grid: int = 9
                       ) -> dict[str, float]:
    """Pixel error of scene points (ray-cast through a ``grid`` x ``grid`` pixel lattice of each image with its true
    orientation) projected with the orientation ``eo`` (any frame; compared in the scene frame)."""
    from skyrig.geometry.pose import Pose
    from skyrig.simulate.render import ray_hits_at_pixels

    e = eo.to_frame(frame)
    t = eo_true.to_frame(frame)
    idx = t.index()
    errs = []
    for i, name in enumerate(e.image):
        k = idx[str(name)]
        cam = rig_true.head(str(t.head[k]) if t.head is not None else "oblique").camera
        u = np.linspace(0.05, 0.95, grid)
        px = np.stack(np.meshgrid(u * (cam.width - 1), u * (cam.height - 1)), -1).reshape(-1, 2)
        hits = ray_hits_at_pixels(scene, cam, Pose(t.rotation[k], t.centre[k], "world", "camera"), px)
        ok = np.isfinite(hits.t)
        pts = t.centre[k] + hits.t[ok, None] * (cam.rays_from_pixels(px[ok]) @ t.rotation[k].T)
        est = cam.world_to_pixel(Pose(e.rotation[i], e.centre[i], "world", "camera"), pts)
        errs.append(np.linalg.norm(est - px[ok], axis=1))
    d = np.concatenate(errs)
    return {"rms_px": float(np.sqrt(np.mean(d ** 2))), "max_px": float(d.max()), "n": int(d.size)}


def skyrig(*args: Any) -> None:
    import subprocess

    print("$ skyrig " + " ".join(map(str, args)), flush=True)
    r = subprocess.run([SKYRIG, *map(str, args)], capture_output=True, text=True)
    print("  " + (r.stdout + r.stderr).strip().replace("\n", "\n  "), flush=True)
    if r.returncode:
        raise RuntimeError(f"skyrig {args[0]} failed with exit {r.returncode}")


def chain(cache: Path, rng: np.random.Generator, scenario: str = "tumblecam") -> dict[str, Any]:
    """Steps 1-3: nadir-only adjustment of the simulated flight, transfer, errors vs truth."""
    from skyrig.georef.transfer import orientation_differences
    from skyrig.io.eo_csv import read_eo_csv
    from skyrig.io.rig_file import read_rig, write_rig
    from skyrig.simulate.scenarios import build_survey, scenario_spec

    da = _dense_acceptance()
    t0 = time.perf_counter()
    b = da.adjusted_block(scenario, cache, nadir=True)
    t_adj = time.perf_counter() - t0
    p = b["project"]
    sv = build_survey(scenario_spec(scenario, "ci", 1))
    curve = lab_calibrated_curve(sv.tumble_curve, rng)
    rig_path = cache / scenario / "output" / "rig_calibrated.yaml"
    write_rig(calibrated_rig(read_rig(p / "rig.yaml"), curve), rig_path)
    res: dict[str, Any] = {"adjust_s": t_adj, "adjust": da.orientation_errors(b["adjust"] / "eo.csv",
                                                                              p / "truth" / "eo_map.csv")}
    truth = read_eo_csv(p / "truth" / "eo_map.csv")
    for label, extra in (("curve", []), ("no_curve", ["--no-curve"])):
        out = cache / scenario / "output" / f"eo_obliques_{label}.csv"
        t1 = time.perf_counter()
        skyrig("transfer", "--eo", b["adjust"] / "eo.csv", "--rig", rig_path, "--events", p / "events.csv", *extra,
               "-o", out)
        eo = read_eo_csv(out)
        d = orientation_differences(eo, truth)
        res[label] = {"transfer_s": time.perf_counter() - t1, "images": len(eo),
                      "angle_rms_deg": float(np.degrees(np.sqrt(np.mean(d["angle_rad"] ** 2)))),
                      "centre_rms_m": float(np.sqrt(np.mean(np.sum(d["centre_m"] ** 2, axis=1)))),
                      "image_space": image_space_errors(eo, truth, sv.scene, sv.rig_true, sv.frame)}
    nadir = read_eo_csv(b["adjust"] / "eo.csv")
    res["nadir_image_space"] = image_space_errors(nadir, truth, sv.scene, sv.rig_true, sv.frame)
    res["rig"] = str(rig_path)
    return res


def town_facades(survey: Any, eo: Any, cams: dict[str, Any], loader: Any, margin_m: float = 20.0,
                 cell_m: float = 0.3) -> dict[str, Any]:
    """Façade textures of the buildings the images ``eo`` see (engineer A's ``texture_facades`` on the scene's analytic
    DSM and true buildings, both in ``eo``'s frame), judged against the scene's façade rule (``judge_facades``:
    whole-façade offset and window corners, in texels).  ``loader(i)``: RGB image of ``eo`` row ``i``."""
    from skyrig.dense.facades import texture_facades
    from skyrig.dense.grid import GridSpec
    from skyrig.simulate.judge_facades import judge_facades, scene_dsm, true_buildings

    crs = eo.frame
    # the buildings whose walls the images see: footprints on the terrain plane, + margin
    ground = float(survey.scene.base_height_m)
    loc = eo.to_frame(survey.frame)
    pts = []
    for k in range(len(loc)):
        cam = cams[str(loc.camera[k])]
        d = cam.rays_from_pixels(cam.corner_pixels()) @ loc.rotation[k].T
        s = (ground - loc.centre[k, 2]) / d[:, 2]
        pts.append(loc.centre[k, :2] + s[:, None] * d[:, :2])
    p = np.concatenate(pts)
    lo, hi = p.min(axis=0) - margin_m, p.max(axis=0) + margin_m
    bl = survey.scene.buildings
    keep = set(np.flatnonzero((bl.cx > lo[0]) & (bl.cx < hi[0]) & (bl.cy > lo[1]) & (bl.cy < hi[1])).tolist())
    c = crs.from_ecef(survey.frame.to_ecef(np.array([[lo[0], hi[1], ground], [hi[0], lo[1], ground]])))
    x0, y0 = np.floor(c[0, 0] / cell_m) * cell_m, np.ceil(c[0, 1] / cell_m) * cell_m
    grid = GridSpec(float(x0), float(y0), cell_m, int(np.ceil((c[1, 0] - x0) / cell_m)),
                    int(np.ceil((y0 - c[1, 1]) / cell_m)))
    t0 = time.perf_counter()
    dsm = scene_dsm(survey.scene, grid, crs)
    blocks = [b for b in true_buildings(survey.scene, crs) if b.id in keep]
    tex = texture_facades(blocks, eo, cams, loader, dsm)
    judged, summ = judge_facades(survey.scene, tex, crs, {str(n) for n in eo.image})
    summ["texture_s"] = time.perf_counter() - t0
    summ["buildings"] = len(blocks)
    summ["judged"] = judged
    return summ


def facades(project: Path, eo_paths: dict[str, Path], rig_path: Path, margin_m: float = 20.0,
            cell_m: float = 0.3, scenario: str = "tumblecam") -> dict[str, Any]:
    """Step 5: façade textures of the town from a simulated project's oblique images with the orientations of each
    EO file (:func:`town_facades`)."""
    from skyrig.io.eo_csv import read_eo_csv
    from skyrig.io.image_read import read_image
    from skyrig.io.rig_file import read_rig
    from skyrig.simulate.scenarios import build_survey, scenario_spec

    sv = build_survey(scenario_spec(scenario, "ci", 1))
    cams = {h.camera.name: h.camera for h in read_rig(rig_path)}
    out: dict[str, Any] = {}
    for label, path in eo_paths.items():
        eo = read_eo_csv(path)
        eo = eo.subset(np.array(["oblique" in str(n) for n in eo.image]))
        images: dict[int, np.ndarray] = {}

        def loader(i: int, eo: Any = eo, images: dict = images) -> np.ndarray:
            if i not in images:
                images[i] = read_image(project / "images" / str(eo.image[i]), gray=False)
            return images[i]

        summ = town_facades(sv, eo, cams, loader, margin_m, cell_m)
        summ.pop("judged")
        out[label] = summ
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, default=Path(os.environ.get("TMPDIR", "/tmp")) / "skyrig-tumblecam-chain")
    ap.add_argument("--step", type=float, default=22.5, help="actuator step of the Fig. 9 circle (deg)")
    ap.add_argument("--png", type=Path, default=None, help="write the Fig. 9 mosaic (with the curve) here")
    ap.add_argument("--skip-chain", action="store_true", help="only the Fig. 9 circle")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--scenario", default="tumblecam-dsm", choices=["tumblecam", "tumblecam-dsm"],
                    help="flight of the chain: tumblecam (CI: 2 strips x 3 exposures, too few obliques for façades) or "
                         "tumblecam-dsm (the same rig, 80/60 block of 4 x 6 exposures)")
    a = ap.parse_args(argv)
    a.cache.mkdir(parents=True, exist_ok=True)
    from skyrig.simulate.scenarios import build_survey, scenario_spec

    rng = np.random.default_rng(a.seed)
    out: dict[str, Any] = {}
    if not a.skip_chain:
        out["chain"] = chain(a.cache, rng, a.scenario)
        c = out["chain"]
        print(f"\n== nadir-only adjustment ({c['adjust_s']:.0f} s incl. cache): nadir vs truth "
              f"{100 * c['adjust']['centre_rms_m']:.1f} cm / {c['adjust']['rotation_rms_deg']:.4f} deg RMS, "
              f"image space {c['nadir_image_space']['rms_px']:.2f} px RMS")
        for k in ("curve", "no_curve"):
            r = c[k]
            print(f"   transferred obliques, {k:8s}: {r['images']} images, {100 * r['centre_rms_m']:.1f} cm / "
                  f"{r['angle_rms_deg']:.4f} deg RMS; image space {r['image_space']['rms_px']:.2f} px RMS, "
                  f"max {r['image_space']['max_px']:.2f} px ({r['transfer_s']:.1f} s)")
        try:
            import skyrig.dense.facades  # noqa: F401  (engineer A's module)
        except ImportError as e:  # pragma: no cover
            print(f"façades skipped: {e}")
        else:
            p = a.cache / a.scenario
            paths = {"truth": p / "truth" / "eo_map.csv",
                     "transferred, curve": p / "output" / "eo_obliques_curve.csv",
                     "transferred, no curve": p / "output" / "eo_obliques_no_curve.csv"}
            out["facades"] = facades(p, paths, Path(c["rig"]), scenario=a.scenario)
            print("\n== façade textures of the town from the oblique images (true buildings, analytic DSM)")
            for k, f in out["facades"].items():
                print(f"   {k:22s}: {f['buildings']} buildings, {f['facades']} façades, {f['seen']} seen; offset median "
                      f"{f['offset_median_px']:.2f} / max {f['offset_max_px']:.2f} texel; windows within 1 texel "
                      f"{f['windows_within_1px']}/{f['windows_found']} (of {f['windows']}); corner error median "
                      f"{f['corner_err_median_px']:.2f} / max {f['corner_err_max_px']:.2f} texel; façades all within 1 texel "
                      f"{100 * f['within_1px']:.0f} % ({f['texture_s']:.1f} s)")
    sv = build_survey(scenario_spec("tumblecam", "ci", 1))
    rig_cal = calibrated_rig(sv.rig_recorded, lab_calibrated_curve(sv.tumble_curve, np.random.default_rng(a.seed)))
    t0 = time.perf_counter()
    circle = hover_circle(sv, a.step, seed=a.seed)
    t_render = time.perf_counter() - t0
    out["fig9"] = {"step_deg": a.step, "images": len(circle.images), "render_s": t_render}
    print(f"\n== Fig. 9: {len(circle.images) - 1} oblique images {a.step:g} deg apart + the nadir image, still head at "
          f"station 0, plane z = {circle.plane_height_m:.1f} m (rendered in {t_render:.1f} s)")
    for label, cv in (("curve", "rig"), ("no_curve", None), ("truth", "truth")):
        f = fig9(circle, rig_cal, cv)
        m = f.pop("mosaic")
        out["fig9"][label] = f
        print(f"   {label:8s}: {f['shape'][1]} x {f['shape'][0]} cells of {100 * f['cell_m']:.1f} cm, "
              f"{len(f['seams'])} seams; offsets median {f['median_offset_px']:.2f} px, RMS {f['rms_offset_px']:.2f}, "
              f"max {f['max_offset_px']:.2f} px (predicted max "
              f"{max(s['predicted_offset_px'] for s in f['seams']):.2f} px); mosaic {f['mosaic_s']:.1f} s, "
              f"seams {f['seams_s']:.1f} s")
        if label == "curve" and a.png is not None:
            import cv2

            a.png.parent.mkdir(parents=True, exist_ok=True)
            tmp = a.png.with_name(f".{a.png.name}.partial.png")
            cv2.imwrite(str(tmp), m.rgb[:, :, ::-1])
            os.replace(tmp, a.png)
            print(f"   mosaic -> {a.png}")
    (a.cache / "tumblecam_chain.json").write_text(json.dumps(out, indent=1, default=float))
    print(f"\nfigures -> {a.cache / 'tumblecam_chain.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
