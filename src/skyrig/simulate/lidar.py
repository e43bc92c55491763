"""The ``uav-bridge-lidar`` scenario (paper 002): a 2D laser scanner on a UAV flying along a bridge.

Everything here is pure computation in memory; :mod:`skyrig.pipeline.simulate` writes the files.

**The object.**  A bridge as in paper 002 (12 m wide, 135 m long, 8 m high; pillars 14.1 m x 1.4 m) made of
oriented boxes in the scene's local ENU frame (:class:`Box`): a deck (underside 6 m, top 7.2 m above the
ground), two parapets up to 8 m, four pillars spaced evenly along the span and two abutments, standing on a
horizontal ground plane.  The bridge axis is rotated by ``axis_deg`` (counter-clockwise from east) so
that nothing is aligned with the map grid.  :meth:`BridgeScene.cast` ray-casts it exactly (slab test per
box, vectorised over rays); :meth:`BridgeScene.sample_surfaces` samples its visible faces densely, which is
the terrestrial reference scan (Z+F Imager 5006 in the paper), independent of any ray casting.

**The flight.**  The true motion is analytic: a path at ``distance_m`` from the bridge side and
``altitude_m`` above the ground, flown at ``speed_mps`` (paper 002: 12 m, 5 m, about 2.4 m/s for its 6 cm
line spacing at 40 lines/s), with the bridge on the right, small sinusoidal position and attitude wobbles.
CI size: one pass along 20 m past a pillar; full size: a pass along the south side, a half circle around
the west abutment and a pass back along the north side.  The true pose of **every pulse** is evaluated
from the analytic motion at the pulse's own time; the trajectory file samples the same motion at
``trajectory_rate_hz`` (IMU reference point, with NED velocities), so that georeferencing it reproduces
the truth up to the interpolation error of 200 Hz samples (far below a micrometre).

**The scanner** (:class:`~skyrig.lidar.scanner.Scanner2D`, default the Hokuyo UTM-30LX-EW: 270 deg field,
0.25 deg step, 40 lines/s, 0.1 m to 30 m) is mounted with its x axis (alpha = 0, the centre of the field
of view) along body y (right, towards the bridge) and its y axis along body z (down): a vertical scan plane
across the flight direction; the blind 90 deg sector points up-left.  Pulses that hit nothing within range
give no return and are not recorded.

**Sensor errors** (:class:`LidarErrors`, all zero by default, each written to the truth file):
boresight (a rotation vector in the scanner frame, ``body_from_scanner_true = body_from_scanner @
expmap(boresight)``, the convention of :meth:`~skyrig.lidar.georef.ScannerMount.corrected` and of
:func:`~skyrig.lidar.boresight.estimate_boresight`), lever-arm error (true minus recorded, body frame),
heading (yaw) error of the magnetometer-aided IMU (recorded ``ned_from_body = Rz(heading_error) @ true``,
so the correction to apply is ``-heading_error``), IMU white noise, GNSS white noise, bias and a slow
wander (sum of sinusoids with periods 15 s to 60 s, paper 002's weak GNSS heights), a barometric
height record (true ellipsoidal IMU height + bias + noise), range noise and bias, and a scanner clock
offset (recorded pulse time = true + offset).

**The strip flight** (issue 34, :func:`strip_scenario_spec`, sizes ``strips-ci`` / ``strips``): strips along both
sides at two distances and heights joined by turns (the scanner records on the strips only; every pulse carries its
strip id), the scan plane tilted 20 deg forward (:data:`BODY_FROM_SCANNER_TILTED`), and :data:`STRIP_ERRORS`: what a
strip adjustment must recover -- boresight, lever arm, range offset and scale (``range_scale_ppm``), per-strip
trajectory position/attitude offsets and drifts drawn from the stated trajectory accuracy -- and a camera boresight
written to the truth for the joint laser + image adjustment.  :func:`strip_truth_vector` turns the truth into the
corrections :mod:`skyrig.lidar.strips` estimates.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.errors import GeometryError, SkyrigError
from skyrig.geodesy.crs import ecef_to_geodetic
from skyrig.georef.eo import WorldFrame
from skyrig.geometry.rotations import (
    ENU_FROM_NED, matrix_from_rpy, quaternion_from_matrix, rot_y, rot_z, rpy_from_matrix,
)
from skyrig.lidar.georef import ScannerMount
from skyrig.lidar.scanner import HOKUYO_UTM_30LX_EW, RawScan, Scanner2D, sensor_from_polar
from skyrig.trajectory.trajectory import Trajectory, ecef_from_ned_rotation

__all__ = [
    "BODY_FROM_SCANNER_ACROSS",
    "Box",
    "BridgeScene",
    "LidarErrors",
    "LidarScenarioSpec",
    "LidarSurvey",
    "PAPER002_ERRORS",
    "STRIP_ERRORS",
    "build_lidar_survey",
    "lidar_scenario_spec",
    "make_bridge",
    "reference_reach_m",
    "strip_scenario_spec",
    "strip_truth_vector",
]

_Vec = tuple[float, float, float]

#: Scanner x (alpha = 0) along body y (right), scanner y (alpha = +90 deg) along body z (down), scanner z
#: along body x (forward): a vertical scan plane across the flight direction.
BODY_FROM_SCANNER_ACROSS = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])

#: The scan plane tilted 20 deg forward (about body y) from :data:`BODY_FROM_SCANNER_ACROSS`, as UAV laser scanners are
#: often mounted: faces across the flight line (pillar faces) are hit at a useful incidence, not grazing.
BODY_FROM_SCANNER_TILTED = rot_y(np.radians(20.0)) @ BODY_FROM_SCANNER_ACROSS

GROUND = -1  # component index of the ground plane in hit records
NO_HIT = -2


# ---------------------------------------------------------------------------------------------- scene
@dataclass(frozen=True, eq=False)
class Box:
    """An oriented box: ``centre`` (local ENU, m), ``half_size`` along its own axes (m), its x axis rotated
    by ``azimuth_rad`` counter-clockwise from east about the vertical; ``reflectivity`` in 0..1."""

    name: str
    centre: NDArray[np.float64]
    half_size: NDArray[np.float64]
    azimuth_rad: float = 0.0
    reflectivity: float = 0.5

    def __post_init__(self) -> None:
        c = np.asarray(self.centre, dtype=np.float64).reshape(3)
        h = np.asarray(self.half_size, dtype=np.float64).reshape(3)
        if np.any(h <= 0):
            raise GeometryError(f"box {self.name!r}: half sizes must be positive, got {h}")
        object.__setattr__(self, "centre", c)
        object.__setattr__(self, "half_size", h)

    @property
    def local_from_box(self) -> NDArray[np.float64]:
        """``(3, 3)`` rotation from the box axes to local ENU."""
        return rot_z(self.azimuth_rad)

    def contains(self, xyz: ArrayLike, tol: float = 1e-7) -> NDArray[np.bool_]:
        """``(N,)`` points inside or on the box (closed, widened by ``tol`` metres)."""
        p = (np.asarray(xyz, dtype=np.float64) - self.centre) @ self.local_from_box
        return np.all(np.abs(p) <= self.half_size + tol, axis=1)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "centre": self.centre.tolist(), "half_size": self.half_size.tolist(),
                "azimuth_rad": float(self.azimuth_rad), "reflectivity": float(self.reflectivity)}


@dataclass(frozen=True, eq=False)
class BridgeScene:
    """A bridge of oriented boxes on a horizontal ground plane ``z = ground_z`` (local ENU, metres).

    Attributes
    ----------
    boxes
        The solid parts.
    ground_z
        Height of the ground plane.
    axis_rad
        Direction of the bridge axis (counter-clockwise from east).
    length_m, width_m, height_m
        Nominal dimensions (deck length, deck width, top of the parapets above the ground).
    ground_reflectivity
        Reflectivity of the ground (intensity model).
    """

    boxes: tuple[Box, ...]
    ground_z: float = 0.0
    axis_rad: float = 0.0
    length_m: float = 135.0
    width_m: float = 12.0
    height_m: float = 8.0
    ground_reflectivity: float = 0.3

    @property
    def local_from_bridge(self) -> NDArray[np.float64]:
        """``(3, 3)``: bridge frame (u along the axis, v across to the left, z up) to local ENU."""
        return rot_z(self.axis_rad)

    def cast(self, origin: ArrayLike, direction: ArrayLike, max_range: float = np.inf
             ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.intp]]:
        """Exact first hits of rays.

        Parameters
        ----------
        origin, direction
            ``(N, 3)`` ray origins and unit directions (local ENU).
        max_range
            Hits farther than this are ignored (metres).

        Returns
        -------
        range_m
            ``(N,)`` distance to the first hit, ``inf`` where nothing is hit.
        normal
            ``(N, 3)`` outward unit normal of the surface hit (zeros where nothing is hit).
        component
            ``(N,)`` index of the box hit, :data:`GROUND` (-1) for the ground, :data:`NO_HIT` (-2).
        """
        o = np.asarray(origin, dtype=np.float64)
        d = np.asarray(direction, dtype=np.float64)
        n = len(o)
        best = np.full(n, np.inf)
        comp = np.full(n, NO_HIT, dtype=np.intp)
        normal = np.zeros((n, 3))
        # ground plane
        with np.errstate(divide="ignore", invalid="ignore"):
            tg = (self.ground_z - o[:, 2]) / d[:, 2]
        hit = (d[:, 2] < 0) & (tg > 0) & (tg <= max_range)
        best[hit] = tg[hit]
        comp[hit] = GROUND
        normal[hit] = (0.0, 0.0, 1.0)
        if n == 0:
            return best, normal, comp
        lo_o, hi_o = o.min(axis=0), o.max(axis=0)
        frames: dict[float, tuple] = {}  # rays in the axes of each distinct box azimuth (column arrays)
        for k, b in enumerate(self.boxes):
            # cull boxes farther than max_range from every origin (bounding sphere vs origins' bounding box)
            gap = np.linalg.norm(np.maximum(np.maximum(lo_o - b.centre, b.centre - hi_o), 0.0))
            if gap - np.linalg.norm(b.half_size) > max_range:
                continue
            r = b.local_from_box
            key = float(b.azimuth_rad)
            if key not in frames:
                ob = o @ r
                db = d @ r
                with np.errstate(divide="ignore"):
                    frames[key] = ([np.ascontiguousarray(ob[:, j]) for j in range(3)],
                                   [1.0 / np.ascontiguousarray(db[:, j]) for j in range(3)])
            oc, inv = frames[key]
            cb = b.centre @ r
            tn, tf = [], []
            with np.errstate(invalid="ignore"):
                for j in range(3):
                    t1 = (cb[j] - b.half_size[j] - oc[j]) * inv[j]
                    t2 = (cb[j] + b.half_size[j] - oc[j]) * inv[j]
                    tn.append(np.fmin(t1, t2))
                    tf.append(np.fmax(t1, t2))
            tmin = np.maximum(np.maximum(tn[0], tn[1]), tn[2])
            tmax = np.minimum(np.minimum(tf[0], tf[1]), tf[2])
            idx = np.flatnonzero((tmax >= tmin) & (tmin > 0) & (tmin < best))
            if idx.size == 0:
                continue
            th = tmin[idx]
            ax = np.where(tn[0][idx] == th, 0, np.where(tn[1][idx] == th, 1, 2))
            nb = np.zeros((idx.size, 3))
            nb[np.arange(idx.size), ax] = -np.sign(np.choose(ax, [1.0 / inv[j][idx] for j in range(3)]))
            best[idx] = th
            comp[idx] = k
            normal[idx] = nb @ r.T
        best[best > max_range] = np.inf
        miss = ~np.isfinite(best)
        comp[miss] = NO_HIT
        normal[miss] = 0.0
        return best, normal, comp

    def reflectivity(self, component: ArrayLike) -> NDArray[np.float64]:
        """``(N,)`` reflectivity of the components hit (0 where nothing is hit)."""
        c = np.asarray(component)
        table = np.array([b.reflectivity for b in self.boxes] + [self.ground_reflectivity, 0.0])
        return table[np.where(c >= 0, c, np.where(c == GROUND, len(self.boxes), len(self.boxes) + 1))]

    def sample_surfaces(
        self,
        rng: np.random.Generator,
        density_per_m2: float = 250.0,
        ground_density_per_m2: float = 60.0,
        noise_m: float = 0.003,
        u_range: tuple[float, float] | None = None,
        ground_v_range: tuple[float, float] = (-30.0, 30.0),
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """A terrestrial-scanner-like reference: the visible surfaces sampled at random, with noise.

        Every face of every box and the ground are sampled uniformly at the given densities; points on
        faces hidden inside or against another box or the ground (pillar tops under the deck, bottoms on
        the ground, the ground under the pillars) are dropped.  Independent of :meth:`cast`.

        Parameters
        ----------
        rng
            Random generator.
        density_per_m2, ground_density_per_m2
            Expected points per square metre on the structure and on the ground.
        noise_m
            Isotropic Gaussian noise of the reference scanner (one sigma, metres).
        u_range
            ``(umin, umax)``: keep only points within this stretch along the bridge axis (metres, bridge
            frame); None: the whole bridge plus 10 m.
        ground_v_range
            Across-axis extent of the sampled ground (metres, bridge frame).

        Returns
        -------
        xyz, normal
            ``(M, 3)`` points (local ENU) and the true outward normals of the faces they were drawn on.
        """
        lb = self.local_from_bridge
        if u_range is None:
            u_range = (-self.length_m / 2 - 10.0, self.length_m / 2 + 10.0)
        pts, nrm, owner = [], [], []
        u0, u1 = u_range
        for bi, b in enumerate(self.boxes):
            r = b.local_from_box
            lo, hi = -b.half_size.copy(), b.half_size.copy()
            if abs(np.sin(b.azimuth_rad - self.axis_rad)) < 1e-12:  # box x along the axis: sample [u0, u1] only
                uc = float((b.centre @ lb)[0])
                sx = float(np.cos(b.azimuth_rad - self.axis_rad))  # +1 or -1
                a, c = sorted(((u0 - uc) * sx, (u1 - uc) * sx))
                lo[0], hi[0] = max(lo[0], a), min(hi[0], c)
                if lo[0] > hi[0]:
                    continue
            for ax in range(3):
                a1, a2 = [i for i in range(3) if i != ax]
                area = (hi[a1] - lo[a1]) * (hi[a2] - lo[a2])
                for sgn in (-1.0, 1.0):
                    face = b.half_size[ax] * sgn
                    if not lo[ax] <= face <= hi[ax]:
                        continue
                    m = int(rng.poisson(area * density_per_m2))
                    q = np.empty((m, 3))
                    q[:, ax] = face
                    q[:, a1] = rng.uniform(lo[a1], hi[a1], m)
                    q[:, a2] = rng.uniform(lo[a2], hi[a2], m)
                    nb = np.zeros(3)
                    nb[ax] = sgn
                    pts.append(b.centre + q @ r.T)
                    nrm.append(np.broadcast_to(r @ nb, (m, 3)))
                    owner.append(np.full(m, bi))
        v0, v1 = ground_v_range
        m = int(rng.poisson((u1 - u0) * (v1 - v0) * ground_density_per_m2))
        g = np.column_stack([rng.uniform(u0, u1, m), rng.uniform(v0, v1, m), np.full(m, self.ground_z)])
        pts.append(g @ lb.T)
        nrm.append(np.broadcast_to(np.array([0.0, 0.0, 1.0]), (m, 3)))
        owner.append(np.full(m, GROUND))
        xyz = np.concatenate(pts)
        normal = np.ascontiguousarray(np.concatenate(nrm))
        box_of = np.concatenate(owner)
        keep = np.ones(len(xyz), bool)
        for bi, b in enumerate(self.boxes):  # hidden inside or against another solid
            near = np.flatnonzero(keep & (box_of != bi) & (np.sum((xyz - b.centre) ** 2, axis=1)
                                                            <= float(b.half_size @ b.half_size) + 1e-6))
            keep[near[b.contains(xyz[near])]] = False
        keep &= ~((box_of != GROUND) & (xyz[:, 2] <= self.ground_z + 1e-7))  # faces on the ground
        uvz = xyz @ lb
        keep &= (uvz[:, 0] >= u0) & (uvz[:, 0] <= u1)
        xyz = xyz[keep] + rng.normal(0.0, noise_m, (int(keep.sum()), 3))
        return xyz, normal[keep]

    def to_dict(self) -> dict[str, Any]:
        return {"boxes": [b.to_dict() for b in self.boxes], "ground_z": self.ground_z, "axis_rad": self.axis_rad,
                "length_m": self.length_m, "width_m": self.width_m, "height_m": self.height_m,
                "ground_reflectivity": self.ground_reflectivity,
                "frame": "local ENU (x east, y north, z up), metres; boxes: centre, half sizes along the box axes, "
                         "box x axis rotated azimuth_rad counter-clockwise from east"}


def make_bridge(
    length_m: float = 135.0,
    width_m: float = 12.0,
    deck_bottom_m: float = 6.0,
    deck_top_m: float = 7.2,
    parapet_top_m: float = 8.0,
    parapet_width_m: float = 0.3,
    n_pillars: int = 4,
    pillar_size_m: tuple[float, float] = (1.4, 14.1),
    axis_deg: float = 20.0,
    ground_z: float = 0.0,
) -> BridgeScene:
    """Paper 002's bridge: a deck with parapets on ``n_pillars`` evenly spaced pillars and two abutments.

    Parameters
    ----------
    length_m, width_m
        Deck length (along the axis) and width (metres).
    deck_bottom_m, deck_top_m, parapet_top_m
        Heights above the ground of the deck's underside, its top and the parapets' top.
    parapet_width_m
        Thickness of the two parapets standing on the deck edges.
    n_pillars, pillar_size_m
        Number of pillars and their size (along the axis, across it): paper 002: 1.4 m x 14.1 m.
    axis_deg
        Direction of the bridge axis, counter-clockwise from east (degrees).
    ground_z
        Height of the ground plane in the local frame.
    """
    if not (ground_z < deck_bottom_m < deck_top_m < parapet_top_m):
        raise GeometryError("need ground < deck underside < deck top < parapet top")
    az = np.radians(axis_deg)
    lb = rot_z(az)

    def box(name: str, u: float, v: float, z0: float, z1: float, hu: float, hv: float, refl: float) -> Box:
        c = lb @ np.array([u, v, 0.0])
        return Box(name, np.array([c[0], c[1], ground_z + (z0 + z1) / 2]), np.array([hu, hv, (z1 - z0) / 2]), az, refl)

    boxes = [box("deck", 0.0, 0.0, deck_bottom_m, deck_top_m, length_m / 2, width_m / 2, 0.55)]
    for side, sgn in (("south", -1.0), ("north", 1.0)):
        boxes.append(box(f"parapet_{side}", 0.0, sgn * (width_m / 2 - parapet_width_m / 2), deck_top_m, parapet_top_m,
                         length_m / 2, parapet_width_m / 2, 0.6))
    span = length_m / (n_pillars + 1)
    for i in range(n_pillars):
        u = -length_m / 2 + (i + 1) * span
        boxes.append(box(f"pillar_{i + 1}", u, 0.0, 0.0, deck_bottom_m, pillar_size_m[0] / 2, pillar_size_m[1] / 2, 0.5))
    for name, sgn in (("abutment_west", -1.0), ("abutment_east", 1.0)):
        boxes.append(box(name, sgn * (length_m / 2 + 2.5), 0.0, 0.0, deck_top_m, 2.5, width_m / 2 + 1.0, 0.45))
    return BridgeScene(tuple(boxes), ground_z, float(az), length_m, width_m, parapet_top_m)


# ---------------------------------------------------------------------------------------------- errors
@dataclass(frozen=True)
class LidarErrors:
    """Sensor errors of the scanning UAV (see the module docstring; all zero by default)."""

    boresight_rad: _Vec = (0.0, 0.0, 0.0)  # rotation vector in the scanner frame: true = recorded @ expmap(b)
    lever_arm_error_m: _Vec = (0.0, 0.0, 0.0)  # true minus recorded scanner lever arm (body frame)
    heading_error_rad: float = 0.0  # recorded ned_from_body = Rz(heading_error) @ true (correction: -heading_error)
    imu_noise_rad: _Vec = (0.0, 0.0, 0.0)  # white noise on roll, pitch, yaw per trajectory sample
    gnss_noise_m: _Vec = (0.0, 0.0, 0.0)  # white noise per trajectory sample, E N U (local frame)
    gnss_bias_m: _Vec = (0.0, 0.0, 0.0)  # constant, E N U
    gnss_wander_m: _Vec = (0.0, 0.0, 0.0)  # amplitude (RMS) of a slow wander, E N U (periods 15 s to 60 s)
    baro_noise_m: float = 0.0  # white noise of the barometric heights
    baro_bias_m: float = 0.0  # barometric minus true ellipsoidal height of the IMU
    range_sigma_m: float = 0.0  # range noise (one sigma)
    range_bias_m: float = 0.0  # recorded minus true range
    time_offset_s: float = 0.0  # recorded minus true pulse time (scanner clock)
    range_scale_ppm: float = 0.0  # recorded = (1 + scale) x true range (+ bias + noise), parts per million
    # per-strip trajectory errors (passes="strips"): drawn per strip from N(0, sigma) and applied as recorded = true +
    # offset + drift x (t - strip mid time) for positions (local ENU, m) and as recorded local_from_body =
    # expmap(offset + drift x (t - mid)) @ true for attitudes (rotation vector in the local ENU frame, rad)
    strip_position_sigma_m: _Vec = (0.0, 0.0, 0.0)
    strip_position_drift_sigma_mps: _Vec = (0.0, 0.0, 0.0)
    strip_attitude_sigma_rad: _Vec = (0.0, 0.0, 0.0)
    strip_attitude_drift_sigma_radps: _Vec = (0.0, 0.0, 0.0)
    scan_angle_sigma_rad: float = 0.0  # white noise of the recorded deflection angle alpha
    # surface roughness: each return hits the surface N(0, roughness) (one sigma) off its plane along the plane's
    # normal, the true range lengthened by that height over |cos incidence| (incidence capped at 85 deg); the model
    # of :class:`skyrig.lidar.strips.StripModel` ``roughness_m`` (a point-to-plane noise independent of the beam)
    surface_roughness_m: float = 0.0
    # the camera's boresight error (rotation vector in the camera frame) of the same system: not used by the laser
    # simulation, written to the truth so that a joint laser + image adjustment can be judged against it
    camera_boresight_rad: _Vec = (0.0, 0.0, 0.0)

    def to_dict(self) -> dict[str, Any]:
        return {f.name: (list(map(float, v)) if isinstance(v := getattr(self, f.name), tuple) else float(v))
                for f in fields(self)}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "LidarErrors":
        known = {f.name for f in fields(cls)}
        bad = set(d) - known
        if bad:
            raise SkyrigError(f"unknown lidar sensor error keys: {sorted(bad)}")
        return cls(**{k: tuple(map(float, v)) if isinstance(v, (list, tuple)) else float(v) for k, v in d.items()})

    @property
    def perfect(self) -> bool:
        return all(not np.any(np.asarray(getattr(self, f.name))) for f in fields(self))


#: Errors of paper 002's magnitudes: 3 cm range noise, a heading error of 1.5 deg (magnetometer disturbed by
#: the UAV's electronics), boresight residuals of a few tenths of a degree, a few centimetres of lever arm,
#: weak GNSS heights (0.5 m wander) and lateral GNSS wander (0.2 m), a barometer of 5 cm noise.
PAPER002_ERRORS = LidarErrors(
    boresight_rad=tuple(np.radians([0.3, -0.2, 0.4])), lever_arm_error_m=(0.02, -0.03, 0.01),
    heading_error_rad=float(np.radians(1.5)), imu_noise_rad=tuple(np.radians([0.02, 0.02, 0.05])),
    gnss_noise_m=(0.02, 0.02, 0.04), gnss_wander_m=(0.2, 0.2, 0.5), baro_noise_m=0.05, baro_bias_m=0.0,
    range_sigma_m=0.03)


#: Errors a LiDAR strip adjustment must recover (issue 34): boresight, lever arm, range offset and scale, per-strip
#: trajectory offsets and drifts drawn from the trajectory's stated accuracy, 2 cm range noise, a camera boresight for
#: the joint adjustment.  No GNSS wander or heading error outside the per-strip model (the model the adjustment fits).
STRIP_ERRORS = LidarErrors(
    boresight_rad=tuple(np.radians([0.25, -0.15, 0.30])), lever_arm_error_m=(0.03, -0.04, 0.05),
    range_sigma_m=0.02, range_bias_m=0.04, range_scale_ppm=800.0,
    strip_position_sigma_m=(0.03, 0.03, 0.05), strip_position_drift_sigma_mps=(0.0005, 0.0005, 0.0008),
    strip_attitude_sigma_rad=tuple(np.radians([0.02, 0.02, 0.05])),
    strip_attitude_drift_sigma_radps=tuple(np.radians([0.0002, 0.0002, 0.0005])),
    camera_boresight_rad=tuple(np.radians([0.1, -0.08, 0.2])))


# ---------------------------------------------------------------------------------------------- spec
@dataclass(frozen=True)
class LidarScenarioSpec:
    """Everything a simulated UAV laser scan is a deterministic function of.

    Attributes
    ----------
    name, size, seed
        Scenario name, ``"ci"`` or ``"full"``, random seed.
    scanner
        The 2D scanner (range limits and pulse timing; its ``range_sigma_m`` is *not* used: the range noise
        is ``errors.range_sigma_m``).
    body_from_scanner, lever_arm_m
        The recorded (nominal) mount.
    errors
        Sensor errors.
    origin
        (lat, lon, h) of the local ENU frame (WGS84, ellipsoidal height of the ground).
    crs
        Map CRS of the reference cloud and of the truth points (ellipsoidal heights).
    bridge
        Keyword arguments of :func:`make_bridge`.
    passes
        ``"one"`` (south side, westward, CI), ``"there-and-back"`` (south side westward, a half circle
        around the west abutment, north side eastward) or ``"strips"`` (a laser strip flight: the strips of
        ``strip_layout``, south side westward and north side eastward in turn, joined by half-circle turns
        that change distance and height smoothly; the scanner records on the strips only, every pulse with its
        strip id).
    strip_layout
        ``((distance_m, altitude_m), ...)`` per strip (``passes="strips"``).
    pass_u_m
        ``(u_start, u_end)`` of the (first) pass along the bridge axis (bridge frame, metres).
    distance_m, altitude_m, speed_mps
        Horizontal distance from the bridge side, height above the ground, ground speed.
    wobble_m, wobble_deg
        Amplitudes of the position (E, N, U) and attitude (roll, pitch, yaw) wobbles.
    trajectory_rate_hz
        Rate of the trajectory file (and barometer) samples.
    reference_density_per_m2, reference_ground_density_per_m2, reference_noise_m
        The terrestrial reference scan.
    t0_s
        GPS seconds of week of the first scan line.
    """

    name: str = "uav-bridge-lidar"
    size: str = "ci"
    seed: int = 1
    scanner: Scanner2D = HOKUYO_UTM_30LX_EW
    body_from_scanner: tuple[tuple[float, float, float], ...] = tuple(map(tuple, BODY_FROM_SCANNER_ACROSS))
    lever_arm_m: _Vec = (0.10, -0.02, 0.15)
    errors: LidarErrors = field(default_factory=LidarErrors)
    origin: tuple[float, float, float] = (51.0275, 13.7258, 150.0)
    crs: str = "EPSG:32633"
    bridge: dict[str, Any] = field(default_factory=dict)
    passes: str = "one"
    pass_u_m: tuple[float, float] = (24.0, 4.0)
    distance_m: float = 12.0
    altitude_m: float = 5.0
    speed_mps: float = 2.4
    wobble_m: _Vec = (0.05, 0.05, 0.10)
    wobble_deg: _Vec = (3.0, 2.0, 4.0)
    trajectory_rate_hz: float = 200.0
    strip_layout: tuple[tuple[float, float], ...] = ((12.0, 5.0), (12.0, 5.0), (9.0, 3.5), (9.0, 3.5))
    reference_density_per_m2: float = 250.0
    reference_ground_density_per_m2: float = 60.0
    reference_noise_m: float = 0.003
    t0_s: float = 345_700.0

    @property
    def mount(self) -> ScannerMount:
        """The recorded (nominal) scanner mount."""
        return ScannerMount(np.array(self.body_from_scanner, dtype=np.float64), np.array(self.lever_arm_m))

    def true_mount(self) -> ScannerMount:
        """The mount as it really is: boresight and lever-arm errors applied."""
        return self.mount.corrected(dboresight_rad=self.errors.boresight_rad, dlever_m=self.errors.lever_arm_error_m)


def lidar_scenario_spec(size: str = "ci", seed: int = 1, errors: LidarErrors | None = None) -> LidarScenarioSpec:
    """The ``uav-bridge-lidar`` scenario (paper 002) in CI or full size.

    ``errors`` defaults to :data:`PAPER002_ERRORS`; pass ``LidarErrors()`` for perfect sensors.
    CI size: one 20 m pass past a pillar (8.3 s, 333 scan lines, about 0.2 million returns); full size: both
    sides of the whole bridge with a turn around its west end (about 160 s, 6,400 lines, 4 million returns).
    """
    if size not in ("ci", "full", "strips-ci", "strips"):
        raise SkyrigError(f"scenario size must be 'ci', 'full', 'strips-ci' or 'strips', not {size!r}")
    err = PAPER002_ERRORS if errors is None else errors
    if size == "ci":
        return LidarScenarioSpec(size="ci", seed=seed, errors=err)
    if size in ("strips-ci", "strips"):
        return strip_scenario_spec(size, seed, errors)
    return LidarScenarioSpec(size="full", seed=seed, errors=err, passes="there-and-back", pass_u_m=(82.0, -82.0),
                             reference_density_per_m2=200.0, reference_ground_density_per_m2=40.0)


def strip_scenario_spec(size: str = "strips", seed: int = 1, errors: LidarErrors | None = None) -> LidarScenarioSpec:
    """The ``uav-bridge-lidar`` strip flight (issue 34): strips along both sides of the bridge at two distances and
    heights, joined by turns (scanner off), with :data:`STRIP_ERRORS` (default) to recover.

    ``"strips"``: five 170 m strips (pass u = 85 -> -85 m; 12/5, 12/5, 9/3.5, 9/3.5, 15/4.5 m distance/height) at
    4 m/s, about 1.1 km of flight, about 6 million returns; ``"strips-ci"``: four 22 m strips past the pillar at
    u = 13.5 m (about 0.6 million returns).
    """
    err = STRIP_ERRORS if errors is None else errors
    tilted = tuple(map(tuple, BODY_FROM_SCANNER_TILTED))
    if size == "strips-ci":
        return LidarScenarioSpec(size=size, seed=seed, errors=err, passes="strips", pass_u_m=(30.0, 8.0),
                                 body_from_scanner=tilted,
                                 speed_mps=2.4, reference_density_per_m2=120.0, reference_ground_density_per_m2=30.0)
    if size != "strips":
        raise SkyrigError(f"strip scenario size must be 'strips' or 'strips-ci', not {size!r}")
    return LidarScenarioSpec(size=size, seed=seed, errors=err, passes="strips", pass_u_m=(85.0, -85.0), speed_mps=4.0,
                             body_from_scanner=tilted,
                             strip_layout=((12.0, 5.0), (12.0, 5.0), (9.0, 3.5), (9.0, 3.5), (15.0, 4.5)),
                             reference_density_per_m2=120.0, reference_ground_density_per_m2=30.0)


def strip_truth_vector(injected: dict[str, Any], strip_epoch_s: ArrayLike) -> NDArray[np.float64]:
    """The corrections a strip adjustment (:mod:`skyrig.lidar.strips`) should find, from a survey's ``injected``
    values: ``(8 + 12 K,)`` in the order of :func:`skyrig.lidar.strips.strip_parameter_names`, the strip corrections
    referred to the adjustment's strip epochs ``(K,)`` (the negatives of the injected errors)."""
    ep = np.asarray(strip_epoch_s, dtype=np.float64)
    strips = injected["strips"]
    if len(strips) != len(ep):
        raise SkyrigError(f"{len(strips)} simulated strips, {len(ep)} strip epochs")
    cal = np.concatenate([injected["boresight_rad"], injected["lever_arm_error_m"],
                          [injected["range_offset_m"], injected["range_scale_ppm"] * 1e-6]])
    rows = []
    for s_, tk in zip(strips, ep):
        dt = tk - s_["t_mid_s"]
        rows.append(np.concatenate([-(np.asarray(s_["position_offset_m"]) + np.asarray(s_["position_drift_mps"]) * dt),
                                    -np.asarray(s_["position_drift_mps"]),
                                    -(np.asarray(s_["attitude_offset_rad"]) + np.asarray(s_["attitude_drift_radps"]) * dt),
                                    -np.asarray(s_["attitude_drift_radps"])]))
    return np.concatenate([cal, *rows])


