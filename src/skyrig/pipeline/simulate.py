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
    OUTDIR/tie/image_measurements.csv     simulated tie-point measurements (only with SensorErrors.tie_points)
    OUTDIR/truth/tie_points.csv, tie_measurements.csv

The laser-scanning scenario ``uav-bridge-lidar`` writes a different folder (:func:`write_lidar_project`)::

    OUTDIR/raw_scan.csv                   recorded raw pulses (docs/formats/raw_scan_csv.md)
    OUTDIR/trajectory.csv                 recorded GNSS/IMU trajectory of the IMU (with errors, NED velocities)
    OUTDIR/barometric.csv                 'time,h' barometric ellipsoidal heights of the IMU
    OUTDIR/scanner.json                   recorded scanner mount and the georeferencing command line
    OUTDIR/reference/tls.laz              terrestrial reference cloud (map CRS, ellipsoidal heights)
    OUTDIR/scene/bridge.json              the bridge (boxes) and the ground plane, local ENU frame
    OUTDIR/truth/truth.json, trajectory.csv, scanner.json, points.laz (true surface point per pulse)

The camera scenario ``uav-bridge-camera`` (:func:`write_bridge_camera_project`)::

    OUTDIR/images/<side>_r<row>_<k>.png   rendered images (true orientations, camera with distortion)
    OUTDIR/rig.yaml                       the camera (one-head rig; calibrated interior orientation)
    OUTDIR/eo.csv                         adjusted-level orientations (truth + seeded noise), map CRS
    OUTDIR/reference/tls.laz              terrestrial reference cloud (map CRS, ellipsoidal heights)
    OUTDIR/scene/bridge.json              the bridge (boxes), ground plane and texture, local ENU frame
    OUTDIR/truth/eo.csv, eo_map.csv       true orientations (local ENU frame / map CRS), truth.json
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
from typing import Any, Sequence

import numpy as np

from skyrig.geodesy.geoid_grid import find_geoid  # noqa: F401 - its old home; callers import it from here
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


@dataclass(frozen=True)
class ProjectInfo:
    """Where a simulated project was written and how long it took."""

    outdir: Path
    n_images: int
    megapixels: float
    render_s: float
    total_s: float
    summary: str = ""


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
    # The grids are north-up grids of the local ENU frame at the scene origin.  Their CRS is PROJ's ellipsoidal
    # orthographic projection at that origin (EPSG method 9840): its x, y are the ENU x, y of the point's foot on
    # the ellipsoid -- for a point h above the ellipsoid d from the origin they differ from the ENU x, y by about
    # h * d / R (1 cm at 80 m and 800 m), far below a cell.  GeoTIFF stores it in its GeoKeys (CT_Orthographic),
    # so GDAL / QGIS place the rasters on the earth.  Heights (DSM values) stay the local ENU z (up from the
    # tangent plane at the origin: h - d^2 / 2R); the SKYRIG_* tags keep the frame for skyrig's own readers.
    lat0, lon0, h0 = sc.origin
    crs = ("+proj=ortho +lat_0=%.12f +lon_0=%.12f +x_0=0 +y_0=0 +ellps=WGS84 +units=m +no_defs +type=crs"
           % (lat0, lon0))
    tags = {"SKYRIG_FRAME": "local ENU (x east, y north, z up), metres",
            "SKYRIG_LOCAL_ORIGIN": "%.12f %.12f %.6f" % sc.origin,
            "SKYRIG_WORLD_FRAME": WorldFrame.local(*sc.origin).to_text(),
            "VERTICAL_REFERENCE": "local ENU z: height above the tangent plane of the WGS84 ellipsoid at lat %.9f "
                                  "lon %.9f h %.3f (not an ellipsoidal height)" % (lat0, lon0, h0)}
    for path, arr, t, dtype in ((outdir / "scene" / "dsm.tif", dsm[None].astype(np.float32), tr, "float32"),
                                (outdir / "scene" / "orthophoto.tif", np.moveaxis(ortho, -1, 0), tr2, "uint8")):
        tmp = path.with_name("." + path.name + ".tmp.tif")
        with rasterio.open(tmp, "w", driver="GTiff", width=arr.shape[2], height=arr.shape[1], count=arr.shape[0],
                           dtype=dtype, transform=Affine(*t), compress="deflate", crs=crs) as ds:
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
        "targets": None if sc.targets is None else {
            "name": sc.targets.name.tolist(), "xyz": sc.targets.xyz.tolist(), "radius_m": sc.targets.radius_m,
            "kind": sc.targets.kind, "half_side_m": sc.targets.half_side_m,
            **({} if sc.targets.codes is None else {"codes": sc.targets.codes.tolist()}),
            **({"code_bits": sc.targets.code_bits} if sc.targets.kind == "coded" else {})},
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
    tie = survey.tie_points
    if tie is not None:
        (out / "tie").mkdir(exist_ok=True)
        write_measurements_csv(out / "tie" / "image_measurements.csv", ImageMeasurements(tie["point"], tie["image"], tie["pixel"]))
        write_measurements_csv(out / "truth" / "tie_measurements.csv",
                               ImageMeasurements(tie["point"], tie["image"], tie["pixel_true"]))
        write_points_csv(out / "truth" / "tie_points.csv", GroundPoints(tie["name"], tie["xyz"], survey.frame))
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
                     "gross_measurements": np.nonzero(m["gross"])[0].tolist(),
                     "wrong_tie_measurements": [] if tie is None else np.nonzero(tie["wrong"])[0].tolist()},
        "files": {"rig": "truth/rig.yaml", "trajectory": "truth/trajectory.csv", "events": "truth/events.csv",
                  "eo_local": "truth/eo.csv", "eo_map": "truth/eo_map.csv", "points_local": "truth/points.csv",
                  "image_measurements": "truth/image_measurements.csv", "injected_errors": "truth/injected_errors.csv",
                  **({} if tie is None else {"tie_measurements": "truth/tie_measurements.csv",
                                             "tie_points_local": "truth/tie_points.csv"})},
        "statistics": {"images": len(survey.eo_true), "megapixels": mp, "render_s": render_s},
    }
    write_truth(out / "truth" / "truth.json", truth)
    return ProjectInfo(out, len(survey.eo_true), mp, render_s, time.perf_counter() - t0)


