"""Paper 000's laboratory set-up simulated, and ``skyrig calibrate tumbling-head`` judged against its truth.

    .venv/bin/python bench/tumbling_lab.py [--positions 72] [--circles 5] [--width 640] [--window-px 32] [--seed 1]
        [--seeds 1-12] [--cache DIR] [--out FILE.json]

The MACS-TumbleCam rig (``skyrig.rig.presets.macs_tumblecam``, cameras scaled to ``--width`` px) plus a static wide
reference camera on the sensor head, held still ``--distance`` m above a textured plane (multi-scale random texture,
3 mm cells).  The true tumbling mount carries a smooth boresight curve (``skyrig.simulate.errors.tumble_curve_samples``,
the tumblecam scenario's amplitudes) and, per circle and position, a repeat error drawn with paper 000 Tab. 2's mean
repeatability (2 sigma -> 1 sigma).  Images are rendered exactly (every pixel's ray meets the plane, texture
sampled bilinearly, 1 DN noise).  The recipe is run with the nominal rig (no curve) and the recovered curve is
compared with the true one; oblique image points are projected with the calibrated and the uncalibrated rig.
With ``--seeds`` the summary pools the labs' normalised errors, (estimate - truth) / stated sigma, of the lookup
values and of the Fourier terms (plain, whitened with the stated covariance, and for the lookup against the old upper
bound), per axis and all axes: mean, std, RMS and the Kolmogorov-Smirnov p against N(0, 1); and how many labs have
every value within the stated simultaneous band.  Images the recipe left out (``images_left_out``: name, circle,
beta, reason) are listed per lab, counted per lab and by kind of failure in the summary; the judged errors use the
images measured.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from skyrig.calibrate.tumbling_simulation import (  # noqa: F401  (the lab moved to the library; re-exported for the tests)
    CURVE_AMP_RAD,
    TAB2_MEAN_2SIGMA_DEG,
    Lab,
    build_lab,
    lab_draws,
    make_texture,
    render_lab,
    render_plane,
)


def draw_check(positions: int, circles: int, seeds: int) -> dict[str, Any]:
    """Are the drawn repeat errors what they should be?  Over labs 1..``seeds``: the mean of each lab's
    ``circles x positions`` draws per axis, in units of its expected sd (N(0, 1) if they are independent), its spread
    over the labs, how often it is as far out as lab 1's worst axis (lab 1 counted), and the draws' lag-1
    correlation between circles and between positions."""
    m, rc, rp = [], [], []
    for s in range(1, seeds + 1):
        z = lab_draws(positions, circles, s)[2]
        m.append(z.mean(axis=(0, 1)) * np.sqrt(circles * positions))
        rc.append(np.mean(z[1:] * z[:-1]))
        rp.append(np.mean(z[:, 1:] * z[:, :-1]))
    m = np.array(m)
    return {"labs": seeds, "lab1_mean_z": m[0].tolist(), "mean_z_sd_over_labs": m.std(axis=0).tolist(),
            "share_at_or_beyond_lab1_worst": np.mean(np.abs(m) >= np.abs(m[0]).max(), axis=0).tolist(),
            "lag1_corr_between_circles": float(np.mean(rc)), "lag1_corr_between_positions": float(np.mean(rp))}


def write_lab(lab: Lab, images: dict[str, np.ndarray], ref: np.ndarray, folder: Path) -> dict[str, Path]:
    """The CLI's inputs: images/, rig.yaml (nominal, no curve), positions.csv (image,circle,beta_deg)."""
    from skyrig.io.rig_file import write_rig

    (folder / "images").mkdir(parents=True, exist_ok=True)
    for n, im in images.items():
        cv2.imwrite(str(folder / "images" / n), im[:, :, ::-1])
    cv2.imwrite(str(folder / "images" / "reference.png"), ref[:, :, ::-1])
    write_rig(lab.setup.rig, folder / "rig.yaml")
    lines = ["image,circle,beta_deg"] + [f"{n},{c},{np.degrees(b):.6f}" for n, c, b in zip(lab.names, lab.circles,
                                                                                           lab.betas)]
    (folder / "positions.csv").write_text("\n".join(lines) + "\n")
    return {"images": folder / "images", "rig": folder / "rig.yaml", "positions": folder / "positions.csv"}


