"""Flight planning for multi-head rigs: strips, exposure stations, footprints, GSD, overlaps, coverage.

Planning frame: any Cartesian frame with x east, y north, z up (the grid of a projected CRS, or the
local ENU frame of a simulation).  Directions are **azimuths clockwise from the frame's y axis**
(grid north), in degrees in the public API.  The platform attitude at a station is level flight with
heading ``track + crab``::

    frame_from_body = ENU_FROM_NED @ matrix_from_rpy(roll, pitch, heading)

and a head's exterior orientation is ``frame_from_camera = frame_from_body @ body_from_camera(beta)``
with the projection centre ``position + frame_from_body @ lever_arm`` (the same chain as
:func:`skyrig.georef.direct_georeference`, here without earth curvature: planning accuracy).

Tumbling heads (paper 000): :func:`tumble_schedule` gives the actuator angle of every frame from the
rotation speed and the frame rate, with the crab angle compensated by shifting the motor's zero point
(``beta_cmd = beta_nominal + crab``: the views keep their azimuths relative to the *track*).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.camera.frame import footprint_on_plane, footprint_on_surface
from skyrig.errors import GeometryError, SkyrigError
from skyrig.geometry.pose import Pose
from skyrig.geometry.rotations import ENU_FROM_NED, matrix_from_rpy
from skyrig.rig.camera_pose import world_from_camera
from skyrig.rig.rig import Head, Rig

_DEG = np.pi / 180.0


def frame_from_body_rotation(heading_rad: ArrayLike, roll_rad: ArrayLike = 0.0, pitch_rad: ArrayLike = 0.0) -> NDArray[np.float64]:
    """``(..., 3, 3)`` body attitude in an ENU-like planning frame from heading (clockwise from y), roll, pitch."""
    return ENU_FROM_NED @ matrix_from_rpy(roll_rad, pitch_rad, heading_rad, unit="rad")


def reference_head(rig: Rig) -> Head:
    """The fixed head looking closest to straight down (the one strips and bases are planned for)."""
    best, score = None, -2.0
    for h in rig:
        if h.is_actuated:
            continue
        s = float(-(h.optical_axis() @ np.array([0.0, 0.0, -1.0])))  # body z is down
        s = float(h.optical_axis()[2])
        if s > score:
            best, score = h, s
    if best is None:
        best = next(iter(rig))
    return best


def tumble_schedule(n: int, frame_rate_hz: float, rotation_speed_deg_s: float, beta0_deg: float = 0.0,
                    crab_deg: float = 0.0) -> NDArray[np.float64]:
    """Actuator angles ``(n,)`` in radians of a tumbling camera's frames (paper 000, section 3.2).

    ``beta_i = beta0 + crab + i * rotation_speed / frame_rate``; the step per frame (the "gear step",
    45 deg in paper 000 Fig. 5) is ``rotation_speed / frame_rate``.  Adding the crab angle to the zero
    point keeps every view's azimuth fixed relative to the track while the aircraft flies crabbed.
    """
    if frame_rate_hz <= 0:
        raise SkyrigError("tumble schedule: frame rate must be positive")
    step = rotation_speed_deg_s / frame_rate_hz
    return (beta0_deg + crab_deg + step * np.arange(int(n))) * _DEG


@dataclass(frozen=True)
class FlightPlan:
    """Exposure stations of a planned flight (``M`` stations, ``S`` strips).

    Attributes
    ----------
    time_s
        ``(M,)`` exposure times (seconds from the plan's start).
    position
        ``(M, 3)`` platform (IMU origin) positions in the planning frame, metres.
    heading_rad
        ``(M,)`` platform heading, clockwise from the frame's y axis (track + crab).
    track_rad
        ``(M,)`` direction of flight.
    strip
        ``(M,)`` strip index (0-based).
    beta_rad
        ``(M,)`` actuator angle for tumbling heads (NaN when the rig has none).
    strip_lines
        ``(S, 2, 3)`` start and end of each strip line.
    flying_height_m
        Height above ``ground_height_m``.
    ground_height_m
        Mean ground height used for planning.
    base_m, spacing_m
        Distance between stations along a strip, and between strips.
    speed_mps
        Ground speed.
    reference_head
        Name of the head the overlaps were planned for.
    """

    time_s: NDArray[np.float64]
    position: NDArray[np.float64]
    heading_rad: NDArray[np.float64]
    track_rad: NDArray[np.float64]
    strip: NDArray[np.int64]
    beta_rad: NDArray[np.float64]
    strip_lines: NDArray[np.float64]
    flying_height_m: float
    ground_height_m: float
    base_m: float
    spacing_m: float
    speed_mps: float
    reference_head: str
    roll_rad: NDArray[np.float64] | None = None
    pitch_rad: NDArray[np.float64] | None = None

    def __len__(self) -> int:
        return int(self.time_s.shape[0])

    def frame_from_body(self) -> NDArray[np.float64]:
        """``(M, 3, 3)`` platform attitudes in the planning frame."""
        r = np.zeros(len(self)) if self.roll_rad is None else self.roll_rad
        p = np.zeros(len(self)) if self.pitch_rad is None else self.pitch_rad
        return frame_from_body_rotation(self.heading_rad, r, p)

    def camera_poses(self, rig: Rig, head: str) -> Pose:
        """Batched ``frame_from_camera`` poses ``(M)`` of one head at every station."""
        h = rig.head(head)
        fb = self.frame_from_body()
        bc = h.body_from_camera(self.beta_rad if h.is_actuated else np.full(len(self), np.nan))
        R, C = world_from_camera(fb, self.position, bc.rotation, bc.translation)
        return Pose(R, C, "world", h.frame)


def head_footprint_extent(rig: Rig, head: str, flying_height_m: float) -> tuple[float, float]:
    """Along- and across-track extent (m) of a head's footprint on flat ground, level flight."""
    plan = _single_station(flying_height_m)
    fp = footprint_on_plane(rig.head(head).camera, plan.camera_poses(rig, head), 0.0)[0] if False else None
    pose = plan.camera_poses(rig, head)
    cam = rig.head(head).camera
    pts = footprint_on_plane(cam, Pose(pose.rotation[0], pose.translation[0], "world", "camera"), 0.0)
    return float(np.ptp(pts[:, 1])), float(np.ptp(pts[:, 0]))


def _single_station(h: float) -> FlightPlan:
    z = np.zeros(1)
    return FlightPlan(z, np.array([[0.0, 0.0, h]]), z, z, np.zeros(1, np.int64), np.zeros(1),
                      np.zeros((1, 2, 3)), h, 0.0, 0.0, 0.0, 1.0, "")


def plan_flight(
    rig: Rig,
    area_xy: ArrayLike,
    *,
    flying_height_m: float | None = None,
    gsd_m: float | None = None,
    ground_height_m: float = 0.0,
    forward_overlap: float = 0.6,
    side_overlap: float = 0.3,
    direction_deg: float = 0.0,
    speed_mps: float = 60.0,
    crab_deg: float = 0.0,
    frame_rate_hz: float | None = None,
    rotation_speed_deg_s: float = 0.0,
    beta0_deg: float = 0.0,
    swath: str = "reference",
    head: str | None = None,
    turn_time_s: float = 60.0,
    n_strips: int | None = None,
    run_in_bases: float = 1.0,
) -> FlightPlan:
    """Plan parallel strips with alternating directions over a polygon.

    Parameters
    ----------
    rig
        The camera rig.
    area_xy
        ``(V, 2)`` polygon vertices in the planning frame (metres).
    flying_height_m, gsd_m
        Height above ground, or the nadir GSD of the reference head it is derived from (exactly one).
    ground_height_m
        Mean ground height (same vertical datum as the planned positions).
    forward_overlap, side_overlap
        Fractions in [0, 1).
    direction_deg
        Azimuth of the strips (clockwise from north/y); odd strips fly the opposite way.
    speed_mps
        Ground speed.
    crab_deg
        Crab angle: heading = track + crab (the tumbling head's zero point compensates it).
    frame_rate_hz
        If given, stations follow this frame rate (``base = speed / rate``) instead of the forward overlap.
    rotation_speed_deg_s, beta0_deg
        Tumbling head: see :func:`tumble_schedule`.
    swath
        ``"reference"``: side overlap of the reference head's footprints; ``"all"``: of the union of all
        fixed heads' footprints (oblique rigs flown for their whole swath).
    head
        Reference head (default :func:`reference_head`).
    turn_time_s
        Time between the end of a strip and the start of the next.
    n_strips
        Force a number of strips (default: enough to cover the polygon).
    run_in_bases
        Stations added before and after the polygon on every strip, in bases.
    """
    poly = np.asarray(area_xy, dtype=np.float64).reshape(-1, 2)
    if poly.shape[0] < 3:
        raise GeometryError("the planning area needs at least 3 vertices")
    if (flying_height_m is None) == (gsd_m is None):
        raise SkyrigError("give exactly one of flying_height_m and gsd_m")
    if not (0 <= forward_overlap < 1 and 0 <= side_overlap < 1):
        raise SkyrigError("overlaps must be fractions in [0, 1)")
    ref = rig.head(head) if head else reference_head(rig)
    if flying_height_m is None:
        flying_height_m = float(gsd_m) * ref.camera.focal_mm / ref.camera.pixel_size_mm
    H = float(flying_height_m)
    along_len, across_len = head_footprint_extent(rig, ref.name, H)
    if swath == "all":
        xs = []
        plan1 = _single_station(H)
        for h in rig:
            if h.is_actuated:
                continue
            pose = plan1.camera_poses(rig, h.name)
            try:
                pts = footprint_on_plane(h.camera, Pose(pose.rotation[0], pose.translation[0], "world", "c"), 0.0)
            except GeometryError:
                continue
            xs.append(pts[:, 0])
        across_len = float(np.ptp(np.concatenate(xs)))
    elif swath != "reference":
        raise SkyrigError(f"swath must be 'reference' or 'all', not {swath!r}")
    base = speed_mps / frame_rate_hz if frame_rate_hz else (1.0 - forward_overlap) * along_len
    spacing = (1.0 - side_overlap) * across_len
    a = direction_deg * _DEG
    u_al = np.array([np.sin(a), np.cos(a)])  # along-track unit vector (azimuth a)
    u_ac = np.array([np.cos(a), -np.sin(a)])  # across, to the right
    s_al, s_ac = poly @ u_al, poly @ u_ac
    width = float(s_ac.max() - s_ac.min())
    ns = n_strips if n_strips else max(1, int(np.ceil(max(width - across_len * 0.0, 0.0) / spacing)) + (0 if width <= 0 else 0))
    if not n_strips:
        ns = max(1, int(np.ceil(width / spacing)))
    centre_ac = 0.5 * (s_ac.max() + s_ac.min())
    offs = centre_ac + (np.arange(ns) - (ns - 1) / 2.0) * spacing
    lo, hi = float(s_al.min()) - run_in_bases * base, float(s_al.max()) + run_in_bases * base
    n_st = int(np.floor((hi - lo) / base + 1e-9)) + 1
    along = lo + base * np.arange(n_st)
    t_list, p_list, hd_list, tr_list, st_list, lines = [], [], [], [], [], []
    t0 = 0.0
    z = ground_height_m + H
    for s, off in enumerate(offs):
        fwd = s % 2 == 0
        al = along if fwd else along[::-1]
        xy = off * u_ac[None, :] + al[:, None] * u_al[None, :]
        track = a if fwd else a + np.pi
        tt = t0 + np.arange(n_st) * base / speed_mps
        t_list.append(tt)
        p_list.append(np.column_stack([xy, np.full(n_st, z)]))
        tr_list.append(np.full(n_st, track))
        hd_list.append(np.full(n_st, track + crab_deg * _DEG))
        st_list.append(np.full(n_st, s))
        lines.append([[*xy[0], z], [*xy[-1], z]])
        t0 = tt[-1] + turn_time_s
    t = np.concatenate(t_list)
    if any(h.is_actuated for h in rig):
        beta = tumble_schedule(len(t), frame_rate_hz or (speed_mps / base), rotation_speed_deg_s, beta0_deg, crab_deg)
    else:
        beta = np.full(len(t), np.nan)
    wrap = lambda v: np.mod(v, 2 * np.pi)  # noqa: E731
    return FlightPlan(t, np.concatenate(p_list), wrap(np.concatenate(hd_list)), wrap(np.concatenate(tr_list)),
                      np.concatenate(st_list).astype(np.int64), beta, np.array(lines), H, float(ground_height_m),
                      float(base), float(spacing), float(speed_mps), ref.name)


def footprints(plan: FlightPlan, rig: Rig, head: str, height=None) -> NDArray[np.float64]:
    """Ground footprints ``(M, 4, 3)`` (image corners TL, TR, BR, BL) of one head at every station.

    ``height``: None (the plan's mean ground height), a number (a plane), or a vectorised surface
    ``height(x, y)`` (a DEM's :meth:`~skyrig.georef.Dem.sample`, a scene's surface); NaN rows where a
    corner ray misses the ground (above the horizon).
    """
    h = rig.head(head)
    poses = plan.camera_poses(rig, head)
    out = np.full((len(plan), 4, 3), np.nan)
    for i in range(len(plan)):
        pose = Pose(poses.rotation[i], poses.translation[i], "world", h.frame)
        try:
            if height is None or np.isscalar(height):
                out[i] = footprint_on_plane(h.camera, pose, plan.ground_height_m if height is None else float(height))
            else:
                out[i] = footprint_on_surface(h.camera, pose, height)
        except GeometryError:
            pass
    return out


@dataclass(frozen=True)
class HeadGsd:
    """GSD of one head (metres, mean of column and row steps) per station: at the image centre, and the
    smallest (near) and largest (far) over the four edge midpoints (for a level nadir head all near the centre)."""

    head: str
    centre_m: NDArray[np.float64]
    near_m: NDArray[np.float64]
    far_m: NDArray[np.float64]


def gsd_per_head(plan: FlightPlan, rig: Rig, head: str, ground_height_m: float | None = None) -> HeadGsd:
    """GSD of a head on the plane ``z = ground_height_m`` at every station (see :class:`HeadGsd`)."""
    h = rig.head(head)
    cam = h.camera
    gh = plan.ground_height_m if ground_height_m is None else ground_height_m
    poses = plan.camera_poses(rig, head)
    cx, cy = (cam.width - 1) / 2.0, (cam.height - 1) / 2.0
    res = []
    for px in ([cx, cy], [cx, cam.height - 1.0], [cx, 0.0], [0.0, cy], [cam.width - 1.0, cy]):
        vals = np.full(len(plan), np.nan)
        for i in range(len(plan)):
            try:
                g = cam.gsd_at(Pose(poses.rotation[i], poses.translation[i], "world", "c"), gh, np.array(px))
                vals[i] = float(g.mean_m)
            except GeometryError:
                pass
        res.append(vals)
    edges = np.array(res[1:])
    near, far = np.nanmin(edges, axis=0), np.nanmax(edges, axis=0)
    return HeadGsd(head, res[0], near, far)


def _polys(fp: NDArray[np.float64]):
    import shapely

    ok = np.all(np.isfinite(fp[:, :, :2]), axis=(1, 2))
    polys = np.array([shapely.Polygon(f[:, :2]) if o else None for f, o in zip(fp, ok)], dtype=object)
    return polys, ok


@dataclass(frozen=True)
class OverlapStats:
    """Overlap statistics of one head (fractions of a footprint's area).

    Attributes
    ----------
    forward
        ``(M,)`` overlap of each footprint with the next one in its strip (NaN at strip ends).
    side
        ``(M,)`` largest overlap of each footprint with a footprint of the next strip (NaN on the last).
    """

    head: str
    forward: NDArray[np.float64]
    side: NDArray[np.float64]

    def summary(self) -> dict[str, float]:
        return {"forward_mean": float(np.nanmean(self.forward)) if np.any(np.isfinite(self.forward)) else float("nan"),
                "forward_min": float(np.nanmin(self.forward)) if np.any(np.isfinite(self.forward)) else float("nan"),
                "side_mean": float(np.nanmean(self.side)) if np.any(np.isfinite(self.side)) else float("nan"),
                "side_min": float(np.nanmin(self.side)) if np.any(np.isfinite(self.side)) else float("nan")}


def overlap_stats(plan: FlightPlan, fp: NDArray[np.float64], head: str = "") -> OverlapStats:
    """Forward and side overlaps of footprints ``fp (M, 4, 3)`` (polygon areas through shapely)."""
    import shapely

    polys, ok = _polys(fp)
    m = len(plan)
    fwd = np.full(m, np.nan)
    side = np.full(m, np.nan)
    for i in range(m - 1):
        if plan.strip[i] == plan.strip[i + 1] and ok[i] and ok[i + 1]:
            fwd[i] = shapely.intersection(polys[i], polys[i + 1]).area / polys[i].area
    for s in np.unique(plan.strip):
        nxt = np.nonzero((plan.strip == s + 1) & ok)[0]
        if nxt.size == 0:
            continue
        for i in np.nonzero((plan.strip == s) & ok)[0]:
            inter = shapely.intersection(polys[i], np.array(list(polys[nxt]), dtype=object))
            side[i] = float(np.max(shapely.area(inter))) / polys[i].area
    return OverlapStats(head, fwd, side)


@dataclass(frozen=True)
class CoverageMap:
    """Number of images covering each cell of a grid (``(rows, cols)``), GDAL north-up transform."""

    count: NDArray[np.int32]
    transform: tuple[float, float, float, float, float, float]


def coverage_map(fps: list[NDArray[np.float64]], extent: tuple[float, float, float, float], cell_m: float) -> CoverageMap:
    """Count footprints (each ``(M, 4, 3)``, any number of heads) covering every cell centre of ``extent``."""
    xmin, ymin, xmax, ymax = extent
    cols = max(1, int(np.ceil((xmax - xmin) / cell_m)))
    rows = max(1, int(np.ceil((ymax - ymin) / cell_m)))
    xx, yy = np.meshgrid(xmin + (np.arange(cols) + 0.5) * cell_m, ymin + rows * cell_m - (np.arange(rows) + 0.5) * cell_m)
    count = np.zeros((rows, cols), np.int32)
    for fp in fps:
        for quad in fp:
            if not np.all(np.isfinite(quad)):
                continue
            q = quad[:, :2]
            bx0, by0 = q.min(axis=0)
            bx1, by1 = q.max(axis=0)
            sel = (xx >= bx0) & (xx <= bx1) & (yy >= by0) & (yy <= by1)
            if not sel.any():
                continue
            px, py = xx[sel], yy[sel]
            sgn = []
            for k in range(4):
                a, b = q[k], q[(k + 1) % 4]
                sgn.append((b[0] - a[0]) * (py - a[1]) - (b[1] - a[1]) * (px - a[0]))
            sgn = np.array(sgn)
            inside = np.all(sgn >= 0, axis=0) | np.all(sgn <= 0, axis=0)
            count[sel] += inside.astype(np.int32)
    return CoverageMap(count, (cell_m, 0.0, xmin, 0.0, -cell_m, ymin + rows * cell_m))
