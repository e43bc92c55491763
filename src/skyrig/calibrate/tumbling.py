"""The ``tumbling-head`` recipe: laboratory calibration of a tumbling camera's boresight curve (paper 000, 3.4).

Paper 000 calibrates MACS-TumbleCam's actuator-dependent mounting in a laboratory: a calibrated static reference
camera fixed to the sensor head frame sees a textured plane covering every footprint of the tumbling camera; the
motor turns in steps (72 positions, 5 deg), and at every rest position the reference, the nadir and the tumbling
camera expose together; five full circles.  "Any oblique image, the nadir image and the concatenation image are
projected onto the same plane", and for every oblique image "the relative angular offset to the reference image was
determined" from features: the difference between the angles of eqs 1-3 and the real ones is the boresight
correction at that position.  The five curves are averaged; their standard deviations about the mean curve are the
repeat accuracy (Tab. 2: mean and max of the per-position standard deviation, 2 sigma, and where the max is).

Sequence (:func:`calibrate_tumbling_head`)
-------------------------------------------
1. Orientations in the lab frame (:class:`LabSetup`): the sensor head (body) frame held still, the reference
   camera at its rig mounting, the tumbling camera at each actuator angle beta from the rig's actuated mounting
   **without** any correction curve (eqs 1-3 only).
2. Per tumbling image: the image and the reference image projected onto the plane on one grid (the image's own
   footprint, cells of its ground sample distance on the plane) with
   :func:`~skyrig.dense.plane_mosaic.plane_mosaic`; a lattice of square windows inside the footprint compared by
   phase correlation (``cv2.phaseCorrelate``, Hann window, iterated to remove the sub-pixel bias): the shift of the
   tumbling image's projection against the reference's, in plane metres, at >= 3 window centres.
3. Per tumbling image: the small correction ``(droll, dpitch, dyaw)`` (added to the tumbling angles exactly as the
   rig applies a :class:`~skyrig.rig.boresight_curve.BoresightCurve`) that predicts those shifts, by Gauss-Newton
   least squares (translation on the plane <-> droll / dpitch, rotation about the optical axis <-> dyaw), with its
   covariance from the window residuals (sigma0^2 Q).
4. The mean curve over the circles and the repeatability per position
   (:meth:`~skyrig.rig.boresight_curve.BoresightCurve.from_circles`), Tab. 2, and a calibrated rig: the rig with the
   curve on the tumbling head, the curve's standard errors as the head's ``actuator`` block, and provenance.

Frames and units: the lab frame is a local Cartesian frame (ENU axes, metres) with the sensor head at its origin,
body x along north, y east, z down; the plane is ``z = -plane_distance_m`` (the floor seen straight below the head).
Angles in the data are radians; tables are in degrees (and 1/1000 deg as the paper prints them).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, cast

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.calibrate.rig_calibration import CovarianceBlock, HeadCalibration, Provenance, RigCalibration
from skyrig.dense.plane_mosaic import Plane, PlaneGrid, default_grid, plane_mosaic
from skyrig.errors import SkyrigError
from skyrig.geodesy.frame import WorldFrame
from skyrig.georef.eo import ExteriorOrientations
from skyrig.rig.boresight_curve import AXES, BoresightCurve
from skyrig.rig.rig import ActuatedHead, Rig

log = logging.getLogger(__name__)

__all__ = ["LabSetup", "PositionOffset", "TumblingCalibration", "measure_position_offset",
           "calibrate_tumbling_head", "ENU_FROM_BODY"]

#: lab frame (east, north, up) from body (x forward = north, y right = east, z down)
ENU_FROM_BODY = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


@dataclass(frozen=True)
class LabSetup:
    """The laboratory set-up: a rig held still above a textured plane.

    Attributes
    ----------
    rig
        The nominal rig: the tumbling head's curve is ignored (the recipe measures it), the reference head is a
        fixed head of the same rig (its mounting and lever arm are the reference camera's pose on the sensor head).
    head
        Name of the tumbling (actuated) head.
    reference_head
        Name of the static reference camera's head.
    plane_distance_m
        Distance of the textured plane below the sensor head origin along body z (m, > 0).
    """

    rig: Rig
    head: str
    reference_head: str
    plane_distance_m: float
    frame: WorldFrame = field(default_factory=lambda: WorldFrame.local(0.0, 0.0, 0.0))

    def __post_init__(self) -> None:
        for opt, name in (("head", self.head), ("reference head", self.reference_head)):
            if name not in self.rig:
                raise SkyrigError(f"{opt} {name!r} is not in rig {self.rig.name!r} (heads: "
                                  f"{', '.join(self.rig.head_names)})")
        if not self.rig.head(self.head).is_actuated:
            raise SkyrigError(f"head {self.head!r} of rig {self.rig.name!r} is not actuated (no tumbling mount)")
        if self.rig.head(self.reference_head).is_actuated:
            raise SkyrigError(f"reference head {self.reference_head!r} must be a fixed head, not an actuated one")
        d = float(self.plane_distance_m)
        if not (np.isfinite(d) and d > 0):
            raise SkyrigError(f"plane distance must be a positive number of metres, got {self.plane_distance_m!r}")
        object.__setattr__(self, "plane_distance_m", d)

    @property
    def plane(self) -> Plane:
        """The textured plane ``z = -plane_distance_m`` of the lab frame (u east, v north)."""
        return Plane.horizontal(-self.plane_distance_m)

    @property
    def nominal_head(self) -> ActuatedHead:
        """The tumbling head without any correction curve (eqs 1-3 of paper 000)."""
        h = cast(ActuatedHead, self.rig.head(self.head))  # checked on construction
        return cast(ActuatedHead, h.with_(curve=None))

    def tumbling_orientation(self, beta_rad: ArrayLike, correction_rad: ArrayLike | None = None
                             ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``lab_from_camera`` rotations ``(..., 3, 3)`` and centre ``(3,)`` of the tumbling camera at ``beta_rad``.

        ``correction_rad``: a constant ``(droll, dpitch, dyaw)`` added to the tumbling angles (radians), applied
        through the rig's own composition (a one-position curve); None: the nominal mounting.
        """
        h = self.nominal_head
        if correction_rad is not None:
            c = np.asarray(correction_rad, dtype=np.float64).reshape(1, 3)
            h = h.with_(curve=BoresightCurve(np.zeros(1), c, interpolation="linear"))  # type: ignore[assignment]
        r = ENU_FROM_BODY @ h.body_from_camera_rotation(np.asarray(beta_rad, dtype=np.float64))
        return r, ENU_FROM_BODY @ h.lever_arm_m

    def reference_orientation(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``lab_from_camera`` rotation ``(3, 3)`` and centre ``(3,)`` of the reference camera."""
        h = self.rig.head(self.reference_head)
        return ENU_FROM_BODY @ h.body_from_camera_rotation(), ENU_FROM_BODY @ h.lever_arm_m

    def eo(self, names: Sequence[str], heads: Sequence[str], rotations: ArrayLike, centres: ArrayLike
           ) -> ExteriorOrientations:
        """Orientations of images in the lab frame."""
        cams = [self.rig.head(h).camera.name for h in heads]
        return ExteriorOrientations(np.asarray(names, dtype=str), np.asarray(cams, dtype=str),
                                    np.asarray(centres, dtype=np.float64).reshape(-1, 3),
                                    np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3), self.frame)


@dataclass(frozen=True)
class PositionOffset:
    """The angular offset of one tumbling image against the reference.

    Attributes
    ----------
    correction_rad
        ``(3,)`` (droll, dpitch, dyaw) to add to the tumbling angles (radians).
    covariance_rad2
        ``(3, 3)`` its covariance ``sigma0^2 Q`` (radians^2), from the window residuals.
    windows
        Number of correlation windows used.
    residual_rms_m
        RMS of the shift residuals after the fit (plane metres).
    shift_rms_m
        RMS of the measured shifts before the fit (plane metres).
    cell_m
        Grid cell (m) of the projections.
    """

    correction_rad: NDArray[np.float64]
    covariance_rad2: NDArray[np.float64]
    windows: int
    residual_rms_m: float
    shift_rms_m: float
    cell_m: float

    @property
    def sigma_rad(self) -> NDArray[np.float64]:
        """``(3,)`` standard deviations of the correction (radians)."""
        return np.sqrt(np.clip(np.diag(self.covariance_rad2), 0, None))


def _window_shifts(ref: NDArray[np.uint8], img: NDArray[np.uint8], both: NDArray[np.bool_], window: int,
                   lattice: int, pad: int = 8, min_response: float = 0.05, min_texture: float = 2.0,
                   refine: int = 4) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Window centres ``(M, 2)`` (row, col) and shifts ``(M, 2)`` (d_col, d_row) of ``img`` against ``ref``."""
    h, w = both.shape
    half = window // 2
    hann = cv2.createHanningWindow((window, window), cv2.CV_64F)
    rows, cols = np.nonzero(both)
    if not rows.size:
        return np.zeros((0, 2)), np.zeros((0, 2))
    r_lo, r_hi, c_lo, c_hi = rows.min(), rows.max(), cols.min(), cols.max()
    centres, shifts = [], []
    for rc in np.linspace(r_lo + half + pad, r_hi - half - pad, lattice):
        for cc in np.linspace(c_lo + half + pad, c_hi - half - pad, lattice):
            r0, c0 = int(round(rc)) - half, int(round(cc)) - half
            if r0 < pad or c0 < pad or r0 + window + pad > h or c0 + window + pad > w:
                continue
            if not np.all(both[r0 - pad:r0 + window + pad, c0 - pad:c0 + window + pad]):
                continue
            a = ref[r0:r0 + window, c0:c0 + window].astype(np.float64)
            b_pad = img[r0 - pad:r0 + window + pad, c0 - pad:c0 + window + pad].astype(np.float64)
            if a.std() < min_texture or b_pad.std() < min_texture:
                continue
            total = np.zeros(2)
            resp = 0.0
            for _ in range(refine + 1):
                m = np.array([[1.0, 0.0, total[0]], [0.0, 1.0, total[1]]])
                b = cv2.warpAffine(b_pad, m, b_pad.shape[::-1], flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                   borderMode=cv2.BORDER_REFLECT)[pad:pad + window, pad:pad + window]
                (dx, dy), resp = cv2.phaseCorrelate(a, b, hann)
                total += (dx, dy)
                if np.hypot(dx, dy) < 0.002 or np.max(np.abs(total)) > pad - 1:
                    break
            if resp < min_response or np.max(np.abs(total)) > pad - 1:
                continue
            centres.append((r0 + (window - 1) / 2.0, c0 + (window - 1) / 2.0))
            shifts.append(total.copy())
    return np.asarray(centres, np.float64).reshape(-1, 2), np.asarray(shifts, np.float64).reshape(-1, 2)


def _predicted_shifts(setup: LabSetup, beta_rad: float, correction_rad: NDArray[np.float64],
                      x_uv: NDArray[np.float64]) -> NDArray[np.float64]:
    """Plane shifts ``(M, 2)`` (m) of the nominal projection of an image taken with the corrected orientation.

    Content at plane point X is seen by the corrected camera along ``R_c^T (X - C)``; the nominal projection puts
    that ray at ``C + R_n R_c^T (X - C)`` on the plane.
    """
    plane = setup.plane
    r_n, c = setup.tumbling_orientation(beta_rad)
    r_c, _ = setup.tumbling_orientation(beta_rad, correction_rad)
    x = plane.to_world(x_uv) - c
    return plane.intersect(c, x @ (r_n @ r_c.T).T) - x_uv


def measure_position_offset(
    setup: LabSetup,
    image: NDArray[np.uint8],
    beta_rad: float,
    reference_image: NDArray[np.uint8],
    *,
    name: str = "image",
    window_px: int = 64,
    lattice: int = 7,
    min_windows: int = 3,
    cell_m: float | None = None,
) -> PositionOffset:
    """The correction ``(droll, dpitch, dyaw)`` of one tumbling image against the reference camera's image.

    Parameters
    ----------
    setup
        The lab set-up.
    image, reference_image
        ``(H, W, 3)`` uint8 RGB (or ``(H, W)`` grey) images of the tumbling and of the reference camera.
    beta_rad
        Actuator angle of ``image`` (radians).
    name
        Image name for messages.
    window_px
        Side of the correlation windows (plane cells, even).
    lattice
        Windows are tried on a ``lattice x lattice`` grid over the image's footprint.
    min_windows
        At least this many windows must correlate (3 determine the three angles with redundancy).
    cell_m
        Plane cell (m); default: the image's ground sample distance on the plane.

    Raises
    ------
    SkyrigError
        Too few usable windows (no texture, not seen by the reference, offset larger than the search range).
    """
    plane = setup.plane
    r_n, c_n = setup.tumbling_orientation(beta_rad)
    r_r, c_r = setup.reference_orientation()
    eo_t = setup.eo([name], [setup.head], r_n[None], c_n[None])
    eo_r = setup.eo(["reference"], [setup.reference_head], r_r[None], c_r[None])
    cams = {h.camera.name: h.camera for h in setup.rig}
    grid, _, _ = default_grid(eo_t, cams, plane, cell_m)
    m_t = plane_mosaic([image if image.ndim == 3 else np.repeat(image[:, :, None], 3, 2)], eo_t, cams, plane,
                       grid=grid)
    m_r = plane_mosaic([reference_image if reference_image.ndim == 3 else
                        np.repeat(reference_image[:, :, None], 3, 2)], eo_r, cams, plane, grid=grid)
    both = m_t.valid[0] & m_r.valid[0]
    centres, shifts = _window_shifts(m_r.gray[0], m_t.gray[0], both, int(window_px) // 2 * 2, lattice)
    if len(centres) < min_windows:
        raise SkyrigError(f"image {name!r} (beta {np.degrees(beta_rad):.3f} deg): only {len(centres)} correlation "
                          f"windows agree with the reference image (need {min_windows}); is the plane textured, "
                          "seen by the reference camera, and the offset smaller than the search range?")
    g: PlaneGrid = grid
    x_uv = g.uv(centres[:, 0], centres[:, 1])
    obs = np.c_[shifts[:, 0] * g.cell_m, -shifts[:, 1] * g.cell_m].reshape(-1)  # (du, dv) in metres
    d = np.zeros(3)
    h = 1e-6
    for _ in range(5):
        f0 = _predicted_shifts(setup, beta_rad, d, x_uv).reshape(-1)
        jac = np.empty((f0.size, 3))
        for k in range(3):
            e = np.zeros(3)
            e[k] = h
            jac[:, k] = (_predicted_shifts(setup, beta_rad, d + e, x_uv).reshape(-1)
                         - _predicted_shifts(setup, beta_rad, d - e, x_uv).reshape(-1)) / (2 * h)
        step, *_ = np.linalg.lstsq(jac, obs - f0, rcond=None)
        d = d + step
        if np.max(np.abs(step)) < 1e-10:
            break
    res = obs - _predicted_shifts(setup, beta_rad, d, x_uv).reshape(-1)
    redundancy = res.size - 3
    q = np.linalg.inv(jac.T @ jac)
    s0sq = float(res @ res / redundancy) if redundancy > 0 else float("nan")
    return PositionOffset(d, s0sq * q, len(centres), float(np.sqrt(np.mean(res ** 2))),
                          float(np.sqrt(np.mean(obs ** 2))), g.cell_m)


@dataclass
class TumblingCalibration:
    """Result of :func:`calibrate_tumbling_head`.

    Attributes
    ----------
    beta_rad
        ``(K,)`` actuator positions (radians, sorted as given by the first circle).
    circles
        ``(C,)`` circle labels.
    corrections_rad
        ``(C, K, 3)`` measured (droll, dpitch, dyaw) per circle and position (radians).
    sigma_rad
        ``(C, K, 3)`` their standard deviations from each image's fit (radians).
    images
        ``(C, K)`` image names.
    windows
        ``(C, K)`` correlation windows used per image.
    curve
        The mean curve with the per-position repeatability (``std_rad``, ``count``).
    setup
        The lab set-up.
    """

    beta_rad: NDArray[np.float64]
    circles: NDArray[np.str_]
    corrections_rad: NDArray[np.float64]
    sigma_rad: NDArray[np.float64]
    images: NDArray[np.str_]
    windows: NDArray[np.int64]
    curve: BoresightCurve
    setup: LabSetup

    @property
    def mean_rad(self) -> NDArray[np.float64]:
        """``(K, 3)`` mean correction per position, in ``beta_rad`` order."""
        return self.corrections_rad.mean(axis=0)

    @property
    def std_rad(self) -> NDArray[np.float64]:
        """``(K, 3)`` repeatability per position (sample std about the mean curve, ``ddof=1``)."""
        return self.corrections_rad.std(axis=0, ddof=1)

    @property
    def standard_error_rad(self) -> NDArray[np.float64]:
        """``(K, 3)`` standard error of the mean curve: ``sqrt(std^2 / C + mean fit sigma^2)``.

        The circles see the same patch of the plane at a position, so the image comparison's error (a function of
        the texture there) repeats from circle to circle and does not average out; only the mechanism's repeat
        error does.  The per-image fit variance is therefore added in full (a slightly conservative bound: on the
        simulated lab, 72 x 5 at 320 px, the curve's error is 0.7 of it)."""
        c = self.corrections_rad.shape[0]
        return np.sqrt(self.std_rad ** 2 / c + np.mean(self.sigma_rad ** 2, axis=0))

    def mechanism_std_rad(self) -> NDArray[np.float64]:
        """``(3,)`` a lower bound of the mechanism's own repeatability: the pooled per-position variance less the
        measurement variance (the mean squared fit sigma of the images), ``sqrt(max(pooled - fit, 0))`` (radians,
        1 sigma).

        The per-position standard deviation holds the actuator's repeat error and the part of the image
        comparison's error that changes from circle to circle; the fit variance also holds the part that repeats
        (the same texture is compared at a position in every circle), so the difference is at most the
        mechanism's variance.  With a camera far coarser than paper 000's the comparison's error dominates."""
        pooled = np.mean(self.std_rad ** 2, axis=0)
        fit = np.mean(self.sigma_rad ** 2, axis=(0, 1))
        return np.sqrt(np.clip(pooled - fit, 0.0, None))

    def table2(self, k_sigma: float = 2.0) -> dict[str, dict[str, Any]]:
        """Paper 000 Tab. 2: per axis the mean and the max of the per-position standard deviation (``k_sigma``
        scaled, degrees and 1/1000 deg), the position (beta, deg) and the image of the max (the image of that
        position farthest from the mean curve); also the per-image measurement sigma (RMS of the fits) and the
        lower bound of the mechanism's repeatability with the measurement noise removed (:meth:`mechanism_std_rad`),
        both scaled."""
        std = self.std_rad
        mech = self.mechanism_std_rad()
        fit = np.sqrt(np.mean(self.sigma_rad ** 2, axis=(0, 1)))
        out = {}
        for i, a in enumerate(AXES):
            k = int(np.argmax(std[:, i]))
            c = int(np.argmax(np.abs(self.corrections_rad[:, k, i] - self.mean_rad[k, i])))
            mean_deg = float(np.degrees(np.mean(std[:, i])) * k_sigma)
            max_deg = float(np.degrees(std[k, i]) * k_sigma)
            out[a] = {"mean_std_deg": mean_deg, "max_std_deg": max_deg, "mean_std_mdeg": 1000 * mean_deg,
                      "max_std_mdeg": 1000 * max_deg, "k_sigma": k_sigma,
                      "beta_at_max_deg": float(np.degrees(self.beta_rad[k])), "image_at_max": str(self.images[c, k]),
                      "measurement_sigma_mdeg": 1000 * float(np.degrees(fit[i]) * k_sigma),
                      "mechanism_std_mdeg": 1000 * float(np.degrees(mech[i]) * k_sigma)}
        return out

    def calibrated_rig(self) -> Rig:
        """The set-up's rig with the mean curve on the tumbling head."""
        from dataclasses import replace

        rig = self.setup.rig
        return replace(rig, heads={n: (h.with_(curve=self.curve) if n == self.setup.head else h)
                                   for n, h in rig.heads.items()})

    def rig_calibration(self, flight: str = "", date: str = "", software: str = "",
                        previous: RigCalibration | None = None) -> RigCalibration:
        """The calibration section: the tumbling head's ``actuator`` block (values: the mean curve, degrees;
        sigma: its standard errors :attr:`standard_error_rad`; uncorrelated) and provenance; other heads kept from
        ``previous``."""
        names = [f"{a}_deg@{np.degrees(b):.4f}" for b in self.beta_rad for a in AXES]
        values = np.degrees(self.mean_rad).reshape(-1)
        sig = np.degrees(self.standard_error_rad).reshape(-1)
        block = CovarianceBlock(tuple(names), np.nan_to_num(sig), np.eye(len(names)), values)
        rep = self.table2(1.0)
        stats = {"positions": int(self.beta_rad.size), "circles": int(self.corrections_rad.shape[0]),
                 "images": int(self.images.size), "windows_min": int(self.windows.min()),
                 **{f"{a}_mean_std_deg": rep[a]["mean_std_deg"] for a in AXES},
                 **{f"{a}_max_std_deg": rep[a]["max_std_deg"] for a in AXES},
                 **{f"{a}_fit_sigma_median_deg": float(np.degrees(np.median(self.sigma_rad[..., i])))
                    for i, a in enumerate(AXES)}}
        prov = Provenance("tumbling-head", flight, date, software, stats,
                          "laboratory calibration (paper 000, 3.4): tumbling images against a static reference camera "
                          "on a common plane, phase correlation, small-rotation least squares per image; "
                          "mean curve over circles")
        heads = dict(previous.heads) if previous is not None else {}
        prev = heads.get(self.setup.head, HeadCalibration())
        heads[self.setup.head] = HeadCalibration(prev.lever_arm_m, prev.boresight_opk_deg, prev.interior, block, prov)
        return RigCalibration(heads, None if previous is None else previous.antenna_lever_arm_m,
                              prov if previous is None or previous.provenance is None else previous.provenance)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready report: Tab. 2, the mean curve with its repeatability, every measurement."""
        return {
            "recipe": "tumbling-head",
            "head": self.setup.head, "reference_head": self.setup.reference_head,
            "plane_distance_m": self.setup.plane_distance_m,
            "positions": int(self.beta_rad.size), "circles": [str(c) for c in self.circles],
            "table2_2sigma": self.table2(2.0),
            "curve": [{"beta_deg": float(np.degrees(b)),
                       **{f"{a}_mdeg": 1000 * float(np.degrees(self.mean_rad[k, i])) for i, a in enumerate(AXES)},
                       **{f"{a}_std_mdeg": 1000 * float(np.degrees(self.std_rad[k, i])) for i, a in enumerate(AXES)}}
                      for k, b in enumerate(self.beta_rad)],
            "measurements": [{"image": str(self.images[c, k]), "circle": str(self.circles[c]),
                              "beta_deg": float(np.degrees(self.beta_rad[k])), "windows": int(self.windows[c, k]),
                              **{f"{a}_mdeg": 1000 * float(np.degrees(self.corrections_rad[c, k, i]))
                                 for i, a in enumerate(AXES)},
                              **{f"{a}_sigma_mdeg": 1000 * float(np.degrees(self.sigma_rad[c, k, i]))
                                 for i, a in enumerate(AXES)}}
                             for c in range(len(self.circles)) for k in range(self.beta_rad.size)],
        }


def calibrate_tumbling_head(
    setup: LabSetup,
    images: Callable[[str], NDArray[np.uint8]],
    image_names: Sequence[str],
    circles: Sequence[str],
    beta_rad: ArrayLike,
    reference_image: NDArray[np.uint8],
    *,
    window_px: int = 64,
    lattice: int = 7,
    cell_m: float | None = None,
    interpolation: str = "cubic",
) -> TumblingCalibration:
    """Laboratory calibration of a tumbling head (paper 000, 3.4): the boresight curve and its repeat accuracy.

    Parameters
    ----------
    setup
        The lab set-up (rig, tumbling and reference heads, plane).
    images
        Function image name -> ``(H, W, 3)`` uint8 RGB image of the tumbling camera.
    image_names, circles, beta_rad
        ``(N,)`` per tumbling image: its name, its circle label and its actuator angle (radians).  Every circle
        must hold the same positions, each once (``C x K = N``).
    reference_image
        The static reference camera's image (one image: the camera does not move).
    window_px, lattice, cell_m
        See :func:`measure_position_offset`.
    interpolation
        Of the mean curve (``cubic`` periodic spline or ``linear``).

    Returns
    -------
    TumblingCalibration
    """
    names = np.asarray(image_names, dtype=str)
    circ = np.asarray(circles, dtype=str)
    beta = np.asarray(beta_rad, dtype=np.float64).reshape(-1)
    if not (names.size == circ.size == beta.size) or names.size == 0:
        raise SkyrigError("tumbling-head: image names, circles and actuator angles must be equally long and non-empty")
    labels = list(dict.fromkeys(circ.tolist()))
    if len(labels) < 2:
        raise SkyrigError("tumbling-head: the repeatability needs at least 2 circles")
    first = beta[circ == labels[0]]
    key0 = np.round(np.degrees(first) % 360.0, 6)
    if len(set(key0.tolist())) != key0.size:
        raise SkyrigError(f"tumbling-head: circle {labels[0]!r} has an actuator position twice")
    order = np.argsort(key0)
    pos = key0[order]
    k_pos = pos.size
    meas = np.full((len(labels), k_pos, 3), np.nan)
    sig = np.full((len(labels), k_pos, 3), np.nan)
    nam = np.empty((len(labels), k_pos), dtype=object)
    win = np.zeros((len(labels), k_pos), np.int64)
    for lab in labels:  # check every circle before measuring anything
        keys = np.round(np.degrees(beta[circ == lab]) % 360.0, 6)
        if keys.size != k_pos or not np.array_equal(np.sort(keys), pos):
            missing = sorted(set(pos.tolist()) ^ set(keys.tolist()))
            raise SkyrigError(f"tumbling-head: circle {lab!r} does not hold the same actuator positions as circle "
                              f"{labels[0]!r} (differing: {', '.join(f'{m:g}' for m in missing[:8])} deg)")
    for ci, lab in enumerate(labels):
        for j in np.flatnonzero(circ == lab):
            k = int(np.searchsorted(pos, np.round(np.degrees(beta[j]) % 360.0, 6)))
            off = measure_position_offset(setup, images(str(names[j])), float(beta[j]), reference_image,
                                          name=str(names[j]), window_px=window_px, lattice=lattice, cell_m=cell_m)
            meas[ci, k] = off.correction_rad
            sig[ci, k] = off.sigma_rad
            nam[ci, k] = str(names[j])
            win[ci, k] = off.windows
            log.info("%s circle %s beta %.2f deg: droll %.2f dpitch %.2f dyaw %.2f mdeg (%d windows, fit RMS %.2f mm)",
                     names[j], lab, np.degrees(beta[j]), *(1000 * np.degrees(off.correction_rad)), off.windows,
                     1000 * off.residual_rms_m)
    b = np.radians(pos)
    curve = BoresightCurve.from_circles(b, meas, interpolation)  # type: ignore[arg-type]
    return TumblingCalibration(b, np.asarray(labels, dtype=str), meas, sig, nam.astype(str), win, curve, setup)