def image_point_errors(lab: Lab, rig: Any, grid: int = 7) -> dict[str, float]:
    """Pixel error of plane points seen through a pixel lattice of every true tumbling image, projected with the
    orientation ``rig`` gives (its curve, if any, at the image's beta)."""
    from skyrig.calibrate.tumbling import ENU_FROM_BODY

    plane = lab.setup.plane
    cam = lab.setup.rig.head(lab.setup.head).camera
    head = rig.head(lab.setup.head)
    g = np.linspace(0.05, 0.95, grid)
    px = np.stack(np.meshgrid(g * (cam.width - 1), g * (cam.height - 1)), -1).reshape(-1, 2)
    errs = []
    k_pos = lab.beta_rad.size
    for i, b in enumerate(lab.betas):
        c, k = divmod(i, k_pos)
        r_t, ctr = lab.setup.tumbling_orientation(b, lab.true_rad[c, k])
        x = plane.to_world(plane.intersect(ctr, cam.rays_from_pixels(px) @ r_t.T))
        r_e = ENU_FROM_BODY @ head.body_from_camera_rotation(b)
        est = cam.project_pixels((x - ctr) @ r_e)
        errs.append(np.linalg.norm(est - px, axis=1))
    d = np.concatenate(errs)
    return {"rms_px": float(np.sqrt(np.mean(d ** 2))), "max_px": float(d.max())}


def written_rig(cal: Any) -> Any:
    """The calibrated rig as ``skyrig calibrate tumbling-head`` writes it (rig file with the calibration section),
    read back (what ``georef``/``transfer`` would use)."""
    import tempfile

    from skyrig.io.rig_file import read_calibrated_rig, write_rig

    with tempfile.TemporaryDirectory() as d:
        f = Path(d) / "calibrated_rig.yaml"
        write_rig(cal.calibrated_rig(), f, cal.rig_calibration("simulated lab"))
        return read_calibrated_rig(f)[0]


