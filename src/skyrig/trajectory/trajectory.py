"""GNSS/IMU trajectories: time-stamped positions and attitudes, interpolated at event times.

Conventions
-----------
* Positions are WGS84 geodetic: latitude and longitude in degrees, ellipsoidal height ``h`` in metres.
  They refer either to the IMU centre or to the GNSS antenna phase centre (``reference``).
* Attitude is ``ned_from_body`` (see :mod:`skyrig.geometry.rotations`): body frame x forward, y right,
  z down; local North-East-Down frame at the trajectory position; roll, pitch, yaw (true heading)
  with ``R = Rz(yaw) Ry(pitch) Rx(roll)``.  It is stored as Hamilton quaternions ``(w, x, y, z)``.
* Time is a plain number of seconds in the trajectory's ``time_system`` (``"gps-sow"`` for GPS seconds
  of week, ``"gps"`` for seconds since the GPS epoch...).  Events must use the same time system.

Interpolation
-------------
Positions are interpolated in ECEF (linear, or a cubic spline; a cubic Hermite spline when
velocities are given).  Attitudes are interpolated by slerp between the two neighbouring samples.
Because the NED frame turns with the position (by the angle travelled over the Earth, about
``v dt / R_earth``: 1.5e-6 rad for 10 m between 200 Hz samples), slerp is done on ``ecef_from_body``,
which is Earth-fixed, and the result is expressed again in the NED frame *of the interpolated
position*.  Slerping ``ned_from_body`` directly would differ by less than the NED frame's rotation
between the two samples, which is negligible over the sub-second spacing of navigation data, but the
ECEF form costs nothing more and is exact for a body turning uniformly about a fixed axis.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import CubicHermiteSpline, CubicSpline

from skyrig.errors import InputFormatError, OutOfRangeError
from skyrig.geodesy.crs import MapProjection, ecef_to_geodetic, geodetic_to_ecef
from skyrig.geodesy.local import ecef_from_ned_rotation  # re-exported: part of this module's API
from skyrig.geometry.angles import from_radians, normalize_unit, to_radians
from skyrig.geometry.rotations import (
    matrix_from_quaternion,
    matrix_from_rpy,
    quaternion_from_matrix,
    rpy_from_matrix,
    slerp,
)

PositionMethod = Literal["cubic", "linear"]
Reference = Literal["imu", "antenna"]
HeadingReference = Literal["true", "grid"]

__all__ = ["Trajectory", "TrajectorySample", "ecef_from_ned_rotation"]


def _arr(name: str, value: ArrayLike | None, shape: tuple[int, ...]) -> NDArray[np.float64] | None:
    if value is None:
        return None
    a = np.array(value, dtype=np.float64)  # copy: the dataclass owns its arrays
    if a.shape != shape:
        raise InputFormatError(f"expected shape {shape}, got {a.shape}", field=name)
    bad = ~np.isfinite(a.reshape(shape[0], -1)).all(axis=1) if a.size else np.zeros(0, bool)
    if np.any(bad):
        raise InputFormatError(f"non-finite value at index {int(np.argmax(bad))}", field=name)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class TrajectorySample:
    """A trajectory interpolated at ``M`` times.

    Attributes
    ----------
    time_s
        ``(M,)`` query times (seconds, the trajectory's time system).
    ecef
        ``(M, 3)`` positions in WGS84 ECEF (metres).
    lat_deg, lon_deg, h_m
        ``(M,)`` the same positions as WGS84 geodetic coordinates (degrees, ellipsoidal metres).
    ned_from_body
        ``(M, 3, 3)`` attitudes, in the NED frame at the interpolated position.
    velocity_ned
        ``(M, 3)`` velocity (m/s, north, east, down): interpolated linearly from the trajectory's
        velocities when it has them, otherwise the time derivative of the position interpolant.
    reference
        ``"imu"`` or ``"antenna"``, copied from the trajectory.
    """

    time_s: NDArray[np.float64]
    ecef: NDArray[np.float64]
    lat_deg: NDArray[np.float64]
    lon_deg: NDArray[np.float64]
    h_m: NDArray[np.float64]
    ned_from_body: NDArray[np.float64]
    velocity_ned: NDArray[np.float64] | None = None
    reference: str = "imu"

    def __len__(self) -> int:
        return int(self.time_s.shape[0])

    @property
    def ecef_from_ned(self) -> NDArray[np.float64]:
        """``(M, 3, 3)`` rotations from the local NED frame at each sample to ECEF."""
        return ecef_from_ned_rotation(self.lat_deg, self.lon_deg)

    @property
    def ecef_from_body(self) -> NDArray[np.float64]:
        """``(M, 3, 3)`` body attitudes in ECEF: ``ecef_from_ned @ ned_from_body``."""
        return self.ecef_from_ned @ self.ned_from_body

    def rpy(self, unit: str = "deg") -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Roll, pitch, yaw (true heading) ``(M,)`` each, in ``unit``."""
        return rpy_from_matrix(self.ned_from_body, unit)


@dataclass(frozen=True, eq=False)
class Trajectory:
    """A GNSS/IMU trajectory: ``N`` time-stamped positions and attitudes.

    Attributes
    ----------
    time_s
        ``(N,)`` strictly increasing times in seconds, in ``time_system``.
    lat_deg, lon_deg
        ``(N,)`` WGS84 latitude and longitude in degrees.
    h_m
        ``(N,)`` WGS84 ellipsoidal height in metres.
    ned_from_body_q
        ``(N, 4)`` attitude quaternions ``(w, x, y, z)`` of ``ned_from_body`` (normalised on input).
    velocity_ned
        Optional ``(N, 3)`` velocity in m/s (north, east, down; true north).
    sigma_ned_m
        Optional ``(N, 3)`` position standard deviations in metres (north, east, down).
    sigma_rpy_rad
        Optional ``(N, 3)`` attitude standard deviations in radians (roll, pitch, yaw).
    time_system
        Name of the time scale, e.g. ``"gps-sow"`` (GPS seconds of week), ``"gps"`` (seconds since
        1980-01-06 GPS time), ``"utc-sod"``.
    reference
        Which point the positions refer to: ``"imu"`` or ``"antenna"``.

    Raises
    ------
    InputFormatError
        On arrays of the wrong shape, non-finite values, latitudes beyond +-90 degrees, zero
        quaternions, an unknown ``reference``, or fewer than 2 samples.
    OutOfRangeError
        If times are not strictly increasing (the message names the first offending index).
    """

    time_s: NDArray[np.float64]
    lat_deg: NDArray[np.float64]
    lon_deg: NDArray[np.float64]
    h_m: NDArray[np.float64]
    ned_from_body_q: NDArray[np.float64]
    velocity_ned: NDArray[np.float64] | None = None
    sigma_ned_m: NDArray[np.float64] | None = None
    sigma_rpy_rad: NDArray[np.float64] | None = None
    time_system: str = "gps-sow"
    reference: str = "imu"

    def __post_init__(self) -> None:
        t = np.asarray(self.time_s)
        if t.ndim != 1:
            raise InputFormatError(f"time must be 1-D, got shape {t.shape}", field="time")
        n = t.shape[0]
        if n < 2:
            raise InputFormatError(f"a trajectory needs at least 2 samples, got {n}", field="time")
        for name in ("time_s", "lat_deg", "lon_deg", "h_m"):
            object.__setattr__(self, name, _arr(name, getattr(self, name), (n,)))
        q = np.array(self.ned_from_body_q, dtype=np.float64)
        if q.shape != (n, 4):
            raise InputFormatError(f"expected shape {(n, 4)}, got {q.shape}", field="ned_from_body_q")
        norm = np.linalg.norm(q, axis=1)
        bad = ~np.isfinite(norm) | (norm < 1e-9)
        if np.any(bad):
            raise InputFormatError(
                f"quaternion at index {int(np.argmax(bad))} is not finite or zero", field="ned_from_body_q"
            )
        q = q / norm[:, None]
        q.setflags(write=False)
        object.__setattr__(self, "ned_from_body_q", q)
        for name in ("velocity_ned", "sigma_ned_m", "sigma_rpy_rad"):
            object.__setattr__(self, name, _arr(name, getattr(self, name), (n, 3)))
        for name in ("sigma_ned_m", "sigma_rpy_rad"):
            s = getattr(self, name)
            if s is not None and np.any(s < 0):
                raise InputFormatError(f"negative standard deviation at index {int(np.argmax((s < 0).any(1)))}",
                                       field=name)
        lat = self.lat_deg
        if np.any(np.abs(lat) > 90.0):
            raise InputFormatError(f"latitude beyond +-90 deg at index {int(np.argmax(np.abs(lat) > 90))}",
                                   field="lat_deg")
        if self.reference not in ("imu", "antenna"):
            raise InputFormatError(f"reference must be 'imu' or 'antenna', not {self.reference!r}",
                                   field="reference")
        dt = np.diff(self.time_s)
        if np.any(dt <= 0):
            i = int(np.argmax(dt <= 0)) + 1
            raise OutOfRangeError(
                f"trajectory times must be strictly increasing: time[{i}] = {self.time_s[i]!r} "
                f"<= time[{i - 1}] = {self.time_s[i - 1]!r}"
            )

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_rpy(
        cls,
        time_s: ArrayLike,
        lat_deg: ArrayLike,
        lon_deg: ArrayLike,
        h_m: ArrayLike,
        roll: ArrayLike,
        pitch: ArrayLike,
        yaw: ArrayLike,
        unit: str = "deg",
        *,
        velocity_ned: ArrayLike | None = None,
        sigma_ned_m: ArrayLike | None = None,
        sigma_rpy: ArrayLike | None = None,
        time_system: str = "gps-sow",
        reference: str = "imu",
    ) -> "Trajectory":
        """Build a trajectory from geodetic positions and roll, pitch, yaw (true heading).

        Parameters
        ----------
        time_s, lat_deg, lon_deg, h_m
            ``(N,)`` each: seconds, degrees, degrees, ellipsoidal metres.
        roll, pitch, yaw
            ``(N,)`` each, in ``unit``; yaw is the true heading (clockwise from geographic north).
        unit
            ``"deg"``, ``"rad"`` or ``"gon"``; also the unit of ``sigma_rpy``.
        velocity_ned, sigma_ned_m
            Optional ``(N, 3)`` velocity (m/s, NED) and position standard deviations (m, NED).
        sigma_rpy
            Optional ``(N, 3)`` roll, pitch, yaw standard deviations in ``unit``.
        time_system, reference
            See :class:`Trajectory`.
        """
        unit = normalize_unit(unit)
        r, p, y = (np.asarray(v, dtype=np.float64) for v in (roll, pitch, yaw))
        for name, v in (("roll", r), ("pitch", p), ("yaw", y)):
            if not np.all(np.isfinite(v)):
                raise InputFormatError(f"non-finite angle at index {int(np.argmax(~np.isfinite(v)))}", field=name)
        q = quaternion_from_matrix(matrix_from_rpy(r, p, y, unit))
        s_rpy = None if sigma_rpy is None else to_radians(sigma_rpy, unit)
        return cls(
            np.asarray(time_s, dtype=np.float64), np.asarray(lat_deg, dtype=np.float64),
            np.asarray(lon_deg, dtype=np.float64), np.asarray(h_m, dtype=np.float64), q,
            velocity_ned=velocity_ned, sigma_ned_m=sigma_ned_m, sigma_rpy_rad=s_rpy,
            time_system=time_system, reference=reference,
        )

    @classmethod
    def from_map(
        cls,
        time_s: ArrayLike,
        xyz_map: ArrayLike,
        projection: MapProjection,
        roll: ArrayLike,
        pitch: ArrayLike,
        yaw: ArrayLike,
        unit: str = "deg",
        heading_reference: HeadingReference = "true",
        **kwargs: Any,
    ) -> "Trajectory":
        """Build a trajectory from map coordinates (a projected or geographic CRS).

        Parameters
        ----------
        time_s
            ``(N,)`` seconds.
        xyz_map
            ``(N, 3)`` easting, northing, height in ``projection`` (for a geographic CRS: longitude,
            latitude in degrees, height).  Heights are orthometric when the projection has a geoid,
            otherwise ellipsoidal.
        projection
            The map frame.
        roll, pitch, yaw
            ``(N,)`` each, in ``unit``.
        heading_reference
            ``"true"``: yaw counts from geographic north; ``"grid"``: yaw counts from grid north and is
            converted with the meridian convergence ``gamma`` (azimuth of grid north clockwise from
            true north, :meth:`MapProjection.factors`): ``yaw_true = yaw_grid + gamma``.
        **kwargs
            Passed to :meth:`from_rpy` (``velocity_ned``, ``sigma_ned_m``, ``sigma_rpy``, ``time_system``,
            ``reference``).  Velocities are always true NED.
        """
        p = np.asarray(xyz_map, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise InputFormatError(f"xyz_map must be (N, 3), got {p.shape}", field="xyz_map")
        llh = projection.to_geodetic(p)
        yaw_rad = to_radians(yaw, unit)
        if heading_reference == "grid":
            gamma, _ = projection.factors(p)
            yaw_rad = yaw_rad + gamma
        elif heading_reference != "true":
            raise InputFormatError(f"heading reference must be 'true' or 'grid', not {heading_reference!r}",
                                   field="heading")
        return cls.from_rpy(time_s, llh[:, 0], llh[:, 1], llh[:, 2], roll, pitch,
                            from_radians(yaw_rad, unit), unit, **kwargs)

    # ------------------------------------------------------------------ views
    def __len__(self) -> int:
        return int(self.time_s.shape[0])

    @property
    def span(self) -> tuple[float, float]:
        """``(first, last)`` time in seconds."""
        return float(self.time_s[0]), float(self.time_s[-1])

    @property
    def ned_from_body(self) -> NDArray[np.float64]:
        """``(N, 3, 3)`` attitude matrices."""
        return matrix_from_quaternion(self.ned_from_body_q)

    def rpy(self, unit: str = "deg") -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Roll, pitch, yaw (true heading) ``(N,)`` each in ``unit``; yaw in (-180, 180] deg."""
        return rpy_from_matrix(self.ned_from_body, unit)

    @cached_property
    def ecef(self) -> NDArray[np.float64]:
        """``(N, 3)`` positions in WGS84 ECEF (metres)."""
        e = geodetic_to_ecef(self.lat_deg, self.lon_deg, self.h_m)
        e.setflags(write=False)
        return e

    @cached_property
    def _ecef_from_body_q(self) -> NDArray[np.float64]:
        r = ecef_from_ned_rotation(self.lat_deg, self.lon_deg) @ self.ned_from_body
        return quaternion_from_matrix(r)

    @cached_property
    def _velocity_ecef(self) -> NDArray[np.float64] | None:
        if self.velocity_ned is None:
            return None
        r = ecef_from_ned_rotation(self.lat_deg, self.lon_deg)
        return np.einsum("nij,nj->ni", r, self.velocity_ned)

    @cached_property
    def _spline(self) -> CubicSpline | CubicHermiteSpline:
        t = self.time_s - self.time_s[0]
        if self._velocity_ecef is not None:
            return CubicHermiteSpline(t, self.ecef, self._velocity_ecef, axis=0)
        if len(t) < 4:
            return CubicSpline(t, self.ecef, axis=0, bc_type="natural")
        return CubicSpline(t, self.ecef, axis=0)

    def to_map(
        self, projection: MapProjection, heading_reference: HeadingReference = "true", unit: str = "deg"
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Positions in map coordinates and attitude angles for writing in a map frame.

        Returns
        -------
        xyz_map
            ``(N, 3)`` coordinates in ``projection`` (orthometric heights if it has a geoid).
        roll, pitch, yaw
            ``(N,)`` each in ``unit``; yaw from grid north when ``heading_reference == "grid"``
            (``yaw_grid = yaw_true - gamma``), wrapped to (-half turn, half turn].
        """
        xyz = projection.from_geodetic(np.stack([self.lat_deg, self.lon_deg, self.h_m], axis=1))
        r, p, y = self.rpy("rad")
        if heading_reference == "grid":
            gamma, _ = projection.factors(xyz)
            y = np.arctan2(np.sin(y - gamma), np.cos(y - gamma))
        elif heading_reference != "true":
            raise InputFormatError(f"heading reference must be 'true' or 'grid', not {heading_reference!r}",
                                   field="heading")
        return xyz, from_radians(r, unit), from_radians(p, unit), from_radians(y, unit)

    # ------------------------------------------------------------------ interpolation
    def locate(self, times: ArrayLike) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
        """Interval index ``i`` and fraction ``u`` in [0, 1] with ``t = t[i] + u (t[i+1] - t[i])``.

        Raises
        ------
        OutOfRangeError
            Naming the first time (and its index) outside ``[time_s[0], time_s[-1]]`` or not finite.
        """
        t = np.asarray(times, dtype=np.float64)
        t0, t1 = self.span
        bad = ~((t >= t0) & (t <= t1))  # also catches NaN
        if np.any(bad):
            k = int(np.flatnonzero(bad.ravel())[0])
            raise OutOfRangeError(
                f"time {t.ravel()[k]!r} (event index {k}) is outside the trajectory's time span "
                f"[{t0!r}, {t1!r}] ({self.time_system})"
            )
        i = np.searchsorted(self.time_s, t, side="right") - 1
        i = np.clip(i, 0, len(self) - 2)
        ta = self.time_s[i]
        u = (t - ta) / (self.time_s[i + 1] - ta)
        return i, u

    def interpolate(self, times: ArrayLike, position: PositionMethod = "cubic") -> TrajectorySample:
        """Positions and attitudes at ``times`` (vectorised; no Python loop over events).

        Parameters
        ----------
        times
            ``(M,)`` seconds in the trajectory's time system, all within its span.
        position
            ``"cubic"``: a not-a-knot cubic spline through the ECEF positions, or a cubic Hermite spline
            when the trajectory has velocities; ``"linear"``: straight lines in ECEF.

        Returns
        -------
        TrajectorySample

        Raises
        ------
        OutOfRangeError
            If a time lies outside the trajectory's span (the first one and its index are named).
        """
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        if t.ndim != 1:
            raise InputFormatError(f"times must be 1-D, got shape {t.shape}", field="time")
        i, u = self.locate(t)
        if position == "linear":
            ecef = self.ecef[i] + u[:, None] * (self.ecef[i + 1] - self.ecef[i])
            vel_ecef = (self.ecef[i + 1] - self.ecef[i]) / (self.time_s[i + 1] - self.time_s[i])[:, None]
        elif position == "cubic":
            s = self._spline
            tr = t - self.time_s[0]
            ecef = s(tr)
            vel_ecef = s(tr, 1)
        else:
            raise InputFormatError(f"position interpolation must be 'cubic' or 'linear', not {position!r}",
                                   field="position")
        lat, lon, h = ecef_to_geodetic(ecef)
        lat, lon, h = (np.asarray(v, dtype=np.float64).reshape(-1) for v in (lat, lon, h))
        q = slerp(self._ecef_from_body_q[i], self._ecef_from_body_q[i + 1], u)
        ned_from_ecef = np.swapaxes(ecef_from_ned_rotation(lat, lon), -1, -2)
        ned_from_body = ned_from_ecef @ matrix_from_quaternion(q)
        if self.velocity_ned is not None:
            v = self.velocity_ned
            vel = v[i] + u[:, None] * (v[i + 1] - v[i])
        else:
            vel = np.einsum("mij,mj->mi", ned_from_ecef, vel_ecef)
        return TrajectorySample(t, ecef, lat, lon, h, ned_from_body, vel, self.reference)
