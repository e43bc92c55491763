"""Normalised errors of ``skyrig calibrate calqc``'s estimated calibration parameters over many seeds (issue 12:
"Normalised errors of every estimated calibration parameter over >= 20 seeds are consistent with N(0,1)").

Per seed a reduced simulated MIDAS boresight flight (:func:`skyrig.calibrate.calqc.midas_calqc_scenario`: two
heights, both directions, IO errors and a GNSS datum shift injected, a new random draw of everything), the recipe
without the Tab. 11 variants, and ``(estimate - truth) / sigma`` of every head's boresight (3), IO (3) and the datum
shift (3): 33 per seed.  Pooled and per parameter kind: mean, standard deviation, share within 2 sigma, and the
Kolmogorov-Smirnov p-value against N(0, 1); per parameter (over seeds) the mean and std, so that a parameter with a
bias or a wrong sigma shows although the pool looks fine.

    nice .venv/bin/python bench/calqc_seeds.py --seeds 20 [--camera-width 600] [--tie-points 800] [--json out.json]
        [--sigmas simulated]   (a-priori sigmas = the simulated noise: the defaults are 5 cm GNSS / control for
                                3/3/5 cm and 2/2/3 cm drawn, so the GNSS- and control-borne sigmas come out too large)
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
from scipy.stats import kstest


def simulated_sigmas(truth) -> dict[str, object]:  # type: ignore[no-untyped-def]
    """The recipe's a-priori sigmas equal to the noise the simulation drew (GNSS E/N/U, IMU roll/pitch/yaw, control,
    image), instead of the recipe's defaults (5 cm GNSS and control for 3/3/5 and 2/2/3 cm simulated)."""
    e = truth.survey.spec.errors
    px_um = truth.survey.rig_recorded.head("nadir").camera.pixel_size_mm * 1000.0
    return {"gnss_sigma_m": tuple(float(v) for v in e.gnss_noise_m),
            "imu_sigma_deg": tuple(float(np.degrees(v)) for v in e.imu_noise_rad),
            "control_sigma_m": tuple(float(v) for v in e.gcp_sigma_m),
            "image_sigma_um": float(e.measurement_sigma_px * px_um)}


def one(seed: int, width: int, ties: int, deformation_px: float, grid: bool, sigmas: str = "recipe",
        grid_method: str = "joint") -> dict[str, float]:
    from skyrig.calibrate.calqc import calibrate_calqc, midas_calqc_scenario

    data, truth = midas_calqc_scenario("reduced", seed, tie_points=ties, camera_width_px=width,
                                       deformation_px=deformation_px)
    kw = simulated_sigmas(truth) if sigmas == "simulated" else {}
    cal = calibrate_calqc(data, variants=False, grid=grid, design=False, grid_method=grid_method, **kw)
    z: dict[str, float] = {}
    for h, (v, cov) in cal.boresight.items():
        for a, x in zip(("rx", "ry", "rz"), (v - truth.boresight_rotvec_rad[h]) / np.sqrt(np.diag(cov))):
            z[f"boresight {h} {a}"] = float(x)
    for h, (names, v, cov) in cal.interior.items():
        tv = np.array([truth.intrinsics[h][n] for n in names])
        for n, x in zip(names, (v - tv) / np.sqrt(np.diag(cov))):
            z[f"IO {h} {n}"] = float(x)
    for a, x in zip("XYZ", (cal.datum_shift_m - truth.datum_shift_m) / np.sqrt(np.diag(cal.datum_shift_cov_m2))):
        z[f"datum shift {a}"] = float(x)
    return z


