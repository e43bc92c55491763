"""LiDAR and camera in one adjustment on the simulated bridge strip flight of paper 002 (issue 34).

For each seed: simulate the laser strip flight with its camera (:func:`skyrig.simulate.lidar_camera.build_joint_flight`:
scanner boresight, lever arm, range offset and scale, per-strip trajectory offsets and drifts, camera boresight
injected), run the joint recipe (:func:`skyrig.calibrate.lidar_camera.calibrate_lidar_camera`) and report

* the normalised errors ``(estimate - truth) / predicted sigma`` of every injected calibration parameter (scanner 8,
  camera boresight 3) and of the strip corrections: per seed the largest, over the seeds mean and std (goal: mean
  within 0.2, std 0.8-1.2);
* the laser cloud against the TLS reference (plane-model C2C RMS, :func:`skyrig.lidar.compare.cloud_to_cloud`) with
  the nominal mount, after the laser-only strip adjustment (:func:`skyrig.lidar.strips.adjust_strips`, the separate
  calibration) and after the joint adjustment;
* the image cloud -- the tie points of the ADJUSTED image block -- against the same reference;
* the systematic part of each cloud's deviation: M3C2 (:func:`skyrig.lidar.compare.m3c2`, PDAL's behaviour) from the
  reference (cloud 1) to the cloud at core points on a 0.5 m grid of the reference: normals from the reference within
  0.5 m, projection cylinders of 0.25 m radius and 0.5 m half-length, so that each distance is the mean of the
  cloud's points in the cylinder and the scanner's per-point range noise averages out (the laser clouds use every
  pulse of the strips; the sparse image tie points cylinders of 1 m radius); cores whose reference points spread
  more than 1 cm along the normal in the cylinder (edges, corners) are left out, a property of the reference alone;
  and the M3C2 RMS left after the rigid motion that best explains the distances (linearised point-to-plane: paper
  002 registers its clouds onto the TLS by ICP before Table 1), which separates the cloud's shape error from its
  datum (the trajectory's absolute accuracy, which neither calibration can improve without control);
* the noise floor: the laser cloud at the TRUE calibration and strip corrections (the recorded ranges, so the range
  noise and the surface roughness only), C2C and M3C2 alike;
* the strip-to-strip discrepancies on the patch planes before and after the joint adjustment
  (:func:`skyrig.calibrate.lidar_camera.strip_discrepancies`);
* the joint adjustment's time, laser points and images.

**Control** (``--control none,sparse,area``): the separate and the joint calibration each run without control and
with the SAME control, a part of the TLS reference given to both as control planes (the laser-only strip adjustment's
``find_planar_patches(control=...)``, the joint recipe's ``JointInputs.control_xyz``); ``gcp``: 8 ground control
points (tie points spread over the site, true coordinates + 5 mm survey noise) measured in the images, which only the
joint adjustment can use (the separate laser calibration has no image: its figures are those without control);
``sparse+gcp``, ``area+gcp``: both.  ``sparse``: the reference
points in a random ``--control-fraction`` of the ``--control-cell`` m plan cells (a surveyor's control planes spread
over the site); ``area``: the reference points in the first third of the flown stretch along the bridge.  The clouds
are then judged against the whole TLS reference and, separately, on the part not used as control (C2C of the laser
points in held-out cells, M3C2 at held-out core points): no circularity.  The acceptance line of issue 34 (joint
<= 1/3 of separate, and <= 1.5 x the range noise) is printed per seed and in the mean for each setting.

Run: ``PYTHONPATH=src python bench/lidar_joint.py --seeds 20 [--size strips-ci|strips] [--control none,sparse]
[--json out.json]``.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
import os
import threading
import time

import numpy as np

from skyrig.calibrate.lidar_camera import (JointInputs, JointOptions, calibrate_lidar_camera, georeference_adjusted,
                                           joint_inputs_from_flight)
from skyrig.errors import CalibrationFailed
from skyrig.lidar.compare import M3C2Params, cloud_to_cloud, m3c2
from skyrig.lidar.strips import StripModel, adjust_strips, find_planar_patches
from skyrig.simulate.lidar import strip_truth_vector
from skyrig.simulate.lidar_camera import build_joint_flight


class RssPeak:
    """The process's resident memory sampled every 0.1 s in a thread (``with RssPeak() as m: ...``): ``m.start_b`` at
    entry, ``m.peak_b`` the largest seen, so that ``peak_b - start_b`` is what the block added at its peak."""

    def __init__(self) -> None:
        self.start_b = self.peak_b = self._rss()
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)

    @staticmethod
    def _rss() -> int:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")

    def _run(self) -> None:
        while not self._stop.wait(0.1):
            self.peak_b = max(self.peak_b, self._rss())

    def __enter__(self) -> "RssPeak":
        self.start_b = self.peak_b = self._rss()
        self._t.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._t.join()
        self.peak_b = max(self.peak_b, self._rss())


def _rms_vs_tls(xyz: np.ndarray, ref: np.ndarray) -> float:
    d = cloud_to_cloud(xyz, ref, model="plane", k=10, max_distance=0.5).distance_m
    d = d[np.isfinite(d)]
    return float(np.sqrt(np.mean(d**2)))


#: M3C2 of a cloud from the TLS reference: normals within 0.5 m of the reference, cylinders 0.25 m x +-0.5 m (the
#: laser clouds, tens of points per cylinder); the image tie points (about 1.5 per m^2): cylinders of 1 m radius, at
#: least 3 points
M3C2_PARAMS = M3C2Params.pdal(normal_radius=0.5, cylinder_radius=0.25, cylinder_half_length=0.5, min_points=5)
M3C2_PARAMS_SPARSE = M3C2Params.pdal(normal_radius=0.5, cylinder_radius=1.0, cylinder_half_length=0.5, min_points=3)
M3C2_CORE_SPACING_M = 0.5
M3C2_PLANAR_STD_M = 0.01  # cores kept: the reference's spread along the normal in the cylinder below this


def m3c2_cores(ref: np.ndarray, spacing: float = M3C2_CORE_SPACING_M) -> np.ndarray:
    """Core points: the first reference point of each ``spacing`` voxel."""
    key = np.floor((ref - ref.min(axis=0)) / spacing).astype(np.int64)
    _, first = np.unique(key, axis=0, return_index=True)
    return ref[np.sort(first)]


def m3c2_vs_tls(xyz: np.ndarray, ref: np.ndarray, core: np.ndarray, params: M3C2Params = M3C2_PARAMS,
                held: np.ndarray | None = None) -> dict:
    """M3C2 from the reference to ``xyz`` at ``core``: RMS, mean and 68th percentile of |d| over the planar cores
    with at least ``params.min_points_for_stats`` points of each cloud, their count and the mean points per cylinder
    of ``xyz`` (NaN figures where no core qualifies); with ``held`` ``(cores,)`` the same over the held-out cores
    (not under the control) as ``"held_out"``."""
    res = m3c2(ref, xyz, core, params)
    ok = np.isfinite(res.distance_m) & np.isfinite(res.uncertainty_m) & (res.std1_m < M3C2_PLANAR_STD_M)
    out = _m3c2_stats(res, ok)
    if held is not None:
        out["held_out"] = _m3c2_stats(res, ok & held)
    return out


def _m3c2_stats(res, ok: np.ndarray) -> dict:
    d = res.distance_m[ok]
    if d.size < 6:
        return {"rms_m": np.nan, "mean_m": np.nan, "p68_abs_m": np.nan, "cores": int(d.size),
                "points_per_cylinder": np.nan, "rms_rigid_m": np.nan, "shift_m": [np.nan] * 3, "rotation_deg": np.nan}
    # the rigid motion that best explains the distances (linearised point-to-plane, as an ICP registration onto the
    # reference, paper 002's Table 1): d ~ n . (t + w x (p - c)); what is left is the cloud's shape error
    n, p = res.normal[ok], res.core[ok] - res.core[ok].mean(axis=0)
    sol = np.linalg.lstsq(np.column_stack([n, np.cross(p, n)]), d, rcond=None)[0]
    left = d - np.column_stack([n, np.cross(p, n)]) @ sol
    return {"rms_m": float(np.sqrt(np.mean(d**2))), "mean_m": float(np.mean(d)),
            "p68_abs_m": float(np.percentile(np.abs(d), 68)), "cores": int(ok.sum()),
            "points_per_cylinder": float(np.mean(res.count2[ok])), "rms_rigid_m": float(np.sqrt(np.mean(left**2))),
            "shift_m": sol[:3].tolist(), "rotation_deg": float(np.degrees(np.linalg.norm(sol[3:])))}


class ControlSplit:
    """Which part of the site is control: ``mode`` ``"sparse"`` (a random ``fraction`` of the ``cell`` m plan cells)
    or ``"area"`` (the first third of the flown stretch along the bridge); :meth:`is_control` of any points."""

    def __init__(self, mode: str, ref: np.ndarray, traj_xy: np.ndarray, seed: int, fraction: float, cell: float):
        self.mode, self.seed, self.fraction, self.cell = mode, seed, fraction, cell
        c = traj_xy - traj_xy.mean(axis=0)
        self.axis = np.linalg.svd(c, full_matrices=False)[2][0]  # the flight direction (plan)
        self.origin = traj_xy.mean(axis=0)
        u = (ref[:, :2] - self.origin) @ self.axis
        self.u_cut = float(np.percentile(u, 100 / 3))

    def is_control(self, xyz: np.ndarray) -> np.ndarray:
        if self.mode == "area":
            return (xyz[:, :2] - self.origin) @ self.axis < self.u_cut
        ij = np.floor(xyz[:, :2] / self.cell).astype(np.int64)
        # a deterministic pseudo-random draw per cell (the same cell is control for every cloud of the seed)
        h = (ij[:, 0] * 73856093) ^ (ij[:, 1] * 19349663) ^ (self.seed * 83492791)
        return (np.abs(h) % 10007) / 10007.0 < self.fraction


def separate_calibration(fl, control: np.ndarray | None = None):
    """The laser-only strip adjustment of the separate path (:func:`separate_seed`), with ``control`` points."""
    sv = fl.survey
    jo = JointOptions()
    st = np.asarray(jo.strip_sigma)
    model = StripModel(range_sigma_m=jo.range_sigma_m, scan_angle_sigma_rad=jo.angle_sigma_rad,
                       roughness_m=jo.roughness_m, strip_position_sigma_m=tuple(st[0:3]),
                       strip_position_drift_sigma_mps=tuple(st[3:6]), strip_attitude_sigma_rad=tuple(st[6:9]),
                       strip_attitude_drift_sigma_radps=tuple(st[9:12]), control_sigma_m=jo.control_sigma_m,
                       control_plane_sigma_m=jo.control_plane_sigma_m)
    patches = find_planar_patches(sv.scan, sv.trajectory_recorded, sv.mount_recorded, sv.frame, options=jo.patches,
                                  control=control)
    t0 = time.perf_counter()
    sep = adjust_strips(patches, sv.mount_recorded, model=model)
    return sep, time.perf_counter() - t0


def cloud_vs_tls(inp: JointInputs, cal: np.ndarray, strips: np.ndarray, epoch: np.ndarray, ids: np.ndarray,
                 rows: np.ndarray, rows_m3c2: np.ndarray, ref: np.ndarray, core: np.ndarray,
                 split: ControlSplit | None) -> dict:
    """A laser cloud (calibration ``cal``, strip corrections ``strips``) against the TLS: C2C RMS of every
    ``rows`` pulse and M3C2 (all pulses), over the whole reference and, with a ``split``, over the held-out part
    (the laser points and the core points not in the control's cells)."""
    xyz = georeference_adjusted(inp, cal, strips, epoch, ids, rows=rows)
    d = cloud_to_cloud(xyz, ref, model="plane", k=10, max_distance=0.5).distance_m
    ok = np.isfinite(d)
    out = {"c2c_rms_m": float(np.sqrt(np.mean(d[ok] ** 2)))}
    held = None
    if split is not None:
        h = ok & ~split.is_control(xyz)
        out["c2c_rms_held_out_m"] = float(np.sqrt(np.mean(d[h] ** 2)))
        held = ~split.is_control(core)
    out["m3c2"] = m3c2_vs_tls(georeference_adjusted(inp, cal, strips, epoch, ids, rows=rows_m3c2), ref, core,
                              held=held)
    return out


def simulated_gcps(fl, seed: int, n: int = 8, sigma_m: float = 0.005, min_rays: int = 6) -> dict:
    """Ground control points of the simulated flight: ``n`` tie points (measured in at least ``min_rays`` images)
    spread over the site (farthest-point order in plan), their true coordinates plus survey noise ``sigma_m`` per
    axis (a seeded draw): the ``gcp_*`` fields of :class:`JointInputs`."""
    rays = np.bincount(fl.obs_point, minlength=len(fl.point_xyz))
    cand = np.flatnonzero(rays >= min_rays)
    xy = fl.point_xyz[cand, :2]
    pick = [int(np.argmin(np.linalg.norm(xy - xy.mean(axis=0), axis=1)))]
    d = np.linalg.norm(xy - xy[pick[0]], axis=1)
    while len(pick) < min(n, len(cand)):
        pick.append(int(np.argmax(d)))
        d = np.minimum(d, np.linalg.norm(xy - xy[pick[-1]], axis=1))
    pts = cand[pick]
    rng = np.random.default_rng([seed, 3402])
    return {"gcp_point": pts, "gcp_xyz": fl.point_xyz[pts] + rng.normal(0.0, sigma_m, (len(pts), 3)),
            "gcp_sigma_m": np.full((len(pts), 3), sigma_m)}


def control_setting(fl, inp: JointInputs, split: ControlSplit | None, rows: np.ndarray, rows_m3c2: np.ndarray,
                    core: np.ndarray, floor: dict | None = None, gcp: dict | None = None,
                    separate: dict | None = None) -> dict:
    """Separate and joint calibration with the control of ``split`` (None: no reference-cloud control) and the
    ground control points ``gcp`` in the images (the joint adjustment only: the laser-only separate calibration has
    no image to measure them in), each cloud judged against the TLS (:func:`cloud_vs_tls`), the noise floor judged
    the same way; ``separate``: the separate figures of the same ``split`` (reused)."""
    sv = fl.survey
    ref = sv.reference_xyz
    ctrl = None if split is None else ref[split.is_control(ref)]
    out: dict
    if separate is None:
        sep, t_sep = separate_calibration(fl, ctrl)
        truth = strip_truth_vector(sv.injected, sep.strip_epoch_s)
        ep, ids = sep.strip_epoch_s, sep.strip_ids
        out = {"control_points": 0 if ctrl is None else int(len(ctrl)), "separate_control_points": sep.n_control,
               "separate": cloud_vs_tls(inp, sep.calibration, sep.strips, ep, ids, rows, rows_m3c2, ref, core,
                                        split),
               "separate_fit": {"held": list(sep.held), "sigma0": sep.sigma0, "time_s": t_sep}}
        out["noise_floor"] = floor if floor is not None and split is None else cloud_vs_tls(
            inp, truth[:8], truth[8:].reshape(-1, 12), ep, ids, rows, rows_m3c2, ref, core, split)
    else:
        out = {k: separate[k] for k in ("control_points", "separate_control_points", "separate", "separate_fit",
                                        "noise_floor")}
    t0 = time.perf_counter()
    try:
        cal = calibrate_lidar_camera(replace(inp, **({} if ctrl is None else {"control_xyz": ctrl}), **(gcp or {})))
    except CalibrationFailed as exc:  # counted and reported, not hidden
        out["joint_fit"] = {"failed": str(exc), "time_s": time.perf_counter() - t0}
        out["joint"] = None
        return out
    out["joint_fit"] = {"time_s": time.perf_counter() - t0, "sigma0": cal.sigma0,
                        "control": None if cal.control is None else cal.control.summary(),
                        "control_rejected": 0 if cal.control_rejected is None else len(cal.control_rejected),
                        "gcp": None if cal.gcp_residual_m is None else {
                            "count": len(cal.gcp_residual_m),
                            "rms_m": np.sqrt(np.mean(cal.gcp_residual_m**2, axis=0)).tolist(),
                            "max_abs_normalised": None if cal.gcp_normalised is None else
                            float(np.nanmax(np.abs(cal.gcp_normalised)))}}
    out["joint"] = cloud_vs_tls(inp, cal.scanner, cal.strips, cal.strip_epoch_s, cal.strip_ids, rows, rows_m3c2,
                                ref, core, split)
    tj = strip_truth_vector(sv.injected, cal.strip_epoch_s)
    out["joint_fit"]["z_scanner"] = ((cal.scanner - tj[:8]) / cal.scanner_sigma).tolist()
    return out


def separate_seed(fl, inp: JointInputs, rows: np.ndarray, rows_m3c2: np.ndarray, core: np.ndarray) -> dict:
    """The separate calibration of the laser (paper 002's "separate": the scanner calibrated from its own strips):
    the laser-only strip adjustment (:func:`skyrig.lidar.strips.adjust_strips`, no control) on the joint recipe's
    patch options, range noise and roughness, with the same priors of the per-strip corrections (the trajectory's
    stated accuracy), all 8 scanner parameters free under the strip adjustment's determinability rule (a lever arm
    along the body z trades with the strips' common height offsets and is held at its nominal value)."""
    sv = fl.survey
    sep, t_sep = separate_calibration(fl)
    truth = strip_truth_vector(sv.injected, sep.strip_epoch_s)
    with np.errstate(invalid="ignore", divide="ignore"):
        z = np.where(sep.calibration_sigma > 0, (sep.calibration - truth[:8]) / sep.calibration_sigma, np.nan)
    ref = sv.reference_xyz
    nominal = georeference_adjusted(inp, np.zeros(8), np.zeros_like(sep.strips), sep.strip_epoch_s, sep.strip_ids,
                                    rows=rows)
    separate = georeference_adjusted(inp, sep.calibration, sep.strips, sep.strip_epoch_s, sep.strip_ids, rows=rows)
    # the noise floor: the recorded data at the true calibration and strip corrections
    floor = georeference_adjusted(inp, truth[:8], truth[8:].reshape(-1, 12), sep.strip_epoch_s, sep.strip_ids,
                                  rows=rows)
    m3 = {}
    for name, cal, st in (("nominal", np.zeros(8), np.zeros_like(sep.strips)), ("separate", sep.calibration, sep.strips),
                          ("noise_floor", truth[:8], truth[8:].reshape(-1, 12))):
        m3[name] = m3c2_vs_tls(georeference_adjusted(inp, cal, st, sep.strip_epoch_s, sep.strip_ids, rows=rows_m3c2),
                               ref, core)
    return {"rms_nominal_m": _rms_vs_tls(nominal, ref), "rms_separate_m": _rms_vs_tls(separate, ref),
            "rms_noise_floor_m": _rms_vs_tls(floor, ref), "m3c2": m3,
            "separate": {"held": list(sep.held), "iterations": sep.iterations, "sigma0": sep.sigma0,
                         "time_s": t_sep, "z_scanner": [None if not np.isfinite(v) else float(v) for v in z],
                         "range_scale": float(sep.calibration[7])}}


def _seed_setup(size: str, seed: int, every: int):  # type: ignore[no-untyped-def]
    """One seed's flight, its survey, the joint recipe's inputs, the laser rows compared by M3C2 (every pulse of the
    strips) and by C2C (every ``every``-th) and the M3C2 core points."""
    fl = build_joint_flight(size, seed)
    sv = fl.survey
    rows_m3c2 = np.flatnonzero(sv.scan.strip_id >= 0)
    return fl, sv, joint_inputs_from_flight(fl), rows_m3c2, rows_m3c2[::every], m3c2_cores(sv.reference_xyz)


def run_seed(size: str, seed: int, every: int, roughness_m: float | None = None, joint: bool = True) -> dict:
    fl, sv, inp, rows_m3c2, rows, core = _seed_setup(size, seed, every)
    sep = separate_seed(fl, inp, rows, rows_m3c2, core)
    if not joint:
        return {"seed": seed, "rms_tls_m": {"nominal": sep["rms_nominal_m"], "separate": sep["rms_separate_m"],
                                            "noise_floor": sep["rms_noise_floor_m"]},
                "m3c2_tls": sep["m3c2"], "separate": sep["separate"]}
    t0, c0 = time.perf_counter(), time.process_time()
    opts = JointOptions() if roughness_m is None else JointOptions(roughness_m=roughness_m)
    with RssPeak() as mem:
        cal = calibrate_lidar_camera(inp, opts)
    t_joint, c_joint = time.perf_counter() - t0, time.process_time() - c0
    truth = strip_truth_vector(sv.injected, cal.strip_epoch_s)
    z_sc = (cal.scanner - truth[:8]) / cal.scanner_sigma
    z_cam = (cal.camera_boresight_rad - fl.camera_boresight_rad) / cal.camera_boresight_sigma_rad
    z_st = ((cal.strips - truth[8:].reshape(-1, 12)) / cal.strips_sigma).ravel()
    ref = sv.reference_xyz
    joint = georeference_adjusted(inp, cal.scanner, cal.strips, cal.strip_epoch_s, cal.strip_ids, rows=rows)
    image = cal.block.point_xyz
    m3 = dict(sep["m3c2"])
    m3["joint"] = m3c2_vs_tls(georeference_adjusted(inp, cal.scanner, cal.strips, cal.strip_epoch_s, cal.strip_ids,
                                                    rows=rows_m3c2), ref, core)
    m3["image_tie_points"] = m3c2_vs_tls(image, ref, core, M3C2_PARAMS_SPARSE)
    return {
        "seed": seed, "time_joint_s": t_joint, "cpu_joint_s": c_joint,
        "rss_joint_start_gb": mem.start_b / 1e9, "rss_joint_peak_gb": mem.peak_b / 1e9, "laser_points": cal.n_laser_points, "images": fl.n_images,
        "image_observations": int(len(cal.block.obs_image)), "pulses": len(sv.scan),
        "patch_planes": cal.n_patch_planes, "tie_planes": cal.n_tie_planes, "dropped_points": cal.n_dropped_points,
        "dropped_planes": cal.n_dropped_planes, "sigma0": cal.sigma0,
        "discrepancies": {"before": cal.discrepancies_before, "after": cal.discrepancies_after},
        "z_scanner": z_sc.tolist(), "z_camera": z_cam.tolist(), "z_strips": z_st.tolist(),
        "rms_tls_m": {"nominal": sep["rms_nominal_m"], "separate": sep["rms_separate_m"],
                      "joint": _rms_vs_tls(joint, ref), "image_tie_points": _rms_vs_tls(image, ref),
                      "noise_floor": sep["rms_noise_floor_m"]},
        "m3c2_tls": m3,
        "separate": sep["separate"],
    }


CLOUDS = ("nominal", "separate", "joint", "image_tie_points", "noise_floor")


def _m3c2_line(r: dict) -> str:
    m = r["m3c2_tls"]
    return "; ".join(f"{k} {m[k]['rms_m'] * 1e3:.1f} mm, {m[k]['rms_rigid_m'] * 1e3:.1f} after a rigid fit (shift "
                     f"{np.round(np.array(m[k]['shift_m']) * 1e3, 1).tolist()} mm, {m[k]['rotation_deg']:.3f} deg; "
                     f"{m[k]['cores']} cores, {m[k]['points_per_cylinder']:.0f} pts/cyl)" for k in CLOUDS if k in m)


def print_table(out: list[dict]) -> None:
    """Paper 002's Table 1 side by side: per cloud the C2C RMS (per-point: range noise included) and the M3C2 RMS,
    mean |d| 68 % and mean (cylinder means: the systematic part), means over the seeds."""
    from skyrig.papers.p002 import PAPER_LSRF, PAPER_SFM

    print(f"\nlaser and image clouds against the TLS reference, mean of {len(out)} seeds (mm)")
    print(f"{'cloud':<18}{'C2C RMS':>9}{'M3C2 RMS':>10}{'M3C2 68%':>10}{'M3C2 mean':>11}{'M3C2 rigid':>12}{'shift':>8}"
          f"{'cores':>8}{'pts/cyl':>9}")
    for k in CLOUDS:
        if not all(k in r["m3c2_tls"] and k in r["rms_tls_m"] for r in out):
            continue
        c2c = np.mean([r["rms_tls_m"][k] for r in out]) * 1e3
        m = {f: np.mean([r["m3c2_tls"][k][f] for r in out]) for f in ("rms_m", "p68_abs_m", "mean_m", "cores",
                                                                        "points_per_cylinder", "rms_rigid_m")}
        shift = np.mean([np.linalg.norm(r["m3c2_tls"][k]["shift_m"]) for r in out])
        print(f"{k:<18}{c2c:>9.1f}{m['rms_m'] * 1e3:>10.1f}{m['p68_abs_m'] * 1e3:>10.1f}{m['mean_m'] * 1e3:>11.1f}"
              f"{m['rms_rigid_m'] * 1e3:>12.1f}{shift * 1e3:>8.1f}{m['cores']:>8.0f}{m['points_per_cylinder']:>9.0f}")
    print(f"paper 002 Table 1 (C2C after ICP): LSRF RMS {PAPER_LSRF[0] * 1e3:.0f}, 2/3 below {PAPER_LSRF[1] * 1e3:.0f}; "
          f"SfM RMS {PAPER_SFM[0] * 1e3:.0f}, 2/3 below {PAPER_SFM[1] * 1e3:.0f}")
    print("(M3C2 rigid: the RMS left after the rigid motion that best explains the M3C2 distances, as the paper's ICP "
          "registration; shift: its length, mean of the seeds)")
    if all("joint" in r["m3c2_tls"] for r in out):
        for what, key in (("C2C", None), ("M3C2", "rms_m"), ("M3C2 after a rigid fit", "rms_rigid_m")):
            v = {k: np.mean([r["rms_tls_m"][k] if key is None else r["m3c2_tls"][k][key] for r in out])
                 for k in ("separate", "joint")}
            print(f"joint / separate {what} RMS: {v['joint'] / v['separate']:.2f} (acceptance <= 1/3)")


def run_control_seed(size: str, seed: int, every: int, modes: list[str], fraction: float, cell: float) -> dict:
    """One seed: separate and joint calibration without control and with each control ``modes`` setting."""
    fl, sv, inp, rows_m3c2, rows, core = _seed_setup(size, seed, every)
    traj_xy = fl.body_rec_position[:, :2]
    out = {"seed": seed, "range_sigma_m": float(sv.spec.errors.range_sigma_m)}
    gcps = simulated_gcps(fl, seed)
    for mode in modes:
        tls, _, g = mode.partition("+")
        tls = "none" if tls == "gcp" else tls
        split = None if tls == "none" else ControlSplit(tls, sv.reference_xyz, traj_xy, seed, fraction, cell)
        t0 = time.perf_counter()
        out[mode] = control_setting(fl, inp, split, rows, rows_m3c2, core, out.get("none", {}).get("noise_floor"),
                                    gcps if (g == "gcp" or mode == "gcp") else None, out.get(tls))
        out[mode]["time_s"] = time.perf_counter() - t0
    return out


def _ctl_fig(r: dict, mode: str, cloud: str, what: str) -> float:
    c = r[mode][cloud]
    if c is None:  # the joint adjustment failed on this seed and setting
        return np.nan
    return {"c2c": c["c2c_rms_m"], "c2c_held": c.get("c2c_rms_held_out_m", np.nan),
            "m3c2": c["m3c2"]["rms_m"], "m3c2_mean": c["m3c2"]["mean_m"],
            "m3c2_held": c["m3c2"].get("held_out", {}).get("rms_m", np.nan),
            "m3c2_mean_held": c["m3c2"].get("held_out", {}).get("mean_m", np.nan),
            "m3c2_rigid": c["m3c2"]["rms_rigid_m"]}[what]


CONTROL_FIGURES = (("c2c", "C2C RMS, all"), ("c2c_held", "C2C RMS, held out"), ("m3c2", "M3C2 RMS, all"),
                   ("m3c2_mean", "M3C2 mean, all"), ("m3c2_held", "M3C2 RMS, held out"),
                   ("m3c2_mean_held", "M3C2 mean, held out"), ("m3c2_rigid", "M3C2 RMS after rigid fit, all"))


def print_control_table(out: list[dict], modes: list[str]) -> None:
    """Per control setting and figure: separate, joint, noise floor (mm), per seed and the mean; the ratio joint /
    separate and the acceptance line (<= 1/3; joint <= 1.5 x range noise)."""
    lim = 1.5 * out[0]["range_sigma_m"]
    print(f"\nlaser cloud vs TLS by control setting (mm); acceptance: joint / separate <= 1/3 and joint <= "
          f"{lim * 1e3:.0f} mm (1.5 x range noise)")
    print(f"{'control':<8}{'figure':<31}{'seed':>6}{'separate':>10}{'joint':>8}{'floor':>8}{'ratio':>7}  <=1/3  "
          f"<=1.5 noise")
    for mode in modes:
        for key, words in CONTROL_FIGURES:
            if "held" in key and mode in ("none", "gcp"):  # no reference-cloud control: all of the TLS is held out
                continue
            rows_ = [(str(r["seed"]), *(_ctl_fig(r, mode, c, key) for c in ("separate", "joint", "noise_floor")))
                     for r in out]
            rows_.append(("mean", *(float(np.nanmean([x[i] for x in rows_])) for i in (1, 2, 3))))
            for sd, a, b, f in rows_:
                signed = "mean" in key
                ratio = abs(b) / abs(a) if not signed else np.nan
                ok1 = "" if signed else ("yes" if ratio <= 1 / 3 else "no")
                ok2 = "" if signed else ("yes" if b <= lim else "no")
                print(f"{mode:<8}{words:<31}{sd:>6}{a * 1e3:>10.1f}{b * 1e3:>8.1f}{f * 1e3:>8.1f}"
                      f"{ratio:>7.2f}  {ok1:<5}  {ok2}")
    for mode in modes:
        failed = [r["seed"] for r in out if r[mode]["joint_fit"].get("failed")]
        if failed:
            print(f"{mode}: the joint adjustment FAILED on seed(s) {failed} (left out of the means): "
                  f"{out[[r['seed'] for r in out].index(failed[0])][mode]['joint_fit']['failed']}")
        gs = [r[mode]["joint_fit"]["gcp"] for r in out if r[mode]["joint_fit"].get("gcp")]
        if gs:
            print(f"{mode}: {gs[0]['count']} ground control points in the images, residual RMS (x, y, z) "
                  f"{np.round(np.mean([g['rms_m'] for g in gs], axis=0) * 1e3, 1).tolist()} mm (mean of the seeds), "
                  f"largest |normalised| {max(g['max_abs_normalised'] or 0.0 for g in gs):.2f}")
        if mode in ("none", "gcp"):
            continue
        c = [r[mode]["joint_fit"]["control"] for r in out if r[mode]["joint_fit"].get("control")]
        if not c:
            continue
        print(f"{mode}: control points {np.mean([r[mode]['control_points'] for r in out]):.0f} (mean), control planes "
              f"in the joint adjustment {np.mean([x['planes'] for x in c]):.0f}, in the separate one's points "
              f"{np.mean([r[mode]['separate_control_points'] for r in out]):.0f}; control residual z mean "
              f"{np.mean([x['z_mean'] for x in c]):+.2f}, std {np.mean([x['z_std'] for x in c]):.2f}, max |z| "
              f"{np.max([x['z_max_abs'] for x in c]):.2f}, left out as blunders "
              f"{sum(r[mode]['joint_fit']['control_rejected'] for r in out)}")
    for mode in modes:
        z = np.array([r[mode]["joint_fit"]["z_scanner"] for r in out if "z_scanner" in r[mode]["joint_fit"]])
        print(f"{mode}: joint scanner calibration z mean {z.mean():+.2f}, std {z.std():.2f} ({z.size} values)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--size", default="strips-ci", choices=("strips-ci", "strips"))
    ap.add_argument("--every", type=int, default=10, help="compare every n-th laser pulse with the TLS")
    ap.add_argument("--json", default=None)
    ap.add_argument("--roughness", type=float, default=None, help="the joint model's roughness floor (m)")
    ap.add_argument("--separate-only", action="store_true",
                    help="only the nominal mount and the separate (laser-only) calibration against the TLS")
    ap.add_argument("--control", default="none",
                    help="comma-separated control settings to compare: none, sparse, area, gcp, sparse+gcp, area+gcp "
                         "(module docstring)")
    ap.add_argument("--control-fraction", type=float, default=0.15, help="sparse: share of the plan cells")
    ap.add_argument("--control-cell", type=float, default=5.0, help="sparse: plan cell size (m)")
    a = ap.parse_args()
    modes = [m.strip() for m in a.control.split(",") if m.strip()]
    known = ("none", "sparse", "area", "gcp", "sparse+gcp", "area+gcp")
    bad = [m for m in modes if m not in known]
    if bad:
        ap.error(f"--control: unknown setting(s) {bad}; choose from {', '.join(known)}")
    if modes != ["none"]:
        modes = ["none"] + [m for m in modes if m != "none"]
        res = []
        for s in range(a.first_seed, a.first_seed + a.seeds):
            r = run_control_seed(a.size, s, a.every, modes, a.control_fraction, a.control_cell)
            res.append(r)
            if a.json:  # after every seed: a late failure keeps the seeds before it
                with open(a.json, "w") as f:
                    json.dump(res, f, indent=1)
            print(f"seed {s}: " + "; ".join(
                f"{m}: C2C separate {r[m]['separate']['c2c_rms_m'] * 1e3:.1f} joint "
                f"{_ctl_fig(r, m, 'joint', 'c2c') * 1e3:.1f} mm, M3C2 separate "
                f"{r[m]['separate']['m3c2']['rms_m'] * 1e3:.1f} joint {_ctl_fig(r, m, 'joint', 'm3c2') * 1e3:.1f} mm "
                f"({r[m]['time_s']:.0f} s)" for m in modes), flush=True)
        print_control_table(res, modes)
        if a.json:
            with open(a.json, "w") as f:
                json.dump(res, f, indent=1)
        return
    out = []
    for s in range(a.first_seed, a.first_seed + a.seeds):
        r = run_seed(a.size, s, a.every, a.roughness, joint=not a.separate_only)
        out.append(r)
        t = r["rms_tls_m"]
        sp = r["separate"]
        print(f"seed {s}: separate calibration {sp['iterations']} iterations, held {sp['held']}, range scale "
              f"{sp['range_scale'] * 1e6:.0f} ppm, z {np.round(np.array(sp['z_scanner'], float), 2).tolist()}; laser vs "
              f"TLS RMS nominal {t['nominal'] * 1e3:.1f} mm, separate {t['separate'] * 1e3:.1f} mm, noise floor "
              f"{t['noise_floor'] * 1e3:.1f} mm", flush=True)
        if a.separate_only:
            print(f"seed {s}: M3C2 RMS vs TLS {_m3c2_line(r)}", flush=True)
            continue
        print(f"seed {s}: range scale z {r['z_scanner'][7]:+.2f}; {r['laser_points']} laser points, {r['images']} images, joint {r['time_joint_s']:.1f} s "
              f"({r['cpu_joint_s']:.1f} s CPU, resident memory {r['rss_joint_start_gb']:.2f} -> peak "
              f"{r['rss_joint_peak_gb']:.2f} GB), "
              f"sigma0 {r['sigma0']:.2f}; max |z| scanner {np.max(np.abs(r['z_scanner'])):.2f}, camera "
              f"{np.max(np.abs(r['z_camera'])):.2f}, strips {np.max(np.abs(r['z_strips'])):.2f}; laser vs TLS RMS "
              f"nominal {t['nominal'] * 1e3:.1f} mm, separate {t['separate'] * 1e3:.1f} mm, joint "
              f"{t['joint'] * 1e3:.1f} mm; image tie points {t['image_tie_points'] * 1e3:.1f} mm; strip-to-strip "
              f"discrepancies RMS {r['discrepancies']['before']['rms_m'] * 1e3:.1f} -> "
              f"{r['discrepancies']['after']['rms_m'] * 1e3:.1f} mm (over sigma "
              f"{r['discrepancies']['before']['normalised_rms']:.2f} -> "
              f"{r['discrepancies']['after']['normalised_rms']:.2f})", flush=True)
        print(f"seed {s}: M3C2 RMS vs TLS {_m3c2_line(r)}", flush=True)
    zsep = np.array([r["separate"]["z_scanner"] for r in out], float)
    print(f"separate calibration z over {len(out)} seeds (held parameters left out): mean per parameter "
          f"{np.round(np.nanmean(zsep, axis=0), 2).tolist()}, std {np.round(np.nanstd(zsep, axis=0), 2).tolist()}")
    for k in ("nominal", "separate"):
        print(f"RMS vs TLS {k}: mean {np.mean([r['rms_tls_m'][k] for r in out]) * 1e3:.1f} mm")
    if a.separate_only:
        print_table(out)
        if a.json:
            with open(a.json, "w") as f:
                json.dump(out, f, indent=1)
        return
    zc = np.array([r["z_scanner"] + r["z_camera"] for r in out])
    zs = np.concatenate([r["z_strips"] for r in out])
    print(f"calibration z over {len(out)} seeds ({zc.size} values): mean {zc.mean():+.2f}, std {zc.std():.2f}; "
          f"per parameter mean {np.round(zc.mean(axis=0), 2).tolist()} std {np.round(zc.std(axis=0), 2).tolist()}")
    print(f"strip corrections z ({zs.size} values): mean {zs.mean():+.2f}, std {zs.std():.2f}")
    for k in ("before", "after"):
        v = np.array([[r["discrepancies"][k][c] for c in ("rms_m", "normalised_rms", "noise_rms_m")] for r in out])
        print(f"strip-to-strip discrepancies {k}: RMS {v[:, 0].mean() * 1e3:.1f} mm, over sigma {v[:, 1].mean():.2f} "
              f"(predicted noise {v[:, 2].mean() * 1e3:.1f} mm)")
    for k in ("joint", "image_tie_points"):
        v = np.array([r["rms_tls_m"][k] for r in out])
        print(f"RMS vs TLS {k}: mean {v.mean() * 1e3:.1f} mm")
    ratio = np.mean([r["rms_tls_m"]["joint"] for r in out]) / np.mean([r["rms_tls_m"]["separate"] for r in out])
    print(f"joint / separate RMS vs TLS: {ratio:.2f} (acceptance <= 1/3)")
    print_table(out)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
