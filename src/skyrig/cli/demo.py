"""``skyrig demo``: run the whole existing chain on built-in demo data."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import click
import numpy as np


def _run(args: list[str]) -> None:
    from skyrig.cli import main

    click.echo(f"\n$ skyrig {' '.join(args)}")
    main.main(args=args, prog_name="skyrig", standalone_mode=False)


@click.command("demo")
@click.argument("outdir", required=False, default=None, metavar="", type=click.Path(file_okay=False))
@click.option("-o", "--output", type=click.Path(file_okay=False), default=None,
              help="Folder for the demo flight and its outputs [default: demo-output] (the positional OUTDIR of "
                   "older versions is deprecated).")
def command(outdir: str | None, output: str | None) -> None:
    """Simulate a small MIDAS penta-rig flight, georeference it and check ground <-> image end to end."""
    from skyrig.cli._common import output_or_positional

    outdir = output_or_positional(output, outdir, "OUTDIR", default="demo-output")
    from skyrig.georef.eo import WorldFrame
    from skyrig.io.eo_csv import read_eo_csv
    from skyrig.io.events_csv import read_events_csv
    from skyrig.io.points_csv import read_measurements_csv, read_points_csv
    from skyrig.io.rig_file import read_rig
    from skyrig.io.trajectory_csv import read_trajectory_csv
    from skyrig.pipeline.demo import CRS, build_demo_project, independent_eo, rotation_angle_deg

    t0 = time.perf_counter()
    p = build_demo_project(outdir)
    click.echo(f"demo project written to {Path(outdir).resolve()}/input (trajectory, events, rig, check points)")
    _run(["georef", "--trajectory", str(p.trajectory), "--events", str(p.events), "--rig", str(p.rig),
          "--crs", CRS, "--convention", "opk", "-o", str(p.eo)])
    _run(["world-to-image", "--eo", str(p.eo), "--camera", str(p.rig), "--points", str(p.check_points),
          "-o", str(p.image_points)])
    _run(["image-to-world", "--eo", str(p.eo), "--camera", str(p.rig), "--measurements", str(p.image_points),
          "--intersect", "-o", str(p.intersected)])

    # --- checks against independent answers ------------------------------------------------------------
    eo = read_eo_csv(p.eo)
    rig = read_rig(p.rig)
    events = read_events_csv(p.events)
    traj = read_trajectory_csv(p.trajectory)
    centres, rots = independent_eo(traj, events, rig)
    order = eo.index()
    rows = np.array([order[n] for n in events.image_name])
    dc = np.abs(eo.centre[rows] - centres).max()
    da = rotation_angle_deg(eo.rotation[rows], rots).max()
    truth = read_points_csv(p.check_points)
    inter = read_points_csv(p.intersected, WorldFrame.map(CRS))
    m = read_measurements_csv(p.image_points)
    ti = truth.index()
    sel = [i for i, n in enumerate(inter.name) if np.all(np.isfinite(inter.xyz[i]))]
    d = np.array([inter.xyz[i] - truth.xyz[ti[inter.name[i]]] for i in sel])
    click.echo("\n=== demo summary ===")
    click.echo(f"images georeferenced: {len(eo)} ({len(set(eo.head))} heads, {len(set(eo.exposure))} exposures)")
    for head in rig.heads:
        sel_h = eo.head == head
        cam = rig.heads[head].camera
        gsd = cam.gsd_at(eo.subset(sel_h).to_frame(WorldFrame.local(52.34, 9.73, 60.0)).pose(), ground_height=0.0)
        click.echo(f"  {head:9s} {int(sel_h.sum()):3d} images, {cam.focal_mm:g} mm, GSD at image centre "
                   f"{np.mean(gsd.mean_m) * 100:.1f} cm")
    click.echo(f"georef vs independent composition: max centre difference {dc * 1000:.3f} mm, "
               f"max attitude difference {da * 3600:.4f} arcsec")
    click.echo(f"check points seen: {len(sel)} of {len(truth)}, {len(m)} image positions")
    click.echo(f"world->image->world closure: max |d| {np.abs(d).max() * 1000:.4f} mm")
    ok = dc < 0.005 and da < 1.0 / 3600 * 5 and np.abs(d).max() < 0.001 and len(sel) > 10
    if not ok:
        raise click.ClickException("demo checks FAILED (built-in flight)")

    # --- bundle adjustment of the demo flight (integrated sensor orientation) ---------------------------
    from skyrig.cli.adjust import adjust_demo_project

    click.echo("\n=== bundle adjustment of the built-in flight (GNSS/IMU + control, check points) ===")
    adj = adjust_demo_project(p, Path(outdir) / "output" / "adjust")
    import json

    rep = json.loads(Path(adj["json"]).read_text())
    sm, chk = rep["summary"], rep["check"]["stats"]
    click.echo(f"sigma0 {sm['sigma0']:.3f}, {sm['images']} images, {sm['points']} points, {sm['iterations']} iterations, "
               f"{sm['wall_s']:.1f} s; check points (n={chk['n']}) RMS X/Y/Z "
               + "/".join(f"{v * 100:.1f}" for v in chk["rms_m"]) + " cm = "
               + "/".join(f"{v:.2f}" for v in chk["rms_gsd"]) + f" GSD; report {adj['html']}")
    if not (0.7 < sm["sigma0"] < 1.3 and max(chk["rms_gsd"]) < 2.0):
        raise click.ClickException("demo checks FAILED (adjustment)")

    # --- simulated penta-rig flight with rendered images (skyrig.simulate) -----------------------------
    from skyrig.pipeline.simulate import simulate_demo_project

    click.echo("\n=== simulated MIDAS flight: render images, write project, georeference, compare with truth ===")
    sim = simulate_demo_project(Path(outdir) / "simulated")
    click.echo(f"{sim['images']} rendered images in {sim['outdir']} ({sim['seconds']:.1f} s); georef vs truth: "
               f"max centre error {sim['max_centre_error_m'] * 1000:.3f} mm, max rotation-matrix error "
               f"{sim['max_rotation_error']:.1e}")
    if sim["max_centre_error_m"] > 1e-3 or sim["max_rotation_error"] > 1e-9:
        raise click.ClickException("demo checks FAILED (simulated flight)")

    # --- tie points on the rendered images, checked against the true orientations ----------------------
    from skyrig.cli._common import load_cameras
    from skyrig.georef.ground import forward_intersection

    sim_dir = Path(sim["outdir"])
    click.echo("\n=== tie points on the rendered images (SIFT, guided pairs), judged with the true orientations ===")
    # guided by the orientations a user has: direct georeferencing of the recorded (noisy) GNSS/IMU with the
    # nominal rig (its boresights are off by 0.01-0.03 deg)
    eo_dg = sim_dir / "output" / "eo_dg.csv"
    _run(["georef", "--trajectory", str(sim_dir / "trajectory.csv"), "--events", str(sim_dir / "events.csv"),
          "--rig", str(sim_dir / "rig.yaml"), "--crs", "EPSG:25832", "-o", str(eo_dg)])
    _run(["match", str(sim_dir), "--eo", str(eo_dg), "--camera", str(sim_dir / "rig.yaml"),
          "--terrain-height", "0", "-o", str(sim_dir / "match")])
    ties = read_measurements_csv(sim_dir / "match" / "tie_points.csv")
    truth_eo = read_eo_csv(sim_dir / "truth" / "eo.csv")
    res = forward_intersection(truth_eo, load_cameras([str(sim_dir / "rig.yaml")]), ties.point, ties.image, ties.pixel,
                               truth_eo.frame)
    rad = np.hypot(res.residual_px[:, 0], res.residual_px[:, 1])
    rad = rad[np.isfinite(rad)]
    p50, p90 = np.percentile(rad, [50, 90])
    blunders = float(np.mean(rad > 3.0))
    click.echo(f"{len(res.point)} tie points, {len(ties)} observations; image residuals with the true orientations: "
               f"median {p50:.3f} px, 90% {p90:.3f} px, {blunders * 100:.1f}% above 3 px (mismatches left for the "
               "adjustment's data snooping)")
    if p50 > 0.3 or blunders > 0.1:
        raise click.ClickException("demo checks FAILED (tie points)")

    # --- integrated sensor orientation of the simulated flight: the whole chain from images ---------------
    click.echo("\n=== integrated sensor orientation of the simulated flight: rig block (recorded GNSS/IMU, matched "
               "ties, GCPs), boresights free, judged against the truth ===")
    blk = sim_dir / "output" / "block" / "block.json"
    _run(["block", "--trajectory", str(sim_dir / "trajectory.csv"), "--events", str(sim_dir / "events.csv"),
          "--rig", str(sim_dir / "rig.yaml"), "--measurements", str(sim_dir / "match" / "tie_points.csv"),
          "--measurements", str(sim_dir / "gcp" / "image_measurements.csv"),
          "--control", str(sim_dir / "gcp" / "ground_points.csv"), "--check", str(sim_dir / "gcp" / "check_points.csv"),
          "--image-sigma-px", "0.3", "--gnss-sigma", "0.03,0.03,0.05", "--imu-sigma-deg", "0.003,0.003,0.006",
          "--control-sigma", "0.01", "--free", "boresight", "-o", str(blk)])
    adj_dir = sim_dir / "output" / "adjust"
    _run(["adjust", str(blk), "-o", str(adj_dir)])
    from skyrig.geometry.rotations import rotvec_from_matrix

    adj_eo = read_eo_csv(adj_dir / "eo.csv")
    truth_m = read_eo_csv(sim_dir / "truth" / "eo_map.csv").to_frame(adj_eo.frame)
    dg = read_eo_csv(eo_dg).to_frame(adj_eo.frame)

    def errors(e):  # type: ignore[no-untyped-def]
        rows = np.array([truth_m.index()[n] for n in e.image])
        dc = np.sqrt(np.mean(np.sum((e.centre - truth_m.centre[rows]) ** 2, axis=1)))
        da = np.degrees(np.linalg.norm(rotvec_from_matrix(np.swapaxes(truth_m.rotation[rows], -1, -2) @ e.rotation),
                                       axis=1))
        return float(dc), float(np.sqrt(np.mean(da ** 2)))

    dg_sel = dg.subset(np.array([dg.index()[n] for n in adj_eo.image]))
    (c0, a0), (c1, a1) = errors(dg_sel), errors(adj_eo)
    rep = json.loads((adj_dir / "report.json").read_text())
    chk = rep.get("check", {}).get("stats", {})
    click.echo(f"sigma0 {rep['summary']['sigma0']:.3f}; image orientations vs truth (RMS): direct georeferencing "
               f"{c0 * 100:.1f} cm / {a0:.4f} deg -> adjusted {c1 * 100:.1f} cm / {a1:.4f} deg"
               + (f"; check points (n={chk['n']}) RMS X/Y/Z " + "/".join(f"{v * 100:.1f}" for v in chk["rms_m"])
                  + " cm" if chk else ""))
    if not (0.5 < rep["summary"]["sigma0"] < 1.5 and a1 < a0):
        raise click.ClickException("demo checks FAILED (integrated sensor orientation of the simulated flight)")

    # --- dense matching: DSM and dense cloud from the adjusted orientations, judged against the scene ------
    click.echo("\n=== dense matching of the nadir images with the ADJUSTED orientations: DSM (COG) + cloud (LAZ), "
               "judged against the scene's analytic surface ===")
    dsm_dir = sim_dir / "output" / "dsm"
    _run(["dsm", "--eo", str(adj_dir / "eo.csv"), "--camera", str(sim_dir / "rig.yaml"), "--images",
          str(sim_dir / "images"), "--heads", "nadir", "--points", str(adj_dir / "points.csv"), "-o", str(dsm_dir)])
    from skyrig.io.dense_laz import read_dense_cloud
    from skyrig.io.dsm_cog import read_dsm_cog
    from skyrig.simulate.judge import cloud_to_surface, judge_dsm
    from skyrig.simulate.scenarios import build_survey, scenario_spec

    survey = build_survey(scenario_spec("midas-dsm", "ci", 1))
    gsd = json.loads((dsm_dir / "dense.json").read_text())["stats"]["gsd_m"]
    j = judge_dsm(read_dsm_cog(dsm_dir / "dsm.tif"), survey.scene, gsd, survey.spec.flights[0].area)
    f, e, a = j["flat"], j["edge"], j["all"]
    dz = cloud_to_surface(read_dense_cloud(dsm_dir / "cloud.laz"), survey.scene)
    click.echo(f"GSD {gsd * 100:.1f} cm; flat cells: NMAD {f['nmad_gsd']:.2f} GSD, bias {f['bias_gsd']:+.2f} GSD, "
               f"completeness {f['completeness'] * 100:.1f} %; building edges (2 GSD): completeness "
               f"{e['completeness'] * 100:.1f} %, RMSE {e['rmse_gsd']:.1f} GSD; cells off by > 5 GSD "
               f"{a['outliers'] * 100:.2f} %; cloud: {len(dz)} points, median |dz| {np.median(np.abs(dz)) * 100:.1f} cm")
    if not _dsm_thresholds_met(j):
        raise click.ClickException("demo checks FAILED (dense matching)")
    _sixteen_bit_step(sim_dir, adj_dir, dsm_dir, survey, gsd)
    # --- true orthomosaic on the matched DSM, judged against the scene's true top-surface colours ---------
    click.echo("\n=== true orthomosaic of the nadir images on the matched DSM (COG + source layer + seamlines), "
               "judged against the scene ===")
    ortho_dir = sim_dir / "output" / "ortho"
    _run(["ortho", "--eo", str(adj_dir / "eo.csv"), "--camera", str(sim_dir / "rig.yaml"), "--images",
          str(sim_dir / "images"), "--heads", "nadir", "--dsm", str(dsm_dir / "dsm.tif"), "-o", str(ortho_dir)])
    jo, og = judge_ortho_folder(ortho_dir, sim_dir, survey)
    noise = survey.spec.image_noise_dn
    cams = load_cameras([str(sim_dir / "rig.yaml")])
    t_, rc_, oc_, sm_ = jo["tiles"], jo["roof_corners"], jo["occluded"], jo["seams"]
    click.echo(f"{og['width']} x {og['height']} cells of {og['cell_m'] * 100:.1f} cm; offset per tile (phase "
               f"correlation, n={t_['n']}) {t_['rms_gsd']:.2f} GSD RMS; roof corners (n={rc_['n']} judged of "
               f"{rc_.get('corners', rc_['n'])}; not judged: "
               + (", ".join(f"{v} {k}" for k, v in rc_.get("not_judged", {}).items() if v) or "none")
               + f") {rc_['rms_gsd']:.2f} GSD RMS, {rc_['within_1gsd'] * 100:.0f} % within 1 GSD; cells hidden from "
               f"their best image and seen by "
               f"another (n={oc_['n']}): {oc_['filled'] * 100:.1f} % filled; colour step across seamlines "
               f"{sm_['step_max_dn']:.2f} DN max, {sm_['step_rms_dn']:.2f} DN RMS ({sm_['pairs']} image pairs; image "
               f"noise {noise:.1f} DN; largest step less 2 standard errors of its seam samples "
               f"{sm_['step_lower_max_dn']:.2f} DN)")
    # a seam's step is the mean of its samples: judged by what they show at 2 standard errors, and on average
    if not (t_["rms_gsd"] <= 0.5 and oc_["filled"] >= 0.95 and sm_["step_lower_max_dn"] <= noise
            and sm_["step_rms_dn"] <= noise
            and rc_["n"] >= 20 and rc_["within_1gsd"] >= 0.95 and rc_["rms_gsd"] <= 0.5):
        raise click.ClickException("demo checks FAILED (orthomosaic)")

    # --- buildings, façade textures from the obliques and the textured 3D model ---------------------------
    click.echo("\n=== buildings from the DSM, façade textures from the oblique images, textured 3D model (GLB + "
               "viewer), judged against the scene ===")
    from skyrig.pipeline.dense import find_images
    from skyrig.pipeline.facades import run_facades
    from skyrig.simulate.judge_facades import judge_facades, walls_seen
    from skyrig.simulate.judge_model import judge_model

    # the obliques see beyond the nadir images' stereo coverage: the left / right heads' own DSMs extend the
    # building extraction there (only beyond the nadir DSM's surveyed area)
    ext = []
    for head in ("left", "right"):
        _run(["dsm", "--eo", str(adj_dir / "eo.csv"), "--camera", str(sim_dir / "rig.yaml"), "--images",
              str(sim_dir / "images"), "--heads", head, "--points", str(adj_dir / "points.csv"), "--no-cloud",
              "-o", str(sim_dir / "output" / f"dsm_{head}")])
        ext.append(str(sim_dir / "output" / f"dsm_{head}" / "dsm.tif"))
    eo_all = read_eo_csv(adj_dir / "eo.csv")
    fac = run_facades(eo_all, cams, find_images(eo_all, [str(sim_dir / "images")]), read_dsm_cog(dsm_dir / "dsm.tif"),
                      sim_dir / "output" / "facades", ortho=ortho_dir / "ortho.tif", extend_dsms=ext,
                      inputs=[str(adj_dir / "eo.csv"), str(dsm_dir / "dsm.tif"), *ext])
    frame_m = WorldFrame.from_text(fac.summary["frame"])
    jm = judge_model(fac.buildings, frame_m, survey.scene, match_radius_m=5.0)
    obl = {str(n) for n in eo_all.image if "nadir" not in str(n)}
    dsm_m = read_dsm_cog(dsm_dir / "dsm.tif")
    seen_w = walls_seen(survey.scene, eo_all, cams, obl)  # every wall an oblique sees, from the truth alone
    _, jf = judge_facades(survey.scene, fac.textures, frame_m, oblique=obl, walls=seen_w, dsm=dsm_m)
    click.echo(f"{len(fac.buildings)} buildings ({jm.get('found')} of the scene's found; footprint corners "
               f"{jm.get('corner_rms_m', float('nan')):.2f} m RMS, eaves {jm.get('eave_bias_m', float('nan')):+.2f} m); "
               f"{jf['facades']} façade textures, {jf['seen']} seen by an oblique: offset vs the façade rule median "
               f"{jf['offset_median_px']:.2f} texel, {jf['within_1px'] * 100:.0f} % with every window within 1 texel; "
               f"model {fac.glb} ({fac.glb.stat().st_size / 1e3:.0f} kB), viewer {fac.viewer}")
    click.echo(f"walls an oblique sees (scene truth): {jf['walls_seen']}, textured {jf['walls_textured']}, every "
               f"window within 1 texel {jf['walls_within_1px']}; of them inside the measured DSM "
               f"{jf.get('walls_seen_in_dsm', '-')}: textured {jf.get('walls_textured_in_dsm', '-')}, within 1 texel "
               f"{jf.get('walls_within_1px_in_dsm', '-')} (the nadir DSM; beyond it the buildings come from the left / right "
               f"oblique DSMs)")
    # every seen wall whose building the nadir DSM measured within 1 texel; beyond it (roofs the DSMs did not
    # measure) at least three in four
    if not (jf["seen"] > 0 and jf["offset_median_px"] <= 1.0 and jf["walls_within_1px"] >= 0.75 * jf["walls_seen"]
            and jf.get("walls_within_1px_in_dsm", 0) == jf.get("walls_seen_in_dsm", -1)):
        raise click.ClickException("demo checks FAILED (façade textures)")

    # buildings the DSMs miss (or cut at their border) from a cadastre: the scene's footprints with the errors of a
    # real cadastre (0.15 m in plan, 0.3 m in height, seeded), completing the DSM's buildings; walls moved onto
    # their feet as the obliques show them
    from skyrig.pipeline.simulate import write_scene_footprints

    cadastre = sim_dir / "cadastre.gpkg"
    write_scene_footprints(cadastre, survey.scene, dsm_m.frame.crs, height_sigma_m=0.3, plan_sigma_m=0.15, seed=0)
    fac_c = run_facades(eo_all, cams, find_images(eo_all, [str(sim_dir / "images")]), dsm_m,
                        sim_dir / "output" / "facades_cadastre", ortho=ortho_dir / "ortho.tif", extend_dsms=ext,
                        footprints=cadastre, eave_field="eave_m", ridge_field="ridge_m", footprint_mode="complete",
                        refine_footprints=True,
                        inputs=[str(adj_dir / "eo.csv"), str(dsm_dir / "dsm.tif"), *ext, str(cadastre)])
    _, jc = judge_facades(survey.scene, fac_c.textures, WorldFrame.from_text(fac_c.summary["frame"]), oblique=obl,
                          walls=seen_w, dsm=dsm_m)
    click.echo(f"with a cadastre ({cadastre.name}: footprints 0.15 m / heights 0.3 m RMS off; footprints used "
               f"{fac_c.summary.get('footprints')}): walls seen {jc['walls_seen']}, textured {jc['walls_textured']}, "
               f"every window within 1 texel {jc['walls_within_1px']}")
    # with the cadastre every wall an oblique sees has every window within 1 texel (issue 11's acceptance line)
    if not (jc["walls_seen"] > 0 and jc["walls_within_1px"] == jc["walls_seen"]):
        raise click.ClickException("demo checks FAILED (façade textures with a cadastre)")

    _tumble_circle_step(Path(outdir) / "tumble_circle")

    # --- LiDAR: simulated UAV 2D-scanner flight along a bridge (paper 002), georeferenced and compared ---
    from skyrig.pipeline.simulate import lidar_demo

    click.echo("\n=== LiDAR: UAV 2D scanner along a bridge (paper 002): georeference, compare with TLS, calibrate ===")
    fig = lidar_demo(Path(outdir) / "lidar")
    click.echo(f"{fig['returns']} returns of {fig['pulses']} pulses vs {fig['reference_points']} reference points "
               f"({fig['seconds']:.1f} s)")
    for key, label in (("gnss_heights", "GNSS heights"), ("barometric_heights", "barometric heights"),
                       ("corrected", "after estimated corrections")):
        if key in fig:
            c = fig[key]
            click.echo(f"  {label:28s} C2C RMS {c['c2c_rms_m']:.3f} m, 68% below {c['c2c_p68_m']:.3f} m, "
                       f"M3C2 median |d| {c['m3c2_median_abs_m']:.3f} m")
    hb = fig["heading_plus_boresight_y_deg"]
    click.echo(f"  heading correction + boresight about scanner y: estimated {hb['estimated']:.3f} deg, "
               f"injected {hb['injected']:.3f} deg")
    if abs(hb["estimated"] - hb["injected"]) > 0.2 or fig["corrected"]["c2c_rms_m"] > fig["gnss_heights"]["c2c_rms_m"]:
        raise click.ClickException("demo checks FAILED (lidar)")
    _terrain_step(outdir)
    _classic_ortho_step(outdir)
    _determinability_step()
    _papers_step(outdir)
    _live_step(outdir)
    _laser_strips_step(outdir)
    _lidar_camera_step(outdir)
    click.echo(f"\ndemo checks passed (total {time.perf_counter() - t0:.1f} s)")


def _dsm_thresholds_met(j: dict) -> bool:
    """Issue 10's figures for a DSM judged by :func:`skyrig.simulate.judge.judge_dsm`: flat cells NMAD <= 1 GSD, bias
    <= 0.2 GSD, completeness >= 95 %; cells off by > 5 GSD <= 1 %."""
    f, a = j["flat"], j["all"]
    return bool(f["nmad_gsd"] <= 1.0 and abs(f["bias_gsd"]) <= 0.2 and f["completeness"] >= 0.95
                and a["outliers"] <= 0.01)


def _sixteen_bit_step(sim_dir: Path, adj_dir: Path, dsm_dir: Path, survey: Any, gsd: float) -> None:
    """The nadir images as 12-bit data in 16-bit TIFFs (16 x the 8-bit value + 40, as large-format cameras deliver
    them), read window by window (``--window-min-mp 0``): a DSM of the block's middle, judged against the scene and
    against the 8-bit DSM of the same cells."""
    import json
    from dataclasses import replace

    import cv2

    from skyrig.io.dsm_cog import read_dsm_cog
    from skyrig.io.eo_csv import read_eo_csv, write_eo_csv
    from skyrig.pipeline.dense import find_images
    from skyrig.pipeline.inputs import select_heads
    from skyrig.simulate.judge import judge_dsm

    click.echo("\n=== the nadir images as 12-bit TIFFs, read window by window: DSM of the block's middle, judged "
               "against the scene and the 8-bit DSM ===")
    eo = select_heads(read_eo_csv(adj_dir / "eo.csv"), "nadir")
    folder = sim_dir / "images_12bit"
    folder.mkdir(exist_ok=True)
    names = []
    for path in find_images(eo, [str(sim_dir / "images")]):
        v = cv2.imread(path, cv2.IMREAD_UNCHANGED)
        name = Path(path).stem + ".tif"
        if not cv2.imwrite(str(folder / name), 16 * v.astype(np.uint16) + 40):
            raise click.ClickException(f"could not write {folder / name}")
        names.append(name)
    eo16 = sim_dir / "output" / "eo_12bit.csv"
    write_eo_csv(replace(eo, image=np.array(names)), eo16)
    # the middle 40 % of the planned block, in the DSM's CRS
    x0, y0, x1, y1 = survey.spec.flights[0].area
    cx, cy, hx, hy = 0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.2 * (x1 - x0), 0.2 * (y1 - y0)
    box = (cx - hx, cy - hy, cx + hx, cy + hy)
    dsm8 = read_dsm_cog(dsm_dir / "dsm.tif")
    from skyrig.geodesy.frame import WorldFrame

    local = WorldFrame.local(*survey.scene.origin)
    corners = np.array([[box[0], box[1], 0.0], [box[2], box[1], 0.0], [box[0], box[3], 0.0], [box[2], box[3], 0.0]])
    m = dsm8.frame.from_ecef(local.to_ecef(corners))
    area = [float(m[:, 0].min()), float(m[:, 1].min()), float(m[:, 0].max()), float(m[:, 1].max())]
    out = sim_dir / "output" / "dsm_12bit"
    _run(["dsm", "--eo", str(eo16), "--camera", str(sim_dir / "rig.yaml"), "--images", str(folder),
          "--points", str(adj_dir / "points.csv"), "--area", *(f"{a:.3f}" for a in area), "--window-min-mp", "0",
          "--no-cloud", "-o", str(out)])
    dsm16 = read_dsm_cog(out / "dsm.tif")
    levels = json.loads((out / "dense.json").read_text())["image_levels_16bit"]
    j = judge_dsm(dsm16, survey.scene, gsd, box)
    f, a = j["flat"], j["all"]
    # the 8-bit DSM's cell under each cell centre of the 12-bit one
    g8 = dsm8.grid
    rr, cc = g8.cell_of(*dsm16.grid.cell_centres())
    inside = (rr >= 0) & (rr < g8.height) & (cc >= 0) & (cc < g8.width)
    h8 = np.full(dsm16.height.shape, np.nan)
    h8[inside] = dsm8.height[rr[inside], cc[inside]]
    both = np.isfinite(h8) & np.isfinite(dsm16.height)
    d = np.abs(dsm16.height[both] - h8[both]) / gsd
    click.echo(f"levels {levels[0]:.0f} .. {levels[1]:.0f} -> 0 .. 255; flat cells: NMAD {f['nmad_gsd']:.2f} GSD, bias "
               f"{f['bias_gsd']:+.2f} GSD, completeness {f['completeness'] * 100:.1f} %; cells off by > 5 GSD "
               f"{a['outliers'] * 100:.2f} %; against the 8-bit DSM: {both.sum()} common cells, median |dz| "
               f"{np.median(d):.3f} GSD, valid {np.isfinite(dsm16.height).mean() * 100:.1f} % vs "
               f"{np.isfinite(h8).mean() * 100:.1f} %")
    if not (_dsm_thresholds_met(j) and np.median(d) <= 0.1
            and abs(np.isfinite(dsm16.height).mean() - np.isfinite(h8).mean()) <= 0.02):
        raise click.ClickException("demo checks FAILED (12-bit images)")


def _tumble_circle_step(folder: Path) -> None:
    """Paper 000 Fig. 9: a TumbleCam circle projected onto one plane by ``skyrig plane-mosaic`` from orientations
    transferred with and without the lab-calibrated boresight curve; each seam's offset against the offset the
    orientation errors predict (geometry alone), the curve's seams within 1 px and the others measurably larger."""
    import csv
    import json

    from skyrig.pipeline.demo import tumble_circle_demo

    click.echo("\n=== TumbleCam circle on one plane (paper 000 Fig. 9): skyrig plane-mosaic with and without the "
               "boresight curve, seam offsets against the offsets the orientation errors predict ===")
    d = tumble_circle_demo(folder)
    got = {}
    for label in ("curve", "no_curve"):
        _run(["plane-mosaic", "--eo", str(d["eo"][label]), "--camera", str(d["rig"]), "--images", str(d["images"]),
              "--height", str(d["plane_height_m"]), "--window", "48", "-o", str(folder / f"mosaic_{label}")])
        s = json.loads((folder / f"mosaic_{label}" / "plane_mosaic.json").read_text())
        with open(folder / f"mosaic_{label}" / "seams.csv", newline="") as fh:
            rows = list(csv.DictReader(fh))
        cell = s["grid"]["cell_m"]
        dev = [abs(float(r["offset_m"]) - d["predicted"][label][(r["a"], r["b"])]) / cell for r in rows
               if (r["a"], r["b"]) in d["predicted"][label]]
        got[label] = (s, max(dev) if dev else float("nan"), len(dev))
        click.echo(f"  {label.replace('_', ' '):9s} {s['seams_measured']} seams: offset median "
                   f"{s['median_offset_px']:.2f} px, max {s['max_offset_px']:.2f} px; measured - predicted at most "
                   f"{got[label][1]:.2f} px (n={len(dev)})")
    (sc, dc, nc), (sn, dn, nn) = got["curve"], got["no_curve"]
    if not (nc >= 10 and nn >= 10 and sc["max_offset_px"] <= 1.0 and dc <= 0.45 and dn <= 0.45
            and sn["median_offset_px"] > 2 * sc["median_offset_px"]):
        raise click.ClickException("demo checks FAILED (Fig. 9 plane mosaic)")


