"""Paper 002 (ADFEX): the UAV laser scanner's point cloud against the TLS reference, as the paper's Table 1 and
Fig. 6b (cloud-to-cloud distances after an ICP fine registration: RMS, "2/3 of all points below", histogram).

The ``uav-bridge-lidar`` scenario (:mod:`skyrig.simulate.lidar`: a Hokuyo UTM-30LX-EW on a UAV flying past a
bridge with GNSS, IMU, heading and barometer errors, and a terrestrial reference scan of the bridge) is
georeferenced by skyrig's chain (:func:`skyrig.lidar.georef.georeference_scan`, GNSS heights and, as in the
paper's Fig. 7b, barometric heights), registered onto the reference by ICP
(:func:`skyrig.lidar.register.icp`; the simulated clouds share one frame, so the paper's three-point coarse
alignment is not needed) and compared point by point (:func:`skyrig.lidar.compare.cloud_to_cloud`: the distance
to the plane of the 8 nearest reference points, CloudCompare's C2C with a local model; the nearest point alone
would measure the reference's point spacing, several centimetres here).  The simulator's true surface points of the same pulses go through the
same comparison: the method's own floor.  At ``full`` size skyrig's dense image cloud of the ``uav-bridge-camera``
flight (the pillar pass; minutes) is compared the same way; at ``ci`` the image column is the paper's only.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from skyrig.papers._figures import new_figure, write_png
from skyrig.papers.base import Comparison, Figure, PaperResult, PaperTable, Size

__all__ = ["scenario", "laser_vs_tls", "run"]

#: paper 002, Table 1 and sections 4.2 / 4.3: (RMS, 2/3 of the points below) in metres
PAPER_LSRF = (0.317, 0.294)
PAPER_SFM = (0.049, 0.041)
MAX_DISTANCE_M = 2.0  # C2C search radius (points farther: not on the reference's surfaces)


def scenario(size: Size, seed: int = 1) -> Any:
    """The ``uav-bridge-lidar`` spec: at ``ci`` one 9 m pass past a pillar with a sparser reference (seconds), at
    ``full`` the scenario's full size."""
    from skyrig.simulate.lidar import lidar_scenario_spec

    if size == "ci":
        spec = lidar_scenario_spec("ci", seed)
        return replace(spec, pass_u_m=(18.0, 9.0), reference_density_per_m2=120.0, reference_ground_density_per_m2=40.0)
    return lidar_scenario_spec("full", seed)


def laser_vs_tls(survey: Any) -> dict[str, Any]:
    """The survey's scan georeferenced with GNSS heights and with barometric heights, each registered onto the
    reference by ICP and compared (C2C); the true points compared the same way.  Distances and statistics."""
    from skyrig.lidar.compare import cloud_to_cloud, distance_statistics
    from skyrig.lidar.georef import georeference_scan
    from skyrig.lidar.register import apply_transform, icp

    ref = survey.reference_xyz
    o = ref.mean(axis=0)
    out: dict[str, Any] = {}
    truth = cloud_to_cloud(survey.truth_xyz - o, ref - o, max_distance=MAX_DISTANCE_M, model="plane", k=8)
    out["truth"] = {"distance_m": truth.distance_m, "stats": distance_statistics(truth.distance_m)}
    for key, baro in (("gnss", None), ("barometric", (survey.barometric_time_s, survey.barometric_h_m))):
        pts = georeference_scan(survey.scan, survey.trajectory_recorded, survey.mount_recorded, survey.frame,
                                barometric=baro)
        before = cloud_to_cloud(pts.xyz - o, ref - o, max_distance=MAX_DISTANCE_M, model="plane", k=8)
        reg = icp(pts.xyz - o, ref - o, max_correspondence_distance=1.0)
        after = cloud_to_cloud(apply_transform(reg.matrix, pts.xyz - o), ref - o, max_distance=MAX_DISTANCE_M, model="plane", k=8)
        out[key] = {"xyz": pts.xyz, "distance_m": after.distance_m, "stats": distance_statistics(after.distance_m),
                    "before_icp": distance_statistics(before.distance_m), "icp": reg}
    return out