def judge(lab: Lab, cal: Any) -> dict[str, Any]:
    """The recovered mean curve against the true curve (normalised by the recipe's own standard errors) and the
    mechanism repeatability the recipe reports (measurement noise removed) against the injected one."""
    from scipy.stats import chi2, kstest

    from skyrig.rig.boresight_curve import AXES

    c, k = lab.true_rad.shape[:2]
    ok = cal.measured  # (C, K) images not left out
    n_k = cal.counts[:, None]  # circles measured per position
    err = cal.mean_rad - lab.true_curve(cal.beta_rad)
    err_img = cal.corrections_rad - lab.true_rad  # every image's measurement error (NaN: left out)
    rep_part = np.nanmean(err_img, axis=0)  # the part that repeats over the circles (+ varying / sqrt(C_k))
    # injected repeat errors, mean over the circles measured at each position
    rep_draw = np.where(ok[..., None], lab.true_rad - lab.true_curve(cal.beta_rad)[None], 0.0).sum(axis=0) / n_k
    vary = np.sqrt(np.nansum((err_img - rep_part) ** 2, axis=(0, 1)) / cal.scatter_dof)
    # the realised repeating share of the fit variance: the circle-mean comparison error's variance less the
    # varying part's over C_k, over the mean fit variance (what TumblingCalibration.repeat_share estimates)
    share = np.mean(rep_part ** 2 - vary[None] ** 2 / n_k, axis=0) / cal.measurement_variance_rad2
    fit_sig = np.sqrt(cal.measurement_variance_rad2)
    se = cal.standard_error_rad  # (K, 3) the recipe's
    z = err / se
    realised = np.sqrt(np.mean(np.var(lab.true_rad, axis=0, ddof=1), axis=0))  # the injected errors' own scatter
    mech, mech_se = cal.mechanism_repeatability_rad()
    bonferroni = float(np.sqrt(chi2.ppf(1 - 0.05 / (k * 3), 1)))  # |z| bound for K x 3 draws at 5 % family-wise
    out: dict[str, Any] = {"positions": int(k), "circles": int(c), "windows_min": int(cal.windows[ok].min()),
                           "windows_median": float(np.median(cal.windows[ok])), "z_bound_familywise_5pct": bonferroni,
                           "images_left_out": [f.to_dict() for f in cal.failed],
                           "circles_per_position_min": int(cal.counts.min())}
    md = lambda x: 1000 * float(np.degrees(x))  # noqa: E731
    for i, a in enumerate(AXES):
        out[a] = {"curve_err_rms_mdeg": md(np.sqrt(np.mean(err[:, i] ** 2))),
                  "curve_err_max_mdeg": md(np.abs(err[:, i]).max()),
                  "curve_amp_mdeg": md(np.abs(lab.true_curve(cal.beta_rad)[:, i]).max()),
                  "recipe_se_median_mdeg": md(np.median(se[:, i])),
                  "max_abs_z": float(np.abs(z[:, i]).max()),
                  "rms_z": float(np.sqrt(np.mean(z[:, i] ** 2))),
                  "within_2sigma": float(np.mean(np.abs(z[:, i]) <= 2)),
                  "positions_beyond_2sigma": int(np.sum(np.abs(z[:, i]) > 2)),
                  "within_2x_repeatability": float(np.mean(np.abs(err[:, i]) <= 2 * cal.std_rad[:, i])),
                  "within_2x_pooled_repeatability": float(np.mean(np.abs(err[:, i]) <= 2 * cal.pooled_std_rad[i])),
                  "image_err_rms_mdeg": md(np.sqrt(np.nanmean(err_img[..., i] ** 2))),
                  "image_err_varying_mdeg": md(vary[i]),
                  "fit_sigma_mdeg": md(fit_sig[i]),
                  "pooled_repeat_mdeg": md(cal.pooled_std_rad[i]),
                  "injected_repeat_mdeg": md(lab.repeat_sigma_rad[i]),
                  "realised_repeat_mdeg": md(realised[i]),
                  "mechanism_repeat_mdeg": md(mech[i]),
                  "mechanism_repeat_se_mdeg": md(mech_se[i]),
                  # the mean curve's error split: the mechanism's repeat errors drawn for this lab (their mean over
                  # the circles; the recipe cannot tell them from the curve) and the image comparison's error
                  "curve_err_from_repeat_draw_rms_mdeg": md(np.sqrt(np.mean(rep_draw[:, i] ** 2))),
                  "curve_err_from_measurement_rms_mdeg": md(np.sqrt(np.mean(rep_part[:, i] ** 2))),
                  "repeat_draw_mean_over_positions_mdeg": md(rep_draw[:, i].mean()),
                  "repeat_draw_mean_expected_sd_mdeg": md(lab.repeat_sigma_rad[i] / np.sqrt(c * k)),
                  "mechanism_over_injected": float(mech[i] / lab.repeat_sigma_rad[i]),
                  "mechanism_over_realised": float(mech[i] / realised[i]),
                  "repeat_share_realised": float(share[i]), "repeat_share_estimated": float(cal.repeat_share.share[i]),
                  "repeat_share_se": float(cal.repeat_share.share_se[i])}
    # a check of the per-position sigma that needs no truth: the mean curve is smooth, so a Fourier series of an order
    # above the curve's fits it to its noise; the weighted residuals' variance factor (chi-square / dof) is then
    # about 1 when the per-position sigma is right, below 1 when it is conservative
    for order in (o for o in (4, 6) if 2 * o + 1 < k):
        A = np.column_stack([np.ones(k)] + [f(j * cal.beta_rad) for j in range(1, order + 1) for f in (np.cos, np.sin)])
        for i, a in enumerate(AXES):
            w = 1.0 / se[:, i] ** 2
            x = np.linalg.solve(A.T @ (A * w[:, None]), A.T @ (w * cal.mean_rad[:, i]))
            r = cal.mean_rad[:, i] - A @ x
            out[a][f"fourier{order}_variance_factor"] = float(np.sum(w * r ** 2) / (k - A.shape[1]))
    out["z_all_ks_pvalue_vs_N01"] = float(kstest(z.ravel(), "norm").pvalue)
    out["curve_statement"] = judge_statement(lab, cal)
    out["image_points_uncalibrated"] = image_point_errors(lab, lab.setup.rig)
    out["image_points_calibrated"] = image_point_errors(lab, cal.calibrated_rig())
    out["image_points_written_rig"] = image_point_errors(lab, written_rig(cal))
    out["image_points_true_curve"] = image_point_errors(lab, lab.rig_true)
    return out