def judge_ortho_folder(ortho_dir: Path, sim_dir: Path, survey: Any, head: str = "nadir") -> tuple[dict, dict]:
    """The orthomosaic of a ``skyrig ortho`` folder judged against a simulated flight's scene
    (:func:`skyrig.simulate.judge.judge_ortho`: tile offsets, roof corners, hidden cells, seams), with the
    flight's true orientations of ``head`` from ``sim_dir/truth/eo.csv`` and its rig file; returns the judge's
    figures and the mosaic's grid (``ortho.json``)."""
    import json

    import rasterio

    from skyrig.cli._common import load_cameras
    from skyrig.dense.grid import GridSpec
    from skyrig.georef.eo import WorldFrame
    from skyrig.io.eo_csv import read_eo_csv
    from skyrig.io.ortho_cog import read_ortho_cog
    from skyrig.simulate.judge import judge_ortho

    rgb, ovalid, _, _ = read_ortho_cog(ortho_dir / "ortho.tif")
    with rasterio.open(ortho_dir / "ortho_source.tif") as src_:
        osource = src_.read(1)
    ometa = json.loads((ortho_dir / "ortho.json").read_text())
    og = ometa["grid"]
    ogrid = GridSpec(og["x0"], og["y0"], og["cell_m"], og["width"], og["height"])
    tl = read_eo_csv(sim_dir / "truth" / "eo.csv")
    tl = tl.subset(np.flatnonzero([head in str(n) for n in tl.image]))
    cams = load_cameras([str(sim_dir / "rig.yaml")])
    jo = judge_ortho(rgb, ovalid, osource, ogrid, WorldFrame.from_text(ometa["frame"]), survey.scene, og["cell_m"],
                     eo_local=tl, cameras=cams, noise_dn=survey.spec.image_noise_dn)
    return jo, og


