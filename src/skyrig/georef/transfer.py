"""Oblique orientations transferred from adjusted nadir orientations (paper 000, sections 3.3-3.4).

MACS-TumbleCam's oblique images overlap each other too little for an aerotriangulation of their own.  Paper 000
orients them without one: the nadir images are adjusted conventionally, and "the exterior orientation of any nadir
image [is transformed] to the corresponding oblique image" through the calibrated, actuator-dependent mounting of
the tumbling head (the nominal tumbling angles of eqs 1-3 plus the boresight corrections of Fig. 8 at the
exposure's actuator angle beta).  No oblique orientation is adjusted.

The chain, computed rigorously in ECEF and expressed in the nadir orientations' frame (or a given one)::

    ecef_from_body(t_n)  = ecef_from_nadir_camera(t_n) @ body_from_nadir_camera^T          (adjusted nadir EO)
    body_origin(t_n)     = nadir_centre(t_n) - ecef_from_body(t_n) @ lever_arm_nadir
    ecef_from_camera(t)  = ecef_from_body(t) @ body_from_camera_oblique(beta(t))             (rig, curve at beta)
    centre(t)            = body_origin(t) + ecef_from_body(t) @ lever_arm_oblique

Time offset between the nadir and the oblique exposure
------------------------------------------------------
The body pose at an oblique exposure time ``t`` comes from the adjusted nadir exposures around it:

* an adjusted nadir exposure at the same time (within ``simultaneous_s``): its body pose, exactly;
* otherwise, **without a trajectory**: the body poses of the two adjusted nadir exposures bracketing ``t``
  interpolated in time (positions linearly in ECEF, attitudes by slerp).  The bracketing exposures must be at
  most ``max_gap_s`` apart (no interpolation across a turn); outside the span of the adjusted exposures, the
  nearest one's pose is used only when it is within ``max_gap_s / 2`` of ``t`` *and* the time difference is
  covered by a trajectory -- without one such an image is an error.
* otherwise, **with a GNSS/IMU trajectory**: the trajectory gives the motion, the adjustment its correction.  At
  every adjusted nadir exposure the correction ``dR = R_adjusted R_traj^T`` (world side) and
  ``dp = p_adjusted - p_traj`` (ECEF) of the trajectory's body pose is formed; at ``t`` the corrections of the
  bracketing adjusted exposures are interpolated (linear / slerp) and applied to the trajectory's pose at ``t``:
  ``R(t) = dR(t) R_traj(t)``, ``p(t) = p_traj(t) + dp(t)``.  Before the first or after the last adjusted
  exposure of a strip (gap > ``max_gap_s``) the nearest exposure's correction is held, up to ``max_gap_s``.
  This keeps the aircraft's attitude changes between the exposures (which linear interpolation would miss).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from skyrig.errors import TransferError  # noqa: F401 - re-exported (defined in skyrig.errors)
from skyrig.georef.eo import ExteriorOrientations, WorldFrame
from skyrig.geometry.rotations import matrix_from_quaternion, quaternion_from_matrix, slerp
from skyrig.rig.boresight_curve import BoresightCurve
from skyrig.rig.camera_pose import body_origin_from_antenna, world_from_camera
from skyrig.rig.rig import ActuatedHead, Rig
from skyrig.trajectory.events import CameraEvents, check_events_in_span
from skyrig.trajectory.trajectory import Trajectory

log = logging.getLogger(__name__)

CurveChoice = BoresightCurve | Literal["rig"] | None

#: How each transferred image's body pose was found (``extra["transfer_method"]`` codes).
METHODS: tuple[str, ...] = ("simultaneous", "interpolated", "trajectory")


@dataclass(frozen=True)
class BodyPoses:
    """Platform (IMU body) poses at the adjusted reference exposures, in ECEF.

    Attributes
    ----------
    time_s
        ``(K,)`` exposure times (s, the events' time system), increasing.
    origin_ecef
        ``(K, 3)`` body origin (IMU origin of the rig file) in ECEF, metres.
    ecef_from_body
        ``(K, 3, 3)`` body attitude.
    image
        ``(K,)`` the reference images the poses come from.
    """

    time_s: NDArray[np.float64]
    origin_ecef: NDArray[np.float64]
    ecef_from_body: NDArray[np.float64]
    image: NDArray[np.str_]


def body_poses_from_reference(nadir_eo: ExteriorOrientations, rig: Rig, events: CameraEvents,
                              reference_head: str = "nadir") -> BodyPoses:
    """Body poses at the reference head's adjusted exposures (the rig's mounting of that head inverted).

    Parameters
    ----------
    nadir_eo
        Adjusted orientations; the rows whose images the events give to ``reference_head`` are used (other rows
        are passed over).
    rig
        The rig (its ``reference_head`` mounting, lever arm and boresight define the body from the camera).
    events
        Camera events: the time of every reference image.
    reference_head
        The fixed head whose adjusted orientations carry the platform (MACS-TumbleCam: ``"nadir"``).

    Raises
    ------
    TransferError
        If the reference head is actuated, or no adjusted orientation is an image of it in the events.
    """
    head = rig.head(reference_head)
    if head.is_actuated:
        raise TransferError(f"reference head {reference_head!r} is actuated: transfer needs a fixed head's orientations")
    ev_row = {str(n): k for k, n in enumerate(events.image_name)}
    rows, evk = [], []
    for i, name in enumerate(nadir_eo.image):
        k = ev_row.get(str(name))
        if k is not None and str(events.head[k]) == reference_head:
            rows.append(i)
            evk.append(k)
    if not rows:
        raise TransferError(
            f"none of the {len(nadir_eo)} adjusted orientations is an image of head {reference_head!r} in the events"
            + (f" ({events.source})" if events.source else "") + "; check --eo against --events and the head name")
    sub = nadir_eo.subset(np.asarray(rows)).to_frame(WorldFrame.ecef())
    t = events.time_s[np.asarray(evk)]
    order = np.argsort(t, kind="stable")
    t, rows_o = t[order], order
    if np.any(np.diff(t) <= 0):
        k = int(np.flatnonzero(np.diff(t) <= 0)[0])
        raise TransferError(f"two adjusted {reference_head} images share the exposure time {float(t[k])!r}: "
                            f"{str(sub.image[rows_o[k]])!r} and {str(sub.image[rows_o[k + 1]])!r}")
    bc = head.body_from_camera()
    ecef_from_body = sub.rotation[rows_o] @ bc.rotation.T
    origin = sub.centre[rows_o] - ecef_from_body @ bc.translation
    return BodyPoses(t, origin, ecef_from_body, sub.image[rows_o])


def _bracket(times: NDArray[np.float64], t: NDArray[np.float64]) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """Interval index ``i`` (``times[i] <= t <= times[i+1]``, clipped) and fraction ``u`` (unclipped)."""
    if times.size == 1:
        return np.zeros(t.size, np.intp), np.zeros(t.size)
    i = np.clip(np.searchsorted(times, t, side="right") - 1, 0, times.size - 2)
    u = (t - times[i]) / (times[i + 1] - times[i])
    return i, u


def _interpolate_poses(p: BodyPoses, t: NDArray[np.float64], i: NDArray[np.intp], u: NDArray[np.float64],
                       origin: NDArray[np.float64], rot: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
    j = np.minimum(i + 1, len(p.time_s) - 1)
    uu = np.clip(u, 0.0, 1.0)
    o = origin[i] + uu[:, None] * (origin[j] - origin[i])
    q = slerp(quaternion_from_matrix(rot[i]), quaternion_from_matrix(rot[j]), uu)
    return o, matrix_from_quaternion(q)


def transfer_orientations(
    nadir_eo: ExteriorOrientations,
    rig: Rig,
    events: CameraEvents,
    *,
    curve: CurveChoice = "rig",
    trajectory: Trajectory | None = None,
    reference_head: str = "nadir",
    heads: list[str] | None = None,
    frame: WorldFrame | None = None,
    simultaneous_s: float = 1e-4,
    max_gap_s: float = 3.0,
) -> ExteriorOrientations:
    """Orientations of the actuated heads' images from the adjusted reference (nadir) orientations.

    Parameters
    ----------
    nadir_eo
        Adjusted orientations of the reference head's images (any frame; e.g. ``skyrig adjust``'s ``eo.csv``).
    rig
        The calibrated rig: reference head mounting, tumbling head (gamma, law, head mounting, constant
        boresight, lever arm) and, in the rig's tumbling head, the boresight correction curve.
    events
        Camera events of both heads: image names, times, heads and actuator angles beta.
    curve
        ``"rig"`` (default): the tumbling head's own curve from the rig file (none if it has none);
        ``None``: no beta-dependent correction (the nominal tumbling angles only); a
        :class:`~skyrig.rig.boresight_curve.BoresightCurve`: that curve instead of the rig's.
    trajectory
        GNSS/IMU trajectory for the motion between a nadir and a non-simultaneous oblique exposure (see the
        module docstring); without it the body pose is interpolated between adjusted exposures.
    reference_head
        The fixed head whose orientations were adjusted.
    heads
        Heads to transfer to (default: every actuated head of the rig that has events).
    frame
        Output frame (default: ``nadir_eo.frame``).
    simultaneous_s
        Exposures closer in time than this (s) count as simultaneous.
    max_gap_s
        Largest time between two adjusted exposures to interpolate across, and twice the largest distance in time
        from the nearest adjusted exposure outside their span (s).

    Returns
    -------
    ExteriorOrientations
        One row per transferred image in the events' order, with ``time_s``, ``head``, ``exposure`` and
        ``extra``: ``beta_rad``, ``transfer_dt_s`` (time to the nearest adjusted reference exposure, s),
        ``transfer_method`` (index into :data:`METHODS`).

    Raises
    ------
    TransferError
        An image has no adjusted reference exposure near enough in time (names the image and the gap), or the
        inputs do not fit together.
    EventOutOfSpanError
        With a trajectory: an event outside its span.
    """
    if frame is None:
        frame = nadir_eo.frame
    poses = body_poses_from_reference(nadir_eo, rig, events, reference_head)
    if heads is None:
        heads = [n for n, h in rig.heads.items() if h.is_actuated and np.any(events.head == n)]
    if not heads:
        raise TransferError("no event belongs to an actuated head of the rig (heads: "
                            f"{', '.join(f'{n} (actuated)' if h.is_actuated else n for n, h in rig.heads.items())}; "
                            f"event heads: {', '.join(events.heads)})")
    sel = np.isin(events.head, np.asarray(heads, dtype=str))
    if not np.any(sel):
        raise TransferError(f"no events of head(s) {', '.join(heads)}")
    ev = events.subset(np.flatnonzero(sel))
    t = ev.time_s
    n = len(ev)
    # ---- body pose at each event time
    i, u = _bracket(poses.time_s, t)
    j = np.minimum(i + 1, len(poses.time_s) - 1)
    dt_i, dt_j = np.abs(t - poses.time_s[i]), np.abs(t - poses.time_s[j])
    nearest = np.where(dt_i <= dt_j, i, j)
    dt_near = np.minimum(dt_i, dt_j)
    inside = (u >= 0.0) & (u <= 1.0) & (poses.time_s.size > 1)
    gap = np.where(inside, poses.time_s[j] - poses.time_s[i], np.inf)
    simult = dt_near <= simultaneous_s
    interp_ok = inside & (gap <= max_gap_s)
    hold_ok = dt_near <= 0.5 * max_gap_s
    method = np.full(n, -1, np.int64)
    method[simult] = 0
    if trajectory is None:
        method[~simult & interp_ok] = 1
    else:
        method[~simult & (interp_ok | hold_ok)] = 2
    bad = method < 0
    if np.any(bad):
        k = int(np.flatnonzero(bad)[0])
        line = None if ev.source_line is None else int(ev.source_line[k])
        where = f" ({ev.source}, line {line})" if ev.source else ""
        how = ("no trajectory is given to carry the pose over" if trajectory is None
               else f"the nearest is {dt_near[k]:.3f} s away (> {0.5 * max_gap_s:g} s)")
        raise TransferError(
            f"image {str(ev.image_name[k])!r} at time {float(t[k])!r}{where}: no adjusted {reference_head} exposure at that time "
            f"and none bracketing it within {max_gap_s:g} s ({how}); {int(bad.sum())} image(s) like it")
    origin = np.empty((n, 3))
    rot = np.empty((n, 3, 3))
    m0 = method == 0
    origin[m0], rot[m0] = poses.origin_ecef[nearest[m0]], poses.ecef_from_body[nearest[m0]]
    m1 = method == 1
    if np.any(m1):
        origin[m1], rot[m1] = _interpolate_poses(poses, t[m1], i[m1], u[m1], poses.origin_ecef, poses.ecef_from_body)
    m2 = method == 2
    if np.any(m2):
        origin[m2], rot[m2] = _trajectory_carried(poses, trajectory, rig,  # type: ignore[arg-type]
                                                  ev.subset(np.flatnonzero(m2)),
                                                  i[m2], u[m2], nearest[m2], interp_ok[m2])
    # ---- the tumbling head's mounting at beta
    rot_cam = np.empty((n, 3, 3))
    lever = np.empty((n, 3))
    cams = np.empty(n, dtype=object)
    for name in np.unique(ev.head):
        hs = ev.head == name
        h = rig.head(str(name))
        if isinstance(h, ActuatedHead):
            if curve is None:
                h = h.with_(curve=None)
            elif isinstance(curve, BoresightCurve):
                h = h.with_(curve=curve)
            elif curve != "rig":
                raise TransferError(f"curve must be 'rig', None or a BoresightCurve, not {curve!r}")
            b = ev.beta_rad[hs]
            if not np.all(np.isfinite(b)):
                k = int(np.flatnonzero(hs)[np.flatnonzero(~np.isfinite(b))[0]])
                line = None if ev.source_line is None else int(ev.source_line[k])
                raise TransferError(f"image {str(ev.image_name[k])!r} of actuated head {name!r} has no actuator angle beta"
                                    + (f" ({ev.source}, line {line}, field beta)" if ev.source else ""))
            pose = h.body_from_camera(b)
        else:
            pose = h.body_from_camera(np.zeros(int(hs.sum())))
        rot_cam[hs] = pose.rotation
        lever[hs] = pose.translation
        cams[hs] = h.camera.name
    ecef_from_camera, centre = world_from_camera(rot, origin, rot_cam, lever)
    out = ExteriorOrientations(
        ev.image_name, cams.astype(str), centre, ecef_from_camera, WorldFrame.ecef(), time_s=t, head=ev.head,
        exposure=ev.exposure_id,
        extra={"beta_rad": np.asarray(ev.beta_rad, dtype=np.float64), "transfer_dt_s": dt_near,
               "transfer_method": method})
    counts = {METHODS[k]: int(np.sum(method == k)) for k in range(len(METHODS)) if np.any(method == k)}
    log.info("transferred %d orientations from %d adjusted %s exposures (%s; curve: %s)", n, len(poses.time_s),
             reference_head, ", ".join(f"{v} {k}" for k, v in counts.items()),
             "none" if curve is None else ("given" if isinstance(curve, BoresightCurve) else "rig's"))
    return out.to_frame(frame)


def _trajectory_carried(poses: BodyPoses, trajectory: Trajectory, rig: Rig, ev: CameraEvents, i: NDArray[np.intp],
                        u: NDArray[np.float64], nearest: NDArray[np.intp], interp: NDArray[np.bool_]
                        ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Trajectory poses at ``ev`` corrected by the adjusted poses (correction interpolated or held)."""
    check_events_in_span(ev, trajectory)
    ref_t = poses.time_s
    need = np.unique(np.concatenate([i[interp], np.minimum(i[interp] + 1, ref_t.size - 1), nearest[~interp]]))
    ref_ev = CameraEvents.create(ref_t[need], np.full(need.size, "ref"), poses.image[need], np.full(need.size, np.nan),
                                 np.arange(need.size), time_system=ev.time_system)
    check_events_in_span(ref_ev, trajectory)

    def body(times: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
        s = trajectory.interpolate(times)
        r = s.ecef_from_body
        o = s.ecef
        if s.reference == "antenna":
            o = body_origin_from_antenna(r, o, rig.antenna_lever_arm_m)
        return o, r

    o_ref, r_ref = body(ref_t[need])
    d_o = np.zeros((ref_t.size, 3))
    d_r = np.broadcast_to(np.eye(3), (ref_t.size, 3, 3)).copy()
    d_o[need] = poses.origin_ecef[need] - o_ref
    d_r[need] = poses.ecef_from_body[need] @ np.swapaxes(r_ref, -1, -2)
    o_t, r_t = body(ev.time_s)
    corr_o = np.empty_like(o_t)
    corr_r = np.empty_like(r_t)
    if np.any(interp):
        dummy = BodyPoses(ref_t, d_o, d_r, poses.image)
        corr_o[interp], corr_r[interp] = _interpolate_poses(dummy, ev.time_s[interp], i[interp], u[interp], d_o, d_r)
    corr_o[~interp], corr_r[~interp] = d_o[nearest[~interp]], d_r[nearest[~interp]]
    return o_t + corr_o, corr_r @ r_t


def orientation_differences(eo: ExteriorOrientations, reference: ExteriorOrientations
                            ) -> dict[str, NDArray[np.float64]]:
    """Per-image differences of ``eo`` from ``reference`` (matched by image name), in a local ENU frame.

    Returns
    -------
    dict
        ``image (M,)``; ``centre_m (M, 3)`` ENU differences (m) in ``reference``'s frame converted to a local
        frame at the first image; ``angle_rad (M,)`` rotation angle of ``R_ref^T R``; ``axis_rad (M, 3)`` the
        rotation vector of ``R_ref^T R`` in the *camera* frame (x right, y up, z back), radians.
    """
    from skyrig.geometry.rotations import rotvec_from_matrix

    idx = reference.index()
    missing = [str(n) for n in eo.image if str(n) not in idx]
    if missing:
        raise TransferError(f"{len(missing)} image(s) have no reference orientation, e.g. {missing[0]!r}")
    rows = np.array([idx[str(n)] for n in eo.image])
    ref = reference.subset(rows)
    ecef = WorldFrame.ecef()
    e_ecef, r_ecef = eo.to_frame(ecef), ref.to_frame(ecef)
    local = WorldFrame.local(*_geodetic_deg(r_ecef.centre[0]))
    e_l, r_l = e_ecef.to_frame(local), r_ecef.to_frame(local)
    d = np.swapaxes(r_l.rotation, -1, -2) @ e_l.rotation
    rv = rotvec_from_matrix(d)
    return {"image": eo.image.copy(), "centre_m": e_l.centre - r_l.centre,
            "angle_rad": np.linalg.norm(rv, axis=1), "axis_rad": rv}


def _geodetic_deg(ecef: NDArray[np.float64]) -> tuple[float, float, float]:
    from skyrig.geodesy.crs import ecef_to_geodetic

    lat, lon, h = ecef_to_geodetic(ecef.reshape(1, 3))
    return float(np.ravel(lat)[0]), float(np.ravel(lon)[0]), float(np.ravel(h)[0])


def with_transferred(nadir_eo: ExteriorOrientations, transferred: ExteriorOrientations) -> ExteriorOrientations:
    """The reference orientations and the transferred ones in one set (transferred frame; extra columns dropped)."""
    a = replace(nadir_eo.to_frame(transferred.frame), extra={})
    b = replace(transferred, extra={})

    def cat(x, y):  # type: ignore[no-untyped-def]
        return None if x is None or y is None else np.concatenate([x, y])

    return ExteriorOrientations(np.concatenate([a.image, b.image]), np.concatenate([a.camera, b.camera]),
                                np.concatenate([a.centre, b.centre]), np.concatenate([a.rotation, b.rotation]),
                                b.frame, time_s=cat(a.time_s, b.time_s), head=cat(a.head, b.head),
                                exposure=cat(a.exposure, b.exposure))