def judge_statement(lab: Lab, cal: Any, level: float = 0.95) -> dict[str, Any]:
    """The two statements of the curve (:meth:`TumblingCalibration.curve_statement`) against the true curve: per
    position (the lookup in the rig file) and as a Fourier series with its covariance; for each the positions beyond
    2 sigma, the largest |z| against the simultaneous band at ``level``, and (series) the terms' z against the true
    curve's own terms."""
    from skyrig.calibrate.tumbling import fourier_design

    truth = lab.true_curve(cal.beta_rad)
    st = cal.curve_statement(level)  # the bands as the recipe states them
    err = cal.mean_rad - truth
    z_l = err / cal.standard_error_rad
    c_l = st["lookup"]["simultaneous_z"]
    # whitened with the stated 3 x 3 covariance of each position (the axes of a position are correlated)
    chol = np.linalg.cholesky(cal.mean_covariance_rad2)
    w_l = np.linalg.solve(chol, err[..., None])[..., 0]
    z_b = err / cal.standard_error_bound_rad
    out: dict[str, Any] = {"level": level, "lookup": {
        "beyond_2sigma": np.sum(np.abs(z_l) > 2, axis=0).tolist(), "max_abs_z": float(np.abs(z_l).max()),
        "simultaneous_z": c_l, "every_within_2sigma": bool(np.all(np.abs(z_l) <= 2)),
        "within_simultaneous": bool(np.all(np.abs(z_l) <= c_l)),
        "p_every_within_2sigma_if_exact": st["lookup"]["p_every_value_within_2sigma"],
        "repeat_share": cal.repeat_share.share.tolist(), "repeat_share_se": cal.repeat_share.share_se.tolist(),
        "repeat_share_order": cal.repeat_share.order, "sigma_dof_median": st["lookup"]["sigma_dof_median"],
        "z": z_l.tolist(), "z_whitened": w_l.tolist(), "z_bound": z_b.tolist(),
        "within_simultaneous_bound": bool(np.all(np.abs(z_b) <= c_l))}}
    if "fourier" in st:
        f = cal.fourier_curve()
        z_f = (f(cal.beta_rad) - truth) / f.sigma_rad(cal.beta_rad)
        c_f = st["fourier"]["simultaneous_z"]
        # the true curve's terms at the same order (the positions are samples of the true curve, a 3-harmonic
        # series: exact for order >= 3)
        a = fourier_design(cal.beta_rad, f.order)
        t_coef = np.linalg.lstsq(a, truth, rcond=None)[0]
        z_c = (f.coefficients_rad - t_coef) / np.sqrt(np.diagonal(f.covariance_rad2, axis1=1, axis2=2)).T
        w_c = np.stack([np.linalg.solve(np.linalg.cholesky(f.covariance_rad2[i]), f.coefficients_rad[:, i]
                                        - t_coef[:, i]) for i in range(3)], axis=1)  # per axis N(0, I)
        out["fourier"] = {"order": f.order, "variance_factor": f.variance_factor.tolist(),
                          "beyond_2sigma": np.sum(np.abs(z_f) > 2, axis=0).tolist(),
                          "max_abs_z": np.abs(z_f).max(axis=0).tolist(), "simultaneous_z": c_f,
                          "every_within_2sigma": bool(np.all(np.abs(z_f) <= 2)),
                          "within_simultaneous": bool(np.all(np.abs(z_f) <= c_f)),
                          "p_every_within_2sigma": st["fourier"]["p_every_value_within_2sigma"],
                          "terms_z": z_c.tolist(), "terms_z_whitened": w_c.tolist(),
                          "value_sigma_median_mdeg": (1000 * np.degrees(np.median(f.sigma_rad(cal.beta_rad), axis=0))
                                                      ).tolist(),
                          "err_rms_mdeg": (1000 * np.degrees(np.sqrt(np.mean((f(cal.beta_rad) - truth) ** 2, axis=0)))
                                           ).tolist()}
    return out


