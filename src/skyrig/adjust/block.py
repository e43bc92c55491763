"""The data of a bundle block: observations, parameters and how each parameter group is treated.

Frames
------
Everything in a :class:`Block` is in **one Cartesian world frame** (normally the tangential / local
ENU frame of the block, :meth:`skyrig.georef.WorldFrame.local`; see ``docs/frames.md``), metres and
radians.  Map inputs are transformed into it before the adjustment and results back afterwards
(:mod:`skyrig.adjust.frames`).

Stations, images and heads
--------------------------
A *station* carries one pose unknown ``world_from_station = (R, C)``: a single image, or one platform
exposure of a rig (station = IMU body).  Each image belongs to a station and has a fixed
``station_from_camera`` rotation and offset (identity and zero for a single camera; the head's
``body_from_camera`` for a rig, possibly per image for an actuated head), and a *head* index whose
small boresight correction ``b`` (a rotation vector, camera frame) may be estimated::

    world_from_camera = R_station @ station_from_camera @ expmap(b_head)
    C_camera          = C_station + R_station @ offset

GNSS antenna positions observe ``C_station + R_station @ lever_arm + datum_shift + strip_shift[s]
+ strip_drift[s] * (t - t0[s])``; IMU attitudes observe ``R_station``.

Parameter groups
----------------
Each group of :class:`AdjustConfig` is ``"fixed"``, ``"free"`` or ``"weighted"`` (free with a prior
equal to the starting value and the sigma given in the config).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Literal, Sequence

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.factors import observation_type
from skyrig.adjust.factors.base import BlockError
from skyrig.camera.frame import FrameCamera

Mode = Literal["fixed", "free", "weighted"]
MODES = ("fixed", "free", "weighted")

__all__ = ["BalCamera", "Block", "AdjustConfig", "Mode", "MODES", "BlockError"]


@dataclass(frozen=True)
class BalCamera:
    """The camera model of the Bundle Adjustment in the Large (BAL) problems (Agarwal et al. 2010).

    ``p = -P_xy / P_z`` (camera looks along -z, y up as skyrig's camera frame),
    ``r = 1 + k1 |p|^2 + k2 |p|^4``, observation ``= f r p`` in pixels relative to the image centre
    (x right, y up).  Intrinsics vector ``(f, k1, k2)``.
    """

    name: str
    f: float
    k1: float = 0.0
    k2: float = 0.0

    @property
    def intrinsic_names(self) -> tuple[str, ...]:
        return ("f", "k1", "k2")

    @property
    def intrinsics(self) -> NDArray[np.float64]:
        return np.array([self.f, self.k1, self.k2])

    def with_intrinsics(self, v: NDArray[np.float64]) -> "BalCamera":
        return replace(self, f=float(v[0]), k1=float(v[1]), k2=float(v[2]))


CameraModel = FrameCamera | BalCamera


def _arr(x, shape_tail, dtype=np.float64, n=None) -> NDArray:  # type: ignore[no-untyped-def]
    a = np.asarray(x, dtype=dtype)
    if n is None:
        n = a.shape[0] if a.ndim else 0
    return a.reshape((n,) + tuple(shape_tail))


@dataclass
class Block:
    """Observations and parameter values of a bundle block (all in one Cartesian world frame).

    Attributes
    ----------
    cameras
        Camera models (interior orientation); images refer to them by index.
    station_name, station_rotation, station_centre
        ``(S,)``, ``(S, 3, 3)`` ``world_from_station``, ``(S, 3)`` metres: pose unknowns.
    station_time
        ``(S,)`` seconds (for strip drift), default zeros.
    station_strip
        ``(S,)`` strip index per station (-1: none), for per-strip GNSS shift and drift.
    image_name, image_station, image_camera, image_head
        ``(I,)`` names and indices into stations, cameras and heads.
    image_rotation, image_offset
        ``(I, 3, 3)`` ``station_from_camera`` and ``(I, 3)`` camera offset in the station frame (m).
    head_name
        ``(H,)`` names of heads (boresight-correction groups).
    point_name, point_xyz
        ``(P,)``, ``(P, 3)`` object points (starting values), metres.
    obs_image, obs_point, obs_pixel, obs_sigma_px
        Image measurements ``(N,)``, ``(N,)``, ``(N, 2)`` (column, row) px, ``(N, 2)`` px.
    control_point, control_xyz, control_sigma, control_check
        Ground coordinates of control points ``(K,)``, ``(K, 3)``, ``(K, 3)`` metres per axis, and
        ``(K,)`` bool: True for a *check* point (not used in the adjustment, compared afterwards).
    gnss_station, gnss_xyz, gnss_sigma
        GNSS antenna positions ``(G,)``, ``(G, 3)``, ``(G, 3)`` metres.
    imu_station, imu_rotation, imu_sigma_rad
        IMU attitudes ``world_from_station`` ``(M,)``, ``(M, 3, 3)``, ``(M, 3)`` rad (about the station axes).
    lever_arm
        ``(3,)`` GNSS antenna in the station frame, metres.
    head_boresight
        ``(H, 3)`` boresight corrections (rotation vectors, camera frame), rad.
    datum_shift, strip_shift, strip_drift
        ``(3,)`` GNSS datum shift, ``(T, 3)`` per-strip shifts (m), ``(T, 3)`` drifts (m/s).
    strip_t0
        ``(T,)`` reference time of each strip's drift (s).
    frame
        Description of the world frame (for reports), e.g. ``WorldFrame.describe()``.
    obs_cov_px2, control_cov_m2, gnss_cov_m2, imu_cov_rad2
        Optional full covariance per observation: ``(N, 2, 2)`` px² (column, row), ``(K, 3, 3)`` and
        ``(G, 3, 3)`` m² (X, Y, Z), ``(M, 3, 3)`` rad² of the IMU attitude error as a rotation vector
        about the station axes (x, y, z; the same components as ``imu_sigma_rad``: ``R_imu^T R_station
        = expmap(e)``).  When given it replaces the per-axis sigma of that group (which is then set to
        ``sqrt(diag)`` for reports); the model whitens each row with the Cholesky factor of the inverse
        covariance (:mod:`skyrig.adjust.model`).
    distance_point, distance_m, distance_sigma_m
        Distance observations (scale bars): ``(D, 2)`` point indices, ``(D,)`` observed distances and
        ``(D,)`` sigma (m).  Their end points are estimated in the reduced part of the unknowns.
    image_beta_rad
        ``(I,)`` actuator angle beta of each exposure (radians; NaN for images of fixed heads).
    head_actuated
        ``(H,)`` :class:`~skyrig.rig.rig.ActuatedHead` of each actuated head, None for fixed heads.
        The mounting ``station_from_camera`` of an image of an actuated head is computed from its
        beta (``image_rotation`` is then only the nominal value, for reports)::

            beta' = (1 + scale) beta + offset
            a     = tilt_angles(beta') + sum_n c_n cos(n beta') + s_n sin(n beta')   (roll, pitch, yaw)
            station_from_camera = body_from_head @ Rz(a_yaw) Ry(a_pitch) Rx(a_roll) @ NADIR @ boresight

        (paper 000 eqs 1-2, :meth:`ActuatedHead.tilt_angles` with its calibrated curve), followed by the
        head's boresight correction ``expmap(head_boresight)`` like any head.
    actuator_correction
        ``(H, 2 + 6 N)`` correction of each actuated head: ``[offset_rad, scale]`` then, for ``n = 1..N``,
        the Fourier coefficients ``[c_roll, c_pitch, c_yaw, s_roll, s_pitch, s_yaw]`` (rad); default zeros.
    """

    cameras: list
    station_name: NDArray[np.str_]
    station_rotation: NDArray[np.float64]
    station_centre: NDArray[np.float64]
    image_name: NDArray[np.str_]
    image_station: NDArray[np.int64]
    image_camera: NDArray[np.int64]
    point_name: NDArray[np.str_]
    point_xyz: NDArray[np.float64]
    obs_image: NDArray[np.int64]
    obs_point: NDArray[np.int64]
    obs_pixel: NDArray[np.float64]
    obs_sigma_px: NDArray[np.float64] | float = 1.0
    image_rotation: NDArray[np.float64] | None = None
    image_offset: NDArray[np.float64] | None = None
    image_head: NDArray[np.int64] | None = None
    head_name: NDArray[np.str_] | None = None
    station_time: NDArray[np.float64] | None = None
    station_strip: NDArray[np.int64] | None = None
    control_point: NDArray[np.int64] | None = None
    control_xyz: NDArray[np.float64] | None = None
    control_sigma: NDArray[np.float64] | float = 0.01
    control_check: NDArray[np.bool_] | None = None
    gnss_station: NDArray[np.int64] | None = None
    gnss_xyz: NDArray[np.float64] | None = None
    gnss_sigma: NDArray[np.float64] | float = 0.05
    imu_station: NDArray[np.int64] | None = None
    imu_rotation: NDArray[np.float64] | None = None
    imu_sigma_rad: NDArray[np.float64] | float = 1e-4
    lever_arm: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    head_boresight: NDArray[np.float64] | None = None
    datum_shift: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    strip_shift: NDArray[np.float64] | None = None
    strip_drift: NDArray[np.float64] | None = None
    strip_t0: NDArray[np.float64] | None = None
    frame: str = "local Cartesian frame"
    obs_cov_px2: NDArray[np.float64] | None = None
    control_cov_m2: NDArray[np.float64] | None = None
    gnss_cov_m2: NDArray[np.float64] | None = None
    distance_point: NDArray[np.int64] | None = None
    distance_m: NDArray[np.float64] | None = None
    distance_sigma_m: NDArray[np.float64] | float = 0.001
    image_beta_rad: NDArray[np.float64] | None = None
    head_actuated: list | None = None
    actuator_correction: NDArray[np.float64] | None = None
    imu_cov_rad2: NDArray[np.float64] | None = None

    def __post_init__(self) -> None:
        self.station_name = np.asarray(self.station_name, dtype=str).reshape(-1)
        s = len(self.station_name)
        self.station_rotation = _arr(self.station_rotation, (3, 3), n=s)
        self.station_centre = _arr(self.station_centre, (3,), n=s)
        self.image_name = np.asarray(self.image_name, dtype=str).reshape(-1)
        i = len(self.image_name)
        self.image_station = _arr(self.image_station, (), np.int64, i)
        self.image_camera = _arr(self.image_camera, (), np.int64, i)
        self.image_rotation = (np.broadcast_to(np.eye(3), (i, 3, 3)).copy() if self.image_rotation is None
                               else _arr(self.image_rotation, (3, 3), n=i))
        self.image_offset = np.zeros((i, 3)) if self.image_offset is None else _arr(self.image_offset, (3,), n=i)
        self.image_head = np.zeros(i, np.int64) if self.image_head is None else _arr(self.image_head, (), np.int64, i)
        nh = int(self.image_head.max()) + 1 if i else 1
        if self.head_name is None:
            self.head_name = np.array([f"head{k}" for k in range(nh)])
        self.head_name = np.asarray(self.head_name, dtype=str).reshape(-1)
        h = len(self.head_name)
        self.head_boresight = np.zeros((h, 3)) if self.head_boresight is None else _arr(self.head_boresight, (3,), n=h)
        self.station_time = np.zeros(s) if self.station_time is None else _arr(self.station_time, (), n=s)
        self.station_strip = (np.full(s, -1, np.int64) if self.station_strip is None
                              else _arr(self.station_strip, (), np.int64, s))
        t = int(self.station_strip.max()) + 1 if s else 0
        self.strip_shift = np.zeros((t, 3)) if self.strip_shift is None else _arr(self.strip_shift, (3,), n=t)
        self.strip_drift = np.zeros((t, 3)) if self.strip_drift is None else _arr(self.strip_drift, (3,), n=t)
        if self.strip_t0 is None:
            t0 = np.zeros(t)
            for k in range(t):
                sel = self.station_strip == k
                t0[k] = self.station_time[sel].mean() if sel.any() else 0.0
            self.strip_t0 = t0
        self.strip_t0 = _arr(self.strip_t0, (), n=t)
        self.point_name = np.asarray(self.point_name, dtype=str).reshape(-1)
        p = len(self.point_name)
        self.point_xyz = _arr(self.point_xyz, (3,), n=p)
        self.obs_image = np.asarray(self.obs_image, dtype=np.int64).reshape(-1)
        n = len(self.obs_image)
        self.obs_point = _arr(self.obs_point, (), np.int64, n)
        self.obs_pixel = _arr(self.obs_pixel, (2,), n=n)
        self.obs_sigma_px = np.broadcast_to(np.asarray(self.obs_sigma_px, dtype=np.float64), (n, 2)).copy()
        self.lever_arm = np.asarray(self.lever_arm, dtype=np.float64).reshape(3)
        self.datum_shift = np.asarray(self.datum_shift, dtype=np.float64).reshape(3)
        if self.control_point is None:
            self.control_point = np.zeros(0, np.int64)
            self.control_xyz = np.zeros((0, 3))
        k = len(np.asarray(self.control_point).reshape(-1))
        self.control_point = _arr(self.control_point, (), np.int64, k)
        self.control_xyz = _arr(self.control_xyz, (3,), n=k)
        self.control_sigma = np.broadcast_to(np.asarray(self.control_sigma, dtype=np.float64), (k, 3)).copy()
        self.control_check = (np.zeros(k, bool) if self.control_check is None
                              else np.asarray(self.control_check, dtype=bool).reshape(k))
        observation_type("gnss").normalise(self)  # type: ignore[union-attr]
        if self.imu_station is None:
            self.imu_station = np.zeros(0, np.int64)
            self.imu_rotation = np.zeros((0, 3, 3))
        m = len(np.asarray(self.imu_station).reshape(-1))
        self.imu_station = _arr(self.imu_station, (), np.int64, m)
        self.imu_rotation = _arr(self.imu_rotation, (3, 3), n=m)
        self.imu_sigma_rad = np.broadcast_to(np.asarray(self.imu_sigma_rad, dtype=np.float64), (m, 3)).copy()
        for cov_name, sig_name, count, d in (("obs_cov_px2", "obs_sigma_px", n, 2), ("control_cov_m2", "control_sigma",
                                                                                     k, 3),
                                             ("imu_cov_rad2", "imu_sigma_rad", m, 3)):
            cv = getattr(self, cov_name)
            if cv is None:
                continue
            cv = np.asarray(cv, dtype=np.float64)
            if cv.shape != (count, d, d):
                raise BlockError(f"{cov_name} must have shape ({count}, {d}, {d}), got {cv.shape}")
            setattr(self, cov_name, cv.copy())
            with np.errstate(invalid="ignore"):
                setattr(self, sig_name, np.sqrt(np.diagonal(cv, axis1=1, axis2=2)).copy())
        h = len(self.head_name)
        if self.head_actuated is None:
            self.head_actuated = [None] * h
        self.head_actuated = list(self.head_actuated)
        if len(self.head_actuated) != h:
            raise BlockError(f"head_actuated has {len(self.head_actuated)} entries for {h} heads")
        self.image_beta_rad = (np.full(i, np.nan) if self.image_beta_rad is None
                               else _arr(self.image_beta_rad, (), n=i).copy())
        ac = np.zeros((h, 2)) if self.actuator_correction is None else np.asarray(self.actuator_correction, float)
        if ac.ndim != 2 or ac.shape[0] != h or ac.shape[1] < 2 or (ac.shape[1] - 2) % 6:
            raise BlockError(f"actuator_correction must have shape ({h}, 2 + 6 N), got {ac.shape}")
        self.actuator_correction = ac.copy()
        if self.distance_point is None:
            self.distance_point = np.zeros((0, 2), np.int64)
            self.distance_m = np.zeros(0)
        nd = len(np.asarray(self.distance_point).reshape(-1, 2))
        self.distance_point = _arr(self.distance_point, (2,), np.int64, nd)
        self.distance_m = _arr(self.distance_m, (), n=nd)
        self.distance_sigma_m = np.broadcast_to(np.asarray(self.distance_sigma_m, dtype=np.float64), (nd,)).copy()

    # ------------------------------------------------------------------ sizes
    @property
    def n_stations(self) -> int:
        return len(self.station_name)

    @property
    def n_images(self) -> int:
        return len(self.image_name)

    @property
    def n_points(self) -> int:
        return len(self.point_name)

    @property
    def n_observations(self) -> int:
        return len(self.obs_image)

    @property
    def n_distances(self) -> int:
        return len(self.distance_point)  # type: ignore[arg-type]

    @property
    def n_strips(self) -> int:
        return len(self.strip_t0)  # type: ignore[arg-type]

    def copy(self) -> "Block":
        """A deep copy of the arrays (cameras are immutable)."""
        kw = {}
        for f in self.__dataclass_fields__:
            v = getattr(self, f)
            kw[f] = v.copy() if isinstance(v, np.ndarray) else (list(v) if isinstance(v, list) else v)
        return Block(**kw)

    # ------------------------------------------------------------------ checks
    def validate(self) -> None:
        """Raise :class:`BlockError` naming the first inconsistency found (indices, NaN, sigma, rays)."""

        def rng(name: str, idx: NDArray, n: int, what: str) -> None:
            bad = np.flatnonzero((idx < 0) | (idx >= n))
            if bad.size:
                raise BlockError(f"{name}[{bad[0]}] = {idx[bad[0]]} names an unknown {what} (have {n})")

        def finite(name: str, a: NDArray) -> None:
            bad = np.flatnonzero(~np.isfinite(a.reshape(len(a), -1)).all(axis=1)) if len(a) else []
            if len(bad):
                raise BlockError(f"{name}[{bad[0]}] is not finite: {a[bad[0]]}")

        def positive(name: str, a: NDArray) -> None:
            bad = np.flatnonzero(~(a.reshape(len(a), -1) > 0).all(axis=1)) if len(a) else []
            if len(bad):
                raise BlockError(f"{name}[{bad[0]}] must be > 0 (a standard deviation), got {a[bad[0]]}")

        rng("image_station", self.image_station, self.n_stations, "station")
        rng("image_camera", self.image_camera, len(self.cameras), "camera")
        rng("image_head", self.image_head, len(self.head_name), "head")  # type: ignore[arg-type]
        rng("obs_image", self.obs_image, self.n_images, "image")
        rng("obs_point", self.obs_point, self.n_points, "point")
        rng("control_point", self.control_point, self.n_points, "point")  # type: ignore[arg-type]
        rng("imu_station", self.imu_station, self.n_stations, "station")  # type: ignore[arg-type]
        for name in ("station_rotation", "station_centre", "point_xyz", "obs_pixel", "obs_sigma_px", "control_xyz",
                     "control_sigma", "imu_rotation", "imu_sigma_rad", "image_rotation",
                     "image_offset"):
            finite(name, getattr(self, name))
        for name in ("obs_sigma_px", "control_sigma", "imu_sigma_rad", "distance_sigma_m"):
            positive(name, getattr(self, name))
        observation_type("gnss").validate(self)  # type: ignore[union-attr]
        for name in ("obs_cov_px2", "control_cov_m2", "imu_cov_rad2"):
            cv = getattr(self, name)
            if cv is None or not len(cv):
                continue
            finite(name, cv)
            asym = np.abs(cv - np.swapaxes(cv, 1, 2)).max(axis=(1, 2)) > 1e-9 * np.abs(cv).max(axis=(1, 2))
            bad = np.flatnonzero(asym | ~(np.linalg.eigvalsh(0.5 * (cv + np.swapaxes(cv, 1, 2)))[:, 0] > 0))
            if bad.size:
                raise BlockError(f"{name}[{bad[0]}] is not a symmetric positive definite covariance: "
                                 f"{cv[bad[0]].tolist()}")
        act_img = np.array([self.head_actuated[k] is not None for k in self.image_head], bool)  # type: ignore[index]
        bad = np.flatnonzero(act_img & ~np.isfinite(self.image_beta_rad))  # type: ignore[arg-type]
        if bad.size:
            raise BlockError(f"image {str(self.image_name[bad[0]])!r} belongs to the actuated head "
                             f"{str(self.head_name[self.image_head[bad[0]]])!r} but has no actuator angle (image_beta_rad)")  # type: ignore[index]
        finite("actuator_correction", self.actuator_correction)  # type: ignore[arg-type]
        rng("distance_point", self.distance_point.reshape(-1), self.n_points, "point")  # type: ignore[union-attr]
        finite("distance_m", self.distance_m)  # type: ignore[arg-type]
        bad = np.flatnonzero(~(self.distance_m > 0))  # type: ignore[operator]
        if bad.size:
            raise BlockError(f"distance_m[{bad[0]}] must be > 0, got {self.distance_m[bad[0]]}")  # type: ignore[index]
        bad = np.flatnonzero(self.distance_point[:, 0] == self.distance_point[:, 1])  # type: ignore[index]
        if bad.size:
            raise BlockError(f"distance {bad[0]} joins point {str(self.point_name[self.distance_point[bad[0], 0]])!r} "  # type: ignore[index]
                             "to itself")
        det = np.linalg.det(self.station_rotation) if self.n_stations else np.ones(0)
        bad = np.flatnonzero(np.abs(det - 1) > 1e-6)
        if bad.size:
            raise BlockError(f"station_rotation[{bad[0]}] is not a rotation (det {det[bad[0]]:.6f})")
        # every point needs two rays or control
        rays = np.bincount(self.obs_point, minlength=self.n_points)
        ctrl = np.zeros(self.n_points, bool)
        ctrl[self.control_point[~self.control_check]] = True  # type: ignore[index]
        bad = np.flatnonzero((rays < 2) & ~ctrl)
        if bad.size:
            raise BlockError(
                f"point {str(self.point_name[bad[0]])!r} is seen in {rays[bad[0]]} image(s) and is not control: "
                f"it cannot be determined ({bad.size} such points); remove it or add observations"
            )
        pair = self.obs_image * max(self.n_points, 1) + self.obs_point
        u, c = np.unique(pair, return_counts=True)
        if (c > 1).any():
            k = u[c > 1][0]
            raise BlockError(f"point {str(self.point_name[k % self.n_points])!r} is measured more than once in image "
                             f"{str(self.image_name[k // self.n_points])!r}")


@dataclass(frozen=True)
class AdjustConfig:
    """How to adjust a block (frozen; unknown keys in a config file are an error).

    Attributes
    ----------
    poses
        Station poses: ``"free"`` (default), ``"fixed"`` or ``"weighted"`` (prior = starting value).
    pose_sigma_m, pose_sigma_rad
        Prior sigma of weighted poses (centre metres, rotation radians).
    points
        Object points: ``"free"`` (default) or ``"fixed"``.
    intrinsics
        ``"fixed"`` (default), ``"free"`` or ``"weighted"``: interior orientation / additional parameters.
    intrinsic_names
        Which intrinsics take part when not fixed (names of the camera's ``intrinsic_names``);
        None = all.  Others stay fixed.
    intrinsic_sigma
        Prior sigma per intrinsic name for ``"weighted"`` (units of the parameter).
    lever_arm, boresight, datum_shift, strip_shift, strip_drift
        Mode of these groups (default fixed).
    lever_arm_sigma_m, boresight_sigma_rad, datum_shift_sigma_m, strip_shift_sigma_m, strip_drift_sigma_m_s
        Prior sigma for ``"weighted"``.
    datum
        ``"auto"`` (control and/or GNSS, whatever the block has), or ``"free"``: inner constraints on
        the station poses (minimum norm of the pose corrections; 7-parameter similarity), or
        ``"none"``: no datum at all, the Levenberg-Marquardt damping picks one solution among the
        equivalent ones (as Ceres does for BAL problems); no rank check, no covariance.
    inner_constraints
        With ``datum="free"``: ``"poses"`` (default; minimum norm of the station pose corrections and of the
        scale-bar end points, which are estimated with them: the Moore-Penrose inverse of the reduced normal
        matrix) or
        ``"points"``: inner constraints on the object points, as close-range programs define the datum -
        the adjusted points keep the centroid, orientation (and, without a scale bar, the scale) of their
        starting coordinates (a Helmert fit of the adjusted onto the starting points, applied to the whole
        block), and the covariance is that of minimum trace over the datum points (an S-transformation).
    datum_points
        Names of the datum points for ``inner_constraints="points"`` (at least 3, not on one line);
        empty = every estimated point.
    max_iterations
        Levenberg-Marquardt iterations.
    function_tolerance, parameter_tolerance, gradient_tolerance
        Stop when the relative cost decrease, the relative step or the max gradient fall below these
        (Ceres's definitions).
    robust
        ``None`` or ``"huber"``: robust reweighting of image observations (Huber's weights).
    robust_k
        Huber threshold in units of the observation's sigma.
    snooping
        Run Baarda's data snooping: repeatedly reject the observation with the largest normalised
        residual above the critical value and re-adjust.
    snooping_alpha
        Significance level (two-sided), default 0.001.  With ``snooping_familywise`` (default) it is the
        probability of *any* false rejection in the block: each of the n tests uses ``alpha / n``
        (Bonferroni; n = 10,000 gives a critical value of 5.3); otherwise it is Baarda's per-test alpha0
        (0.001 -> 3.29, which rejects about one good observation per thousand tests).
    snooping_familywise
        See ``snooping_alpha``.
    max_rejections
        Cap on rejected observations.  Reaching it with observations still above the critical value is
        a failure of the adjustment (``AdjustmentResult.failures``): so many blunders mean a wrong model.
    snooping_max_group_share
        Largest share of a GNSS, IMU, control or distance group that data snooping may reject (at least
        3 observations): beyond it snooping stops and the result fails with a probable model error
        (uncalibrated boresight, lever arm, datum shift...) named in words.
    statistics
        Compute covariance, redundancy numbers and normalised residuals (costs one inverse of the
        reduced system; skipped above ``max_statistics_parameters``).
    max_statistics_parameters
        Size limit of the reduced system for full statistics.  Above it, only the covariance of chosen
        unknowns is computed (sparse solves with the factorised reduced system): every reduced unknown
        that is not a station pose (calibration, lever arm, boresight, shifts, actuator corrections,
        end points of distances) plus ``statistics_images`` and ``statistics_points``.
    statistics_images
        Image (or station) names whose pose covariance is wanted at any block size.
    statistics_points
        Point names whose covariance is wanted at any block size.
    actuator, actuator_sigma
        Mode of the actuator-angle correction of actuated heads (``offset`` rad and ``scale``: ``beta' =
        (1 + scale) beta + offset``) and its prior sigma ``(offset_rad, scale)`` for ``"weighted"``.
        Needs beta to vary over the head's images (a constant beta is reported as a datum defect).
    actuator_curve, actuator_fourier_order, actuator_curve_sigma_rad
        Mode, order N and prior sigma (rad) of the Fourier series of the periodic boresight curve
        (roll, pitch, yaw corrections, orders 1..N; the constant term is the head's boresight).  The
        first order in roll/pitch is the same motion as the actuator offset: estimate one of them.
    """

    poses: Mode = "free"
    pose_sigma_m: float = 1.0
    pose_sigma_rad: float = 1e-3
    points: Literal["free", "fixed"] = "free"
    intrinsics: Mode = "fixed"
    intrinsic_names: tuple[str, ...] | None = None
    intrinsic_sigma: tuple[tuple[str, float], ...] = ()
    lever_arm: Mode = "fixed"
    lever_arm_sigma_m: float = 0.1
    boresight: Mode = "fixed"
    boresight_sigma_rad: float = 0.01
    datum_shift: Mode = "fixed"
    datum_shift_sigma_m: float = 1.0
    strip_shift: Mode = "fixed"
    strip_shift_sigma_m: float = 1.0
    strip_drift: Mode = "fixed"
    strip_drift_sigma_m_s: float = 0.01
    datum: Literal["auto", "free", "none"] = "auto"
    inner_constraints: Literal["poses", "points"] = "poses"
    datum_points: tuple[str, ...] = ()
    max_iterations: int = 50
    function_tolerance: float = 1e-6
    parameter_tolerance: float = 1e-8
    gradient_tolerance: float = 1e-10
    robust: Literal["huber"] | None = None
    robust_k: float = 2.5
    snooping: bool = False
    snooping_alpha: float = 0.001
    snooping_familywise: bool = True
    max_rejections: int = 100
    snooping_max_group_share: float = 0.1
    statistics: bool = True
    max_statistics_parameters: int = 6000
    statistics_images: tuple[str, ...] = ()
    statistics_points: tuple[str, ...] = ()
    actuator: Mode = "fixed"
    actuator_sigma: tuple[float, float] = (1e-3, 1e-3)
    actuator_curve: Mode = "fixed"
    actuator_fourier_order: int = 0
    actuator_curve_sigma_rad: float = 1e-3

    def __post_init__(self) -> None:
        if int(self.actuator_fourier_order) < 0:
            raise ValueError(f"AdjustConfig.actuator_fourier_order must be >= 0, got {self.actuator_fourier_order}")
        for name in ("poses", "intrinsics", "lever_arm", "boresight", "datum_shift", "strip_shift", "strip_drift",
                     "actuator", "actuator_curve"):
            if getattr(self, name) not in MODES:
                raise ValueError(f"AdjustConfig.{name} must be one of {MODES}, got {getattr(self, name)!r}")
        if self.points not in ("free", "fixed"):
            raise ValueError(f"AdjustConfig.points must be 'free' or 'fixed', got {self.points!r}")
        if self.datum not in ("auto", "free", "none"):
            raise ValueError(f"AdjustConfig.datum must be 'auto', 'free' or 'none', got {self.datum!r}")
        if self.inner_constraints not in ("poses", "points"):
            raise ValueError(f"AdjustConfig.inner_constraints must be 'poses' or 'points', got "
                             f"{self.inner_constraints!r}")
        if self.inner_constraints == "points" and self.datum != "free":
            raise ValueError("AdjustConfig.inner_constraints='points' needs datum='free' (inner constraints define "
                             f"a free network's datum), got datum={self.datum!r}")
        if self.datum_points and self.inner_constraints != "points":
            raise ValueError("AdjustConfig.datum_points is given but inner_constraints is not 'points' (the datum "
                             "points are only used by inner constraints on points)")
        if not 0.0 < float(self.snooping_max_group_share) <= 1.0:
            raise ValueError(f"AdjustConfig.snooping_max_group_share must be in (0, 1], got "
                             f"{self.snooping_max_group_share!r}")
        if self.robust not in (None, "huber"):
            raise ValueError(f"AdjustConfig.robust must be None or 'huber', got {self.robust!r}")

    def with_(self, **changes: object) -> "AdjustConfig":
        return replace(self, **changes)  # type: ignore[arg-type]

    @classmethod
    def from_dict(cls, data: dict, source: str = "config") -> "AdjustConfig":
        """Build from a mapping; unknown keys raise ``ValueError`` naming them."""
        known = set(cls.__dataclass_fields__)
        bad = sorted(set(data) - known)
        if bad:
            raise ValueError(f"{source}: unknown adjustment option(s) {bad}; known: {sorted(known)}")
        d = dict(data)
        if "intrinsic_names" in d and d["intrinsic_names"] is not None:
            d["intrinsic_names"] = tuple(d["intrinsic_names"])
        if "actuator_sigma" in d:
            d["actuator_sigma"] = tuple(float(v) for v in d["actuator_sigma"])
        for key in ("statistics_images", "statistics_points", "datum_points"):
            if key in d:
                d[key] = tuple(str(v) for v in d[key])
        if "intrinsic_sigma" in d:
            v = d["intrinsic_sigma"]
            d["intrinsic_sigma"] = tuple(sorted(v.items())) if isinstance(v, dict) else tuple(map(tuple, v))
        return cls(**d)


def sequence_index(names: Sequence[str]) -> dict[str, int]:
    return {str(n): i for i, n in enumerate(names)}