def _determinability_step() -> None:
    """Issue 28: a UAV self-calibration the block cannot determine is held at its prior, in words; one it can is
    freed and lands within its sigma of the simulation's truth (metadata focal length 20 % off, prior sigma 10 %)."""
    import logging

    from skyrig.orient.gnss_block import UavConfig, adjust_uav_block
    from skyrig.rig.presets import uav_single
    from skyrig.simulate.scenarios import ci_camera
    from skyrig.simulate.uav_block import CROSS, FLAT, flat_site_block

    click.echo("\n=== UAV self-calibration: what a block can determine (flat nadir at one height vs cross strips at "
               "50 / 80 m; metadata focal length 20 % off) ===")
    cam = ci_camera(uav_single().heads["camera"].camera, 800)
    cfg = UavConfig(gnss_sigma_m=(0.3, 0.3, 0.5), pixel_sigma_px=0.3, pnp_threshold_px=4.0,
                    self_calibration=("focal_mm", "ppx_mm", "ppy_mm", "k1", "k2"))
    ok = True
    for label, strips, seed in (("flat, one height", FLAT, 11), ("cross strips, two heights", CROSS, 12)):
        inp, truth = flat_site_block(strips, seed, cam)
        logging.getLogger("skyrig.adjust.determinability").setLevel(logging.ERROR)  # the verdict is printed below
        res = adjust_uav_block(inp, cfg)
        logging.getLogger("skyrig.adjust.determinability").setLevel(logging.NOTSET)
        v = next(x for x in res.summary["calibration"] if x["name"] == "focal_mm")
        err = res.camera.focal_mm / truth.camera.focal_mm - 1
        sf = res.adjustment.sigma_reduced().get(("intrinsics", res.camera.name, "focal_mm"))
        z = (res.camera.focal_mm - truth.camera.focal_mm) / sf if sf else float("nan")
        click.echo(f"  {label:26s} verdict: {v['verdict']}{' (held at the prior)' if v['held'] else ''}; formal "
                   f"sigma {v['ratio']:.2f} x the prior's; focal length {100 * err:+.1f} % from the truth"
                   + ("" if v["held"] else f" (z = {z:+.2f} of its sigma)"))
        if strips is FLAT:
            ok &= v["held"] and "second altitude" in v["words"]
        else:
            ok &= (not v["held"]) and abs(z) < 3
    if not ok:
        raise click.ClickException("demo checks FAILED (self-calibration determinability)")


