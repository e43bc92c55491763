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
2. Per tumbling image: the reference image carried through the plane into the tumbling image's pixel grid (each
   tumbling pixel's ray meets the plane, the plane point is projected into the reference camera, bicubic
   sampling by Keys' cubic convolution with a = -0.5), so that only the reference is resampled; non-overlapping
   square windows of the tumbling image compared with it by phase correlation (``cv2.phaseCorrelate``, Hann
   window): the shift per window, in pixels.
3. Per tumbling image: the small correction ``(droll, dpitch, dyaw)`` (added to the tumbling angles exactly as the
   rig applies a :class:`~skyrig.rig.boresight_curve.BoresightCurve`) that predicts those shifts (the pixel motion
   of each window centre's plane point per radian), by Gauss-Newton: the reference is warped again with the
   current estimate until the shifts vanish (there the correlation's sub-pixel bias vanishes too; its gain, the
   reported over the true shift, is measured by a +-0.03 px probe and divided out); covariance ``sigma0^2 Q`` from
   the window residuals.  On the simulated lab at 320 px this is 2-6 mdeg per image, against 12-30 mdeg when both
   images were resampled onto a plane grid and compared there.
4. The mean curve over the circles and the repeatability per position
   (:meth:`~skyrig.rig.boresight_curve.BoresightCurve.from_circles`), Tab. 2 with the mechanism's repeatability
   (the scatter over the circles less the fits' measurement variance, with its standard error), and a calibrated
   rig: the rig with the curve on the tumbling head, the curve's standard errors as the head's ``actuator`` block,
   and provenance.  The standard error of the mean at a position is ``pooled^2 / C`` (the circle-to-circle
   scatter) plus the part of the comparison's error that repeats in every circle, ``lambda`` times the position's
   fit variance, with ``lambda`` estimated by REML from the mean curve's residuals about a Fourier series
   (:attr:`TumblingCalibration.repeat_share`); ``lambda = 1`` is the upper bound
   (:attr:`TumblingCalibration.standard_error_bound_rad`).  An image whose measurement fails (step 2-3 raise) is
   left out with a warning and recorded (:attr:`TumblingCalibration.failed`); the statistics use the ``C_k`` circles
   measured at each position; more than 10 % failed images, or a position with fewer than 2 circles, stop the recipe.
5. The curve's statement (:meth:`TumblingCalibration.curve_statement`, in the JSON report): the per-position
   values (the paper's lookup, the rig file's curve) with their standard errors and Sidak's simultaneous band over
   the ``3 K`` values, and the same curve as a Fourier series in beta (:class:`FourierCurve`, the order by a
   chi-square test per harmonic) with its terms' covariance, its simultaneous band and the probability, under that
   covariance, that every value is within 2 sigma.  With 216 values "every position within 2 sigma" is not what a
   right sigma promises (0.9545^216 = 4e-5 for exact independent sigmas); the simultaneous band is.

Frames and units: the lab frame is a local Cartesian frame (ENU axes, metres) with the sensor head at its origin,
body x along north, y east, z down; the plane is ``z = -plane_distance_m`` (the floor seen straight below the head).
Angles in the data are radians; tables are in degrees (and 1/1000 deg as the paper prints them).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, cast

import cv2
import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.adjust.stats import sidak_z
from skyrig.calibrate.rig_calibration import CovarianceBlock, HeadCalibration, Provenance, RigCalibration
from skyrig.dense.plane_mosaic import Plane
from skyrig.errors import SkyrigError
from skyrig.geodesy.frame import WorldFrame
from skyrig.georef.eo import ExteriorOrientations
from skyrig.rig.boresight_curve import AXES, BoresightCurve
from skyrig.rig.rig import ActuatedHead, Rig

log = logging.getLogger(__name__)

__all__ = ["LabSetup", "PositionOffset", "TumblingCalibration", "FailedImage", "FourierCurve", "RepeatShare",
           "measure_position_offset", "calibrate_tumbling_head", "fit_fourier_curve", "fourier_design",
           "estimate_repeat_share", "default_max_order", "ENU_FROM_BODY"]

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
    residual_rms_px
        RMS of the window shift residuals after the fit (tumbling image pixels, per coordinate).
    shift_rms_px
        RMS of the window shifts at the last comparison (pixels).
    cofactor
        ``(3, 3)`` ``(J^T J)^-1`` of the fit (radians^2 per pixel^2): the covariance for unit window shift variance.
    gain
        The phase correlation's measured sub-pixel gain (reported shift / true shift), divided out.
    """

    correction_rad: NDArray[np.float64]
    covariance_rad2: NDArray[np.float64]
    windows: int
    residual_rms_px: float
    shift_rms_px: float
    cofactor: NDArray[np.float64]
    gain: float = 1.0

    @property
    def sigma_rad(self) -> NDArray[np.float64]:
        """``(3,)`` standard deviations of the correction (radians)."""
        return np.sqrt(np.clip(np.diag(self.covariance_rad2), 0, None))


def _gray(img: NDArray[Any]) -> NDArray[np.float32]:
    """Grey values (float32) of an ``(H, W, 3)`` RGB or ``(H, W)`` image."""
    a = np.asarray(img)
    if a.ndim == 3:
        a = a[..., :3].astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)
    return np.ascontiguousarray(a, dtype=np.float32)


def _reference_gray(setup: LabSetup, reference_image: NDArray[Any]) -> NDArray[np.float32]:
    """The reference camera's image in grey values, checked against its camera's size."""
    ref = _gray(reference_image)
    rc = setup.rig.head(setup.reference_head).camera
    if ref.shape != (rc.height, rc.width):
        raise SkyrigError(f"reference image is {ref.shape[1]} x {ref.shape[0]} px, camera {rc.name!r} of head "
                          f"{setup.reference_head!r} is {rc.width} x {rc.height}")
    return ref


@numba.njit(cache=True, nogil=True, inline="always")
def _keys(d: float, a: float) -> float:  # pragma: no cover - compiled
    """Keys' cubic-convolution kernel at distance ``d >= 0``."""
    if d <= 1.0:
        return ((a + 2.0) * d - (a + 3.0)) * d * d + 1.0
    return ((a * d - 5.0 * a) * d + 8.0 * a) * d - 4.0 * a


@numba.njit(cache=True, nogil=True)
def _cubic_sample_kernel(image: NDArray[np.float32], x: NDArray[np.float32], y: NDArray[np.float32],
                         a: float) -> NDArray[np.float32]:  # pragma: no cover - compiled
    n_pts = x.size
    out = np.empty(n_pts, np.float32)
    xr, yr = x.reshape(-1), y.reshape(-1)
    for n in range(n_pts):
        xf, yf = np.floor(xr[n]), np.floor(yr[n])
        tx, ty = xr[n] - xf, yr[n] - yf
        wx0, wx1, wx2, wx3 = _keys(tx + 1.0, a), _keys(tx, a), _keys(1.0 - tx, a), _keys(2.0 - tx, a)
        c0, r0 = int(xf) - 1, int(yf) - 1
        acc = 0.0
        for j in range(4):
            row = (wx0 * image[r0 + j, c0] + wx1 * image[r0 + j, c0 + 1] + wx2 * image[r0 + j, c0 + 2]
                   + wx3 * image[r0 + j, c0 + 3])
            acc += _keys(abs(ty - (j - 1)), a) * row
        out[n] = acc
    return out


def _cubic_sample(image: NDArray[np.float32], x: NDArray[np.float32], y: NDArray[np.float32]) -> NDArray[np.float32]:
    """Bicubic samples of ``image`` at the pixel positions ``(x, y)``: Keys' cubic convolution with ``a = -0.5``, the
    one that reproduces linear (and quadratic) grey-value ramps, so the sampled content sits where it is asked for;
    the positions must lie at least one pixel inside the border.

    ``cv2.remap``'s ``INTER_CUBIC`` uses ``a = -0.75``: a ramp sampled at fractional position ``t`` comes out at
    ``t + e(t)`` with ``|e|`` up to 0.047 px and ``de/dt`` from +0.5 to -0.4 over the pixel, so the warped reference
    did not move uniformly with the trial rotation.  (It was first taken for the cause of the iteration circling
    between two estimates 2 mdeg apart on the 72 x 5 lab; it is not the only one: with ``a = -0.5`` other images
    circled, from the phase correlation's roughness near zero shift; see :func:`measure_position_offset`.)"""
    xs = np.ascontiguousarray(x, np.float32)
    return _cubic_sample_kernel(np.ascontiguousarray(image, dtype=np.float32), xs,
                                np.ascontiguousarray(y, np.float32), -0.5).reshape(xs.shape)


class _Warp:
    """The reference image resampled into the tumbling image's pixel grid through the plane, for a trial correction.

    A tumbling pixel's ray (the tumbling camera at ``beta`` with the trial correction) meets the plane; the plane point
    is projected into the reference camera and the reference image is sampled there (bicubic,
    :func:`_cubic_sample`).  Only the reference is resampled: the tumbling image is compared at its own pixels."""

    def __init__(self, setup: LabSetup, beta_rad: float, reference: NDArray[np.float32], shape: tuple[int, int]):
        self.setup, self.beta = setup, float(beta_rad)
        self.cam = setup.rig.head(setup.head).camera
        self.ref_cam = setup.rig.head(setup.reference_head).camera
        self.r_r, self.c_r = setup.reference_orientation()
        self.reference = reference
        h, w = shape
        self.shape = (h, w)
        # the map is smooth (a homography but for distortion): computed every STEP pixels, interpolated between
        self.step = 4
        gc = np.arange(0, w - 1 + self.step, self.step, dtype=np.float64)
        gr = np.arange(0, h - 1 + self.step, self.step, dtype=np.float64)
        cols, rows = np.meshgrid(gc, gr)
        self.coarse = cols.shape
        self.rays = self.cam.rays_from_pixels(np.c_[cols.ravel(), rows.ravel()])
        fc, fr = np.meshgrid(np.arange(w, dtype=np.float32) / self.step, np.arange(h, dtype=np.float32) / self.step)
        self.fine = (fc, fr)

    def plane_points(self, correction_rad: NDArray[np.float64], rays: NDArray[np.float64]) -> NDArray[np.float64]:
        r, c = self.setup.tumbling_orientation(self.beta, correction_rad)
        return self.setup.plane.to_world(self.setup.plane.intersect(c, rays @ r.T))

    def pixels(self, correction_rad: NDArray[np.float64], x_world: NDArray[np.float64]) -> NDArray[np.float64]:
        """Pixels of world points in the tumbling camera with the trial correction."""
        r, c = self.setup.tumbling_orientation(self.beta, correction_rad)
        return self.cam.project_pixels((x_world - c) @ r)

    def __call__(self, correction_rad: NDArray[np.float64]) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
        x = self.plane_points(correction_rad, self.rays)
        p = self.ref_cam.project_pixels((x - self.c_r) @ self.r_r).reshape(*self.coarse, 2)
        p = np.where(np.isfinite(p), p, -1e6).astype(np.float32)
        fc, fr = self.fine
        mx = cv2.remap(np.ascontiguousarray(p[..., 0]), fc, fr, cv2.INTER_LINEAR)
        my = cv2.remap(np.ascontiguousarray(p[..., 1]), fc, fr, cv2.INTER_LINEAR)
        hr, wr = self.reference.shape
        ok = (mx >= 2) & (mx <= wr - 3) & (my >= 2) & (my <= hr - 3)
        mx[~ok] = 2.0
        my[~ok] = 2.0
        out = _cubic_sample(self.reference, mx, my)
        out[~ok] = 0.0
        return out, ok


def _windows(valid: NDArray[np.bool_], window: int, pad: int) -> list[tuple[int, int]]:
    """Top-left corners of non-overlapping ``window`` x ``window`` tiles whose padded extent is valid."""
    h, w = valid.shape
    n_r, n_c = (h - 2 * pad) // window, (w - 2 * pad) // window
    r_off, c_off = (h - n_r * window) // 2, (w - n_c * window) // 2
    out = []
    for i in range(n_r):
        for j in range(n_c):
            r0, c0 = r_off + i * window, c_off + j * window
            if r0 - pad >= 0 and c0 - pad >= 0 and r0 + window + pad <= h and c0 + window + pad <= w \
                    and np.all(valid[r0 - pad:r0 + window + pad, c0 - pad:c0 + window + pad]):
                out.append((r0, c0))
    return out


def measure_position_offset(
    setup: LabSetup,
    image: NDArray[np.uint8],
    beta_rad: float,
    reference_image: NDArray[np.uint8],
    *,
    name: str = "image",
    window_px: int = 32,
    min_windows: int = 6,
    min_texture: float = 2.0,
    min_response: float = 0.05,
    iterations: int = 12,
    reject_k: float = 4.0,
    converge_sigma: float = 0.5,
) -> PositionOffset:
    """The correction ``(droll, dpitch, dyaw)`` of one tumbling image against the reference camera's image.

    The reference image is carried through the plane into the tumbling image's pixel grid with the tumbling
    orientation of the current estimate (:class:`_Warp`); non-overlapping square windows of the tumbling image are
    compared with the warped reference by phase correlation (``cv2.phaseCorrelate``, Hann window), and the
    correction is updated by least squares from the window shifts (the pixel motion of the window centres' plane
    points per radian of each angle), until the shifts vanish (Gauss-Newton; at convergence the correlation is
    evaluated at near-zero shift, where its sub-pixel bias vanishes).  Near zero shift the correlation's sub-pixel
    answer is rough at a few 1/1000 px (its spectrum is whitened, so noise-level frequencies weigh as much as the
    texture's), and a full step could undo the previous one for ever (on the 72 x 5 lab at 320 px about one image in
    400 circled between two estimates 0.4-2 mdeg apart, 0.2-0.4 of their sigma); once an update undoes the previous
    one the steps are halved from there on, so the estimate settles inside that roughness.  The iteration stops once
    the full update is below ``converge_sigma`` of the estimate's own standard deviation: how small an update can
    get is set by that roughness, not by a pixel tolerance (on the 72 x 5 lab at 640 px, where the texture is smooth
    across the pixels and the correlation's gain is about 0.3, the updates settled at 0.15-0.3 sigma, 0.002-0.005 px,
    and never went below the former fixed 1/1000 px: "did not converge in 12 iterations"); the last step, with the
    probed gain, finishes the estimate from where the iteration stopped, so stopping half a sigma from the zero-shift
    point costs the gain's relative error times half a sigma.  Windows whose shift
    residual exceeds ``reject_k`` robust sigmas are dropped once.  The covariance is ``sigma0^2 (J^T J)^-1`` from
    the final window residuals (pixels); the windows do not overlap, so their errors are close to independent.

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
        Side of the correlation windows (tumbling image pixels).
    min_windows
        At least this many windows must correlate.
    min_texture, min_response
        A window needs this grey-value standard deviation in both images and this phase-correlation response.
    iterations
        Gauss-Newton iterations at most.
    converge_sigma
        Converged once the full (undamped) update is below this many of the estimate's own standard deviations
        (its Mahalanobis length under ``sigma0^2 (g^2 J^T J)^-1``, which does not depend on the gain), or moves no
        window by 1/1000 px.
    reject_k
        Outlier threshold (robust sigmas of the shift residuals).

    Raises
    ------
    SkyrigError
        Too few usable windows (no texture, not seen by the reference camera), or no convergence.
    """
    gray_t = _gray(image)
    cam = setup.rig.head(setup.head).camera
    if gray_t.shape != (cam.height, cam.width):
        raise SkyrigError(f"image {name!r} is {gray_t.shape[1]} x {gray_t.shape[0]} px, camera "
                          f"{cam.name!r} of head {setup.head!r} is {cam.width} x {cam.height}")
    ref = _reference_gray(setup, reference_image)
    warp = _Warp(setup, beta_rad, ref, gray_t.shape)
    win = max(8, int(window_px))
    pad = 2
    hann = cv2.createHanningWindow((win, win), cv2.CV_64F)
    w0, ok0 = warp(np.zeros(3))  # the windows are chosen once, at the nominal orientation
    tiles = [(r0, c0) for r0, c0 in _windows(ok0, win, pad)
             if gray_t[r0:r0 + win, c0:c0 + win].std() >= min_texture
             and w0[r0:r0 + win, c0:c0 + win].std() >= min_texture]
    if len(tiles) < min_windows:
        raise SkyrigError(f"image {name!r} (beta {np.degrees(beta_rad):.3f} deg): only {len(tiles)} textured windows "
                          f"are seen by the reference camera (need {min_windows}); is the plane textured and inside "
                          "the reference camera's view?")
    centres_all = np.array([(c0 + (win - 1) / 2.0, r0 + (win - 1) / 2.0) for r0, c0 in tiles])
    rays_c = cam.rays_from_pixels(centres_all)

    def compare(d: NDArray[np.float64], w_img: NDArray[np.float32] | None = None,
                ok: NDArray[np.bool_] | None = None) -> NDArray[np.float64]:
        """``(T, 2)`` shift (d_col, d_row) per window of the image against the reference warped with ``d`` (NaN:
        unusable): the content of the warped reference at p is at p + shift in the image."""
        if w_img is None or ok is None:
            w_img, ok = warp(d)
        out = np.full((len(tiles), 2), np.nan)
        for i, (r0, c0) in enumerate(tiles):
            if not ok[r0:r0 + win, c0:c0 + win].all():
                continue
            (dx, dy), resp = cv2.phaseCorrelate(w_img[r0:r0 + win, c0:c0 + win].astype(np.float64),
                                                gray_t[r0:r0 + win, c0:c0 + win].astype(np.float64), hann)
            if resp >= min_response and abs(dx) < win / 4 and abs(dy) < win / 4:
                out[i] = (dx, dy)
        return out

    def jacobian(d: NDArray[np.float64]) -> NDArray[np.float64]:
        """``(T, 2, 3)`` pixel motion of the window centres' plane points per radian of each angle."""
        x = warp.plane_points(d, rays_c)
        jac = np.empty((len(tiles), 2, 3))
        for k in range(3):
            e = np.zeros(3)
            e[k] = 1e-6
            jac[:, :, k] = (warp.pixels(d + e, x) - warp.pixels(d - e, x)) / 2e-6
        return jac

    def too_few(n: int) -> SkyrigError:
        return SkyrigError(f"image {name!r} (beta {np.degrees(beta_rad):.3f} deg): only {n} correlation windows agree "
                           f"with the reference image (need {min_windows}); is the offset larger than the search "
                           "range?")

    def solve(obs: NDArray[np.float64], jac: NDArray[np.float64], gain: float, use: NDArray[np.bool_]
              ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        a_mat = gain * jac[use].reshape(-1, 3)
        o = obs[use].reshape(-1)
        step, *_ = np.linalg.lstsq(a_mat, o, rcond=None)
        return step, o - a_mat @ step

    # Phase correlation with a Hann window reports a sub-pixel shift scaled by a gain g (about 1.45 near zero shift
    # for this texture, about 1 at a pixel): the iteration updates g by the secant (the change of the shifts against
    # the predicted change), and at convergence g is measured by a symmetric probe (the reference warped with a
    # known extra rotation of +-0.03 px) and divided out of the last step and of the residuals (the estimate's error
    # is the shift noise / g).
    d = np.zeros(3)
    obs = compare(d, w0, ok0)
    jac = jacobian(d)
    gain = 1.0
    keep = np.ones(len(tiles), bool)
    rejected = False
    converged = False
    step = np.zeros(3)
    use = keep
    damping, last_move = 1.0, None
    for it in range(int(iterations)):
        use = keep & np.all(np.isfinite(obs), axis=1)
        if use.sum() < min_windows:
            raise too_few(int(use.sum()))
        step, res = solve(obs, jac, gain, use)
        if not rejected and it >= 1:  # reject gross windows once, after a first update
            rejected = True
            r2 = np.hypot(*res.reshape(-1, 2).T)
            bad = r2 > reject_k * (np.median(r2) / 1.1774 + 1e-12)  # Rayleigh median -> sigma per coordinate
            if bad.any() and (~bad).sum() >= min_windows:
                keep[np.flatnonzero(use)[bad]] = False
                use = keep & np.all(np.isfinite(obs), axis=1)
                step, res = solve(obs, jac, gain, use)
        moved = jac[use].reshape(-1, 3) @ step  # the full update's window motion (px)
        # the full update in units of the estimate's own standard deviation (sigma0^2 (g^2 J^T J)^-1)
        step_sigmas = float(np.sqrt(gain ** 2 * (moved @ moved) * max(res.size - 3, 1) / max(res @ res, 1e-300)))
        full = jac.reshape(-1, 3) @ step
        if last_move is not None and full @ last_move < -0.5 * np.linalg.norm(full) * np.linalg.norm(last_move):
            # the update undoes the last one: near zero shift the phase correlation's sub-pixel answer is rough at
            # a few 1/1000 px (its whitened spectrum), which a full Gauss-Newton step turns into a cycle between
            # two estimates; halve the steps from here on, so that the estimate settles inside that roughness
            damping *= 0.5
        last_move = full
        step = damping * step
        moved = damping * moved
        d = d + step
        log.debug("%s: iteration %d, step %s mdeg (damping %.3g), gain %.3f, %d windows, largest window move "
                  "%.4f px, full update %.3f sigma", name, it, np.round(1000 * np.degrees(step), 4), damping, gain,
                  int(use.sum()), float(np.max(np.abs(moved))), step_sigmas)
        prev = obs
        obs = compare(d)
        jac = jacobian(d)
        if rejected and (step_sigmas < converge_sigma or np.max(np.abs(full)) < 1e-3):
            # the full update is a small fraction of the estimate's own sigma (or moves no window by 1/1000 px):
            # the iterates now wander inside the correlation's roughness, and the last step below (with the
            # probed gain) finishes the estimate from here
            converged = True
            break
        both = use & np.all(np.isfinite(obs), axis=1)
        a_ = (jac[both] @ step).reshape(-1)
        b_ = (prev[both] - obs[both]).reshape(-1)
        if np.sqrt(np.mean(a_ ** 2)) > 0.01:
            g_s = float(a_ @ b_ / (a_ @ a_))
            if 0.1 < g_s < 4.0:  # (0.2-0.4 at 640 px, ~1.45 at 320 px on the lab)
                gain = g_s
    if not converged:
        raise SkyrigError(f"image {name!r} (beta {np.degrees(beta_rad):.3f} deg): the angular offset did not converge "
                          f"in {iterations} iterations (last update {1000 * np.degrees(np.abs(step)).max():.3f} mdeg)")
    ifov = cam.pixel_size_mm / cam.focal_mm
    probe = np.full(3, 0.03 * ifov / np.sqrt(3))
    o_p, o_m = compare(d + probe), compare(d - probe)
    use = keep & np.all(np.isfinite(obs), axis=1) & np.all(np.isfinite(o_p), axis=1) & np.all(np.isfinite(o_m), axis=1)
    if use.sum() < min_windows:
        raise too_few(int(use.sum()))
    a_ = (2 * jac[use] @ probe).reshape(-1)
    b_ = (o_m[use] - o_p[use]).reshape(-1)
    gain = float(a_ @ b_ / (a_ @ a_))
    e_ = b_ - gain * a_
    gain_se = float(np.sqrt(e_ @ e_ / max(e_.size - 1, 1) / (a_ @ a_)))
    # the correlation must follow the known rotation: a gain far from zero against its own standard error (unrelated
    # images give a gain about zero), and not above 4 (~1.45 on the lab at 320 px, 0.2-0.4 at 640 px, where the
    # texture is smooth across the pixels and the whitened correlation peak is broad)
    if not (gain > 3.0 * gain_se and gain < 4.0):
        raise SkyrigError(f"image {name!r} (beta {np.degrees(beta_rad):.3f} deg): the correlation does not follow a "
                          f"known rotation of the reference (gain {gain:.2f} +- {gain_se:.2f}); are the images of the "
                          "same textured plane, and the rig's orientations right?")
    step, res = solve(obs, jac, gain, use)
    d = d + step
    res = res / gain  # true pixels
    j_use = jac[use].reshape(-1, 3)
    redundancy = res.size - 3
    q = np.linalg.inv(j_use.T @ j_use)
    s0sq = float(res @ res / redundancy) if redundancy > 0 else float("nan")
    log.debug("%s: gain %.3f +- %.3f, %d iterations, %d windows, residual RMS %.4f px", name, gain, gain_se, it + 1,
              int(use.sum()), np.sqrt(s0sq))
    return PositionOffset(d, s0sq * q, int(use.sum()), float(np.sqrt(np.mean(res ** 2))),
                          float(np.sqrt(np.mean(obs[use] ** 2))) / gain, q, gain)


# --------------------------------------------------------------------------------------------- curve statements
def fourier_design(beta_rad: ArrayLike, order: int) -> NDArray[np.float64]:
    """``(n, 2 order + 1)`` design of a Fourier series in the actuator angle: ``1, cos b, sin b, ..., cos Nb,
    sin Nb``."""
    b = np.asarray(beta_rad, dtype=np.float64).reshape(-1)
    cols = [np.ones_like(b)]
    for j in range(1, int(order) + 1):
        cols += [np.cos(j * b), np.sin(j * b)]
    return np.column_stack(cols)


@dataclass(frozen=True)
class FourierCurve:
    """A boresight curve stated as a Fourier series in the actuator angle, with the covariance of its terms.

    The series is fitted by weighted least squares to the per-position mean curve (weights ``1 / sigma_k^2``,
    :attr:`TumblingCalibration.standard_error_rad`, positions independent), so its covariance is
    ``(A^T W A)^-1`` per axis, **not** scaled by the fit's variance factor: the per-position sigma already holds
    the variance estimated from these residuals (the repeating comparison error's share,
    :attr:`TumblingCalibration.repeat_share`, by REML at the order stated), so the variance factor is about 1 by
    construction there and scaling by it would count the residuals twice.  The sigmas are estimates, so a term's
    ``error / sigma`` is about Student-t with the degrees of freedom of :attr:`TumblingCalibration.standard_error_dof`
    (about the series' ``dof`` where the repeating part dominates); the bands below take the sigmas as exact.  The
    axes are fitted separately (the per-position correlations between axes are not used).

    Attributes
    ----------
    order
        Highest harmonic ``N``.
    coefficients_rad
        ``(2 N + 1, 3)`` terms ``[a_0, a_1, b_1, ..., a_N, b_N]`` per axis (radians): ``a_0 + sum_j a_j cos(j beta)
        + b_j sin(j beta)``.
    covariance_rad2
        ``(3, 2 N + 1, 2 N + 1)`` their covariance per axis (radians^2).
    variance_factor
        ``(3,)`` weighted residual square sum / ``dof`` (a diagnostic; about 1 if the series holds the curve and the
        per-position sigma is right, below 1 where the sigma is conservative (a share held at 1, the bound), above 1
        where the series misses harmonics).
    dof
        Redundancy of the fit (positions - terms).
    harmonic_chi2
        ``(N,)`` per harmonic the chi-square (6 degrees of freedom: cos and sin of three axes) of its terms against
        zero, from the fit at the order the selection started from; NaN where not computed.
    """

    order: int
    coefficients_rad: NDArray[np.float64]
    covariance_rad2: NDArray[np.float64]
    variance_factor: NDArray[np.float64]
    dof: int
    harmonic_chi2: NDArray[np.float64]

    def __call__(self, beta_rad: ArrayLike) -> NDArray[np.float64]:
        """``(n, 3)`` the series at ``beta_rad`` (radians)."""
        return fourier_design(beta_rad, self.order) @ self.coefficients_rad

    def value_covariance(self, beta_rad: ArrayLike) -> NDArray[np.float64]:
        """``(3, n, n)`` covariance of the series' values at ``beta_rad`` per axis (radians^2)."""
        a = fourier_design(beta_rad, self.order)
        return np.einsum("ik,akl,jl->aij", a, self.covariance_rad2, a)

    def sigma_rad(self, beta_rad: ArrayLike) -> NDArray[np.float64]:
        """``(n, 3)`` standard deviations of the series' values at ``beta_rad`` (radians)."""
        a = fourier_design(beta_rad, self.order)
        return np.sqrt(np.einsum("ik,akl,il->ia", a, self.covariance_rad2, a))

    def max_abs_z_draws(self, beta_rad: ArrayLike, draws: int = 20000, seed: int = 0) -> NDArray[np.float64]:
        """``(draws,)`` the largest ``|error / sigma|`` over the positions ``beta_rad`` and the three axes, for errors
        drawn from the terms' covariance (fixed ``seed``: reproducible)."""
        a = fourier_design(beta_rad, self.order)
        sig = self.sigma_rad(beta_rad)
        rng = np.random.default_rng(seed)
        out = np.zeros(int(draws))
        for i in range(3):
            chol = np.linalg.cholesky(self.covariance_rad2[i])
            x = rng.standard_normal((int(draws), a.shape[1])) @ chol.T
            out = np.maximum(out, np.abs(x @ a.T / sig[:, i]).max(axis=1))
        return out

    def simultaneous_z(self, beta_rad: ArrayLike, level: float = 0.95, draws: int = 20000, seed: int = 0) -> float:
        """The ``|z|`` half-width of the simultaneous band: the series' errors at every position ``beta_rad`` and on
        every axis stay within ``z sigma`` with probability ``level`` (the ``level`` quantile of
        :meth:`max_abs_z_draws`; the values are correlated, so it is below :func:`skyrig.adjust.stats.sidak_z`)."""
        return float(np.quantile(self.max_abs_z_draws(beta_rad, draws, seed), level))

    def probability_all_within(self, beta_rad: ArrayLike, k_sigma: float = 2.0, draws: int = 20000,
                               seed: int = 0) -> float:
        """Probability (under the terms' covariance) that the errors at every position and on every axis are within
        ``k_sigma`` of their own sigma."""
        return float(np.mean(self.max_abs_z_draws(beta_rad, draws, seed) <= k_sigma))


def fit_fourier_curve(beta_rad: ArrayLike, values_rad: ArrayLike, sigma_rad: ArrayLike, order: int | None = None,
                      alpha: float = 1e-3, max_order: int | None = None) -> FourierCurve:
    """Weighted least-squares Fourier series of a per-position curve (:class:`FourierCurve`).

    ``order`` None: chosen from the data: the series is fitted at ``max_order`` (default ``min(12, (K - 2) // 4)``
    for ``K`` positions, at least 1) and the order is the highest harmonic whose six terms (cos, sin of the three
    axes) differ from zero by a chi-square test at ``alpha`` (at least 1).  A curve with a harmonic above
    ``max_order``, or one too weak to pass the test, is biased in the series; the variance factor shows the former.
    """
    from scipy.stats import chi2

    b = np.asarray(beta_rad, dtype=np.float64).reshape(-1)
    y = np.asarray(values_rad, dtype=np.float64).reshape(b.size, 3)
    s = np.asarray(sigma_rad, dtype=np.float64).reshape(b.size, 3)
    if not (np.all(np.isfinite(y)) and np.all(np.isfinite(s)) and np.all(s > 0)):
        raise SkyrigError("Fourier curve: the values and their sigmas must be finite, the sigmas > 0")
    k = b.size

    def fit(n: int) -> FourierCurve:
        a = fourier_design(b, n)
        coef = np.empty((a.shape[1], 3))
        cov = np.empty((3, a.shape[1], a.shape[1]))
        vf = np.empty(3)
        for i in range(3):
            w = 1.0 / s[:, i] ** 2
            n_mat = a.T @ (a * w[:, None])
            cov[i] = np.linalg.inv(n_mat)
            coef[:, i] = cov[i] @ (a.T @ (w * y[:, i]))
            r = y[:, i] - a @ coef[:, i]
            vf[i] = float(np.sum(w * r ** 2) / (k - a.shape[1])) if k > a.shape[1] else float("nan")
        hc = np.full(n, np.nan)
        for j in range(1, n + 1):
            sl = slice(2 * j - 1, 2 * j + 1)
            hc[j - 1] = sum(float(coef[sl, i] @ np.linalg.solve(cov[i][sl, sl], coef[sl, i])) for i in range(3))
        return FourierCurve(n, coef, cov, vf, k - a.shape[1], hc)

    if order is not None:
        if int(order) < 0 or 2 * int(order) + 1 > k:
            raise SkyrigError(f"Fourier curve: order {order} needs {2 * int(order) + 1} positions, the curve has {k}")
        return fit(int(order))
    top = default_max_order(k) if max_order is None else int(max_order)
    if 2 * top + 1 > k:
        raise SkyrigError(f"Fourier curve: order {top} needs {2 * top + 1} positions, the curve has {k}")
    full = fit(top)
    sig = np.flatnonzero(full.harmonic_chi2 > chi2.ppf(1.0 - alpha, 6))
    chosen = fit(int(sig.max()) + 1 if sig.size else 1)
    return FourierCurve(chosen.order, chosen.coefficients_rad, chosen.covariance_rad2, chosen.variance_factor,
                        chosen.dof, full.harmonic_chi2)


def default_max_order(positions: int) -> int:
    """The order a Fourier curve of ``positions`` values is first fitted at (the selection's start, and the series the
    repeating error's share is first estimated with): ``min(12, (K - 2) // 4)``, at least 1."""
    return max(1, min(12, (int(positions) - 2) // 4))


@dataclass(frozen=True)
class RepeatShare:
    """The repeating part of the image comparison's error, as a share of the fits' variance, per axis
    (:func:`estimate_repeat_share`).

    Attributes
    ----------
    share
        ``(3,)`` ``lambda``: the repeating error's variance at a position is ``lambda`` times the position's mean fit
        variance; in ``[0, 1]`` (1: the fit variance is all repeating, the upper bound; 0: none repeats).
    share_se
        ``(3,)`` its standard error (REML Fisher information, ``sqrt(2 / tr(P F P F))``).
    order
        Order of the Fourier series whose residuals estimated it.
    dof
        Redundancy of that series (positions - terms).
    """

    share: NDArray[np.float64]
    share_se: NDArray[np.float64]
    order: int
    dof: int


def estimate_repeat_share(beta_rad: ArrayLike, values_rad: ArrayLike, scatter_var_rad2: ArrayLike,
                          fit_var_rad2: ArrayLike, order: int) -> RepeatShare:
    """Restricted maximum likelihood (REML) estimate of the share ``lambda`` in the per-position variance model
    ``var_k = s + lambda f_k`` of a curve's values, from the residuals of a Fourier series of ``order`` that holds
    the curve.

    ``values_rad`` ``(K, 3)``: the per-position values (the mean curve); ``scatter_var_rad2`` ``(3,)`` or ``(K, 3)``:
    the known part ``s`` (the circle-to-circle scatter over ``C``); ``fit_var_rad2`` ``(K, 3)``: ``f_k`` (the mean
    fit variance of the position's images).  Per axis the REML log-likelihood
    ``-1/2 (sum log var_k + log det(A^T W A) + y^T P y)``, ``W = diag(1 / var_k)``, ``P = W - W A (A^T W A)^-1 A^T W``,
    is maximised over ``lambda in [0, 1]`` (bounded Brent); its standard error is ``sqrt(2 / tr(P F P F))`` at the
    estimate (``F = diag(f_k)``).  The REML estimate accounts for the ``2 order + 1`` terms the series takes from the
    residuals (the plain ``max(vf s^2 - s, 0) / f`` would not, and would not weight the positions).  A series that
    misses a harmonic of the curve puts it into the residuals and the share leans high (towards the bound); a share
    at 1 says the residuals are as large as the bound allows or larger.
    """
    from scipy.optimize import minimize_scalar

    b = np.asarray(beta_rad, dtype=np.float64).reshape(-1)
    k = b.size
    y = np.asarray(values_rad, dtype=np.float64).reshape(k, 3)
    s = np.broadcast_to(np.asarray(scatter_var_rad2, dtype=np.float64), (k, 3))
    f = np.asarray(fit_var_rad2, dtype=np.float64).reshape(k, 3)
    a = fourier_design(b, order)
    if k <= a.shape[1]:
        raise SkyrigError(f"repeat share: a series of order {order} needs more than {a.shape[1]} positions, got {k}")
    if not (np.all(np.isfinite(y)) and np.all(np.isfinite(s)) and np.all(s >= 0) and np.all(np.isfinite(f))
            and np.all(f > 0)):
        raise SkyrigError("repeat share: values and variances must be finite, the fit variances > 0")
    share, se = np.empty(3), np.empty(3)
    for i in range(3):
        yi, si, fi = y[:, i], s[:, i], f[:, i]
        floor = 1e-12 * float(np.mean(fi))

        def p_matrix(lam: float, si: NDArray[np.float64] = si, fi: NDArray[np.float64] = fi,
                     floor: float = floor) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
            v = np.maximum(si + lam * fi, floor)
            w = 1.0 / v
            aw = a * w[:, None]
            n_mat = a.T @ aw
            pm = np.diag(w) - aw @ np.linalg.solve(n_mat, aw.T)
            return pm, v, float(np.linalg.slogdet(n_mat)[1])

        def neg_loglik(lam: float, yi: NDArray[np.float64] = yi) -> float:
            pm, v, logdet_n = p_matrix(lam)
            return 0.5 * (float(np.sum(np.log(v))) + logdet_n + float(yi @ pm @ yi))

        res = minimize_scalar(neg_loglik, bounds=(0.0, 1.0), method="bounded", options={"xatol": 1e-9})
        lam = float(res.x)
        for end in (0.0, 1.0):  # Brent stops xatol short of a bound: the bound itself if it is as likely
            if neg_loglik(end) <= neg_loglik(lam):
                lam = end
        pm = p_matrix(lam)[0]
        pf = pm * fi[None, :]
        share[i] = lam
        se[i] = float(np.sqrt(2.0 / max(float(np.sum(pf * pf.T)), 1e-300)))
    return RepeatShare(share, se, int(order), int(k - a.shape[1]))


@dataclass(frozen=True)
class FailedImage:
    """A tumbling image the recipe left out (:func:`measure_position_offset` raised for it).

    Attributes
    ----------
    name, circle
        The image and its circle label.
    beta_rad
        Its actuator angle (radians).
    reason
        The error message.
    """

    name: str
    circle: str
    beta_rad: float
    reason: str

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: image, circle, beta_deg, reason."""
        return {"image": self.name, "circle": self.circle, "beta_deg": float(np.degrees(self.beta_rad)),
                "reason": self.reason}


@dataclass
class TumblingCalibration:
    """Result of :func:`calibrate_tumbling_head`.

    An image the recipe could not measure (:attr:`failed`) is NaN in :attr:`corrections_rad`, :attr:`sigma_rad`
    and :attr:`covariance_rad2` and 0 in :attr:`windows`; every statistic uses the ``C_k`` circles measured at
    position ``k`` (:attr:`counts`): the mean and std of the position over its ``C_k`` values, the pooled scatter
    with ``N - K`` degrees of freedom (``N`` images measured), the mean's scatter part ``pooled^2 / C_k``.

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
        ``(C, K)`` image names (also of the images left out).
    windows
        ``(C, K)`` correlation windows used per image (0: left out).
    curve
        The mean curve with the per-position repeatability (``std_rad``, ``count``).
    setup
        The lab set-up.
    covariance_rad2
        ``(C, K, 3, 3)`` each image's fit covariance (radians^2; the tilt across the view and the yaw are strongly
        correlated in one image), or None: uncorrelated with ``sigma_rad``.
    failed
        The images left out, with the reasons (:class:`FailedImage`).
    """

    beta_rad: NDArray[np.float64]
    circles: NDArray[np.str_]
    corrections_rad: NDArray[np.float64]
    sigma_rad: NDArray[np.float64]
    images: NDArray[np.str_]
    windows: NDArray[np.int64]
    curve: BoresightCurve
    setup: LabSetup
    covariance_rad2: NDArray[np.float64] | None = None
    failed: tuple[FailedImage, ...] = ()

    @property
    def measured(self) -> NDArray[np.bool_]:
        """``(C, K)`` whether the image was measured (not left out: its corrections are finite)."""
        return np.all(np.isfinite(self.corrections_rad), axis=-1)

    @property
    def counts(self) -> NDArray[np.int64]:
        """``(K,)`` ``C_k``: the circles measured at each position."""
        return self.measured.sum(axis=0).astype(np.int64)

    @property
    def scatter_dof(self) -> int:
        """Degrees of freedom of the pooled scatter :attr:`pooled_std_rad`: ``sum_k (C_k - 1) = N - K``
        (``K (C - 1)`` when every image was measured)."""
        return int(np.sum(self.counts - 1))

    def _position_mean(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """Mean over the circles measured at each position of a ``(C, K, ...)`` per-image array."""
        m = self.measured.reshape(self.measured.shape + (1,) * (x.ndim - 2))
        return np.where(m, x, 0.0).sum(axis=0) / self.counts.reshape((-1,) + (1,) * (x.ndim - 2))

    @property
    def mean_rad(self) -> NDArray[np.float64]:
        """``(K, 3)`` mean correction per position (over its ``C_k`` circles), in ``beta_rad`` order."""
        return self._position_mean(self.corrections_rad)

    @property
    def std_rad(self) -> NDArray[np.float64]:
        """``(K, 3)`` repeatability per position (sample std of its ``C_k`` values about their mean, ``ddof=1``)."""
        dev = np.where(self.measured[..., None], self.corrections_rad - self.mean_rad[None], 0.0)
        return np.sqrt(np.sum(dev ** 2, axis=0) / (self.counts[:, None] - 1))

    @property
    def pooled_std_rad(self) -> NDArray[np.float64]:
        """``(3,)`` the repeatability pooled over the positions: ``sqrt(sum_k (C_k - 1) std_k^2 / (N - K))``
        (:attr:`scatter_dof` degrees of freedom; ``sqrt(mean_k std_k^2)`` when every image was measured)."""
        w = (self.counts - 1)[:, None]
        return np.sqrt(np.sum(w * self.std_rad ** 2, axis=0) / self.scatter_dof)

    @property
    def fit_variance_rad2(self) -> NDArray[np.float64]:
        """``(K, 3)`` ``fit_k^2``: the mean fit variance of the images measured at each position."""
        return self._position_mean(self.sigma_rad ** 2)

    @property
    def measurement_variance_rad2(self) -> NDArray[np.float64]:
        """``(3,)`` the mean variance of one image's angular offset from its fit (``sigma0^2 (J^T J)^-1`` of the
        window shifts, :func:`measure_position_offset`), over the measured images."""
        return np.mean(self.sigma_rad[self.measured] ** 2, axis=0)

    @cached_property
    def repeat_share(self) -> RepeatShare:
        """The repeating part of the image comparison's error as a share ``lambda`` of the fit variance, per axis
        (:func:`estimate_repeat_share` on the mean curve).

        The mean curve's error at position ``k`` is the circle mean of the mechanism's repeat errors and of the part
        of the comparison's error that changes from circle to circle (image noise, the sampling phase), variance
        ``pooled^2 / C``, plus the part that repeats (the same texture is compared at a position in every circle),
        which does not average out: ``rep_k^2``, independent between positions.  Its shape follows the position's
        fit variance (the repeating part of the window shifts goes through the same ``(J^T J)^-1``):
        ``rep_k^2 = lambda f_k`` with ``0 <= lambda <= 1`` (all of a fit's error at most repeats).  A smooth series
        that holds the curve leaves residuals with variance ``pooled^2 / C + lambda f_k``; ``lambda`` is their REML
        estimate, ``pooled^2`` taken as known (``K (C - 1)`` degrees of freedom).  The series: first the default
        highest order (:func:`default_max_order`), then the order :func:`fit_fourier_curve` selects (``alpha = 1e-3``)
        with the sigmas of that share, re-estimated until the order repeats (the final share is estimated with the
        series :meth:`fourier_curve` states).  Fewer than 4 positions: no redundancy, ``lambda = 1`` (the bound),
        ``order`` and ``dof`` 0.  With images left out the scatter part is ``pooled^2 / C_k`` per position."""
        k = self.corrections_rad.shape[1]
        s = self.pooled_std_rad[None] ** 2 / self.counts[:, None]
        f = self.fit_variance_rad2
        if k < 4:
            return RepeatShare(np.ones(3), np.full(3, np.nan), 0, 0)
        order = default_max_order(k)
        rs = estimate_repeat_share(self.beta_rad, self.mean_rad, s, f, order)
        for _ in range(5):
            n = fit_fourier_curve(self.beta_rad, self.mean_rad, np.sqrt(s + rs.share * f), None, 1e-3).order
            if n == order:
                break
            order = n
            rs = estimate_repeat_share(self.beta_rad, self.mean_rad, s, f, order)
        return rs

    @property
    def standard_error_rad(self) -> NDArray[np.float64]:
        """``(K, 3)`` standard error of the mean curve: ``sqrt(pooled^2 / C + lambda fit_k^2)``, ``pooled`` the
        repeatability pooled over the positions (one position's own std has only ``C - 1`` degrees of freedom, too
        few to weight it), ``fit_k^2`` the mean fit variance of the position's images and ``lambda`` the share of
        it that repeats from circle to circle (:attr:`repeat_share`, estimated from the mean curve's residuals about
        a Fourier series).

        An estimate, not a bound: the scatter over the circles holds the mechanism's repeat error and the part of
        the comparison's error that changes from circle to circle; the repeating part is added once, as estimated.
        Both variance parts are estimated, so ``(mean - truth) / standard_error`` is about Student-t with
        :attr:`standard_error_dof` degrees of freedom (near N(0, 1) at 30 or more).  The upper bound the recipe
        stated before (the fit variance added in full, ``lambda = 1``) is :attr:`standard_error_bound_rad`.  With
        images left out, ``C`` is the position's ``C_k`` (:attr:`counts`) and ``fit_k^2`` the mean over its measured
        images."""
        lam = self.repeat_share.share
        return np.sqrt(self.pooled_std_rad[None] ** 2 / self.counts[:, None] + lam[None] * self.fit_variance_rad2)

    @property
    def standard_error_bound_rad(self) -> NDArray[np.float64]:
        """``(K, 3)`` an upper bound of the mean curve's standard error: ``sqrt(pooled^2 / C + fit_k^2)``, the fit
        variance added in full as the bound of the repeating comparison error (``lambda = 1`` in
        :attr:`standard_error_rad`; it counts the part of the comparison's error that changes from circle to circle
        twice: once in ``pooled`` and again in the fit variance); ``C_k`` circles where images were left out."""
        return np.sqrt(self.pooled_std_rad[None] ** 2 / self.counts[:, None] + self.fit_variance_rad2)

    @property
    def standard_error_dof(self) -> NDArray[np.float64]:
        """``(K, 3)`` Satterthwaite's degrees of freedom of :attr:`standard_error_rad`'s variance
        ``v_k = s + lambda f_k``: ``2 v_k^2 / (2 s^2 / (K (C - 1)) + f_k^2 se(lambda)^2)``, ``s = pooled^2 / C`` a
        chi-square with ``K (C - 1)`` degrees of freedom and ``se(lambda)`` :attr:`repeat_share`'s standard error
        (the share is estimated from the series' ``dof`` residuals, so this is about ``dof`` where the repeating
        part dominates and about ``K (C - 1)`` where the scatter does; with images left out ``s = pooled^2 / C_k``
        and :attr:`scatter_dof` = ``N - K`` in place of ``K (C - 1)``)."""
        s = self.pooled_std_rad[None] ** 2 / self.counts[:, None]
        f = self.fit_variance_rad2
        rs = self.repeat_share
        v = s + rs.share[None] * f
        var_v = 2 * s ** 2 / self.scatter_dof + f ** 2 * np.nan_to_num(rs.share_se)[None] ** 2
        return 2 * v ** 2 / np.maximum(var_v, 1e-300)

    @property
    def fit_covariance_rad2(self) -> NDArray[np.float64]:
        """``(C, K, 3, 3)`` each image's fit covariance (:attr:`covariance_rad2`, or diagonal from
        :attr:`sigma_rad`)."""
        if self.covariance_rad2 is not None:
            return self.covariance_rad2
        return self.sigma_rad[..., :, None] * np.eye(3) * self.sigma_rad[..., None, :]

    @property
    def mean_covariance_rad2(self) -> NDArray[np.float64]:
        """``(K, 3, 3)`` covariance of the mean curve per position, the matrix form of :attr:`standard_error_rad`:
        the scatter over the circles pooled over the positions (``K (C - 1)`` degrees of freedom) over ``C`` plus
        the repeating part, the position's mean fit covariance scaled by ``sqrt(lambda_i lambda_j)``
        (:attr:`repeat_share`).  Its diagonal is ``standard_error_rad^2``; positions uncorrelated.  With images
        left out: the scatter over ``N - K`` degrees of freedom, over ``C_k``, and the mean fit covariance of the
        position's measured images."""
        dev = np.where(self.measured[..., None], self.corrections_rad - self.mean_rad[None], 0.0)
        scatter = np.einsum("cki,ckj->ij", dev, dev) / self.scatter_dof
        root = np.sqrt(self.repeat_share.share)
        return (scatter[None] / self.counts[:, None, None]
                + self._position_mean(self.fit_covariance_rad2) * np.outer(root, root)[None])

    def mechanism_repeatability_rad(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(std, se)``, each ``(3,)`` radians, 1 sigma: the mechanism's own repeatability with the measurement
        noise removed, ``sqrt(max(pooled^2 - m, 0))`` (``m`` = :attr:`measurement_variance_rad2`), and its standard
        error by the delta method from the chi-square spread of the pooled variance (``K (C - 1)`` degrees of
        freedom) and of the fit variances (``sum of the fits' redundancies``).

        The scatter over the circles holds the mechanism's repeat error and the part of the comparison's error
        that changes from circle to circle; ``m`` also holds the part that repeats, so the estimate leans low by at
        most that part, ``lambda m`` with ``lambda`` the share of :attr:`repeat_share` (on the simulated 72 x 5 lab
        at 320 px the realised share averages 0.16-0.21 per axis over 24 labs; the estimate is not used here: it
        averages 0.19-0.24 and scatters by 0.13-0.27 between labs, as much as the bias it would
        remove).  Where ``pooled^2 <= m`` the std is 0
        and ``se`` is the one-sided bound ``sqrt(2 sd(pooled^2))``.  With images left out: ``N - K`` degrees of
        freedom (:attr:`scatter_dof`) and the measured images' fits."""
        dof = self.scatter_dof
        pooled2 = self.pooled_std_rad ** 2
        m = self.measurement_variance_rad2
        red = max(int(np.sum(2 * self.windows[self.measured] - 3)), 1)
        var_v = 2 * pooled2 ** 2 / dof + 2 * m ** 2 / red
        v = pooled2 - m
        std = np.sqrt(np.clip(v, 0.0, None))
        se = np.where(v > 0, np.sqrt(var_v) / (2 * np.sqrt(np.clip(v, 1e-300, None))), np.sqrt(2 * np.sqrt(var_v)))
        return std, se

    def mechanism_std_rad(self) -> NDArray[np.float64]:
        """``(3,)`` the mechanism's repeatability with the measurement noise removed (see
        :meth:`mechanism_repeatability_rad`)."""
        return self.mechanism_repeatability_rad()[0]

    def fourier_curve(self, order: int | None = None, alpha: float = 1e-3) -> FourierCurve:
        """The mean curve stated as a Fourier series in the actuator angle with the covariance of its terms
        (:func:`fit_fourier_curve` on :attr:`mean_rad` weighted by :attr:`standard_error_rad`; ``order`` None: the
        highest harmonic that differs from zero at ``alpha``; at the default ``alpha`` this is the order
        :attr:`repeat_share` was estimated with)."""
        return fit_fourier_curve(self.beta_rad, self.mean_rad, self.standard_error_rad, order, alpha)

    def curve_statement(self, level: float = 0.95, order: int | None = None) -> dict[str, Any]:
        """How far the estimated curve may be from the mechanism's, stated two ways (JSON-ready, 1/1000 deg).

        ``lookup``: the per-position means (paper 000's table, written into the rig file) with their standard
        errors (:attr:`standard_error_rad`: estimates, not bounds), positions independent: the simultaneous band
        over the ``3 K`` values is Sidak's ``|z|`` bound (:func:`skyrig.adjust.stats.sidak_z`), and "every value
        within 2 sigma" has probability ``0.9545^(3 K)`` if the sigmas are exact; also the repeating comparison
        error's share of the fit variance (:attr:`repeat_share`, with its standard error, the series order and
        redundancy it was estimated with), the sigmas' median degrees of freedom per axis
        (:attr:`standard_error_dof`) and the upper bound of the sigmas (:attr:`standard_error_bound_rad`), the
        circles measured per position (fewest) and the images left out (:attr:`failed`: names and reasons).
        ``fourier``: the series of :meth:`fourier_curve` with its terms' sigma, its values' sigma at the
        positions, the simultaneous band from its covariance (the values are correlated) and the probability of
        "every value within 2 sigma" under that covariance."""
        from scipy.stats import norm

        k = int(self.beta_rad.size)
        md = 1000.0 * 180.0 / np.pi
        p2 = float((2.0 * norm.cdf(2.0) - 1.0) ** (3 * k))
        rs = self.repeat_share
        dof = np.median(self.standard_error_dof, axis=0)
        out: dict[str, Any] = {"level": level, "lookup": {
            "values": 3 * k, "simultaneous_z": sidak_z(3 * k, level), "p_every_value_within_2sigma": p2,
            "sigma_mdeg": {a: (md * self.standard_error_rad[:, i]).tolist() for i, a in enumerate(AXES)},
            "sigma_model": "sqrt(pooled^2 / C_k + repeat_share * fit_k^2), C_k circles measured at the position",
            "circles_per_position_min": int(self.counts.min()), "pooled_dof": self.scatter_dof,
            "images_left_out": [f.to_dict() for f in self.failed],
            "repeat_share": dict(zip(AXES, rs.share.tolist())),
            "repeat_share_se": dict(zip(AXES, rs.share_se.tolist())),
            "repeat_share_order": rs.order, "repeat_share_dof": rs.dof,
            "sigma_dof_median": dict(zip(AXES, dof.tolist())),
            "sigma_bound_mdeg": {a: (md * self.standard_error_bound_rad[:, i]).tolist() for i, a in enumerate(AXES)}}}
        if k >= 4:  # a series of order 1 with a redundancy
            f = self.fourier_curve(order)
            sd = np.sqrt(np.diagonal(f.covariance_rad2, axis1=1, axis2=2))
            draws = f.max_abs_z_draws(self.beta_rad)
            names = ["a0"] + [f"{t}{j}" for j in range(1, f.order + 1) for t in ("a", "b")]
            out["fourier"] = {
                "order": f.order, "dof": f.dof, "terms": names,
                "coefficients_mdeg": {a: (md * f.coefficients_rad[:, i]).tolist() for i, a in enumerate(AXES)},
                "coefficient_sigma_mdeg": {a: (md * sd[i]).tolist() for i, a in enumerate(AXES)},
                "variance_factor": dict(zip(AXES, f.variance_factor.tolist())),
                "harmonic_chi2_6dof": f.harmonic_chi2.tolist(),
                "values_mdeg": {a: (md * f(self.beta_rad)[:, i]).tolist() for i, a in enumerate(AXES)},
                "values_sigma_mdeg": {a: (md * f.sigma_rad(self.beta_rad)[:, i]).tolist() for i, a in enumerate(AXES)},
                "simultaneous_z": float(np.quantile(draws, level)),
                "p_every_value_within_2sigma": float(np.mean(draws <= 2.0))}
        return out

    def table2(self, k_sigma: float = 2.0) -> dict[str, dict[str, Any]]:
        """Paper 000 Tab. 2: per axis the mean and the max of the per-position standard deviation (``k_sigma``
        scaled, degrees and 1/1000 deg), the position (beta, deg) and the image of the max (the image of that
        position farthest from the mean curve); also the per-image measurement sigma (RMS of the fits), the pooled
        repeatability, and the mechanism's repeatability with the measurement noise removed and its standard error
        (:meth:`mechanism_repeatability_rad`), all scaled.  Images left out (:attr:`failed`) are not in it."""
        std = self.std_rad
        mech, mech_se = self.mechanism_repeatability_rad()
        fit = np.sqrt(self.measurement_variance_rad2)
        pooled = self.pooled_std_rad
        out = {}
        for i, a in enumerate(AXES):
            k = int(np.argmax(std[:, i]))
            c = int(np.nanargmax(np.abs(self.corrections_rad[:, k, i] - self.mean_rad[k, i])))
            mean_deg = float(np.degrees(np.mean(std[:, i])) * k_sigma)
            max_deg = float(np.degrees(std[k, i]) * k_sigma)
            out[a] = {"mean_std_deg": mean_deg, "max_std_deg": max_deg, "mean_std_mdeg": 1000 * mean_deg,
                      "max_std_mdeg": 1000 * max_deg, "k_sigma": k_sigma,
                      "beta_at_max_deg": float(np.degrees(self.beta_rad[k])), "image_at_max": str(self.images[c, k]),
                      "measurement_sigma_mdeg": 1000 * float(np.degrees(fit[i]) * k_sigma),
                      "pooled_std_mdeg": 1000 * float(np.degrees(pooled[i]) * k_sigma),
                      "mechanism_std_mdeg": 1000 * float(np.degrees(mech[i]) * k_sigma),
                      "mechanism_std_deg": float(np.degrees(mech[i]) * k_sigma),
                      "mechanism_std_se_mdeg": 1000 * float(np.degrees(mech_se[i]) * k_sigma)}
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
        sigma: its standard errors :attr:`standard_error_rad`; correlations: the three axes of a position from
        :attr:`mean_covariance_rad2`, positions uncorrelated) and provenance (with the repeating comparison error's
        share :attr:`repeat_share` per axis, the number of images left out and the fewest circles at a position;
        the notes name the images left out and why); other heads kept from ``previous``."""
        names = [f"{a}_deg@{np.degrees(b):.4f}" for b in self.beta_rad for a in AXES]
        values = np.degrees(self.mean_rad).reshape(-1)
        sig = np.degrees(self.standard_error_rad).reshape(-1)
        cov = self.mean_covariance_rad2
        sd = np.sqrt(np.einsum("kii->ki", cov))
        corr = np.zeros((len(names), len(names)))
        for k in range(self.beta_rad.size):  # block diagonal: the three axes of a position are correlated
            corr[3 * k:3 * k + 3, 3 * k:3 * k + 3] = np.clip(cov[k] / np.outer(sd[k], sd[k]), -1.0, 1.0)
        corr[np.diag_indices_from(corr)] = 1.0
        block = CovarianceBlock(tuple(names), np.nan_to_num(sig), np.nan_to_num(corr), values)
        rep = self.table2(1.0)
        stats = {"positions": int(self.beta_rad.size), "circles": int(self.corrections_rad.shape[0]),
                 "images": int(self.measured.sum()), "images_left_out": len(self.failed),
                 "circles_per_position_min": int(self.counts.min()),
                 "windows_min": int(self.windows[self.measured].min()),
                 **{f"{a}_mean_std_deg": rep[a]["mean_std_deg"] for a in AXES},
                 **{f"{a}_max_std_deg": rep[a]["max_std_deg"] for a in AXES},
                 **{f"{a}_fit_sigma_median_deg": float(np.degrees(np.median(self.sigma_rad[self.measured][:, i])))
                    for i, a in enumerate(AXES)},
                 **{f"{a}_mechanism_std_deg": rep[a]["mechanism_std_deg"] for a in AXES},
                 **{f"{a}_mechanism_std_se_deg": rep[a]["mechanism_std_se_mdeg"] / 1000 for a in AXES},
                 **{f"{a}_repeat_share": float(self.repeat_share.share[i]) for i, a in enumerate(AXES)},
                 **{f"{a}_repeat_share_se": float(self.repeat_share.share_se[i]) for i, a in enumerate(AXES)}}
        notes = ("laboratory calibration (paper 000, 3.4): tumbling images against a static reference camera "
                 "through a common plane, phase correlation of windows, small-rotation least squares per "
                 "image iterated to zero shift; mean curve over circles")
        if self.failed:
            notes += (f"; {len(self.failed)} images left out (the curve at their positions from the other circles): "
                      + _failed_list(self.failed, most=len(self.failed)))
        prov = Provenance("tumbling-head", flight, date, software, stats, notes)
        heads = dict(previous.heads) if previous is not None else {}
        prev = heads.get(self.setup.head, HeadCalibration())
        heads[self.setup.head] = HeadCalibration(prev.lever_arm_m, prev.boresight_opk_deg, prev.interior, block, prov)
        return RigCalibration(heads, None if previous is None else previous.antenna_lever_arm_m,
                              prov if previous is None or previous.provenance is None else previous.provenance)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready report: Tab. 2, the mean curve with its repeatability, every measurement, the images left
        out (``images_left_out``: image, circle, beta_deg, reason)."""
        fc = self.fit_covariance_rad2
        mc = self.mean_covariance_rad2
        se, se_bound = self.standard_error_rad, self.standard_error_bound_rad
        return {
            "recipe": "tumbling-head",
            "head": self.setup.head, "reference_head": self.setup.reference_head,
            "plane_distance_m": self.setup.plane_distance_m,
            "positions": int(self.beta_rad.size), "circles": [str(c) for c in self.circles],
            "images_measured": int(self.measured.sum()),
            "images_left_out": [f.to_dict() for f in self.failed],
            "table2_2sigma": self.table2(2.0),
            "curve_statement": self.curve_statement(),
            "curve": [{"beta_deg": float(np.degrees(b)), "circles_measured": int(self.counts[k]),
                       **{f"{a}_mdeg": 1000 * float(np.degrees(self.mean_rad[k, i])) for i, a in enumerate(AXES)},
                       **{f"{a}_std_mdeg": 1000 * float(np.degrees(self.std_rad[k, i])) for i, a in enumerate(AXES)},
                       **{f"{a}_se_mdeg": 1000 * float(np.degrees(se[k, i])) for i, a in enumerate(AXES)},
                       **{f"{a}_se_bound_mdeg": 1000 * float(np.degrees(se_bound[k, i])) for i, a in enumerate(AXES)},
                       **{f"r_{AXES[i]}_{AXES[j]}": float(mc[k, i, j] / np.sqrt(mc[k, i, i] * mc[k, j, j]))
                          for i, j in ((0, 1), (0, 2), (1, 2))}}
                      for k, b in enumerate(self.beta_rad)],
            "measurements": [{"image": str(self.images[c, k]), "circle": str(self.circles[c]),
                              "beta_deg": float(np.degrees(self.beta_rad[k])), "windows": int(self.windows[c, k]),
                              **{f"{a}_mdeg": 1000 * float(np.degrees(self.corrections_rad[c, k, i]))
                                 for i, a in enumerate(AXES)},
                              **{f"{a}_sigma_mdeg": 1000 * float(np.degrees(self.sigma_rad[c, k, i]))
                                 for i, a in enumerate(AXES)},
                              **{f"r_{AXES[i]}_{AXES[j]}":
                                 float(fc[c, k, i, j] / np.sqrt(fc[c, k, i, i] * fc[c, k, j, j]))
                                 for i, j in ((0, 1), (0, 2), (1, 2))}}
                             for c in range(len(self.circles)) for k in range(self.beta_rad.size)
                             if self.measured[c, k]],
        }


def calibrate_tumbling_head(
    setup: LabSetup,
    images: Callable[[str], NDArray[np.uint8]],
    image_names: Sequence[str],
    circles: Sequence[str],
    beta_rad: ArrayLike,
    reference_image: NDArray[np.uint8],
    *,
    window_px: int = 32,
    interpolation: str = "cubic",
    min_circles: int = 2,
    max_failed_share: float = 0.10,
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
    window_px
        See :func:`measure_position_offset`.
    interpolation
        Of the mean curve (``cubic`` periodic spline or ``linear``).
    min_circles
        Every position must keep at least this many measured circles (>= 2: the repeatability needs two).
    max_failed_share
        At most this share of the images may fail; more is a systematic problem (wrong rig, plane distance,
        reference image, lighting), not a bad image, and stops the recipe.

    Returns
    -------
    TumblingCalibration

    Raises
    ------
    SkyrigError
        Inconsistent inputs; more than ``max_failed_share`` of the images failed; a position keeps fewer than
        ``min_circles`` measured circles (the message names the positions and the images left out).

    An image that :func:`measure_position_offset` (or loading it) fails for with a :class:`SkyrigError` (too few
    textured windows, no convergence, a correlation that does not follow the probe rotation, a wrong size) is left
    out with a WARNING naming it, its circle, its beta and the reason, and recorded in
    :attr:`TumblingCalibration.failed`; its position's statistics use the circles measured there.
    """
    names = np.asarray(image_names, dtype=str)
    circ = np.asarray(circles, dtype=str)
    beta = np.asarray(beta_rad, dtype=np.float64).reshape(-1)
    if not (names.size == circ.size == beta.size) or names.size == 0:
        raise SkyrigError("tumbling-head: image names, circles and actuator angles must be equally long and non-empty")
    labels = list(dict.fromkeys(circ.tolist()))
    if int(min_circles) < 2:
        raise SkyrigError(f"tumbling-head: min_circles must be at least 2 (the repeatability needs two), got "
                          f"{min_circles}")
    if not 0.0 <= float(max_failed_share) < 1.0:
        raise SkyrigError(f"tumbling-head: max_failed_share must be in [0, 1), got {max_failed_share}")
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
    cov = np.full((len(labels), k_pos, 3, 3), np.nan)
    nam = np.empty((len(labels), k_pos), dtype=object)
    win = np.zeros((len(labels), k_pos), np.int64)
    for lab in labels:  # check every circle before measuring anything
        keys = np.round(np.degrees(beta[circ == lab]) % 360.0, 6)
        if keys.size != k_pos or not np.array_equal(np.sort(keys), pos):
            missing = sorted(set(pos.tolist()) ^ set(keys.tolist()))
            raise SkyrigError(f"tumbling-head: circle {lab!r} does not hold the same actuator positions as circle "
                              f"{labels[0]!r} (differing: {', '.join(f'{m:g}' for m in missing[:8])} deg)")
    # one reference for every image (checked and converted to grey once): its size is not a per-image failure
    ref_gray = _reference_gray(setup, reference_image)
    max_failed = int(np.floor(float(max_failed_share) * names.size + 1e-9))
    failed: list[FailedImage] = []
    for ci, lab in enumerate(labels):
        for j in np.flatnonzero(circ == lab):
            k = int(np.searchsorted(pos, np.round(np.degrees(beta[j]) % 360.0, 6)))
            nam[ci, k] = str(names[j])
            try:
                off = measure_position_offset(setup, images(str(names[j])), float(beta[j]), ref_gray,
                                              name=str(names[j]), window_px=window_px)
            except SkyrigError as exc:
                failed.append(FailedImage(str(names[j]), str(lab), float(beta[j]), str(exc)))
                log.warning("%s circle %s beta %.2f deg: left out of its position's statistics: %s", names[j], lab,
                            np.degrees(beta[j]), exc)
                if len(failed) > max_failed:
                    raise SkyrigError(
                        f"tumbling-head: {len(failed)} of {names.size} images failed (at most "
                        f"{100 * float(max_failed_share):g} % = {max_failed} may: more is a systematic problem, "
                        "e.g. the rig's orientations, the plane distance, the reference image or the lighting, not "
                        f"a bad image); failed: {_failed_list(failed)}") from None
                continue
            meas[ci, k] = off.correction_rad
            sig[ci, k] = off.sigma_rad
            cov[ci, k] = off.covariance_rad2
            nam[ci, k] = str(names[j])
            win[ci, k] = off.windows
            log.info("%s circle %s beta %.2f deg: droll %.2f dpitch %.2f dyaw %.2f mdeg (%d windows, fit RMS %.3f px)",
                     names[j], lab, np.degrees(beta[j]), *(1000 * np.degrees(off.correction_rad)), off.windows,
                     off.residual_rms_px)
    b = np.radians(pos)
    ok = np.all(np.isfinite(meas), axis=-1)
    short = np.flatnonzero(ok.sum(axis=0) < int(min_circles))
    if short.size:
        raise SkyrigError(
            f"tumbling-head: {short.size} actuator positions keep fewer than {int(min_circles)} measured circles "
            f"(beta {', '.join(f'{pos[k]:g} deg ({int(ok[:, k].sum())} of {len(labels)})' for k in short[:12])}"
            f"{', ...' if short.size > 12 else ''}): their repeatability cannot be measured; "
            f"failed: {_failed_list(failed)}")
    if failed:
        log.warning("tumbling-head: %d of %d images left out (%s); fewest circles at a position: %d of %d",
                    len(failed), names.size, ", ".join(f.name for f in failed), int(ok.sum(axis=0).min()),
                    len(labels))
    # the mean curve over the circles measured at each position (from_circles is from_samples of every circle)
    curve = BoresightCurve.from_samples(np.tile(b, len(labels))[ok.reshape(-1)], meas[ok],
                                        interpolation)  # type: ignore[arg-type]
    return TumblingCalibration(b, np.asarray(labels, dtype=str), meas, sig, nam.astype(str), win, curve, setup,
                               cov, tuple(failed))


def _failed_list(failed: Sequence[FailedImage], most: int = 8) -> str:
    """The failed images for a message or a note: name, circle, beta and reason of the first ``most``."""
    out = "; ".join(f"{f.name} (circle {f.circle}, beta {np.degrees(f.beta_rad):.4f} deg): {f.reason}"
                    for f in failed[:most])
    return out + (f"; and {len(failed) - most} more" if len(failed) > most else "")
