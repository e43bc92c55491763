"""The built-in demo: a small MIDAS penta-rig flight, georeferenced and checked end to end.

``build_demo_project`` writes the inputs a real survey would have (trajectory CSV with antenna positions,
camera events, rig file with lever arms and boresights, check points) into ``OUTDIR/input``.
``run_demo`` then runs the command-line stages on them exactly as a user would:

1. ``skyrig georef``           trajectory + events + rig -> exterior orientations (UTM 32N, omega-phi-kappa)
2. ``skyrig world-to-image``   check points -> image positions in every image that sees them
3. ``skyrig image-to-world``   those image positions -> forward intersection -> ground coordinates

and compares step 3 with the check points (a closed loop through every frame conversion) and step 1
with an independent composition of the same flight written out explicitly in this module.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skyrig.geodesy.crs import MapProjection
from skyrig.geometry.rotations import matrix_from_opk
from skyrig.rig.presets import midas
from skyrig.rig.rig import Rig, boresight_from_opk
from skyrig.trajectory.events import CameraEvents
from skyrig.trajectory.trajectory import Trajectory

CRS = "EPSG:25832"  # ETRS89 / UTM zone 32N
ORIGIN_EN = (550_000.0, 5_800_000.0)  # near Hannover
GROUND_H = 60.0  # ellipsoidal ground height (m)
FLYING_H = 600.0  # above ground (paper 004: 28 mm nadir at 600 m)


def demo_rig() -> Rig:
    """MIDAS with plausible lever arms, an antenna offset and small boresight misalignments."""
    base = midas()
    arms = {"nadir": (0.00, 0.00, 0.10), "forward": (0.12, 0.0, 0.12), "backward": (-0.12, 0.0, 0.12),
            "left": (0.0, -0.12, 0.12), "right": (0.0, 0.12, 0.12)}
    bores = {"nadir": (0.010, -0.020, 0.030), "forward": (-0.015, 0.012, -0.020), "backward": (0.020, 0.005, 0.010),
             "left": (0.004, -0.018, 0.025), "right": (-0.012, 0.009, -0.015)}
    heads = [h.with_(lever_arm_m=np.array(arms[n]), boresight=boresight_from_opk(*bores[n], unit="deg"))
             for n, h in base.heads.items()]
    return Rig("midas-demo", heads, antenna_lever_arm_m=np.array([0.05, 0.0, -1.30]),
               description="demo: MIDAS penta rig with invented lever arms and boresights")


def demo_flight(rate_hz: float = 50.0) -> tuple[Trajectory, CameraEvents]:
    """Two opposite strips, 8 exposures each, 5 heads: 80 images; trajectory of the GNSS antenna."""
    speed, spacing, strips = 60.0, 240.0, 2
    t_list, e_list, n_list, yaw_list = [], [], [], []
    ev_t, ev_head, ev_img, ev_exp = [], [], [], []
    t0 = 345_600.0
    exposure = 0
    for s in range(strips):
        north = s % 2 == 0
        length = 8 * spacing + 400.0
        tt = np.arange(0.0, length / speed, 1.0 / rate_hz)
        along = tt * speed - 200.0
        e = ORIGIN_EN[0] + s * 500.0 + 3.0 * np.sin(0.05 * tt)
        n = ORIGIN_EN[1] + (along if north else 8 * spacing - along)
        t_list.append(t0 + tt)
        e_list.append(e)
        n_list.append(n)
        yaw_list.append(np.full(len(tt), 0.0 if north else 180.0))
        for k in range(8):
            exposure += 1
            te = t0 + (200.0 + k * spacing) / speed + 0.0123
            for head in ("nadir", "forward", "backward", "left", "right"):
                ev_t.append(te)
                ev_head.append(head)
                ev_img.append(f"s{s + 1}_e{exposure:03d}_{head}.tif")
                ev_exp.append(exposure)
        t0 = t0 + tt[-1] + 60.0
    t = np.concatenate(t_list)
    proj = MapProjection(CRS)
    en = np.column_stack([np.concatenate(e_list), np.concatenate(n_list), np.full(len(t), GROUND_H + FLYING_H)])
    llh = proj.to_geodetic(en)
    conv, _ = proj.factors(en)
    rng = np.random.default_rng(2026)
    roll = 1.5 * np.sin(0.31 * t) + rng.normal(0, 0.002, len(t))
    pitch = 2.0 + 0.8 * np.sin(0.17 * t + 1.0)
    yaw = np.concatenate(yaw_list) + np.degrees(conv) + 2.0 * np.sin(0.07 * t)  # true heading along the grid lines
    traj = Trajectory.from_rpy(t, llh[:, 0], llh[:, 1], llh[:, 2], roll, pitch, yaw, unit="deg",
                               reference="antenna", time_system="gps-sow")
    events = CameraEvents.create(np.array(ev_t), np.array(ev_head), np.array(ev_img),
                                 exposure_id=np.array(ev_exp), time_system="gps-sow")
    return traj, events


def demo_check_points() -> np.ndarray:
    """A 5 x 9 grid of check points (E, N, h ellipsoidal) under the block, with some relief."""
    e, n = np.meshgrid(np.linspace(-300.0, 800.0, 5), np.linspace(-100.0, 2000.0, 9))
    e, n = e.ravel() + ORIGIN_EN[0], n.ravel() + ORIGIN_EN[1]
    h = GROUND_H + 15.0 * np.sin((e - ORIGIN_EN[0]) / 300.0) * np.cos((n - ORIGIN_EN[1]) / 500.0)
    return np.column_stack([e, n, h])


@dataclass(frozen=True)
class DemoPaths:
    trajectory: Path
    events: Path
    rig: Path
    check_points: Path
    eo: Path
    image_points: Path
    intersected: Path


def build_demo_project(outdir: str | Path) -> DemoPaths:
    """Write the demo inputs into ``outdir/input``; return the paths of inputs and (future) outputs."""
    from skyrig.georef.eo import WorldFrame
    from skyrig.georef.observations import GroundPoints
    from skyrig.io.events_csv import write_events_csv
    from skyrig.io.points_csv import write_points_csv
    from skyrig.io.rig_file import write_rig
    from skyrig.io.trajectory_csv import write_trajectory_csv

    out = Path(outdir)
    (out / "input").mkdir(parents=True, exist_ok=True)
    (out / "output").mkdir(parents=True, exist_ok=True)
    traj, events = demo_flight()
    p = DemoPaths(out / "input" / "trajectory.csv", out / "input" / "events.csv", out / "input" / "rig.yaml",
                  out / "input" / "check_points.csv", out / "output" / "eo.csv", out / "output" / "check_points_in_images.csv",
                  out / "output" / "check_points_intersected.csv")
    write_trajectory_csv(p.trajectory, traj, crs=CRS)
    write_events_csv(p.events, events)
    write_rig(demo_rig(), p.rig)
    cps = demo_check_points()
    write_points_csv(p.check_points, GroundPoints([f"CP{i:02d}" for i in range(len(cps))], cps, WorldFrame.map(CRS)))
    return p


def independent_eo(traj: Trajectory, events: CameraEvents, rig: Rig) -> tuple[np.ndarray, np.ndarray]:
    """Projection centres (UTM) and grid-axis omega-phi-kappa rotations of the demo images, composed here
    explicitly (closed-form WGS84 ECEF, explicit NED/ENU matrices, PROJ only for UTM <-> geodetic and the
    meridian convergence), independent of :mod:`skyrig.georef` and of :mod:`skyrig.rig.camera_pose` (it checks them)."""
    a, f = 6378137.0, 1 / 298.257223563
    e2 = f * (2 - f)

    def ecef(lat, lon, h):
        lat, lon = np.radians(lat), np.radians(lon)
        nn = a / np.sqrt(1 - e2 * np.sin(lat) ** 2)
        return np.column_stack([(nn + h) * np.cos(lat) * np.cos(lon), (nn + h) * np.cos(lat) * np.sin(lon),
                                (nn * (1 - e2) + h) * np.sin(lat)])

    def ecef_from_ned(lat, lon):
        lat, lon = np.radians(lat), np.radians(lon)
        sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
        n = np.stack([-sl * co, -sl * so, cl], -1)
        e = np.stack([-so, co, 0 * so], -1)
        d = np.stack([-cl * co, -cl * so, -sl], -1)
        return np.stack([n, e, d], axis=-1)

    # linear interpolation of the antenna position and of roll/pitch/yaw: adequate at 50 Hz for this check
    t = events.time_s
    rpy = traj.rpy("deg")
    lat = np.interp(t, traj.time_s, traj.lat_deg)
    lon = np.interp(t, traj.time_s, traj.lon_deg)
    h = np.interp(t, traj.time_s, traj.h_m)
    r, p, y = (np.radians(np.interp(t, traj.time_s, np.unwrap(np.radians(v)) * 180 / np.pi)) for v in rpy)
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    ned_from_body = np.stack([
        np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
        np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
        np.stack([-sp, cp * sr, cp * cr], -1)], axis=-2)
    ecef_from_body = ecef_from_ned(lat, lon) @ ned_from_body
    antenna = ecef(lat, lon, h)
    imu = antenna - ecef_from_body @ rig.antenna_lever_arm_m
    centres, rots = [], []
    for i, head in enumerate(events.head):
        hd = rig.heads[str(head)]
        centres.append(imu[i] + ecef_from_body[i] @ hd.lever_arm_m)
        rots.append(ecef_from_body[i] @ hd.mounting @ hd.boresight)
    import pyproj

    c = np.array(centres)
    lon_c, lat_c, h_c = pyproj.Transformer.from_crs(4978, 4979, always_xy=True).transform(c[:, 0], c[:, 1], c[:, 2])
    x, yy = pyproj.Transformer.from_crs(4326, CRS, always_xy=True).transform(lon_c, lat_c)
    conv = np.radians(pyproj.Proj(CRS).get_factors(lon_c, lat_c).meridian_convergence)
    enu_from_ned = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]])
    cc, sc = np.cos(conv), np.sin(conv)
    grid_from_enu = np.stack([np.stack([cc, -sc, 0 * cc], -1), np.stack([sc, cc, 0 * cc], -1),
                              np.stack([0 * cc, 0 * cc, 1 + 0 * cc], -1)], axis=-2)
    grid_from_cam = grid_from_enu @ enu_from_ned @ np.swapaxes(ecef_from_ned(lat_c, lon_c), -1, -2) @ np.array(rots)
    return np.column_stack([x, yy, h_c]), grid_from_cam


def rotation_angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle (degrees) of the rotations ``a^T b`` for stacks of rotation matrices."""
    # ||A - B||_F = 2 sqrt(2) sin(theta / 2): well conditioned for small angles, unlike arccos of the trace
    d = np.linalg.norm(np.asarray(a) - np.asarray(b), axis=(-2, -1))
    return np.degrees(2.0 * np.arcsin(np.clip(d / (2.0 * np.sqrt(2.0)), 0.0, 1.0)))


