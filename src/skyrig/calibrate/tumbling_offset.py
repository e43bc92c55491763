"""One tumbling image against the static reference camera (steps 2-3 of the ``tumbling-head`` recipe, paper 000, 3.4).

The reference image is carried through the plane into the tumbling image's pixel grid (:class:`_Warp`, Keys' cubic
convolution), windows are compared by phase correlation and the small correction ``(droll, dpitch, dyaw)`` is
estimated by Gauss-Newton until the shifts vanish (:func:`measure_position_offset`).  The recipe:
:mod:`skyrig.calibrate.tumbling`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import cv2
import numba
import numpy as np
from numpy.typing import NDArray

from skyrig.calibrate.tumbling_setup import LabSetup
from skyrig.errors import SkyrigError

log = logging.getLogger("skyrig.calibrate.tumbling")

__all__ = ["PositionOffset", "measure_position_offset"]


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
    cmp = _WindowComparison(setup, gray_t, beta_rad, ref, name, window_px, min_windows, min_texture, min_response)
    it, d, obs, jac, keep = _gauss_newton(cmp, iterations, reject_k, converge_sigma)
    ifov = cam.pixel_size_mm / cam.focal_mm
    return _finish_with_probed_gain(cmp, it, d, obs, jac, keep, ifov)


class _WindowComparison:
    """The tumbling image's windows against the reference warped with a trial correction (:class:`_Warp`).

    The windows (non-overlapping ``window_px`` squares, textured in both images, seen by the reference) are chosen
    once, at the nominal orientation."""

    def __init__(self, setup: LabSetup, gray_t: NDArray[np.float32], beta_rad: float, ref: NDArray[np.float32],
                 name: str, window_px: int, min_windows: int, min_texture: float, min_response: float):
        self.name, self.beta_rad, self.gray_t = name, beta_rad, gray_t
        self.min_windows, self.min_response = min_windows, min_response
        cam = setup.rig.head(setup.head).camera
        self.warp = warp = _Warp(setup, beta_rad, ref, gray_t.shape)
        self.win = win = max(8, int(window_px))
        pad = 2
        self.hann = cv2.createHanningWindow((win, win), cv2.CV_64F)
        self.w0, self.ok0 = w0, ok0 = warp(np.zeros(3))  # the windows are chosen once, at the nominal orientation
        self.tiles = tiles = [(r0, c0) for r0, c0 in _windows(ok0, win, pad)
                              if gray_t[r0:r0 + win, c0:c0 + win].std() >= min_texture
                              and w0[r0:r0 + win, c0:c0 + win].std() >= min_texture]
        if len(tiles) < min_windows:
            raise SkyrigError(f"image {name!r} (beta {np.degrees(beta_rad):.3f} deg): only {len(tiles)} textured "
                              f"windows are seen by the reference camera (need {min_windows}); is the plane textured "
                              "and inside the reference camera's view?")
        centres_all = np.array([(c0 + (win - 1) / 2.0, r0 + (win - 1) / 2.0) for r0, c0 in tiles])
        self.rays_c = cam.rays_from_pixels(centres_all)

    def compare(self, d: NDArray[np.float64], w_img: NDArray[np.float32] | None = None,
                ok: NDArray[np.bool_] | None = None) -> NDArray[np.float64]:
        """``(T, 2)`` shift (d_col, d_row) per window of the image against the reference warped with ``d`` (NaN:
        unusable): the content of the warped reference at p is at p + shift in the image."""
        if w_img is None or ok is None:
            w_img, ok = self.warp(d)
        win, gray_t = self.win, self.gray_t
        out = np.full((len(self.tiles), 2), np.nan)
        for i, (r0, c0) in enumerate(self.tiles):
            if not ok[r0:r0 + win, c0:c0 + win].all():
                continue
            (dx, dy), resp = cv2.phaseCorrelate(w_img[r0:r0 + win, c0:c0 + win].astype(np.float64),
                                                gray_t[r0:r0 + win, c0:c0 + win].astype(np.float64), self.hann)
            if resp >= self.min_response and abs(dx) < win / 4 and abs(dy) < win / 4:
                out[i] = (dx, dy)
        return out

    def jacobian(self, d: NDArray[np.float64]) -> NDArray[np.float64]:
        """``(T, 2, 3)`` pixel motion of the window centres' plane points per radian of each angle."""
        x = self.warp.plane_points(d, self.rays_c)
        jac = np.empty((len(self.tiles), 2, 3))
        for k in range(3):
            e = np.zeros(3)
            e[k] = 1e-6
            jac[:, :, k] = (self.warp.pixels(d + e, x) - self.warp.pixels(d - e, x)) / 2e-6
        return jac

    def too_few(self, n: int) -> SkyrigError:
        return SkyrigError(f"image {self.name!r} (beta {np.degrees(self.beta_rad):.3f} deg): only {n} correlation "
                           f"windows agree with the reference image (need {self.min_windows}); is the offset larger "
                           "than the search range?")