def reference_reach_m(spec: LidarScenarioSpec) -> float:
    """How far the terrestrial reference's ground reaches out from the bridge side (metres, both sides): the farthest
    flight line (a strip flight's widest strip, else ``distance_m``) plus 8 m, where the scanner's ground returns end
    (its blind sector points up and away from the bridge)."""
    far = max([spec.distance_m] + ([float(d) for d, _ in spec.strip_layout] if spec.passes == "strips" else []))
    return far + 8.0


# ---------------------------------------------------------------------------------------------- flight
@dataclass(frozen=True)
class _Segment:
    kind: str  # "line" or "arc"
    start: NDArray[np.float64]  # line: start point (u, v); arc: centre
    direction: NDArray[np.float64]  # line: unit direction; arc: (radius, start angle, sense +1 ccw / -1 cw[, end radius])
    length: float
    heights: tuple[float, float] | None = None  # (start, end) altitude above the ground; None: the spec's altitude


def _arc(centre_u: float, r0: float, r1: float, a0: float, h: tuple[float, float] | None = None) -> _Segment:
    """A clockwise half turn about ``(centre_u, 0)`` from angle ``a0``, radius ``r0`` -> ``r1`` linearly."""
    return _Segment("arc", np.array([centre_u, 0.0]), np.array([r0, a0, -1.0, r1]), np.pi * (r0 + r1) / 2, h)


