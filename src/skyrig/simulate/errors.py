"""Configurable sensor errors of a simulated survey; every injected value is returned for the truth file.

Sign conventions (all vectors in the scene's local ENU frame, metres; angles radians):

* **GNSS** recorded antenna position = true + ``noise`` (white, per sample) + ``bias`` + per-strip shift
  (drawn once per strip with ``strip_shift_sigma_m``) + ``drift_mps * (t - t_strip_start)`` + ``datum_shift_m``
  (a constant shift between the GNSS frame and the control frame, paper 003 Tab. 4).
* **antenna lever arm**: the rig file records ``true - antenna_lever_error_m`` (an unknown offset, paper 003).
* **time offset**: recorded event time = true time + ``time_offset_s``.
* **IMU**: recorded roll, pitch, yaw = true + ``imu_bias_rad`` + white ``imu_noise_rad``.
* **boresight** per head: the true rig has ``body_from_camera = R_rpy(droll, dpitch, dyaw) @ mounting``
  (misalignment as roll/pitch/yaw about the body axes, the way paper 003 Tab. 4 reports it); the rig file
  records the nominal mounting.
* **tumbling head curve**: the true head carries a smooth periodic beta-dependent correction
  ``sum_k a_k sin(k beta + phase_k)`` per axis (paper 000 Fig. 8); the rig file has none.
* **focal length** change in flight per head (true = recorded + change).
* **image measurements**: Gaussian noise ``measurement_sigma_px``; ``gross_measurements`` of them moved by
  ``gross_measurement_px``; ``displaced_gcps`` ground control points moved by ``gcp_displacement_m``.
* **tie points**: ``tie_points`` surface points (roofs and ground) drawn over the flown area, measured in every
  image that sees them (unoccluded, in the frame) with the measurement noise; ``wrong_tie_points`` of these
  observations are false matches: the image position of another tie point in the same image (or, in an
  image with no other, a random position).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np
from numpy.typing import NDArray

from skyrig.errors import SkyrigError

_Vec = tuple[float, float, float]


@dataclass(frozen=True)
class SensorErrors:
    """Error configuration (see the module docstring; all zero by default)."""

    gnss_noise_m: _Vec = (0.0, 0.0, 0.0)  # 1-sigma white noise per sample, E N U
    gnss_bias_m: _Vec = (0.0, 0.0, 0.0)  # constant bias, E N U
    gnss_strip_shift_sigma_m: float = 0.0  # sigma of a random shift per strip (each axis)
    gnss_drift_mps: _Vec = (0.0, 0.0, 0.0)  # drift per second since the start of each strip
    datum_shift_m: _Vec = (0.0, 0.0, 0.0)  # GNSS frame minus control frame
    antenna_lever_error_m: _Vec = (0.0, 0.0, 0.0)  # true antenna lever arm minus the recorded one (body)
    time_offset_s: float = 0.0  # recorded minus true event time
    imu_noise_rad: _Vec = (0.0, 0.0, 0.0)  # white noise roll, pitch, yaw
    imu_bias_rad: _Vec = (0.0, 0.0, 0.0)  # constant bias roll, pitch, yaw
    boresight_rpy_rad: dict[str, _Vec] = field(default_factory=dict)  # per head misalignment (roll, pitch, yaw)
    tumble_curve_amp_rad: _Vec = (0.0, 0.0, 0.0)  # amplitude of the beta-dependent curve per axis
    focal_change_mm: dict[str, float] = field(default_factory=dict)  # per head, true minus recorded
    measurement_sigma_px: float = 0.0
    gross_measurements: int = 0
    gross_measurement_px: float = 25.0
    gcp_sigma_m: _Vec = (0.0, 0.0, 0.0)  # noise of the surveyed GCP coordinates (E N U)
    displaced_gcps: int = 0
    gcp_displacement_m: float = 5.0
    tie_points: int = 0  # natural tie points (roof / ground points seen in >= 2 images) to simulate
    wrong_tie_points: int = 0  # tie observations replaced by a false match (another point's image position)

    def to_dict(self) -> dict:
        out = {}
        for f in fields(self):
            v = getattr(self, f.name)
            out[f.name] = {k: list(map(float, np.atleast_1d(x))) for k, x in v.items()} if isinstance(v, dict) else (
                list(map(float, v)) if isinstance(v, tuple) else v)
        return out

    @classmethod
    def from_dict(cls, d: dict) -> "SensorErrors":
        known = {f.name for f in fields(cls)}
        bad = set(d) - known
        if bad:
            raise SkyrigError(f"unknown sensor error keys: {sorted(bad)}")
        kw = {}
        for k, v in d.items():
            if k == "focal_change_mm":
                kw[k] = {h: float(np.atleast_1d(x)[0]) for h, x in v.items()}
            elif k == "boresight_rpy_rad":
                kw[k] = {h: tuple(map(float, x)) for h, x in v.items()}
            elif isinstance(v, list):
                kw[k] = tuple(map(float, v))
            elif k in ("tie_points", "wrong_tie_points", "gross_measurements", "displaced_gcps"):
                kw[k] = int(v)
            else:
                kw[k] = v
        return cls(**kw)


@dataclass(frozen=True)
class GnssErrorSeries:
    """Injected GNSS errors per trajectory sample ``(N, 3)`` ENU metres and the per-strip shifts ``(S, 3)``."""

    total_m: NDArray[np.float64]
    noise_m: NDArray[np.float64]
    strip_shift_m: NDArray[np.float64]


def gnss_errors(err: SensorErrors, time_s: NDArray[np.float64], strip: NDArray[np.int64],
                rng: np.random.Generator) -> GnssErrorSeries:
    """Error vectors for samples at ``time_s (N,)`` belonging to strips ``strip (N,)``."""
    n = time_s.shape[0]
    ns = int(strip.max()) + 1 if n else 0
    noise = rng.normal(0.0, 1.0, (n, 3)) * np.asarray(err.gnss_noise_m)
    shifts = rng.normal(0.0, err.gnss_strip_shift_sigma_m, (ns, 3)) if err.gnss_strip_shift_sigma_m > 0 else np.zeros((ns, 3))
    t_start = np.array([time_s[strip == s].min() if np.any(strip == s) else 0.0 for s in range(ns)])
    drift = (time_s - t_start[strip])[:, None] * np.asarray(err.gnss_drift_mps)
    total = noise + np.asarray(err.gnss_bias_m) + shifts[strip] + drift + np.asarray(err.datum_shift_m)
    return GnssErrorSeries(total, noise, shifts)


def imu_errors(err: SensorErrors, n: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """``(N, 3)`` roll, pitch, yaw errors (radians) added to the recorded attitudes."""
    return rng.normal(0.0, 1.0, (n, 3)) * np.asarray(err.imu_noise_rad) + np.asarray(err.imu_bias_rad)


def tumble_curve_samples(amp_rad: NDArray[np.float64] | tuple, rng: np.random.Generator, n_pos: int = 72,
                         harmonics: int = 3) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A smooth periodic boresight curve: positions ``(n_pos,)`` and corrections ``(n_pos, 3)`` (radians)."""
    beta = np.arange(n_pos) * 2 * np.pi / n_pos
    amp = np.asarray(amp_rad, dtype=np.float64)
    out = np.zeros((n_pos, 3))
    for k in range(1, harmonics + 1):
        ph = rng.uniform(0, 2 * np.pi, 3)
        out += (amp / k) * np.sin(k * beta[:, None] + ph)
    return beta, out


def add_measurement_errors(pixel: NDArray[np.float64], err: SensorErrors, rng: np.random.Generator
                           ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Noisy measurements ``(N, 2)`` and the mask of gross errors."""
    noisy = pixel + rng.normal(0.0, err.measurement_sigma_px, pixel.shape) if err.measurement_sigma_px > 0 else pixel.copy()
    gross = np.zeros(pixel.shape[0], bool)
    k = min(err.gross_measurements, pixel.shape[0])
    if k:
        idx = rng.choice(pixel.shape[0], k, replace=False)
        ang = rng.uniform(0, 2 * np.pi, k)
        noisy[idx] += err.gross_measurement_px * np.column_stack([np.cos(ang), np.sin(ang)])
        gross[idx] = True
    return noisy, gross
