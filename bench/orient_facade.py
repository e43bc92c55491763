"""Orientation without GNSS on the simulated façade (:func:`skyrig.simulate.closerange.facade_set`): skyrig from the
CLI (``skyrig adjust-uav --no-gps --scale-bar`` or ``--control``) and pycolmap's incremental mapper on **the same
tie-point measurements** (:func:`skyrig.orient.reference.pycolmap_from_tracks`), both against the truth of the
seeded simulation, in one run.

Usage::

    .venv/bin/python bench/orient_facade.py [--work /tmp/skyrig-bench-orient-facade] [--seed 1] [--points 1500]
        [--per-row 9] [--width 1500] [--sigma-px 0.5] [--datum scale-bar|control]

The start camera (skyrig and pycolmap alike) has the focal length 4 % off, no principal-point offset, no distortion
(the true camera has both).  Printed: images oriented, reprojection RMS; centres against the truth after a rigid motion
(scale-bar datum: the scale is what the bars give) or directly (control datum), and after a similarity (both
programs: pycolmap has no scale); the errors in units of skyrig's predicted sigma (max and RMS of |d| / |sigma|;
for a correct prediction the RMS of the normalised 3D error is about 1 and its max below 4); skyrig - pycolmap
centres after a similarity; the focal length each found against the truth.  Results in
``WORK/bench_orient_facade.json``; nothing is written into the repository.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np


def _write_project(proj: Path, s, start_camera, bar_sigma_m: float, n_control: int) -> None:
    from skyrig.georef.observations import ImageMeasurements
    from skyrig.io.points_csv import write_measurements_csv
    from skyrig.io.rig_file import write_rig
    from skyrig.rig.rig import Head, Rig

    (proj / "match").mkdir(parents=True, exist_ok=True)
    write_measurements_csv(proj / "match" / "tie_points.csv",
                           ImageMeasurements(s.point_name[s.obs_point], s.names[s.obs_image], s.obs_pixel))
    write_rig(Rig("start", {"camera": Head("camera", start_camera)}), proj / "camera.yaml")
    idx = {n: k for k, n in enumerate(s.point_name)}
    head = "# crs: local 48.85 2.35 35.0\nname,x,y,z\n"
    rows = [f"{n},{s.X[idx[n]][0]:.4f},{s.X[idx[n]][1]:.4f},{s.X[idx[n]][2]:.4f}\n" for n in s.target_names]
    (proj / "gcp.csv").write_text(head + "".join(rows[:n_control]))
    (proj / "check.csv").write_text(head + "".join(rows[n_control:]))
    (proj / "bars.csv").write_text("from,to,length_m,sigma_m\n" + "".join(
        f"{a},{b},{v:.4f},{bar_sigma_m}\n" for (a, b), v in zip(s.bars, s.bar_length)))


def _stats(d: np.ndarray, sig: np.ndarray) -> dict:
    e = np.linalg.norm(d, axis=1)
    z = e / np.linalg.norm(sig, axis=1)
    return {"rms_m": float(np.sqrt(np.mean(e ** 2))), "max_m": float(e.max()),
            "normalised_rms": float(np.sqrt(np.mean(z ** 2))), "normalised_max": float(z.max())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--work", default="/tmp/skyrig-bench-orient-facade")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--points", type=int, default=1500)
    ap.add_argument("--per-row", type=int, default=9)
    ap.add_argument("--width", type=int, default=1500)
    ap.add_argument("--sigma-px", type=float, default=0.5)
    ap.add_argument("--datum", choices=["scale-bar", "control"], default="scale-bar")
    a = ap.parse_args()
    from click.testing import CliRunner

    from skyrig.camera.opencv import OpenCVDistortion
    from skyrig.cli import main as cli
    from skyrig.match.colmap_check import similarity_transform
    from skyrig.orient.reference import pycolmap_from_tracks
    from skyrig.simulate.closerange import facade_set

    bar_sigma = 0.0005
    s = facade_set(seed=a.seed, n_points=a.points, n_per_row=a.per_row, width_px=a.width, sigma_px=a.sigma_px)
    start = s.camera.with_(focal_mm=s.camera.focal_mm * 1.04, ppx_mm=0.0, ppy_mm=0.0, distortion=OpenCVDistortion())
    work = Path(a.work)
    proj = work / "facade"
    proj.mkdir(parents=True, exist_ok=True)
    _write_project(proj, s, start, bar_sigma, 6)
    (proj / "orient.json").write_text(json.dumps({"pixel_sigma_px": a.sigma_px}))
    args = ["adjust-uav", str(proj), "--no-gps", "--camera", str(proj / "camera.yaml"), "--config",
            str(proj / "orient.json"), "-o", str(work / "orient")]
    args += (["--scale-bar", str(proj / "bars.csv")] if a.datum == "scale-bar" else
             ["--control", str(proj / "gcp.csv"), "--control-sigma", "0.002", "--check", str(proj / "check.csv")])
    t = time.perf_counter()
    r = CliRunner().invoke(cli, args)
    t_sky = time.perf_counter() - t
    if r.exit_code != 0:
        print(r.output)
        raise SystemExit(f"skyrig adjust-uav --no-gps exited {r.exit_code}")
    rep = json.loads((work / "orient" / "report.json").read_text())
    u = rep["uav"]
    from skyrig.io.eo_csv import read_eo_csv

    if a.datum == "control":
        eo = read_eo_csv(work / "orient" / "eo.csv")
        names, C = np.asarray(eo.image, str), np.asarray(eo.centre, float)
    else:  # model-frame table (metres)
        import csv

        text = (work / "orient" / "eo.csv").read_text().splitlines()
        rows = list(csv.DictReader(x for x in text if not x.startswith("#")))
        names = np.array([q["image"] for q in rows], str)
        C = np.array([[float(q[c]) for c in "xyz"] for q in rows])
    k = np.array([list(s.names).index(n) for n in names])
    sig = np.array([u["centre_sigma_m"][n] for n in names])
    T = s.C[k]
    out: dict = {"command": "skyrig " + " ".join(args), "images": int(len(s.names)), "skyrig_s": t_sky,
                 "skyrig": {"oriented": u["oriented"], "reprojection_rms_px": u["reprojection_rms_px"],
                            "sigma0": u["sigma0"], "focal_px": u["focal_px"], "true_focal_px": s.camera.focal_px,
                            "start_focal_px": start.focal_px,
                            "centre_sigma_rms_3d_m": float(np.sqrt(np.mean(np.sum(sig ** 2, axis=1))))}}
    if a.datum == "control":
        out["skyrig"]["vs_truth_direct"] = _stats(C - T, sig)
    else:  # rigid motion: the scale is the scale bars'
        _, Rr, _ = similarity_transform(C, T)
        d = (C - C.mean(axis=0)) @ Rr.T + T.mean(axis=0) - T
        out["skyrig"]["vs_truth_rigid"] = _stats(d, sig)
    sc, Rs, ts = similarity_transform(C, T)
    out["skyrig"]["vs_truth_similarity"] = _stats(sc * C @ Rs.T + ts - T, sig * sc)
    # pycolmap on the same measurements
    t = time.perf_counter()
    peer = pycolmap_from_tracks(s.names, start, s.obs_point, s.obs_image, s.obs_pixel, work / "pycolmap")
    out["pycolmap_s"] = time.perf_counter() - t
    if peer is None:
        out["pycolmap"] = {"registered": 0}
    else:
        kp = np.array([list(s.names).index(n) for n in peer.names])
        sp, Rp, tp = similarity_transform(peer.C, s.C[kp])
        dp = sp * peer.C @ Rp.T + tp - s.C[kp]
        isk = {n: q for q, n in enumerate(names)}
        com = [q for q, n in enumerate(peer.names) if n in isk]
        sig_p = np.array([sig[isk[peer.names[q]]] for q in com])
        out["pycolmap"] = dict(peer.summary, focal_px=peer.focal_px,
                               vs_truth_similarity=_stats(dp[com], sig_p))
        A, B = peer.C[com], C[[isk[peer.names[q]] for q in com]]
        s2, R2, t2 = similarity_transform(A, B)
        out["skyrig_minus_pycolmap"] = dict(_stats(s2 * A @ R2.T + t2 - B, sig_p * np.sqrt(2.0)), common=len(com))
    print(json.dumps(out, indent=1))
    (work / "bench_orient_facade.json").write_text(json.dumps(out, indent=1))
    print(f"written {work / 'bench_orient_facade.json'}")


if __name__ == "__main__":
    main()
