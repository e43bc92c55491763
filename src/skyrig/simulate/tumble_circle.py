"""A tumbling camera's circle seen from a still sensor head: paper 000's laboratory set-up of Fig. 9, simulated.

The sensor head of a flight station is held still; the tumbling camera takes one full circle of oblique images at
actuator angles ``step_deg`` apart, and the nadir camera one image, all rendered with the TRUE rig
(:func:`hover_circle`).  The obliques' orientations are then transferred from one noisy nadir orientation through a
rig's mounting, with or without its boresight curve (:func:`circle_orientations`), and projected onto the plane of the
scene's mean terrain height (:func:`fig9`, :mod:`skyrig.dense.plane_mosaic`); :func:`predicted_shifts` gives the seam
offsets those orientation errors must cause, from geometry alone (no image), to judge the measured ones.

:func:`lab_calibrated_curve` is the curve paper 000's laboratory calibration would find (5 circles measured with the
repeatability of its Tab. 2, averaged); :func:`calibrated_rig` puts a curve on a rig's actuated heads.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

__all__ = ["TAB2_MEAN_2SIGMA_DEG", "Circle", "lab_calibrated_curve", "calibrated_rig", "hover_circle",
           "circle_orientations", "predicted_shifts", "fig9"]

#: paper 000 Tab. 2: mean repeatability (2 sigma) of roll, pitch, yaw over the 72 positions, degrees
TAB2_MEAN_2SIGMA_DEG = (8.6e-3, 7.8e-3, 35.9e-3)


# --------------------------------------------------------------------------------------------- calibration
def lab_calibrated_curve(true_curve: Any, rng: np.random.Generator, circles: int = 5,
                         sigma_deg: tuple[float, float, float] | None = None) -> Any:
    """The boresight curve as paper 000's laboratory calibration would find it: ``circles`` full circles at the true
    curve's positions, each position measured with 1-sigma noise ``sigma_deg`` (default: Tab. 2's mean / 2), averaged
    (:meth:`BoresightCurve.from_circles`)."""
    from skyrig.rig.boresight_curve import BoresightCurve

    sig = np.radians(np.asarray(sigma_deg if sigma_deg is not None else np.asarray(TAB2_MEAN_2SIGMA_DEG) / 2.0))
    meas = true_curve.corrections_rad[None] + rng.normal(0.0, 1.0, (circles, true_curve.beta_rad.size, 3)) * sig
    return BoresightCurve.from_circles(true_curve.beta_rad, meas)


def calibrated_rig(rig: Any, curve: Any) -> Any:
    """``rig`` with ``curve`` on its actuated head(s)."""
    return replace(rig, name=rig.name + "-calibrated",
                   heads={n: (h.with_(curve=curve) if h.is_actuated else h) for n, h in rig.heads.items()})


# --------------------------------------------------------------------------------------------- Fig. 9
@dataclass
class Circle:
    """One full circle of the tumbling camera from a still sensor head (the laboratory set-up of Fig. 9)."""

    images: list[np.ndarray]  # obliques in beta order, then the nadir image
    eo_true: Any  # ExteriorOrientations (local frame): obliques, then nadir
    nadir_eo: Any  # the nadir orientation (noisy) once per oblique exposure, images named like the events' nadir
    events: Any  # CameraEvents: per beta one nadir + one oblique exposure at the same time
    camera: Any  # the oblique camera the images were rendered with
    nadir_camera: Any
    plane_height_m: float
    station_xy: np.ndarray


def hover_circle(survey: Any, step_deg: float = 22.5, station: int = 0, seed: int = 7,
                 nadir_sigma: tuple[float, float] = (1e-4, 0.05), noise_dn: float = 1.0,
                 width: int | None = None) -> Circle:
    """Render one circle of the tumbling head (true rig) from the true body pose of flight station ``station``,
    held still, and a nadir orientation with adjustment-size errors (``nadir_sigma``: rad per axis, m per axis);
    ``width``: render with the cameras' field of view on a sensor this many pixels wide (faster, coarser)."""
    from skyrig.georef.eo import ExteriorOrientations
    from skyrig.geometry.pose import Pose
    from skyrig.geometry.rotations import matrix_from_rotvec
    from skyrig.rig.camera_pose import camera_poses
    from skyrig.simulate.render import render_image
    from skyrig.simulate.scenarios import ci_camera
    from skyrig.trajectory.events import CameraEvents

    rng = np.random.default_rng(seed)
    fb = survey.plan.frame_from_body()[station]
    pos = survey.plan.position[station]
    ob, nd = survey.rig_true.head("oblique"), survey.rig_true.head("nadir")
    betas = np.radians(np.arange(0.0, 360.0 - 1e-9, step_deg))
    k = betas.size
    # the oblique head at every beta and the nadir head, all from the one held body pose
    R, C, _ = camera_poses(survey.rig_true, np.r_[["oblique"] * k, ["nadir"]], np.r_[betas, [np.nan]],
                           np.broadcast_to(fb, (k + 1, 3, 3)), np.broadcast_to(pos, (k + 1, 3)))
    r_ob, c_ob, r_nd, c_nd = R[:k], C[:k], R[k], C[k]
    names = np.array([f"c{int(round(np.degrees(b) * 10)):04d}_oblique.png" for b in betas])
    nnames = np.array([n.replace("oblique", "nadir") for n in names])
    eo_true = ExteriorOrientations(np.r_[names, ["still_nadir.png"]], np.r_[[ob.camera.name] * k, [nd.camera.name]],
                                   np.r_[c_ob, c_nd[None]], np.r_[r_ob, r_nd[None]], survey.frame)
    r_adj = r_nd @ matrix_from_rotvec(rng.normal(0.0, nadir_sigma[0], 3))
    c_adj = c_nd + rng.normal(0.0, nadir_sigma[1], 3)
    nadir_eo = ExteriorOrientations(nnames, nd.camera.name, np.broadcast_to(c_adj, (k, 3)),
                                    np.broadcast_to(r_adj, (k, 3, 3)), survey.frame)
    t = 1000.0 + np.arange(k, dtype=np.float64)
    events = CameraEvents.create(np.r_[t, t], np.r_[["nadir"] * k, ["oblique"] * k], np.r_[nnames, names],
                                 np.r_[np.full(k, np.nan), betas], np.r_[np.arange(k), np.arange(k)])
    cam_o = ob.camera if width is None else ci_camera(ob.camera, width)
    cam_n = nd.camera if width is None else ci_camera(nd.camera, width)
    images = [render_image(survey.scene, cam_o, Pose(r_ob[i], c_ob[i], "world", "camera"), noise_dn=noise_dn,
                           seed=i) for i in range(k)]
    images.append(render_image(survey.scene, cam_n, Pose(r_nd, c_nd, "world", "camera"), noise_dn=noise_dn, seed=k))
    return Circle(images, eo_true, nadir_eo, events, cam_o, cam_n, float(survey.scene.base_height_m), pos[:2].copy())