def simulate_scenario(name: str, outdir: str | Path, size: str = "ci", seed: int = 1, workers: int | None = None,
                      images: bool = True) -> ProjectInfo:
    """Build and write a named scenario (``skyrig simulate``).

    ``uav-bridge-lidar`` writes a laser-scanning project (:func:`write_lidar_project`, no images; the
    returned info has ``n_images = 0`` and the pulse counts in ``summary``); ``uav-bridge-camera`` a camera
    flight along the same bridge (:func:`write_bridge_camera_project`)."""
    if name.strip().lower() == "uav-bridge-camera":
        from skyrig.simulate.bridge_camera import bridge_camera_spec, build_bridge_camera_survey

        return write_bridge_camera_project(build_bridge_camera_survey(bridge_camera_spec(size, seed)), outdir,
                                           workers, images)
    if name.strip().lower() == "uav-bridge-lidar":
        from skyrig.simulate.lidar import build_lidar_survey, lidar_scenario_spec

        t0 = time.perf_counter()
        info = write_lidar_project(build_lidar_survey(lidar_scenario_spec(size, seed)), outdir)
        return ProjectInfo(info.outdir, 0, 0.0, 0.0, time.perf_counter() - t0,
                           f"{info.n_returns:,} returns of {info.n_pulses:,} pulses, {info.n_reference:,} reference points")
    return write_project(build_survey(scenario_spec(name, size, seed)), outdir, workers, images)


def simulate_demo_project(outdir: str | Path, workers: int | None = None, scenario: str = "midas-dsm"
                          ) -> dict[str, Any]:
    """``make demo``: simulate a small MIDAS penta-rig flight (default: the 80/60 surface flight ``midas-dsm``,
    3 strips x 4 exposures x 5 heads), georeference the written files with the truth rig and compare with the
    true orientations; returns the largest deviations."""
    from skyrig.georef.direct import direct_georeference
    from skyrig.io.eo_csv import read_eo_csv
    from skyrig.io.events_csv import read_events_csv
    from skyrig.io.rig_file import read_rig
    from skyrig.io.trajectory_csv import read_trajectory_csv

    out = Path(outdir)
    info = write_project(build_survey(scenario_spec(scenario, "ci", 1)), out, workers)
    truth_eo = read_eo_csv(out / "truth" / "eo.csv")
    eo = direct_georeference(read_trajectory_csv(out / "truth" / "trajectory.csv"), read_rig(out / "truth" / "rig.yaml"),
                             read_events_csv(out / "truth" / "events.csv"), truth_eo.frame)
    dc = float(np.max(np.linalg.norm(eo.centre - truth_eo.centre, axis=1)))
    dr = float(np.max(np.abs(eo.rotation - truth_eo.rotation)))
    return {"outdir": str(out), "images": info.n_images, "max_centre_error_m": dc, "max_rotation_error": dr,
            "seconds": info.total_s}