__all__ = ["build_demo_project", "demo_flight", "demo_rig", "demo_check_points", "independent_eo",
           "rotation_angle_deg", "matrix_from_opk"]


def tumble_circle_demo(outdir: str | Path, step_deg: float = 30.0, width: int = 400, seed: int = 5) -> dict:
    """Files for the demo's Fig. 9 check (paper 000): one circle of a tumbling camera from a still sensor head
    (the simulated TumbleCam, :mod:`skyrig.simulate.tumble_circle`), rendered at ``width`` pixels, the oblique
    orientations transferred from one noisy nadir orientation with a lab-calibrated boresight curve
    (``eo_curve.csv``) and without it (``eo_no_curve.csv``), the rig file of the rendered cameras, the images; plus
    the library's own mosaic of each with the seam offsets predicted from the orientation errors alone.

    Returns ``{"images", "rig", "eo": {"curve": path, "no_curve": path}, "plane_height_m", "predicted":
    {label: {(a, b): offset in metres}}, "cell_m": {label: m}}``.
    """
    import cv2

    from skyrig.io.eo_csv import write_eo_csv
    from skyrig.io.rig_file import write_rig
    from skyrig.simulate.scenarios import build_survey, scenario_spec
    from skyrig.simulate.tumble_circle import (calibrated_rig, circle_orientations, fig9, hover_circle,
                                               lab_calibrated_curve)

    out = Path(outdir)
    (out / "images").mkdir(parents=True, exist_ok=True)
    survey = build_survey(scenario_spec("tumblecam", "ci", 1))
    circ = hover_circle(survey, step_deg=step_deg, seed=seed, width=width)
    rig = calibrated_rig(survey.rig_recorded, lab_calibrated_curve(survey.tumble_curve, np.random.default_rng(seed)))
    res: dict = {"images": out / "images", "rig": out / "rig.yaml", "eo": {}, "predicted": {}, "cell_m": {},
                 "plane_height_m": circ.plane_height_m}
    for label, curve in (("curve", "rig"), ("no_curve", None)):
        eo = circle_orientations(circ, rig, curve)
        write_eo_csv(eo, out / f"eo_{label}.csv", unit="deg", convention="opk")
        res["eo"][label] = out / f"eo_{label}.csv"
        f = fig9(circ, rig, curve, window_px=48)
        res["predicted"][label] = {(s["a"], s["b"]): s["predicted_offset_px"] * f["cell_m"] for s in f["seams"]}
        res["cell_m"][label] = f["cell_m"]
    for name, img in zip(eo.image, circ.images):
        if not cv2.imwrite(str(out / "images" / str(name)), cv2.cvtColor(img, cv2.COLOR_RGB2BGR)):
            raise OSError(f"cannot write {out / 'images' / str(name)}")
    heads = {"oblique": rig.head("oblique").with_(camera=circ.camera),
             "nadir": rig.head("nadir").with_(camera=circ.nadir_camera)}
    from dataclasses import replace

    write_rig(replace(rig, heads=heads), out / "rig.yaml")
    return res
