"""Paper 003 (Redweik & Jacobsen, uncalibrated GNSS/IMU data): the recipe's tables next to the paper's, the
mapping-scale check and an orientation export for a stereo plotter.

The simulated Southeast flight (:func:`skyrig.calibrate.gnss_imu.paper003_scenario`: 4 north-south strips with
Tab. 4's boresight misalignment and datum shift injected, a -0.75 m antenna offset, 0.6 m control in PT-TM06 with
geoid heights) goes through the recipe of ``skyrig calibrate uncalibrated-gnss-imu``
(:func:`skyrig.calibrate.gnss_imu.calibrate_uncalibrated_gnss_imu`).  ``ci`` flies the recipe's ``reduced`` block
(4 strips x 14 km, seconds), ``full`` the 4 x 55 km block.

Mapping-scale check, with the paper's own rule (section 6): a map at scale 1 : m needs ``0.1 mm x m`` in
planimetry and one third of the contour interval in height (1 : 25000: 2.5 m and 10 m / 3 = 3.3 m); the
accuracy delivered is the check-point RMS of the orientation (Tab. 5: spatial intersection with the corrected
GNSS/IMU, and integrated sensor orientation).  The largest map scale the orientation supports is
``1 : hypot(SX, SY) / 0.1 mm`` (the paper: 1 : 9600 for orthophotos from its Tab. 5).  For stereo plotting the
paper asks for y-parallaxes below 20 um RMS per model (Tab. 8).

Export: the integrated-sensor-orientation and the corrected direct orientations in the national frame (the
control's projection, orthometric heights: what the paper's operators map in) as IGN OPK text (image, X, Y, Z,
omega, phi, kappa in degrees about the grid axes, camera; :func:`skyrig.io.ign.write_ign_opk`), the
omega-phi-kappa list a digital stereo plotter imports, with the camera as a MicMac calibration file.  No plotter was
run here: the file is read back with skyrig's reader and checked against what was written.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from skyrig.papers.base import Comparison, PaperResult, PaperTable, Size

__all__ = ["MAP_SCALE", "CONTOUR_INTERVAL_M", "map_scale_requirements", "largest_map_scale", "run"]

MAP_SCALE = 25000  # the project's mapping scale (paper 003, section 3)
CONTOUR_INTERVAL_M = 10.0  # the 1:25000 map's contour interval (section 6: "1/3 of contour interval = 10 m/3")
GON = np.pi / 200.0

#: paper 003's printed values
PAPER_TAB4 = {"pitch_gon": -0.00952, "roll_gon": -0.08722, "yaw_gon": -0.02018, "X_m": 7.248, "Y_m": 1.714, "Z_m": 0.984}
PAPER_TAB4_RMS = {"pitch_gon": 0.0042, "roll_gon": 0.0058, "yaw_gon": 0.0042, "X_m": 0.169, "Y_m": 0.221, "Z_m": 0.082}
PAPER_TAB5 = {"spatial_intersection": {"ground_points": (0.645, 0.721, 0.839), "combined_adjustment_points": (0.438, 0.279, 0.441)},
              "integrated_sensor_orientation": {"ground_points": (0.640, 0.754, 0.785),
                                                "combined_adjustment_points": (0.419, 0.262, 0.398)}}
PAPER_TAB6 = {"corrected_gnss_imu-combined": (0.0077, 0.0049, 0.0058), "iso-combined": (0.0084, 0.0058, 0.0025),
              "iso-corrected_gnss_imu": (0.0057, 0.0057, 0.0045)}
PAPER_TAB8 = {"tangential/corrected_gnss_imu": (7, 0), "tangential/integrated_sensor_orientation": (0, 0),
              "national/corrected_gnss_imu": (48, 0), "national/integrated_sensor_orientation": (37, 0)}
PAPER_ORTHO_SCALE = 9600  # section 6: orthophotos up to 1 : 9600 from the worst of Tab. 5


def map_scale_requirements(scale: float, contour_interval_m: float) -> tuple[float, float]:
    """(planimetric, height) accuracy a map at 1 : ``scale`` needs (paper 003, section 6): 0.1 mm at map scale
    and a third of the contour interval; metres."""
    return 1e-4 * scale, contour_interval_m / 3.0


def largest_map_scale(sx_m: float, sy_m: float) -> float:
    """The scale number m of the largest map (1 : m) whose 0.1 mm the planimetric RMS ``hypot(sx, sy)`` meets."""
    return float(np.hypot(sx_m, sy_m) / 1e-4)


def _r(v: Any, nd: int = 4) -> Any:
    return None if v is None else round(float(v), nd)


def _export(out_dir: Path, cal: Any) -> list[tuple[str, bool, str]]:
    """OPK files of the ISO and the corrected direct orientations in the national frame, the camera as IGN camera
    text; each read back and compared with what was written."""
    from skyrig.io.exchange import write_camera_file
    from skyrig.io.ign import read_ign_opk, write_ign_opk

    checks = []
    cams = {h.camera.name: h.camera for h in cal.rig.heads.values()}
    write_camera_file(out_dir / "camera_micmac.xml", "micmac-calibration", cams)
    for key, eo in (("iso", cal.eo_iso), ("corrected_gnss_imu", cal.eo_corrected)):
        nat = eo.to_frame(cal.national)
        path = out_dir / f"orientation_{key}_national.opk"
        write_ign_opk(path, nat)
        back = read_ign_opk(path, cal.national)
        dc = float(np.abs(back.centre - nat.centre).max())
        da = float(np.degrees(np.max(np.abs(back.rotation - nat.rotation))))
        checks.append((f"{path.name} reads back (centres within 1 mm, rotations within 1e-8)",
                       bool(len(back) == len(nat) and dc <= 1e-3 and da <= 1e-6),
                       f"{len(back)} images; max |dX| {1000 * dc:.2f} mm, max |dR| {da:.1e}"))
    return checks


def run(out_dir: Path, size: Size) -> PaperResult:
    from skyrig.calibrate.gnss_imu import calibrate_uncalibrated_gnss_imu, flight_data_from_survey, paper003_scenario
    from skyrig.simulate.scenarios import build_survey

    out_dir = Path(out_dir)
    res = PaperResult("003", "Uncalibrated GNSS/IMU data: the recipe's tables, the mapping-scale check, a plotter export",
                      size)
    survey = build_survey(paper003_scenario("reduced" if size == "ci" else "full", seed=1))
    cal = calibrate_uncalibrated_gnss_imu(flight_data_from_survey(survey))
    t = cal.tables
    err = survey.spec.errors
    gsd = cal.gsd_m
    scen = (f"simulated Southeast block ({'reduced' if size == 'ci' else 'full'}: {cal.n_images} images, GSD "
            f"{gsd:.2f} m; the paper's 14 um scan of the 1:22700 photos is 0.32 m)")

    # Tab. 2
    rows2 = []
    for k, r in enumerate(t["table2_strip_shifts"]["rows"]):
        p = [(-6.315, -2.728, -1.364), (-6.476, -0.998, -0.382)][k] if k < 2 else (None,) * 3
        rows2.append((f"strip {r['strip']} (paper: STRIP {k + 1})", *(_r(v, 3) for v in r["shift_m"]),
                      *(_r(v, 3) for v in r["scatter_m"]), *p))
    res.tables.append(PaperTable(
        "table2_strip_shifts", "Tab. 2: shift of the projection centres per reference strip (GNSS minus adjusted)",
        ("strip", "X (m)", "Y (m)", "Z (m)", "SX (m)", "SY (m)", "SZ (m)", "paper X (m)", "paper Y (m)", "paper Z (m)"),
        tuple(rows2), caption=f"{scen}.  The shifts hold the datum shift and the antenna offset of the simulation, "
                              "not the paper's flight; the difference between the strips is the offset's signature."))
    # Tab. 4
    t4 = t["table4_misalignment"]
    truth4 = {"roll_gon": err.boresight_rpy_rad["camera"][0] / GON, "pitch_gon": err.boresight_rpy_rad["camera"][1] / GON,
              "yaw_gon": err.boresight_rpy_rad["camera"][2] / GON, "X_m": err.datum_shift_m[0], "Y_m": err.datum_shift_m[1],
              "Z_m": err.datum_shift_m[2]}
    rows4 = []
    for q in ("pitch_gon", "roll_gon", "yaw_gon", "X_m", "Y_m", "Z_m"):
        est, sig = t4["misalignment"][q], t4["sigma"][q]
        rows4.append((q, _r(est, 5), _r(sig, 5), _r(truth4[q], 5), PAPER_TAB4[q], _r(t4["rms_after_bias"][q], 4),
                      PAPER_TAB4_RMS[q]))
        ok = abs(est - truth4[q]) <= 3.0 * sig
        res.comparisons.append(Comparison(f"Tab. 4 misalignment {q.replace('_', ' (')})", _r(est, 5), PAPER_TAB4[q],
                                          q.split("_")[1], "the simulation injects the paper's Tab. 4 values: agreement "
                                          f"within 3 sigma ({3 * sig:.5f}) of skyrig's estimate", bool(ok), "Tab. 4"))
    res.tables.append(PaperTable(
        "table4_misalignment", "Tab. 4: boresight misalignment and datum shift (IMU vs reference orientation)",
        ("quantity", "skyrig", "skyrig sigma", "injected (simulation)", "paper", "skyrig RMS after bias", "paper RMS after bias"),
        tuple(rows4), caption=f"{scen}; grads and metres."))
    # Tab. 5 and the mapping-scale check
    t5 = t["table5_check_points"]
    rows5 = []
    for label in ("spatial_intersection", "integrated_sensor_orientation"):
        for pts in ("ground_points", "combined_adjustment_points"):
            v = t5[label][pts]
            rows5.append((label.replace("_", " "), pts.replace("_", " "), v["n"], *(_r(x, 3) for x in v["rms_m"]),
                          *PAPER_TAB5[label][pts]))
    res.tables.append(PaperTable(
        "table5_check_points", "Tab. 5: RMS differences at the check points",
        ("orientation", "points", "n", "SX (m)", "SY (m)", "SZ (m)", "paper SX (m)", "paper SY (m)", "paper SZ (m)"),
        tuple(rows5), caption=f"{scen}.  Ground points: the simulated control (sigma 0.6 m, PT-TM06, geoid heights)."))
    need_xy, need_z = map_scale_requirements(MAP_SCALE, CONTOUR_INTERVAL_M)
    rows_m = []
    for label in ("spatial_intersection", "integrated_sensor_orientation"):
        sx, sy, sz = t5[label]["ground_points"]["rms_m"]
        psx, psy, psz = PAPER_TAB5[label]["ground_points"]
        ok = max(sx, sy) <= need_xy and sz <= need_z
        m = largest_map_scale(sx, sy)
        rows_m.append((label.replace("_", " "), _r(max(sx, sy), 3), need_xy, _r(sz, 3), _r(need_z, 3),
                       "yes" if ok else "no", f"1 : {m:.0f}", f"1 : {largest_map_scale(psx, psy):.0f}"))
        res.checks.append((f"1 : {MAP_SCALE} mapping with the {label.replace('_', ' ')} (0.1 mm = {need_xy:.1f} m, "
                           f"contour interval / 3 = {need_z:.1f} m)", bool(ok),
                           f"SX {sx:.2f} SY {sy:.2f} SZ {sz:.2f} m at {t5[label]['ground_points']['n']} check points"))
    m_iso = largest_map_scale(*t5["integrated_sensor_orientation"]["ground_points"]["rms_m"][:2])
    m_si = largest_map_scale(*t5["spatial_intersection"]["ground_points"]["rms_m"][:2])
    res.tables.append(PaperTable(
        "mapping_scale", f"Sec. 6: the accuracy a 1 : {MAP_SCALE} map needs against what the orientation delivers",
        ("orientation", "worse of SX, SY (m)", "planimetry needed (m)", "SZ (m)", "height needed (m)",
         f"1 : {MAP_SCALE} met", "largest map scale (skyrig)", "largest map scale (paper's Tab. 5)"),
        tuple(rows_m), caption="The paper's rule: 0.1 mm at map scale in planimetry, a third of the contour interval "
                               f"({CONTOUR_INTERVAL_M:g} m) in height; largest scale 1 : hypot(SX, SY) / 0.1 mm."))
    res.comparisons.append(Comparison(
        "largest orthophoto scale from the corrected GNSS/IMU (worst of Tab. 5)", f"1 : {max(m_si, m_iso):.0f}",
        f"1 : {PAPER_ORTHO_SCALE}", "", f"the simulated camera's GSD is {gsd:.2f} m against the paper's 0.32 m, so the "
        "check points are coarser in proportion", None, "Sec. 6"))
    # Tab. 6
    t6 = t["table6_attitudes"]
    rows6 = tuple((k, *(_r(t6[k][c], 4) for c in ("S_phi_gon", "S_omega_gon", "S_kappa_gon")), *PAPER_TAB6[k])
                  for k in PAPER_TAB6)
    res.tables.append(PaperTable(
        "table6_attitudes", "Tab. 6: RMS of the attitude differences (grads)",
        ("pair", "S phi", "S omega", "S kappa", "paper S phi", "paper S omega", "paper S kappa"), rows6,
        caption=f"{scen}; {t6['images']} images."))
    # Tab. 8 and the stereo-plotting check
    t8 = t["table8_y_parallax"]
    rows8 = tuple((k, t8[k]["models"], t8[k]["over_10um"], t8[k]["over_20um"], _r(t8[k]["max_rms_um"], 2), *PAPER_TAB8[k])
                  for k in PAPER_TAB8)
    res.tables.append(PaperTable(
        "table8_y_parallax", "Tab. 8: stereo models with RMS y-parallax above 10 um and 20 um",
        ("frame / orientation", "models", "> 10 um", "> 20 um", "max RMS (um)", "paper > 10 um", "paper > 20 um"), rows8,
        caption=f"{scen}.  The paper had 95 models."))
    iso = [k for k in t8 if k.endswith("integrated_sensor_orientation")]
    worst = max(t8[k]["over_20um"] for k in iso)
    res.checks.append(("stereo plotting with the exported (ISO) orientation: no model above 20 um RMS y-parallax "
                       "(Tab. 8)", bool(worst == 0), f"{worst} models above 20 um; largest RMS "
                       f"{max((t8[k]['max_rms_um'] or 0.0) for k in iso):.1f} um (tangential and national frame)"))
    direct = t8["national/corrected_gnss_imu"]
    res.comparisons.append(Comparison(
        "models above 20 um y-parallax with the corrected GNSS/IMU (national frame)", direct["over_20um"], 0, "models",
        "the simulation draws the IMU attitude noise independently per exposure at the POS/AV 410 figures (the "
        "paper's Tab. 4 RMS after bias), which turns into y-parallax model by model; the paper does not say how "
        "its flight's IMU errors varied from photo to photo.  The integrated sensor orientation removes them (0 models).",
        direct["over_20um"] == 0, "Tab. 8"))
    res.checks += _export(out_dir, cal)
    res.notes.append(f"Stereo-plotter export: orientation_iso_national.opk and orientation_corrected_gnss_imu_national.opk "
                     f"(IGN OPK text: image X Y Z omega phi kappa [deg] camera) in {cal.national.describe()}, "
                     "and camera_micmac.xml (the interior orientation as a MicMac calibration file, which IGN tools read with OPK).")
    return res