def _path(spec: LidarScenarioSpec, scene: BridgeScene) -> list[_Segment]:
    r = scene.width_m / 2 + spec.distance_m
    u0, u1 = spec.pass_u_m
    d = np.array([np.sign(u1 - u0), 0.0])
    if spec.passes == "strips":
        if u1 >= u0:
            raise SkyrigError("a strip flight starts at the east end (pass_u_m decreasing)")
        if not spec.strip_layout:
            raise SkyrigError("a strip flight needs at least one strip in strip_layout")
        segs: list[_Segment] = []
        lay = [(scene.width_m / 2 + float(dist), float(alt)) for dist, alt in spec.strip_layout]
        for k, (rk, hk) in enumerate(lay):
            if k:
                rp, hp = lay[k - 1]
                # odd strips (north side, eastward) follow a turn about the west end, even ones a turn about the east
                segs.append(_arc(u1, rp, rk, -np.pi / 2, (hp, hk)) if k % 2 else _arc(u0, rp, rk, np.pi / 2, (hp, hk)))
            if k % 2 == 0:
                segs.append(_Segment("line", np.array([u0, -rk]), d, abs(u1 - u0), (hk, hk)))
            else:
                segs.append(_Segment("line", np.array([u1, rk]), -d, abs(u1 - u0), (hk, hk)))
        return segs
    first = _Segment("line", np.array([u0, -r]), d, abs(u1 - u0))
    if spec.passes == "one":
        return [first]
    if spec.passes != "there-and-back":
        raise SkyrigError(f"passes must be 'one', 'there-and-back' or 'strips', not {spec.passes!r}")
    if u1 >= u0:
        raise SkyrigError("a there-and-back flight starts at the east end (pass_u_m decreasing)")
    arc = _Segment("arc", np.array([u1, 0.0]), np.array([r, -np.pi / 2, -1.0]), np.pi * r)
    back = _Segment("line", np.array([u1, r]), np.array([1.0, 0.0]), abs(u1 - u0))
    return [first, arc, back]