def _terrain_step(outdir: str | Path) -> None:
    """Issue 31 on the simulated town: the dense cloud classified (cloth simulation filter + ASPRS rule), the DTM on
    the DSM's grid, contours, and a building's volume above the DTM, each judged against the scene's truth (its
    analytic bare earth and building footprints): open-ground DTM NMAD <= 1 GSD and |bias| <= 0.3 GSD, ground class
    error <= 5 %, building recall >= 90 %, the building's volume within 3 predicted sigmas of the scene's; a stockpile
    of the scene (opt-in, :data:`skyrig.simulate.scenarios.MIDAS_DSM_STOCKPILE`) within 2 (:func:`_stockpile_volume`)."""
    import json

    import laspy
    import shapely

    from skyrig.io.dense_laz import read_dense_cloud
    from skyrig.io.gpkg import write_gpkg
    from skyrig.io.terrain_files import read_dtm_cog
    from skyrig.simulate.judge_terrain import building_volume_truth, footprint_polygon_map, judge_classes, judge_dtm
    from skyrig.simulate.scenarios import build_survey, scenario_spec

    click.echo("\n=== terrain (issue 31): skyrig terrain classify / dtm / contours / volume on the simulated town, "
               "judged against the scene's bare earth, footprints and building volumes ===")
    sim_dir = Path(outdir) / "simulated"
    dsm_dir, out = sim_dir / "output" / "dsm", sim_dir / "output" / "terrain"
    survey = build_survey(scenario_spec("midas-dsm", "ci", 1))
    scene, area = survey.scene, survey.spec.flights[0].area
    gsd = json.loads((dsm_dir / "dense.json").read_text())["stats"]["gsd_m"]
    _run(["terrain", "classify", str(dsm_dir / "cloud.laz"), "-o", str(out / "classified.laz"), "--copc",
          str(out / "classified.copc.laz")])
    import laspy

    with laspy.CopcReader.open(out / "classified.copc.laz") as rd:  # an independent COPC reader: every point once
        n_copc, n_laz = len(rd.query()), laspy.read(out / "classified.laz").header.point_count
    click.echo(f"  COPC (cloud-optimised, for web viewers): {n_copc} of {n_laz} points read back by laspy's reader")
    if n_copc != n_laz:
        raise click.ClickException("demo checks FAILED (COPC copy of the classified cloud)")
    _run(["terrain", "dtm", str(out / "classified.laz"), "--dsm", str(dsm_dir / "dsm.tif"), "-o", str(out / "dtm")])
    _run(["terrain", "contours", str(out / "dtm" / "dtm.tif"), "--interval", "0.5", "-o", str(out / "contours.gpkg")])
    dtm = read_dtm_cog(out / "dtm" / "dtm.tif")
    jd = judge_dtm(dtm, scene, gsd, area)
    cl = read_dense_cloud(out / "classified.laz")
    code = np.asarray(laspy.read(out / "classified.laz").classification)
    jc = judge_classes(cl.xyz, code, cl.frame, scene, gsd, area)
    # the largest building wholly inside the block: its volume above the DTM within its footprint + 1 m
    b = scene.buildings
    inner = [i for i in range(len(b)) if area[0] + 5 < b.cx[i] - b.hl[i] - b.hw[i] and b.cx[i] + b.hl[i] + b.hw[i]
             < area[2] - 5 and area[1] + 5 < b.cy[i] - b.hl[i] - b.hw[i] and b.cy[i] + b.hl[i] + b.hw[i] < area[3] - 5]
    i = max(inner, key=lambda k: b.hl[k] * b.hw[k])
    poly = shapely.Polygon(footprint_polygon_map(scene, i, dtm.frame, margin_m=1.0))
    write_gpkg(out / "building.gpkg", {"building": ([poly], {"building": [i]})}, dtm.frame.crs)
    _run(["terrain", "volume", "--top", str(dsm_dir / "dsm.tif"), "--base", str(out / "dtm" / "dtm.tif"),
          "--polygon", str(out / "building.gpkg"), "-o", str(out / "volume.json")])
    v = json.loads((out / "volume.json").read_text())
    v_true = building_volume_truth(scene, i, margin_m=1.0)
    o, u = jd["open"], jd["under_buildings"]
    click.echo(f"DTM ({dtm.grid.cell_m:.3f} m cells) vs the true bare earth: open ground NMAD {o['nmad_gsd']:.2f} GSD, "
               f"bias {o['bias_gsd']:+.2f} GSD, RMSE {o['rmse_m']:.3f} m (n={o['valid']}); under buildings RMSE "
               f"{u['rmse_m']:.3f} m, bias {u['bias_m']:+.3f} m (n={u['valid']}, {jd['footprint_flagged'] * 100:.1f} % "
               f"flagged)")
    click.echo(f"classes vs the scene ({jc['points_judged']} points): ground class error "
               f"{jc['ground_class_error'] * 100:.2f} % (type I {jc['ground_type1'] * 100:.2f} %, type II "
               f"{jc['ground_type2'] * 100:.2f} %), building recall {jc['building_recall'] * 100:.1f} %, precision "
               f"{jc['building_precision'] * 100:.1f} %")
    dv = v["net_m3"] - v_true
    click.echo(f"building {i}: volume above the DTM {v['net_m3']:.1f} +- {v['sigma_net_m3']:.1f} m3, scene "
               f"{v_true:.1f} m3 ({dv / v_true * 100:+.2f} %, {dv / v['sigma_net_m3']:+.2f} sigma)")
    # a stockpile of the scene (opt-in: skyrig.simulate.scenarios.MIDAS_DSM_STOCKPILE) is measured and judged too
    pile_ok = _stockpile_volume(out, dsm_dir, dtm, scene) if scene.stockpiles is not None else True
    if not (o["nmad_gsd"] <= 1.0 and abs(o["bias_gsd"]) <= 0.3 and jc["ground_class_error"] <= 0.05
            and jc["building_recall"] >= 0.9 and abs(dv) <= 3 * v["sigma_net_m3"] and pile_ok):
        raise click.ClickException("demo checks FAILED (terrain)")