def image_cloud_vs_tls(seed: int = 1, pairs_per_image: int = 3) -> dict[str, Any]:
    """skyrig's dense image cloud of the ``uav-bridge-camera`` flight (CI camera: GT3300C binned 4 x, the pillar
    pass along the south side, adjusted-level orientations) against its TLS reference: ICP, then C2C as for the
    laser.  The dense area is what a user has: the reference's structure (points 0.3 m above the lowest) plus
    3 m, cut back on the cameras' side and to the stretch the cameras pass (as ``bench/dense_acceptance.py``)."""
    from skyrig.dense.pairs import PairConfig
    from skyrig.dense.surface import DenseConfig, assemble, plan_dense, run_tile
    from skyrig.georef.eo import WorldFrame
    from skyrig.lidar.compare import cloud_to_cloud, distance_statistics
    from skyrig.lidar.register import apply_transform, icp
    from skyrig.simulate.bridge_camera import bridge_camera_spec, build_bridge_camera_survey

    sv = build_bridge_camera_survey(bridge_camera_spec("ci", seed))
    out = WorldFrame.map(sv.spec.crs)
    ref = out.from_ecef(sv.frame.to_ecef(sv.reference_xyz))
    eo = sv.eo_adjusted.to_frame(out)
    st = ref[ref[:, 2] > ref[:, 2].min() + 0.3]
    cam, m = eo.centre, 3.0
    x0, y0 = st[:, :2].min(axis=0) - m
    x1, y1 = st[:, :2].max(axis=0) + m
    if cam[:, 1].mean() < st[:, 1].mean():
        y0 = max(y0, cam[:, 1].max() + m)
    else:
        y1 = min(y1, cam[:, 1].min() - m)
    x0, x1 = max(x0, cam[:, 0].min() - m), min(x1, cam[:, 0].max() + m)
    area = (float(np.floor(x0)), float(np.floor(y0)), float(np.ceil(x1)), float(np.ceil(y1)))
    hr = (float(ref[:, 2].min() - 1.0), float(ref[:, 2].max() + 1.0))
    cache: dict[int, Any] = {}

    def load(i: int) -> Any:
        if i not in cache:
            cache[i] = sv.render(i)
        return cache[i]

    cfg = replace(DenseConfig(), pairs=replace(PairConfig(), pairs_per_image=pairs_per_image))
    plan = plan_dense(eo, {sv.camera.name: sv.camera}, out, hr, area, cfg)
    _, cloud, stats = assemble(plan, [run_tile(plan, k, load) for k in range(len(plan.tiles))])
    if cloud is None or len(cloud.xyz) == 0:
        raise ValueError("the dense image cloud of the bridge is empty")
    o = ref.mean(axis=0)
    xyz = np.asarray(cloud.xyz, dtype=np.float64) - o
    reg = icp(xyz, ref - o, max_correspondence_distance=0.5)
    after = cloud_to_cloud(apply_transform(reg.matrix, xyz), ref - o, max_distance=MAX_DISTANCE_M, model="plane", k=8)
    return {"distance_m": after.distance_m, "stats": distance_statistics(after.distance_m), "images": len(eo),
            "pairs": stats.pairs, "gsd_m": stats.gsd_m, "points": int(len(cloud.xyz))}


def _histogram(path: Path, res: dict[str, Any]) -> None:
    from skyrig.lidar.compare import histogram

    fig = new_figure(7.5, 4.0)
    ax = fig.add_subplot(111)
    top = float(np.nanpercentile(np.abs(np.concatenate([res[k]["distance_m"] for k in ("gnss", "barometric")])), 99.5))
    rng = (0.0, max(top, PAPER_LSRF[0] * 1.2))
    series = [("gnss", "#c0504d", "laser, GNSS heights"), ("barometric", "#335c99", "laser, barometric heights")]
    if "image" in res:
        series.append(("image", "#2a7a2a", "image (dense matching) cloud"))
    for key, colour, label in series:
        counts, edges = histogram(res[key]["distance_m"], bins=60, range_m=rng)
        st = res[key]["stats"]
        ax.stairs(100.0 * counts / max(counts.sum(), 1), edges, color=colour,
                  label=f"{label}: RMS {100 * st.rms_m:.1f} cm, 2/3 below {100 * st.p68_abs_m:.1f} cm")
        ax.axvline(st.p68_abs_m, color=colour, ls=":", lw=1)
    ax.axvline(PAPER_LSRF[1], color="k", ls="--", lw=1, label=f"paper 002: 2/3 below {100 * PAPER_LSRF[1]:.1f} cm "
                                                             f"(RMS {100 * PAPER_LSRF[0]:.1f} cm)")
    ax.set_xlabel("absolute cloud-to-cloud distance to the TLS reference after ICP (m)")
    ax.set_ylabel("points (%)")
    ax.legend(fontsize=8)
    write_png(fig, path)