def _path_at(segments: list[_Segment], s: NDArray[np.float64], height: float = 0.0
             ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                        NDArray[np.intp]]:
    """Positions ``(N, 2)``, tangents ``(N, 2)`` (d position / d s: unit except on turns that change radius;
    bridge frame), altitudes ``(N,)`` and their derivatives d h / d s ``(N,)`` at arc lengths ``s``
    (extrapolated along the first and last line beyond the ends), and the segment index ``(N,)``."""
    cum = np.cumsum([0.0] + [g.length for g in segments])
    k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(segments) - 1)
    pos = np.empty((len(s), 2))
    tan = np.empty((len(s), 2))
    hgt = np.full(len(s), float(height))
    dh = np.zeros(len(s))
    for i, g in enumerate(segments):
        m = k == i
        ds = s[m] - cum[i]
        if g.heights is not None:
            h0, h1 = g.heights
            f = np.clip(ds / g.length, 0.0, 1.0)
            hgt[m] = h0 + (h1 - h0) * f
            dh[m] = np.where((ds >= 0) & (ds <= g.length), (h1 - h0) / g.length, 0.0)
        if g.kind == "line":
            pos[m] = g.start + ds[:, None] * g.direction
            tan[m] = g.direction
        elif len(g.direction) == 3:
            rad, a0, sense = g.direction
            th = a0 + sense * ds / rad
            pos[m] = g.start + rad * np.column_stack([np.cos(th), np.sin(th)])
            tan[m] = sense * np.column_stack([-np.sin(th), np.cos(th)])
        else:  # a turn from radius r0 to r1: angle and radius linear in s
            r0, a0, sense, r1 = g.direction
            f = ds / g.length
            th = a0 + sense * np.pi * f
            rad = r0 + (r1 - r0) * f
            c, sn = np.cos(th), np.sin(th)
            pos[m] = g.start + rad[:, None] * np.column_stack([c, sn])
            dth, drad = sense * np.pi / g.length, (r1 - r0) / g.length
            tan[m] = drad * np.column_stack([c, sn]) + (rad * dth)[:, None] * np.column_stack([-sn, c])
    return pos, tan, hgt, dh, k