def _classic_ortho_step(outdir: str | Path) -> None:
    """Issue 31: a classic orthophoto of the nadir images on the terrain step's DTM (``skyrig ortho --surface dtm``),
    next to the true ortho, judged against the scene: the ground in place (tile offsets <= 0.5 GSD RMS, as the true
    ortho's) and the roofs leaning off their footprints (roof corners > 2 GSD RMS: what a classic ortho shows)."""
    from skyrig.simulate.scenarios import build_survey, scenario_spec

    click.echo("\n=== classic orthophoto on the DTM (skyrig ortho --surface dtm), next to the true ortho, judged "
               "against the scene ===")
    sim_dir = Path(outdir) / "simulated"
    out = sim_dir / "output" / "ortho_dtm"
    _run(["ortho", "--eo", str(sim_dir / "output" / "adjust" / "eo.csv"), "--camera", str(sim_dir / "rig.yaml"),
          "--images", str(sim_dir / "images"), "--heads", "nadir", "--surface", "dtm", "--dtm",
          str(sim_dir / "output" / "terrain" / "dtm" / "dtm.tif"), "-o", str(out)])
    jo, og = judge_ortho_folder(out, sim_dir, build_survey(scenario_spec("midas-dsm", "ci", 1)))
    t_, rc_ = jo["tiles"], jo["roof_corners"]
    click.echo(f"{og['width']} x {og['height']} cells of {og['cell_m'] * 100:.1f} cm; offset per tile on the ground "
               f"(n={t_['n']}) {t_['rms_gsd']:.2f} GSD RMS; roof corners (n={rc_['n']}) {rc_['rms_gsd']:.2f} GSD RMS "
               f"off their footprints, {rc_['within_1gsd'] * 100:.0f} % within 1 GSD (buildings lean)")
    if not (t_["rms_gsd"] <= 0.5 and rc_["n"] >= 20 and rc_["rms_gsd"] > 2.0):
        raise click.ClickException("demo checks FAILED (classic ortho on the DTM)")