def run(out_dir: Path, size: Size) -> PaperResult:
    from skyrig.simulate.lidar import build_lidar_survey

    out_dir = Path(out_dir)
    res = PaperResult("002", "ADFEX UAV laser scanner vs the TLS reference (Table 1, Fig. 6b)", size)
    survey = build_lidar_survey(scenario(size))
    r = laser_vs_tls(survey)
    if size == "full":
        r["image"] = image_cloud_vs_tls()
    g, b, t = r["gnss"]["stats"], r["barometric"]["stats"], r["truth"]["stats"]
    im = r["image"]["stats"] if "image" in r else None
    n_ref = len(survey.reference_xyz)
    res.tables.append(PaperTable(
        "table1", "Table 1: properties of the laser (LSRF) and image (SfM) point clouds against the TLS reference",
        ("property", "skyrig laser, GNSS heights", "skyrig laser, barometric heights", "skyrig image cloud",
         "paper LSRF", "paper SfM"),
        (("sensor", "Hokuyo UTM-30LX-EW (simulated)", "Hokuyo UTM-30LX-EW (simulated)",
          "Prosilica GT3300C (simulated)" if im else "not run at ci size", "Hokuyo UTM-30LX-EW", "Prosilica GT3300C"),
         ("RMS point accuracy (m)", round(g.rms_m, 4), round(b.rms_m, 4), _r4(im and im.rms_m), PAPER_LSRF[0],
          PAPER_SFM[0]),
         ("2/3 of the points below (m)", round(g.p68_abs_m, 4), round(b.p68_abs_m, 4), _r4(im and im.p68_abs_m),
          PAPER_LSRF[1], PAPER_SFM[1]),
         ("RMS before ICP (m)", round(r["gnss"]["before_icp"].rms_m, 4), round(r["barometric"]["before_icp"].rms_m, 4),
          None, None, None),
         ("points compared", g.count, b.count, im and im.count, "1 mil (bridge only)", "13 mil"),
         ("points without a reference point within 2 m", g.n_undefined, b.n_undefined, im and im.n_undefined, None,
          None)),
        caption=f"Scenario uav-bridge-lidar ({survey.spec.size} size, seed {survey.spec.seed}; {len(survey.scan)} returns, "
                f"TLS reference {n_ref} points).  C2C after ICP: distance to the plane of the 8 nearest reference "
                "points; RMS of the distances and their 68th percentile ('2/3 of all points').  "
                + (f"Image cloud: uav-bridge-camera pillar pass, {r['image']['images']} images, {r['image']['pairs']} "
                   f"pairs, GSD {100 * r['image']['gsd_m']:.1f} cm, against its own TLS reference." if im else
                   "The image cloud is run at --size full only (minutes).")))
    res.comparisons += [
        Comparison("laser cloud vs TLS: RMS (GNSS heights)", round(g.rms_m, 4), PAPER_LSRF[0], "m",
                   "the simulated GNSS/IMU errors are the scenario's (stated in skyrig.simulate.lidar), not the "
                   "ADFEX flight's; the paper corrected the yaw by aligning the pillars, here ICP absorbs any "
                   "constant heading error, and over a short pass (ci: 9 m) much of the slow GNSS wander too; "
                   f"before ICP the RMS is {r['gnss']['before_icp'].rms_m:.3f} m", None, "Sec. 4.2, Table 1"),
        Comparison("laser cloud vs TLS: 2/3 of the points below (GNSS heights)", round(g.p68_abs_m, 4), PAPER_LSRF[1],
                   "m", "as above", None, "Sec. 4.2"),
        Comparison("laser cloud vs TLS: RMS (barometric heights)", round(b.rms_m, 4), None, "m",
                   "the paper shows the barometric heights' gain in Fig. 7b without a figure for it", None, "Fig. 7b"),
        Comparison("image (SfM) cloud vs TLS: RMS", _r4(im.rms_m) if im else "not run at ci size (minutes)",
                   PAPER_SFM[0], "m", "skyrig's dense matching of the simulated bridge images (uav-bridge-camera: the "
                   "pillar pass, GT3300C binned 4 x, adjusted-level orientations) after ICP; run at --size full "
                   "only", None if im is None else bool(im.rms_m <= PAPER_SFM[0]), "Sec. 4.3, Table 1"),
    ]
    _histogram(out_dir / "fig6b_histogram.png", r)
    res.figures.append(Figure("fig6b", "Fig. 6b: histogram of the absolute distances to the TLS reference",
                              "fig6b_histogram.png", "Both laser clouds after ICP; dotted: their 2/3 marks; dashed: "
                              "the paper's."))
    res.checks.append(("the comparison's own floor: the true surface points lie on the reference (RMS < 2 cm)",
                       bool(t.rms_m < 0.02), f"RMS {100 * t.rms_m:.2f} cm over {t.count} points"))
    fit = min(r["gnss"]["icp"].fitness, r["barometric"]["icp"].fitness)
    res.checks.append(("ICP registered the laser clouds (90 % or more of their points within 1 m of the reference)",
                       bool(fit >= 0.9), f"fitness {r['gnss']['icp'].fitness:.3f} (GNSS heights), "
                       f"{r['barometric']['icp'].fitness:.3f} (barometric); RMS before -> after ICP: GNSS heights "
                       f"{100 * r['gnss']['before_icp'].rms_m:.1f} -> {100 * g.rms_m:.1f} cm, barometric "
                       f"{100 * r['barometric']['before_icp'].rms_m:.1f} -> {100 * b.rms_m:.1f} cm"))
    res.checks.append(("nearly every laser point has a reference point within 2 m (95 % or more)",
                       bool(min(g.count / (g.count + g.n_undefined), b.count / (b.count + b.n_undefined)) >= 0.95),
                       f"{g.count} of {g.count + g.n_undefined} (GNSS), {b.count} of {b.count + b.n_undefined} (barometric)"))
    if im is not None:
        res.checks.append(("the image cloud is closer to the TLS reference than the laser clouds (the paper's finding)",
                           bool(im.rms_m < min(g.rms_m, b.rms_m)),
                           f"image {100 * im.rms_m:.1f} cm ({r['image']['pairs']} pairs, {r['image']['points']} points), "
                           f"laser {100 * min(g.rms_m, b.rms_m):.1f} cm"))
    return res


def _r4(v: float | None) -> float | None:
    return None if v is None else round(float(v), 4)