def _solve(obs: NDArray[np.float64], jac: NDArray[np.float64], gain: float, use: NDArray[np.bool_]
           ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Least-squares step (radians) from the window shifts ``obs[use]`` and its residuals (reported pixels)."""
    a_mat = gain * jac[use].reshape(-1, 3)
    o = obs[use].reshape(-1)
    step, *_ = np.linalg.lstsq(a_mat, o, rcond=None)
    return step, o - a_mat @ step


def _gauss_newton(cmp: _WindowComparison, iterations: int, reject_k: float, converge_sigma: float
                  ) -> tuple[int, NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """The iteration of :func:`measure_position_offset` until the full update is below ``converge_sigma`` of the
    estimate's own sigma: ``(last iteration, correction, window shifts there, jacobian there, windows kept)``.

    Phase correlation with a Hann window reports a sub-pixel shift scaled by a gain g (about 1.45 near zero shift
    for this texture, about 1 at a pixel): the iteration updates g by the secant (the change of the shifts against
    the predicted change); :func:`_finish_with_probed_gain` measures it at convergence."""
    name, min_windows = cmp.name, cmp.min_windows
    d = np.zeros(3)
    obs = cmp.compare(d, cmp.w0, cmp.ok0)
    jac = cmp.jacobian(d)
    gain = 1.0
    keep = np.ones(len(cmp.tiles), bool)
    rejected = False
    converged = False
    step = np.zeros(3)
    use = keep
    damping, last_move = 1.0, None
    for it in range(int(iterations)):
        use = keep & np.all(np.isfinite(obs), axis=1)
        if use.sum() < min_windows:
            raise cmp.too_few(int(use.sum()))
        step, res = _solve(obs, jac, gain, use)
        if not rejected and it >= 1:  # reject gross windows once, after a first update
            rejected = True
            r2 = np.hypot(*res.reshape(-1, 2).T)
            bad = r2 > reject_k * (np.median(r2) / 1.1774 + 1e-12)  # Rayleigh median -> sigma per coordinate
            if bad.any() and (~bad).sum() >= min_windows:
                keep[np.flatnonzero(use)[bad]] = False
                use = keep & np.all(np.isfinite(obs), axis=1)
                step, res = _solve(obs, jac, gain, use)
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
        obs = cmp.compare(d)
        jac = cmp.jacobian(d)
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
        raise SkyrigError(f"image {name!r} (beta {np.degrees(cmp.beta_rad):.3f} deg): the angular offset did not "
                          f"converge in {iterations} iterations (last update "
                          f"{1000 * np.degrees(np.abs(step)).max():.3f} mdeg)")
    return it, d, obs, jac, keep


def _finish_with_probed_gain(cmp: _WindowComparison, it: int, d: NDArray[np.float64], obs: NDArray[np.float64],
                             jac: NDArray[np.float64], keep: NDArray[np.bool_], ifov: float) -> PositionOffset:
    """The last step of :func:`measure_position_offset`: the correlation's gain measured by a symmetric probe (the
    reference warped with a known extra rotation of +-0.03 px), divided out of the last step and of the residuals
    (the estimate's error is the shift noise / g), and the covariance from the window residuals."""
    name, min_windows = cmp.name, cmp.min_windows
    probe = np.full(3, 0.03 * ifov / np.sqrt(3))
    o_p, o_m = cmp.compare(d + probe), cmp.compare(d - probe)
    use = keep & np.all(np.isfinite(obs), axis=1) & np.all(np.isfinite(o_p), axis=1) & np.all(np.isfinite(o_m), axis=1)
    if use.sum() < min_windows:
        raise cmp.too_few(int(use.sum()))
    a_ = (2 * jac[use] @ probe).reshape(-1)
    b_ = (o_m[use] - o_p[use]).reshape(-1)
    gain = float(a_ @ b_ / (a_ @ a_))
    e_ = b_ - gain * a_
    gain_se = float(np.sqrt(e_ @ e_ / max(e_.size - 1, 1) / (a_ @ a_)))
    # the correlation must follow the known rotation: a gain far from zero against its own standard error (unrelated
    # images give a gain about zero), and not above 4 (~1.45 on the lab at 320 px, 0.2-0.4 at 640 px, where the
    # texture is smooth across the pixels and the whitened correlation peak is broad)
    if not (gain > 3.0 * gain_se and gain < 4.0):
        raise SkyrigError(f"image {name!r} (beta {np.degrees(cmp.beta_rad):.3f} deg): the correlation does not follow "
                          f"a known rotation of the reference (gain {gain:.2f} +- {gain_se:.2f}); are the images of "
                          "the same textured plane, and the rig's orientations right?")
    step, res = _solve(obs, jac, gain, use)
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