def run_seed(positions: int, circles: int, width: int, window_px: int, seed: int,
             cache: Path | None = None) -> tuple[Lab, Any, float, float]:
    """Build the lab of ``seed``, render and calibrate it (or load the measurements from ``cache``/seedS_KxC_W.npz,
    written on the first run); the calibration, render and calibration seconds."""
    from skyrig.calibrate.tumbling import FailedImage, TumblingCalibration, calibrate_tumbling_head
    from skyrig.rig.boresight_curve import BoresightCurve

    t0 = time.perf_counter()
    lab = build_lab(positions, circles, width, seed=seed)
    f = None if cache is None else cache / f"seed{seed}_{positions}x{circles}_{width}_w{window_px}.npz"
    if f is not None and f.is_file():
        d = np.load(f)
        if not np.array_equal(d["true_rad"], lab.true_rad):
            raise SystemExit(f"{f}: cached for another lab (true corrections differ); remove it")
        k = lab.beta_rad.size
        ok = np.all(np.isfinite(d["corr"]), axis=-1).reshape(-1)  # images measured (not left out)
        failed = ()
        if "failed_name" in d.files:
            failed = tuple(FailedImage(str(n), str(c), float(b), str(r)) for n, c, b, r in
                           zip(*(d[x] for x in ("failed_name", "failed_circle", "failed_beta", "failed_reason"))))
        cal = TumblingCalibration(lab.beta_rad, np.array([f"{c + 1}" for c in range(circles)]), d["corr"], d["sig"],
                                  np.asarray(lab.names).reshape(circles, k), d["win"],
                                  BoresightCurve.from_samples(np.tile(lab.beta_rad, circles)[ok],
                                                              d["corr"].reshape(-1, 3)[ok]), lab.setup,
                                  d["cov"] if "cov" in d.files else None, failed)
        return lab, cal, 0.0, 0.0
    imgs, ref = render_lab(lab)
    t1 = time.perf_counter()
    cal = calibrate_tumbling_head(lab.setup, imgs.__getitem__, lab.names, lab.circles, lab.betas, ref,
                                  window_px=window_px)
    t2 = time.perf_counter()
    if f is not None:
        f.parent.mkdir(parents=True, exist_ok=True)
        tmp = f.with_suffix(".tmp.npz")
        np.savez(tmp, true_rad=lab.true_rad, corr=cal.corrections_rad, sig=cal.sigma_rad, win=cal.windows,
                 cov=cal.fit_covariance_rad2, failed_name=np.array([f.name for f in cal.failed], dtype=str),
                 failed_circle=np.array([f.circle for f in cal.failed], dtype=str),
                 failed_beta=np.array([f.beta_rad for f in cal.failed], dtype=np.float64),
                 failed_reason=np.array([f.reason for f in cal.failed], dtype=str))
        tmp.replace(f)
    return lab, cal, t1 - t0, t2 - t1


def _seeds(text: str) -> list[int]:
    out: list[int] = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out += list(range(int(a), int(b) + 1)) if b else [int(a)]
    return out


def z_stats(z: Any) -> dict[str, Any]:
    """Count, mean, std, RMS and the Kolmogorov-Smirnov p-value against N(0, 1) of normalised errors."""
    from scipy.stats import kstest

    z = np.asarray(z, dtype=np.float64).ravel()
    return {"n": int(z.size), "mean": float(z.mean()), "std": float(z.std()), "rms": float(np.sqrt(np.mean(z ** 2))),
            "ks_p": float(kstest(z, "norm").pvalue)}


