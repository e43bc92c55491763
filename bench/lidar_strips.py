"""Benchmark / acceptance of the LiDAR strip adjustment (issue 34, skyrig.lidar.strips).

    .venv/bin/python bench/lidar_strips.py --seeds 20      # normalised errors over seeds (strips-ci)
    .venv/bin/python bench/lidar_strips.py --full          # the 1.1-km strip flight: time, planes, TLS comparison
    .venv/bin/python bench/lidar_strips.py --autzen        # real ALS: strip discrepancies before/after

``--seeds``: every calibration parameter's and strip correction's error over its predicted sigma, per seed, and the
mean / std of all of them (acceptance: mean within 0.2, std 0.8-1.2; every calibration |z| < 3).
``--full``: seconds for patches and adjustment (the simulation apart), laser points and planes, strip-to-strip
discrepancies before/after, and the cloud against the TLS reference (C2C with a local plane, RMS) for the nominal
mount, after skyrig.lidar.boresight's separate TLS calibration (boresight) and after the strip adjustment, next to
the scanner's range noise.
``--autzen``: ../shared/data/autzen-lidar has georeferenced points only (no trajectory, no ranges or scan angles
of a full strip adjustment): two epochs of two flight lines each; what the data supports is a vertical offset per
flight line from planar patches (skyrig.lidar.strips.adjust_line_offsets, the lidar stage's LAS path; corrections
summing to zero), and the discrepancies on the patches before and after (autzen_trim.laz is one flight line).
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from skyrig.lidar.scanner import Scanner2D
from skyrig.lidar.strips import (CALIBRATION_NAMES, PatchOptions, StripModel, adjust_strips, apply_strip_corrections,
                                 find_planar_patches, patch_discrepancies)
from skyrig.simulate.lidar import build_lidar_survey, lidar_scenario_spec, strip_truth_vector


def _model(err) -> StripModel:
    return StripModel(range_sigma_m=err.range_sigma_m, strip_position_sigma_m=err.strip_position_sigma_m,
                      strip_position_drift_sigma_mps=err.strip_position_drift_sigma_mps,
                      strip_attitude_sigma_rad=err.strip_attitude_sigma_rad,
                      strip_attitude_drift_sigma_radps=err.strip_attitude_drift_sigma_radps)


def seeds(n: int, first: int = 1, step_deg: float = 0.25) -> dict:
    """``n`` seeds of the strips-ci flight (the Hokuyo's 0.25 deg steps; ``step_deg`` 1: the sparse variant of the
    fast test, whose patches are ground and across-track faces only -- no ceiling -- a weak geometry)."""
    rows, zs_cal, zs_all = [], [], []
    for seed in range(first, first + n):
        spec = lidar_scenario_spec("strips-ci", seed)
        if step_deg != 0.25:
            spec = replace(spec, scanner=Scanner2D(step_deg=step_deg))
        sv = build_lidar_survey(spec)
        t = time.perf_counter()
        sparse = step_deg > 0.5
        p = find_planar_patches(sv.scan, sv.trajectory_recorded, sv.mount_recorded, sv.frame, control=sv.reference_xyz,
                                options=PatchOptions(min_points_per_strip=12, max_points_per_strip=24) if sparse
                                else PatchOptions())
        r = adjust_strips(p, sv.mount_recorded, model=_model(spec.errors))
        z = (r.value - strip_truth_vector(sv.injected, r.strip_epoch_s)) / np.where(r.sigma > 0, r.sigma, np.nan)
        zs_cal.append(z[:8])
        zs_all.append(z)
        n_cls = np.abs(p.normal[:, 2]) > 0.9
        rows.append({"seed": seed, "horizontal_patches_above_3m": int(np.sum(n_cls & (p.centre[:, 2] > 3.0))), "seconds": time.perf_counter() - t, "planes": p.n_planes, "points": len(p),
                     "sigma0": r.sigma0, "iterations": r.iterations, "held": list(r.held),
                     "z_calibration": np.round(z[:8], 2).tolist(),
                     "max_abs_z_strips": float(np.nanmax(np.abs(z[8:])))})
        print(json.dumps(rows[-1]), flush=True)
    zc, za = np.concatenate(zs_cal), np.concatenate(zs_all)
    return {"seeds": n, "calibration_z_mean": float(np.nanmean(zc)), "calibration_z_std": float(np.nanstd(zc)),
            "all_z_mean": float(np.nanmean(za)), "all_z_std": float(np.nanstd(za)),
            "calibration_within_3_sigma_share": float(np.mean(np.abs(zc) < 3)),
            "per_parameter_z_mean": dict(zip(CALIBRATION_NAMES, np.nanmean(np.array(zs_cal), axis=0).round(2).tolist())),
            "per_parameter_z_std": dict(zip(CALIBRATION_NAMES, np.nanstd(np.array(zs_cal), axis=0).round(2).tolist()))}


def full(seed: int = 1) -> dict:
    from skyrig.lidar.boresight import estimate_boresight
    from skyrig.lidar.compare import cloud_to_cloud
    from skyrig.lidar.georef import georeference_scan

    t = time.perf_counter()
    spec = lidar_scenario_spec("strips", seed)
    sv = build_lidar_survey(spec)
    out = {"simulation_s": time.perf_counter() - t, "returns": len(sv.scan), "flight_s": sv.injected["motion"]["duration_s"],
           "reference_points": len(sv.reference_xyz)}
    model = _model(spec.errors)
    t = time.perf_counter()
    p = find_planar_patches(sv.scan, sv.trajectory_recorded, sv.mount_recorded, sv.frame, control=sv.reference_xyz)
    out["patches_s"] = time.perf_counter() - t
    t = time.perf_counter()
    r = adjust_strips(p, sv.mount_recorded, model=model)
    out["adjust_s"] = time.perf_counter() - t
    z = (r.value - strip_truth_vector(sv.injected, r.strip_epoch_s)) / r.sigma
    out.update({"planes": p.n_planes, "laser_points_used": len(p), "sigma0": r.sigma0, "iterations": r.iterations,
                "held": list(r.held), "z_calibration": dict(zip(CALIBRATION_NAMES, np.round(z[:8], 2).tolist())),
                "max_abs_z_strips": float(np.abs(z[8:]).max()),
                "discrepancies_before": patch_discrepancies(p, sv.mount_recorded, model),
                "discrepancies_after": patch_discrepancies(p, sv.mount_recorded, model, r)})
    rng = np.random.default_rng(seed)
    sub = np.sort(rng.choice(len(sv.scan), min(200_000, len(sv.scan)), replace=False))
    scan = sv.scan.subset(sub)

    def rms(xyz: np.ndarray) -> float:
        d = cloud_to_cloud(xyz, sv.reference_xyz, model="plane", k=8, max_distance=1.0).distance_m
        return float(np.sqrt(np.nanmean(d**2)))

    out["tls_rms_nominal_m"] = rms(georeference_scan(scan, sv.trajectory_recorded, sv.mount_recorded, sv.frame).xyz)
    b = estimate_boresight(sv.scan, sv.trajectory_recorded, sv.mount_recorded, sv.reference_xyz, sv.frame,
                           estimate=("boresight",), max_points=30_000, max_distance=0.5, seed=seed)
    out["tls_rms_separate_boresight_m"] = rms(georeference_scan(scan, sv.trajectory_recorded, b.mount, sv.frame).xyz)
    out["tls_rms_strip_adjusted_m"] = rms(apply_strip_corrections(scan, sv.trajectory_recorded, sv.mount_recorded,
                                                                  sv.frame, r))
    out["tls_rms_truth_points_m"] = rms(sv.truth_xyz[sub])
    out["range_noise_m"] = spec.errors.range_sigma_m
    return out


def autzen(root: Path, cell: float = 4.0) -> dict:
    """Per-flight-line vertical offsets (skyrig.lidar.strips.adjust_line_offsets, the lidar stage's LAS/LAZ path) of
    two epochs x two flight lines; heights converted from the files' US survey feet to metres."""
    import laspy
    import pyproj

    from skyrig.lidar.strips import adjust_line_offsets

    pts, line = [], []
    for name in ("autzen-bmx-2010.las", "autzen-bmx-2023.las"):
        f = laspy.read(root / name)
        axes = pyproj.CRS.from_wkt(f.header.parse_crs().to_wkt()).axis_info
        hv = [float(ax.unit_conversion_factor) for ax in axes]
        pts.append(np.column_stack([np.asarray(f.x) * hv[0], np.asarray(f.y) * hv[1], np.asarray(f.z) * hv[-1]]))
        line.append(np.asarray(f.point_source_id, np.int64))
    r = adjust_line_offsets(np.concatenate(pts), np.concatenate(line), cell_m=cell, mode="vertical")
    trim = laspy.read(root / "autzen_trim.laz")
    return {**r.to_dict(), "cell_m": cell, "lines_note": "point_source_id 7328/7329: 2010 epoch, 310/311: 2023 epoch",
            "autzen_trim_lines": np.unique(np.asarray(trim.point_source_id)).tolist()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=0)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--step-deg", type=float, default=0.25, help="scanner step of the --seeds flights")
    ap.add_argument("--full", action="store_true")
    ap.add_argument("--autzen", action="store_true")
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[1] / ".." / "shared" / "data"))
    a = ap.parse_args()
    if a.seeds:
        print(json.dumps({"seeds_summary": seeds(a.seeds, a.first_seed, a.step_deg)}, indent=1), flush=True)
    if a.full:
        print(json.dumps({"full": full()}, indent=1), flush=True)
    if a.autzen:
        print(json.dumps({"autzen": autzen(Path(a.data) / "autzen-lidar")}, indent=1), flush=True)


if __name__ == "__main__":
    main()