def _papers_step(outdir: str | Path) -> None:
    """Issue 36: ``skyrig paper 001 --size ci``: paper 001's field of view, GSD and swath from the 3K preset and the
    DSM chain's time shares, next to the paper's values, into one folder with an index page (a failed check or a
    raised error makes the command fail, and the demo with it)."""
    import json

    click.echo("\n=== the papers reproduced: skyrig paper 001 (DLR 3K) ===")
    out = Path(outdir) / "papers"
    _run(["paper", "001", "--size", "ci", "--out", str(out)])
    res = json.loads((out / "001" / "result.json").read_text())
    for c in res["comparisons"]:
        click.echo(f"  {c['quantity']}: skyrig {c['skyrig']} {c['unit']}, paper {c['paper']}")
    click.echo(f"  index page: {out / 'index.html'}")


def _live_step(outdir: str | Path) -> None:
    """Issue 35: a short 3K flight (8 exposures of the triple rig, boresights misaligned) replayed at 4 x its rate
    into a project's inputs, ``skyrig run --live --then-batch`` on it (OUTPUT/live published whole, then the georef
    stage); judged against the batch answer: the online boresight within 3 of its sigma (nine angles) of the batch
    adjustment (every exposure in one adjustment; bench/live.py states the difference in its own sigma, which needs
    the windows' observations) and within 3 of its sigma of the injected truth (the window's sigma is realistic since
    only the image group's variance is estimated: error / sigma RMS 1.04 over 5 seeds, bench/live_stats.py), the
    live mosaic within 0.5 GSD of the batch ortho."""
    import json

    import numpy as np

    from skyrig.pipeline import live_check as lc

    import shutil

    from skyrig.io.stage import verify_folder

    click.echo("\n=== skyrig run --live: a 3K flight replayed into a project's inputs, judged against the batch "
               "answer ===")
    base = Path(outdir).resolve() / "live"  # absolute: the project file's paths are read relative to its folder
    flight, proj = base / "flight", base / "project"
    if not (flight / "events.csv").exists():
        lc.simulate_3k_flight(flight, half_length_m=300.0)
    dem = flight / "reference_dem.tif"
    shutil.rmtree(proj, ignore_errors=True)
    proj.mkdir(parents=True)
    shutil.copyfile(flight / "rig.yaml", proj / "rig.yaml")
    (proj / "project.yaml").write_text(
        "format: skyrig-project\nversion: 1\ncrs: EPSG:25832\noutput: output\n"
        "inputs: {images: [images], trajectory: trajectory.csv, events: events.csv, rig: rig.yaml}\n"
        f"stages:\n  live: {{dem: {dem}, height_sigma: 2.0, window: 4, image_timeout: 60.0, "
        "trajectory_timeout: 60.0}\n  georef: {}\n")
    _run(["run", str(proj), "--live", "--replay", str(flight), "--speed", "4", "--no-serve", "--then-batch"])
    live_out = proj / "output" / "live"
    if verify_folder(live_out) or not (proj / "output" / "georef" / "eo.csv").is_file():
        raise click.ClickException(f"demo checks FAILED (live project: {verify_folder(live_out)[:1]})")
    s = json.loads((live_out / "summary.json").read_text())
    from skyrig.pipeline.live import LiveConfig

    batch = lc.batch_boresight(flight, "EPSG:25832", None, dem, 2.0, LiveConfig().features)  # same observations
    truth = lc.true_corrections(flight)
    worst_b = worst_t = 0.0
    for h in sorted(s["boresight_deg"]):
        so = np.radians(s["boresight_sigma_deg"][h])
        on = np.radians(s["boresight_deg"][h])
        worst_b = max(worst_b, float(np.max(np.abs(on - batch.correction[h]) / so)))
        worst_t = max(worst_t, float(np.max(np.abs(on - truth[h]) / so)))
    cell = s["cell_m"]["median"]
    ortho = lc.batch_ortho(flight, "EPSG:25832", 80.0, batch.correction, cell, None, dem)
    off = lc.mosaic_offsets(live_out / "tiles", max(s["zooms"]), ortho)
    click.echo(f"{s['exposures_done']} exposures live; online boresight ({s['boresight_windows']} windows) - batch: "
               f"at most {worst_b:.2f} sigma, - truth: at most {worst_t:.2f} sigma; live mosaic - batch ortho: median "
               f"{off['median_offset_m'] / cell:.2f} GSD over {off['patches']} patches")
    if not (s["exposures_done"] == 8 and worst_b <= 3.0 and worst_t <= 3.0 and off["median_offset_m"] <= 0.5 * cell):
        raise click.ClickException("demo checks FAILED (live)")


