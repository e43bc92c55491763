"""Is the online boresight's sigma realistic, is it biased, and what sigma judges "online vs batch" (issue 35)?

Per seed: the simulated 3K flight of ``bench/live.py`` (:func:`skyrig.pipeline.live_check.simulate_3k_flight`,
two strips, 52 exposures, seed-dependent scene, GNSS/IMU noise and image rendering), then without the replay's
timing (the same window code the live run calls, :func:`skyrig.calibrate.online_boresight.estimate_window`, the
rig of each window corrected by the windows before it as in the live run):

* the online estimate after ``--exposures`` exposures (windows of ``--window``), combined over the windows;
* the batch calibration: every exposure in one adjustment, the same features (``--features`` per image), the same
  kinds of observations (tie points of consecutive exposures and across heads, reference DEM heights, GNSS/IMU);

each twice: with one variance factor for every observation group (sigma0^2, the live default before this check)
and with the groups' variance components estimated from the residuals (``variance_components``).

Per angle (3 heads x roll/pitch/yaw) it records the errors against the injected truth and the online - batch
differences; the summary over seeds gives, for each candidate sigma, the RMS and the largest of the normalised
values (a realistic sigma gives RMS ~1) and the mean error over seeds (a bias).  Candidates for the difference
``d = online - batch``: ``sqrt(s_on^2 - s_b^2)`` (the online's observations a subset of the batch's),
``sqrt(s_on^2 + s_b^2)`` (independent) and ``sqrt(s_on^2 + (1 - 2 f) s_b^2)`` with ``f`` the share of the online's
tie observations that the batch also holds (derivation in docs/cli.md, live mode).

Run: ``nice .venv/bin/python bench/live_stats.py OUT --seeds 1 2 3 4 5`` (a flight per seed in OUT/seed<N>/flight,
simulated unless there; per seed about 4 min of CPU); ``--summary`` only summarises OUT/seed*/stats.json.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np


#: variant name -> (variance components, data snooping) of every adjustment
VARIANTS = {"sigma0": (False, False), "vce": (True, False), "snooping": (False, True),
            "imagevce": ("image", True)}  # imagevce: the live default (runs stored before its covariance was taken
#                                            unscaled hold sigma0^2 x it: docs/cli.md)


def one_seed(out: Path, seed: int, window: int, n_exposures: int, n_features: int, dem_sigma: float,
             half_length: float, variants: list[str], dem_cell: float = 30.0) -> dict:
    from skyrig._plain import plain
    from skyrig.calibrate import online_boresight as ob
    from skyrig.georef.direct import direct_georeference
    from skyrig.io.dem import read_dem
    from skyrig.io.images import read_image
    from skyrig.match.features import FeatureConfig
    from skyrig.pipeline import live_check as lc

    flight = out / f"seed{seed}" / "flight"
    if not (flight / "events.csv").exists():
        t = time.time()
        lc.simulate_3k_flight(flight, half_length, seed=seed, workers=1)
        print(f"seed {seed}: simulated in {time.time() - t:.0f} s", flush=True)
    crs = "EPSG:25832"
    traj, ev, rig, frame = lc._flight(flight, crs)
    dem_file = flight / ("reference_dem.tif" if dem_cell == 30.0 else f"reference_dem_{dem_cell:g}m.tif")
    if not dem_file.exists():
        lc.reference_dem(flight, crs, dem_cell, dem_file.name)
    dem = read_dem(dem_file)
    cams = {h.camera.name: h.camera for h in rig}
    cross = [("nadir", h) for h in rig.heads if h != "nadir"]

    def height_at(x, y):
        h = dem.sample(x, y)
        return np.where(np.isfinite(h), h, 80.0)

    feats: dict = {}

    def feature(name: str):
        if name not in feats:
            feats[name] = ob.features_of(read_image(flight / "images" / name),
                                         FeatureConfig(max_size=None, max_features=n_features))
        return feats[name]

    exposures = sorted(set(ev.exposure_id.tolist()))
    truth = lc.true_corrections(flight)
    res: dict = {"seed": seed, "window": window, "exposures": n_exposures, "features": n_features,
                 "truth": truth, "variants": {}}
    path = out / f"seed{seed}" / "stats.json"
    if path.exists():  # earlier variants of this seed are kept
        res["variants"] = json.loads(path.read_text()).get("variants", {})
    for variant in variants:
        vce, snoop = VARIANTS[variant]
        key = variant if dem_cell == 30.0 else f"{variant}_dem{dem_cell:g}m"
        t = time.time()
        windows: list = []
        est = ob.BoresightEstimate()
        for k in range(n_exposures // window):
            sel = np.flatnonzero(np.isin(ev.exposure_id, exposures[k * window:(k + 1) * window]))
            eo = direct_georeference(traj, ob.rig_with_corrections(rig, est.correction), ev.subset(sel), frame)
            windows.append(ob.estimate_window(eo, cams, lambda i, eo=eo: feature(str(eo.image[i])), traj, rig, ev,
                                              height_at, dem_sigma, cross=cross, prefix=f"w{k}_",
                                              variance_components=vce, snooping=snoop))
            est = ob.combine(windows)
        t_on = time.time() - t
        t = time.time()
        eo = direct_georeference(traj, rig, ev, frame)
        batch = ob.estimate_window(eo, cams, lambda i: feature(str(eo.image[i])), traj, rig, ev, height_at,
                                   dem_sigma, cross=cross, prefix="b", variance_components=vce, snooping=snoop)
        t_b = time.time() - t
        shared = lc.shared_observations([w.ties for w in windows], batch.ties)
        res["variants"][key] = {
            "online": {"correction": est.correction, "covariance": est.covariance, "seconds": t_on,
                       "sigma0": [w.sigma0 for w in windows], "points": [w.n_points for w in windows]},
            "batch": {"correction": batch.correction, "covariance": batch.covariance, "seconds": t_b,
                      "sigma0": batch.sigma0, "points": batch.n_points},
            "shared_tie_observations": shared}
        print(f"seed {seed} {key}: online {t_on:.0f} s, batch {t_b:.0f} s, shared ties "
              f"{shared:.2f}", flush=True)
    path.write_text(json.dumps(plain(res)))
    return res


def summarise(out: Path) -> dict:
    from scipy.stats import chi2

    from skyrig.pipeline.live_check import difference_sigma

    runs = [json.loads(p.read_text()) for p in sorted(out.glob("seed*/stats.json"))]
    if not runs:
        raise SystemExit(f"no {out}/seed*/stats.json")
    summary: dict = {"seeds": [r["seed"] for r in runs]}
    names = sorted({k for r in runs for k in r["variants"]})
    for var in names:
        runs_v = [r for r in runs if var in r["variants"]]
        if not runs_v:
            continue
        z: dict[str, list] = {k: [] for k in ("online_truth", "batch_truth", "diff_online_sigma", "diff_nested",
                                              "diff_independent", "diff_shared")}
        err_on, err_b, f_all = [], [], []
        for r in runs_v:
            v = r["variants"][var]
            f = v["shared_tie_observations"]
            f_all.append(f)
            for h in sorted(r["truth"]):
                tr = np.array(r["truth"][h])
                on, b = np.array(v["online"]["correction"][h]), np.array(v["batch"]["correction"][h])
                so = np.sqrt(np.diag(np.array(v["online"]["covariance"][h])))
                sb = np.sqrt(np.diag(np.array(v["batch"]["covariance"][h])))
                d = on - b
                z["online_truth"] += list((on - tr) / so)
                z["batch_truth"] += list((b - tr) / sb)
                z["diff_online_sigma"] += list(d / so)
                z["diff_nested"] += list(d / np.sqrt(np.abs(so**2 - sb**2)))
                z["diff_independent"] += list(d / np.sqrt(so**2 + sb**2))
                z["diff_shared"] += list(d / difference_sigma(so, sb, f))
                err_on.append(np.degrees(on - tr))
                err_b.append(np.degrees(b - tr))
        n = len(z["online_truth"])
        s = {k: {"rms": float(np.sqrt(np.mean(np.square(x)))), "max_abs": float(np.max(np.abs(x))),
                 "within_2": float(np.mean(np.abs(x) <= 2.0))} for k, x in z.items()}
        e_on = np.array(err_on).reshape(len(runs_v), -1, 3)  # seed, head, angle
        e_b = np.array(err_b).reshape(len(runs_v), -1, 3)
        s["seeds"] = [r["seed"] for r in runs_v]
        s["n_values"] = n
        s["shared_tie_observations"] = f_all
        s["online_mean_error_deg"] = e_on.mean(axis=0).tolist()
        s["online_mean_error_se_deg"] = (e_on.std(axis=0, ddof=1) / np.sqrt(len(runs_v))).tolist() \
            if len(runs_v) > 1 else None
        s["batch_mean_error_deg"] = e_b.mean(axis=0).tolist()
        s["online_rms_error_deg"] = float(np.sqrt(np.mean(e_on**2)))
        # the errors less their mean over the seeds (the bias common to the seeds), in sigma: the random part
        if len(runs_v) > 1:
            k = len(runs_v)
            for name, e, key in (("online_truth_less_mean", e_on, "online"), ("batch_truth_less_mean", e_b, "batch")):
                sig = np.degrees(np.array([[np.sqrt(np.diag(np.array(r["variants"][var][key]["covariance"][h])))
                                            for h in sorted(r["truth"])] for r in runs_v]))
                zz = (e - e.mean(axis=0)) / sig * np.sqrt(k / (k - 1))
                s[name] = {"rms": float(np.sqrt(np.mean(zz**2))), "max_abs": float(np.max(np.abs(zz)))}
            s["online_mean_error_in_sigma"] = (e_on.mean(axis=0) / np.degrees(np.array(
                [[np.sqrt(np.diag(np.array(r["variants"][var]["online"]["covariance"][h]))) for h in sorted(r["truth"])]
                 for r in runs_v])).mean(axis=0)).tolist()
        summary[var] = s
        # the chi-square bounds a realistic sigma's RMS of n normalised values stays within (95 %, independent)
        s["rms_bounds_95"] = [float(np.sqrt(chi2.ppf(0.025, n) / n)), float(np.sqrt(chi2.ppf(0.975, n) / n))]
    return summary


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out")
    ap.add_argument("--seeds", type=int, nargs="*", default=[1, 2, 3, 4, 5])
    ap.add_argument("--window", type=int, default=10)
    ap.add_argument("--exposures", type=int, default=50)
    ap.add_argument("--features", type=int, default=800)
    ap.add_argument("--dem-sigma", type=float, default=2.0)
    ap.add_argument("--half-length", type=float, default=2450.0)
    ap.add_argument("--variants", nargs="*", default=["imagevce"], choices=sorted(VARIANTS),
                    help="sigma0: one variance factor, no snooping (the live default before); vce: variance "
                         "components of every group; snooping: data snooping, one variance factor; imagevce: "
                         "snooping and the image sigma estimated alone (the live default)")
    ap.add_argument("--dem-cell", type=float, default=30.0,
                    help="cell of the reference DEM made from the scene's surface (30: a public DEM; a few metres: "
                         "nearly the true surface, to tell the DEM's share of the error)")
    ap.add_argument("--summary", action="store_true", help="only summarise OUT/seed*/stats.json")
    a = ap.parse_args(argv)
    out = Path(a.out)
    if not a.summary:
        for seed in a.seeds:
            one_seed(out, seed, a.window, a.exposures, a.features, a.dem_sigma, a.half_length, a.variants, a.dem_cell)
    s = summarise(out)
    (out / "summary.json").write_text(json.dumps(s, indent=1))
    print(json.dumps(s, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