def z_table(zs: list[Any]) -> dict[str, Any]:
    """:func:`z_stats` pooled over the labs' ``(n, 3)`` normalised errors, per axis and all axes."""
    from skyrig.rig.boresight_curve import AXES

    z = np.concatenate([np.asarray(a, dtype=np.float64).reshape(-1, 3) for a in zs])
    return {"pooled": z_stats(z), **{a: z_stats(z[:, i]) for i, a in enumerate(AXES)}}


def summary(results: list[dict[str, Any]]) -> dict[str, Any]:
    """Over the seeds: how often every position is within 2 sigma and within the simultaneous band, per statement;
    the normalised errors of the lookup values and the series' terms (per axis and pooled; plain, whitened with the
    stated covariance, and for the lookup against the old upper bound) with their KS p-values; Tab. 2's
    repeatability and the image-point error."""
    from scipy.stats import kstest

    from skyrig.rig.boresight_curve import AXES

    n = len(results)
    out: dict[str, Any] = {"seeds": [r["seed"] for r in results]}
    for m in ("lookup", "fourier"):
        rs = [r["curve_statement"][m] for r in results if m in r["curve_statement"]]
        if not rs:
            continue
        out[m] = {"every_within_2sigma": f"{sum(r['every_within_2sigma'] for r in rs)}/{n}",
                  "within_simultaneous": f"{sum(r['within_simultaneous'] for r in rs)}/{n}",
                  "beyond_2sigma_per_seed": [r["beyond_2sigma"] for r in rs],
                  "max_abs_z_per_seed": [r["max_abs_z"] for r in rs],
                  "simultaneous_z": [r["simultaneous_z"] for r in rs]}
        if m == "lookup":
            out[m] |= {"within_simultaneous_bound": f"{sum(r['within_simultaneous_bound'] for r in rs)}/{n}",
                       "z": z_table([r["z"] for r in rs]), "z_whitened": z_table([r["z_whitened"] for r in rs]),
                       "z_bound": z_table([r["z_bound"] for r in rs]),
                       "repeat_share_per_seed": [r["repeat_share"] for r in rs],
                       "repeat_share_mean": np.mean([r["repeat_share"] for r in rs], axis=0).tolist(),
                       "repeat_share_sd": np.std([r["repeat_share"] for r in rs], axis=0).tolist(),
                       "repeat_share_se_mean": np.nanmean([r["repeat_share_se"] for r in rs], axis=0).tolist()}
        if m == "fourier":
            out[m] |= {"terms_z_table": z_table([r["terms_z"] for r in rs]),
                       "terms_z_whitened": z_table([r["terms_z_whitened"] for r in rs])}
            z = np.concatenate([np.ravel(r["terms_z"]) for r in rs])
            out[m] |= {"orders": [r["order"] for r in rs], "terms_z_rms": float(np.sqrt(np.mean(z ** 2))),
                       "terms_z_mean": float(np.mean(z)), "terms": int(z.size),
                       "terms_z_ks_pvalue": float(kstest(z, "norm").pvalue),
                       "p_every_within_2sigma_model": [r["p_every_within_2sigma"] for r in rs]}
        else:
            out[m]["p_every_within_2sigma_if_exact"] = rs[0]["p_every_within_2sigma_if_exact"]
    out["table2"] = {a: {"mean_std_2sigma_over_injected_2sigma": [
                             r["table2_2sigma"][a]["mean_std_mdeg"] / (2 * r[a]["injected_repeat_mdeg"])
                             for r in results],
                         "mechanism_over_injected": [r[a]["mechanism_over_injected"] for r in results]}
                     for a in AXES}
    out["repeat_share_realised_mean"] = [float(np.mean([r[a]["repeat_share_realised"] for r in results])) for a in AXES]
    out["repeat_share_estimated_mean"] = [float(np.mean([r[a]["repeat_share_estimated"] for r in results]))
                                          for a in AXES]
    out["images_left_out_per_lab"] = [len(r["images_left_out"]) for r in results]
    out["images_left_out_reasons"] = _reason_counts([f["reason"] for r in results for f in r["images_left_out"]])
    out["circles_per_position_min_per_lab"] = [r["circles_per_position_min"] for r in results]
    out["image_points_written_rig_max_px"] = [r["image_points_written_rig"]["max_px"] for r in results]
    out["image_points_written_rig_rms_px"] = [r["image_points_written_rig"]["rms_px"] for r in results]
    return out


