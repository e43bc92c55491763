"""Write a simulated survey as a project folder in the documented formats real data uses.

Layout (``docs/formats/simulated_project.md``)::

    OUTDIR/images/<image>                 rendered images (PNG or TIFF)
    OUTDIR/trajectory.csv                 recorded GNSS/IMU trajectory (antenna positions, with errors)
    OUTDIR/events.csv                     recorded camera events
    OUTDIR/rig.yaml                       recorded (nominal) rig
    OUTDIR/gcp/ground_points.csv          surveyed GCPs (noisy; maybe another CRS with geoid heights)
    OUTDIR/gcp/check_points.csv           surveyed check points
    OUTDIR/gcp/image_measurements.csv     measured target centres (noisy, with gross errors if configured)
    OUTDIR/plan.gpkg                      stations, footprints per head, strip lines (map CRS)
    OUTDIR/scene/dsm.tif, orthophoto.tif  the world sampled on grids (local ENU frame, see scene.json)
    OUTDIR/scene/scene.json               buildings, terrain and texture parameters, façade rule
    OUTDIR/truth/truth.json               scenario, seed, error configuration and drawn values
    OUTDIR/truth/rig.yaml, trajectory.csv, events.csv, eo.csv (local frame), eo_map.csv (map CRS),
    OUTDIR/truth/points.csv, image_measurements.csv, injected_errors.csv
"""

from __future__ import annotations

import csv
import json
import logging
import os
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from skyrig.georef.eo import WorldFrame
from skyrig.georef.observations import GroundPoints, ImageMeasurements
from skyrig.geometry.pose import Pose
from skyrig.simulate.render import render_image
from skyrig.simulate.scenarios import Survey, build_survey, scenario_spec
from skyrig.simulate.world import Scene, rasterize_dsm, rasterize_orthophoto

logger = logging.getLogger(__name__)

_SCENE: Scene | None = None


def _init_worker(scene: Scene) -> None:
    global _SCENE
    _SCENE = scene


def _render_one(args: tuple) -> float:
    from skyrig.io.images import write_image

    cam, rot, centre, path, noise, seed = args
    t = time.perf_counter()
    assert _SCENE is not None
    img = render_image(_SCENE, cam, Pose(rot, centre, "world", "camera"), noise_dn=noise, seed=seed)
    write_image(path, img)
    return time.perf_counter() - t


def find_geoid() -> str | None:
    """An EGM96 grid: ``$SKYRIG_GEOID``, ``../shared/data/geoid/egm96_15.gtx`` next to the repository, or None."""
    env = os.environ.get("SKYRIG_GEOID")
    if env and Path(env).exists():
        return str(Path(env).resolve())
    here = Path(__file__).resolve()
    for parent in here.parents:
        cand = parent.parent / "shared" / "data" / "geoid" / "egm96_15.gtx"
        if cand.exists():
            return str(cand)
    return None


@dataclass(frozen=True)
class ProjectInfo:
    """Where a simulated project was written and how long it took."""

    outdir: Path
    n_images: int
    megapixels: float
    render_s: float
    total_s: float


