"""The live mode's acceptance (issue 35): a simulated 3K flight replayed at its real exposure rate (or ``--speed``
times it) into a watched folder, ``skyrig live``'s chain on it, and the batch answer of the same flight.

Printed (and written to OUT/acceptance.json):

* the time between exposures and, per exposure, the seconds from its last image being written to its ortho tiles
  (median, 95 %, max; and the CPU seconds of that work), and to its DSM tiles in exposure intervals;
* the online boresight after the windows so far (``--window`` exposures each) against the batch adjustment
  (every exposure in one adjustment: the same kinds of observations, tie points of all images + the reference DEM's
  heights, :func:`skyrig.pipeline.live_check.batch_boresight`), in units of the sigma of their difference
  (:func:`skyrig.pipeline.live_check.difference_sigma`: the two share most observations, so neither the online
  sigma nor the root sum of squares is the yardstick; the share is counted, docs/cli.md) and, as before, of the
  online sigma; also against a batch calibration with the surveyed control points instead of the DEM, and against
  the injected truth (``bench/live_stats.py`` checks over seeds that the sigmas are realistic);
* the live mosaic (finest zoom) against the batch ortho (all nadir images, DG with the control-point calibrated
  rig, same reference DEM):
  phase-correlation offsets of textured patches, in GSD.

Run: ``.venv/bin/python bench/live.py OUT [--speed 1] [--window 10] [--half-length 2450]`` (simulates into
OUT/flight unless it exists; about 10 minutes on 2 cores).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import threading
import time
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out")
    ap.add_argument("--speed", type=float, default=1.0)
    ap.add_argument("--window", type=int, default=10)
    ap.add_argument("--half-length", type=float, default=2450.0)
    ap.add_argument("--max-exposures", type=int, default=None)
    ap.add_argument("--dem-sigma", type=float, default=2.0)
    ap.add_argument("--features", type=int, default=800,
                    help="SIFT features per image of the online boresight and of the batch calibration it is judged "
                         "against (the same observations)")
    a = ap.parse_args(argv)
    from skyrig._plain import plain
    from skyrig.pipeline import live_check as lc
    from skyrig.pipeline.live import LiveConfig, LiveRun
    from skyrig.pipeline.live_replay import replay_flight

    out = Path(a.out)
    flight = out / "flight"
    if not (flight / "events.csv").exists():
        t = time.time()
        info = lc.simulate_3k_flight(flight, a.half_length)
        print(f"simulated {info['exposures']} exposures ({info['images']} images) in {time.time() - t:.0f} s")
    crs, height = "EPSG:25832", 80.0
    watch = out / "watched"
    shutil.rmtree(watch, ignore_errors=True)
    watch.mkdir(parents=True)
    shutil.copyfile(flight / "rig.yaml", watch / "rig.yaml")
    rep = threading.Thread(target=replay_flight, args=(flight, watch, a.speed),
                           kwargs={"max_exposures": a.max_exposures}, daemon=True)
    dem = flight / "reference_dem.tif"
    if not dem.exists():
        lc.reference_dem(flight, crs)
    cfg = LiveConfig(surface_height_m=height, crs=crs, window=a.window, dem_path=str(dem), surface_sigma_m=a.dem_sigma,
                     features=a.features)
    run = LiveRun(watch, out / "live", cfg,
                  say=lambda line: print("live:", line, flush=True))
    import os

    load0 = os.getloadavg()
    rep.start()
    t = time.time()
    s = run.run(max_wall_s=3600)
    load1 = os.getloadavg()
    print(f"live run {time.time() - t:.0f} s wall; load average (1, 5, 15 min) before {load0}, after {load1} "
          f"on {os.cpu_count()} CPUs")
    iv = s["exposure_interval_s"]
    for k in ("ortho_latency_s", "dsm_latency_s", "dsm_latency_exposures", "ortho_cpu_s", "dsm_cpu_s"):
        v = s.get(k) or {}
        print(f"{k}: median {v.get('median', float('nan')):.2f}, p90 {v.get('p90', float('nan')):.2f}, "
              f"max {v.get('max', float('nan')):.2f} (n {v.get('n')})")
    print(f"interval {iv:.2f} s; orthos within it: {s['ortho_within_interval_fraction']:.0%}; caught up "
          f"{s['caught_up']}; CPU s per exposure: ortho thread {s['ortho_cpu_s']['median']:.2f}, DSM thread "
          f"{(s.get('dsm_cpu_s') or {}).get('median', float('nan')):.2f}, online boresight "
          f"{s['boresight_cpu_s_per_exposure'] or float('nan'):.2f}, whole process "
          f"{s['process_cpu_s_per_exposure']:.2f} (interval {iv:.2f} s)", flush=True)
    truth = lc.true_corrections(flight)
    t = time.time()
    batch = lc.batch_boresight(flight, crs, a.max_exposures, dem, a.dem_sigma, a.features)
    print(f"batch calibration {time.time() - t:.0f} s: sigma0 {batch.sigma0:.3f}, {batch.n_points} points")
    t = time.time()
    gcp = lc.batch_boresight(flight, crs, a.max_exposures)
    print(f"batch calibration with control points {time.time() - t:.0f} s: sigma0 {gcp.sigma0:.3f}")
    est = run.estimate
    # the share of the online windows' tie observations the batch also holds: the sigma of online - batch
    shared = lc.shared_observations([w.ties for w in run._windows if w.ties is not None], batch.ties)
    print(f"online tie observations also in the batch: {shared:.1%}")
    rows = {}
    for h in sorted(est.correction):
        so = est.sigma(h)
        sb = np.sqrt(np.diag(batch.covariance[h]))
        d = est.correction[h] - batch.correction[h]
        sd = lc.difference_sigma(so, sb, shared)
        rows[h] = {"online_deg": np.degrees(est.correction[h]), "online_sigma_deg": np.degrees(so),
                   "batch_deg": np.degrees(batch.correction[h]), "batch_sigma_deg": np.degrees(sb),
                   "truth_deg": np.degrees(truth[h]), "online_minus_batch_in_online_sigma": d / so,
                   "difference_sigma_deg": np.degrees(sd), "online_minus_batch_in_difference_sigma": d / sd,
                   "online_minus_batch_in_nested_sigma": d / np.sqrt(np.abs(so**2 - sb**2)),
                   "batch_gcp_deg": np.degrees(gcp.correction[h]),
                   "batch_gcp_sigma_deg": np.degrees(np.sqrt(np.diag(gcp.covariance[h]))),
                   "online_minus_batch_gcp_in_online_sigma": (est.correction[h] - gcp.correction[h]) / so,
                   "online_minus_truth_in_online_sigma": (est.correction[h] - truth[h]) / so,
                   "batch_minus_truth_in_batch_sigma": (batch.correction[h] - truth[h]) / sb}
        print(f"{h}: online - batch = {np.round(d / sd, 2)} sigma of the difference ({np.round(d / so, 2)} online "
              f"sigma); online sigma {np.round(np.degrees(so), 4)} deg, batch sigma {np.round(np.degrees(sb), 4)} deg, "
              f"difference sigma {np.round(np.degrees(sd), 4)} deg")
    zmax = max(s["zooms"])
    t = time.time()
    cell = float(s["cell_m"]["median"])  # the nadir images' GSD on the plane, the live orthos' cell
    ortho = lc.batch_ortho(flight, crs, height, gcp.correction, cell, a.max_exposures, dem)
    off = lc.mosaic_offsets(out / "live" / "tiles", zmax, ortho)
    gsd = cell
    off["gsd_m"] = gsd
    off["median_offset_gsd"] = off["median_offset_m"] / gsd
    off["p90_offset_gsd"] = off["p90_offset_m"] / gsd
    print(f"batch ortho + comparison {time.time() - t:.0f} s: {off}")
    res = {"speed": a.speed, "window": a.window, "shared_tie_observations": shared, "load_before": load0,
           "load_after": load1, "summary": s, "boresight": rows,
           "boresight_windows": est.n_windows, "boresight_exposures": est.n_exposures, "mosaic": off}
    (out / "acceptance.json").write_text(json.dumps(plain(res), indent=1))
    for k in ("exposure_interval_s", "ortho_latency_s", "ortho_cpu_s", "dsm_latency_s", "dsm_latency_exposures",
              "dsm_cpu_s", "boresight_cpu_s_per_exposure", "process_cpu_s_per_exposure", "caught_up"):
        print(k, json.dumps(plain(s.get(k))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