# ------------------------------------------------------------------------------------------ laser scanning
@dataclass(frozen=True)
class LidarProjectInfo:
    """Where a simulated laser-scanning project was written."""

    outdir: Path
    n_pulses: int
    n_returns: int
    n_reference: int
    total_s: float


SCANNER_JSON_FORMAT = "skyrig-scanner-mount"


def _mount_json(mount: Any, scanner: Any, crs: str, note: str) -> dict[str, Any]:
    from dataclasses import asdict

    b = np.asarray(mount.body_from_scanner)
    lever = np.asarray(mount.lever_arm_m)
    cmd = ("skyrig lidar georef --scan raw_scan.csv --trajectory trajectory.csv "
           f"--mounting {','.join('%.15g' % v for v in b.ravel())} --lever-arm {','.join('%.15g' % v for v in lever)} "
           f"--crs {crs} -o georef.laz")
    return {"format": SCANNER_JSON_FORMAT, "version": 1, "note": note,
            "scanner": {"model": "2D line scanner", **asdict(scanner)},
            "body_from_scanner": b.tolist(), "lever_arm_m": lever.tolist(),
            "antenna_lever_arm_m": np.asarray(mount.antenna_lever_arm_m).tolist(),
            "boresight": "included in body_from_scanner", "trajectory_reference": "imu",
            "georef_command": cmd,
            "georef_command_barometric": cmd.replace(" -o georef.laz", " --barometric barometric.csv -o georef.laz")}


def _write_json(path: Path, obj: Any) -> None:
    from skyrig.io._text import atomic_write
    from skyrig.io.truth import _plain

    with atomic_write(path) as fh:
        json.dump(_plain(obj), fh, indent=1)
        fh.write("\n")


def _write_reference(out: Path, frame: WorldFrame, xyz_local: np.ndarray, crs: str) -> None:
    """``reference/tls.laz``: the terrestrial reference scan ``(M, 3)`` (local ENU) in the map CRS
    (ellipsoidal heights, 1 mm steps)."""
    from skyrig.io.laz import write_las

    (out / "reference").mkdir(parents=True, exist_ok=True)
    write_las(out / "reference" / "tls.laz", WorldFrame.map(crs).from_ecef(frame.to_ecef(xyz_local)), crs)