def render_images(survey: Survey, outdir: Path, workers: int | None = None) -> tuple[float, float]:
    """Render every image of the survey into ``outdir/images``; returns (megapixels, seconds)."""
    (outdir / "images").mkdir(parents=True, exist_ok=True)
    eo = survey.eo_true
    jobs = []
    mp = 0.0
    for k in range(len(eo)):
        cam = survey.rig_true.head(str(eo.head[k])).camera
        mp += cam.width * cam.height / 1e6
        jobs.append((cam, eo.rotation[k], eo.centre[k], outdir / "images" / str(eo.image[k]), survey.spec.image_noise_dn,
                     survey.spec.seed * 100_003 + k))
    t = time.perf_counter()
    n = workers if workers is not None else min(os.cpu_count() or 1, len(jobs))
    if n <= 1:
        _init_worker(survey.scene)
        for j in jobs:
            _render_one(j)
    else:
        with ProcessPoolExecutor(max_workers=n, initializer=_init_worker, initargs=(survey.scene,)) as ex:
            list(ex.map(_render_one, jobs, chunksize=max(1, len(jobs) // (4 * n))))
    return mp, time.perf_counter() - t


def _write_rasters(survey: Survey, outdir: Path, max_cells: int = 800) -> None:
    import rasterio
    from affine import Affine

    sc = survey.scene
    xmin, ymin, xmax, ymax = sc.extent
    cell = max((xmax - xmin), (ymax - ymin)) / max_cells
    dsm, tr = rasterize_dsm(sc, cell)
    ortho, tr2 = rasterize_orthophoto(sc, cell / 2.0)
    tags = {"SKYRIG_FRAME": "local ENU (x east, y north, z up), metres",
            "SKYRIG_LOCAL_ORIGIN": "%.12f %.12f %.6f" % sc.origin}
    for path, arr, t, dtype in ((outdir / "scene" / "dsm.tif", dsm[None].astype(np.float32), tr, "float32"),
                                (outdir / "scene" / "orthophoto.tif", np.moveaxis(ortho, -1, 0), tr2, "uint8")):
        tmp = path.with_name("." + path.name + ".tmp.tif")
        with rasterio.open(tmp, "w", driver="GTiff", width=arr.shape[2], height=arr.shape[1], count=arr.shape[0],
                           dtype=dtype, transform=Affine(*t), compress="deflate") as ds:
            ds.write(arr)
            ds.update_tags(**tags)
        os.replace(tmp, path)


def _scene_json(sc: Scene) -> dict[str, Any]:
    b = sc.buildings
    return {
        "frame": {"kind": "local", "origin": list(sc.origin)}, "extent": list(sc.extent), "seed": sc.seed,
        "terrain": {"base_height_m": sc.base_height_m, "amp_m": sc.terrain_amp_m.tolist(), "kx": sc.terrain_kx.tolist(),
                    "ky": sc.terrain_ky.tolist(), "phase": sc.terrain_phase.tolist(),
                    "formula": "z = base + sum amp_k sin(kx_k x + ky_k y + phase_k)"},
        "buildings": {k: getattr(b, k).tolist() for k in ("cx", "cy", "hl", "hw", "azimuth_rad", "base_z", "eave_z", "ridge_z")},
        "texture": {"fine_m": sc.texture_fine_m, "coarse_m": sc.texture_coarse_m,
                    "facade_rule": "skyrig.simulate.world.Scene.facade_rgb: per-building hashed wall colour, windows "
                                   f"on a {sc.window_spacing_m} m grid, hashed value noise at 0.25 m and 0.06 m",
                    "window_spacing_m": sc.window_spacing_m},
        "sun": sc.sun.tolist(),
        "targets": None if sc.targets is None else {"name": sc.targets.name.tolist(), "xyz": sc.targets.xyz.tolist(),
                                                    "radius_m": sc.targets.radius_m},
    }


def write_plan_gpkg(path: Path, survey: Survey, crs: str) -> None:
    """Stations, footprints per head and strip lines of the flown plan, in ``crs`` (ellipsoidal heights)."""
    import shapely

    from skyrig.io.gpkg import write_gpkg
    from skyrig.plan.flight import footprints

    mf = WorldFrame.map(crs)
    to_map = lambda p: mf.from_ecef(survey.frame.to_ecef(np.asarray(p).reshape(-1, 3)))  # noqa: E731
    plan = survey.plan
    st = to_map(plan.position)
    layers: dict[str, Any] = {
        "stations": ([shapely.Point(p[0], p[1]) for p in st],
                     {"time_s": plan.time_s + survey.spec.t0_s, "strip": plan.strip, "height": st[:, 2],
                      "heading_deg": np.degrees(plan.heading_rad), "beta_deg": np.degrees(plan.beta_rad)}),
        "strips": ([shapely.LineString(to_map(l)[:, :2]) for l in plan.strip_lines],
                   {"strip": np.arange(len(plan.strip_lines))}),
    }
    geoms, heads, stn, strip = [], [], [], []
    for h in survey.rig_true.head_names:
        fp = footprints(plan, survey.rig_true, h, survey.scene.surface_height)
        for i, q in enumerate(fp):
            if np.all(np.isfinite(q)):
                geoms.append(shapely.Polygon(to_map(q)[:, :2]))
                heads.append(h)
                stn.append(i)
                strip.append(int(plan.strip[i]))
    layers["footprints"] = (geoms, {"head": np.array(heads), "station": np.array(stn), "strip": np.array(strip)})
    write_gpkg(path, layers, crs)


def write_project(survey: Survey, outdir: str | Path, workers: int | None = None, images: bool = True) -> ProjectInfo:
    """Write the survey as a project folder (see the module docstring)."""
    from skyrig.io.eo_csv import write_eo_csv
    from skyrig.io.events_csv import write_events_csv
    from skyrig.io.points_csv import write_measurements_csv, write_points_csv
    from skyrig.io.rig_file import write_rig
    from skyrig.io.trajectory_csv import write_trajectory_csv
    from skyrig.io.truth import write_truth

    t0 = time.perf_counter()
    out = Path(outdir)
    for sub in ("images", "gcp", "truth", "scene"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    spec = survey.spec
    write_trajectory_csv(out / "trajectory.csv", survey.trajectory_recorded, crs=spec.crs)
    write_events_csv(out / "events.csv", survey.events_recorded)
    write_rig(survey.rig_recorded, out / "rig.yaml")
    write_trajectory_csv(out / "truth" / "trajectory.csv", survey.trajectory_true, crs=spec.crs)
    write_events_csv(out / "truth" / "events.csv", survey.events_true)
    write_rig(survey.rig_true, out / "truth" / "rig.yaml")
    write_eo_csv(survey.eo_true, out / "truth" / "eo.csv")
    write_eo_csv(survey.eo_true.to_frame(WorldFrame.map(spec.crs)), out / "truth" / "eo_map.csv")
    # ground control in its own CRS (maybe with geoid heights)
    geoid = spec.gcp_geoid
    geoid_note = None
    if geoid == "auto":
        geoid = find_geoid()
        if geoid is None:
            geoid_note = "no geoid grid found: GCP heights are ellipsoidal"
    gframe = WorldFrame.map(spec.gcp_crs or spec.crs, geoid)
    surveyed = gframe.from_ecef(survey.frame.to_ecef(survey.gcp_surveyed)) if len(survey.gcp_names) else np.zeros((0, 3))
    chk = survey.gcp_is_check
    write_points_csv(out / "gcp" / "ground_points.csv", GroundPoints(survey.gcp_names[~chk], surveyed[~chk], gframe))
    write_points_csv(out / "gcp" / "check_points.csv", GroundPoints(survey.gcp_names[chk], surveyed[chk], gframe))
    m = survey.measurements
    write_measurements_csv(out / "gcp" / "image_measurements.csv", ImageMeasurements(m["point"], m["image"], m["pixel"]))
    write_measurements_csv(out / "truth" / "image_measurements.csv", ImageMeasurements(m["point"], m["image"], m["pixel_true"]))
    write_points_csv(out / "truth" / "points.csv", GroundPoints(survey.gcp_names, survey.gcp_local, survey.frame))
    traj = survey.trajectory_true
    with open(out / "truth" / "injected_errors.csv", "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["time", "de_m", "dn_m", "du_m", "droll_rad", "dpitch_rad", "dyaw_rad"])
        for i in range(len(traj)):
            w.writerow(["%.6f" % traj.time_s[i], *("%.6f" % v for v in survey.gnss_error_m[i]),
                        *("%.9e" % v for v in survey.imu_error_rad[i])])
    _write_rasters(survey, out)
    with open(out / "scene" / "scene.json", "w") as fh:
        json.dump(_scene_json(survey.scene), fh, indent=1)
    try:
        write_plan_gpkg(out / "plan.gpkg", survey, spec.crs)
    except ImportError as e:  # pragma: no cover - pyogrio/shapely missing
        logger.warning("plan.gpkg not written: %s", e)
    mp, render_s = render_images(survey, out, workers) if images else (0.0, 0.0)
    truth = {
        "scenario": spec.name, "size": spec.size, "seed": spec.seed,
        "local_frame": list(spec.origin), "crs": spec.crs, "gcp_crs": gframe.crs, "gcp_geoid": gframe.geoid,
        "notes": [n for n in (geoid_note,) if n],
        "errors": spec.errors.to_dict(),
        "injected": {"gnss_strip_shift_m": survey.gnss_strip_shift_m,
                     "true_antenna_lever_m": survey.rig_true.antenna_lever_arm_m,
                     "recorded_antenna_lever_m": survey.rig_recorded.antenna_lever_arm_m,
                     "tumble_curve": None if survey.tumble_curve is None else {
                         "beta_rad": survey.tumble_curve.beta_rad, "corrections_rad": survey.tumble_curve.corrections_rad},
                     "displaced_gcps": survey.gcp_names[survey.gcp_displaced].tolist(),
                     "gross_measurements": np.nonzero(m["gross"])[0].tolist()},
        "files": {"rig": "truth/rig.yaml", "trajectory": "truth/trajectory.csv", "events": "truth/events.csv",
                  "eo_local": "truth/eo.csv", "eo_map": "truth/eo_map.csv", "points_local": "truth/points.csv",
                  "image_measurements": "truth/image_measurements.csv", "injected_errors": "truth/injected_errors.csv"},
        "statistics": {"images": len(survey.eo_true), "megapixels": mp, "render_s": render_s},
    }
    write_truth(out / "truth" / "truth.json", truth)
    return ProjectInfo(out, len(survey.eo_true), mp, render_s, time.perf_counter() - t0)


def simulate_scenario(name: str, outdir: str | Path, size: str = "ci", seed: int = 1, workers: int | None = None,
                      images: bool = True) -> ProjectInfo:
    """Build and write a named scenario (``skyrig simulate``)."""
    if name.strip().lower() == "uav-bridge-lidar":
        from skyrig.errors import SkyrigError

        raise SkyrigError("scenario 'uav-bridge-lidar' is not implemented yet (the 2D scanner simulator is pending)")
    return write_project(build_survey(scenario_spec(name, size, seed)), outdir, workers, images)


def simulate_demo_project(outdir: str | Path, workers: int | None = None) -> dict[str, Any]:
    """``make demo``: simulate a small MIDAS penta-rig flight, georeference the written files with the
    truth rig and compare with the true orientations; returns the largest deviations."""
    from skyrig.georef.direct import direct_georeference
    from skyrig.io.eo_csv import read_eo_csv
    from skyrig.io.events_csv import read_events_csv
    from skyrig.io.rig_file import read_rig
    from skyrig.io.trajectory_csv import read_trajectory_csv

    out = Path(outdir)
    info = write_project(build_survey(scenario_spec("midas-demo", "ci", 1)), out, workers)
    truth_eo = read_eo_csv(out / "truth" / "eo.csv")
    eo = direct_georeference(read_trajectory_csv(out / "truth" / "trajectory.csv"), read_rig(out / "truth" / "rig.yaml"),
                             read_events_csv(out / "truth" / "events.csv"), truth_eo.frame)
    dc = float(np.max(np.linalg.norm(eo.centre - truth_eo.centre, axis=1)))
    dr = float(np.max(np.abs(eo.rotation - truth_eo.rotation)))
    return {"outdir": str(out), "images": info.n_images, "max_centre_error_m": dc, "max_rotation_error": dr,
            "seconds": info.total_s}
