"""Laser scanner measurement models: raw polar measurements <-> the scanner (sensor) frame.

Paper 002, eq. 1: a pulse with range ``D``, horizontal deflection ``alpha`` and vertical deflection ``beta``
is, in the scanner coordinate system (scs)::

    X_scs = D cos(beta) cos(alpha),   Y_scs = D cos(beta) sin(alpha),   Z_scs = D sin(beta)

A 2D scanner (the Hokuyo UTM-30LX-EW of paper 002) measures in its x-y plane (``beta = 0``, where this is
exactly the paper's equation); ``alpha = 0`` is the centre of its field of view.  The paper prints
``(cos a, sin a, sin b)``, which equals the above for ``beta = 0``; skyrig uses the spherical form so that a
3D scanner's ``beta`` is handled correctly.

An airborne line scanner (oscillating mirror, rotating polygon) is the same model with its scan plane
mounted across the flight direction: :meth:`AirborneLineScanner.sensor_from_scan_angle` puts a pulse at
scan angle ``theta`` at ``D (0, sin theta, cos theta)`` so that ``theta = 0`` is the scanner's z axis (nadir
when the scanner z is mounted along body z, down) and positive angles point to the right (body y),
which is how LAS's ``scan_angle`` counts (positive to the right of the flight direction).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.errors import InputFormatError, OutOfRangeError

__all__ = [
    "AirborneLineScanner",
    "RawScan",
    "Scanner2D",
    "HOKUYO_UTM_30LX_EW",
    "polar_from_sensor",
    "sensor_from_polar",
]


def sensor_from_polar(range_m: ArrayLike, alpha_rad: ArrayLike, beta_rad: ArrayLike | None = None) -> NDArray[np.float64]:
    """Scanner-frame coordinates ``(N, 3)`` (metres) of pulses (paper 002 eq. 1).

    Parameters
    ----------
    range_m
        ``(N,)`` measured distances ``D`` (metres).
    alpha_rad
        ``(N,)`` horizontal deflection angles (radians, from the scanner x axis towards y).
    beta_rad
        ``(N,)`` vertical deflection angles (radians, towards z); None for a 2D scanner (0).
    """
    d = np.asarray(range_m, dtype=np.float64)
    a = np.asarray(alpha_rad, dtype=np.float64)
    out = np.empty(np.broadcast(d, a).shape + (3,))
    if beta_rad is None:
        out[..., 0] = d * np.cos(a)
        out[..., 1] = d * np.sin(a)
        out[..., 2] = 0.0
    else:
        b = np.asarray(beta_rad, dtype=np.float64)
        dc = d * np.cos(b)
        out[..., 0] = dc * np.cos(a)
        out[..., 1] = dc * np.sin(a)
        out[..., 2] = d * np.sin(b)
    return out


def polar_from_sensor(xyz: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Inverse of :func:`sensor_from_polar`: ``(range_m, alpha_rad, beta_rad)``, ``(N,)`` each.

    ``alpha`` is in (-pi, pi], ``beta`` in [-pi/2, pi/2].
    """
    p = np.asarray(xyz, dtype=np.float64)
    horiz = np.hypot(p[..., 0], p[..., 1])
    return np.sqrt(horiz**2 + p[..., 2] ** 2), np.arctan2(p[..., 1], p[..., 0]), np.arctan2(p[..., 2], horiz)