def _laser_strips_step(outdir: str | Path) -> None:
    """Issues 34 / 31: a laser project (four short strips of the simulated bridge flight: raw scan with strip ids,
    recorded trajectory, nominal scanner record, a TLS reference) through ``skyrig run``: the lidar stage's strip
    adjustment, then the DTM on its cloud; judged against the simulation's truth: strip discrepancies at the noise
    level (normalised RMS < 1.5, > 5 before), every calibration value the stage estimated within 3 sigma of the
    injected one, the cloud's 3D error at most 0.55 x the nominal georeferencing's, the DTM on the true ground."""
    import json

    import numpy as np

    from skyrig.geodesy.frame import WorldFrame
    from skyrig.io.laz import read_las
    from skyrig.io.scanner_record import read_scanner_mount
    from skyrig.io.terrain_files import read_dtm_cog
    from skyrig.lidar.georef import georeference_scan
    from skyrig.pipeline.lidar import simulate_laser_project

    click.echo("\n=== laser project: skyrig run with the lidar stage (strip adjustment) and the DTM on its cloud ===")
    root = Path(outdir) / "laser_project"
    sv = simulate_laser_project(root)
    _run(["run", str(root / "project.yaml")])
    out = root / "output"
    rep = json.loads((out / "lidar" / "strips.json").read_text())
    b, a = rep["discrepancies_before"], rep["discrepancies_after"]
    _, extra = read_scanner_mount(out / "lidar" / "scanner.yaml")
    cal = extra["calibration"]
    inj = sv.injected
    truth = {"boresight_rad": inj["boresight_rad"], "lever_arm_m": inj["lever_arm_error_m"],
             "range": [inj["range_offset_m"], inj["range_scale_ppm"]]}
    z = []
    for key in ("boresight_rad", "lever_arm_m", "range"):
        for name, v, s, t in zip(cal[key]["parameters"], cal[key]["values"], cal[key]["sigma"], truth[key]):
            if s > 0 and name.replace("_m", "").replace("_ppm", "") not in cal["held"]:
                z.append((name, (v - t) / s))
    utm = WorldFrame.map("EPSG:32633")
    xyz = read_las(out / "lidar" / "laser.laz").xyz
    true = utm.from_ecef(sv.frame.to_ecef(sv.truth_xyz))
    nominal = georeference_scan(sv.scan, sv.trajectory_recorded, sv.mount_recorded, utm).xyz
    d_a, d_n = (float(np.sqrt(np.mean(np.sum((q - true) ** 2, axis=1)))) for q in (xyz, nominal))
    h = np.asarray(read_dtm_cog(out / "dtm" / "dtm.tif").height)
    dz = float(np.nanmedian(h)) - 150.0  # the scene's ground: the local frame's z = 0 at ellipsoidal height 150 m
    click.echo(f"strip discrepancies on {a['pairs']} patch pairs: RMS {b['rms_m'] * 1000:.1f} -> {a['rms_m'] * 1000:.1f} "
               f"mm (noise {a['noise_rms_m'] * 1000:.1f} mm; normalised {b['normalised_rms']:.1f} -> "
               f"{a['normalised_rms']:.2f}); calibration vs injected: "
               + ", ".join(f"{n} {v:+.2f} sigma" for n, v in z) + f" (held: {', '.join(cal['held']) or 'none'})")
    click.echo(f"cloud vs the true points: 3D RMS {d_a * 1000:.1f} mm (nominal georeferencing {d_n * 1000:.1f} mm); "
               f"DTM median - true ground {dz * 1000:+.1f} mm; {rep['crs']}, {rep['vertical_reference']}")
    if not (b["normalised_rms"] > 5 and a["normalised_rms"] < 1.5 and all(abs(v) < 3 for _, v in z)
            and d_a < 0.55 * d_n and abs(dz) < 0.1):
        raise click.ClickException("demo checks FAILED (laser project)")


