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

Modules: :mod:`~skyrig.calibrate.tumbling_setup` (the lab set-up), :mod:`~skyrig.calibrate.tumbling_offset` (steps
2-3), :mod:`~skyrig.calibrate.tumbling_result` (step 4: the result, Tab. 2, the report),
:mod:`~skyrig.calibrate.tumbling_fourier` (step 5: the Fourier series, the repeating share); this module runs the
sequence and re-exports their names.  :mod:`~skyrig.calibrate.tumbling_reference` checks that the reference camera
did not move over the session (the paper's block matching; ``calibrate tumbling-head --reference-series``) and
:mod:`~skyrig.calibrate.tumbling_simulation` simulates the lab with its truth.

Frames and units: the lab frame is a local Cartesian frame (ENU axes, metres) with the sensor head at its origin,
body x along north, y east, z down; the plane is ``z = -plane_distance_m`` (the floor seen straight below the head).
Angles in the data are radians; tables are in degrees (and 1/1000 deg as the paper prints them).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.calibrate.tumbling_fourier import (
    FourierCurve,
    RepeatShare,
    default_max_order,
    estimate_repeat_share,
    fit_fourier_curve,
    fourier_design,
)
from skyrig.calibrate.tumbling_offset import (  # noqa: F401  (_cubic_sample*: the kernel's test reads them here)
    PositionOffset,
    _cubic_sample,
    _cubic_sample_kernel,
    _reference_gray,
    measure_position_offset,
)
from skyrig.calibrate.tumbling_result import FailedImage, TumblingCalibration, _failed_list
from skyrig.calibrate.tumbling_setup import ENU_FROM_BODY, LabSetup
from skyrig.errors import SkyrigError
from skyrig.rig.boresight_curve import BoresightCurve

log = logging.getLogger(__name__)

__all__ = ["LabSetup", "PositionOffset", "TumblingCalibration", "FailedImage", "FourierCurve", "RepeatShare",
           "measure_position_offset", "calibrate_tumbling_head", "fit_fourier_curve", "fourier_design",
           "estimate_repeat_share", "default_max_order", "ENU_FROM_BODY"]


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
    labels, pos = _positions(names, circ, beta, min_circles, max_failed_share)
    # one reference for every image (checked and converted to grey once): its size is not a per-image failure
    ref_gray = _reference_gray(setup, reference_image)
    meas, sig, cov, nam, win, failed = _measure_circles(setup, images, names, circ, beta, labels, pos, ref_gray,
                                                        window_px, max_failed_share)
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


def _positions(names: NDArray[np.str_], circ: NDArray[np.str_], beta: NDArray[np.float64], min_circles: int,
               max_failed_share: float) -> tuple[list[str], NDArray[np.float64]]:
    """The circle labels (in order of appearance) and the sorted actuator positions (degrees in [0, 360), rounded
    to 1e-6) every circle must hold, checked before anything is measured."""
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
    for lab in labels:  # check every circle before measuring anything
        keys = np.round(np.degrees(beta[circ == lab]) % 360.0, 6)
        if keys.size != k_pos or not np.array_equal(np.sort(keys), pos):
            missing = sorted(set(pos.tolist()) ^ set(keys.tolist()))
            raise SkyrigError(f"tumbling-head: circle {lab!r} does not hold the same actuator positions as circle "
                              f"{labels[0]!r} (differing: {', '.join(f'{m:g}' for m in missing[:8])} deg)")
    return labels, pos


def _measure_circles(setup: LabSetup, images: Callable[[str], NDArray[np.uint8]], names: NDArray[np.str_],
                     circ: NDArray[np.str_], beta: NDArray[np.float64], labels: list[str], pos: NDArray[np.float64],
                     ref_gray: NDArray[np.float32], window_px: int, max_failed_share: float
                     ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[Any],
                                NDArray[np.int64], list[FailedImage]]:
    """Every tumbling image measured (:func:`measure_position_offset`): ``(C, K, 3)`` corrections and sigmas,
    ``(C, K, 3, 3)`` covariances (NaN where left out), ``(C, K)`` names and windows, and the images left out; more
    than ``max_failed_share`` failed images stop it."""
    k_pos = pos.size
    meas = np.full((len(labels), k_pos, 3), np.nan)
    sig = np.full((len(labels), k_pos, 3), np.nan)
    cov = np.full((len(labels), k_pos, 3, 3), np.nan)
    nam = np.empty((len(labels), k_pos), dtype=object)
    win = np.zeros((len(labels), k_pos), np.int64)
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
    return meas, sig, cov, nam, win, failed