def write_lidar_project(survey: Any, outdir: str | Path) -> LidarProjectInfo:
    """Write a :class:`skyrig.simulate.lidar.LidarSurvey` as a project folder (see the module docstring
    and ``docs/formats/simulated_project.md``)."""
    from skyrig.io._text import atomic_write
    from skyrig.io.laz import write_las
    from skyrig.io.raw_scan_csv import write_raw_scan_csv
    from skyrig.lidar.georef import PulseGeoreferencer, scan_angle_from_nadir_deg
    from skyrig.io.trajectory_csv import write_trajectory_csv
    from skyrig.io.truth import write_truth

    t0 = time.perf_counter()
    out = Path(outdir)
    for sub in ("reference", "scene", "truth"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    spec = survey.spec
    write_raw_scan_csv(out / "raw_scan.csv", survey.scan, "deg", survey.trajectory_recorded.time_system)
    write_trajectory_csv(out / "trajectory.csv", survey.trajectory_recorded, crs="EPSG:4979")
    write_trajectory_csv(out / "truth" / "trajectory.csv", survey.trajectory_true, crs="EPSG:4979")
    with atomic_write(out / "barometric.csv") as fh:
        fh.write("time,h\n")
        np.savetxt(fh, np.column_stack([survey.barometric_time_s, survey.barometric_h_m]), fmt=["%.6f", "%.5f"],
                   delimiter=",")
    _write_json(out / "scanner.json", _mount_json(survey.mount_recorded, spec.scanner, spec.crs,
                                                  "recorded (nominal) mount"))
    _write_json(out / "truth" / "scanner.json", _mount_json(survey.mount_true, spec.scanner, spec.crs,
                                                            "TRUE mount (boresight and lever-arm errors applied)"))
    mf = WorldFrame.map(spec.crs)
    to_map = lambda p: mf.from_ecef(survey.frame.to_ecef(p))  # noqa: E731
    _write_reference(out, survey.frame, survey.reference_xyz, spec.crs)
    n = survey.truth_normal
    write_las(out / "truth" / "points.laz", to_map(survey.truth_xyz), spec.crs, gps_time=survey.scan.time_s,
              intensity=survey.scan.intensity, scan_angle_deg=scan_angle_from_nadir_deg(
                  PulseGeoreferencer(survey.trajectory_true, survey.mount_true), survey.mount_true,
                  survey.true_time_s, survey.frame.to_ecef(survey.truth_xyz)), scale=1e-4,
              extra={"true_time": survey.true_time_s, "true_range": survey.true_range_m, "normal_e": n[:, 0],
                     "normal_n": n[:, 1], "normal_u": n[:, 2], "component": survey.truth_component.astype(float)})
    _write_json(out / "scene" / "bridge.json", {"local_frame": list(spec.origin), **survey.scene.to_dict()})
    err = spec.errors
    truth = {
        "scenario": spec.name, "size": spec.size, "seed": spec.seed, "local_frame": list(spec.origin), "crs": spec.crs,
        "notes": ["heights of trajectory, barometer, reference and truth points are WGS84 ellipsoidal",
                  "truth/points.laz row i is the true surface point of raw_scan.csv pulse i; normals in the local ENU "
                  "frame; component: index into scene/bridge.json boxes, -1 ground"],
        "errors": err.to_dict(), "injected": survey.injected,
        "files": {"trajectory": "truth/trajectory.csv", "scanner": "truth/scanner.json", "points": "truth/points.laz",
                  "scene": "scene/bridge.json", "reference": "reference/tls.laz"},
        "statistics": {"pulses": survey.pulses_fired, "returns": len(survey.scan),
                       "reference_points": len(survey.reference_xyz),
                       "scan_lines": survey.injected["motion"]["scan_lines"]},
    }
    write_truth(out / "truth" / "truth.json", truth)
    return LidarProjectInfo(out, survey.pulses_fired, len(survey.scan), len(survey.reference_xyz),
                            time.perf_counter() - t0)


def lidar_demo(outdir: str | Path, size: str = "ci", seed: int = 1) -> dict[str, Any]:
    """``make demo``: simulate the ``uav-bridge-lidar`` project (paper 002's errors), then from its files
    georeference the scan (GNSS heights, then barometric heights), compare it with the terrestrial
    reference (C2C with a local plane, M3C2), estimate the heading correction and the boresight against
    the reference, georeference again with them and compare again.

    Writes ``OUTDIR/georef_gnss.laz``, ``georef_baro.laz``, ``georef_corrected.laz`` (C2C distance as an
    extra dimension) next to the project files.  Returns the figures: point counts, C2C statistics
    (RMS and paper 002's "2/3 of the points below") of each cloud, M3C2 (normal radius 0.25 m, cylinder
    radius 0.15 m, half-length 1 m, on 5,000 reference points; mean, median and 68 % of the absolute values,
    std - inflated by cylinders at the bridge's edges - and the significant share) of each, the estimated
    heading correction and boresight with their standard deviations next to the injected values (degrees;
    flying level, the heading correction and the boresight about the scanner's downward y axis are one
    unknown, so their sum is reported too), and the seconds.
    The other injected errors (GNSS wander, IMU noise, lever arm) are not modelled by the estimation and
    bias it beyond its sigmas: the figures show how far a paper-002 flight gets.
    """
    from skyrig.io.laz import read_las, write_las
    from skyrig.io.raw_scan_csv import read_raw_scan_csv
    from skyrig.io.trajectory_csv import read_trajectory_csv
    from skyrig.io.truth import read_truth
    from skyrig.lidar.boresight import estimate_boresight
    from skyrig.lidar.compare import M3C2Params, cloud_to_cloud, distance_statistics, m3c2
    from skyrig.lidar.georef import ScannerMount, georeference_scan
    from skyrig.simulate.lidar import build_lidar_survey, lidar_scenario_spec

    t0 = time.perf_counter()
    out = Path(outdir)
    info = write_lidar_project(build_lidar_survey(lidar_scenario_spec(size, seed)), out)
    truth = read_truth(out / "truth" / "truth.json")
    scan, _ = read_raw_scan_csv(out / "raw_scan.csv")
    traj = read_trajectory_csv(out / "trajectory.csv")
    baro = np.loadtxt(out / "barometric.csv", delimiter=",", skiprows=1, ndmin=2)
    mj = json.loads((out / "scanner.json").read_text(encoding="utf-8"))
    mount = ScannerMount(np.array(mj["body_from_scanner"]), np.array(mj["lever_arm_m"]))
    ref_las = read_las(out / "reference" / "tls.laz", require_crs=True)
    crs = truth["crs"]
    frame = WorldFrame.map(crs)
    origin = ref_las.xyz.mean(axis=0)
    ref = ref_las.xyz - origin
    rng = np.random.default_rng(seed)
    core = ref[np.sort(rng.choice(len(ref), min(5000, len(ref)), replace=False))]
    params = M3C2Params.cloudcompare(0.25, 0.15, 1.0)

    def judge(xyz: np.ndarray, name: str) -> dict[str, float]:
        c2c = cloud_to_cloud(xyz - origin, ref, model="plane", k=8, max_distance=2.0).distance_m
        st = distance_statistics(c2c)
        write_las(out / f"{name}.laz", xyz, crs, extra={"distance": np.nan_to_num(c2c, nan=-9999.0)})
        r = m3c2(ref, xyz - origin, core, params)
        ok = np.isfinite(r.distance_m)
        return {"c2c_rms_m": st.rms_m, "c2c_p68_m": st.p68_abs_m, "c2c_mean_m": st.mean_m,
                "m3c2_core_points": int(ok.sum()), "m3c2_mean_m": float(np.mean(r.distance_m[ok])),
                "m3c2_median_abs_m": float(np.median(np.abs(r.distance_m[ok]))),
                "m3c2_p68_abs_m": float(np.percentile(np.abs(r.distance_m[ok]), 68.0)),
                "m3c2_std_m": float(np.std(r.distance_m[ok])), "m3c2_significant_share": float(np.mean(r.significant[ok]))}

    gnss = georeference_scan(scan, traj, mount, frame)
    fig: dict[str, Any] = {"outdir": str(out), "pulses": info.n_pulses, "returns": info.n_returns,
                           "reference_points": info.n_reference}
    fig["gnss_heights"] = judge(gnss.xyz, "georef_gnss")
    barom = (baro[:, 0], baro[:, 1])
    bar = georeference_scan(scan, traj, mount, frame, barometric=barom)
    fig["barometric_heights"] = judge(bar.xyz, "georef_baro")
    # paper 002: a heading correction term from the reference first, then the boresight
    from skyrig.lidar.georef import with_barometric_height

    traj_b = with_barometric_height(traj, *barom)
    yaw = estimate_boresight(scan, traj_b, mount, ref_las.xyz, frame, estimate=("yaw",), max_points=30_000,
                             max_distance=1.0, seed=seed)
    bore = estimate_boresight(scan, traj_b, mount, ref_las.xyz, frame, estimate=("boresight",),
                              yaw_correction_rad=yaw.yaw_correction_rad, max_points=30_000, max_distance=0.5, seed=seed)
    inj = truth["injected"]
    # flying level, a rotation about the scanner's y axis (body z, down) IS a heading change: only their sum
    # is determined (skyrig.lidar.boresight refuses to estimate both at once); report x, z and the sum
    b_est, b_sig, b_inj = np.degrees(bore.value), np.degrees(bore.sigma), np.degrees(inj["boresight_rad"])
    yaw_d, yaw_inj = float(np.degrees(yaw.yaw_correction_rad)), float(np.degrees(inj["heading_correction_rad"]))
    fig["heading_correction_deg"] = {"estimated": yaw_d, "sigma": float(np.degrees(yaw.get("yaw")[1])), "injected": yaw_inj}
    fig["boresight_deg"] = {"estimated": b_est.tolist(), "sigma": b_sig.tolist(), "injected": b_inj.tolist()}
    fig["heading_plus_boresight_y_deg"] = {"estimated": yaw_d + float(b_est[1]), "injected": yaw_inj + float(b_inj[1])}
    cor = georeference_scan(scan, traj, bore.mount, frame, barometric=barom, yaw_correction_rad=yaw.yaw_correction_rad)
    fig["corrected"] = judge(cor.xyz, "georef_corrected")
    fig["seconds"] = time.perf_counter() - t0
    return fig


# ------------------------------------------------------------------------------------------ bridge camera
_BRIDGE: tuple | None = None


def _init_bridge_worker(state: tuple) -> None:
    global _BRIDGE
    _BRIDGE = state


def _render_bridge_one(job: tuple) -> float:
    """Render and write image ``k`` of the bridge flight (in a worker or in-process)."""
    from skyrig.io.images import write_image
    from skyrig.simulate.bridge_camera import render_bridge_image

    k, path, seed = job
    if _BRIDGE is None:  # pragma: no cover - a worker without its initializer
        raise RuntimeError("bridge render worker not initialised")
    scene, look, camera, rotation, centre, noise = _BRIDGE
    t = time.perf_counter()
    img = render_bridge_image(scene, look, camera, Pose(rotation[k], centre[k], "world", "camera"), noise, seed)
    write_image(path, img)
    return time.perf_counter() - t


def write_bridge_camera_project(survey: Any, outdir: str | Path, workers: int | None = None,
                                images: bool = True) -> ProjectInfo:
    """Write a :class:`skyrig.simulate.bridge_camera.BridgeCameraSurvey` as a project folder.

    Layout (``docs/formats/simulated_project.md``, section "The camera flight along the bridge"):
    ``images/*.png``, ``rig.yaml``, ``eo.csv`` (adjusted-level orientations, map CRS), ``reference/tls.laz``,
    ``scene/bridge.json``, ``truth/eo.csv`` (local ENU), ``truth/eo_map.csv`` (map CRS), ``truth/truth.json``.

    Parameters
    ----------
    survey
        The simulated flight.
    outdir
        Project folder (created).
    workers
        Processes rendering images (None: all cores, at most one per image; 1: in this process).
    images
        Render the images (False: everything else only).
    """
    from skyrig.io.eo_csv import write_eo_csv
    from skyrig.io.rig_file import write_rig
    from skyrig.io.truth import write_truth

    t0 = time.perf_counter()
    out = Path(outdir)
    for sub in ("images", "reference", "scene", "truth"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    spec = survey.spec
    mframe = WorldFrame.map(spec.crs)
    write_rig(survey.rig, out / "rig.yaml")
    write_eo_csv(survey.eo_adjusted.to_frame(mframe), out / "eo.csv")
    write_eo_csv(survey.eo_true, out / "truth" / "eo.csv")
    write_eo_csv(survey.eo_true.to_frame(mframe), out / "truth" / "eo_map.csv")
    _write_reference(out, survey.frame, survey.reference_xyz, spec.crs)
    _write_json(out / "scene" / "bridge.json", {"local_frame": list(spec.origin), **survey.scene.to_dict(),
                                                 "look": spec.look.to_dict(),
                                                 "texture_rule": "skyrig.simulate.bridge_camera.shade_bridge"})
    eo = survey.eo_true
    n = len(eo)
    cam = survey.camera
    mp = n * cam.width * cam.height / 1e6 if images else 0.0
    render_s = 0.0
    if images:
        jobs = [(k, out / "images" / str(eo.image[k]), survey.image_seed(k)) for k in range(n)]
        state = (survey.scene, spec.look, cam, eo.rotation, eo.centre, spec.noise_dn)
        nw = workers if workers is not None else min(os.cpu_count() or 1, n)
        t = time.perf_counter()
        if nw <= 1:
            _init_bridge_worker(state)
            for j in jobs:
                _render_bridge_one(j)
        else:
            with ProcessPoolExecutor(max_workers=nw, initializer=_init_bridge_worker, initargs=(state,)) as ex:
                list(ex.map(_render_bridge_one, jobs))
        render_s = time.perf_counter() - t
    c = cam
    truth = {
        "scenario": spec.name, "size": spec.size, "seed": spec.seed, "local_frame": list(spec.origin), "crs": spec.crs,
        "notes": ["eo.csv: ADJUSTED-LEVEL orientations = truth + independent Gaussian errors per image "
                  f"(centre {spec.adjusted_sigma_m} m per local ENU axis, rotation {spec.adjusted_sigma_deg} deg per "
                  "camera axis as a rotation vector on the camera side: R_adjusted = R_true @ expmap(error))",
                  "truth/eo.csv: exact orientations in the local ENU frame; truth/eo_map.csv: the same in the map CRS",
                  "heights of eo.csv, truth/eo_map.csv and reference/tls.laz are WGS84 ellipsoidal",
                  "images are rendered with the true orientations and the rig.yaml camera (distortion included); "
                  "the camera in rig.yaml is exact (a perfect calibration)"],
        "errors": {"adjusted_sigma_m": spec.adjusted_sigma_m, "adjusted_sigma_deg": spec.adjusted_sigma_deg,
                   "image_noise_dn": spec.noise_dn, "jitter_m": list(spec.jitter_m), "jitter_deg": list(spec.jitter_deg)},
        "injected": {"eo_centre_error_m": survey.adjusted_error_m, "eo_rotation_error_rad": survey.adjusted_error_rad,
                     "images": eo.image.tolist()},
        "camera": {"name": c.name, "width_px": c.width, "height_px": c.height, "pixel_size_mm": c.pixel_size_mm,
                   "focal_mm": c.focal_mm, "ppx_mm": c.ppx_mm, "ppy_mm": c.ppy_mm, "distortion": c.distortion.to_dict(),
                   "binning": spec.binning},
        "flight": survey.flight,
        "reference": {"density_per_m2": spec.reference_density_per_m2,
                      "ground_density_per_m2": spec.reference_ground_density_per_m2, "noise_m": spec.reference_noise_m,
                      "points": len(survey.reference_xyz)},
        "files": {"images": "images/", "camera": "rig.yaml", "eo_adjusted_map": "eo.csv", "eo_local": "truth/eo.csv",
                  "eo_map": "truth/eo_map.csv", "reference": "reference/tls.laz", "scene": "scene/bridge.json"},
        "statistics": {"images": n, "megapixels": mp, "render_s": render_s},
    }
    write_truth(out / "truth" / "truth.json", truth)
    return ProjectInfo(out, n if images else 0, mp, render_s, time.perf_counter() - t0,
                       f"{n} images ({cam.width} x {cam.height} px), GSD {100 * survey.flight['gsd_on_deck_side_m']:.2f} cm "
                       f"on the deck side, {len(survey.reference_xyz):,} reference points")


# ------------------------------------------------------------------------------------------ given rasters
def load_raster_scene(dsm_path: str | Path, ortho_path: str | Path, origin: tuple[float, float, float] | None = None,
                      cell_m: float | None = None, seed: int = 0, geoid: str | None = None) -> Any:
    """A :class:`skyrig.simulate.world.RasterScene` from a DSM and an orthophoto GeoTIFF (issue 3 item 2).

    Two kinds of input:

    * rasters of a simulated project (``scene/dsm.tif``, ``scene/orthophoto.tif``): tags ``SKYRIG_FRAME`` /
      ``SKYRIG_LOCAL_ORIGIN`` (and, since they carry one, the orthographic CRS at the origin): already on a grid of
      the local ENU frame, used as they are;
    * real rasters in a projected CRS (heights ellipsoidal, or orthometric with ``geoid``): resampled
      (bilinear) onto north-up grids of the local ENU frame at ``origin`` (default: the DSM's centre on its
      surface), with the DSM's cell size unless ``cell_m`` is given.  A local node (x, y) takes the height
      at the map position of (x, y, 0); the earth's curvature is then applied to the height, the horizontal
      shift it implies (height x distance / earth radius, 1 cm at 100 m and 600 m) is neglected.

    Raises
    ------
    InputFormatError
        A raster without CRS and without the skyrig local-frame tags, a rotated grid, a DSM that is not one
        band or an orthophoto that is not 3 bands (or 1: grey).
    """
    import rasterio

    from skyrig.errors import InputFormatError
    from skyrig.simulate.world import RasterScene

    def read(path: str | Path) -> tuple[np.ndarray, Any, Any, dict]:
        with rasterio.open(path) as ds:
            arr = ds.read()
            tr = ds.transform
            if abs(tr.b) > 1e-12 or abs(tr.d) > 1e-12 or tr.e >= 0:
                raise InputFormatError("only north-up, unrotated rasters are supported", path)
            nod = ds.nodata
            return arr, tr, ds.crs, {**ds.tags(), "_nodata": nod}

    z, tz, crs, tags = read(dsm_path)
    o, to, crs_o, _ = read(ortho_path)
    if z.shape[0] != 1:
        raise InputFormatError(f"the DSM must have one band, not {z.shape[0]}", dsm_path)
    if o.shape[0] == 1:
        o = np.repeat(o, 3, axis=0)
    if o.shape[0] < 3:
        raise InputFormatError(f"the orthophoto must have 3 bands (RGB) or 1, not {o.shape[0]}", ortho_path)
    z = z[0].astype(np.float64)
    if tags["_nodata"] is not None:
        z[z == tags["_nodata"]] = np.nan
    rgb = np.moveaxis(o[:3], 0, -1)
    if rgb.dtype != np.uint8:
        rgb = np.clip(rgb.astype(np.float32) / max(float(np.nanmax(rgb)), 1e-9), 0, 1)
    if "SKYRIG_LOCAL_ORIGIN" in tags or crs is None:  # a simulated project's grids (with or without their CRS)
        if "SKYRIG_LOCAL_ORIGIN" not in tags:
            raise InputFormatError("the DSM has neither a CRS nor skyrig's local-frame tags", dsm_path, field="crs")
        org = tuple(float(v) for v in tags["SKYRIG_LOCAL_ORIGIN"].split())
        return RasterScene.from_grids(org, z, tz.c, tz.f, tz.a, rgb, to.c, to.f, to.a, seed=seed)
    # a projected CRS: resample onto the local frame
    if crs_o is not None and crs_o != crs:
        raise InputFormatError("the orthophoto's CRS differs from the DSM's", ortho_path, field="crs")
    mf = WorldFrame.map(crs.to_wkt(), geoid)
    rows, cols = z.shape
    if origin is None:
        cx, cy = tz.c + tz.a * cols / 2, tz.f + tz.e * rows / 2
        hc = float(np.nanmedian(z))
        from skyrig.geodesy.crs import ecef_to_geodetic

        lat, lon, h = ecef_to_geodetic(mf.to_ecef(np.array([[cx, cy, hc]])))
        origin = (float(np.ravel(lat)[0]), float(np.ravel(lon)[0]), float(np.ravel(h)[0]))
    lf = WorldFrame.local(*origin)
    corners = np.array([[tz.c, tz.f, 0.0], [tz.c + tz.a * cols, tz.f, 0.0], [tz.c, tz.f + tz.e * rows, 0.0],
                        [tz.c + tz.a * cols, tz.f + tz.e * rows, 0.0]])
    corners[:, 2] = origin[2]
    lc = lf.from_ecef(mf.to_ecef(corners))
    # the inscribed north-up local rectangle (the map grid is turned by the meridian convergence)
    x0, x1 = np.sort(lc[:, 0])[1], np.sort(lc[:, 0])[2]
    y0, y1 = np.sort(lc[:, 1])[1], np.sort(lc[:, 1])[2]

    def resample(grid: np.ndarray, tr: Any, cell: float) -> tuple[np.ndarray, float, float]:
        nx, ny = int(np.floor((x1 - x0) / cell)), int(np.floor((y1 - y0) / cell))
        xs = x0 + (np.arange(nx) + 0.5) * cell
        ys = y1 - (np.arange(ny) + 0.5) * cell
        xx, yy = np.meshgrid(xs, ys)
        m = mf.from_ecef(lf.to_ecef(np.column_stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)])))
        from skyrig.simulate.world import _bilinear

        v = _bilinear(grid, tr.c, tr.f, tr.a, m[:, 0], m[:, 1])[0]
        return v.reshape((ny, nx) + grid.shape[2:]), m

    cell = float(cell_m or tz.a)
    zz, m = resample(z, tz, cell)
    # heights: the local z of the map point (mx, my, H)
    loc = lf.from_ecef(mf.to_ecef(np.column_stack([m[:, :2], zz.ravel()])))
    zl = loc[:, 2].reshape(zz.shape)
    ocell = float(to.a) if cell_m is None else cell / 2.0
    oo, _ = resample(rgb.astype(np.float32) / (255.0 if rgb.dtype == np.uint8 else 1.0), to, ocell)
    return RasterScene.from_grids(origin, zl, x0, y1, cell, oo, x0, y1, ocell, seed=seed)


def write_scene_footprints(path: str | Path, scene: Scene, crs: str, buildings: Sequence[int] | None = None, *,
                           height_sigma_m: float = 0.0, plan_sigma_m: float = 0.0, seed: int = 0,
                           layer: str = "buildings") -> dict:
    """Write :func:`skyrig.simulate.footprints.scene_footprints` in ``crs`` (a projected map CRS, e.g.
    ``"EPSG:25832"``) as GeoPackage layer ``layer`` (temp-and-rename); returns what ``scene_footprints`` returned.
    (Moved here from :mod:`skyrig.simulate.footprints`: writing a format is above the simulation's layer.)"""
    import shapely

    from skyrig.io.gpkg import write_gpkg
    from skyrig.simulate.footprints import scene_footprints

    fp = scene_footprints(scene, WorldFrame.map(crs), buildings, height_sigma_m=height_sigma_m,
                          plan_sigma_m=plan_sigma_m, seed=seed)
    polys = [shapely.Polygon(r) for r in fp["rings"]]
    write_gpkg(path, {layer: (polys, {"id": fp["ids"], "eave_m": fp["eave_m"], "ridge_m": fp["ridge_m"],
                                      "ground_h": fp["ground_h"]})}, crs)
    return fp