def _lidar_camera_step(outdir: str | Path) -> None:
    """Issue 34: paper 002's bridge strip flight (CI size) with its camera, laser and images in one adjustment
    (``skyrig calibrate lidar-camera --simulate``); judged against the injected truth: scanner boresight, lever arm,
    range offset and scale and camera boresight within 3 predicted sigmas (the range scale's bias of about 2 sigma
    is gone with the Jacobians at the adjusted observations, see bench/lidar_joint.py), and the strip-to-strip
    discrepancies on the patch planes at the noise level after the adjustment (RMS over their sigma < 1.2)."""
    import json

    import numpy as np

    click.echo("\n=== skyrig calibrate lidar-camera: laser strips and images of the bridge flight in one adjustment ===")
    out = Path(outdir) / "lidar_camera" / "rig.yaml"
    _run(["calibrate", "lidar-camera", "--simulate", "strips-ci", "--seed", "2", "-o", str(out)])
    rep = json.loads(out.with_suffix(".json").read_text())
    z = [(v["value"] - t) / v["sigma"] for v, t in zip(rep["scanner"].values(), rep["truth"]["scanner"])]
    cb = rep["camera_boresight_rad"]
    z += ((np.array(cb["value"]) - rep["truth"]["camera_boresight_rad"]) / np.array(cb["sigma"])).tolist()
    click.echo(f"largest |estimate - truth| / sigma over 11 calibration parameters: {max(map(abs, z)):.2f}")
    dis = rep["strip_discrepancies"]
    click.echo(f"strip-to-strip discrepancies: RMS {dis['before']['rms_m'] * 1e3:.1f} mm before, "
               f"{dis['after']['rms_m'] * 1e3:.1f} mm after (over their sigma {dis['after']['normalised_rms']:.2f})")
    if max(map(abs, z)) > 3.0 or not dis["after"]["normalised_rms"] < 1.2:
        raise click.ClickException("demo checks FAILED (lidar-camera)")


def _stockpile_volume(out: Path, dsm_dir: Path, dtm: Any, scene: Any) -> bool:
    """Issue 31: the simulated town's stockpile (:data:`skyrig.simulate.scenarios.MIDAS_DSM_STOCKPILE`) measured as a
    surveyor does: a ring of 48 points 2 m outside its toe, their heights (and sigmas) read from the DTM, the DSM's
    volume above the plane fitted through them (``skyrig terrain volume --base-points --base-fit plane``: a ring's
    triangulation is a fan of slivers, one point weighing a third of the area) inside the ring; judged within 2
    predicted sigmas of the scene's truth for that base, and reported against the pile's closed-form volume."""
    import json

    import shapely

    from skyrig.georef.observations import GroundPoints
    from skyrig.io.gpkg import write_gpkg
    from skyrig.io.points_csv import write_points_csv
    from skyrig.simulate.judge_terrain import ring_to_map, stockpile_toe_ring, stockpile_volume_truth
    from skyrig.terrain.dtm import sample_grid, sample_surface

    ring = stockpile_toe_ring(scene, 0)
    xy = ring_to_map(scene, ring, dtm.frame)
    z, sz = sample_surface(dtm, xy[:, 0], xy[:, 1]), sample_grid(dtm.grid, dtm.sigma, xy[:, 0], xy[:, 1])
    write_gpkg(out / "stockpile.gpkg", {"stockpile": ([shapely.Polygon(xy)], {"name": ["pile 0"]})}, dtm.frame.crs)
    write_points_csv(out / "stockpile_toe.csv", GroundPoints(np.array([f"toe{k:02d}" for k in range(len(xy))]),
                                                              np.column_stack([xy, z]), dtm.frame), {"sz": sz})
    _run(["terrain", "volume", "--top", str(dsm_dir / "dsm.tif"), "--base-points", str(out / "stockpile_toe.csv"),
          "--base-fit", "plane", "--polygon", str(out / "stockpile.gpkg"), "-o", str(out / "stockpile_volume.json")])
    v = json.loads((out / "stockpile_volume.json").read_text())
    t = stockpile_volume_truth(scene, 0, ring, fit="plane")
    d, s = v["net_m3"] - t["above_toe_base"], v["sigma_net_m3"]
    click.echo(f"stockpile: {v['net_m3']:.1f} +- {s:.1f} m3 above its toe ({len(xy)} points from the DTM); scene "
               f"{t['above_toe_base']:.1f} m3 for that base ({d / t['above_toe_base'] * 100:+.2f} %, {d / s:+.2f} "
               f"sigma); the pile's closed form {t['pile']:.1f} m3 ({(v['net_m3'] - t['pile']) / t['pile'] * 100:+.2f} "
               f"%; the toe's base under the pile {t['base_error']:+.1f} m3 off the natural ground)")
    return bool(np.isfinite(v["net_m3"]) and abs(d) <= 2 * s and s < 0.05 * t["pile"])
