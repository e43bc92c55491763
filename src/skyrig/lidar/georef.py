"""Laser scanner direct georeferencing (paper 002 eqs. 1-4), per pulse, vectorised, and its inverse.

The chain for a pulse fired at time ``t``::

    x_scs  = sensor_from_polar(D, alpha, beta)                                  (eq. 1, skyrig.lidar.scanner)
    x_body = lever_arm + body_from_scanner @ x_scs                              (eq. 2)
    x_ned  = Rz(yaw + dyaw) Ry(pitch) Rx(roll) @ x_body                         (eq. 3)
    X_ecef = P_ecef(t) + ecef_from_ned(lat, lon) @ x_ned                        (eq. 4)

computed as ``X_ecef = P(t) + ecef_from_body(t) @ x_body`` with the trajectory interpolated **at each pulse's
own time** (scan lines and navigation are not synchronised; a 2D scanner's 1080 pulses span 19 ms of a
line): the position by the same spline as :meth:`skyrig.trajectory.Trajectory.interpolate` (cubic, or
linear as in paper 002), the attitude by slerp of ``ecef_from_body`` between the two neighbouring samples.
Paper 002's eq. 4 writes ``ecef_from_ned`` as ``(Ry(lat + pi/2) Rz(lon))^T`` (passive rotations);
skyrig builds the same matrix from the north/east/down unit vectors (``ecef_from_ned_rotation``).
The result is then expressed in any :class:`~skyrig.georef.eo.WorldFrame` (ECEF, a local ENU frame,
or a map CRS with ellipsoidal or geoid heights) by one batched transformation.

* **Yaw correction** (paper 002 section 4.2: magnetometer heading disturbed by the UAV's electronics):
  a constant (or per-trajectory-sample) ``dyaw`` added to the heading, i.e. ``ned_from_body`` pre-multiplied
  by ``Rz(dyaw)`` (:func:`with_yaw_correction`).
* **Barometric height** (paper 002 Fig. 7): heights from a barometer replace the GNSS heights of the
  trajectory (:func:`with_barometric_height`).
* **Antenna reference**: when the trajectory positions are the GNSS antenna's, the mount's
  ``antenna_lever_arm_m`` is subtracted in the body frame.
* **Rotation conventions**: :func:`rotation_from_angles` builds a boresight (or an attitude) from three
  angles with any axis sequence, active or passive, so that a scanner maker's (or PDAL's) convention can
  be entered as it is documented.

Speed: the kernel works on chunks of pulses that stay in cache, rotates by quaternions
(``v' = v + w t + q x t``, ``t = 2 q x v``) and never builds per-pulse 3x3 matrices; see ``bench/lidar.py``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import CubicHermiteSpline, CubicSpline

from skyrig.errors import InputFormatError, OutOfRangeError
from skyrig.georef.eo import WorldFrame
from skyrig.geometry.angles import normalize_unit, to_radians
from skyrig.geometry.rotations import (
    matrix_from_quaternion,
    matrix_from_rotvec,
    quaternion_from_matrix,
    rot_x,
    rot_y,
    rot_z,
)
from skyrig.lidar.scanner import RawScan, polar_from_sensor
from skyrig.trajectory.trajectory import Trajectory, ecef_from_ned_rotation

logger = logging.getLogger(__name__)

__all__ = [
    "GeoreferencedPoints",
    "PulseGeoreferencer",
    "ScannerMount",
    "georeference_scan",
    "invert_points",
    "rotation_from_angles",
    "scan_angle_from_nadir_deg",
    "with_barometric_height",
    "with_yaw_correction",
]

_ELEMENTARY = {"x": rot_x, "y": rot_y, "z": rot_z}


def rotation_from_angles(
    angles: ArrayLike, sequence: str = "zyx", unit: str = "deg", passive: bool = False
) -> NDArray[np.float64]:
    """A rotation matrix from three angles about the x, y and z axes.

    Parameters
    ----------
    angles
        ``(3,)`` or ``(N, 3)``: the angles about x, y and z (in that order whatever the sequence), in ``unit``.
    sequence
        Order of the elementary rotations in the product, left to right: ``"zyx"`` gives
        ``Rz(az) Ry(ay) Rx(ax)`` (aerospace roll-pitch-yaw, skyrig's ``ned_from_body``); ``"xyz"`` gives
        ``Rx(ax) Ry(ay) Rz(az)`` (omega-phi-kappa).  Any permutation of ``x``, ``y``, ``z``.
    unit
        ``"deg"``, ``"rad"`` or ``"gon"``.
    passive
        True for makers that document passive (frame) rotations: the transpose is returned.

    Returns
    -------
    ``(3, 3)`` or ``(N, 3, 3)``.
    """
    if sorted(sequence) != ["x", "y", "z"]:
        raise InputFormatError(f"rotation sequence must be a permutation of 'xyz', not {sequence!r}", field="sequence")
    a = to_radians(np.asarray(angles, dtype=np.float64), normalize_unit(unit))
    if a.shape[-1] != 3:
        raise InputFormatError(f"expected 3 angles, got shape {a.shape}", field="angles")
    axis = {"x": 0, "y": 1, "z": 2}
    r = _ELEMENTARY[sequence[0]](a[..., axis[sequence[0]]])
    for s in sequence[1:]:
        r = r @ _ELEMENTARY[s](a[..., axis[s]])
    return np.swapaxes(r, -1, -2) if passive else r


@dataclass(frozen=True, eq=False)
class ScannerMount:
    """How a scanner sits on the platform (lever arm and boresight, paper 002 eq. 2).

    Attributes
    ----------
    body_from_scanner
        ``(3, 3)`` rotation ``R_scs^rcs``: nominal mounting times boresight.
    lever_arm_m
        ``(3,)`` scanner origin in the body (IMU) frame, metres.
    antenna_lever_arm_m
        ``(3,)`` GNSS antenna phase centre in the body frame (used for ``reference="antenna"`` trajectories).
    """

    body_from_scanner: NDArray[np.float64]
    lever_arm_m: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    antenna_lever_arm_m: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        r = np.array(self.body_from_scanner, dtype=np.float64)
        if r.shape != (3, 3) or not np.allclose(r @ r.T, np.eye(3), atol=1e-9) or np.linalg.det(r) < 0:
            raise InputFormatError("body_from_scanner must be a 3x3 rotation matrix", field="body_from_scanner")
        object.__setattr__(self, "body_from_scanner", r)
        for name in ("lever_arm_m", "antenna_lever_arm_m"):
            v = np.array(getattr(self, name), dtype=np.float64)
            if v.shape != (3,) or not np.all(np.isfinite(v)):
                raise InputFormatError(f"must be 3 finite numbers, got {v!r}", field=name)
            object.__setattr__(self, name, v)

    @classmethod
    def from_angles(
        cls,
        lever_arm_m: ArrayLike,
        boresight: ArrayLike = (0.0, 0.0, 0.0),
        unit: str = "deg",
        sequence: str = "zyx",
        passive: bool = False,
        mounting: ArrayLike | None = None,
        antenna_lever_arm_m: ArrayLike = (0.0, 0.0, 0.0),
    ) -> "ScannerMount":
        """``body_from_scanner = mounting @ rotation_from_angles(boresight, sequence, unit, passive)``."""
        m = np.eye(3) if mounting is None else np.asarray(mounting, dtype=np.float64)
        return cls(m @ rotation_from_angles(boresight, sequence, unit, passive), np.asarray(lever_arm_m, float),
                   np.asarray(antenna_lever_arm_m, float))

    def corrected(self, dboresight_rad: ArrayLike = (0.0, 0.0, 0.0), dlever_m: ArrayLike = (0.0, 0.0, 0.0)) -> "ScannerMount":
        """A mount with a small boresight correction (rotation vector in the *scanner* frame:
        ``body_from_scanner @ expmap(d)``) and a lever-arm correction added."""
        r = self.body_from_scanner @ matrix_from_rotvec(np.asarray(dboresight_rad, dtype=np.float64))
        return ScannerMount(r, self.lever_arm_m + np.asarray(dlever_m, float), self.antenna_lever_arm_m)


def with_yaw_correction(trajectory: Trajectory, dyaw_rad: ArrayLike) -> Trajectory:
    """The trajectory with its heading corrected: ``ned_from_body <- Rz(dyaw) @ ned_from_body``.

    ``dyaw_rad`` is a scalar or ``(N,)`` per sample (e.g. a correction term fitted as a function of time).
    """
    d = np.broadcast_to(np.asarray(dyaw_rad, dtype=np.float64), (len(trajectory),))
    r = rot_z(d) @ trajectory.ned_from_body
    return Trajectory(trajectory.time_s, trajectory.lat_deg, trajectory.lon_deg, trajectory.h_m,
                      quaternion_from_matrix(r), velocity_ned=trajectory.velocity_ned,
                      sigma_ned_m=trajectory.sigma_ned_m, sigma_rpy_rad=trajectory.sigma_rpy_rad,
                      time_system=trajectory.time_system, reference=trajectory.reference)


def with_barometric_height(trajectory: Trajectory, time_s: ArrayLike, h_m: ArrayLike) -> Trajectory:
    """The trajectory with its (GNSS) heights replaced by barometric heights.

    Parameters
    ----------
    trajectory
        GNSS/IMU trajectory.
    time_s, h_m
        ``(K,)`` barometer times (strictly increasing, same time system) and heights as WGS84 ellipsoidal
        heights of the trajectory's reference point (convert an altitude first: ``h = H + N`` with
        :class:`skyrig.geodesy.crs.Geoid`, and add the barometer's offset from a reference height),
        linearly interpolated at the trajectory's times.

    Raises
    ------
    OutOfRangeError
        If the barometer record does not cover the trajectory, or its times are not increasing.
    """
    t = np.asarray(time_s, dtype=np.float64)
    h = np.asarray(h_m, dtype=np.float64)
    if t.shape != h.shape or t.ndim != 1 or len(t) < 2:
        raise InputFormatError(f"barometric times and heights must be two (K,) arrays, K >= 2, got {t.shape}, {h.shape}",
                               field="barometric")
    if np.any(np.diff(t) <= 0):
        k = int(np.argmax(np.diff(t) <= 0)) + 1
        raise OutOfRangeError(f"barometric times must be strictly increasing: sample {k} ({t[k]!r})")
    t0, t1 = trajectory.span
    if t[0] > t0 or t[-1] < t1:
        raise OutOfRangeError(f"barometric heights cover [{t[0]!r}, {t[-1]!r}], the trajectory [{t0!r}, {t1!r}]")
    return Trajectory(trajectory.time_s, trajectory.lat_deg, trajectory.lon_deg, np.interp(trajectory.time_s, t, h),
                      trajectory.ned_from_body_q, velocity_ned=trajectory.velocity_ned,
                      sigma_ned_m=trajectory.sigma_ned_m, sigma_rpy_rad=trajectory.sigma_rpy_rad,
                      time_system=trajectory.time_system, reference=trajectory.reference)


def _rotate(q: NDArray[np.float64], v: NDArray[np.float64], inverse: bool = False) -> NDArray[np.float64]:
    """Rotate vectors ``v (n, 3)`` by unit quaternions ``q (n, 4)`` (w, x, y, z) without building matrices."""
    w = q[:, 0:1]
    u = -q[:, 1:4] if inverse else q[:, 1:4]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


class PulseGeoreferencer:
    """Per-pulse poses and georeferencing against one trajectory and one scanner mount.

    Parameters
    ----------
    trajectory
        GNSS/IMU trajectory (apply :func:`with_yaw_correction` / :func:`with_barometric_height` first).
    mount
        Lever arm and boresight.
    position
        ``"cubic"`` (the spline of :meth:`Trajectory.interpolate`) or ``"linear"`` (paper 002).
    chunk
        Pulses per batch (65536 keeps the working arrays in cache).
    """

    def __init__(self, trajectory: Trajectory, mount: ScannerMount, position: str = "cubic", chunk: int = 65536) -> None:
        if position not in ("cubic", "linear"):
            raise InputFormatError(f"position interpolation must be 'cubic' or 'linear', not {position!r}", field="position")
        self.trajectory = trajectory
        self.mount = mount
        self.position = position
        self.chunk = int(chunk)
        #: use the compiled kernel when numba is installed (set False to force the numpy path)
        self.use_numba = True
        t = trajectory.time_s
        self._t = t
        e = trajectory.ecef
        self._origin = e.mean(axis=0)  # positions relative to this: smaller numbers, same result
        if position == "cubic":
            tr = t - t[0]
            if trajectory.velocity_ned is not None:
                r = ecef_from_ned_rotation(trajectory.lat_deg, trajectory.lon_deg)
                v = np.einsum("nij,nj->ni", r, trajectory.velocity_ned)
                sp: CubicSpline | CubicHermiteSpline = CubicHermiteSpline(tr, e, v, axis=0)
            elif len(t) < 4:
                sp = CubicSpline(tr, e, axis=0, bc_type="natural")
            else:
                sp = CubicSpline(tr, e, axis=0)
            c = sp.c.copy()  # (4, n-1, 3): c0 dt^3 + c1 dt^2 + c2 dt + c3
            c[3] -= self._origin
            self._c = c
        else:
            self._p = e - self._origin
        q = quaternion_from_matrix(ecef_from_ned_rotation(trajectory.lat_deg, trajectory.lon_deg) @ trajectory.ned_from_body)
        q0, q1 = q[:-1], q[1:].copy()
        d = np.sum(q0 * q1, axis=1)
        q1[d < 0] *= -1.0
        d = np.abs(d)
        self._q0, self._q1 = q0, q1
        theta = np.arccos(np.clip(d, -1.0, 1.0))
        self._theta = theta
        lin = d > 0.9999995  # as skyrig.geometry.rotations.slerp
        self._lin = lin
        self._inv_sin = np.where(lin, 1.0, 1.0 / np.where(lin, 1.0, np.sin(theta)))
        lever = mount.lever_arm_m - (mount.antenna_lever_arm_m if trajectory.reference == "antenna" else 0.0)
        self._lever = lever

    # ------------------------------------------------------------------ helpers
    def _locate(self, t: NDArray[np.float64]) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
        t0, t1 = self.trajectory.span
        bad = ~((t >= t0) & (t <= t1))
        if np.any(bad):
            k = int(np.argmax(bad))
            raise OutOfRangeError(
                f"pulse {k} at time {t[k]!r} is outside the trajectory's time span [{t0!r}, {t1!r}] "
                f"({self.trajectory.time_system}); {int(bad.sum())} pulse(s) in all"
            )
        i = np.searchsorted(self._t, t, side="right") - 1
        np.clip(i, 0, len(self._t) - 2, out=i)
        return i, t - self._t[i]

    def _pose(self, i: NDArray[np.intp], dt: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Positions (relative to ``_origin``) ``(n, 3)`` and ecef_from_body quaternions ``(n, 4)``."""
        if self.position == "cubic":
            c = self._c
            p = c[0, i] * dt[:, None]
            p += c[1, i]
            p *= dt[:, None]
            p += c[2, i]
            p *= dt[:, None]
            p += c[3, i]
        else:
            u = dt / (self._t[i + 1] - self._t[i])
            p = self._p[i] + u[:, None] * (self._p[i + 1] - self._p[i])
        u = dt / (self._t[i + 1] - self._t[i])
        th = self._theta[i]
        lin = self._lin[i]
        inv = self._inv_sin[i]
        wa = np.where(lin, 1.0 - u, np.sin((1.0 - u) * th) * inv)
        wb = np.where(lin, u, np.sin(u * th) * inv)
        q = wa[:, None] * self._q0[i] + wb[:, None] * self._q1[i]
        q /= np.sqrt(np.einsum("ij,ij->i", q, q))[:, None]
        return p, q

    # ------------------------------------------------------------------ public
    def poses(self, time_s: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """IMU (trajectory reference point) positions in ECEF ``(N, 3)`` and ``ecef_from_body`` ``(N, 3, 3)``."""
        t = np.asarray(time_s, dtype=np.float64).ravel()
        i, dt = self._locate(t)
        p, q = self._pose(i, dt)
        return p + self._origin, matrix_from_quaternion(q)

    def ecef(self, time_s: ArrayLike, sensor_xyz: ArrayLike) -> NDArray[np.float64]:
        """ECEF coordinates ``(N, 3)`` of pulses given in the scanner frame ``(N, 3)`` at times ``(N,)``.

        Raises
        ------
        OutOfRangeError
            Naming the first pulse outside the trajectory's span.
        """
        t = np.asarray(time_s, dtype=np.float64).ravel()
        xs = np.asarray(sensor_xyz, dtype=np.float64)
        if xs.shape != (len(t), 3):
            raise InputFormatError(f"sensor points must be ({len(t)}, 3), got {xs.shape}", field="sensor_xyz")
        if _NUMBA_KERNEL is not None and self.use_numba:
            t0, t1 = self.trajectory.span
            if len(t) and (t.min() < t0 or t.max() > t1):
                self._locate(t)  # raises, naming the first pulse outside the span
            return self._ecef_numba(t, xs)
        i_all, dt_all = self._locate(t)
        out = np.empty((len(t), 3))
        b = self.mount.body_from_scanner
        lev = self._lever
        # structure-of-arrays tables: 1-D gathers and element-wise ops on contiguous columns
        if self.position == "cubic":
            cc = [[np.ascontiguousarray(self._c[k, :, j]) for j in range(3)] for k in range(4)]
        else:
            p0 = [np.ascontiguousarray(self._p[:-1, j]) for j in range(3)]
            dp = [np.ascontiguousarray(self._p[1:, j] - self._p[:-1, j]) for j in range(3)]
        inv_h = 1.0 / np.diff(self._t)
        th = np.where(self._theta > 1e-12, self._theta, 1e-12)  # sin(u th)/sin(th) -> u as th -> 0
        inv_sin = 1.0 / np.sin(th)
        q0 = [np.ascontiguousarray(self._q0[:, j]) * inv_sin for j in range(4)]
        q1 = [np.ascontiguousarray(self._q1[:, j]) * inv_sin for j in range(4)]
        for a in range(0, len(t), self.chunk):
            sl = slice(a, a + self.chunk)
            i, dt = i_all[sl], dt_all[sl]
            x0, x1, x2 = xs[sl, 0], xs[sl, 1], xs[sl, 2]
            # body frame: lever + body_from_scanner @ x_scs
            v = [b[r, 0] * x0 + b[r, 1] * x1 + b[r, 2] * x2 + lev[r] for r in range(3)]
            # attitude: slerp weights sin((1-u) th) / sin th, sin(u th) / sin th
            tht = th[i]
            ut = dt * inv_h[i] * tht
            wa = np.sin(tht - ut)
            wb = np.sin(ut)
            qw, qx, qy, qz = (wa * q0[j][i] + wb * q1[j][i] for j in range(4))
            nrm = 1.0 / np.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
            qw *= nrm
            qx *= nrm
            qy *= nrm
            qz *= nrm
            # v' = v + w t + q x t,  t = 2 q x v
            t0 = 2.0 * (qy * v[2] - qz * v[1])
            t1 = 2.0 * (qz * v[0] - qx * v[2])
            t2 = 2.0 * (qx * v[1] - qy * v[0])
            r0 = v[0] + qw * t0 + (qy * t2 - qz * t1)
            r1 = v[1] + qw * t1 + (qz * t0 - qx * t2)
            r2 = v[2] + qw * t2 + (qx * t1 - qy * t0)
            for j, rj in enumerate((r0, r1, r2)):
                if self.position == "cubic":
                    pj = ((cc[0][j][i] * dt + cc[1][j][i]) * dt + cc[2][j][i]) * dt + cc[3][j][i]
                else:
                    pj = p0[j][i] + (dt * inv_h[i]) * dp[j][i]
                out[sl, j] = rj + pj
        out += self._origin
        return out

    def _ecef_numba(self, t: NDArray[np.float64], xs: NDArray[np.float64]) -> NDArray[np.float64]:
        """The same arithmetic as the numpy path, one pulse at a time in a compiled loop (numba)."""
        th = np.where(self._theta > 1e-12, self._theta, 1e-12)
        inv_sin = 1.0 / np.sin(th)
        q0 = np.ascontiguousarray(self._q0 * inv_sin[:, None])
        q1 = np.ascontiguousarray(self._q1 * inv_sin[:, None])
        inv_h = 1.0 / np.diff(self._t)
        if self.position == "cubic":
            coef = np.ascontiguousarray(np.transpose(self._c, (1, 0, 2)))  # (n-1, 4, 3)
            cubic = True
        else:
            p = self._p
            coef = np.zeros((len(p) - 1, 4, 3))
            coef[:, 3] = p[:-1]
            coef[:, 2] = (p[1:] - p[:-1]) * inv_h[:, None]  # linear: slope per second
            cubic = False
        out = np.empty((len(t), 3))
        _NUMBA_KERNEL(np.ascontiguousarray(t), np.ascontiguousarray(self._t), np.ascontiguousarray(xs, dtype=np.float64),
                      np.ascontiguousarray(self.mount.body_from_scanner, dtype=np.float64),
                      np.asarray(self._lever, dtype=np.float64), th, inv_h, q0, q1, coef, cubic,
                      np.asarray(self._origin, dtype=np.float64), out)
        return out

    def sensor(self, time_s: ArrayLike, ecef: ArrayLike) -> NDArray[np.float64]:
        """Inverse of :meth:`ecef`: scanner-frame coordinates ``(N, 3)`` of ECEF points at pulse times."""
        t = np.asarray(time_s, dtype=np.float64).ravel()
        x = np.asarray(ecef, dtype=np.float64)
        i_all, dt_all = self._locate(t)
        out = np.empty((len(t), 3))
        r = self.mount.body_from_scanner
        for a in range(0, len(t), self.chunk):
            sl = slice(a, a + self.chunk)
            p, q = self._pose(i_all[sl], dt_all[sl])
            xb = _rotate(q, (x[sl] - self._origin) - p, inverse=True) - self._lever
            out[sl] = xb @ r
        return out


@dataclass(frozen=True, eq=False)
class GeoreferencedPoints:
    """Georeferenced pulses.

    Attributes
    ----------
    xyz
        ``(N, 3)`` coordinates in ``frame``.
    time_s
        ``(N,)`` pulse times.
    frame
        The world frame of ``xyz``.
    intensity
        ``(N,)`` or None.
    scan_angle_deg
        ``(N,)`` LAS's scan angle in degrees: the beam's angle from nadir (roll included), positive to the right
        of the aircraft; not the scanner's alpha.
    """

    xyz: NDArray[np.float64]
    time_s: NDArray[np.float64]
    frame: WorldFrame
    intensity: NDArray[np.float64] | None = None
    scan_angle_deg: NDArray[np.float64] | None = None

    def __len__(self) -> int:
        return int(self.xyz.shape[0])


def georeference_scan(
    scan: RawScan,
    trajectory: Trajectory,
    mount: ScannerMount,
    frame: WorldFrame,
    *,
    position: str = "cubic",
    yaw_correction_rad: float | ArrayLike = 0.0,
    barometric: tuple[ArrayLike, ArrayLike] | None = None,
    progress: Callable[[int, int], None] | None = None,
    block: int = 2_000_000,
) -> GeoreferencedPoints:
    """Georeference raw pulses into ``frame`` (paper 002 eqs. 1-4).

    Parameters
    ----------
    scan
        Raw pulses (times within the trajectory's span).
    trajectory, mount
        Navigation and scanner mounting.
    frame
        Output frame (ECEF, local ENU, or a map CRS with its heights).
    position
        ``"cubic"`` or ``"linear"`` position interpolation.
    yaw_correction_rad
        Heading correction added to the IMU yaw (scalar or per trajectory sample).
    barometric
        Optional ``(time_s, h_m)`` barometric ellipsoidal heights replacing the GNSS heights.
    progress
        Optional callback ``progress(done, total)`` (the CLI draws a bar with it).
    block
        Pulses per progress step.

    Raises
    ------
    OutOfRangeError
        A pulse outside the trajectory's time span (the first one is named).
    """
    traj = trajectory
    if barometric is not None:
        traj = with_barometric_height(traj, *barometric)
    if np.any(np.asarray(yaw_correction_rad) != 0):
        traj = with_yaw_correction(traj, yaw_correction_rad)
    geo = PulseGeoreferencer(traj, mount, position)
    geo._locate(scan.time_s)  # fail before any work, naming the first bad pulse
    n = len(scan)
    xyz = np.empty((n, 3))
    nadir = np.empty(n)
    for a in range(0, n, block):
        sl = slice(a, a + block)
        sub = scan.subset(sl)
        e = geo.ecef(sub.time_s, sub.sensor_xyz())
        xyz[sl] = frame.from_ecef(e) if frame.kind != "ecef" else e
        nadir[sl] = scan_angle_from_nadir_deg(geo, mount, sub.time_s, e)
        if progress is not None:
            progress(min(a + block, n), n)
    return GeoreferencedPoints(xyz, scan.time_s.copy(), frame, scan.intensity, nadir)


def scan_angle_from_nadir_deg(geo: PulseGeoreferencer, mount: ScannerMount, time_s: NDArray[np.float64],
                               ecef: NDArray[np.float64]) -> NDArray[np.float64]:
    """LAS's scan angle of pulses (degrees): the beam's angle from nadir, roll included, positive to the right of
    the aircraft (its body y axis made horizontal), 0 for a pulse without length."""
    from skyrig.geodesy.crs import ecef_to_geodetic

    p, R = geo.poses(time_s)
    emitter = p + np.einsum("nij,j->ni", R, mount.lever_arm_m)
    d = ecef - emitter
    lat, lon, _ = ecef_to_geodetic(emitter)
    la, lo = np.radians(lat), np.radians(lon)
    up = np.column_stack([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)])
    right = R[:, :, 1] - np.einsum("ni,ni->n", R[:, :, 1], up)[:, None] * up
    right /= np.linalg.norm(right, axis=1, keepdims=True)
    return np.degrees(np.arctan2(np.einsum("ni,ni->n", d, right), -np.einsum("ni,ni->n", d, up)))


def invert_points(
    xyz: ArrayLike,
    time_s: ArrayLike,
    trajectory: Trajectory,
    mount: ScannerMount,
    frame: WorldFrame,
    *,
    position: str = "cubic",
    yaw_correction_rad: float | ArrayLike = 0.0,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Raw ``(range_m, alpha_rad, beta_rad)`` ``(N,)`` each of georeferenced points at their pulse times."""
    traj = trajectory if np.all(np.asarray(yaw_correction_rad) == 0) else with_yaw_correction(trajectory, yaw_correction_rad)
    geo = PulseGeoreferencer(traj, mount, position)
    e = frame.to_ecef(np.asarray(xyz, dtype=np.float64))
    return polar_from_sensor(geo.sensor(time_s, e))


def _make_numba_kernel():  # pragma: no cover - exercised when numba is installed
    try:
        import numba
    except ImportError:
        return None

    @numba.njit(cache=True, fastmath=False, nogil=True)
    def kernel(t, knots, xs, b, lev, th, inv_h, q0, q1, coef, cubic, origin, out):
        last = knots.shape[0] - 2
        j = 0
        for k in range(t.shape[0]):
            tk = t[k]
            # interval of tk: walk from the previous one (pulses are nearly sorted), binary search otherwise
            if not (knots[j] <= tk < knots[j + 1]):
                if j < last and knots[j + 1] <= tk < knots[j + 2]:
                    j += 1
                else:
                    j = np.searchsorted(knots, tk, "right") - 1
                    if j < 0:
                        j = 0
                    elif j > last:
                        j = last
            d = tk - knots[j]
            x0, x1, x2 = xs[k, 0], xs[k, 1], xs[k, 2]
            v0 = b[0, 0] * x0 + b[0, 1] * x1 + b[0, 2] * x2 + lev[0]
            v1 = b[1, 0] * x0 + b[1, 1] * x1 + b[1, 2] * x2 + lev[1]
            v2 = b[2, 0] * x0 + b[2, 1] * x1 + b[2, 2] * x2 + lev[2]
            tht = th[j]
            ut = d * inv_h[j] * tht
            wa = np.sin(tht - ut)
            wb = np.sin(ut)
            qw = wa * q0[j, 0] + wb * q1[j, 0]
            qx = wa * q0[j, 1] + wb * q1[j, 1]
            qy = wa * q0[j, 2] + wb * q1[j, 2]
            qz = wa * q0[j, 3] + wb * q1[j, 3]
            nrm = 1.0 / np.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
            qw *= nrm
            qx *= nrm
            qy *= nrm
            qz *= nrm
            t0 = 2.0 * (qy * v2 - qz * v1)
            t1 = 2.0 * (qz * v0 - qx * v2)
            t2 = 2.0 * (qx * v1 - qy * v0)
            r0 = v0 + qw * t0 + (qy * t2 - qz * t1)
            r1 = v1 + qw * t1 + (qz * t0 - qx * t2)
            r2 = v2 + qw * t2 + (qx * t1 - qy * t0)
            for a in range(3):
                if cubic:
                    pa = ((coef[j, 0, a] * d + coef[j, 1, a]) * d + coef[j, 2, a]) * d + coef[j, 3, a]
                else:
                    pa = coef[j, 3, a] + d * coef[j, 2, a]
                if a == 0:
                    out[k, 0] = r0 + pa + origin[0]
                elif a == 1:
                    out[k, 1] = r1 + pa + origin[1]
                else:
                    out[k, 2] = r2 + pa + origin[2]

    return kernel


_NUMBA_KERNEL = _make_numba_kernel()