def summary(v: np.ndarray) -> dict[str, float]:
    v = np.asarray(v, float)
    return {"n": int(v.size), "mean": float(v.mean()), "std": float(v.std(ddof=1)),
            "within_2sigma": float(np.mean(np.abs(v) <= 2)), "max_abs": float(np.abs(v).max()),
            "ks_pvalue": float(kstest(v, "norm").pvalue)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--camera-width", type=int, default=600)
    ap.add_argument("--tie-points", type=int, default=800)
    ap.add_argument("--deformation-px", type=float, default=0.0)
    ap.add_argument("--grid", action="store_true", help="with the correction grid (iterated with the IO)")
    ap.add_argument("--sigmas", choices=("recipe", "simulated"), default="recipe",
                    help="a-priori sigmas: the recipe's defaults, or the noise the simulation drew")
    ap.add_argument("--grid-method", choices=("joint", "cycles"), default="joint",
                    help="grid node values as unknowns of the adjustment (joint) or grids from residuals (cycles)")
    ap.add_argument("--json", default=None)
    ap.add_argument("--rows", default=None, help="append each seed's normalised errors to this file as a JSON line "
                                                 "(a long run can be summarised while it goes: --from-rows)")
    ap.add_argument("--from-rows", default=None, help="summarise the seeds of a --rows file instead of running")
    a = ap.parse_args(argv)
    from skyrig.calibrate.calqc import CalqcFailed

    rows: list[dict[str, float]] = []
    failed: list[dict[str, object]] = []
    t0 = time.perf_counter()
    if a.from_rows:
        with open(a.from_rows) as fh:
            for line in fh:
                rec = json.loads(line)
                if "error" in rec:
                    failed.append(rec)
                else:
                    rows.append(rec["z"])
        print(f"{len(rows)} seeds from {a.from_rows}")
    for s in range(a.first_seed, a.first_seed + a.seeds) if not a.from_rows else ():
        t = time.perf_counter()
        try:
            rows.append(one(s, a.camera_width, a.tie_points, a.deformation_px, a.grid, a.sigmas, a.grid_method))
        except CalqcFailed as exc:  # counted and reported, not dropped silently
            failed.append({"seed": s, "error": str(exc)})
            print(f"seed {s}: FAILED: {exc}", flush=True)
            if a.rows:
                with open(a.rows, "a") as fh:
                    fh.write(json.dumps(failed[-1]) + "\n")
            continue
        if a.rows:
            with open(a.rows, "a") as fh:
                fh.write(json.dumps({"seed": s, "z": rows[-1]}) + "\n")
        print(f"seed {s}: max |z| {max(abs(x) for x in rows[-1].values()):.2f} ({time.perf_counter() - t:.0f} s)",
              flush=True)
    if not rows:
        print(json.dumps({"failed": failed}, indent=1))
        return 1
    keys = list(rows[0])
    m = np.array([[r[k] for k in keys] for r in rows])
    out = {"args": vars(a), "seconds": time.perf_counter() - t0, "failed": failed, "pooled": summary(m.ravel()),
           "kinds": {}, "parameters": {k: {"mean": float(m[:, i].mean()), "std": float(m[:, i].std(ddof=1))}
                                       for i, k in enumerate(keys)}, "z": {k: m[:, i].tolist() for i, k in enumerate(keys)}}
    for kind in ("boresight", "IO", "datum shift"):
        sel = [i for i, k in enumerate(keys) if k.startswith(kind)]
        out["kinds"][kind] = summary(m[:, sel].ravel())
    for kind in ("focal_mm", "ppx_mm", "ppy_mm"):
        sel = [i for i, k in enumerate(keys) if k.endswith(kind)]
        out["kinds"][f"IO {kind}"] = summary(m[:, sel].ravel())
    # a parameter whose mean over the seeds is off by more than 3 standard errors (biased), or whose std is
    # outside the chi-square 99 % band (sigma wrong)
    from scipy.stats import chi2

    n = m.shape[0]
    lo, hi = np.sqrt(chi2.ppf([0.005, 0.995], n - 1) / (n - 1))
    out["suspect_parameters"] = [k for i, k in enumerate(keys)
                                 if abs(m[:, i].mean()) > 3 / np.sqrt(n) or not lo <= m[:, i].std(ddof=1) <= hi]
    print(json.dumps({k: out[k] for k in ("pooled", "kinds", "suspect_parameters", "seconds", "failed")}, indent=1))
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=1)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