@dataclass(frozen=True, eq=False)
class RawScan:
    """Raw pulses of a scanner: ``N`` time-stamped polar measurements.

    Attributes
    ----------
    time_s
        ``(N,)`` pulse times (seconds, the trajectory's time system), non-decreasing.
    range_m
        ``(N,)`` distances (metres).
    alpha_rad
        ``(N,)`` horizontal deflection (2D scanners: the angle in the scan plane).
    beta_rad
        ``(N,)`` vertical deflection, or None (2D scanner).
    intensity
        ``(N,)`` return intensities, or None.
    strip_id
        ``(N,)`` integer strip (flight line) of each pulse, or None (one strip); -1 for pulses outside any strip.

    Raises
    ------
    InputFormatError
        On mismatched shapes, non-finite values or negative ranges.
    OutOfRangeError
        If the times decrease (names the first pulse index).
    """

    time_s: NDArray[np.float64]
    range_m: NDArray[np.float64]
    alpha_rad: NDArray[np.float64]
    beta_rad: NDArray[np.float64] | None = None
    intensity: NDArray[np.float64] | None = None
    strip_id: NDArray[np.int64] | None = None

    def __post_init__(self) -> None:
        t = np.asarray(self.time_s, dtype=np.float64)
        if t.ndim != 1:
            raise InputFormatError(f"pulse times must be 1-D, got shape {t.shape}", field="time")
        n = len(t)
        for name in ("time_s", "range_m", "alpha_rad", "beta_rad", "intensity"):
            v = getattr(self, name)
            if v is None:
                continue
            a = np.asarray(v, dtype=np.float64)
            if a.shape != (n,):
                raise InputFormatError(f"expected shape {(n,)}, got {a.shape}", field=name)
            bad = ~np.isfinite(a)
            if np.any(bad):
                raise InputFormatError(f"non-finite value at pulse {int(np.argmax(bad))}", field=name)
            object.__setattr__(self, name, a)
        if self.strip_id is not None:
            sid = np.asarray(self.strip_id)
            if sid.shape != (n,):
                raise InputFormatError(f"expected shape {(n,)}, got {sid.shape}", field="strip_id")
            if sid.dtype.kind == "f":
                bad = ~np.isfinite(sid) | (sid != np.round(sid))
                if np.any(bad):
                    raise InputFormatError(f"strip ids must be integers: pulse {int(np.argmax(bad))} has "
                                           f"{sid[int(np.argmax(bad))]!r}", field="strip_id")
            elif sid.dtype.kind not in "iu":
                raise InputFormatError(f"strip ids must be integers, got dtype {sid.dtype}", field="strip_id")
            object.__setattr__(self, "strip_id", sid.astype(np.int64))
        if np.any(self.range_m < 0):
            raise InputFormatError(f"negative range at pulse {int(np.argmax(self.range_m < 0))}", field="range_m")
        dt = np.diff(self.time_s)
        if np.any(dt < 0):
            k = int(np.argmax(dt < 0)) + 1
            raise OutOfRangeError(
                f"pulse timestamps must not decrease: time[{k}] = {self.time_s[k]!r} < time[{k - 1}] = "
                f"{self.time_s[k - 1]!r} (pulse {k})"
            )

    def __len__(self) -> int:
        return int(self.time_s.shape[0])

    def sensor_xyz(self) -> NDArray[np.float64]:
        """``(N, 3)`` pulse coordinates in the scanner frame (eq. 1)."""
        return sensor_from_polar(self.range_m, self.alpha_rad, self.beta_rad)

    def subset(self, rows: ArrayLike | slice) -> "RawScan":
        r = rows if isinstance(rows, slice) else np.asarray(rows)
        pick = (lambda v: None if v is None else v[r])  # noqa: E731
        return RawScan(self.time_s[r], self.range_m[r], self.alpha_rad[r], pick(self.beta_rad), pick(self.intensity),
                       pick(self.strip_id))