def _reason_counts(reasons: list[str]) -> dict[str, int]:
    """How often each kind of failure occurred (by the message's wording)."""
    kinds = {"gain": "does not follow a known rotation", "convergence": "did not converge",
             "windows": "correlation windows agree", "texture": "textured windows"}
    out = {k: sum(v in r for r in reasons) for k, v in kinds.items()}
    out["other"] = len(reasons) - sum(out.values())
    return out


def main(argv: list[str] | None = None) -> int:
    from skyrig.errors import SkyrigError

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--positions", type=int, default=72)
    ap.add_argument("--circles", type=int, default=5)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--window-px", type=int, default=32)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--seeds", default=None, help="several labs, e.g. 1-12 or 1,3,5: each judged, then a summary")
    ap.add_argument("--cache", type=Path, default=None,
                    help="keep each lab's measurements here (seedS_KxC_W_wP.npz) and reuse them on the next run")
    ap.add_argument("--out", type=Path, default=None, help="write the figures (JSON) here")
    ap.add_argument("--draw-check", type=int, default=0, metavar="N",
                    help="only check the simulated repeat errors over labs 1..N (no images) and exit")
    a = ap.parse_args(argv)
    if a.draw_check:
        print(json.dumps(draw_check(a.positions, a.circles, a.draw_check), indent=1))
        return 0
    seeds = _seeds(a.seeds) if a.seeds else [a.seed]
    results = []
    failed = []
    for seed in seeds:
        try:
            lab, cal, t_render, t_cal = run_seed(a.positions, a.circles, a.width, a.window_px, seed, a.cache)
        except SkyrigError as exc:  # a recipe failure is a result too: counted, named, and the run exits 1
            print(f"seed {seed}: FAILED: {exc}", flush=True)
            failed.append({"seed": seed, "error": str(exc)})
            continue
        res = judge(lab, cal)
        res["seed"] = seed
        res["render_s"], res["calibrate_s"] = t_render, t_cal
        res["table2_2sigma"] = cal.table2(2.0)
        results.append(res)
        if len(seeds) == 1:
            print(json.dumps(res, indent=1))
        else:
            st = res["curve_statement"]
            mech = [round(res[x]["mechanism_over_injected"], 3) for x in ("droll", "dpitch", "dyaw")]
            print(f"seed {seed}: lookup beyond 2 sigma {st['lookup']['beyond_2sigma']} max |z| "
                  f"{st['lookup']['max_abs_z']:.2f} (simultaneous {st['lookup']['simultaneous_z']:.2f}); fourier "
                  f"order {st['fourier']['order']} beyond {st['fourier']['beyond_2sigma']} max |z| "
                  f"{max(st['fourier']['max_abs_z']):.2f} (simultaneous {st['fourier']['simultaneous_z']:.2f}); "
                  f"repeat share {[round(x, 2) for x in st['lookup']['repeat_share']]}; mechanism/injected {mech}"
                  f"; image points (written rig file) max {res['image_points_written_rig']['max_px']:.3f} px"
                  f"; images left out {len(cal.failed)} ({', '.join(f.name for f in cal.failed)})", flush=True)
    out: dict[str, Any] = {"args": vars(a) | {"out": str(a.out), "cache": str(a.cache)}, "failed": failed}
    if len(seeds) == 1 and results:
        out |= results[0]
    elif results:
        out["summary"] = summary(results)
        out["per_seed"] = results
        print(json.dumps(out["summary"], indent=1))
    if a.out is not None:
        tmp = a.out.with_suffix(a.out.suffix + ".tmp")
        tmp.write_text(json.dumps(out, indent=1))
        tmp.replace(a.out)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