@dataclass(frozen=True, eq=False)
class _Motion:
    """The analytic true motion of the IMU in the local ENU frame."""

    segments: list[_Segment]
    local_from_bridge: NDArray[np.float64]
    t0: float
    speed: float
    height: float  # altitude above the ground where a segment does not give its own
    wob_amp: NDArray[np.float64]  # (3,) E N U, m
    wob_w: NDArray[np.float64]  # (3,) rad/s
    wob_phase: NDArray[np.float64]  # (3,)
    att_amp: NDArray[np.float64]  # (3,) roll pitch yaw, rad
    att_w: NDArray[np.float64]
    att_phase: NDArray[np.float64]
    ground_z: float = 0.0

    def segment_of(self, t: ArrayLike) -> NDArray[np.intp]:
        """``(N,)`` index of the path segment flown at times ``t``."""
        return _path_at(self.segments, self.speed * (np.asarray(t, dtype=np.float64) - self.t0))[4]

    def __call__(self, t: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Positions ``(N, 3)`` and velocities ``(N, 3)`` (local ENU) and ``local_from_body`` ``(N, 3, 3)``."""
        tt = np.asarray(t, dtype=np.float64) - self.t0
        p2, t2, hgt, dh, _ = _path_at(self.segments, self.speed * tt, self.height)
        lb = self.local_from_bridge[:2, :2]
        pos = np.empty((len(tt), 3))
        pos[:, :2] = p2 @ lb.T
        pos[:, 2] = hgt + self.ground_z
        tan = t2 @ lb.T
        vel = np.zeros((len(tt), 3))
        vel[:, :2] = self.speed * tan
        vel[:, 2] = self.speed * dh
        arg = self.wob_w * tt[:, None] + self.wob_phase
        pos += self.wob_amp * np.sin(arg)
        vel += self.wob_amp * self.wob_w * np.cos(arg)
        att = self.att_amp * np.sin(self.att_w * tt[:, None] + self.att_phase)
        heading = np.arctan2(tan[:, 0], tan[:, 1]) + att[:, 2]
        return pos, vel, ENU_FROM_NED @ matrix_from_rpy(att[:, 0], att[:, 1], heading, unit="rad")


def _ned_from_local_body(frame: WorldFrame, xyz_local: NDArray, local_from_body: NDArray) -> NDArray[np.float64]:
    lat, lon, _ = ecef_to_geodetic(frame.to_ecef(xyz_local))
    return np.swapaxes(ecef_from_ned_rotation(lat, lon), -1, -2) @ (frame.tangent.ecef_from_local @ local_from_body)


def _trajectory(frame: WorldFrame, t: NDArray, pos: NDArray, vel: NDArray, ned_from_body: NDArray) -> Trajectory:
    ecef = frame.to_ecef(pos)
    lat, lon, h = ecef_to_geodetic(ecef)
    v_ned = np.einsum("nji,nj->ni", ecef_from_ned_rotation(lat, lon), vel @ frame.tangent.ecef_from_local.T)
    return Trajectory(t, np.asarray(lat, float), np.asarray(lon, float), np.asarray(h, float),
                      quaternion_from_matrix(ned_from_body), velocity_ned=v_ned, time_system="gps-sow", reference="imu")


# ---------------------------------------------------------------------------------------------- survey
@dataclass(frozen=True, eq=False)
class LidarSurvey:
    """A simulated UAV laser scan in memory.

    Attributes
    ----------
    spec, scene, frame
        The scenario, the bridge and the local ENU frame of the scene.
    trajectory_true, trajectory_recorded
        IMU trajectories (true motion sampled at ``spec.trajectory_rate_hz``; recorded: with GNSS and IMU
        errors and the heading error).
    barometric_time_s, barometric_h_m
        ``(K,)`` barometer record: ellipsoidal heights of the IMU with the barometer's errors.
    mount_true, mount_recorded
        The scanner mount as it is and as recorded.
    scan
        The recorded raw pulses (returns only), ``N`` of them.
    true_time_s, true_range_m
        ``(N,)`` the pulses' true times and ranges.
    truth_xyz, truth_normal
        ``(N, 3)`` the true surface point of every recorded pulse and the surface normal (local ENU).
    truth_component
        ``(N,)`` index of the box hit (``scene.boxes``), -1 for the ground.
    reference_xyz, reference_normal
        ``(M, 3)`` the terrestrial reference scan (local ENU) and the true normals of its faces.
    injected
        The drawn error values (for the truth file).
    pulses_fired
        Pulses fired in all (returns and misses).
    strip_time_s
        ``(K, 2)`` start and end times of the strips (the straight passes; ``scan.strip_id`` indexes them, -1 on
        turns).
    """

    spec: LidarScenarioSpec
    scene: BridgeScene
    frame: WorldFrame
    trajectory_true: Trajectory
    trajectory_recorded: Trajectory
    barometric_time_s: NDArray[np.float64]
    barometric_h_m: NDArray[np.float64]
    mount_true: ScannerMount
    mount_recorded: ScannerMount
    scan: RawScan
    true_time_s: NDArray[np.float64]
    true_range_m: NDArray[np.float64]
    truth_xyz: NDArray[np.float64]
    truth_normal: NDArray[np.float64]
    truth_component: NDArray[np.intp]
    reference_xyz: NDArray[np.float64]
    reference_normal: NDArray[np.float64]
    injected: dict[str, Any]
    pulses_fired: int
    strip_time_s: NDArray[np.float64] | None = None


def _strip_errors(err: LidarErrors, rng: np.random.Generator, spans: NDArray[np.float64]) -> list[dict[str, Any]]:
    """Per-strip trajectory errors drawn from ``N(0, sigma)`` (see :class:`LidarErrors`), strips ``spans (K, 2)``."""
    out = []
    for k, (a, b) in enumerate(spans):
        out.append({"strip": k, "t_start_s": float(a), "t_end_s": float(b), "t_mid_s": float((a + b) / 2),
                    "position_offset_m": rng.normal(0.0, 1.0, 3) * np.asarray(err.strip_position_sigma_m),
                    "position_drift_mps": rng.normal(0.0, 1.0, 3) * np.asarray(err.strip_position_drift_sigma_mps),
                    "attitude_offset_rad": rng.normal(0.0, 1.0, 3) * np.asarray(err.strip_attitude_sigma_rad),
                    "attitude_drift_radps": rng.normal(0.0, 1.0, 3) * np.asarray(err.strip_attitude_drift_sigma_radps)})
    return out


def _strip_error_at(strips: list[dict[str, Any]], key: str, t: NDArray[np.float64]
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Value ``(N, 3)`` and rate ``(N, 3)`` of a per-strip error at times ``t``: ``offset + drift (t - mid)`` on each
    strip, linear between the end of one strip and the start of the next, constant before the first and after the
    last."""
    kt = np.array([[s["t_start_s"], s["t_end_s"]] for s in strips]).ravel()
    off, dr = key + ("_offset_m" if key == "position" else "_offset_rad"), key + ("_drift_mps" if key == "position"
                                                                                   else "_drift_radps")
    kv = np.array([[s[off] + s[dr] * (s["t_start_s"] - s["t_mid_s"]), s[off] + s[dr] * (s["t_end_s"] - s["t_mid_s"])]
                   for s in strips]).reshape(-1, 3)
    val = np.column_stack([np.interp(t, kt, kv[:, j]) for j in range(3)])
    slope = np.diff(kv, axis=0) / np.maximum(np.diff(kt), 1e-12)[:, None]
    i = np.searchsorted(kt, t, side="right") - 1
    inside = (i >= 0) & (i < len(kt) - 1)
    rate = np.zeros_like(val)
    rate[inside] = slope[i[inside]]
    return val, rate


def _wander(rng: np.random.Generator, amp_rms: ArrayLike) -> dict[str, NDArray[np.float64]]:
    a = np.asarray(amp_rms, dtype=np.float64) / np.sqrt(1.5)  # three sinusoids per axis
    periods = rng.uniform(15.0, 60.0, (3, 3))
    return {"amplitude_m": np.broadcast_to(a[None, :], (3, 3)).copy(), "period_s": periods,
            "phase_rad": rng.uniform(0, 2 * np.pi, (3, 3))}


def _wander_at(w: dict[str, NDArray], t: NDArray) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    om = 2 * np.pi / w["period_s"]  # (3 terms, 3 axes)
    arg = om[None] * t[:, None, None] + w["phase_rad"][None]
    return (np.sum(w["amplitude_m"] * np.sin(arg), axis=1), np.sum(w["amplitude_m"] * om * np.cos(arg), axis=1))


def build_lidar_survey(spec: LidarScenarioSpec, lines_per_chunk: int = 200) -> LidarSurvey:
    """Simulate the scan in memory: bridge, true motion, ray-cast pulses, recorded data and the reference.

    Deterministic for a given ``spec`` (its seed).

    Raises
    ------
    GeometryError
        If no pulse returns (the flight does not see the bridge).
    """
    rng = np.random.default_rng(spec.seed)
    err = spec.errors
    scene = make_bridge(**spec.bridge)
    frame = WorldFrame.local(*spec.origin)
    sc = spec.scanner
    segs = _path(spec, scene)
    duration = sum(g.length for g in segs) / spec.speed_mps
    n_lines = int(np.floor(duration * sc.lines_per_s))
    wob_w = np.array([0.9, 0.7, 0.4])
    att_w = np.array([0.7, 0.5, 0.3])
    motion = _Motion(segs, scene.local_from_bridge, spec.t0_s, spec.speed_mps, spec.altitude_m,
                     np.asarray(spec.wobble_m, float), wob_w, rng.uniform(0, 2 * np.pi, 3),
                     np.radians(spec.wobble_deg), att_w, rng.uniform(0, 2 * np.pi, 3), scene.ground_z)
    # ---- trajectory samples (1 s margin on both sides)
    rate = spec.trajectory_rate_hz
    k = np.arange(-int(round(rate)), int(np.ceil((n_lines / sc.lines_per_s + 1.0) * rate)) + 1)
    t_traj = spec.t0_s + k / rate
    pos, vel, lfb = motion(t_traj)
    ned_true = _ned_from_local_body(frame, pos, lfb)
    traj_true = _trajectory(frame, t_traj, pos, vel, ned_true)
    # ---- pulses
    mount_true = spec.true_mount()
    mount_rec = spec.mount
    b_true = mount_true.body_from_scanner
    # strips: the line segments of the path, numbered in flight order; the turns are -1
    line_of_seg = np.full(len(segs), -1, dtype=np.int64)
    line_of_seg[[i for i, g in enumerate(segs) if g.kind == "line"]] = np.arange(sum(g.kind == "line" for g in segs))
    cum = np.cumsum([0.0] + [g.length for g in segs]) / spec.speed_mps + spec.t0_s
    spans = np.array([[cum[i], cum[i + 1]] for i, g in enumerate(segs) if g.kind == "line"])
    scanning_turns = spec.passes != "strips"  # a strip flight records on the strips only
    out_t, out_a, out_r, out_n, out_c, out_x, out_o, out_s = [], [], [], [], [], [], [], []
    for l0 in range(0, n_lines, lines_per_chunk):
        starts = spec.t0_s + np.arange(l0, min(l0 + lines_per_chunk, n_lines)) / sc.lines_per_s
        t, alpha = sc.pulse_times_and_angles(starts)
        sid = line_of_seg[motion.segment_of(t)]
        if not scanning_turns:
            t, alpha, sid = t[sid >= 0], alpha[sid >= 0], sid[sid >= 0]
        p, _, r = motion(t)
        o = p + r @ mount_true.lever_arm_m
        d = np.einsum("nij,nj->ni", r, sensor_from_polar(np.ones_like(alpha), alpha) @ b_true.T)
        rng_m, nrm, comp = scene.cast(o, d, sc.range_max_m)
        keep = np.isfinite(rng_m) & (rng_m >= sc.range_min_m)
        out_t.append(t[keep])
        out_a.append(alpha[keep])
        out_r.append(rng_m[keep])
        out_n.append(nrm[keep])
        out_c.append(comp[keep])
        out_x.append(o[keep] + rng_m[keep, None] * d[keep])
        out_o.append(d[keep])
        out_s.append(sid[keep])
    t_true = np.concatenate(out_t)
    if t_true.size == 0:
        raise GeometryError("no pulse of the simulated flight hits the bridge or the ground")
    alpha = np.concatenate(out_a)
    r_true = np.concatenate(out_r)
    normal = np.concatenate(out_n)
    comp = np.concatenate(out_c)
    truth = np.concatenate(out_x)
    n_ret = len(t_true)
    if err.surface_roughness_m:  # an independent stream: the other draws stay as they were
        beam0 = np.concatenate(out_o)
        cos_i = np.maximum(np.abs(np.einsum("ij,ij->i", beam0, normal)), np.cos(np.radians(85.0)))
        dr = np.random.default_rng([spec.seed, 5]).normal(0.0, err.surface_roughness_m, n_ret) / cos_i
        r_true = r_true + dr
        truth = truth + dr[:, None] * beam0
    r_rec = r_true + err.range_bias_m + (rng.normal(0.0, err.range_sigma_m, n_ret) if err.range_sigma_m else 0.0)
    if err.range_scale_ppm:
        r_rec = r_rec + r_true * err.range_scale_ppm * 1e-6
    r_rec = np.maximum(r_rec, 0.0)
    if err.scan_angle_sigma_rad:  # an independent stream: the other draws stay as they were
        alpha = alpha + np.random.default_rng([spec.seed, 4]).normal(0.0, err.scan_angle_sigma_rad, n_ret)
    # intensity: reflectivity x cosine of the incidence angle, weaker with range, with a little noise
    beam = np.concatenate(out_o)
    cosi = np.abs(np.einsum("ij,ij->i", beam, normal))
    inten = 300.0 + 5000.0 * scene.reflectivity(comp) * cosi * np.sqrt(10.0 / np.maximum(r_true, 10.0))
    inten = np.clip(np.round(inten + rng.normal(0.0, 20.0, n_ret)), 0, 65535)
    scan = RawScan(t_true + err.time_offset_s, r_rec, alpha, None, inten, np.concatenate(out_s))
    # ---- recorded trajectory
    tr = t_traj - spec.t0_s
    w = _wander(rng, err.gnss_wander_m)
    dw, dwv = _wander_at(w, tr)
    gnss = dw + np.asarray(err.gnss_bias_m) + rng.normal(0.0, 1.0, pos.shape) * np.asarray(err.gnss_noise_m)
    # per-strip trajectory errors (an independent stream: the other draws stay as they were)
    strips = _strip_errors(err, np.random.default_rng([spec.seed, 3]), spans)
    sp, sv = _strip_error_at(strips, "position", t_traj)
    gnss = gnss + sp
    dwv = dwv + sv
    ned_rec = ned_true
    if np.any([np.any(s_["attitude_offset_rad"]) or np.any(s_["attitude_drift_radps"]) for s_ in strips]):
        from skyrig.geometry.rotations import matrix_from_rotvec

        sa, _ = _strip_error_at(strips, "attitude", t_traj)
        ned_rec = _ned_from_local_body(frame, pos, matrix_from_rotvec(sa) @ lfb)
    imu_noise = rng.normal(0.0, 1.0, (len(t_traj), 3)) * np.asarray(err.imu_noise_rad)
    if np.any(imu_noise):
        r0, p0, y0 = rpy_from_matrix(ned_true, unit="rad")
        ned_rec = matrix_from_rpy(r0 + imu_noise[:, 0], p0 + imu_noise[:, 1], y0 + imu_noise[:, 2], unit="rad")
    if err.heading_error_rad:
        ned_rec = rot_z(err.heading_error_rad) @ ned_rec
    traj_rec = _trajectory(frame, t_traj, pos + gnss, vel + dwv, ned_rec)
    # ---- barometer: true ellipsoidal IMU heights + bias + noise, at the trajectory's times
    baro = traj_true.h_m + err.baro_bias_m + (rng.normal(0.0, err.baro_noise_m, len(t_traj)) if err.baro_noise_m else 0.0)
    # ---- the terrestrial reference scan
    uv = pos[:, :2] @ scene.local_from_bridge[:2, :2]
    u_range = (float(uv[:, 0].min()) - 5.0, float(uv[:, 0].max()) + 5.0)
    rv = scene.width_m / 2 + reference_reach_m(spec)
    ref_rng = np.random.default_rng([spec.seed, 2])  # independent stream: the reference does not change with errors
    ref, ref_n = scene.sample_surfaces(ref_rng, spec.reference_density_per_m2, spec.reference_ground_density_per_m2,
                                       spec.reference_noise_m, u_range, (-rv, rv))
    injected = {
        "boresight_rad": np.asarray(err.boresight_rad, float), "lever_arm_error_m": np.asarray(err.lever_arm_error_m),
        "heading_error_rad": err.heading_error_rad, "heading_correction_rad": -err.heading_error_rad,
        "mount_true": {"body_from_scanner": mount_true.body_from_scanner, "lever_arm_m": mount_true.lever_arm_m},
        "mount_recorded": {"body_from_scanner": mount_rec.body_from_scanner, "lever_arm_m": mount_rec.lever_arm_m},
        "range_offset_m": err.range_bias_m, "range_scale_ppm": err.range_scale_ppm,
        "camera_boresight_rad": np.asarray(err.camera_boresight_rad, float),
        "strips": strips,
        "strips_note": ("recorded = true + offset + drift x (t - t_mid_s): positions in the local ENU frame; attitudes "
                        "as recorded local_from_body = expmap(offset + drift x (t - t_mid_s)) @ true; the corrections "
                        "a strip adjustment estimates are their negatives"),
        "gnss_wander": {k_: v for k_, v in w.items()},
        "gnss_error_rms_m": np.sqrt(np.mean(gnss**2, axis=0)),
        "motion": {"wobble_phase_rad": motion.wob_phase, "wobble_rad_s": wob_w, "attitude_phase_rad": motion.att_phase,
                   "attitude_rad_s": att_w, "duration_s": n_lines / sc.lines_per_s, "scan_lines": n_lines},
    }
    return LidarSurvey(spec, scene, frame, traj_true, traj_rec, t_traj.copy(), np.asarray(baro, float), mount_true,
                       mount_rec, scan, t_true, r_true, truth, normal, comp, ref, ref_n, injected,
                       n_lines * sc.pulses_per_line, spans)