def circle_orientations(circle: Circle, rig: Any, curve: Any) -> Any:
    """Obliques transferred from the circle's nadir orientation (``curve``: 'rig' or None), then the nadir image."""
    from skyrig.georef.eo import ExteriorOrientations
    from skyrig.georef.transfer import transfer_orientations

    tr = transfer_orientations(circle.nadir_eo, rig, circle.events, curve=curve)
    n = circle.nadir_eo
    return ExteriorOrientations(np.r_[tr.image, ["still_nadir.png"]], np.r_[tr.camera, n.camera[:1]],
                                np.r_[tr.centre, n.centre[:1]], np.r_[tr.rotation, n.rotation[:1]], tr.frame)


def predicted_shifts(mosaic: Any, seams: list[Any], eo_used: Any, eo_true: Any) -> list[np.ndarray]:
    """Seam shifts ``(d_col, d_row)`` predicted from the orientations alone at every correlation window.

    For a common projection centre C: the content that image *a* puts at plane point X lies along the true ray
    ``R_a,true R_a,used^T (X - C)``; image *b* puts it where its used orientation sends that true direction:
    ``C + R_b,used R_b,true^T R_a,true R_a,used^T (X - C)`` meets the plane.  Independent of the images and of the
    scene relief (valid only for images with one projection centre).
    """
    plane, grid = mosaic.grid.plane, mosaic.grid
    out = []
    for s in seams:
        a, b = s.a, s.b
        c = eo_used.centre[a]
        d_ab = eo_used.rotation[b] @ eo_true.rotation[b].T @ eo_true.rotation[a] @ eo_used.rotation[a].T
        x = plane.to_world(grid.uv(s.centres[:, 0], s.centres[:, 1]))
        rc2 = grid.cell_of(plane.intersect(c, (x - c) @ d_ab.T))
        out.append(np.c_[rc2[:, 1] - s.centres[:, 1], rc2[:, 0] - s.centres[:, 0]])
    return out


def fig9(circle: Circle, rig: Any, curve: Any, cell_m: float | None = None, window_px: int = 64) -> dict[str, Any]:
    """The circle mosaic and its seam offsets with orientations transferred with (``'rig'``) or without (None)
    the curve, or with the true orientations (``'truth'``)."""
    from skyrig.dense.plane_mosaic import Plane, plane_mosaic, seam_offsets

    eo = circle.eo_true if curve == "truth" else circle_orientations(circle, rig, curve)
    plane = Plane.horizontal(circle.plane_height_m, circle.station_xy)
    cams = {str(eo.camera[0]): circle.camera, str(eo.camera[-1]): circle.nadir_camera}
    t0 = time.perf_counter()
    m = plane_mosaic(circle.images, eo, cams, plane, cell_m=cell_m)
    t1 = time.perf_counter()
    seams = seam_offsets(m, window_px=window_px)
    t2 = time.perf_counter()
    pred = predicted_shifts(m, seams, eo, circle.eo_true)
    rows = []
    for s, p in zip(seams, pred):
        if not len(s.shift_px):
            continue
        rows.append({"a": str(m.images[s.a]), "b": str(m.images[s.b]), "windows": int(len(s.shift_px)),
                     "measured_px": s.median_shift_px.tolist(), "offset_px": s.offset_px,
                     "predicted_px": np.median(p, axis=0).tolist(),
                     "predicted_offset_px": float(np.linalg.norm(np.median(p, axis=0))),
                     "nadir_seam": bool("nadir" in str(m.images[s.a]) or "nadir" in str(m.images[s.b]))})
    off = np.array([r["offset_px"] for r in rows])
    return {"mosaic": m, "seams": rows, "cell_m": m.grid.cell_m, "shape": list(m.source.shape),
            "max_offset_px": float(off.max()) if off.size else float("nan"),
            "median_offset_px": float(np.median(off)) if off.size else float("nan"),
            "rms_offset_px": float(np.sqrt(np.mean(off ** 2))) if off.size else float("nan"),
            "mosaic_s": t1 - t0, "seams_s": t2 - t1}
