"""Laser points as observations of the adjustment (issue 34): LiDAR and camera in one block.

Model
-----
A laser point ``i`` (pulse time ``t``, recorded range ``rho_rec``, unit beam ``u`` in the scanner frame from its
scan angle, strip ``k``) is georeferenced in the block's frame from the recorded trajectory pose at the pulse
time (``P(t)``, ``R(t)`` = ``world_from_body``) and the unknowns (paper 002 eqs 1-4, the model of
:mod:`skyrig.lidar.strips`)::

    rho = (rho_rec - range_offset) / (1 + range_scale)                           range correction
    x_b = lever_nominal + dlever + B_nominal expmap(boresight) (rho u)            body frame
    X   = P(t) + dp_k + dv_k tau + expmap(da_k + dw_k tau) R(t) x_b,  tau = t - t_k  (t_k: strip epoch)

Every point lies on a plane; the observation is the point-to-plane distance (computed minus zero):

* a **patch** plane (``plane_point = -1``) seen by overlapping strips: ``r = n . (X - c) - d`` with the plane
  ``(n, d)`` a nuisance unknown (strip adjustment);
* a **tie** plane (``plane_point = j``): the local plane of the image block's tie point ``j`` (an object point of
  the adjustment, so images and laser share it), ``r = n . (X - X_j)``, the normal a nuisance unknown.  The
  points ``j`` are estimated in the reduced part (:meth:`Lidar.reduced_points`, ``Layout.rpoint``): a row that
  touches the scanner's unknowns and a tie point cannot be eliminated with the points.

* **control** on a patch plane (optional, ``LidarPoints.control_*``): points of a reference cloud (a terrestrial
  scan registered to the survey's control, a surveyor's control planes) on the same surface, fixed observations of
  the plane ``r = n . (y - c)`` with the noise ``control_sigma_m`` per point and ``control_plane_sigma_m`` common to
  the plane's points (the reference's own registration error): the datum of the laser block that no calibration
  without control has (the trajectory's absolute accuracy).  Kept as moments per plane (count, sum, second
  moments about the plane's reference point): a plane's control enters its reduction as 4 square-root rows
  (:func:`control_gram`, shared with :mod:`skyrig.lidar.strips`); :func:`control_residuals` tests each control plane
  against the laser's own plane (a blunder shows as a large normalised residual).

Unknowns declared here (:class:`~skyrig.adjust.factors.base.ParameterGroup`)
----------------------------------------------------------------------------
* ``lidar_scanner`` (one owner, ``scanner``): boresight (rotation vector, scanner frame, rad), lever-arm
  correction (body frame, m), range offset (m), range scale (dimensionless);
* ``lidar_strip`` (one owner per strip ``strip<k>``): position offset and drift (block frame, m and m/s),
  attitude offset and drift (rotation vector, block frame, rad and rad/s).

The trajectory's accuracy enters as priors of ``lidar_strip`` (mode ``"weighted"`` with ``group_sigma``), the
calibration's nominal values as wide priors of ``lidar_scanner`` or none (``"free"``); see
:func:`lidar_unknowns`.  The camera's boresight, IO and the image orientations are the block's own unknowns.

Stochastic model
----------------
The variance of a point-to-plane distance is propagated from range noise (along the beam), scan-angle noise
(across the beam in the scan plane), white trajectory noise (position, and attitude times the lever from the body
origin) and a surface roughness::

    s^2 = (s_r^2 + s_rough^2 / b0^2) (n.u_w)^2 / (1 + range_scale)^2 + s_a^2 rho^2 (n.u'_w)^2 + s_p^2
          + s_att^2 |y x n|^2 + s_rough^2 (1 - g0^2 / b0^2),      b0 = max(|g0|, 0.1)

with ``u_w``, ``u'_w`` the beam and its derivative by the scan angle in the block frame and ``y = R x_b``.  The
roughness is where the beam met the rough surface, an error of the measured range of sigma ``s_rough / |g0|``
(:func:`roughness_variances`, shared with :mod:`skyrig.lidar.strips`), ``g0 = n0 . u_w`` a constant of the point:
its beam against its plane's starting fit (nominal calibration, no strip corrections; ``LidarPoints.incidence0``);
beams within ~6 deg of their plane keep the rest of it across the plane.  (With the roughness across the plane the
range's deviation it causes stays in the range-scale, plane-tilt and boresight columns correlated with the
residual, an errors-in-variables bias where the floor is most of a grazing beam's variance: the joint range scale
came out +0.47 sigma off on average over 20 seeds of the strips-ci flight.)

The Jacobians are those at the *adjusted observations* (Gauss-Helmert; :meth:`Lidar.point_rows`): the derivatives
of ``r / s`` with ``s`` a function of the unknowns and the plane.  At the recorded points (``s`` frozen,
``LidarPoints.linearise = "observed"``) the range noise, which lies along a slanted beam and not along the
normal, enters the plane's tilt and the range-scale, boresight and attitude columns correlated with the residual:
a bias of ``O(s^2)`` per point that does not shrink with the number of points (on the simulated bridge strip
flight the range scale came out +2.2 sigma off on average over 10 seeds; +0.22 at the adjusted observations).

Memory: one factor row per unknown of a plane, not per point
------------------------------------------------------------
Each plane's whitened rows ``[B | A | r]`` (``B``: the plane's nuisance columns, ``A``: the ``k`` unknowns it
touches) are reduced by a QR factorisation; the rows below the nuisance block, ``k + 1`` of them, carry exactly
the same normal equations and the same sum of squares as the plane's points with the plane eliminated (a Schur
complement in square-root form, the plane refitted at every evaluation: variable projection).  The factor has
``sum_planes (k_p + 1)`` rows whatever the number of points; ``Factor.n_extra`` counts the observations they
stand for in the redundancy.  (The points themselves are the data: a caller keeps a bounded number per plane and
strip, as :mod:`skyrig.lidar.strips` does.)  The points are georeferenced with their Jacobians a chunk of whole
planes at a time (:func:`plane_chunks`, :data:`CHUNK_POINTS`), and the rows of a plane, which share their columns,
enter the normal equations as one ``k x k`` block per column set (:func:`skyrig.adjust.schur_engine.set_normals`),
not one per row: the adjustment's memory grows with the planes (and the largest plane's points), not with the
laser points.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.factors import register, register_group
from skyrig.adjust.factors.base import (BlockError, Factor, ObservationType, ParameterGroup, check_finite,
                                        check_index)
from skyrig.adjust.factors.rolling_shutter import right_jacobian
from skyrig.geometry.rotations import matrix_from_rotvec, rotvec_from_matrix, skew

if TYPE_CHECKING:  # pragma: no cover
    from skyrig.adjust.block import Block
    from skyrig.adjust.config import Unknowns
    from skyrig.adjust.model import Model, State

__all__ = ["LidarPoints", "Lidar", "LidarScanner", "LidarStrip", "lidar_unknowns", "georeference", "NAME", "SCANNER",
           "STRIP", "SCANNER_COMPONENTS", "STRIP_COMPONENTS", "GRAZING_INCIDENCE", "roughness_variances", "plane_basis",
           "control_gram", "control_residuals", "ControlResiduals"]

NAME = "lidar"
SCANNER = "lidar_scanner"
STRIP = "lidar_strip"
SCANNER_COMPONENTS = ("bore_x_rad", "bore_y_rad", "bore_z_rad", "lever_x_m", "lever_y_m", "lever_z_m",
                      "range_offset_m", "range_scale")
STRIP_COMPONENTS = ("dp_x_m", "dp_y_m", "dp_z_m", "dv_x_m_s", "dv_y_m_s", "dv_z_m_s", "da_x_rad", "da_y_rad",
                    "da_z_rad", "dw_x_rad_s", "dw_y_rad_s", "dw_z_rad_s")
NS, NK = len(SCANNER_COMPONENTS), len(STRIP_COMPONENTS)


@dataclass
class LidarPoints:
    """Laser points on planes (rows of the ``lidar`` type, ``block.observations["lidar"]``).

    Attributes
    ----------
    time_s, strip, range_m
        ``(N,)`` pulse time (s, the trajectory's time scale), strip index, recorded range (m).
    beam, beam_dangle
        ``(N, 3)`` unit beam direction in the scanner frame (from the scan angle) and its derivative by the scan
        angle (per rad).
    plane
        ``(N,)`` plane index of each point.
    position_m, rotation
        ``(N, 3)`` trajectory position (IMU origin, block frame, m) and ``(N, 3, 3)`` ``world_from_body`` at the
        pulse time.
    plane_point
        ``(Q,)`` per plane: -1 for a patch plane, else the object point (tie point) the plane passes through.
    strip_epoch_s
        ``(K,)`` reference time of each strip's drifts (s).
    body_from_scanner, lever_arm_m
        ``(3, 3)`` nominal mounting (a rotation: right-handed) and ``(3,)`` nominal lever arm (body frame, m).
    range_sigma_m, angle_sigma_rad, position_sigma_m, attitude_sigma_rad, roughness_m
        The stochastic model (module docstring), one sigma each.
    """

    time_s: Any
    strip: Any
    range_m: Any
    beam: Any
    beam_dangle: Any
    plane: Any
    position_m: Any
    rotation: Any
    plane_point: Any
    strip_epoch_s: Any
    body_from_scanner: Any
    lever_arm_m: Any
    range_sigma_m: float = 0.02
    angle_sigma_rad: float = 0.0
    position_sigma_m: float = 0.0
    attitude_sigma_rad: float = 0.0
    roughness_m: float = 0.002
    #: stations of the block flown on the same trajectory (camera exposures): ``(S,)`` station index, strip,
    #: time (s), recorded trajectory position ``(S, 3)`` and ``world_from_body`` ``(S, 3, 3)``; the station pose
    #: is observed as the recorded pose corrected by its strip's corrections (the factor ``lidar:trajectory``),
    #: with white noise ``station_position_sigma_m`` / ``station_attitude_sigma_rad``: images and laser share
    #: the trajectory's errors
    station: Any = None
    station_strip: Any = None
    station_time_s: Any = None
    station_position_m: Any = None
    station_rotation: Any = None
    station_position_sigma_m: float = 0.005
    station_attitude_sigma_rad: float = 2e-5
    #: ``(N, 1)`` sigma placeholder for reports (the rows are per plane; not used by variance components)
    sigma: Any = None
    #: where the Jacobians are evaluated: ``"adjusted"`` (the Gauss-Helmert adjusted observations, unbiased) or
    #: ``"observed"`` (the recorded points, sigmas frozen: biased by the noise along slanted beams); see
    #: :meth:`Lidar.point_rows`
    linearise: str = "adjusted"
    #: ``(N,)`` ``n0 . beam`` of each point at its plane's starting fit (nominal calibration, no strip corrections,
    #: the plane through its points unweighted): the constant that makes the roughness an error of the range
    #: (:func:`roughness_variances`); computed at first use (:meth:`incidence`) when None
    incidence0: Any = None
    #: control per plane (module docstring): ``(Q,)`` counts, ``(Q, 3)`` sums and ``(Q, 3, 3)`` second moments of
    #: the reference points ``y - control_ref`` (``(Q, 3)``, e.g. the patch centres); None: no control
    control_count: Any = None
    control_sum: Any = None
    control_sum2: Any = None
    control_ref: Any = None
    control_sigma_m: float = 0.003  # one control point's noise across its surface
    control_plane_sigma_m: float = 0.0  # common to a plane's control points (the reference's registration)

    def __len__(self) -> int:
        return len(self.time_s)

    def incidence(self, rows: NDArray[np.int64] | slice = slice(None)) -> NDArray[np.float64]:
        """``n0 . beam`` of the points ``rows`` (:attr:`incidence0`, computed once for all points)."""
        if self.incidence0 is None:
            geo = georeference(self, np.zeros(NS), np.zeros((self.n_strips, NK)))
            self.incidence0 = np.einsum("ni,ni->n", _start_normals(self, geo["X"]), geo["beam_w"])
        return np.asarray(self.incidence0)[rows]

    @property
    def n_planes(self) -> int:
        return len(self.plane_point)

    @property
    def n_strips(self) -> int:
        return len(self.strip_epoch_s)

    def normalise(self, block: "Block") -> None:
        self.time_s = np.asarray(self.time_s, float).reshape(-1)
        n = len(self.time_s)
        self.strip = np.asarray(self.strip, np.int64).reshape(n)
        self.range_m = np.asarray(self.range_m, float).reshape(n)
        self.beam = np.asarray(self.beam, float).reshape(n, 3)
        self.beam_dangle = np.asarray(self.beam_dangle, float).reshape(n, 3)
        self.plane = np.asarray(self.plane, np.int64).reshape(n)
        self.position_m = np.asarray(self.position_m, float).reshape(n, 3)
        self.rotation = np.asarray(self.rotation, float).reshape(n, 3, 3)
        self.plane_point = np.asarray(self.plane_point, np.int64).reshape(-1)
        self.strip_epoch_s = np.asarray(self.strip_epoch_s, float).reshape(-1)
        self.body_from_scanner = np.asarray(self.body_from_scanner, float).reshape(3, 3)
        self.lever_arm_m = np.asarray(self.lever_arm_m, float).reshape(3)
        self.sigma = np.full((n, 1), float(self.range_sigma_m))
        self.station = np.zeros(0, np.int64) if self.station is None else np.asarray(self.station, np.int64).reshape(-1)
        m = len(self.station)
        self.station_strip = np.asarray(self.station_strip if m else np.zeros(0), np.int64).reshape(m)
        self.station_time_s = np.asarray(self.station_time_s if m else np.zeros(0), float).reshape(m)
        self.station_position_m = np.asarray(self.station_position_m if m else np.zeros(0), float).reshape(m, 3)
        self.station_rotation = np.asarray(self.station_rotation if m else np.zeros(0), float).reshape(m, 3, 3)
        q = len(self.plane_point)
        if self.control_count is not None:
            self.control_count = np.asarray(self.control_count, float).reshape(q)
            self.control_sum = np.asarray(self.control_sum, float).reshape(q, 3)
            self.control_sum2 = np.asarray(self.control_sum2, float).reshape(q, 3, 3)
            self.control_ref = np.asarray(self.control_ref, float).reshape(q, 3)

    @property
    def has_control(self) -> NDArray[np.bool_]:
        """``(Q,)`` planes with control (at least 3 reference points)."""
        if self.control_count is None:
            return np.zeros(self.n_planes, bool)
        return np.asarray(self.control_count, float) >= 3

    def validate(self, block: "Block") -> None:
        w = f"observations['{NAME}']"
        for nm in ("time_s", "range_m", "beam", "beam_dangle", "position_m", "rotation", "strip_epoch_s"):
            check_finite(f"{w}.{nm}", getattr(self, nm))
        check_index(f"{w}.strip", self.strip, self.n_strips, "strip")
        check_index(f"{w}.plane", self.plane, self.n_planes, "plane")
        tie = self.plane_point[self.plane_point >= 0]
        check_index(f"{w}.plane_point", tie, block.n_points, "point")
        nb = np.abs(np.linalg.norm(self.beam, axis=1) - 1.0)
        if len(nb) and nb.max() > 1e-6:
            raise BlockError(f"{w}.beam[{int(np.argmax(nb))}] is not a unit vector")
        m = self.body_from_scanner
        if not np.allclose(m @ m.T, np.eye(3), atol=1e-9) or np.linalg.det(m) < 0:
            raise BlockError(f"{w}.body_from_scanner is not a rotation (det {np.linalg.det(m):+.3f}): a scanner frame "
                             "with a left-handed axis set must be turned right-handed (flip one axis) first")
        det = np.linalg.det(self.rotation) if len(self) else np.ones(0)
        if len(det) and (np.abs(det - 1.0) > 1e-6).any():
            raise BlockError(f"{w}.rotation[{int(np.argmax(np.abs(det - 1.0)))}] is not a rotation")
        if self.linearise not in ("adjusted", "observed"):
            raise BlockError(f"{w}.linearise must be 'adjusted' or 'observed', got {self.linearise!r}")
        for nm in ("range_sigma_m", "angle_sigma_rad", "position_sigma_m", "attitude_sigma_rad", "roughness_m"):
            v = float(getattr(self, nm))
            if not (np.isfinite(v) and v >= 0):
                raise BlockError(f"{w}.{nm} must be >= 0 (a standard deviation), got {v!r}")
        if self.range_sigma_m + self.roughness_m <= 0:
            raise BlockError(f"{w}: range_sigma_m and roughness_m are both zero: the point-to-plane sigma needs one")
        check_index(f"{w}.station", self.station, block.n_stations, "station")
        check_index(f"{w}.station_strip", self.station_strip, self.n_strips, "strip")
        for nm in ("station_time_s", "station_position_m", "station_rotation"):
            check_finite(f"{w}.{nm}", getattr(self, nm))
        if len(self.station) and not (self.station_position_sigma_m > 0 and self.station_attitude_sigma_rad > 0):
            raise BlockError(f"{w}: station_position_sigma_m and station_attitude_sigma_rad must be > 0")
        if self.control_count is not None:
            for nm in ("control_count", "control_sum", "control_sum2", "control_ref"):
                check_finite(f"{w}.{nm}", getattr(self, nm))
            if (self.control_count < 0).any() or (self.control_count[self.plane_point >= 0] > 0).any():
                raise BlockError(f"{w}.control_count: negative, or control on a tie plane (control is for patch planes)")
            for nm in ("control_sigma_m", "control_plane_sigma_m"):
                v = float(getattr(self, nm))
                if not (np.isfinite(v) and v >= 0):
                    raise BlockError(f"{w}.{nm} must be >= 0 (a standard deviation), got {v!r}")
            if self.control_sigma_m + self.control_plane_sigma_m <= 0:
                raise BlockError(f"{w}: control_sigma_m and control_plane_sigma_m are both zero")
        counts = np.bincount(self.plane, minlength=self.n_planes)
        need = np.where(self.plane_point >= 0, 3, 4)
        bad = np.flatnonzero(counts < need)
        if bad.size:
            raise BlockError(f"{w}: plane {int(bad[0])} has {int(counts[bad[0]])} points (a patch plane needs 4, a "
                             "tie plane 3)")


    def without(self, drop_points: NDArray[np.bool_] | None = None, drop_planes: NDArray[np.bool_] | None = None
                ) -> "LidarPoints":
        """A copy without the points ``drop_points (N,)`` and the planes ``drop_planes (Q,)`` (and their points);
        planes left with too few points (3 for a tie plane, 4 for a patch) go as well; the rest renumbered."""
        keep = np.ones(len(self), bool) if drop_points is None else ~np.asarray(drop_points, bool)
        keep_pl = np.ones(self.n_planes, bool) if drop_planes is None else ~np.asarray(drop_planes, bool)
        cnt = np.bincount(self.plane[keep], minlength=self.n_planes)
        keep_pl &= cnt >= np.where(self.plane_point >= 0, 3, 4)
        new = np.cumsum(keep_pl) - 1
        k = keep & keep_pl[self.plane]
        return replace(self, time_s=self.time_s[k], strip=self.strip[k], range_m=self.range_m[k], beam=self.beam[k],
                       beam_dangle=self.beam_dangle[k], plane=new[self.plane[k]], position_m=self.position_m[k],
                       rotation=self.rotation[k], plane_point=self.plane_point[keep_pl], sigma=None,
                       incidence0=None if self.incidence0 is None else np.asarray(self.incidence0)[k],
                       **({} if self.control_count is None else {
                           nm: np.asarray(getattr(self, nm))[keep_pl] for nm in
                           ("control_count", "control_sum", "control_sum2", "control_ref")}))

    def without_control(self, drop: NDArray[np.bool_]) -> "LidarPoints":
        """A copy with the control of the planes ``drop (Q,)`` removed (the planes and their laser points kept)."""
        if self.control_count is None:
            return self
        keep = ~np.asarray(drop, bool)
        return replace(self, control_count=self.control_count * keep, control_sum=self.control_sum * keep[:, None],
                       control_sum2=self.control_sum2 * keep[:, None, None])


#: Below this ``|n . beam|`` (a beam within ~6 deg of its plane) the roughness is not all an error of the range.
GRAZING_INCIDENCE = 0.1


def roughness_variances(roughness_m: float, incidence: NDArray[np.float64]
                        ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A laser point's surface roughness as an error of its measured range.

    The beam meets a rough surface ``N(0, roughness)`` off the mean plane along its normal, which lengthens the
    measured range by that height over ``|n . beam|``: a range error of variance ``(roughness / |n . beam|)^2``,
    moving the point along its beam, not across the plane.  For beams within ~6 deg of the plane
    (``|n . beam| <`` :data:`GRAZING_INCIDENCE`) the range's share is capped and the rest is left across the plane,
    so that the total across the plane stays ``roughness^2``.  The joint laser factor (:class:`Lidar`) and the
    laser-only strip adjustment (:func:`skyrig.lidar.strips.plane_residuals`) both take their roughness from here.

    Parameters
    ----------
    roughness_m
        One sigma of the surface's height about its plane (m).
    incidence
        ``(n,)`` ``n . beam`` of each point (a constant of the point: its beam against its plane's starting fit).

    Returns
    -------
    range_var, normal_var
        ``(n,)`` variance added to the measured range (m^2) and variance left across the plane (m^2).
    """
    g = np.asarray(incidence, dtype=np.float64)
    b0 = np.maximum(np.abs(g), GRAZING_INCIDENCE)
    return (roughness_m / b0) ** 2, roughness_m ** 2 * (1.0 - (g / b0) ** 2)


def _data(block: Any) -> LidarPoints | None:
    return block.observations.get(NAME)


class LidarScanner(ParameterGroup):
    """The laser scanner's calibration: boresight, lever-arm correction, range offset and scale."""

    name = SCANNER
    components = SCANNER_COMPONENTS
    words = "laser scanner calibration (boresight, lever arm, range offset and scale)"

    def owners(self, block: Any) -> list[str]:
        return ["scanner"]

    def estimated(self, block: Any) -> bool:
        return _data(block) is not None


class LidarStrip(ParameterGroup):
    """Per-strip corrections of the trajectory under the laser: position/attitude offsets and drifts."""

    name = STRIP
    components = STRIP_COMPONENTS
    words = "per-strip trajectory correction of the laser (offsets and drifts)"

    def owners(self, block: Any) -> list[str]:
        d = _data(block)
        return [] if d is None else [f"strip{k}" for k in range(d.n_strips)]

    def estimated(self, block: Any) -> bool:
        return _data(block) is not None


def georeference(d: LidarPoints, scanner: NDArray[np.float64], strips: NDArray[np.float64], jac: bool = False,
                 rows: NDArray[np.int64] | slice = slice(None)) -> dict[str, NDArray[np.float64]]:
    """Laser points in the block frame from the unknowns (module docstring).

    Parameters
    ----------
    d
        The laser points.
    scanner, strips
        ``(8,)`` scanner calibration and ``(K, 12)`` strip corrections (the groups' component order).
    jac
        Also return the Jacobians ``dX/dscanner (n, 3, 8)`` and ``dX/dstrip (n, 3, 12)``.
    rows
        The points to georeference (default all).

    Returns
    -------
    dict
        ``X (n, 3)``, ``beam_w (n, 3)``, ``dbeam_w (n, 3)`` (beam and its scan-angle derivative, block frame),
        ``rho (n,)``, ``y (n, 3)`` (``R x_b``, the body-to-point vector), ``rows (n,)`` (the points' indices), and
        ``JS``, ``JK`` when ``jac``.
    """
    st = d.strip[rows]
    tau = d.time_s[rows] - d.strip_epoch_s[st]
    sc = np.asarray(scanner, float)
    bore, dl, off, scale = sc[0:3], sc[3:6], sc[6], sc[7]
    Eb = matrix_from_rotvec(bore)
    Bc = d.body_from_scanner @ Eb
    rho = (d.range_m[rows] - off) / (1.0 + scale)
    xs = rho[:, None] * d.beam[rows]
    xb = d.lever_arm_m + dl + xs @ Bc.T
    R = d.rotation[rows]
    y = np.einsum("nij,nj->ni", R, xb)
    S = np.asarray(strips, float)[st]
    g = S[:, 6:9] + S[:, 9:12] * tau[:, None]
    E = matrix_from_rotvec(g)
    X = d.position_m[rows] + S[:, 0:3] + S[:, 3:6] * tau[:, None] + np.einsum("nij,nj->ni", E, y)
    ER = E @ R
    ERB = ER @ Bc
    out = {"X": X, "beam_w": np.einsum("nij,nj->ni", ERB, d.beam[rows]),
           "dbeam_w": np.einsum("nij,nj->ni", ERB, d.beam_dangle[rows]), "rho": rho, "y": np.einsum("nij,nj->ni", E, y),
           "gain": np.full(len(rho), 1.0 / (1.0 + scale)), "tau": tau, "rows": np.arange(len(d))[rows]}
    if not jac:
        return out
    n = len(rho)
    # the beam and its scan-angle derivative (block frame) by the boresight and the strip's attitude offset
    Jr_b, Jr_g = right_jacobian(bore[None])[0], right_jacobian(g)
    for key, u in (("U", d.beam[rows]), ("D", d.beam_dangle[rows])):
        out[f"J{key}_bore"] = -(ERB @ skew(u)) @ Jr_b
        out[f"J{key}_att"] = -(E @ skew(np.einsum("nij,nj->ni", R @ Bc, u))) @ Jr_g
    JS = np.empty((n, 3, NS))
    JS[:, :, 0:3] = -(ERB @ skew(xs)) @ right_jacobian(bore[None])[0]
    JS[:, :, 3:6] = ER
    JS[:, :, 6] = out["beam_w"] * (-1.0 / (1.0 + scale))
    JS[:, :, 7] = out["beam_w"] * (-(d.range_m[rows] - off) / (1.0 + scale) ** 2)[:, None]
    JK = np.zeros((n, 3, NK))
    JK[:, [0, 1, 2], [0, 1, 2]] = 1.0
    JK[:, [0, 1, 2], [3, 4, 5]] = tau[:, None]
    Ja = -(E @ skew(y)) @ right_jacobian(g)
    JK[:, :, 6:9] = Ja
    JK[:, :, 9:12] = Ja * tau[:, None, None]
    out["JS"], out["JK"] = JS, JK
    return out


@dataclass
class _Planes:
    """Per-model constants: points sorted by plane, plane offsets, strips per plane."""

    order: NDArray[np.int64]
    ptr: NDArray[np.int64]
    strips: list[NDArray[np.int64]]
    width: int


#: laser points georeferenced (with their Jacobians) at once by :meth:`Lidar.evaluate`: whole planes up to about
#: this many points per chunk, so that the evaluation's memory does not grow with the number of points
CHUNK_POINTS = 8192


def _sorted_planes(d: LidarPoints) -> _Planes:
    """The points sorted by plane (stable), the planes' offsets and strips, the factor rows' width."""
    order = np.argsort(d.plane, kind="stable")
    ptr = np.concatenate([[0], np.cumsum(np.bincount(d.plane, minlength=d.n_planes))])
    strips = [np.unique(d.strip[order[ptr[p]:ptr[p + 1]]]) for p in range(d.n_planes)]
    smax = max([len(s) for s in strips] + [0])
    return _Planes(order, ptr, strips, NS + NK * smax + 3)


def plane_chunks(pc: _Planes, n_planes: int, max_points: int | None = None):
    """``(p0, p1, rows)``: runs of whole planes ``p0 .. p1 - 1`` of about ``max_points`` points
    (:data:`CHUNK_POINTS`; a larger plane alone), ``rows`` their points in plane order (each plane's points in
    their own order)."""
    m = CHUNK_POINTS if max_points is None else max_points
    p0 = 0
    while p0 < n_planes:
        p1 = int(np.searchsorted(pc.ptr, pc.ptr[p0] + m, side="right")) - 1
        p1 = min(max(p1, p0 + 1), n_planes)
        yield p0, p1, pc.order[pc.ptr[p0]:pc.ptr[p1]]
        p0 = p1


def _projected_ss(r: NDArray, B: NDArray, plane: NDArray, is_tie: NDArray, q: int, G: NDArray | None = None
                  ) -> NDArray[np.float64]:
    """Per plane ``(Q,)``: ``|r|^2 - |P_B r|^2``, the sum of squares left with the plane's columns ``B (n, 3)``
    eliminated (a tie plane's two tilts, a patch plane's tilts and offset); ``G (Q, 4, 4)``: the control's rows
    (:func:`control_gram`) added."""
    Bt = np.where(is_tie[plane][:, None], B * [1.0, 1.0, 0.0], B)
    N = np.zeros((q, 3, 3))
    np.add.at(N, plane, Bt[:, :, None] * Bt[:, None, :])
    g = np.column_stack([np.bincount(plane, Bt[:, j] * r, q) for j in range(3)])
    rr = np.bincount(plane, r**2, q)
    if G is not None:
        N += G[:, :3, :3]
        g += G[:, :3, 3]
        rr += G[:, 3, 3]
    N[is_tie, 2, 2] = 1.0
    ss = rr - np.einsum("qi,qi->q", g, np.linalg.solve(N, g[:, :, None])[:, :, 0])
    return np.maximum(ss, 0.0)


def _start_normals(d: LidarPoints, X: NDArray) -> NDArray[np.float64]:
    """``(N, 3)`` each point's plane normal at the nominal georeferencing ``X``, fitted to the points of its own strip
    on the plane (strips disagree by their trajectory and calibration errors until adjusted: centimetres over a patch
    of a metre or two tilt a fit of all strips by degrees); the fit of all its strips where its own strip's points on
    the plane are fewer than 5 or nearly collinear."""
    q, k = d.n_planes, max(d.n_strips, 1)
    n_all, _ = _fit_planes(X, np.ones(len(X)), d.plane, np.zeros((q, 3)), np.zeros(q, bool), q)
    g = d.plane * k + d.strip
    ug, grp = np.unique(g, return_inverse=True)
    m = len(ug)
    cnt = np.bincount(grp, minlength=m)
    c = np.column_stack([np.bincount(grp, X[:, j], m) for j in range(3)]) / cnt[:, None]
    dx = X - c[grp]
    S = np.zeros((m, 3, 3))
    np.add.at(S, grp, dx[:, :, None] * dx[:, None, :])
    w, V = np.linalg.eigh(S)
    ok = (cnt >= 5) & (w[:, 1] > 0.01 * w[:, 2])  # a patch of the strip, not a line of it
    n_grp = np.where(ok[:, None], V[:, :, 0], n_all[ug // k])
    return n_grp[grp]


def _fit_planes(X: NDArray, w: NDArray, plane: NDArray, anchor: NDArray, is_tie: NDArray, q: int,
                ctrl: tuple[NDArray, NDArray, NDArray] | None = None) -> tuple[NDArray, NDArray]:
    """Weighted planes ``(normal (Q, 3), centre (Q, 3))``: patch planes through their weighted centroid, tie planes
    through their anchor (the tie point); the normal minimises the weighted squared distances.  ``ctrl``: control
    points per plane as ``(weight sum (Q,), centroid (Q, 3), weighted scatter about it (Q, 3, 3))``."""
    sw = np.bincount(plane, w, q)
    sx = np.column_stack([np.bincount(plane, w * X[:, j], q) for j in range(3)])
    if ctrl is not None:
        sw = sw + ctrl[0]
        sx = sx + ctrl[0][:, None] * ctrl[1]
    c = sx / sw[:, None]
    c = np.where(is_tie[:, None], anchor, c)
    dx = X - c[plane]
    S = np.zeros((q, 3, 3))
    np.add.at(S, plane, w[:, None, None] * dx[:, :, None] * dx[:, None, :])
    if ctrl is not None:
        dc = ctrl[1] - c
        S += ctrl[2] + ctrl[0][:, None, None] * dc[:, :, None] * dc[:, None, :]
    _, V = np.linalg.eigh(S)
    return V[:, :, 0], c


def plane_basis(n: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Two unit tangents ``(t1, t2)`` ``(Q, 3)`` of unit normals ``n (Q, 3)`` (the tilt directions of a plane's
    nuisance unknowns here and in :mod:`skyrig.lidar.strips`)."""
    a = np.where(np.abs(n[:, 0:1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    t1 = np.cross(n, a)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return t1, np.cross(n, t1)


def _control_central(count: NDArray, s1: NDArray, s2: NDArray, ref: NDArray) -> tuple[NDArray, NDArray]:
    """Control centroid ``(Q, 3)`` and scatter about it ``(Q, 3, 3)`` (sum of ``(y - ybar)(y - ybar)^T``) from the
    moments of ``y - ref``."""
    c = np.maximum(count, 1.0)
    m = s1 / c[:, None]
    S = s2 - c[:, None, None] * m[:, :, None] * m[:, None, :]
    return ref + m, np.where((count > 0)[:, None, None], S, 0.0)


def control_gram(count: NDArray, s1: NDArray, s2: NDArray, ref: NDArray, normal: NDArray, point: NDArray,
                 offset: NDArray | float, sigma: float, plane_sigma: float = 0.0) -> NDArray[np.float64]:
    """Normal-equation blocks of control points on planes, from their moments.

    Each control point ``y`` of plane ``(normal n, point c, offset d)`` observes ``r = n . (y - c) - d`` with
    derivatives ``[t1 . (y - c), t2 . (y - c), -1]`` by the plane's two tilts (along :func:`plane_basis`) and its
    offset; its noise is ``sigma`` per point and ``plane_sigma`` common to the plane's points (the control's
    centroid has variance ``sigma^2 / count + plane_sigma^2``, its scatter about the centroid ``sigma^2`` per
    point).  Returns ``G (Q, 4, 4)``, the Gram matrix of the whitened rows ``[tilt1, tilt2, offset | r]``: ``G[:3,
    :3]`` the normal matrix, ``G[:3, 3]`` ``J^T r``, ``G[3, 3]`` the weighted squared residuals (zero where
    ``count`` is 0).  ``count (Q,)``, ``s1 (Q, 3)``, ``s2 (Q, 3, 3)``: counts, sums and second moments of ``y -
    ref`` (``ref (Q, 3)``).  The laser-only strip adjustment (:mod:`skyrig.lidar.strips`) and the joint factor
    (:class:`Lidar`) share it.
    """
    t1, t2 = plane_basis(normal)
    E = np.stack([t1, t2, normal], axis=1)
    ybar, S = _control_central(count, s1, s2, ref)
    Se = np.einsum("qai,qij,qbj->qab", E, S, E) / sigma**2
    G = np.zeros((len(count), 4, 4))
    ix = np.array([0, 1, 3])
    G[:, ix[:, None], ix[None, :]] = Se
    db = ybar - point
    v = np.column_stack([np.einsum("qi,qi->q", t1, db), np.einsum("qi,qi->q", t2, db), -np.ones(len(count)),
                         np.einsum("qi,qi->q", normal, db) - offset])
    wm = np.where(count > 0, count / (sigma**2 + count * plane_sigma**2), 0.0)
    return G + wm[:, None, None] * v[:, :, None] * v[:, None, :]


def _control_sqrt(G: NDArray) -> NDArray[np.float64]:
    """Square-root rows ``R (Q, 4, 4)`` with ``R^T R = G`` (``G`` positive semi-definite)."""
    w, V = np.linalg.eigh(G)
    return np.sqrt(np.maximum(w, 0.0))[:, :, None] * np.swapaxes(V, 1, 2)


def _control_fit_moments(d: LidarPoints, p0: int, p1: int) -> tuple[NDArray, NDArray, NDArray] | None:
    """The control of planes ``p0 .. p1 - 1`` for the weighted plane fit: each point weighted ``1 / (sigma^2 +
    count plane_sigma^2)`` (its centroid has the weight of its variance), ``(weight sum, centroid, scatter)``."""
    if d.control_count is None or not d.has_control[p0:p1].any():
        return None
    cnt = np.where(d.has_control[p0:p1], d.control_count[p0:p1], 0.0)
    ybar, S = _control_central(cnt, d.control_sum[p0:p1], d.control_sum2[p0:p1], d.control_ref[p0:p1])
    wc = 1.0 / (d.control_sigma_m**2 + cnt * d.control_plane_sigma_m**2)
    return cnt * wc, ybar, wc[:, None, None] * S


def _control_block(d: LidarPoints, p0: int, p1: int, normal: NDArray, centre: NDArray) -> NDArray | None:
    """:func:`control_gram` of planes ``p0 .. p1 - 1`` at the planes ``normal``, ``centre`` (offset 0), or None."""
    if d.control_count is None or not d.has_control[p0:p1].any():
        return None
    cnt = np.where(d.has_control[p0:p1], d.control_count[p0:p1], 0.0)
    return control_gram(cnt, d.control_sum[p0:p1], d.control_sum2[p0:p1], d.control_ref[p0:p1],
                        normal, centre, 0.0, d.control_sigma_m, d.control_plane_sigma_m)


class Lidar(ObservationType):
    """Laser points on planes: point-to-plane distances, reduced per plane (module docstring)."""

    name = NAME
    words = "laser point-to-plane"
    components = ("d",)
    units = "m"
    order = 47.0
    snooped = False
    share_checked = False
    datum_words = "the laser trajectory (laser points)"
    vce_split = None

    def reduced_points(self, block: "Block") -> NDArray[np.int64] | None:
        d = _data(block)
        if d is None:
            return None
        return np.unique(d.plane_point[d.plane_point >= 0])

    def initial_weight(self, block: "Block") -> None:
        return None  # rows per plane: not reweighted, not snooped

    def get_sigma(self, block: "Block") -> NDArray[np.float64]:
        return np.ones((0, 1))

    def set_sigma(self, block: "Block", value: NDArray[np.float64]) -> None:
        pass

    def prepare(self, model: "Model") -> _Planes:
        d = _data(model.block)
        assert d is not None
        return _sorted_planes(d)

    def point_sigma(self, d: LidarPoints, geo: dict[str, NDArray], normal: NDArray) -> NDArray[np.float64]:
        """``(n,)`` point-to-plane sigma (m) of points with georeferencing ``geo`` on planes of ``normal (n, 3)``."""
        nu = np.einsum("ni,ni->n", normal, geo["beam_w"]) * geo["gain"]
        nd = np.einsum("ni,ni->n", normal, geo["dbeam_w"]) * geo["rho"]
        ya = np.linalg.norm(np.cross(geo["y"], normal), axis=1)
        rough_rng, rough_nrm = roughness_variances(d.roughness_m, d.incidence(geo["rows"]))
        return np.sqrt((d.range_sigma_m ** 2 + rough_rng) * nu ** 2 + (d.angle_sigma_rad * nd) ** 2
                       + d.position_sigma_m ** 2 + (d.attitude_sigma_rad * ya) ** 2 + rough_nrm)

    def variance_derivatives(self, d: LidarPoints, geo: dict[str, NDArray], normal: NDArray, tangents: NDArray
                             ) -> dict[str, NDArray]:
        """Derivatives of the points' point-to-plane variance (:meth:`point_sigma` squared) by the plane's two
        tilts (``n -> n + delta t_k``, ``tangents (n, 2, 3)``): ``"tilt" (n, 2)``; and, when ``geo`` carries the
        Jacobians, by the scanner ``"scanner" (n, 8)`` and strip ``"strip" (n, 12)`` unknowns."""
        u, ud, y, rho, gain = geo["beam_w"], geo["dbeam_w"], geo["y"], geo["rho"], geo["gain"]
        # the recorded range's variance (noise and roughness, a constant of each point) in the corrected range
        cr = (d.range_sigma_m ** 2 + roughness_variances(d.roughness_m, d.incidence(geo["rows"]))[0]) * gain ** 2
        ca = d.angle_sigma_rad ** 2
        ct = d.attitude_sigma_rad ** 2
        nu = np.einsum("ni,ni->n", normal, u)
        nd = np.einsum("ni,ni->n", normal, ud)
        yn = np.einsum("ni,ni->n", y, normal)
        # var = cr nu^2 + ca rho^2 nd^2 + ct (|y|^2 - (y.n)^2) + const
        out = {"tilt": 2.0 * (cr * nu)[:, None] * np.einsum("nki,ni->nk", tangents, u)
               + 2.0 * (ca * rho**2 * nd)[:, None] * np.einsum("nki,ni->nk", tangents, ud)
               - 2.0 * (ct * yn)[:, None] * np.einsum("nki,ni->nk", tangents, y)}
        if "JS" not in geo:
            return out
        yp = 2.0 * ct * (y - yn[:, None] * normal)  # d |y x n|^2 / dy, times ct
        dS = np.einsum("ni,nik->nk", yp, geo["JS"])
        dS[:, 0:3] += 2.0 * (cr * nu)[:, None] * np.einsum("ni,nik->nk", normal, geo["JU_bore"]) \
            + 2.0 * (ca * rho**2 * nd)[:, None] * np.einsum("ni,nik->nk", normal, geo["JD_bore"])
        drho = -gain  # d rho / d range offset; d rho / d range scale = -rho gain
        dS[:, 6] += 2.0 * ca * rho * nd**2 * drho
        dS[:, 7] += 2.0 * ca * rho * nd**2 * drho * rho - 2.0 * cr * nu**2 * gain
        dK = np.zeros((len(rho), NK))
        dK[:, 6:12] = np.einsum("ni,nik->nk", yp, geo["JK"][:, :, 6:12])
        da = 2.0 * (cr * nu)[:, None] * np.einsum("ni,nik->nk", normal, geo["JU_att"]) \
            + 2.0 * (ca * rho**2 * nd)[:, None] * np.einsum("ni,nik->nk", normal, geo["JD_att"])
        tau = geo["tau"]
        dK[:, 6:9] += da
        dK[:, 9:12] += da * tau[:, None]
        out["scanner"], out["strip"] = dS, dK
        return out

    def point_rows(self, d: LidarPoints, geo: dict[str, NDArray], normal: NDArray, centre: NDArray, sig: NDArray
                   ) -> dict[str, NDArray]:
        """Whitened per-point rows at the planes ``normal (n, 3)`` / ``centre (n, 3)`` (per point): ``r (n,)``,
        the plane columns ``B (n, 3)`` (tilts along ``t1``, ``t2`` and the offset), the tangents ``T (n, 2, 3)``,
        and with the Jacobians in ``geo`` ``AS (n, 8)``, ``AK (n, 12)``.

        ``d.linearise == "adjusted"`` (default): the derivatives of ``r / sigma`` with ``sigma`` a function of the
        unknowns and the plane (the slant of the beam to the plane, the range, the lever from the body origin),
        ``d(r/s) = dr / s - (r/s) dvar / (2 var)``.  These are the Jacobians at the *adjusted observations* of the
        Gauss-Helmert model to first order in the residual (each error source ``l`` moved by its share
        ``sigma_l^2 B_l r / var``, which puts the point on its plane: ``dr(l_hat) = dr(l) - r sum_l sigma_l^2 B_l
        dB_l / var``), the exact gradient of the maximum-likelihood cost ``sum r^2 / var``.  With the Jacobians at
        the recorded points (``"observed"``: ``sigma`` frozen) the noise along a slanted beam enters the plane's
        tilt and the range-scale, boresight and attitude columns correlated with the residual, a bias of
        ``O(sigma^2)`` per point that does not shrink with the number of points (errors-in-variables; the same
        correction as :func:`skyrig.lidar.strips.plane_residuals` ``linearise="adjusted"``)."""
        T = np.stack(plane_basis(normal), axis=1)
        dx = geo["X"] - centre
        r = np.einsum("ni,ni->n", normal, dx) / sig
        B = np.column_stack([np.einsum("nki,ni->nk", T, dx), -np.ones(len(r))]) / sig[:, None]
        out = {"r": r, "B": B, "T": T}
        adjusted = d.linearise == "adjusted"
        dv = self.variance_derivatives(d, geo, normal, T) if adjusted else {}
        h = r / (2.0 * sig**2)  # d(r/s) = dr/s - h dvar
        if adjusted:
            B[:, :2] -= h[:, None] * dv["tilt"]
        if "JS" in geo:
            out["AS"] = np.einsum("ni,nik->nk", normal, geo["JS"]) / sig[:, None]
            out["AK"] = np.einsum("ni,nik->nk", normal, geo["JK"]) / sig[:, None]
            if adjusted:
                out["AS"] -= h[:, None] * dv["scanner"]
                out["AK"] -= h[:, None] * dv["strip"]
        return out

    def planes(self, d: LidarPoints, X: NDArray, geo: dict[str, NDArray], tie_xyz: NDArray,
               planes: tuple[int, int] | None = None) -> tuple[NDArray, NDArray, NDArray]:
        """Planes at the current georeferencing: ``normal (Q, 3)``, ``centre (Q, 3)`` and the points' sigma ``(N,)``
        (an unweighted fit gives the normals for the weights of a weighted fit, the planes, which takes the planes'
        control too; the sigmas are those at the planes).  ``planes=(p0, p1)``: ``X``/``geo`` are the points of the planes ``p0 .. p1 - 1`` only
        (``geo["rows"]``, :func:`plane_chunks`), ``tie_xyz`` those planes' anchors, the planes returned those."""
        p0, p1 = (0, d.n_planes) if planes is None else planes
        q = p1 - p0
        is_tie = d.plane_point[p0:p1] >= 0
        plane = d.plane[geo["rows"]] - p0
        n0, _ = _fit_planes(X, np.ones(len(X)), plane, tie_xyz, is_tie, q)
        sig = self.point_sigma(d, geo, n0[plane])
        n1, c1 = _fit_planes(X, 1.0 / sig**2, plane, tie_xyz, is_tie, q, _control_fit_moments(d, p0, p1))
        return n1, c1, self.point_sigma(d, geo, n1[plane])

    def normalised_residuals(self, block: "Block") -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Each point's point-to-plane residual over its sigma ``(N,)`` at the block's values (planes refitted),
        and each plane's RMS of them over its redundancy ``(Q,)`` (about 1 for a plane that fits its model; a
        point over an edge or a plane over a corner shows far more)."""
        d = _data(block)
        assert d is not None
        sc = LidarScanner().initial(block)[0]
        st = LidarStrip().initial(block)
        anchor = np.zeros((d.n_planes, 3))
        tie = d.plane_point >= 0
        anchor[tie] = block.point_xyz[d.plane_point[tie]]
        r = np.zeros(len(d))
        for p0, p1, rows in plane_chunks(_sorted_planes(d), d.n_planes):  # (whole planes a chunk at a time)
            geo = georeference(d, sc, st, False, rows)
            normal, centre, sig = self.planes(d, geo["X"], geo, anchor[p0:p1], (p0, p1))
            plane = d.plane[rows] - p0
            r[rows] = np.einsum("ni,ni->n", normal[plane], geo["X"] - centre[plane]) / sig
        cnt = np.bincount(d.plane, minlength=d.n_planes)
        dof = np.maximum(cnt - np.where(tie, 2, 3), 1)
        return r, np.sqrt(np.bincount(d.plane, r**2, d.n_planes) / dof)

    def evaluate(self, model: "Model", s: "State", jac: bool) -> list[Factor]:
        b, lay = model.block, model.layout
        d = _data(b)
        assert d is not None
        pc: _Planes = model.cache[NAME]
        tie = d.plane_point >= 0
        anchor = np.zeros((d.n_planes, 3))
        anchor[tie] = s.X[d.plane_point[tie]]
        sc, st_ = s.groups[SCANNER][0], s.groups[STRIP]
        has_c = d.has_control
        c_cnt = np.where(has_c, 0.0 if d.control_count is None else d.control_count, 0.0).astype(np.int64)
        n_ctrl = int(c_cnt.sum())  # control points: observations of the planes they lie on
        if not jac:  # the same sum of squares as the reduced rows (the plane eliminated), one row per plane
            ss = np.zeros(d.n_planes)
            for p0, p1, rows in plane_chunks(pc, d.n_planes):
                geo = georeference(d, sc, st_, False, rows)
                normal, centre, sig = self.planes(d, geo["X"], geo, anchor[p0:p1], (p0, p1))
                plane = d.plane[rows] - p0
                pr = self.point_rows(d, geo, normal[plane], centre[plane], sig)
                ss[p0:p1] = _projected_ss(pr["r"], pr["B"], plane, tie[p0:p1], p1 - p0,
                                          _control_block(d, p0, p1, normal, centre))
            n_nuis = int(np.where(tie, 2, 3).sum())
            f0 = Factor(NAME, np.sqrt(ss)[:, None], np.ones((d.n_planes, 1)),
                        n_extra=len(d) + n_ctrl - n_nuis - d.n_planes)
            return [f0] + ([self.trajectory(model, s, jac)] if len(d.station) else [])
        scols = lay.groups[SCANNER][0]
        kcols = lay.groups[STRIP]
        rp = lay.rpoint_cols
        W = pc.width
        # rows of each plane: k + 1 below its nuisance block, fewer when it has fewer points (mode "r" QR)
        n_pts = np.diff(pc.ptr) + 4 * has_c  # a plane's control: 4 square-root rows
        nb_all = np.where(tie, 2, 3)
        k_all = NS + NK * np.array([len(x) for x in pc.strips], np.int64) + np.where(tie, 3, 0)
        n_rows = np.minimum(n_pts, nb_all + k_all + 1) - nb_all
        row0 = np.concatenate([[0], np.cumsum(n_rows)])
        jc_all = np.zeros((int(row0[-1]), 1, W))
        cols_all = np.full((int(row0[-1]), W), -1, np.int64)
        r_all = np.zeros((int(row0[-1]), 1))
        extra = 0
        # the points a chunk of whole planes at a time: the per-point Jacobians of one chunk only, the factor's
        # rows per plane (at most k + 1 each)
        for p0, p1, rows in plane_chunks(pc, d.n_planes):
            geo = georeference(d, sc, st_, True, rows)
            normal, centre, sig = self.planes(d, geo["X"], geo, anchor[p0:p1], (p0, p1))
            nrm = normal[d.plane[rows] - p0]
            pr = self.point_rows(d, geo, nrm, centre[d.plane[rows] - p0], sig)
            r, Bm, AS, AK = pr["r"], pr["B"], pr["AS"], pr["AK"]
            G = _control_block(d, p0, p1, normal, centre)
            Rc = None if G is None else _control_sqrt(G)
            for p in range(p0, p1):
                idx = np.arange(pc.ptr[p] - pc.ptr[p0], pc.ptr[p + 1] - pc.ptr[p0])  # (chunk-local)
                strips = pc.strips[p]
                nb = 2 if tie[p] else 3
                k = NS + NK * len(strips) + (3 if tie[p] else 0)
                M = np.zeros((len(idx), nb + k + 1))
                M[:, :nb] = Bm[idx, :nb]
                M[:, nb:nb + NS] = AS[idx]
                cols = np.full(W, -1, np.int64)
                cols[:NS] = scols
                st = d.strip[rows[idx]]
                for j, sk in enumerate(strips):
                    on = st == sk
                    o = nb + NS + NK * j
                    M[on, o:o + NK] = AK[idx[on]]
                    cols[NS + NK * j:NS + NK * (j + 1)] = kcols[sk]
                if tie[p]:
                    M[:, nb + k - 3:nb + k] = -nrm[idx] / sig[idx, None]
                    cols[k - 3:k] = rp[d.plane_point[p]]
                M[:, -1] = r[idx]
                if has_c[p] and Rc is not None:  # the control's rows: the plane's columns and the residual only
                    Mc = np.zeros((4, M.shape[1]))
                    Mc[:, :3] = Rc[p - p0, :, :3]
                    Mc[:, -1] = Rc[p - p0, :, 3]
                    M = np.vstack([M, Mc])
                Rq: NDArray[np.float64] = np.asarray(np.linalg.qr(M, mode="r"))
                rows_p = Rq[nb:nb + k + 1]
                out = slice(row0[p], row0[p + 1])
                assert len(rows_p) == n_rows[p]
                jc_all[out, 0, :k] = rows_p[:, nb:nb + k]
                cols_all[out] = cols
                r_all[out, 0] = rows_p[:, -1]
                extra += len(idx) + int(c_cnt[p]) - nb - len(rows_p)
        f = Factor(NAME, r_all, np.ones_like(r_all), jc=jc_all, cols=cols_all, n_extra=extra)
        return [f] + ([self.trajectory(model, s, jac)] if len(d.station) else [])

    def trajectory(self, model: "Model", s: "State", jac: bool) -> Factor:
        """The stations' poses against the recorded trajectory corrected by their strips' corrections: ``(S, 6)``
        rows ``C - (P + dp + dv tau)`` and ``log(R_s^T expmap(da + dw tau) R_rec)`` (body frame), whitened."""
        b, lay = model.block, model.layout
        d = _data(b)
        assert d is not None
        st, k = d.station, d.station_strip
        tau = d.station_time_s - d.strip_epoch_s[k]
        S = s.groups[STRIP][k]
        g = S[:, 6:9] + S[:, 9:12] * tau[:, None]
        E = matrix_from_rotvec(g)
        Q = np.swapaxes(s.R[st], 1, 2) @ E @ d.station_rotation
        sp, sa = float(d.station_position_sigma_m), float(d.station_attitude_sigma_rad)
        sig = np.array([sp, sp, sp, sa, sa, sa])
        r = np.column_stack([s.C[st] - d.station_position_m - S[:, 0:3] - S[:, 3:6] * tau[:, None],
                             rotvec_from_matrix(Q)]) / sig
        f = Factor(f"{NAME}:trajectory", r, np.broadcast_to(sig, r.shape).copy())
        if not jac:
            return f
        m = len(st)
        jc = np.zeros((m, 6, 6 + NK))
        i3 = np.eye(3)
        jc[:, 0:3, 0:3] = i3
        jc[:, 3:6, 3:6] = -i3
        jc[:, 0:3, 6:9] = -i3
        jc[:, 0:3, 9:12] = -i3 * tau[:, None, None]
        Ja = np.swapaxes(d.station_rotation, 1, 2) @ right_jacobian(g)
        jc[:, 3:6, 12:15] = Ja
        jc[:, 3:6, 15:18] = Ja * tau[:, None, None]
        f.jc = jc / sig[None, :, None]
        f.cols = np.concatenate([lay.pose[st], lay.groups[STRIP][k]], axis=1)
        return f

    def varying(self, model: "Model", factor: Factor) -> NDArray[np.bool_]:
        if factor.name != NAME and factor.cols is not None:
            return np.asarray((factor.cols >= 0).any(axis=1), bool)
        return np.ones(len(factor), bool)  # laser points observe their planes whatever is free

    def label(self, block: "Block", i: int) -> str:
        return f"laser plane row {i}"


def lidar_unknowns(unknowns: "Unknowns", strip_sigma: tuple[float, ...] | None = None,
                   scanner_sigma: tuple[float, ...] | None = None) -> "Unknowns":
    """``unknowns`` with the laser groups on: the scanner calibration ``"free"`` (or ``"weighted"`` with
    ``scanner_sigma``, 8 sigmas in the component order), the strip corrections ``"weighted"`` with ``strip_sigma``
    (12 sigmas: the trajectory's accuracy, component order of ``lidar_strip``) or ``"free"`` when None."""
    groups: tuple[Any, ...] = tuple((n, m) for n, m in unknowns.groups if n not in (SCANNER, STRIP))
    gs: tuple[Any, ...] = tuple((n, v) for n, v in unknowns.group_sigma if n not in (SCANNER, STRIP))
    groups += ((SCANNER, "free" if scanner_sigma is None else "weighted"),
               (STRIP, "free" if strip_sigma is None else "weighted"))
    if scanner_sigma is not None:
        gs += ((SCANNER, tuple(float(v) for v in scanner_sigma)),)
    if strip_sigma is not None:
        gs += ((STRIP, tuple(float(v) for v in strip_sigma)),)
    return replace(unknowns, groups=groups, group_sigma=gs)


@dataclass(frozen=True, eq=False)
class ControlResiduals:
    """Each control plane against the laser (:func:`control_residuals`); ``(C,)`` arrays over the planes with
    control.

    ``plane``: plane index; ``count``: control points; ``centroid`` ``(C, 3)`` their centroid (block frame);
    ``normal`` ``(C, 3)``; ``residual_m``: the control centroid's distance from the laser's own plane (the plane
    fitted to the adjusted laser points alone), along the normal; ``sigma_m``: its predicted sigma (control noise,
    the laser plane's fit and, with a covariance, the scanner's and strips' uncertainty); ``z = residual / sigma``;
    ``blunder``: ``|z|`` above the threshold the caller used (and a redundancy number that allows the test);
    ``redundancy``: the redundancy numbers (1 without a covariance).
    """

    plane: NDArray[np.int64]
    count: NDArray[np.int64]
    centroid: NDArray[np.float64]
    normal: NDArray[np.float64]
    residual_m: NDArray[np.float64]
    sigma_m: NDArray[np.float64]
    z: NDArray[np.float64]
    blunder: NDArray[np.bool_]
    redundancy: NDArray[np.float64] | None = None

    def __len__(self) -> int:
        return len(self.plane)

    def subset(self, keep: NDArray[np.bool_]) -> "ControlResiduals":
        """The control planes ``keep`` selects."""
        kw: dict[str, Any] = {f.name: None if getattr(self, f.name) is None else getattr(self, f.name)[keep]
                              for f in fields(self)}
        return replace(self, **kw)

    @staticmethod
    def concatenate(parts: list["ControlResiduals"]) -> "ControlResiduals":
        """The control planes of ``parts`` one after the other (redundancy numbers only when all have them)."""
        kw: dict[str, Any] = {f.name: None if any(getattr(r, f.name) is None for r in parts)
                              else np.concatenate([getattr(r, f.name) for r in parts]) for f in fields(ControlResiduals)}
        return replace(parts[0], **kw)

    def summary(self) -> dict[str, Any]:
        n = len(self)
        if not n:
            return {"planes": 0}
        return {"planes": n, "points": int(self.count.sum()), "rms_m": float(np.sqrt(np.mean(self.residual_m**2))),
                "mean_m": float(np.mean(self.residual_m)), "z_mean": float(np.mean(self.z)),
                "z_std": float(np.std(self.z)), "z_max_abs": float(np.max(np.abs(self.z))),
                "blunders": int(self.blunder.sum()),
                "untested": 0 if self.redundancy is None else int(np.sum(self.redundancy < 0.2))}

    def to_dict(self) -> dict[str, Any]:
        return {**self.summary(), "units": "m (residual: control minus laser plane, along the normal)",
                "control_planes": [{"plane": int(p), "count": int(c), "centroid_m": [float(v) for v in y],
                                    "normal": [float(v) for v in nn], "residual_m": float(r), "sigma_m": float(sg),
                                    "z": float(z), "blunder": bool(b), "redundancy": float(rd)}
                                   for p, c, y, nn, r, sg, z, b, rd in zip(
                                       self.plane, self.count, self.centroid, self.normal, self.residual_m,
                                       self.sigma_m, self.z, self.blunder,
                                       np.ones(len(self)) if self.redundancy is None else self.redundancy)]}


def control_residuals(d: LidarPoints, scanner: NDArray[np.float64], strips: NDArray[np.float64],
                      covariance: NDArray[np.float64] | None = None, max_z: float = 4.0,
                      min_redundancy: float = 0.2) -> ControlResiduals:
    """Each control plane tested against the laser: the control centroid's distance from the plane fitted to the
    plane's laser points alone at the calibration ``scanner (8,)`` and strip corrections ``strips (K, 12)``.

    Its variance: the control centroid's (``control_sigma_m^2 / count + control_plane_sigma_m^2``) and the laser
    plane's at the centroid (weighted fit of its points, their point-to-plane sigmas); with ``covariance`` (``(8 +
    12 K)`` square, scanner then strips in the groups' component order: the cofactors of the adjustment the control
    took part in) less the part the adjustment explained, ``a^T Q a`` with ``a`` the laser plane's distance at the
    centroid by the unknowns (Baarda's normalised residual, the w-test: ``z ~ N(0, 1)`` for a control plane that
    fits).  ``|z| > max_z``: a blunder (a control plane that is not where the laser sees the surface: a moved object,
    a wrong reference, a surface change), tested where the redundancy number is at least ``min_redundancy`` (the
    sigma uses ``max(r, min_redundancy)``).  The laser plane does not take the control (the test is of the control
    against the laser).
    """
    cpl = np.flatnonzero(d.has_control)
    C, K = len(cpl), d.n_strips
    if C == 0:
        e = np.zeros(0)
        return ControlResiduals(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)), e, e,
                                e, np.zeros(0, bool))
    loc = np.full(d.n_planes, -1)
    loc[cpl] = np.arange(C)
    rows = np.flatnonzero(loc[d.plane] >= 0)
    pl = loc[d.plane[rows]]
    geo = georeference(d, scanner, strips, covariance is not None, rows)
    X = geo["X"]
    no_tie = np.zeros(C, bool)
    n0, _ = _fit_planes(X, np.ones(len(X)), pl, np.zeros((C, 3)), no_tie, C)
    sig = LIDAR.point_sigma(d, geo, n0[pl])
    w = 1.0 / sig**2
    n1, c1 = _fit_planes(X, w, pl, np.zeros((C, 3)), no_tie, C)
    sig = LIDAR.point_sigma(d, geo, n1[pl])
    w = 1.0 / sig**2
    t1, t2 = plane_basis(n1)
    dx = X - c1[pl]
    J = np.column_stack([np.einsum("ni,ni->n", t1[pl], dx), np.einsum("ni,ni->n", t2[pl], dx), np.ones(len(X))])
    N = np.zeros((C, 3, 3))
    np.add.at(N, pl, w[:, None, None] * J[:, :, None] * J[:, None, :])
    cnt = np.asarray(d.control_count, float)[cpl]
    ybar, _ = _control_central(cnt, d.control_sum[cpl], d.control_sum2[cpl], d.control_ref[cpl])
    db = ybar - c1
    v = np.column_stack([np.einsum("qi,qi->q", t1, db), np.einsum("qi,qi->q", t2, db), np.ones(C)])
    Ninv_v = np.linalg.solve(N, v[:, :, None])[:, :, 0]
    var = d.control_sigma_m**2 / cnt + d.control_plane_sigma_m**2 + np.einsum("qi,qi->q", v, Ninv_v)
    if covariance is not None:
        # the laser plane's distance at the centroid by the unknowns: v^T N^-1 sum_i w_i J_i (n . dX_i / dtheta)
        A = np.concatenate([np.einsum("ni,nik->nk", n1[pl], geo["JS"]), np.einsum("ni,nik->nk", n1[pl], geo["JK"])],
                           axis=1) * w[:, None]
        g = pl * K + d.strip[rows]
        H = np.zeros((C * K, 3, NS + NK))
        np.add.at(H, g, J[:, :, None] * A[:, None, :])
        a = np.einsum("qi,qkiu->qku", Ninv_v, H.reshape(C, K, 3, NS + NK))  # (C, K, 20)
        full = np.zeros((C, NS + NK * K))
        full[:, :NS] = a[:, :, :NS].sum(axis=1)
        full[:, NS:] = a[:, :, NS:].reshape(C, K * NK)
        # Baarda's normalised residual: the control plane and the laser took part in the adjustment that gave the
        # unknowns, so the residual's variance is the observation's less what the adjustment explained of it
        # (redundancy number r = 1 - a^T Q a / var); a plane with r < min_redundancy is not tested (it determines
        # unknowns nearly alone: its residual shows little of its error; strips-ci seed 6 flagged a plane 0.8 mm
        # off with r clipped at 0.05)
        red = np.clip(1.0 - np.einsum("qu,uv,qv->q", full, np.asarray(covariance, float), full) / var, 0.0, 1.0)
    else:
        red = np.ones(C)
    res = np.einsum("qi,qi->q", n1, db)
    sd = np.sqrt(var * np.maximum(red, min_redundancy))
    z = res / sd
    return ControlResiduals(cpl.astype(np.int64), cnt.astype(np.int64), ybar, n1, res, sd, z,
                            (np.abs(z) > max_z) & (red >= min_redundancy), red)


LIDAR = Lidar()
register(LIDAR)
register_group(LidarScanner())
register_group(LidarStrip())