@dataclass(frozen=True)
class Scanner2D:
    """A 2D line scanner with a rotating mirror (e.g. the Hokuyo UTM-30LX-EW of paper 002).

    Attributes
    ----------
    field_of_view_deg
        Angular field of view, centred on the scanner x axis (paper 002: 270 deg).
    step_deg
        Angular step between pulses (0.25 deg).
    lines_per_s
        Mirror revolutions (scan lines) per second (40).  A line's pulses are spread over the part of
        the revolution inside the field of view: pulse ``k`` is fired ``(alpha_k - alpha_0) / 360 deg``
        of a revolution after the line start.
    range_min_m, range_max_m
        Measurable distances (0.1 m to 30 m).
    range_sigma_m
        Range noise, one sigma (30 mm to 50 mm for the UTM-30LX-EW; 0.03 here).
    """

    field_of_view_deg: float = 270.0
    step_deg: float = 0.25
    lines_per_s: float = 40.0
    range_min_m: float = 0.1
    range_max_m: float = 30.0
    range_sigma_m: float = 0.03

    @property
    def pulses_per_line(self) -> int:
        return int(round(self.field_of_view_deg / self.step_deg))

    def angles_rad(self) -> NDArray[np.float64]:
        """``(pulses_per_line,)`` deflection angles alpha (radians), symmetric about 0."""
        k = np.arange(self.pulses_per_line)
        return np.radians(-self.field_of_view_deg / 2 + (k + 0.5) * self.step_deg)

    def pulse_times_and_angles(self, line_start_s: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Times and alphas ``(L * pulses_per_line,)`` of the pulses of lines starting at ``line_start_s`` ``(L,)``."""
        t0 = np.asarray(line_start_s, dtype=np.float64).reshape(-1, 1)
        a = self.angles_rad()
        dt = (a - a[0]) / (2 * np.pi) / self.lines_per_s
        return (t0 + dt).ravel(), np.broadcast_to(a, (t0.shape[0], a.size)).ravel().copy()


#: Paper 002's scanner.
HOKUYO_UTM_30LX_EW = Scanner2D()


@dataclass(frozen=True)
class AirborneLineScanner:
    """An airborne across-track line scanner.

    Attributes
    ----------
    field_of_view_deg
        Full scan angle (e.g. 60 deg: +-30 deg).
    pulse_rate_hz
        Pulses per second.
    lines_per_s
        Scan lines per second (one sweep across the field of view per line).
    range_sigma_m
        Range noise (one sigma).
    """

    field_of_view_deg: float = 60.0
    pulse_rate_hz: float = 200_000.0
    lines_per_s: float = 100.0
    range_sigma_m: float = 0.02

    @staticmethod
    def sensor_from_scan_angle(range_m: ArrayLike, scan_angle_rad: ArrayLike) -> NDArray[np.float64]:
        """``(N, 3)`` scanner-frame points ``D (0, sin theta, cos theta)``."""
        d = np.asarray(range_m, dtype=np.float64)
        th = np.asarray(scan_angle_rad, dtype=np.float64)
        return np.stack([np.zeros_like(d * th), d * np.sin(th), d * np.cos(th)], axis=-1)

    @staticmethod
    def scan_angle_from_sensor(xyz: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Inverse of :meth:`sensor_from_scan_angle`: ``(range_m, scan_angle_rad)`` (ignores x)."""
        p = np.asarray(xyz, dtype=np.float64)
        return np.linalg.norm(p, axis=-1), np.arctan2(p[..., 1], p[..., 2])

    def as_raw_angles(self, scan_angle_rad: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(alpha_rad, beta_rad)`` of eq. 1 for scan angles, so that a :class:`RawScan` holds them:
        ``D (0, sin theta, cos theta) = D (cos b cos a, cos b sin a, sin b)`` with ``a = pi/2`` and
        ``b = pi/2 - theta``."""
        th = np.asarray(scan_angle_rad, dtype=np.float64)
        return np.full_like(th, np.pi / 2), np.pi / 2 - th

    def pulse_times_and_angles(self, t0: float, duration_s: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Times and scan angles of a sawtooth sweep from ``t0`` for ``duration_s`` seconds."""
        n = int(round(duration_s * self.pulse_rate_hz))
        t = t0 + np.arange(n) / self.pulse_rate_hz
        phase = ((t - t0) * self.lines_per_s) % 1.0
        half = np.radians(self.field_of_view_deg) / 2
        return t, -half + 2 * half * phase
